"""Time histories of the full equations: Eq. (1) with attitude (Eq. 3 or 23-24), prescribed
hinges (Sec. II B), hinge laws and controllers, external loads and, optionally, Eq. (2).

:func:`simulate` integrates the first-order form of Eqs. (25)-(27): the state holds the
attitude variables of b_0, omega0, the angles and rates of the hinges that are not
prescribed (prescribed hinges are excluded, as in Eq. 25), the internal states of a
controller and, when asked for, the position and velocity of the system mass center
(Eq. 2). Internally the ODE state is one flat vector in that order (the layout of
:class:`Problem`): a single leaf keeps diffrax's per-stage linear algebra to a few fused
operations (on this project's 2-core CPU a four-leaf pytree state ran 1.4-2x slower).
:meth:`Problem.state` turns it back into a :class:`~jaxtree.State` for event functions and
control laws.

Each right-hand side solves Eq. (1) once (:func:`jaxtree.solve_accelerations`, Cholesky).
diffrax does the integration: solvers, step-size controllers, adjoints, events and
progress meters are diffrax objects, passed to :func:`diffrax.diffeqsolve` unchanged.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any, NamedTuple, cast

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

from ..equations.attitude import AbstractAttitude, Quaternion, get_attitude, orthogonality_error
from ..equations.control import AbstractController, with_model_laws
from ..equations.dynamics import (
    SINGULAR_CONDITION,
    energy_and_momentum,
    mass_center_acceleration,
    matrix_condition,
    null_direction_text,
    rotational_equations,
    solve_accelerations,
    solve_unchecked,
    unknown_labels,
    unknown_rows,
)
from ..equations.kinematics import full_precision
from ..errors import SceneError, SceneTypeError, SceneWarning, short
from ..numerics import regular
from ..values import as_float
from ..vehicle import hinges
from ..vehicle.model import Model, State
from ..vehicle.validate import check_model
from .autosolver import choose_checked, given
from .core import (
    DEFAULT_MAX_STEPS,
    DEFAULT_SAVE_POINTS,
    MESSAGES,
    Failure,
    SimulationError,
    check_state,
    check_times,
    default_controller,
    failure_kind,
    failure_report,
    integrate,
    is_traced,
    progress_meter,
    report_failures,
    result_code,
    solver_statistics,
    tolerances,
)
from .core import default_tolerance as default_tolerance  # jaxtree.default_tolerance, named in the docs
from .radau import Radau5, jacobian_by_parts


def _check_arguments(model, t0, t1, dt0, translation, solver, stepsize_controller, adjoint, throw):
    """The other arguments of :func:`simulate`, before tracing: the model a valid
    :class:`~jaxtree.Model` (:func:`jaxtree.validate_model` when concrete), `dt0` finite and
    pointing from `t0` toward `t1`, `translation` a bool or ``(X0 (3,), X_dot0 (3,))``, and
    diffrax objects where diffrax objects go."""
    check_model("simulate", model)
    if getattr(model, "appendages", ()):
        warnings.warn(
            f"simulate: the scene's finite-element appendages ({', '.join(a.name for a in model.appendages)}) are "
            "not part of the full Eq. (1) and are left out; integrate them in hybrid coordinates: "
            "jaxtree.hybrid_model(model, small, appendages=jaxtree.scene_appendages(model))",
            SceneWarning,
            stacklevel=4,
        )
    if dt0 is not None and not is_traced((dt0, t0, t1)):
        h = float(as_float(dt0, "simulate: dt0", ()))
        direction = float(np.asarray(t1, float)) - float(np.asarray(t0, float))
        if h * direction < 0:
            raise SceneError(
                f"simulate: dt0 = {h:g} points away from t1 (t0 = {float(np.asarray(t0)):g}, "
                f"t1 = {float(np.asarray(t1)):g})"
            )
    if isinstance(translation, tuple):
        if len(translation) != 2:
            raise SceneError(
                f"simulate: translation must be True, False or (X0, X_dot0), got a tuple of {len(translation)}"
            )
        for label, x in zip(("X0", "X_dot0"), translation):
            if not is_traced(x):
                as_float(x, f"simulate: translation {label}", (3,))
            elif jnp.shape(x) != (3,):
                raise SceneError(f"simulate: translation {label} must have shape (3,), got {jnp.shape(x)}")
    elif not isinstance(translation, (bool, np.bool_)):
        raise SceneTypeError(f"simulate: translation must be True, False or (X0, X_dot0), got {short(translation)}")
    if isinstance(solver, str) and solver != "auto":
        raise SceneError(f"simulate: solver must be 'auto' or a diffrax solver, got {solver!r}")
    for label, value, kind in (
        ("solver", None if isinstance(solver, str) else solver, dfx.AbstractSolver),
        ("stepsize_controller", stepsize_controller, dfx.AbstractStepSizeController),
        ("adjoint", adjoint, dfx.AbstractAdjoint),
    ):
        if value is not None and not isinstance(value, kind):
            raise SceneTypeError(f"simulate: {label} must be a diffrax.{kind.__name__}, got {short(value)}")
    if not isinstance(throw, (bool, np.bool_)):
        raise SceneTypeError(f"simulate: throw must be True or False, got {short(throw)}")


# ----------------------------------------------------------------------------- the ODE
class Problem(eqx.Module):
    """The ODE of a simulation, passed to diffrax as ``args`` (so event functions see it).

    Fields: the `model`, the `attitude` parametrisation, the hinge `law` ``tau(t, state,
    params)`` or `controller`, the user's `params`, and static layout sizes of the flat state
    ``[attitude, omega0 (3), gamma_u, gamma_dot_u, controller states, X (3), X_dot (3)]``
    (``gamma_u``: the hinges that are not prescribed, :attr:`free_hinges`).
    """

    model: Model
    attitude: AbstractAttitude
    law: Any
    controller: AbstractController | None
    params: Any
    translation: bool = eqx.field(static=True)
    control_size: int = eqx.field(static=True)

    @property
    def free_hinges(self) -> tuple[int, ...]:
        """Hinges (1..n) in the state: all but the prescribed ones. They are the unknowns of
        Eq. (1) plus any inert hinges (only massless bodies outboard), whose acceleration is zero."""
        return hinges.free_hinges(self.model)

    @property
    def n_unknown(self) -> int:
        return len(self.free_hinges)

    @property
    def size(self) -> int:
        return self.attitude.size + 3 + 2 * self.n_unknown + self.control_size + (6 if self.translation else 0)

    def _offsets(self):
        a, nu = self.attitude.size, self.n_unknown
        o = [0, a, a + 3, a + 3 + nu, a + 3 + 2 * nu, a + 3 + 2 * nu + self.control_size]
        return o

    def unpack(self, y):
        """``(attitude, omega0, gamma_u, gamma_dot_u, z_flat, X, X_dot)`` slices of a flat state."""
        o = self._offsets()
        parts = [y[o[i] : o[i + 1]] for i in range(5)]
        if self.translation:
            parts += [y[o[5] : o[5] + 3], y[o[5] + 3 : o[5] + 6]]
        else:
            parts += [None, None]
        return parts

    def _unravel_control(self, z_flat):
        if self.controller is None:
            return None
        _, unravel = ravel_pytree(self.controller.initial())
        return unravel(z_flat)

    def control_state(self, y):
        """The controller's internal states (a pytree) in a flat state, or None."""
        return self._unravel_control(self.unpack(y)[4])

    def _complete(self, t, y):
        """The :class:`~jaxtree.State` (all n hinges, C from the attitude variables) of a flat
        state and the prescribed accelerations (one evaluation of the prescription)."""
        att, w, g, gd, _, _, _ = self.unpack(y)
        gamma, gamma_dot, gdd_p = hinges.from_free(self.model, t, g, gd)
        return State(self.attitude.to_dcm(att), w, gamma, gamma_dot), gdd_p

    def state(self, t, y) -> State:
        """The :class:`~jaxtree.State` (all n hinges, C from the attitude variables) of a flat state."""
        return self._complete(t, y)[0]

    def torque(self, t, state, z):
        """User hinge torques (n,) (None when there is no law or controller)."""
        if self.controller is not None:
            tau = self.controller.torque(t, state, z, self.params)
            if self.law is not None:
                tau = tau + self.law(t, state, self.params)
            return tau
        if self.law is not None:
            return self.law(t, state, self.params)
        return None

    def accelerations(self, t, y):
        """``(state, z, tau, Accelerations)`` at (t, y)."""
        att, w, g_u, gd_u, z_flat, _, _ = self.unpack(y)
        return self._accelerations(t, att, w, g_u, gd_u, z_flat)

    def _accelerations(self, t, att, w, g_u, gd_u, z_flat):
        """:meth:`accelerations` from the parts of a flat state (:meth:`unpack`)."""
        gamma, gamma_dot, gdd_p = hinges.from_free(self.model, t, g_u, gd_u)
        state = State(self.attitude.to_dcm(att), w, gamma, gamma_dot)
        z = self._unravel_control(z_flat)
        tau = self.torque(t, state, z)
        if tau is not None:
            tau = jnp.asarray(tau, gamma.dtype)
        return state, z, tau, solve_unchecked(self.model, state, t, tau, completed=gdd_p)

    def vector_field(self, t, y, args=None):
        """Right side of the first-order equations (Eqs. 25-27; Eq. 2 when enabled)."""
        return self._field(t, *self.unpack(y))

    def _field(self, t, att, w, g_u, gd_u, z_flat, X, Xd):
        """:meth:`vector_field` of the parts of a flat state (:meth:`unpack`)."""
        dtype = w.dtype
        state, z, _, acc = self._accelerations(t, att, w, g_u, gd_u, z_flat)
        u = np.asarray(self.free_hinges, dtype=np.int64) - 1
        parts = [self.attitude.rate(att, w), acc.omega0_dot, gd_u, acc.gamma_ddot[u]]
        if self.controller is not None:
            dz, _ = ravel_pytree(self.controller.rate(t, state, z, self.params))
            parts.append(dz.astype(dtype))
        if self.translation:
            acc_X = mass_center_acceleration(self.model, state, t).astype(dtype)
            if self.model.orbit is not None:  # Eq. (2) with the central body: -mu X / |X|^3 per unit mass
                mu = jnp.asarray(self.model.orbit.mu, dtype)
                acc_X = acc_X - mu * X / jnp.sum(X * X) ** 1.5
            parts += [Xd, acc_X]
        dy = jnp.concatenate(parts)
        # A singular Eq. (1) matrix gives NaN accelerations. diffrax's step-size control turns a
        # NaN error estimate into a NaN step; a huge finite rate instead makes it reject and shrink
        # the step until it reports dt_min_reached (or max_steps), with time and state.
        big = jnp.asarray(np.sqrt(np.finfo(np.dtype(dtype)).max), dtype)
        return jnp.where(jnp.isfinite(dy), dy, big)

    def jacobian(self, t, y):
        """``d vector_field / d y`` (size x size) in two forward-mode passes: the configuration
        (attitude, hinge angles, mass-center position), then the rates (omega0, hinge rates,
        controller states, mass-center velocity). In the second pass the configuration carries no
        tangent, so the implicit-function rule of Eq. (1) differentiates only the velocity terms
        (the geometry is computed once, not once per tangent); one pass over all columns would
        push every rate's tangent through the geometry as well. For :class:`jaxtree.Radau5`."""
        return jacobian_by_parts(lambda *p: self._field(t, *p), self.unpack(y), ((0, 2, 5), (1, 3, 4, 6)))

    def pack(self, state: State, z=None, X=None, X_dot=None):
        """Flat state from a :class:`~jaxtree.State` (prescribed entries dropped), controller
        states and mass-center position/velocity."""
        dtype = jnp.result_type(self.model.mass)
        u = np.asarray(self.free_hinges, dtype=np.int64) - 1
        parts = [
            self.attitude.from_dcm(jnp.asarray(state.dcm, dtype)),
            jnp.asarray(state.omega0, dtype),
            jnp.asarray(state.gamma, dtype)[u],
            jnp.asarray(state.gamma_dot, dtype)[u],
        ]
        if self.controller is not None:
            zf, _ = ravel_pytree(self.controller.initial() if z is None else z)
            parts.append(zf.astype(dtype))
        if self.translation:
            parts.append(jnp.zeros(3, dtype) if X is None else jnp.asarray(X, dtype))
            parts.append(jnp.zeros(3, dtype) if X_dot is None else jnp.asarray(X_dot, dtype))
        return jnp.concatenate([jnp.reshape(p, (-1,)) for p in parts])


