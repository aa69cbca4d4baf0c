"""The batch-first evaluation of Eq. (1) (``jaxtree._src.equations.batched``), which ``jax.vmap``
of the engine runs on a CPU from ``BATCH_FIRST_MIN`` members on: the same accelerations and
holding torques as the single-member solves (each held to the Lagrange oracle and the printed
equations elsewhere) on every bundled scene, on random trees with massless gimbal frames, inert
hinges, a prescribed hinge, loads and dispersed parameters, in float32, and under derivatives."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.equations import dynamics, rules, solve

from helpers import equations, random_state, scene_names
from trees import deep_and_wide, gimbal_model, random_tree

# Both paths solve the same equations in a different order of operations (an articulated-body
# recursion against a Cholesky factorization or a blocked recursion): round-off amplified by the
# condition number of Eq. (1)'s matrix (random states put gimbals near lock: up to ~1e8). A
# difference relative to the largest acceleration within CONDITIONED x cond x eps, and never above
# ROUNDOFF where the matrix is well conditioned.
CONDITIONED = 100.0
ROUNDOFF = 1e-11
# float32 against float64 on the same members: single precision amplified by the condition
FLOAT32 = 2e-3

B = solve.BATCH_FIRST_MIN  # the CPU's threshold (the tests below run on a CPU or pass the path explicitly)


def rel(a, b):
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def states(model, seed, size=B, scale=0.5):
    rng = np.random.default_rng(seed)
    members = [random_state(model, rng, scale) for _ in range(size)]
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *members)


def accelerations(model, state, t=0.3, tau=None):
    """``jaxtree.solve_accelerations`` of a batch of states (and of models, when `model` has
    stacked leaves: ``model_axes``), vmapped: the batch-first path."""
    return jax.vmap(lambda s: jaxtree.solve_accelerations(model, s, t, tau))(state)


def one_by_one(model, state, t=0.3, tau=None, members=range(0, B, 9)):
    f = jax.jit(lambda s: jaxtree.solve_accelerations(model, s, t, tau))
    return {i: f(jax.tree_util.tree_map(lambda x: x[i], state)) for i in members}


def tolerance(model, state):
    """The round-off bound of a member: CONDITIONED x cond(Eq. 1) x eps, at least ROUNDOFF."""
    A, _ = dynamics.rotational_equations(model, state)
    cond = float(dynamics.matrix_condition(model, A)[0])
    return max(ROUNDOFF, CONDITIONED * cond * float(jnp.finfo(A.dtype).eps))


def assert_same(batch, singles, model, state):
    """`batch` (vmapped) against the single solves `singles` {member: Accelerations} of the
    members of `state` (a dict {member: State} or a stacked State)."""
    for i, acc in singles.items():
        si = state[i] if isinstance(state, dict) else jax.tree_util.tree_map(lambda x: x[i], state)
        tol = tolerance(model, si)
        for field in ("omega0_dot", "gamma_ddot", "hold_torque"):
            got, want = getattr(batch, field)[i], getattr(acc, field)
            if want.size:
                assert rel(got, want) < tol, (field, i, rel(got, want), tol)


def _runs_batch_first(closed) -> bool:
    """Whether a jaxpr holds operations of the batch-first recursion (named ``batch_first``)."""
    return any("batch_first" in str(e.source_info.name_stack) for e in equations(closed.jaxpr))


@pytest.mark.parametrize("name", ["wings", "chain50"])
def test_vmap_runs_the_batch_first_recursion(scenes, name):
    """From batch_first_min(model) members on, vmap lands in the batch-first program; a smaller
    batch vmaps the single-member solve. The threshold falls with the tree: 64 members for
    wings' 8 hinges, 16 for chain50's 50, whose single-member solve costs twice the recursion's
    share already at 16 (benchmarks/FINDINGS.md)."""
    model = scenes[name]
    size = solve.batch_first_min(model)
    assert (size < solve.batch_first_min(scenes["wings"])) == (name == "chain50")

    def program(size):
        s = states(model, 0, size)
        return jax.make_jaxpr(lambda s: accelerations(model, s))(s)

    assert _runs_batch_first(program(size))
    assert not _runs_batch_first(program(size - 1))


def test_the_accelerators_stages_on_a_cpu(scenes):
    """The recursion with the accelerator's stages ("none": fusion left to the compiler, tested
    here on a CPU) and with the CPU's (barriers) gives the single solves' accelerations, its
    chained levels scanned or unrolled alike; a stage mode that does not exist is named."""
    model = scenes["wings"]
    s = states(model, 12)
    singles = one_by_one(model, s)
    for stages, scan_min in (("none", solve.batched.SCAN_MIN), ("barrier", 1), ("none", 1)):
        batch = jax.jit(lambda s: solve.batch_first(model, s, 0.3, stages=stages, scan_min=scan_min))(s)
        assert_same(batch, singles, model, s)
    with pytest.raises(ValueError, match="stages must be"):
        solve.batch_first(model, s, 0.3, stages="cond")


def test_a_scanned_run_of_one_level(scenes):
    """fig4_free's levels (widths 2, 2, 3, 2, 1; only the second continues the first slot for
    slot) with every chained run scanned: a run of a single level has its axis of levels too."""
    model = scenes["fig4_free"]
    s = states(model, 5, size=3)
    units = solve.batched._units(solve.batched.plan(model.topology.parents, (), ()).levels, 1)
    assert ("run", 2, 2) in units
    batch = jax.jit(lambda s: solve.batch_first(model, s, 0.3, scan_min=1))(s)
    assert_same(batch, one_by_one(model, s, members=range(3)), model, s)


@pytest.mark.parametrize("name", scene_names())
def test_every_bundled_scene(scenes, name):
    model = scenes[name]
    s = states(model, 1)
    assert_same(jax.jit(lambda s: accelerations(model, s))(s), one_by_one(model, s), model, s)


def test_random_trees_gimbals_inert_prescribed_and_loads():
    """A deep-and-wide random tree with a massless leaf (an inert hinge), a prescribed hinge and
    state- and time-dependent loads on a massive body, a massless body and the base; and three
    orthogonal gimbal hinges through massless frames."""
    rng = np.random.default_rng(7)
    parents = deep_and_wide(rng, 24)
    leaf = max(set(range(1, 25)) - set(parents))
    model = random_tree(rng, parents, gimbals=(leaf,))
    assert leaf in model.inert

    def push(t, s):
        return jnp.array([jnp.sin(t), s.gamma[2], 1.0]), jnp.array([0.1, -s.omega0[0], jnp.cos(2 * t)])

    model = model.with_loads(jaxtree.PerBodyLoads({0: push, 5: push, leaf: push}))
    model = eqx.tree_at(
        lambda m: m.prescription,
        model,
        jaxtree.SinePrescription((3,), jnp.array([0.4]), jnp.array([1.3]), jnp.array([0.2])),
        is_leaf=lambda x: x is None,
    )
    s = states(model, 2)
    tau = jnp.linspace(-1.0, 1.0, model.n)
    batch = jax.jit(lambda s: accelerations(model, s, 0.8, tau))(s)
    assert_same(batch, one_by_one(model, s, 0.8, tau), model, s)
    assert np.all(np.asarray(batch.gamma_ddot)[:, leaf - 1] == 0.0)  # inert: no acceleration

    gimbals = gimbal_model(np.random.default_rng(8))
    s = states(gimbals, 3)
    assert_same(jax.jit(lambda s: accelerations(gimbals, s))(s), one_by_one(gimbals, s), gimbals, s)


def test_dispersed_parameters_and_times(scenes):
    """Every member its own masses, inertias, hinge geometry, stiffness and time (the model's
    leaves batched, as in a Monte Carlo campaign)."""
    model = scenes["fig4_free"]
    rng = np.random.default_rng(11)
    where = lambda m: (m.mass, m.inertia, m.hinge_on_parent, m.hinge_on_body, m.stiffness)
    spread = lambda shape: 1 + 0.1 * rng.uniform(-1, 1, size=shape)
    mass, inertia, hop, hob, stiffness = (np.asarray(a) for a in where(model))
    dispersed = tuple(
        jnp.asarray(a)
        for a in (
            mass * spread((B, 1)),
            inertia * spread((B, 1, 1, 1)),  # one factor per member: the inertias stay symmetric
            hop * spread((B,) + hop.shape),
            hob * spread((B,) + hob.shape),
            stiffness * spread((B,) + stiffness.shape),
        )
    )
    models = eqx.tree_at(where, model, dispersed)
    axes = eqx.tree_at(where, jax.tree_util.tree_map(lambda _: None, model), (0,) * 5, is_leaf=lambda x: x is None)
    s = states(model, 4)
    t = jnp.linspace(0.0, 5.0, B)
    f = jax.jit(jax.vmap(lambda m, s, t: jaxtree.solve_accelerations(m, s, t), in_axes=(axes, 0, 0)))
    batch = f(models, s, t)
    for i in range(0, B, 13):
        mi = eqx.tree_at(where, model, tuple(a[i] for a in dispersed))
        si = jax.tree_util.tree_map(lambda x: x[i], s)
        assert_same(batch, {i: jaxtree.solve_accelerations(mi, si, t[i])}, mi, {i: si})


def _scan_lengths(closed):
    """The lengths of the ``scan`` loops in a jaxpr, nested ones included."""
    return [e.params["length"] for e in equations(closed.jaxpr) if e.primitive.name == "scan"]


def test_a_batch_of_more_than_a_group_runs_group_after_group(scenes):
    """On a CPU a batch of more than BATCH_GROUP members runs the recursion group after group, as
    even as can be, the last group filled up by repeating the last member: 131 members of
    fig4_free with dispersed masses, states and times run as 3 groups of 44 (a loop of 3 in the
    program) and give each member's single solve, the first and last of each group and the last
    member included."""
    model = scenes["fig4_free"]
    size = 2 * solve.BATCH_GROUP + 3
    assert solve.member_groups(size) == (3, 44)
    assert solve.member_groups(solve.BATCH_GROUP) == (1, solve.BATCH_GROUP)
    rng = np.random.default_rng(13)
    masses = jnp.asarray(np.asarray(model.mass) * (1 + 0.1 * rng.uniform(-1, 1, (size, 1))))
    models = eqx.tree_at(lambda m: m.mass, model, masses)
    blank = jax.tree_util.tree_map(lambda _: None, model)
    axes = eqx.tree_at(lambda m: m.mass, blank, 0, is_leaf=lambda x: x is None)
    s = states(model, 6, size)
    t = jnp.linspace(0.0, 5.0, size)
    f = jax.vmap(lambda m, s, t: jaxtree.solve_accelerations(m, s, t), in_axes=(axes, 0, 0))
    program = jax.make_jaxpr(f)(models, s, t)
    assert _runs_batch_first(program) and 3 in _scan_lengths(program)
    batch = jax.jit(f)(models, s, t)
    for i in (0, 43, 44, 87, 88, 100, size - 1):
        mi = eqx.tree_at(lambda m: m.mass, model, masses[i])
        si = jax.tree_util.tree_map(lambda x: x[i], s)
        assert_same(batch, {i: jaxtree.solve_accelerations(mi, si, t[i])}, mi, {i: si})


def test_cos_and_sin_of_the_recursion_to_an_ulp():
    """The recursion's vectorizable cos and sin (``components.cos_sin``: fdlibm's polynomials
    after a reduction by pi/2) against numpy's, to an ulp of 1 for angles up to 1e5 rad and at
    the quadrants' edges; angles beyond 2^19 pi by the C library's; the derivatives -sin and cos;
    float32 by ``jnp.cos`` and ``jnp.sin``."""
    from jaxtree._src.equations.components import cos_sin

    rng = np.random.default_rng(21)
    edges = np.pi / 4 * np.arange(-16, 17)
    q = np.concatenate([rng.uniform(-s, s, 20000) for s in (1e-3, 1.0, 40.0, 1e5)] + [edges, edges + 1e-9])
    c, s = (np.asarray(x) for x in jax.jit(cos_sin)(q))
    assert np.max(np.abs(c - np.cos(q))) <= 2.3e-16 and np.max(np.abs(s - np.sin(q))) <= 2.3e-16
    big = np.array([0.3, 3.0e6, -1.0e9])
    c, s = (np.asarray(x) for x in jax.jit(cos_sin)(big))
    assert np.max(np.abs(c - np.cos(big))) <= 2.3e-16 and np.max(np.abs(s - np.sin(big))) <= 2.3e-16
    d = jax.jacfwd(lambda x: jnp.stack(cos_sin(x)))(0.7)
    np.testing.assert_allclose(np.asarray(d), [-np.sin(0.7), np.cos(0.7)], rtol=0, atol=2.3e-16)
    c32, s32 = cos_sin(jnp.float32(0.7))
    assert c32.dtype == jnp.float32 and abs(float(s32) - np.sin(0.7)) < 1e-7


def test_float32(scenes):
    model = scenes["wings"]
    s = states(model, 5)
    want = jax.jit(lambda s: accelerations(model, s))(s)
    m32 = model.astype(jnp.float32)
    s32 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float32), s)
    got = jax.jit(lambda s: accelerations(m32, s))(s32)
    assert got.gamma_ddot.dtype == jnp.float32
    for field in ("omega0_dot", "gamma_ddot"):
        assert rel(getattr(got, field), getattr(want, field)) < FLOAT32


def test_derivatives_of_the_vmapped_function(scenes):
    """jvp, grad and jacfwd of the vmapped accelerations equal the per-member ones."""
    model = scenes["fig4_free"]
    s = states(model, 6)
    s = s._replace(gamma=0.2 * s.gamma)  # away from gimbal lock: a moderate condition number
    f = lambda g, gd: jaxtree.forward_dynamics(model, s.dcm[0], s.omega0[0], g, gd)[1]
    tangent = jnp.ones_like(s.gamma)
    primal, jvp = jax.jit(jax.vmap(lambda g, gd, v: jax.jvp(lambda g: f(g, gd), (g,), (v,))))(
        s.gamma, s.gamma_dot, tangent
    )
    batched_primal = jax.jit(jax.vmap(f))(s.gamma, s.gamma_dot)
    grads = jax.jit(jax.vmap(jax.grad(lambda g, gd: jnp.sum(f(g, gd) ** 2))))(s.gamma, s.gamma_dot)
    jac = jax.jit(jax.vmap(jax.jacfwd(f)))(s.gamma, s.gamma_dot)
    for i in range(0, B, 21):
        si = jaxtree.State(s.dcm[0], s.omega0[0], s.gamma[i], s.gamma_dot[i])
        tol = tolerance(model, si)
        p1, j1 = jax.jvp(lambda g: f(g, s.gamma_dot[i]), (s.gamma[i],), (tangent[i],))
        assert rel(primal[i], p1) < tol and rel(batched_primal[i], p1) < tol
        # a tree this small keeps the implicit-function rule in a batch: the same arithmetic
        assert rel(jvp[i], j1) < ROUNDOFF
        g1 = jax.grad(lambda g: jnp.sum(f(g, s.gamma_dot[i]) ** 2))(s.gamma[i])
        assert rel(grads[i], g1) < ROUNDOFF
        assert rel(jac[i], jax.jacfwd(f)(s.gamma[i], s.gamma_dot[i])) < ROUNDOFF


def _prescribed_tree_with_loads():
    """A random tree of 10 bodies with a prescribed hinge, loads that depend on time and state,
    and hinge springs: every kind of input the rule differentiates."""
    rng = np.random.default_rng(21)
    model = random_tree(rng, deep_and_wide(rng, 10))

    def push(t, s):
        return jnp.array([jnp.sin(t), s.gamma[2], 1.0]), jnp.array([0.1, -s.omega0[0], jnp.cos(2 * t)])

    model = model.with_loads(jaxtree.PerBodyLoads({0: push, 4: push}))
    return eqx.tree_at(
        lambda m: m.prescription,
        model,
        jaxtree.SinePrescription((3,), jnp.array([0.4]), jnp.array([1.3]), jnp.array([0.2])),
        is_leaf=lambda x: x is None,
    )


@pytest.fixture
def batch_first_derivatives(monkeypatch):
    """Derivatives through the batch-first form for any tree (the engine keeps it for trees of
    BATCH_FIRST_DERIVATIVES_MIN bodies and more, whose programs compile for long), and a count
    of the batch-first programs differentiated."""
    monkeypatch.setattr(rules, "BATCH_FIRST_DERIVATIVES_MIN", 1)
    calls = []
    members = rules._members
    monkeypatch.setattr(rules, "_members", lambda *a: calls.append(1) or members(*a))
    return calls


def test_derivative_rule_in_the_batch_first_form(batch_first_derivatives):
    """Tangents along a mass, the whole state, the hinge torques and the time, of every output
    (holding torque included), by jacfwd and grad of the vmapped function: the batch-first
    recursion's derivatives equal each member's implicit-function rule."""
    model = _prescribed_tree_with_loads()
    s = states(model, 9)
    s = s._replace(gamma=0.3 * s.gamma)
    tau = jnp.linspace(-1.0, 1.0, model.n)

    def f(mass, omega0, gamma, gamma_dot, tau, t):
        m = eqx.tree_at(lambda m: m.mass, model, model.mass.at[2].set(mass))
        acc = jaxtree.solve_accelerations(m, jaxtree.State(s.dcm[0], omega0, gamma, gamma_dot), t, tau)
        return jnp.concatenate([acc.omega0_dot, acc.gamma_ddot, acc.hold_torque])

    rng = np.random.default_rng(3)
    mass = jnp.asarray(model.mass[2] * (1 + 0.1 * rng.uniform(-1, 1, B)))
    taus = jnp.tile(tau, (B, 1))
    times = jnp.linspace(0.0, 2.0, B)
    args = (mass, s.omega0, s.gamma, s.gamma_dot, taus, times)
    every = tuple(range(len(args)))
    jacfwd = jax.jacfwd(f, argnums=every)
    grad = jax.grad(lambda *a: jnp.sum(f(*a) ** 2), argnums=every)
    jac = jax.jit(jax.vmap(jacfwd))(*args)
    assert batch_first_derivatives  # the tangents of the batch-first program
    grads = jax.jit(jax.vmap(grad))(*args)
    jacfwd, grad = jax.jit(jacfwd), jax.jit(grad)
    for i in range(0, B, 21):
        ai = tuple(a[i] for a in args)
        tol = tolerance(model, jaxtree.State(s.dcm[0], s.omega0[i], s.gamma[i], s.gamma_dot[i]))
        for got, want in zip(jac + grads, jacfwd(*ai) + grad(*ai)):
            assert rel(got[i], want) < tol


def test_massless_bodies_masses_are_no_parameters_in_a_batch_either(batch_first_derivatives):
    """The single-member solve leaves the scene's massless bodies out (their mass and inertia
    leaves are no parameters: the derivatives along them are zero); the batch-first recursion
    and its derivatives treat them so too, instead of differentiating their zero masses (which
    gave fig4_free's gimbal frames a derivative like their neighbours'). Gimbal frames, the
    gradient along every mass by the vmapped batch-first form against each member's."""
    model = gimbal_model(np.random.default_rng(8))
    light = [k for k in range(model.n + 1) if k not in model.massive]
    assert light
    s = states(model, 14)

    def loss(mass, state):
        m = eqx.tree_at(lambda m: m.mass, model, mass)
        acc = jaxtree.solve_accelerations(m, state)
        return jnp.sum(acc.omega0_dot**2) + jnp.sum(acc.gamma_ddot**2)

    batch = jax.jit(jax.vmap(jax.grad(loss), in_axes=(None, 0)))(model.mass, s)
    assert batch_first_derivatives
    one = jax.jit(jax.grad(loss))
    for i in range(0, B, 21):
        want = one(model.mass, jax.tree_util.tree_map(lambda x: x[i], s))
        assert np.all(np.abs(np.asarray(want)[light]) < 1e-12 * np.max(np.abs(np.asarray(want))))
        assert rel(batch[i], want) < tolerance(model, jax.tree_util.tree_map(lambda x: x[i], s))


