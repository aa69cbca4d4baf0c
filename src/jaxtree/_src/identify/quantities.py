"""The numbers of a model by name, for identification: ``"<body>.mass"`` and the like, resolved
once, before anything is traced, into where they live in the model's array leaves.

A *quantity* is one number of the model (or a symmetric pair of inertia entries); a *parameter*
is what a fit estimates: one or more quantities set to one value together. Names:

- ``"<body>.mass"``, ``"<body>.inertia[i,j]"`` (about the body's mass center, in its frame; the
  entries ``[i,j]`` and ``[j,i]`` are set together, so the matrix stays symmetric);
- ``"<body>.stiffness"``, ``"<body>.damping"``: the spring-damper law of the body's hinge;
- ``"<body>.hinge_on_parent[i]"``, ``"<body>.hinge_on_body[i]"``: the hinge's points (Def. 13);
- ``"<body>.initial_angle"``, ``"<body>.initial_rate"``: the hinge's initial angle and rate;
- any other array leaf of the model by its path and index, as ``jax.tree_util.keystr`` spells
  the path without the leading dot: ``"initial.omega0[2]"`` (the base body's initial rate),
  ``"loads.torque[1]"`` (a thruster's torque), ``"law.kp[0]"`` (a law's gain), ``"orbit.rate"``.

Bodies are named as in the scene (``model.names``) or by index. A mass, a diagonal inertia entry,
a stiffness and a damping must stay positive: they are fitted as logarithms unless told otherwise
(the standard errors of a logarithm are relative ones).
"""

from __future__ import annotations

import dataclasses
import re

import equinox as eqx
import jax
import numpy as np

from ..errors import SceneError, SceneKeyError, SceneTypeError
from ..vehicle.model import Model

# the quantities named after a body and where they live: (leaf path, row of the leaf, positive?)
_BODY_FIELDS = {
    "mass": ("mass", "body", 0, True),
    "inertia": ("inertia", "body", 2, None),  # positive on the diagonal only
    "stiffness": ("stiffness", "hinge", 0, True),
    "damping": ("damping", "hinge", 0, True),
    "hinge_on_parent": ("hinge_on_parent", "hinge", 1, False),
    "hinge_on_body": ("hinge_on_body", "hinge", 1, False),
    "initial_angle": ("initial.gamma", "hinge", 0, False),
    "initial_rate": ("initial.gamma_dot", "hinge", 0, False),
}
_NAME = re.compile(r"^\s*(?P<head>[^\[\]]+?)\s*(?:\[(?P<index>[^\]]*)\])?\s*$")


@dataclasses.dataclass(frozen=True)
class Quantity:
    """One number of a model: `leaf` (the index of its array leaf among the model's inexact array
    leaves), `index` (its place in that leaf; `mirror`: a second place set with it, the transposed
    inertia entry), `positive` (a mass, a diagonal inertia, a stiffness or a damping)."""

    name: str
    leaf: int
    index: tuple[int, ...]
    mirror: tuple[int, ...] | None
    positive: bool


def _leaf_paths(model: Model) -> list[str]:
    """The paths of the model's inexact array leaves, ``keystr`` without the leading dot."""
    leaves = jax.tree_util.tree_leaves_with_path(model)
    return [jax.tree_util.keystr(p).lstrip(".") for p, x in leaves if eqx.is_inexact_array(x)]


def _indices(text: str | None, name: str) -> tuple[int, ...]:
    if text is None or not text.strip():
        return ()
    try:
        return tuple(int(part) for part in text.split(","))
    except ValueError:
        raise SceneError(f"identify: quantity {name!r}: the index [{text}] must be integers") from None


def body_of(model: Model, body: str, what: str, hinge: bool = False) -> int:
    """The index of `body` (a name of ``model.names`` or an index) for `what` (a quantity or a
    sensor, named in the error), which needs the body's hinge when `hinge`."""
    try:
        k = model.body_index(int(body) if body.isdigit() else body)
    except (KeyError, IndexError):
        raise SceneKeyError(f"identify: {what}: no body {body!r}; bodies are {', '.join(model.names)}") from None
    if hinge and k == 0:
        raise SceneError(f"identify: {what}: body {model.names[0]!r} is the base; it has no hinge")
    return k


def resolve(model: Model, name) -> Quantity:
    """The :class:`Quantity` a name denotes in `model`; a :class:`SceneError` naming it if none."""
    if not isinstance(name, str):
        raise SceneTypeError(f"identify: a quantity is named by a string such as 'hub.mass', got {name!r}")
    m = _NAME.match(name)
    if m is None:
        raise SceneError(f"identify: quantity {name!r}: expected '<body>.<field>' or '<leaf path>[index]'")
    head, index = m.group("head"), _indices(m.group("index"), name)
    paths = _leaf_paths(model)
    body, _, field = head.rpartition(".")
    if field in _BODY_FIELDS and body:
        path, kind, dims, positive = _BODY_FIELDS[field]
        k = body_of(model, body, f"quantity {name!r}", hinge=kind == "hinge")
        if kind == "hinge" and field in ("stiffness", "damping") and k not in model.sprung:
            raise SceneError(
                f"identify: quantity {name!r}: the hinge of body {model.names[k]!r} carries no spring-damper law "
                f"(sprung hinges: {', '.join(model.names[s] for s in model.sprung) or 'none'})"
            )
        if len(index) != dims:
            want = {0: "no index", 1: "one index [i]", 2: "two indices [i,j]"}[dims]
            raise SceneError(f"identify: quantity {name!r}: '{field}' takes {want}")
        if any(not 0 <= i < 3 for i in index):
            raise SceneError(f"identify: quantity {name!r}: indices run over 0, 1, 2")
        row = k if kind == "body" else k - 1
        full = (row, *index)
        mirror = (row, index[1], index[0]) if dims == 2 and index[0] != index[1] else None
        if positive is None:
            positive = index[0] == index[1]
        if field == "mass" or field == "inertia":
            if k not in model.massive:
                raise SceneError(f"identify: quantity {name!r}: body {model.names[k]!r} is massless in the scene")
        return Quantity(name, paths.index(path), full, mirror, bool(positive))
    if head not in paths:
        raise SceneKeyError(
            f"identify: unknown quantity {name!r}: use '<body>.<field>' with field one of "
            f"{', '.join(_BODY_FIELDS)}, or the path of an array leaf of the model: {', '.join(paths)}"
        )
    leaf = paths.index(head)
    shape = np.shape([x for x in jax.tree_util.tree_leaves(model) if _inexact(x)][leaf])
    if len(index) != len(shape) or any(not 0 <= i < s for i, s in zip(index, shape)):
        raise SceneError(f"identify: quantity {name!r}: leaf {head!r} has shape {shape}; give one index per axis")
    return Quantity(name, leaf, index, None, False)


def _inexact(x) -> bool:
    return eqx.is_inexact_array(x)


def value(model: Model, q: Quantity) -> float:
    """The quantity's value in `model` (concrete)."""
    leaf = [x for x in jax.tree_util.tree_leaves(model) if _inexact(x)][q.leaf]
    return float(np.asarray(leaf)[q.index])
