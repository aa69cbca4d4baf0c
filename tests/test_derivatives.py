"""Derivatives of the solution of Eq. (1) by the implicit-function rule
(jaxtree._src.equations.dynamics._solve_completed_jvp) against two independent derivations:

- forward-mode differentiation through the operations of the plain solve (the Cholesky
  factorization or the articulated recursion, ``_solve_plain``), which knows nothing of the rule;
- central finite differences of the accelerations.

Each on random trees and the bundled scenes, for both methods, float64 and float32, under
``jax.vmap``, in forward and reverse mode, for the state and the model's parameters, and a
second derivative (the linearization's ``jacfwd`` of a ``jacfwd``)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.equations import dynamics

from helpers import ConstantLoads, random_state
from trees import chain, deep_and_wide, random_tree, star

# float64: the rule and the differentiated solve are two exact expressions of one derivative;
# they differ by round-off times the condition number of Eq. (1) (<= 1e6 on these trees).
RULE_RTOL = 1e-9
# central differences with step 1e-6 (relative): truncation ~1e-12 x third derivative, round-off
# ~eps / 1e-6 = 2e-10 of the accelerations' scale.
FD_RTOL = 1e-6


def _accelerations(model, solve):
    """The accelerations (and holding torques) as one vector, by `solve` ("rule": the public
    path, differentiated by the implicit-function rule; "plain": the solve's own operations)."""

    def acc(model, state, t):
        if solve == "rule":
            a = dynamics.solve_unchecked(model, state, t, None)
        else:
            full, gdd_p = dynamics.complete_state(model, t, state)
            dtype = dynamics._dtype(model, full.gamma, full.gamma_dot, full.omega0)
            full = jaxtree.State(*(jnp.asarray(x, dtype) for x in full))
            a = dynamics._solve_plain(model, full, jnp.asarray(t, dtype), None, gdd_p)
        return jnp.concatenate([a.omega0_dot, a.gamma_ddot, a.hold_torque])

    return acc


def _state_jacobian(solve):
    @eqx.filter_jit
    def jac(model, state, t):
        acc = _accelerations(model, solve)
        f = lambda w, g, gd: acc(model, jaxtree.State(state.dcm, w, g, gd), t)
        return jnp.concatenate(jax.jacfwd(f, argnums=(0, 1, 2))(state.omega0, state.gamma, state.gamma_dot), 1)

    return jac


state_jacobian = {s: _state_jacobian(s) for s in ("rule", "plain")}


def rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def _trees():
    rng = np.random.default_rng(23)
    return {
        "chain14": random_tree(rng, chain(14)),
        "star8": random_tree(rng, star(8)),
        "deep_wide18": random_tree(rng, deep_and_wide(rng, 18)),
    }


TREES = _trees()
# blocks of at most 4 hinges: several block levels (chains) and several blocks per level (stars)
# in trees small enough to compile fast
BLOCK = 4


@pytest.mark.parametrize("name", sorted(TREES))
def test_configuration_tangent_closed_form_equals_jvp(name):
    """The rule's closed-form tangent of the configuration and the body angular velocities
    (dynamics._configuration_tangent: small rotations about the hinge axes inboard of each body)
    against forward-mode differentiation of dynamics.configuration_and_rates (products of rotations)."""
    model = TREES[name]
    rng = np.random.default_rng(5)
    n = model.n
    g, gd, w = (jnp.asarray(rng.normal(size=k)) for k in (n, n, 3))
    dg, dgd, dw = (jnp.asarray(rng.normal(size=k)) for k in (n, n, 3))
    f = lambda g, gd, w: dynamics.configuration_and_rates(model, g, w, gd)
    (cfg, omega), (cfg_dot, omega_dot) = jax.jvp(f, (g, gd, w), (dg, dgd, dw))
    closed_cfg, closed_omega = dynamics._configuration_tangent(model, cfg, omega, gd, dg, dgd, dw)
    for field, a, b in zip(cfg._fields, closed_cfg, cfg_dot):
        assert rel(a, b) < 1e-13, field
    assert rel(closed_omega, omega_dot) < 1e-13
    # rates only: the configuration does not move (forward mode gives zeros, the rule no tangent)
    _, (cfg_dot, omega_dot) = jax.jvp(f, (g, gd, w), (jnp.zeros(n), dgd, dw))
    closed_cfg, closed_omega = dynamics._configuration_tangent(model, cfg, omega, gd, None, dgd, dw)
    assert all(float(jnp.abs(a).max()) == 0.0 for a in cfg_dot) and closed_cfg is None
    assert rel(closed_omega, omega_dot) < 1e-13


@pytest.mark.parametrize("method", ["dense", "articulated"])
@pytest.mark.parametrize("name", sorted(TREES))
def test_state_jacobian_rule_equals_differentiated_solve(name, method):
    model = TREES[name].with_method(method, BLOCK)
    rng = np.random.default_rng(5)
    state = random_state(model, rng)
    rule = state_jacobian["rule"](model, state, 0.0)
    plain = state_jacobian["plain"](model, state, 0.0)
    assert rule.shape == (model.n + 3, 2 * model.n + 3)
    assert rel(rule, plain) < RULE_RTOL


@pytest.mark.parametrize("name", ["fig4", "fig4_free", "appendix_c", "wings"])
def test_scene_jacobian_rule_equals_differentiated_solve(scenes, name):
    """fig4 has a prescribed hinge (its holding torque is differentiated too)."""
    model = scenes[name]
    state = random_state(model, np.random.default_rng(11))
    assert rel(state_jacobian["rule"](model, state, 0.3), state_jacobian["plain"](model, state, 0.3)) < RULE_RTOL


def test_rule_equals_central_differences_with_loads_and_time():
    """Against finite differences in every state variable and in time (time-varying loads)."""
    rng = np.random.default_rng(8)
    model = random_tree(rng, deep_and_wide(rng, 14))
    loads = ConstantLoads((0, 3, 9), jnp.asarray(rng.normal(size=(3, 3)) * 5), jnp.asarray(rng.normal(size=(3, 3))))
    model = model.with_loads(loads)
    state = random_state(model, rng)
    acc = jax.jit(_accelerations(model, "rule"))
    x0 = np.concatenate([np.asarray(state.omega0), np.asarray(state.gamma), np.asarray(state.gamma_dot)])
    n = model.n

    def at(x):
        return np.asarray(acc(model, jaxtree.State(state.dcm, x[:3], x[3 : 3 + n], x[3 + n :]), 0.0))

    fd = np.empty((n + 3, x0.size))
    for i in range(x0.size):
        h = 1e-6 * max(1.0, abs(x0[i]))
        e = np.zeros_like(x0)
        e[i] = h
        fd[:, i] = (at(x0 + e) - at(x0 - e)) / (2 * h)
    rule = state_jacobian["rule"](model, state, 0.0)
    assert rel(rule, fd) < FD_RTOL


def test_parameter_derivatives_forward_and_reverse():
    """d(accelerations)/d(mass, inertia, geometry, stiffness, damping) by the rule, in forward
    and reverse mode, equal forward mode through the plain solve; both methods."""
    rng = np.random.default_rng(3)
    base = random_tree(rng, deep_and_wide(rng, 12))
    state = random_state(base, rng)
    params = lambda m: (m.mass, m.inertia, m.hinge_on_parent, m.stiffness, m.damping)
    weights = jnp.asarray(rng.normal(size=base.n + 3))
    for method in ("dense", "articulated"):
        model = base.with_method(method, BLOCK)

        def loss(p, solve, model=model):
            m = eqx.tree_at(params, model, p)
            return _accelerations(m, solve)(m, state, 0.0) @ weights

        p0 = params(model)
        g_rule = jax.jit(jax.grad(loss), static_argnums=1)(p0, "rule")
        g_fwd_rule = jax.jit(jax.jacfwd(loss), static_argnums=1)(p0, "rule")
        g_plain = jax.jit(jax.jacfwd(loss), static_argnums=1)(p0, "plain")
        for a, b, c in zip(_sym(g_rule), _sym(g_fwd_rule), _sym(g_plain)):
            assert rel(a, c) < RULE_RTOL
            assert rel(b, c) < RULE_RTOL


def _sym(grads):
    """The inertia's gradient on symmetric matrices: the plain solve's Cholesky factorization
    reads one triangle of Eq. (1)'s matrix, so its derivative along an antisymmetric change of an
    inertia (not an inertia) differs from the rule's; along symmetric changes both agree."""
    mass, inertia, *rest = grads
    return (mass, 0.5 * (inertia + jnp.swapaxes(inertia, -1, -2)), *rest)


def test_second_derivatives():
    """jacfwd of jacfwd (the linearization's second derivatives) through the rule, which is
    itself differentiated, equals it through the plain solve."""
    rng = np.random.default_rng(4)
    model = random_tree(rng, deep_and_wide(rng, 4))
    state = random_state(model, rng)

    def hess(solve):
        acc = _accelerations(model, solve)
        f = lambda g: acc(model, state._replace(gamma=g), 0.0)
        return jax.jit(jax.jacfwd(jax.jacfwd(f)))(state.gamma)

    assert rel(hess("rule"), hess("plain")) < RULE_RTOL


def test_vmap_and_float32():
    """Under jax.vmap over states (a Monte Carlo batch), in float64 and float32, both methods.
    float32: the two derivations differ by round-off amplified by the condition number of
    Eq. (1), bounded here by 100 kappa eps of the Jacobian's scale."""
    rng = np.random.default_rng(9)
    base = random_tree(rng, chain(10))
    states = [random_state(base, rng, scale=0.5) for _ in range(3)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    # three pairings cover both methods in float32 (GPU batches) and the articulated one in float64
    for dtype, method in ((jnp.float64, "articulated"), (jnp.float32, "dense"), (jnp.float32, "articulated")):
        model = base.with_method(method, BLOCK).astype(dtype)
        b = jax.tree_util.tree_map(lambda x: x.astype(dtype), batch)
        jr = jax.vmap(state_jacobian["rule"], in_axes=(None, 0, None))(model, b, 0.0)
        jp = jax.vmap(state_jacobian["plain"], in_axes=(None, 0, None))(model, b, 0.0)
        assert jr.dtype == dtype and jr.shape == (3, base.n + 3, 2 * base.n + 3)
        if dtype == jnp.float64:
            assert rel(jr, jp) < RULE_RTOL
        else:
            kappa = max(float(np.linalg.cond(np.asarray(jaxtree.mass_matrix(base, s.gamma)))) for s in states)
            assert rel(jr, jp) < 100 * kappa * float(jnp.finfo(jnp.float32).eps)


def test_gradient_through_radau5_equals_central_differences():
    """A gradient through the implicit integrator (jaxtree.Radau5, its Jacobians by the rule) on
    the stiff chain, w.r.t. the stiffness and damping of hinges, against central differences of
    the same compiled simulation. The bound, 1e-3 of the gradient's scale, is what the integrator's
    derivative delivers: reverse mode runs through its simplified Newton iterations, whose frozen
    Jacobian (stop_gradient) makes the iterated derivative converge only at the Newton rate;
    measured 4e-5 to 1.2e-4 relative at rtol 1e-12, where the differences agree with each other
    to 1e-7 over steps 1e-3..1e-5 (benchmarks/FINDINGS.md; the implicit-function theorem on the
    converged stage equations is the way to round-off)."""
    model = jaxtree.stiff_chain(1e4)
    ts = jnp.linspace(0.0, 0.1, 3)

    @jax.jit
    def loss(k, c):
        m = eqx.tree_at(lambda m: (m.stiffness, m.damping), model, (k, c))
        sol = jaxtree.simulate(m, 0.1, saveat=ts, solver=jaxtree.Radau5(), rtol=1e-9, atol=1e-9, throw=False)
        return jnp.sum(sol.gamma[-1] ** 2) + jnp.sum(sol.omega0[-1] ** 2)

    k0, c0 = model.stiffness, model.damping
    grads = jax.jit(jax.grad(loss, argnums=(0, 1)))(k0, c0)
    for which, g in enumerate(grads):
        scale = float(jnp.abs(g).max())
        for i in (0, model.n // 2):
            x = (k0, c0)[which]
            h = 1e-3 * float(x[i])
            plus, minus = [k0, c0], [k0, c0]
            plus[which] = x.at[i].add(h)
            minus[which] = x.at[i].add(-h)
            fd = (float(loss(*plus)) - float(loss(*minus))) / (2 * h)
            assert abs(float(g[i]) - fd) <= 1e-3 * scale, (which, i, float(g[i]), fd, scale)