@eqx.filter_jit
def _problem_jacobian(t, y, args: Problem):
    """The Jacobian that :func:`simulate` gives :class:`jaxtree.Radau5` (:meth:`Problem.jacobian`);
    jitted, as :func:`_vector_field`, so that the solver's several traces reuse one jaxpr."""
    return args.jacobian(t, y)


def _with_jacobian(solver):
    """`solver`, and for a :class:`jaxtree.Radau5` without a Jacobian of its own the problem's
    structured one (:meth:`Problem.jacobian`)."""
    if isinstance(solver, Radau5) and solver.jacobian is None:
        return eqx.tree_at(lambda s: s.jacobian, solver, _problem_jacobian, is_leaf=lambda x: x is None)
    return solver


@eqx.filter_jit
def _vector_field(t, y, args: Problem):
    # jitted so that diffrax's several traces of the vector field reuse one jaxpr; traced inside
    # `simulate`, so at its full matrix-product precision
    return args.vector_field(t, y)


# ----------------------------------------------------------------------------- events
class _HingeAngle(eqx.Module):
    angle: jax.Array
    hinge: int = eqx.field(static=True)

    def __call__(self, t, y, args: Problem, **kwargs):
        return args.state(t, y).gamma[self.hinge - 1] - self.angle.astype(y.dtype)


