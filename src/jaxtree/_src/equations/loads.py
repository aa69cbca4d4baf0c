"""External loads F^k, T^k (Defs. 19-20) as functions of time and state, per body.

A model carries its loads as a :class:`~jaxtree.BodyLoads` (``model.with_loads(...)``);
bodies not listed feel nothing, and a model without loads traces no load terms at all.
This module builds such objects:

- :class:`PerBodyLoads` from a mapping ``{body: fn(t, state) -> (force (3,), torque (3,))}``
  (components in that body's frame, force at its mass center);
- :class:`BodyTorque`: a torque history ``torque(t)`` on one body, e.g. a thruster pair on
  the bus (:func:`thruster_pulse` gives a smooth on/off pulse);
- :class:`GravityGradient`: the gravity-gradient torques and tidal forces of a circular orbit;
- :class:`ScheduledLoads`: the scene format's forces and torques, each a constant vector in a
  body's frame times a profile of time (constant, pulse or table: :mod:`jaxtree.profiles`);
- :class:`AttitudePD`: a PD law on the reference body's attitude, as a torque on it;
- :class:`CircularOrbit`: the circular orbit of the mass center about a central body (Eq. 2),
  whose rate the gravity gradient uses;
- :class:`CombinedLoads` (:func:`combine_loads`): several of the above side by side.

Loads written as equinox Modules keep their numbers as array leaves (traced, differentiable).
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from ..vehicle.model import BodyLoads, Model, State
from ..vehicle.profiles import linear_table, pad_tables
from .assembly import configuration


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


def thruster_pulse(t, start, duration, rise: ArrayLike = 1e-2):
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

    def __init__(
        self,
        model: Model,
        mu: ArrayLike = 3.986004418e14,
        radius: ArrayLike = 7.0e6,
        phase: ArrayLike = 0.0,
        bodies=None,
    ):
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


LOAD_PROFILES = ("constant", "pulse", "table")


class ScheduledLoads(BodyLoads):
    """Forces and torques of the scene format: load i is ``vector_i * p_i(t)`` on body
    ``rows[i]`` (components in that body's frame; a force acts at its mass center), a torque
    or a force as ``kinds[i]`` says, with the profile ``profiles[i]``: ``"constant"`` (1),
    ``"pulse"`` (:func:`thruster_pulse` with `start`, `duration`, `rise`) or ``"table"``
    (linear interpolation of `times`, `values`, held constant outside; the tables padded as in
    :func:`jaxtree.profiles.pad_tables` to one length, `lengths` the true ones).

    Leaves: `vector` (m, 3), `start`, `duration`, `rise` (m,), `times`, `values` (m, L); the
    kinds, profiles, rows and lengths are static. One vectorized evaluation per profile kind.
    """

    vector: jax.Array
    start: jax.Array
    duration: jax.Array
    rise: jax.Array
    times: jax.Array
    values: jax.Array
    rows: tuple[int, ...] = eqx.field(static=True)
    kinds: tuple[str, ...] = eqx.field(static=True)
    profiles: tuple[str, ...] = eqx.field(static=True)
    lengths: tuple[int, ...] = eqx.field(static=True)
    bodies: tuple[int, ...] = eqx.field(static=True)

    def __init__(self, rows, kinds, vectors, profiles, start=None, duration=None, rise=None, tables=None):
        """**Arguments:** per load: `rows` body index, `kinds` ``"torque"`` or ``"force"``,
        `vectors` (3,), `profiles` a kind of :data:`LOAD_PROFILES`; `start`, `duration`, `rise`
        the pulse parameters (ignored elsewhere); `tables` ``(times, values)`` of each table
        profile (None elsewhere)."""
        m = len(rows)
        self.rows = tuple(int(k) for k in rows)
        self.kinds = tuple(kinds)
        self.profiles = tuple(profiles)
        self.bodies = tuple(sorted(set(self.rows)))
        self.vector = jnp.asarray(np.reshape(np.asarray(vectors, float), (m, 3)))
        fill = lambda x, v: np.full(m, v) if x is None else np.asarray(x, float)
        self.start = jnp.asarray(fill(start, 0.0))
        self.duration = jnp.asarray(fill(duration, 0.0))
        self.rise = jnp.asarray(fill(rise, 1.0))
        tables = [None] * m if tables is None else list(tables)
        ts = [np.asarray(tb[0], float) if tb is not None else np.array([0.0, 1.0]) for tb in tables]
        vs = [np.asarray(tb[1], float) if tb is not None else np.array([1.0, 1.0]) for tb in tables]
        self.lengths = tuple(len(t) if tb is not None else 0 for t, tb in zip(ts, tables))
        T, V = pad_tables(ts, vs)
        self.times, self.values = jnp.asarray(T), jnp.asarray(V)

    def profile(self, t):
        """The factors ``p_i(t)`` (m,)."""
        kinds = np.asarray(self.profiles)
        dtype = self.vector.dtype
        p = jnp.ones((len(self.rows),), dtype)
        if (kinds == "pulse").any():
            p = jnp.where(kinds == "pulse", thruster_pulse(t, self.start, self.duration, self.rise), p)
        if (kinds == "table").any():
            table = jax.vmap(linear_table, in_axes=(None, 0, 0))(t, self.times, self.values)
            p = jnp.where(kinds == "table", table, p)
        return p

    def __call__(self, t, state):
        dtype = state.omega0.dtype
        p = self.profile(jnp.asarray(t, dtype)).astype(dtype)
        v = self.vector.astype(dtype) * p[:, None]
        force = np.asarray([k == "force" for k in self.kinds], dtype=float)[:, None]
        # rows -> bodies: a constant 0/1 matrix (several loads on one body add)
        S = np.zeros((len(self.bodies), len(self.rows)))
        S[[self.bodies.index(k) for k in self.rows], np.arange(len(self.rows))] = 1.0
        S = jnp.asarray(S, dtype)
        return S @ (v * force), S @ (v * (1.0 - force))


class CircularOrbit(eqx.Module):
    """A circular orbit of the system mass center about a central body of gravitational
    parameter `mu`: Eq. (2) with the central body's attraction ``-mu M X / |X|^3`` alone, whose
    circular solution in the ``i_1, i_2`` plane is ``X(t) = radius (cos a, sin a, 0)``,
    ``a = rate t + phase``, ``rate = sqrt(mu / radius^3)`` (the mean motion).

    The vehicle's own loads do not perturb it: the tidal forces of :class:`GravityGradient` sum
    to zero over the vehicle (``sum m_k rho_k = 0``), and scheduled forces are assumed small
    against the central attraction over the run. Leaves: `mu`, `radius`, `phase`.
    """

    mu: jax.Array
    radius: jax.Array
    phase: jax.Array

    def __init__(self, mu: ArrayLike = 3.986004418e14, radius: ArrayLike = 7.0e6, phase: ArrayLike = 0.0):
        self.mu = jnp.asarray(mu, float)
        self.radius = jnp.asarray(radius, float)
        self.phase = jnp.asarray(phase, float)

    @property
    def rate(self) -> jax.Array:
        """The mean motion ``sqrt(mu / radius^3)`` (rad/s)."""
        return jnp.sqrt(self.mu / self.radius**3)

    def position(self, t) -> jax.Array:
        """``X(t)`` (3,) in inertial components."""
        a = self.rate * t + self.phase
        return self.radius * jnp.stack([jnp.cos(a), jnp.sin(a), jnp.zeros_like(a)])

    def velocity(self, t) -> jax.Array:
        """``X_dot(t)`` (3,) in inertial components."""
        a = self.rate * t + self.phase
        return self.radius * self.rate * jnp.stack([-jnp.sin(a), jnp.cos(a), jnp.zeros_like(a)])

    def gravity_gradient(self, model: Model, bodies=None) -> GravityGradient:
        """The :class:`GravityGradient` of this orbit on `model` (`bodies`: default all with mass)."""
        return GravityGradient(model, self.mu, self.radius, self.phase, bodies)


class AttitudePD(BodyLoads):
    """A PD law on the attitude of the reference body b_0 to a set point, as an external torque on
    it (thrusters): ``T^0 = -kp e - kd omega0`` in {b^0}, with ``e = vee(C_e^T - C_e) / 2``
    (``sin(angle) axis`` of the error rotation ``C_e = C C_r^T``; ``C`` of Def. 9 and the set
    point ``C_r``). About one axis from rest it is ``J theta'' = -kp sin(theta) - kd theta'``.

    Leaves: `kp`, `kd` (3,) per axis of {b^0}; `set_point` (3, 3) the direction cosines ``C_r``.
    """

    kp: jax.Array
    kd: jax.Array
    set_point: jax.Array
    bodies: tuple[int, ...] = eqx.field(static=True)

    def __init__(self, kp, kd, set_point=None):
        self.kp = jnp.broadcast_to(jnp.asarray(kp, float), (3,))
        self.kd = jnp.broadcast_to(jnp.asarray(kd, float), (3,))
        self.set_point = jnp.eye(3) if set_point is None else jnp.asarray(set_point, float).reshape(3, 3)
        self.bodies = (0,)

    def error(self, dcm) -> jax.Array:
        """The attitude error ``e`` (3,) in {b^0}."""
        Ce = dcm @ self.set_point.astype(dcm.dtype).T
        S = 0.5 * (Ce.T - Ce)
        return jnp.stack([S[2, 1], S[0, 2], S[1, 0]])

    def __call__(self, t, state):
        dtype = state.omega0.dtype
        e = self.error(jnp.asarray(state.dcm, dtype))
        T = -self.kp.astype(dtype) * e - self.kd.astype(dtype) * state.omega0
        return jnp.zeros((1, 3), dtype), T[None, :]