def test_second_derivatives_through_the_rule(scenes, batch_first_derivatives):
    """The rule differentiated again: forward over forward under vmap equals each member's, and
    a member's forward-over-reverse Hessian (through the transposed solve) equals its
    forward-over-forward one and central differences of its gradient."""
    model = scenes["fig4_free"]
    s = states(model, 10)
    s = s._replace(gamma=0.2 * s.gamma)
    f = lambda g, gd: jnp.sum(jaxtree.forward_dynamics(model, s.dcm[0], s.omega0[0], g, gd)[1] ** 2)
    hessians = jax.jit(jax.vmap(jax.jacfwd(jax.jacfwd(f))))(s.gamma, s.gamma_dot)
    forward = jax.jit(jax.jacfwd(jax.jacfwd(f)))
    reverse = jax.jit(jax.jacfwd(jax.grad(f)))
    grad = jax.jit(jax.grad(f))
    for i in range(0, B, 31):
        g, gd = s.gamma[i], s.gamma_dot[i]
        tol = tolerance(model, jaxtree.State(s.dcm[0], s.omega0[0], g, gd))
        H = forward(g, gd)
        assert rel(hessians[i], H) < tol
        assert rel(reverse(g, gd), H) < tol
        h = 1e-6
        fd = jnp.stack([(grad(g.at[k].add(h), gd) - grad(g.at[k].add(-h), gd)) / (2 * h) for k in range(model.n)], 1)
        assert rel(fd, H) < 1e-6


