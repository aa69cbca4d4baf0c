"""Eq. (1) by the blocked articulated-body recursion (jaxtree.articulated) against independent
references: the Lagrange oracle of tests/oracle.py (kinetic energy by autodiff), central finite
differences for gradients, and the dense solve only where that is itself checked against the
oracle (test_dynamics.py). Small block sizes force several block levels, ports and padding."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.equations import articulated

from helpers import ConstantLoads, random_state
from oracle import oracle_at
from trees import chain, deep_and_wide, gimbal_model, random_tree, star

# the backward error of the accelerations in the oracle's equations (relative to |A| |x|), and the block
# elimination against numpy's solve and Cholesky: float64 round-off
ROUNDOFF = 1e-12
# the forward error against the oracle or the dense solve: CONDITIONING * cond(A) * EPS, the float64
# forward error of a solve of condition cond(A) (EPS its machine epsilon) with a factor 20 for the
# different operation orders, and never under FORWARD_FLOOR
EPS = 2.2e-16
CONDITIONING = 20
FORWARD_FLOOR = 1e-10
# the holding torques of the articulated and the dense solve on fig4, relative: observed 3e-13, with margin
HOLD_TORQUE = 1e-10
# a vmapped call against single calls, the same arithmetic batched: round-off
SAME_ARITHMETIC = 1e-13
# reverse mode against central differences with h = 1e-6 of the entry: truncation ~ h^2 ~ 1e-12 and
# round-off ~ 1e-16 / h ~ 1e-10 of the objective's size, so this leaves a margin of 1e4
FD = 1e-6
# panels95 in float32 against float64: float32 round-off times the mass matrix's condition (2e4);
# observed 5e-5, with margin
FLOAT32 = 1e-3


def forward_bound(kappa):
    return max(FORWARD_FLOOR, CONDITIONING * kappa * EPS)


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


accelerations = jax.jit(jaxtree.solve_accelerations)


def with_loads(model, rng, bodies):
    bodies = tuple(sorted(int(b) for b in bodies))
    F = rng.normal(size=(len(bodies), 3)) * 20
    T = rng.normal(size=(len(bodies), 3)) * 5
    Ff, Tf = np.zeros((model.n + 1, 3)), np.zeros((model.n + 1, 3))
    Ff[list(bodies)], Tf[list(bodies)] = F, T
    return model.with_loads(ConstantLoads(bodies, jnp.asarray(F), jnp.asarray(T))), Ff, Tf


def against_oracle(model, state, rng, loads=True):
    """The articulated accelerations in the oracle's equations: backward error at round-off,
    forward error within the conditioning of Eq. (1)."""
    tau = rng.normal(size=model.n)
    F = T = None
    if loads:
        model, F, T = with_loads(model, rng, rng.choice(model.n + 1, size=min(3, model.n + 1), replace=False))
    acc = accelerations(model, state, 0.0, jnp.asarray(tau))
    spring = np.asarray(jaxtree.hinge_torques(model, state.gamma, state.gamma_dot))
    ref = oracle_at(model, state, tau=tau + spring, F=F, T=T)
    x = np.concatenate([acc.omega0_dot, acc.gamma_ddot])
    A, b = np.asarray(ref["mass_matrix"]), np.asarray(ref["rhs"])
    assert np.abs(A @ x - b).max() <= ROUNDOFF * np.abs(A).max() * np.abs(x).max()
    kappa = np.linalg.cond(A)
    assert rel(x, np.concatenate([ref["omega0_dot"], ref["gamma_ddot"]])) < forward_bound(kappa)


TREES = {
    "chain": lambda rng: random_tree(rng, chain(9)),
    "star": lambda rng: random_tree(rng, star(6)),
    "deep_and_wide": lambda rng: random_tree(rng, deep_and_wide(rng, 12)),
    "massless_frames": lambda rng: random_tree(rng, [0, 1, 2, 0, 4, 1, 6, 7], gimbals=(1, 4, 7), spring=False),
    "gimbals": gimbal_model,
}


@pytest.mark.parametrize("kind,block", [(kind, 2) for kind in sorted(TREES)] + [("deep_and_wide", 1)])
def test_random_trees_against_the_oracle(kind, block):
    """block = 1 is the classical articulated-body recursion, one body per level."""
    rng = np.random.default_rng(99 + sorted(TREES).index(kind) + 10 * block)
    model = TREES[kind](rng).with_method("articulated", block)
    bp = articulated.plan(model)
    if kind in ("chain", "deep_and_wide"):
        assert len(bp.levels) > 1  # the case is not trivial: ports and several levels
    for _ in range(2):
        against_oracle(model, random_state(model, rng), rng)


@pytest.mark.parametrize("name,block", [("fig4", 2), ("panels95", 0), ("chain50", 7)])
def test_scenes_against_the_oracle(scenes, name, block):
    rng = np.random.default_rng(5)
    model = scenes[name].with_method("articulated", block)
    if model.prescribed:  # the oracle has no prescriptions: compare the free vehicle
        d = jaxtree.scene_to_dict(model)
        for k in model.prescribed:
            d["bodies"][k]["joint"] = {"kind": "free"}
        model = jaxtree.scene_from_dict(d).with_method("articulated", block)
    against_oracle(model, random_state(model, rng), rng)


@pytest.mark.parametrize("name,block", [("fig4", 3), ("wings", 0), ("panels95", 0), ("chain200", 0)])
def test_scenes_equal_the_dense_solve(scenes, name, block):
    """Same accelerations and holding torques as the dense solve (itself checked against the
    oracle), with loads, hinge torques and prescriptions."""
    rng = np.random.default_rng(11)
    base, _, _ = with_loads(scenes[name], rng, (0, scenes[name].n))
    s = random_state(base, rng)
    tau = jnp.asarray(rng.normal(size=base.n))
    ref = accelerations(base.with_method("dense"), s, 0.9, tau)
    A = np.asarray(jaxtree.mass_matrix(base, s.gamma))
    bound = forward_bound(np.linalg.cond(A))
    acc = accelerations(base.with_method("articulated", block), s, 0.9, tau)
    assert rel(acc.omega0_dot, ref.omega0_dot) < bound
    assert rel(acc.gamma_ddot, ref.gamma_ddot) < bound
    if base.prescribed:
        assert rel(acc.hold_torque, ref.hold_torque) < HOLD_TORQUE


def test_plan_partitions_the_tree(scenes):
    """Blocks cover each hinge that is not inert exactly once, are connected, hang from one body,
    and their child blocks hang from their port; chains are cut into blocks of the given size."""
    for name in ("fig4", "panels95", "chain200"):
        model = scenes[name]
        for block in (0, 5):
            bp = articulated.plan(model.with_method("articulated", block))
            hinges = bp.hinge[bp.hinge < model.n]
            assert sorted(hinges.tolist()) == [k - 1 for k in range(1, model.n + 1) if k not in model.inert]
            for j in range(len(bp.parent)):
                members = [h + 1 for h in bp.hinge[j] if h < model.n]
                for k in members:  # connected: each member's parent is in the block or is the block's parent
                    p = model.topology.parents[k - 1]
                    assert p in members or p == bp.parent[j]
                for c in bp.children[j]:
                    assert bp.parent[c] == bp.port[j]
    bp = articulated.plan(scenes["chain200"].with_method("articulated", 16))
    assert len(bp.parent) == 13 and len(bp.levels) == 13 and bp.size == 16
    bp = articulated.plan(scenes["panels95"])
    assert len(bp.levels) == 1 and len(bp.parent) == 7  # the platform chain and six wings on the bus


def test_a_massless_branch_body_is_never_a_port():
    """A massless body with two children would leave its block's matrix singular as a port: the
    plan takes its subtree into the block instead, and the solve stays exact."""
    rng = np.random.default_rng(3)
    parents = [0, 1, 2, 3, 3, 4, 5]  # body 3 massless with children 4 and 5
    model = random_tree(rng, parents, gimbals=(3,), spring=False).with_method("articulated", 3)
    bp = articulated.plan(model)
    assert 3 not in bp.port.tolist()
    against_oracle(model, random_state(model, rng), rng)


def test_method_rule_and_override(scenes):
    if jax.default_backend() == "cpu":
        assert articulated.resolve_method(scenes["fig4"]) == "dense"
        assert articulated.resolve_method(scenes["chain200"]) == "articulated"
        assert articulated.resolve_method(scenes["panels95"]) == "articulated"
        # the cost model's calls on trees where the measured winner was clear (FINDINGS):
        # chain50 dense 2.2x faster, a star of 40 hinges articulated 4x faster
        assert articulated.resolve_method(scenes["chain50"]) == "dense"
        star = random_tree(np.random.default_rng(2), [0] * 40)
        assert articulated.resolve_method(star) == "articulated"
    assert articulated.resolve_method(scenes["chain200"].with_method("dense")) == "dense"
    with pytest.raises(ValueError, match="method"):
        scenes["fig4"].with_method("fastest")
    with pytest.raises(jaxtree.SceneError, match="method"):
        jaxtree.build_model([jaxtree.Body("b", 1.0, np.eye(3))], method="fastest")


def test_vmap_and_gradients(scenes):
    """vmapped calls equal single calls; gradients with respect to mass, geometry and stiffness
    equal central finite differences."""
    model = scenes["wings"].with_method("articulated", 2)
    rng = np.random.default_rng(8)
    states = [random_state(model, rng) for _ in range(3)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    w, g = jax.jit(jax.vmap(jaxtree.forward_dynamics, (None, 0, 0, 0, 0)))(
        model, batch.dcm, batch.omega0, batch.gamma, batch.gamma_dot
    )
    for i, s in enumerate(states):
        a = accelerations(model, s, 0.0, None)
        assert rel(w[i], a.omega0_dot) < SAME_ARITHMETIC and rel(g[i], a.gamma_ddot) < SAME_ARITHMETIC
    s = states[0]

    def objective(m):
        w, g = jaxtree.forward_dynamics(m, s.dcm, s.omega0, s.gamma, s.gamma_dot)
        return jnp.sum(w * jnp.arange(1.0, 4.0)) + jnp.sum(g * jnp.linspace(-1, 1, m.n))

    grads = jax.jit(jax.grad(objective))(model)
    f = jax.jit(objective)
    for field, index in [
        ("mass", 3),
        ("hinge_on_parent", (4, 0)),
        ("stiffness", 2),
        ("inertia", (6, 1, 1)),
        ("axis", (1, 2)),
    ]:
        h = 1e-6 * max(1.0, abs(float(getattr(model, field)[index])))
        bump = lambda d: jaxtree._src.vehicle.model.eqx.tree_at(
            lambda m: getattr(m, field), model, getattr(model, field).at[index].add(d)
        )
        fd = (f(bump(h)) - f(bump(-h))) / (2 * h)
        assert abs(float(getattr(grads, field)[index] - fd)) <= FD * max(1.0, abs(float(fd))), field


def test_float32(scenes):
    model = scenes["panels95"].with_method("articulated")
    s = random_state(model, np.random.default_rng(2))
    ref = accelerations(model, s, 0.0, None)
    m32 = model.astype(jnp.float32)
    s32 = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), s)
    acc = accelerations(m32, s32, 0.0, None)
    assert acc.gamma_ddot.dtype == jnp.float32
    assert rel(acc.gamma_ddot, ref.gamma_ddot) < FLOAT32


def test_eliminate_against_numpy():
    """numerics.eliminate (the block recursion's LAPACK-free factorization): A11^{-1} A12, the Schur
    complement and the LDL^T pivots of a stack of SPD matrices, against numpy's solve and
    Cholesky."""
    from jaxtree._src.numerics import eliminate

    rng = np.random.default_rng(5)
    X = rng.normal(size=(4, 11, 11))
    A = X @ np.swapaxes(X, -1, -2) + 0.5 * np.eye(11)
    G, S, piv = eliminate(jnp.asarray(A), 7)
    A11, A12, A21, A22 = A[:, :7, :7], A[:, :7, 7:], A[:, 7:, :7], A[:, 7:, 7:]
    assert rel(G, np.linalg.solve(A11, A12)) < ROUNDOFF
    assert rel(S, A22 - A21 @ np.linalg.solve(A11, A12)) < ROUNDOFF
    assert rel(piv, np.diagonal(np.linalg.cholesky(A11), axis1=-2, axis2=-1) ** 2) < ROUNDOFF


def test_no_lapack_calls_in_the_articulated_recursion(scenes):
    """jaxlib 0.10's batched CPU LAPACK kernels can deadlock XLA's thread pool when two run at
    once (simulate on chain50 hung that way): the recursion, its vmap and its Jacobian (what
    an implicit solver evaluates) compile to no LAPACK call."""
    model = scenes["chain50"].with_method("articulated")
    s = model.initial
    y = jnp.concatenate([s.omega0, s.gamma, s.gamma_dot])

    def rhs(y):
        acc = jaxtree.solve_accelerations(model, s._replace(omega0=y[:3], gamma=y[3 : 3 + model.n]), 0.0, None)
        return jnp.concatenate([acc.omega0_dot, acc.gamma_ddot])

    for f, x in [(rhs, y), (jax.jacfwd(rhs), y), (jax.vmap(rhs), jnp.stack([y, y]))]:
        text = jax.jit(f).lower(x).compile().as_text()
        assert "custom_call_target" not in text, re.findall(r'custom_call_target="([^"]+)"', text)
    # the check sees LAPACK where it is: the dense solve's factorization is one
    dense = jax.jit(lambda m: jaxtree.solve_accelerations(m, m.initial)).lower(model.with_method("dense"))
    assert "lapack" in " ".join(re.findall(r'custom_call_target="([^"]+)"', dense.compile().as_text()))
