"""Scenes: the ``jaxtree-scene/1`` JSON format, a Python builder, and validation.

The format is defined in the docstring of ``make_scenes.py`` of the shared
reference scenes (bundled here under ``jaxtree/scenes``); jaxtree's optional keys
(``loads``, ``control``, ``orbit``, the prescribed ``ramp``, ``smooth_step`` and ``table``)
are defined in ``docs/scene_format.md`` and read in :mod:`jaxtree.scene_laws`. All validation runs
on plain numpy data before anything is traced, and every error names the body
and the field at fault.
"""

from __future__ import annotations

import abc
import dataclasses
import json
import os
import pathlib
import tempfile
from collections.abc import Callable, Iterable, Sequence
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError, SceneTypeError, short
from ..values import as_float, rotation
from ..vehicle.model import BodyLoads, Model, Prescription, SinePrescription, State
from ..vehicle.profiles import (
    FunctionPrescription,
    PrescriptionGroup,
    ShapePrescription,
    TablePrescription,
    checked_table,
    pad_tables,
)
from ..vehicle.topology import Topology
from ..vehicle.validate import body_label as _where
from .appendages import parse_appendages
from .keys import unknown_keys
from .laws import laws_to_dict, prescribed_joints, with_scene_laws

FORMAT = "jaxtree-scene/1"
_SCENES = pathlib.Path(__file__).resolve().parents[2] / "scenes"  # jaxtree/scenes


# ----------------------------------------------------------------------------- joints
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


_SHAPED = (PrescribedRamp, PrescribedSmoothStep)


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


# ----------------------------------------------------------------------------- validation


def _vector(value, k, name, field, length=3):
    return as_float(value, f"{_where(k, name)}: field {field!r}", (length,))


def _scalar(value, k, name, field):
    if value is None:
        raise SceneError(f"{_where(k, name)}: field {field!r} is missing")
    return float(as_float(value, f"{_where(k, name)}: field {field!r}", ()))


def _inertia(value, mass, k, name):
    J = as_float(value, f"{_where(k, name)}: field 'inertia'", (3, 3))
    scale = max(float(np.abs(J).max()), 1e-300)
    tol = 1e-9 * scale
    if np.abs(J - J.T).max() > tol:
        raise SceneError(f"{_where(k, name)}: field 'inertia' is not symmetric: {J.tolist()}")
    if mass == 0.0 and np.abs(J).max() > 0.0:
        raise SceneError(f"{_where(k, name)}: a massless body must have zero 'inertia', got {J.tolist()}")
    ev = np.linalg.eigvalsh(0.5 * (J + J.T))
    if ev[0] < -tol:
        raise SceneError(f"{_where(k, name)}: field 'inertia' is not positive semidefinite (eigenvalues {ev.tolist()})")
    if ev[0] + ev[1] < ev[2] - tol:
        raise SceneError(
            f"{_where(k, name)}: field 'inertia' violates the triangle inequality of principal moments "
            f"({ev.tolist()}: {ev[0]:.6g} + {ev[1]:.6g} < {ev[2]:.6g}); no mass distribution has it"
        )
    return 0.5 * (J + J.T)


_JOINT_KEYS = {
    "free": {"kind"},
    "spring_damper": {"kind", "stiffness", "damping"},
    "prescribed": {"kind", "function", "amplitude", "frequency", "phase"},
}
# the keys of each prescribed function (beside "kind" and "function") and the required ones
_FUNCTION_KEYS = {
    "sine": ({"amplitude", "frequency", "phase"}, ("amplitude", "frequency")),
    "ramp": ({"initial", "final", "start", "duration"}, ("final", "duration")),
    "smooth_step": ({"initial", "final", "start", "duration"}, ("final", "duration")),
    "table": ({"times", "angles"}, ("times", "angles")),
}
_FUNCTIONS = "'sine', 'ramp', 'smooth_step' or 'table'"


