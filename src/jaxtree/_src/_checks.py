"""Input checks shared by the public functions: every bad input is named before tracing.

A scene, a builder call or an argument of :func:`jaxtree.simulate`, :func:`jaxtree.linearize`,
:func:`jaxtree.modes` or :func:`jaxtree.hybrid_model` that cannot describe a vehicle or a run
raises :class:`SceneError` naming the body and the field (or the function and the argument),
on plain numpy data and before anything is traced, so that no exception from inside JAX or
numpy reaches the user. Values that are traced (under ``jax.jit``, ``jax.vmap``,
``jax.grad``) are left to run time.

:class:`SceneError` is a :class:`ValueError`; a wrong type raises a SceneError that is also a
:class:`TypeError`, an unknown body name one that is also a :class:`KeyError`, so that both
``except jaxtree.SceneError`` and the built-in exception types catch them.

This module holds the basic checks and imports nothing else of the package; the checks of
one public function's arguments stand beside that function (``linearize_args`` in
:mod:`~jaxtree._src.linear.linearize`, ``check_model`` beside ``validate_model`` in
:mod:`~jaxtree._src.scene.scene`, ...) and return the values they parse.
"""

from __future__ import annotations

import difflib
from typing import NamedTuple

import jax
import numpy as np
from jax.core import Tracer


class SceneError(ValueError):
    """Invalid vehicle description or argument; the message names the body and the field
    (or the function and the argument)."""


class SceneTypeError(SceneError, TypeError):
    """A :class:`SceneError` for a value of the wrong type (also a :class:`TypeError`)."""


class SceneKeyError(SceneError, KeyError):
    """A :class:`SceneError` for an unknown name (also a :class:`KeyError`)."""

    __str__ = Exception.__str__  # KeyError quotes its message


class SceneWarning(UserWarning):
    """A scene or builder input was accepted with a change the user should know of. (Unknown
    keys were such warnings; they are errors now, see :func:`unknown_keys`.)"""


def is_traced(tree) -> bool:
    """True when any leaf of `tree` is a JAX tracer (inside jit, vmap or grad): its value is
    known only at run time, so checks on values are left to run time."""
    return any(isinstance(x, Tracer) for x in jax.tree_util.tree_leaves(tree))


def short(value, limit: int = 80) -> str:
    """``repr(value)``, cut to `limit` characters (a 400-digit integer stays readable)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _shape_text(shape) -> str:
    if len(shape) == 1:
        return f"length {shape[0]}"
    if len(shape) == 2 and shape[0] == shape[1]:
        return f"{shape[0]}x{shape[1]}"
    return f"shape {shape}"


def as_float(value, what: str, shape=None, *, finite: bool = True) -> np.ndarray:
    """`value` as a float64 numpy array, or :class:`SceneError` naming `what`.

    Rejected: strings, booleans, complex numbers, ``None``, dicts and other non-numbers
    (SceneTypeError), ragged nested lists, a shape other than `shape` (when given), and
    non-finite entries or integers too large for a float (when `finite`). A traced value
    raises too: call this only on concrete data."""
    if isinstance(value, Tracer):
        raise SceneTypeError(f"{what} is traced (inside jax.jit / vmap / grad); it needs a concrete value here")
    if value is None:
        raise SceneTypeError(f"{what} must be numeric, got None")
    if isinstance(value, (str, bytes)):
        raise SceneTypeError(f"{what} must be numeric, got the string {short(value)}")
    try:
        a = np.asarray(value)
    except (TypeError, ValueError, OverflowError):
        raise SceneError(
            f"{what} must be a number or a (nested) list of numbers of one shape, got {short(value)}"
        ) from None
    kind = a.dtype.kind
    if kind == "O":
        if any(x is None for x in a.flat):
            raise SceneTypeError(f"{what} must be numeric, got None in {short(value)}")
        try:
            a = np.asarray(value, dtype=float)
        except OverflowError:
            raise SceneError(f"{what} must be finite, got an integer too large for a float: {short(value)}") from None
        except (TypeError, ValueError):
            raise SceneTypeError(f"{what} must be numeric, got {short(value)}") from None
    elif kind == "b":
        raise SceneTypeError(f"{what} must be numeric, got a boolean {short(value)}")
    elif kind in "US":
        raise SceneTypeError(f"{what} must be numeric, got strings {short(value)}")
    elif kind == "c":
        raise SceneTypeError(f"{what} must be real, got a complex value {short(value)}")
    elif kind not in "iuf":
        raise SceneTypeError(f"{what} must be numeric, got {short(value)}")
    with np.errstate(over="ignore"):
        a = a.astype(float)
    if shape is not None and a.shape != tuple(shape):
        raise SceneError(f"{what} must have {_shape_text(tuple(shape))}, got shape {a.shape}")
    if finite and not np.all(np.isfinite(a)):
        raise SceneError(f"{what} must be finite, got {short(a.tolist())}")
    return a


def as_int(value, what: str, minimum=None) -> int:
    """A Python int (not a bool, not a float with a fraction), at least `minimum`."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        if isinstance(value, (float, np.floating)) and np.isfinite(value) and float(value).is_integer():
            value = int(value)
        else:
            raise SceneTypeError(f"{what} must be an integer, got {short(value)}")
    value = int(value)
    if minimum is not None and value < minimum:
        raise SceneError(f"{what} must be at least {minimum}, got {value}")
    return value


