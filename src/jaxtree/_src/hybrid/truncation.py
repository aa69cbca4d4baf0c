"""The error of the modes a hybrid model leaves out (not in the seed; :func:`jaxtree.simulate_hybrid`'s
``truncation`` histories): the generalized force that the hybrid motion leaves unbalanced on the
small rows of Eq. (1) (:func:`small_unbalanced`, the mode-acceleration method; a finite-element
appendage's on its interface, :func:`appendage_unbalanced`) drives each neglected mode's equation
``q_j' = lambda_j q_j + d_j . f`` (:class:`~.model.Truncation`, from the modes of Eq. 42),
solved exactly for that force interpolated linearly between the save times
(:func:`truncation_estimate`), from the start's content of the mode (:func:`truncation_start`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..equations.dynamics import unbalanced
from .model import HybridModel
from .rhs import equations_of_parts, solve


def small_unbalanced(hm: HybridModel, t, y):
    """The generalized force on the small rows left unbalanced by the hybrid motion at ``(t, y)``:
    ``rhs - A x`` of Eq. (1) at the physical state and the hybrid's accelerations (the inertia
    loads of the base's motion and of the retained modes, springs, velocity products, loads). Its
    part along the retained modes is balanced by their equations (to second order); the rest
    drives the neglected modes (mode-acceleration method)."""
    model = hm.model
    wd, gddL, acc = solve(hm, t, hm.unpack(y))
    _, _, gL, gdL, _ = hm.unpack(y)
    _, _, gddP = hm.large_configuration(t, gL, gdL)
    dtype = y.dtype
    gdd = jnp.zeros(model.n, dtype)
    gdd = gdd.at[np.asarray(hm.large, np.int64) - 1].set(gddL)
    gdd = gdd.at[np.asarray(hm.small, np.int64) - 1].set(hm.accel[: hm.nu] @ (acc * hm.keep_u().astype(dtype)))
    if gddP is not None:
        gdd = gdd.at[np.asarray(model.prescribed, np.int64) - 1].set(gddP)
    f = unbalanced(model, hm.state(t, y), t, None, wd, gdd)
    return f[np.asarray(hm.small, np.int64) + 2]


def appendage_unbalanced(hm: HybridModel, t, y):
    """The unbalanced generalized force ``rhs - A x`` of Eq. (30) on the appendages' held-interface
    coordinates at ``(t, y)``, the accelerations those of the hybrid model: the rows of its
    :attr:`HybridModel.physical` model (Eq. 30 in the small coordinates themselves) at the small
    motion that the retained modes make (zero when every mode is retained)."""
    ph = hm.physical
    assert ph is not None, "built by hybrid_model for a model with appendages"
    parts = hm.unpack(y)
    att, w, gL, gdL, s = parts
    dtype = w.dtype
    wd, gddL, acc = solve(hm, t, parts)
    km = hm.keep_m().astype(dtype)
    s_in = s * km
    if hm.form == "real":
        ds = jnp.concatenate([s_in[hm.n_modes :], acc * hm.keep.astype(dtype)])
    else:
        ds = acc * km
    ns = hm.n_small
    P = ph.positions[:, :ns]  # the physical model's coordinates: a permutation of the small ones
    y_, yd_, ydd_ = (P.T @ (m @ v) for m, v in ((hm.positions, s_in), (hm.rates, s_in), (hm.rates, ds)))
    mat, rhs = equations_of_parts(ph, t, (att, w, gL, gdL, jnp.concatenate([y_, yd_])))
    r = mat @ jnp.concatenate([wd, gddL, ydd_]) - rhs
    return -(P @ r[3 + len(hm.large) :])[hm.nu :]


def truncation_estimate(hm: HybridModel, t0, ts, ys, q_start, appendages: bool = False):
    """``(dynamic (T, nu), static (T, nu), q at the last save time (N, 2))``: the neglected modes'
    contribution to the small angles at the save times, driven by :func:`small_unbalanced` (see
    :func:`simulate_hybrid`). The force is interpolated linearly between save times (held at its
    first value from `t0` to the first save time) and each neglected mode's equation solved
    exactly on that interpolation, from `q_start` (N, 2) (real and imaginary parts: the
    start's content of each mode, :func:`truncation_start`, or a previous run's end)."""
    tr = hm.appendage_truncation if appendages else hm.truncation
    assert tr is not None, "called for a model built by hybrid_model"
    dtype = ys.dtype
    force = appendage_unbalanced if appendages else small_unbalanced
    f = jax.vmap(lambda t, y: force(hm, t, y))(ts, ys)  # (T, nu)
    w = tr.weights(hm.keep.astype(dtype))
    lam = tr.lam
    g = f.astype(lam.dtype) @ tr.d.T  # (T, N) modal forces
    static = jnp.real((g * (w / -lam)) @ tr.c.T)
    times = jnp.concatenate([jnp.reshape(t0, (1,)).astype(dtype), ts])
    G = jnp.concatenate([g[:1], g], 0)
    h = jnp.diff(times)[:, None].astype(lam.dtype)  # (T, 1)
    z = lam * h
    small = jnp.abs(z) < 1e-3
    safe_lam = jnp.where(small, 1.0, lam)
    safe_z = jnp.where(small, 1.0, z)
    e = jnp.exp(z)
    p1 = jnp.where(small, h * (1 + z / 2 + z * z / 6), (e - 1) / safe_lam)  # int_0^h e^{lam (h-s)} ds
    p2 = jnp.where(small, h * (0.5 + z / 6 + z * z / 24), (e - 1 - z) / (safe_lam * safe_z))  # ... s / h ds

    def step(q, k):
        e_k, a_k, b_k, g0, g1 = k
        q = e_k * q + g0 * a_k + (g1 - g0) * b_k
        return q, q

    q0 = jax.lax.complex(q_start[:, 0], q_start[:, 1])
    q_end, qs = jax.lax.scan(step, q0, (e, p1, p2, G[:-1], G[1:]))
    dynamic = jnp.real((qs * w) @ tr.c.T)
    return dynamic, static, jnp.stack([jnp.real(q_end), jnp.imag(q_end)], -1)


def truncation_histories(hybrid: HybridModel, t0, ts, ys, q_start, dtype):
    """``(truncation, truncation_static, truncation_state, appendage_truncation)`` of a run's
    saved states (:func:`truncation_estimate`; None where the model has no such terms)."""
    dyn = stat = q_end = app = None
    if hybrid.truncation is not None:
        dyn, stat, q_end = truncation_estimate(hybrid, t0, ts, ys, q_start)
    if hybrid.appendage_truncation is not None:
        n_app = hybrid.appendage_truncation.lam_parts.shape[0]
        app, _, _ = truncation_estimate(hybrid, t0, ts, ys, jnp.zeros((n_app, 2), dtype), appendages=True)
    return dyn, stat, q_end, app


def truncation_start(hybrid: HybridModel, x0):
    """Every mode's content ``d0 x0`` of a small motion ``x0 = [y; y']`` (real and imaginary
    parts, (N, 2)), or None for a model without truncation terms."""
    if hybrid.truncation is None:
        return None
    q = hybrid.truncation.d0 @ x0.astype(hybrid.truncation.lam.dtype)
    return jnp.stack([jnp.real(q), jnp.imag(q)], -1)
