"""The cost model of ``solver="auto"`` (its rule is :mod:`.autosolver`'s text): the measured
constants (steps per radian of each method, a Radau5 step's cost in Dopri8 steps, the slow
motion's factor), Dopri8's stability region from its tableau, and the steps each method is
predicted over a run from the linearized right side (:func:`predict_steps`: the modes, their
amplitudes in tolerances, the slow motion). numpy only; the constants are measured by
``benchmarks/bench_auto.py``.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import diffrax as dfx
import numpy as np

# Dopri8's stability region as the step-size controller meets it: |h lambda| up to r(arg lambda),
# from Dopri8's own Butcher tableau (:func:`stability_radius`: 3.7 on the imaginary axis, 5.1-5.5
# from 95 to 180 degrees). Measured: the fast rotor's 15 300 steps (5650 rad/s, gyroscopic: r 3.7),
# flex95's 900 (r 4.8), stiff_1e2's 295 (damping ratio 0.7: r 5.1). R_STABILITY is the screen's
# (no angle known there).
R_STABILITY = 3.0
# Steps per radian of a mode whose amplitude is `a` tolerances: C a^(1/order) (a harmonic
# oscillator, rtol = atol from 1e-3 to 1e-8, amplitudes 1 and 1e-2: within 15 % of both fits).
C_EXPLICIT, ORDER_EXPLICIT = 0.17, 8.0
C_IMPLICIT, ORDER_IMPLICIT = 0.27, 4.0
# A Radau5 step in Dopri8 steps, RHO_BASE + size / RHO_SIZE for a state of `size` (run time per
# step, both methods in one quiet run of benchmarks/bench_auto.py, 2026-11-27: 1.0-1.25 on fig4_free,
# wings, the stiff chains and the fast rotor, size 23-27; 2.4 on flex95, 195; 2.6 on wings4, 167:
# its Jacobian's columns and factorizations grow with the state, Dopri8's twelve right sides less
# so). The hybrid models: RHO_HYBRID (0.97 on flex95's, 1.06 on wings4's).
RHO_BASE, RHO_SIZE = 1.0, 130.0
RHO = 1.5  # at a state of 65
RHO_HYBRID = 1.0


def rho(size: int) -> float:
    """A Radau5 step's run time in Dopri8 steps for a state of `size` (see :data:`RHO_BASE`)."""
    return RHO_BASE + max(int(size), 1) / RHO_SIZE


# Radians of slow motion per unit of the right side's relative total variation (flex95's slew:
# two tanh edges, Radau5's 31 steps at rtol 1e-4 and 146 at 1e-6).
SLOW_FACTOR = 6.0
# Radau5's real eigenvalue of A^-1 (its error estimate's filter, (I - h J / GAMMA)^-1).
GAMMA = 3.6378


@functools.cache
def _stability_table() -> tuple[np.ndarray, np.ndarray]:
    """Dopri8's stability radius r(theta) every 2 degrees from 90 to 180: the least |z| on
    the ray z = r e^(i theta) where its stability function |R(z)| exceeds 1 + 1e-6 (Hairer and
    Wanner's R(z) = 1 + z b^T (I - z A)^-1 1 of diffrax's tableau; the 1e-6 passes the excess of
    order |z|^9 that an order-8 method has along the imaginary axis near 0)."""
    tableau = dfx.Dopri8.tableau
    s = len(tableau.b_sol)
    a = np.zeros((s, s))
    for i, row in enumerate(tableau.a_lower):
        a[i + 1, : len(row)] = np.asarray(row, float)
    b = np.asarray(tableau.b_sol, float)
    one = np.ones(s)
    grid = np.linspace(0.0, 8.0, 401)[1:]
    angles = np.radians(np.arange(90, 181, 2))
    radii = np.empty(len(angles))
    for k, theta in enumerate(angles):
        z = grid * np.exp(1j * theta)
        stages = np.linalg.solve(
            np.eye(s)[None] - z[:, None, None] * a[None], np.broadcast_to(one, (len(z), s))[..., None]
        )
        gain = np.abs(1 + z * (stages[..., 0] @ b))
        bad = np.nonzero(gain > 1 + 1e-6)[0]
        radii[k] = grid[bad[0] - 1] if len(bad) and bad[0] > 0 else grid[-1]
    return angles, radii


def stability_radius(lam) -> np.ndarray:
    """Dopri8's largest stable ``|h lambda|`` along the direction of each eigenvalue (growing
    modes, Re lambda > 0, as the imaginary axis)."""
    angles, radii = _stability_table()
    theta = np.clip(np.abs(np.angle(np.asarray(lam, complex))), np.pi / 2, np.pi)
    return np.interp(theta, angles, radii)


class Prediction(NamedTuple):
    """Steps predicted for a run (:func:`predict_steps`): `explicit` Dopri8's, `stability` the
    part of them its stability alone forces, `implicit` Radau5's; `fastest` the largest
    ``|lambda|``; `resolved` the modes either method must follow over the run (count) and
    `resolved_fastest` the fastest of them (rad/s, 0 without one)."""

    explicit: float
    stability: float
    implicit: float
    fastest: float
    resolved: int
    resolved_fastest: float


