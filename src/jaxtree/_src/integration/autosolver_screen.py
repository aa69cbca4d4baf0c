"""The screen of ``solver="auto"`` (:mod:`.autosolver`): what the scene shows without a
Jacobian, numpy on the scene. Each sprung hinge's spring and damper against its own body's
inertia about the hinge line (:func:`sprung_hinge_laws`, :func:`local_rates`), the fastest rate
with margins (:func:`screen_rate`: the hinge laws and the initial rates), and the least steps
that Radau5 needs for the sprung hinges that start away from rest (:func:`ringing_hinges`).
When even that rate holds Dopri8 to fewer steps than Radau5's least, Dopri8 is chosen without
linearizing.
"""

from __future__ import annotations

import numpy as np

from ..vehicle.model import Model, State
from .autosolver_cost import C_IMPLICIT, ORDER_IMPLICIT, mode_steps

# The screen's margins over the rates it sees without the Jacobian: a hinge law's own rate, and
# a spin (a rotor's nutation is at most (axial / transverse inertia) x its spin, below 2).
SCREEN_MARGIN = 10.0
SPIN_MARGIN = 2.0


def sprung_hinge_laws(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per sprung hinge: its index (0-based), the inertia J of its own body about the hinge line
    (parallel axes through the hinge point; 0 for a massless body), its stiffness and damping."""
    i = np.asarray(model.sprung, np.int64) - 1
    axis = np.asarray(model.axis, float)[i]
    r = np.asarray(model.hinge_on_body, float)[i]
    J = np.einsum("ki,kij,kj->k", axis, np.asarray(model.inertia, float)[i + 1], axis)
    J = J + np.asarray(model.mass, float)[i + 1] * np.sum(np.cross(axis, r) ** 2, 1)
    return i, J, np.asarray(model.stiffness, float)[i], np.asarray(model.damping, float)[i]


def local_rates(model: Model) -> np.ndarray:
    """Per sprung hinge, the largest |root| of ``J s^2 + c s + k`` (:func:`sprung_hinge_laws`)."""
    if not model.sprung:
        return np.zeros(0)
    _, J, k, c = sprung_hinge_laws(model)
    J = np.where(J > 0, J, np.finfo(float).tiny)  # a massless body: as fast as it gets
    disc = c * c - 4 * J * k
    over = np.sqrt(np.maximum(disc, 0.0))
    fast = np.where(disc >= 0, (c + over) / (2 * J), np.sqrt(np.maximum(k, 0.0) / J))
    return np.abs(fast)


def ringing_hinges(model: Model, y0: State, span: float, rtol: float, atol: float) -> float:
    """A lower bound of Radau5's steps from the scene alone: each sprung hinge that starts away
    from its spring's rest (an angle, or a rate) rings at its own spring and damper against its
    body's inertia about the hinge line, ``lambda = -c/(2J) + i sqrt(k/J - (c/2J)^2)``, at an
    amplitude of ``max(|gamma|, |gamma_dot| / |lambda|)`` in tolerances of the angle; the tree's
    mode is within a small factor of it, so a third of its frequency is taken. 0 without one."""
    if not model.sprung:
        return 0.0
    i, J, k, c = sprung_hinge_laws(model)
    ok = (J > 0) & (k > 0)
    J = np.where(ok, J, 1.0)
    sigma = c / (2 * J)
    wd = np.sqrt(np.maximum(k / J - sigma**2, 0.0))
    lam = -sigma + 1j * wd / 3.0
    g = np.abs(np.asarray(y0.gamma, float)[i])
    gd = np.abs(np.asarray(y0.gamma_dot, float)[i])
    amp = np.maximum(g, gd / np.maximum(np.abs(lam), np.finfo(float).tiny)) / (atol + rtol * g)
    amp = np.where(ok & (wd > 0), np.minimum(amp, 1.0 / rtol), 0.0)
    return float(mode_steps(lam, amp, span, ORDER_IMPLICIT, C_IMPLICIT).max(initial=0.0))


def screen_rate(model: Model, y0: State) -> float:
    """The fastest rate (rad/s) the scene shows without a Jacobian: :data:`SCREEN_MARGIN` times each
    sprung hinge's spring and damper against its body's inertia about the hinge line (a tree's
    fastest mode is within a small factor of it), and :data:`SPIN_MARGIN` times each hinge's and
    the bus's initial rate (a rotor's nutation, a spinning body's gyroscopic modes)."""
    local = local_rates(model)
    rates = [SCREEN_MARGIN * float(local.max(initial=0.0))]
    rates.append(SPIN_MARGIN * float(np.abs(np.asarray(y0.gamma_dot, float)).max(initial=0.0)))
    rates.append(SPIN_MARGIN * float(np.linalg.norm(np.asarray(y0.omega0, float))))
    return max(rates)
