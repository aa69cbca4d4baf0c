"""Partial linearization and constant-coefficient equations: Sec. III A-C of Likins (1972),
Eqs. (28)-(69).

The seed builds the linearized equations by hand: every symbol is split into a
*bar* part (free of the small variables) and a *caret* part (linear in them),
Eq. (29); the products are expanded to first order, Eqs. (30)-(37); the
constant-coefficient equations of the small hinges (Eq. 40 with Eqs. 41a, b)
are written ``I y'' + J y' + K y = 0`` (Eq. 42) with ``I`` the nominal block
``a_bar`` of Eq. (36d) and ``J``, ``K`` from Eqs. (43)-(44), (47)-(50).

Here the same result is produced mechanically, as the implementation note of
Sec. III C recommends: the residual of the *exact* Eq. (1),

    r = [a](gamma) [omega0_dot; gamma_ddot] - rhs(gamma, gamma_dot, omega0),

is expanded to first order in the small variables by forward-mode automatic
differentiation (``jax.jacfwd``) about the nominal motion. The bar part is the
value of ``r`` there and the caret part its derivative; nothing of (36e), (37e),
(49) or (50) is transcribed, so none of their misprints can enter. Hinge
spring/damper torques (Eqs. 45-46) and the model's external loads are part of
``rhs`` and enter through the same derivative.

Public functions:

- :func:`linearized_equations`: Eq. (30) (all n + 3 rows of Eq. 1, first-order
  Taylor expansion in the small variables, large variables arbitrary);
- :func:`linearize`: Eqs. (40)-(44): ``(I, J, K)`` of the hinges of the set A,
  the rest of the vehicle on its nominal motion (constant spin ``omega0``,
  other angles fixed, rates and accelerations zero);
- :func:`linearize_vehicle`: the all-small "vehicle normal mode" case of
  Sec. III B, with three small attitude angles of b_0 relative to the nominally
  spinning frame (the three imaginary massless bodies of the seed);
- :func:`structure`: the symmetry diagnostics of Sec. III C (Eqs. 51-69).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.dynamics import rotational_equations
from ..equations.kinematics import full_precision, tilde
from ..errors import BUILTIN_ERRORS, SCENE_ERRORS, Errors, SceneTypeError, short
from ..numerics import is_traced, program_jit
from ..values import as_float, rotation
from ..vehicle.hinges import selector
from ..vehicle.model import Model, State
from ..vehicle.validate import check_model


class LinearSystem(eqx.Module):
    """Constant-coefficient equations ``I y'' + J y' + K y = bias`` (Eq. 42 with the forcing
    of Eq. 38 kept as `bias`).

    Unpacks as ``I, J, K = linearize(...)``. `bias` is minus the residual of the
    selected rows of Eq. (1) on the nominal motion: zero when the nominal motion is
    an equilibrium (relative equilibrium when spinning), otherwise the constant
    forcing of Eq. (38) and a warning that the homogeneous Eq. (40) is only an
    approximation.

    Static fields: `coordinates` (one name per entry of ``y``), `hinges` (the hinge
    index 1..n of each coordinate, 0 for an attitude angle of b_0).
    """

    I: jax.Array
    J: jax.Array
    K: jax.Array
    bias: jax.Array
    coordinates: tuple[str, ...] = eqx.field(static=True)
    hinges: tuple[int, ...] = eqx.field(static=True)

    def __iter__(self):
        return iter((self.I, self.J, self.K))

    def __len__(self):
        return 3

    def __getitem__(self, i):
        return (self.I, self.J, self.K)[i]

    @property
    def nu(self) -> int:
        """Number of small coordinates (the seed's nu)."""
        return len(self.coordinates)


class PartialLinearization(NamedTuple):
    """Eq. (30): the residual of all n + 3 rows of Eq. (1) to first order in the small variables,

        r ~= residual + accel @ y'' + rate @ y' + angle @ y,

    at a given state of the large variables (``omega0``, ``omega0_dot``, the angles, rates
    and accelerations of the hinges not in A). Rows: ``omega0`` (3, in {b^0}), then
    hinges 1..n. ``residual`` holds the bar terms (``a_bar x - rhs_bar``); the columns
    of ``accel`` are the bar coefficients ``a_bar_{.k}`` of the small accelerations;
    ``angle`` and ``rate`` hold the caret terms, including ``a_hat`` times the large
    accelerations (Eqs. 37a-d) and minus the caret parts of the right side (37e).
    """

    residual: jax.Array  # (n+3,)
    accel: jax.Array  # (n+3, nu)
    rate: jax.Array  # (n+3, nu)
    angle: jax.Array  # (n+3, nu)


class Structure(NamedTuple):
    """Symmetry properties of Sec. III C (and the definiteness that Sec. III D needs)."""

    I_symmetric: bool
    I_positive: bool  # positive definite
    J_zero: bool
    J_skew: bool
    K_symmetric: bool
    K_positive: bool  # positive definite
    K_semidefinite: bool  # positive semidefinite
    kind: str  # "real" (J = 0, K symmetric), "gyroscopic" (J skew, K symmetric) or "general"

    def describe(self) -> str:
        parts = [
            "I symmetric" if self.I_symmetric else "I NOT symmetric",
            "J = 0" if self.J_zero else ("J skew-symmetric" if self.J_skew else "J neither zero nor skew"),
            "K symmetric" if self.K_symmetric else "K NOT symmetric",
        ]
        if self.K_symmetric:
            parts.append(
                "K positive definite"
                if self.K_positive
                else ("K positive semidefinite (zero-frequency modes)" if self.K_semidefinite else "K indefinite")
            )
        return f"{self.kind}: " + ", ".join(parts)


# ----------------------------------------------------------------------------- input checks
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


def resolve_hinges(model: Model, small) -> tuple[int, ...]:
    """The set A as an ascending tuple of hinge indices 1..n.

    `small` may hold hinge indices k = 1..n (hinge k joins body k to its parent, as in
    the seed) or body names (hinge k is named by body k). Raises ``ValueError`` /
    ``KeyError`` with a clear message for an unknown name, an index outside 1..n, the
    reference body, a repeated hinge or a kinematically prescribed hinge.
    """
    return hinge_set(model, small, "linearize", BUILTIN_ERRORS)


def linearize_args(name: str, model, small=None, *, omega0=None, gamma=None, dcm=None, t=0.0) -> tuple[int, ...] | None:
    """The arguments of :func:`linearize`, :func:`linearize_vehicle` (and the linearization of
    :func:`jaxtree.hybrid_model`), checked before tracing with :class:`SceneError` naming the
    function `name`: the model (validated when concrete), the set A and the nominal motion.
    Returns the set A as :func:`resolve_hinges` does (None when `small` is None)."""
    check_model(name, model)
    hinges = None if small is None else hinge_set(model, small, name)
    nominal_motion(name, model.n, omega0, gamma, dcm, t)
    return hinges


def _linearized_equations_args(model, small, state, omega0_dot, gamma_ddot, t) -> tuple[int, ...]:
    """The arguments of :func:`linearized_equations`, checked before tracing; returns the set A."""
    name = "linearized_equations"
    check_model(name, model)
    hinges = hinge_set(model, small, name)
    if not isinstance(state, State):
        raise SceneTypeError(f"{name}: state must be a jaxtree.State, got {type(state).__name__}")
    shapes = {"dcm": (3, 3), "omega0": (3,), "gamma": (model.n,), "gamma_dot": (model.n,)}
    for field, shape in shapes.items():
        value = getattr(state, field)
        if not is_traced(value):
            as_float(value, f"{name}: state.{field}", shape)
    for label, value, shape in (("omega0_dot", omega0_dot, (3,)), ("gamma_ddot", gamma_ddot, (model.n,)), ("t", t, ())):
        if value is not None and not is_traced(value):
            as_float(value, f"{name}: {label}", shape)
    return hinges


def nominal_state(model, omega0, gamma, dcm):
    dtype = model.mass.dtype
    n = model.n
    w = jnp.zeros(3, dtype) if omega0 is None else jnp.asarray(omega0, dtype)
    g = jnp.zeros(n, dtype) if gamma is None else jnp.asarray(gamma, dtype)
    C = jnp.eye(3, dtype=dtype) if dcm is None else jnp.asarray(dcm, dtype)
    if w.shape != (3,):
        raise ValueError(f"linearize: omega0 must have shape (3,), got {w.shape}")
    if g.shape != (n,):
        raise ValueError(f"linearize: gamma must have shape ({n},), got {g.shape}")
    if C.shape != (3, 3):
        raise ValueError(f"linearize: dcm must have shape (3, 3), got {C.shape}")
    return w, g, C


def small_jacobian(fun, nu3):
    """Value and Jacobian of ``fun`` at zero by ``jax.jacfwd``."""
    z0 = jnp.zeros((nu3,), jnp.float64)
    jac, value = jax.jacfwd(lambda z: (lambda r: (r, r))(fun(z)), has_aux=True)(z0)
    return value, jac


# ----------------------------------------------------------------------------- Eq. (30)
@program_jit
def _partial(model, hinges, dcm, omega0, gamma, gamma_dot, omega0_dot, gamma_ddot, t):
    n, nu = model.n, len(hinges)
    E = selector(n, hinges, gamma.dtype)

    def residual(z):
        y, yd, ydd = z[:nu], z[nu : 2 * nu], z[2 * nu :]
        state = State(dcm, omega0, gamma + E @ y, gamma_dot + E @ yd)
        A, rhs = rotational_equations(model, state, t)
        return A @ jnp.concatenate([omega0_dot, gamma_ddot + E @ ydd]) - rhs

    value, jac = small_jacobian(residual, 3 * nu)
    return PartialLinearization(value, jac[:, 2 * nu :], jac[:, nu : 2 * nu], jac[:, :nu])


@full_precision
def linearized_equations(
    model: Model, small, state: State, *, omega0_dot=None, gamma_ddot=None, t=0.0
) -> PartialLinearization:
    """Eq. (30): Eq. (1) to first order in the hinges of the set A, the rest unrestricted.

    **Arguments:**

    - `small`: the set A (hinge indices 1..n or body names, see :func:`resolve_hinges`);
    - `state`: the large variables (``dcm``, ``omega0``) and the nominal angles and rates;
      the small hinges' entries are the point of expansion (normally zero);
    - `omega0_dot` (3,), `gamma_ddot` (n,): the accelerations of the large variables
      (the small hinges' entries are the expansion point of ``y''``, normally zero);
    - `t`: time passed to the model's loads.

    Prescribed hinges are not filled in from the prescription: give their angle, rate
    and acceleration in `state` and `gamma_ddot` (the ``G`` terms of Eq. 30c).

    **Returns:** :class:`PartialLinearization` (all n + 3 rows of Eq. 1).
    """
    hinges = _linearized_equations_args(model, small, state, omega0_dot, gamma_ddot, t)
    dtype = model.mass.dtype
    n = model.n
    w0d = jnp.zeros(3, dtype) if omega0_dot is None else jnp.asarray(omega0_dot, dtype)
    gdd = jnp.zeros(n, dtype) if gamma_ddot is None else jnp.asarray(gamma_ddot, dtype)
    return _partial(
        model,
        hinges,
        jnp.asarray(state.dcm, dtype),
        jnp.asarray(state.omega0, dtype),
        jnp.asarray(state.gamma, dtype),
        jnp.asarray(state.gamma_dot, dtype),
        w0d,
        gdd,
        jnp.asarray(t, dtype),
    )


# ----------------------------------------------------------------------------- Eqs. (40)-(44)
@program_jit
def _held(model, hinges, dcm, omega0, gamma, t):
    n = model.n
    dtype = gamma.dtype
    lin = _partial(model, hinges, dcm, omega0, gamma, jnp.zeros(n, dtype), jnp.zeros(3, dtype), jnp.zeros(n, dtype), t)
    rows = np.asarray(hinges, dtype=np.int64) + 2  # row of hinge k in Eq. (1) is k + 2 (0-based)
    return lin.accel[rows], lin.rate[rows], lin.angle[rows], -lin.residual[rows]


@full_precision
def linearize(model: Model, small, *, omega0=None, gamma=None, dcm=None, t=0.0) -> LinearSystem:
    """Eqs. (40)-(44): ``I y'' + J y' + K y = 0`` for the small hinges of the set A.

    The rest of the vehicle moves on its nominal motion: ``omega0`` constant (in {b^0},
    default zero), every angle not in A fixed at `gamma` (default zero; prescribed
    hinges too), all their rates and accelerations zero, ``omega0_dot = 0``. That is
    exactly the approximation of Eq. (40): the rows of A of Eq. (1) with the nominal
    terms held, differentiated by ``jax.jacfwd`` with respect to ``y''``, ``y'``, ``y``
    at ``y = y' = y'' = 0`` (``y`` is measured from the nominal angles ``gamma[A]``).

    - ``I = d r / d y''`` is the nominal ``a_bar`` block of Eq. (36d);
    - ``J = d r / d y'`` is Eq. (43) (hinge dampers of Eq. 46 give ``+ d_i delta_ij``);
    - ``K = d r / d y`` is Eq. (44) (springs of Eq. 45 give ``+ k_i delta_ij``).

    External loads of the model (evaluated at attitude `dcm`, default identity, and time
    `t`) enter through the same derivative. Coordinates are ordered by ascending hinge
    index. Differentiable with respect to every array leaf of the model.

    **Returns:** :class:`LinearSystem` (unpacks as ``I, J, K``).
    """
    hinges = linearize_args("linearize", model, small, omega0=omega0, gamma=gamma, dcm=dcm, t=t)
    if hinges is None:  # small=None: a TypeError
        hinges = resolve_hinges(model, small)
    w, g, C = nominal_state(model, omega0, gamma, dcm)
    I, J, K, bias = _held(model, hinges, C, w, g, jnp.asarray(t, g.dtype))
    return LinearSystem(I, J, K, bias, tuple(model.names[k] for k in hinges), hinges)


# ----------------------------------------------------------------------------- vehicle modes
@program_jit
def _vehicle(model, hinges, dcm, omega0, gamma, t):
    n, nu = model.n, len(hinges)
    dtype = gamma.dtype
    E = selector(n, hinges, dtype)
    m = 3 + nu

    def residual(z):
        q, qd, qdd = z[:m], z[m : 2 * m], z[2 * m :]
        th, thd, thdd = q[:3], qd[:3], qdd[:3]
        # b_0 = C_theta {f}, C_theta = U - tilde(theta) + ...; {f} spins at the constant omega0:
        # omega^0 = omega0 + theta' + omega0 x theta, d/dt omega^0 = theta'' + omega0 x theta' (first order).
        w = omega0 + thd + jnp.cross(omega0, th)
        wd = thdd + jnp.cross(omega0, thd)
        state = State((jnp.eye(3, dtype=dtype) - tilde(th)) @ dcm, w, gamma + E @ q[3:], E @ qd[3:])
        A, rhs = rotational_equations(model, state, t)
        r = A @ jnp.concatenate([wd, E @ qdd[3:]]) - rhs
        return jnp.concatenate([r[:3], r[3:][np.asarray(hinges) - 1]])

    value, jac = small_jacobian(residual, 3 * m)
    return jac[:, 2 * m :], jac[:, m : 2 * m], jac[:, :m], -value


@full_precision
def linearize_vehicle(model: Model, *, omega0=None, gamma=None, dcm=None, t=0.0, small=None) -> LinearSystem:
    """Full-system linearization: the all-small "vehicle normal mode" case of Sec. III B.

    Every hinge that is not prescribed is small (or those of `small`), and the attitude of
    b_0 is free: three small angles ``theta`` (the three imaginary massless bodies of
    Sec. III B, hinge axes b^0_1, b^0_2, b^0_3 through the mass center of b_0) give the
    attitude of b_0 relative to a reference frame that spins steadily at ``omega0``. So
    ``omega^0 = omega0 + theta' + omega0 x theta`` (the omega^0 perturbations) and the
    three rows of Eq. (1) for omega^0 join the hinge rows (to first order about a relative
    equilibrium they are the Lagrange equations of ``theta``).

    Coordinates: ``y = [theta_1, theta_2, theta_3, gamma_A]``; the attitude coordinates are
    named ``"<b0 name>.rotation_1"`` etc. and have hinge index 0. ``K`` is singular: the
    rigid rotations (about the spin axis when spinning; all three at rest) have zero
    stiffness, and :func:`jaxtree.modes` reports them as zero-frequency rigid-body modes.
    """
    hinges = linearize_args("linearize_vehicle", model, small, omega0=omega0, gamma=gamma, dcm=dcm, t=t)
    return vehicle_linearization(model, hinges, omega0=omega0, gamma=gamma, dcm=dcm, t=t)


@full_precision
def vehicle_linearization(model: Model, hinges=None, *, omega0=None, gamma=None, dcm=None, t=0.0) -> LinearSystem:
    """:func:`linearize_vehicle` of arguments that the caller has checked (:func:`linearize_args`;
    :func:`jaxtree.simulate` through :func:`jaxtree.choose_solver`): `hinges` the set A as
    :func:`resolve_hinges` gives it, or None for every hinge that is not prescribed."""
    if hinges is None:
        hinges = model.unknown_hinges
        if not hinges:
            raise ValueError("linearize_vehicle: the model has no hinge that is not prescribed")
    w, g, C = nominal_state(model, omega0, gamma, dcm)
    I, J, K, bias = _vehicle(model, hinges, C, w, g, jnp.asarray(t, g.dtype))
    b0 = model.names[0]
    coords = tuple(f"{b0}.rotation_{a}" for a in (1, 2, 3)) + tuple(model.names[k] for k in hinges)
    return LinearSystem(I, J, K, bias, coords, (0, 0, 0) + tuple(hinges))


# ----------------------------------------------------------------------------- Sec. III C
def structure(I, J, K, *, rtol: float = 1e-9) -> Structure:
    """Symmetry diagnostics of Sec. III C for concrete ``I, J, K``.

    Relative tolerance `rtol` on the norms: ``J`` counts as zero when
    ``|J| <= rtol * sqrt(|I| |K|)`` (J has the size of ``I sigma``), skew when
    ``|J + J^T| <= rtol * (|J| + sqrt(|I| |K|))``; ``K`` symmetric when
    ``|K - K^T| <= rtol |K|``. Definiteness from Cholesky / eigenvalues.
    """
    I, J, K = (np.asarray(x, dtype=float) for x in (I, J, K))
    nI = np.abs(I).max(initial=0.0)
    nK = np.abs(K).max(initial=0.0)
    nJ = np.abs(J).max(initial=0.0)
    scale = np.sqrt(nI * nK) if nK > 0 else nI
    I_sym = np.abs(I - I.T).max(initial=0.0) <= rtol * nI
    J_zero = nJ <= rtol * scale
    J_skew = np.abs(J + J.T).max(initial=0.0) <= rtol * (nJ + scale)
    K_sym = np.abs(K - K.T).max(initial=0.0) <= rtol * max(nK, rtol * nI)
    try:
        np.linalg.cholesky(0.5 * (I + I.T))
        I_pos = bool(I_sym)
    except np.linalg.LinAlgError:
        I_pos = False
    ev = np.linalg.eigvalsh(0.5 * (K + K.T)) if K.size else np.zeros(0)
    tolK = 1e-10 * max(nK, 1e-300)
    K_semi = bool(K_sym and (ev.size == 0 or ev[0] >= -tolK))
    K_pos = bool(K_semi and (ev.size == 0 or ev[0] > tolK))
    if J_zero and K_sym:
        kind = "real"
    elif J_skew and K_sym:
        kind = "gyroscopic"
    else:
        kind = "general"
    return Structure(bool(I_sym), I_pos, bool(J_zero), bool(J_skew), bool(K_sym), K_pos, K_semi, kind)
