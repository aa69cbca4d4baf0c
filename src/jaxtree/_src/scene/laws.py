"""The loads and laws a ``jaxtree-scene/1`` document may carry: its optional keys ``loads``,
``control`` and ``orbit`` (Sec. II D inputs 7-8 of Likins 1972; Eq. 2 with a central body).

- ``loads``: forces and torques ``F^k``, ``T^k`` (Defs. 19-20) on named bodies, each a constant
  vector in the body's frame times a profile of time (constant, pulse, table), and the gravity
  gradient of the orbit (:class:`~jaxtree.ScheduledLoads`, :class:`~jaxtree.GravityGradient`);
- ``control``: hinge laws to a set point, PD (``model.law``, a :class:`~jaxtree.HingePD`) and PID
  with an integrator and a filtered rate (``model.controller``, a :class:`~jaxtree.HingePID`),
  and a PD law on the reference body's attitude (a torque on it among the loads,
  :class:`~jaxtree.AttitudePD`);
- ``orbit``: the circular orbit of the mass center (:class:`~jaxtree.CircularOrbit`).

Every entry is checked here on plain Python and numpy values before anything is built or
traced; an error names the key, its index and the body (``loads[1] (torque on body 2
('wing')): field 'vector' ...``). :func:`laws_to_dict` writes the same keys back, and
:func:`describe_laws` gives the lines ``jaxtree check`` prints.
"""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np

from ..equations.attitude import dcm_to_euler123, euler123_to_dcm
from ..equations.control import HingePD, HingePID
from ..equations.loads import AttitudePD, CircularOrbit, CombinedLoads, GravityGradient, ScheduledLoads, combine_loads
from ..errors import SceneError, SceneTypeError, short
from ..values import as_float, rotation
from ..vehicle.model import Model, SinePrescription
from ..vehicle.profiles import (
    FunctionPrescription,
    PrescriptionGroup,
    ShapePrescription,
    TablePrescription,
    checked_table,
)
from .keys import unknown_keys

SCENE_LAW_KEYS = ("loads", "control", "orbit")
EARTH_MU = 3.986004418e14  # m^3/s^2, the default central body

_LOAD_KEYS = {
    "torque": {"kind", "body", "vector", "profile"},
    "force": {"kind", "body", "vector", "profile"},
    "gravity_gradient": {"kind", "bodies"},
}
_PROFILE_KEYS = {
    "constant": {"kind"},
    "pulse": {"kind", "start", "duration", "rise"},
    "table": {"kind", "times", "values"},
}
_CONTROL_KEYS = {
    "hinge_pd": {"kind", "hinge", "kp", "kd", "set_point"},
    "hinge_pid": {"kind", "hinge", "kp", "ki", "kd", "filter_time", "set_point"},
    "attitude_pd": {"kind", "kp", "kd", "euler123", "attitude_dcm"},
}
_ORBIT_KEYS = {"mu", "radius", "phase"}


def _body(k: int, names) -> str:
    return f"body {k} ({names[k]!r})"


def _index(value, where: str, field: str, names, first: int = 0) -> int:
    """A body given by name or index (`first`..n)."""
    n = len(names) - 1
    if isinstance(value, str):
        if value not in names:
            raise SceneError(f"{where}: field {field!r} names {value!r}, which is not a body (bodies: {list(names)})")
        k = names.index(value)
    elif isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise SceneTypeError(f"{where}: field {field!r} must be a body name or index, got {short(value)}")
    else:
        k = int(value)
    if not first <= k <= n:
        what = "a hinge body (hinge k joins body k to its parent)" if first else "a body"
        raise SceneError(f"{where}: field {field!r} must name {what}, index {first}..{n}, got {short(value)}")
    return k


