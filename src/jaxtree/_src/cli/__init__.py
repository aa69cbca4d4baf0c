"""The ``jaxtree`` command line: from a scene file to results, plots and an animation.

Subcommands (``jaxtree SUBCOMMAND --help`` for each):

- ``simulate SCENE --t1 T``: integrate Eq. (1) (or the hybrid-coordinate equations with
  ``--hybrid-small``) and write a NetCDF result, written in parts as the run goes (``--resume``
  continues an interrupted run), with a summary: steps, an error estimate, energy and momentum
  drift;
- ``modes SCENE --small ...``: the modes of the linearized small hinges (Eqs. 40-104): a
  frequency table with labels and damping, a modes result file and a mode-shape plot;
- ``animate RESULT -o page.html``: an HTML page animating a simulation, or one mode (``--mode``)
  of a modes result;
- ``check SCENE``: validate a scene; its tree, the seed's Tables 1-2, masses and the condition
  number of Eq. (1) at the initial state;
- ``plot RESULT``: the plots of a result file;
- ``identify SCENE RECORD --free ... --sigma ...``: estimate named parameters from a record of
  sensor readings (:func:`jaxtree.identify`; :mod:`~jaxtree._src.identify.command`);
- ``bench [CASE ...]``: error against run time for each solver, formulation and peer: a CSV,
  a Markdown report and one work-precision plot per case (:func:`jaxtree.work_precision`);
- ``sample`` (also: no subcommand at all): the seed's sample problem (``python -m jaxtree``).

A user's mistake (a missing file, an invalid scene, a bad option) prints one line naming what
is wrong and exits with status 2; a run that fails numerically prints its diagnosis (time,
state) and exits with status 1; an interrupted run (Ctrl-C, SIGTERM) keeps what it computed and
exits with status 130.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import os
import pathlib
import signal
import sys
import threading
import time
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

from ...bench import SOLVERS as BENCH_SOLVERS
from ...bench import BenchReport, bench_case, work_precision
from .. import programs
from ..appendage.files import scene_appendages
from ..campaigns.chunked import ChunkedRunError, chunked_config, simulate_to_file
from ..campaigns.chunked import solver_named as solver_named
from ..hybrid.linear import linearize
from ..identify import command as identify_command
from ..integration.autosolver import MAX_SAVE_POINTS, SAMPLES_LEAST, SAMPLES_PER_PERIOD, samples_per_period, save_points
from ..integration.simulate import simulate
from ..io import output, plots
from ..io.drift import change_text, drift_causes, near_zero
from ..io.results import command_line, modes_dataset, save_result, to_solution, versions, write_netcdf
from ..linear.linearize import structure
from ..linear.modes import ModalError, modes
from ..scene.check import check_scene
from ..scene.scene import SceneError
from .common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    EXIT_USAGE,
    SOLVERS,
    SUBCOMMANDS,
    UserError,
)
from .common import Parser as _Parser
from .common import existing as _existing
from .common import fast_cpu_compiler as _fast_cpu_compiler
from .common import hinges as _hinges
from .common import model_of as _model_of
from .common import open_result as _load_result
from .common import open_scene as _load_scene
from .common import say as _say
from .common import start_warming as _warming
from .common import use_matplotlib as _matplotlib
from .common import wrote as _wrote
from .parser import parser as _parser

# Seconds to sleep after each part of `simulate` is written: lets a test interrupt a run
# between parts deterministically. Not for users.
CHUNK_DELAY_ENV = "JAXTREE_CHUNK_DELAY"


class _Interrupted(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C."""


# ----------------------------------------------------------------------------- main
@contextlib.contextmanager
def _one_line_warnings(command: str):
    """Warnings printed as one line, ``<command>: warning: <message>``, without Python's source
    location (which named the ``jaxtree`` launcher script, not the user's mistake)."""
    saved = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        print(f"{command}: warning: {text}", file=file or sys.stderr, flush=True)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = saved


