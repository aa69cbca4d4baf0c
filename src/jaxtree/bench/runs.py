"""Error against run time: the runs of the work-precision report behind ``jaxtree bench``.

For each case (a scene, its time span and save times), each formulation that applies
(``full``: Eq. 1; ``float32``: Eq. 1 with the model in float32, as GPU batches run it;
``eq30``: the partially linearized equations, Eq. 30, in the small hinges'
modal coordinates with every mode kept; ``hybrid-k``: k modes per substructure, Eqs.
105-123), each solver (diffrax's Tsit5, Dopri5, Dopri8; Kvaerno3, Kvaerno5, KenCarp4; the
classical RK4 at fixed steps) and a ladder of tolerances (or steps), :func:`work_precision`
records

- the error: the largest absolute error over the save times in ``omega0`` (rad/s) and
  ``gamma`` (rad) (flex95: relative, see :class:`BenchCase`) against a reference computed at
  rtol = atol = 1e-12 by a *different* solver (two references per case, Dopri8 and Tsit5, or
  Kvaerno5 and Dopri8 for the stiff chains; every row is measured against the one whose solver
  differs from its own, and their difference is the report's floor);
- the wall time (median of repeated calls after the first), the compile time apart (first
  call minus the median), accepted and rejected steps, right sides, energy and momentum drift;

and the same for the peers that are installed and can represent the scene
(:mod:`jaxtree.bench.peers`: Pinocchio's ABA under scipy's DOP853, RK45 and Radau; MuJoCo's RK4
and implicitfast), each cross-checked against the reference at its tightest setting before
its timings count.

The cases (:mod:`.cases`) are the reference scenes, flex95's slew (stiff
latched wing hinges, a torque on the bus; relative errors; Radau5 among the solvers, the bus
torque given to Pinocchio as its free flyer's generalized force), the *stiff* chains
(chain10 with its tip hinge's spring stiffened by s = 1e2 ... 1e8 and damped at a ratio of
0.7: separated time scales with the fast one decaying; scaling every spring alike would make
the problem faster, not stiffer) and the *extreme* cases (a fast rotor, a spinning bus, gimbal
frames near lock, a body with 1e-6 of the bus's inertia, a 1000 s run).
"""

from __future__ import annotations

import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np

from jaxtree._src.equations.dynamics import mass_matrix
from jaxtree._src.hybrid import hybrid_model, simulate_hybrid
from jaxtree._src.integration.autosolver import choose_solver
from jaxtree._src.integration.failures import failure_kind
from jaxtree._src.integration.simulate import simulate
from jaxtree._src.vehicle.model import Model
from jaxtree.bench.cases import (
    CASES,
    EVERY_SOLVER_CASES,
    IMPLICIT,
    IMPLICIT_STEP_CAP,
    IMPLICIT_TIGHTEST,
    NONSTIFF_SOLVERS,
    QUICK_CASES,
    QUICK_SOLVERS,
    QUICK_TOLERANCES,
    REFERENCE_TOL,
    SOLVERS,
    STEP_CAP,
    TOLERANCES,
    BenchCase,
    bench_case,
)
from jaxtree.bench.peer_basilisk import basilisk_available, basilisk_run, basilisk_supports
from jaxtree.bench.peers import mujoco_runner, peer_support, pinocchio_runner
from jaxtree.bench.report import BenchReport, machine_line, setting_text

# The full Eq. (1) in float32 (GPU batches): tolerances above its roundoff (1000 eps ~ 1e-4)
FLOAT32_TOLERANCES = (1e-3, 1e-4)
RK4_STEPS = (2, 4, 8, 16, 32)  # RK4 steps per save interval
RK4_STABILITY = 2.78  # |h lambda| where RK4's stability region ends on the real and imaginary axes
QUICK_RK4_STEPS = (4, 16)
# After a run that stalls or takes longer than this, a method's tighter settings are skipped.
SLOW_S = 20.0
REFERENCE_STEPS = 2_000_000
REFERENCE_FALLBACK = (1e-11, 1e-10)  # a reference whose steps collapse at REFERENCE_TOL tries these
# A peer's model agrees with jaxtree's when its most accurate setting is this close to the reference.
PEER_AGREEMENT = 1e-6


