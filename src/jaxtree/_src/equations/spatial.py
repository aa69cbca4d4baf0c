"""Spatial (six-dimensional) algebra about one point: the rigid-body inertias, motion and force
cross products that the articulated recursion (:mod:`jaxtree._src.equations.articulated`) and the hybrid
model's large bodies and substructures (:mod:`jaxtree._src.hybrid`, :mod:`jaxtree._src.hybrid.substructure`)
share. Motions are ``(w, u)`` (angular, then the velocity of the point), forces ``(n, f)`` (moment
about the point, then force), all in {b^0} components (Featherstone's conventions).
"""

from __future__ import annotations

import jax.numpy as jnp

from .kinematics import cross, mv


# A rigid-body inertia about O is kept as (J (..., 3, 3), h = m rho (..., 3), m (...)); sums of
# inertias about the same point are sums of these parts.
def inertia_apply(J, h, m, w, u):
    """``M (w, u)`` for the inertia (J, h, m) about O: ``(J w + h x u, m u - h x w)``."""
    return mv(J, w) + cross(h, u), m[..., None] * u - cross(h, w)


def inertia_matrix(J, h, m):
    """The 6 x 6 matrix of the inertia (J, h, m)."""
    z = jnp.zeros_like(m)
    ht = jnp.stack(
        [
            jnp.stack([z, -h[..., 2], h[..., 1]], -1),
            jnp.stack([h[..., 2], z, -h[..., 0]], -1),
            jnp.stack([-h[..., 1], h[..., 0], z], -1),
        ],
        -2,
    )
    eye = jnp.eye(3, dtype=J.dtype) * m[..., None, None]
    return jnp.concatenate([jnp.concatenate([J, ht], -1), jnp.concatenate([-ht, eye], -1)], -2)


def motion_cross(vw, vu, mw, mu):
    """Spatial motion cross product ``(vw, vu) x (mw, mu) = (vw x mw, vw x mu + vu x mw)``."""
    return cross(vw, mw), cross(vw, mu) + cross(vu, mw)


def force_cross(vw, vu, n, f):
    """``(vw, vu) x* (n, f) = (vw x n + vu x f, vw x f)``."""
    return cross(vw, n) + cross(vu, f), cross(vw, f)
