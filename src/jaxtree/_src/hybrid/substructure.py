"""Substructures of the small set and their share of Eq. (30), precomputed once in the frame of
the body they hang from (Sec. III E of Likins 1972; the design note notes/hybrid_invariants.md).

A *substructure* is a connected group of small hinges (Sec. III A: a flexible appendage, e.g. one
wing): its bodies form a subtree hanging from one large body ``b``, its *base*. When no large or
prescribed hinge lies outboard of it (a *terminal* appendage), everything about it, seen from its
base, depends on its own small angles ``y`` and rates ``y'`` and on the motion of ``b`` only.

**Its share of the equations.** Take ``b``'s frame and its mass center as reference (spatial
vectors ``(angular, linear)`` about that point, in {b} components). With ``a_b`` the spatial
acceleration of ``b`` and ``v_b`` its spatial velocity, Gauss's function of the substructure's
bodies (see :mod:`jaxtree._src.equations.articulated`) is a quadratic in ``(a_b, y'')``:

    Z_S = 1/2 [a_b; y'']^T A(y) [a_b; y''] + [a_b; y'']^T b(y, y', v_b) - tau_S . y''

- ``A(y)`` ((6 + nu) square): the substructure's spatial inertia about ``b``'s mass center
  (block ``aa``), the momenta of its hinge motions (``a y''`` blocks: the "participation
  factors") and its joint-space matrix (``y'' y''``: ``a_bar`` of Eq. 36d, constant at ``y = 0``);
- ``b(y, y', v_b)``: the velocity-product (gyroscopic, centripetal, Coriolis) terms of Def. 41,
  quadratic in ``(v_b, y')``.

Eq. (30) keeps the coefficients of the large accelerations to first order in ``y``, those of
``y''`` at ``y = 0`` and the right side to first order in ``(y, y')``. So the substructure is
summarized by the Taylor coefficients (exact, by forward-mode automatic differentiation of the
function above at the nominal angles):

    A(y) = A0 + A1 . y,      b = 1/2 G0 : v v + 1/2 (G1 . y) : v v + (G2 . y') . v,

``A0`` ((6+nu)^2), ``A1`` ((6+nu)^2 nu), ``G0`` ((6+nu) 6 6), ``G1`` ((6+nu) 6 6 nu), ``G2``
((6+nu) 6 nu); the hinge springs and dampers ``tau_S = -k (y_bar + y) - d y'`` are linear. The
terms that are second order in the small variables (``y' y'``, ``y y'``, ``y y`` products) are the
ones Eq. (30) drops. Projected on the retained modes (``y = positions s``, ``y' = rates s``), every
stored array has the size of the modes, not of the substructure: :mod:`jaxtree.hybrid` then
evaluates Eq. (1) over the large bodies only, each substructure entering through its base's
acceleration and velocity.

**Held-base modes.** With ``b`` moving on the nominal motion (``a_b`` its steady centripetal
acceleration), the small rows give ``I y'' + J y' + K y`` with ``I = A0[y'' y'']`` and ``J``,
``K`` from ``G1, G2, A1`` and the springs (:func:`held_base`): the substructure's modes on its own
held base (cantilever modes, with centrifugal stiffening and Coriolis coupling when the nominal
spins), the default basis of :func:`jaxtree.hybrid_model`.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.kinematics import ancestor_sum, body_rotations, cross, mm, mv, take_rows
from ..equations.spatial import force_cross, inertia_apply, inertia_matrix, motion_cross
from ..numerics import build_jit, is_traced
from ..vehicle.topology import Topology


class Substructure(NamedTuple):
    """A connected group of small hinges: `hinges` (ascending, 1..n), the `base` body it hangs
    from, and whether it is `terminal` (no large or prescribed hinge outboard of it)."""

    hinges: tuple
    base: int
    terminal: bool


def substructures(model, small) -> tuple[Substructure, ...]:
    """Split the set A (hinge indices) into its substructures: two small hinges belong together
    when one's body is the other's parent."""
    small = tuple(sorted(small))
    in_small = set(small)
    parents = model.topology.parents
    root = {}
    for k in small:  # ascending: a parent hinge is seen before its children
        p = parents[k - 1]
        root[k] = root[p] if p in in_small else k
    groups = {}
    for k in small:
        groups.setdefault(root[k], []).append(k)
    eps = model.topology.path_elements
    others = [k for k in range(1, model.n + 1) if k not in in_small and k not in model.inert]
    out = []
    for r, hs in sorted(groups.items()):
        terminal = not any(eps[s - 1, o] for s in hs for o in others)
        out.append(Substructure(tuple(hs), parents[r - 1], terminal))
    return tuple(out)


def _local_topology(model, sub: Substructure) -> Topology:
    pos = {k: i + 1 for i, k in enumerate(sub.hinges)}
    parents = [pos.get(model.topology.parents[k - 1], 0) for k in sub.hinges]
    return Topology(parents, (model.names[sub.base],) + tuple(model.names[k] for k in sub.hinges))


class _Bodies(NamedTuple):
    """The substructure's data (its bodies in ascending order, the base first with no mass)."""

    mass: jax.Array  # (nu+1,)
    inertia: jax.Array  # (nu+1, 3, 3)
    axis: jax.Array  # (nu, 3)
    hinge_on_parent: jax.Array  # (nu, 3)
    hinge_on_body: jax.Array  # (nu, 3)


