"""Error against run time: the work-precision report behind ``jaxtree bench``.

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

The cases (:data:`CASES`, :func:`bench_case`) are the reference scenes, flex95's slew (stiff
latched wing hinges, a torque on the bus; relative errors; Radau5 among the solvers, the bus
torque given to Pinocchio as its free flyer's generalized force), the *stiff* chains
(chain10 with its tip hinge's spring stiffened by s = 1e2 ... 1e8 and damped at a ratio of
0.7: separated time scales with the fast one decaying; scaling every spring alike would make
the problem faster, not stiffer) and the *extreme* cases (a fast rotor, a spinning bus, gimbal
frames near lock, a body with 1e-6 of the bus's inertia, a 1000 s run).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Sequence

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from jaxtree._src.equations.dynamics import mass_matrix
from jaxtree._src.equations.loads import BodyTorque
from jaxtree._src.hybrid import hybrid_model, simulate_hybrid
from jaxtree._src.integration.autosolver import choose_solver
from jaxtree._src.integration.failures import failure_kind
from jaxtree._src.integration.radau import Radau5
from jaxtree._src.integration.rk4 import RK4
from jaxtree._src.integration.simulate import simulate
from jaxtree._src.io.files import atomic_write
from jaxtree._src.io.plots import plot_work_precision
from jaxtree._src.scene.scene import load_scene
from jaxtree._src.vehicle.model import Model
from jaxtree.bench.peer_basilisk import basilisk_available, basilisk_run, basilisk_supports
from jaxtree.bench.peers import mujoco_runner, peer_support, pinocchio_runner

# ----------------------------------------------------------------------------- solvers
SOLVERS: dict[str, Callable[[], dfx.AbstractSolver]] = {
    "Tsit5": dfx.Tsit5,
    "Dopri5": dfx.Dopri5,
    "Dopri8": dfx.Dopri8,
    "Kvaerno3": dfx.Kvaerno3,
    "Kvaerno5": dfx.Kvaerno5,
    "KenCarp4": dfx.KenCarp4,
    "Radau5": Radau5,
    "RK4": RK4,
}
EXPLICIT = ("Tsit5", "Dopri5", "Dopri8")
IMPLICIT = ("Kvaerno3", "Kvaerno5", "KenCarp4", "Radau5")
# On the large trees one implicit solver shows the point (each implicit step evaluates a Jacobian
# of 100-200 states by forward differentiation of Eq. 1; compiling it takes minutes here).
LARGE_SOLVERS = ("Tsit5", "Dopri5", "Dopri8", "Kvaerno5", "RK4")
TOLERANCES = (1e-4, 1e-6, 1e-8, 1e-10)
# Implicit solvers on a case that is not stiff: a step costs 10-50 explicit ones, a compile 20-50 s
# here, and at 1e-8 and below their runs take minutes (20k steps on fig4 at 1e-10) without ever
# competing. Outside the stiff group they run at the tolerances from this one up, and only
# Kvaerno5 except on EVERY_SOLVER_CASES, where every solver runs.
IMPLICIT_TIGHTEST = 1e-6
# flex95's slew: its wing modes (to 433 rad/s) hold the explicit solvers to ~1000 steps (about 1 s
# a run here) at every tolerance; Radau5 is the stiff solver, Kvaerno5 5-10x its time (bench_stiff.py)
FLEX95_SOLVERS = ("Tsit5", "Dopri8", "Radau5")
NONSTIFF_SOLVERS = ("Tsit5", "Dopri5", "Dopri8", "Kvaerno5", "RK4")
EVERY_SOLVER_CASES = ("appendix_c", "wings")
# The full Eq. (1) in float32 (GPU batches): tolerances above its roundoff (1000 eps ~ 1e-4)
FLOAT32_TOLERANCES = (1e-3, 1e-4)
QUICK_TOLERANCES = (1e-5, 1e-8)
RK4_STEPS = (2, 4, 8, 16, 32)  # RK4 steps per save interval
RK4_STABILITY = 2.78  # |h lambda| where RK4's stability region ends on the real and imaginary axes
QUICK_RK4_STEPS = (4, 16)
REFERENCE_TOL = 1e-12
TARGETS = (1e-6, 1e-9)
# A run that needs more steps than this stops there: "stalled" in the report (the explicit
# solvers on the stiffest chains; their time to the end is the stall's time / fraction done).
STEP_CAP = 100_000
IMPLICIT_STEP_CAP = 20_000  # an implicit step (Newton iterations, a Jacobian) costs 10-50 explicit ones
# After a run that stalls or takes longer than this, a method's tighter settings are skipped.
SLOW_S = 20.0
REFERENCE_STEPS = 2_000_000
REFERENCE_FALLBACK = (1e-11, 1e-10)  # a reference whose steps collapse at REFERENCE_TOL tries these
# A peer's model agrees with jaxtree's when its most accurate setting is this close to the reference.
PEER_AGREEMENT = 1e-6
# Goals of the work-precision report (time of jaxtree's best / the fastest peer's, at 1e-6 and 1e-9).
GOALS = {"wings": (1.0, 0.5)}


# ----------------------------------------------------------------------------- cases
@dataclasses.dataclass(frozen=True)
class BenchCase:
    """One row group of the report: `model` run from 0 to `t1` with `n_save` save times.
    `group`: ``"reference"``, ``"stiff"`` or ``"extreme"``; `small`: the small hinges of the
    ``eq30`` / ``hybrid-k`` formulations (None: full only); `hybrid_modes`: the k of the
    ``hybrid-k`` rows; `solvers` / `tolerances`: restrictions for long cases (None: all);
    `references`: the two reference solvers (None: the group's, see :func:`_references`);
    `relative`: the hinges of a relative error, the larger of the hub rate's error over its
    peak and these hinges' angles' over theirs (None: the absolute error in omega0 and every
    gamma); `peer_torque`: ``t -> (3,)`` in numpy, the torque on body 0 (its axes) that the
    model's loads apply, for the peers, which take no jaxtree loads (Pinocchio as the free
    flyer's generalized force; a peer that takes no base torque is skipped with a note; None:
    a case with loads has no peers); `peer_methods`: scipy's methods for Pinocchio, each over the
    whole ladder, the first the cross-check (None: the group's, RK45 and Radau at their two
    loosest settings)."""

    name: str
    group: str
    description: str
    model: Model
    t1: float
    n_save: int = 101
    small: tuple[int, ...] | None = None
    hybrid_modes: tuple[int, ...] = ()
    solvers: tuple[str, ...] | None = None
    tolerances: tuple[float, ...] | None = None
    references: tuple[str, str] | None = None
    relative: tuple[int, ...] | None = None
    peer_torque: Callable[[float], np.ndarray] | None = None
    peer_methods: tuple[str, ...] | None = None


def _scene(name):

    return load_scene(name)


def _with(model: Model, **fields) -> Model:
    names = tuple(fields)
    return eqx.tree_at(lambda m: tuple(getattr(m, k) for k in names), model, tuple(fields.values()))


def _hinge_inertia(model: Model) -> np.ndarray:
    """Per hinge, its body's moment of inertia about the hinge line (parallel axes)."""
    axis, r = np.asarray(model.axis, float), np.asarray(model.hinge_on_body, float)
    inertia, mass = np.asarray(model.inertia, float)[1:], np.asarray(model.mass, float)[1:]
    return np.einsum("ki,kij,kj->k", axis, inertia, axis) + mass * np.sum(np.cross(axis, r) ** 2, 1)


