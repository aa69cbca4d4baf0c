"""Attitude variables of b_0 (Eqs. 3, 23, 24 and quaternions): each parametrisation's C and rate
against Eq. (3) by forward-mode differentiation, and the conversions against each other."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.equations.attitude import (
    dcm_to_euler123,
    dcm_to_quaternion,
    euler123_rate_matrix,
    euler123_to_dcm,
    get_attitude,
    orthogonality_error,
    quaternion_rate,
    quaternion_to_dcm,
)
from jaxtree._src.equations.kinematics import tilde

# float64 round-off of a few products of unit-size numbers
ROUNDOFF = 1e-14


def _elementary(axis, angle):
    """Frame rotation C_a(angle) about axis a ({b} = C {a-frame}): a textbook matrix."""
    c, s = np.cos(angle), np.sin(angle)
    if axis == 1:
        return np.array([[1, 0, 0], [0, c, s], [0, -s, c]])
    if axis == 2:
        return np.array([[c, 0, -s], [0, 1, 0], [s, 0, c]])
    return np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])


@pytest.mark.parametrize("seed", range(5))
def test_eq23_is_the_product_of_elementary_rotations(seed):
    theta = np.random.default_rng(seed).uniform(-3, 3, size=3)
    expected = _elementary(1, theta[0]) @ _elementary(2, theta[1]) @ _elementary(3, theta[2])
    assert np.abs(np.asarray(euler123_to_dcm(jnp.asarray(theta))) - expected).max() < ROUNDOFF


@pytest.mark.parametrize("seed", range(5))
def test_eq24_rate_gives_eq3(seed):
    """d/dt C(theta) with theta_dot = P omega0 equals -tilde(omega0) C (Eq. 3)."""
    rng = np.random.default_rng(seed)
    theta = jnp.asarray(rng.uniform(-1.3, 1.3, size=3))
    w = jnp.asarray(rng.normal(size=3))
    C, Cdot = jax.jvp(euler123_to_dcm, (theta,), (euler123_rate_matrix(theta) @ w,))
    assert np.abs(np.asarray(Cdot + tilde(w) @ C)).max() < 10 * ROUNDOFF


@pytest.mark.parametrize("seed", range(5))
def test_quaternion_rate_gives_eq3(seed):
    rng = np.random.default_rng(seed)
    q = jnp.asarray(rng.normal(size=4))  # any norm: C uses q / |q|
    w = jnp.asarray(rng.normal(size=3))
    C, Cdot = jax.jvp(quaternion_to_dcm, (q,), (quaternion_rate(q, w),))
    assert orthogonality_error(C) < ROUNDOFF
    assert np.abs(np.asarray(Cdot + tilde(w) @ C)).max() < 10 * ROUNDOFF


def test_quaternion_of_a_hinge_rotation_matches_eq4():
    """q = (cos(g/2), sin(g/2) axis) is the rotation of Eq. (4) about `axis` by g."""
    axis = jnp.asarray([1.0, -2.0, 0.5]) / np.sqrt(5.25)
    for g in (0.3, 2.0, -2.9):
        q = jnp.concatenate([jnp.cos(g / 2)[None], jnp.sin(g / 2) * axis])
        expected = jaxtree.hinge_rotation(axis, jnp.asarray(g))
        assert np.abs(np.asarray(quaternion_to_dcm(q) - expected)).max() < ROUNDOFF


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("xp", [jnp, np], ids=["jax", "numpy"])
def test_conversions_round_trip(seed, xp):
    """C to attitude variables and back, by jax.numpy and by numpy on the host (how an eager
    simulate packs its start)."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q = q / np.linalg.norm(q) * np.sign(q[0])
    C = quaternion_to_dcm(jnp.asarray(q))
    assert np.abs(np.asarray(dcm_to_quaternion(xp.asarray(C), xp)) - q).max() < 10 * ROUNDOFF
    theta = dcm_to_euler123(xp.asarray(C), xp)
    assert np.abs(np.asarray(euler123_to_dcm(jnp.asarray(theta)) - C)).max() < 10 * ROUNDOFF


@pytest.mark.parametrize("xp", [jnp, np], ids=["jax", "numpy"])
def test_quaternion_of_half_turns(xp):
    """Shepperd's branch choice: rotations by pi (q0 = 0) about each axis."""
    for k in range(3):
        C = -np.eye(3)
        C[k, k] = 1.0
        q = np.asarray(dcm_to_quaternion(xp.asarray(C), xp))
        assert abs(abs(q[k + 1]) - 1) < ROUNDOFF and np.abs(np.delete(q, k + 1)).max() < ROUNDOFF


def test_parametrisations_by_name():
    assert isinstance(get_attitude("quaternion"), jaxtree.Quaternion)
    assert isinstance(get_attitude("dcm"), jaxtree.DirectionCosines)
    assert isinstance(get_attitude("euler123"), jaxtree.Euler123)
    with pytest.raises(ValueError, match="attitude"):
        get_attitude("euler321")


def test_euler_margin_measures_cos_theta2():
    att = jaxtree.Euler123(singularity_tol=0.05)
    assert float(att.margin(jnp.asarray([0.0, 0.0, 0.0]))) == pytest.approx(0.95)
    assert float(att.margin(jnp.asarray([0.0, np.pi / 2 - 0.01, 0.0]))) < 0
