"""The ``appendages`` of a ``jaxtree-scene/1`` document: finite-element appendages fixed to bodies
of the tree, described by a file or by the beam generator (docs/scene_format.md).

Each entry is an object:

- ``body``: the body it is fixed to (name or index); ``point`` (3, default 0): the interface point
  from the body's mass center, body's frame; ``frame`` (3 x 3, default the body's axes): the
  structure's axes in the body's frame (columns);
- the structure, one of: ``file`` (a ``jaxtree-fe/1`` or ``jaxtree-appendage/1`` ``.npz``, a path
  relative to the scene file; a precomputed ``jaxtree-appendage/1`` carries its own modes, point
  and frame, so ``point``, ``frame``, ``modes``, ``tol``, ``interface``, ``damping``, ``outputs`` and
  ``geometric`` are not given with it), or ``beam``: the arguments of :func:`jaxtree.beam`
  (``length``, ``elements``, ``E``, ``rho``, ``area``, ``Iy``; optional ``Iz``, ``J``, ``G``,
  ``direction``, ``up``, ``origin``), or ``plate``: those of :func:`jaxtree.plate` (``length``,
  ``width``, ``n_length``, ``n_width``, ``E``, ``rho``, ``thickness``; optional ``nu``,
  ``direction``, ``across``, ``origin``), held by default along its root edge;
- ``modes``: a number or ``"auto"`` (default) with ``tol`` (default 0.01); ``interface`` (default
  [0], a plate's root edge); ``damping`` (modal damping ratio, default 0); ``outputs`` (node indices); ``geometric``
  (default true); ``name`` (default ``"appendage<i>"``).

This module parses and checks the entries (errors name the appendage and the field) into
:class:`AppendageSpec` records that a :class:`~jaxtree._src.vehicle.model.Model` carries as a
static field, and builds the appendages from them (:func:`scene_appendages`, through
:mod:`jaxtree._src.appendage`: the files, the generators and the held-interface modes).
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib

import numpy as np

from ..appendage.fe import beam, plate, plate_edge
from ..appendage.files import APPENDAGE_FORMAT, load_appendage, load_fe
from ..appendage.model import Appendage, appendage
from ..errors import SceneError, SceneTypeError, short
from ..values import as_float, rotation
from .keys import unknown_keys

_KEYS = {
    "name",
    "body",
    "point",
    "frame",
    "file",
    "beam",
    "plate",
    "modes",
    "tol",
    "interface",
    "damping",
    "outputs",
    "geometric",
}
_BEAM_KEYS = {"length", "elements", "E", "rho", "area", "Iy", "Iz", "J", "G", "direction", "up", "origin"}
_BEAM_REQUIRED = ("length", "elements", "E", "rho", "area", "Iy")
_PLATE_KEYS = {"length", "width", "n_length", "n_width", "E", "rho", "thickness", "nu", "direction", "across", "origin"}
_PLATE_REQUIRED = ("length", "width", "n_length", "n_width", "E", "rho", "thickness")
_INTEGERS = ("elements", "n_length", "n_width")
_VECTORS = ("direction", "up", "origin", "across")


@dataclasses.dataclass(frozen=True)
class AppendageSpec:
    """One appendage of a scene (module docstring), checked; hashable (a static field of a model).
    `file` is an absolute path; `beam` a tuple of ``(key, value)`` pairs (vectors as tuples)."""

    name: str
    body: str | int
    point: tuple = (0.0, 0.0, 0.0)
    frame: tuple | None = None
    file: str | None = None
    beam: tuple | None = None
    plate: tuple | None = None
    modes: int | str = "auto"
    tol: float = 1e-2
    interface: tuple | None = None
    damping: float = 0.0
    outputs: tuple = ()
    geometric: bool = True

    def beam_arguments(self) -> dict:
        return {k: (np.asarray(v) if isinstance(v, tuple) else v) for k, v in (self.beam or ())}

    def plate_arguments(self) -> dict:
        return {k: (np.asarray(v) if isinstance(v, tuple) else v) for k, v in (self.plate or ())}

    def to_dict(self, base_dir=None) -> dict:
        """The scene entry (the file relative to `base_dir` when it lies below it)."""
        d: dict = {"name": self.name, "body": self.body}
        if self.file is not None:
            f = pathlib.Path(self.file)
            if base_dir is not None:
                try:
                    f = f.relative_to(pathlib.Path(base_dir).resolve())
                except ValueError:
                    pass
            d["file"] = str(f)
        for key in ("beam", "plate"):
            gen = getattr(self, key)
            if gen is not None:
                d[key] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in gen}
        precomputed = self.file is not None and _is_precomputed(self.file)
        if not precomputed:
            d.update(
                point=list(self.point),
                modes=self.modes,
                tol=self.tol,
                **({} if self.interface is None else {"interface": list(self.interface)}),
                damping=self.damping,
                outputs=list(self.outputs),
                geometric=self.geometric,
            )
            if self.frame is not None:
                d["frame"] = [list(r) for r in self.frame]
        return d


def _is_precomputed(path) -> bool:
    try:
        with np.load(path, allow_pickle=False) as data:
            return str(data["format"]) == "jaxtree-appendage/1" if "format" in data.files else False
    except (OSError, ValueError):
        return False


def _ints(value, where: str, field: str) -> tuple:
    items = value if isinstance(value, (list, tuple)) else [value]
    out = []
    for v in items:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or int(v) < 0:
            raise SceneError(f"{where}: field {field!r} must hold node indices (integers >= 0), got {short(value)}")
        out.append(int(v))
    return tuple(out)


def _generator(b, key, keys, required, where) -> tuple:
    """A generator's arguments (``beam`` or ``plate``) as sorted ``(key, value)`` pairs."""
    if not isinstance(b, dict):
        raise SceneTypeError(f"{where}: field {key!r} must be an object, got {short(b)}")
    unknown_keys(b, keys, f"{where}: field {key!r}")
    missing = [k for k in required if k not in b]
    if missing:
        raise SceneError(f"{where}: field {key!r} needs {', '.join(missing)}")
    items = []
    for k in sorted(b):
        v = b[k]
        if k in _INTEGERS:
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise SceneError(f"{where}: field '{key}.{k}' must be a positive integer, got {short(v)}")
        elif k in _VECTORS:
            v = tuple(float(x) for x in as_float(v, f"{where}: field '{key}.{k}'", (3,)))
        else:
            v = float(as_float(v, f"{where}: field '{key}.{k}'", ()))
            if k == "nu":
                if not -1.0 < v < 0.5:
                    raise SceneError(f"{where}: field '{key}.nu' must be in (-1, 0.5), got {v}")
            elif not v > 0:
                raise SceneError(f"{where}: field '{key}.{k}' must be positive, got {v}")
        items.append((k, v))
    return tuple(items)


