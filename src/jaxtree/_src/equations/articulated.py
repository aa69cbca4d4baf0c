"""Eq. (1) solved by a blocked articulated-body recursion over the tree's substructures.

The dense solve (:mod:`jaxtree._src.equations.dynamics`) assembles the (n+3)-square matrix of Eq. (1) and factors
it: n^2 assembly and n^3/3 factorization, right for small trees. This module solves *the same
equations* by exploiting the tree: independent subtrees and deep chains. It is the
spatial-operator (articulated-body) factorization that grew out of this line of work at JPL,
applied to substructures ("blocks") instead of single bodies, so that the work inside a block is
dense and vectorized over all blocks, and only the few levels of the block tree are sequential.

**Formulation.** Body 0 carries six unknowns, its angular acceleration ``omega0_dot`` and the
inertial acceleration of the point fixed to it at the system mass center; the translation of the
mass center then separates (Eq. 2) and the hinge accelerations and ``omega0_dot`` are those of
Eq. (1) (Sec. II A: Eq. 1 is the rotational part of the same Newton-Euler equations). Every
spatial quantity is taken about one point O, the system mass center at this instant, in {b^0}
components, so no transformation is needed between bodies (the shifts of Defs. 37-40 are inside
the inertias about O):

- motion of hinge k: ``S_k = (g^k, h_k x g^k)`` (``h_k`` the hinge point from O);
- spatial velocity of body k: ``v_k = (omega^k, u_k)``, ``u_k`` the velocity of the point of
  b_k at O, relative to the system mass center (an inertial frame moving with it);
- inertia of body k about O: ``M_k = [[J_k^O, m_k rho_k~], [-m_k rho_k~, m_k U]]`` (``rho_k``
  its mass center from O, ``J_k^O`` its inertia about O: the dyadics of Def. 38);
- spatial acceleration ``a_k = a_0 + sum_r epsilon_rk (S_r gamma_ddot_r + c_r)``, with the
  velocity-product term ``c_r = v_{N_r} x S_r gamma_dot_r`` (the products of Def. 41; for a
  prescribed hinge also ``S_r gamma_ddot_r``);
- the equations: ``S_k . sum_{i outboard of k} (M_i a_i + b_i) = tau_k`` for each hinge, and
  ``sum_i (M_i a_i + b_i) = 0`` for body 0, with the bias wrench
  ``b_i = v_i x* (M_i v_i) - f_i`` (``f_i`` the external force and its moment about O).

They are the stationarity conditions of Gauss's function
``Z = sum_i (a_i . M_i a_i / 2 + a_i . b_i) - sum_k tau_k gamma_ddot_k``.

**Blocks.** The tree is cut into blocks (:func:`plan`): connected sets of hinges, each hanging
from one parent body, whose child blocks all hang from one body of it, its *port*. Minimizing Z
over a block's accelerations for a given acceleration ``a`` of its parent leaves a quadratic
``(a, 1) . P (a, 1) / 2`` (P: 7 x 7, its articulated inertia and bias force, homogeneous in the
last coordinate). With the block's joint-space matrix ``A`` (dense, its own hinges only), the
coupling ``K`` to the parent's acceleration, its composite inertia and bias ``C``, the map
``N = [L, X]`` from its accelerations and the parent's to the port's acceleration, and the
articulated inertia ``P_out`` of its child blocks (summed at the port), Z restricted to the block
and everything outboard of it is the quadratic form of

    M = [[A, K], [K^T, C]] + N^T P_out N

in ``(gamma_ddot, a, 1)``. Eliminating the b hinge accelerations (:func:`jaxtree._src.numerics.eliminate`:
b Gauss-Jordan rank-one updates, the blocks of one level at once, no LAPACK call) leaves the
Schur complement ``P = M22 - M21 M11^{-1} M12`` for the block's parent and ``G = M11^{-1} M12``
for the way out: ``gamma_ddot = -G (a, 1)``, and the port's acceleration is
``N (gamma_ddot, a, 1)``.

The cost is O(n (b + 7)^2) for the blocks (b their size) plus a few 7 x 7 operations per block level:
linear in n for chains cut into blocks of fixed size, and one level for a hub with appendages.
:func:`jaxtree._src.equations.dynamics.solve_accelerations` uses it when ``model.method`` says so
(:func:`resolve_method`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import eliminate
from ..numerics import regular_pivots as _regular_pivots
from .kinematics import ancestor_sum, cross, dot, take_rows
from .spatial import force_cross, inertia_apply, inertia_matrix, motion_cross

METHODS = ("auto", "dense", "articulated")

# Largest number of hinges in one block. Blocks are dense inside (their factorization costs
# b^3/3), the levels of the block tree are sequential: for a chain of n hinges the cost is about
# n b^2 + (n / b) per-level costs, least near this size on CPUs (benchmarks/README.md).
DEFAULT_BLOCK = 16

# A cost model of one evaluation of Eq. (1) on a CPU, in microseconds, fitted to in-loop timings
# on this project's 2-core machine (benchmarks/bench_methods.py; chains of 25-200 segments, panels95,
# Pinocchio's humanoid, stars and deep-and-wide random trees of 40-100 bodies; 2026-11-25, FINDINGS).
# Dense: assembling the n_u x n_u matrix of Eq. (1) over the path-element masks (n_u^2) and its
# Cholesky factor (n_u^3, steeper once the matrices leave the cache: chain200 9x chain100).
# Articulated: per unknown hinge the spatial passes, per block level `size` unrolled elimination
# steps that run one after another (a level's blocks at once). Only the comparison decides; it
# picks the faster method on all ten trees measured, the closest calls being panels95 (articulated 0.89x
# dense) and chain200 (0.72x).
DENSE_COST = (12.0, 0.0125, 6.6e-5)  # us: constant, per n_u^2, per n_u^3
ARTICULATED_COST = (0.6, 2.5)  # us: per unknown hinge, per unrolled elimination step


def method_costs(model) -> dict[str, float]:
    """The modelled cost (microseconds on a CPU) of one evaluation of Eq. (1) by each method:
    ``{"dense": ..., "articulated": ...}`` (see :data:`DENSE_COST`, :data:`ARTICULATED_COST`)."""
    n = len(model.unknown_hinges)
    c0, c2, c3 = DENSE_COST
    per_hinge, per_step = ARTICULATED_COST
    bp = plan(model)
    return {
        "dense": c0 + c2 * n**2 + c3 * n**3,
        "articulated": per_hinge * n + per_step * bp.size * len(bp.levels),
    }


def resolve_method(model) -> str:
    """The method that solves Eq. (1) for `model`: its ``method`` field, or for ``"auto"`` a static
    rule: ``"dense"`` on GPUs (batches of small dense factorizations run well there), and on CPUs
    the cheaper of the two by :func:`method_costs` (dense for small trees and for deep ones cut
    into many block levels, articulated for wide trees such as a hub with appendages and for very
    long chains)."""
    method = getattr(model, "method", "auto")
    if method != "auto":
        return method
    if not model.unknown_hinges or jax.default_backend() != "cpu":
        return "dense"
    cost = method_costs(model)
    return "articulated" if cost["articulated"] < cost["dense"] else "dense"


# ----------------------------------------------------------------------------- static plan
class BlockPlan(NamedTuple):
    """The blocks of a tree, padded to ``size`` slots each (all arrays numpy, built once).

    Per block ``j`` and slot ``a``: `hinge` (0-based hinge, or n for a padding slot), `unknown`
    (1 for an unknown of Eq. 1), `inboard` (``inboard[j, a, b] = 1`` if slot b's body is the body
    of slot a or outboard of it, within the block), `to_port` (1 for the hinges between the
    block's parent and its port). Per block: `parent` (the body it hangs from), `port` (the body
    its child blocks hang from, or -1), `levels` (block indices by depth in the block tree,
    level 1 first: level 0 is body 0), `children` (child blocks of each block; of body 0 in
    `root_children`), `parent_block` (the block each block hangs from, -1 for body 0).
    """

    size: int
    hinge: np.ndarray
    unknown: np.ndarray
    inboard: np.ndarray
    to_port: np.ndarray
    parent: np.ndarray
    port: np.ndarray
    levels: tuple
    children: tuple
    root_children: tuple
    parent_block: tuple


def plan(model, block: int | None = None) -> BlockPlan:
    """The blocks of `model`'s tree (static; cached on the model's structure), at most `block`
    hinges each where the tree allows (default :data:`DEFAULT_BLOCK`)."""
    size: int = block if block is not None else (getattr(model, "block_size", 0) or DEFAULT_BLOCK)
    return _plan(model.topology, tuple(model.massive), tuple(model.unknown_hinges), tuple(model.inert), int(size))


def _blocks(topology, massive, inert, block) -> list[tuple]:
    """The tree cut into blocks of at most `block` hinges where it allows, grown outward from body 0, inert
    hinges left out: per block its members (sorted bodies = hinges), the body it hangs from, its port (the
    body its child blocks hang from, or -1: a massless branch body is never a port) and its parent block
    (or -1 for body 0)."""
    n = topology.n
    inert = set(inert)
    children = [[c for c in ch if c not in inert] for ch in topology.children]
    heavy = np.zeros(n + 1, bool)
    heavy[list(massive)] = True
    size = np.zeros(n + 1, np.int64)  # hinges in the subtree of body k (k included), inert ones left out
    for k in range(n, 0, -1):
        if k not in inert:
            size[k] += 1
            size[topology.parents[k - 1]] += size[k]

    def subtree(k):
        out, stack = [], [k]
        while stack:
            b = stack.pop()
            out.append(b)
            stack.extend(children[b])
        return sorted(out)

    blocks = []  # (members (sorted bodies = hinges), parent body, port or -1, parent block or -1)

    def grow(root, parent_block):
        members, cur = [], root
        while True:
            budget = block - len(members)
            if size[cur] <= budget or not children[cur]:
                members += subtree(cur)
                port = -1
                break
            members.append(cur)
            if len(children[cur]) == 1 and (len(members) < block or not heavy[cur]):
                cur = children[cur][0]  # continue along a chain (past massless bodies always)
                continue
            if not heavy[cur]:
                # a massless branch body cannot be a port (the block's matrix would be singular):
                # take its whole subtree into this block
                for c in children[cur]:
                    members += subtree(c)
                port = -1
                break
            port = cur
            break
        j = len(blocks)
        blocks.append((tuple(sorted(members)), topology.parents[root - 1], port, parent_block))
        if port >= 0:
            for c in children[port]:
                grow(c, j)

    for c in children[0]:
        grow(c, -1)
    return blocks


def _slots(blocks, n, b, unknown, eps):
    """The per-slot arrays of :class:`BlockPlan` for `blocks` padded to `b` slots: `hinge` (n for padding),
    `unknown`, `inboard` and `to_port`, from the set of unknown hinges and the path elements `eps` of Def. 27
    (``eps[s-1, k] = 1`` iff hinge s lies between b_0 and b_k)."""
    m = len(blocks)
    hinge = np.full((m, b), n, np.int64)
    unk = np.zeros((m, b))
    inboard = np.zeros((m, b, b))
    to_port = np.zeros((m, b))
    for j, (members, _par, port, _) in enumerate(blocks):
        for a, k in enumerate(members):
            hinge[j, a] = k - 1
            unk[j, a] = 1.0 if k in unknown else 0.0
            if port >= 0 and eps[k - 1, port]:
                to_port[j, a] = 1.0
            for c, k2 in enumerate(members):
                if eps[k - 1, k2]:
                    inboard[j, a, c] = 1.0
    return hinge, unk, inboard, to_port


@functools.lru_cache(maxsize=64)
def _plan(topology, massive, unknown, inert, block):
    n = topology.n
    blocks = _blocks(topology, massive, inert, block)
    m = len(blocks)
    b = max((len(x[0]) for x in blocks), default=1)
    eps = topology.path_elements  # eps[s-1, k]
    hinge, unk, inboard, to_port = _slots(blocks, n, b, set(unknown), eps)
    depth = []
    for _members, _par, _port, pb in blocks:
        depth.append(1 if pb < 0 else depth[pb] + 1)
    levels = tuple(tuple(j for j in range(m) if depth[j] == d) for d in range(1, max(depth, default=0) + 1))
    kids = tuple(tuple(j2 for j2 in range(m) if blocks[j2][3] == j) for j in range(m))
    root_children = tuple(j for j in range(m) if blocks[j][3] < 0)
    return BlockPlan(
        size=b,
        hinge=hinge,
        unknown=unk,
        inboard=inboard,
        to_port=to_port,
        parent=np.asarray([x[1] for x in blocks], np.int64),
        port=np.asarray([x[2] for x in blocks], np.int64),
        levels=levels,
        children=kids,
        root_children=root_children,
        parent_block=tuple(x[3] for x in blocks),
    )


# ----------------------------------------------------------------------------- the solve
def solve(model, cfg, omega, vel, gamma_dot, tau, loads, prescribed_acc=None):
    """Accelerations of Eq. (1) by the blocked articulated recursion.

    **Arguments:** the configuration `cfg` and body angular velocities `omega` of
    :func:`jaxtree._src.equations.dynamics.configuration_and_rates`, the mass-center velocities `vel` relative to the
    system mass center, `gamma_dot` (n,), the hinge torques `tau` (n,), the external `loads`
    ``(bodies, force, torque)`` in {b^0} components or None, and the accelerations of the
    prescribed hinges (in ``model.prescribed`` order) or None.

    **Returns:** ``(omega0_dot (3,), gamma_ddot (n,), hold_torque)``: the unknown hinges solved,
    prescribed hinges from `prescribed_acc`, inert hinges zero, and the torques that hold the
    prescribed hinges (as :func:`jaxtree.solve_accelerations`).
    """
    bp = plan(model)
    body = _body_terms(model, cfg, omega, vel, gamma_dot, loads, prescribed_acc)
    blocks = _block_systems(bp, cfg, body, tau)
    gains, a0, ok = _inward(bp, blocks, body)
    gdd = _outward(model.n, bp, blocks, gains, a0)
    gdd, a0 = jnp.where(ok, gdd, jnp.nan), jnp.where(ok, a0, jnp.nan)
    if prescribed_acc is None:
        return a0[:3], gdd, jnp.zeros((0,), gdd.dtype)
    gdd = gdd.at[np.asarray(model.prescribed, np.int64) - 1].set(prescribed_acc)
    return a0[:3], gdd, _holding_torques(model, body, tau, a0, gdd)


class _Bodies(NamedTuple):
    """Per body, about the system mass center O: the velocity-product accelerations `cbar` (n+1, 6)
    of the hinges' rates (and prescribed accelerations), inertia `J`, first moment `h`, `mass`,
    bias wrench (`bw`, `bu`), ``W = M cbar + b`` and the columns summed over blocks; the hinges'
    motions (`Sw`, `Su`)."""

    cbar: jax.Array
    J: jax.Array
    h: jax.Array
    mass: jax.Array
    bw: jax.Array
    bu: jax.Array
    W: jax.Array
    cols: jax.Array
    Sw: jax.Array
    Su: jax.Array


def _body_terms(model, cfg, omega, vel, gamma_dot, loads, prescribed_acc):
    """The bodies' spatial inertias and bias wrenches about O and the hinges' motions (:class:`_Bodies`)."""
    n = model.n
    dtype = cfg.rho.dtype
    par = np.asarray(model.topology.parents, np.int64)
    # spatial velocities about O, motion of the hinges, velocity-product accelerations
    uO = vel + cross(cfg.rho, omega)  # velocity of the point of b_k at O
    Sw, Su = cfg.axis, cross(cfg.hinge, cfg.axis)
    cw, cu = motion_cross(take_rows(omega, par), take_rows(uO, par), Sw * gamma_dot[:, None], Su * gamma_dot[:, None])
    if prescribed_acc is not None:
        p = np.asarray(model.prescribed, np.int64) - 1
        cw = cw.at[p].add(Sw[p] * prescribed_acc[:, None])
        cu = cu.at[p].add(Su[p] * prescribed_acc[:, None])
    cbar = ancestor_sum(
        model.topology, jnp.concatenate([jnp.zeros((1, 6), dtype), jnp.concatenate([cw, cu], 1)], 0)
    )  # (n+1, 6)
    # inertias about O and bias wrenches of the bodies (zero rows for massless bodies)
    mass = model.mass.astype(dtype)
    idx = np.asarray(model.massive, np.int64)
    rho = cfg.rho
    eye = jnp.eye(3, dtype=dtype)
    Jm = cfg.inertia + mass[idx, None, None] * (
        dot(rho[idx], rho[idx])[:, None, None] * eye - rho[idx, :, None] * rho[idx, None, :]
    )
    J = jnp.zeros((n + 1, 3, 3), dtype).at[idx].set(Jm) if len(idx) < n + 1 else Jm
    h = mass[:, None] * rho
    Lw, Lu = inertia_apply(J, h, mass, omega, uO)  # momentum about O
    bw, bu = force_cross(omega, uO, Lw, Lu)
    if loads is not None:
        lb, F, T = loads
        bw = bw.at[lb].add(-(T + cross(rho[lb], F)))
        bu = bu.at[lb].add(-F)
    Mcw, Mcu = inertia_apply(J, h, mass, cbar[:, :3], cbar[:, 3:])
    W = jnp.concatenate([Mcw + bw, Mcu + bu], 1)  # M_i cbar_i + b_i
    cols = jnp.concatenate([mass[:, None], h, J.reshape(-1, 9), W], 1)  # (n+1, 19)
    return _Bodies(cbar, J, h, mass, bw, bu, W, cols, Sw, Su)


class _Blocks(NamedTuple):
    """Every block at once: ``M0 = [[A, K], [K^T, C]]`` ((m, b+7, b+7), the block's quadratic form
    in (gamma_ddot, a~)), the port map ``N = [L, X]`` and its parts, and the unknown slots."""

    M0: jax.Array
    N: jax.Array
    Lmat: jax.Array
    Xh: jax.Array
    unk: jax.Array


def _block_systems(bp, cfg, body, tau):
    """The blocks' systems (:class:`_Blocks`), all blocks in one batch."""
    n = len(tau)
    dtype = cfg.rho.dtype
    hinge = bp.hinge  # (m, b); n = padding
    b = bp.size
    pad_body = np.where(hinge < n, hinge + 1, 0)
    valid = jnp.asarray((hinge < n).astype(float), dtype)
    cols = body.cols[pad_body] * valid[..., None]  # (m, b, 19)
    inboard = jnp.asarray(bp.inboard, dtype)
    comp = jnp.einsum("jab,jbc->jac", inboard, cols)  # within-block outboard sums per slot
    cm, ch, cJ, cW = comp[..., 0], comp[..., 1:4], comp[..., 4:13].reshape(comp.shape[:2] + (3, 3)), comp[..., 13:]
    hp = np.where(hinge < n, hinge, 0)
    sw, su = body.Sw[hp] * valid[..., None], body.Su[hp] * valid[..., None]  # (m, b, 3)
    Yw, Yu = inertia_apply(cJ, ch, cm, sw, su)  # I^c S per slot
    unk = jnp.asarray(bp.unknown, dtype)
    # joint-space matrix of each block: X[a, c] = S_a . (I^c_c S_c) where a is inboard of c
    X = jnp.einsum("jai,jci->jac", sw, Yw) + jnp.einsum("jai,jci->jac", su, Yu)
    strict = bp.inboard - np.eye(b)[None]
    A = inboard * X + jnp.swapaxes(jnp.asarray(strict, dtype) * X, -1, -2)
    um = unk[..., :, None] * unk[..., None, :]
    A = A * um + jnp.eye(b, dtype=dtype) * (1.0 - unk)[..., None]  # non-unknown slots: 1 * x = 0
    # coupling to the parent's acceleration and the block's generalized bias forces
    cpar = body.cbar[bp.parent]  # (m, 6)
    Icw, Icu = inertia_apply(
        cJ, ch, cm, jnp.broadcast_to(cpar[:, None, :3], ch.shape), jnp.broadcast_to(cpar[:, None, 3:], ch.shape)
    )
    kconst = dot(sw, cW[..., :3] - Icw) + dot(su, cW[..., 3:] - Icu) - tau[hp] * valid
    K = jnp.concatenate([Yw, Yu, kconst[..., None]], -1) * unk[..., None]  # (m, b, 7)
    # the whole block: composite inertia C and bias (7 x 7, homogeneous)
    tot = jnp.sum(cols, 1)  # (m, 19)
    Cm = inertia_matrix(tot[:, 4:13].reshape(-1, 3, 3), tot[:, 1:4], tot[:, 0])  # (m, 6, 6)
    C = _homogeneous(Cm, tot[:, 13:] - jnp.einsum("jab,jb->ja", Cm, cpar))
    # Z of a block as a quadratic form in (gamma_ddot, a~): M0 = [[A, K], [K^T, C]]; the port's
    # acceleration is N (gamma_ddot, a~) with N = [L, X] (7 x (b + 7)).
    M0 = jnp.concatenate([jnp.concatenate([A, K], -1), jnp.concatenate([jnp.swapaxes(K, -1, -2), C], -1)], -2)
    tp = jnp.asarray(bp.to_port, dtype) * unk  # unknown hinges between parent and port
    Lmat = jnp.concatenate([sw * tp[..., None], su * tp[..., None], jnp.zeros_like(tp)[..., None]], -1)  # (m, b, 7)
    dport = body.cbar[np.where(bp.port >= 0, bp.port, 0)] - cpar  # bias of the port relative to the parent
    Xh = _homogeneous(jnp.broadcast_to(jnp.eye(6, dtype=dtype), Cm.shape), dport, corner=1.0, lower=False)
    N = jnp.concatenate([jnp.swapaxes(Lmat, -1, -2), Xh], -1)  # (m, 7, b + 7)
    return _Blocks(M0, N, Lmat, Xh, unk)


