"""What a run of Eq. (1) returns: :class:`Solution`, its histories completed with the prescribed
hinges (Sec. II B), energy and angular momentum, hold torques and the solver's statistics.
"""

from __future__ import annotations

from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.attitude import Quaternion, orthogonality_error
from ..equations.dynamics import (
    energy_and_momentum,
    solve_accelerations,
    unknown_labels,
)
from ..numerics import is_traced, program_jit
from ..vehicle.model import Model, State
from .failures import condition_at, condition_jit, failure_kind, raise_failures, report_failures
from .problem import Problem


class Solution(eqx.Module):
    """Time histories of a simulation (rows: saved times) and its diagnostics.

    - `ts` (T,); `gamma`, `gamma_dot` (T, n) for every hinge, prescribed ones included
      (``gamma[:, k-1] = gamma_k``); `omega0` (T, 3) in {b^0}; `dcm` (T, 3, 3) C of Def. 9,
      whatever the attitude variables; `attitude` (T, size) the integrated attitude variables;
      `control_state` the controller's states (leading axis T) or None; `X`, `X_dot` (T, 3)
      inertial position and velocity of the system mass center (Eq. 2) or None.
    - `hold_torque` (T, len(model.prescribed)): torque holding each prescribed hinge
      (Sec. II B), in the order of ``model.prescribed``.
    - `energy` (T,): kinetic energy relative to the mass center plus hinge-spring energy;
      `angular_momentum` (T, 3) about the mass center, inertial components;
      `orthogonality` (T,) ``max |C C^T - U|`` (the drift of Eq. 3 for ``attitude="dcm"``).
    - `t_final`, `final` (:class:`~jaxtree.State`), `final_control_state`, `final_X`,
      `final_X_dot`: where the run ended (t1, an event time or the time of a failure).
    - `result` (:class:`diffrax.RESULTS`), `event_mask` (the user's event; None without one),
      `singular` (True if the attitude angles reached their singularity), `margin` (distance
      of the attitude angles to their singularity at `t_final`; NaN if none), `failure` (0 when
      the run reached t1 or a user event; else a code for :class:`SimulationError`).
    - `stats`: ``num_steps``, ``num_accepted_steps``, ``num_rejected_steps``, ``max_steps`` and
      ``rhs_evaluations`` (steps times the solver's stages, plus the start-up evaluations;
      -1 for solvers that are not explicit Runge-Kutta), and ``solver``: the
      :class:`~jaxtree.SolverChoice` (which solver ran, whether ``"auto"`` picked it, and why).
    - `raw`: the :class:`diffrax.Solution` (its dense output, if requested, evaluates flat
      states; :meth:`evaluate` turns them into :class:`~jaxtree.State`); `problem`: the ODE.
    """

    ts: jax.Array
    gamma: jax.Array
    gamma_dot: jax.Array
    omega0: jax.Array
    dcm: jax.Array
    attitude: jax.Array
    control_state: Any
    X: jax.Array | None
    X_dot: jax.Array | None
    hold_torque: jax.Array
    energy: jax.Array
    angular_momentum: jax.Array
    orthogonality: jax.Array
    t_final: jax.Array
    final: State
    final_control_state: Any
    final_X: jax.Array | None
    final_X_dot: jax.Array | None
    result: Any
    event_mask: Any
    singular: jax.Array
    margin: jax.Array
    failure: jax.Array
    stats: dict
    raw: dfx.Solution | None  # None in a Solution read back from a file (jaxtree.results)
    problem: Problem

    @property
    def ok(self) -> bool:
        """True when the run reached t1 or stopped at a user event (concrete values only)."""
        return failure_kind(self.failure) is None

    def evaluate(self, t) -> State:
        """State at time t from the dense output (needs ``saveat=diffrax.SaveAt(..., dense=True)``)."""
        if self.raw is None:
            raise ValueError("evaluate: this Solution has no dense output (it was read back from a file)")
        if self.raw.interpolation is None:
            raise ValueError("evaluate: run simulate with saveat=diffrax.SaveAt(..., dense=True)")
        return self.problem.state(t, self.raw.evaluate(t))

    def energy_drift(self):
        """``max |E(t) - E(t0)| / |E(t0)|`` over the saved times (:func:`relative_drift`)."""
        return relative_drift(self.energy)

    def momentum_drift(self):
        """``max |H(t) - H(t0)| / |H(t0)|`` over the saved times, H about the mass center
        (:func:`relative_drift`)."""
        return relative_drift(self.angular_momentum)

    def check(self) -> Solution:
        """Raise :class:`SimulationError` (time, state, diagnosis) if the run failed; else return self."""
        check_solution(self)
        return self


