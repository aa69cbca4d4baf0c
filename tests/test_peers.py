"""The Pinocchio adapters of the benchmarks (``jaxtree.bench.peers``), against Pinocchio's ABA.

``from_pinocchio`` turns a Pinocchio tree (revolute joints on a free flyer, rotated joint frames
included) into a jaxtree model; ``pinocchio_model`` goes the other way. Eq. (1)'s accelerations
of the one must equal ``pinocchio.aba`` of the other at random states (with the scenes' spring-damper hinges): a
second derivation (Featherstone's articulated-body algorithm, in C++) of the same dynamics.
Pinocchio's base velocity is a uniform translation of the whole tree, which changes no
acceleration (Galilean invariance), so it is drawn at random as well.
"""

import jax.numpy as jnp
import numpy as np
import pinocchio as pin
import pytest

import jaxtree
from jaxtree.bench.peers import _laws, from_pinocchio, pinocchio_model


def _compare(pm, model, iq, iv, rng):
    g, gd = rng.uniform(-1.0, 1.0, (2, model.n))
    w, lin = rng.uniform(-1.0, 1.0, (2, 3))
    stiffness, damping = _laws(model)
    tau = -stiffness * g - damping * gd  # the model's joint laws, as the benchmarks' peer applies them
    q = pin.neutral(pm)
    q[iq] = g
    v = np.zeros(pm.nv)
    v[:3], v[3:6], v[iv] = lin, w, gd
    t = np.zeros(pm.nv)
    t[iv] = tau
    a = pin.aba(pm, pm.createData(), q, v, t)
    wd, gdd = jaxtree.forward_dynamics(model, jnp.eye(3), jnp.asarray(w), jnp.asarray(g), jnp.asarray(gd))
    scale = np.abs(a).max()
    assert np.abs(np.asarray(wd) - a[3:6]).max() <= 1e-11 * scale
    assert np.abs(np.asarray(gdd) - a[iv]).max() <= 1e-11 * scale


@pytest.mark.parametrize("method", ["dense", "articulated"])
def test_from_pinocchio_humanoid_matches_aba(method):
    """Pinocchio's sample humanoid (28 revolute joints, some joint frames rotated)."""
    pm = pin.buildSampleModelHumanoid()
    model = from_pinocchio(pm, method=method)
    assert model.n == 28 and model.names[1] == "rleg_shoulder1_joint"
    rng = np.random.default_rng(7)
    for _ in range(3):
        _compare(pm, model, np.arange(7, pm.nq), np.arange(6, pm.nv), rng)


def test_from_pinocchio_rotated_frames_and_unaligned_axes():
    """A random tree whose joint frames are rotated and whose axes are unaligned: the body axes
    taken parallel at the neutral configuration carry every rotation."""
    rng = np.random.default_rng(3)

    def inertia():  # a box's, at a random lever and orientation
        box = pin.Inertia.FromBox(rng.uniform(0.5, 2.0), *rng.uniform(0.1, 1.0, 3))
        R = pin.SE3.Random().rotation
        return pin.Inertia(box.mass, rng.uniform(-0.5, 0.5, 3), R @ box.inertia @ R.T)

    pm = pin.Model()
    pm.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    pm.appendBodyToJoint(1, inertia(), pin.SE3.Identity())
    for j in range(2, 10):
        parent = int(rng.integers(1, j))
        axis = rng.standard_normal(3)
        pm.addJoint(parent, pin.JointModelRevoluteUnaligned(axis / np.linalg.norm(axis)), pin.SE3.Random(), f"j{j}")
        pm.appendBodyToJoint(j, inertia(), pin.SE3.Identity())
    model = from_pinocchio(pm)
    _compare(pm, model, np.arange(7, pm.nq), np.arange(6, pm.nv), rng)


def test_pinocchio_model_of_a_scene_matches_aba():
    """The other direction, as the benchmarks use it: fig4_free's free hinges and the wings'
    spring-damper hinges."""
    rng = np.random.default_rng(5)
    for name in ("fig4_free", "wings"):
        model = jaxtree.load_scene(name)
        pm, _, iq, iv, _ = pinocchio_model(model)
        _compare(pm, model, iq, iv, rng)


def test_from_pinocchio_refuses_other_joints():
    pm = pin.Model()
    pm.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    pm.addJoint(1, pin.JointModelPX(), pin.SE3.Identity(), "slider")
    with pytest.raises(ValueError, match="joint 2 \\('slider'\\) is a JointModelPX"):
        from_pinocchio(pm)
    fixed = pin.Model()
    fixed.addJoint(0, pin.JointModelRX(), pin.SE3.Identity(), "arm")
    with pytest.raises(ValueError, match="JointModelFreeFlyer"):
        from_pinocchio(fixed)