def main(argv=None) -> int:
    """The ``jaxtree`` command: a subcommand, else the sample problem (:func:`sample`)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    name = f"jaxtree {argv[0]}" if argv and argv[0] in SUBCOMMANDS else "jaxtree"
    with _one_line_warnings(name):
        return _main(argv)


def _main(argv) -> int:
    if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version")):
        argv = ["sample"] + argv
    if argv[0] == "sample":
        try:
            return sample(argv[1:])
        except UserError as e:
            _say(f"{e.prog or 'python -m jaxtree'}: error: {e}")
            return EXIT_USAGE
    command = f"jaxtree {argv[0]}" if argv[0] in SUBCOMMANDS else "jaxtree"
    try:
        args = _parser().parse_args(argv)
        args.argv = argv
        if args.version:
            _fast_cpu_compiler()
            print(
                " ".join(f"{k.removesuffix('_version')} {v}" for k, v in versions().items() if k.endswith("_version"))
            )
            return 0
        if args.command is None:
            _parser().print_help()
            return EXIT_USAGE
        _fast_cpu_compiler()
        return {
            "simulate": cmd_simulate,
            "modes": cmd_modes,
            "animate": cmd_animate,
            "check": cmd_check,
            "plot": cmd_plot,
            "identify": cmd_identify,
            "bench": cmd_bench,
        }[args.command](args)
    except UserError as e:
        _say(f"{e.prog or command}: error: {e}")
        return EXIT_USAGE


# ----------------------------------------------------------------------------- bench
def cmd_bench(args) -> int:
    cases = []
    for name in args.cases:
        try:
            cases.append(bench_case(name))
        except ValueError as e:
            raise UserError(str(e)) from None
    by_lower = {k.lower(): k for k in BENCH_SOLVERS}
    solvers = None
    if args.solvers:
        bad = [s for s in args.solvers if s.lower() not in by_lower]
        if bad:
            raise UserError(f"unknown solver(s) {', '.join(bad)}; known: {', '.join(BENCH_SOLVERS)}")
        solvers = [by_lower[s.lower()] for s in args.solvers]
    if not args.no_plots:
        _matplotlib()
    command = "jaxtree " + " ".join(getattr(args, "argv", ["bench"]))
    if args.merge:
        parts = []
        for d in args.merge:
            try:
                parts.append(BenchReport.load(d))
            except (OSError, ValueError, TypeError) as e:
                raise UserError(f"--merge: no report in {d!r} ({e})") from None
        report = BenchReport.merge(parts, command=command.strip())
        paths = report.save(args.out, plots=not args.no_plots)
        _say(f"wrote {paths['csv']}, {paths['md']} ({len(report.rows)} runs from {len(parts)} reports)")
        return 0
    t = time.perf_counter()
    report = work_precision(
        cases or None,
        solvers=solvers,
        tolerances=args.tols,
        peers=not args.no_peers,
        quick=args.quick,
        repeats=args.repeats,
        progress=not args.no_progress,
        command=command.strip(),
        on_case=lambda partial: partial.save(args.out, plots=not args.no_plots),
    )
    paths = report.save(args.out, plots=not args.no_plots)
    for case in report.cases():
        print(f"{case}:")
        for line in report.summary(case):
            print("  " + line.removeprefix("- "))
    failed = [r for r in report.rows if r["status"] == "failed"]
    _say(f"wrote {paths['csv']}, {paths['md']} ({len(report.rows)} runs, {time.perf_counter() - t:.0f} s)")
    if failed:
        _say(f"{len(failed)} runs failed: see the report's notes")
    return 0


# ----------------------------------------------------------------------------- check
def cmd_identify(args) -> int:
    model = _load_scene(args.scene)
    try:
        return identify_command.run(args, model, matplotlib_ok=not args.no_plot and _matplotlib())
    except SceneError as e:
        raise UserError(str(e).removeprefix("identify: ")) from None


def cmd_check(args) -> int:
    model = _load_scene(args.scene)
    src = pathlib.Path(args.scene)
    report = dataclasses.replace(
        check_scene(model), source=str(src) if src.exists() else f"bundled scene {args.scene!r}"
    )
    print(report.format(tables=True if args.tables else None))
    return 0


# ----------------------------------------------------------------------------- simulate
def _config(args, model):
    """The run's configuration (:func:`~jaxtree._src.campaigns.chunked.chunked_config` of the options)."""
    return chunked_config(
        model,
        args.t1,
        t0=args.t0,
        points=_save_points(args, model),
        chunks=args.chunks,
        solver=SOLVERS[args.solver],
        rtol=args.rtol,
        atol=args.atol,
        attitude=args.attitude,
        max_steps=args.max_steps,
        hybrid_small=args.hybrid_small,
        modes=args.modes,
        modes_tol=args.modes_tol,
        cutoff=args.cutoff,
        spin=args.spin,
        modal_damping=args.modal_damping,
    )


