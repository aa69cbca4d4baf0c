"""Eq. (1) and Eq. (2) against independent derivations.

The reference is tests/oracle.py: the kinetic energy built from scratch from the
positions and attitudes of every body, and the equations of motion from it by
automatic differentiation (Hamel's equations for the reference body's
quasi-velocities, Lagrange's for the hinge angles). Conservation laws and the
printed form of Defs. 38-41 (jaxtree._src.equations.barycentric.seed_equations) give further,
separate checks.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.equations.barycentric import seed_equations

from helpers import ConstantLoads, count_equations, random_state, scene_names
from helpers import equations as jaxpr_equations
from oracle import oracle_at, oracle_body_states
from trees import chain, deep_and_wide, gimbal_model, random_tree, star

RTOL = 1e-10  # the bound; double-precision results agree to ~1e-15 relative
# backward error of the accelerations in the oracle's equations, relative to |A| |x|: a stable solve
# gives ~1e-16
BACKWARD = 1e-13
# the forward error of the accelerations: CONDITIONING * kappa * EPS, the float64 forward error of a solve
# of condition kappa (EPS the machine epsilon, 20 for the different operation orders), and never under RTOL
EPS = 2.2e-16
CONDITIONING = 20
ROUNDOFF = 1e-12  # O(1) float64 identities (A symmetric, two unit axes aligned): round-off
SAME_ARITHMETIC = 1e-13  # a vmapped call against single calls, the same arithmetic batched: round-off
ULPS = 1e-14  # the prescription's sine against numpy's, O(1) numbers: tens of ulps
# reverse mode against central differences with h ~ 1e-6: ~1e-9 relative truncation and rounding
# error, so this leaves a margin of 1000
FD = 1e-6
# single precision: ~1e-7 unit roundoff times the condition number of the matrix (~5e3 for fig4_free)
FLOAT32 = 2e-3
# one rigid body: Euler's equations by a 3 x 3 solve against numpy's (a few hundred ulps, and an absolute
# floor for components near zero), the mass matrix against the inertia given (a few ulps)
EULER_RTOL, EULER_ATOL = 1e-13, 1e-15
EULER_INERTIA = 1e-15


equations = jax.jit(jaxtree.rotational_equations)
accelerations = jax.jit(jaxtree.solve_accelerations)
seed_form = jax.jit(seed_equations)


@jax.jit
def equations_and_accelerations(model, state, tau):
    """One compilation per model for the oracle comparison."""
    A, rhs = jaxtree.rotational_equations(model, state, 0.0, tau)
    return A, rhs, jaxtree.solve_accelerations(model, state, 0.0, tau)


def rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-300))


def oracle(model, state, tau=None, F=None, T=None):
    return oracle_at(model, state, tau=tau, F=F, T=T)


def with_random_loads(model, rng, bodies):
    bodies = tuple(sorted(int(b) for b in bodies))
    loads = ConstantLoads(
        bodies, jnp.asarray(rng.normal(size=(len(bodies), 3)) * 20), jnp.asarray(rng.normal(size=(len(bodies), 3)) * 5)
    )
    F = np.zeros((model.n + 1, 3))
    T = np.zeros((model.n + 1, 3))
    F[list(bodies)] = np.asarray(loads.force)
    T[list(bodies)] = np.asarray(loads.torque)
    return model.with_loads(loads), F, T


def check_against_oracle(model, state, rng, loads=True):
    """A, rhs and accelerations of Eq. (1) equal the oracle's, with hinge torques and loads."""
    tau = rng.normal(size=model.n)
    F = T = None
    if loads:
        bodies = rng.choice(model.n + 1, size=min(3, model.n + 1), replace=False)
        model, F, T = with_random_loads(model, rng, bodies)
    A, rhs, acc = equations_and_accelerations(model, state, jnp.asarray(tau))
    spring = np.asarray(jaxtree.hinge_torques(model, state.gamma, state.gamma_dot))
    ref = oracle(model, state, tau=tau + spring, F=F, T=T)
    assert rel(A, ref["mass_matrix"]) < RTOL
    assert rel(rhs, ref["rhs"]) < RTOL
    if not model.prescribed:
        x = np.concatenate([acc.omega0_dot, acc.gamma_ddot])
        Aref, bref = np.asarray(ref["mass_matrix"]), np.asarray(ref["rhs"])
        # backward error of our solution in the oracle's equations
        assert np.abs(Aref @ x - bref).max() <= BACKWARD * np.abs(Aref).max() * np.abs(x).max()
        # forward error: the accelerations inherit the conditioning of Eq. (1) (kappa ~ 3e8 for
        # chain200 at rest), so the bound is the larger of 1e-10 and a few kappa * epsilon
        kappa = np.linalg.cond(Aref)
        assert rel(x, np.concatenate([ref["omega0_dot"], ref["gamma_ddot"]])) < max(RTOL, CONDITIONING * kappa * EPS)
    return model, ref


