"""Hinge bookkeeping: the subsets of the n hinges that the seed's equations treat apart, and the
state completed with its prescribed hinges.

- the *prescribed* hinges (Sec. II B): their angles, rates and accelerations are given functions
  of time, moved to the right side of Eq. (1) and left out of the state (Eq. 25);
- the *inert* hinges: only massless bodies outboard, no law: they drop out of Eq. (1) (zero
  acceleration);
- the *unknowns* of Eq. (1): all others;
- the set A of *small* hinges (Eq. 29) and its complement, the large hinges (Eqs. 30, 105).

Hinges are numbered 1..n as in the seed (hinge k joins body k to its parent); the index arrays
here are 0-based numpy arrays, static at trace time. A subset enters traced code by a constant
*selector* matrix (``gamma = E @ gamma_subset``, no scatter) or by one concatenation and a static
permutation (:func:`order`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .model import Model, State


def index(hinges) -> np.ndarray:
    """0-based int64 indices of 1-based hinge numbers."""
    return np.asarray(hinges, dtype=np.int64).reshape(-1) - 1


def selector(n: int, hinges, dtype=None):
    """The constant n x len(hinges) matrix E with ``gamma = E @ gamma_hinges`` (numpy, or a JAX
    array of `dtype`)."""
    E = np.zeros((n, len(hinges)))
    E[index(hinges), np.arange(len(hinges))] = 1.0
    return E if dtype is None else jnp.asarray(E, dtype)


def order(*subsets) -> np.ndarray:
    """The permutation that puts the concatenation of `subsets` (1-based hinge tuples that
    partition 1..n) back in hinge order: ``concatenate(parts)[order(...)]``."""
    return np.argsort(np.concatenate([index(s) for s in subsets]))


def split(model: Model):
    """Unknowns, prescribed (0-based) and the permutation that puts ``[unknowns, prescribed,
    inert]`` back in hinge order."""
    return (
        index(model.unknown_hinges),
        index(model.prescribed),
        order(model.unknown_hinges, model.prescribed, model.inert),
    )


def free_hinges(model: Model) -> tuple[int, ...]:
    """The hinges in a simulation's state (Eq. 25): all but the prescribed ones."""
    p = set(model.prescribed)
    return tuple(k for k in range(1, model.n + 1) if k not in p)


def prescribed_motion(model: Model, t, dtype):
    """``(gamma_P, gamma_dot_P, gamma_ddot_P)`` of the prescribed hinges at time t, or None."""
    if model.prescription is None:
        return None
    return tuple(x.astype(dtype) for x in model.prescription.derivatives(jnp.asarray(t, dtype)))


def complete(model: Model, t, state: State, dtype=None):
    """`state` with its prescribed hinges' angles and rates replaced by the prescription at time
    t, and their accelerations (None without a prescription): one evaluation of the
    prescription."""
    dtype = jnp.result_type(state.gamma) if dtype is None else dtype
    motion = prescribed_motion(model, t, dtype)
    if motion is None:
        return state, None
    g, gd, gdd = motion
    keep = free_hinges(model)
    perm = order(keep, model.prescribed)
    k = index(keep)
    merge = lambda full, pres: jnp.concatenate([full.astype(dtype)[k], pres])[perm]
    return state._replace(gamma=merge(state.gamma, g), gamma_dot=merge(state.gamma_dot, gd)), gdd


def from_free(model: Model, t, gamma_u, gamma_dot_u):
    """All n hinge angles and rates from those of the free hinges (:func:`free_hinges`, the
    simulation's state) and the prescription at time t, with the prescribed accelerations
    (None without a prescription): one evaluation of the prescription."""
    motion = prescribed_motion(model, t, gamma_u.dtype)
    if motion is None:
        return gamma_u, gamma_dot_u, None
    g, gd, gdd = motion
    perm = order(free_hinges(model), model.prescribed)
    return jnp.concatenate([gamma_u, g])[perm], jnp.concatenate([gamma_dot_u, gd])[perm], gdd