def _joint(joint, k, name):
    family = (Free, SpringDamper, PrescribedSine, PrescribedRamp, PrescribedSmoothStep, PrescribedTable, Prescribed)
    if isinstance(joint, family):  # the closed family
        j = joint
    elif isinstance(joint, dict):
        if "kind" not in joint:
            raise SceneError(
                f"{_where(k, name)}: field 'joint.kind' is missing (expected 'free', 'spring_damper' or 'prescribed')"
            )
        kind = joint["kind"]
        if not isinstance(kind, str) or kind not in _JOINT_KEYS:
            raise SceneError(
                f"{_where(k, name)}: unknown joint kind {short(kind)} in field 'joint' "
                "(expected 'free', 'spring_damper' or 'prescribed')"
            )
        if kind == "prescribed":
            fn = joint.get("function")
            if not isinstance(fn, str) or fn not in _FUNCTION_KEYS:
                raise SceneError(f"{_where(k, name)}: field 'joint.function' must be {_FUNCTIONS}, got {short(fn)}")
            unknown_keys(
                joint, {"kind", "function"} | _FUNCTION_KEYS[fn][0], f"{_where(k, name)}: field 'joint' ({fn})"
            )
            for field in _FUNCTION_KEYS[fn][1]:
                if field not in joint:
                    raise SceneError(f"{_where(k, name)}: field 'joint.{field}' is missing (a {fn} needs it)")
        else:
            unknown_keys(joint, _JOINT_KEYS[kind], f"{_where(k, name)}: field 'joint' ({kind})")
        if kind == "free":
            j = Free()
        elif kind == "spring_damper":
            if "stiffness" not in joint:
                raise SceneError(
                    f"{_where(k, name)}: field 'joint.stiffness' is missing (a spring_damper needs it; "
                    "use 0 for a pure damper)"
                )
            j = SpringDamper(joint["stiffness"], joint.get("damping", 0.0))
        elif joint["function"] == "sine":
            j = PrescribedSine(joint["amplitude"], joint["frequency"], joint.get("phase", 0.0))
        elif joint["function"] == "table":
            j = PrescribedTable(joint["times"], joint["angles"])
        else:
            cls = PrescribedRamp if joint["function"] == "ramp" else PrescribedSmoothStep
            j = cls(joint["final"], joint["duration"], joint.get("initial", 0.0), joint.get("start", 0.0))
    elif joint is None:
        j = Free()
    else:
        raise SceneTypeError(f"{_where(k, name)}: field 'joint' has an unknown joint {short(joint)}")
    if isinstance(j, SpringDamper):
        j = SpringDamper(_scalar(j.stiffness, k, name, "joint.stiffness"), _scalar(j.damping, k, name, "joint.damping"))
        for field, value in (("stiffness", j.stiffness), ("damping", j.damping)):
            if value < 0:
                raise SceneError(
                    f"{_where(k, name)}: field 'joint.{field}' must be >= 0, got {value} (a negative "
                    f"{'spring' if field == 'stiffness' else 'damper'} is no spring_damper)"
                )
    if isinstance(j, PrescribedSine):
        j = PrescribedSine(
            _scalar(j.amplitude, k, name, "joint.amplitude"),
            _scalar(j.frequency, k, name, "joint.frequency"),
            _scalar(j.phase, k, name, "joint.phase"),
        )
    if isinstance(j, _SHAPED):
        fields = {f: _scalar(getattr(j, f), k, name, f"joint.{f}") for f in ("final", "duration", "initial", "start")}
        if fields["duration"] <= 0:
            raise SceneError(f"{_where(k, name)}: field 'joint.duration' must be > 0, got {fields['duration']}")
        j = type(j)(**fields)
    if isinstance(j, PrescribedTable):
        j = PrescribedTable(*checked_table(j.times, j.angles, f"{_where(k, name)}: field 'joint", "angles"))
    if isinstance(j, Prescribed) and not callable(j.fn):
        raise SceneTypeError(f"{_where(k, name)}: field 'joint.fn' must be callable")
    return j


