"""Basilisk (pip package ``bsk``) as an independent integrator of the same vehicles: its
spinningBodyNDOFStateEffector chains on a spacecraft hub (Vaz Carneiro, Allard and Schaub 2023,
a back-substitution derivation of its own) against jaxtree's Eq. (1), and Basilisk's own energy
and angular momentum conservation on the mapped vehicle."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import jaxtree
from jaxtree.bench.peer_basilisk import basilisk_available, basilisk_run, basilisk_supports

from helpers import random_state
from trees import sprung_tree

TOL = 1e-12  # both integrators, relative and absolute
AGREE = 1e-8  # the agreement asked of the two trajectories (reached: a few 1e-10, see below)


def _compare(model, t1, ts):
    bsk = basilisk_run(model, t1, ts, integrator="rkf78", dt=0.01, rtol=TOL, atol=TOL)
    sol = jaxtree.simulate(model, t1, saveat=jnp.asarray(ts), rtol=TOL, atol=TOL)
    return {f: np.abs(np.asarray(getattr(sol, f)) - bsk[f]).max() for f in ("omega0", "gamma", "gamma_dot")}


def test_available_and_supports(scenes):
    assert basilisk_available()
    assert basilisk_supports(scenes["wings"]) is None
    assert basilisk_supports(scenes["chain10"]) is None
    assert "prescribed" in basilisk_supports(scenes["fig4"])
    assert "children" in basilisk_supports(scenes["fig4_free"])  # a branch within a wing


def test_wings_agree_with_jaxtree(scenes):
    """The `wings` scene over 2 s, saved every 0.1 s: hub rate and hinge angles and rates agree
    (max abs error over the save times; omega0 is in rad/s, the angles in rad)."""
    ts = np.linspace(0.0, 2.0, 21)
    err = _compare(scenes["wings"], 2.0, ts)
    assert max(err.values()) < AGREE, err


def test_random_chains_agree_with_jaxtree():
    """Oblique hinge axes, full inertia tensors, hinge points off the axes, a tumbling hub with
    a non-identity attitude and large hinge angles: two chains (1-2-3, 4-5) with springs and
    dampers. Checks every geometric convention of the mapping, not just those `wings` exercises."""
    rng = np.random.default_rng(7)
    model = sprung_tree(rng, [0, 1, 2, 0, 4], damping=0.5)
    state = random_state(model, rng, scale=0.5)
    model = eqx.tree_at(lambda m: m.initial, model, state)
    err = _compare(model, 1.0, np.linspace(0.0, 1.0, 11))
    assert max(err.values()) < AGREE, err


def _undamped_wings(scenes):
    model = scenes["wings"]
    return eqx.tree_at(lambda m: m.damping, model, jnp.zeros_like(model.damping))


def test_conservation_without_damping(scenes):
    """`wings` with the dampers removed: Basilisk's total rotational energy (kinetic about the
    system mass center plus the springs') and its angular momentum about the mass center stay
    constant, and their initial values are jaxtree's kinetic energy plus the closed-form spring
    energy sum(k gamma^2 / 2) and jaxtree's angular momentum (inertial components)."""
    model = _undamped_wings(scenes)
    t1, dt = 5.0, 0.01
    ts = np.linspace(0.0, t1, 51)
    out = basilisk_run(model, t1, ts, integrator="rkf78", dt=dt, rtol=TOL, atol=TOL, diagnostics=True)
    E, H = out["energy"], out["angular_momentum"]
    k, g0 = np.asarray(model.stiffness), np.asarray(model.initial.gamma)
    E0 = float(jaxtree.kinetic_energy(model, model.initial)) + 0.5 * np.sum(k * g0**2)
    H0 = np.asarray(jaxtree.angular_momentum(model, model.initial))
    np.testing.assert_allclose(E[0], E0, rtol=1e-12)
    np.testing.assert_allclose(H[0], H0, rtol=0, atol=1e-12 * np.linalg.norm(H0))
    # each task step's local errors are held to TOL relative to states of order one: over
    # t1 / dt = 500 steps the drift stays below 2 * 500 * TOL (observed 1.0e-10 in energy)
    bound = 2 * (t1 / dt) * TOL
    assert np.abs(E - E[0]).max() < bound * E0
    assert np.abs(H - H[0]).max() < bound * np.linalg.norm(H0)
    # and the springs do work: energy moves between them and the motion
    assert np.ptp(out["gamma"]) > 0.05


def test_rk4_drift_converges_at_fifth_order(scenes):
    """What drift remains is the integrator's: RK4's amplification factor on an undamped mode,
    |R(i h w)|^2 = 1 - (h w)^6 / 72 + ..., loses energy O(h^6) a step, O(h^5) over a fixed time.
    Halving the step divides the energy and angular momentum errors by 2^5."""
    model = _undamped_wings(scenes)
    ts = np.linspace(0.0, 2.0, 21)
    drift = []
    for dt in (0.005, 0.0025):
        out = basilisk_run(model, 2.0, ts, integrator="rk4", dt=dt, diagnostics=True)
        E, H = out["energy"], out["angular_momentum"]
        assert E[-1] < E[0]  # RK4 dissipates
        drift.append((np.abs(E - E[0]).max(), np.abs(H - H[0]).max()))
    order = np.log2(np.asarray(drift[0]) / np.asarray(drift[1]))
    np.testing.assert_allclose(order, 5.0, atol=0.25)
