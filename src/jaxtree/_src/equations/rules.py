"""The derivative (``custom_jvp``) and batching (``custom_vmap``) rules of the solution of Eq. (1)
of Likins (1972).

Eq. (1) is ``A(p) x = b(p)``, p everything the accelerations depend on (state, parameters, time,
torques, prescribed accelerations; the prescribed hinges of Sec. II B on the right side). Its
derivatives follow the implicit-function theorem instead of the operations of the solve: with the
unbalanced force ``F(p, x) = b - A x`` (:func:`jaxtree._src.equations.assembly.unbalanced`, one
pass of inverse dynamics through Def. 41, zero at the solution in the unknowns' rows u),
``x_u' = A_uu^{-1} (dF/dp p')``. The tangent of the configuration along the state is in closed
form (:func:`configuration_tangent`: small rotations about the hinge axes inboard of each body,
Def. 27 and Eq. 5). Under ``jax.vmap`` of at least
:func:`~jaxtree._src.equations.solve.batch_first_min` members the tangents and cotangents are
those of the batch-first recursion of :mod:`.batched` instead, differentiated forward and
backward (:func:`jaxtree._src.equations.solve.vmap_dispatch` decides, where JAX batches).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import is_forward_only, spd_inverse
from .assembly import (
    Configuration,
    configuration_and_rates,
    massive_rows,
    parent_indices,
    rotational_equations,
    unbalanced_at,
)
from .kinematics import ancestor_sum, cross, mm, take_rows, tilde
from .solve import (
    Accelerations,
    Inverse,
    all_batched,
    batch_first_min,
    factored_one,
    factorize,
    full_accelerations,
    solve_members,
    solve_plain,
    solver,
    unknown_rows_and_prescribed,
    vmap_dispatch,
)


@eqx.filter_custom_jvp
def solve_completed(model, state, t, tau, gdd_p):
    """Eq. (1) for a state completed with its prescribed hinges (their accelerations `gdd_p`), by
    the model's method; its derivatives follow the implicit-function rule of
    :func:`solve_completed_jvp` instead of the operations of the solve."""
    return solve_plain(model, state, t, tau, gdd_p)


@eqx.filter_custom_jvp
def _solve_factored(model, state, t, tau, gdd_p):
    """``(accelerations, factor)``: :func:`solve_completed` as its derivative rule computes it,
    from the factor of the matrix that the rule's tangents reuse (:func:`factored_one`); under
    a batch-first ``jax.vmap`` the batch-first accelerations and a placeholder factor (the
    tangents are then the recursion's, which makes no factor). Differentiated by the same rule
    (the factor a constant), so second derivatives never differentiate a ``custom_vmap``."""
    return solve_plain(model, state, t, tau, gdd_p, one=factored_one)


def configuration_tangent(model, cfg, omega, gamma_dot, d_gamma, d_gamma_dot, d_omega0):
    """Tangents of ``(cfg, omega)`` of :func:`configuration_and_rates` along state tangents
    ``(d_gamma, d_gamma_dot, d_omega0)`` (None: zero), in closed form; the configuration's tangent is
    None when `d_gamma` is (its rates alone do not move it).

    A change ``d_gamma`` of the angles turns every body about the hinge axes inboard of it: body
    k by the small rotation ``theta_k = sum_r epsilon_{rk} d_gamma_r g^r`` (the path-element sum
    of the angular velocities, Def. 27, with ``d_gamma`` for the rates and no ``omega0``). Every
    vector fixed in b_k turns by ``theta_k x``, so ``dC^{0k} = tilde(theta_k) C^{0k}``, the axes
    and hinge offsets turn with their bodies, the mass centers move as with velocities
    ``theta`` (recentred on the system mass center), the inertias as ``[theta, I]``, and the
    angular velocities change through the turned axes of Eq. (5)'s sum. One path-element sum for
    theta and one for the positions and rates replace the differentiated product of rotations."""
    dtype = cfg.rho.dtype
    topo = model.topology
    par = parent_indices(model)
    G = cfg.axis
    zero = jnp.zeros((1, 3), dtype)
    w0 = zero if d_omega0 is None else jnp.asarray(d_omega0, dtype)[None, :]
    rates = jnp.zeros_like(G) if d_gamma_dot is None else G * jnp.asarray(d_gamma_dot, dtype)[:, None]
    if d_gamma is None:  # the configuration does not move: no tangent (None), not a zero one
        d_omega = ancestor_sum(topo, jnp.concatenate([w0, rates], 0))
        return None, d_omega
    theta = ancestor_sum(topo, jnp.concatenate([zero, G * jnp.asarray(d_gamma, dtype)[:, None]], 0))
    tp = take_rows(theta, par)
    d_axis = cross(tp, G)
    d_to = cross(tp, cfg.to_hinge)
    d_from = cross(theta[1:], cfg.from_hinge)
    steps = jnp.concatenate([zero, d_to + d_from], 0)
    rates = jnp.concatenate([w0, rates + d_axis * gamma_dot[:, None]], 0)
    both = ancestor_sum(topo, jnp.concatenate([steps, rates], 1))
    mass = model.mass.astype(dtype)
    d_rho = both[:, :3] - jnp.sum(mass[:, None] * both[:, :3], 0) / jnp.sum(mass)
    d_hinge = take_rows(d_rho, par) + d_to
    d_R = mm(tilde(theta), cfg.R)
    th = massive_rows(model, theta)
    turned = mm(tilde(th), cfg.inertia)
    d_inertia = turned + jnp.swapaxes(turned, -1, -2)  # [theta, I] = theta x I - I theta x, I symmetric
    return Configuration(d_R, d_axis, d_to, d_from, d_rho, d_hinge, d_inertia), both[:, 3:]


def _differentiated(primals, tangents):
    """The leaves of `primals` that carry a tangent, their tangents, and a function that puts new
    values of those leaves back into `primals` (the others stay constants)."""
    leaves, tree = jax.tree_util.tree_flatten(primals)
    tleaves = tree.flatten_up_to(tangents)
    idx = [i for i, tl in enumerate(tleaves) if tl is not None]

    def rebuild(values):
        out = list(leaves)
        for i, v in zip(idx, values):
            out[i] = v
        return jax.tree_util.tree_unflatten(tree, out)

    return [leaves[i] for i in idx], [tleaves[i] for i in idx], rebuild


def solve_completed_jvp(primals, tangents):
    """Derivatives of the solution of Eq. (1) by the implicit-function theorem.

    Eq. (1) is ``A(p) x = b(p)``, p everything the accelerations depend on (state, parameters,
    time, torques, prescribed accelerations). With the unbalanced force ``F(p, x) = b - A x``
    (:func:`unbalanced`, zero at the solution in the unknowns' rows u):

        x_u' = A_uu^{-1} (dF/dp p')   and   hold' = -(dF_p/dp p') + A_pu x_u',

    where ``dF/dp p'`` is one JVP of F at *fixed* x (no solve inside; the configuration's tangent
    along the state in closed form, :func:`_unbalanced_jvp`) and ``A_uu^{-1}`` is
    applied to every tangent at once (``jax.jacfwd``: one solve with many right sides): with the
    dense method's Cholesky factor, or for the articulated method (which calls no LAPACK routine)
    as an inverse by Gauss-Jordan elimination in a loop (:func:`jaxtree._src.numerics.spd_inverse`),
    computed once from the primal configuration and applied to all tangents by one product
    (:func:`_tangent_one`).

    Under ``jax.vmap`` of at least :func:`batch_first_min` members the tangents are those of the
    batch-first recursion of :mod:`.batched` instead, differentiated forward (and its transpose
    for reverse mode): the members' tangents in the layout of the batch, the same derivatives to
    round-off. Which of the two runs is decided where JAX batches (``custom_vmap``); the map
    ``p' -> x'`` is handed to JAX as a linear solve (:func:`_tangent_map`) so that reverse mode
    transposes it through a rule of its own. The rule is written in JAX, so it can be
    differentiated again (the linearization's second derivatives)."""
    acc, _, acc_dot = _rule(primals, tangents)
    return acc, acc_dot


def _solve_factored_jvp(primals, tangents):
    """:func:`solve_completed_jvp` for :func:`_solve_factored` (the factor's tangent zero: only the
    rule's own solves read it)."""
    acc, factor, acc_dot = _rule(primals, tangents)
    return (acc, factor), (acc_dot, jnp.zeros_like(factor))


def _rule(primals, tangents):
    """``(accelerations, factor, their tangents)``: by :func:`_tangent_map` for a tree of at least
    :data:`BATCH_FIRST_DERIVATIVES_MIN` bodies, else by :func:`member_jvp`."""
    if primals[0].n < BATCH_FIRST_DERIVATIVES_MIN:
        return member_jvp(primals, tangents)
    acc, factor = _solve_factored(*primals)
    spec, arr, dots = _differentiated_arrays(primals, tangents)
    if spec is None:
        return acc, factor, jax.tree_util.tree_map(jnp.zeros_like, acc)
    if is_forward_only():  # never transposed nor differentiated again: no linear solve around it
        return acc, factor, _tangent_of(spec, jax.jit(functools.partial(_tangent_one, spec)), arr, (acc, factor), dots)
    return acc, factor, _tangent_map(spec, arr, (acc, factor), dots)


def member_jvp(primals, tangents):
    """``(accelerations, factor, their tangents)`` of Eq. (1) for one member by the
    implicit-function rule in plain JAX, ``primals`` ``(model, state, t, tau, gdd_p)`` of a state
    completed with its prescribed hinges: the derivative of trees under
    :data:`BATCH_FIRST_DERIVATIVES_MIN` bodies, which ``jax.vmap`` batches as it is (and the peer
    that ``benchmarks/bench_batch.py --tangents`` times against the batch-first tangents)."""
    acc, factor = factored_one(*primals)
    spec, arr, dots = _differentiated_arrays(primals, tangents)
    if spec is None:
        return acc, factor, jax.tree_util.tree_map(jnp.zeros_like, acc)
    return acc, factor, _tangent_one(spec, arr, (acc, factor), dots)


def _differentiated_arrays(primals, tangents):
    """``(spec, arrays, tangents)`` of the leaves of `primals` that carry a tangent (:func:`_spec`),
    or ``(None, None, None)`` when none does."""
    leaves, tree = jax.tree_util.tree_flatten(primals)
    tleaves = tree.flatten_up_to(tangents)
    diff = tuple(i for i, tl in enumerate(tleaves) if tl is not None)
    if not diff:
        return None, None, None
    spec, arr = _spec(leaves, tree, diff)
    return spec, arr, [jnp.asarray(tleaves[i], jnp.result_type(leaves[i])) for i in diff]


# Trees of at least this many bodies differentiate Eq. (1) through :func:`_tangent_map`, whose
# tangents run the batch-first recursion under a vmap of batch_first_min() members; smaller ones
# keep the single-member rule in plain JAX. On this 2-core CPU (64 members, tangents of all hinge
# angles, 2026-11-27) the batch-first tangents ran fig4_free (4 bodies) 1.4x and chain10 2x faster
# but compiled in 23-38 s against 3 s; chain50 ran 1.75x faster (jacfwd 1.49 against 2.60 ms a member)
# and flex95 9x (6 tangents at 256 members: 125 against 1176 us a member). `benchmarks/bench_batch.py
# --tangents K` times both forms, called explicitly (`member_jvp` and the batch-first recursion's JVP),
# on any tree.
BATCH_FIRST_DERIVATIVES_MIN = 16


def _spec(leaves, tree, diff):
    """The :class:`_Spec` of flattened inputs with tangents on the leaves `diff`, and their arrays."""
    arrays = tuple(i for i, x in enumerate(leaves) if eqx.is_array(x))
    if not set(diff) <= set(arrays):
        raise TypeError("Eq. (1): a tangent on an input that is not an array")
    where = tuple(arrays.index(i) for i in diff)
    spec = _Spec(tree, tuple(None if eqx.is_array(x) else x for x in leaves), arrays, where)
    return spec, [leaves[i] for i in arrays]


solve_completed.def_jvp(solve_completed_jvp)
_solve_factored.def_jvp(_solve_factored_jvp)


def _tangent_map(spec, arr, res, dots):
    """The tangents of the accelerations along `dots` (those of ``leaves[i]``, i in `diff`).

    The map ``G: p' -> acc'`` is linear; it is passed to JAX as the solve of the linear system
    ``M (p', y) = (p', y - G p')``, whose inverse ``(p', y + G p')`` (:func:`_tangent_of`) and
    transposed inverse ``(c_p + G^T c_y, c_y)`` (:func:`_cotangent_of`) are evaluated by the
    single-member rule or, under a batch, by the batch-first recursion: ``custom_vmap``
    chooses, and ``custom_linear_solve`` carries the choice through transposition, which JAX
    would otherwise have to do for ``custom_vmap`` itself (it cannot)."""
    # one tangent of one member, traced once for the solve, its transpose, the matrix and the
    # batches below (each would otherwise trace the rule again)
    per = jax.jit(functools.partial(_tangent_one, spec))

    @jax.jit  # traced once for the matrix and its transpose
    def own_factor(arr):
        # an inverse by Gauss-Jordan, whatever the method: no LAPACK call, which a batch of
        # second derivatives would otherwise run batched beside others (the LAPACK deadlock of
        # benchmarks/FINDINGS.md), and differentiable as it is
        model, state, t, tau, _ = spec.primals(arr)
        rows_u, _ = unknown_rows_and_prescribed(model)
        A, _ = rotational_equations(model, state, t, tau)
        return Inverse(spd_inverse(A[np.ix_(rows_u, rows_u)])[0])

    def matvec(x):  # read only when the solve is differentiated: its own factor, differentiable
        p, y = x
        return p, jax.tree_util.tree_map(jnp.subtract, y, _tangents(spec, per, arr, (res[0], own_factor(arr)), p))

    def solve(_, b):
        p, y = b
        return p, jax.tree_util.tree_map(jnp.add, y, _tangent_of(spec, per, arr, res, p))

    def transpose_solve(_, c):
        cp, cy = c
        return [u + v for u, v in zip(cp, _cotangent_of(spec, per, arr, res, cy))], cy

    # the second part of the right side is zero, but linear in the tangents: JAX transposes a
    # linear solve only when all of its right side is
    nothing = 0.0 * jnp.sum(dots[0])
    zeros = jax.tree_util.tree_map(lambda a: jnp.zeros_like(a) + nothing.astype(a.dtype), res[0])
    return jax.lax.custom_linear_solve(matvec, (dots, zeros), solve, transpose_solve)[1]


class _Spec(NamedTuple):
    """Where the arrays of a flattened ``(model, state, t, tau, gdd_p)`` are: `tree` its structure,
    `fixed` its leaves that are not arrays (None at the arrays), `arrays` the positions of the
    array leaves, `where` the positions among those of the differentiated ones."""

    tree: Any
    fixed: tuple
    arrays: tuple
    where: tuple

    def primals(self, arr):
        leaves = list(self.fixed)
        for i, a in zip(self.arrays, arr):
            leaves[i] = a
        return jax.tree_util.tree_unflatten(self.tree, leaves)

    def tangents(self, dots):
        leaves = [None] * len(self.fixed)
        for j, d in zip(self.where, dots):
            leaves[self.arrays[j]] = d
        return jax.tree_util.tree_unflatten(self.tree, leaves)


def _minimum(spec, arr):
    """The members from which a vmap of the rule runs the batch-first recursion: the model's
    :func:`batch_first_min`, the same as its solve's."""
    return batch_first_min(spec.primals(arr)[0])


def _over_axes(fn, extra):
    """`fn` of one tangent (or cotangent) mapped over `extra` leading axes of its argument."""
    for _ in range(extra):
        fn = jax.vmap(fn)
    return fn


def _tangents(spec, per, arr, res, dots):
    """``G p'`` for one member by `per` (:func:`_tangent_one`); `dots` may carry leading axes of
    tangents beyond the shapes of their primals (the same on every one): the factor is made
    once (it does not depend on them) and applied to all."""
    extra = jnp.ndim(dots[0]) - jnp.ndim(arr[spec.where[0]])
    return _over_axes(lambda d: per(arr, res, d), extra)(dots)


def _tangent_one(spec, arr, res, dots):
    """``G p'`` for one member and one tangent by the implicit-function rule. `res`: the
    accelerations and :func:`factorize`'s factor (None: make it here)."""
    acc, factor = res
    primals = spec.primals(arr)
    model, state, t, tau, gdd_p = primals
    rows_u, rows_p = unknown_rows_and_prescribed(model)
    if factor is None:
        A, _, factor, _ = factorize(model, state, t, tau)
    elif len(rows_p):
        A, _ = rotational_equations(model, state, t, tau)
    solve_u = solver(model, factor)
    x_u = jnp.concatenate([acc.omega0_dot, acc.gamma_ddot[rows_u[3:] - 3]])
    A_pu = A[np.ix_(rows_p, rows_u)] if len(rows_p) else None
    values = [arr[j] for j in spec.where]
    rebuild = lambda v: spec.primals([dict(zip(spec.where, v)).get(j, a) for j, a in enumerate(arr)])

    def one(d):
        tangents = spec.tangents(d)
        F_dot = _unbalanced_jvp(primals, tangents, x_u, values, d, rebuild)
        x_dot = solve_u(F_dot[rows_u])
        gdd_p_dot = None if gdd_p is None else (jnp.zeros_like(gdd_p) if tangents[4] is None else tangents[4])
        w_dot_dot, gdd_dot = full_accelerations(model, x_dot, gdd_p_dot)
        hold_dot = -F_dot[rows_p]
        if A_pu is not None:
            hold_dot = hold_dot + A_pu @ x_dot
        return Accelerations(w_dot_dot, gdd_dot, hold_dot)

    return one(dots)


def _members(spec, size, arr, arr_f):
    """``(values, f)``: the differentiated leaves, each with the members on axis 0, and the
    batch-first accelerations of :func:`solve_members` as a function of them."""
    values = [arr[j] if arr_f[j] else jnp.broadcast_to(arr[j], (size,) + jnp.shape(arr[j])) for j in spec.where]
    flags = list(arr_f)
    for j in spec.where:
        flags[j] = True

    def f(v):
        full = list(arr)
        for j, x in zip(spec.where, v):
            full[j] = x
        dyn, static = eqx.partition(spec.primals(full), eqx.is_array)
        return solve_members(size, dyn, jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(dyn), flags), static)

    return values, f


