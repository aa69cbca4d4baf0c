"""The precomputed right side: Eq. (30) from the substructures' Taylor coefficients (Likins
1972, Sec. III E; :mod:`.substructure`), with nothing of the size of the small set.

Used when every substructure is terminal and no external load acts on a small body (the default
then). Each substructure's share of Eq. (1) is summarized once, in its base's frame, by the
Taylor coefficients of :mod:`.substructure`, projected on the retained modes
(:class:`~.model.Precomputed`). A right side evaluates Eq. (1) over the large bodies only
(:func:`_large_frame`: a Newton-Euler form with the translation of b_0, eliminated at the end as
in Eq. 1), adds each substructure through its base's velocity and acceleration
(:func:`pre_blocks`), and costs ``O(n_L^3 + k^2)``. Large hinges (free, sprung, prescribed), loads
on large bodies and a spinning nominal keep this cost. :func:`pre_system` gives the system of
Eq. (118)/(121) in the global order of the modes, as :func:`.rhs._project` gives it from the
general form; :func:`.rhs.solve` may keep the substructure order (:func:`substructure_order`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..equations.kinematics import ancestor_sum, body_rotations, cross, mm, mv, take_rows
from ..equations.spatial import force_cross, inertia_apply, inertia_matrix, motion_cross
from ..vehicle.model import State
from ..vehicle.topology import Topology
from .model import PAIRS, HybridModel


def _large_structure(hm: HybridModel):
    """Static: the large bodies (body 0 and the bodies of the large and prescribed hinges,
    ascending), their parents among them, and the hinges of the Newton-Euler columns after
    ``omega0`` (3) and the translation of b_0 (3): the large hinges, then the prescribed ones."""
    model = hm.model
    hinges = tuple(sorted(hm.large + model.prescribed))
    bodies = (0,) + hinges
    local = {b: i for i, b in enumerate(bodies)}
    parents = tuple(local[model.topology.parents[k - 1]] for k in hinges)
    return bodies, parents, hm.large + model.prescribed, local


def _to_base(E, r, x):
    """Motion vectors (6 along axis -2) from {b^0} components about b_0's mass center to a base's
    components about its mass center: ``(E w, E (u - r x w))``."""
    w, u = x[..., :3, :], x[..., 3:, :]
    rw = jnp.stack(
        [
            r[..., 1, None] * w[..., 2, :] - r[..., 2, None] * w[..., 1, :],
            r[..., 2, None] * w[..., 0, :] - r[..., 0, None] * w[..., 2, :],
            r[..., 0, None] * w[..., 1, :] - r[..., 1, None] * w[..., 0, :],
        ],
        -2,
    )
    return jnp.concatenate([E @ w, E @ (u - rw)], -2)


def _large_frame(hm: HybridModel, bases, t, dcm, w, gL, gdL, v0=None):
    """Eq. (1) over the large bodies, as a Newton-Euler Gauss function in ``z = [omega0_dot,
    acceleration of b_0's mass center, gamma_ddot of the large hinges, of the prescribed ones]``
    about b_0's mass center in {b^0} components (b_0's mass center at rest: Eq. 1 does not depend
    on a uniform translation), and the motion of each substructure's base.

    **Returns:** ``(A (nz, nz), b (nz,), Jb (p, 6, nz), vb (p, 6), cb (p, 6), prescribed
    accelerations)``: the large bodies' matrix and bias (hinge laws of the large hinges included),
    and for each substructure (its base body in `bases`) the base's acceleration map, velocity and
    velocity-product acceleration in the base's frame about its mass center. `v0`: the spatial
    velocity of b_0 about its mass center (default: ``omega0`` and no translation)."""
    model = hm.model
    bodies, parents, cols, local = _large_structure(hm)
    topo = Topology(parents)
    hinges = bodies[1:]
    dtype = w.dtype
    nP = len(model.prescribed)
    gddP = None
    gcol, gdcol = gL, gdL
    if nP:
        assert model.prescription is not None, "a model with prescribed hinges has a prescription"
        gp, gdp, gddP = model.prescription.derivatives(jnp.asarray(t, dtype))
        gcol = jnp.concatenate([gL, gp.astype(dtype)])
        gdcol = jnp.concatenate([gdL, gdp.astype(dtype)])
        gddP = gddP.astype(dtype)
    order = np.asarray([cols.index(k) for k in hinges], np.int64)  # body order -> column order
    gam, gamd = take_rows(gcol, order), take_rows(gdcol, order)
    hk = np.asarray(hinges, np.int64) - 1
    axis = take_rows(model.axis, hk).astype(dtype)
    R = body_rotations(topo, axis, gam)
    par = np.asarray(parents, np.int64)
    zero3 = jnp.zeros((1, 3), dtype)
    Rp = take_rows(R, par)
    to_h = mv(Rp, take_rows(model.hinge_on_parent, hk).astype(dtype))
    r = ancestor_sum(
        topo, jnp.concatenate([zero3, to_h - mv(R[1:], take_rows(model.hinge_on_body, hk).astype(dtype))], 0)
    )
    g = mv(Rp, axis)
    S = jnp.concatenate([g, cross(take_rows(r, par) + to_h, g)], 1)  # (nh, 6) hinge motions
    v0 = jnp.concatenate([w, jnp.zeros(3, dtype)]) if v0 is None else v0
    vel = ancestor_sum(topo, jnp.concatenate([v0[None], S * gamd[:, None]], 0))
    vp = take_rows(vel, par)
    cw, cu = motion_cross(vp[:, :3], vp[:, 3:], S[:, :3] * gamd[:, None], S[:, 3:] * gamd[:, None])
    c = jnp.concatenate([cw, cu], 1)  # (the prescribed accelerations enter through their columns of z)
    cbar = ancestor_sum(topo, jnp.concatenate([jnp.zeros((1, 6), dtype), c], 0))
    bidx = np.asarray(bodies, np.int64)
    mass = take_rows(model.mass, bidx).astype(dtype)
    Jc = mm(mm(R, take_rows(model.inertia, bidx).astype(dtype)), jnp.swapaxes(R, -1, -2))
    eye = jnp.eye(3, dtype=dtype)
    J = Jc + mass[:, None, None] * (jnp.sum(r * r, -1)[:, None, None] * eye - r[:, :, None] * r[:, None, :])
    h = mass[:, None] * r
    Lw, Lu = inertia_apply(J, h, mass, vel[:, :3], vel[:, 3:])
    bw, bu = force_cross(vel[:, :3], vel[:, 3:], Lw, Lu)
    Mcw, Mcu = inertia_apply(J, h, mass, cbar[:, :3], cbar[:, 3:])
    wrench = jnp.concatenate([Mcw + bw, Mcu + bu], 1)
    if model.loads is not None:
        lb = np.asarray([local[int(b)] for b in model.loads.bodies], np.int64)
        F, T = model.loads(t, _loads_state(hm, t, dcm, w, gL, gdL))
        F0, T0 = mv(R[lb], F.astype(dtype)), mv(R[lb], T.astype(dtype))
        wrench = wrench.at[lb].add(-jnp.concatenate([T0 + cross(r[lb], F0), F0], 1))
    # the unknowns' motion map of each large body: rotation and translation of b_0, then the hinges
    inv = _inverse(order)  # column -> body order
    path = topo.path_elements[inv].T  # (nb, nc): the column's hinge is on the path to the body
    Jac = jnp.concatenate(
        [
            jnp.broadcast_to(jnp.eye(6, dtype=dtype), (len(bodies), 6, 6)),
            jnp.einsum("ca,ic->iac", S[inv], jnp.asarray(path, dtype)),
        ],
        -1,
    )
    M6 = inertia_matrix(J, h, mass)
    A = jnp.einsum("iak,iab,ibl->kl", Jac, M6, Jac)
    b = jnp.einsum("iak,ia->k", Jac, wrench)
    # hinge laws of the large hinges (b is minus the generalized force)
    sprung = [k for k in cols if k in model.sprung]
    if sprung:
        ci = np.asarray([cols.index(k) for k in sprung], np.int64)
        ki = np.asarray(sprung, np.int64) - 1
        tau = -model.stiffness[ki].astype(dtype) * gcol[ci] - model.damping[ki].astype(dtype) * gdcol[ci]
        b = b.at[6 + ci].add(-tau)
    # the substructures' bases
    lbs = np.asarray([local[bb] for bb in bases], np.int64)
    E = jnp.swapaxes(take_rows(R, lbs), -1, -2)
    rb = take_rows(r, lbs)
    Jb = _to_base(E, rb, take_rows(Jac, lbs))
    vb = _to_base(E, rb, take_rows(vel, lbs)[..., None])[..., 0]
    cb = _to_base(E, rb, take_rows(cbar, lbs)[..., None])[..., 0]
    return A, b, Jb, vb, cb, gddP


def _inverse(order):
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    return inv


def _loads_state(hm, t, dcm, w, gL, gdL):
    """The physical state for the loads' law (small hinges at their nominal angles; loads act on
    large bodies only, whose forces do not depend on the small angles to the order kept)."""
    gamma, gamma_dot, _ = hm.large_configuration(t, gL, gdL)
    return State(dcm, w, gamma, gamma_dot)


def pre_blocks(hm: HybridModel, t, parts, with_ww: bool = True):
    """Eq. (30) from the precomputed substructure terms, its modal rows and columns in
    substructure order (``P = p * uS`` of them: substructure j's rows at ``j * uS ...``, padding
    rows zero; :func:`substructure_order` maps them to the global ones). `parts`: the state's
    ``hm.unpack(y)`` (kept apart, so that a tangent of the modal coordinates alone does not enter
    the large bodies' frame: a Jacobian's modal columns skip it).

    Each substructure's bias is one product with the features ``psi = [v_b v_c, v, c, 1]`` of its
    base's motion (velocity v, velocity-product acceleration c): the zeroth-order part
    ``bias0 . psi``, the first-order part ``bias1 . (psi (x) s)``; its matrix ``mat0 + mat1 . s``
    (base columns), mapped to the unknowns by the base's acceleration map Jb. Then the translation
    of b_0 is eliminated (Eq. 1 is the Schur complement, Eq. 30 its first-order part; M, the total
    mass, carries no caret).

    **Returns:** ``(Mxx (nx, nx), Mxw (nx, P), Mwx (P, nx), Mww (P, P) or None, rx (nx,),
    rw (P,))`` with ``nx = 3 + len(large)``: the system of ``[omega0_dot, gamma_ddot_L]`` and the
    modal unknowns, without the constant modal block ``kin`` and the spring rows ``kin_rhs . s``
    (added by the callers); `Mww`, the part of the modal block that the elimination adds, only
    when `with_ww`."""
    att, w, gL, gdL, s = parts
    dtype = w.dtype
    s_in = s * hm.keep_m().astype(dtype)
    pre = hm.pre
    assert pre is not None, "called for a model with precomputed terms only"
    A, b, Jb, vb, cb, gddP = _large_frame(hm, pre.bases, t, hm.attitude.to_dcm(att), w, gL, gdL)
    p, uS = len(pre.bases), len(pre.ucols[0])
    sS = jnp.concatenate([s_in, jnp.zeros((1,), dtype)])[np.asarray(pre.mcols, np.int64)]  # (p, mS)
    # the substructures' forces on their bases (rows :6) and modal rows (6:), bar and caret parts
    iu, ju = PAIRS
    psi = jnp.concatenate([vb[:, iu] * vb[:, ju], vb, cb, jnp.ones((p, 1), dtype)], 1)
    f0 = jnp.einsum("pil,pl->pi", pre.bias0, psi)
    # the caret part: bias1 . (psi (x) s) as (bias1 . psi) . s (linear in s through a (p, rows, mS)
    # coefficient: tangents of s, a Jacobian's columns, do not pass through the features)
    C1 = jnp.einsum("pilm,pl->pim", pre.bias1.reshape(p, pre.bias1.shape[1], psi.shape[1], -1), psi)
    f1 = jnp.einsum("pim,pm->pi", C1, sS)
    # bar and caret apart, not stacked: a tangent of the modal coordinates alone (a Jacobian's modal
    # columns) then passes through the caret products only, the bar ones carrying no tangent
    B1 = jnp.einsum("pijm,pm->pij", pre.mat1, sS)  # (p, 6 + uS, 6): the caret matrix; the bar one is mat0
    X0 = jnp.einsum("pia,pak->pik", pre.mat0, Jb)  # (p, 6 + uS, nz): base and modal rows
    X1 = jnp.einsum("pia,pak->pik", B1, Jb)
    Azz0 = A + jnp.einsum("pak,pal->kl", Jb, X0[:, :6])
    Azz1 = jnp.einsum("pak,pal->kl", Jb, X1[:, :6])
    Azw = jnp.einsum("pak,pau->kpu", Jb, pre.aw0).reshape(-1, p * uS)  # bar only (Eq. 30c)
    bz0 = b + jnp.einsum("pak,pa->k", Jb, f0[:, :6])
    bz1 = jnp.einsum("pak,pa->k", Jb, f1[:, :6])
    # rows: the kept z rows, then the modal ones; eliminate the translation of b_0 (z 3..5)
    nL, nP = len(hm.large), len(hm.model.prescribed)
    nz = A.shape[0]
    Rz = np.concatenate([np.arange(3), np.arange(6, 6 + nL)])
    T = np.arange(3, 6)
    Kc = np.concatenate([np.arange(3), np.arange(6, nz)])
    A0 = jnp.concatenate([Azz0[Rz], X0[:, 6:].reshape(p * uS, -1)], 0)  # (rows, nz)
    A1 = jnp.concatenate([Azz1[Rz], X1[:, 6:].reshape(p * uS, -1)], 0)
    b0 = jnp.concatenate([bz0[Rz], f0[:, 6:].reshape(p * uS)])
    b1 = jnp.concatenate([bz1[Rz], f1[:, 6:].reshape(p * uS)])
    minv = 1.0 / total_mass(hm, dtype)
    A0T, A1T = Azz0[T], Azz1[T]  # the translation rows (3, nz)
    AK = A0[:, Kc] + A1[:, Kc] - minv * (A0[:, T] @ A0T[:, Kc] + A1[:, T] @ A0T[:, Kc] + A0[:, T] @ A1T[:, Kc])
    rhs = -(b0 + b1 - minv * (A0[:, T] @ bz0[T] + A1[:, T] @ bz0[T] + A0[:, T] @ bz1[T]))
    nx = 3 + nL
    if nP:
        assert gddP is not None, "_large_frame returns the prescribed accelerations when there are some"
        rhs = rhs - AK[:, nx:] @ gddP
    Mxw = Azw[Rz] - minv * A0[:nx, T] @ Azw[T]
    Pww = A0[nx:, T] @ Azw[T] if with_ww else None
    return AK[:nx, :nx], Mxw, AK[nx:, :nx], Pww, rhs[:nx], rhs[nx:]


def total_mass(hm: HybridModel, dtype):
    """The vehicle's mass: the tree's and the finite-element appendages'."""
    m = jnp.sum(hm.model.mass.astype(dtype))
    pre = hm.pre
    return m if pre is None or pre.added_mass is None else m + pre.added_mass.astype(dtype)


