"""Scene files: the ``jaxtree-scene/1`` JSON format read into a model and written from one, and the
bundled scenes."""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import tempfile

import jax
import numpy as np

from ..errors import SceneError, SceneTypeError, short
from ..vehicle.model import Model
from .appendages import parse_appendages
from .keys import unknown_keys
from .laws import laws_to_dict, prescribed_joints, with_scene_laws
from .scene import FORMAT, SCENES, build_model

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
    p = SCENES / f"{name}.json"
    if not p.exists():
        raise FileNotFoundError(f"no bundled scene {name!r}; available: {list_scenes()}")
    return p


def list_scenes() -> list[str]:
    """Names of the bundled reference scenes."""
    return sorted(p.stem for p in SCENES.glob("*.json"))


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