def _save_points(args, model) -> int:
    """--points, or by default enough for the fastest motion that rings; a note where too few."""
    span = float(args.t1 - args.t0)
    default, rate = save_points(model, span)
    points = default if args.points is None else int(args.points)
    per = samples_per_period(points, span, rate)
    if args.points is not None and per < SAMPLES_LEAST:
        _say(
            f"note: {points} save points sample the fastest hinge motion ({rate:.3g} rad/s) {per:.1f} times a "
            f"period: its curves will look jagged (the default here is {default})"
        )
    elif args.points is None and per < SAMPLES_PER_PERIOD and default == MAX_SAVE_POINTS:
        _say(
            f"note: the default {points} save points sample the fastest hinge motion ({rate:.3g} rad/s) only "
            f"{per:.1f} times a period; give --points for more"
        )
    return points


class _Meter:
    """The progress of `simulate`: a bar on a terminal (where tqdm is installed), and the pause
    after each part that CHUNK_DELAY_ENV asks for."""

    def __init__(self, args):
        self.show = not args.no_progress and sys.stderr.isatty()
        self.delay = float(os.environ.get(CHUNK_DELAY_ENV, "0") or 0)
        self.bar = None
        self.started = False

    def __call__(self, done, total):
        if not self.started:
            self.bar = _progress_bar(total, done) if self.show else None
        elif self.bar is not None:
            self.bar.update(done - self.bar.n)
        if self.started and self.delay:
            time.sleep(self.delay)
        self.started = True
        if done >= total:
            self.close()

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None


@contextlib.contextmanager
def _elapsed(label: str, show: bool):
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


def _progress_bar(total, initial):
    try:
        from tqdm import tqdm  # optional: no bar without it
    except ImportError:
        return None
    return tqdm(
        total=total,
        initial=initial,
        unit="s",
        file=sys.stderr,
        leave=False,
        bar_format="{l_bar}{bar}| t = {n:.4g} of {total:.4g} s [{elapsed}<{remaining}]",
    )


@contextlib.contextmanager
def _interrupts():
    """SIGTERM interrupts like Ctrl-C; Ctrl-C interrupts even where the command was started with
    SIGINT ignored, as a shell does for background jobs (Python keeps the inherited disposition)."""

    def terminate(signum, frame):
        raise _Interrupted()

    old = signal.signal(signal.SIGTERM, terminate)
    old_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)
        signal.signal(signal.SIGINT, old_int)


def _check_simulate_options(args):
    if args.t1 == args.t0:
        raise UserError("--t1 equals --t0: nothing to integrate")
    if args.t1 < args.t0:
        raise UserError(
            f"--t1 {args.t1:g} is before --t0 {args.t0:g}: the command line integrates forward in time "
            "(jaxtree.simulate integrates backward when t1 < t0)"
        )
    if args.hybrid_small is None:
        for opt, val in (
            ("--modes", args.modes),
            ("--cutoff", args.cutoff),
            ("--spin", args.spin),
            ("--modal-damping", args.modal_damping),
            ("--modes-tol", args.modes_tol),
        ):
            if val is not None:
                raise UserError(f"{opt} needs --hybrid-small (the hinges in modal coordinates)")
    elif args.modes_tol is not None and args.modes != "auto":
        raise UserError("--modes-tol needs --modes auto")