class _StateCondition(eqx.Module):
    fn: Callable = eqx.field(static=True)

    def __call__(self, t, y, args: Problem, **kwargs):
        return self.fn(t, args.state(t, y))


def _root_finder(tol):
    return optx.Newton(rtol=tol, atol=tol)


def hinge_angle_event(hinge: int, angle, direction: bool | None = None, tol: float = 1e-10) -> dfx.Event:
    """A :class:`diffrax.Event` that stops the run when hinge `hinge` (1-based) reaches `angle`.

    The crossing time is found by Newton root finding on the dense output (tolerance `tol`;
    use about 1e-5 for float32 models). `direction`: None either way, True on an increasing
    crossing, False on a decreasing one.
    """
    return dfx.Event(_HingeAngle(jnp.asarray(angle, float), int(hinge)), _root_finder(tol), direction)


def state_event(fn: Callable, direction: bool | None = None, tol: float = 1e-10) -> dfx.Event:
    """A :class:`diffrax.Event` from ``fn(t, state) -> scalar``: stops where it changes sign
    (root finding) or, for a boolean, on the first step where it is True. `fn` is static."""
    return dfx.Event(_StateCondition(fn), _root_finder(tol), direction)


class _Singularity(eqx.Module):
    """Boolean: the attitude variables are within tolerance of their singularity."""

    def __call__(self, t, y, args: Problem, **kwargs):
        margin = args.attitude.margin(args.unpack(y)[0])
        assert margin is not None  # the guard is installed only when attitude.has_singularity
        return margin < 0


class _Crossing(eqx.Module):
    """Real: changes sign if a step jumps across the singular set without landing near it."""

    def __call__(self, t, y, args: Problem, **kwargs):
        return args.attitude.side(args.unpack(y)[0])


