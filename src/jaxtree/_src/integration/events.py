"""Events of a run of Eq. (1): a hinge angle or a function of the state crossing zero
(:func:`hinge_angle_event`, :func:`state_event`), combined with the stops that a run always
watches (an attitude singularity of Euler angles, a non-finite state) into one diffrax event.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ..equations.attitude import AbstractAttitude
from ..errors import SceneTypeError, short
from .problem import Problem


class _HingeAngle(eqx.Module):
    angle: jax.Array
    hinge: int = eqx.field(static=True)

    def __call__(self, t, y, args: Problem, **kwargs):
        return args.state(t, y).gamma[self.hinge - 1] - self.angle.astype(y.dtype)


class _StateCondition(eqx.Module):
    fn: Callable = eqx.field(static=True)

    def __call__(self, t, y, args: Problem, **kwargs):
        return self.fn(t, args.state(t, y))


def _root_finder(tol):
    return optx.Newton(rtol=tol, atol=tol)


def hinge_angle_event(hinge: int, angle, direction: bool | None = None, tol: float = 1e-10) -> dfx.Event:
    """A :class:`diffrax.Event` that stops the run when hinge `hinge` (1-based) reaches `angle`.

    The crossing time is found by Newton root finding on the dense output (tolerance `tol`;
    use about 1e-5 for float32 models). `direction`: None either way, True on an increasing
    crossing, False on a decreasing one.
    """
    return dfx.Event(_HingeAngle(jnp.asarray(angle, float), int(hinge)), _root_finder(tol), direction)


def state_event(fn: Callable, direction: bool | None = None, tol: float = 1e-10) -> dfx.Event:
    """A :class:`diffrax.Event` from ``fn(t, state) -> scalar``: stops where it changes sign
    (root finding) or, for a boolean, on the first step where it is True. `fn` is static."""
    return dfx.Event(_StateCondition(fn), _root_finder(tol), direction)


class _Singularity(eqx.Module):
    """Boolean: the attitude variables are within tolerance of their singularity."""

    def __call__(self, t, y, args: Problem, **kwargs):
        margin = args.attitude.margin(args.unpack(y)[0])
        assert margin is not None  # the guard is installed only when attitude.has_singularity
        return margin < 0


class _Crossing(eqx.Module):
    """Real: changes sign if a step jumps across the singular set without landing near it."""

    def __call__(self, t, y, args: Problem, **kwargs):
        return args.attitude.side(args.unpack(y)[0])


def guard_any(mask):
    near, crossed = mask
    return jnp.asarray(near) | jnp.asarray(crossed)


def combine_events(event, attitude: AbstractAttitude) -> tuple[Any, bool, bool]:
    """``(event, has_guard, has_user_event)``: the user's event unchanged, or the user's
    conditions and the attitude guard side by side in one diffrax Event."""
    guard = attitude.has_singularity
    if event is not None and not isinstance(event, dfx.Event):
        if callable(event):
            event = state_event(event)
        else:
            raise SceneTypeError(
                f"simulate: event must be a diffrax.Event or a function (t, state) -> scalar, got {short(event)}"
            )
    if not guard:
        return event, False, event is not None
    guards = (_Singularity(), _Crossing())
    if event is None:
        return dfx.Event(guards), True, False
    return dfx.Event((event.cond_fn, guards), event.root_finder, (event.direction, (None, None))), True, True
