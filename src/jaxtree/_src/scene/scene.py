"""Scenes: the Python builder (:func:`build_model`) and the validation of what a scene says.

The format is defined in the docstring of ``make_scenes.py`` of the shared
reference scenes (bundled here under ``jaxtree/scenes``); jaxtree's optional keys
(``loads``, ``control``, ``orbit``, the prescribed ``ramp``, ``smooth_step`` and ``table``)
are defined in ``docs/scene_format.md`` and read in :mod:`jaxtree.scene_laws`. All validation runs
on plain numpy data before anything is traced, and every error names the body
and the field at fault.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Iterable, Sequence
from typing import NamedTuple

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
from .joints import (
    SHAPED,
    Body,
    Free,
    Joint,
    Prescribed,
    PrescribedRamp,
    PrescribedSine,
    PrescribedSmoothStep,
    PrescribedTable,
    SpringDamper,
)
from .keys import unknown_keys

FORMAT = "jaxtree-scene/1"
SCENES = pathlib.Path(__file__).resolve().parents[2] / "scenes"  # jaxtree/scenes


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
    if isinstance(j, SHAPED):
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
        elif isinstance(j, SHAPED):
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
