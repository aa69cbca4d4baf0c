"""The solver that a run needs: the cheaper of an explicit and an implicit method at the
requested accuracy, predicted from the linearized equations (Eq. 42 in first-order form).

``simulate(..., solver="auto")`` (the default) and ``simulate_hybrid(..., solver="auto")`` call
this module. Both candidates are predicted a number of steps; the cheaper wins:

- **Dopri8** (explicit, order 8): ``N_e = max(stability, accuracy)``. Stability bounds its step
  by ``|h lambda| <= r(arg lambda)`` for *every* eigenvalue, whatever the mode's amplitude (r from
  Dopri8's tableau, 3.7 on the imaginary axis to 5.5): ``span max |lambda| / r`` steps. Accuracy
  asks ``C_E a^(1/8)`` steps per radian of every mode whose amplitude ``a`` (in units of the
  tolerance) is above one, and of the slow motion.
- **Radau5** (:class:`jaxtree.Radau5`, implicit, L-stable, its error estimate of local order 4):
  ``N_i`` = ``C_I a^(1/4)`` steps per radian of the same modes and motion only. An L-stable
  method steps over a fast mode whose amplitude is below the tolerance (it follows the mode's
  quasi-static part, and damps the rest), which an explicit method can never do. Its error
  estimate passes a mode through ``(I - h J / GAMMA)^-1``: at a step ``h`` it follows a mode only
  where ``a > max(1, h |lambda| / GAMMA)`` (a fixed point in ``h = span / N_i``).

A Radau5 step costs ``rho = RHO_BASE + size / RHO_SIZE`` Dopri8 steps for a state of ``size``
(its Newton iterations, Jacobian and factorizations against Dopri8's 12 right sides: about one
step for small states, 2.5 at 200; :data:`RHO_HYBRID` for the hybrid model): Radau5 is chosen
when ``rho N_i < N_e``.

**The modes and their amplitudes.** ``A = d f / d y`` is the Jacobian of the run's own
first-order right side at the initial state (the one :class:`jaxtree.Radau5` uses: attitude
variables, rates, the hinge laws and loads included; the hybrid model's for
:func:`jaxtree.simulate_hybrid`), ``A = V diag(lambda) V^-1``. About the initial state
``y0`` the modal coordinates ``z = V^-1 (y - y0)`` obey ``z' = lambda z + g(t)``,
``g = V^-1 f(t, y0)``, sampled at :data:`SAMPLES` times over the run. For :func:`jaxtree.simulate`
``A`` comes from central differences of Eq. (1)'s matrix and right side (one vmapped program, no
solve), its acceleration rows ``M^-1 d(rhs)/dy`` with Eq. (1)'s accelerations held
(:func:`equation_jacobian_and_samples`: a preloaded stiff spring would otherwise show real
eigenvalues of either sign that its snap erases within microseconds). A mode that starts at
rest under a slowly varying ``g`` follows its quasi-static value ``-g/lambda``; it rings at

    |z| ~ |g(t0)| / |lambda| + min(2 max|g(t) - g(t0)| / |lambda|, max|g'| / |lambda|^2),

the first term the start away from equilibrium (an initial rate, a preloaded spring, a load on
at ``t0``), the second the load's changes (a jump: twice the static change; a ramp: the lag of
the quasi-static response). In units of the tolerance ``a = |z| max_i |V_ik| / (atol + rtol
|y0_i|)``, at most ``1 / rtol``. A mode that rings below the tolerance (``a <= 1``) is not
followed; one that decays (``sigma = -Re lambda > 0``) is followed until ``ln(a) / sigma``, at
fewer steps per radian as it fades (:func:`_radians`).

**The slow motion.** Both methods also follow the motion that the modes do not describe (the
rigid motion under a load's edges, a spin): ``SLOW_FACTOR`` radians per unit of the total
variation of ``f(t, y0)`` over the run (each component relative to its largest value), at
``a = 1 / rtol``, at least one radian over the span.

The constants are measured (``benchmarks/bench_auto.py``): ``C_E``, ``C_I`` on a harmonic
oscillator (Dopri8 0.17 a^(1/8), Radau5 0.27 a^(1/4) steps per radian, rtol 1e-3 ... 1e-8);
``rho`` from the per-step times of both methods on the stiff chains, flex95 and the hybrid
models; ``SLOW_FACTOR`` from flex95's slew.

A **screen** comes first, since the Jacobian costs a compilation (and its tracing, every
process): when even ``SCREEN_MARGIN`` times the fastest rate that the scene shows without it (each
sprung hinge's spring against its body's inertia about the hinge line, each hinge's and the bus's
initial rate) holds Dopri8 to fewer steps than Radau5's least (one slow radian at the tolerance,
or the sprung hinges that start away from rest ringing at a third of their own frequency),
Dopri8 is chosen unseen.

The choice needs concrete values: under ``jax.jit`` / ``jax.vmap`` / ``jax.grad`` (traced
model, state, times or tolerance) ``"auto"`` is Dopri8. It predicts run time, not compilation
(Radau5's program compiles several times longer than Dopri8's). A solver that the user passes
is always used as is.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import diffrax as dfx
import equinox as eqx
import jax
import numpy as np

from ..numerics import is_traced, program_jit
from ..vehicle.model import Model, State
from .core import default_tolerance
from .radau import Radau5

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
# Times at which the right side is sampled over the run (the load's edges and its changes).
SAMPLES = 128
# The screen's margins over the rates it sees without the Jacobian: a hinge law's own rate, and
# a spin (a rotor's nutation is at most (axial / transverse inertia) x its spin, below 2).
SCREEN_MARGIN = 10.0
SPIN_MARGIN = 2.0


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


class SolverChoice(eqx.Module):
    """What ``solver="auto"`` picked and why (``sol.stats["solver"]``).

    Static fields only: it passes through ``jax.jit`` and ``jax.vmap`` as structure.
    `name` the diffrax solver's class name; `auto` whether it was chosen automatically;
    `reason` one sentence; `fastest` the largest ``|lambda|`` found (rad/s; the screen's fastest
    hinge law when it decided without linearizing; NaN when not estimated); `explicit_steps`,
    `implicit_steps` the steps predicted for Dopri8 and Radau5 over the span (NaN when not
    predicted).
    """

    name: str = eqx.field(static=True)
    auto: bool = eqx.field(static=True)
    reason: str = eqx.field(static=True)
    fastest: float = eqx.field(static=True, default=math.nan)
    explicit_steps: float = eqx.field(static=True, default=math.nan)
    implicit_steps: float = eqx.field(static=True, default=math.nan)

    def __str__(self) -> str:
        return f"{self.name} ({'auto' if self.auto else 'given'}): {self.reason}"


def _sprung_hinge_laws(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per sprung hinge: its index (0-based), the inertia J of its own body about the hinge line
    (parallel axes through the hinge point; 0 for a massless body), its stiffness and damping."""
    i = np.asarray(model.sprung, np.int64) - 1
    axis = np.asarray(model.axis, float)[i]
    r = np.asarray(model.hinge_on_body, float)[i]
    J = np.einsum("ki,kij,kj->k", axis, np.asarray(model.inertia, float)[i + 1], axis)
    J = J + np.asarray(model.mass, float)[i + 1] * np.sum(np.cross(axis, r) ** 2, 1)
    return i, J, np.asarray(model.stiffness, float)[i], np.asarray(model.damping, float)[i]