def _number(entry: dict, field: str, where: str, default=None, minimum=None, positive=False) -> float:
    if field not in entry:
        if default is None:
            raise SceneError(f"{where}: field {field!r} is missing")
        return float(default)
    x = float(as_float(entry[field], f"{where}: field {field!r}", ()))
    if positive and not x > 0:
        raise SceneError(f"{where}: field {field!r} must be > 0, got {x}")
    if minimum is not None and x < minimum:
        raise SceneError(f"{where}: field {field!r} must be >= {minimum}, got {x}")
    return x


def _entries(value, key: str) -> list[dict]:
    if not isinstance(value, list):
        raise SceneTypeError(f"scene: field {key!r} must be a list of objects, got {short(value)}")
    for i, e in enumerate(value):
        if not isinstance(e, dict):
            raise SceneTypeError(f"{key}[{i}]: expected an object, got {short(e)}")
        if "kind" not in e:
            raise SceneError(f"{key}[{i}]: field 'kind' is missing")
    return value


def _kind(entry: dict, where: str, known: dict) -> str:
    kind = entry["kind"]
    if not isinstance(kind, str) or kind not in known:
        raise SceneError(f"{where}: unknown kind {short(kind)} (expected {', '.join(map(repr, known))})")
    unknown_keys(entry, known[kind], f"{where} ({kind})")
    return kind


# ----------------------------------------------------------------------------- reading
def parse_orbit(value) -> CircularOrbit:
    """The scene's ``orbit`` object: ``mu`` (default the Earth's), ``radius``, ``phase`` (default 0)."""
    if not isinstance(value, dict):
        raise SceneTypeError(f"scene: field 'orbit' must be an object, got {short(value)}")
    unknown_keys(value, _ORBIT_KEYS, "orbit")
    mu = _number(value, "mu", "orbit", EARTH_MU, positive=True)
    radius = _number(value, "radius", "orbit", positive=True)
    phase = _number(value, "phase", "orbit", 0.0)
    return CircularOrbit(mu, radius, phase)


def _profile(value, where: str) -> tuple[str, tuple, tuple | None]:
    """``(kind, (start, duration, rise), table)`` of a load's profile (default constant)."""
    if value is None:
        return "constant", (0.0, 0.0, 1.0), None
    if not isinstance(value, dict) or "kind" not in value:
        raise SceneTypeError(f"{where}: field 'profile' must be an object with a 'kind', got {short(value)}")
    kind = _kind(value, f"{where}: field 'profile'", _PROFILE_KEYS)
    w = f"{where}: field 'profile' ({kind})"
    if kind == "pulse":
        start = _number(value, "start", w)
        duration = _number(value, "duration", w, minimum=0.0)
        rise = _number(value, "rise", w, 1e-2, positive=True)
        return kind, (start, duration, rise), None
    if kind == "table":
        for field in ("times", "values"):
            if field not in value:
                raise SceneError(f"{w}: field {field!r} is missing")
        return (
            kind,
            (0.0, 0.0, 1.0),
            checked_table(value["times"], value["values"], f"{where}: field 'profile", "values"),
        )
    return kind, (0.0, 0.0, 1.0), None


