"""Hinge laws and controllers: the torques tau_k of Def. 21 beyond the model's joint laws.

Sec. II D, inputs 7-8: ``tau_k`` "as functions of the system variables or as control-law ODEs".
:func:`jaxtree.simulate` takes either

- a **hinge law**, any callable ``tau(t, state, params) -> (n,)`` of time, the full
  :class:`~jaxtree.State` (prescribed hinges filled in, ``state.dcm`` from the attitude
  variables) and the user's ``params`` pytree; :class:`HingePD` is one (a PD pointing law); or
- a **controller** with internal states, an :class:`AbstractController`: its states ``z``
  are appended to the ODE state and integrated with the motion (:class:`HingePID` holds an
  integrator and a first-order rate filter; :class:`Controller` wraps two plain functions).

The torques add to the model's spring-damper laws. Entries for prescribed hinges are
accepted and change the hold torque, not the motion (Sec. II B).
Laws written as equinox Modules keep their gains as array leaves, so they are traced
(no recompilation when a gain changes) and differentiable; plain functions are static and
must be the same object from call to call to reuse a compiled simulation.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..vehicle.hinges import selector
from ..vehicle.model import State


def hinge_torque_vector(n: int, hinges, torque):
    """Scatter torques on `hinges` (1-based, static) into an (n,) vector (a constant 0/1 product)."""
    hinges = tuple(int(k) for k in np.atleast_1d(hinges))
    torque = jnp.atleast_1d(torque)
    return selector(n, hinges, torque.dtype) @ torque


def _split_reference(reference, hinges):
    """``(function or None, constant angles or None)``: functions are static, arrays are leaves."""
    if reference is None:
        return None, None
    if callable(reference):
        return reference, None
    return None, jnp.broadcast_to(jnp.asarray(reference, float), (len(hinges),))


def _reference(fn, value, t, hinges, dtype):
    """Reference angles and rates of `hinges` at t."""
    if fn is not None:
        t = jnp.asarray(t, dtype)
        g, gd = jax.jvp(
            lambda s: jnp.broadcast_to(jnp.asarray(fn(s), dtype), (len(hinges),)), (t,), (jnp.ones_like(t),)
        )
        return g, gd
    if value is not None:
        g = value.astype(dtype)
        return g, jnp.zeros_like(g)
    z = jnp.zeros((len(hinges),), dtype)
    return z, z


class HingePD(eqx.Module):
    """PD law ``tau_k = -kp (gamma_k - r_k(t)) - kd (gamma_dot_k - r_dot_k(t))`` on static `hinges`.

    **Arguments:** `n` number of hinges of the model; `hinges` (1-based); `kp`, `kd` gains
    (scalars or one per hinge); `reference` a function of time (differentiated for the rate
    reference), an array of constant angles, or None (zero).
    Called as a hinge law ``law(t, state, params)``; `params` is not used.
    """

    kp: jax.Array
    kd: jax.Array
    reference_value: jax.Array | None
    n: int = eqx.field(static=True)
    hinges: tuple[int, ...] = eqx.field(static=True)
    reference_fn: Callable | None = eqx.field(static=True, default=None)

    def __init__(self, n, hinges, kp, kd, reference=None):
        self.n = int(n)
        self.hinges = tuple(int(k) for k in np.atleast_1d(hinges))
        self.kp = jnp.broadcast_to(jnp.asarray(kp, float), (len(self.hinges),))
        self.kd = jnp.broadcast_to(jnp.asarray(kd, float), (len(self.hinges),))
        self.reference_fn, self.reference_value = _split_reference(reference, self.hinges)

    def __call__(self, t, state: State, params=None):
        i = np.asarray(self.hinges) - 1
        dtype = state.gamma.dtype
        r, rd = _reference(self.reference_fn, self.reference_value, t, self.hinges, dtype)
        tau = -self.kp.astype(dtype) * (state.gamma[i] - r) - self.kd.astype(dtype) * (state.gamma_dot[i] - rd)
        return hinge_torque_vector(self.n, self.hinges, tau)


class AbstractController(eqx.Module):
    """A control law with internal states ``z`` (any pytree of arrays) integrated with the motion.

    Subclasses implement :meth:`initial`, :meth:`torque` and :meth:`rate`.
    """

    @abc.abstractmethod
    def initial(self):
        """Initial internal states ``z(t0)`` (a pytree of arrays)."""

    @abc.abstractmethod
    def torque(self, t, state: State, z, params):
        """Hinge torques (n,) at time t."""

    @abc.abstractmethod
    def rate(self, t, state: State, z, params):
        """``dz/dt`` (same structure as z)."""


class Controller(AbstractController):
    """A controller from plain functions ``torque(t, state, z, params) -> (n,)`` and
    ``rate(t, state, z, params) -> dz/dt``, with initial states `z0`."""

    z0: Any
    torque_fn: Callable = eqx.field(static=True)
    rate_fn: Callable = eqx.field(static=True)

    def initial(self):
        return self.z0

    def torque(self, t, state, z, params):
        return self.torque_fn(t, state, z, params)

    def rate(self, t, state, z, params):
        return self.rate_fn(t, state, z, params)


class HingePID(AbstractController):
    """PID law on static `hinges` with an integrator and a first-order filtered rate.

    ``e = gamma - r(t)``; internal states ``z = (integral of e, filtered e_dot)`` with
    ``d/dt integral = e`` and ``d/dt f = (e_dot - f) / filter_time``;
    ``tau = -kp e - ki integral - kd f``.

    **Arguments:** `n` number of hinges of the model; `hinges` (1-based); gains `kp`, `ki`,
    `kd` and `filter_time` (scalars or one per hinge); `reference` as for :class:`HingePD`;
    `z0` the initial internal states (default zero), e.g. where a run in parts continues.
    """

    kp: jax.Array
    ki: jax.Array
    kd: jax.Array
    filter_time: jax.Array
    reference_value: jax.Array | None
    n: int = eqx.field(static=True)
    hinges: tuple[int, ...] = eqx.field(static=True)
    reference_fn: Callable | None = eqx.field(static=True, default=None)
    z0: Any = None

    def __init__(self, n, hinges, kp, ki, kd, filter_time, reference=None, z0=None):
        self.n = int(n)
        self.hinges = tuple(int(k) for k in np.atleast_1d(hinges))
        shape = (len(self.hinges),)
        self.kp, self.ki, self.kd, self.filter_time = (
            jnp.broadcast_to(jnp.asarray(x, float), shape) for x in (kp, ki, kd, filter_time)
        )
        self.reference_fn, self.reference_value = _split_reference(reference, self.hinges)
        self.z0 = z0

    def initial(self):
        if self.z0 is not None:
            return self.z0
        z = jnp.zeros((len(self.hinges),), self.kp.dtype)
        return {"integral": z, "rate": z}

    def _error(self, t, state):
        i = np.asarray(self.hinges) - 1
        r, rd = _reference(self.reference_fn, self.reference_value, t, self.hinges, state.gamma.dtype)
        return state.gamma[i] - r, state.gamma_dot[i] - rd

    def torque(self, t, state, z, params):
        e, _ = self._error(t, state)
        dt = e.dtype
        tau = -self.kp.astype(dt) * e - self.ki.astype(dt) * z["integral"] - self.kd.astype(dt) * z["rate"]
        return hinge_torque_vector(self.n, self.hinges, tau)

    def rate(self, t, state, z, params):
        e, ed = self._error(t, state)
        return {"integral": e, "rate": (ed - z["rate"]) / self.filter_time.astype(e.dtype)}


class LawSum(eqx.Module):
    """Several hinge laws ``tau(t, state, params)`` side by side: their torques add."""

    laws: tuple

    def __call__(self, t, state: State, params=None):
        tau = self.laws[0](t, state, params)
        for law in self.laws[1:]:
            tau = tau + law(t, state, params)
        return tau


class ControllerGroup(AbstractController):
    """Several controllers side by side: internal states a tuple (one entry per controller),
    torques that add."""

    parts: tuple[AbstractController, ...]

    def initial(self):
        return tuple(c.initial() for c in self.parts)

    def torque(self, t, state, z, params):
        tau: Any = self.parts[0].torque(t, state, z[0], params)
        for c, zc in zip(self.parts[1:], z[1:]):
            tau = tau + c.torque(t, state, zc, params)
        return tau

    def rate(self, t, state, z, params):
        return tuple(c.rate(t, state, zc, params) for c, zc in zip(self.parts, z))


def with_model_laws(model, law, controller):
    """The hinge law and controller of a run: the model's own (``model.law``,
    ``model.controller``, from its scene) and those given to :func:`jaxtree.simulate`, side by
    side (the model's first)."""
    laws = [x for x in (getattr(model, "law", None), law) if x is not None]
    ctrls = [x for x in (getattr(model, "controller", None), controller) if x is not None]
    law = None if not laws else laws[0] if len(laws) == 1 else LawSum(tuple(laws))
    controller = None if not ctrls else ctrls[0] if len(ctrls) == 1 else ControllerGroup(tuple(ctrls))
    return law, controller
