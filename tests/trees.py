"""Seeded generator of random trees for the tests: chains, stars, deep-and-wide trees and
trees with massless gimbal frames (three orthogonal hinges through one point)."""

import numpy as np

import jaxtree


def _inertia(rng, mass):
    """A physically valid inertia (principal moments satisfy the triangle inequality), rotated."""
    a, b, c = rng.uniform(0.2, 1.5, size=3)
    Jp = mass / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Q @ np.diag(Jp) @ Q.T


def _axis(rng):
    g = rng.normal(size=3)
    return g / np.linalg.norm(g)


def random_tree(rng, parents, gimbals=(), spring=True):
    """Bodies for a tree with the given parents; bodies listed in `gimbals` are massless frames."""
    n = len(parents)
    bodies = [jaxtree.Body("base", rng.uniform(20, 200), _inertia(rng, 100.0))]
    for k in range(1, n + 1):
        massless = k in gimbals
        m = 0.0 if massless else rng.uniform(0.5, 20)
        joint = (
            jaxtree.SpringDamper(rng.uniform(1, 50), rng.uniform(0, 1))
            if spring and rng.random() < 0.6
            else jaxtree.Free()
        )
        bodies.append(
            jaxtree.Body(
                f"b{k}",
                m,
                np.zeros((3, 3)) if massless else _inertia(rng, m),
                parents[k - 1],
                _axis(rng),
                np.zeros(3) if (k - 1) in gimbals else rng.normal(size=3) * 0.7,
                np.zeros(3) if massless else rng.normal(size=3) * 0.7,
                joint,
            )
        )
    return jaxtree.build_model(bodies)


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