def parse_loads(value, model: Model, orbit: CircularOrbit | None):
    """The scene's ``loads`` list as one :class:`~jaxtree.BodyLoads` (None for an empty list)."""
    names = model.names
    rows, kinds, vectors, profiles, pulses, tables = [], [], [], [], [], []
    gravity = None
    for i, e in enumerate(_entries(value, "loads")):
        where = f"loads[{i}]"
        kind = _kind(e, where, _LOAD_KEYS)
        if kind == "gravity_gradient":
            if orbit is None:
                raise SceneError(f"{where} (gravity_gradient): needs the scene's 'orbit' (its rate sets the torque)")
            if gravity is not None:
                raise SceneError(f"{where} (gravity_gradient): given twice (also loads[{gravity[0]}])")
            bodies = None
            if "bodies" in e:
                if not isinstance(e["bodies"], list) or not e["bodies"]:
                    raise SceneTypeError(f"{where} (gravity_gradient): field 'bodies' must be a non-empty list")
                bodies = [_index(b, f"{where} (gravity_gradient)", "bodies", names) for b in e["bodies"]]
                if len(set(bodies)) != len(bodies):
                    raise SceneError(f"{where} (gravity_gradient): field 'bodies' lists a body twice: {e['bodies']}")
            gravity = (i, bodies)
            continue
        if "body" not in e:
            raise SceneError(f"{where} ({kind}): field 'body' is missing")
        k = _index(e["body"], f"{where} ({kind})", "body", names)
        w = f"{where} ({kind} on {_body(k, names)})"
        if "vector" not in e:
            raise SceneError(f"{w}: field 'vector' is missing")
        vectors.append(as_float(e["vector"], f"{w}: field 'vector'", (3,)))
        p, pulse, table = _profile(e.get("profile"), w)
        rows.append(k)
        kinds.append(kind)
        profiles.append(p)
        pulses.append(pulse)
        tables.append(table)
    parts = []
    if rows:
        start, duration, rise = (list(x) for x in zip(*pulses))
        parts.append(ScheduledLoads(rows, kinds, vectors, profiles, start, duration, rise, tables))
    if gravity is not None:
        assert orbit is not None
        parts.append(orbit.gravity_gradient(model, gravity[1]))
    return combine_loads(*parts)


def _attitude_pd(e: dict, where: str, names) -> AttitudePD:
    w = f"{where} (attitude_pd on {_body(0, names)})"
    gains = []
    for field in ("kp", "kd"):
        if field not in e:
            raise SceneError(f"{w}: field {field!r} is missing")
        g = as_float(e[field], f"{w}: field {field!r}")
        if g.shape not in ((), (3,)):
            raise SceneError(
                f"{w}: field {field!r} must be a number or 3 numbers (one per axis of b0), got shape {g.shape}"
            )
        if np.any(g < 0):
            raise SceneError(f"{w}: field {field!r} must be >= 0, got {g.tolist()}")
        gains.append(g)
    if "euler123" in e and "attitude_dcm" in e:
        raise SceneError(f"{w}: give the set point once, as 'euler123' or as 'attitude_dcm', not both")
    if "attitude_dcm" in e:
        C = rotation(e["attitude_dcm"], f"{w}: field 'attitude_dcm'")
    elif "euler123" in e:
        # (one small program, not each operation compiled on its own)
        C = np.asarray(jax.jit(euler123_to_dcm)(as_float(e["euler123"], f"{w}: field 'euler123'", (3,))))
    else:
        C = np.eye(3)
    return AttitudePD(gains[0], gains[1], C)


def parse_control(value, model: Model):
    """The scene's ``control`` list as ``(law, controller, attitude)``: one
    :class:`~jaxtree.HingePD` for all PD entries, one :class:`~jaxtree.HingePID` for all PID
    entries, the :class:`~jaxtree.AttitudePD` of the reference body (None when absent)."""
    names, n = model.names, model.n
    seen: dict[int, int] = {}
    pd: list[tuple[int, list[float]]] = []
    pid: list[tuple[int, list[float]]] = []
    attitude = None
    for i, e in enumerate(_entries(value, "control")):
        where = f"control[{i}]"
        kind = _kind(e, where, _CONTROL_KEYS)
        if kind == "attitude_pd":
            if attitude is not None:
                raise SceneError(f"{where} (attitude_pd): given twice (also control[{attitude[0]}])")
            attitude = (i, _attitude_pd(e, where, names))
            continue
        if "hinge" not in e:
            raise SceneError(f"{where} ({kind}): field 'hinge' is missing")
        if n == 0:
            raise SceneError(f"{where} ({kind}): the scene has no hinge to control")
        k = _index(e["hinge"], f"{where} ({kind})", "hinge", names, first=1)
        w = f"{where} ({kind} on hinge {k}, {_body(k, names)})"
        if k in seen:
            raise SceneError(f"{w}: the hinge already has a law (control[{seen[k]}]); give one law per hinge")
        if k in model.prescribed:
            raise SceneError(f"{w}: the hinge is prescribed (its joint), so a law would change only its hold torque")
        seen[k] = i
        kp = _number(e, "kp", w, minimum=0.0)
        kd = _number(e, "kd", w, minimum=0.0)
        set_point = _number(e, "set_point", w, 0.0)
        if kind == "hinge_pd":
            pd.append((k, [kp, kd, set_point]))
        else:
            ki = _number(e, "ki", w, minimum=0.0)
            tf = _number(e, "filter_time", w, positive=True)
            pid.append((k, [kp, ki, kd, tf, set_point]))
    law = controller = None
    if pd:
        kp, kd, r = (list(x) for x in zip(*(v for _, v in pd)))
        law = HingePD(n, [k for k, _ in pd], kp, kd, reference=np.asarray(r))
    if pid:
        kp, ki, kd, tf, r = (list(x) for x in zip(*(v for _, v in pid)))
        controller = HingePID(n, [k for k, _ in pid], kp, ki, kd, tf, reference=np.asarray(r))
    return law, controller, None if attitude is None else attitude[1]


