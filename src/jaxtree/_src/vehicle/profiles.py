"""Time profiles that scenes carry: prescribed hinge angles beyond the sine (Sec. II B) and the
scalar histories of scheduled body loads (Defs. 19-20).

Prescribed angles ``gamma_k(t)`` (a :class:`~jaxtree._src.vehicle.model.Prescription`; rates and accelerations
by forward-mode differentiation, as for every prescription):

- *ramp*: ``a0 + (a1 - a0) s``, ``s = clip((t - start) / duration, 0, 1)`` (constant rate
  ``(a1 - a0) / duration`` inside; the rate jumps at both ends, the impulsive hold torque there
  is not represented);
- *smooth step*: ``a0 + (a1 - a0) (10 s^3 - 15 s^4 + 6 s^5)`` (the quintic whose rate and
  acceleration vanish at both ends: the hold torque is continuous);
- *table*: a cubic Hermite curve through ``(times_i, angles_i)`` with the slopes of the
  centred differences ``(a_{i+1} - a_{i-1}) / (t_{i+1} - t_{i-1})`` inside and zero at the two
  ends (a tabulated slew starts and ends at rest; continuous rate), constant outside the table.

Scalar load profiles (the factor of a scheduled force or torque): *constant* (1), *pulse*
(:func:`jaxtree.thruster_pulse`: tanh edges of width `rise`), *table* (linear interpolation,
held constant outside the table).

Each kind is one vectorized evaluation over all the hinges (or loads) that use it: the kinds are
static, their numbers array leaves. Tables of different lengths are padded to one length: the
last point repeated at later times (1 s apart), its value held; the true lengths are static.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError
from ..values import as_float
from .model import Prescription

PRESCRIBED_SHAPES = ("ramp", "smooth_step")


def ramp_shape(s):
    """``clip(s, 0, 1)`` with a right-continuous derivative (1 at s = 0, 0 at s = 1; ``jnp.clip``
    would give 1/2 at both ends)."""
    return jnp.where(s < 0.0, 0.0, jnp.where(s >= 1.0, 1.0, s))


def smooth_step_shape(s):
    """``10 s^3 - 15 s^4 + 6 s^5`` of ``clip(s, 0, 1)``: 0 -> 1 with zero rate and acceleration at both ends."""
    s = jnp.clip(s, 0.0, 1.0)
    return s**3 * (10.0 + s * (-15.0 + 6.0 * s))


def pad_tables(times: list[np.ndarray], values: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Tables of different lengths as ``(m, L)`` arrays: each padded with its last value at
    later times (1 s apart), so that every row stays strictly increasing."""
    L = max(len(t) for t in times)
    T = np.zeros((len(times), L))
    V = np.zeros((len(times), L))
    for i, (t, v) in enumerate(zip(times, values)):
        k = len(t)
        T[i, :k], V[i, :k] = t, v
        T[i, k:] = t[-1] + np.arange(1, L - k + 1)
        V[i, k:] = v[-1]
    return T, V


class ShapePrescription(Prescription):
    """Ramp and smooth-step hinges: ``gamma_k = initial_k + (final_k - initial_k) shape_k(s)``,
    ``s = (t - start_k) / duration_k`` (module docstring). `shapes` (static): ``"ramp"`` or
    ``"smooth_step"`` per hinge; `initial`, `final`, `start`, `duration` (m,) leaves."""

    hinges: tuple[int, ...] = eqx.field(static=True)
    shapes: tuple[str, ...] = eqx.field(static=True)
    initial: jax.Array
    final: jax.Array
    start: jax.Array
    duration: jax.Array

    def __call__(self, t):
        s = (t - self.start) / self.duration
        ramp = np.asarray([k == "ramp" for k in self.shapes])
        if ramp.all():
            shape = ramp_shape(s)
        elif not ramp.any():
            shape = smooth_step_shape(s)
        else:
            shape = jnp.where(ramp, ramp_shape(s), smooth_step_shape(s))
        return self.initial + (self.final - self.initial) * shape


class TablePrescription(Prescription):
    """Tabulated hinges: a cubic Hermite curve per hinge (module docstring). `times`, `angles`
    (m, L) padded tables (leaves); `lengths` (static) the true number of points per hinge."""

    hinges: tuple[int, ...] = eqx.field(static=True)
    lengths: tuple[int, ...] = eqx.field(static=True)
    times: jax.Array
    angles: jax.Array

    def __call__(self, t):
        # one trace for all rows: the static lengths enter as a constant vector
        lengths = jnp.asarray(np.asarray(self.lengths))
        return jax.vmap(hermite_table, in_axes=(None, 0, 0, 0))(t, self.times, self.angles, lengths)


def hermite_table(t, times, values, length):
    """The cubic Hermite curve of a padded table row (see the module docstring) at time t;
    `length` (static or traced) the row's true number of points."""
    L = times.shape[0]
    j = np.arange(L)
    inner = (j > 0) & (j < length - 1)  # centred-difference slopes; zero at the ends and the padding
    lo, hi = np.clip(j - 1, 0, L - 1), np.clip(j + 1, 0, L - 1)
    slopes = jnp.where(inner, (values[hi] - values[lo]) / (times[hi] - times[lo]), 0.0)
    i = jnp.clip(jnp.searchsorted(times, t, side="right") - 1, 0, L - 2)
    h = times[i + 1] - times[i]
    s = (t - times[i]) / h  # in [0, 1) inside the table (a clip would halve the rate at the knots)
    s2, s3 = s * s, s * s * s
    inside = (
        (2 * s3 - 3 * s2 + 1) * values[i]
        + (s3 - 2 * s2 + s) * h * slopes[i]
        + (-2 * s3 + 3 * s2) * values[i + 1]
        + (s3 - s2) * h * slopes[i + 1]
    )
    return jnp.where(t < times[0], values[0], jnp.where(t >= times[L - 1], values[L - 1], inside))


def linear_table(t, times, values):
    """Linear interpolation of a (padded) table row at t, held constant outside it."""
    return jnp.interp(t, times, values)


class PrescriptionGroup(Prescription):
    """Several prescriptions side by side (e.g. sine hinges and user functions)."""

    hinges: tuple[int, ...] = eqx.field(static=True)
    parts: tuple[Prescription, ...]

    def __call__(self, t):
        return jnp.concatenate([jnp.atleast_1d(p(t)) for p in self.parts])


class FunctionPrescription(Prescription):
    """Prescribed angles from user functions of time, one per hinge (a scene's ``joint.fn``)."""

    hinges: tuple[int, ...] = eqx.field(static=True)
    fns: tuple[Callable, ...] = eqx.field(static=True)

    def __call__(self, t):
        return jnp.stack([jnp.asarray(f(t)) for f in self.fns])


def checked_table(times, values, where: str, label: str) -> tuple[np.ndarray, np.ndarray]:
    """A checked table: at least two strictly increasing finite `times` and as many finite values.
    `where` names the object up to the field (``"... field 'joint"``), closed here with the key."""
    t = as_float(times, f"{where}.times'")
    if t.ndim != 1 or len(t) < 2:
        raise SceneError(f"{where}.times' must be a list of at least 2 times, got shape {t.shape}")
    if not np.all(np.diff(t) > 0):
        raise SceneError(f"{where}.times' must be strictly increasing, got {t.tolist()}")
    v = as_float(values, f"{where}.{label}'", t.shape)
    return t, v