def stiff_chain(scale: float) -> Model:
    """chain10 with the tip hinge's spring x `scale` and damped at a ratio of 0.7; the other
    hinges keep their springs, damped at a ratio of 0.02 (benchmarks/bench_stability.py)."""
    base = _scene("chain10")
    k = np.asarray(base.stiffness, float).copy()
    k[-1] *= scale
    zeta = np.full(base.n, 0.02)
    zeta[-1] = 0.7
    c = 2 * zeta * np.sqrt(k * _hinge_inertia(base))
    return _with(base, stiffness=jnp.asarray(k), damping=jnp.asarray(c))


def _fig4_state(**changes) -> Model:
    model = _scene("fig4_free")
    s = model.initial
    gamma, gamma_dot = np.asarray(s.gamma, float).copy(), np.asarray(s.gamma_dot, float).copy()
    omega0 = np.asarray(s.omega0, float).copy()
    if "rotor" in changes:
        gamma_dot[model.names.index("rotor") - 1] = changes["rotor"]
    if "inner" in changes:
        gamma[model.names.index("gimbal_inner") - 1] = changes["inner"]
    if "omega0" in changes:
        omega0 = np.asarray(changes["omega0"], float)
    state = s._replace(omega0=jnp.asarray(omega0), gamma=jnp.asarray(gamma), gamma_dot=jnp.asarray(gamma_dot))
    return _with(model, initial=state)


