"""``python -m jaxtree``: the sample problem of Sec. II E (Fig. 4) end to end.

With a subcommand (``simulate``, ``modes``, ``animate``, ``check``, ``plot``) this is the
``jaxtree`` command line of :mod:`jaxtree.cli`; with no subcommand it runs the sample problem.

Runs ``fig4`` (gamma_1 = sin 0.5 t prescribed, rotor at 10 pi rad/s, sprung panels) for 100 s,
once with the Euler angles of Eqs. (23)-(24) and once with quaternions, prints a summary (final
state, energy and momentum drift, steps, wall time), and writes the time histories (``.npz`` and
one ``.csv`` per run) and a plot into the output folder.
"""

from __future__ import annotations

import contextlib
import io
import os
import sys
import time


def _fast_cpu_compiler():
    # XLA:CPU's older LLVM emitters compile these many small fusions about twice as fast as the
    # default fusion emitters, with the same run time. Only effective before JAX starts its CPU
    # backend, which importing jaxtree does not do; an explicit XLA_FLAGS setting wins.
    flag = "--xla_cpu_use_fusion_emitters=false"
    current = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" not in current:
        os.environ["XLA_FLAGS"] = f"{current} {flag}".strip()


def _parser():
    from ._src.cli import _Parser

    # the name it was started by: `python -m jaxtree` runs this file, the `jaxtree` script the command line
    started_here = os.path.abspath(sys.argv[0]) == os.path.abspath(__file__)
    prog = "python -m jaxtree" if started_here else "jaxtree sample"
    p = _Parser(prog=prog, description=(__doc__ or "").split("\n\n")[0])
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
        "--no-progress", action="store_true", help="do not show the progress meter (shown on a terminal only)"
    )
    p.add_argument("--no-plot", action="store_true", help="do not write the plot")
    return p


def main(argv=None) -> int:
    """The ``jaxtree`` command: a subcommand of :mod:`jaxtree.cli`, else the sample problem."""
    from ._src.cli import main as cli_main

    return cli_main(argv)


def sample(argv=None) -> int:
    """The sample problem (``python -m jaxtree`` with no subcommand, or ``jaxtree sample``)."""
    args = _parser().parse_args(argv)
    _fast_cpu_compiler()
    start = time.perf_counter()

    import jax
    import numpy as np

    import jaxtree
    from jaxtree._src import output
    from jaxtree._src.results import command_line, save_result

    from ._src.autosolver import save_points
    from ._src.cli import _load_scene

    model = _load_scene(args.scene)
    # a progress bar on a terminal only: redrawn into a log it is kilobytes of noise
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
    runs, lines = {}, []
    for att in attitudes:
        kw = dict(attitude=att, saveat=points, rtol=args.rtol, atol=args.atol)
        print(f"-- {att}: compiling and running")
        t0 = time.perf_counter()
        sol = jaxtree.simulate(model, args.duration, progress=show_progress, **kw)
        jax.block_until_ready(sol.gamma)
        first = time.perf_counter() - t0
        # Again, now compiled, for the run time alone (same configuration, meter output muted).
        with contextlib.redirect_stdout(io.StringIO()):
            t0 = time.perf_counter()
            sol = jaxtree.simulate(model, args.duration, progress=show_progress, **kw)
            jax.block_until_ready(sol.gamma)
            jax.effects_barrier()
            wall = time.perf_counter() - t0
        runs[att] = sol
        lines.append(output.summary(att, sol, wall=wall, first=first))
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

    os.makedirs(out, exist_ok=True)
    stem = model.name or "scene"
    output.save_npz(os.path.join(out, f"{stem}_histories.npz"), runs)
    written = [f"{stem}_histories.npz"]
    for att, sol in runs.items():
        # the result file of `jaxtree simulate` (jaxtree.load_result, `jaxtree plot` and `animate`
        # read it), and the same histories as CSV
        save_result(os.path.join(out, f"{stem}_{att}.nc"), sol, {"command": command_line()})
        output.save_csv(os.path.join(out, f"{stem}_{att}.csv"), sol)
        written += [f"{stem}_{att}.nc", f"{stem}_{att}.csv"]
    if not args.no_plot:
        if output.save_plot(
            os.path.join(out, f"{stem}.png"), runs, title=f"{stem}: {args.duration:g} s, " + " vs ".join(runs)
        ):
            written.append(f"{stem}.png")
        else:
            print("matplotlib is not installed: no plot (pip install matplotlib)")
    print(f"wrote {', '.join(written)} to {out}")
    print(f"total wall time {time.perf_counter() - start:.1f} s")
    return 0 if all(s.ok for s in runs.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