_INITIAL_KEYS = {"gamma", "gamma_dot", "omega0", "dcm", "attitude_dcm"}


def _initial(initial, n) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The checked initial state as numpy arrays, in the order of :class:`~jaxtree.State`'s fields
    (``dcm, omega0, gamma, gamma_dot``): build_model makes the JAX arrays after all checks."""
    if isinstance(initial, State):
        initial = initial._asdict()
    elif initial is None:
        initial = {}
    elif not isinstance(initial, dict):
        raise SceneTypeError(
            f"initial: expected an object with fields {sorted(_INITIAL_KEYS)} or a jaxtree.State, got {short(initial)}"
        )
    initial = dict(initial)
    unknown_keys(initial, _INITIAL_KEYS, "initial")
    if initial.get("dcm") is not None and initial.get("attitude_dcm") is not None:
        raise SceneError("initial: give the attitude once, as 'dcm' or as 'attitude_dcm', not both")
    if initial.get("dcm") is None and "attitude_dcm" in initial:
        initial["dcm"] = initial.pop("attitude_dcm")

    def vec(field, length):
        v = initial.get(field)
        return np.zeros(length) if v is None else as_float(v, f"initial: field {field!r}", (length,))

    gamma = vec("gamma", n)
    gamma_dot = vec("gamma_dot", n)
    omega0 = vec("omega0", 3)
    C = initial.get("dcm")
    C = np.eye(3) if C is None else rotation(C, "initial: field 'attitude_dcm'")
    return C, omega0, gamma, gamma_dot


# ----------------------------------------------------------------------------- building
def _device(x) -> jax.Array:
    """`x` as a JAX array of JAX's canonical dtype (float64 under x64), put on the device without
    compiling anything (``jnp.asarray`` of a numpy array compiles a copy per shape)."""
    x = np.asarray(x)
    return jax.device_put(x.astype(jax.dtypes.canonicalize_dtype(x.dtype), copy=False))


def build_model(
    bodies: Sequence[Body | dict],
    initial: dict | State | None = None,
    *,
    loads: BodyLoads | None = None,
    name: str = "",
    method: str = "auto",
) -> Model:
    """Validate a list of bodies and build a :class:`~jaxtree.Model`.

    **Arguments:**

    - `bodies`: :class:`Body` records (or dicts with the scene format's keys),
      the reference body first; a parent may be given by index or by name.
    - `initial`: dict with `gamma`, `gamma_dot`, `omega0`, `dcm` (or
      `attitude_dcm`), or a :class:`~jaxtree.State`; missing entries are zero / identity.
    - `loads`: optional external loads (:class:`~jaxtree.BodyLoads`).
    - `method`: how Eq. (1) is solved, ``"auto"`` (default), ``"dense"`` or ``"articulated"``
      (:class:`~jaxtree.Model`).

    Raises :class:`SceneError` naming the body and field of any invalid input.
    """
    bodies = _body_records(bodies)
    if not isinstance(name, str):
        raise SceneTypeError(f"name: expected a string, got {short(name)}")
    if not isinstance(method, str):
        raise SceneTypeError(f"method: must be 'auto', 'dense' or 'articulated', got {short(method)}")
    _method(method)
    n = len(bodies) - 1
    names = _body_names(bodies)
    fields = _body_fields(bodies, names)
    if sum(fields.masses) <= 0:
        raise SceneError("bodies: the total mass must be positive (field 'mass' is 0 on every body)")
    topology = Topology(fields.parents, names)
    laws = _joint_laws(fields.joints, n)
    state = _initial(initial, n)
    massive = tuple(k for k in range(n + 1) if fields.masses[k] > 0)
    _check_sprung_hinges(topology, laws.sprung, massive, names)
    if loads is not None:
        _check_loads(loads, n)

    # every check passed: only now make JAX arrays (nothing above touches JAX)
    return Model(
        mass=_device(fields.masses),
        inertia=_device(np.stack(fields.inertias)),
        axis=_device(np.reshape(np.asarray(fields.axes, dtype=float), (n, 3))),
        hinge_on_parent=_device(np.reshape(np.asarray(fields.on_parent, dtype=float), (n, 3))),
        hinge_on_body=_device(np.reshape(np.asarray(fields.on_body, dtype=float), (n, 3))),
        stiffness=_device(laws.stiffness),
        damping=_device(laws.damping),
        initial=State(*(_device(x) for x in state)),
        prescription=_prescription(laws),
        loads=loads,
        topology=topology,
        joints=tuple(j.kind for j in fields.joints),
        sprung=tuple(laws.sprung),
        massive=massive,
        name=name,
        method=_method(method),
    )


def _body_records(bodies) -> list[Body]:
    """`bodies` as a non-empty list of :class:`Body` records (dicts converted)."""
    if isinstance(bodies, (str, bytes, dict)) or not isinstance(bodies, Iterable):
        raise SceneTypeError(f"bodies: expected a list of Body records or objects, got {short(bodies)}")
    bodies = [b if isinstance(b, Body) else _body_from_dict(b, i) for i, b in enumerate(bodies)]
    if not bodies:
        raise SceneError("bodies: a scene needs at least the reference body")
    return bodies


def _body_names(bodies: list[Body]) -> list[str]:
    """The bodies' names, each a non-empty string and none repeated."""
    for k, b in enumerate(bodies):
        if not isinstance(b.name, str) or not b.name:
            raise SceneTypeError(f"body {k}: field 'name' must be a non-empty string, got {short(b.name)}")
    names = [b.name for b in bodies]
    first = {}
    for k, nm in enumerate(names):
        if nm in first:
            raise SceneError(f"{_where(k, nm)}: field 'name' duplicates body {first[nm]}")
        first[nm] = k
    return names


@dataclasses.dataclass
class _BodyFields:
    """The checked fields of all bodies: `masses`, `inertias` per body (n+1), the hinge fields
    per hinge body (n)."""

    masses: list[float] = dataclasses.field(default_factory=list)
    inertias: list[np.ndarray] = dataclasses.field(default_factory=list)
    parents: list[int] = dataclasses.field(default_factory=list)
    axes: list[np.ndarray] = dataclasses.field(default_factory=list)
    on_parent: list[np.ndarray] = dataclasses.field(default_factory=list)
    on_body: list[np.ndarray] = dataclasses.field(default_factory=list)
    joints: list[Joint] = dataclasses.field(default_factory=list)


def _body_fields(bodies: list[Body], names: list[str]) -> _BodyFields:
    """Check every body in turn (mass, inertia, then its hinge fields) and collect the fields."""
    out = _BodyFields()
    for k, b in enumerate(bodies):
        nm = names[k]
        if b.mass is None:
            raise SceneError(f"{_where(k, nm)}: field 'mass' is missing")
        m = _scalar(b.mass, k, nm, "mass")
        if m < 0:
            raise SceneError(f"{_where(k, nm)}: field 'mass' must be >= 0, got {m}")
        out.masses.append(m)
        if b.inertia is None:
            raise SceneError(f"{_where(k, nm)}: field 'inertia' is missing")
        out.inertias.append(_inertia(b.inertia, m, k, nm))
        if k == 0:
            _check_reference_body(b, nm)
            continue
        out.parents.append(_parent(b.parent, k, names))
        out.axes.append(_axis(b.axis, k, nm))
        for field, store in (("hinge_on_parent", out.on_parent), ("hinge_on_body", out.on_body)):
            v = getattr(b, field)
            if v is None:
                raise SceneError(f"{_where(k, nm)}: field {field!r} is missing")
            store.append(_vector(v, k, nm, field))
        out.joints.append(_joint(b.joint, k, nm))
    return out


def _check_reference_body(b: Body, nm: str) -> None:
    """The reference body b_0 has no parent, no hinge fields and no joint law."""
    if b.parent is not None:
        raise SceneError(f"{_where(0, nm)}: the reference body must not have a 'parent'")
    for field in ("axis", "hinge_on_parent", "hinge_on_body"):
        if getattr(b, field) is not None:
            raise SceneError(f"{_where(0, nm)}: the reference body has no hinge: remove field {field!r}")
    if not (
        b.joint is None or isinstance(b.joint, Free) or (isinstance(b.joint, dict) and b.joint == {"kind": "free"})
    ):
        raise SceneError(f"{_where(0, nm)}: the reference body has no hinge: remove field 'joint'")


def _parent(p, k: int, names: list[str]) -> int:
    """The index of body k's parent, given by index or name: an earlier body (Def. 4)."""
    nm = names[k]
    if p is None:
        raise SceneError(f"{_where(k, nm)}: field 'parent' is missing (every body but the first needs one)")
    if isinstance(p, str):
        if p not in names[:k]:
            later = f" (body {names.index(p)}: parents come before children)" if p in names else ""
            raise SceneError(
                f"{_where(k, nm)}: field 'parent' names {p!r}, which is not an earlier body{later} (Def. 4)"
            )
        p = names.index(p)
    if isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, np.integer)) or not 0 <= int(p) < k:
        raise SceneError(
            f"{_where(k, nm)}: field 'parent' must be an index in 0..{k - 1} (Def. 4: parents before children), "
            f"got {short(p)}"
        )
    return int(p)


