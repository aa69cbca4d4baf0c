"""The ``jaxtree`` command's argparse parser: its subcommands, each with its one-line help,
description and options (the ``sample`` verb's own parser is in :mod:`.sample_problem`)."""

from __future__ import annotations

from ...bench import CASES as BENCH_CASES
from ..identify import command as identify_command
from .common import ATTITUDES, SOLVERS, Parser, count, finite, modes_arg, positive, vector3


def parser():
    p = Parser(
        prog="jaxtree",
        description="Dynamics of hinge-connected rigid-body trees (Likins, JPL TR 32-1565).",
        epilog="With no subcommand (or with options only), runs the seed's sample problem: "
        "see 'jaxtree sample --help'.",
    )
    p.add_argument("--version", action="store_true", help="print the versions and exit")
    sub = p.add_subparsers(dest="command", metavar="SUBCOMMAND", parser_class=Parser)
    for add in (
        _simulate_parser,
        _modes_parser,
        _animate_parser,
        _check_parser,
        _plot_parser,
        _identify_parser,
        _bench_parser,
    ):
        add(sub)
    sub.add_parser("sample", help="the seed's sample problem (the default without a subcommand)", add_help=False)
    return p


# the subcommands: one-line help (in `jaxtree --help`) and description (in their own help)
_COMMANDS = {
    "simulate": (
        "integrate a scene and write a NetCDF result",
        "Integrate Eq. (1) (or the hybrid-coordinate equations with --hybrid-small) "
        "and write the time histories to a NetCDF result file, in parts as the run "
        "goes (an interrupted run is readable and --resume continues it).",
    ),
    "modes": (
        "modes of the linearized small hinges: table, result file, shape plot",
        "Linearize the small hinges about a nominal motion (Eqs. 40-44) and print their "
        "modes (Eqs. 70-104): frequencies, damping, the coordinates that dominate each; "
        "write a modes result file and a plot of the mode shapes.",
    ),
    "animate": (
        "an HTML page animating a result",
        "Write an HTML page animating a simulation result, or one mode of a modes result.",
    ),
    "check": (
        "validate a scene and describe it",
        "Validate a scene; print its tree, the seed's Tables 1-2 (network and path "
        "elements), masses and the condition number of Eq. (1) at the initial state.",
    ),
    "plot": (
        "plots of a result file",
        "Plot a result: time histories and drift (simulation) or mode shapes (modes).",
    ),
    "identify": ("estimate parameters from a record of sensor readings", identify_command.DESCRIPTION),
    "bench": (
        "error against run time: solvers, formulations and peers",
        "Work-precision report: for each case, formulation (full Eq. 1, Eq. 30, hybrid) and solver, "
        "the error against a tight reference by a different solver and the run time, with the installed peers "
        "(Pinocchio + scipy, MuJoCo, Basilisk) in the same run. Writes OUT/work_precision.csv, .md and one "
        "PNG per case. Cases: " + ", ".join(BENCH_CASES) + " (default: all; --quick: wings).",
    ),
}


def _subparser(sub, name):
    short, description = _COMMANDS[name]
    return sub.add_parser(name, help=short, description=description)


def _simulate_parser(sub):
    s = _subparser(sub, "simulate")
    s.add_argument("scene", metavar="SCENE", help="scene JSON file (jaxtree-scene/1) or a bundled scene name")
    s.add_argument("--t1", type=finite(), required=True, help="end time (s)")
    s.add_argument("--t0", type=finite(), default=0.0, help="start time (s; default 0)")
    s.add_argument(
        "--points",
        type=count(2),
        help="number of evenly spaced save times (default: 20 per period of the fastest sprung hinge that "
        "still rings, at least 101)",
    )
    s.add_argument("--rtol", type=positive(), help="relative tolerance (default 1e-9)")
    s.add_argument("--atol", type=positive(), help="absolute tolerance (default 1e-9)")
    s.add_argument(
        "--solver",
        default="auto",
        type=str.lower,
        choices=sorted(SOLVERS),
        help="solver (default auto: dopri8 or radau5, whichever is predicted to reach the tolerance in "
        "less run time from the linearized equations at the start; radau5, kvaerno3/4/5 and kencarp4 "
        "are implicit)",
    )
    s.add_argument(
        "--attitude",
        default="quaternion",
        type=str.lower,
        choices=ATTITUDES,
        help="attitude variables of b0 (default quaternion)",
    )
    s.add_argument("--max-steps", type=count(), default=200_000, help="step limit of each part (default 200000)")
    _hybrid_options(s)
    s.add_argument(
        "--out", "-o", metavar="RESULT", help="result file (NetCDF; default SCENENAME.nc in the current folder)"
    )
    s.add_argument("--csv", metavar="FILE", help="also export the histories as CSV")
    s.add_argument(
        "--plot",
        metavar="PREFIX",
        help="plots PREFIX_histories.png and PREFIX_drift.png (default: the result's name without .nc)",
    )
    s.add_argument("--no-plot", action="store_true", help="write no plots")
    s.add_argument("--chunks", type=count(), default=10, help="number of parts the run is written in (default 10)")
    s.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted run of the same command from its last written part",
    )
    s.add_argument(
        "--no-error-estimate", action="store_true", help="skip the error estimate (a second run at 10x the tolerances)"
    )
    s.add_argument("--no-progress", action="store_true", help="no progress bar")


