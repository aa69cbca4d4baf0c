"""``jaxtree simulate``: a scene integrated to a NetCDF result written in parts (resumable), its
CSV export and plots, and the summary of the run (steps, error estimates, drift)."""

from __future__ import annotations

import contextlib
import os
import pathlib
import signal
import sys
import time

import numpy as np

from ..campaigns.chunked import simulate_to_file
from ..campaigns.chunked_config import ChunkedRunError, chunked_config
from ..integration.save_grid import MAX_SAVE_POINTS, SAMPLES_LEAST, SAMPLES_PER_PERIOD, samples_per_period, save_points
from ..io import history_plots, output
from ..io.drift import change_text, drift_causes, near_zero
from ..io.result_files import command_line, to_solution
from .common import (
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    SOLVERS,
    UserError,
    open_scene,
    say,
    start_warming,
    use_matplotlib,
)

# Seconds to sleep after each part of `simulate` is written: lets a test interrupt a run
# between parts deterministically. Not for users.
CHUNK_DELAY_ENV = "JAXTREE_CHUNK_DELAY"


class _Interrupted(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C."""


def _config(args, model):
    """The run's configuration (:func:`~jaxtree._src.campaigns.chunked_config.chunked_config` of the options)."""
    return chunked_config(
        model,
        args.t1,
        t0=args.t0,
        points=save_points_of(args, model),
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


def save_points_of(args, model) -> int:
    """--points, or by default enough for the fastest motion that rings; a note where too few."""
    span = float(args.t1 - args.t0)
    default, rate = save_points(model, span)
    points = default if args.points is None else int(args.points)
    per = samples_per_period(points, span, rate)
    if args.points is not None and per < SAMPLES_LEAST:
        say(
            f"note: {points} save points sample the fastest hinge motion ({rate:.3g} rad/s) {per:.1f} times a "
            f"period: its curves will look jagged (the default here is {default})"
        )
    elif args.points is None and per < SAMPLES_PER_PERIOD and default == MAX_SAVE_POINTS:
        say(
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
    model = open_scene(args.scene)
    out = pathlib.Path(args.out if args.out else f"{model.name or pathlib.Path(args.scene).stem}.nc")
    if out.exists() and out.is_dir():
        raise UserError(f"--out {str(out)!r} is a folder; give a file name such as run.nc")
    # the writers' imports and first use (the result file, the plots) on a thread while XLA
    # integrates (output.warm_writers); waited for before the plots
    warming = start_warming(plot=not args.no_plot)
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
                log=lambda message: say(f"jaxtree simulate: {message}"),
                progress=meter,
            )
    except ChunkedRunError as e:
        raise _option_error(e) from None
    except KeyboardInterrupt as e:
        ds = getattr(e, "dataset", None)
        if ds is None:
            say("jaxtree simulate: interrupted before the first part was written; nothing saved")
        else:
            say(
                f"jaxtree simulate: interrupted; {ds.sizes['time']} saved times up to t = {float(ds['time'][-1]):g} s "
                f"are in {out} (complete = 0). Continue with the same command and --resume."
            )
        return EXIT_INTERRUPTED
    warming.join()
    written = [str(out)] + (_exports(args, out, run.dataset) if run.ok else [])
    print(_summary(model, run, written, time.perf_counter() - start_wall))
    if not run.ok:
        say(run.failure)
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
        if not use_matplotlib():
            say("matplotlib is not installed: no plots (pip install 'jaxtree[plot]')")
            return written
        prefix = args.plot if args.plot else str(out.with_suffix("")) if out.suffix == ".nc" else str(out)
        history_plots.plot_histories(ds, f"{prefix}_histories.png")
        history_plots.plot_drift(ds, f"{prefix}_drift.png")
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