def _inward(bp, blocks, body):
    """The inward pass over block levels: ``(G (m, b, 7), a0 (7,), ok)``.

    Minimizing Z over gamma_ddot is a Schur complement: eliminating the block's b hinge
    accelerations from M = [[A, K], [K^T, C]] leaves the articulated inertia of the block,
    P = C - K^T A^{-1} K, and G = A^{-1} K for the outward pass (numerics.eliminate: no LAPACK
    call, whose batched CPU kernels can deadlock XLA's thread pool)."""
    b = bp.size
    M0, N = blocks.M0, blocks.N
    m = len(bp.parent)
    P = [None] * m
    gains: list = [None] * m  # G of every block, filled level by level below
    ok = jnp.asarray(True)  # no pivot at round-off level (see jaxtree.dynamics.SINGULAR_PIVOT)
    leaves = np.asarray([j for j in range(m) if not bp.children[j]], np.int64)
    if len(leaves):
        Gl, Pl, piv = eliminate(M0[leaves], b)
        ok = _regular_pivots(piv, M0[leaves])
        for i, j in enumerate(leaves):
            P[j], gains[j] = Pl[i], Gl[i]
    for level in reversed(bp.levels):
        ported = np.asarray([j for j in level if bp.children[j]], np.int64)
        if not len(ported):
            continue
        Pout = jnp.stack([sum(P[c] for c in bp.children[j]) for j in ported])
        Nl = N[ported]
        Mp = M0[ported] + jnp.einsum("jia,jik,jkb->jab", Nl, Pout, Nl)
        Gp, Pp, piv = eliminate(Mp, b)
        ok = ok & _regular_pivots(piv, Mp)
        for i, j in enumerate(ported):
            P[j], gains[j] = Pp[i], Gp[i]
    # body 0: its own inertia and bias, and the articulated inertias of the blocks on it
    P0 = _homogeneous(inertia_matrix(body.J[0], body.h[0], body.mass[0]), body.W[0]) + sum(
        P[c] for c in bp.root_children
    )
    G0, _, piv0 = eliminate(P0, 6)
    ok = ok & _regular_pivots(piv0, P0)
    return jnp.stack(gains), -G0[:, 0], ok