def with_scene_laws(model: Model, data: dict) -> Model:
    """`model` (built from the scene's bodies and initial state) with the loads, control laws and
    orbit of the scene document `data` (each key optional)."""
    orbit = parse_orbit(data["orbit"]) if data.get("orbit") is not None else None
    loads = parse_loads(data["loads"], model, orbit) if data.get("loads") is not None else None
    law = controller = None
    if data.get("control") is not None:
        law, controller, attitude = parse_control(data["control"], model)
        loads = combine_loads(*_safe_parts(loads), attitude)  # one level of parts
    if loads is None and law is None and controller is None and orbit is None:
        return model
    return eqx.tree_at(
        lambda m: (m.loads, m.law, m.controller, m.orbit),
        model,
        (loads, law, controller, orbit),
        is_leaf=lambda x: x is None,
    )


# ----------------------------------------------------------------------------- writing
def _load_parts(loads) -> list:
    if loads is None:
        return []
    parts = list(loads.parts) if isinstance(loads, CombinedLoads) else [loads]
    for p in parts:
        if not isinstance(p, (ScheduledLoads, GravityGradient, AttitudePD)):
            raise ValueError(
                f"scene_to_dict: loads of type {type(p).__name__} have no JSON form "
                "(only ScheduledLoads and GravityGradient, the scene format's 'loads')"
            )
    return parts


def _same_orbit(a: CircularOrbit, g: GravityGradient) -> bool:
    return all(float(x) == float(y) for x, y in ((a.mu, g.mu), (a.radius, g.radius), (a.phase, g.phase)))