def _error(omega0, gamma, ref, relative: tuple[int, ...] | None = None) -> float:
    """The largest absolute error in omega0 and gamma against `ref`, or with `relative` (hinges)
    the larger of the hub rate's error over its peak and those hinges' angles' over theirs."""
    w, g = np.asarray(omega0, float), np.asarray(gamma, float)
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(g))):
        return math.nan
    if relative is None:
        return float(max(np.abs(w - ref[0]).max(), np.abs(g - ref[1]).max()))
    cols = np.asarray(relative) - 1
    gr = np.asarray(ref[1])[:, cols]
    hub = np.abs(w - ref[0]).max() / np.abs(ref[0]).max()
    return float(max(hub, np.abs(g[:, cols] - gr).max() / np.abs(gr).max()))


def _timed(call, repeats: int, budget: float, first_done=None):
    """``(result, first call s, median s)``: `repeats` more calls, fewer past `budget` seconds
    (at least one)."""
    if first_done is None:
        t = time.perf_counter()
        out = jax.block_until_ready(call())
        first = time.perf_counter() - t
    else:
        out, first = first_done
    runs, start = [], time.perf_counter()
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(call())
        runs.append(time.perf_counter() - t)
        if time.perf_counter() - start > budget:
            break
    return out, first, statistics.median(runs)


def _stats_row(sol, span):
    st = sol.stats
    steps = int(st["num_accepted_steps"])
    rhs = int(st.get("rhs_evaluations", -1))
    t_final = float(np.asarray(sol.t_final))
    return steps, int(st["num_rejected_steps"]), rhs, t_final


def _drifts(sol, model: Model) -> tuple[float, float]:
    e = np.asarray(sol.energy, float)
    h = np.asarray(sol.angular_momentum, float)
    ok = np.isfinite(e) & np.all(np.isfinite(h), 1)
    if not ok.any():
        return math.nan, math.nan
    e, h = e[ok], h[ok]
    de = float(np.abs(e - e[0]).max() / max(abs(e[0]), 1e-300))
    # relative to the initial momentum, or, for a run that starts with little or none (chain50, the
    # stiff chains), to sqrt(2 E J_max): the momentum of the whole vehicle turning rigidly with the
    # run's initial energy about its axis of largest inertia

    J = np.asarray(mass_matrix(model, model.initial.gamma), float)[:3, :3]
    rigid = math.sqrt(2.0 * abs(float(e[0])) * float(np.linalg.eigvalsh(J).max()))
    scale = max(float(np.linalg.norm(h[0])), rigid, 1e-300)
    dh = float(np.linalg.norm(h - h[0], axis=1).max() / scale)
    return de, dh


def _jaxtree_row(case, form, solver, setting, call, ref, repeats, budget, cap, conservative):
    t = time.perf_counter()
    sol = jax.block_until_ready(call())
    first = time.perf_counter() - t
    steps, rejected, rhs, t_final = _stats_row(sol, case.t1)
    ok = bool(sol.failure == 0) if hasattr(sol, "failure") else bool(sol.result == dfx.RESULTS.successful)
    status, note = "ok", ""
    median = first
    if ok:
        _, _, median = _timed(call, repeats, budget, first_done=(sol, first))
    elif (kind := _failure_kind(sol)) in REFUSALS:
        # simulate's checks refused the initial state (in float32, gimbal frames 1e-3 rad from lock
        # leave a pivot of Eq. 1 at round-off level): the verdict is the state's, not the solver's
        status, note = "refused", REFUSALS[kind]
    else:
        stalled = steps + rejected >= cap
        status = "stalled" if stalled else ("unstable" if solver == "RK4" else "failed")
        if not stalled and kind == "dt_min" and solver != "RK4":
            # the controller rejected steps down to the minimum step: the solver's verdict on the
            # case, like a stall (KenCarp4 with the whole right side implicit on the stiffest chain)
            status = "collapsed"
        note = f"stopped at t = {t_final:.4g} of {case.t1:g} s" + (f" after {cap} steps" if stalled else "")
        if status == "collapsed":
            note += ": the step size collapsed"
    de, dh = _drifts(sol, case.model) if ok and form in ("full", "float32") else (math.nan, math.nan)
    if not conservative:
        de = math.nan  # damped hinges: the energy is not conserved
    if case.model.loads is not None:
        dh = math.nan  # external torques change the angular momentum
    return _row_of(
        case, form, "jaxtree", solver, setting, (sol.omega0, sol.gamma), ref if ok else None, first, median,
        dict(status=status, steps=steps, rejected=rejected, rhs=rhs, energy_drift=de, momentum_drift=dh, note=note),
    )  # fmt: skip


