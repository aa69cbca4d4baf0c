"""The small 3-vector / 3x3 algebra and the tree sums of kinematics.py against numpy, and
take_rows against numpy's indexing (values, derivatives, bad indices)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.equations.kinematics import (
    ancestor_sum,
    body_rotations,
    cross,
    hinge_rotation,
    mm,
    mv,
    take_rows,
    tilde,
)

from helpers import TABLE_2, table

RNG = np.random.default_rng(7)


@pytest.mark.parametrize(
    "sa, sb",
    [((5, 3), (5, 3)), ((5, 3), (3,)), ((3,), (4, 3)), ((2, 4, 3), (4, 3)), ((3,), (3,))],
)
def test_cross_is_numpys_on_stacks_and_broadcasts(sa, sb):
    a, b = RNG.normal(size=sa), RNG.normal(size=sb)
    np.testing.assert_allclose(cross(jnp.asarray(a), jnp.asarray(b)), np.cross(a, b), rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("sa, sx", [((6, 3, 3), (6, 3)), ((6, 3, 3), (3,)), ((3, 3), (4, 3)), ((2, 5, 3, 3), (5, 3))])
def test_mv_is_numpys_matmul(sa, sx):
    A, x = RNG.normal(size=sa), RNG.normal(size=sx)
    np.testing.assert_allclose(mv(jnp.asarray(A), jnp.asarray(x)), (A @ x[..., None])[..., 0], rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("sa, sb", [((6, 3, 3), (6, 3, 3)), ((6, 3, 3), (3, 3)), ((3, 3), (2, 6, 3, 3))])
def test_mm_is_numpys_matmul(sa, sb):
    A, B = RNG.normal(size=sa), RNG.normal(size=sb)
    np.testing.assert_allclose(mm(jnp.asarray(A), jnp.asarray(B)), A @ B, rtol=1e-14, atol=1e-15)


def test_tilde_is_the_cross_product_matrix():
    v, w = RNG.normal(size=(7, 3)), RNG.normal(size=(7, 3))
    T = np.asarray(tilde(jnp.asarray(v)))
    assert T.shape == (7, 3, 3)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", T, w), np.cross(v, w), rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(T, -np.swapaxes(T, -1, -2))
    np.testing.assert_array_equal(np.diagonal(T, axis1=-2, axis2=-1), 0.0)


def test_body_rotations_and_ancestor_sums_follow_the_path_elements():
    """Fig. 4's tree: R_k is the product of the hinge rotations from b_0 to b_k (Eq. 22, in
    order along the path), and ancestor_sum is the path-element sum of Def. 27, both checked
    against the seed's Table 2 by plain numpy loops."""
    topo = jaxtree.load_scene("fig4").topology
    n = len(topo.parents)
    axis = RNG.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    gamma = RNG.uniform(-2, 2, n)
    R = np.asarray(body_rotations(topo, jnp.asarray(axis), jnp.asarray(gamma)))
    local = np.swapaxes(np.asarray(hinge_rotation(jnp.asarray(axis), jnp.asarray(gamma))), -1, -2)
    eps = table(TABLE_2)  # eps[s - 1, k] = 1 when hinge s is on the path from b_0 to b_k
    for k in range(1, n + 1):
        path = [s for s in range(1, n + 1) if eps[s - 1, k]]  # inboard first: ascending indices
        expect = np.eye(3)
        for s in path:
            expect = expect @ local[s - 1]
        np.testing.assert_allclose(R[k], expect, atol=1e-14)
    x = RNG.normal(size=(n + 1, 4))
    y = np.asarray(ancestor_sum(topo, jnp.asarray(x)))
    np.testing.assert_allclose(y[0], x[0], atol=1e-15)
    for k in range(1, n + 1):
        np.testing.assert_allclose(y[k], x[0] + sum(x[s] for s in range(1, n + 1) if eps[s - 1, k]), atol=1e-14)


@pytest.mark.parametrize("idx", [[0, 0, 1, 5, 2], [3, 1], list(range(6)), [5]])
def test_take_rows_is_indexing_with_its_derivatives(idx):
    x = RNG.normal(size=(6, 3, 2))
    idx_np = np.asarray(idx)
    np.testing.assert_array_equal(take_rows(jnp.asarray(x), idx_np), x[idx_np])
    np.testing.assert_array_equal(take_rows(jnp.asarray(x), tuple(idx)), x[idx_np])
    ct = RNG.normal(size=(len(idx), 3, 2))
    _, vjp = jax.vjp(lambda x: take_rows(x, idx_np), jnp.asarray(x))
    expect = np.zeros_like(x)
    np.add.at(expect, idx_np, ct)  # the transpose of a gather: repeated rows add up
    np.testing.assert_allclose(vjp(jnp.asarray(ct))[0], expect, rtol=1e-15)
    batch = jax.vmap(lambda y: take_rows(y, idx_np))(jnp.asarray(np.stack([x, 2 * x])))
    np.testing.assert_array_equal(batch, np.stack([x[idx_np], 2 * x[idx_np]]))


def test_take_rows_refuses_rows_it_does_not_have():
    x = jnp.zeros((4, 3))
    with pytest.raises(IndexError, match="out of range for 4 rows"):
        take_rows(x, [0, 4])
    with pytest.raises(IndexError, match="out of range"):
        take_rows(x, [-1])
    assert take_rows(x, np.zeros(0, int)).shape == (0, 3)