def _guard_any(mask):
    near, crossed = mask
    return jnp.asarray(near) | jnp.asarray(crossed)


def _combine_events(event, attitude: AbstractAttitude) -> tuple[Any, bool, bool]:
    """``(event, has_guard, has_user_event)``: the user's event unchanged, or the user's
    conditions and the attitude guard side by side in one diffrax Event."""
    guard = attitude.has_singularity
    if event is not None and not isinstance(event, dfx.Event):
        if callable(event):
            event = state_event(event)
        else:
            raise SceneTypeError(
                f"simulate: event must be a diffrax.Event or a function (t, state) -> scalar, got {short(event)}"
            )
    if not guard:
        return event, False, event is not None
    guards = (_Singularity(), _Crossing())
    if event is None:
        return dfx.Event(guards), True, False
    return dfx.Event((event.cond_fn, guards), event.root_finder, (event.direction, (None, None))), True, True


# ----------------------------------------------------------------------------- solution
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
        """``max |E(t) - E(t0)| / |E(t0)|`` over the saved times (the absolute drift when E(t0) = 0,
        e.g. a vehicle at rest: finite, with finite derivatives)."""
        e = self.energy
        return jnp.nanmax(jnp.abs(e - e[0])) / _nonzero(jnp.abs(e[0]))

    def momentum_drift(self):
        """``max |H(t) - H(t0)| / |H(t0)|`` over the saved times (H about the mass center; the
        absolute drift when H(t0) = 0: finite, with finite derivatives)."""
        H = self.angular_momentum
        return jnp.nanmax(_safe_norm(H - H[0])) / _nonzero(_safe_norm(H[0]))

    def check(self) -> Solution:
        """Raise :class:`SimulationError` (time, state, diagnosis) if the run failed; else return self."""
        check_solution(self)
        return self


def _safe_norm(x):
    """Euclidean norm over the last axis whose derivative at zero is zero, not NaN (the norm of a
    zero vector, e.g. the angular momentum of a vehicle at rest, has an undefined gradient)."""
    sq = jnp.sum(x * x, axis=-1)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1.0)), 0.0)


def _nonzero(x):
    """`x`, or 1 where it is zero (a relative measure falls back to an absolute one)."""
    return jnp.where(x > 0, x, jnp.ones_like(x))


def _history(problem: Problem, ts, ys):
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


@eqx.filter_jit
def _diagnostics(model: Model, law, controller, params, ts, states: State, zs):
    """Energy, angular momentum and hold torques of the saved states.

    Compiled apart from the solve, and keyed on the model alone when it has no prescribed hinges
    (the hold torques need the hinge law only then): runs that differ in attitude variables,
    solver, tolerances, events or control laws share it.
    """
    problem = Problem(model, Quaternion(), law, controller, params, False, 0)

    def row(t, state, z):
        kinetic, H = energy_and_momentum(model, state)
        energy = kinetic + 0.5 * jnp.sum(model.stiffness * state.gamma**2)
        if model.prescription is None:
            hold = jnp.zeros((0,), state.gamma.dtype)
        else:
            tau = problem.torque(t, state, z)
            tau = None if tau is None else jnp.asarray(tau, state.gamma.dtype)
            hold = solve_accelerations(model, state, t, tau).hold_torque
        return energy, H, hold

    return jax.vmap(row)(ts, states, zs)


def _condition(model: Model, state: State, t):
    """Condition number and near-null direction of the Eq. (1) matrix at a state
    (:func:`jaxtree._src.equations.dynamics.matrix_condition`)."""
    return matrix_condition(model, rotational_equations(model, state, t)[0])


condition_jit = eqx.filter_jit(_condition)


def _rhs_evaluations(solver, stats, dt0_given: bool):
    tableau = getattr(solver, "tableau", None)
    if tableau is None or not isinstance(solver, dfx.AbstractERK):
        return jnp.asarray(-1)
    stages = len(tableau.c) + 1
    per_step = stages - 1 if tableau.fsal else stages
    start = (1 if tableau.fsal else 0) + (0 if dt0_given else 2)
    return stats["num_steps"] * per_step + start


def _singular(problem: Problem, t, y):
    """True when the Eq. (1) matrix at (t, y) is singular to working precision (a pivot at
    round-off level, :func:`~jaxtree._src.numerics.regular`): one factorization, no eigenvalues. An exactly singular matrix may leave the
    factorization a pivot at round-off level instead of failing it, and the solve then returns
    finite garbage; this catches both."""
    model = problem.model
    state = problem.state(t, y)
    A = rotational_equations(model, state, t)[0]
    u = unknown_rows(model)
    A = A[np.ix_(u, u)]
    return ~regular(jax.lax.linalg.cholesky(A, symmetrize_input=False), A)  # a failed factorization (NaN) too


def _initial_step(problem: Problem, y0, t0, t1):
    """A first step of about 0.01 rad of the fastest rotation (no vector-field evaluation, so
    nothing more to compile); the step-size controller corrects it within a few steps."""
    _, w, _, gd, _, _, _ = problem.unpack(y0)
    rate = jnp.max(jnp.abs(jnp.concatenate([w, gd, jnp.zeros((1,), y0.dtype)])))
    rate = jnp.where(jnp.isfinite(rate), rate, 0.0)  # a non-finite state fails on the first steps
    h = jnp.minimum(1e-2 / (1.0 + rate), jnp.abs(t1 - t0))
    return jnp.where(t1 >= t0, h, -h)