@pytest.mark.parametrize("name", scene_names())
def test_eq1_equals_lagrange_oracle(scenes, name):
    rng = np.random.default_rng(abs(hash(name)) % 2**32)
    model = scenes[name]
    check_against_oracle(model, model.initial, rng, loads=False)
    check_against_oracle(model, random_state(model, rng), rng, loads=True)


@pytest.mark.parametrize("name", ["fig4", "panels95"])
def test_eq1_with_separate_outboard_products_equals_the_oracle(scenes, name, monkeypatch):
    """The formulation traced on GPUs (two outboard-set products instead of one, see
    jaxtree._src.equations.dynamics.merge_outboard_sums) against the oracle too, with loads and a prescription."""
    import jaxtree._src.equations.assembly as assembly

    monkeypatch.setattr(assembly, "merge_outboard_sums", lambda: False)
    rng = np.random.default_rng(7)
    model = scenes[name]
    check_against_oracle(model, random_state(model, rng), rng, loads=True)


@pytest.mark.parametrize("name", ["appendix_c", "fig4", "wings", "chain50"])
def test_eq1_equals_printed_defs_38_to_41(scenes, name):
    """The fast assembly equals Defs. 38-41 evaluated term by term (barycentric form), with loads.

    Four scenes (two-body star, gimbals with a prescribed hinge, two wings, a long chain)
    cover every term; each compilation of the printed form takes several seconds."""
    rng = np.random.default_rng(7)
    model, _, _ = with_random_loads(scenes[name], rng, (0, scenes[name].n))
    state = random_state(model, rng)
    tau = jnp.asarray(rng.normal(size=model.n))
    # the printed form fills in prescribed hinges; do the same on the fast side
    state_full, _ = jaxtree._src.equations.dynamics.complete_state(model, 0.0, state)
    A, rhs = equations(model, state_full, 0.0, tau)
    As, rhss = seed_form(model, state, 0.0, tau)
    assert rel(A, As) < RTOL
    assert rel(rhs, rhss) < RTOL


@pytest.mark.parametrize("name", scene_names())
def test_matrix_is_symmetric_positive_definite(scenes, name):
    model = scenes[name]
    rng = np.random.default_rng(3)
    for _ in range(3):
        A, _ = equations(model, random_state(model, rng), 0.0, None)
        A = np.asarray(A)
        assert np.abs(A - A.T).max() <= ROUNDOFF * np.abs(A).max()
        assert np.linalg.eigvalsh(0.5 * (A + A.T))[0] > 0


@pytest.mark.parametrize("name", ["fig4_free", "wings", "chain10", "panels95"])
def test_angular_momentum_rate_equals_external_moment(scenes, name):
    """dH/dt about the mass center = sum of external moments about it (inertial components)."""
    rng = np.random.default_rng(11)
    model, F, T = with_random_loads(scenes[name], rng, (0, 2, scenes[name].n))
    state = random_state(model, rng)
    acc = accelerations(model, state, 0.0, None)
    rate = jaxtree.State(jaxtree.dcm_rate(state.dcm, state.omega0), acc.omega0_dot, state.gamma_dot, acc.gamma_ddot)
    # jitted: an eager jvp runs (and compiles) each operation on its own
    _, dH = jax.jit(lambda s, r: jax.jvp(lambda s: jaxtree.angular_momentum(model, s), (s,), (r,)))(state, rate)
    geo = oracle_body_states(
        model.topology.parents,
        np.asarray(model.mass),
        np.asarray(model.axis),
        np.asarray(model.hinge_on_parent),
        np.asarray(model.hinge_on_body),
        np.asarray(state.gamma),
    )
    R, r = np.asarray(geo["R"]), np.asarray(geo["r"])
    Fb0, Tb0 = np.einsum("kij,kj->ki", R, F), np.einsum("kij,kj->ki", R, T)
    moment = np.asarray(state.dcm).T @ (np.cross(r, Fb0) + Tb0).sum(0)
    assert rel(dH, moment) < RTOL


