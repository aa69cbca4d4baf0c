"""Radau IIA of order 5 as a collocation method: its coefficients and its collocation polynomial.

The coefficients (Hairer & Wanner, *Solving Ordinary Differential Equations II*, Sec. IV.8, as in
their code RADAU5; defined in :mod:`.radau`'s docstring) are computed once in float64 numpy: the
nodes `C`, the Butcher matrix `A`, the eigenvalues `GAMMA` and `ALPHA` ± i `BETA` of A⁻¹, the
transformation `T` (and `T_INV`) that brings A⁻¹ to its block form, the error-estimate weights `E`,
and `LAGRANGE`, the Lagrange basis of the collocation polynomial on the nodes (0, c1, c2, 1).

Dense output
------------
:class:`Radau5Interpolation` evaluates the collocation polynomial, the cubic through (t0, y0) and
(t0 + c_i h, y0 + Z_i): order 3 between the step points (local error O(h⁴)).
:func:`lagrange_weights` gives the weights of the stage increments in it, which
:class:`~.radau.Radau5` also uses to extrapolate the last step's polynomial to the next stages.
"""

from __future__ import annotations

from typing import Any

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

__all__ = [
    "A",
    "ALPHA",
    "BETA",
    "C",
    "E",
    "GAMMA",
    "LAGRANGE",
    "T",
    "T_INV",
    "Radau5Interpolation",
    "lagrange_weights",
]


def _constants():
    """The tableau, transformation and error coefficients of Radau IIA(5), in float64 numpy."""
    s6 = np.sqrt(6.0)
    c = np.array([(4.0 - s6) / 10.0, (4.0 + s6) / 10.0, 1.0])
    a = np.array(
        [
            [(88.0 - 7.0 * s6) / 360.0, (296.0 - 169.0 * s6) / 1800.0, (-2.0 + 3.0 * s6) / 225.0],
            [(296.0 + 169.0 * s6) / 1800.0, (88.0 + 7.0 * s6) / 360.0, (-2.0 - 3.0 * s6) / 225.0],
            [(16.0 - s6) / 36.0, (16.0 + s6) / 36.0, 1.0 / 9.0],
        ]
    )
    gamma = 3.0 + 3.0 ** (2.0 / 3.0) - 3.0 ** (1.0 / 3.0)
    alpha = 3.0 + 0.5 * (3.0 ** (1.0 / 3.0) - 3.0 ** (2.0 / 3.0))
    beta = 0.5 * (3.0 ** (5.0 / 6.0) + 3.0 ** (7.0 / 6.0))
    a_inv = np.linalg.inv(a)

    def eigvec(lam):
        # (A⁻¹ - λ I) v = 0 with v[2] = 1: the first two rows fix v[0], v[1]
        m = a_inv - lam * np.eye(3)
        v01 = np.linalg.solve(m[:2, :2], -m[:2, 2])
        return np.array([v01[0], v01[1], 1.0 + 0.0j])

    real_vec = np.real(eigvec(gamma + 0.0j))
    cplx_vec = eigvec(alpha - 1j * beta)  # A⁻¹ [u, w] = [u, w] [[α, -β], [β, α]] for u + iw
    t = np.column_stack([real_vec, np.real(cplx_vec), np.imag(cplx_vec)])
    t_inv = np.linalg.inv(t)
    # error estimate: e = (b̂ - b)ᵀ A⁻¹ / γ0 with the embedded weights (γ0, b̂) of order 3, γ0 = 1/γ
    e = np.array([-(13.0 + 7.0 * s6) / 3.0, (-13.0 + 7.0 * s6) / 3.0, -1.0 / 3.0])
    # collocation polynomial: Lagrange basis on the nodes (0, c1, c2, 1) for the three stage values,
    # as polynomial coefficients in τ = (t - t0)/h, highest power first
    nodes = np.concatenate([[0.0], c])
    lagrange = np.zeros((3, 4))
    for j in range(1, 4):
        others = np.delete(nodes, j)
        lagrange[j - 1] = np.poly(others) / np.prod(nodes[j] - others)
    return c, a, gamma, alpha, beta, t, t_inv, e, lagrange


C, A, GAMMA, ALPHA, BETA, T, T_INV, E, LAGRANGE = _constants()


def lagrange_weights(tau: Array) -> Array:
    """Weights of the stage increments Z_1..3 in the collocation polynomial at `tau` (any shape)."""
    powers = jnp.stack([tau**3, tau**2, tau, jnp.ones_like(tau)], axis=-1)
    return powers @ jnp.asarray(LAGRANGE.T, dtype=tau.dtype)


class Radau5Interpolation(dfx.AbstractLocalInterpolation):
    """Dense output of one Radau5 step: the collocation polynomial through (t0, y0) and the three
    stage values (order 3 between step points)."""

    t0: Any
    t1: Any
    y0: Any
    zs: Any  # like y0, each leaf with a leading axis of 3: Z_1, Z_2, Z_3

    def evaluate(self, t0: Any, t1: Any = None, left: bool = True) -> Any:
        del left
        if t1 is not None:
            return jax.tree_util.tree_map(lambda a, b: a - b, self.evaluate(t1), self.evaluate(t0))
        dt = self.t1 - self.t0
        zero = dt == 0
        tau = jnp.where(zero, 0.0, (t0 - self.t0) / jnp.where(zero, 1.0, dt))

        def leaf(y, z):
            w = lagrange_weights(jnp.asarray(tau, dtype=z.dtype))
            return y + jnp.tensordot(w, z, axes=1, precision=jax.lax.Precision.HIGHEST)

        return jax.tree_util.tree_map(leaf, self.y0, self.zs)