def _hybrid_options(s):
    """The options of `simulate` --hybrid-small."""
    s.add_argument(
        "--hybrid-small",
        metavar="HINGES",
        help="hybrid coordinates (Eqs. 105-123): the small hinges (indices, names, ranges a-b, or 'all') "
        "replaced by truncated modal coordinates; 'none' for the scene's finite-element appendages alone "
        "(a scene's appendages are always in modal coordinates here)",
    )
    s.add_argument(
        "--modes",
        type=modes_arg,
        metavar="K",
        help="with --hybrid-small: modes retained per substructure (each connected group of small "
        "hinges, e.g. one wing; the lowest first, a repeated frequency kept whole), or 'auto': per "
        "substructure the fewest whose neglected share of the quasi-static response to the base's "
        "motion is at most --modes-tol (default all)",
    )
    s.add_argument(
        "--modes-tol",
        type=positive(),
        metavar="TOL",
        help="with --modes auto: the neglected share allowed (default 0.01)",
    )
    s.add_argument("--cutoff", type=positive(), help="with --hybrid-small: retain modes up to this frequency (rad/s)")
    _nominal_options(
        s,
        "--modal-damping",
        spin="with --hybrid-small: nominal omega0 of the modes, wx,wy,wz in {b0} (rad/s; default the "
        "scene's initial omega0)",
        damping="with --hybrid-small: modal damping ratio of the retained modes",
    )


def _nominal_options(p, damping_flag, *, spin, damping):
    """--spin and a damping ratio: the nominal motion of modes (`modes`, `simulate --hybrid-small`)."""
    p.add_argument("--spin", type=vector3(), help=spin)
    p.add_argument(damping_flag, type=finite(), metavar="ZETA", help=damping)


def _modes_parser(sub):
    m = _subparser(sub, "modes")
    m.add_argument("scene", metavar="SCENE", help="scene JSON file or a bundled scene name")
    m.add_argument(
        "--small",
        default="all",
        metavar="HINGES",
        help="the small hinges: indices, names, ranges a-b, or 'all' (default: every hinge that is not "
        "prescribed or inert), or 'none'; a scene's finite-element appendages join with their modal coordinates",
    )
    _nominal_options(
        m,
        "--damping",
        spin="nominal omega0, one number (about b0's axis 3) or wx,wy,wz in {b0} (rad/s; default 0)",
        damping="modal damping ratio added to every mode (Eq. 104)",
    )
    m.add_argument("--out", "-o", metavar="RESULT", help="modes result file (default SCENENAME_modes.nc)")
    m.add_argument("--plot", metavar="PNG", help="mode-shape plot (default: the result's name, .png)")
    m.add_argument("--no-plot", action="store_true", help="write no plot")
    m.add_argument("--show", type=count(), default=6, metavar="K", help="modes drawn in the plot (default 6)")


def _animate_parser(sub):
    a = _subparser(sub, "animate")
    a.add_argument("result", metavar="RESULT", help="result file of 'jaxtree simulate' or 'jaxtree modes'")
    a.add_argument("-o", "--out", required=True, metavar="PAGE", help="HTML file to write")
    a.add_argument(
        "--mode", type=count(), metavar="K", help="with a modes result: the mode to animate (1 = lowest; default 1)"
    )
    a.add_argument("--amplitude", type=positive(), help="with --mode: largest hinge angle of the oscillation (rad)")
    a.add_argument("--title", help="page title")
    a.add_argument(
        "--scale",
        type=positive(),
        default=1.0,
        metavar="FACTOR",
        help="finite-element appendages' output nodes drawn at FACTOR times their displacement (default 1)",
    )


def _check_parser(sub):
    c = _subparser(sub, "check")
    c.add_argument("scene", metavar="SCENE", help="scene JSON file or a bundled scene name")
    c.add_argument("--tables", action="store_true", help="print Tables 1-2 for any number of hinges")


def _plot_parser(sub):
    pl = _subparser(sub, "plot")
    pl.add_argument("result", metavar="RESULT", help="result file")
    pl.add_argument("-o", "--out", metavar="PREFIX", help="file name prefix (default: RESULT without .nc)")


def _identify_parser(sub):
    identify_command.add_arguments(_subparser(sub, "identify"))


def _bench_parser(sub):
    b = _subparser(sub, "bench")
    b.add_argument("cases", metavar="CASE", nargs="*", help="bench cases (see above), or stiff_<scale>")
    b.add_argument(
        "-o", "--out", default="work_precision", metavar="DIR", help="output folder (default work_precision)"
    )
    b.add_argument("--quick", action="store_true", help="a short run: wings, four solvers, two tolerances")
    b.add_argument("--solvers", nargs="+", metavar="NAME", help="solver names (default all)")
    b.add_argument("--tols", nargs="+", type=positive(), metavar="TOL", help="tolerance ladder")
    b.add_argument("--no-peers", action="store_true", help="leave the peers out")
    b.add_argument("--no-plots", action="store_true", help="CSV and Markdown only")
    b.add_argument("--repeats", type=count(1), help="timed calls after the first (default 3)")
    b.add_argument("--no-progress", action="store_true", help="no progress bar")
    b.add_argument(
        "--merge",
        nargs="+",
        metavar="DIR",
        help="merge the reports saved in these folders (runs of parts of the cases) into --out; runs nothing",
    )
