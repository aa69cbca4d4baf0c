"""Checks behind docs/errata.md for the core equations: the printed readings that fail."""

import jax.numpy as jnp
import numpy as np

import jaxtree
from jaxtree._src.equations.barycentric import barycentric, coupling_inertia

from helpers import random_state
from oracle import oracle_at

# the corrected Def. 39 against the oracle's a_0k, relative to its largest entry: float64 round-off of
# two different sums over the bodies
ROUNDOFF = 1e-12


def test_def39_with_the_ocr_path_element_is_wrong():
    """Def. 39 as the OCR reads it, epsilon_{kr} with r in P, against the oracle's a_0k; the
    corrected reading (epsilon_{kj}, r over all of B) is what jaxtree.barycentric uses."""
    model = jaxtree.load_scene("fig4_free")
    s = random_state(model, np.random.default_rng(5))
    R = jaxtree.body_rotations(model.topology, model.axis, s.gamma)
    Phi = coupling_inertia(model, s.gamma, barycentric(model))
    Psi = jnp.einsum("rab,rsbc,sdc->rsad", R, Phi, R)  # C^{0r} Phi^{rs} C^{s0}
    g0 = jnp.einsum("kab,kb->ka", R[1:], model.axis)  # C^{0k} g^k
    eps = jnp.asarray(model.topology.path_elements, float)  # eps[k-1, r]
    ocr = jnp.einsum("kr,rjab,kb->ak", eps, Psi, g0)  # path element of the row body r
    fixed = jnp.einsum("kj,rjab,kb->ak", eps, Psi, g0)  # path element of the column body j
    ref = oracle_at(model, s)["mass_matrix"]
    a0k = np.asarray(ref)[:3, 3:]
    scale = np.abs(a0k).max()
    assert np.abs(np.asarray(fixed) - a0k).max() < ROUNDOFF * scale
    # the OCR reading misses by a sizeable fraction of the scale, far above round-off
    assert np.abs(np.asarray(ocr) - a0k).max() > 0.05 * scale