def _tiny_body() -> Model:
    model = _scene("fig4_free")
    k = model.names.index("panel_side")
    mass = np.asarray(model.mass, float).copy()
    inertia = np.asarray(model.inertia, float).copy()
    mass[k] = 1e-6 * mass[0]
    inertia[k] = 1e-6 * inertia[0]
    return _with(model, mass=jnp.asarray(mass), inertia=jnp.asarray(inertia))


def _panel_hinges(model: Model, prefix: str) -> tuple[int, ...]:
    return tuple(k for k in range(1, model.n + 1) if model.names[k].startswith(prefix))


FLEX95_TORQUE = (15.0, 9.0, 0.0)  # N m on the bus in flex95's slew


def _slew_pulse(t):
    """flex95's slew profile: on at 1 s, off at 3 s, tanh edges of ~0.2 s (0.1 s time constant)."""
    return 0.5 * (jnp.tanh((t - 1.0) / 0.1) - jnp.tanh((t - 3.0) / 0.1))


def _slew_torque_np(t) -> np.ndarray:
    """flex95's slew torque in numpy, for the peers' right sides (a JAX call per right side would
    add its dispatch to every Pinocchio evaluation and distort the peer's timing)."""
    return np.asarray(FLEX95_TORQUE) * (0.5 * (math.tanh((t - 1.0) / 0.1) - math.tanh((t - 3.0) / 0.1)))


def flex95_slew() -> Model:
    """flex95 (the scene: rotor at 10 pi rad/s, the bus spinning, wings straight) with the slew
    torque of the slew on the bus: :data:`FLEX95_TORQUE` times :func:`_slew_pulse`."""

    return _scene("flex95").with_loads(BodyTorque(0, jnp.asarray(FLEX95_TORQUE), _slew_pulse))


