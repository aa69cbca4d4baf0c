"""The main entry points compile once per shape: called again with the same shapes and other
values (initial state, spring constants, spin rate, end time) they neither trace nor compile
anything. Counted with JAX's public monitoring events (``jax.monitoring``): one
``jaxpr_trace_duration`` event per trace of a jitted function, one ``backend_compile_duration``
event per XLA compilation (eager operations included). The smallest bundled scene,
``appendix_c`` (two hinges), keeps the first compilations short (the module takes about 25 s
of CPU, most of it the hybrid model's build and first run)."""

import collections
import contextlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree

_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "traces",
    "/jax/core/compile/backend_compile_duration": "compiles",
}
_SEEN = collections.Counter()  # every trace and compilation of this process since the import
# one listener for the process, never removed (as in test_fuzz.py)
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration_secs, **kwargs: _SEEN.update([_EVENTS[event]]) if event in _EVENTS else None
)


@contextlib.contextmanager
def compilations():
    """Counts the traces and XLA compilations inside, as a Counter {"traces": .., "compiles": ..}."""
    before = _SEEN.copy()
    counts = collections.Counter()
    yield counts
    counts.update(_SEEN - before)


@pytest.fixture(scope="module")
def scene():
    """appendix_c and the same scene with other values: initial state and spring constants."""
    model = jaxtree.load_scene("appendix_c")
    s = model.initial
    other = eqx.tree_at(
        lambda m: (m.initial.omega0, m.initial.gamma, m.initial.gamma_dot, m.stiffness),
        model,
        (s.omega0 * 1.2 + jnp.array([0.05, -0.03, 0.0]), s.gamma * -1.5, s.gamma_dot + 0.02, model.stiffness * 1.3),
    )
    return model, other


def test_the_counter_sees_a_compilation():
    """A new shape is traced and compiled once, and counted (the tests below are not vacuous)."""
    f = jax.jit(lambda x: jnp.sin(x) * 3.0)
    x, y = np.ones(17), np.full(17, 2.0)  # numpy: strong float64, no weak type
    with compilations() as c:
        f(x)
    assert c["traces"] >= 1 and c["compiles"] >= 1, dict(c)
    with compilations() as c:
        f(y)
    assert not c, dict(c)


def test_simulate(scene):
    model, other = scene
    first = jaxtree.simulate(model, 1.0)
    with compilations() as c:
        second = jax.block_until_ready(jaxtree.simulate(other, 1.5))
    assert not c, dict(c)
    assert second.stats["solver"].name == first.stats["solver"].name  # the same path, other numbers
    assert float(second.ts[-1]) == 1.5 and not np.allclose(second.gamma, first.gamma)


def test_forward_dynamics_jitted(scene):
    model, other = scene

    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def accelerations(model, state):
        return jaxtree.forward_dynamics(model, *state)

    first = accelerations(model, model.initial)
    with compilations() as c:
        second = jax.block_until_ready(accelerations(other, other.initial))
    assert not c, dict(c)
    assert not np.allclose(second[1], first[1])  # (omega0_dot, gamma_ddot)


def test_linearize_and_modes(scene):
    model, other = scene
    spin = np.array([0.0, 0.0, 1.0])
    first = jaxtree.modes(jaxtree.linearize(model, (1, 2), omega0=spin))
    with compilations() as c:
        lin = jaxtree.linearize(other, (1, 2), omega0=1.4 * spin)
        second = jax.block_until_ready(jaxtree.modes(lin))
    assert not c, dict(c)
    assert second.kind == first.kind
    assert not np.allclose(second.frequencies, first.frequencies)


def test_simulate_hybrid(scene, monkeypatch):
    """One hybrid model (building it is the costly part), run from two initial states to two end
    times; and the projection of a physical start on the modes is compiled with the rest: the
    second run calls no Python of ``HybridModel.pack`` (op by op, the projection cost flex95's
    slew ~30 ms a run, as much as its integration)."""
    model, other = scene
    hybrid = jaxtree.hybrid_model(model, (1, 2), omega0=[0.0, 0.0, 1.0], basis="set")
    first = jaxtree.simulate_hybrid(hybrid, 1.0)
    calls = collections.Counter()
    pack = jaxtree.HybridModel.pack

    def counted(self, state):
        calls["pack"] += 1
        return pack(self, state)

    monkeypatch.setattr(jaxtree.HybridModel, "pack", counted)
    with compilations() as c:
        second = jax.block_until_ready(jaxtree.simulate_hybrid(hybrid, 1.5, y0=other.initial))
    assert not c, dict(c)
    assert calls["pack"] == 0, dict(calls)
    assert not np.allclose(second.gamma, first.gamma)


