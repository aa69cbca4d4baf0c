"""``jaxtree sample`` (and ``python -m jaxtree`` with no subcommand): the seed's sample problem,
Sec. II E (Fig. 4), end to end: one run per attitude formulation, each timed apart from its
programs' preparation, the files and plot written while the same runs at 10x the tolerances
estimate the integration error, and a summary."""

from __future__ import annotations

import concurrent.futures
import contextlib
import os
import sys
import threading
import time
from typing import Any

import jax
import numpy as np

import jaxtree

from .. import programs
from ..integration.save_grid import save_points
from ..integration.simulate import simulate
from ..io import output
from ..io.result_files import command_line, save_result
from .common import Parser, fast_cpu_compiler, open_scene, start_warming

# `python -m jaxtree` runs jaxtree/__main__.py: the sample problem is named so there
_MAIN_FILE = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "__main__.py")
SAMPLE_DESCRIPTION = "``python -m jaxtree``: the sample problem of Sec. II E (Fig. 4) end to end."


def _sample_parser():
    # the name it was started by: `python -m jaxtree` runs this file, the `jaxtree` script the command line
    started_here = os.path.abspath(sys.argv[0]) == _MAIN_FILE
    prog = "python -m jaxtree" if started_here else "jaxtree sample"
    p = Parser(prog=prog, description=SAMPLE_DESCRIPTION)
    p.add_argument("--scene", default="fig4", help="bundled scene name or path to a scene JSON (default: fig4)")
    p.add_argument("--duration", type=float, default=100.0, help="simulated time in seconds (default: 100)")
    p.add_argument(
        "--points",
        type=int,
        default=None,
        help="number of saved times (default: 20 per period of the fastest sprung hinge, at least 101; 3384 for fig4)",
    )
    p.add_argument(
        "--attitudes",
        default="euler123,quaternion",
        help="comma-separated attitude variables: euler123, quaternion, dcm (default: euler123,quaternion)",
    )
    p.add_argument("--rtol", type=float, default=1e-9, help="relative tolerance (default: 1e-9)")
    p.add_argument("--atol", type=float, default=1e-9, help="absolute tolerance (default: 1e-9)")
    p.add_argument("--out", default="results", help="output folder (default: ./results)")
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="do not show each run's elapsed time as it goes (shown on a terminal only)",
    )
    p.add_argument("--no-plot", action="store_true", help="do not write the plot")
    return p


@contextlib.contextmanager
def elapsed(label: str, show: bool):
    """On a terminal (`show`), ``label: N s`` on stderr, redrawn every half second while the block
    runs and erased when it ends; elsewhere nothing. Drawn by a thread of this process (XLA
    releases Python's lock while it compiles and integrates), not by a progress meter inside the
    integration: that is a host callback, and a program with one can be neither exported nor
    kept in the compilation cache, so every process would trace and compile it again."""
    if not show:
        yield
        return
    stop = threading.Event()
    start = time.perf_counter()

    def draw():
        while not stop.wait(0.5):
            sys.stderr.write(f"\r   {label}: {time.perf_counter() - start:.0f} s elapsed")
            sys.stderr.flush()

    ticker = threading.Thread(target=draw, name="jaxtree-elapsed", daemon=True)
    ticker.start()
    try:
        yield
    finally:
        stop.set()
        ticker.join()
        sys.stderr.write("\r\033[K")
        sys.stderr.flush()


def sample(argv=None) -> int:
    """The sample problem (``python -m jaxtree`` with no subcommand, or ``jaxtree sample``)."""
    args = _sample_parser().parse_args(argv)
    fast_cpu_compiler()
    start = time.perf_counter()

    model = open_scene(args.scene)
    # each run's elapsed time on a terminal only: redrawn into a log it is kilobytes of noise
    show_progress = not args.no_progress and sys.stderr.isatty()
    attitudes = [a.strip() for a in args.attitudes.split(",") if a.strip()]
    # save points that draw the fastest panel's oscillation as a smooth curve (numpy on the scene)
    points = args.points if args.points is not None else save_points(model, args.duration)[0]
    out = os.path.abspath(args.out)
    print(
        f"jaxtree {jaxtree.__version__}: scene {model.name!r} ({model.n + 1} bodies, prescribed hinges "
        f"{list(model.prescribed)}), {args.duration:g} s ({points} save points), rtol {args.rtol:g}, atol {args.atol:g}, "
        f"JAX {jax.__version__} on {jax.default_backend()}"
    )
    runs, times = {}, {}
    # the writers' imports and first use on a thread meanwhile (output.warm_writers); the two
    # attitudes run one after the other: side by side on two threads, each compile and each
    # integration slowed down (XLA:CPU already spreads its compilation and some kernels over the
    # cores; the first run took 55 s instead of 45-49 s, the second no less, measured on
    # 2026-11-28 before the diagnostics loop of run_diagnostics)
    warming = start_warming(plot=not args.no_plot)
    for att in attitudes:
        runs[att], times[att] = _timed_run(model, args, att, points, show_progress)
    loose, written, plotted = _write_while_estimating(model, args, runs, points, out, warming)

    _print_summaries(runs, loose, times)
    if plotted is False:
        print("matplotlib is not installed: no plot (pip install matplotlib)")
    print(f"wrote {', '.join(written)} to {out}")
    print(f"total wall time {time.perf_counter() - start:.1f} s")
    return 0 if all(s.ok for s in runs.values()) else 1