# Failures of `simulate` that are its refusal of the initial state, with the report's note.
REFUSALS = {
    "singular_start": "refused at t = 0: Eq. (1) is singular at the initial state to working precision",
    "nonfinite_start": "refused at t = 0: the initial state is not finite",
}


def _failure_kind(sol) -> str | None:

    return failure_kind(sol.failure) if hasattr(sol, "failure") else None


class _Runner:
    """The jaxtree runs of one case and formulation: ``run(solver name, setting)``."""

    def __init__(self, case: BenchCase, formulation: str):

        self.case, self.formulation = case, formulation
        self.ts = np.linspace(0.0, case.t1, case.n_save)
        self.hybrid = None
        self.model = case.model.astype(jnp.float32) if formulation == "float32" else case.model
        if formulation not in ("full", "float32"):
            assert case.small is not None
            k = None if formulation == "eq30" else int(formulation.split("-")[1])
            self.hybrid = hybrid_model(case.model, case.small, k)
        self._simulate, self._simulate_hybrid = simulate, simulate_hybrid

    def call(self, solver_name: str, setting: float, max_steps: int):
        solver = SOLVERS[solver_name]()
        ts = jnp.asarray(self.ts, jnp.result_type(self.model.mass))
        kw: dict = dict(saveat=ts, solver=solver, max_steps=max_steps, throw=False)
        if solver_name == "RK4":
            kw.update(stepsize_controller=dfx.ConstantStepSize(), dt0=(self.ts[1] - self.ts[0]) / setting)
        else:
            kw.update(rtol=setting, atol=setting)
        hybrid = self.hybrid
        if hybrid is None:
            return lambda: self._simulate(self.model, self.case.t1, **kw)
        # the integration alone: the truncation estimate (a pass over the saved solution) is a
        # diagnostic beside it, not part of the work-precision trade
        return lambda: self._simulate_hybrid(hybrid, self.case.t1, truncation_error=False, **kw)


def _energy_of(sol):
    return getattr(sol, "energy", None)


def _row_of(case, formulation, engine, solver, setting, sol_fields, ref, first, median, extra):
    row = dict(
        case=case.name,
        group=case.group,
        formulation=formulation,
        engine=engine,
        solver=solver,
        method=f"{engine} {solver}" + ("" if formulation == "full" else f" [{formulation}]"),
        setting=setting,
        error=_error(sol_fields[0], sol_fields[1], ref, case.relative)
        if ref is not None and sol_fields is not None
        else math.nan,
        time_s=median,
        compile_s=max(first - median, 0.0) if engine == "jaxtree" else math.nan,
    )
    row.update(extra)
    return row


