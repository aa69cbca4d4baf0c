"""The assembly of Eq. (1) of Likins (1972), the unrestricted discrete-coordinate equations, and Eq. (2).

Eq. (1) is ``[a] [omega0_dot; gamma_ddot] = rhs`` with the coefficient matrix of
Defs. 38-40 and the right side assembled from Def. 41 and the hinge torques.
This module evaluates *the same matrix and right side* with the sums over path
elements reorganised so that they cost O(n log depth) plus one entry per
nonzero path element; :mod:`jaxtree.barycentric` evaluates the printed
formulas term by term, and the tests check that the two agree.

The reorganisation. Def. 37-40 write ``[a] = sum_{r,s} J_r^T Phi^{rs} J_s`` where
``J_r`` maps ``(omega0, gamma_dot)`` to the angular velocity of body r (its
columns are ``U`` and ``epsilon_{kr} g^k``) and ``Phi`` holds the barycentric
inertia dyadics. With the barycentric identity ``r_k = sum_j D^{jk}`` (the mass
center of b_k relative to the system mass center, Sec. II A.3) this quadratic
form is the kinetic energy of the motion relative to the system mass center,
``2T = sum_k m_k |dr_k/dt|^2 + w_k . I^k w_k``. Written with the vectors
``rho_k`` (mass center of b_k from the system mass center, {b^0} components)
and the hinge points ``h_s``, the entry of hinges ``s`` and ``k`` with
``epsilon_{sk} = 1`` is

    a_sk = S_s . (I^c_k S_k) - p_s . p_k / M,

where ``S_s = (g_s, h_s x g_s)`` is the motion of hinge s, ``I^c_k`` the inertia
of all bodies outboard of hinge k about the system mass center (a path-element
sum, ``sum_r epsilon_{kr}``) and ``p_k`` the momentum of those bodies. Entries
of hinges not on one path keep only the ``-p_s . p_k / M`` part, which is the
``-M D^{jk} . D^{kj}`` coupling of Def. 37. The rows of ``omega0`` take the same form as
three "hinges" inboard of all others, about e_1..e_3 through the system mass center
(``S = (e_i, 0)``, ``p = 0``, ``I^c`` of all bodies), so the whole matrix is one masked
outer product. The right side is the virtual power of the external loads and hinge torques
minus that of the velocity-product (gyroscopic, centripetal) accelerations of Def. 41,
accumulated over the same outboard sets.

The same outboard sums give the unbalanced generalized force ``rhs - A x`` at given accelerations
(:func:`unbalanced`, one pass of inverse dynamics, read by the derivative rule of
:mod:`.rules`), the kinetic energy (the quadratic form above) and angular momentum about the system
mass center, and the mass-center acceleration of Eq. (2). The solve of Eq. (1) is in
:mod:`.solve`.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, overload

import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import eager_jit
from ..vehicle import hinges
from ..vehicle.model import Model, State
from .kinematics import ancestor_sum, body_rotations, cross, dot, full_precision, mm, mv, subtree_sum, take_rows


class Configuration(NamedTuple):
    """Geometry of the tree at one set of hinge angles, in {b^0} components."""

    R: jax.Array  # (n+1, 3, 3)  C^{0k}
    axis: jax.Array  # (n, 3)     g^k
    to_hinge: jax.Array  # (n, 3) from the parent's mass center to h_k
    from_hinge: jax.Array  # (n, 3) from h_k to the mass center of b_k
    rho: jax.Array  # (n+1, 3) mass center of b_k from the system mass center
    hinge: jax.Array  # (n, 3)   h_k from the system mass center
    inertia: jax.Array  # (len(model.massive), 3, 3) R_k I^k R_k^T of the massive bodies


def check_shapes(name, model, state=None, prefix="", **fields):
    """Shapes of the state fields (and hinge-vector arguments) for the model's n hinges, checked
    when tracing: a short or long vector would otherwise fail deep inside with a broadcasting
    message, or be clamped by JAX's indexing and run. Under ``jax.vmap`` the shapes are those of
    one member."""
    n = model.n
    expected = {"dcm": (3, 3), "omega0": (3,), "gamma": (n,), "gamma_dot": (n,), "tau": (n,)}
    if state is not None:
        fields = {**{f: getattr(state, f) for f in State._fields}, **fields}
    for field, x in fields.items():
        if x is None:
            continue
        got = jnp.shape(x)
        if got != expected[field]:
            raise ValueError(
                f"{name}: {prefix}{field} has shape {got}; the model '{model.name}' with {n} hinges needs "
                f"{expected[field]}"
            )


def parent_indices(model):
    return np.asarray(model.topology.parents, dtype=np.int32)


def dtype_of(model, *xs):
    return jnp.result_type(model.mass, *xs)


@full_precision
@eager_jit
def configuration(model: Model, gamma) -> Configuration:
    """Rotations (Eqs. 4-5, 21-22), hinge axes, hinge points and mass centers at angles `gamma`."""
    check_shapes("configuration", model, gamma=gamma)
    return configuration_and_rates(model, gamma)[0]


@overload
def configuration_and_rates(
    model: Model, gamma, omega0: None = None, gamma_dot: None = None
) -> tuple[Configuration, None]: ...
@overload
def configuration_and_rates(
    model: Model, gamma, omega0: jax.Array, gamma_dot: jax.Array
) -> tuple[Configuration, jax.Array]: ...
def configuration_and_rates(model, gamma, omega0=None, gamma_dot=None):
    """:func:`configuration`, and with `omega0` and `gamma_dot` also the body angular velocities
    (:func:`body_angular_velocities`), whose path-element sum shares one pass with the mass
    centers' (else None)."""
    dtype = dtype_of(model, gamma)
    gamma = jnp.asarray(gamma, dtype)
    topo = model.topology
    par = parent_indices(model)
    R = body_rotations(topo, model.axis.astype(dtype), gamma)
    Rp = take_rows(R, par)
    axis = mv(Rp, model.axis.astype(dtype))
    to_hinge = mv(Rp, model.hinge_on_parent.astype(dtype))
    from_hinge = -mv(R[1:], model.hinge_on_body.astype(dtype))
    zero = jnp.zeros((1, 3), dtype)
    steps = jnp.concatenate([zero, to_hinge + from_hinge], 0)
    if omega0 is None:
        rho, omega = ancestor_sum(topo, steps), None
    else:
        assert gamma_dot is not None, "omega0 and gamma_dot come together"
        rates = jnp.concatenate([omega0[None, :], axis * gamma_dot[:, None]], 0)
        both = ancestor_sum(topo, jnp.concatenate([steps, rates], 1))
        rho, omega = both[:, :3], both[:, 3:]
    mass = model.mass.astype(dtype)
    rho = rho - jnp.sum(mass[:, None] * rho, 0) / jnp.sum(mass)
    hinge = take_rows(rho, par) + to_hinge
    idx = np.asarray(model.massive)
    Ri = take_rows(R, idx)
    inertia = mm(mm(Ri, take_rows(model.inertia, idx).astype(dtype)), jnp.swapaxes(Ri, -1, -2))
    return Configuration(R, axis, to_hinge, from_hinge, rho, hinge, inertia), omega


