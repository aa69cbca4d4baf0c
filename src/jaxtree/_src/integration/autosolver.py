"""The solver that a run needs, from the time scales of its linearized equations (Eq. 42).

``simulate(..., solver="auto")`` (the default) calls :func:`choose_solver`: an explicit
Runge-Kutta method (Dopri8) unless the run is *stiff*, i.e. unless the linearized equations
at the initial state (Eq. 42's ``I y'' + J y' + K y = 0`` for every free hinge and the
attitude of b_0, :func:`jaxtree.linearize_vehicle`, plus the stiffness and damping of a
user's hinge law) have eigenvalues that

1. would hold an explicit method's step far below what the tolerance asks for: the steps
   that Dopri8's stability alone needs over the span, ``span max|lambda| / R_STABILITY``,
   exceed ``EXPLICIT_STEPS`` (scaled by ``(1e-6 / rtol)^(1/8)``: at tighter tolerances the
   accuracy itself needs more steps, and the stability limit matters less), and
2. die out: every such eigenvalue decays below the tolerance within the first tenth of the
   span (``0.1 span |Re lambda| >= ln(1 / rtol)``).

Then an L-stable implicit method (:class:`jaxtree.Radau5`, Radau IIA of order 5, which keeps its
Jacobian and factorizations over many steps; diffrax's Kvaerno5 forms and factors a new Jacobian
every step: 2.5-7x slower on the stiff chains) steps over the decayed modes at the step size the
slow motion needs. A fast mode that does *not* decay (an undamped hinge spring, a
rotor's nutation) must be resolved by any method, and an explicit one does it at a fraction
of an implicit step's cost: Dopri8 again. (Measured in ``benchmarks/results/work_precision``:
the stiff chains, the fast rotor.)

The full linearization costs seconds of compilation for large trees, so a screen comes
first: each sprung hinge's own time scale (its spring and damper against the inertia of its
body about the hinge line, within a small factor of the tree's fastest mode for the trees
of this field). When even ten times the screen's fastest rate is far from stiff, the
linearization is skipped.

The choice needs concrete values: under ``jax.jit`` / ``jax.vmap`` / ``jax.grad`` (traced
model, state, times or tolerance) ``"auto"`` is Dopri8. Controllers with internal states are
not part of the estimate. A solver that the user passes is always used as is.
"""

from __future__ import annotations

import math

import diffrax as dfx
import equinox as eqx
import jax
import numpy as np

from ..linear.linearize import linearize_vehicle, vehicle_linearization
from ..numerics import is_traced
from ..vehicle.model import Model, State
from .core import default_tolerance
from .radau import Radau5

# Dopri8's stability region reaches |h lambda| of about 3 on the directions that matter here
# (the stiff-hinge study of benchmarks/bench_stability.py: 29k steps over 1 s at 8.2e4 rad/s).
R_STABILITY = 3.0
# Explicit steps over the span, forced by stability, from which an implicit method pays (at
# rtol 1e-6; an implicit step with its Newton iterations and Jacobian costs 10-50 explicit ones).
EXPLICIT_STEPS = 2000.0
# The screen skips the linearization when its estimate x SCREEN_MARGIN is still this far from it.
SCREEN_MARGIN = 10.0


class SolverChoice(eqx.Module):
    """What ``solver="auto"`` picked and why (``sol.stats["solver"]``).

    Static fields only: it passes through ``jax.jit`` and ``jax.vmap`` as structure.
    `name` the diffrax solver's class name; `auto` whether it was chosen automatically;
    `reason` one sentence; `fastest` the largest ``|lambda|`` found (rad/s; NaN when not
    estimated); `explicit_steps` the steps an explicit method's stability needs over the span.
    """

    name: str = eqx.field(static=True)
    auto: bool = eqx.field(static=True)
    reason: str = eqx.field(static=True)
    fastest: float = eqx.field(static=True, default=math.nan)
    explicit_steps: float = eqx.field(static=True, default=math.nan)

    def __str__(self) -> str:
        return f"{self.name} ({'auto' if self.auto else 'given'}): {self.reason}"


def _local_rates(model: Model) -> np.ndarray:
    """Per sprung hinge, the largest |root| of ``J s^2 + c s + k`` with J the inertia of the
    hinge's own body about the hinge line (parallel axes through the hinge point)."""
    if not model.sprung:
        return np.zeros(0)
    i = np.asarray(model.sprung) - 1
    axis = np.asarray(model.axis, float)[i]
    r = np.asarray(model.hinge_on_body, float)[i]
    inertia = np.asarray(model.inertia, float)[i + 1]
    mass = np.asarray(model.mass, float)[i + 1]
    J = np.einsum("ki,kij,kj->k", axis, inertia, axis) + mass * np.sum(np.cross(axis, r) ** 2, 1)
    k = np.asarray(model.stiffness, float)[i]
    c = np.asarray(model.damping, float)[i]
    J = np.where(J > 0, J, np.finfo(float).tiny)  # a massless body: as fast as it gets
    disc = c * c - 4 * J * k
    over = np.sqrt(np.maximum(disc, 0.0))
    fast = np.where(disc >= 0, (c + over) / (2 * J), np.sqrt(np.maximum(k, 0.0) / J))
    return np.abs(fast)


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
    i = np.asarray(model.sprung) - 1
    axis = np.asarray(model.axis, float)[i]
    r = np.asarray(model.hinge_on_body, float)[i]
    J = np.einsum("ki,kij,kj->k", axis, np.asarray(model.inertia, float)[i + 1], axis)
    J = J + np.asarray(model.mass, float)[i + 1] * np.sum(np.cross(axis, r) ** 2, 1)
    k, c = np.asarray(model.stiffness, float)[i], np.asarray(model.damping, float)[i]
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


