"""Reverse-mode gradients through simulate with respect to every array leaf of a model: masses,
inertias, hinge axes and points, stiffness, damping, a load parameter and the initial state.

On fig4_free over 10 s (with damping and a thruster torque on the bus, so that every kind of
leaf acts), one random direction per leaf: the gradient of a loss over the whole trajectory
against central finite differences (Richardson-extrapolated, an independent derivative), against
forward-mode (diffrax.ForwardMode) and against the continuous adjoint (BacksolveAdjoint).
Then no NaN or inf at the nominal configuration (angles, rates and spin zero), with the massless
gimbal frames, and with a prescribed hinge. The compiled programs are shared by the tests."""

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree

T, TOL, SAVES = 10.0, 1e-12, 11
# The finite-difference reference integrates at a tolerance 50x tighter than the gradient it checks
# (2e-14: just above the 50 unit roundoffs below which simulate warns). At TOL itself the adaptive
# steps' noise over h was 5e-6 of the thruster torque's derivative on an AMD EPYC (0.0324216574 against
# 0.0324218785 by reverse mode; at 1e-14 the same differences give 0.0324218769, 4.7e-8 from reverse
# mode): a reference must be more accurate than the tolerance it checks, on every CPU.
FD_TOL = 2e-14
# reverse mode against Richardson-extrapolated central differences (h = 1e-3 of each leaf: truncation
# O(h^4) ~ 1e-12, the solver's noise of ~1e-13 of the loss over h ~ 1e-10), each directional
# derivative relative to the largest one (observed on an AMD EPYC, 2026-11-29: 8.6e-9)
FD_OF_LARGEST = 1e-7
# the same, each component relative to itself: what is left is the derivative of the discrete solve
# at TOL against the exact one (observed: 9.6e-8 for the thruster torque, 8.0e-8 for the inertias,
# 4.2e-8 for the stiffness, 9e-9 or less for the rest; at TOL itself the differences' noise gave
# 7e-7 here and 6.8e-6 on another AMD EPYC)
FD_OF_ITSELF = 1e-6
# reverse against forward mode: both differentiate the same discrete solve, only the order of the
# operations differs
FORWARD_MODE = 1e-8
# against the continuous adjoint, which solves its own ODE backward at the same tolerance TOL: that
# integration's error, relative to the largest entry of each leaf's gradient
BACKSOLVE = 1e-6


def _model():
    model = jaxtree.load_scene("fig4_free")
    sprung = np.asarray(model.sprung) - 1
    thruster = jaxtree.BodyTorque(0, [2.0, -1.0, 0.5], profile=lambda t: jaxtree.thruster_pulse(t, 1.0, 2.0, rise=0.2))
    model = eqx.tree_at(lambda m: m.damping, model, model.damping.at[sprung].set(0.05))
    return model.with_loads(thruster)


WEIGHTS = {
    k: np.random.default_rng(3).standard_normal(s)
    for k, s in [
        ("omega0", (SAVES, 3)),
        ("gamma", (SAVES, 10)),
        ("gamma_dot", (SAVES, 10)),
        ("energy", (SAVES,)),
        ("angular_momentum", (SAVES, 3)),
        ("dcm", (SAVES, 3, 3)),
    ]
}
SCALE = {"omega0": 1.0, "gamma": 1.0, "gamma_dot": 0.1, "energy": 1e-3, "angular_momentum": 1e-2, "dcm": 1.0}


def _loss(sol):
    # a smooth function of the whole trajectory (the drifts, maxima over time, have kinks that
    # finite differences straddle; their derivatives are checked for NaN below)
    return sum(SCALE[k] * jnp.sum(WEIGHTS[k] * getattr(sol, k)) for k in WEIGHTS)


@pytest.fixture(scope="module")
def setup():
    model = _model()
    params, static = eqx.partition(model, eqx.is_inexact_array)

    def L(p, adjoint=None, tol=TOL):
        m = eqx.combine(p, static)
        return _loss(jaxtree.simulate(m, T, saveat=SAVES, rtol=tol, atol=tol, adjoint=adjoint))

    grad = jax.jit(jax.grad(L))
    return model, params, L, grad


def _leaf_names(params):
    return [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_leaves_with_path(params)]


def _directions(params, seed=0):
    """One random direction per array leaf, scaled like the leaf (zero entries get a fixed scale,
    except the mass and inertia of massless bodies, which are structural);
    for the direction cosines a rotation, dC = -tilde(v) C, so the perturbed C stays orthogonal."""
    rng = np.random.default_rng(seed)
    leaves, tdef = jax.tree_util.tree_flatten(params)
    names = _leaf_names(params)
    dirs = []
    for i, (name, x) in enumerate(zip(names, leaves)):
        x = np.asarray(x)
        r = rng.standard_normal(x.shape)
        if name.endswith("inertia"):
            r = r + np.swapaxes(r, -1, -2)
        scale = np.where(np.abs(x) > 0, np.abs(x), max(0.01 * np.abs(x).max(), 0.05))
        if name in (".mass", ".inertia"):
            scale = np.abs(x)  # a massless body's zeros are structural (the static model.massive)
        d = r * scale
        if name.endswith(".axis"):
            d = d - np.sum(d * x, -1, keepdims=True) * x  # tilt the unit axes (their length is not a parameter)
        if name.endswith("dcm"):
            d = -np.asarray(jaxtree.tilde(jnp.asarray(rng.standard_normal(3)))) @ x
        tangent = [np.zeros_like(np.asarray(y)) for y in leaves]
        tangent[i] = d
        dirs.append(jax.tree_util.tree_unflatten(tdef, [jnp.asarray(t) for t in tangent]))
    return names, dirs


