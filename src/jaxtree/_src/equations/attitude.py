"""Attitude variables of the reference body b_0: direction cosines (Eq. 3), the Euler angles of
Eqs. (23)-(24), and unit quaternions.

Every parametrisation maps to the direction cosine matrix ``C`` of Def. 9 (``{b^0} = C {i}``)
and integrates the kinematics ``dC/dt = -tilde(omega0) C`` (Eq. 3) in its own variables; the
choice is static (a Python object, fixed before tracing). Sec. II D, optional input 1: "attitude
variables for b_0, with C expressed in them; they replace Eq. (3)".

- :class:`DirectionCosines`: the nine elements of C with Eq. (3) itself. Nothing keeps C
  orthogonal; :func:`orthogonality_error` measures the drift.
- :class:`Euler123`: the angles ``theta_1, theta_2, theta_3`` of the seed's sample problem, with
  C of Eq. (23) and ``theta_dot = P omega0`` of Eq. (24). P is singular at ``cos theta_2 = 0``;
  :meth:`Euler123.margin` measures the distance to it and the simulation stops with an error
  when it falls below ``singularity_tol``.
- :class:`Quaternion`: Euler parameters ``q = (q_0, q_1, q_2, q_3)`` (scalar first) with
  ``C = (q_0^2 - v.v) U + 2 v v^T - 2 q_0 tilde(v)`` (``v = (q_1, q_2, q_3)``) divided by
  ``|q|^2``, so C stays orthogonal whatever the norm drift, and
  ``q_0_dot = -v.omega0 / 2``, ``v_dot = (q_0 omega0 - omega0 x v) / 2``.

Eq. (23) is ``C = C_1(theta_1) C_2(theta_2) C_3(theta_3)`` with ``C_a`` the elementary
frame rotation about axis a: ``theta_3`` about ``i_3`` first, then ``theta_2`` about the
displaced 2-axis, then ``theta_1`` about ``b^0_1`` (see EQUATIONS.md Sec. 3.5 for the reading
of the OCR).
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ..errors import SceneError, short
from .kinematics import tilde


# ----------------------------------------------------------------------------- functions
def euler123_to_dcm(theta):
    """Eq. (23): C of Def. 9 from ``theta = (theta_1, theta_2, theta_3)`` (..., 3)."""
    c = jnp.cos(theta)
    s = jnp.sin(theta)
    c1, c2, c3 = c[..., 0], c[..., 1], c[..., 2]
    s1, s2, s3 = s[..., 0], s[..., 1], s[..., 2]
    rows = [
        [c2 * c3, c2 * s3, -s2],
        [s1 * s2 * c3 - c1 * s3, s1 * s2 * s3 + c1 * c3, s1 * c2],
        [c1 * s2 * c3 + s1 * s3, c1 * s2 * s3 - s1 * c3, c1 * c2],
    ]
    return jnp.stack([jnp.stack(r, -1) for r in rows], -2)


def dcm_to_euler123(C, xp=jnp):
    """Inverse of Eq. (23): ``theta`` with ``theta_2`` in [-pi/2, pi/2] (..., 3). `xp`: the array
    module (numpy for a concrete C on the host)."""
    theta2 = xp.arcsin(xp.clip(-C[..., 0, 2], -1.0, 1.0))
    theta1 = xp.arctan2(C[..., 1, 2], C[..., 2, 2])
    theta3 = xp.arctan2(C[..., 0, 1], C[..., 0, 0])
    return xp.stack([theta1, theta2, theta3], -1)


def euler123_rate_matrix(theta):
    """P of Eq. (24), ``theta_dot = P omega0`` (singular at ``cos theta_2 = 0``)."""
    c1, s1 = jnp.cos(theta[..., 0]), jnp.sin(theta[..., 0])
    c2, s2 = jnp.cos(theta[..., 1]), jnp.sin(theta[..., 1])
    t2 = s2 / c2
    one, zero = jnp.ones_like(c1), jnp.zeros_like(c1)
    rows = [[one, s1 * t2, c1 * t2], [zero, c1, -s1], [zero, s1 / c2, c1 / c2]]
    return jnp.stack([jnp.stack(r, -1) for r in rows], -2)


def quaternion_to_dcm(q):
    """C of Def. 9 from Euler parameters ``q = (q0, q1, q2, q3)`` (scalar first, any norm)."""
    q0, v = q[..., 0], q[..., 1:]
    vv = jnp.sum(v * v, -1)
    eye = jnp.eye(3, dtype=q.dtype)
    C = (
        (q0 * q0 - vv)[..., None, None] * eye
        + 2.0 * v[..., :, None] * v[..., None, :]
        - 2.0 * q0[..., None, None] * tilde(v)
    )
    return C / (q0 * q0 + vv)[..., None, None]


def dcm_to_quaternion(C, xp=jnp):
    """Euler parameters (scalar first, ``q0 >= 0``) of a rotation matrix C (Shepperd's method).
    `xp`: the array module (numpy for a concrete C on the host)."""
    tr = xp.trace(C, axis1=-2, axis2=-1)
    d = xp.diagonal(C, axis1=-2, axis2=-1)
    # 4 q_i^2 for i = 0..3; the largest is computed directly, the others from off-diagonals.
    sq = xp.stack([1.0 + tr, 1.0 + 2 * d[..., 0] - tr, 1.0 + 2 * d[..., 1] - tr, 1.0 + 2 * d[..., 2] - tr], -1)
    a = C[..., 1, 2] - C[..., 2, 1]  # 4 q0 q1
    b = C[..., 2, 0] - C[..., 0, 2]  # 4 q0 q2
    c = C[..., 0, 1] - C[..., 1, 0]  # 4 q0 q3
    e = C[..., 0, 1] + C[..., 1, 0]  # 4 q1 q2
    f = C[..., 0, 2] + C[..., 2, 0]  # 4 q1 q3
    g = C[..., 1, 2] + C[..., 2, 1]  # 4 q2 q3
    cand = xp.stack(
        [
            xp.stack([sq[..., 0], a, b, c], -1),
            xp.stack([a, sq[..., 1], e, f], -1),
            xp.stack([b, e, sq[..., 2], g], -1),
            xp.stack([c, f, g, sq[..., 3]], -1),
        ],
        -2,
    )  # row i = 4 q_i q
    i = xp.argmax(sq, -1)
    row = xp.take_along_axis(cand, i[..., None, None], -2)[..., 0, :]
    q = row / xp.sqrt(xp.maximum(xp.take_along_axis(sq, i[..., None], -1), 1e-300))
    q = 0.5 * q
    return xp.where(q[..., :1] < 0, -q, q)


def quaternion_rate(q, omega0):
    """``dq/dt`` for ``dC/dt = -tilde(omega0) C`` (Eq. 3), omega0 in {b^0}."""
    q0, v = q[..., :1], q[..., 1:]
    return 0.5 * jnp.concatenate([-jnp.sum(v * omega0, -1, keepdims=True), q0 * omega0 - jnp.cross(omega0, v)], -1)


def orthogonality_error(C):
    """``max |C C^T - U|`` (..., ): the drift of a direction cosine matrix from orthogonality."""
    eye = jnp.eye(3, dtype=C.dtype)
    return jnp.max(jnp.abs(C @ jnp.swapaxes(C, -1, -2) - eye), axis=(-2, -1))


# ----------------------------------------------------------------------------- classes
class AbstractAttitude(eqx.Module):
    """Attitude variables of b_0: ``size`` numbers with C (Def. 9) and the rate of Eq. (3)."""

    name: ClassVar[str]
    size: ClassVar[int]
    has_singularity: ClassVar[bool] = False

    @abc.abstractmethod
    def from_dcm(self, C, xp=jnp) -> jax.Array:
        """The attitude variables (size,) of a rotation matrix C; `xp` the array module (numpy
        for a concrete C on the host)."""

    @abc.abstractmethod
    def to_dcm(self, x) -> jax.Array:
        """C of Def. 9 (3, 3) from the attitude variables (size,)."""

    @abc.abstractmethod
    def rate(self, x, omega0) -> jax.Array:
        """Time derivative of the variables for angular velocity omega0 (in {b^0})."""

    def margin(self, x) -> jax.Array | None:
        """Distance to a singularity of the parametrisation; the run stops when it falls below 0.
        None when the parametrisation has none."""
        return None

    def side(self, x) -> jax.Array | None:
        """A continuous function whose sign changes where the variables cross their singular set
        (a run that steps across it stops there too); None when there is none."""
        return None


class DirectionCosines(AbstractAttitude):
    """The nine direction cosines of C, integrated with Eq. (3) (row-major)."""

    name: ClassVar[str] = "dcm"
    size: ClassVar[int] = 9

    def from_dcm(self, C, xp=jnp):
        return xp.reshape(C, (9,))

    def to_dcm(self, x):
        return jnp.reshape(x, (3, 3))

    def rate(self, x, omega0):
        return jnp.reshape(-tilde(omega0) @ jnp.reshape(x, (3, 3)), (9,))


class Euler123(AbstractAttitude):
    """The angles of Eqs. (23)-(24); the run stops with an error when ``|cos theta_2|`` falls
    below `singularity_tol` (P of Eq. 24 grows like ``1 / cos theta_2``)."""

    singularity_tol: float = eqx.field(static=True, default=1e-2)
    name: ClassVar[str] = "euler123"
    size: ClassVar[int] = 3
    has_singularity: ClassVar[bool] = True

    def from_dcm(self, C, xp=jnp):
        return dcm_to_euler123(C, xp)

    def to_dcm(self, x):
        return euler123_to_dcm(x)

    def rate(self, x, omega0):
        return euler123_rate_matrix(x) @ omega0

    def margin(self, x):
        return jnp.abs(jnp.cos(x[1])) - self.singularity_tol

    def side(self, x):
        return jnp.cos(x[1])


class Quaternion(AbstractAttitude):
    """Euler parameters (scalar first); C is formed from ``q / |q|`` so it stays orthogonal."""

    name: ClassVar[str] = "quaternion"
    size: ClassVar[int] = 4

    def from_dcm(self, C, xp=jnp):
        return dcm_to_quaternion(C, xp)

    def to_dcm(self, x):
        return quaternion_to_dcm(x)

    def rate(self, x, omega0):
        return quaternion_rate(x, omega0)


_BY_NAME = {"dcm": DirectionCosines, "euler123": Euler123, "quaternion": Quaternion}


def get_attitude(attitude: str | AbstractAttitude) -> AbstractAttitude:
    """An attitude parametrisation from its name (``"quaternion"``, ``"dcm"``, ``"euler123"``)
    or an instance (returned as is)."""
    if isinstance(attitude, AbstractAttitude):
        return attitude
    if isinstance(attitude, str) and attitude.lower() in _BY_NAME:
        return _BY_NAME[attitude.lower()]()
    raise ValueError(f"attitude: expected one of {sorted(_BY_NAME)} or an AbstractAttitude, got {attitude!r}")


def attitude_argument(name: str, attitude) -> AbstractAttitude:
    """The `attitude` argument of the public function `name` (a name of :func:`get_attitude` or an
    instance) as attitude variables, or :class:`SceneError` naming the function."""
    if isinstance(attitude, AbstractAttitude) or (isinstance(attitude, str) and attitude.lower() in _BY_NAME):
        return get_attitude(attitude)
    raise SceneError(
        f"{name}: attitude must be one of {sorted(_BY_NAME)} or an AbstractAttitude, got {short(attitude)}"
    )