def _case(name: str) -> BenchCase:
    if name.startswith("stiff_"):
        try:
            scale = float(name.split("_", 1)[1])
        except ValueError:
            raise ValueError(f"bench case {name!r}: expected stiff_<scale>, e.g. stiff_1e6") from None
        model = stiff_chain(scale)
        return BenchCase(
            name,
            "stiff",
            f"chain10, tip hinge's spring x {scale:g} (damping ratio 0.7), 1 s",
            model,
            1.0,
            # every hinge small: Eq. (30) keeps the fast tip mode, the hybrid model's 2 modes leave it out
            small=tuple(range(1, model.n + 1)),
            hybrid_modes=(2,),
        )
    if name in ("fig4", "fig4_free"):
        what = {"fig4": "the seed's Fig. 4 (platform prescribed)", "fig4_free": "Fig. 4, platform free"}
        return BenchCase(name, "reference", what[name] + ", 10 s", _scene(name), 10.0)
    if name == "chain50":
        what = "hub and a sprung boom of 50 segments, 10 s"
        return BenchCase(name, "reference", what, _scene(name), 10.0, solvers=LARGE_SOLVERS)
    if name == "appendix_c":
        m = _scene(name)
        return BenchCase(name, "reference", "the seed's Appendix C, 10 s", m, 10.0, small=(1, 2), hybrid_modes=(1,))
    if name == "wings":
        m = _scene(name)
        return BenchCase(
            name, "reference", "hub and two wings of 4 sprung panels, 10 s", m, 10.0,
            small=tuple(range(1, m.n + 1)), hybrid_modes=(1, 2),
        )  # fmt: skip
    if name == "panels95":
        m = _scene(name)
        return BenchCase(
            name, "reference", "the 95-body vehicle of Fig. 2/3c, 10 s", m, 10.0,
            small=_panel_hinges(m, "wing"), hybrid_modes=(2,), solvers=LARGE_SOLVERS,
        )  # fmt: skip
    if name == "flex95":
        m = flex95_slew()
        return BenchCase(
            name, "stiff",
            "flex95's slew (wing modes to 433 rad/s; rotor at 10 pi rad/s, the scene's bus spin, (15, 9, 0) N m on "
            "the bus from 1 s to 3 s, 0.2 s tanh edges), 10 s; error: the hub rate relative to its peak and the "
            "wing angles relative to theirs, the larger",
            m, 10.0, solvers=FLEX95_SOLVERS, references=("Dopri8", "Tsit5"), relative=_panel_hinges(m, "wing"),
            peer_torque=_slew_torque_np, peer_methods=("DOP853", "Radau"),
        )  # fmt: skip
    extreme = {
        "rotor_10pi": (lambda: _fig4_state(rotor=10 * math.pi), "fig4_free, rotor at 10 pi rad/s, 10 s", 10.0),
        "rotor_1000pi": (lambda: _fig4_state(rotor=1000 * math.pi), "fig4_free, rotor at 1000 pi rad/s, 10 s", 10.0),
        "bus_spin": (lambda: _fig4_state(omega0=(0.0, 0.0, 10.0)), "fig4_free, bus spinning at 10 rad/s, 10 s", 10.0),
        "gimbal_lock": (
            lambda: _fig4_state(inner=math.pi / 2 - 1e-3),
            "fig4_free, inner gimbal 1e-3 rad from lock, 10 s",
            10.0,
        ),
        "tiny_body": (_tiny_body, "fig4_free, panel_side with 1e-6 of the bus's mass and inertia, 10 s", 10.0),
    }
    if name in extreme:
        build, what, t1 = extreme[name]
        return BenchCase(name, "extreme", what, build(), t1)
    if name == "long_run":
        return BenchCase(
            name, "extreme", "fig4_free over 1000 s (drift against time)", _scene("fig4_free"), 1000.0,
            n_save=201, solvers=("Tsit5", "Dopri8", "Kvaerno5"), tolerances=(1e-6, 1e-8, 1e-10),
        )  # fmt: skip
    raise ValueError(f"unknown bench case {name!r}; known: {', '.join(CASES)}")


CASES = (
    "fig4",
    "fig4_free",
    "appendix_c",
    "wings",
    "chain50",
    "panels95",
    "flex95",
    "stiff_1e2",
    "stiff_1e4",
    "stiff_1e6",
    "stiff_1e8",
    "rotor_10pi",
    "rotor_1000pi",
    "bus_spin",
    "gimbal_lock",
    "tiny_body",
    "long_run",
)
QUICK_CASES = ("wings",)
QUICK_SOLVERS = ("Tsit5", "Dopri8", "Kvaerno5", "RK4")


def bench_case(name: str) -> BenchCase:
    """The case `name` of :data:`CASES` (``"stiff_1e8"`` etc. for any scale)."""
    return _case(name)


# ----------------------------------------------------------------------------- runs
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


