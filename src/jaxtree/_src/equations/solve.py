"""The solve of Eq. (1) of Likins (1972) for the accelerations, and its dispatch.

Eq. (1) is ``[a] [omega0_dot; gamma_ddot] = rhs`` with the coefficient matrix of Defs. 38-40 and
the right side of Def. 41 and the hinge torques, assembled by :mod:`.assembly`. This module
solves it for one member by the model's method, the dense Cholesky factorization of the matrix
or the blocked articulated-body recursion of :mod:`.articulated`, with prescribed hinges as in
Sec. II B: a prescribed hinge j takes ``gamma_j``, ``gamma_dot_j`` and ``gamma_ddot_j`` from the
prescription, its row and column leave the matrix and ``a_{.j} gamma_ddot_j`` moves to the right
side; the torque that holds the prescription is returned too. Under ``jax.vmap`` of at least
:func:`batch_first_min` members Eq. (1) runs the batch-first recursion of :mod:`.batched` (the
same accelerations to round-off): :func:`vmap_dispatch` makes that choice where JAX batches, for
the solve and for its tangents and cotangents (:mod:`.rules`).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import regular as _regular
from ..numerics import regular_pivots as _regular_pivots
from ..numerics import spd_inverse
from ..vehicle import hinges
from ..vehicle.model import State
from . import articulated, batched
from .assembly import (
    configuration_and_rates,
    dtype_of,
    external_loads,
    hinge_torques,
    mass_center_velocities,
    rotational_equations,
)


class Accelerations(NamedTuple):
    """Solution of Eq. (1): accelerations and, for prescribed hinges, the torque that holds them."""

    omega0_dot: jax.Array  # (3,)
    gamma_ddot: jax.Array  # (n,), prescribed hinges included
    hold_torque: jax.Array  # (len(model.prescribed),)


# Batches of at least this many members run the batch-first recursion (:mod:`.batched`) when Eq. (1)
# is vmapped on a CPU; smaller ones vmap the single-member solve, whose program is smaller to
# compile (benchmarks/FINDINGS.md, "`bench_batch.py`: Eq. (1) batch-first" and "Stages by barrier,
# not by conditional": with barriers the batch-first program wins per member from 8 members on,
# but compiles for longer).
BATCH_FIRST_MIN = 64
# The same for trees of at least LARGE_TREE_HINGES hinges, whose single-member solve costs several
# times the recursion's share already at 16 members (one device, 16 members: chain50 2.1x,
# random60 3.4x, chain200 2.9x, flex95 8.1x; the compilation 1.2 s longer on chain50, 10 s on
# flex95, 29 s on random60, 5 s shorter on chain200: FINDINGS, "A batch-first threshold that falls
# with the tree").
BATCH_FIRST_MIN_LARGE = 16
LARGE_TREE_HINGES = 48
# The same on an accelerator, where each of the batch-first program's kernels is a launch: it lost
# to the vmapped single solve up to 8192 members and won at 65 536 (FINDINGS, "`bench_gpu.py` on
# an NVIDIA H200"; between them not measured).
BATCH_FIRST_MIN_ACCELERATOR = 65536


def batch_first_min(model=None) -> int:
    """Members from which a vmapped Eq. (1) of `model` runs the batch-first recursion on JAX's
    default backend (without a model: the threshold of the small trees)."""
    if jax.default_backend() != "cpu":
        return BATCH_FIRST_MIN_ACCELERATOR
    if model is not None and model.n >= LARGE_TREE_HINGES:
        return BATCH_FIRST_MIN_LARGE
    return BATCH_FIRST_MIN


def vmap_dispatch(one, args, members, unbatched=None, decide=None, *, minimum):
    """``one(*args)``, one member, under a ``custom_vmap`` whose rule takes one of three paths
    for a batch of `size` members, the same decision for the solve of Eq. (1)
    (:func:`solve_plain`) and for its tangents and cotangents (:mod:`.rules`), `minimum` the
    model's :func:`batch_first_min`:

    - nothing batched in the first `decide` arguments (the primals; all arguments when None):
      ``unbatched(size, in_batched, *args)``, by default one call of `one`, its result not
      batched (e.g. only tangents batched, in a JVP);
    - at least `minimum` members: ``members(size, in_batched, *args)``, the
      batch-first recursion of :mod:`.batched`;
    - fewer: `one` member by member (``jax.vmap``).

    `members` and `unbatched` return ``(out, out_batched)``, as a ``custom_vmap`` rule does."""

    @jax.custom_batching.custom_vmap
    def g(*args):
        return one(*args)

    @g.def_vmap
    def _rule(size, in_batched, *args):
        primal = in_batched if decide is None else in_batched[:decide]
        if not any(jax.tree_util.tree_leaves(primal)):
            if unbatched is not None:
                return unbatched(size, in_batched, *args)
            out = one(*args)  # nothing batched (e.g. only tangents, in a JVP): one solve
            return out, jax.tree_util.tree_map(lambda _: False, out)
        if size >= minimum:
            return members(size, in_batched, *args)
        return all_batched(jax.vmap(one, in_axes=batch_axes(in_batched), axis_size=size)(*args))

    return g(*args)


def batch_axes(in_batched):
    """``jax.vmap``'s `in_axes` from a ``custom_vmap`` rule's flags: 0 where batched, else None."""
    return jax.tree_util.tree_map(lambda b: 0 if b else None, in_batched)


def all_batched(out):
    """``(out, out_batched)`` of a ``custom_vmap`` rule whose outputs all carry the members."""
    return out, jax.tree_util.tree_map(lambda _: True, out)


def solve_plain(model, state, t, tau, gdd_p, one=None):
    """Eq. (1) by the model's method; under ``jax.vmap`` of at least :func:`batch_first_min`
    members, by the batch-first recursion of :mod:`jaxtree._src.equations.batched` (the same
    accelerations to round-off)."""
    one = solve_one if one is None else one
    dyn, static = eqx.partition((model, state, t, tau, gdd_p), eqx.is_array)
    # custom_vmap sees a flat list of arrays: its JVP compares pytree structures in which None
    # leaves (eqx.partition's placeholders) would not match
    leaves, tree = jax.tree_util.tree_flatten(dyn)
    args = lambda leaves: eqx.combine(jax.tree_util.tree_unflatten(tree, leaves), static)

    def members(size, in_batched, leaves):
        (flags,) = in_batched
        dyn, flags = jax.tree_util.tree_unflatten(tree, leaves), jax.tree_util.tree_unflatten(tree, flags)
        out = solve_members(size, dyn, flags, static)
        if one is factored_one:  # the factor's placeholder, the same for all members
            rows = len(unknown_rows_and_prescribed(static[0])[0])
            placeholder = jnp.zeros((rows, rows), out.omega0_dot.dtype)
            return (out, placeholder), (jax.tree_util.tree_map(lambda _: True, out), False)
        return all_batched(out)

    minimum = batch_first_min(static[0])
    return vmap_dispatch(lambda leaves: one(*args(leaves)), (leaves,), members, minimum=minimum)


# On a CPU a batch of more than this many members runs the recursion group after group (a
# ``lax.map``), each group's arrays small enough to stay in a core's cache: flex95, one device,
# 9.7 us a member in groups of 64 against 30 us as one group of 256 (benchmarks/FINDINGS.md,
# "Eq. (1) in groups of members").
BATCH_GROUP = 64


def member_groups(size: int) -> tuple[int, int]:
    """``(groups, members in each)`` that a batch of `size` members runs as on JAX's default
    backend: one group but on a CPU, where groups of at most :data:`BATCH_GROUP`, as even as
    can be (the last group made full by repeating the last member)."""
    if jax.default_backend() != "cpu" or size <= BATCH_GROUP:
        return 1, size
    groups = -(-size // BATCH_GROUP)
    return groups, -(-size // groups)


def solve_members(size, dyn, flags, static, *, stages=None, scan_min=batched.SCAN_MIN):
    """Eq. (1) for a batch (members on axis 0 of the leaves flagged in `flags`) by the batch-first
    recursion: the hinge laws, torques and loads of each member by ``jax.vmap``, then one
    recursion over the members with the members as the contiguous axis, group after group of
    :func:`member_groups`."""
    groups, each = member_groups(size)
    if groups == 1:
        return _solve_group(size, dyn, flags, static, stages, scan_min)
    padded = groups * each

    def split(a, batched_leaf):  # (size, ...) -> (groups, each, ...); others left out
        if not batched_leaf:
            return None
        if padded > size:
            a = jnp.concatenate([a, jnp.broadcast_to(a[-1:], (padded - size,) + a.shape[1:])])
        return a.reshape((groups, each) + a.shape[1:])

    parts = jax.tree_util.tree_map(split, dyn, flags)
    shared = jax.tree_util.tree_map(lambda a, b: None if b else a, dyn, flags)
    out = jax.lax.map(
        lambda part: _solve_group(each, eqx.combine(part, shared), flags, static, stages, scan_min), parts
    )
    return jax.tree_util.tree_map(lambda o: o.reshape((padded,) + o.shape[2:])[:size], out)


def _solve_group(size, dyn, flags, static, stages, scan_min):
    """:func:`solve_members` for one group of `size` members."""
    model, state, t, tau, gdd_p = eqx.combine(dyn, static)
    mflags, sflags = eqx.combine(flags, static)[:2]
    axes = batch_axes(flags)
    prescribed = hinges.index(model.prescribed)

    def member(d):
        m, s, tt, ta, gp = eqx.combine(d, static)
        torque = hinge_torques(m, s.gamma, s.gamma_dot)
        if ta is not None:
            torque = torque + ta
        gdd = jnp.zeros_like(s.gamma) if gp is None else jnp.zeros_like(s.gamma).at[prescribed].set(gp)
        loads = None if m.loads is None else m.loads(tt, s)
        return torque, gdd, loads

    torque, gdd, loads = jax.vmap(member, in_axes=(axes,), axis_size=size)(dyn)
    if loads is not None:
        loads = (model.loads.bodies, loads[0], loads[1])
    pl = batched.plan(model.topology.parents, model.prescribed + model.inert, model.prescribed)
    keys = ("mass", "inertia", "axis", "hinge_on_parent", "hinge_on_body")
    on = {k: bool(getattr(mflags, k)) for k in keys}
    on.update(omega0=bool(sflags.omega0), gamma=bool(sflags.gamma), gamma_dot=bool(sflags.gamma_dot))
    on.update(tau=True, gdd=True, loads=True)
    x = batched.inputs(model, pl, state.omega0, state.gamma, state.gamma_dot, torque, gdd, loads, on)
    w, gdd_rows, hold_rows, _ = batched.solve(pl, x, stages=stages, scan_min=scan_min)
    w = jnp.broadcast_to(jnp.concatenate([jnp.reshape(c, (1, -1)) for c in w], 0), (3, size)).T
    hinge_row = np.argsort(pl.order - 1)
    gdd_out = jnp.broadcast_to(gdd_rows, (model.n, size))[hinge_row].T
    hold = jnp.broadcast_to(hold_rows, (model.n, size))[pl.prescribed_rows].T
    return Accelerations(w, gdd_out, hold)


def batch_first(model, state, t=0.0, tau=None, gdd_p=None, *, stages=None, scan_min=batched.SCAN_MIN):
    """Eq. (1) for a batch of states (a :class:`~jaxtree.State` whose arrays carry the members on
    axis 0; `tau` and `gdd_p` per member when 2-D) by the batch-first recursion, whatever the
    batch's size; `stages`, `scan_min`: see :func:`jaxtree._src.equations.batched.solve`. What
    ``jax.vmap`` of the solve runs from :func:`batch_first_min` members on, as an explicit call
    (benchmarks of its variants, tests of the accelerator's form on a CPU)."""
    size = int(jnp.shape(state.gamma)[0])
    dyn, static = eqx.partition((model, state, t, tau, gdd_p), eqx.is_array)
    flags = (
        jax.tree_util.tree_map(lambda _: False, dyn[0]),
        jax.tree_util.tree_map(lambda _: True, dyn[1]),
        None if dyn[2] is None else False,
        None if dyn[3] is None else jnp.ndim(dyn[3]) == 2,
        None if dyn[4] is None else jnp.ndim(dyn[4]) == 2,
    )
    return solve_members(size, dyn, flags, static, stages=stages, scan_min=scan_min)


def solve_one(model, state, t, tau, gdd_p):
    """Eq. (1) for one member by the model's method (no batching rule): what ``jax.vmap`` of the
    solve runs for fewer than :func:`batch_first_min` members."""
    if articulated.resolve_method(model) == "articulated":
        return _solve_articulated(model, state, t, tau, gdd_p)
    A, rhs = rotational_equations(model, state, t, tau)
    return _from_matrix(model, A, rhs, gdd_p, cholesky_solve)


def unknown_rows_and_prescribed(model):
    """Rows of Eq. (1) of its unknowns (omega0, then the unknown hinges) and of the prescribed hinges."""
    u, p, _ = hinges.split(model)
    return np.concatenate([np.arange(3), u + 3]), p + 3


def _from_matrix(model, A, rhs, gdd_p, solve):
    """The accelerations and holding torques of Eq. (1) from its matrix and right side, with
    ``solve(A_uu, b_u)`` solving the block of the unknowns (the prescribed accelerations moved to
    the right side, Sec. II B)."""
    rows_u, rows_p = unknown_rows_and_prescribed(model)
    if len(rows_u) == A.shape[0]:
        x_u = solve(A, rhs)  # every row an unknown: no gathers
    else:
        rhs_u = rhs[rows_u]
        if gdd_p is not None:
            rhs_u = rhs_u - A[np.ix_(rows_u, rows_p)] @ gdd_p
        x_u = solve(A[np.ix_(rows_u, rows_u)], rhs_u)
    w_dot, gdd = full_accelerations(model, x_u, gdd_p)
    hold = A[rows_p] @ jnp.concatenate([w_dot, gdd]) - rhs[rows_p] if len(rows_p) else jnp.zeros((0,), A.dtype)
    return Accelerations(w_dot, gdd, hold)


def full_accelerations(model, x_u, gdd_p):
    """``(omega0_dot, gamma_ddot)`` from the unknowns `x_u` (omega0_dot, then the unknown hinges)
    and the prescribed accelerations (inert hinges: zero)."""
    _, _, inverse = hinges.split(model)
    parts = [x_u[3:]] + ([] if gdd_p is None else [gdd_p]) + [jnp.zeros((len(model.inert),), x_u.dtype)]
    return x_u[:3], jnp.concatenate(parts)[inverse]


def factorize(model, state, t, tau):
    """``(A, solve_u)``: the matrix of Eq. (1) and the solve with its block of the unknowns, by the
    dense method's Cholesky factor or, for the articulated method (which calls no LAPACK
    routine), an inverse by Gauss-Jordan elimination in a loop
    (:func:`jaxtree._src.numerics.spd_inverse`) applied by one product; and whether the
    block is regular."""
    rows_u, _ = unknown_rows_and_prescribed(model)
    A, rhs = rotational_equations(model, state, t, tau)
    Auu = A[np.ix_(rows_u, rows_u)]
    if articulated.resolve_method(model) == "articulated":
        Ainv, pivots = spd_inverse(Auu)
        return A, rhs, Ainv, _regular_pivots(pivots, Auu)
    L = jax.lax.linalg.cholesky(Auu, symmetrize_input=False)
    return A, rhs, L, _regular(L, Auu)


class Inverse(NamedTuple):
    """``A_uu^{-1}`` as a factor (:func:`solver` applies it by a product)."""

    inverse: jax.Array


def solver(model, factor):
    """``A_uu^{-1} r`` by :func:`factorize`'s factor or an :class:`Inverse` (r: a vector)."""
    if isinstance(factor, Inverse):
        return lambda r: factor.inverse @ r
    if articulated.resolve_method(model) == "articulated":
        return lambda r: factor @ r
    return lambda r: _cho_apply(factor, r)


def factored_one(model, state, t, tau, gdd_p):
    """Eq. (1) for one member by :func:`factorize` (NaN where its block is singular), and the factor."""
    A, rhs, factor, ok = factorize(model, state, t, tau)
    solve_u = solver(model, factor)
    return _from_matrix(model, A, rhs, gdd_p, lambda _, b: jnp.where(ok, solve_u(b), jnp.nan)), factor


def _cho_apply(L, b):
    """``A^{-1} b`` from the lower Cholesky factor L of A (b: a vector)."""
    y = jax.lax.linalg.triangular_solve(L, b[:, None], left_side=True, lower=True)
    return jax.lax.linalg.triangular_solve(L, y, left_side=True, lower=True, transpose_a=True)[:, 0]


def _solve_articulated(model, state, t, tau, gdd_p):
    """Eq. (1) by the blocked articulated-body recursion of :mod:`jaxtree._src.equations.articulated` (the
    state completed with its prescribed hinges, their accelerations `gdd_p`)."""
    dtype = dtype_of(model, state.gamma, state.gamma_dot, state.omega0)
    gamma, gamma_dot = jnp.asarray(state.gamma, dtype), jnp.asarray(state.gamma_dot, dtype)
    state = State(jnp.asarray(state.dcm, dtype), jnp.asarray(state.omega0, dtype), gamma, gamma_dot)
    cfg, omega = configuration_and_rates(model, gamma, state.omega0, gamma_dot)
    torque = hinge_torques(model, gamma, gamma_dot)
    if tau is not None:
        torque = torque + tau
    loads = external_loads(model, t, state, cfg)
    w_dot, gdd, hold = articulated.solve(
        model, cfg, omega, mass_center_velocities(model, cfg, omega), gamma_dot, torque, loads, gdd_p
    )
    return Accelerations(w_dot, gdd, hold)


def cholesky_solve(A, b):
    """Solve ``A x = b`` for the symmetric positive definite matrix of Eq. (1) (Cholesky).

    The factorization is of ``A`` bordered by ``b`` and a huge corner, ``[[A, b], [b^T, c]]``:
    its last row is ``(L^{-1} b)^T``, so LAPACK's ``potrf`` does the forward substitution and
    one triangular solve with ``L^T`` remains (two library calls instead of three; one right
    side of fig4 3 % faster, vmapped chain50 10 %). ``c`` only has to exceed
    ``b^T A^{-1} b``; a singular ``A`` still fails the factorization (NaN)."""
    n = A.shape[0]
    big = jnp.asarray(np.finfo(np.dtype(A.dtype)).max / 16, A.dtype)
    M = jnp.concatenate([jnp.concatenate([A, b[:, None]], 1), jnp.concatenate([b, big[None]])[None, :]], 0)
    L = jax.lax.linalg.cholesky(M, symmetrize_input=False)
    y = L[n, :n]  # = L_A^{-1} b: the bordered factorization does the forward substitution
    x = jax.lax.linalg.triangular_solve(L[:n, :n], y[:, None], left_side=True, lower=True, transpose_a=True)[:, 0]
    return jnp.where(_regular(L[:n, :n], A), x, jnp.nan)