def _option_error(e: ChunkedRunError) -> UserError:
    """The library's complaint about an argument, as one about the option that gave it."""
    options = "/".join("--" + name.replace("_", "-") for name in e.option.split("/"))
    return UserError(f"{options}: {e.reason}")


def cmd_simulate(args) -> int:
    _check_simulate_options(args)
    start_wall = time.perf_counter()
    model = _load_scene(args.scene)
    out = pathlib.Path(args.out if args.out else f"{model.name or pathlib.Path(args.scene).stem}.nc")
    if out.exists() and out.is_dir():
        raise UserError(f"--out {str(out)!r} is a folder; give a file name such as run.nc")
    # the writers' imports and first use (the result file, the plots) on a thread while XLA
    # integrates (output.warm_writers); waited for before the plots
    warming = _warming(plot=not args.no_plot)
    try:
        cfg = _config(args, model)
        with _interrupts(), contextlib.closing(_Meter(args)) as meter:
            run = simulate_to_file(
                out,
                model,
                cfg,
                resume=args.resume,
                error_estimate=not args.no_error_estimate,
                attrs={"command": command_line()},
                log=lambda message: _say(f"jaxtree simulate: {message}"),
                progress=meter,
            )
    except ChunkedRunError as e:
        raise _option_error(e) from None
    except KeyboardInterrupt as e:
        ds = getattr(e, "dataset", None)
        if ds is None:
            _say("jaxtree simulate: interrupted before the first part was written; nothing saved")
        else:
            _say(
                f"jaxtree simulate: interrupted; {ds.sizes['time']} saved times up to t = {float(ds['time'][-1]):g} s "
                f"are in {out} (complete = 0). Continue with the same command and --resume."
            )
        return EXIT_INTERRUPTED
    warming.join()
    written = [str(out)] + (_exports(args, out, run.dataset) if run.ok else [])
    print(_summary(model, run, written, time.perf_counter() - start_wall))
    if not run.ok:
        _say(run.failure)
        return EXIT_FAILED
    return 0


def _per_substructure(hyb, cfg) -> str:
    """The modes of each substructure, and how they were chosen."""
    if hyb.basis == "set":
        how = "modes of the whole set"
    else:
        per = hyb.modes_per_substructure
        how = (
            f"{per[0]} per substructure" if len(set(per)) == 1 else f"per substructure {list(per)}"
        ) + f", {len(per)} substructure{'s' if len(per) > 1 else ''}"
    if cfg.get("n_modes") == "auto":
        how += f", chosen for --modes-tol {cfg['modes_tol']:g}"
    return how


def _exports(args, out, ds):
    """The CSV export and the plots of a finished run; returns the files written."""
    written = []
    if args.csv:
        output.save_csv(args.csv, to_solution(ds))
        written.append(args.csv)
    if not args.no_plot:
        if not _matplotlib():
            _say("matplotlib is not installed: no plots (pip install 'jaxtree[plot]')")
            return written
        prefix = args.plot if args.plot else str(out.with_suffix("")) if out.suffix == ".nc" else str(out)
        plots.plot_histories(ds, f"{prefix}_histories.png")
        plots.plot_drift(ds, f"{prefix}_drift.png")
        written += [f"{prefix}_histories.png", f"{prefix}_drift.png"]
    return written