def _axis(value, k: int, nm: str) -> np.ndarray:
    """The unit hinge axis g^k of body k, from a nonzero 3-vector."""
    if value is None:
        raise SceneError(f"{_where(k, nm)}: field 'axis' is missing")
    g = _vector(value, k, nm, "axis")
    big = float(np.abs(g).max())
    norm = big * float(np.linalg.norm(g / big)) if big > 0 else 0.0  # no overflow for huge entries
    if norm < 1e-12:
        raise SceneError(f"{_where(k, nm)}: field 'axis' must be a nonzero 3-vector, got {g.tolist()}")
    return (g / big) / (norm / big)


class _JointLaws(NamedTuple):
    """The joint laws sorted by kind: spring-damper coefficients per hinge (zero on the others)
    and the `sprung` hinges, and the ``(hinge, joint)`` pairs of the sine and function
    prescriptions."""

    stiffness: np.ndarray
    damping: np.ndarray
    sprung: list[int]
    sine: list[tuple[int, PrescribedSine]]
    funcs: list[tuple[int, Prescribed]]
    shaped: list[tuple[int, PrescribedRamp | PrescribedSmoothStep]]
    tables: list[tuple[int, PrescribedTable]]


def _joint_laws(joints: list[Joint], n: int) -> _JointLaws:
    laws = _JointLaws(np.zeros(n), np.zeros(n), [], [], [], [], [])
    for k, j in enumerate(joints, start=1):
        if isinstance(j, SpringDamper):
            laws.stiffness[k - 1], laws.damping[k - 1] = j.stiffness, j.damping
            laws.sprung.append(k)
        elif isinstance(j, PrescribedSine):
            laws.sine.append((k, j))
        elif isinstance(j, Prescribed):
            laws.funcs.append((k, j))
        elif isinstance(j, _SHAPED):
            laws.shaped.append((k, j))
        elif isinstance(j, PrescribedTable):
            laws.tables.append((k, j))
    return laws