# The batch-first tangent below is jitted with the spec, the batch's size and which arrays carry
# members static, and traced for one tangent: JAX keeps the traced program, so a signature is traced
# once, and its batches over tangents and its transpose (the cotangents) are made from that program
# rather than by tracing the recursion again. A linear solve's batching rule batches its functions
# again until it knows which of its outputs are batched (a fixed point: twice at least), and a second
# derivative batches the rule's own tangent solve too; each of those passes would otherwise trace the
# batch-first recursion and its derivative afresh (fig4_free's vmapped Hessian: 10 traces of it).
@functools.partial(jax.jit, static_argnums=(0, 1, 2))
def _members_tangent(spec, size, arr_f, arr, dots):
    """The tangent along `dots` (one per differentiated leaf, the members on axis 0) of the
    batch-first accelerations of :func:`_members`."""
    values, f = _members(spec, size, arr, arr_f)
    return jax.jvp(f, (values,), (dots,))[1]


def _members_jvp(spec, size, arr_f, extra, arr, dots):
    """:func:`_members_tangent` along `dots` with `extra` leading tangent axes, the members then
    moved to axis 0."""
    out = _over_axes(lambda d: _members_tangent(spec, size, arr_f, arr, d), extra)(dots)
    return jax.tree_util.tree_map(lambda x: jnp.moveaxis(x, extra, 0), out)