def _summary(model, run, written, wall):
    cfg, ds, compile_time = run.config, run.dataset, run.compile_time
    a = ds.attrs

    def fmt(values):
        return np.array2string(values, precision=6, suppress_small=True, max_line_width=150)

    hyb = run.hybrid
    lines = [
        f"scene {model.name!r}: {model.n + 1} bodies; "
        + (
            f"hybrid coordinates, small hinges {list(hyb.small)} in {hyb.n_modes} modes ({hyb.form} form; "
            f"{_per_substructure(hyb, cfg)})"
            if hyb is not None
            else "Eq. (1)"
        )
        + f"; {cfg['solver']}, rtol {cfg['rtol']:g}, atol {cfg['atol']:g}, attitude {cfg['attitude']}",
        f"  solver: {cfg['solver']}, {cfg.get('solver_choice', 'given')}",
    ]
    lines.append(
        f"  result: {a.get('result')} at t = {float(a.get('t_final')):.6g} s"
        + ("" if run.ok else " (the run stopped early)")
    )
    rhs = int(a.get("rhs_evaluations", -1))
    lines.append(
        f"  steps: {int(a.get('steps_accepted'))} accepted, {int(a.get('steps_rejected'))} rejected"
        + (f", {rhs} right-hand sides" if rhs >= 0 else "")
        + f", in {int(a.get('parts'))} part{'s' if int(a.get('parts')) > 1 else ''}"
    )
    if "error_estimate_gamma" in a:
        lines.append(
            f"  integration error estimate (difference from a run at 10x the tolerances): angles "
            f"{float(a['error_estimate_gamma']):.2e} rad, rates {float(a['error_estimate_rates']):.2e} rad/s, "
            f"C {float(a['error_estimate_dcm']):.2e}"
        )
    elif "error_estimate" in a:
        lines.append(f"  integration error estimate: {a['error_estimate']}")
    if "truncation_error" in a:
        peak = float(a["truncation_peak_small_angle"])
        est = float(a["truncation_error"])
        lines.append(
            f"  truncation error estimate (the neglected modes, against the full model): small angles "
            f"{est:.2e} rad"
            + (f" ({est / peak:.1e} of their peak {peak:.2e} rad)" if peak > 0 else "")
            + f", quasi-static part {float(a['truncation_error_static']):.2e} rad; "
            "the linearization of Eq. (30) is not included"
        )
    why, turn = drift_causes(model)
    if "energy" in ds and "angular_momentum" in ds:
        e = np.asarray(ds["energy"].values, float)
        if "dampers dissipate" in why and len(e) > 1 and e[-1] < e[0] and not near_zero(e, e[0]):
            why[why.index("dampers dissipate")] = f"dampers dissipated {(e[0] - e[-1]) / abs(e[0]):.1%} of it"
        H = np.asarray(ds["angular_momentum"].values, float)
        lines.append(
            f"  energy: E0 = {e[0]:.9g} J, {change_text(e, e[0], 'J')}"
            + (f" (not conserved: {', '.join(why)})" if why else "")
        )
        lines.append(
            f"  angular momentum: |H0| = {np.linalg.norm(H[0]):.9g} N m s, {change_text(H, H[0], 'N m s')}"
            + (f" (not conserved: {', '.join(turn)})" if turn else "")
        )
    last = ds.isel(time=-1)
    lines.append(f"  at the last saved time, t = {float(last['time']):.6g} s:")
    lines.append(f"    gamma  = {fmt(last['gamma'].values)}")
    lines.append(f"    omega0 = {fmt(last['omega0'].values)}")
    lines.append(f"  wrote {', '.join(written)}")
    t = f"  wall time {wall:.1f} s"
    if compile_time is not None:
        t += f" (first part, compile included: {compile_time:.1f} s)"
    lines.append(t)
    return "\n".join(lines)