def relative_drift(history):
    """``max_t |x(t) - x(t0)| / |x(t0)|`` of a history (saved times on axis 0; vectors on axis 1
    measured by their Euclidean norm), NaN rows (a padded or failed run's) left out; the absolute
    drift when x(t0) = 0 (a vehicle at rest): finite, with finite derivatives.

    Of a concrete history it is computed by numpy, a number with no program compiled (a notebook's
    summary of a run; eager ``jax.numpy`` compiles one program per operation and shape); under a
    trace by ``jax.numpy``."""
    xp, x = (jnp, history) if is_traced(history) else (np, np.asarray(history))
    size = (lambda v: xp.abs(v)) if x.ndim == 1 else (lambda v: _safe_norm(v, xp))
    return xp.nanmax(size(x - x[0])) / _nonzero(size(x[0]), xp)


def _safe_norm(x, xp):
    """Euclidean norm over the last axis whose derivative at zero is zero, not NaN (the norm of a
    zero vector, e.g. the angular momentum of a vehicle at rest, has an undefined gradient)."""
    sq = xp.sum(x * x, axis=-1)
    pos = sq > 0
    return xp.where(pos, xp.sqrt(xp.where(pos, sq, 1.0)), 0.0)


def _nonzero(x, xp):
    """`x`, or 1 where it is zero (a relative measure falls back to an absolute one)."""
    return xp.where(x > 0, x, xp.ones_like(x))


def histories_of(problem: Problem, ts, ys):
    """The saved flat states decoded: all hinges, C, attitude variables, controller states, X."""

    def row(t, y) -> dict[str, Any]:
        state = problem.state(t, y)
        att, _, _, _, _, X, Xd = problem.unpack(y)
        return dict(
            gamma=state.gamma,
            gamma_dot=state.gamma_dot,
            omega0=state.omega0,
            dcm=state.dcm,
            attitude=att,
            control_state=problem.control_state(y),
            X=X,
            X_dot=Xd,
            orthogonality=orthogonality_error(state.dcm),
        )

    return jax.vmap(row)(ts, ys)


# The diagnostics of `rows` saved states of a tree of `n` hinges compile at XLA's level 0
# (program_jit's `light`) while rows * (n + 1) is at most this: their loop then runs ~5x slower,
# ~2 us more per body and row (at most ~40 ms a call), for ~0.3 s less compilation on fig4_free
# and wings (benchmarks/FINDINGS.md, "Short programs at XLA's level 0").
LIGHT_BODY_ROWS = 16384


def _light_diagnostics(model, law, controller, params, ts, *_, **__) -> bool:
    return ts.shape[0] * (model.n + 1) <= LIGHT_BODY_ROWS