class _Progress:
    def __init__(self, total: int, enabled: bool):
        self.total, self.done, self.enabled = total, 0, enabled
        self.start = time.perf_counter()
        self.bar = None
        if enabled and sys.stderr.isatty():  # a bar on a terminal; one line per run in a log
            try:
                from tqdm.auto import tqdm

                self.bar = tqdm(total=total, unit="run", file=sys.stderr, dynamic_ncols=True)
            except ImportError:
                pass

    def step(self, label: str, n: int = 1):
        self.done += n
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.set_description_str(label[:60])
            self.bar.update(n)
        else:
            print(f"[{self.done}/{self.total} {time.perf_counter() - self.start:6.0f} s] {label}", file=sys.stderr)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _references(case: BenchCase):
    """Two tight runs by different solvers: ``(pair, ref arrays by name, floor, tolerances by name)``.
    Each runs at :data:`REFERENCE_TOL`, or, where its step size collapses there (Kvaerno5 on the
    1e8-stiff chain: its Newton iterations cannot meet 1e-12 against stiffness 1e12 in the
    round-off of float64), at the first of :data:`REFERENCE_FALLBACK` that it meets; the report
    names the tolerances and the floor shows what they cost."""

    pair = case.references or (("Kvaerno5", "Dopri8") if case.group == "stiff" else ("Dopri8", "Tsit5"))
    ts = jnp.asarray(np.linspace(0.0, case.t1, case.n_save))
    refs, tols = {}, {}
    for name in pair:
        why = ""
        for tol in (REFERENCE_TOL, *REFERENCE_FALLBACK):
            sol = simulate(
                case.model,
                case.t1,
                saveat=ts,
                solver=SOLVERS[name](),
                rtol=tol,
                atol=tol,
                max_steps=REFERENCE_STEPS,
                throw=False,
            )
            if int(sol.failure) == 0:
                break
            why = f"at rtol {tol:g}: stopped at t = {float(np.asarray(sol.t_final)):.3g}"
        else:
            raise RuntimeError(f"bench case {case.name}: no reference by {name} ({why})")
        refs[name] = (np.asarray(sol.omega0, float), np.asarray(sol.gamma, float))
        tols[name] = tol
    (w, g), ref = refs[pair[1]], refs[pair[0]]
    floor = _error(w, g, ref, case.relative)
    return pair, refs, floor, tols


def _formulations(case: BenchCase, wanted: Sequence[str] | None) -> list[str]:
    forms = ["full", "float32"]
    if case.small is not None:
        forms += ["eq30"] + [f"hybrid-{k}" for k in case.hybrid_modes]
    if wanted is not None:
        forms = [f for f in forms if f in wanted or (f.startswith("hybrid") and "hybrid" in wanted)]
    return forms


# Why a peer is not run on a case whose model has a bus torque (BenchCase.peer_torque).
NO_BASE_TORQUE = {
    "mujoco": "not run, no bus torque in its runner (MuJoCo holds an applied force over each step, which would "
    "cut its integrators to first or second order on the pulse)",
    "basilisk": "not run, no bus torque in its runner (jaxtree's loads are not mapped onto Basilisk's effectors)",
}