def _members_vjp(spec, size, arr_f, extra, arr, c):
    """The cotangents of the differentiated leaves from the accelerations' cotangents `c` (as in
    :func:`_members_jvp`): the transpose of :func:`_members_tangent`."""
    shapes = [
        jax.ShapeDtypeStruct(jnp.shape(arr[j]) if arr_f[j] else (size,) + jnp.shape(arr[j]), jnp.result_type(arr[j]))
        for j in spec.where
    ]
    transposed = jax.linear_transpose(lambda d: _members_tangent(spec, size, arr_f, arr, d), shapes)
    return [jnp.moveaxis(x, extra, 0) for x in _over_axes(lambda c: list(transposed(c)[0]), extra)(c)]


def _tangent_of(spec, per, arr, res, dots):
    """``G p'`` (:func:`_tangent_one`), by the batch-first recursion differentiated forward under
    ``jax.vmap`` of at least :func:`batch_first_min` members."""

    def unbatched(size, in_batched, arr, res, dots):
        # tangents alone batched (jax.jacfwd): one more leading axis of tangents on all
        dots = [d if b else jnp.broadcast_to(d, (size,) + jnp.shape(d)) for d, b in zip(dots, in_batched[2])]
        return all_batched(_tangent_of(spec, per, arr, res, dots))

    def members(size, in_batched, arr, res, dots):
        arr_f, _, dot_f = in_batched
        j = spec.where[0]
        extra = jnp.ndim(dots[0]) - int(dot_f[0]) - (jnp.ndim(arr[j]) - int(arr_f[j]))
        d = [_tangent_axes(x, b, size, extra) for x, b in zip(dots, dot_f)]
        return all_batched(_members_jvp(spec, size, tuple(arr_f), extra, arr, d))

    one = lambda arr, res, dots: _tangents(spec, per, arr, res, dots)
    return vmap_dispatch(one, (arr, res, dots), members, unbatched, decide=2, minimum=_minimum(spec, arr))