def massive_rows(model, x):
    """Rows of the massive bodies (all of `x` when no body is massless)."""
    return x if len(model.massive) == model.n + 1 else take_rows(x, model.massive)


def _composite(model, cfg, extra=None):
    """Mass, first moment and inertia about the system mass center of the bodies outboard of
    each hinge (row 0: all bodies): the path-element sums ``sum_r epsilon_{kr}`` of Defs. 38-40.

    `extra` (massive bodies x c) is summed over the same outboard sets in the same product
    (the right side's wrenches), and returned as the fourth result (None without it)."""
    mass = massive_rows(model, model.mass.astype(cfg.rho.dtype))
    rho = massive_rows(model, cfg.rho)
    eye = jnp.eye(3, dtype=rho.dtype)
    J = cfg.inertia + mass[:, None, None] * (dot(rho, rho)[:, None, None] * eye - rho[:, :, None] * rho[:, None, :])
    columns = [mass[:, None], mass[:, None] * rho, J.reshape(-1, 9)] + ([] if extra is None else [extra])
    sub = subtree_sum(model.topology, jnp.concatenate(columns, 1), model.massive)
    return sub[:, 0], sub[:, 1:4], sub[:, 4:13].reshape(-1, 3, 3), None if extra is None else sub[:, 13:]