def _peer_ladders(case, ts, quick):
    """``[(engine, solver, settings, run(setting) -> (omega0, gamma, wall s, right sides), why,
    check)]`` for the peers that are installed and can represent `case`; `why` is "" or the
    reason a peer is not run (one row, skipped, at its first setting); `check` the setting of
    the cross-check (an engine's first integrator's)."""

    ladders: list = []
    # a case's bus torque reaches the peers as a numpy function of time, not as jaxtree loads
    model = case.model if case.peer_torque is None else case.model.with_loads(None)
    if peer_support(model) is not None:
        return ladders
    tols = QUICK_TOLERANCES if quick else TOLERANCES
    steps = QUICK_RK4_STEPS if quick else (1, 2, 4, 8, 16, 32, 64)
    try:
        import pinocchio  # noqa: F401  # pyright: ignore[reportMissingImports]  (optional: the peers extra)
        import scipy  # noqa: F401

        run = pinocchio_runner(model, ts, base_torque=case.peer_torque)
        # On the stiff chains scipy's explicit methods take 1e4-1e6 stability-limited steps in Python
        # (minutes a run): there Radau, the implicit one, is the peer, at its two loosest settings.
        methods = case.peer_methods or (("Radau",) if case.group == "stiff" else ("DOP853", "RK45", "Radau"))
        for method in methods:
            # RK45 and Radau at tight tolerances cost minutes in Python: their loosest settings (a
            # case that names its methods runs them over the whole ladder)
            ladder = tols if method == "DOP853" or case.peer_methods else tols[:2]
            # DOP853 cross-checks at the full ladder's tightest setting, cheap for an 8th-order method,
            # in a quick run too: at 1e-8 its error is ~2e-6 of flex95's peak wing angles, which would
            # read as a disagreement of the models
            check = min(ladder[-1], TOLERANCES[-1]) if method == "DOP853" else ladder[-1]
            ladders.append(("pinocchio", f"scipy {method}", ladder, lambda s, m=method: run(m, s, s), "", check))
    except ImportError:
        pass
    try:
        import mujoco  # noqa: F401  # pyright: ignore[reportMissingImports]  (optional: the peers extra)

        if case.peer_torque is not None:
            for integ in ("RK4", "implicitfast"):
                ladders.append(("mujoco", integ, steps[:1], None, NO_BASE_TORQUE["mujoco"], None))
        else:
            mrun = mujoco_runner(model, ts)
            ladders.append(("mujoco", "RK4", steps, lambda k: mrun("RK4", k), "", steps[-1]))
            ladders.append(("mujoco", "implicitfast", steps, lambda k: mrun("implicitfast", k), "", steps[-1]))
    except ImportError:
        pass
    if basilisk_available() and basilisk_supports(model) is None:
        if case.peer_torque is not None:
            for integ in ("RKF78", "RKF45", "RK4"):
                first = (steps if integ == "RK4" else tols)[:1]
                ladders.append(("basilisk", integ, first, None, NO_BASE_TORQUE["basilisk"], None))
            return ladders
        interval = float(ts[1] - ts[0])

        def bsk(integrator, setting):
            if integrator == "rk4":
                out = basilisk_run(model, case.t1, ts, integrator="rk4", dt=interval / setting)
                rhs = 4 * setting * (len(ts) - 1)
            else:  # the task step = the save interval (a smaller one caps Basilisk's steps)
                out = basilisk_run(model, case.t1, ts, integrator=integrator, dt=interval, rtol=setting, atol=setting)
                rhs = -1
            return out["omega0"], out["gamma"], out["time"], rhs

        for integ in ("rkf78", "rkf45"):
            ladders.append(("basilisk", integ.upper(), tols, lambda s, i=integ: bsk(i, s), "", tols[-1]))
        ladders.append(("basilisk", "RK4", steps, lambda k: bsk("rk4", k), "", steps[-1]))
    return ladders


def _peer_runs(case, ts, ref, quick, repeats, budget, progress):
    """The peers' rows and cross-checks for `case`."""
    rows, checks = [], {}

    def row(engine, solver, setting, **kw):
        base = dict(
            case=case.name, group=case.group, formulation="full", engine=engine, solver=solver,
            method=f"{engine} {solver}", setting=setting, status="ok", error=math.nan, time_s=math.nan,
            compile_s=math.nan, steps="", rejected="", rhs="", energy_drift=math.nan, momentum_drift=math.nan, note="",
        )  # fmt: skip
        base.update(kw)
        return base

    verdict: dict[str, str] = {}  # per engine: "" when its model agrees with jaxtree's, else why not
    for engine, solver, ladder, fn, why, check in _peer_ladders(case, ts, quick):
        # Cross-check each engine once, with its first (most accurate) integrator at its tightest
        # setting: an engine whose model disagrees is reported, not timed. A low-order integrator
        # of an engine that agrees is timed whatever its accuracy (that is what it costs).
        if why:
            verdict[engine] = why
        elif engine not in verdict:
            try:
                tight = fn(check)
                err = _error(tight[0], tight[1], ref, case.relative)
                checks[f"{engine} {solver}"] = err
                verdict[engine] = "" if err <= PEER_AGREEMENT else f"disagrees with the reference by {err:.1e}"
            except Exception as e:  # a peer's failure is a row of the report, not the end of it
                verdict[engine] = "failed: " + str(e).splitlines()[0][:100]
        skip = verdict[engine]
        for setting in ladder:
            progress.step(f"{case.name} {engine} {solver} {setting:g}")
            if skip:
                rows.append(row(engine, solver, setting, status="skipped", note=skip))
                continue
            try:
                out = fn(setting)
                times, start = [], time.perf_counter()
                for _ in range(max(1, repeats)):
                    times.append(fn(setting)[2])
                    if time.perf_counter() - start > budget:
                        break
                rows.append(
                    row(
                        engine,
                        solver,
                        setting,
                        error=_error(out[0], out[1], ref, case.relative),
                        time_s=statistics.median(times),
                        rhs=out[3],
                    )
                )
                if rows[-1]["time_s"] > SLOW_S:
                    skip = f"skipped: slower than {SLOW_S:g} s at a looser setting"
            except Exception as e:
                rows.append(row(engine, solver, setting, status="failed", note=str(e).splitlines()[0][:120]))
                skip = "skipped after a failure"
    return rows, checks


