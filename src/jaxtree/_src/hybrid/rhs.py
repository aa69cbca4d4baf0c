"""The right side of the hybrid-coordinate equations: Eq. (30) projected on the retained modes,
Eqs. (115)-(118) (first-order form) and (121) (real form) of Likins (1972), Sec. III E, and its
solution for ``[omega0_dot, gamma_ddot_L, modal accelerations]``.

**Two ways to evaluate Eq. (30).**

- *Precomputed* (every substructure terminal, no external load on a small body; the default then):
  :mod:`.precomputed`, from the substructures' Taylor coefficients, at a cost independent of the
  number of small hinges.
- *General* (an internal substructure: a large hinge outboard of a small one): the bar parts are
  Eq. (1) at the small hinges' nominal angles and the caret parts its directional derivative along
  the current small displacement (one forward-mode ``jax.jvp`` of Eq. 1 per right side,
  :func:`_eq30`), then the small columns post-multiplied by the modal matrix (Eq. 115) and the
  small rows premultiplied by the left one (Eq. 117; :func:`_project`).

Both give the same equations to round-off (tests/test_hybrid.py). When the modal block of the
projected system is constant (all substructures terminal and on one base body: ``a_bar`` of the
small hinges is then constant, note to Eq. 30c), :func:`solve` uses a Schur complement on the
``3 + n_L`` large unknowns with that block's inverse precomputed (``HybridModel.modal_inverse``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..equations.dynamics import rotational_equations
from ..equations.kinematics import full_precision
from ..integration.jacobian import jacobian_by_parts
from ..numerics import eager_jit
from ..vehicle.model import State
from .model import HybridModel
from .precomputed import pre_blocks, pre_system, substructure_order


def _eq30(hm: HybridModel, t, dcm, w, gL, gdL, y, yd):
    """Eq. (30) at the current large state: ``(M_large, M_small, R)`` with ``M_large`` the bar +
    caret columns of the large accelerations (omega0, then the large hinges), ``M_small`` the bar
    columns of the small accelerations and ``R`` the right side to first order (bar + caret,
    prescribed accelerations moved over with bar + caret coefficients)."""
    model = hm.model
    gamma, gamma_dot, gdd = hm.large_configuration(t, gL, gdL)
    ES, _, _ = hm.selectors(gamma.dtype)

    def eq1(g, gd):
        return rotational_equations(model, State(dcm, w, g, gd), t)

    (A, rhs), (dA, drhs) = jax.jvp(eq1, (gamma, gamma_dot), (ES @ y, ES @ yd))
    cols = _large_columns(hm)
    Ml = (A + dA)[:, cols]
    Ms = A[:, np.asarray(hm.small, dtype=np.int64) + 2]
    R = rhs + drhs
    if gdd is not None:
        R = R - (A + dA)[:, np.asarray(model.prescribed, dtype=np.int64) + 2] @ gdd
    return Ml, Ms, R


def _large_columns(hm):
    return np.concatenate([np.arange(3), np.asarray(hm.large, dtype=np.int64) + 2]).astype(np.int64)


def _project(hm: HybridModel, Ml, Ms, R, s_in):
    """Eq. (115)-(118) / (121): small columns post-multiplied by the modal matrix, small rows
    premultiplied by the left modal matrix."""
    X = _large_columns(hm)
    S = np.asarray(hm.small, dtype=np.int64) + 2
    top = jnp.concatenate([Ml[X], Ms[X] @ hm.accel], 1)
    bot = jnp.concatenate([hm.rows.T @ Ml[S], hm.kin + hm.rows.T @ Ms[S] @ hm.accel], 1)
    mat = jnp.concatenate([top, bot], 0)
    rhs = jnp.concatenate([R[X], hm.rows.T @ R[S] + hm.kin_rhs @ s_in])
    return mat, rhs


def _mask(hm, mat, rhs):
    nx = 3 + len(hm.large)
    ku = hm.keep_u().astype(mat.dtype)
    r = jnp.concatenate([jnp.ones(nx, mat.dtype), ku])
    mat = mat * r[:, None] * r[None, :] + jnp.diag(jnp.concatenate([jnp.zeros(nx, mat.dtype), 1.0 - ku]))
    return mat, rhs * r


def _schur_solve(hinv, Mxx, Mxh, Mhx, rx, rh, xh=None):
    """Solve ``[[Mxx, Mxh], [Mhx, H]] [x; a] = [rx; rh]`` with ``H^{-1} = hinv`` known: a system of
    the size of the large unknowns only."""
    xh = Mxh @ hinv if xh is None else xh
    x = jnp.linalg.solve(Mxx - xh @ Mhx, rx - xh @ rh)
    return x, hinv @ (rh - Mhx @ x)


@full_precision
@eager_jit
def hybrid_equations(hybrid: HybridModel, t, y):
    """The linear system of Eq. (118) (first-order form) or Eq. (121) (real form) at ``(t, y)``:
    ``(matrix, rhs)`` for the unknowns ``[omega0_dot, gamma_ddot_L, modal]`` (modal: ``eta_r''``
    or ``Y_r'``), masked modes included as ``1 * x = 0`` rows. For inspection and tests; the
    right-hand side :func:`hybrid_rhs` solves the same system."""
    return equations_of_parts(hybrid, t, hybrid.unpack(y))


def equations_of_parts(hm: HybridModel, t, parts):
    """:func:`hybrid_equations` of the state's parts (``hm.unpack(y)``)."""
    if hm.pre is not None:
        mat, rhs = pre_system(hm, t, parts)
    else:
        att, w, gL, gdL, s = parts
        s_in = s * hm.keep_m().astype(w.dtype)
        dcm = hm.attitude.to_dcm(att)
        Ml, Ms, R = _eq30(hm, t, dcm, w, gL, gdL, hm.positions @ s_in, hm.rates @ s_in)
        mat, rhs = _project(hm, Ml, Ms, R, s_in)
    return _mask(hm, mat, rhs)


def solve(hm: HybridModel, t, parts):
    """``(omega0_dot, gamma_ddot_L, modal accelerations)`` of Eq. (118)/(121) at the state whose
    parts (``hm.unpack(y)``) are given."""
    nx = 3 + len(hm.large)
    dtype = parts[1].dtype
    if hm.modal_inverse is None:
        mat, rhs = equations_of_parts(hm, t, parts)
        x = jnp.linalg.solve(mat, rhs)
        return x[:3], x[3:nx], x[nx:]
    # constant modal block: a Schur complement on the large unknowns
    ku = hm.keep_u().astype(dtype)
    if hm.pre is not None and substructure_order(hm)[1]:
        # in substructure order (no scatter of the substructures' rows): permute the constant
        # inverse and the spring rows instead, and the modal accelerations back
        Mxx, Mxw, Mwx, _, rx, rw = pre_blocks(hm, t, parts, with_ww=False)
        order, _ = substructure_order(hm)
        pos = np.zeros(hm.u, np.int64)
        pos[order[order < hm.u]] = np.nonzero(order < hm.u)[0]
        s_in = parts[4] * hm.keep_m().astype(dtype)
        pad = lambda v: jnp.concatenate([v, jnp.zeros((1,), dtype)])
        kp = pad(ku)[order]
        Hinv = jnp.pad(hm.modal_inverse, ((0, 1), (0, 1)))[np.ix_(order, order)]
        rw = (rw + pad(hm.kin_rhs @ s_in)[order]) * kp
        x, acc = _schur_solve(Hinv, Mxx, Mxw * kp[None, :], Mwx * kp[:, None], rx, rw)
        return x[:3], x[3:], acc[pos]
    if hm.pre is not None:
        mat, rhs = pre_system(hm, t, parts)
    else:
        att, w, gL, gdL, s = parts
        s_in = s * hm.keep_m().astype(dtype)
        Ml, Ms, R = _eq30(hm, t, hm.attitude.to_dcm(att), w, gL, gdL, hm.positions @ s_in, hm.rates @ s_in)
        mat, rhs = _project(hm, Ml, Ms, R, s_in)
    x, acc = _schur_solve(
        hm.modal_inverse,
        mat[:nx, :nx],
        mat[:nx, nx:] * ku[None, :],
        mat[nx:, :nx] * ku[:, None],
        rhs[:nx],
        rhs[nx:] * ku,
    )
    return x[:3], x[3:], acc


@full_precision
@eager_jit
def hybrid_rhs(t, y, args: HybridModel):
    """Right side of the hybrid-coordinate equations (diffrax signature ``(t, y, args)``).

    Solves Eq. (118) (first-order modes) or Eq. (121) (real modes) for
    ``[omega0_dot, gamma_ddot_L, modal]`` and returns the time derivative of the flat state
    ``[attitude, omega0, gamma_L, gamma_dot_L, s]``. Jittable and vmappable.
    """
    return _field(args, t, args.unpack(y))


def _field(hm: HybridModel, t, parts):
    """:func:`hybrid_rhs` of the state's parts (``hm.unpack(y)``)."""
    att, w, gL, gdL, s = parts
    dtype = w.dtype
    km = hm.keep_m().astype(dtype)
    s_in = s * km
    wd, gddL, acc = solve(hm, t, parts)
    if hm.form == "real":
        k = hm.n_modes
        ds = jnp.concatenate([s_in[k:], acc * hm.keep.astype(dtype)])
    else:
        ds = acc * km
    dy = jnp.concatenate([hm.attitude.rate(att, w), wd, gdL, gddL, ds])
    big = jnp.asarray(np.sqrt(np.finfo(np.dtype(dtype)).max), dtype)
    return jnp.where(jnp.isfinite(dy), dy, big)


@full_precision
@eager_jit
def hybrid_jacobian(t, y, args: HybridModel):
    """``d hybrid_rhs / d y`` (size x size), for :class:`jaxtree.Radau5` (its `jacobian` option;
    :func:`jaxtree.simulate_hybrid` passes it by default).

    Two forward-mode passes over the parts of the state: the large variables (attitude,
    ``omega0``, ``gamma_L``, ``gamma_dot_L``), whose tangents go through the large bodies' frame,
    and the modal coordinates, whose tangents do not (the frame does not depend on them: with the
    precomputed terms Eq. 30 is affine in them after the frame). One pass over the flat state
    would carry every modal column through the frame as well (measured on flex95 with 3 modes per
    wing: the modal pass is then most of the Jacobian's cost)."""
    return jacobian_by_parts(lambda *p: _field(args, t, p), args.unpack(y), ((0, 1, 2, 3), (4,)))
