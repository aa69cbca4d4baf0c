"""A user's eager ``jax.vmap`` of ``simulate`` split over the host devices
(jaxtree/_src/integration/spread.py): the same members as one device runs them, each its single
run, failures reported with their indices in the user's batch, and the plain ``vmap`` kept inside
the user's ``jit`` and under derivatives."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.integration import spread

# the host devices (one per core; JAXTREE_HOST_DEVICES=1 gives one): with one, nothing is split
# and the plain vmap must give the same members
DEVICES = spread.host_devices()


def split_over(size):
    """The devices a batch of `size` members is split over, or None where it runs unsplit."""
    return min(DEVICES, size) if DEVICES > 1 else None


T1, TOL = 1.0, 1e-9


@pytest.fixture
def splits(monkeypatch):
    """The calls of the split run: (batch size, devices, group) each."""
    calls = []
    inner = spread._split

    def counted(fn, args, flags, size, devices, group):
        calls.append((size, devices, group))
        return inner(fn, args, flags, size, devices, group)

    monkeypatch.setattr(spread, "_split", counted)
    return calls


def rates(n, seed=0):
    return jnp.asarray(0.05 * np.random.default_rng(seed).normal(size=(n, 3)))


def test_an_eager_vmap_is_split_and_each_member_is_its_single_run(scenes, splits):
    """Five fig4_free members (padded to six, three a device): every history equals the member's
    own run to the tolerance's order, and the one-device batch of the user's jit to round-off."""
    model = scenes["fig4_free"]

    def run(w):
        return jaxtree.simulate(model, T1, y0=model.initial._replace(omega0=w), saveat=5, rtol=TOL, atol=TOL)

    w = rates(5)
    split = jax.vmap(run)(w)
    # one split run; the dense method's groups for LAPACK (217 members of fig4_free) hold a share
    if split_over(5):
        ((size, devices, group),) = splits
        assert (size, devices) == (5, split_over(5)) and group >= 3
    else:
        assert splits == []
    together = jax.jit(jax.vmap(run))(w)
    assert len(splits) == (1 if split_over(5) else 0)  # inside the user's jit the batch is the user's program
    for i in range(5):
        single = run(w[i])
        np.testing.assert_allclose(np.asarray(split.gamma[i]), np.asarray(single.gamma), atol=1e-7)
        np.testing.assert_allclose(np.asarray(split.omega0[i]), np.asarray(single.omega0), atol=1e-7)
    np.testing.assert_allclose(np.asarray(split.gamma), np.asarray(together.gamma), atol=1e-7)
    assert np.all(np.asarray(split.failure) == 0)
    # the diagnostics ran on the split histories: energy conserved as in the single runs
    assert float(jnp.max(jnp.abs(split.energy[:, -1] - split.energy[:, 0]) / jnp.abs(split.energy[:, 0]))) < 1e-7


def test_a_failure_is_named_by_its_index_in_the_users_batch(scenes, splits):
    """Member 3 of five starts with a non-finite rate: the report names batch index 3 (on the
    second device it is that device's first member)."""
    model = scenes["fig4_free"]
    w = rates(5).at[3, 0].set(jnp.nan)

    def run(w):
        return jaxtree.simulate(model, T1, y0=model.initial._replace(omega0=w), saveat=3).gamma

    # split: a SimulationError from the host; unsplit: the same report from the run's callback
    error = jaxtree.SimulationError if split_over(5) else Exception
    with pytest.raises(error, match=r"(?s)\[batch index \(3,\)\].*initial state is not finite"):
        jax.block_until_ready(jax.vmap(run)(w))
    assert [s[:2] for s in splits] == ([(5, split_over(5))] if split_over(5) else [])


def test_an_implicit_solver_runs_each_devices_members_one_after_another(splits):
    """Radau5 on a stiff chain: a device's members in a plain loop (group 1), each taking its
    single run's steps."""
    model = jaxtree.stiff_chain(1e6)
    ks = jnp.asarray([0.9, 1.0, 1.1, 1.2])

    def run(k):
        m = eqx.tree_at(lambda m: m.stiffness, model, model.stiffness.at[-1].multiply(k))
        return jaxtree.simulate(m, 0.1, solver=jaxtree.Radau5(), rtol=1e-6, atol=1e-6, saveat=3)

    split = jax.vmap(run)(ks)
    assert splits == ([(4, split_over(4), 1)] if split_over(4) else [])
    for i in range(4):
        single = run(ks[i])
        assert int(split.stats["num_steps"][i]) == int(single.stats["num_steps"])
        np.testing.assert_allclose(np.asarray(split.gamma[i]), np.asarray(single.gamma), atol=1e-10)


def test_under_a_derivative_the_plain_vmap_runs(scenes, splits):
    """A gradient of the batch (vmap inside grad and grad inside vmap) never takes the split path,
    whose batching rule has no transpose."""
    model = scenes["fig4_free"]

    def final(w):
        sol = jaxtree.simulate(
            model, 0.3, y0=model.initial._replace(omega0=w), saveat=2, adjoint=diffrax.RecursiveCheckpointAdjoint()
        )
        return jnp.sum(sol.gamma[-1])

    w = rates(2)
    g1 = jax.grad(lambda w: jnp.sum(jax.vmap(final)(w)))(w)
    g2 = jax.vmap(jax.grad(final))(w)
    np.testing.assert_allclose(np.asarray(g1), np.asarray(g2), rtol=1e-8)
    assert splits == []


def test_an_eager_vmap_of_simulate_hybrid_is_split_too(scenes, splits):
    """wings in hybrid coordinates (4 modes), three initial hub rates: split over the devices,
    each member its single run; a member whose run fails is named by its batch index."""
    hm = jaxtree.hybrid_model(scenes["wings"], tuple(scenes["wings"].sprung), 4)
    start = scenes["wings"].initial

    def run(w, max_steps=4096):
        return jaxtree.simulate_hybrid(
            hm, 2.0, y0=start._replace(omega0=w), saveat=3, rtol=TOL, atol=TOL, max_steps=max_steps
        )

    w = rates(3, seed=1)
    split = jax.vmap(run)(w)
    assert [s[:2] for s in splits] == ([(3, split_over(3))] if split_over(3) else [])
    for i in range(3):
        single = run(w[i])
        np.testing.assert_allclose(np.asarray(split.gamma[i]), np.asarray(single.gamma), atol=1e-7)
        np.testing.assert_allclose(np.asarray(split.modal[i]), np.asarray(single.modal), atol=1e-7)
    bad = w.at[2, 1].set(jnp.inf)
    with pytest.raises(jaxtree.SimulationError if split_over(3) else Exception, match=r"(?s)\[batch index \(2,\)\]"):
        jax.block_until_ready(jax.vmap(run)(bad).gamma)
