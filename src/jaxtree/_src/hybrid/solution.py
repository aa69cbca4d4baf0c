"""Simulation in hybrid coordinates: :func:`simulate_hybrid` integrates the right side of
:mod:`.rhs` (Eqs. 118/121 of Likins 1972, Sec. III E) by the integration that
:func:`jaxtree.simulate` runs too (:mod:`jaxtree._src.integration.driver`: the same checks of the
start, singular Eq. (1) included, the same controller, loop and failure codes) and returns a
:class:`HybridSolution` (the physical histories rebuilt by Eqs. 111-112, energy and momentum for
drift checks, and the error of the modes left out, :mod:`.truncation`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from ..cache import checks_without_callbacks
from ..equations.dynamics import configuration_and_rates, energy_and_momentum, mass_center_velocities
from ..equations.kinematics import cross, full_precision
from ..integration.autosolver import choose_for_field, given
from ..integration.core import (
    DEFAULT_MAX_STEPS,
    check_state,
    check_times,
    cut_rows,
    grid_times,
    padded_times,
    progress_meter,
    solver_statistics,
    tolerances,
)
from ..integration.driver import drive, singular_after_failure
from ..integration.failures import MESSAGES, Failure, SimulationError, failure_report, report_failures
from ..integration.radau import with_jacobian
from ..integration.solution import relative_drift
from ..integration.spread import inline_group, over_devices
from ..numerics import eager_jit, is_traced, program_jit
from ..vehicle.model import State
from .model import HybridModel, appendage_body
from .rhs import hybrid_jacobian, hybrid_rhs
from .truncation import truncation_histories, truncation_start


class HybridSolution(eqx.Module):
    """Time histories of :func:`simulate_hybrid` (rows: saved times).

    `ts` (T,); `omega0` (T, 3); `dcm` (T, 3, 3); `gamma`, `gamma_dot` (T, n): all hinges, the
    small ones rebuilt from the modal coordinates (Eqs. 111-112), prescribed ones from the
    prescription; `modal` (T, m): the modal coordinates; `ys` (T, size): the flat states;
    `t_final` (where the run stopped: `t1` unless it failed), `result` (:class:`diffrax.RESULTS`),
    `stats` (diffrax's step counts; with :class:`~jaxtree.Radau5` also its `jacobians`,
    `factorizations`, `newton_iterations` and `rhs_evaluations`), `hybrid`, and at `t_final` the physical
    :class:`~jaxtree.State` `final` and the modal coordinates `final_modal`.

    For drift checks, at the saved times: `energy` (T,), the kinetic energy relative to the
    system mass center of the physical state plus the potential energy of the hinge springs, and
    `angular_momentum` (T, 3) about the system mass center in inertial components (both of the
    full vehicle rebuilt from the modal coordinates: constant for a free vehicle without damping
    up to the linearization and truncation errors). `projection_residual`: the part of the
    initial small motion outside the retained modes, ``|[y; y'] - [positions; rates] s| /
    |[y; y']|`` (0 when the start lies in the retained modes; NaN for a flat start).

    Truncation (:func:`simulate_hybrid`; None with ``truncation_error=False``): `truncation`
    (T, nu), the estimated contribution of the neglected modes to the small angles (full minus
    hybrid), `truncation_static` (T, nu) its quasi-static part, `truncation_error` (T,) the
    largest entry of `truncation` in magnitude per save time (rad); `truncation_state` (N, 2):
    the neglected modes' coordinates at the last save time (real and imaginary parts), to
    continue the estimate in a next run (``simulate_hybrid(..., truncation_start=...)``).
    With finite-element appendages, `appendage_truncation` (T, sum of their held-interface
    coordinates): the neglected held-base modes' contribution to those coordinates, the same
    estimate driven by the appendages' unbalanced force (:func:`appendage_unbalanced`; from rest);
    :meth:`appendage_truncation_at` turns it into a node's displacement.
    """

    ts: jax.Array
    omega0: jax.Array
    dcm: jax.Array
    gamma: jax.Array
    gamma_dot: jax.Array
    modal: jax.Array
    ys: jax.Array
    t_final: jax.Array
    result: Any
    stats: dict
    hybrid: HybridModel
    final: State | None = None
    final_modal: jax.Array | None = None
    energy: jax.Array | None = None
    angular_momentum: jax.Array | None = None
    projection_residual: jax.Array | None = None
    failure: jax.Array | None = None
    truncation: jax.Array | None = None
    truncation_static: jax.Array | None = None
    truncation_error: jax.Array | None = None
    truncation_state: jax.Array | None = None
    appendage_truncation: jax.Array | None = None

    @property
    def ok(self) -> bool:
        return bool(np.all(np.asarray(self.failure == 0)))

    def max_truncation_error(self):
        """``max_t truncation_error``: the estimated largest error of the small angles (rad) from
        the neglected modes over the run (per run of a batch)."""
        return jnp.max(jnp.asarray(self.truncation_error), -1)

    def appendage_truncation_at(self, index: int = 0, node: int | None = None):
        """(T, 6): the estimated displacement of `node` (default: the first output node) of
        appendage `index` from its neglected modes (translations, then small rotations; body's
        frame): the mode shapes times :attr:`appendage_truncation`'s coordinates."""
        hm = self.hybrid
        if self.appendage_truncation is None:
            raise ValueError("appendage_truncation_at: no estimate (truncation_error=False, or no appendage)")
        ap = hm.appendages[index]
        if node is None:
            if not ap.outputs:
                raise ValueError("appendage_truncation_at: the appendage has no output nodes; pass node=")
            node = ap.outputs[0]
        o = sum(a.n_modes for a in hm.appendages[:index])
        q = jnp.asarray(self.appendage_truncation)[..., o : o + ap.n_modes]
        d = ap.dofs
        return q @ ap.shapes[d * node : d * node + d].T

    def appendage_motion(self, scale: float = 1.0) -> list[dict]:
        """The finite-element appendages' nodes at the saved times, for
        :func:`jaxtree.write_animation` (its `appendages`): per appendage a dict with ``name``,
        ``body`` (the index of the body it is fixed to), ``nodes`` (n, 3: undeformed, from the
        body's mass center, its frame), ``edges`` (the elements' sides) and ``displacement``
        (T, n, 3): the held-interface mode shapes times the modal coordinates (the translations,
        body's frame), times `scale` (a deformation too small to see at 1)."""
        hm = self.hybrid
        ys = jnp.asarray(self.ys)
        out = []
        for i, ap in enumerate(hm.appendages):
            q = jax.vmap(lambda y, i=i: hm.appendage_coordinates(y)[i][0])(ys)  # (T, k)
            n = ap.nodes.shape[0]
            shapes = jnp.reshape(ap.shapes, (n, ap.dofs, -1))[:, :3]  # (n, 3, k)
            out.append(
                {
                    "name": ap.name or f"appendage{i}",
                    "body": appendage_body(hm.model, ap),
                    "nodes": np.asarray(ap.nodes + ap.point[None, :]),
                    "edges": ap.edges,
                    "displacement": float(scale) * np.asarray(jnp.einsum("nck,tk->tnc", shapes, q)),
                }
            )
        return out

    def energy_drift(self):
        """``max |E - E_0| / |E_0|`` over the saved times (as :meth:`jaxtree.Solution.energy_drift`)."""
        return relative_drift(self.energy)

    def momentum_drift(self):
        """``max |H - H_0| / |H_0|`` over the saved times (as :meth:`jaxtree.Solution.momentum_drift`)."""
        return relative_drift(self.angular_momentum)


def _hybrid_failure_message(code, t, state, modal):
    """The report of failed hybrid runs (batch index, time, physical state, modal coordinates),
    or None when every run succeeded."""
    np.set_printoptions(precision=6, suppress=False, linewidth=120)

    def describe(kind, pick):
        lines = [
            f"jaxtree.simulate_hybrid: {MESSAGES[kind]}.",
            f"  stopped at t = {float(pick(t)):.9g}",
            f"  omega0 = {pick(state.omega0)}",
            f"  gamma = {pick(state.gamma)}",
            f"  gamma_dot = {pick(state.gamma_dot)}",
            f"  C = {pick(state.dcm).tolist()}",
            f"  modal coordinates = {pick(modal)}",
        ]
        if not all(np.all(np.isfinite(pick(x))) for x in state):
            lines.append("  diagnosis: the state is not finite")
        return "\n".join(lines)

    return failure_report(code, describe)


@eager_jit
def _energy_and_momentum(hm: HybridModel, state, coords=()):
    """Kinetic energy plus the potential energy of the hinge springs and of the appendages' modes,
    and the angular momentum about the vehicle's mass center (inertial components).

    The tree's bodies give their share from their velocities relative to the tree's mass center
    (:func:`~jaxtree._src.equations.dynamics.energy_and_momentum`). Each finite-element appendage
    (`coords`: its modal coordinates and rates, :meth:`HybridModel.appendage_coordinates`) gives
    its generalized momentum ``h = A(q) z`` from the Gauss function's Taylor terms of its base
    (``A = A0 + A1 q``, the same first order in ``q`` as its equations; ``z`` the base's angular
    velocity and mass-center velocity in its frame, then ``q'``; the base's rows of ``A`` and its
    modal block, which the geometric stiffness leaves alone): ``z . A z / 2`` of kinetic energy,
    ``h[:3]`` its angular momentum about the base's mass center, ``h[3:6]`` its linear momentum,
    ``omega_j^2 q_j^2 / 2`` of strain energy. Koenig's theorem then moves the sum from the tree's
    mass center to the vehicle's: ``T - M |v_c|^2 / 2`` and ``H - M r_c x v_c``, with ``v_c`` and
    ``r_c`` the vehicle's mass center velocity and position relative to the tree's. (The
    geometric stiffness's share, the work of the preload, is not in the potential energy.)"""
    model = hm.model
    T, H = energy_and_momentum(model, state)
    if model.sprung:
        k = np.asarray(model.sprung, np.int64) - 1
        T = T + 0.5 * jnp.sum(model.stiffness[k] * state.gamma[k] ** 2)
    if not coords:
        return T, H
    dtype = T.dtype
    cfg, omega = configuration_and_rates(
        model, state.gamma, jnp.asarray(state.omega0, dtype), jnp.asarray(state.gamma_dot, dtype)
    )
    vel = mass_center_velocities(model, cfg, omega)
    H0 = jnp.zeros((3,), dtype)  # {b^0} components, about the tree's mass center
    P = jnp.zeros((3,), dtype)
    S = jnp.zeros((3,), dtype)
    M = jnp.sum(model.mass.astype(dtype))
    for ap, (q, qd) in zip(hm.appendages, coords, strict=True):
        b = appendage_body(model, ap)
        R = cfg.R[b]
        z = jnp.concatenate([R.T @ omega[b], R.T @ vel[b], qd])
        A = ap.terms.A0 + ap.terms.A1 @ q
        h = A[:6] @ z  # the base's rows: the geometric stiffness is in the modal rows only
        T = T + 0.5 * (z[:6] @ h + qd @ (A[:6, 6:].T @ z[:6] + A[6:, 6:] @ qd)) + 0.5 * jnp.sum(ap.stiffness * q * q)
        p = R @ h[3:6]
        H0 = H0 + R @ h[:3] + cross(cfg.rho[b], p)
        P = P + p
        first = ap.first_moment + ap.mass * ap.point + ap.participation[:, 3:6].T @ q  # about b's mass center
        S = S + ap.mass * cfg.rho[b] + R @ first
        M = M + ap.mass
    v_c, r_c = P / M, S / M
    T = T - 0.5 * M * v_c @ v_c
    H = H + jnp.asarray(state.dcm, dtype).T @ (H0 - M * cross(r_c, v_c))
    return T, H


_HISTORIES = (
    "ts", "omega0", "dcm", "gamma", "gamma_dot", "modal", "ys", "energy", "angular_momentum",
    "truncation", "truncation_static", "truncation_error", "appendage_truncation",
)  # fmt: skip


@program_jit
def _solve_hybrid(
    hybrid, y0, t0, t1, ts, rtol, atol, dt0, solver, controller, max_steps, report, residual, meter, truncation, q_start,
    check_start,
):  # fmt: skip
    # the shared integration (integration/driver.py): the start checked (finite; with
    # `check_start`, Eq. (1) regular there), the default controller, the loop, the failure code
    dtype = y0.dtype
    model = hybrid.model
    rest = hybrid.pack(
        State(
            jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype), hybrid.gamma_nominal.astype(dtype), jnp.zeros(model.n, dtype)
        )
    )
    driven = drive(
        hybrid_rhs,
        hybrid,
        y0,
        t0,
        t1,
        solver=solver,
        controller=controller,
        rtol=rtol,
        atol=atol,
        dt0=dt0,
        rest=rest,
        max_steps=max_steps,
        ts=ts,
        progress_meter=meter,
        check_start=check_start,
        # `check_start` is set in a traced run alone; an eager run is never differentiated: plain
        # while loops (diffrax.ForwardMode), without reverse mode's checkpointing
        adjoint=dfx.RecursiveCheckpointAdjoint() if check_start else dfx.ForwardMode(),
    )
    ts_h, ys_h, t_final, y_final, sol, code = driven[:6]
    states = jax.vmap(hybrid.state)(ts_h, ys_h)
    final = hybrid.state(t_final, y_final)
    energy, momentum = jax.vmap(lambda st, y: _energy_and_momentum(hybrid, st, hybrid.appendage_coordinates(y)))(
        states, ys_h
    )
    dyn, stat, q_end, app = truncation_histories(hybrid, t0, ts_h, ys_h, q_start, dtype) if truncation else (None,) * 4
    out = HybridSolution(
        ts=ts_h,
        omega0=states.omega0,
        dcm=states.dcm,
        gamma=states.gamma,
        gamma_dot=states.gamma_dot,
        modal=jax.vmap(hybrid.modal)(ys_h),
        ys=ys_h,
        t_final=t_final,
        result=sol.result,
        stats=dict(sol.stats, **solver_statistics(solver, sol)),
        hybrid=hybrid,
        final=final,
        final_modal=hybrid.modal(y_final),
        energy=energy,
        angular_momentum=momentum,
        projection_residual=residual,
        failure=code,
        truncation=dyn,
        truncation_static=stat,
        truncation_error=None if dyn is None else jnp.max(jnp.abs(dyn), -1, initial=0.0),
        truncation_state=q_end,
        appendage_truncation=app,
    )
    if report:  # under a caller's jit/vmap: report failures from one host callback (for a whole batch)
        report_failures(_raise_if_failed, code != 0, jax.lax.stop_gradient((code, t_final, final, out.final_modal)))
    return out


_REPORT = 11  # the position of `report` among _solve_hybrid's arguments


def _quiet(args):
    """:func:`_solve_hybrid`'s arguments without its in-program failure report (for
    :func:`~jaxtree._src.integration.spread.over_devices`)."""
    return args[:_REPORT] + (False,) + args[_REPORT + 1 :]


def _report_batch(args, rerun, sol) -> None:
    """The failure report of a batch split over the devices, made on the host from the whole
    batch (as a vmapped run's callback makes it), where the run reports."""
    if args[_REPORT]:
        tree = lambda x: jax.tree_util.tree_map(np.asarray, x)
        _raise_if_failed(np.asarray(sol.failure), np.asarray(sol.t_final), tree(sol.final), tree(sol.final_modal))


def _group(args, share: int):
    """Members per vmapped group of a device's `share`: one after another for an implicit solver,
    else groups whose dense solve of the hybrid system (at most the state's size) stays under
    jaxlib's threshold for splitting a batched LAPACK call over the thread pool."""
    if isinstance(args[8], dfx.AbstractImplicitSolver):
        return 1
    return inline_group(int(np.shape(args[1])[-1]))


def _raise_if_failed(code, t, state, modal):
    """Raise :class:`jaxtree.SimulationError` with the report of the failed hybrid runs, if any."""
    message = _hybrid_failure_message(code, t, state, modal)
    if message is not None:
        raise SimulationError(message)


@program_jit
def _jacobian(t, y, args: HybridModel):
    """:func:`.rhs.hybrid_jacobian`, jitted so that the solver's several traces share one jaxpr."""
    return hybrid_jacobian(t, y, args)


@program_jit(light=True)
def _pack_with_residual(hybrid: HybridModel, y0: State):
    # One compiled call: op by op (eagerly) the projection took ~50 ms of dispatches, more than
    # a whole 10 s run of wings in hybrid coordinates.
    dtype = jnp.result_type(hybrid.model.mass)
    S = np.asarray(hybrid.small, np.int64) - 1
    y = jnp.asarray(y0.gamma, dtype)[S] - hybrid.gamma_nominal.astype(dtype)[S]
    x0 = jnp.concatenate([y, jnp.asarray(y0.gamma_dot, dtype)[S]])
    return hybrid.pack(y0), hybrid.projection_residual(y0), truncation_start(hybrid, x0)


@full_precision
def simulate_hybrid(
    hybrid: HybridModel,
    t1,
    *,
    t0: float | jax.Array = 0.0,
    y0: State | jax.Array | None = None,
    saveat: int | ArrayLike = 101,
    solver: dfx.AbstractSolver | str | None = "auto",
    stepsize_controller: dfx.AbstractStepSizeController | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt0=None,
    max_steps: int = DEFAULT_MAX_STEPS,
    throw: bool = True,
    progress: bool | dfx.AbstractProgressMeter = False,
    truncation_error: bool = True,
    truncation_start: ArrayLike | None = None,
) -> HybridSolution:
    """Integrate the hybrid-coordinate equations with diffrax.

    - `y0`: a physical :class:`~jaxtree.State` (default ``hybrid.model.initial``), projected on
      the retained modes by :meth:`HybridModel.pack`, or a flat hybrid state;
    - `saveat`: a number of evenly spaced save times (default 101) or an array of times (an
      eager call compiles for a bucket of save times, as :func:`jaxtree.simulate` does);
    - `solver`: a diffrax solver (a :class:`jaxtree.Radau5` without a Jacobian of its own gets
      :func:`jaxtree.hybrid_jacobian`), or ``"auto"`` (the default; None too): Dopri8 or
      Radau5, whichever :func:`jaxtree.choose_solver`'s rule predicts to reach the tolerance in
      less run time, from the hybrid right side's Jacobian and its values over the run
      (``sol.stats["solver"]`` says which and why; Dopri8 when the inputs are traced);
      `stepsize_controller`: default a PID controller
      with `rtol`, `atol` (as :func:`jaxtree.simulate`: default :func:`jaxtree.default_tolerance`
      of the model's dtype); `dt0`: default ``1e-3 |t1 - t0|``;
    - `progress`: diffrax's progress meter, as in :func:`jaxtree.simulate`;
    - `truncation_error`: estimate the small angles' error from the neglected modes (default;
      ``False`` saves its cost: one evaluation of Eq. 1 per save time, and its compilation);
      `truncation_start`: a previous run's ``truncation_state``, for a run that continues it
      (default: the neglected modes' content of `y0`, none for a flat state).

    **Truncation error.** ``sol.truncation`` (T, nu) estimates the neglected modes' part of the
    small angles at the save times, i.e. the full model's small angles minus the hybrid ones
    (``sol.gamma[:, small] + sol.truncation`` is a corrected history), ``sol.truncation_error``
    (T,) its largest magnitude per save time (rad), ``sol.max_truncation_error()`` the largest
    over the run; ``sol.truncation_static`` the quasi-static part alone (static correction).
    The neglected modes (left out, or masked by :meth:`HybridModel.retain`) are driven by the
    generalized force that the hybrid motion leaves unbalanced on the small rows of Eq. (1),
    interpolated linearly between save times: save times that resolve the slowest neglected
    modes' forcing are needed (those of a 0.2 s edge: 101 over 10 s suffice). It is the
    one-way response: the neglected modes' reaction on the large motion is left out, as is the
    linearization error of Eq. (30) and the integration error.

    The integration is :func:`jaxtree.simulate`'s (:mod:`jaxtree._src.integration.core`): the same
    step-size control, save-time layout, failure kinds and failure report.

    Raises :class:`jaxtree.SimulationError` when the run fails and `throw` is set, naming the
    time, the physical state and the modal coordinates where it stopped: at once when called
    eagerly, from a host callback at run time under ``jax.jit`` or ``jax.vmap`` (one for a whole
    batch). Tolerances, controllers and solvers may be traced (a vmapped tolerance sweep).
    """

    dtype = jnp.result_type(hybrid.model.mass)
    # (stacklevel 3: the caller of full_precision's wrapper)
    rtol, atol = tolerances("simulate_hybrid", rtol, atol, max_steps, dtype, stepsize_controller, stacklevel=3)
    y, residual, q_start = _hybrid_start(hybrid, y0, truncation_start, dtype)
    # an eager run's save grid is padded to its size bucket and the histories cut back after
    # (save_bucket): another number of save points or other times compile nothing
    exact = is_traced((hybrid, y, t0, t1, saveat, rtol, atol, dt0, solver, stepsize_controller, q_start))
    ts, n_saved = _hybrid_save_times(saveat, t0, t1, dtype, exact)
    t0a, t1a = jnp.asarray(t0, dtype), jnp.asarray(t1, dtype)
    dt0 = 1e-3 * (t1a - t0a) if dt0 is None else jnp.asarray(dt0, dtype)
    if solver is None or isinstance(solver, str):
        if solver not in (None, "auto"):
            raise ValueError(f"simulate_hybrid: solver must be a diffrax solver or 'auto', got {solver!r}")
        solver, choice = choose_for_field(
            hybrid_rhs, hybrid, y, t0a, t1a, rtol=rtol, atol=atol, what="the hybrid equations linearized at the start"
        )
    else:
        choice = given(solver)
    solver = with_jacobian(solver, _jacobian)  # a Radau5 without one: the hybrid model's structured Jacobian
    traced = is_traced((hybrid, y, t0a, t1a, ts, rtol, atol, dt0, solver, stepsize_controller))
    with checks_without_callbacks():  # diffrax's checks of inputs checked above: cacheable program
        # (an eager jax.vmap of simulate_hybrid: its members split over the host devices, spread.py)
        sol = over_devices(
            _solve_hybrid,
            (
                hybrid,
                y,
                t0a,
                t1a,
                ts,
                jnp.asarray(rtol, dtype),
                jnp.asarray(atol, dtype),
                dt0,
                solver,
                stepsize_controller,
                int(max_steps),
                bool(throw and traced),
                residual,
                progress_meter(progress),
                bool(truncation_error),
                q_start,
                traced,  # an eager run tests its start for a singular Eq. (1) only once it failed (below)
            ),
            quiet=_quiet,
            report=_report_batch,
            group=_group,
        )
    if not traced:
        sol = _singular_start_after(sol, hybrid, y, t0a)
    sol = eqx.tree_at(lambda s: s.stats, sol, dict(sol.stats, solver=choice))
    if n_saved is not None:
        size = sol.ts.shape[0]
        sol = dataclasses.replace(sol, **{k: cut_rows(getattr(sol, k), size, n_saved) for k in _HISTORIES})
    if throw and not traced:
        _raise_if_failed(sol.failure, sol.t_final, sol.final, sol.final_modal)
    return sol


def _singular_start_after(sol: HybridSolution, hybrid: HybridModel, y, t0) -> HybridSolution:
    """`sol` of an eager run, reported as a singular start (as the in-program test of a traced run
    reports it: t_final `t0`, NaN histories) where it failed and Eq. (1) is singular at its
    start (:func:`jaxtree._src.integration.driver.singular_after_failure`)."""
    if sol.failure is None or int(sol.failure) == 0 or not bool(singular_after_failure(hybrid, t0, y)):
        return sol
    nan = lambda a: None if a is None else jnp.full_like(a, jnp.nan)
    failure = jnp.asarray(int(Failure.SINGULAR_START), jnp.result_type(sol.failure))
    start = dict(t_final=t0, final=hybrid.state(t0, y), final_modal=hybrid.modal(y))
    return dataclasses.replace(sol, failure=failure, **start, **{k: nan(getattr(sol, k)) for k in _HISTORIES[1:]})


def _hybrid_start(hybrid: HybridModel, y0, truncation_start, dtype):
    """``(y, residual, q_start)`` of simulate_hybrid's `y0` (default the model's initial state):
    the flat start, its projection residual and the neglected modes' start, checked."""
    y0 = hybrid.model.initial if y0 is None else y0
    if isinstance(y0, State):
        check_state("simulate_hybrid", hybrid.model, y0)
        y, residual, q_start = _pack_with_residual(hybrid, y0)
    else:  # a flat state holds the retained modes only: the neglected ones start at rest
        y, residual = jnp.asarray(y0, dtype), jnp.asarray(np.nan, dtype)
        q_start = None if hybrid.truncation is None else jnp.zeros(hybrid.truncation.lam_parts.shape, dtype)
    if truncation_start is not None:
        q_start = jnp.asarray(truncation_start, dtype)
    if y.shape != (hybrid.size,):
        raise ValueError(f"simulate_hybrid: flat state of size {hybrid.size} expected, got {y.shape}")
    return y, residual, q_start


def _hybrid_save_times(saveat, t0, t1, dtype, exact: bool):
    """``(ts, n_saved)``: simulate_hybrid's save times, checked; unless `exact` (traced inputs)
    padded to their size bucket, with `n_saved` the number asked for (else None)."""
    if isinstance(saveat, (int, np.integer)) and not isinstance(saveat, bool):
        if exact:
            ts = jnp.linspace(jnp.asarray(t0, dtype), jnp.asarray(t1, dtype), int(saveat))
        else:
            ts = grid_times(t0, t1, int(saveat), dtype)
    else:
        ts = jnp.asarray(saveat, dtype) if exact else np.asarray(saveat, dtype)
    check_times("simulate_hybrid", t0, t1, ts)
    n_saved = None if exact or ts.shape[0] == 0 else ts.shape[0]
    return (ts if n_saved is None else padded_times(ts)), n_saved
