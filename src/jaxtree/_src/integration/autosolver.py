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
step for small states, 2.5 at 200; :data:`.autosolver_cost.RHO_HYBRID` for the hybrid model):
Radau5 is chosen when ``rho N_i < N_e``.

**The modes and their amplitudes.** ``A = d f / d y`` is the Jacobian of the run's own
first-order right side at the initial state (the one :class:`jaxtree.Radau5` uses: attitude
variables, rates, the hinge laws and loads included; the hybrid model's for
:func:`jaxtree.simulate_hybrid`), ``A = V diag(lambda) V^-1``. About the initial state
``y0`` the modal coordinates ``z = V^-1 (y - y0)`` obey ``z' = lambda z + g(t)``,
``g = V^-1 f(t, y0)``, sampled at :data:`.autosolver_linearize.SAMPLES` times over the run.
For :func:`jaxtree.simulate` ``A`` comes from central differences of Eq. (1)'s matrix and right
side (one vmapped program, no solve), its acceleration rows ``M^-1 d(rhs)/dy`` with Eq. (1)'s
accelerations held (:func:`.autosolver_linearize.equation_jacobian_and_samples`: a preloaded
stiff spring would otherwise show real eigenvalues of either sign that its snap erases within
microseconds). A mode that starts at
rest under a slowly varying ``g`` follows its quasi-static value ``-g/lambda``; it rings at

    |z| ~ |g(t0)| / |lambda| + min(2 max|g(t) - g(t0)| / |lambda|, max|g'| / |lambda|^2),

the first term the start away from equilibrium (an initial rate, a preloaded spring, a load on
at ``t0``), the second the load's changes (a jump: twice the static change; a ramp: the lag of
the quasi-static response). In units of the tolerance ``a = |z| max_i |V_ik| / (atol + rtol
|y0_i|)``, at most ``1 / rtol``. A mode that rings below the tolerance (``a <= 1``) is not
followed; one that decays (``sigma = -Re lambda > 0``) is followed until ``ln(a) / sigma``, at
fewer steps per radian as it fades (:func:`.autosolver_cost.mode_steps`).

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

This module holds the choice and its record (:class:`SolverChoice`, :func:`choose_solver`,
:func:`choose_checked`, :func:`choose_for_field`, :func:`given`); the cost model and its
constants are :mod:`.autosolver_cost`, the screen :mod:`.autosolver_screen`, the linearization
and the samples :mod:`.autosolver_linearize`.
"""

from __future__ import annotations

import math

import diffrax as dfx
import equinox as eqx
import jax
import numpy as np

from ..numerics import is_traced
from ..vehicle.model import Model, State
from .autosolver_cost import R_STABILITY, RHO_HYBRID, Prediction, least_implicit_steps, predict_steps, rho
from .autosolver_linearize import equation_jacobian_and_samples, jacobian_and_samples, sample_times
from .autosolver_screen import local_rates, ringing_hinges, screen_rate
from .core import default_tolerance
from .radau import Radau5


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
    least = max(least_implicit_steps(rtol), ringing_hinges(model, y0, span, rtol, atol))
    if not laws and span * rate / R_STABILITY < rho(size) * least:
        why = (
            "nothing in the scene moves or rings fast enough to make the run stiff"
            if rate == 0.0
            else f"no hinge law or rate is near stiff over {span:g} s (at most {rate:.3g} rad/s with margins)"
        )
        local = float(local_rates(model).max(initial=0.0))  # the screen's own estimate, no margin
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