def _local_rates(model: Model) -> np.ndarray:
    """Per sprung hinge, the largest |root| of ``J s^2 + c s + k`` (:func:`_sprung_hinge_laws`)."""
    if not model.sprung:
        return np.zeros(0)
    _, J, k, c = _sprung_hinge_laws(model)
    J = np.where(J > 0, J, np.finfo(float).tiny)  # a massless body: as fast as it gets
    disc = c * c - 4 * J * k
    over = np.sqrt(np.maximum(disc, 0.0))
    fast = np.where(disc >= 0, (c + over) / (2 * J), np.sqrt(np.maximum(k, 0.0) / J))
    return np.abs(fast)


def _ringing_hinges(model: Model, y0: State, span: float, rtol: float, atol: float) -> float:
    """A lower bound of Radau5's steps from the scene alone: each sprung hinge that starts away
    from its spring's rest (an angle, or a rate) rings at its own spring and damper against its
    body's inertia about the hinge line, ``lambda = -c/(2J) + i sqrt(k/J - (c/2J)^2)``, at an
    amplitude of ``max(|gamma|, |gamma_dot| / |lambda|)`` in tolerances of the angle; the tree's
    mode is within a small factor of it, so a third of its frequency is taken. 0 without one."""
    if not model.sprung:
        return 0.0
    i, J, k, c = _sprung_hinge_laws(model)
    ok = (J > 0) & (k > 0)
    J = np.where(ok, J, 1.0)
    sigma = c / (2 * J)
    wd = np.sqrt(np.maximum(k / J - sigma**2, 0.0))
    lam = -sigma + 1j * wd / 3.0
    g = np.abs(np.asarray(y0.gamma, float)[i])
    gd = np.abs(np.asarray(y0.gamma_dot, float)[i])
    amp = np.maximum(g, gd / np.maximum(np.abs(lam), np.finfo(float).tiny)) / (atol + rtol * g)
    amp = np.where(ok & (wd > 0), np.minimum(amp, 1.0 / rtol), 0.0)
    return float(_radians(lam, amp, span, ORDER_IMPLICIT, C_IMPLICIT).max(initial=0.0))