def _appendage_body(e: dict, names, where: str):
    """The body that an appendage entry is fixed to, checked: a name of `names` as given, or an index into them."""
    body = e["body"]
    if isinstance(body, str):
        if body not in names:
            raise SceneError(f"{where}: field 'body' names no body: {short(body)}; bodies: {list(names)}")
    elif isinstance(body, bool) or not isinstance(body, (int, np.integer)) or not 0 <= int(body) < len(names):
        raise SceneError(f"{where}: field 'body' must be a body name or an index 0..{len(names) - 1}")
    else:
        body = int(body)
    return body


def _appendage_source(e: dict, where: str, base_dir) -> dict:
    """An appendage entry's one source of modes as keyword arguments of :class:`AppendageSpec`: its file
    (resolved against `base_dir`; a file of precomputed modes admits none of the fields that it fixes) or a
    beam's or plate's generator arguments."""
    given = [k for k in ("file", "beam", "plate") if k in e]
    if len(given) != 1:
        raise SceneError(f"{where}: give exactly one of 'file' (a .npz), 'beam' and 'plate' (a generator's arguments)")
    kw: dict = {}
    if given[0] == "file":
        f = e["file"]
        if not isinstance(f, str):
            raise SceneTypeError(f"{where}: field 'file' must be a path, got {short(f)}")
        p = pathlib.Path(f)
        if not p.is_absolute() and base_dir is not None:
            p = pathlib.Path(base_dir) / p
        if not p.is_file():
            raise SceneError(f"{where}: field 'file': no such file {str(p)!r}")
        kw["file"] = str(p.resolve())
        if _is_precomputed(p):
            fixed = sorted(set(e) & {"point", "frame", "modes", "tol", "interface", "damping", "outputs", "geometric"})
            if fixed:
                raise SceneError(
                    f"{where}: {p.name} holds precomputed modes (jaxtree-appendage/1), which fix "
                    f"{', '.join(fixed)}; leave them out of the scene"
                )
    else:
        key = given[0]
        keys, required = (_BEAM_KEYS, _BEAM_REQUIRED) if key == "beam" else (_PLATE_KEYS, _PLATE_REQUIRED)
        kw[key] = _generator(e[key], key, keys, required, where)
    return kw