def laws_to_dict(model: Model) -> dict:
    """The scene keys ``orbit``, ``loads`` and ``control`` of `model` (only those it has).

    Raises ValueError for loads or laws that have no JSON form (a Python function)."""
    f = lambda a: np.asarray(a, dtype=float).tolist()
    names = model.names
    out: dict = {}
    loads: list[dict] = []
    orbit = model.orbit
    for p in _load_parts(model.loads):
        if isinstance(p, AttitudePD):
            continue  # a law: written under 'control'
        if isinstance(p, GravityGradient):
            if orbit is None:
                orbit = CircularOrbit(p.mu, p.radius, p.phase)
            elif not _same_orbit(orbit, p):
                raise ValueError("scene_to_dict: the gravity-gradient load's orbit differs from model.orbit")
            entry: dict = {"kind": "gravity_gradient"}
            if tuple(p.bodies) != tuple(model.massive):
                entry["bodies"] = [names[k] for k in p.bodies]
            loads.append(entry)
            continue
        for i, k in enumerate(p.rows):
            profile: dict = {"kind": p.profiles[i]}
            if p.profiles[i] == "pulse":
                profile.update(start=float(p.start[i]), duration=float(p.duration[i]), rise=float(p.rise[i]))
            elif p.profiles[i] == "table":
                L = p.lengths[i]
                profile.update(times=f(p.times[i, :L]), values=f(p.values[i, :L]))
            loads.append({"kind": p.kinds[i], "body": names[k], "vector": f(p.vector[i]), "profile": profile})
    if orbit is not None:
        out["orbit"] = {"mu": float(orbit.mu), "radius": float(orbit.radius), "phase": float(orbit.phase)}
    if loads:
        out["loads"] = loads
    control: list[dict] = []
    for p in _load_parts(model.loads):
        if isinstance(p, AttitudePD):
            control.append({"kind": "attitude_pd", "kp": f(p.kp), "kd": f(p.kd), "attitude_dcm": f(p.set_point)})
    for law, kind in ((model.law, "hinge_pd"), (model.controller, "hinge_pid")):
        if law is None:
            continue
        if type(law) is not (HingePD if kind == "hinge_pd" else HingePID) or law.reference_fn is not None:
            raise ValueError(
                f"scene_to_dict: model.{'law' if kind == 'hinge_pd' else 'controller'} "
                f"({type(law).__name__}) has no JSON form (a {'HingePD' if kind == 'hinge_pd' else 'HingePID'} "
                "to constant set points has)"
            )
        r = np.zeros(len(law.hinges)) if law.reference_value is None else np.asarray(law.reference_value, float)
        for i, k in enumerate(law.hinges):
            entry = {"kind": kind, "hinge": names[k], "kp": float(law.kp[i])}
            if kind == "hinge_pid":
                assert isinstance(law, HingePID)
                entry.update(ki=float(law.ki[i]), kd=float(law.kd[i]), filter_time=float(law.filter_time[i]))
            else:
                entry["kd"] = float(law.kd[i])
            entry["set_point"] = float(r[i])
            control.append(entry)
    if control:
        out["control"] = control
    return out


def prescribed_joints(model: Model) -> dict[int, dict]:
    """The ``joint`` objects of the prescribed hinges, by hinge (ValueError for a prescription
    given as a Python function: it has no JSON form)."""

    pres = model.prescription
    parts = [] if pres is None else list(pres.parts) if isinstance(pres, PrescriptionGroup) else [pres]
    f = lambda a: np.asarray(a, dtype=float).tolist()
    out: dict[int, dict] = {}
    for p in parts:
        for i, k in enumerate(p.hinges):
            if isinstance(p, SinePrescription):
                out[k] = {
                    "kind": "prescribed",
                    "function": "sine",
                    "amplitude": float(p.amplitude[i]),
                    "frequency": float(p.frequency[i]),
                    "phase": float(p.phase[i]),
                }
            elif isinstance(p, ShapePrescription):
                out[k] = {"kind": "prescribed", "function": p.shapes[i]}
                out[k].update({x: float(getattr(p, x)[i]) for x in ("initial", "final", "start", "duration")})
            elif isinstance(p, TablePrescription):
                L = p.lengths[i]
                out[k] = {
                    "kind": "prescribed",
                    "function": "table",
                    "times": f(p.times[i, :L]),
                    "angles": f(p.angles[i, :L]),
                }
            else:
                what = "a Python function" if isinstance(p, FunctionPrescription) else type(p).__name__
                raise ValueError(f"scene_to_dict: the prescription of hinge {k} ({what}) has no JSON form")
    return out


# ----------------------------------------------------------------------------- describing
def _g(x) -> str:
    return f"{float(x):.6g}"


def _vec(x) -> str:
    return "[" + ", ".join(_g(v) for v in np.asarray(x, float)) + "]"