@program_jit(light=_light_diagnostics)
def run_diagnostics(model: Model, law, controller, params, ts, states: State, zs, count=None):
    """Energy, angular momentum and hold torques of the saved states; with `count` (an integer
    array) of the first `count` rows alone, the others NaN: one program for every number of rows
    up to the arrays' length, at the cost of those rows (a save grid padded to its bucket,
    :func:`.core.save_bucket`).

    Compiled apart from the solve, and keyed on the model alone when it has no prescribed hinges
    (the hold torques need the hinge law only then): runs that differ in attitude variables,
    solver, tolerances, events or control laws share it.

    On a CPU one saved time after the other (``lax.map``: a loop around the equations of one
    state), not ``vmap`` over all of them: XLA:CPU compiled fig4's vmapped diagnostics over 3384
    saved times in 11.5 s (2.6 s to lower), the loop in 2.1 s (0.9 s), for a run of 0.11 s
    instead of 0.02 s (benchmarks/FINDINGS.md, "The diagnostics program was the largest
    compilation"). Elsewhere ``vmap``: on an accelerator each pass of a loop launches its kernels
    again, 3384 times.
    """
    problem = Problem(model, Quaternion(), law, controller, params, False, 0)
    held = model.prescription is not None

    def row(args):
        t, state, z = args
        kinetic, H = energy_and_momentum(model, state)
        energy = kinetic + 0.5 * jnp.sum(model.stiffness * state.gamma**2)
        if not held:
            return energy, H
        tau = problem.torque(t, state, z)
        tau = None if tau is None else jnp.asarray(tau, state.gamma.dtype)
        return energy, H, solve_accelerations(model, state, t, tau).hold_torque

    rows = (ts, states, zs)
    if count is not None:
        out = _first_rows(row, rows, count, ts.shape[0])
    else:
        out = jax.lax.map(row, rows) if jax.default_backend() == "cpu" else jax.vmap(row)(rows)
    energy, H, *hold = out
    if held:
        return energy, H, hold[0]
    # no hinge held: no column (and none through lax.map, whose batched form fails to reshape a
    # zero-sized axis)
    return energy, H, jnp.zeros((ts.shape[0], 0), states.gamma.dtype)


def _first_rows(row, rows, count, size):
    """``row`` over the first `count` of `size` rows, one after the other (a loop whose trip count
    is a value, not a shape), the other rows NaN."""
    shapes = jax.eval_shape(row, jax.tree.map(lambda x: x[0], rows))
    out = jax.tree.map(lambda s: jnp.full((size, *s.shape), jnp.nan, s.dtype), shapes)

    def body(i, out):
        values = row(jax.tree.map(lambda x: x[i], rows))
        return jax.tree.map(lambda o, v: o.at[i].set(v), out, values)

    return jax.lax.fori_loop(0, count, body, out)


def rhs_evaluations(solver, stats, dt0_given: bool):
    tableau = getattr(solver, "tableau", None)
    if tableau is None or not isinstance(solver, dfx.AbstractERK):
        return jnp.asarray(-1)
    stages = len(tableau.c) + 1
    per_step = stages - 1 if tableau.fsal else stages
    start = (1 if tableau.fsal else 0) + (0 if dt0_given else 2)
    return stats["num_steps"] * per_step + start


def report_from_callback(failure, t_final, final: State, margin, problem: Problem) -> None:
    """Under a caller's jit/vmap the values are not known until run time: report the failures of
    a run (its ``Solution`` fields of these names) from a host callback, which raises with the
    time and state of every failed member."""
    attitude_name, labels = problem.attitude.name, unknown_labels(problem.model)

    def host(code, t, state, margin, model, condition, direction):
        raise_failures(code, t, state, condition, margin, attitude_name, direction, labels)

    def diagnose(code, t, state, margin, model):  # only when a run failed: an eigendecomposition
        return condition_at(model, state, t)

    report_failures(
        host,
        failure != 0,
        jax.lax.stop_gradient((failure, t_final, final, margin, problem.model)),
        diagnose,
    )


def check_solution(sol: Solution) -> None:
    """Raise :class:`SimulationError` with the time, the state and a diagnosis if `sol` failed.

    For solutions computed under ``jax.vmap`` the first failed members are reported.
    """
    code = np.asarray(sol.failure)
    if not np.any(code):
        return
    # The condition number is a diagnosis, computed only for a failed run (for a batch of
    # solutions the model may be batched too, and it is left out).
    if code.ndim == 0:
        condition, direction = condition_jit(sol.problem.model, sol.final, sol.t_final)
    else:
        condition, direction = np.full(code.shape, np.nan), None
    raise_failures(
        code,
        sol.t_final,
        sol.final,
        condition,
        sol.margin,
        sol.problem.attitude.name,
        direction=direction,
        labels=unknown_labels(sol.problem.model),
    )