# The fields of a Solution that simulate fills in from _diagnostics, compiled apart from the
# solve: None until then (typed as the arrays they become; no Solution is returned with them None).
_FILLED_BY_SIMULATE = cast(jax.Array, None)


class _Options(NamedTuple):
    """Static choices of one simulation (hashable: part of the compilation key)."""

    has_guard: bool
    user_event: bool
    max_steps: int
    grid: int | None  # number of evenly spaced save times, or None
    user_saveat: bool
    report_in_callback: bool


class _Run(NamedTuple):
    """The inputs of one simulation that JAX may trace: the mass center's start (or None), the
    times, tolerances and first step (arrays or None), and the diffrax objects."""

    X0: Any
    Xd0: Any
    t0: Any
    t1: Any
    rtol: Any
    atol: Any
    dt0: Any
    solver: Any
    controller: Any
    saveat: Any
    adjoint: Any
    event: Any
    progress_meter: Any


@eqx.filter_jit
def _solve(problem: Problem, y0: State, run: _Run, opts: _Options):
    dtype = jnp.result_type(problem.model.mass)
    y = problem.pack(y0, None, run.X0, run.Xd0)
    start_ok, singular_start, rest = _start(problem, y, run.t0)
    controller, dt0 = run.controller, run.dt0
    if controller is None:
        controller = default_controller(run.rtol, run.atol, run.t0, run.t1)
        if dt0 is None:
            # a choice of the discretization, not a function to differentiate (BacksolveAdjoint
            # refuses a first step that carries a tangent)
            dt0 = jax.lax.stop_gradient(_initial_step(problem, jnp.where(start_ok, y, rest), run.t0, run.t1))
    ts = None
    if not opts.user_saveat:
        ts = jnp.linspace(run.t0, run.t1, opts.grid, dtype=dtype) if opts.grid is not None else run.saveat
    solver = _with_jacobian(run.solver)
    ends = integrate(
        _vector_field,
        solver,
        run.t0,
        run.t1,
        dt0,
        y,
        problem,
        ts=ts,
        saveat=run.saveat if opts.user_saveat else None,
        controller=controller,
        adjoint=run.adjoint,
        event=run.event,
        max_steps=opts.max_steps,
        progress_meter=run.progress_meter,
        start_ok=start_ok,
        rest=rest,
    )
    out = _solution(problem, opts, solver, dt0 is not None, (start_ok, singular_start), ends)
    if opts.report_in_callback:
        _report_in_callback(out)
    return out


def _start(problem: Problem, y, t0):
    """``(start_ok, singular_start, rest)`` of a flat start `y`.

    A non-finite start cannot be integrated: NaN error estimates give NaN steps until max_steps
    (a vmapped batch would wait for its worst member). Nor can a start where Eq. (1) is singular
    to working precision (exact gimbal lock): the accelerations are undetermined, and the
    factorization may even return finite garbage. Such a run integrates the vehicle at rest
    (`rest`) in their place, reports "nonfinite_start" / "singular_start" and returns NaN histories."""
    dtype = jnp.result_type(problem.model.mass)
    finite_start = jnp.all(jnp.isfinite(y))
    singular_start = finite_start & _singular(problem, t0, jax.lax.stop_gradient(y))
    n, z3 = problem.model.n, jnp.zeros(3, dtype)
    rest = problem.pack(State(jnp.eye(3, dtype=dtype), z3, jnp.zeros(n, dtype), jnp.zeros(n, dtype)))
    return finite_start & ~singular_start, singular_start, rest


def _solution(problem: Problem, opts: _Options, solver, dt0_given: bool, start, ends) -> Solution:
    """The :class:`Solution` of an integration: `start` ``(start_ok, singular_start)`` of
    :func:`_start`, `ends` ``(ts, ys, t_final, y_final, diffrax solution)`` of ``integrate``; the
    energy, momentum and hold torques are left to :func:`_with_diagnostics`."""
    start_ok, singular_start = start
    ts_h, ys_h, t_final, y_final, sol = ends
    hist = _history(problem, ts_h, ys_h)
    _, _, _, _, _, Xf, Xdf = problem.unpack(y_final)
    mask = sol.event_mask
    singular = jnp.asarray(False)
    if opts.has_guard:
        if opts.user_event:
            mask, guard_mask = mask
        else:
            mask, guard_mask = None, mask
        singular = _guard_any(guard_mask)
    stats = dict(sol.stats)
    stats["rhs_evaluations"] = _rhs_evaluations(solver, sol.stats, dt0_given)
    stats.update(solver_statistics(solver, sol))
    R = dfx.RESULTS
    ok = (sol.result == R.successful) | ((sol.result == R.event_occurred) & ~singular)
    failure = jnp.where(
        start_ok,
        jnp.where(ok, 0, result_code(sol.result, singular)),
        jnp.where(singular_start, int(Failure.SINGULAR_START), int(Failure.NONFINITE_START)),
    )
    return Solution(
        ts=ts_h,
        gamma=hist["gamma"],
        gamma_dot=hist["gamma_dot"],
        omega0=hist["omega0"],
        dcm=hist["dcm"],
        attitude=hist["attitude"],
        control_state=hist["control_state"],
        X=hist["X"],
        X_dot=hist["X_dot"],
        hold_torque=_FILLED_BY_SIMULATE,
        energy=_FILLED_BY_SIMULATE,
        angular_momentum=_FILLED_BY_SIMULATE,
        orthogonality=hist["orthogonality"],
        t_final=t_final,
        final=problem.state(t_final, y_final),
        final_control_state=problem.control_state(y_final),
        final_X=Xf,
        final_X_dot=Xdf,
        result=sol.result,
        event_mask=mask,
        singular=singular,
        margin=_margin(problem, y_final),
        failure=failure,
        stats=stats,
        raw=sol,
        problem=problem,
    )


