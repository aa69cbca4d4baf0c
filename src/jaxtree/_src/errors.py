"""The errors of jaxtree: a bad vehicle description or argument, named before anything is traced.

A scene, a builder call or an argument of a public function that cannot describe a vehicle or a
run raises :class:`SceneError` naming the body and the field (or the function and the argument),
on plain numpy data and before anything is traced, so that no exception from inside JAX or
numpy reaches the user. Values that are traced (under ``jax.jit``, ``jax.vmap``, ``jax.grad``)
are left to run time.

:class:`SceneError` is a :class:`ValueError`; a wrong type raises a SceneError that is also a
:class:`TypeError`, an unknown body name one that is also a :class:`KeyError`, so that both
``except jaxtree.SceneError`` and the built-in exception types catch them. :class:`Errors`
names the three classes a check raises (:data:`SCENE_ERRORS`, or the built-in ones for the
functions documented to raise those).

The checked conversions that raise these errors are in :mod:`.values`; each check of one
function's arguments stands beside that function (``linearize_args`` and ``hinge_set`` in
:mod:`~jaxtree._src.linear.linearize`, ``modes_args`` in :mod:`~jaxtree._src.linear.modes`,
``check_model`` in :mod:`~jaxtree._src.vehicle.validate`, ...).
"""

from __future__ import annotations

from typing import NamedTuple


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


class Errors(NamedTuple):
    """The exception classes a check raises: for a bad value, an unknown name, a wrong type."""

    value: type[Exception]
    key: type[Exception]
    type: type[Exception]


SCENE_ERRORS = Errors(SceneError, SceneKeyError, SceneTypeError)
BUILTIN_ERRORS = Errors(ValueError, KeyError, TypeError)


def short(value, limit: int = 80) -> str:
    """``repr(value)``, cut to `limit` characters (a 400-digit integer stays readable)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