# ----------------------------------------------------------------------------- modes
def cmd_modes(args) -> int:
    model = _load_scene(args.scene)
    small = _hinges(model, args.small, "--small")
    spin = np.zeros(3) if args.spin is None else np.asarray(args.spin, float)
    dtype = jnp.result_type(model.mass)
    apps = scene_appendages(model) if getattr(model, "appendages", ()) else ()
    lin = linearize(model, small, omega0=jnp.asarray(spin, dtype), appendages=apps)
    st = structure(lin.I, lin.J, lin.K)
    if args.damping is not None and args.damping < 0:
        raise UserError(f"--damping must be >= 0, got {args.damping}")
    try:
        md = modes(lin, damping=args.damping)
    except ModalError as e:
        raise UserError(f"modes of {model.name!r} with small hinges {list(small)}: {e}") from None
    out = pathlib.Path(args.out if args.out else f"{model.name or pathlib.Path(args.scene).stem}_modes.nc")
    ds = modes_dataset(
        model,
        md,
        small=small,
        hinges=lin.hinges,
        omega0=spin,
        attrs={"command": command_line(), "damping": args.damping, "structure": st.describe()},
    )
    existed = _existing([out, args.plot if args.plot else out.with_suffix(".png")])
    write_netcdf(ds, out)
    f = np.asarray(md.frequencies)
    z = np.asarray(md.damping_ratios)
    what = (
        f"the small hinges {list(small)} ({', '.join(model.names[k] for k in small[:6])}{', ...' if len(small) > 6 else ''})"
        if small
        else "no hinge"
    )
    print(f"scene {model.name!r}: modes of {what}, nominal omega0 = {spin.tolist()} rad/s")
    if apps:
        names = ", ".join(f"{ap.name or i} ({ap.n_modes})" for i, ap in enumerate(apps))
        print(f"  and the finite-element appendages' held-interface modal coordinates: {names}")
    print(f"  {st.describe()}")
    print(f"{'mode':>5} {'sigma (rad/s)':>14} {'f (Hz)':>11} {'period (s)':>11} {'zeta':>8}  dominated by")
    for j in range(md.nu):
        period = 2 * np.pi / f[j] if f[j] > 0 else float("inf")
        label = md.labels[j] if md.labels else ""
        print(f"{j + 1:5d} {f[j]:14.6g} {f[j] / (2 * np.pi):11.5g} {period:11.5g} {z[j]:8.4f}  {label}")
    print(
        "  dominated by: each coordinate's share of the mode's participation sum_i |phi_i|^2 I_ii (its kinetic "
        "energy by the diagonal of I), largest first; + / - in phase / antiphase with the first"
    )
    wrote = [str(out)]
    if not args.no_plot:
        if _matplotlib():
            png = args.plot if args.plot else str(out.with_suffix(".png"))
            plots.plot_mode_shapes(model, ds, path=png, modes=list(range(min(args.show, md.nu))))
            wrote.append(png)
        else:
            _say("matplotlib is not installed: no mode-shape plot (pip install 'jaxtree[plot]')")
    print(_wrote(wrote, existed))
    return 0


# ----------------------------------------------------------------------------- animate, plot
def _viewer():
    try:
        from ..io import viewer  # looked up when used: an installation may lack it (a test stands one in)
    except ImportError:
        raise UserError("the 3D viewer (jaxtree.write_animation) is not available in this installation") from None
    return viewer


def cmd_animate(args) -> int:
    existed = _existing([args.out])
    ds = _load_result(args.result)
    model = _model_of(ds, args.result)
    viewer = _viewer()
    kind = ds.attrs.get("kind")
    title = args.title
    if kind == "modes":
        nu = ds.sizes["mode"]
        k = 1 if args.mode is None else args.mode
        if not 1 <= k <= nu:
            raise UserError(f"--mode {k}: the result has modes 1..{nu}")
        shape = np.asarray(ds["hinge_shape"].values[:, k - 1], float)
        freq = float(ds["frequency"].values[k - 1])
        if title is None:
            label = str(ds["mode_label"].values[k - 1])
            title = f"{model.name}: mode {k}, {freq:.4g} rad/s ({freq / (2 * np.pi):.4g} Hz)" + (
                f", {label}" if label else ""
            )
        viewer.write_mode_animation(
            args.out,
            model,
            shape,
            freq,
            gamma=np.asarray(ds["gamma_nominal"].values, float),
            amplitude=args.amplitude,
            title=title,
        )
    else:
        if args.mode is not None or args.amplitude is not None:
            raise UserError(
                f"--mode and --amplitude apply to a modes result (jaxtree modes), {args.result} is a simulation"
            )
        if title is None:
            title = f"{model.name}: t = {float(ds['time'][0]):g} .. {float(ds['time'][-1]):g} s" + (
                "" if int(ds.attrs.get("complete", 1)) else " (partial run)"
            )
        viewer.write_animation(
            args.out,
            model,
            np.asarray(ds["time"].values),
            np.asarray(ds["dcm"].values),
            np.asarray(ds["gamma"].values),
            title=title,
            appendages=_output_nodes(ds, args.scale),
        )
    print(_wrote([args.out], existed))
    return 0