# Save points per period of the fastest retained hinge motion: at 4 a curve looks jagged, at 20
# it is smooth to the eye (and linear interpolation between them is within 1.2 % of a sine).
SAMPLES_PER_PERIOD = 20
# Fewer than this per period and a plot misses the motion's shape: the command line says so.
SAMPLES_LEAST = 8
# The default grid never exceeds this many points (a long run of a stiff tree): the command line warns.
MAX_SAVE_POINTS = 20001


def fastest_oscillation(model: Model, span: float) -> float:
    """The highest angular frequency (rad/s) of a sprung hinge that still rings during a run of
    `span` seconds: per sprung hinge, the damped frequency of its spring and damper against the
    inertia of its own body about the hinge line (the screen of :func:`choose_solver`, within a
    small factor of the tree's fastest mode), among those that do not die out in the first tenth
    of the run (to 1e-3). Zero without such a hinge. No JAX computation: numpy on the scene."""
    if not model.sprung:
        return 0.0
    _, J, k, c = _sprung_hinge_laws(model)
    ok = J > 0  # a massless body's hinge has no motion of its own
    J = np.where(ok, J, 1.0)
    decay = c / (2 * J)
    wd2 = k / J - decay**2
    rings = ok & (wd2 > 0) & (0.1 * abs(span) * decay < math.log(1e3))
    return float(np.sqrt(np.where(rings, wd2, 0.0)).max(initial=0.0))


def save_points(model: Model, span: float, *, least: int = 101) -> tuple[int, float]:
    """The default number of evenly spaced save times of a run of `span` seconds:
    :data:`SAMPLES_PER_PERIOD` per period of :func:`fastest_oscillation`, at least `least`, at
    most :data:`MAX_SAVE_POINTS`. Returns ``(points, that frequency in rad/s)``."""
    rate = fastest_oscillation(model, span)
    want = math.ceil(abs(span) * rate / (2 * math.pi) * SAMPLES_PER_PERIOD) + 1
    return int(min(max(least, want), MAX_SAVE_POINTS)), rate


