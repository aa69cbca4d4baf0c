"""The rule of ``solver="auto"`` (integration/autosolver.py) against step counts that diffrax's
Dopri8 and jaxtree's Radau5 actually take, on linear systems whose modes and amplitudes are
known in closed form."""

import math

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.integration import autosolver as au
from jaxtree._src.integration import autosolver_cost as cost

SPAN = 10.0
SLOW, FAST, ZETA_FAST = 1.0, 5.0e3, 1e-3  # rad/s; the fast mode lightly damped: it never dies out


def two_oscillators(t, y, args):
    """A slow oscillator and a fast, lightly damped one, uncoupled: y = (x_s, x_f, v_s, v_f)."""
    x, v = y[:2], y[2:]
    w = jnp.asarray([SLOW, FAST])
    c = jnp.asarray([0.0, 2 * ZETA_FAST * FAST])
    return jnp.concatenate([v, -(w**2) * x - c * v])


def steps(solver, y0, rtol):
    sol = dfx.diffeqsolve(
        dfx.ODETerm(two_oscillators),
        solver,
        0.0,
        SPAN,
        None,
        y0,
        stepsize_controller=dfx.PIDController(rtol=rtol, atol=rtol),
        max_steps=200_000,
    )
    return int(sol.stats["num_accepted_steps"])


@pytest.mark.parametrize("fast_amplitude", [1e-12, 1e-2])
def test_the_predicted_steps_follow_the_fast_modes_amplitude(fast_amplitude):
    """A fast mode far below the tolerance (1e-12 against 1e-6): Radau5 steps over it, Dopri8's
    stability still needs |h lambda| <= 3 - Radau5 is predicted, and takes far fewer steps. The
    same mode at 1e-2: both must follow it, Dopri8 at fewer steps - Dopri8 is predicted. The
    predicted counts are within 3x of the counts the solvers take."""
    rtol = 1e-6
    # the fast mode's displacement and the matching rate of a free oscillation
    y0 = jnp.asarray([1.0, fast_amplitude, 0.0, 0.0])
    _, choice = au.choose_for_field(two_oscillators, None, y0, 0.0, SPAN, rtol=rtol, atol=rtol, cost_ratio=cost.RHO)
    explicit = steps(dfx.Dopri8(), y0, rtol)
    implicit = steps(jaxtree.Radau5(), y0, rtol)
    assert 1 / 3 <= choice.explicit_steps / explicit <= 3, (choice, explicit)
    assert 1 / 3 <= choice.implicit_steps / implicit <= 3, (choice, implicit)
    if fast_amplitude < rtol:
        assert choice.name == "Radau5" and implicit * cost.RHO < explicit, (choice, explicit, implicit)
    else:
        assert choice.name == "Dopri8" and implicit * cost.RHO > explicit, (choice, explicit, implicit)


def test_modal_amplitudes_of_a_free_oscillation_and_of_a_suddenly_applied_load():
    """Closed forms for x'' + w^2 x = f, in units of the tolerance scale atol + rtol |y0|. Released
    from x0 at rest, x = x0 cos(w t) = (x0 / 2)(e^(iwt) + e^(-iwt)): each mode carries x0 / 2 in
    x and w x0 / 2 in the rate. At rest under f from t0 on, each carries half the static
    deflection f / w^2, and f / (2 w) in the rate."""
    w, rtol, atol = 50.0, 1e-9, 1e-3
    A = np.array([[0.0, 1.0], [-(w**2), 0.0]])
    x0 = 1e-3
    y0 = np.array([x0, 0.0])
    lam, a, _ = cost.modal_amplitudes(A, (A @ y0)[None, :], np.array([0.0]), y0, rtol, atol)
    np.testing.assert_allclose(np.sort(np.abs(lam)), [w, w])
    np.testing.assert_allclose(a, w * x0 / 2 / atol, rtol=1e-9)
    f = 3.0
    lam, a, _ = cost.modal_amplitudes(A, np.array([[0.0, f]]), np.array([0.0]), np.zeros(2), rtol, atol)
    np.testing.assert_allclose(a, f / (2 * w) / atol, rtol=1e-9)


def test_a_ramped_load_rings_a_fast_mode_by_its_quasi_static_lag():
    """The change term against x'' + w^2 x = f' t (a ramp from rest): x = (f'/w^2)(t - sin(w t)/w),
    whose rate rings at f'/w^2 about its quasi-static value, f'/(2 w^2) in each of the two modes.
    A jump between two samples reads as a ramp over one sample interval dt (the samples cannot
    tell them apart): f/(dt w^2) in the rate, half per mode."""
    w, rtol, atol = 1000.0, 1e-9, 1e-6
    A = np.array([[0.0, 1.0], [-(w**2), 0.0]])
    ts = np.linspace(0.0, 2.0, 201)
    dt = ts[1] - ts[0]
    ramp = np.clip(ts - 0.5, 0.0, 1.0)  # f' = 1 over a second
    jump = (ts >= 1.0).astype(float)
    _, a_ramp, _ = cost.modal_amplitudes(A, np.stack([0 * ts, ramp], 1), ts, np.zeros(2), rtol, atol)
    _, a_jump, _ = cost.modal_amplitudes(A, np.stack([0 * ts, jump], 1), ts, np.zeros(2), rtol, atol)
    np.testing.assert_allclose(a_ramp, 1.0 / (2 * w**2) / atol, rtol=1e-6)
    np.testing.assert_allclose(a_jump, 1.0 / (2 * dt * w**2) / atol, rtol=1e-6)


def test_hybrid_default_records_its_choice(scenes):
    hm = jaxtree.hybrid_model(scenes["wings"], tuple(range(1, scenes["wings"].n + 1)), n_modes=2)
    sol = jaxtree.simulate_hybrid(hm, 0.2, saveat=3, truncation_error=False)
    choice = sol.stats["solver"]
    assert choice.auto and choice.name in ("Dopri8", "Radau5") and not math.isnan(choice.explicit_steps)
    given = jaxtree.simulate_hybrid(hm, 0.2, saveat=3, solver=dfx.Tsit5(), truncation_error=False)
    assert given.stats["solver"].name == "Tsit5" and not given.stats["solver"].auto
    traced = jax.eval_shape(
        lambda r: jaxtree.simulate_hybrid(hm, 0.2, saveat=3, rtol=r, truncation_error=False).stats["solver"], 1e-6
    )
    assert traced.name == "Dopri8" and "traced" in traced.reason