def modal_amplitudes(A, F, ts, y0, rtol: float, atol: float):
    """Eigenvalues of `A` and how far each mode rings over the run, in tolerances (see
    :mod:`.autosolver`'s text): ``(lambda, a, g)`` with ``a`` at most ``1 / rtol`` and ``g`` the
    modal forcing samples ``V^-1 f(t_j, y0)`` (shape ``(len(ts), len(lambda))``). `F` holds
    ``f(t_j, y0)`` at the times `ts`. numpy."""
    A = np.asarray(A, float)
    F = np.atleast_2d(np.asarray(F, float))
    ts = np.asarray(ts, float)
    lam, V = np.linalg.eig(A)  # finite A (the callers check)
    try:
        g = np.linalg.solve(V, F.T.astype(complex)).T
    except np.linalg.LinAlgError:  # defective A: its least-squares modal content
        g = np.linalg.lstsq(V, F.T.astype(complex), rcond=None)[0].T
    mag = np.abs(lam)
    tiny = np.finfo(float).tiny
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        start = np.abs(g[0]) / mag
        change = 2 * np.abs(g - g[0]).max(axis=0) / mag
        if len(ts) > 1:
            dt = np.diff(ts)[:, None]
            slope = np.abs(np.diff(g, axis=0) / np.where(dt == 0, np.inf, dt)).max(axis=0)
            change = np.minimum(change, slope / mag**2)
        z = np.nan_to_num(start + change, nan=np.inf, posinf=np.inf)
    scale = atol + rtol * np.abs(np.asarray(y0, float))
    reach = (np.abs(V) / np.maximum(scale, tiny)[:, None]).max(axis=0)
    with np.errstate(invalid="ignore", over="ignore"):
        a = np.nan_to_num(z * reach, nan=np.inf, posinf=np.inf)
    return lam, np.minimum(a, 1.0 / rtol), g


def slow_radians(F, y0, rtol: float, atol: float, span: float) -> float:
    """Radians of slow motion that a run must follow: :data:`SLOW_FACTOR` per unit of the total
    variation of ``f(t_j, y0)`` over the samples (each component relative to its largest value,
    components below the tolerance left out), at least one."""
    F = np.atleast_2d(np.asarray(F, float))
    if F.shape[0] < 2:
        return 1.0
    scale = atol + rtol * np.abs(np.asarray(y0, float))
    top = np.abs(F).max(axis=0)
    keep = top > scale
    if not np.any(keep):
        return 1.0
    steps = np.abs(np.diff(F[:, keep], axis=0)) / top[keep]
    return max(1.0, SLOW_FACTOR * float(steps.max(axis=1).sum()))


def mode_steps(lam, a, span: float, order: float, c: float) -> np.ndarray:
    """Steps each mode asks of a method of error order `order` (``c a^(1/order)`` per radian)
    while it rings above the tolerance: a mode that decays at ``sigma = -Re lambda`` from ``a``
    tolerances rings until ``ln(a) / sigma``, and its steps per radian fall with its amplitude:
    ``|lambda| c (order / sigma) (a^(1/order) - 1)`` when that is within the run, else
    ``|lambda| c a^(1/order) (order / sigma) (1 - exp(-sigma span / order))`` (``span`` times
    it without decay)."""
    mag = np.abs(lam)
    sigma = np.maximum(-np.real(lam), 0.0)
    root = a ** (1 / order)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ends = sigma * span >= np.log(np.maximum(a, 1.0))
        decayed = (order / sigma) * (root - 1.0)
        partial = root * (order / sigma) * -np.expm1(-sigma * span / order)
        time = np.where(sigma > 0, np.where(ends, decayed, partial), span * root)
    return np.where(a > 1.0, mag * c * np.nan_to_num(time, nan=0.0, posinf=0.0), 0.0)


def predict_steps(A, F, ts, y0, rtol: float, atol: float, span: float) -> Prediction:
    """Dopri8's and Radau5's steps over a run of `span` seconds (:mod:`.autosolver`'s text): `A`
    the Jacobian of the right side at `y0`, `F` the right side at `y0` at the times `ts`. numpy."""
    span = abs(float(span))
    lam, a, _ = modal_amplitudes(A, F, ts, y0, rtol, atol)
    mag = np.abs(lam)
    fastest = float(mag.max(initial=0.0))
    top = 1.0 / rtol
    slow = slow_radians(F, y0, rtol, atol, span)
    e_modes = mode_steps(lam, a, span, ORDER_EXPLICIT, C_EXPLICIT)
    i_modes = mode_steps(lam, a, span, ORDER_IMPLICIT, C_IMPLICIT)
    stability = span * float((mag / stability_radius(lam)).max(initial=0.0))
    explicit = max(stability, slow * C_EXPLICIT * top ** (1 / ORDER_EXPLICIT) + float(e_modes.max(initial=0.0)))
    # Radau5's error estimate passes a mode through (I - h J / GAMMA)^-1: at a step h it sees
    # a mode of amplitude a as a / max(1, h |lambda| / GAMMA), and follows it only above one.
    i_slow = slow * C_IMPLICIT * top ** (1 / ORDER_IMPLICIT)
    implicit = i_slow
    for _ in range(8):
        seen = a > np.maximum(1.0, span / max(implicit, 1.0) * mag / GAMMA)
        new = i_slow + float(i_modes[seen].max(initial=0.0))
        if new <= implicit * (1 + 1e-9):
            break
        implicit = new
    resolved = (i_modes > 0) & (a > np.maximum(1.0, span / max(implicit, 1.0) * mag / GAMMA))
    return Prediction(
        explicit, stability, implicit, fastest, int(resolved.sum()), float(mag[resolved].max(initial=0.0))
    )


def least_implicit_steps(rtol: float) -> float:
    """The fewest steps :func:`predict_steps` can give Radau5: one slow radian at the tolerance."""
    return SLOW_FACTOR * C_IMPLICIT * (1.0 / rtol) ** (1 / ORDER_IMPLICIT)