def _bodies(model, sub: Substructure) -> _Bodies:
    h = np.asarray(sub.hinges, np.int64) - 1
    bodies = np.concatenate([[0], h + 1])
    leaves = (model.mass, model.inertia, model.axis, model.hinge_on_parent, model.hinge_on_body)
    if not is_traced(leaves):  # gathers in numpy: eager ones would each compile on a first build
        mass, inertia, axis, on_parent, on_body = (np.asarray(x) for x in leaves)
        mass, inertia = mass[bodies].copy(), inertia[bodies].copy()
        mass[0], inertia[0] = 0.0, 0.0
        return _Bodies(*(jnp.asarray(x) for x in (mass, inertia, axis[h], on_parent[h], on_body[h])))
    return _Bodies(
        model.mass[bodies].at[0].set(0.0),
        model.inertia[bodies].at[0].set(0.0),
        model.axis[h],
        model.hinge_on_parent[h],
        model.hinge_on_body[h],
    )


def _gauss(topo, d: _Bodies, gamma, yd, v):
    """``(A (6+nu, 6+nu), b (6+nu,))`` of the substructure's Gauss function at its angles `gamma`,
    rates `yd` and base velocity `v` (6: angular, linear at the base's mass center, {b} comps)."""
    nu = gamma.shape[0]
    dtype = gamma.dtype
    axis = d.axis.astype(dtype)
    R = body_rotations(topo, axis, gamma)  # body i -> {b} components; R[0] = U
    par = np.asarray(topo.parents, np.int64)
    Rp = take_rows(R, par)
    to_hinge = mv(Rp, d.hinge_on_parent.astype(dtype))  # the root's: from b's mass center, {b}
    from_hinge = -mv(R[1:], d.hinge_on_body.astype(dtype))
    zero = jnp.zeros((1, 3), dtype)
    r = ancestor_sum(topo, jnp.concatenate([zero, to_hinge + from_hinge], 0))  # mass centers from b's
    hp = take_rows(r, par) + to_hinge
    g = mv(Rp, axis)
    Sw, Su = g, cross(hp, g)
    # bodies of the substructure: inertia about b's mass center, velocities, bias accelerations
    mass = d.mass.astype(dtype)
    Jc = mm(mm(R, d.inertia.astype(dtype)), jnp.swapaxes(R, -1, -2))
    eye = jnp.eye(3, dtype=dtype)
    J = Jc + mass[:, None, None] * (jnp.sum(r * r, -1)[:, None, None] * eye - r[:, :, None] * r[:, None, :])
    hm = mass[:, None] * r
    rates = jnp.concatenate([v[None, :], jnp.concatenate([Sw, Su], 1) * yd[:, None]], 0)
    vel = ancestor_sum(topo, rates)  # (nu+1, 6)
    vp = take_rows(vel, par)
    cw, cu = motion_cross(vp[:, :3], vp[:, 3:], Sw * yd[:, None], Su * yd[:, None])
    cbar = ancestor_sum(topo, jnp.concatenate([jnp.zeros((1, 6), dtype), jnp.concatenate([cw, cu], 1)], 0))
    Lw, Lu = inertia_apply(J, hm, mass, vel[:, :3], vel[:, 3:])
    bw, bu = force_cross(vel[:, :3], vel[:, 3:], Lw, Lu)
    Mcw, Mcu = inertia_apply(J, hm, mass, cbar[:, :3], cbar[:, 3:])
    wrench = jnp.concatenate([Mcw + bw, Mcu + bu], 1)  # M_i c_i + v_i x* M_i v_i
    # J_i = [U | S_k on the path to body i]
    E = jnp.asarray(topo.path_elements, dtype)  # (nu, nu+1): hinge k on the path to body i
    S = jnp.concatenate([Sw, Su], 1)  # (nu, 6)
    Jac = jnp.concatenate(
        [jnp.broadcast_to(jnp.eye(6, dtype=dtype), (nu + 1, 6, 6)), jnp.einsum("ka,ki->iak", S, E)], -1
    )  # (nu+1, 6, 6+nu)
    M6 = inertia_matrix(J, hm, mass)
    A = jnp.einsum("iak,iab,ibl->kl", Jac, M6, Jac)
    b = jnp.einsum("iak,ia->k", Jac, wrench)
    return A, b


