"""Eq. (1) of Likins (1972) solved for the accelerations at a state, as it is called: the public
:func:`forward_dynamics` and :func:`solve_accelerations` (prescribed hinges as in Sec. II B), and
:func:`solve_unchecked`, the engine's call.

An eager (untraced) call is one compiled program, and non-finite accelerations raise
:class:`DynamicsError` with a diagnosis (:func:`diagnose`: a non-finite input, or a singular
matrix of Defs. 38-40 with its near-null direction). The solve is in :mod:`.solve`, its
derivatives in :mod:`.rules`.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..numerics import eager_jit, is_traced
from ..vehicle.model import Model, State
from .assembly import check_shapes, complete_state, dtype_of, rotational_equations
from .diagnostics import SINGULAR_CONDITION, matrix_condition, null_direction_text, unknown_labels
from .kinematics import full_precision
from .rules import solve_completed
from .solve import Accelerations


class DynamicsError(ArithmeticError):
    """Eq. (1) gave non-finite accelerations in an eager (untraced) call of
    :func:`forward_dynamics` or :func:`solve_accelerations`. The message gives the time, the
    state and a diagnosis: a non-finite input, or a singular matrix with its near-null
    direction (e.g. gimbal lock: two hinge axes aligned through a massless gimbal frame).
    Under ``jax.jit`` or ``jax.vmap`` the accelerations are NaN instead (``jaxtree.simulate``
    reports such runs with the same diagnosis)."""


@full_precision
def solve_accelerations(model: Model, state: State, t=0.0, tau=None) -> Accelerations:
    """Solve Eq. (1) by Cholesky factorization, with prescribed hinges as in Sec. II B.

    A prescribed hinge j takes ``gamma_j``, ``gamma_dot_j`` and ``gamma_ddot_j`` from
    the prescription at time t (its entries in `state` are ignored); its row and
    column leave the matrix and ``a_{.j} gamma_ddot_j`` moves to the right side.
    The torque needed to hold the prescription is returned as `hold_torque`.
    """
    check_shapes("solve_accelerations", model, state, tau=tau)
    acc = _solve_eager(model, state, t, tau)
    _check_finite("solve_accelerations", model, state, t, tau, acc)
    return acc


def solve_unchecked(model, state, t, tau, completed=None):
    """Eq. (1) at a state; `completed`: the prescribed accelerations of a state already
    completed with its prescribed hinges (:func:`jaxtree._src.vehicle.hinges.complete`, once per right side),
    or None to complete it here."""
    if completed is None:
        state, gdd_p = complete_state(model, t, state)
    else:
        gdd_p = completed if model.prescription is not None else None
    dtype = dtype_of(model, state.gamma, state.gamma_dot, state.omega0)
    state = State(*(jnp.asarray(x, dtype) for x in state))
    return solve_completed(model, state, jnp.asarray(t, dtype), tau, gdd_p)


# an eager call of the public functions below: one program (the finite check stays outside it)
_solve_eager = eager_jit(solve_unchecked)


def _check_finite(name, model, state, t, tau, acc):
    """Raise :class:`DynamicsError` when an eager call gives non-finite accelerations."""
    if is_traced((model, state, t, tau, acc)):
        return
    if all(bool(np.all(np.isfinite(np.asarray(x)))) for x in (acc.omega0_dot, acc.gamma_ddot)):
        return
    raise DynamicsError(diagnose(name, model, state, t, tau))


def diagnose(name, model, state, t, tau):
    """The message of :class:`DynamicsError` for the call `name`: the time, the state, and why
    the accelerations are not finite."""
    lines = [f"jaxtree.{name}: the accelerations of Eq. (1) are not finite", f"  t = {float(t):.9g}"]
    for field in State._fields:
        lines.append(f"  {field} = {np.asarray(getattr(state, field)).tolist()}")
    bad = [f for f in State._fields if not np.all(np.isfinite(np.asarray(getattr(state, f))))]
    if tau is not None and not np.all(np.isfinite(np.asarray(tau))):
        bad.append("tau")
    bad += [
        f"model.{f}"
        for f in ("mass", "inertia", "axis", "hinge_on_parent", "hinge_on_body", "stiffness", "damping")
        if not np.all(np.isfinite(np.asarray(getattr(model, f))))
    ]
    if bad:
        lines.append(f"  diagnosis: not finite: {', '.join(bad)}")
        return "\n".join(lines)
    full, gdd_p = complete_state(model, t, state)
    A, rhs = rotational_equations(model, full, t, tau)
    if not np.all(np.isfinite(np.asarray(A))):
        lines.append("  diagnosis: the Eq. (1) matrix is not finite")
        return "\n".join(lines)
    cond, direction = matrix_condition(model, A)
    cond = float(cond)
    if not np.isfinite(cond) or cond > SINGULAR_CONDITION:
        lines.append(
            f"  diagnosis: the Eq. (1) matrix is singular or nearly so (condition number {cond:.3g}); "
            f"{null_direction_text(direction, unknown_labels(model))}"
        )
    elif not np.all(np.isfinite(np.asarray(rhs))) or (gdd_p is not None and not np.all(np.isfinite(np.asarray(gdd_p)))):
        lines.append(
            "  diagnosis: the right side of Eq. (1) is not finite (a joint law, external load or "
            "prescription gave a non-finite value)"
        )
    return "\n".join(lines)


@full_precision
def forward_dynamics(model: Model, dcm, omega0, gamma, gamma_dot, t=0.0):
    """Accelerations of Eq. (1): ``(omega0_dot (3,), gamma_ddot (n,))``.

    **Arguments:** `dcm` C of Def. 9 ({b^0} = C {i}); `omega0` (3,) in {b^0};
    `gamma`, `gamma_dot` (n,) with ``gamma[k-1] = gamma_k``; `t` time. Hinge torques
    come from the model's joint laws, external loads from `model.loads` (none
    traced when it is None), prescribed hinges from `model.prescription`.
    Jittable and vmappable.
    """
    check_shapes("forward_dynamics", model, dcm=dcm, omega0=omega0, gamma=gamma, gamma_dot=gamma_dot)
    state = State(dcm, omega0, gamma, gamma_dot)
    acc = _solve_eager(model, state, t, None)
    _check_finite("forward_dynamics", model, state, t, None, acc)
    return acc.omega0_dot, acc.gamma_ddot