def _plan(case: BenchCase, solvers, tolerances, quick, formulations):
    default = QUICK_SOLVERS if quick else tuple(SOLVERS)
    if not quick and case.group != "stiff" and case.name not in EVERY_SOLVER_CASES:
        default = NONSTIFF_SOLVERS
    allowed = tuple(solvers or default)
    if quick and not solvers and case.solvers:  # a quick run keeps a case's own implicit solver (flex95's Radau5)
        allowed += tuple(s for s in case.solvers if s in IMPLICIT)
    names = [s for s in (case.solvers or default) if s in allowed]
    tols = tolerances or case.tolerances or (QUICK_TOLERANCES if quick else TOLERANCES)
    plan = []

    def ladder(s):
        if s == "RK4":
            return QUICK_RK4_STEPS if quick else RK4_STEPS
        if s in IMPLICIT and case.group != "stiff" and not tolerances:
            return tuple(t for t in tols if t >= IMPLICIT_TIGHTEST) or tols[:1]
        return tols

    for form in _formulations(case, formulations):
        if form == "float32":  # Eq. (1) in float32 by the solver that its class of scene needs
            s = "Kvaerno5" if case.group == "stiff" else "Dopri8"
            if s in names:
                plan.append((form, s, FLOAT32_TOLERANCES))
            continue
        # the modal formulations: the solvers that matter for them (explicit Dopri8, implicit Kvaerno5)
        for s in names if form == "full" else [s for s in names if s in ("Dopri8", "Kvaerno5")]:
            plan.append((form, s, tuple(ladder(s))))
    return plan


def _jaxtree_runs(case: BenchCase, plan, refs, pair, choice, repeats, budget, bar) -> list[dict]:
    """jaxtree's rows of one case: each formulation and solver of `plan` over its settings, against the other
    solver's reference of `pair`; RK4 is not run past its stability limit, a ladder stops after a failed or slow run."""
    rows: list[dict] = []
    # energy is conserved without dampers, loads and prescribed hinges (whose motors do work)
    conservative = (
        not np.any(np.asarray(case.model.damping) != 0.0)
        and case.model.loads is None
        and case.model.prescription is None
    )
    for form, solver, settings in plan:
        runner = _Runner(case, form)
        ref = refs[pair[1] if solver == pair[0] else pair[0]]
        cap = IMPLICIT_STEP_CAP if solver in IMPLICIT else STEP_CAP
        skip = ""
        for setting in settings:
            label = f"{case.name} {form} {solver} {setting:g}"
            h = case.t1 / (case.n_save - 1) / setting
            if solver == "RK4" and h * choice.fastest > RK4_STABILITY:
                rows.append(
                    _row_of(case, form, "jaxtree", solver, setting, None, None, math.nan, math.nan,
                            dict(status="unstable", note=f"h |lambda|max = {h * choice.fastest:.3g} > "
                                 f"{RK4_STABILITY} (RK4's stability limit): not run"))
                )  # fmt: skip
                bar.step(label)
                continue
            if skip:
                rows.append(
                    _row_of(case, form, "jaxtree", solver, setting, None, None, math.nan, math.nan,
                            dict(status="skipped", note=skip))
                )  # fmt: skip
                bar.step(label)
                continue
            rows.append(_jaxtree_row(case, form, solver, setting, runner.call(solver, setting, cap), ref,
                                     repeats, budget, cap, conservative))  # fmt: skip
            last = rows[-1]
            if last["status"] != "ok" or last["time_s"] > SLOW_S:
                skip = f"skipped: {last['status']} or slower than {SLOW_S:g} s at {setting_text(last)}"
            bar.step(label)
    return rows