def describe_laws(model: Model) -> list[str]:
    """Lines that list the model's prescribed hinges, loads, control laws and orbit (for
    ``jaxtree check``); empty when it has none of them."""
    names = model.names
    lines: list[str] = []
    try:
        joints = prescribed_joints(model)
    except ValueError:
        joints = {k: {"function": "a Python function"} for k in model.prescribed}
    for k in sorted(joints):
        j = joints[k]
        fn = j["function"]
        if fn == "sine":
            text = f"{_g(j['amplitude'])} sin({_g(j['frequency'])} t + {_g(j['phase'])}) rad"
        elif fn in ("ramp", "smooth_step"):
            text = (
                f"{fn.replace('_', ' ')} {_g(j['initial'])} -> {_g(j['final'])} rad from t = {_g(j['start'])} s "
                f"over {_g(j['duration'])} s"
            )
        elif fn == "table":
            text = (
                f"table of {len(j['times'])} points, t = {_g(j['times'][0])} .. {_g(j['times'][-1])} s (cubic Hermite)"
            )
        else:
            text = fn
        lines.append(f"  prescribed hinge {k} ({names[k]!r}): {text}")
    orbit = model.orbit
    for p in _safe_parts(model.loads):
        if isinstance(p, GravityGradient):
            o = CircularOrbit(p.mu, p.radius, p.phase)
            lines.append(
                f"  load: gravity gradient at the orbit's rate {_g(o.rate)} rad/s on bodies {list(p.bodies)} "
                "(3 n^2 r x (I r) about each mass center, tidal forces)"
            )
            if orbit is None:
                orbit = o
        elif isinstance(p, ScheduledLoads):
            for i, k in enumerate(p.rows):
                unit = "N m" if p.kinds[i] == "torque" else "N"
                prof = p.profiles[i]
                if prof == "pulse":
                    prof = f"pulse from t = {_g(p.start[i])} s for {_g(p.duration[i])} s (rise {_g(p.rise[i])} s)"
                elif prof == "table":
                    L = p.lengths[i]
                    prof = f"times a table of {L} points, t = {_g(p.times[i, 0])} .. {_g(p.times[i, L - 1])} s"
                lines.append(f"  load: {p.kinds[i]} {_vec(p.vector[i])} {unit} on {_body(k, names)}, {prof}")
        elif isinstance(p, AttitudePD):
            angles = _vec(dcm_to_euler123(p.set_point))
            lines.append(
                f"  control: {_body(0, names)} attitude PD to Euler 1-2-3 angles {angles} rad, kp {_vec(p.kp)} N m/rad, "
                f"kd {_vec(p.kd)} N m s/rad (a torque on it)"
            )
        else:
            lines.append(f"  load: {type(p).__name__} on bodies {list(p.bodies)} (Python)")
    for law in (model.law, model.controller):
        if isinstance(law, (HingePD, HingePID)) and law.reference_fn is None:
            r = np.zeros(len(law.hinges)) if law.reference_value is None else np.asarray(law.reference_value, float)
            for i, k in enumerate(law.hinges):
                if isinstance(law, HingePD):
                    gains = f"kp {_g(law.kp[i])} N m/rad, kd {_g(law.kd[i])} N m s/rad"
                else:
                    gains = (
                        f"kp {_g(law.kp[i])}, ki {_g(law.ki[i])}, kd {_g(law.kd[i])}, "
                        f"rate filter {_g(law.filter_time[i])} s"
                    )
                kind = "PD" if isinstance(law, HingePD) else "PID"
                lines.append(f"  control: hinge {k} ({names[k]!r}) {kind} to {_g(r[i])} rad, {gains}")
        elif law is not None:
            lines.append(f"  control: {type(law).__name__} (Python)")
    if orbit is not None:
        period = 2 * np.pi / float(orbit.rate)
        lines.append(
            f"  orbit: circular, radius {_g(orbit.radius)} m, mu {_g(orbit.mu)} m^3/s^2, rate {_g(orbit.rate)} rad/s "
            f"(period {period / 60:.4g} min), phase {_g(orbit.phase)} rad"
        )
    return lines


def _safe_parts(loads) -> list:
    if loads is None:
        return []
    return list(loads.parts) if isinstance(loads, CombinedLoads) else [loads]
