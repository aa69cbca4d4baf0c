"""A scene's bodies and the joint laws of their hinges, as a user writes them in Python (the records
:func:`jaxtree.build_model` takes; a scene file's ``joint`` objects are read into the same)."""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable
from typing import Any, ClassVar


class Joint(abc.ABC):
    """The law of one hinge, a closed family (Def. 21, Sec. II B): :class:`Free` and
    :class:`SpringDamper` give the joint torque ``tau_k`` of Eq. (1) (the model's `sprung`
    hinges); :class:`PrescribedSine`, :class:`PrescribedRamp`, :class:`PrescribedSmoothStep`,
    :class:`PrescribedTable` and :class:`Prescribed` prescribe ``gamma_k(t)``
    kinematically (the model's `prescribed` hinges, moved to the right side of Eq. 1). Laws of
    the whole state act beside them at run time: a user law ``tau(t, state, params)`` and a
    controller with internal states (:mod:`jaxtree.control`), arguments of
    :func:`jaxtree.simulate` or carried by the model from its scene's ``control``. `kind` is the
    scene format's joint kind."""

    kind: ClassVar[str]


@dataclasses.dataclass(frozen=True)
class Free(Joint):
    """A hinge with no torque law (tau_k = 0 unless a controller adds one)."""

    kind: ClassVar[str] = "free"


@dataclasses.dataclass(frozen=True)
class SpringDamper(Joint):
    """``tau_k = -stiffness * gamma_k - damping * gamma_dot_k``."""

    stiffness: float
    damping: float = 0.0
    kind: ClassVar[str] = "spring_damper"


@dataclasses.dataclass(frozen=True)
class PrescribedSine(Joint):
    """Prescribed ``gamma_k(t) = amplitude * sin(frequency * t + phase)`` (the scene's ``sine``)."""

    amplitude: float
    frequency: float
    phase: float = 0.0
    kind: ClassVar[str] = "prescribed"


@dataclasses.dataclass(frozen=True)
class _PrescribedTransition(Joint):
    """A prescribed move from `initial` to `final` over `duration` from `start` (the fields of
    the scene's ``ramp`` and ``smooth_step``; the subclass names the profile)."""

    final: float
    duration: float
    initial: float = 0.0
    start: float = 0.0
    kind: ClassVar[str] = "prescribed"


@dataclasses.dataclass(frozen=True)
class PrescribedRamp(_PrescribedTransition):
    """Prescribed ``gamma_k(t) = initial + (final - initial) clip((t - start) / duration, 0, 1)``
    (the scene's ``ramp``: constant rate inside, held before and after)."""

    function: ClassVar[str] = "ramp"


@dataclasses.dataclass(frozen=True)
class PrescribedSmoothStep(_PrescribedTransition):
    """Prescribed ``gamma_k(t) = initial + (final - initial) (10 s^3 - 15 s^4 + 6 s^5)``,
    ``s = clip((t - start) / duration, 0, 1)`` (the scene's ``smooth_step``: rate and
    acceleration zero at both ends)."""

    function: ClassVar[str] = "smooth_step"


@dataclasses.dataclass(frozen=True)
class PrescribedTable(Joint):
    """Prescribed ``gamma_k(t)`` through tabulated ``(times, angles)`` (the scene's ``table``): a
    cubic Hermite curve with centred-difference slopes, zero slope at the first and last
    point, constant outside the table (:mod:`jaxtree.profiles`)."""

    times: Any
    angles: Any
    kind: ClassVar[str] = "prescribed"
    function: ClassVar[str] = "table"


SHAPED = (PrescribedRamp, PrescribedSmoothStep)  # the prescribed joints of a shape over a time


@dataclasses.dataclass(frozen=True)
class Prescribed(Joint):
    """Prescribed ``gamma_k(t) = fn(t)`` for any JAX-differentiable scalar function of time."""

    fn: Callable
    kind: ClassVar[str] = "prescribed"


@dataclasses.dataclass(frozen=True)
class Body:
    """One body of the tree (Sec. II D input). The first body is the reference body b_0 and
    has no hinge fields; every other body names its `parent` (index or name, Def. 4)."""

    name: str
    mass: float
    inertia: Any
    parent: int | str | None = None
    axis: Any = None
    hinge_on_parent: Any = None
    hinge_on_body: Any = None
    joint: Any = Free()