def _check_sprung_hinges(topology: Topology, sprung: list[int], massive: tuple[int, ...], names: list[str]) -> None:
    """A spring or damper needs some mass outboard of its hinge (else the motion is undetermined)."""
    heavy = np.zeros(len(names), dtype=bool)
    heavy[list(massive)] = True
    for k in sprung:
        if not heavy[topology.path_elements[k - 1].astype(bool)].any():
            raise SceneError(
                f"{_where(k, names[k])}: field 'joint' puts a spring or damper on a hinge with only massless "
                "bodies outboard (zero inertia about the hinge: the motion is undetermined)"
            )


def _check_loads(loads, n: int) -> None:
    """`loads` a :class:`~jaxtree.BodyLoads` whose bodies are indices 0..n."""
    if not isinstance(loads, BodyLoads):
        raise SceneTypeError(f"loads: expected a jaxtree.BodyLoads, got {short(loads)}")
    for k in loads.bodies:
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or not 0 <= int(k) <= n:
            raise SceneError(f"loads: body index {short(k)} is not in 0..{n}")


def _prescription(laws: _JointLaws) -> Prescription | None:
    """One :class:`~jaxtree.Prescription` of the prescribed hinges (a group when several kinds
    occur: one vectorized part per kind), or None when no hinge is prescribed."""
    sine, funcs, shaped, tables = laws.sine, laws.funcs, laws.shaped, laws.tables
    parts = []
    if sine:
        parts.append(
            SinePrescription(
                tuple(k for k, _ in sine),
                jnp.asarray([j.amplitude for _, j in sine]),
                jnp.asarray([j.frequency for _, j in sine]),
                jnp.asarray([j.phase for _, j in sine]),
            )
        )
    if shaped:
        parts.append(
            ShapePrescription(
                tuple(k for k, _ in shaped),
                tuple(j.function for _, j in shaped),
                *(jnp.asarray([getattr(j, f) for _, j in shaped]) for f in ("initial", "final", "start", "duration")),
            )
        )
    if tables:
        T, V = pad_tables([j.times for _, j in tables], [j.angles for _, j in tables])
        parts.append(
            TablePrescription(
                tuple(k for k, _ in tables), tuple(len(j.times) for _, j in tables), jnp.asarray(T), jnp.asarray(V)
            )
        )
    if funcs:
        parts.append(FunctionPrescription(tuple(k for k, _ in funcs), tuple(j.fn for _, j in funcs)))
    prescription = None
    if len(parts) == 1:
        prescription = parts[0]
    elif parts:
        prescription = PrescriptionGroup(sum((p.hinges for p in parts), ()), tuple(parts))
    return prescription