@pytest.mark.parametrize("name", ["fig4_free", "wings", "chain50"])
def test_energy_rate_equals_hinge_power(scenes, name):
    """Without loads, dT/dt equals the power of the hinge torques (springs, dampers, tau)."""
    model = scenes[name]
    rng = np.random.default_rng(5)
    state = random_state(model, rng)
    tau = jnp.asarray(rng.normal(size=model.n))
    acc = accelerations(model, state, 0.0, tau)
    rate = jaxtree.State(jnp.zeros((3, 3)), acc.omega0_dot, state.gamma_dot, acc.gamma_ddot)
    _, dT = jax.jit(lambda s, r: jax.jvp(lambda s: jaxtree.kinetic_energy(model, s), (s,), (r,)))(state, rate)
    power = jnp.dot(jaxtree.hinge_torques(model, state.gamma, state.gamma_dot) + tau, state.gamma_dot)
    assert abs(float(dT - power)) <= RTOL * float(jaxtree.kinetic_energy(model, state))


def test_kinetic_energy_and_momentum_match_oracle(scenes):
    model = scenes["fig4_free"]
    state = random_state(model, np.random.default_rng(2))
    ref = oracle(model, state)
    assert rel(jaxtree.kinetic_energy(model, state), ref["kinetic_energy"]) < RTOL
    assert rel(jaxtree.angular_momentum(model, state), ref["angular_momentum"]) < RTOL
    # the kinetic energy is the quadratic form of Eq. (1)'s matrix
    A = jaxtree.mass_matrix(model, state.gamma)
    x = jnp.concatenate([state.omega0, state.gamma_dot])
    assert rel(0.5 * x @ A @ x, ref["kinetic_energy"]) < RTOL


def test_eq2_mass_center_acceleration(scenes):
    rng = np.random.default_rng(9)
    model, F, T = with_random_loads(scenes["wings"], rng, (0, 3, 5))
    state = random_state(model, rng)
    ref = oracle(model, state, F=F, T=T)
    got = jaxtree.mass_center_acceleration(model, state)
    assert rel(got, np.asarray(state.dcm).T @ np.asarray(ref["cm_acceleration"])) < RTOL
    assert np.all(np.asarray(jaxtree.mass_center_acceleration(scenes["wings"], state)) == 0)


# ----------------------------------------------------------------------------- random trees
TREES = {
    "chain": lambda rng: random_tree(rng, chain(6)),
    "star": lambda rng: random_tree(rng, star(6)),
    "deep_and_wide": lambda rng: random_tree(rng, deep_and_wide(rng, 9)),
    "massless_frames": lambda rng: random_tree(rng, [0, 1, 2, 0, 4, 1], gimbals=(1, 4), spring=False),
    "gimbals": gimbal_model,
}


@pytest.mark.parametrize("kind", sorted(TREES))
def test_random_trees_against_oracle(kind):
    rng = np.random.default_rng(2024 + sorted(TREES).index(kind))
    model = TREES[kind](rng)
    for _ in range(2):
        check_against_oracle(model, random_state(model, rng), rng)


# ----------------------------------------------------------------------------- invariances
def _relabelled(model, order):
    """The same vehicle with body order[i] renamed i (order[0] == 0, parents before children)."""
    d = jaxtree.scene_to_dict(model)
    new_of = {old: new for new, old in enumerate(order)}
    bodies = []
    for old in order:
        b = dict(d["bodies"][old])
        if old:
            b["parent"] = new_of[b["parent"]]
        bodies.append(b)
    perm = [o - 1 for o in order[1:]]
    initial = dict(d["initial"])
    initial["gamma"] = [initial["gamma"][p] for p in perm]
    initial["gamma_dot"] = [initial["gamma_dot"][p] for p in perm]
    return jaxtree.scene_from_dict({**d, "bodies": bodies, "initial": initial}), np.asarray(perm)


def _random_topological_order(topology, rng):
    order, frontier = [0], list(topology.children[0])
    while frontier:
        k = frontier.pop(rng.integers(len(frontier)))
        order.append(k)
        frontier.extend(topology.children[k])
    return order


