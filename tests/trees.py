"""Seeded generator of random trees for the tests: chains, stars, deep-and-wide trees and
trees with massless gimbal frames (three orthogonal hinges through one point)."""

import numpy as np

import jaxtree


def principal_moments(rng, mass=1.0):
    """Principal moments of a box of the given mass with random sides (they satisfy the triangle
    inequality)."""
    a, b, c = rng.uniform(0.2, 1.5, size=3)
    return mass / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


def _inertia(rng, mass):
    """A physically valid inertia (principal moments satisfy the triangle inequality), rotated."""
    Jp = principal_moments(rng, mass)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q @ np.diag(Jp) @ Q.T


def _axis(rng):
    g = rng.normal(size=3)
    return g / np.linalg.norm(g)


def random_tree(
    rng,
    parents,
    gimbals=(),
    spring=True,
    *,
    stiffness=(1.0, 50.0),
    damping=None,
    link_mass=(0.5, 20.0),
    axes=None,
    hinge_on_parent=None,
    hinge_on_body=None,
    inertia=None,
):
    """The tests' one random tree: a built model with the given parents, random masses, inertias,
    hinge axes and hinge points; bodies listed in `gimbals` are massless frames.

    spring: True puts a spring-damper on about 60 % of the hinges (the others Free), False none,
    "all" one on every hinge. Spring constants are drawn from the range `stiffness`; damping
    constants from [0, 1), or all equal to `damping` when it is given; link masses from the range
    `link_mass` (the base's from [20, 200)). `axes`, `hinge_on_parent`,
    `hinge_on_body` (per hinge) and `inertia` (per body, base first) replace those draws. A given
    rng and arguments always give the same tree (the draws are made in a fixed order)."""
    n = len(parents)
    base_mass = rng.uniform(20, 200)
    bodies = [jaxtree.Body("base", base_mass, _inertia(rng, 100.0) if inertia is None else inertia[0])]
    for k in range(1, n + 1):
        massless = k in gimbals
        m = 0.0 if massless else rng.uniform(*link_mass)
        if spring == "all" or (spring and rng.random() < 0.6):
            joint = jaxtree.SpringDamper(rng.uniform(*stiffness), rng.uniform(0, 1) if damping is None else damping)
        else:
            joint = jaxtree.Free()
        if massless:
            J = np.zeros((3, 3))
        else:
            J = _inertia(rng, m) if inertia is None else inertia[k]
        bodies.append(
            jaxtree.Body(
                f"b{k}",
                m,
                J,
                parents[k - 1],
                _axis(rng) if axes is None else axes[k - 1],
                _given_or(hinge_on_parent, k, lambda: np.zeros(3) if (k - 1) in gimbals else rng.normal(size=3) * 0.7),
                _given_or(hinge_on_body, k, lambda: np.zeros(3) if massless else rng.normal(size=3) * 0.7),
                joint,
            )
        )
    return jaxtree.build_model(bodies)


def _given_or(values, k, draw):
    return draw() if values is None else values[k - 1]


def sprung_tree(rng, parents, damping=0.0, **kw):
    """A random tree for the linearization and modes tests: light links (1-3 kg) on a spring of
    20-60 N m/rad each, stiff enough that spinning the base at about 1 rad/s leaves it stable."""
    return random_tree(rng, parents, spring="all", stiffness=(20.0, 60.0), damping=damping, link_mass=(1.0, 3.0), **kw)


def planar_model(rng, parents, g, positions):
    """A `sprung_tree` with all hinge axes `g`, hinge points and mass centers given by
    `positions(k) -> (hinge_on_parent, hinge_on_body)` of hinge k."""
    n = len(parents)
    hop, hob = zip(*[positions(k) for k in range(1, n + 1)])
    return sprung_tree(rng, parents, axes=[g] * n, hinge_on_parent=hop, hinge_on_body=hob)


# One tree shape for the linearization and modes tests, so that the jitted linearization (keyed on
# the model structure and the set A) and the oracle compile once: b0 - 1 - 2 - 3, b0 - 4 - 5, 1 - 6.
PARENTS = [0, 1, 2, 0, 4, 1]
ALL = (1, 2, 3, 4, 5, 6)


def chain(n):
    return list(range(n))


def star(n):
    return [0] * n


def deep_and_wide(rng, n):
    return [int(rng.integers(max(0, k - 3), k)) for k in range(1, n + 1)]


def gimballed(n_extra=3):
    """0 -> 1 (massless) -> 2 (massless) -> 3 (rotor), plus a branch from 0; gimbals 1, 2."""
    return [0, 1, 2] + [0] + list(range(4, 4 + n_extra - 1)), (1, 2)


def gimbal_model(rng):
    """Three orthogonal hinges through one point with massless frames between them."""
    parents, gimbals = gimballed()
    n = len(parents)
    axes = {1: [0, 0, 1.0], 2: [0, -1.0, 0], 3: [-1.0, 0, 0]}
    bodies = [jaxtree.Body("base", 150.0, _inertia(rng, 150.0))]
    for k in range(1, n + 1):
        massless = k in gimbals
        m = 0.0 if massless else rng.uniform(1, 10)
        on_parent = rng.normal(size=3) if (k == 1 or k >= 4) else np.zeros(3)
        on_body = np.zeros(3) if massless or k == 3 else rng.normal(size=3) * 0.5
        bodies.append(
            jaxtree.Body(
                f"b{k}",
                m,
                np.zeros((3, 3)) if massless else _inertia(rng, m),
                parents[k - 1],
                axes.get(k, _axis(rng)),
                on_parent,
                on_body,
            )
        )
    return jaxtree.build_model(bodies)