def test_a_member_in_gimbal_lock_is_nan_and_its_batch_mates_are_not(scenes):
    """Hinge 3 of fig4_free at 90 deg aligns the rotor's axis with the outer gimbal's: Eq. (1) is
    singular there. The batch gives that member NaN (as the dense solve does) and the others
    their accelerations."""
    model = scenes["fig4_free"]
    s = model.initial
    lock = np.arange(B) % 3 == 0
    gamma = jnp.tile(s.gamma, (B, 1)).at[lock, 2].set(jnp.pi / 2)
    rates = jnp.tile(s.gamma_dot, (B, 1)) + 0.01 * jnp.arange(B)[:, None] / B
    f = lambda g, gd: jaxtree.forward_dynamics(model, s.dcm, s.omega0, g, gd)[1]
    batch = np.asarray(jax.jit(jax.vmap(f))(gamma, rates))
    single = jax.jit(f)
    assert np.all(np.isnan(batch[lock])) and np.all(np.isnan(np.asarray(single(gamma[0], rates[0]))))
    assert np.all(np.isfinite(batch[~lock]))
    for i in np.flatnonzero(~lock)[::7]:
        member = jaxtree.State(s.dcm, s.omega0, gamma[i], rates[i])
        assert rel(batch[i], single(gamma[i], rates[i])) < tolerance(model, member)
