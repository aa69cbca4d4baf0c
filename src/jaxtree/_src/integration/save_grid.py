"""The default save grid of a run: evenly spaced save times, enough per period of the fastest
sprung hinge that still rings (:func:`fastest_oscillation`, from the same hinge laws as the
screen of ``solver="auto"``, :mod:`.autosolver_screen`), and how many a grid gives per period
(:func:`samples_per_period`, which the command line warns about). numpy on the scene.
"""

from __future__ import annotations

import math

import numpy as np

from ..vehicle.model import Model
from .autosolver_screen import sprung_hinge_laws

# Save points per period of the fastest retained hinge motion: at 4 a curve looks jagged, at 20
# it is smooth to the eye (and linear interpolation between them is within 1.2 % of a sine).
SAMPLES_PER_PERIOD = 20
# Fewer than this per period and a plot misses the motion's shape: the command line says so.
SAMPLES_LEAST = 8
# The default grid never exceeds this many points (a long run of a stiff tree): the command line warns.
MAX_SAVE_POINTS = 20001


def fastest_oscillation(model: Model, span: float) -> float:
    """The highest angular frequency (rad/s) of a sprung hinge that still rings during a run of
    `span` seconds: per sprung hinge, the damped frequency of its spring and damper against the
    inertia of its own body about the hinge line (the screen of :func:`.autosolver.choose_solver`,
    within a small factor of the tree's fastest mode), among those that do not die out in the
    first tenth of the run (to 1e-3). Zero without such a hinge. No JAX computation: numpy on
    the scene."""
    if not model.sprung:
        return 0.0
    _, J, k, c = sprung_hinge_laws(model)
    ok = J > 0  # a massless body's hinge has no motion of its own
    J = np.where(ok, J, 1.0)
    decay = c / (2 * J)
    wd2 = k / J - decay**2
    rings = ok & (wd2 > 0) & (0.1 * abs(span) * decay < math.log(1e3))
    return float(np.sqrt(np.where(rings, wd2, 0.0)).max(initial=0.0))


def save_points(model: Model, span: float, *, least: int = 101) -> tuple[int, float]:
    """The default number of evenly spaced save times of a run of `span` seconds:
    :data:`SAMPLES_PER_PERIOD` per period of :func:`fastest_oscillation`, at least `least`, at
    most :data:`MAX_SAVE_POINTS`. Returns ``(points, that frequency in rad/s)``."""
    rate = fastest_oscillation(model, span)
    want = math.ceil(abs(span) * rate / (2 * math.pi) * SAMPLES_PER_PERIOD) + 1
    return int(min(max(least, want), MAX_SAVE_POINTS)), rate


def samples_per_period(points: int, span: float, rate: float) -> float:
    """Save intervals per period of an oscillation at `rate` rad/s (inf without one)."""
    if rate <= 0 or span == 0:
        return math.inf
    return (points - 1) * 2 * math.pi / (abs(span) * rate)
