"""Eq. (1) for a batch of members: an articulated-body recursion with the batch as the last axis.

A single call of Eq. (1) pays XLA:CPU's cost per kernel, which is why :mod:`.dynamics` (one dense
matrix) and :mod:`.articulated` (blocks of hinges eliminated densely) use few, large kernels. In
a batch one kernel serves every member and the flops and bytes decide: this module solves the
same equations by the articulated-body recursion, a few hundred flops per body, with every array
laid out as ``(components..., bodies of one level, members)`` so that XLA's fused loops run along
the contiguous members.

**Formulation** (the same as :mod:`.articulated` with one hinge per block). Every spatial
quantity is taken about O, the mass center of b_0 at this instant, in {b^0} components; the
velocity of the point of b_0 at O is taken as zero, i.e. velocities are relative to the inertial
frame that moves with it (a uniform velocity of every body changes no acceleration, so the
hinge accelerations and ``omega0_dot`` are those of Eq. (1); the translation of the mass center
separates, Eq. 2). With ``S_k = (g^k, h_k x g^k)`` the motion of hinge k (``h_k`` its hinge
point from O), ``M_k`` the rigid-body inertia of b_k about O, ``v_k`` its spatial velocity,
``c_k = v_{N_k} x S_k gamma_dot_k`` the velocity-product acceleration of Def. 41 and
``p_k = v_k x* (M_k v_k) - f_k`` its bias force (``f_k`` the external force and its moment
about O):

- outward, level by level: rotations ``C^{0k}``, hinge points, mass centers, velocities, ``c_k``;
- inward: the articulated inertia ``I^A_k = M_k + sum (children's I^a)`` and bias force
  ``p^A_k``; for an unknown hinge ``U = I^A S``, ``D = S . U``, ``u = tau - S . p^A``,
  ``I^a = I^A - U U^T / D``, ``p^a = p^A + I^a c + U u / D``; for a prescribed or inert hinge
  (locked to its given acceleration) ``I^a = I^A``, ``p^a = p^A + I^A (c + S gamma_ddot)``;
- b_0: ``I^A_0 a_0 = -p^A_0`` (6 x 6), ``omega0_dot`` the angular part of ``a_0``;
- outward: ``a_k = a_{N_k} + c_k``, ``gamma_ddot_k = (u - U . a_k) / D``, ``a_k += S gamma_ddot_k``;
  the holding torque of a prescribed hinge ``S . (I^A a_k + p^A) - tau_k``.

Each level is a few batched operations over its bodies and all members (static gathers between
neighbouring levels, none where a level continues chains slot for slot); runs of such chained
levels are one ``lax.scan``, so compile time follows the number of distinct levels, not the depth.
Symmetric 6 x 6 inertias are kept as their 21 entries, vectors as tuples of component arrays.

**What XLA:CPU needs** (measured, ``benchmarks/FINDINGS.md``): XLA fuses an elementwise producer
into every consumer and recomputes it there, so the recursion is cut into *stages* whose results
are buffers (:func:`_stages`: an ``optimization_barrier`` on each stage's results); a
concatenation of more than 8 operands is not fused, so a stage returns chunks of at most 8
components (:func:`stacked`). Without the stages flex95 cost 1.1 Mflop a member (the rotations
recomputed ~120 times), with them ~50 k.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import SINGULAR_PIVOT
from .components import (
    PAIRS,
    add,
    body_inertia,
    components_of,
    cos_sin,
    cross,
    ldl6,
    ldl6_solve,
    mm,
    mv,
    scale,
    split_stacked,
    stacked,
    sym_apply,
    total,
)

# ----------------------------------------------------------------------------- static plan


class _Level(NamedTuple):
    bodies: np.ndarray  # bodies of this level, in slot order
    parent_slot: np.ndarray  # slot of each body's parent in the level before
    locked: np.ndarray  # bool: prescribed or inert hinge (its acceleration given)
    chained: bool  # parent_slot == arange and the levels have one width: no gather
    children: np.ndarray  # (width of the level before, most children): slots, or width (none)


class Plan(NamedTuple):
    levels: tuple[_Level, ...]  # levels 1..depth
    order: np.ndarray  # the bodies 1..n level by level: order[i] is the body of row i
    prescribed_rows: np.ndarray  # for each prescribed hinge (model order), its row in `order`


@functools.lru_cache(maxsize=64)
def plan(parents: tuple[int, ...], locked: tuple[int, ...], prescribed: tuple[int, ...]) -> Plan:
    """Levels of the tree (depth from b_0) with the slots of their bodies, arranged so that a
    body continues the slot of its parent where it can (chains: no gathers between levels)."""
    n = len(parents)
    par = np.asarray((-1,) + tuple(parents))
    depth = np.zeros(n + 1, np.int64)
    for k in range(1, n + 1):
        depth[k] = depth[par[k]] + 1
    slot = np.zeros(n + 1, np.int64)
    prev = np.array([0])
    levels = []
    for d in range(1, int(depth.max(initial=0)) + 1):
        bodies = np.flatnonzero(depth == d)
        # first children (one per parent) in their parent's slot order, then the others
        first, rest, seen = {}, [], set()
        for k in bodies:
            if par[k] not in seen:
                seen.add(par[k])
                first[slot[par[k]]] = k
            else:
                rest.append(k)
        ordered = [first[s] for s in sorted(first)] + rest
        bodies = np.asarray(ordered, np.int64)
        slot[bodies] = np.arange(len(bodies))
        pslot = slot[par[bodies]]
        chained = len(bodies) == len(prev) and bool(np.all(pslot == np.arange(len(bodies))))
        counts = np.bincount(pslot, minlength=len(prev))
        children = np.full((len(prev), int(counts.max())), len(bodies), np.int64)
        fill = np.zeros(len(prev), np.int64)
        for i, p in enumerate(pslot):
            children[p, fill[p]] = i
            fill[p] += 1
        lock = np.isin(bodies, np.asarray(locked, np.int64))
        levels.append(_Level(bodies, pslot, lock, chained, children))
        prev = bodies
    order = np.concatenate([lv.bodies for lv in levels]) if levels else np.zeros(0, np.int64)
    row = np.zeros(n + 1, np.int64)
    row[order] = np.arange(len(order))
    return Plan(tuple(levels), order, row[np.asarray(prescribed, np.int64)])


# ----------------------------------------------------------------------------- the recursion


class Inputs(NamedTuple):
    """Arrays of one batch, rows in plan order (``plan.order`` for the bodies 1..n), members
    last: `mass` (n+1, B), `inertia` (6 entries i <= j of 3 x 3, each (n+1, B)), `axis`,
    `hinge_on_parent`, `hinge_on_body` (3, each (n, B)), `omega0` (3 of (1, B)), `gamma`,
    `gamma_dot`, `tau`, `gdd` (each (n, B); gdd the given accelerations of locked hinges, zero
    elsewhere), `force`, `torque` (3 of (n+1, B), body frames) or None. B may be 1 for
    constants."""

    mass: Any
    inertia: Any
    axis: Any
    hinge_on_parent: Any
    hinge_on_body: Any
    omega0: Any
    gamma: Any
    gamma_dot: Any
    tau: Any
    gdd: Any
    force: Any
    torque: Any


def _stages(mode: str):
    """``stage(fn, *args)``: ``fn(*args)`` (a pytree of arrays) computed as one unit whose results
    are buffers.

    XLA:CPU fuses an elementwise producer into each of its consumers and recomputes it there:
    written as one expression, a level's rotations were recomputed by each of the dozens of
    entries that read them (flex95: 1.1 Mflop a member instead of ~100 k). `mode` "barrier" puts
    an ``optimization_barrier`` on a stage's results; "none" leaves fusion to the compiler (see
    :func:`default_stages`). A stage returns few stacked arrays (components leading): one loop
    each, not one per component."""
    if mode == "none":
        return lambda fn, *args: fn(*args)
    if mode == "barrier":
        return lambda fn, *args: jax.lax.optimization_barrier(fn(*args))
    raise ValueError(f"batched.solve: stages must be 'barrier' or 'none', got {mode!r}")


def default_stages() -> str:
    """How the recursion is cut into stages on JAX's default backend: "barrier" on a CPU, "none"
    elsewhere. The rule from measurements (benchmarks/FINDINGS.md, "Stages by barrier, not by
    conditional" and "bench_gpu.py on an NVIDIA H200"): on XLA:CPU the barriers keep the stages'
    results from being recomputed by every consumer; XLA:GPU's fusion does not recompute them, and
    there the barriers cost a factor of two. Stages as conditionals lost on both and were removed."""
    return "barrier" if jax.default_backend() == "cpu" else "none"


def _gather_rows(a, lv: _Level, parent_width):
    """Rows of the parent level's stacked array `a` (k, width, B) for the bodies of level `lv`."""
    if lv.chained or parent_width == 1 and len(lv.bodies) == 1:
        return a
    if isinstance(a, tuple):
        return tuple(_gather_rows(c, lv, parent_width) for c in a)
    return a[:, lv.parent_slot]


def _sum_children(a, lv: _Level):
    """Sums over the children of each slot of the level before, of level `lv`'s stacked (k, w, B)."""
    if lv.chained:
        return a
    if isinstance(a, tuple):
        return tuple(_sum_children(c, lv) for c in a)
    pad = jnp.concatenate([a, jnp.zeros(a.shape[:1] + (1,) + a.shape[2:], a.dtype)], 1)
    g = pad[:, lv.children]  # (k, parent width, most children, B)
    return jnp.sum(g, 2) if g.shape[2] > 1 else g[:, :, 0]


def _rotation(co, si, g):
    """``C^{N_k k}`` (transpose of Eq. 4's ``C^{k N_k}``): ``cos U + sin g~ + (1 - cos) g g^T``."""
    one_c = 1.0 - co
    sk = ((None, -g[2], g[1]), (g[2], None, -g[0]), (-g[1], g[0], None))
    return tuple(tuple(one_c * g[i] * g[j] + (co if i == j else si * sk[i][j]) for j in range(3)) for i in range(3))


def _level_kinematics(K_prev, co_si, g, hp, hb, gd, first):
    """Stage of one level, outward: ``(R (9), c (3), w (3), v (3))`` of its bodies and
    ``(S (6), c_k (6))``, from its parents' `K_prev` (same layout; for b_0 without R)."""
    if first:
        (cp, wp, vp) = split_stacked(K_prev, (3, 3, 3))
        Rp = None
    else:
        R9, cp, wp, vp = split_stacked(K_prev, (9, 3, 3, 3))
        Rp = (R9[0:3], R9[3:6], R9[6:9])
    E = _rotation(co_si[0], co_si[1], g)
    R = E if Rp is None else mm(Rp, E)
    gw = g if Rp is None else mv(Rp, g)
    h = add(cp, hp if Rp is None else mv(Rp, hp))
    c = tuple(a - b for a, b in zip(h, mv(R, hb)))
    sL = cross(h, gw)
    sw, sl = scale(gw, gd), scale(sL, gd)
    w, v = add(wp, sw), add(vp, sl)
    cb = cross(wp, sw) + add(cross(wp, sl), cross(vp, sw))
    R9 = R[0] + R[1] + R[2]
    return stacked(R9, c, w, v), stacked(gw + sL, cb)


def _rigid_inertia(R9, c, m, Jb):
    """Stage: the rigid-body inertias about O (21 entries) of a level's bodies."""
    if R9 is None:
        J = Jb
    else:
        R = (R9[0:3], R9[3:6], R9[6:9])
        Jfull = tuple(tuple(Jb[(min(i, j), max(i, j))] for j in range(3)) for i in range(3))
        RJ = mm(R, Jfull)
        J = {
            (i, j): RJ[i][0] * R[j][0] + RJ[i][1] * R[j][1] + RJ[i][2] * R[j][2] for i in range(3) for j in range(i, 3)
        }
    M = body_inertia(m, J, c)
    return stacked(tuple(M[k] for k in PAIRS))


def _bias(M21, c, w, v, F, T, R9):
    """Stage: the bias force ``p = v x* (M v) - f`` (6) of a level's bodies, ``f`` the external
    force F at the mass center c and torque T (body frames, or None) as a wrench about O."""
    M = dict(zip(PAIRS, M21))
    h = sym_apply(M, w + v)
    pA = add(cross(w, h[:3]), cross(v, h[3:]))
    pL = cross(w, h[3:])
    if F is not None:
        if R9 is not None:
            R = (R9[0:3], R9[3:6], R9[6:9])
            F, T = mv(R, F), mv(R, T)
        pA = tuple(a - b for a, b in zip(pA, add(T, cross(c, F))))
        pL = tuple(a - b for a, b in zip(pL, F))
    return stacked(pA, pL)


def _articulate(M21, p, carry, S, tau, free):
    """Stage, inward: ``I^A`` (21), ``p^A`` (6), ``U = I^A S`` (6), ``1/D`` (1) and ``u`` (1) of a
    level's bodies from their own inertia and bias and their children's sums `carry` (27 or None).
    `free`: None when every hinge of the level is unknown, else its 0/1 mask (1/D = 0 where locked)."""
    if carry is None:
        IA, pA = M21, p
    else:
        IA = tuple(M21[i] + carry[i] for i in range(21))
        pA = tuple(p[i] + carry[21 + i] for i in range(6))
    M = dict(zip(PAIRS, IA))
    U = sym_apply(M, S)
    D = total([S[i] * U[i] for i in range(6)])
    # the pivot D against the scale of I^A along S (its diagonal): at round-off level the hinge
    # is singular (gimbal lock) and the member's accelerations are NaN, as the dense solve's
    scale = total([S[i] * S[i] * M[(i, i)] for i in range(6)])
    tol = SINGULAR_PIVOT * float(np.sqrt(6.0)) * float(jnp.finfo(jnp.result_type(D)).eps)
    Dinv = jnp.where(D > tol * scale, 1.0 / D, jnp.nan)
    if free is not None:
        Dinv = jnp.where(free > 0, Dinv, 0.0)
    u = tau - total([S[i] * pA[i] for i in range(6)])
    return stacked(U, (Dinv, u), IA, pA)


def _articulated(IA, pA, U, Dinv, u, S, cb, gdd, free, all_locked):
    """Stage, inward: what a level's bodies pass to their parents, ``(I^a (21), p^a (6))``."""
    if all_locked:
        Ia = IA
        acc = tuple(cb[i] + S[i] * gdd for i in range(6))
        pa = add(pA, sym_apply(dict(zip(PAIRS, Ia)), acc))
        return stacked(Ia, pa)
    Ia = tuple(IA[k] - U[i] * U[j] * Dinv for k, (i, j) in enumerate(PAIRS))
    acc = cb if free is None else tuple(cb[i] + S[i] * gdd * (1.0 - free) for i in range(6))
    pa = add(tuple(pA[i] + u * Dinv * U[i] for i in range(6)), sym_apply(dict(zip(PAIRS, Ia)), acc))
    return stacked(Ia, pa)


def _accelerate(a_prev, cb, S, U, Dinv, u, gdd, free, all_locked):
    """Stage, outward: ``a`` (6) and ``gamma_ddot`` (1) of a level's bodies."""
    a = add(a_prev, cb)
    if all_locked:
        q = gdd + jnp.zeros_like(a[0])
    else:
        q = (u - total([U[i] * a[i] for i in range(6)])) * Dinv
        if free is not None:
            q = q + gdd * (1.0 - free)
    return stacked(tuple(a[i] + S[i] * q for i in range(6)), (q,))


def _hold(a, IA, pA, S, tau):
    """Stage: the holding torque ``S . (I^A a + p^A) - tau`` of a level's locked hinges."""
    f = add(sym_apply(dict(zip(PAIRS, IA)), a), pA)
    return total([S[i] * f[i] for i in range(6)]) - tau


def _hold_from(a, A, Sc, tau):
    """:func:`_hold` from the stacked results of :func:`_articulate` and the kinematics stage."""
    _, _, IA, pA = split_stacked(A, (6, 2, 21, 6))
    (S,) = split_stacked(Sc, (6,))
    return _hold(a, IA, pA, S, tau)


# A run of more than this many consecutive levels that continue chains slot for slot (same width,
# same locked hinges) is traversed by one ``lax.scan`` instead of unrolled: compile time then
# follows the number of distinct levels, not the depth; shorter runs are unrolled, where a scan's
# iteration costs more than it saves (the rule's measurements: benchmarks/FINDINGS.md,
# "`bench_batch.py`: Eq. (1) batch-first", step 4).
SCAN_MIN = 16


def _units(levels, scan_min: int = SCAN_MIN):
    """The levels (1-based) as units: ``("one", d)``, or ``("run", a, b)`` for levels a..b that
    each continue the level before slot for slot with the same locked hinges."""
    units, d, n = [], 1, len(levels)
    while d <= n:
        units.append(("one", d))
        b = d
        while b + 1 <= n and levels[b].chained and np.array_equal(levels[b].locked, levels[d - 1].locked):
            b += 1
        if b - d >= scan_min:
            units.append(("run", d + 1, b))
        else:
            units.extend(("one", k) for k in range(d + 1, b + 1))
        d = b + 1
    return units


def solve(pl: Plan, x: Inputs, *, stages: str | None = None, scan_min: int = SCAN_MIN):
    """``(omega0_dot (3 of (1, B)), gamma_ddot (n, B), hold (n, B), pivots (6 of (1, B)))``: rows of
    the hinges in plan order; `hold` zero but in the rows of locked hinges; `pivots` those of
    b_0's articulated inertia (LDL^T). `stages`: how the recursion is cut ("barrier" or "none";
    default :func:`default_stages`); `scan_min`: the chained levels from which a run of them is
    one ``lax.scan`` (:data:`SCAN_MIN`)."""
    with jax.named_scope("batch_first"):  # (its operations named so in profiles and jaxprs)
        return _solve(pl, x, _stages(default_stages() if stages is None else stages), scan_min)


class _Pass(NamedTuple):
    """What each level's step of the recursion reads besides its own inputs."""

    levels: tuple[_Level, ...]
    stage: Any  # :func:`_stages`
    dtype: Any


def _unit_data(x: Inputs, starts, units, stage):
    """The inputs of each unit's levels ``{unit: {field: rows}}``, a run's with a leading axis of
    levels (a scan's): every array split once at the units' first rows (one operation an array,
    not one a unit and pass)."""
    cuts = [int(starts[_span(u)[0] - 1]) for u in units[1:]]

    def pieces(arr, first=0):  # hinge rows; body rows with first = 1 (row 0: b_0)
        parts = jnp.split(arr, [first + c for c in ([0] if first else []) + cuts])[first:]
        return [
            p.reshape((_span(u)[1] - _span(u)[0] + 1, -1) + p.shape[1:]) if u[0] == "run" else p
            for u, p in zip(units, parts)
        ]

    bpieces = functools.partial(pieces, first=1)
    cs = stage(lambda q: jnp.stack(cos_sin(q)), x.gamma)  # every hinge's at once: one loop
    fields = dict(
        g=tuple(pieces(c) for c in x.axis),
        hp=tuple(pieces(c) for c in x.hinge_on_parent),
        hb=tuple(pieces(c) for c in x.hinge_on_body),
        co=pieces(cs[0]),
        si=pieces(cs[1]),
        gd=pieces(x.gamma_dot),
        tau=pieces(x.tau),
        gdd=pieces(x.gdd),
        m=bpieces(x.mass),
        J={k: bpieces(c) for k, c in x.inertia.items()},
        F=None if x.force is None else tuple(bpieces(c) for c in x.force),
        T=None if x.torque is None else tuple(bpieces(c) for c in x.torque),
    )
    pick = lambda f, i: jax.tree_util.tree_map(lambda p: p[i], f, is_leaf=lambda z: isinstance(z, list))
    return {u: {k: None if f is None else pick(f, i) for k, f in fields.items()} for i, u in enumerate(units)}


def _free(lv: _Level, dtype):
    """None when every hinge of the level is unknown, else its 0/1 mask (0 where locked)."""
    if not lv.locked.any():
        return None
    return jnp.asarray((~lv.locked).astype(np.float64), dtype)[:, None]


def _kinematics_step(ps: _Pass, d, K_prev, xd):
    """Level d outward: its kinematics `K` (the next level's input) and what the inward and
    acceleration passes read, ``(S and c, rigid inertias, bias forces)``."""
    stage, lv = ps.stage, ps.levels[d - 1]
    first, par_w = d == 1, 1 if d == 1 else len(ps.levels[d - 2].bodies)
    co_si = (xd["co"], xd["si"])
    K, Sc = stage(
        lambda K_prev, cs, g, hp, hb, gd: _level_kinematics(_gather_rows(K_prev, lv, par_w), cs, g, hp, hb, gd, first),
        *(K_prev, co_si, xd["g"], xd["hp"], xd["hb"], xd["gd"]),
    )
    R9, c, w, v = split_stacked(K, (9, 3, 3, 3))
    M = stage(_rigid_inertia, R9, c, xd["m"], xd["J"])
    p = stage(lambda M, c, w, v, F, T, R9: _bias(components_of(M), c, w, v, F, T, R9), M, c, w, v, xd["F"], xd["T"], R9)
    return K, (Sc, M, p)


def _articulate_step(ps: _Pass, d, carry, inputs):
    """Level d inward: the sums its bodies pass to their parents, and its articulated terms."""
    (Sc, M, p), xd = inputs
    stage, lv = ps.stage, ps.levels[d - 1]
    S, cb = split_stacked(Sc, (6, 6))
    free, all_locked = _free(lv, ps.dtype), bool(lv.locked.all())
    A = stage(
        lambda M, p, carry, S, tau, free: _articulate(
            components_of(M), components_of(p), None if carry is None else components_of(carry), S, tau, free
        ),
        *(M, p, carry, S, xd["tau"], free),
    )
    out = stage(
        lambda A, S, cb, gdd, free: _articulated(*_unpack(A), S, cb, gdd, free, all_locked), A, S, cb, xd["gdd"], free
    )
    return _sum_children(out, lv), A


def _accelerate_step(ps: _Pass, d, a_prev, inputs):
    """Level d outward again: its bodies' spatial accelerations, hinge accelerations and the
    holding torques of its locked hinges."""
    saved, A, xd = inputs
    stage, lv = ps.stage, ps.levels[d - 1]
    par_w = 1 if d == 1 else len(ps.levels[d - 2].bodies)
    Sc = saved[0]
    free, all_locked = _free(lv, ps.dtype), bool(lv.locked.all())
    aq = stage(
        lambda a_prev, Sc, A, gdd, free: _accelerate_from(a_prev, Sc, A, gdd, free, all_locked, lv, par_w),
        *(a_prev, Sc, A, xd["gdd"], free),
    )
    a_new, (q,) = split_stacked(aq, (6, 1))
    if lv.locked.any():
        hold = stage(_hold_from, a_new, A, Sc, xd["tau"]) * (1.0 - free if free is not None else 1.0)
    else:
        hold = jnp.zeros_like(q)
    return stacked(a_new), (q, hold)


def _solve(pl: Plan, x: Inputs, stage, scan_min: int):
    levels = pl.levels
    starts = np.cumsum([0] + [len(lv.bodies) for lv in levels])
    dtype = x.gamma.dtype
    ps = _Pass(levels, stage, dtype)

    # --- b_0
    w0 = tuple(jnp.broadcast_to(a, jnp.broadcast_shapes(*[jnp.shape(z) for z in x.omega0])) for a in x.omega0)
    zero = jnp.zeros_like(w0[0])
    z3 = (zero, zero, zero)
    J0 = {k: v[:1] for k, v in x.inertia.items()}
    M0 = split_stacked(stage(lambda m, J: _rigid_inertia(None, z3, m, J), x.mass[:1], J0), (21,))[0]
    F0 = None if x.force is None else tuple(c[:1] for c in x.force)
    T0 = None if x.torque is None else tuple(c[:1] for c in x.torque)
    p0 = split_stacked(stage(lambda M, w, F, T: _bias(M, z3, w, z3, F, T, None), M0, w0, F0, T0), (6,))[0]

    units = _units(levels, scan_min)
    data = _unit_data(x, starts, units, stage)

    def nothing_outboard(u):  # the inward carry entering the deepest levels' run
        shape = (len(levels[u[1] - 1].bodies),) + jnp.shape(x.gamma)[1:]
        return stacked(tuple(jnp.zeros((27,) + shape, dtype)))

    # --- outward: kinematics; inward: articulated inertias
    K0 = stacked(z3, w0, z3)  # (c, w, v) of b_0
    _, saved = _sweep(units, functools.partial(_kinematics_step, ps), K0, lambda u: data[u])
    art_in = lambda u: (saved[u], data[u])
    step = functools.partial(_articulate_step, ps)
    carry, art = _sweep(units, step, None, art_in, reverse=True, start=nothing_outboard)

    cs = None if carry is None else components_of(carry)
    IA0 = M0 if cs is None else tuple(M0[i] + cs[i] for i in range(21))
    pA0 = p0 if cs is None else tuple(p0[i] + cs[21 + i] for i in range(6))
    Ld = stage(ldl6, IA0)
    diag0 = tuple(IA0[PAIRS.index((i, i))] for i in range(6))
    a0 = stage(ldl6_solve, Ld, tuple(-a for a in pA0), diag0)
    pivots = split_stacked(Ld, (15, 6))[1]

    # --- outward: accelerations
    acc_in = lambda u: (saved[u], art[u], data[u])
    _, out = _sweep(units, functools.partial(_accelerate_step, ps), a0, acc_in)
    rows = [tuple(z.reshape((-1,) + z.shape[2:]) if u[0] == "run" else z for z in out[u]) for u in units]
    q_rows, hold_rows = [r[0] for r in rows], [r[1] for r in rows]
    width = jnp.shape(components_of(a0)[0])
    gdd = jnp.concatenate(q_rows, 0) if q_rows else jnp.zeros((0,) + tuple(width[1:]), dtype)
    hold = jnp.concatenate(hold_rows, 0) if hold_rows else gdd
    return split_stacked(a0, (3,))[0], gdd, hold, pivots


def _span(unit):
    """The first and last level (1-based) of a unit of :func:`_units`."""
    return (unit[1], unit[1]) if unit[0] == "one" else (unit[1], unit[2])


def _sweep(units, step, carry, inputs, reverse=False, start=None):
    """One pass of the recursion over the levels: ``carry, out = step(d, carry, inputs(u))`` for
    each unit u of :func:`_units` in order (`reverse`: from the deepest), a run of chained levels as
    one ``lax.scan`` of `step` over them (its inputs and outputs with a leading axis of levels;
    `start(u)` the carry entering a run when `carry` is still None). Returns ``(carry, {unit: out})``."""
    out = {}
    for u in reversed(units) if reverse else units:
        if u[0] == "one":
            carry, out[u] = step(u[1], carry, inputs(u))
            continue
        if carry is None:
            assert start is not None, "a run entered without a carry needs `start`"
            carry = start(u)
        carry, out[u] = jax.lax.scan(lambda c, i, d=u[1]: step(d, c, i), carry, inputs(u), reverse=reverse)
    return carry, out


def _unpack(A):
    """``(I^A, p^A, U, 1/D, u)`` of :func:`_articulate`'s stacked result."""
    U, (Dinv, u), IA, pA = split_stacked(A, (6, 2, 21, 6))
    return IA, pA, U, Dinv, u


def _accelerate_from(a_prev, Sc, A, gdd, free, all_locked, lv, par_w):
    S, cb = split_stacked(Sc, (6, 6))
    U, (Dinv, u) = split_stacked(A, (6, 2))
    return _accelerate(components_of(_gather_rows(a_prev, lv, par_w)), cb, S, U, Dinv, u, gdd, free, all_locked)


# ----------------------------------------------------------------------------- from a model


def _members_last(a, batched):
    """`a` with its member axis (0 when `batched`) moved last; a constant gains an axis of 1."""
    a = jnp.asarray(a)
    if batched:
        return jnp.moveaxis(a, 0, -1)
    return a[..., None]


def inputs(model, pl: Plan, omega0, gamma, gamma_dot, tau, gdd, loads, batched):
    """The kernel's :class:`Inputs` from one member's or a batch's arrays (`batched`: a dict of
    flags for 'mass', 'inertia', 'axis', 'hinge_on_parent', 'hinge_on_body', 'omega0', 'gamma',
    'gamma_dot', 'tau', 'gdd', 'loads'; a batched array has the members on axis 0)."""
    rows = pl.order - 1  # hinge rows in plan order
    brows = np.concatenate([[0], pl.order])
    mass = _members_last(model.mass, batched["mass"])[brows]
    I = _members_last(model.inertia, batched["inertia"])[brows]  # (n+1, 3, 3, B)
    if len(model.massive) < model.n + 1:
        # the scene's massless bodies carry no mass and no inertia, as in the single-member solve
        # (which leaves them out): their leaves are no parameters, their derivatives zero there too
        keep = np.isin(brows, np.asarray(model.massive))
        mass = jnp.where(keep[:, None], mass, 0.0)
        I = jnp.where(keep[:, None, None, None], I, 0.0)
    inertia = {(i, j): I[:, i, j] for i in range(3) for j in range(i, 3)}

    def vec(a, key):  # (n, 3) -> 3 of (n, B) in plan order
        a = _members_last(a, batched[key])[rows]
        return (a[:, 0], a[:, 1], a[:, 2])

    w0 = _members_last(omega0, batched["omega0"])
    force = torque = None
    if loads is not None:
        bodies, F, T = loads
        nb = len(brows)
        where = np.zeros(model.n + 1, np.int64)
        where[brows] = np.arange(nb)
        Fz = _members_last(F, batched["loads"])
        Tz = _members_last(T, batched["loads"])
        full = lambda a: jnp.zeros((nb,) + a.shape[1:], a.dtype).at[where[np.asarray(bodies)]].set(a)
        Fz, Tz = full(Fz), full(Tz)
        force = (Fz[:, 0], Fz[:, 1], Fz[:, 2])
        torque = (Tz[:, 0], Tz[:, 1], Tz[:, 2])
    return Inputs(
        mass,
        inertia,
        vec(model.axis, "axis"),
        vec(model.hinge_on_parent, "hinge_on_parent"),
        vec(model.hinge_on_body, "hinge_on_body"),
        (w0[0:1], w0[1:2], w0[2:3]),
        _members_last(gamma, batched["gamma"])[rows],
        _members_last(gamma_dot, batched["gamma_dot"])[rows],
        _members_last(tau, batched["tau"])[rows],
        _members_last(gdd, batched["gdd"])[rows],
        force,
        torque,
    )
