"""What a vehicle's sensors read, from a simulation: the models behind the residuals of a fit.

Sensors are named after the body they sit on (``model.names`` or an index):

- ``"<body>.omega"`` (T, 3): a gyro on the body, its inertial angular rate in its own frame,
  ``omega^k = C^{k0} (omega0 + sum_s epsilon_{sk} C^{0s} g^s gamma_dot_s)`` (Defs. 27 and Eqs. 4-5:
  each hinge adds its rate about its axis to its parent's angular velocity);
- ``"<body>.angle"``, ``"<body>.rate"`` (T,): the angle and rate of the body's hinge (a
  potentiometer, a tachometer);
- ``"<body>.attitude"``: a star tracker on the body, read as its direction cosines ``C^k``
  ({b^k} = C^k {i}; (T, 3, 3)) or as Euler parameters, scalar first (T, 4), with ``C^k =
  C^{k0} C``. The residual is the small rotation that takes the modelled attitude to the
  measured one (3 components, in the body's frame, radians): ``C_meas C_model^T = U - tilde(phi)``
  to first order, so a quaternion's sign is no residual.

A measurement may hold NaN where a sample is missing: that residual is left out of the fit.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..equations.attitude import quaternion_to_dcm
from ..equations.kinematics import ancestor_sum, body_rotations, mv
from ..errors import SceneError, SceneKeyError, SceneTypeError
from ..vehicle.model import Model
from .quantities import body_of

KINDS = ("omega", "angle", "rate", "attitude")
# components of one sample of each kind's residual
WIDTH = {"omega": 3, "angle": 1, "rate": 1, "attitude": 3}


@dataclasses.dataclass(frozen=True)
class Sensor:
    """A sensor resolved in a model: `body` (index), `kind` (one of :data:`KINDS`) and, for an
    attitude, `form` (``"dcm"`` or ``"quaternion"``: how its measurements are given)."""

    name: str
    body: int
    kind: str
    form: str = ""


def resolve(model: Model, name, shape: tuple[int, ...], batched: bool) -> Sensor:
    """The :class:`Sensor` `name` denotes, checked against its measurement's `shape` (a leading
    member axis dropped when `batched`)."""
    if not isinstance(name, str):
        raise SceneTypeError(f"identify: a sensor is named by a string such as 'hub.omega', got {name!r}")
    body, _, kind = name.rpartition(".")
    if kind not in KINDS or not body:
        raise SceneKeyError(
            f"identify: unknown sensor {name!r}: expected '<body>.<kind>' with kind one of {', '.join(KINDS)}"
        )
    k = body_of(model, body, f"sensor {name!r}", hinge=kind in ("angle", "rate"))
    sample = shape[1:]
    form = ""
    if kind == "attitude":
        form = {(3, 3): "dcm", (4,): "quaternion"}.get(sample, "")
        if not form:
            raise SceneError(
                f"identify: measurements[{name!r}]: an attitude is (T, 3, 3) direction cosines or (T, 4) "
                f"Euler parameters, got samples of shape {sample}"
            )
    elif sample != {"omega": (3,), "angle": (), "rate": ()}[kind]:
        want = "(T, 3)" if kind == "omega" else "(T,)"
        raise SceneError(
            f"identify: measurements[{name!r}]: expected shape {want}{' after the members axis' if batched else ''}, "
            f"got samples of shape {sample}"
        )
    return Sensor(name, k, kind, form)


def body_rates(model: Model, gamma, gamma_dot, omega0):
    """Every body's inertial angular rate in its own frame at one time: (n + 1, 3)."""
    R = body_rotations(model.topology, model.axis, gamma)  # R[k] = C^{0k}
    own = jnp.concatenate([omega0[None], model.axis * gamma_dot[:, None]], 0)  # in frames b^0, b^s
    in_base = ancestor_sum(model.topology, mv(R, own))  # omega^k in {b^0}
    return mv(jnp.swapaxes(R, -1, -2), in_base)


def _vee_of_skew(E):
    """The vector phi of ``(E - E^T) / 2 = tilde(phi)``."""
    return 0.5 * jnp.stack([E[..., 2, 1] - E[..., 1, 2], E[..., 0, 2] - E[..., 2, 0], E[..., 1, 0] - E[..., 0, 1]], -1)


def body_dcms(model: Model, gamma, dcm):
    """Every body's direction cosines ``C^k = C^{k0} C`` at one time: (n + 1, 3, 3)."""
    R = body_rotations(model.topology, model.axis, gamma)
    return jnp.einsum("kji,jl->kil", R, dcm)


def read(model: Model, sensors: tuple[Sensor, ...], sol) -> dict:
    """What each sensor reads along a :class:`Solution` `sol`: ``"omega"`` (T, 3), ``"angle"``
    and ``"rate"`` (T,), ``"attitude"`` the body's direction cosines (T, 3, 3)."""
    need_rates = any(s.kind == "omega" and s.body != 0 for s in sensors)
    need_dcms = any(s.kind == "attitude" and s.body != 0 for s in sensors)
    rates = (
        jax.vmap(lambda g, gd, w: body_rates(model, g, gd, w))(sol.gamma, sol.gamma_dot, sol.omega0)
        if need_rates
        else None
    )
    dcms = jax.vmap(lambda g, C: body_dcms(model, g, C))(sol.gamma, sol.dcm) if need_dcms else None
    out = {}
    for s in sensors:
        if s.kind == "omega":
            out[s.name] = sol.omega0 if rates is None else rates[:, s.body]
        elif s.kind in ("angle", "rate"):
            out[s.name] = (sol.gamma if s.kind == "angle" else sol.gamma_dot)[:, s.body - 1]
        else:
            out[s.name] = sol.dcm if dcms is None else dcms[:, s.body]
    return out


def readings(model: Model, sensors: tuple[Sensor, ...], sol, data: dict) -> dict:
    """Each sensor's residual, model minus measurement (T, width), from a :class:`Solution`
    `sol` at the measurement times; an attitude's as the small rotation phi of the module
    docstring (``C_meas = (U - tilde(phi)) C_model`` to first order)."""
    model_reads = read(model, sensors, sol)
    out = {}
    for s in sensors:
        y, x = data[s.name], model_reads[s.name]
        if s.kind == "attitude":
            measured = quaternion_to_dcm(y) if s.form == "quaternion" else y
            out[s.name] = -_vee_of_skew(jnp.einsum("tij,tkj->tik", measured, x))
        else:
            out[s.name] = (x - y).reshape(x.shape[0], -1)
    return out


def width(sensor: Sensor) -> int:
    return WIDTH[sensor.kind]


def check_sigma(name: str, sigma, sensor: Sensor) -> np.ndarray:
    """The noise standard deviation of `sensor`: a positive scalar or one per component."""
    try:
        s = np.asarray(sigma, dtype=float)
    except (TypeError, ValueError):
        raise SceneTypeError(f"identify: sigma[{name!r}] must be a number or an array, got {sigma!r}") from None
    w = width(sensor)
    if s.ndim == 0:
        s = np.full(w, float(s))
    if s.shape != (w,):
        raise SceneError(f"identify: sigma[{name!r}]: a scalar or {w} components, got shape {s.shape}")
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise SceneError(f"identify: sigma[{name!r}] must be positive and finite, got {s.tolist()}")
    return s