def _method(method):
    if method not in ("auto", "dense", "articulated"):
        raise SceneError(f"method: must be 'auto', 'dense' or 'articulated', got {method!r}")
    return method


_BODY_KEYS = {"name", "mass", "inertia", "parent", "axis", "hinge_on_parent", "hinge_on_body", "joint"}


def _body_from_dict(d, k):
    if not isinstance(d, dict):
        raise SceneTypeError(f"body {k}: expected an object, got {short(d)}")
    name = d.get("name", "?")
    unknown_keys(d, _BODY_KEYS, _where(k, name) if isinstance(name, str) else f"body {k}")
    for field in ("name", "mass", "inertia"):
        if field not in d:
            raise SceneError(f"{_where(k, name)}: field {field!r} is missing")
    return Body(**{key: d[key] for key in _BODY_KEYS if key in d})


# ----------------------------------------------------------------------------- JSON
_SCENE_KEYS = {"format", "name", "description", "bodies", "initial", "loads", "control", "orbit", "appendages"}


def scene_from_dict(data: dict, base_dir=None) -> Model:
    """Build a model from a parsed ``jaxtree-scene/1`` document.

    Besides the bodies and the initial state, the optional keys ``loads``, ``control`` and
    ``orbit`` give the model its external loads, hinge laws and orbit
    (:mod:`jaxtree.scene_laws`; docs/guide.md, "Loads and laws in a scene").

    Raises :class:`SceneError` naming the body and the field of any invalid entry, and for an
    unknown key anywhere (naming it, its place and the nearest known key); keys of the user's own
    begin with ``"x-"`` and are read past (not written back by :func:`scene_to_dict`)."""
    if not isinstance(data, dict):
        raise SceneTypeError(f"scene: expected a JSON object, got {short(data)}")
    if data.get("format") != FORMAT:
        raise SceneError(f"scene: field 'format' must be {FORMAT!r}, got {short(data.get('format'))}")
    unknown_keys(data, _SCENE_KEYS, "scene")
    if "bodies" not in data or not isinstance(data["bodies"], list):
        raise SceneError("scene: field 'bodies' must be a list")
    for field in ("name", "description"):
        if not isinstance(data.get(field, ""), str):
            raise SceneTypeError(f"scene: field {field!r} must be a string, got {short(data[field])}")
    initial = data.get("initial")
    if initial is not None and not isinstance(initial, dict):
        raise SceneTypeError(f"scene: field 'initial' must be an object, got {short(initial)}")

    model = with_scene_laws(build_model(data["bodies"], initial, name=data.get("name", "")), data)
    specs = parse_appendages(data.get("appendages"), model.names, base_dir)
    return dataclasses.replace(model, appendages=specs) if specs else model