def work_precision(
    cases: Sequence[str | BenchCase] | None = None,
    *,
    solvers: Sequence[str] | None = None,
    tolerances: Sequence[float] | None = None,
    formulations: Sequence[str] | None = None,
    peers: bool = True,
    quick: bool = False,
    repeats: int | None = None,
    budget: float = 2.0,
    progress: bool = True,
    command: str = "jaxtree bench",
    on_case: Callable[[BenchReport], object] | None = None,
) -> BenchReport:
    """Measure error against run time (see the module's text) and return a :class:`BenchReport`
    (``.save(directory)`` writes CSV, Markdown and PNG plots).

    - `cases`: names of :data:`CASES` or :class:`BenchCase` objects (default: all;
      ``quick``: ``wings``); `solvers`: names of :data:`SOLVERS` (default all);
      `tolerances`: the ladder (default :data:`TOLERANCES`); `formulations`: a subset of
      ``("full", "float32", "eq30", "hybrid")`` (``float32``: Eq. 1 with the model cast to
      float32, at :data:`FLOAT32_TOLERANCES`); `peers`: time the installed peers too;
    - `quick`: two tolerances, one repeat, the quick case list (a minute or so);
    - `repeats`: timed calls after the first (default 3, quick 1), fewer past `budget` seconds;
    - `on_case`: called with the report so far after each case (``jaxtree bench`` saves it
      there, so that a long run interrupted keeps the cases it finished).
    """

    quick = bool(quick)
    repeats = max(1, (1 if quick else 3) if repeats is None else int(repeats))
    chosen = [c if isinstance(c, BenchCase) else bench_case(c) for c in (cases or (QUICK_CASES if quick else CASES))]
    unknown = [s for s in (solvers or ()) if s not in SOLVERS]
    if unknown:
        raise ValueError(f"unknown solver(s) {unknown}; known: {', '.join(SOLVERS)}")
    plans = {c.name: _plan(c, solvers, tolerances, quick, formulations) for c in chosen}
    total = sum(len(p[2]) for plan in plans.values() for p in plan) + 2 * len(chosen)
    if peers:
        total += sum(
            sum(len(ld[2]) for ld in _peer_ladders(c, np.linspace(0.0, c.t1, c.n_save), quick)) for c in chosen
        )
    bar = _Progress(total, progress)
    run_settings = dict(quick=quick, repeats=repeats, command=command)

    def report() -> BenchReport:
        date = time.strftime("%Y-%m-%d %H:%M %Z")
        return BenchReport(list(rows), machine_line(), date, refs_info, auto, checks, run_settings)

    rows: list[dict] = []
    refs_info: dict[str, dict] = {}
    auto: dict[str, str] = {}
    checks: dict[str, dict] = {}
    try:
        for case in chosen:
            pair, refs, floor, ref_tols = _references(case)
            bar.step(f"{case.name}: references", 2)
            refs_info[case.name] = dict(
                primary=pair[0], secondary=pair[1], floor=floor, description=case.description,
                primary_tol=ref_tols[pair[0]], secondary_tol=ref_tols[pair[1]],
            )  # fmt: skip
            choice = choose_solver(case.model, case.t1)[1]
            auto[case.name] = str(choice)
            rows += _jaxtree_runs(case, plans[case.name], refs, pair, choice, repeats, budget, bar)
            if peers:
                peer_rows, peer_checks = _peer_runs(
                    case, np.linspace(0.0, case.t1, case.n_save), refs[pair[0]], quick, repeats, budget, bar
                )
                rows += peer_rows
                if peer_checks:
                    checks[case.name] = peer_checks
            if on_case is not None:
                on_case(report())
    finally:
        bar.close()
    return report()
