"""Helpers shared by the tests (imported as ``from helpers import ...``; pytest puts this folder
on the import path): random states, the reference scenes, the Appendix C system with its
closed-form parameters. The independent derivation of Eq. (1) lives in ``oracle.py`` (with
``oracle_at``, the one way the tests call it on a model), random trees in ``trees.py``
(``random_tree``, the one builder)."""

import pathlib

import equinox as eqx
import jax
import numpy as np

import jaxtree

SHARED_SCENES = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "scenes"


def scene_names():
    return jaxtree.list_scenes()


def random_state(model, rng, scale=1.0):
    """A random state of `model`: angles over the full circle, rates of order `scale`."""
    n = model.n
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    dcm = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
            [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
            [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    return jaxtree.State(
        jax.numpy.asarray(dcm),
        jax.numpy.asarray(scale * rng.normal(size=3)),
        jax.numpy.asarray(rng.uniform(-np.pi, np.pi, size=n)),
        jax.numpy.asarray(scale * rng.normal(size=n)),
    )


def appendix_c():
    """The Appendix C system (Fig. C-1) and the parameters of its closed forms (C-3, C-48, C-52)."""
    model = jaxtree.load_scene("appendix_c")
    m0, m = float(model.mass[0]), float(model.mass[1])
    I0 = np.diag(np.asarray(model.inertia[0]))
    L = -float(model.hinge_on_body[0, 1])  # rod of length 2L hinged at its end
    r = float(model.hinge_on_parent[0, 1])  # cylinder radius
    k = float(model.stiffness[0])
    # the scene is the system of Fig. C-1: identical thin rods on +-b2, hinge axes b1
    np.testing.assert_allclose(np.asarray(model.inertia[1]), np.diag([m * (2 * L) ** 2 / 12, 0, m * (2 * L) ** 2 / 12]))
    np.testing.assert_allclose(np.asarray(model.inertia[2]), np.asarray(model.inertia[1]))
    np.testing.assert_allclose(np.asarray(model.axis), [[1, 0, 0], [1, 0, 0]])
    np.testing.assert_allclose(np.asarray(model.hinge_on_parent[1]), [0, -r, 0])
    np.testing.assert_allclose(np.asarray(model.hinge_on_body[1]), [0, L, 0])
    M = m0 + 2 * m
    R = m * L / M  # (C-3)
    Jc = 4.0 / 3.0 * m * L**2  # (C-48)
    c = Jc + M * R * r
    extra = 2 * m * (r**2 + 2 * r * L + 4.0 / 3.0 * L**2)  # (C-52)
    I1, I2, I3 = I0[0] + extra, I0[1], I0[2] + extra
    return model, dict(M=M, R=R, J=Jc, c=c, r=r, k=k, I1=I1, I2=I2, I3=I3)


# ----------------------------------------------------------------------------- the seed's Tables 1-2 (Fig. 4)
# Table 1 of the seed (network elements N_kr, rows k, columns r); row 10 is garbled in the
# OCR and is completed from Def. 26 (see docs/errata.md).
TABLE_1 = """
0 1 1 1 1 5 5 5 5 5 5
0 1 2 2 2 0 0 0 0 0 0
1 1 2 3 3 1 1 1 1 1 1
2 2 2 3 4 2 2 2 2 2 2
3 3 3 3 4 3 3 3 3 3 3
0 0 0 0 0 5 6 6 6 6 6
5 5 5 5 5 5 6 7 7 7 10
6 6 6 6 6 6 6 7 8 8 6
7 7 7 7 7 7 7 7 8 9 7
8 8 8 8 8 8 8 8 8 9 8
6 6 6 6 6 6 6 6 6 6 10
"""

# Table 2 of the seed (path elements epsilon_sk, rows s = 1..10, columns k = 0..10).
TABLE_2 = """
0 1 1 1 1 0 0 0 0 0 0
0 0 1 1 1 0 0 0 0 0 0
0 0 0 1 1 0 0 0 0 0 0
0 0 0 0 1 0 0 0 0 0 0
0 0 0 0 0 1 1 1 1 1 1
0 0 0 0 0 0 1 1 1 1 1
0 0 0 0 0 0 0 1 1 1 0
0 0 0 0 0 0 0 0 1 1 0
0 0 0 0 0 0 0 0 0 1 0
0 0 0 0 0 0 0 0 0 0 1
"""

NEIGHBOURS = {
    0: {1, 5},
    1: {0, 2},
    2: {1, 3},
    3: {2, 4},
    4: {3},
    5: {0, 6},
    6: {5, 7, 10},
    7: {6, 8},
    8: {7, 9},
    9: {8},
    10: {6},
}

# Branch sets printed in Sec. II E (B_76 and B_87 with body 10 restored, see docs/errata.md).
BRANCHES = {
    (0, 1): {1, 2, 3, 4},
    (0, 5): {5, 6, 7, 8, 9, 10},
    (1, 0): {0, 5, 6, 7, 8, 9, 10},
    (1, 2): {2, 3, 4},
    (2, 1): {0, 1, 5, 6, 7, 8, 9, 10},
    (2, 3): {3, 4},
    (3, 2): {0, 1, 2, 5, 6, 7, 8, 9, 10},
    (3, 4): {4},
    (4, 3): {0, 1, 2, 3, 5, 6, 7, 8, 9, 10},
    (5, 0): {0, 1, 2, 3, 4},
    (5, 6): {6, 7, 8, 9, 10},
    (6, 5): {0, 1, 2, 3, 4, 5},
    (6, 7): {7, 8, 9},
    (6, 10): {10},
    (7, 6): {0, 1, 2, 3, 4, 5, 6, 10},
    (7, 8): {8, 9},
    (8, 7): {0, 1, 2, 3, 4, 5, 6, 7, 10},
    (8, 9): {9},
    (9, 8): {0, 1, 2, 3, 4, 5, 6, 7, 8, 10},
    (10, 6): {0, 1, 2, 3, 4, 5, 6, 7, 8, 9},
}


def table(text):
    """A printed table as an integer array."""
    return np.array([[int(x) for x in row.split()] for row in text.strip().splitlines()])


# ----------------------------------------------------------------------------- loads as array leaves
class ConstantLoads(jaxtree.BodyLoads):
    """Forces and torques (body frames) on a static set of bodies, as array leaves."""

    bodies: tuple = eqx.field(static=True)
    force: jax.Array
    torque: jax.Array

    def __call__(self, t, state):
        return self.force, self.torque


def equations(jaxpr):
    """Every equation of a jaxpr, those of nested jaxprs included (the solve of Eq. 1 sits inside a
    custom_jvp call, its derivative rule)."""
    import jax.extend.core

    for e in jaxpr.eqns:
        yield e
        for sub in jax.extend.core.jaxprs_in_params(e.params):
            yield from equations(sub)


def count_equations(jaxpr) -> int:
    """How many :func:`equations` a jaxpr has."""
    return sum(1 for _ in equations(jaxpr))


def primitive_names(jaxpr) -> set[str]:
    """The primitives of a jaxpr's :func:`equations`."""
    return {e.primitive.name for e in equations(jaxpr)}