@pytest.mark.parametrize("name", ["fig4_free", "wings"])
def test_relabelling_permutes_the_result(scenes, name):
    model = scenes[name]
    rng = np.random.default_rng(17)
    order = _random_topological_order(model.topology, rng)
    assert order != list(range(model.n + 1))
    other, perm = _relabelled(model, order)
    s = random_state(model, rng)
    s2 = jaxtree.State(s.dcm, s.omega0, s.gamma[perm], s.gamma_dot[perm])
    a = accelerations(model, s, 0.0, None)
    b = accelerations(other, s2, 0.0, None)
    assert rel(b.omega0_dot, a.omega0_dot) < RTOL
    assert rel(b.gamma_ddot, a.gamma_ddot[perm]) < RTOL
    A = np.asarray(jaxtree.mass_matrix(model, s.gamma))
    idx = np.concatenate([np.arange(3), perm + 3])
    assert rel(jaxtree.mass_matrix(other, s2.gamma), A[np.ix_(idx, idx)]) < RTOL


@pytest.mark.parametrize("attach", [0, 4, 9])
def test_massless_leaf_changes_nothing(scenes, attach):
    model = scenes["fig4_free"]
    d = jaxtree.scene_to_dict(model)
    leaf = {
        "name": "probe",
        "mass": 0.0,
        "inertia": np.zeros((3, 3)).tolist(),
        "parent": attach,
        "axis": [0.3, -0.5, 0.8],
        "hinge_on_parent": [0.2, 0.1, -0.3],
        "hinge_on_body": [0.0, 0.0, 0.0],
        "joint": {"kind": "free"},
    }
    d["bodies"] = d["bodies"] + [leaf]
    d["initial"] = {
        **d["initial"],
        "gamma": d["initial"]["gamma"] + [0.7],
        "gamma_dot": d["initial"]["gamma_dot"] + [-1.3],
    }
    bigger = jaxtree.scene_from_dict(d)
    assert bigger.inert == (model.n + 1,)
    rng = np.random.default_rng(attach)
    s = random_state(model, rng)
    s2 = jaxtree.State(s.dcm, s.omega0, jnp.append(s.gamma, 0.7), jnp.append(s.gamma_dot, -1.3))
    a = accelerations(model, s, 0.0, None)
    b = accelerations(bigger, s2, 0.0, None)
    assert rel(b.omega0_dot, a.omega0_dot) < RTOL
    assert rel(b.gamma_ddot[:-1], a.gamma_ddot) < RTOL
    A = jaxtree.mass_matrix(bigger, s2.gamma)
    assert rel(A[:-1, :-1], jaxtree.mass_matrix(model, s.gamma)) < RTOL
    assert np.all(np.asarray(A[-1]) == 0)  # an inert hinge has an exactly zero row


# ----------------------------------------------------------------------------- prescribed hinges
def test_prescribed_hinge_hold_torque(scenes):
    """Sec. II B: the hold torque of the prescribed fig4 run, applied to the same vehicle with
    hinge 1 free, reproduces the prescribed acceleration and all the others."""
    model = scenes["fig4"]
    d = jaxtree.scene_to_dict(model)
    d["bodies"][1]["joint"] = {"kind": "free"}
    free = jaxtree.scene_from_dict(d)
    rng = np.random.default_rng(23)
    s = random_state(model, rng)
    t = 1.7
    acc = accelerations(model, s, t, None)
    g, gd, gdd = model.prescription.derivatives(t)
    np.testing.assert_allclose(g, np.sin(0.5 * t), rtol=ULPS)
    np.testing.assert_allclose(gdd, -0.25 * np.sin(0.5 * t), rtol=ULPS)
    s_free = jaxtree.State(s.dcm, s.omega0, s.gamma.at[0].set(g[0]), s.gamma_dot.at[0].set(gd[0]))
    tau = jnp.zeros(model.n).at[0].set(acc.hold_torque[0])
    ref = accelerations(free, s_free, t, tau)
    assert rel(ref.gamma_ddot, acc.gamma_ddot) < RTOL
    assert rel(ref.omega0_dot, acc.omega0_dot) < RTOL


# ----------------------------------------------------------------------------- JAX transformations
def test_vmap_matches_single_calls(scenes):
    model = scenes["fig4"]
    rng = np.random.default_rng(31)
    states = [random_state(model, rng) for _ in range(4)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *states)
    f = jax.jit(jax.vmap(jaxtree.forward_dynamics, (None, 0, 0, 0, 0, None)))
    w, g = f(model, batch.dcm, batch.omega0, batch.gamma, batch.gamma_dot, 0.4)
    for i, s in enumerate(states):
        w1, g1 = jaxtree.forward_dynamics(model, s.dcm, s.omega0, s.gamma, s.gamma_dot, 0.4)
        assert rel(w[i], w1) < SAME_ARITHMETIC and rel(g[i], g1) < SAME_ARITHMETIC