def _hinge_momenta(model, cfg, extra=None):
    """Momentum ``p_k`` and angular momentum ``L_k`` (about the system mass center) of the bodies
    outboard of hinge k for a unit rate of hinge k alone, and the hinge point velocity ``v_k``
    (and the outboard sums of `extra`, see :func:`_composite`)."""
    Mc, cc, Jc, extra = _composite(model, cfg, extra)
    G = cfg.axis
    v = cross(cfg.hinge, G)  # velocity of the point at the system mass center, fixed to b_k
    p = Mc[1:, None] * v + cross(G, cc[1:])
    L = cross(cc[1:], v) + mv(Jc[1:], G)
    return Mc[0], Jc[0], v, p, L, extra


@full_precision
@eager_jit
def mass_matrix(model: Model, gamma) -> jax.Array:
    """The (n+3) x (n+3) coefficient matrix of Eq. (1) (Defs. 38-40) at hinge angles `gamma` (n,).

    Rows and columns: ``omega0`` (3, in {b^0}), then ``gamma_1 .. gamma_n``.
    """
    check_shapes("mass_matrix", model, gamma=gamma)
    cfg = configuration(model, gamma)
    return _mass_matrix(model, cfg)


def _outer3(a, b):
    """``a @ b.T`` for (m, 3) and (k, 3) arrays, as three outer products (fused by XLA)."""
    t = a[:, None, :] * b[None, :, :]
    return (t[..., 0:1] + t[..., 1:2] + t[..., 2:3])[..., 0]


def _masks(model):
    """Static 0/1 masks of Eq. (1)'s matrix in the extended form of :func:`_mass_matrix`."""
    n = model.n
    eps = model.topology.path_elements[:, 1:].astype(np.int8)
    upper = np.zeros((n + 3, n + 3), np.int8)
    upper[:3, :] = 1
    upper[3:, 3:] = eps
    strict = np.zeros_like(upper)
    strict[:3, 3:] = 1
    strict[3:, 3:] = eps - np.eye(n, dtype=np.int8)
    return upper, strict


@overload
def _mass_matrix(model: Model, cfg: Configuration, extra: None = None) -> jax.Array: ...
@overload
def _mass_matrix(model: Model, cfg: Configuration, extra: jax.Array) -> tuple[jax.Array, jax.Array]: ...
def _mass_matrix(model, cfg, extra=None):
    """The matrix of Eq. (1); with `extra`, also its outboard sums: ``(matrix, sums)``."""
    total_mass, J0, v, p, L, sums = _hinge_momenta(model, cfg, extra)
    G = cfg.axis
    # X[s, k] = S_s . (I^c_k S_k); it is an entry of [a] where epsilon_{sk} = 1 (s inboard of k),
    # its transpose where epsilon_{ks} = 1, and absent for hinges on different branches. The rows
    # of omega0 join as three hinges inboard of all others (axes e_1..e_3 through the system mass
    # center: no momentum, L = J0 e_i), so the whole matrix is one masked outer-product form.
    dtype = G.dtype
    zero = jnp.zeros((3, 3), dtype)
    Ge = jnp.concatenate([jnp.eye(3, dtype=dtype), G], 0)
    Le = jnp.concatenate([J0, L], 0)
    ve = jnp.concatenate([zero, v], 0)
    pe = jnp.concatenate([zero, p], 0)
    X = _outer3(Ge, Le) + _outer3(ve, pe)
    upper, strict = _masks(model)
    A = jnp.asarray(upper, dtype) * X + (jnp.asarray(strict, dtype) * X).T - _outer3(pe, pe) / total_mass
    return A if extra is None else (A, sums)