# A key that begins with this is an extension of the user's (a note, a tool's own data): read past
# silently and not written back. Any other unknown key is an error: a misspelt "initial" would
# otherwise simulate the vehicle at rest.
EXTENSION_PREFIX = "x-"


def unknown_keys(given, known, where: str) -> None:
    """Refuse (:class:`SceneError`) the first key of `given` that is neither in `known` nor an
    extension key (:data:`EXTENSION_PREFIX`), naming it, its place and the nearest known key."""
    for key in given:
        if key in known or str(key).startswith(EXTENSION_PREFIX):
            continue
        close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1)
        hint = f"did you mean {close[0]!r}?" if close else f"known: {sorted(map(str, known))}"
        raise SceneError(f"{where}: unknown key {key!r} ({hint}; a key of your own begins with {EXTENSION_PREFIX!r})")


def rotation(C, what: str, tol: float = 1e-9) -> np.ndarray:
    """A concrete 3x3 proper rotation matrix (orthonormal, determinant +1)."""
    C = as_float(C, what, (3, 3))
    err, det = float(np.abs(C @ C.T - np.eye(3)).max()), float(np.linalg.det(C))
    if err > tol or det < 0:
        raise SceneError(
            f"{what} must be a proper rotation matrix (orthonormal, det +1): max |C C^T - I| = "
            f"{err:.3g}, det C = {det:.6g}"
        )
    return C


# ----------------------------------------------------------------------------- hinge sets
class Errors(NamedTuple):
    """The exception classes a check raises: for a bad value, an unknown name, a wrong type."""

    value: type[Exception]
    key: type[Exception]
    type: type[Exception]


SCENE_ERRORS = Errors(SceneError, SceneKeyError, SceneTypeError)
BUILTIN_ERRORS = Errors(ValueError, KeyError, TypeError)


def hinge_set(model, small, name: str, errors: Errors = SCENE_ERRORS) -> tuple[int, ...]:
    """The set A of `model` (``n``, ``names``, ``prescribed``) as an ascending tuple of hinge
    indices 1..n: `small` holds hinge indices or body names (hinge k is named by body k), none
    repeated, none prescribed. Raises the classes of `errors` with messages that begin with `name`."""
    if isinstance(small, (str, int, np.integer)):
        small = (small,)
    try:
        items = list(small)
    except TypeError:
        raise errors.type(
            f"{name}: small must be hinge indices 1..{model.n} or body names, got {short(small)}"
        ) from None
    if not items:
        raise errors.value(f"{name}: the set A of small hinges is empty")
    out: list[int] = []
    for item in items:
        if isinstance(item, str):
            if item not in model.names:
                raise errors.key(
                    f"{name}: no body named {item!r}; hinges are named by their outboard body: {model.names[1:]}"
                )
            k = model.names.index(item)
            if k == 0:
                raise errors.value(f"{name}: {item!r} is the reference body b_0, which has no hinge")
        elif isinstance(item, (bool, np.bool_)) or not isinstance(item, (int, np.integer)):
            raise errors.type(f"{name}: hinges are given by index 1..{model.n} or by body name, got {short(item)}")
        else:
            k = int(item)
            if not 1 <= k <= model.n:
                raise errors.value(
                    f"{name}: hinge index {k} is not in 1..{model.n} (hinge k joins body k to its parent)"
                )
        if k in out:
            raise errors.value(f"{name}: hinge {k} ({model.names[k]!r}) is listed twice in the set A")
        if k in model.prescribed:
            raise errors.value(
                f"{name}: hinge {k} ({model.names[k]!r}) is kinematically prescribed; it cannot be a "
                "small (linearized) variable. Leave it out of the set A: it is then held at its "
                "nominal angle."
            )
        out.append(k)
    return tuple(sorted(out))