def _cotangent_one(spec, per, arr, res, c):
    """``G^T c`` for one member: the transpose of :func:`_tangent_one` (`c` may carry leading
    axes beyond the accelerations' shapes)."""
    values = [arr[j] for j in spec.where]
    extra = jnp.ndim(c.omega0_dot) - 1
    transposed = jax.linear_transpose(lambda d: per(arr, res, d), values)
    return _over_axes(lambda c: list(transposed(c)[0]), extra)(c)


def _cotangent_of(spec, per, arr, res, c):
    """``G^T c`` (:func:`_cotangent_one`), by the batch-first recursion differentiated backward
    under ``jax.vmap`` of at least :func:`batch_first_min` members."""

    def unbatched(size, in_batched, arr, res, c):
        c = jax.tree_util.tree_map(
            lambda x, b: x if b else jnp.broadcast_to(x, (size,) + jnp.shape(x)), c, in_batched[2]
        )
        return all_batched(_cotangent_of(spec, per, arr, res, c))

    def members(size, in_batched, arr, res, c):
        arr_f, _, c_f = in_batched
        extra = jnp.ndim(c.omega0_dot) - int(c_f.omega0_dot) - 1
        cc = jax.tree_util.tree_map(lambda x, b: _tangent_axes(x, b, size, extra), c, c_f)
        return all_batched(_members_vjp(spec, size, tuple(arr_f), extra, arr, cc))

    # fewer members: one by one (a batch this small made its factors member by member, solve_plain)
    one = lambda arr, res, c: _cotangent_one(spec, per, arr, res, c)
    return vmap_dispatch(one, (arr, res, c), members, unbatched, decide=2, minimum=_minimum(spec, arr))