@full_precision
def body_angular_velocities(model: Model, cfg: Configuration, omega0, gamma_dot):
    """``omega^k`` of every body in {b^0} components: ``omega0 + sum_r epsilon_{rk} gamma_dot_r g^r``."""
    terms = jnp.concatenate([omega0[None, :], cfg.axis * gamma_dot[:, None]], 0)
    return ancestor_sum(model.topology, terms)


def mass_center_velocities(model, cfg, omega):
    """Velocities of the mass centers relative to the system mass center, {b^0} components."""
    par = parent_indices(model)
    inc = cross(take_rows(omega, par), cfg.to_hinge) + cross(omega[1:], cfg.from_hinge)
    vel = ancestor_sum(model.topology, jnp.concatenate([jnp.zeros((1, 3), inc.dtype), inc], 0))
    mass = model.mass.astype(vel.dtype)
    return vel - jnp.sum(mass[:, None] * vel, 0) / jnp.sum(mass)


@eager_jit
def hinge_torques(model: Model, gamma, gamma_dot):
    """Joint-law torques tau_k (Def. 21): springs and dampers on `model.sprung`, zero elsewhere."""
    check_shapes("hinge_torques", model, gamma=gamma, gamma_dot=gamma_dot)
    dtype = dtype_of(model, gamma, gamma_dot)
    if not model.sprung:
        return jnp.zeros((model.n,), dtype)
    if len(model.sprung) == model.n:
        return (-model.stiffness * gamma - model.damping * gamma_dot).astype(dtype)
    i = np.asarray(model.sprung) - 1
    law = (
        -take_rows(model.stiffness, i) * take_rows(gamma, i) - take_rows(model.damping, i) * take_rows(gamma_dot, i)
    ).astype(dtype)
    where = np.full(model.n, len(i))  # hinges without a law read the appended zero
    where[i] = np.arange(len(i))
    return take_rows(jnp.concatenate([law, jnp.zeros((1,), dtype)]), where)


class _Rotations(Protocol):
    """What :func:`external_loads` reads of a configuration: the rotations C^{0k} of the
    bodies (a :class:`Configuration`, or the barycentric module's own frames)."""

    @property
    def R(self) -> jax.Array: ...


def external_loads(model: Model, t, state: State, cfg: _Rotations):
    """``(bodies, force, torque)`` of the model's external loads in {b^0} components, or None."""
    if model.loads is None:
        return None
    bodies = np.asarray(model.loads.bodies, dtype=np.int32)
    F, T = model.loads(t, state)
    R = cfg.R[bodies]
    dtype = cfg.R.dtype
    return bodies, mv(R, F.astype(dtype)), mv(R, T.astype(dtype))


