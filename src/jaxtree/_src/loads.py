"""External loads F^k, T^k (Defs. 19-20) as functions of time and state, per body.

A model carries its loads as a :class:`~jaxtree.BodyLoads` (``model.with_loads(...)``);
bodies not listed feel nothing, and a model without loads traces no load terms at all.
This module builds such objects:

- :class:`PerBodyLoads` from a mapping ``{body: fn(t, state) -> (force (3,), torque (3,))}``
  (components in that body's frame, force at its mass center);
- :class:`BodyTorque`: a torque history ``torque(t)`` on one body, e.g. a thruster pair on
  the bus (:func:`thruster_pulse` gives a smooth on/off pulse);
- :class:`GravityGradient`: the gravity-gradient torques and tidal forces of a circular orbit;
- :class:`CombinedLoads` (:func:`combine_loads`): several of the above side by side.

Loads written as equinox Modules keep their numbers as array leaves (traced, differentiable).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .dynamics import configuration
from .model import BodyLoads, Model, State


class PerBodyLoads(BodyLoads):
    """Loads from one function per body: ``fn(t, state) -> (force (3,), torque (3,))``.

    **Arguments:** `loads` a mapping ``{body index: fn}``. The functions are static (hashed by
    identity): pass the same objects to reuse a compiled simulation.
    """

    bodies: tuple[int, ...] = eqx.field(static=True)
    fns: tuple[Callable, ...] = eqx.field(static=True)

    def __init__(self, loads: dict):
        items = sorted((int(k), f) for k, f in loads.items())
        self.bodies = tuple(k for k, _ in items)
        self.fns = tuple(f for _, f in items)

    def __call__(self, t, state):
        out = [f(t, state) for f in self.fns]
        dtype = state.omega0.dtype
        F = jnp.stack([jnp.broadcast_to(jnp.asarray(f, dtype), (3,)) for f, _ in out])
        T = jnp.stack([jnp.broadcast_to(jnp.asarray(m, dtype), (3,)) for _, m in out])
        return F, T


def thruster_pulse(t, start, duration, rise=1e-2):
    """Smooth 0 -> 1 -> 0 pulse (tanh edges of width `rise`) from `start` for `duration`."""
    on = 0.5 * (1 + jnp.tanh((t - start) / rise))
    off = 0.5 * (1 + jnp.tanh((t - start - duration) / rise))
    return on - off


class BodyTorque(BodyLoads):
    """A pure torque on one body: ``torque * profile(t)`` in the body's frame.

    **Arguments:** `body` index; `torque` (3,) components in the body frame; `profile` a
    scalar function of time (static; default constant 1), e.g.
    ``lambda t: thruster_pulse(t, 5.0, 2.0)``.
    """

    torque: jax.Array
    bodies: tuple[int, ...] = eqx.field(static=True)
    profile: Callable | None = eqx.field(static=True, default=None)

    def __init__(self, body: int, torque, profile: Callable | None = None):
        self.bodies = (int(body),)
        self.torque = jnp.asarray(torque, float).reshape(3)
        self.profile = profile

    def __call__(self, t, state):
        dtype = state.omega0.dtype
        T = self.torque.astype(dtype)
        if self.profile is not None:
            T = T * jnp.asarray(self.profile(t), dtype)
        return jnp.zeros((1, 3), dtype), T[None, :]


class GravityGradient(BodyLoads):
    """Gravity-gradient torques and tidal forces on a vehicle in a circular orbit.

    The mass center moves on a circle of radius `radius` in the ``i_1, i_2`` plane at the
    orbital rate ``w = sqrt(mu / radius^3)``, at ``r_hat(t) = (cos(w t + phase), sin(w t + phase), 0)``
    (inertial). Relative to that orbit each body feels, about its mass center,
    ``T^k = 3 w^2 r_k x (I^k r_k)`` (``r_k`` the components of r_hat in its frame) and the tidal
    force ``F^k = w^2 m_k (3 r_hat (r_hat . rho_k) - rho_k)`` (``rho_k`` its mass center from the
    system mass center). The vehicle's mass geometry is copied from `model` when built.

    **Arguments:** `model` the vehicle; `mu` gravitational parameter; `radius` orbit radius;
    `phase` orbit angle at t = 0; `bodies` the bodies that feel it (default: all with mass).
    """

    geometry: Model
    mu: jax.Array
    radius: jax.Array
    phase: jax.Array
    bodies: tuple[int, ...] = eqx.field(static=True)

    def __init__(self, model: Model, mu=3.986004418e14, radius=7.0e6, phase=0.0, bodies=None):
        self.geometry = model.with_loads(None)
        self.mu = jnp.asarray(mu, float)
        self.radius = jnp.asarray(radius, float)
        self.phase = jnp.asarray(phase, float)
        self.bodies = tuple(model.massive) if bodies is None else tuple(int(b) for b in bodies)

    def __call__(self, t, state: State):
        dtype = state.omega0.dtype
        cfg = configuration(self.geometry, state.gamma)
        b = np.asarray(self.bodies)
        w2 = (self.mu / self.radius**3).astype(dtype)
        ang = jnp.sqrt(w2) * t + self.phase.astype(dtype)
        r_in = jnp.stack([jnp.cos(ang), jnp.sin(ang), jnp.zeros_like(ang)])
        r0 = jnp.asarray(state.dcm, dtype) @ r_in  # {b^0} components
        R = cfg.R[b]  # C^{0k}
        rk = jnp.einsum("kji,j->ki", R, r0)  # {b^k} components: C^{k0} r0
        I = self.geometry.inertia[b].astype(dtype)
        T = 3.0 * w2 * jnp.cross(rk, jnp.einsum("kij,kj->ki", I, rk))
        rho = cfg.rho[b]
        m = self.geometry.mass[b].astype(dtype)
        F0 = w2 * m[:, None] * (3.0 * r0[None, :] * (rho @ r0)[:, None] - rho)
        F = jnp.einsum("kji,kj->ki", R, F0)
        return F, T


class CombinedLoads(BodyLoads):
    """Several loads side by side; a body listed by several feels their sum."""

    parts: tuple[BodyLoads, ...]
    bodies: tuple[int, ...] = eqx.field(static=True)

    def __init__(self, parts):
        self.parts = tuple(parts)
        self.bodies = tuple(sorted({int(b) for p in self.parts for b in p.bodies}))

    def __call__(self, t, state):
        dtype = state.omega0.dtype
        index = {b: i for i, b in enumerate(self.bodies)}
        F = jnp.zeros((len(self.bodies), 3), dtype)
        T = jnp.zeros((len(self.bodies), 3), dtype)
        for p in self.parts:
            f, m = p(t, state)
            rows = np.asarray([index[int(b)] for b in p.bodies])
            F = F.at[rows].add(jnp.asarray(f, dtype))
            T = T.at[rows].add(jnp.asarray(m, dtype))
        return F, T


def combine_loads(*loads: BodyLoads | None) -> BodyLoads | None:
    """Combine loads (None entries dropped); None when nothing is left."""
    parts = [p for p in loads if p is not None]
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    return CombinedLoads(parts)