def _timed_run(model, args, att, points, show_progress):
    """One attitude's run: its solution and (first call, run alone) wall times in seconds."""
    kw: dict[str, Any] = dict(attitude=att, saveat=points, rtol=args.rtol, atol=args.atol)
    print(f"-- {att}: running (the summary below splits program preparation from the run)", flush=True)
    with programs.PREPARED.timing(), elapsed(att, show_progress):
        mark = programs.PREPARED.mark()
        t0 = time.perf_counter()
        sol = simulate(model, args.duration, **kw)
        jax.block_until_ready(sol.gamma)
        first = time.perf_counter() - t0
    prepared, timed = programs.PREPARED.since(mark)
    if timed:  # every program's preparation was timed: the run is the rest
        wall = first - prepared
    else:  # a program compiled inside its call (the kept programs off): again, compiled
        t0 = time.perf_counter()
        sol = simulate(model, args.duration, **kw)
        jax.block_until_ready(sol.gamma)
        wall = time.perf_counter() - t0
    return sol, (first, wall)


def _write_while_estimating(model, args, runs, points, out, warming):
    """The runs at 10x the tolerances (by attitude), while the files and the plot are written;
    returns them, the files written and whether the plot was (None: not asked for)."""

    # The integration error: the same runs at 10x the tolerances (the tolerances are not compiled
    # in: the same programs), over all saved times. They run one after the other on a worker
    # thread (XLA releases Python's lock while it integrates) while this one writes the files and
    # the plot on the other core (two workers: three busy threads on two cores, and the figure
    # took 2.8-3.0 s instead of 2.2 on the 2-core reference machine).
    def loose_run(att):
        return simulate(model, args.duration, attitude=att, saveat=points, rtol=10 * args.rtol, atol=10 * args.atol)

    with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
        loose = {att: pool.submit(loose_run, att) for att in runs}
        warming.join()
        written, plotted = _write_files(model, args, runs, out)
        loose = {att: f.result() for att, f in loose.items()}
    return loose, written, plotted


def _write_files(model, args, runs, out):
    """The histories (npz, and per attitude a result file and a CSV) and the plot in folder `out`;
    returns the names written and whether the plot was (None: not asked for)."""
    os.makedirs(out, exist_ok=True)
    stem = model.name or "scene"
    output.save_npz(os.path.join(out, f"{stem}_histories.npz"), runs)
    written = [f"{stem}_histories.npz"]
    for att, sol in runs.items():
        # the result file of `jaxtree simulate` (jaxtree.load_result, `jaxtree plot` and
        # `animate` read it), and the same histories as CSV
        save_result(os.path.join(out, f"{stem}_{att}.nc"), sol, {"command": command_line()})
        output.save_csv(os.path.join(out, f"{stem}_{att}.csv"), sol)
        written += [f"{stem}_{att}.nc", f"{stem}_{att}.csv"]
    plotted = None
    if not args.no_plot:
        title = f"{stem}: {args.duration:g} s, " + " vs ".join(runs)
        plotted = output.save_plot(os.path.join(out, f"{stem}.png"), runs, title=title)
        if plotted:
            written.append(f"{stem}.png")
    return written, plotted


def _error_estimate(sol, other) -> dict[str, float]:
    """The largest differences of a run from the same run at 10x the tolerances (`other`)."""
    return {
        "gamma": float(np.max(np.abs(np.asarray(other.gamma) - np.asarray(sol.gamma)))),
        "rates": max(
            float(np.max(np.abs(np.asarray(other.gamma_dot) - np.asarray(sol.gamma_dot)))),
            float(np.max(np.abs(np.asarray(other.omega0) - np.asarray(sol.omega0)))),
        ),
        "dcm": float(np.max(np.abs(np.asarray(other.dcm) - np.asarray(sol.dcm)))),
    }


def _print_summaries(runs, loose, times):
    """Each run's summary with its error estimate, and how far the attitudes' runs differ."""
    lines = []
    for att, sol in runs.items():
        first, wall = times[att]
        lines.append(output.summary(att, sol, wall=wall, first=first, estimate=_error_estimate(sol, loose[att])))
    print()
    print("\n".join(lines))
    if len(runs) > 1:
        names = list(runs)
        ref = runs[names[0]]
        for other in names[1:]:
            d = max(
                float(np.max(np.abs(np.asarray(getattr(runs[other], f)) - np.asarray(getattr(ref, f)))))
                for f in ("gamma", "omega0", "dcm")
            )
            print(f"max difference {other} vs {names[0]} (gamma, omega0, C over all saved times): {d:.3e}")
