"""Validation of a model's array leaves -- of one model or of a batch of dispersed models --
before anything is traced, and the `model` argument of the public functions.

:func:`~jaxtree.build_model` checks its input as it builds; a campaign or a parameter study changes
the leaves afterwards (``eqx.tree_at``, leaves with a leading batch axis for ``jax.vmap``), and
every public function that takes a model checks it here (:func:`check_model`) when it is concrete.
The engine imports this module, never the scene format's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError, SceneTypeError, short
from ..numerics import is_traced
from .model import Model, SinePrescription
from .profiles import PrescriptionGroup, ShapePrescription, TablePrescription


def body_label(k, name):
    """How a message names body `k`: ``body 3 ('panel')``."""
    return f"body {k} ({name!r})"


def validate_model(model: Model) -> Model:
    """Check the array leaves of a model -- or of a batch of models -- before anything is traced.

    :func:`build_model` validates its input, but a Monte Carlo campaign or a parameter study
    changes masses, inertias, axes and stiffnesses afterwards (``eqx.tree_at``, or leaves with a
    leading batch axis for ``jax.vmap``). This applies the same checks to the leaves as they are
    now, over any leading batch axes, and the checks that the model's static structure still
    describes them: a body built massless (not in ``model.massive``) must keep zero mass and
    inertia (else its mass would be silently left out of Eq. 1), and hinge axes must stay unit
    vectors (Eq. 4 assumes it; :func:`build_model` normalizes them).

    Raises :class:`SceneError` naming the run (the batch index, for a batch), the body and the
    field, e.g. ``run (17,): body 0 ('bus'): field 'inertia' violates the triangle inequality``;
    returns `model` unchanged.
    """
    if not isinstance(model, Model):
        raise SceneTypeError(f"validate_model: expected a jaxtree.Model, got {short(model)}")
    if is_traced(model):
        raise SceneTypeError(
            "validate_model needs concrete arrays: call it on the model (or batch of models) "
            "before jax.jit / jax.vmap, not inside"
        )
    check = _LeafCheck(model, _batch_axes(model))
    check.bodies()
    if model.n == 0:
        return model
    check.hinges()
    _validate_leaves_of(model)
    return model


def check_model(name: str, model) -> Model:
    """The `model` argument of the public function `name`: a :class:`~jaxtree.Model`
    (:class:`SceneTypeError` naming the function), validated (:func:`validate_model`) when concrete."""
    if not isinstance(model, Model):
        raise SceneTypeError(
            f"{name}: model must be a jaxtree.Model (load_scene / build_model), got {type(model).__name__}"
        )
    if not is_traced(model):
        validate_model(model)
    return model


# the array leaves of a Model that validate_model checks, and the shape each ends in
def _leaf_tails(n: int) -> dict[str, tuple[int, ...]]:
    return {
        "mass": (n + 1,),
        "inertia": (n + 1, 3, 3),
        "axis": (n, 3),
        "hinge_on_parent": (n, 3),
        "hinge_on_body": (n, 3),
        "stiffness": (n,),
        "damping": (n,),
    }


def _batch_axes(model: Model) -> tuple[int, ...]:
    """The leading batch axes of a model's array leaves (() for one model), once each leaf is
    checked to be a floating-point array ending in its shape."""
    tails = _leaf_tails(model.n)
    for k in tails:
        x = getattr(model, k)
        kind = x.dtype if isinstance(x, (np.ndarray, jax.Array)) else None
        if kind is None or not jnp.issubdtype(kind, jnp.floating):
            raise SceneTypeError(
                f"model: field {k!r} must be a floating-point array, got "
                f"{short(x) if kind is None else f'an array of {kind}'}"
            )
    shapes = {k: np.shape(getattr(model, k)) for k in tails}
    for k, tail in tails.items():
        if shapes[k][len(shapes[k]) - len(tail) :] != tail:
            raise SceneError(f"model: field {k!r} must end in shape {tail}, got {shapes[k]}")
    try:
        return np.broadcast_shapes(*(shapes[k][: len(shapes[k]) - len(t)] for k, t in tails.items()))
    except ValueError:
        raise SceneError(f"model: the batch axes of the leaves do not match: {shapes}") from None


class _LeafCheck:
    """The checks of :func:`validate_model` on the leaves of a model, broadcast to its batch axes."""

    def __init__(self, model: Model, batch: tuple[int, ...]):
        self.model, self.batch = model, batch
        # relative tolerance of the checks: 1e-9 as in build_model, or the rounding of a float32 model
        self.rel = max(1e-9, 100 * float(np.finfo(np.asarray(model.mass).dtype).eps))

    def leaf(self, field: str):
        """The leaf `field` as float, broadcast to the batch axes."""
        return np.broadcast_to(
            np.asarray(getattr(self.model, field), dtype=float), self.batch + _leaf_tails(self.model.n)[field]
        )

    def fail(self, bad, message, body_offset=0):
        """Raise for the first True of `bad` (batch + (bodies,)) with message(run, body)."""
        hit = np.argwhere(bad)
        if len(hit):
            run, k = tuple(int(i) for i in hit[0][:-1]), int(hit[0][-1]) + body_offset
            prefix = f"run {run}: " if self.batch else ""
            raise SceneError(prefix + f"{body_label(k, self.model.names[k])}: " + message(run, k))

    def bodies(self) -> None:
        """Masses and inertias: finite, mass >= 0, inertia symmetric, positive semidefinite, with
        principal moments that a mass distribution can have; zero for a body built massless."""
        model, fail = self.model, self.fail
        mass, J = self.leaf("mass"), self.leaf("inertia")
        fail(~np.isfinite(mass), lambda r, k: f"field 'mass' must be finite, got {mass[r][k]}")
        fail(mass < 0, lambda r, k: f"field 'mass' must be >= 0, got {mass[r][k]}")
        fail(~np.isfinite(J).all((-1, -2)), lambda r, k: "field 'inertia' must be finite")
        tol = self.rel * np.maximum(np.abs(J).max((-1, -2)), 1e-300)
        fail(
            np.abs(J - np.swapaxes(J, -1, -2)).max((-1, -2)) > tol,
            lambda r, k: f"field 'inertia' is not symmetric: {J[r][k].tolist()}",
        )
        massless = np.ones(model.n + 1, dtype=bool)
        massless[list(model.massive)] = False
        fail(
            massless & ((mass != 0) | (np.abs(J).max((-1, -2)) > 0)),
            lambda r, k: (
                f"fields 'mass' / 'inertia' must stay zero: the model was built with this body massless "
                f"(mass {mass[r][k]}); rebuild it with build_model to give the body mass"
            ),
        )
        fail(
            (mass == 0) & (np.abs(J).max((-1, -2)) > 0),
            lambda r, k: f"a massless body must have zero 'inertia', got {J[r][k].tolist()}",
        )
        ev = np.linalg.eigvalsh(0.5 * (J + np.swapaxes(J, -1, -2)))
        fail(
            ev[..., 0] < -tol,
            lambda r, k: f"field 'inertia' is not positive semidefinite (eigenvalues {ev[r][k].tolist()})",
        )
        fail(
            ev[..., 0] + ev[..., 1] < ev[..., 2] - tol,
            lambda r, k: (
                f"field 'inertia' violates the triangle inequality of principal moments ({ev[r][k].tolist()}); "
                "no mass distribution has it"
            ),
        )
        total = mass.sum(-1)
        if np.any(total <= 0):
            run = tuple(int(i) for i in np.argwhere(total <= 0)[0])
            raise SceneError((f"run {run}: " if self.batch else "") + "bodies: the total mass must be positive")

    def hinges(self) -> None:
        """Hinge axes finite unit vectors, hinge points finite, springs and dampers finite and
        (where sprung) >= 0."""
        model, fail, rel = self.model, self.fail, self.rel
        axis = self.leaf("axis")
        fail(~np.isfinite(axis).all(-1), lambda r, k: f"field 'axis' must be finite, got {axis[r][k - 1].tolist()}", 1)
        fail(
            np.abs(np.linalg.norm(axis, axis=-1) - 1) > rel,
            lambda r, k: (
                f"field 'axis' must be a unit vector (Eq. 4), got {axis[r][k - 1].tolist()} of norm "
                f"{np.linalg.norm(axis[r][k - 1]):.12g}"
            ),
            1,
        )
        for field in ("hinge_on_parent", "hinge_on_body"):
            v = self.leaf(field)
            fail(
                ~np.isfinite(v).all(-1),
                lambda r, k, v=v, f=field: f"field {f!r} must be finite, got {v[r][k - 1].tolist()}",
                1,
            )
        sprung = np.zeros(model.n, dtype=bool)
        sprung[np.asarray(model.sprung, dtype=np.int64) - 1] = True
        for field in ("stiffness", "damping"):
            v = self.leaf(field)
            fail(~np.isfinite(v), lambda r, k, v=v, f=field: f"field 'joint.{f}' must be finite, got {v[r][k - 1]}", 1)
            fail(sprung & (v < 0), lambda r, k, v=v, f=field: f"field 'joint.{f}' must be >= 0, got {v[r][k - 1]}", 1)


def _validate_leaves_of(model: Model) -> None:
    """The initial state and the sine prescription of a (batch of) model(s): finite, of the
    model's shapes (after any batch axes), and ``initial.dcm`` a rotation."""
    n = model.n
    for field, tail in (("dcm", (3, 3)), ("omega0", (3,)), ("gamma", (n,)), ("gamma_dot", (n,))):
        x = getattr(model.initial, field)
        what = f"model: field 'initial.{field}'"
        if not isinstance(x, (np.ndarray, jax.Array)) or not jnp.issubdtype(x.dtype, jnp.floating):
            raise SceneTypeError(f"{what} must be a floating-point array, got {short(x)}")
        x = np.asarray(x, float)
        if x.shape[x.ndim - len(tail) :] != tail or x.ndim < len(tail):
            raise SceneError(f"{what} must end in shape {tail}, got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise SceneError(f"{what} must be finite")
        if field == "dcm":
            tol = max(1e-6, 1e3 * float(np.finfo(np.asarray(model.initial.dcm).dtype).eps))
            err = np.abs(x @ np.swapaxes(x, -1, -2) - np.eye(3)).max()
            if err > tol or np.any(np.linalg.det(x) < 0):
                raise SceneError(
                    f"{what} must be a proper rotation matrix (orthonormal, det +1): max |C C^T - I| = {err:.3g}"
                )
    pres = model.prescription
    parts = [] if pres is None else list(pres.parts) if isinstance(pres, PrescriptionGroup) else [pres]
    fields = {
        SinePrescription: ("amplitude", "frequency", "phase"),
        ShapePrescription: ("initial", "final", "start", "duration"),
        TablePrescription: ("times", "angles"),
    }
    for p in parts:
        for field in fields.get(type(p), ()):
            v = np.asarray(getattr(p, field), float)
            for bad, what in ((~np.isfinite(v), "finite"), (v <= 0 if field == "duration" else None, "> 0")):
                if bad is not None and bad.any():
                    i = int(np.argwhere(bad)[0][v.ndim - (2 if isinstance(p, TablePrescription) else 1)])
                    k = p.hinges[i]
                    raise SceneError(f"{body_label(k, model.names[k])}: field 'joint.{field}' must be {what}")