def _wrenches(model, cfg, omega, gamma_dot, loads, accelerations=None):
    """Def. 41 per massive body: the moment about the system mass center and the force of the
    velocity-product (gyroscopic, centripetal) inertia loads, with the mass-center share of the
    external force (massive bodies x 6). Their outboard sums make the right side of Eq. (1).

    With `accelerations` ``(omega0_dot (3,), gamma_ddot (n,))`` the inertia loads of those
    accelerations are included: the outboard sums then make ``rhs - A x`` (the unbalanced
    generalized force of :func:`unbalanced`), without assembling A."""
    topo = model.topology
    par = parent_indices(model)
    dtype = cfg.rho.dtype
    G = cfg.axis
    # velocity-product parts of the angular accelerations: sum_r epsilon_{rk} gamma_dot_r (omega^r x g^r)
    wp = take_rows(omega, par)
    rates = cross(wp, G) * gamma_dot[:, None]
    if accelerations is None:
        root = jnp.zeros((1, 3), dtype)
    else:
        root = accelerations[0].astype(dtype)[None, :]
        rates = rates + G * accelerations[1].astype(dtype)[:, None]
    zero = jnp.zeros((1, 3), dtype)
    alpha = ancestor_sum(topo, jnp.concatenate([root, rates], 0))
    ap, wk, ak = take_rows(alpha, par), omega[1:], alpha[1:]
    inc = (
        cross(ap, cfg.to_hinge)
        + cross(wp, cross(wp, cfg.to_hinge))
        + cross(ak, cfg.from_hinge)
        + cross(wk, cross(wk, cfg.from_hinge))
    )
    acc = massive_rows(model, ancestor_sum(topo, jnp.concatenate([zero, inc], 0)))
    mass = massive_rows(model, model.mass.astype(dtype))
    total = jnp.sum(mass)
    acc = acc - jnp.sum(mass[:, None] * acc, 0) / total
    w, al, rho = massive_rows(model, omega), massive_rows(model, alpha), massive_rows(model, cfg.rho)
    force = -mass[:, None] * acc
    torque = -(mv(cfg.inertia, al) + cross(w, mv(cfg.inertia, w)))
    if loads is not None:
        F = loads[1]
        force = force - mass[:, None] * (jnp.sum(F, 0) / total)  # the mass-center share of F (Eq. 2)
    return jnp.concatenate([torque + cross(rho, force), force], 1)


def _rhs_from_sums(model, cfg, sub, tau, loads):
    """Right side of Eq. (1) (Def. 41 projected as in Eq. 1, plus tau) from the outboard sums
    `sub` ((n+1) x 6) of :func:`_wrenches`; the applied loads' moments and forces are added here."""
    if loads is not None:
        bodies, F, T = loads
        applied = jnp.concatenate([T + cross(cfg.rho[bodies], F), F], 1)
        sub = sub + subtree_sum(model.topology, applied, tuple(int(b) for b in bodies))
    rhs0 = sub[0, :3]
    hinge = dot(cfg.axis, sub[1:, :3] - cross(cfg.hinge, sub[1:, 3:])) + tau
    return jnp.concatenate([rhs0, hinge])


def complete_state(model, t, state: State):
    """`state` with its prescribed hinges from the prescription at time t, and their accelerations."""
    return hinges.complete(model, t, state, dtype_of(model, state.gamma))


@full_precision
@eager_jit
def rotational_equations(model: Model, state: State, t=0.0, tau=None):
    """Matrix and right side of Eq. (1) for all n hinges, ``(A (n+3, n+3), rhs (n+3,))``.

    `tau` (n,) adds hinge torques to the joint laws of the model. Prescribed hinges
    are not treated specially here (see :func:`solve_accelerations`).
    """
    check_shapes("rotational_equations", model, state, tau=tau)
    dtype = dtype_of(model, state.gamma, state.gamma_dot, state.omega0)
    gamma = jnp.asarray(state.gamma, dtype)
    gamma_dot = jnp.asarray(state.gamma_dot, dtype)
    omega0 = jnp.asarray(state.omega0, dtype)
    state = State(jnp.asarray(state.dcm, dtype), omega0, gamma, gamma_dot)
    cfg, omega = configuration_and_rates(model, gamma, omega0, gamma_dot)
    torque = hinge_torques(model, gamma, gamma_dot)
    if tau is not None:
        torque = torque + tau
    loads = external_loads(model, t, state, cfg)
    wrenches = _wrenches(model, cfg, omega, gamma_dot, loads)
    if merge_outboard_sums():
        A, sums = _mass_matrix(model, cfg, wrenches)
    else:
        A = _mass_matrix(model, cfg)
        sums = subtree_sum(model.topology, wrenches, model.massive)
    return A, _rhs_from_sums(model, cfg, sums, torque, loads)