@dataclasses.dataclass
class BenchReport:
    """The rows of a work-precision run (one dict per run: case, group, formulation, engine,
    solver, method, setting, error, time_s, compile_s, steps, rejected, rhs, energy_drift,
    momentum_drift, status, note) with the machine line, the references' floors per case, the
    solver that ``"auto"`` picks per case, and the peers' cross-checks."""

    rows: list[dict]
    machine: str
    date: str
    references: dict[str, dict]
    auto: dict[str, str]
    cross_checks: dict[str, dict]
    settings: dict

    COLUMNS = (
        "case", "group", "formulation", "engine", "solver", "method", "setting", "status", "error",
        "time_s", "compile_s", "steps", "rejected", "rhs", "energy_drift", "momentum_drift", "note",
    )  # fmt: skip

    def best(self, case: str, target: float) -> dict[str, dict]:
        """Per method, its cheapest row of `case` that reaches `target`."""
        out: dict[str, dict] = {}
        for r in self.rows:
            if r["case"] != case or not (r["error"] <= target) or r["status"] != "ok":
                continue
            if r["method"] not in out or r["time_s"] < out[r["method"]]["time_s"]:
                out[r["method"]] = r
        return out

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=self.COLUMNS, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for r in self.rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
        return buf.getvalue()

    def cases(self) -> list[str]:
        return list(dict.fromkeys(r["case"] for r in self.rows))

    def summary(self, case: str) -> list[str]:
        """Markdown lines: time to each target per method, fastest first, with the ratio to the
        fastest peer."""
        lines = []
        for target in TARGETS:
            best = sorted(self.best(case, target).values(), key=lambda r: r["time_s"])
            if not best:
                lines.append(f"- to {target:g}: no run reached it")
                continue
            peers = [r for r in best if r["engine"] != "jaxtree"]
            ours = [r for r in best if r["engine"] == "jaxtree"]
            part = ", ".join(f"{r['method']} {_ms(r['time_s'])}" for r in best[:6])
            ratio = ""
            if peers and ours:
                x = ours[0]["time_s"] / peers[0]["time_s"]
                ratio = f" — jaxtree's best ({ours[0]['method']}) / fastest peer ({peers[0]['method']}): **{x:.2f}x**"
                if case in GOALS:
                    goal = GOALS[case][TARGETS.index(target)]
                    ratio += f" (goal <= {goal:g}x: {'met' if x <= goal else 'not met'})"
            lines.append(f"- to {target:g}: {part}{ratio}")
        return lines

    def _fastest(self, case: str, target: float, engine: str | None, formulation: str | None = "full"):
        """The cheapest row of `case` reaching `target`: jaxtree's (`engine` "jaxtree"), the
        peers' (`engine` None) or any; `formulation` None admits every formulation."""
        best = [
            r
            for r in self.best(case, target).values()
            if (engine is None and r["engine"] != "jaxtree") or engine in (r["engine"], "any")
            if formulation is None or r["formulation"] == formulation
        ]
        return min(best, key=lambda r: r["time_s"]) if best else None

    def findings(self) -> list[str]:
        """Markdown lines drawn from the rows: the fastest settings per case and target, where
        explicit solvers stall, what float32 and the modal formulations give, and the solver
        that the data recommends per group of cases. Regenerated with the report."""
        out = [
            "## Findings (drawn from the rows below)",
            "",
            "| case | group | `auto` picks | jaxtree fastest to 1e-6 | to 1e-9 | fastest peer to 1e-6 | to 1e-9 |",
            "|---|---|---|---|---|---|---|",
        ]

        def cell(r):
            return "-" if r is None else f"{r['method'].removeprefix('jaxtree ')} {_ms(r['time_s'])}"

        wins: dict[str, dict[str, int]] = {}
        for case in self.cases():
            group = next(r["group"] for r in self.rows if r["case"] == case)
            ours = [self._fastest(case, t, "jaxtree") for t in TARGETS]
            peers = [self._fastest(case, t, None) for t in TARGETS]
            auto = self.auto.get(case, "-").split(" (")[0]
            out.append(
                f"| {case} | {group} | {auto} | {cell(ours[0])} | {cell(ours[1])} | {cell(peers[0])} | {cell(peers[1])} |"
            )
            for r in ours:
                if r is not None:
                    tally = wins.setdefault(group, {})
                    tally[r["solver"]] = tally.get(r["solver"], 0) + 1
        out.append("")
        stalls = [
            r for r in self.rows if r["engine"] == "jaxtree" and r["status"] in ("stalled", "collapsed", "unstable")
        ]
        if stalls:
            out.append(
                f"Runs held at the step cap ({STEP_CAP} explicit, {IMPLICIT_STEP_CAP} implicit steps: *stalled*), "
                "whose step size collapsed below the minimum step (*collapsed*) or beyond RK4's stability region "
                "(*unstable*, not run):"
            )
            by_case: dict[str, list[str]] = {}
            for r in stalls:
                kind = "implicit" if r["solver"] in IMPLICIT else "explicit"
                form = "" if r["formulation"] == "full" else f" [{r['formulation']}]"
                by_case.setdefault(r["case"], []).append(f"{r['solver']}{form} ({kind}) {_setting(r)} {r['status']}")
            out += [f"- {c}: " + ", ".join(v) for c, v in by_case.items()]
            out.append("")
        failed = [r for r in self.rows if r["status"] == "failed"]
        out.append(
            "Failed runs: "
            + (", ".join(f"{r['case']} {r['method']} {_setting(r)} ({r['note']})" for r in failed) or "none")
            + "."
        )
        refused = [r for r in self.rows if r["status"] == "refused"]
        if refused:
            out.append(
                "Refused by `simulate`'s checks of the initial state (singular to working precision): "
                + ", ".join(f"{r['case']} {r['method']} {_setting(r)}" for r in refused)
                + "."
            )
        out.append("")
        f32 = [r for r in self.rows if r["formulation"] == "float32" and r["status"] == "ok"]
        if f32:
            parts = []
            for case in dict.fromkeys(r["case"] for r in f32):
                rs = [r for r in f32 if r["case"] == case]
                best = min(rs, key=lambda r: r["error"])
                parts.append(f"{case} {best['error']:.1e} ({_setting(best)}, {_ms(best['time_s'])})")
            out += [
                "Float32 (the model cast; error against the float64 reference, smallest reached): "
                + ", ".join(parts)
                + ".",
                "",
            ]
        modal = [r for r in self.rows if r["formulation"] not in ("full", "float32") and r["status"] == "ok"]
        if modal:
            out.append(
                "Modal formulations (their error is the model's, against the full Eq. 1: it stays as the tolerance "
                "tightens), cheapest run of each against the full Eq. (1) by the same solver at the same tolerance:"
            )
            for case in dict.fromkeys(r["case"] for r in modal):
                parts = []
                for form in dict.fromkeys(r["formulation"] for r in modal if r["case"] == case):
                    rs = [r for r in modal if r["case"] == case and r["formulation"] == form]
                    r = min(rs, key=lambda r: r["time_s"])
                    full = [
                        x for x in self.rows
                        if x["case"] == case and x["formulation"] == "full" and x["solver"] == r["solver"]
                        and x["setting"] == r["setting"] and x["status"] == "ok"
                    ]  # fmt: skip
                    vs = f" (full: {_ms(full[0]['time_s'])}, {full[0].get('steps', '')} steps)" if full else ""
                    parts.append(f"{form} error {r['error']:.1e}, {_ms(r['time_s'])}, {r.get('steps', '')} steps{vs}")
                out.append(f"- {case}: " + "; ".join(parts))
            out.append("")
        if wins:
            out.append("The solver of jaxtree's fastest run to 1e-6 and 1e-9, counted per group of cases:")
            for group, tally in wins.items():
                ranked = sorted(tally.items(), key=lambda kv: -kv[1])
                out.append(f"- {group}: " + ", ".join(f"{k} {v}" for k, v in ranked))
            out.append("")
        return out

    def to_markdown(self, plots: dict[str, str] | None = None) -> str:
        s = self.settings
        out = [
            "# Work-precision report",
            "",
            f"Generated by `{s.get('command', 'jaxtree bench')}` on {self.date}"
            + (f", merging {s['parts']}." if s.get("parts") else "."),
            "",
            f"Machine: {self.machine}",
            "",
            "Error: the largest absolute error over the save times in omega0 (rad/s) and gamma (rad), "
            f"against a reference at rtol = atol = {REFERENCE_TOL:g} by a different solver (the floor column: the two "
            "references' difference; a case that names a relative error, as flex95, takes the hub rate's error over "
            "its peak and its wing angles' over theirs). Time: the median of repeated calls after the first, compile time apart "
            "(jaxtree only). Peers run only on the scenes they can represent, cross-checked first. "
            f"A run stopped at the step cap ({STEP_CAP} steps) is *stalled*; its note says how far it got.",
            "",
        ]
        out += self.findings()
        for case in self.cases():
            rows = [r for r in self.rows if r["case"] == case]
            ref = self.references.get(case, {})
            out += [f"## {case} ({rows[0]['group']})", ""]
            if ref:
                out.append(
                    f"{ref.get('description', '')}. References {ref['primary']}{_at(ref, 'primary')} / "
                    f"{ref['secondary']}{_at(ref, 'secondary')}, floor "
                    f'{ref["floor"]:.1e}. `solver="auto"` picks: {self.auto.get(case, "-")}.'
                )
            checks = self.cross_checks.get(case, {})
            if checks:
                out.append(
                    "Peers' cross-check at their tightest setting: "
                    + ", ".join(f"{k} {v:.1e}" for k, v in checks.items())
                    + "."
                )
            idle: dict[str, list[str]] = {}  # the peers' skipped methods by reason
            for r in rows:
                if r["engine"] != "jaxtree" and r["status"] == "skipped":
                    methods = idle.setdefault(r["note"], [])
                    methods += [r["method"]] if r["method"] not in methods else []
            if idle:
                out.append("Peers not timed: " + "; ".join(f"{', '.join(m)}: {why}" for why, m in idle.items()) + ".")
            out.append("")
            out += self.summary(case)
            if plots and case in plots:
                out += ["", f"![{case}]({plots[case]})"]
            out += [
                "",
                "| method | setting | status | error | time (ms) | compile (s) | steps | rejected | energy drift | momentum drift |",
                "|---|---|---|---|---|---|---|---|---|---|",
            ]
            for r in rows:
                out.append(
                    f"| {r['method']} | {_setting(r)} | {r['status']} | {_e(r['error'])} | {_ms(r['time_s'], False)} | "
                    f"{_f(r['compile_s'])} | {r.get('steps', '')} | {r.get('rejected', '')} | "
                    f"{_e(r.get('energy_drift', math.nan))} | {_e(r.get('momentum_drift', math.nan))} |"
                )
            out.append("")
        return "\n".join(out) + "\n"

    def plot(self, case: str, path=None):

        methods: dict[str, tuple[list, list]] = {}
        for r in self.rows:
            if r["case"] == case and r["status"] == "ok":
                e, t = methods.setdefault(r["method"], ([], []))
                e.append(r["error"])
                t.append(r["time_s"])
        return plot_work_precision(methods, path, title=f"{case}: error against run time", error_label="max error")

    def save(self, directory, *, stem: str = "work_precision", plots: bool = True) -> dict[str, str]:
        """Write ``<stem>.csv``, ``<stem>.md`` and one ``<stem>_<case>.png`` per case into
        `directory` (each atomically); returns the paths."""

        os.makedirs(directory, exist_ok=True)
        paths = {"csv": os.path.join(directory, f"{stem}.csv"), "md": os.path.join(directory, f"{stem}.md")}
        figs: dict[str, str] = {}
        if plots:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            for case in self.cases():
                name = f"{stem}_{case}.png"
                fig = self.plot(case, os.path.join(directory, name))
                plt.close(fig)
                figs[case] = name
                paths[case] = os.path.join(directory, name)
        paths["json"] = os.path.join(directory, f"{stem}.json")
        with atomic_write(paths["json"], "w") as fh:
            json.dump(dataclasses.asdict(self), fh, indent=1)
        with atomic_write(paths["csv"], "w") as fh:
            fh.write(self.to_csv())
        with atomic_write(paths["md"], "w") as fh:
            fh.write(self.to_markdown(figs))
        return paths

    @classmethod
    def load(cls, path) -> BenchReport:
        """A report saved by :meth:`save` (its ``.json``; a folder: its ``work_precision.json``)."""
        if os.path.isdir(path):
            path = os.path.join(path, "work_precision.json")
        with open(path) as fh:
            return cls(**json.load(fh))

    @classmethod
    def merge(cls, reports: Sequence[BenchReport], command: str = "") -> BenchReport:
        """One report of several run apart (e.g. two halves of the cases in two processes): rows in
        the order of :data:`CASES`, each part's machine line and command kept."""
        rank = {c: i for i, c in enumerate(CASES)}
        rows = sorted((r for rep in reports for r in rep.rows), key=lambda r: rank.get(r["case"], len(rank)))
        merged: dict[str, dict] = {"references": {}, "auto": {}, "cross_checks": {}}
        for rep in reports:
            for key in merged:
                merged[key].update(getattr(rep, key))
        machines = list(dict.fromkeys(rep.machine for rep in reports))
        # a merged report brings its own parts along (merges of merges keep every run's command)
        parts = "; ".join(
            rep.settings.get("parts") or f"`{rep.settings.get('command', '')}` ({rep.date})" for rep in reports
        )
        settings = dict(reports[0].settings, command=command or "jaxtree bench --merge", parts=parts)
        return cls(rows, " | ".join(machines), max(rep.date for rep in reports), settings=settings, **merged)