def _outward(n, bp, blocks, G, a0):
    """The outward pass: the hinge accelerations (n,) in hinge order from the gains `G` and the
    base's acceleration `a0`; ``gamma_ddot = -M11^{-1} M12 a~ = -G a~``, and the port's
    acceleration is ``N (gamma_ddot, a~)``."""
    dtype = a0.dtype
    m = len(bp.parent)
    ported = [j for j in range(m) if bp.children[j]]
    T = {}
    if ported:
        pa = np.asarray(ported, np.int64)
        Tp = blocks.Xh[pa] - jnp.einsum("jai,jak->jik", blocks.Lmat[pa], G[pa])  # port acceleration = T a~
        T = {j: Tp[i] for i, j in enumerate(ported)}
    base = jnp.concatenate([a0, jnp.ones((1,), dtype)])
    at: list = [None] * m  # homogeneous acceleration of each block's parent
    for level in bp.levels:
        inner = [j for j in level if bp.parent_block[j] >= 0]
        if inner:
            pbs = [bp.parent_block[j] for j in inner]
            acc = jnp.einsum("jik,jk->ji", jnp.stack([T[pb] for pb in pbs]), jnp.stack([at[pb] for pb in pbs]))
            for i, j in enumerate(inner):
                at[j] = acc[i]
        for j in level:
            if bp.parent_block[j] < 0:
                at[j] = base
    atp = jnp.stack(at)
    qdd = -jnp.einsum("jak,jk->ja", G, atp) * blocks.unk
    # the block slots back in hinge order (a static permutation; padding slots dropped)
    flat = bp.hinge.reshape(-1)
    order = np.full(n, flat.size, np.int64)
    order[flat[flat < n]] = np.flatnonzero(flat < n)
    return jnp.concatenate([qdd.reshape(-1), jnp.zeros((1,), dtype)])[order]