def merge_outboard_sums() -> bool:
    """Static choice, made when tracing: one outboard-set product for the matrix's composite
    bodies and the right side's wrenches, or two. Both give the same numbers. On CPUs one
    library product fewer pays (fig4: 7.5 -> 7.1 us per evaluation in a loop, vmapped 5.0 ->
    4.3 us per state); on GPUs the two products run faster apart (H100, fig4 batches of 65536:
    35 against 40 ns per state in float32, 52 against 54 in float64). Decided by JAX's default
    backend."""
    return jax.default_backend() == "cpu"


def unbalanced(model, state, t, tau, omega0_dot, gamma_ddot):
    """The unbalanced generalized force ``rhs - A x`` of Eq. (1) at accelerations ``x =
    (omega0_dot, gamma_ddot)`` (n + 3,), by one pass of inverse dynamics: the inertia loads of
    the accelerations join the velocity-product loads of Def. 41 (:func:`_wrenches`), so A is
    never assembled. Zero in the rows of the unknowns at the solution; minus the holding torques
    in the rows of prescribed hinges."""
    cfg, omega = configuration_and_rates(model, state.gamma, state.omega0, state.gamma_dot)
    return unbalanced_at(model, state, t, tau, cfg, omega, omega0_dot, gamma_ddot)


def unbalanced_at(model, state, t, tau, cfg, omega, omega0_dot, gamma_ddot):
    """:func:`unbalanced` with the configuration and the body angular velocities given (the
    state's angles and rates are read only by the hinge laws and the loads)."""
    torque = hinge_torques(model, state.gamma, state.gamma_dot)
    if tau is not None:
        torque = torque + tau
    loads = external_loads(model, t, state, cfg)
    wrenches = _wrenches(model, cfg, omega, state.gamma_dot, loads, (omega0_dot, gamma_ddot))
    sums = subtree_sum(model.topology, wrenches, model.massive)
    return _rhs_from_sums(model, cfg, sums, torque, loads)


def _momenta(model, state):
    dtype = dtype_of(model, state.gamma)
    cfg, omega = configuration_and_rates(
        model, state.gamma, jnp.asarray(state.omega0, dtype), jnp.asarray(state.gamma_dot, dtype)
    )
    vel = massive_rows(model, mass_center_velocities(model, cfg, omega))
    w = massive_rows(model, omega)
    mass = massive_rows(model, model.mass.astype(vel.dtype))
    return cfg, mass, vel, w, mv(cfg.inertia, w)


@full_precision
@eager_jit
def kinetic_energy(model: Model, state: State):
    """Kinetic energy relative to the system mass center (the quadratic form of Eq. 1's matrix)."""
    check_shapes("kinetic_energy", model, state)
    return energy_and_momentum(model, state)[0]


@full_precision
@eager_jit
def angular_momentum(model: Model, state: State):
    """Angular momentum about the system mass center, inertial components ``{i}`` (3,)."""
    check_shapes("angular_momentum", model, state)
    return energy_and_momentum(model, state)[1]


def energy_and_momentum(model, state):
    """:func:`kinetic_energy` and :func:`angular_momentum` from one evaluation of the velocities
    (``simulate``'s diagnostics need both: half the tracing)."""
    cfg, mass, vel, w, Jw = _momenta(model, state)
    energy = 0.5 * (jnp.sum(mass * jnp.sum(vel * vel, -1)) + jnp.sum(w * Jw))
    H0 = jnp.sum(cross(massive_rows(model, cfg.rho), mass[:, None] * vel) + Jw, 0)
    return energy, jnp.asarray(state.dcm, H0.dtype).T @ H0


@full_precision
@eager_jit
def mass_center_acceleration(model: Model, state: State, t=0.0):
    """Eq. (2): ``X_ddot = F / M`` in inertial components (zero when the model has no loads)."""
    check_shapes("mass_center_acceleration", model, state)
    cfg = configuration(model, state.gamma)
    dtype = cfg.R.dtype
    loads = external_loads(model, t, state, cfg)
    if loads is None:
        return jnp.zeros((3,), dtype)
    _, F, _ = loads
    return jnp.asarray(state.dcm, dtype).T @ jnp.sum(F, 0) / jnp.sum(model.mass.astype(dtype))