def _appendage_options(e: dict, where: str) -> dict:
    """An appendage entry's optional fields (point, frame, modes, tol, damping, interface, outputs,
    geometric), checked, as keyword arguments of :class:`AppendageSpec`."""
    kw: dict = {}
    if "point" in e:
        kw["point"] = tuple(float(x) for x in as_float(e["point"], f"{where}: field 'point'", (3,)))
    if "frame" in e:
        C = rotation(as_float(e["frame"], f"{where}: field 'frame'", (3, 3)), f"{where}: field 'frame'")
        kw["frame"] = tuple(tuple(float(x) for x in row) for row in C)
    if "modes" in e:
        m = e["modes"]
        if m != "auto" and (isinstance(m, bool) or not isinstance(m, int) or m < 1):
            raise SceneError(f"{where}: field 'modes' must be a positive integer or 'auto', got {short(m)}")
        kw["modes"] = m
    if "tol" in e:
        t = float(as_float(e["tol"], f"{where}: field 'tol'", ()))
        if not 0 < t < 1:
            raise SceneError(f"{where}: field 'tol' must be in (0, 1), got {t}")
        kw["tol"] = t
    if "damping" in e:
        z = float(as_float(e["damping"], f"{where}: field 'damping'", ()))
        if z < 0:
            raise SceneError(f"{where}: field 'damping' must be >= 0, got {z}")
        kw["damping"] = z
    if "interface" in e:
        kw["interface"] = _ints(e["interface"], where, "interface")
        if not kw["interface"]:
            raise SceneError(f"{where}: field 'interface' is empty")
    if "outputs" in e:
        kw["outputs"] = _ints(e["outputs"], where, "outputs")
    if "geometric" in e:
        if not isinstance(e["geometric"], bool):
            raise SceneTypeError(f"{where}: field 'geometric' must be true or false, got {short(e['geometric'])}")
        kw["geometric"] = e["geometric"]
    return kw


def parse_appendages(entries, names, base_dir=None) -> tuple[AppendageSpec, ...]:
    """The scene's ``appendages`` list as checked :class:`AppendageSpec` records; `names` are the
    model's body names, `base_dir` the scene file's folder (files are relative to it)."""
    if entries is None:
        return ()
    if not isinstance(entries, list):
        raise SceneTypeError(f"scene: field 'appendages' must be a list, got {short(entries)}")
    out = []
    for i, e in enumerate(entries):
        where = f"appendage {i}"
        if not isinstance(e, dict):
            raise SceneTypeError(f"{where}: expected an object, got {short(e)}")
        name = e.get("name", f"appendage{i}")
        if not isinstance(name, str):
            raise SceneTypeError(f"{where}: field 'name' must be a string, got {short(name)}")
        where = f"appendage {i} ({name!r})"
        unknown_keys(e, _KEYS, where)
        if "body" not in e:
            raise SceneError(f"{where}: field 'body' is missing (the body it is fixed to)")
        body = _appendage_body(e, names, where)
        kw = _appendage_source(e, where, base_dir)
        kw.update(_appendage_options(e, where))
        out.append(AppendageSpec(name=name, body=body, **kw))
    if len({s.name for s in out}) < len(out):
        raise SceneError("scene: two appendages share a name")
    return tuple(out)


@functools.lru_cache(maxsize=64)
def _built(spec: AppendageSpec, mtime) -> Appendage:
    """The appendage of one entry (its file read, or its beam or plate generated, and reduced to
    its held-interface modes), kept per entry and file version."""
    del mtime  # part of the cache key: a file written again is read again
    if spec.file is not None:
        with np.load(spec.file, allow_pickle=False) as data:
            fmt = str(data["format"]) if "format" in data.files else ""
        if fmt == APPENDAGE_FORMAT:
            ap = load_appendage(spec.file)
            if ap.body != spec.body:
                raise SceneError(
                    f"appendage {spec.name!r}: {pathlib.Path(spec.file).name} was computed for body {ap.body!r}, "
                    f"the scene fixes it to {spec.body!r}"
                )
            return dataclasses.replace(ap, name=spec.name) if ap.name != spec.name else ap
        fe = load_fe(spec.file)
    elif spec.plate is not None:
        args = spec.plate_arguments()
        na, nb = args.pop("n_length"), args.pop("n_width")
        fe = plate(args.pop("length"), args.pop("width"), na, nb, **args)
    else:
        args = spec.beam_arguments()
        fe = beam(args.pop("length"), args.pop("elements"), area=args.pop("area"), **args)
    interface = spec.interface
    if interface is None:
        interface = plate_edge(na, nb) if spec.plate is not None else (0,)
    frame = None if spec.frame is None else np.asarray(spec.frame)
    try:
        return appendage(
            fe,
            spec.body,
            interface=interface,
            point=spec.point,
            frame=frame,
            n_modes=spec.modes,
            tol=spec.tol,
            damping=spec.damping,
            outputs=spec.outputs,
            geometric=spec.geometric,
            name=spec.name,
        )
    except SceneError as e:
        raise SceneError(f"appendage {spec.name!r}: {e}") from None


def scene_appendages(model) -> tuple[Appendage, ...]:
    """The finite-element appendages the scene of `model` declares (its ``appendages``, parsed into
    :class:`AppendageSpec` records above), built (and cached per entry and file) for :func:`jaxtree.hybrid_model`'s `appendages`."""
    out = []
    for spec in getattr(model, "appendages", ()):
        mtime = pathlib.Path(spec.file).stat().st_mtime_ns if spec.file is not None else 0
        out.append(_built(spec, mtime))
    return tuple(out)