def test_gradients_match_finite_differences(scenes):
    """d(accelerations)/d(mass, geometry, stiffness) by jax.grad against central differences."""
    model = scenes["fig4_free"]
    s = random_state(model, np.random.default_rng(41))

    def objective(m):
        w, g = jaxtree.forward_dynamics(m, s.dcm, s.omega0, s.gamma, s.gamma_dot)
        return jnp.sum(w * jnp.arange(1.0, 4.0)) + jnp.sum(g * jnp.linspace(-1, 1, m.n))

    grads = jax.jit(jax.grad(objective))(model)
    f = jax.jit(objective)
    for field, index in [("mass", 6), ("hinge_on_parent", (5, 0)), ("stiffness", 7), ("inertia", (4, 2, 2))]:
        h = 1e-6 * max(1.0, abs(float(getattr(model, field)[index])))
        bump = lambda d: jaxtree._src.vehicle.model.eqx.tree_at(
            lambda m: getattr(m, field), model, getattr(model, field).at[index].add(d)
        )
        fd = (f(bump(h)) - f(bump(-h))) / (2 * h)
        assert abs(float(getattr(grads, field)[index] - fd)) <= FD * max(1.0, abs(float(fd))), field


def test_eager_nonfinite_accelerations_raise_with_a_diagnosis(scenes):
    """An eager call that would return NaN raises DynamicsError with the state and the cause;
    under jit the function stays pure (NaN out, no host check)."""
    model = scenes["fig4"]
    s = model.initial
    gd = np.asarray(s.gamma_dot, float).copy()
    gd[4] = np.nan
    with pytest.raises(jaxtree.DynamicsError, match="not finite: gamma_dot"):
        jaxtree.forward_dynamics(model, s.dcm, s.omega0, s.gamma, jnp.asarray(gd))
    with pytest.raises(jaxtree.DynamicsError, match="not finite: gamma_dot"):
        jaxtree.solve_accelerations(model, s._replace(gamma_dot=jnp.asarray(gd)))
    w, g = jax.jit(jaxtree.forward_dynamics)(model, s.dcm, s.omega0, s.gamma, jnp.asarray(gd))
    assert not np.all(np.isfinite(np.asarray(g)))


def test_singular_matrix_diagnosis_names_the_locked_gimbal(scenes):
    """fig4 with the inner gimbal at 90 degrees: the outer gimbal's axis and the rotor's axis are
    parallel (checked from the configuration), Eq. (1)'s matrix is singular, and the diagnosis
    names exactly those two hinges."""
    from jaxtree._src.equations.dynamics import _diagnose

    model = scenes["fig4"]
    s = model.initial
    gamma = np.asarray(s.gamma, float).copy()
    gamma[2] = np.pi / 2
    cfg = jaxtree.configuration(model, jnp.asarray(gamma))
    g2, g4 = np.asarray(cfg.axis[1]), np.asarray(cfg.axis[3])
    assert np.linalg.norm(np.cross(g2, g4)) < ROUNDOFF  # the two axes are aligned
    text = _diagnose("forward_dynamics", model, s._replace(gamma=jnp.asarray(gamma)), 0.0, None)
    assert "singular" in text and "gimbal lock" in text
    direction = text.split("near-null direction:")[1].split(". Rates")[0]
    assert "hinge 2 (gimbal_outer)" in direction and "hinge 4 (rotor)" in direction
    assert direction.count("hinge") == 2 and "omega0" not in direction


def test_float32(scenes):
    model = scenes["fig4_free"]
    s = random_state(model, np.random.default_rng(43), scale=0.5)
    w64, g64 = jaxtree.forward_dynamics(model, s.dcm, s.omega0, s.gamma, s.gamma_dot)
    m32 = model.astype(jnp.float32)
    s32 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), s)
    w32, g32 = jax.jit(jaxtree.forward_dynamics)(m32, s32.dcm, s32.omega0, s32.gamma, s32.gamma_dot)
    assert w32.dtype == jnp.float32 and g32.dtype == jnp.float32
    assert rel(w32, w64) < FLOAT32 and rel(g32, g64) < FLOAT32


def _dot_precisions(closed_jaxpr):
    """The precision of every dot_general in a jaxpr, nested jaxprs (jit, while, cond) included."""
    return [e.params["precision"] for e in jaxpr_equations(closed_jaxpr.jaxpr) if e.primitive.name == "dot_general"]