class Terms(eqx.Module):
    """Taylor coefficients of one substructure's Gauss function (module docstring), in its base's
    frame about the base's mass center. Rows and columns: the base's acceleration (6), then the
    substructure's hinges (nu)."""

    A0: jax.Array
    A1: jax.Array
    G0: jax.Array
    G1: jax.Array
    G2: jax.Array
    mass: jax.Array


def _polarization(k: int):
    """Index pairs ``(a, b)``, ``a < b``, of `k` coordinates and the unit vectors of the
    polarization of a quadratic form: rows ``e_a`` (k), then ``e_a + e_b`` (pairs)."""
    ia, ib = np.triu_indices(k, 1)
    eye = np.eye(k)
    return ia, ib, np.concatenate([eye, eye[ia] + eye[ib]], 0)


def _hessian_of_quadratic(values, k: int):
    """The symmetric Hessian ``H (.., k, k)`` of a homogeneous quadratic form ``q(x) = x^T H x / 2``
    from its values at the rows of :func:`_polarization` (last axis of `values`): ``H_aa = 2
    q(e_a)`` and ``H_ab = q(e_a + e_b) - q(e_a) - q(e_b)``. Exact for a quadratic form (round-off
    aside), and it needs no nested differentiation."""
    ia, ib, _ = _polarization(k)
    single, pair = values[..., :k], values[..., k:]
    H = jnp.zeros(values.shape[:-1] + (k, k), values.dtype)
    H = H.at[..., np.arange(k), np.arange(k)].set(2.0 * single)
    off = pair - single[..., ia] - single[..., ib]
    return H.at[..., ia, ib].set(off).at[..., ib, ia].set(off)


# Up to this many hinges a substructure's terms come from one batched evaluation of its Gauss
# function, differentiated as a whole (the quickest to compile: flex95's build 3.9 s); beyond it
# the rows that need no derivative are evaluated apart, since differentiating them makes memory
# grow as nu^4 (35 GB for chain200's boom of 200 hinges).
ONE_BATCH_HINGES = 64


@build_jit
def _terms(topo, d: _Bodies, gamma_bar, one_batch: bool):
    # One compilation per substructure shape: identical wings share it.
    gauss = lambda y, yd, v: _gauss(topo, d, gamma_bar + y, yd, v)
    return taylor_terms(gauss, gamma_bar.shape[0], gamma_bar.dtype, one_batch, jnp.sum(d.mass.astype(gamma_bar.dtype)))