def _holding_torques(model, body, tau, a0, gdd):
    """Torques that hold the prescribed hinges: ``S_k . sum_{i outboard of k} (M_i a_i + b_i) - tau_k``."""
    dtype = gdd.dtype
    pk = np.asarray(model.prescribed, np.int64)
    Sw, Su = body.Sw, body.Su
    rates = jnp.concatenate([jnp.zeros((1, 6), dtype), jnp.concatenate([Sw, Su], 1) * gdd[:, None]], 0)
    rates = rates.at[pk].set(0.0)  # the prescribed accelerations are in cbar already
    acc = a0[None, :] + body.cbar + ancestor_sum(model.topology, rates)
    fw, fu = inertia_apply(body.J, body.h, body.mass, acc[:, :3], acc[:, 3:])
    f = jnp.concatenate([fw + body.bw, fu + body.bu], 1)
    out = jnp.tensordot(jnp.asarray(model.topology.descendants[pk], dtype), f, axes=1)
    return dot(Sw[pk - 1], out[:, :3]) + dot(Su[pk - 1], out[:, 3:]) - tau[pk - 1]


def _homogeneous(M, v, corner=0.0, lower=True):
    """``[[M, v], [v^T, corner]]`` (lower=True) or ``[[M, v], [0, corner]]`` for stacks."""
    col = v[..., :, None]
    row = v[..., None, :] if lower else jnp.zeros_like(v)[..., None, :]
    c = jnp.full(v.shape[:-1] + (1, 1), corner, v.dtype)
    return jnp.concatenate([jnp.concatenate([M, col], -1), jnp.concatenate([row, c], -1)], -2)
