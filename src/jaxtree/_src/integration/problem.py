"""The first-order form of Eq. (1) that :func:`jaxtree.simulate` integrates (Eqs. 25-27): the
flat state (attitude variables of b_0, omega0, the angles and rates of the hinges that are not
prescribed, a controller's states and, when asked for, the mass center's position and velocity of
Eq. 2), its packing, the vector field and its Jacobian by parts.

Internally the ODE state is one flat vector in that order: a single leaf keeps diffrax's per-stage
linear algebra to a few fused operations (on this project's 2-core CPU a four-leaf pytree state ran
1.4-2x slower). :meth:`Problem.state` turns it back into a :class:`~jaxtree.State` for event
functions and control laws. Each right-hand side solves Eq. (1) once
(:func:`jaxtree.solve_accelerations`).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ..equations.attitude import AbstractAttitude, DirectionCosines, Euler123, Quaternion
from ..equations.control import AbstractController
from ..equations.dynamics import (
    mass_center_acceleration,
    solve_unchecked,
)
from ..numerics import is_traced, program_jit
from ..vehicle import hinges
from ..vehicle.model import Model, State
from . import radau
from .jacobian import jacobian_by_parts


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

    def pack(self, state: State, z=None, X=None, X_dot=None, xp=jnp):
        """Flat state from a :class:`~jaxtree.State` (prescribed entries dropped), controller
        states and mass-center position/velocity. `xp`: the array module (numpy for a concrete
        state on the host, :func:`packed_start`)."""
        dtype = np.dtype(jnp.result_type(self.model.mass))
        u = np.asarray(self.free_hinges, dtype=np.int64) - 1
        parts = [
            self.attitude.from_dcm(xp.asarray(state.dcm, dtype), xp=xp),
            xp.asarray(state.omega0, dtype),
            xp.asarray(state.gamma, dtype)[u],
            xp.asarray(state.gamma_dot, dtype)[u],
        ]
        if self.controller is not None:
            zf, _ = ravel_pytree(self.controller.initial() if z is None else z)
            parts.append(zf.astype(dtype))
        if self.translation:
            parts.append(xp.zeros(3, dtype) if X is None else xp.asarray(X, dtype))
            parts.append(xp.zeros(3, dtype) if X_dot is None else xp.asarray(X_dot, dtype))
        return xp.concatenate([xp.reshape(p, (-1,)) for p in parts])


def packed_start(problem: Problem, y0: State, X0=None, X_dot0=None):
    """``problem.pack(y0, None, X0, X_dot0)`` of a concrete start: by numpy on the host where the
    attitude variables are jaxtree's own and no controller adds states (no program to compile:
    ~0.08 s of a first call), else as one small program (:func:`_packed_start_program`)."""
    host = type(problem.attitude) in (Quaternion, DirectionCosines, Euler123) and problem.controller is None
    if host and not is_traced((y0, X0, X_dot0)):
        return problem.pack(y0, None, X0, X_dot0, xp=np)
    return _packed_start_program(problem, y0, X0, X_dot0)


@program_jit(light=True)
def _packed_start_program(problem: Problem, y0: State, X0=None, X_dot0=None):
    """``problem.pack(y0, None, X0, X_dot0)`` as one small program (kept across processes where
    it can be), not a dozen operations compiled one by one in every process."""
    return problem.pack(y0, None, X0, X_dot0)


@eqx.filter_jit
def _problem_jacobian(t, y, args: Problem):
    """The Jacobian that :func:`simulate` gives :class:`jaxtree.Radau5` (:meth:`Problem.jacobian`);
    jitted, as :func:`problem_field`, so that the solver's several traces reuse one jaxpr."""
    return args.jacobian(t, y)


def with_jacobian(solver):
    """`solver`, and for a :class:`jaxtree.Radau5` without a Jacobian of its own the problem's
    structured one (:meth:`Problem.jacobian`)."""
    return radau.with_jacobian(solver, _problem_jacobian)


@eqx.filter_jit
def problem_field(t, y, args: Problem):
    # jitted so that diffrax's several traces of the vector field reuse one jaxpr; traced inside
    # `simulate`, so at its full matrix-product precision
    return args.vector_field(t, y)


def make_problem(model: Model, att: AbstractAttitude, law, controller, params, translation: bool) -> Problem:
    """The ODE: `model` with its attitude variables, laws, controller states and, if
    `translation`, the mass center's position and velocity."""
    control_size = 0
    if controller is not None:
        control_size = sum(int(np.prod(x.shape)) for x in jax.tree_util.tree_leaves(jax.eval_shape(controller.initial)))
    return Problem(model, att, law, controller, params, translation, control_size)