def substructure_order(hm: HybridModel):
    """Static: ``(order (P,), partition)``: the global modal row of each substructure-ordered row
    (u, one past the end, for padding), and whether each global row belongs to one substructure
    (the substructure basis: the order is a permutation, see :func:`.rhs.solve`); with the set
    basis the substructures share the modes and their rows add up."""
    pre = hm.pre
    assert pre is not None
    order = np.asarray(pre.ucols, np.int64).reshape(-1)
    real = order[order < hm.u]
    return order, len(set(real.tolist())) == len(real)


def pre_system(hm: HybridModel, t, parts):
    """Eq. (118)/(121) from the precomputed substructure terms (:func:`pre_blocks`) in the
    global order: ``(matrix, rhs)`` as :func:`.rhs._project` returns them from the general form
    (`parts`: ``hm.unpack(y)``)."""
    Mxx, Mxw, Mwx, Pww, rx, rw = pre_blocks(hm, t, parts)
    order, _ = substructure_order(hm)
    dtype = parts[1].dtype
    U = np.zeros((len(order), hm.u + 1))
    U[np.arange(len(order)), order] = 1.0
    U = jnp.asarray(U[:, : hm.u], dtype)  # substructure rows -> global rows (summed)
    minv = 1.0 / total_mass(hm, dtype)
    s_in = parts[4] * hm.keep_m().astype(dtype)
    assert hm.pre is not None and Pww is not None
    Mww = hm.pre.ww0 - minv * U.T @ Pww @ U + hm.kin
    mat = jnp.concatenate([jnp.concatenate([Mxx, Mxw @ U], 1), jnp.concatenate([U.T @ Mwx, Mww], 1)], 0)
    return mat, jnp.concatenate([rx, U.T @ rw + hm.kin_rhs @ s_in])