def nominal_motion(name: str, n: int, omega0, gamma, dcm, t) -> None:
    """The nominal motion's omega0 (3,), gamma (n,), dcm (a rotation) and t: concrete ones
    finite and of the right shape (None and traced values are left alone)."""
    for label, value, shape in (
        ("omega0", omega0, (3,)),
        ("gamma", gamma, (n,)),
        ("dcm", dcm, (3, 3)),
        ("t", t, ()),
    ):
        if value is None or is_traced(value):
            continue
        if label == "dcm":
            rotation(value, f"{name}: dcm", tol=1e-6)
        else:
            as_float(value, f"{name}: {label}", shape)


def tolerance(name: str, rtol, label: str = "rtol") -> float:
    """A relative tolerance in [0, 1)."""
    r = float(as_float(rtol, f"{name}: {label}", ()))
    if not 0.0 <= r < 1.0:
        raise SceneError(f"{name}: {label} must be in [0, 1), got {r}")
    return r


# ----------------------------------------------------------------------------- functions
def _matrices(I, J, K):
    """``(I, J, K)``, or those of a :class:`jaxtree._src.linear.linearize.LinearSystem` given as `I` (known by
    its fields: this module imports nothing of the package)."""
    if all(hasattr(I, field) for field in ("I", "J", "K", "coordinates", "hinges")):
        return I.I, I.J, I.K
    return I, J, K


def modes_args(I, J=None, K=None, damping=None, kind=None, labels=None, rtol=1e-9):
    """Arguments of :func:`jaxtree.modes`: I, J, K square float matrices of one size (finite
    when concrete), `damping` a non-negative scalar or one per coordinate, `kind` known,
    `labels` one string per coordinate, `rtol` in [0, 1)."""
    name = "modes"
    I, J, K = _matrices(I, J, K)
    if J is None or K is None:
        raise SceneTypeError(f"{name}: give I, J, K (or a LinearSystem)")
    sizes = []
    for label, M in (("I", I), ("J", J), ("K", K)):
        shape = np.shape(M) if is_traced(M) else as_float(M, f"{name}: {label}", finite=True).shape
        if len(shape) != 2 or shape[0] != shape[1]:
            raise SceneError(f"{name}: {label} must be a square matrix, got shape {shape}")
        sizes.append(shape[0])
    if len(set(sizes)) != 1:
        raise SceneError(f"{name}: I, J, K must have one size, got {sizes[0]}, {sizes[1]}, {sizes[2]}")
    nu = sizes[0]
    if nu == 0:
        raise SceneError(f"{name}: I, J, K are empty (no coordinate)")
    if kind is not None and kind not in ("real", "gyroscopic", "general"):
        raise SceneError(f"{name}: kind must be 'real', 'gyroscopic', 'general' or None, got {short(kind)}")
    if damping is not None and not is_traced(damping):
        z = as_float(damping, f"{name}: damping")
        if z.ndim > 1 or (z.ndim == 1 and z.shape != (nu,)):
            raise SceneError(
                f"{name}: damping must be a scalar or one ratio per coordinate ({nu}), got shape {z.shape}"
            )
        if np.any(z < 0):
            raise SceneError(f"{name}: modal damping ratios must be >= 0, got {z.tolist()}")
    if labels is not None:
        if isinstance(labels, str):
            raise SceneTypeError(f"{name}: labels must be a sequence of {nu} names, got the string {labels!r}")
        try:
            labels = list(labels)
        except TypeError:
            raise SceneTypeError(f"{name}: labels must be a sequence of {nu} names, got {short(labels)}") from None
        if len(labels) != nu:
            raise SceneError(f"{name}: {len(labels)} labels for {nu} coordinates")
    tolerance(name, rtol)