def _output_nodes(ds, scale: float) -> list[dict]:
    """The finite-element appendages' output nodes of a simulation result, for the viewer: each a
    point on its body, displaced by `scale` times its translation."""
    if "appendage_displacement" not in ds or "appendage_output_position" not in ds:
        return []
    disp = np.asarray(ds["appendage_displacement"].values, float)[..., :3]
    places = np.asarray(ds["appendage_output_position"].values, float)
    bodies = np.asarray(ds["appendage_output_body"].values)
    names = [str(x) for x in ds["appendage_output"].values]
    return [
        {
            "name": names[p],
            "body": int(bodies[p]),
            "nodes": places[p][None],
            "displacement": scale * disp[:, p][:, None],
        }
        for p in range(len(names))
    ]


def cmd_plot(args) -> int:
    ds = _load_result(args.result)
    if not _matplotlib():
        raise UserError("matplotlib is not installed (pip install 'jaxtree[plot]')")
    res = pathlib.Path(args.result)
    prefix = args.out if args.out else str(res.with_suffix("") if res.suffix == ".nc" else res)
    if ds.attrs.get("kind") == "modes":
        model = _model_of(ds, args.result)
        files = [f"{prefix}_shapes.png"]
        existed = _existing(files)
        plots.plot_mode_shapes(model, ds, path=files[0])
    else:
        files = [f"{prefix}_histories.png", f"{prefix}_drift.png"]
        existed = _existing(files)
        plots.plot_histories(ds, files[0])
        plots.plot_drift(ds, files[1])
    print(_wrote(files, existed))
    return 0


# ----------------------------------------------------------------------------- sample
# `python -m jaxtree` runs jaxtree/__main__.py: the sample problem is named so there
_MAIN_FILE = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "__main__.py")
SAMPLE_DESCRIPTION = "``python -m jaxtree``: the sample problem of Sec. II E (Fig. 4) end to end."


def _sample_parser():
    # the name it was started by: `python -m jaxtree` runs this file, the `jaxtree` script the command line
    started_here = os.path.abspath(sys.argv[0]) == _MAIN_FILE
    prog = "python -m jaxtree" if started_here else "jaxtree sample"
    p = _Parser(prog=prog, description=SAMPLE_DESCRIPTION)
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


def sample(argv=None) -> int:
    """The sample problem (``python -m jaxtree`` with no subcommand, or ``jaxtree sample``)."""
    args = _sample_parser().parse_args(argv)
    _fast_cpu_compiler()
    start = time.perf_counter()

    model = _load_scene(args.scene)
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
    warming = _warming(plot=not args.no_plot)
    for att in attitudes:
        kw: dict[str, Any] = dict(attitude=att, saveat=points, rtol=args.rtol, atol=args.atol)
        print(f"-- {att}: running (the summary below splits program preparation from the run)", flush=True)
        with programs.PREPARED.timing(), _elapsed(att, show_progress):
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
        runs[att], times[att] = sol, (first, wall)

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
        loose = {att: f.result() for att, f in loose.items()}

    lines = []
    for att, sol in runs.items():
        other = loose[att]
        estimate = {
            "gamma": float(np.max(np.abs(np.asarray(other.gamma) - np.asarray(sol.gamma)))),
            "rates": max(
                float(np.max(np.abs(np.asarray(other.gamma_dot) - np.asarray(sol.gamma_dot)))),
                float(np.max(np.abs(np.asarray(other.omega0) - np.asarray(sol.omega0)))),
            ),
            "dcm": float(np.max(np.abs(np.asarray(other.dcm) - np.asarray(sol.dcm)))),
        }
        first, wall = times[att]
        lines.append(output.summary(att, sol, wall=wall, first=first, estimate=estimate))
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
    if plotted is False:
        print("matplotlib is not installed: no plot (pip install matplotlib)")
    print(f"wrote {', '.join(written)} to {out}")
    print(f"total wall time {time.perf_counter() - start:.1f} s")
    return 0 if all(s.ok for s in runs.values()) else 1