def test_float32_products_run_at_full_precision(scenes):
    """Every matrix product that Eq. (1) and a simulation trace asks for full precision: JAX's
    default would let GPUs run float32 products in TF32 (~1e-3), which the GPU benchmark showed
    turns float32 accelerations into noise (benchmarks/README.md)."""
    model = scenes["fig4"].astype(jnp.float32)
    s = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), model.initial)
    highest = (jax.lax.Precision.HIGHEST, jax.lax.Precision.HIGHEST)
    traced = {
        "forward_dynamics": jax.make_jaxpr(jaxtree.forward_dynamics)(model, s.dcm, s.omega0, s.gamma, s.gamma_dot),
        "mass_matrix": jax.make_jaxpr(jaxtree.mass_matrix)(model, s.gamma),
        "simulate": jax.make_jaxpr(lambda m: jaxtree.simulate(m, 1.0, saveat=3, throw=False).gamma)(model),
    }
    for name, jaxpr in traced.items():
        precisions = _dot_precisions(jaxpr)
        assert precisions, name
        assert all(p == highest for p in precisions), (name, precisions)


def test_loads_are_not_traced_when_absent(scenes):
    """A model without loads compiles to fewer operations than the same model with loads."""
    model = scenes["fig4_free"]
    loaded, _, _ = with_random_loads(model, np.random.default_rng(0), (0, 3))
    s = model.initial

    def flops(m):
        c = jax.jit(jaxtree.forward_dynamics).lower(m, s.dcm, s.omega0, s.gamma, s.gamma_dot).compile()
        ca = c.cost_analysis()
        return (ca[0] if isinstance(ca, list) else ca)["flops"]

    def n_eqns(m):
        return count_equations(jax.make_jaxpr(jaxtree.forward_dynamics)(m, s.dcm, s.omega0, s.gamma, s.gamma_dot).jaxpr)

    assert flops(model) < flops(loaded)
    assert n_eqns(model) < n_eqns(loaded)


def test_single_rigid_body_is_eulers_equations():
    """n = 0 (a tree of one body): Eq. (1) is Euler's equation I w' = -w x I w."""
    J = np.array([[3.0, 0.1, 0.0], [0.1, 4.0, 0.2], [0.0, 0.2, 5.0]])
    model = jaxtree.build_model([jaxtree.Body("rock", 2.0, J)], {"omega0": [0.3, -0.2, 0.5]})
    w = np.array([0.3, -0.2, 0.5])
    wd, gdd = jaxtree.forward_dynamics(model, np.eye(3), w, np.zeros(0), np.zeros(0))
    np.testing.assert_allclose(
        np.asarray(wd), -np.linalg.solve(J, np.cross(w, J @ w)), rtol=EULER_RTOL, atol=EULER_ATOL
    )
    assert gdd.shape == (0,)
    np.testing.assert_allclose(np.asarray(jaxtree.mass_matrix(model, np.zeros(0))), J, rtol=EULER_INERTIA)


def test_wrong_state_shapes_are_named():
    """A state vector of the wrong length fails with the function, the field and the shape the
    model needs (not a broadcasting error deep inside, nor a clamped gather that runs), also under
    jit; vmapped batches are checked per member."""
    model = jaxtree.load_scene("chain10")
    s = model.initial
    need = r"the model 'chain10' with 10 hinges needs"
    with pytest.raises(ValueError, match=rf"mass_matrix: gamma has shape \(9,\); {need} \(10,\)"):
        jaxtree.mass_matrix(model, s.gamma[:-1])
    with pytest.raises(ValueError, match=rf"forward_dynamics: gamma_dot has shape \(12,\); {need} \(10,\)"):
        jaxtree.forward_dynamics(model, s.dcm, s.omega0, s.gamma, jnp.zeros(12))
    with pytest.raises(ValueError, match=rf"forward_dynamics: omega0 has shape \(4,\); {need} \(3,\)"):
        jax.jit(jaxtree.forward_dynamics)(model, s.dcm, jnp.zeros(4), s.gamma, s.gamma_dot)
    with pytest.raises(ValueError, match=r"solve_accelerations: tau has shape \(3,\)"):
        jaxtree.solve_accelerations(model, s, tau=jnp.zeros(3))
    with pytest.raises(ValueError, match=r"kinetic_energy: dcm has shape \(2, 2\)"):
        jaxtree.kinetic_energy(model, s._replace(dcm=jnp.eye(2)))
    batch = jax.vmap(lambda g: jaxtree.forward_dynamics(model, s.dcm, s.omega0, g, s.gamma_dot)[1])(jnp.zeros((4, 10)))
    assert batch.shape == (4, 10)