def _report_in_callback(out: Solution) -> None:
    """Under a caller's jit/vmap the values are not known until run time: report failures from a
    host callback, which raises with the time and state of every failed member."""
    problem = out.problem
    attitude_name, labels = problem.attitude.name, unknown_labels(problem.model)

    def host(code, t, state, margin, model, condition, direction):
        _raise_from_callback(code, t, state, condition, margin, attitude_name, direction, labels)

    def diagnose(code, t, state, margin, model):  # only when a run failed: an eigendecomposition
        return _condition(model, state, t)

    report_failures(
        host,
        out.failure != 0,
        jax.lax.stop_gradient((out.failure, out.t_final, out.final, out.margin, problem.model)),
        diagnose,
    )


# ----------------------------------------------------------------------------- failures
def _margin(problem, y):
    m = problem.attitude.margin(problem.unpack(y)[0])
    return jnp.asarray(jnp.nan, y.dtype) if m is None else m


def _format_failure(
    kind, t, state: State, condition, margin, attitude_name, result_message="", direction=None, labels=None
):
    np.set_printoptions(precision=6, suppress=False, linewidth=120)
    lines = [f"jaxtree.simulate: {MESSAGES[kind]}."]
    if result_message:
        lines.append(f"  diffrax: {result_message}")
    lines.append(f"  stopped at t = {float(t):.9g}")
    lines.append(f"  omega0 = {np.asarray(state.omega0)}")
    lines.append(f"  gamma = {np.asarray(state.gamma)}")
    lines.append(f"  gamma_dot = {np.asarray(state.gamma_dot)}")
    lines.append(f"  C = {np.asarray(state.dcm).tolist()}")
    finite = all(np.all(np.isfinite(np.asarray(x))) for x in state)
    if not finite:
        lines.append("  diagnosis: the state is not finite")
    c = float(condition)
    if np.isnan(c):
        pass
    elif not np.isfinite(c) or c > SINGULAR_CONDITION:
        where = (
            null_direction_text(direction, labels)
            if direction is not None and labels is not None and np.all(np.isfinite(np.asarray(direction)))
            else "for a gimbal this is gimbal lock"
        )
        lines.append(f"  diagnosis: the Eq. (1) matrix is singular or nearly so (condition number {c:.3g}); {where}")
    if attitude_name == "euler123" and np.isfinite(float(margin)):
        lines.append(f"  attitude ({attitude_name}) singularity margin |cos theta_2| - tol = {float(margin):.3g}")
    return "\n".join(lines)


def _raise_from_callback(code, t, state, condition, margin, attitude_name, direction=None, labels=None):
    def describe(kind, pick):
        return _format_failure(
            kind,
            pick(t),
            State(*(pick(x) for x in state)),
            pick(condition),
            pick(margin),
            str(attitude_name),
            direction=None if direction is None else pick(direction),
            labels=labels,
        )

    message = failure_report(code, describe)
    if message is not None:
        raise SimulationError(message)


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
    _raise_from_callback(
        code,
        sol.t_final,
        sol.final,
        condition,
        sol.margin,
        sol.problem.attitude.name,
        direction=direction,
        labels=unknown_labels(sol.problem.model),
    )


# ----------------------------------------------------------------------------- simulate