def scene_path(name: str) -> pathlib.Path:
    """Path of a bundled reference scene, e.g. ``scene_path("fig4")``."""
    p = _SCENES / f"{name}.json"
    if not p.exists():
        raise FileNotFoundError(f"no bundled scene {name!r}; available: {list_scenes()}")
    return p


def list_scenes() -> list[str]:
    """Names of the bundled reference scenes."""
    return sorted(p.stem for p in _SCENES.glob("*.json"))


def load_scene(path) -> Model:
    """Load a ``jaxtree-scene/1`` JSON file; a bare name (``"fig4"``) loads a bundled scene."""
    p = pathlib.Path(path)
    if not p.exists() and p.suffix == "" and p.parent == pathlib.Path("."):
        p = scene_path(str(path))
    with open(p) as f:
        try:
            data = json.load(f)
        except json.JSONDecodeError as e:
            raise SceneError(f"{p}: not valid JSON ({e})") from None
    return scene_from_dict(data, p.parent)


def scene_to_dict(model: Model, description: str = "", base_dir=None) -> dict:
    """The ``jaxtree-scene/1`` document of a model, with its loads, control laws and orbit.

    Raises ValueError for what has no JSON form: a prescription, load or law given as a Python
    function (or another class than the scene format's)."""

    # the arrays on the host first: indexing JAX arrays one by one compiles an operation per shape
    model = jax.tree_util.tree_map(lambda x: np.asarray(x) if isinstance(x, jax.Array) else x, model)
    prescribed = prescribed_joints(model)
    laws = laws_to_dict(model)
    f = lambda a: np.asarray(a, dtype=float).tolist()
    bodies = [{"name": model.names[0], "mass": float(model.mass[0]), "inertia": f(model.inertia[0])}]
    for k in range(1, model.n + 1):
        if k in prescribed:
            joint = prescribed[k]
        elif k in model.sprung:
            joint = {
                "kind": "spring_damper",
                "stiffness": float(model.stiffness[k - 1]),
                "damping": float(model.damping[k - 1]),
            }
        else:
            joint = {"kind": "free"}
        bodies.append(
            {
                "name": model.names[k],
                "mass": float(model.mass[k]),
                "inertia": f(model.inertia[k]),
                "parent": model.topology.parents[k - 1],
                "axis": f(model.axis[k - 1]),
                "hinge_on_parent": f(model.hinge_on_parent[k - 1]),
                "hinge_on_body": f(model.hinge_on_body[k - 1]),
                "joint": joint,
            }
        )
    s = model.initial
    return {
        "format": FORMAT,
        "name": model.name,
        "description": description,
        "bodies": bodies,
        "initial": {"gamma": f(s.gamma), "gamma_dot": f(s.gamma_dot), "omega0": f(s.omega0), "attitude_dcm": f(s.dcm)},
        **laws,
        **({"appendages": [a.to_dict(base_dir) for a in model.appendages]} if model.appendages else {}),
    }


def save_scene(model: Model, path, description: str = "") -> None:
    """Write a model as ``jaxtree-scene/1`` JSON, atomically (temporary file, then rename)."""
    path = pathlib.Path(path)
    text = json.dumps(scene_to_dict(model, description, path.parent.resolve()), indent=1) + "\n"
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