def samples_per_period(points: int, span: float, rate: float) -> float:
    """Save intervals per period of an oscillation at `rate` rad/s (inf without one)."""
    if rate <= 0 or span == 0:
        return math.inf
    return (points - 1) * 2 * math.pi / (abs(span) * rate)


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
    """Eigenvalues of `A` and how far each mode rings over the run, in tolerances (see the
    module's text): ``(lambda, a, g)`` with ``a`` at most ``1 / rtol`` and ``g`` the modal
    forcing samples ``V^-1 f(t_j, y0)`` (shape ``(len(ts), len(lambda))``). `F` holds
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


def _radians(lam, a, span: float, order: float, c: float) -> np.ndarray:
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
    """Dopri8's and Radau5's steps over a run of `span` seconds (the module's text): `A` the
    Jacobian of the right side at `y0`, `F` the right side at `y0` at the times `ts`. numpy."""
    span = abs(float(span))
    lam, a, _ = modal_amplitudes(A, F, ts, y0, rtol, atol)
    mag = np.abs(lam)
    fastest = float(mag.max(initial=0.0))
    top = 1.0 / rtol
    slow = slow_radians(F, y0, rtol, atol, span)
    e_modes = _radians(lam, a, span, ORDER_EXPLICIT, C_EXPLICIT)
    i_modes = _radians(lam, a, span, ORDER_IMPLICIT, C_IMPLICIT)
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


def _unusable(A, F) -> SolverChoice | None:
    """The explicit default when the start gives no spectrum (a non-finite state or right side:
    the run then fails at its start, where jaxtree reports it), else None."""
    if np.all(np.isfinite(A)) and np.all(np.isfinite(F)):
        return None
    return SolverChoice("Dopri8", True, "the right side at the start is not finite: the explicit default")


def pick(prediction: Prediction, cost_ratio: float, linearized: str) -> tuple[dfx.AbstractSolver, SolverChoice]:
    """The cheaper solver of a :class:`Prediction` (Radau5 when ``cost_ratio N_i < N_e``, the ratio a
    Radau5 step's time over a Dopri8 step's), with its reason; `linearized` says what was linearized."""
    p = prediction
    steps = f"Dopri8 ~{p.explicit:.0f} steps, Radau5 ~{p.implicit:.0f} x {cost_ratio:.2g}"
    if p.resolved:
        modes = f"{p.resolved} mode(s) ring above the tolerance (to {p.resolved_fastest:.3g} rad/s)"
    else:
        modes = "no mode rings above the tolerance"
    stiff = p.stability >= 0.5 * p.explicit
    fast = f"the fastest at {p.fastest:.3g} rad/s" + (" holds Dopri8 by stability" if stiff else "")
    why = f"{linearized}: {modes}, {fast}; predicted {steps}"
    if cost_ratio * p.implicit < p.explicit:
        return Radau5(), SolverChoice("Radau5", True, "stiff, " + why, p.fastest, p.explicit, p.implicit)
    return dfx.Dopri8(), SolverChoice("Dopri8", True, why, p.fastest, p.explicit, p.implicit)


def screen_rate(model: Model, y0: State) -> float:
    """The fastest rate (rad/s) the scene shows without a Jacobian: :data:`SCREEN_MARGIN` times each
    sprung hinge's spring and damper against its body's inertia about the hinge line (a tree's
    fastest mode is within a small factor of it), and :data:`SPIN_MARGIN` times each hinge's and
    the bus's initial rate (a rotor's nutation, a spinning body's gyroscopic modes)."""
    local = _local_rates(model)
    rates = [SCREEN_MARGIN * float(local.max(initial=0.0))]
    rates.append(SPIN_MARGIN * float(np.abs(np.asarray(y0.gamma_dot, float)).max(initial=0.0)))
    rates.append(SPIN_MARGIN * float(np.linalg.norm(np.asarray(y0.omega0, float))))
    return max(rates)


@program_jit
def _field_batch(field, ts, ys, args):
    return jax.vmap(lambda t, y: field(t, y, args))(ts, ys)


# relative step of the central differences (about eps^(1/3): truncation and round-off balanced)
FD_STEP = 2.0**-18


def _differences(y):
    """The states ``y +- h_i e_i`` (2n, n) of the central differences and the steps `h`. numpy
    on the host (y is concrete here): a handful of JAX operations called one by one would each
    be compiled, in every process."""
    y = np.asarray(y)
    h = FD_STEP * np.maximum(np.abs(y), 1.0)
    return np.concatenate([y + np.diag(h), y - np.diag(h)]), np.asarray(h, float)


def jacobian_and_samples(field, t0, y, ts, args):
    """``d f / d y`` at ``(t0, y)`` by central differences and ``f(t_j, y)`` at the times `ts`,
    all from one vmapped program of the right side `field(t, y, args)` (cheaper to compile than a
    forward-mode Jacobian, and free of host callbacks, so the persistent cache keeps it). numpy."""
    n = np.shape(y)[0]
    ys, h = _differences(y)
    ts = np.asarray(ts)
    ys = np.concatenate([ys, np.broadcast_to(np.asarray(y), (ts.shape[0], n))])
    tt = np.concatenate([np.full(2 * n, t0, ts.dtype), ts])
    out = np.asarray(_field_batch(field, tt, ys, args), float)
    A = (out[:n] - out[n : 2 * n]).T / (2 * h)[None, :]
    return A, out[2 * n :]


def _equation_parts(t, y, problem):
    """At a flat state of `problem`: the attitude variables' rates, and Eq. (1)'s matrix and right
    side on the rows of ``omega0`` and the unknown hinges (prescribed accelerations moved to the
    right side; the hinge law's torque included). No solve."""
    import jax.numpy as jnp

    from ..equations.dynamics import rotational_equations
    from ..vehicle import hinges

    model = problem.model
    att, w, g_u, gd_u, z, _, _ = problem.unpack(y)
    gamma, gamma_dot, gdd_p = hinges.from_free(model, t, g_u, gd_u)
    state = State(problem.attitude.to_dcm(att), w, gamma, gamma_dot)
    tau = problem.torque(t, state, problem._unravel_control(z))
    M, rhs = rotational_equations(model, state, t, None if tau is None else jnp.asarray(tau, gamma.dtype))
    if gdd_p is not None:
        cols = 3 + np.asarray(model.prescribed, np.int64) - 1
        rhs = rhs - M[:, cols] @ gdd_p
    rows = np.concatenate([np.arange(3), 3 + np.asarray(model.unknown_hinges, np.int64) - 1])
    return problem.attitude.rate(att, w), M[np.ix_(rows, rows)], rhs[rows]


@program_jit
def _parts_batch(ts, ys, problem, base: int):
    kin, M, rhs = jax.vmap(lambda t, y: _equation_parts(t, y, problem))(ts, ys)
    return kin, M[base:], rhs


def equation_jacobian_and_samples(problem, t0, y, ts):
    """``(A, F)``: the Jacobian of `problem`'s right side at ``(t0, y)`` and the right side at
    ``y`` at the times `ts`, from one vmapped program of Eq. (1)'s matrix and right side (no
    solve; central differences of the right side). The rows of the accelerations are
    ``M^-1 d(rhs)/dy``: Eq. (1) with its current accelerations held, without ``-M^-1 (dM/dy)
    M^-1 rhs``. That term linearizes a vehicle that starts far from equilibrium (a preloaded stiff
    spring gives real eigenvalues of either sign, which the spring's snap erases within
    microseconds); Eq. (42) leaves it out too. The rows of a controller's states and of Eq. (2)
    are left zero. numpy."""
    n = np.shape(y)[0]
    m = len(ts)
    ys, h = _differences(y)
    ts = np.asarray(ts)
    ys = np.concatenate([ys, np.broadcast_to(np.asarray(y), (m, n))])
    tt = np.concatenate([np.full(2 * n, t0, ts.dtype), ts])
    kin, M, rhs = (np.asarray(x, float) for x in _parts_batch(tt, ys, problem, 2 * n))
    two_h = (2 * h)[None, :]
    o = problem._offsets()
    nu = problem.n_unknown
    acc_rows = np.concatenate([np.arange(o[1], o[2]), o[3] + hinges_free_positions(problem)])
    A = np.zeros((n, n))
    A[o[0] : o[1]] = (kin[:n] - kin[n : 2 * n]).T / two_h
    A[acc_rows] = np.linalg.solve(M[0], (rhs[:n] - rhs[n : 2 * n]).T / two_h)
    A[np.arange(o[2], o[3]), np.arange(o[3], o[3] + nu)] = 1.0
    F = np.zeros((m, n))
    F[:, o[0] : o[1]] = kin[2 * n :]
    F[:, o[2] : o[3]] = np.asarray(y, float)[o[3] : o[4]]
    F[:, acc_rows] = np.linalg.solve(M, rhs[2 * n :][..., None])[..., 0]
    return A, F


def hinges_free_positions(problem) -> np.ndarray:
    """Positions of the unknown hinges among the problem's free hinges (its state's hinges)."""
    free = list(problem.free_hinges)
    return np.asarray([free.index(k) for k in problem.model.unknown_hinges], np.int64)


def sample_times(t0: float, t1: float, dtype) -> np.ndarray:
    return np.linspace(t0, t1, SAMPLES).astype(dtype)


def choose_solver(
    model: Model,
    t1,
    *,
    t0: float | jax.Array = 0.0,
    y0: State | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    law=None,
    params=None,
) -> tuple[dfx.AbstractSolver, SolverChoice]:
    """The solver for a run of `model` from `t0` to `t1` at `rtol`, `atol` (see the module's
    text): ``(diffrax solver, SolverChoice)``, Dopri8 or :class:`jaxtree.Radau5`, whichever is
    predicted to reach the tolerance in less run time. `law` and `params` as in
    :func:`jaxtree.simulate` (the scene's own laws are added)."""
    from ..vehicle.validate import check_model

    model = check_model("choose_solver", model)
    return _choose(model, t1, t0, y0, rtol, atol, law, params)


def choose_checked(
    model: Model, t1, *, t0: float | jax.Array = 0.0, y0: State | None = None, rtol=None, atol=None, law=None,
    params=None, problem=None, y=None,
) -> tuple[dfx.AbstractSolver, SolverChoice]:  # fmt: skip
    """:func:`choose_solver` for a caller that has checked the model and `y0` (:func:`jaxtree.simulate`,
    which passes its `problem`, the right side the solver will integrate, its flat initial state
    `y` and its `law`, the scene's laws included)."""
    return _choose(model, t1, t0, y0, rtol, atol, law, params, problem, y)


def _choose(model: Model, t1, t0, y0, rtol, atol, law, params, problem=None, y=None):
    import jax.numpy as jnp

    y0 = model.initial if y0 is None else y0
    if is_traced((model, y0, t0, t1, rtol, atol, params)):
        return dfx.Dopri8(), SolverChoice("Dopri8", True, "traced inputs (jit/vmap/grad): the explicit default")
    dtype = jnp.result_type(model.mass)
    rtol = default_tolerance(dtype) if rtol is None else rtol
    atol = rtol if atol is None else atol
    if np.size(rtol) != 1 or np.size(atol) != 1:
        return dfx.Dopri8(), SolverChoice("Dopri8", True, "several tolerances: the explicit default")
    rtol, atol = float(np.ravel(rtol)[0]), float(np.ravel(atol)[0])
    span = abs(float(t1) - float(t0))
    rate = screen_rate(model, y0)
    laws = law is not None or model.law is not None or model.controller is not None
    size = 2 * len(model.unknown_hinges) + 7
    least = max(least_implicit_steps(rtol), _ringing_hinges(model, y0, span, rtol, atol))
    if not laws and span * rate / R_STABILITY < rho(size) * least:
        why = (
            "nothing in the scene moves or rings fast enough to make the run stiff"
            if rate == 0.0
            else f"no hinge law or rate is near stiff over {span:g} s (at most {rate:.3g} rad/s with margins)"
        )
        local = float(_local_rates(model).max(initial=0.0))  # the screen's own estimate, no margin
        return dfx.Dopri8(), SolverChoice("Dopri8", True, why, local, span * rate / R_STABILITY)
    from .problem import make_problem, packed_start

    if problem is None:
        from ..equations.attitude import get_attitude
        from ..equations.control import with_model_laws

        law, controller = with_model_laws(model, law, None)
        problem = make_problem(model, get_attitude("quaternion"), law, controller, params, False)
    y = packed_start(problem, y0) if y is None else y
    ts = sample_times(float(t0), float(t1), dtype)
    try:
        A, F = equation_jacobian_and_samples(problem, float(t0), y, ts)
    except np.linalg.LinAlgError:  # Eq. (1)'s matrix singular at the start: simulate reports it
        return dfx.Dopri8(), SolverChoice("Dopri8", True, "Eq. (1) is singular at the start: the explicit default")
    unusable = _unusable(A, F)
    if unusable is not None:
        return dfx.Dopri8(), unusable
    prediction = predict_steps(A, F, ts, y, rtol, atol, span)
    return pick(prediction, rho(np.shape(y)[0]), "linearized at the initial state")


def choose_for_field(field, args, y, t0, t1, *, rtol, atol, cost_ratio: float = RHO_HYBRID, what: str = "linearized"):
    """The cheaper of Dopri8 and Radau5 (the module's rule) for ``y' = field(t, y, args)`` from the
    flat state `y` at `t0` to `t1` (:func:`jaxtree.simulate_hybrid`: the hybrid right side), its
    Jacobian by central differences. Dopri8 when anything is traced."""
    import jax.numpy as jnp

    if is_traced((args, y, t0, t1, rtol, atol)):
        return dfx.Dopri8(), SolverChoice("Dopri8", True, "traced inputs (jit/vmap/grad): the explicit default")
    if np.size(rtol) != 1 or np.size(atol) != 1:
        return dfx.Dopri8(), SolverChoice("Dopri8", True, "several tolerances: the explicit default")
    y = jnp.asarray(y)
    rtol, atol = float(np.ravel(rtol)[0]), float(np.ravel(atol)[0])
    span = abs(float(t1) - float(t0))
    ts = sample_times(float(t0), float(t1), y.dtype)
    A, F = jacobian_and_samples(field, float(t0), y, ts, args)
    unusable = _unusable(A, F)
    if unusable is not None:
        return dfx.Dopri8(), unusable
    return pick(predict_steps(A, F, ts, y, rtol, atol, span), cost_ratio, what)


def given(solver) -> SolverChoice:
    """The record of a solver the user passed."""
    return SolverChoice(type(solver).__name__, False, "given by the caller")