@full_precision
def simulate(
    model: Model,
    t1,
    *,
    t0: float | jax.Array = 0.0,
    y0: State | None = None,
    saveat=None,
    solver: dfx.AbstractSolver | str | None = "auto",
    stepsize_controller: dfx.AbstractStepSizeController | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt0=None,
    max_steps: int = DEFAULT_MAX_STEPS,
    attitude: str | AbstractAttitude = "quaternion",
    adjoint: dfx.AbstractAdjoint | None = None,
    event: dfx.Event | Callable | None = None,
    progress: bool | dfx.AbstractProgressMeter = False,
    law: Callable | None = None,
    controller: AbstractController | None = None,
    params: Any = None,
    translation: bool | tuple = False,
    throw: bool = True,
) -> Solution:
    """Integrate the equations of motion of `model` from `t0` to `t1`.

    Implements the first-order form of Eqs. (25)-(27) of Likins (1972): Eq. (1) with the
    prescribed hinges of Sec. II B moved to the right side, the attitude kinematics of Eq. (3)
    or Eqs. (23)-(24), and Eq. (2) when `translation` is set.

    **Arguments:**

    - `model`: the vehicle (:func:`jaxtree.load_scene`, :func:`jaxtree.build_model`); its
      joint laws, prescription and external loads (``model.loads``) are used.
    - `t1`, `t0`: end and start times (``t1 < t0`` integrates backward).
    - `y0`: initial :class:`~jaxtree.State` (default ``model.initial``); entries of prescribed
      hinges are ignored (they follow the prescription). Field shapes and a proper rotation
      ``dcm`` are checked before tracing.
    - `saveat`: a :class:`diffrax.SaveAt` (used as is; the final state is its last saved row),
      a number of evenly spaced save times (default 101), or an array of times (from `t0`
      toward `t1`, within the run; checked before tracing, as are finite `t0` and `t1`). Values
      between steps come from the solver's dense output; Dopri8's (a degree-6 polynomial)
      is 2-3x less accurate than the steps at tight tolerances (fig4_free over 10 s at rtol =
      atol = 2e-10: 1.2e-9 at the save times, 3.9e-10 at the steps). For step accuracy at
      the save times let the steps land on them, ``stepsize_controller=
      diffrax.PIDController(rtol=..., atol=..., step_ts=ts)``, at 2-3 more steps per save time.
    - `solver`: a diffrax solver, used as is; or ``"auto"`` (the default; None too):
      :func:`jaxtree.choose_solver` picks Dopri8, or :class:`jaxtree.Radau5` when the linearized
      equations at `y0` are stiff (fast modes that decay early; a screen of the hinge laws skips
      the linearization when nothing is close to stiff), and Dopri8 whenever the inputs are
      traced. ``sol.stats["solver"]`` (a :class:`~jaxtree.SolverChoice`) says what ran and why;
      with Radau5, ``sol.stats`` also counts its ``jacobians``, ``factorizations`` and
      ``newton_iterations``. IMEX solvers (``diffrax.KenCarp4`` ...) get the whole right side as
      their implicit part.
    - `stepsize_controller`: a diffrax step-size controller (used as is); default a
      :class:`diffrax.PIDController` with `rtol`, `atol`, PI coefficients 0.3 / 0.3 and a
      minimum step of 1e-12 |t1 - t0| (and an initial step from the largest rate in `y0`).
    - `rtol`, `atol`: tolerances of the default controller; default
      :func:`default_tolerance` of the model's dtype (1e-9 in float64, 1e-4 in float32). A
      concrete `rtol` below 50 x the dtype's unit roundoff gives a warning.
    - `dt0`: initial step (default: chosen by the controller).
    - `max_steps`: step limit (the run fails with a :class:`SimulationError` beyond it).
    - `attitude`: ``"quaternion"``, ``"dcm"`` (Eq. 3), ``"euler123"`` (Eqs. 23-24) or an
      :class:`~jaxtree._src.equations.attitude.AbstractAttitude`.
    - `adjoint`: a diffrax adjoint (default :class:`diffrax.RecursiveCheckpointAdjoint`).
    - `event`: a :class:`diffrax.Event` (its functions get ``(t, y, args)`` with ``args`` the
      :class:`Problem`; ``args.state(t, y)`` is the :class:`~jaxtree.State`), or a function
      ``(t, state) -> scalar`` (see :func:`state_event`, :func:`hinge_angle_event`).
    - `progress`: show diffrax's progress meter (tqdm when installed, else text), or a diffrax
      progress meter.
    - `law`: hinge law ``tau(t, state, params) -> (n,)`` added to the joint laws (and to the
      model's own ``model.law``, from its scene's ``control``).
    - `controller`: an :class:`~jaxtree.control.AbstractController` whose internal states are
      appended to the ODE state (beside those of ``model.controller``: then ``control_state``
      is a pair, the model's first).
    - `params`: pytree passed to `law` and `controller` (traced; differentiable).
    - `translation`: integrate Eq. (2) for the mass center: True (start at rest at the origin,
      or on ``model.orbit`` at `t0` where the model has one) or ``(X0, X_dot0)`` in inertial
      components. With ``model.orbit`` Eq. (2) has the central body's attraction ``-mu M X /
      |X|^3`` beside the loads' net force.
    - `throw`: raise :class:`SimulationError` (time, state, diagnosis) if the run fails: at
      once when called eagerly, from a host callback at run time under ``jax.jit`` or
      ``jax.vmap``. With False, inspect ``sol.result`` / call ``sol.check()``.

    **Returns:** a :class:`Solution`.

    Pure: jittable, vmappable over initial states and model parameters, and differentiable
    (through the diffrax adjoint).
    """
    _check_arguments(model, t0, t1, dt0, translation, solver, stepsize_controller, adjoint, throw)
    att = _check_attitude_and_laws(attitude, controller, law)
    law, controller = with_model_laws(model, law, controller)  # a scene's own laws first
    dtype = jnp.result_type(model.mass)
    # (stacklevel 3: the caller of full_precision's wrapper)
    rtol, atol = tolerances("simulate", rtol, atol, max_steps, dtype, stepsize_controller, stacklevel=3)
    y0 = model.initial if y0 is None else y0
    check_state("simulate", model, y0)
    saveat, grid, user_saveat = _check_saveat(saveat, t0, t1)
    ev, has_guard, user_event = _combine_events(event, att)
    meter = progress_meter(progress)
    # every argument is checked: from here on JAX may trace
    if not (grid is not None or user_saveat):
        saveat = jnp.asarray(saveat, dtype)
    X0 = Xd0 = None
    if isinstance(translation, tuple):
        X0, Xd0 = translation
        translation = True
    elif translation and model.orbit is not None:  # start on the scene's orbit
        X0, Xd0 = model.orbit.position(jnp.asarray(t0, dtype)), model.orbit.velocity(jnp.asarray(t0, dtype))
    problem = _problem(model, att, law, controller, params, bool(translation))
    if solver is None or isinstance(solver, str):
        solver, choice = choose_checked(model, t1, t0=t0, y0=y0, rtol=rtol, law=law, params=params)
    else:
        choice = given(solver)
    if adjoint is None:
        adjoint = dfx.RecursiveCheckpointAdjoint()
    inputs = (model, y0, t0, t1, params, controller, law, saveat, ev, translation, X0, Xd0)
    traced = is_traced((*inputs, rtol, atol, dt0, solver, stepsize_controller, adjoint))
    if not traced and throw:
        _check_finite_start(y0, X0, Xd0, t0, att)
    opts = _Options(has_guard, user_event, int(max_steps), grid, user_saveat, bool(throw and traced))
    as_array = lambda x: None if x is None else jnp.asarray(x, dtype)
    arrays = (as_array(X0), as_array(Xd0), as_array(t0), as_array(t1), as_array(rtol), as_array(atol), as_array(dt0))
    sol = _solve(problem, y0, _Run(*arrays, solver, stepsize_controller, saveat, adjoint, ev, meter), opts)
    sol = _with_diagnostics(sol, model, law, controller, params)
    sol = eqx.tree_at(lambda s: s.stats, sol, dict(sol.stats, solver=choice))
    if throw and not traced:
        check_solution(sol)
    return sol


