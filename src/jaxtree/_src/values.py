"""Checked conversions of user input: numbers, integers and rotations to numpy values, or an error
of :mod:`.errors` that names what was given and where.

Shared by the scene format (:mod:`~jaxtree._src.scene`), the builder and the checks of the public
functions' arguments, all on concrete data before anything is traced.
"""

from __future__ import annotations

import numpy as np
from jax.core import Tracer

from .errors import SceneError, SceneTypeError, short


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