def _ms(seconds, unit=True) -> str:
    if not (seconds == seconds):
        return "-"
    return f"{1e3 * seconds:.3g} ms" if unit else f"{1e3 * seconds:.3g}"


def _e(x) -> str:
    return "-" if x is None or not (x == x) else f"{x:.1e}"


def _f(x) -> str:
    return "-" if x is None or not (x == x) else f"{x:.2f}"


def _setting(r) -> str:
    if r["solver"] in ("RK4", "RK4 (MuJoCo)") or r["engine"] == "mujoco":
        return f"{r['setting']:g} steps/save"
    return f"tol {r['setting']:g}"


def machine_line() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    from importlib.metadata import version

    def v(name):
        try:
            return version(name)
        except Exception:
            return "-"

    load = "load average {:.1f} {:.1f} {:.1f}; ".format(*os.getloadavg()) if hasattr(os, "getloadavg") else ""
    return (
        f"{platform.system()} {platform.release()}, {cpu}, {os.cpu_count()} cores, {load}python {platform.python_version()}, "
        f"jax {jax.__version__}, diffrax {v('diffrax')}, equinox {v('equinox')}, numpy {np.__version__}, "
        f"jaxtree {v('jaxtree')}, pin {v('pin')}, mujoco {v('mujoco')}, scipy {v('scipy')}; "
        f"backend {jax.default_backend()}"
    )


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


def _at(ref: dict, which: str) -> str:
    """`` (rtol 1e-11)`` where a reference ran looser than :data:`REFERENCE_TOL`."""
    tol = ref.get(f"{which}_tol", REFERENCE_TOL)
    return "" if tol == REFERENCE_TOL else f" (rtol {tol:g})"


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
            # energy is conserved without dampers, loads and prescribed hinges (whose motors do work)
            conservative = (
                not np.any(np.asarray(case.model.damping) != 0.0)
                and case.model.loads is None
                and case.model.prescription is None
            )
            for form, solver, settings in plans[case.name]:
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
                        skip = f"skipped: {last['status']} or slower than {SLOW_S:g} s at {_setting(last)}"
                    bar.step(label)
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