def _tangent_axes(x, batched, size, extra):
    """`x` (members on axis 0 when `batched`, then `extra` leading tangent axes) as (tangent
    axes..., members, ...)."""
    if not batched:
        x = jnp.broadcast_to(x, (size,) + jnp.shape(x))
    return jnp.moveaxis(x, 0, extra)


def _unbalanced_jvp(primals, tangents, x_u, values, dots, rebuild):
    """``dF/dp p'`` of the unbalanced force at fixed unknown accelerations `x_u`: the tangents of
    the configuration and the angular velocities along the state's angles and rates in closed
    form (:func:`configuration_tangent`), those along the model's parameters by differentiating
    :func:`configuration_and_rates`, and one JVP of the rest (:func:`unbalanced_at`) with all of them."""
    model, state, *_ = primals
    d_model, d_state = tangents[0], tangents[1]
    d_g, d_gd, d_w = (None, None, None) if d_state is None else (d_state.gamma, d_state.gamma_dot, d_state.omega0)
    cfg, omega = configuration_and_rates(model, state.gamma, state.omega0, state.gamma_dot)
    cfg_dot, omega_dot = configuration_tangent(model, cfg, omega, state.gamma_dot, d_g, d_gd, d_w)
    if d_model is not None:
        m_values, m_dots, m_rebuild = _differentiated(model, d_model)
        if m_values:

            def configuration_of(v):
                return configuration_and_rates(m_rebuild(v), state.gamma, state.omega0, state.gamma_dot)

            _, (c_dot, o_dot) = jax.jvp(configuration_of, (m_values,), (m_dots,))
            cfg_dot = c_dot if cfg_dot is None else jax.tree_util.tree_map(jnp.add, cfg_dot, c_dot)
            omega_dot = omega_dot + o_dot

    def force(values, cfg, omega):
        m, s, tt, ta, gp = rebuild(values)
        return unbalanced_at(m, s, tt, ta, cfg, omega, *full_accelerations(m, x_u, gp))

    if cfg_dot is None:  # rates only: the geometry carries no tangent, so none of its products is differentiated
        return jax.jvp(lambda v, o: force(v, cfg, o), (values, omega), (dots, omega_dot))[1]
    return jax.jvp(force, (values, cfg, omega), (dots, cfg_dot, omega_dot))[1]