def _check_attitude_and_laws(attitude, controller, law) -> AbstractAttitude:
    """The attitude variables of `attitude`, once `controller` and `law` are checked too."""
    try:
        att = get_attitude(attitude)
    except ValueError as e:
        raise SceneError(f"simulate: {e}") from None
    if controller is not None and not isinstance(controller, AbstractController):
        raise SceneTypeError(f"simulate: controller must be an AbstractController, got {short(controller)}")
    if law is not None and not callable(law):
        raise SceneTypeError(f"simulate: law must be a callable tau(t, state, params), got {short(law)}")
    return att


def _check_saveat(saveat, t0, t1):
    """``(saveat, grid, user_saveat)``: a SaveAt (used as is), a number of evenly spaced save
    times (`grid`; saveat None) or an array of times, checked with `t0` and `t1`."""
    grid, user_saveat = None, False
    if isinstance(saveat, dfx.SaveAt):
        if saveat.subs is None:
            raise SceneError("simulate: saveat: the SaveAt must save at least one time (t0, t1, ts or steps)")
        user_saveat = True
    elif saveat is None or (isinstance(saveat, (int, np.integer)) and not isinstance(saveat, bool)):
        grid = DEFAULT_SAVE_POINTS if saveat is None else int(saveat)
        if grid < 2:
            raise SceneError(f"simulate: saveat: need at least 2 save points, got {grid}")
        saveat = None
    else:
        shape = jnp.shape(saveat) if is_traced(saveat) else as_float(saveat, "simulate: saveat", finite=False).shape
        if len(shape) != 1:
            raise SceneError(
                f"simulate: saveat: expected a number of save points or a 1-D array of times, got shape {shape}"
            )
    check_times("simulate", t0, t1, None if grid is not None or user_saveat else saveat)
    return saveat, grid, user_saveat


def _problem(model: Model, att: AbstractAttitude, law, controller, params, translation: bool) -> Problem:
    """The ODE: `model` with its attitude variables, laws, controller states and, if
    `translation`, the mass center's position and velocity."""
    control_size = 0
    if controller is not None:
        control_size = sum(int(np.prod(x.shape)) for x in jax.tree_util.tree_leaves(jax.eval_shape(controller.initial)))
    return Problem(model, att, law, controller, params, translation, control_size)


def _check_finite_start(y0: State, X0, Xd0, t0, att: AbstractAttitude) -> None:
    """Raise SimulationError for a concrete start that is not finite."""
    start = [np.asarray(x, float) for x in (*y0, *(() if X0 is None else (X0, Xd0)))]
    if not all(np.all(np.isfinite(x)) for x in start):
        # (under jit the solver would reject every step until max_steps: NaN step sizes)
        raise SimulationError(_format_failure("nonfinite_start", t0, y0, np.nan, np.nan, att.name))


def _with_diagnostics(sol: Solution, model: Model, law, controller, params) -> Solution:
    """`sol` with its energy, angular momentum and hold torques (see :func:`_diagnostics`)."""
    needs_law = model.prescription is not None
    diag = _diagnostics(
        model,
        law if needs_law else None,
        controller if needs_law else None,
        params if needs_law else None,
        sol.ts,
        State(sol.dcm, sol.omega0, sol.gamma, sol.gamma_dot),
        sol.control_state if needs_law else None,
    )
    return eqx.tree_at(lambda s: (s.energy, s.angular_momentum, s.hold_torque), sol, diag, is_leaf=lambda x: x is None)