def taylor_terms(gauss, nu: int, dtype, one_batch: bool, mass) -> Terms:
    """:class:`Terms` of the Gauss function ``gauss(y, y', v) -> (A, b)`` of `nu` small
    coordinates (a substructure's hinges, or an appendage's modal coordinates, :mod:`jaxtree.
    _src.appendage`), traced inside the caller's compilation.

    The velocity products are exactly quadratic in (v, y'): their second derivatives come from b's
    values at sums of unit vectors (_hessian_of_quadratic), not from nested jacfwd (whose
    compilation took 8 of a flex95 build's 24 s). Rows (y', v): the 21 of V with y' = 0, then
    (e_k, e_a) for all k, a, then (e_k, 0) and (0, e_a); only A and the first 21 rows need the
    derivative in y. With `one_batch` False the rows that need no derivative are evaluated apart
    (memory that would grow as nu^4)."""
    zn = jnp.zeros(nu, dtype)
    _, _, V = _polarization(6)  # (21, 6): v = e_a, then e_a + e_b
    eye_n, eye_6 = np.eye(nu), np.eye(6)
    yd_mixed = np.concatenate([np.repeat(eye_n, 6, 0), eye_n, np.zeros((6, nu))])
    v_mixed = np.concatenate([np.tile(eye_6, (nu, 1)), np.zeros((nu, 6)), eye_6])
    if one_batch:
        yd_rows = jnp.asarray(np.concatenate([np.zeros((21, nu)), yd_mixed]), dtype)
        v_rows = jnp.asarray(np.concatenate([V, v_mixed]), dtype)
    else:
        yd_rows, v_rows = jnp.zeros((21, nu), dtype), jnp.asarray(V, dtype)

    def at(y):  # A(y), the Hessian of b in the base's velocity (6+nu, 6, 6), [the mixed rows]
        # A depends on y only: one unbatched copy (out_axes None), one gauss in the program
        A, b = jax.vmap(lambda yd, v: gauss(y, yd, v), out_axes=(None, 0))(yd_rows, v_rows)
        out = (A, _hessian_of_quadratic(b[:21].T, 6), b[21:])
        return out, out

    (A1, G1, _), (A0, G0, mixed) = jax.jacfwd(at, has_aux=True)(zn)
    if not one_batch:
        rows = (jnp.asarray(yd_mixed, dtype), jnp.asarray(v_mixed, dtype))
        mixed = jax.vmap(lambda yd, v: gauss(zn, yd, v)[1])(*rows)
    # the mixed second derivative in (y', v) at y = 0: b(e_k, e_a) - b(e_k, 0) - b(0, e_a)
    both = mixed[: 6 * nu].reshape(nu, 6, -1)
    only_yd, only_v = mixed[6 * nu : 7 * nu], mixed[7 * nu :]
    G2 = jnp.transpose(both - only_yd[:, None] - only_v[None], (2, 1, 0))  # (6+nu, 6, nu)
    return Terms(A0, A1, G0, G1, G2, mass)


def terms(model, sub: Substructure, gamma_nominal) -> Terms:
    """The Taylor coefficients of `sub` at the nominal angles (all n; its own entries are used)."""
    h = np.asarray(sub.hinges, np.int64) - 1
    topo = Topology(_local_topology(model, sub).parents)  # unnamed: equal shapes share a compilation
    g = gamma_nominal[h] if is_traced(gamma_nominal) else jnp.asarray(np.asarray(gamma_nominal)[h])
    return _terms(topo, _bodies(model, sub), g, len(sub.hinges) <= ONE_BATCH_HINGES)


def held_base(t: Terms, v, c, stiffness, damping, xp=jnp):
    """``(I, J, K)`` of the substructure with its base moving at spatial velocity `v` and
    acceleration `c` (6 each, {b} components about the base's mass center): the small rows of
    ``A(y) [c; y''] + b(y, y', v) - tau_S = 0`` to first order (Eq. 40 for one substructure).
    `xp`: the array module (numpy for a concrete build: no dispatch of small eager operations)."""
    A1, G1, G2 = (xp.asarray(x) for x in (t.A1, t.G1, t.G2))
    I = xp.asarray(t.A0)[6:, 6:]
    K = xp.einsum("iaj,a->ij", A1[6:, :6], c) + 0.5 * xp.einsum("iabj,a,b->ij", G1[6:], v, v) + xp.diag(stiffness)
    J = xp.einsum("iaj,a->ij", G2[6:], v) + xp.diag(damping)
    return I, J, K