def test_an_eager_call_is_one_program():
    """Eq. (1), its energy and the appendage builders called eagerly (outside any jit): each call
    compiles one program, not each of its operations on its own (hundreds for Eq. 1: seconds of
    a notebook's first cell), and a loop over times compiles once. A tree of a shape no other
    test uses, so nothing is in JAX's caches yet."""
    rng = np.random.default_rng(7)
    bodies = [jaxtree.Body("base", 50.0, np.diag([10.0, 12.0, 14.0]))]
    for k in range(1, 8):
        axis = rng.normal(size=3)
        bodies.append(
            jaxtree.Body(
                f"b{k}",
                1.0 + k,
                np.diag([1.0, 1.5, 2.0]),
                int(rng.integers(k)),
                tuple(axis / np.linalg.norm(axis)),
                tuple(rng.normal(size=3)),
                tuple(rng.normal(size=3)),
            )
        )
    model = jaxtree.build_model(
        bodies, {"gamma": rng.normal(size=7).tolist(), "gamma_dot": rng.normal(size=7).tolist()}
    )
    s = model.initial
    with compilations() as c:
        acc = jaxtree.solve_accelerations(model, s, 0.25)
    assert 1 <= c["compiles"] <= 2, dict(c)
    with compilations() as c:
        for t in (0.5, 1.0, np.float64(1.5)):
            jaxtree.solve_accelerations(model, s, t)
        energy = jaxtree.kinetic_energy(model, s)
    assert c["compiles"] <= 2, dict(c)
    # the same numbers as the traced path, which a jit of the caller's takes
    want = jax.jit(lambda m, st: jaxtree.solve_accelerations(m, st, 0.25))(model, s)
    np.testing.assert_allclose(acc.gamma_ddot, want.gamma_ddot, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(energy, jax.jit(jaxtree.kinetic_energy)(model, s), rtol=1e-13)
    fe = jaxtree.beam(1.7, 9, E=7e10, rho=2700.0, area=1e-4, Iy=1e-8)
    with compilations() as c:
        jaxtree.appendage(fe, "b3", n_modes=3)
    assert c["compiles"] <= 2, dict(c)  # the held-interface modes, then the rest


def test_a_notebook_session_compiles_nothing_twice(scene):
    """What a user changes while exploring a vehicle in a notebook (the number of save points
    within its size bucket, the save times themselves, t1, the tolerances, a mass, the initial
    rate) reuses the programs of the first runs: simulate, linearize and modes again compile
    and trace nothing. The runs are still the runs asked for: the requested rows, the same
    trajectory where only the save grid changed, other numbers where the model changed."""
    model, other = scene
    spin = np.array([0.0, 0.0, 1.0])
    first = jaxtree.simulate(model, 1.0)  # the default grid: 101 save points
    jaxtree.simulate(model, 1.0, saveat=np.linspace(0.0, 1.0, 33))  # a grid of the user's
    jaxtree.modes(jaxtree.linearize(model, (1, 2), omega0=spin))
    heavier = eqx.tree_at(lambda m: m.mass, model, model.mass * jnp.linspace(1.0, 1.3, model.mass.shape[0]))
    faster = eqx.tree_at(lambda m: m.initial.omega0, model, model.initial.omega0 + jnp.array([0.0, 0.0, 0.2]))
    times = np.linspace(0.1, 0.9, 80)
    with compilations() as c:
        coarse = jax.block_until_ready(jaxtree.simulate(model, 1.0, saveat=57))
        at_times = jax.block_until_ready(jaxtree.simulate(model, 1.0, saveat=times))
        longer = jax.block_until_ready(jaxtree.simulate(model, 2.0))
        looser = jax.block_until_ready(jaxtree.simulate(model, 1.0, rtol=1e-6, atol=1e-8))
        runs = [jax.block_until_ready(jaxtree.simulate(m, 1.0)) for m in (heavier, faster)]
        lin = jaxtree.linearize(heavier, (1, 2), omega0=1.3 * spin)
        heavy_modes = jax.block_until_ready(jaxtree.modes(lin))
    assert not c, dict(c)
    # the rows asked for, at the times asked for
    assert coarse.gamma.shape == (57, model.n) and at_times.gamma.shape == (80, model.n)
    np.testing.assert_allclose(coarse.ts, np.linspace(0.0, 1.0, 57), rtol=0, atol=4e-16)
    np.testing.assert_array_equal(at_times.ts, times)
    assert coarse.energy.shape == (57,) and at_times.angular_momentum.shape == (80, 3)
    # one trajectory whatever the grid: the same steps, so the same end, to the bit
    np.testing.assert_array_equal(coarse.gamma[-1], first.gamma[-1])
    np.testing.assert_array_equal(coarse.gamma[::14], first.gamma[::25])  # t = 0, 0.25, 0.5, 0.75, 1
    assert float(longer.ts[-1]) == 2.0 and int(looser.stats["num_steps"]) < int(first.stats["num_steps"])
    for run in runs:
        assert not np.allclose(run.gamma, first.gamma)
    assert heavy_modes.frequencies.shape[0] > 0