def _eigenvalues(model: Model, y0: State, t0, law, params, checked: bool) -> np.ndarray:
    """Eigenvalues of the first-order form of the linearized equations at `y0` (the model and
    `y0` checked by :func:`jaxtree.linearize_vehicle` unless `checked`)."""

    linearization = vehicle_linearization if checked else linearize_vehicle
    lin = linearization(model, omega0=y0.omega0, gamma=y0.gamma, dcm=y0.dcm, t=t0)
    I, J, K = (np.array(x, float) for x in (lin.I, lin.J, lin.K))  # writable copies
    if law is not None:
        hinges = np.asarray(lin.hinges[3:]) - 1

        def torque(g, gd):
            return law(t0, State(y0.dcm, y0.omega0, g, gd), params)

        dg, dgd = jax.jacfwd(torque, argnums=(0, 1))(y0.gamma, y0.gamma_dot)
        rows = 3 + np.arange(len(hinges))
        K[np.ix_(rows, rows)] -= np.asarray(dg, float)[np.ix_(hinges, hinges)]
        J[np.ix_(rows, rows)] -= np.asarray(dgd, float)[np.ix_(hinges, hinges)]
    m = I.shape[0]
    A = np.zeros((2 * m, 2 * m))
    A[:m, m:] = np.eye(m)
    A[m:, :m] = -np.linalg.solve(I, K)
    A[m:, m:] = -np.linalg.solve(I, J)
    return np.linalg.eigvals(A)


def _budget(rtol: float) -> float:
    return EXPLICIT_STEPS * max(1.0, (1e-6 / rtol) ** 0.125)


def choose_solver(
    model: Model,
    t1,
    *,
    t0: float | jax.Array = 0.0,
    y0: State | None = None,
    rtol: float | None = None,
    law=None,
    params=None,
) -> tuple[dfx.AbstractSolver, SolverChoice]:
    """The solver for a run of `model` from `t0` to `t1` at `rtol` (see the module's text):
    ``(diffrax solver, SolverChoice)``. Dopri8 unless the linearized equations at `y0` (default
    ``model.initial``) are stiff, then :class:`jaxtree.Radau5`."""
    return _choose(model, t1, t0, y0, rtol, law, params, checked=False)


def choose_checked(
    model: Model, t1, *, t0: float | jax.Array = 0.0, y0: State | None = None, rtol=None, law=None, params=None
) -> tuple[dfx.AbstractSolver, SolverChoice]:
    """:func:`choose_solver` for a caller that has checked the model and `y0` (:func:`jaxtree.simulate`):
    its linearization does not validate them again."""
    return _choose(model, t1, t0, y0, rtol, law, params, checked=True)


def _choose(model: Model, t1, t0, y0, rtol, law, params, checked: bool):

    y0 = model.initial if y0 is None else y0
    if is_traced((model, y0, t0, t1, rtol, params)):
        return dfx.Dopri8(), SolverChoice("Dopri8", True, "traced inputs (jit/vmap/grad): the explicit default")
    if rtol is None:
        import jax.numpy as jnp

        rtol = default_tolerance(jnp.result_type(model.mass))
    rtol = float(rtol)
    span = abs(float(t1) - float(t0))
    budget = _budget(rtol)
    local = _local_rates(model)
    screen = float(local.max()) if local.size else 0.0
    if law is None and span * SCREEN_MARGIN * screen / R_STABILITY < budget:
        why = (
            "no sprung hinge is fast enough to make the run stiff"
            if screen == 0.0
            else f"the fastest hinge law ({screen:.3g} rad/s alone) is far from stiff over {span:g} s"
        )
        return dfx.Dopri8(), SolverChoice("Dopri8", True, why, screen, span * screen / R_STABILITY)
    lam = _eigenvalues(model, y0, t0, law, params, checked)
    mag = np.abs(lam)
    fastest = float(mag.max()) if mag.size else 0.0
    steps = span * fastest / R_STABILITY
    if steps <= budget:
        why = f"the fastest linearized mode ({fastest:.3g} rad/s) costs an explicit method {steps:.0f} steps"
        return dfx.Dopri8(), SolverChoice("Dopri8", True, why, fastest, steps)
    # every eigenvalue an explicit method could not step over within the budget must decay
    fast = mag * span / R_STABILITY > budget
    decays = 0.1 * span * np.abs(np.minimum(np.real(lam), 0.0)) >= math.log(1.0 / rtol)
    if np.all(decays[fast]):
        why = (
            f"stiff: modes up to {fastest:.3g} rad/s would hold an explicit method to {steps:.3g} steps, "
            "and they decay early in the run"
        )
        return Radau5(), SolverChoice("Radau5", True, why, fastest, steps)
    slow = float(mag[fast & ~decays].max())
    why = (
        f"a fast mode that does not decay ({slow:.3g} rad/s) must be resolved by any method; explicit steps "
        "are the cheaper"
    )
    return dfx.Dopri8(), SolverChoice("Dopri8", True, why, fastest, steps)


def given(solver) -> SolverChoice:
    """The record of a solver the user passed."""
    return SolverChoice(type(solver).__name__, False, "given by the caller")