def _perturbed(params, direction, h, name_dcm=".initial.dcm"):
    """params + h direction; the direction cosines rotated exactly: C(h) = expm(h W) C with W C = dC."""

    def move(path, p, d):
        if jax.tree_util.keystr(path) == name_dcm:
            W = d @ p.T  # d = W C, W skew
            return jax.scipy.linalg.expm(h * W) @ p
        return p + h * d

    return jax.tree_util.tree_map_with_path(move, params, direction)


def _project(grad, direction):
    return sum(jnp.vdot(a, b) for a, b in zip(jax.tree_util.tree_leaves(grad), jax.tree_util.tree_leaves(direction)))


@pytest.fixture(scope="module")
def gradient(setup):
    _, params, _, grad = setup
    return grad(params)


def test_gradient_matches_finite_differences_for_every_leaf(setup, gradient):
    model, params, L, _ = setup
    names, dirs = _directions(params)
    h = 1e-3  # relative to each leaf: Richardson leaves O(h^4) ~ 1e-12; the solver's noise (~1e-11 of the loss) over h stays ~1e-8
    D = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *dirs)

    def central(d, h):
        return (L(_perturbed(params, d, h), tol=FD_TOL) - L(_perturbed(params, d, -h), tol=FD_TOL)) / (2 * h)

    both = jax.jit(jax.vmap(lambda d: jnp.stack([central(d, h), central(d, h / 2)])))(D)
    fd = np.asarray((4 * both[:, 1] - both[:, 0]) / 3)  # Richardson: the h^2 term cancels
    ad = np.asarray([_project(gradient, d) for d in dirs])
    # the relative error of the gradient (the vector of directional derivatives), then per component
    scale = np.abs(fd).max()
    checked = 0
    for name, a, f in zip(names, ad, fd):
        if name.endswith("omega0") and abs(f) == 0 and abs(a) == 0:
            continue
        assert abs(a - f) <= FD_OF_LARGEST * scale, f"{name}: reverse mode {a:.12g}, finite differences {f:.12g}"
        assert abs(a - f) <= FD_OF_ITSELF * abs(f), f"{name}: reverse mode {a:.12g}, finite differences {f:.12g}"
        checked += 1
    # every leaf the dynamics reads: the scene's masses, inertias, hinge axes and points, the laws,
    # the thruster's torque and the whole initial state
    assert checked == len(names)


def test_forward_mode_and_backsolve_adjoint_agree_with_the_default(setup, gradient):
    _, params, L, _ = setup
    names, dirs = _directions(params, seed=1)
    D = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *dirs)
    jvp = jax.jit(jax.vmap(lambda d: jax.jvp(lambda p: L(p, dfx.ForwardMode()), (params,), (d,))[1]))(D)
    for name, d, f in zip(names, dirs, np.asarray(jvp)):
        a = float(_project(gradient, d))
        assert abs(a - f) <= FORWARD_MODE * max(abs(f), 1e-300), f"{name}: reverse {a:.12g}, forward mode {f:.12g}"
    back = jax.jit(jax.grad(lambda p: L(p, dfx.BacksolveAdjoint())))(params)
    for name, a, b in zip(names, jax.tree_util.tree_leaves(gradient), jax.tree_util.tree_leaves(back)):
        a, b = np.asarray(a), np.asarray(b)
        assert np.abs(a - b).max() <= BACKSOLVE * np.abs(a).max(), (
            f"{name}: backsolve differs by {np.abs(a - b).max():.3g}"
        )


def test_gradient_is_finite_at_the_nominal_configuration(setup, gradient):
    """All angles zero, zero rates, no spin (zero angular momentum: its norm, the relative drifts),
    with the massless gimbals of fig4_free; the same compiled gradient as above."""
    model, params, _, grad = setup
    s = model.initial
    rest = jaxtree.State(s.dcm, jnp.zeros(3), jnp.zeros(model.n), jnp.zeros(model.n))
    g = grad(eqx.tree_at(lambda p: p.initial, params, rest))
    for name, leaf in zip(_leaf_names(params), jax.tree_util.tree_leaves(g)):
        assert np.all(np.isfinite(np.asarray(leaf))), name
    # and something moves: the thruster spins the vehicle up from rest
    assert np.abs(np.asarray(g.initial.omega0)).max() > 0 and np.abs(np.asarray(g.inertia)).max() > 0
    assert np.all(np.isfinite(np.asarray(gradient.mass)))


def test_gradient_is_finite_with_a_prescribed_hinge():
    """fig4: the platform hinge follows a sine (its amplitude, frequency and phase are leaves too)."""
    model = jaxtree.load_scene("fig4")
    s = model.initial
    model = eqx.tree_at(
        lambda m: m.initial, model, jaxtree.State(s.dcm, jnp.zeros(3), jnp.zeros(model.n), jnp.zeros(model.n))
    )
    params, static = eqx.partition(model, eqx.is_inexact_array)

    def L(p):
        sol = jaxtree.simulate(eqx.combine(p, static), 1.0, saveat=5, rtol=1e-8, atol=1e-8)
        return jnp.sum(sol.hold_torque) + jnp.sum(sol.omega0) + jnp.sum(sol.gamma) + sol.momentum_drift()

    g = jax.jit(jax.grad(L))(params)
    for name, leaf in zip(_leaf_names(params), jax.tree_util.tree_leaves(g)):
        assert np.all(np.isfinite(np.asarray(leaf))), name
    assert np.abs(np.asarray(g.prescription.amplitude)).max() > 0
