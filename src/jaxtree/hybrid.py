"""Hybrid-coordinate equations in truncated large-deformation modal coordinates: Sec. III E of
Likins (1972), Eqs. (105)-(123).

The vehicle is split as in Sec. III A-B: the set A of *small* hinges (the even groups
``gamma^2, gamma^4, ...`` of Eq. 30c; ``nu`` of them) and the *large* variables (``omega0`` and
the hinges not in A, the odd groups). Eq. (30), the partially linearized Eq. (1), keeps the
large variables unrestricted and the small ones to first order. The small hinges then get
constant-coefficient equations ``I y'' + J y' + K y = 0`` on a nominal motion (Eq. 42 = Eq. 105
per group, :func:`jaxtree.linearize`), whose modes (:func:`jaxtree.modes`, Eqs. 70-104) define
the *large-deformation modal coordinates*; keeping only some modes (truncation) gives the
hybrid-coordinate equations:

- **real modes** (``J = 0``, ``K`` symmetric; Eqs. 119-121): ``y = phi_r eta_r``; the small-hinge
  columns of Eq. (30c) are post-multiplied by ``phi_r`` and its rows premultiplied by
  ``phi_r^T``; second order in ``eta_r``; modal damping ``-2 zeta sigma eta_r'`` added to
  ``phi_r^T R`` (end of Sec. III E, Eq. 104);
- **first-order modes** (gyroscopic or general ``J``, ``K``; Eqs. 106-118): the first-order form
  (30d) of the small rows, ``Gamma = [y; y'] = Phi_r Y_r`` (Eq. 109), columns post-multiplied by
  ``Phi_r`` (Eq. 115), rows premultiplied by the left eigenvectors (Eq. 117), truncation
  (Eq. 118); modal damping ``-zeta sigma Y_r`` (the replacement ``i sigma -> -zeta sigma + i
  sigma`` of Sec. III E, spinning case).

Conventions and the two choices the seed leaves open (see ``docs/errata_hybrid.md``):

* **Left eigenvectors and the scaling of the kinematic rows.** :func:`jaxtree.modes` uses Eq. (70)
  with ``P = diag(K, I)``, ``Q = [[0, K], [-K, -J]]`` and normalizes ``Phi'^T P Phi = U``
  (Eq. 89). The rows of (30d) are ``[U 0; 0 a_bar] Gamma' = [y'; R]``: their nominal matrix is
  ``diag(U, I)``, not ``P``, so Eq. (116) ("``P^k`` is the nominal value of ``A_kk``") and
  Eq. (117) hold only with the left eigenvectors of the unscaled pencil,
  ``Phi''= diag(K^T, U) Phi'``, for which ``Phi''^T diag(U, I) Phi = U``. This module uses them
  (equivalently: it multiplies the kinematic rows of (30d) by ``K``).
* **Real arithmetic.** Each retained conjugate pair ``(Phi^j, Phi^j*)`` is replaced by the real
  pair ``(Re Phi^j, Im Phi^j)`` (a change of basis, as the seed's implementation note allows);
  the left vectors likewise, renormalized so that the projected nominal matrix is ``U``. The
  real-mode case in first-order form (``Phi = diag(phi, phi)``, Eqs. 122-123) is the same
  construction with left vectors ``diag(I phi, phi)``.

The flat ODE state is ``[attitude of b_0, omega0 (3), gamma_L, gamma_dot_L, s]`` with ``gamma_L``
the large hinges that are unknowns of Eq. (1) (prescribed hinges follow their prescription and
leave the state, as in Eq. 25) and ``s`` the modal coordinates: ``[eta_r; eta_r']`` (real form)
or the ``2 k`` real coordinates of ``Y_r`` (first-order form; ``k`` retained pairs).

Each right-hand side evaluates Eq. (30) at the current large state: the bar parts are Eq. (1)
at the small hinges' nominal angles and the caret parts its directional derivative along the
current small displacement (one forward-mode ``jax.jvp`` of Eq. 1; nothing of Eqs. 36-37 is
transcribed), then solves Eq. (118)/(121). Two cheaper cases:

- a **terminal appendage** (no large or prescribed hinge outboard of a small one, Sec. III A):
  the block ``a_bar`` of the small hinges is constant (note to Eq. 30c), so is the modal block,
  and the solve is a Schur complement on the ``3 + n_L`` large unknowns with its inverse
  precomputed;
- **omega0 the only large variable** (no large or prescribed hinge, no external load): every
  coefficient is a polynomial in ``omega0`` (Eq. 1 is quadratic in the rates) with constant
  modal matrices; they are computed once (``precompute``) and a right-hand side costs
  ``O(k^2)`` plus a 3 x 3 solve.

With all modes retained the hybrid equations are Eq. (30) in other coordinates (exactly, to
round-off); truncation removes the modes left out.
"""

from __future__ import annotations

from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .attitude import AbstractAttitude, get_attitude
from .kinematics import full_precision
from .dynamics import rotational_equations
from .linearize import linearize, resolve_hinges
from .model import Model, State
from .modes import ModalError, modes as _modes

__all__ = [
    "HybridModel",
    "HybridSolution",
    "hybrid_model",
    "hybrid_rhs",
    "hybrid_equations",
    "simulate_hybrid",
]


# ----------------------------------------------------------------------------- the model
class _Poly(eqx.Module):
    """Constant coefficients of the hybrid equations when the only large variable is omega0.

    Rows ``r`` of the projected system (3 omega0 rows, then the ``u`` modal rows), columns
    ``[omega0_dot (3), modal unknowns (u)]``; ``s`` the modal state (m), ``w`` = omega0:

    - matrix ``mat0 + [dmat @ s, 0]`` (only the omega0 columns carry the caret parts);
    - right side ``c0 + c1 w + c2 : w w / 2 + (g0 + g1 . w + g2 : w w / 2) s``;
    - ``xh`` (3, u) = ``mat0[omega0 rows, modal columns] @ modal_inverse`` (masked), for the
      Schur-complement solve.
    """

    mat0: jax.Array
    dmat: jax.Array  # (r, 3, m)
    c0: jax.Array  # (r,)
    c1: jax.Array  # (r, 3)
    c2: jax.Array  # (r, 3, 3)
    g0: jax.Array  # (r, m)
    g1: jax.Array  # (r, m, 3)
    g2: jax.Array  # (r, m, 3, 3)
    xh: jax.Array


class HybridModel(eqx.Module):
    """The hybrid-coordinate equations of a vehicle (built by :func:`hybrid_model`).

    Array leaves:

    - `model`: the vehicle; `gamma_nominal` (n,), `omega0_nominal` (3,): the nominal motion the
      modes were computed on (the small hinges' entries of `gamma_nominal` are the expansion
      point ``gamma_bar`` of Eq. 29);
    - `inertia` (nu, nu): ``I`` of Eq. (42) on the nominal motion (``a_bar`` of the small hinges);
    - `frequencies`, `damping_ratios` (k,): ``sigma_j`` and the modal damping ``zeta_j`` of the
      retained modes (ascending frequency);
    - `positions`, `rates` (nu, m): ``y = positions @ s`` and ``y' = rates @ s``
      (``Gamma_1 Phi_r`` and ``Gamma_2 Phi_r`` of Eqs. 111-112);
    - `accel` (nu, u): the small accelerations from the modal unknowns (``phi_r``, or
      ``Gamma_2 Phi_r``); `rows` (nu, u): the premultiplier of the small-hinge dynamic rows
      (``phi_r``, or the lower half of the left eigenvectors); `kin` (u, u) and `kin_rhs` (u, m):
      the projected kinematic rows of (30d) and the modal damping;
    - `project` (m, 2nu): ``s = project @ [y; y']`` (exact for motions in the retained modes);
    - `keep` (k,): 1 for a retained mode, 0 for a mode masked by :meth:`retain`;
    - `modal_inverse` (u, u) or None: the inverse of the modal block of Eq. (118)/(121) (masked
      modes included), present when that block is constant: the set A is a terminal appendage
      (no large or prescribed hinge outboard of a small one, Sec. III A), so ``a_bar`` of the small
      hinges is constant (note to Eq. 30c) and equals ``I``; the linear system is then solved by a
      Schur complement on the large unknowns only;
    - `poly`: the precomputed coefficients, or None.

    Static: `small` (the set A), `large` (the large hinges in the state), `form`
    (``"real"``: Eq. 121; ``"first_order"``: Eq. 118), `kind` (of :func:`jaxtree.modes`),
    `mode_index` (index of each retained mode in the ordering of :func:`jaxtree.modes`) and the
    `attitude` parametrisation of b_0.
    """

    model: Model
    gamma_nominal: jax.Array
    omega0_nominal: jax.Array
    inertia: jax.Array
    frequencies: jax.Array
    damping_ratios: jax.Array
    positions: jax.Array
    rates: jax.Array
    accel: jax.Array
    rows: jax.Array
    kin: jax.Array
    kin_rhs: jax.Array
    project: jax.Array
    keep: jax.Array
    modal_inverse: jax.Array | None
    poly: _Poly | None
    attitude: AbstractAttitude
    small: tuple[int, ...] = eqx.field(static=True)
    large: tuple[int, ...] = eqx.field(static=True)
    form: str = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    mode_index: tuple[int, ...] = eqx.field(static=True)

    # ------------------------------------------------------------------ sizes
    @property
    def nu(self) -> int:
        """Number of small hinges."""
        return len(self.small)

    @property
    def n_modes(self) -> int:
        """Number of modal coordinates (pairs in the first-order form) carried in the state."""
        return len(self.mode_index)

    @property
    def m(self) -> int:
        """Size of the modal state ``s``."""
        return self.positions.shape[1]

    @property
    def u(self) -> int:
        """Number of modal unknowns of the linear system (k real form, 2k first-order form)."""
        return self.accel.shape[1]

    @property
    def size(self) -> int:
        return self.attitude.size + 3 + 2 * len(self.large) + self.m

    @property
    def precomputed(self) -> bool:
        return self.poly is not None

    def _keep_u(self):
        return self.keep if self.form == "real" else jnp.concatenate([self.keep, self.keep])

    def _keep_m(self):
        return jnp.concatenate([self.keep, self.keep])

    # ------------------------------------------------------------------ state
    def unpack(self, y):
        """``(attitude, omega0, gamma_L, gamma_dot_L, s)`` slices of a flat state."""
        a, nl = self.attitude.size, len(self.large)
        o = np.cumsum([0, a, 3, nl, nl, self.m])
        return tuple(y[o[i]:o[i + 1]] for i in range(5))

    def _selectors(self, dtype):
        n = self.model.n
        sel = lambda hs: jnp.asarray(_selector(n, hs), dtype)
        return sel(self.small), sel(self.large), sel(self.model.prescribed)

    def _base(self, dtype):
        """Nominal angles with the large and prescribed entries zeroed (they are added back)."""
        mask = np.ones(self.model.n)
        idx = [k - 1 for k in self.large + self.model.prescribed]
        mask[idx] = 0.0
        return self.gamma_nominal.astype(dtype) * jnp.asarray(mask, dtype)

    def _large_configuration(self, t, gL, gdL):
        """All n angles and rates with the small hinges at their nominal angles (the bar state),
        and the prescribed accelerations."""
        dtype = gL.dtype
        ES, EL, EG = self._selectors(dtype)
        gamma = self._base(dtype) + EL @ gL
        gamma_dot = EL @ gdL
        gdd = None
        if self.model.prescription is not None:
            g, gd, gdd = self.model.prescription.derivatives(jnp.asarray(t, dtype))
            gamma = gamma + EG @ g.astype(dtype)
            gamma_dot = gamma_dot + EG @ gd.astype(dtype)
            gdd = gdd.astype(dtype)
        return gamma, gamma_dot, gdd

    def state(self, t, y) -> State:
        """The physical :class:`~jaxtree.State` (all n hinges) of a flat hybrid state:
        ``gamma_A = gamma_bar_A + Gamma_1 Phi_r Y_r``, ``gamma_dot_A = Gamma_2 Phi_r Y_r``
        (Eqs. 111-112), prescribed hinges from the prescription at `t`."""
        att, w, gL, gdL, s = self.unpack(y)
        gamma, gamma_dot, _ = self._large_configuration(t, gL, gdL)
        ES, _, _ = self._selectors(y.dtype)
        s = s * self._keep_m().astype(y.dtype)
        gamma = gamma + ES @ (self.positions @ s)
        gamma_dot = gamma_dot + ES @ (self.rates @ s)
        return State(self.attitude.to_dcm(att), w, gamma, gamma_dot)

    def pack(self, state: State) -> jax.Array:
        """Flat hybrid state of a physical :class:`~jaxtree.State`: the modal coordinates are
        ``s = project @ [y; y']`` (``y = gamma_A - gamma_bar_A``), the projection of the small
        motion on the retained modes (exact when the motion lies in them)."""
        dtype = jnp.result_type(self.model.mass)
        gamma = jnp.asarray(state.gamma, dtype)
        gamma_dot = jnp.asarray(state.gamma_dot, dtype)
        S = np.asarray(self.small, dtype=np.int64) - 1
        L = np.asarray(self.large, dtype=np.int64) - 1
        y = gamma[S] - self.gamma_nominal.astype(dtype)[S]
        s = self.project @ jnp.concatenate([y, gamma_dot[S]]) * self._keep_m().astype(dtype)
        return jnp.concatenate([
            self.attitude.from_dcm(jnp.asarray(state.dcm, dtype)),
            jnp.asarray(state.omega0, dtype),
            gamma[L],
            gamma_dot[L],
            s,
        ])

    def modal(self, y):
        """The modal coordinates ``s`` of a flat state."""
        return self.unpack(y)[4]

    # ------------------------------------------------------------------ truncation
    def retain(self, n_modes: int) -> "HybridModel":
        """The same model with only the first `n_modes` of its modes active (the others are
        masked: their coordinates stay zero and their rows read ``eta'' = 0``). Mathematically the
        truncation of Eq. (118)/(121) to `n_modes`; the array shapes are unchanged, so a compiled
        simulation is reused. For smaller arrays build a new model with ``n_modes``."""
        k = self.n_modes
        if not 1 <= int(n_modes) <= k:
            raise ValueError(f"retain: n_modes must be in 1..{k}, got {n_modes}")
        keep = jnp.asarray(np.arange(k) < int(n_modes), self.keep.dtype)
        return _with_inverse(eqx.tree_at(lambda h: h.keep, self, keep))


def _selector(n, hinges):
    """Constant n x len(hinges) matrix E with ``gamma = E @ gamma_hinges`` (no scatter)."""
    E = np.zeros((n, len(hinges)))
    E[np.asarray(hinges, dtype=np.int64) - 1, np.arange(len(hinges))] = 1.0
    return E


def _modal_block(hm: HybridModel):
    """The constant modal block ``kin + rows^T I accel`` of a terminal appendage, masked."""
    ku = hm._keep_u()
    H = hm.kin + hm.rows.T @ hm.inertia @ hm.accel
    return H * ku[:, None] * ku[None, :] + jnp.diag(1.0 - ku)


def _with_inverse(hm: HybridModel) -> HybridModel:
    """Recompute `modal_inverse` and the polynomial path's ``xh`` for the current mask (eager)."""
    if hm.modal_inverse is None:
        return hm
    hinv = jnp.linalg.inv(_modal_block(hm))
    out = eqx.tree_at(lambda h: h.modal_inverse, hm, hinv)
    if hm.poly is not None:
        xh = (hm.poly.mat0[:3, 3:] * hm._keep_u()[None, :]) @ hinv
        out = eqx.tree_at(lambda h: h.poly.xh, out, xh)
    return out


# ----------------------------------------------------------------------------- Eq. (30) parts
def _eq30(hm: HybridModel, t, dcm, w, gL, gdL, y, yd):
    """Eq. (30) at the current large state: ``(M_large, M_small, R)`` with ``M_large`` the bar +
    caret columns of the large accelerations (omega0, then the large hinges), ``M_small`` the bar
    columns of the small accelerations and ``R`` the right side to first order (bar + caret,
    prescribed accelerations moved over with bar + caret coefficients)."""
    model = hm.model
    gamma, gamma_dot, gdd = hm._large_configuration(t, gL, gdL)
    ES, _, _ = hm._selectors(gamma.dtype)

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
    ku = hm._keep_u().astype(mat.dtype)
    r = jnp.concatenate([jnp.ones(nx, mat.dtype), ku])
    mat = mat * r[:, None] * r[None, :] + jnp.diag(jnp.concatenate([jnp.zeros(nx, mat.dtype), 1.0 - ku]))
    return mat, rhs * r


def _poly_rhs(p: _Poly, w, s_in):
    ww = w[:, None] * w[None, :]
    c = p.c0 + p.c1 @ w + 0.5 * jnp.einsum("rab,ab->r", p.c2, ww)
    G = p.g0 + p.g1 @ w + 0.5 * jnp.einsum("rjab,ab->rj", p.g2, ww)
    return c + G @ s_in


@full_precision
def hybrid_equations(hybrid: HybridModel, t, y):
    """The linear system of Eq. (118) (first-order form) or Eq. (121) (real form) at ``(t, y)``:
    ``(matrix, rhs)`` for the unknowns ``[omega0_dot, gamma_ddot_L, modal]`` (modal: ``eta_r''``
    or ``Y_r'``), masked modes included as ``1 * x = 0`` rows. For inspection and tests; the
    right-hand side :func:`hybrid_rhs` solves the same system."""
    att, w, gL, gdL, s = hybrid.unpack(y)
    s_in = s * hybrid._keep_m().astype(y.dtype)
    if hybrid.poly is not None:
        p = hybrid.poly
        mat = jnp.concatenate([p.mat0[:, :3] + p.dmat @ s_in, p.mat0[:, 3:]], 1)
        rhs = _poly_rhs(p, w, s_in)
    else:
        dcm = hybrid.attitude.to_dcm(att)
        Ml, Ms, R = _eq30(hybrid, t, dcm, w, gL, gdL, hybrid.positions @ s_in, hybrid.rates @ s_in)
        mat, rhs = _project(hybrid, Ml, Ms, R, s_in)
    return _mask(hybrid, mat, rhs)


def _schur_solve(hinv, Mxx, Mxh, Mhx, rx, rh, xh=None):
    """Solve ``[[Mxx, Mxh], [Mhx, H]] [x; a] = [rx; rh]`` with ``H^{-1} = hinv`` known: a system of
    the size of the large unknowns only."""
    xh = Mxh @ hinv if xh is None else xh
    x = jnp.linalg.solve(Mxx - xh @ Mhx, rx - xh @ rh)
    return x, hinv @ (rh - Mhx @ x)


def _solve_poly(hm: HybridModel, w, s_in):
    """Polynomial path: a 3 x 3 system per call."""
    p = hm.poly
    ku = hm._keep_u().astype(w.dtype)
    Mw = p.mat0[:, :3] + p.dmat @ s_in  # (r, 3)
    rhs = _poly_rhs(p, w, s_in)
    return _schur_solve(hm.modal_inverse, Mw[:3], None, Mw[3:] * ku[:, None], rhs[:3], rhs[3:] * ku, xh=p.xh)


def _solve_terminal(hm: HybridModel, t, y):
    """General path for a terminal appendage: Eq. (30) by jvp, then a Schur complement on the
    large unknowns with the constant modal block (which is therefore never formed)."""
    att, w, gL, gdL, s = hm.unpack(y)
    s_in = s * hm._keep_m().astype(y.dtype)
    ku = hm._keep_u().astype(y.dtype)
    Ml, Ms, R = _eq30(hm, t, hm.attitude.to_dcm(att), w, gL, gdL, hm.positions @ s_in, hm.rates @ s_in)
    X = _large_columns(hm)
    S = np.asarray(hm.small, dtype=np.int64) + 2
    Mxh = (Ms[X] @ hm.accel) * ku[None, :]
    Mhx = (hm.rows.T @ Ml[S]) * ku[:, None]
    rh = (hm.rows.T @ R[S] + hm.kin_rhs @ s_in) * ku
    return _schur_solve(hm.modal_inverse, Ml[X], Mxh, Mhx, R[X], rh)


@full_precision
def hybrid_rhs(t, y, args: HybridModel):
    """Right side of the hybrid-coordinate equations (diffrax signature ``(t, y, args)``).

    Solves Eq. (118) (first-order modes) or Eq. (121) (real modes) for
    ``[omega0_dot, gamma_ddot_L, modal]`` and returns the time derivative of the flat state
    ``[attitude, omega0, gamma_L, gamma_dot_L, s]``. Jittable and vmappable.
    """
    hm = args
    att, w, gL, gdL, s = hm.unpack(y)
    km = hm._keep_m().astype(y.dtype)
    s_in = s * km
    nl = len(hm.large)
    if hm.poly is not None:
        wd, acc = _solve_poly(hm, w, s_in)
        gddL = jnp.zeros((0,), y.dtype)
    elif hm.modal_inverse is not None:
        x, acc = _solve_terminal(hm, t, y)
        wd, gddL = x[:3], x[3:]
    else:
        mat, rhs = hybrid_equations(hm, t, y)
        x = jnp.linalg.solve(mat, rhs)
        wd, gddL, acc = x[:3], x[3:3 + nl], x[3 + nl:]
    if hm.form == "real":
        k = hm.n_modes
        ds = jnp.concatenate([s_in[k:], acc * hm.keep.astype(y.dtype)])
    else:
        ds = acc * km
    dy = jnp.concatenate([hm.attitude.rate(att, w), wd, gdL, gddL, ds])
    big = jnp.asarray(np.sqrt(np.finfo(np.dtype(y.dtype)).max), y.dtype)
    return jnp.where(jnp.isfinite(dy), dy, big)


# ----------------------------------------------------------------------------- construction
def _real_pairs(md, picked, tol):
    """Real bases ``(right, left)`` (2nu, 2k) of the retained pairs: ``[Re Phi^j ..., Im Phi^j ...]``
    for complex pairs, ``[Phi^j ..., Phi^{j+nu} ...]`` for pairs of real eigenvalues."""
    nu = md.nu
    R, Lf = np.asarray(md.right), np.asarray(md.left)
    lam = np.asarray(md.eigenvalues)
    a_r, b_r, a_l, b_l = [], [], [], []
    for j in picked:
        if abs(lam[j].imag) > tol:
            a_r.append(R[:, j].real), b_r.append(R[:, j].imag)
            a_l.append(Lf[:, j].real), b_l.append(Lf[:, j].imag)
        else:
            a_r.append(R[:, j].real), b_r.append(R[:, j + nu].real)
            a_l.append(Lf[:, j].real), b_l.append(Lf[:, j + nu].real)
    return np.stack(a_r + b_r, 1), np.stack(a_l + b_l, 1)


# Sample rates for the exact quadratic interpolation in omega0: 0, +-e_a, e_a + e_b (a < b).
_W_POINTS = np.concatenate([np.zeros((1, 3)), np.eye(3), -np.eye(3), np.eye(3)[[0, 0, 1]] + np.eye(3)[[1, 2, 2]]])


def _quadratic(F):
    """``(f0, f1, f2)`` with ``f(w) = f0 + f1 . w + f2 : w w / 2`` from the values `F` (10, ...) of a
    quadratic at `_W_POINTS` (exact up to round-off); f1 and f2 carry the w axes last."""
    f0, fp, fm, fab = F[0], F[1:4], F[4:7], F[7:10]
    f1 = 0.5 * (fp - fm)
    diag = fp + fm - 2.0 * f0
    f2 = np.zeros((3, 3) + f0.shape)
    for a in range(3):
        f2[a, a] = diag[a]
    for i, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
        f2[a, b] = f2[b, a] = fab[i] - fp[a] - fp[b] + f0
    return f0, np.moveaxis(f1, 0, -1), np.moveaxis(f2, (0, 1), (-2, -1))


@eqx.filter_jit
def _poly_physical(model, gamma_nominal, hinges, dcm):
    """Eq. (30) coefficients for a vehicle whose only large variable is omega0: the matrix and
    its derivative along the small angles (independent of omega0), and the right side and its
    derivatives along ``(y, y')`` at the sample rates `_W_POINTS` (Eq. 1 is quadratic in the rates
    and Eq. 30 linear in ``y, y'``, so a quadratic in omega0 through these points is exact)."""
    n, nu = model.n, len(hinges)
    dtype = gamma_nominal.dtype
    E = jnp.asarray(_selector(n, hinges), dtype)

    def eq1(w, y, yd):
        return rotational_equations(model, State(dcm, w, gamma_nominal + E @ y, E @ yd), 0.0)

    def jvp(w, t):  # Eq. (1) and its derivative along the small angles and rates t = (y, y')
        return jax.jvp(lambda v: eq1(w, v[:nu], v[nu:]), (jnp.zeros(2 * nu, dtype),), (t,))

    # one trace of Eq. (1): vmapped over the 2 nu unit tangents and the sample rates
    (A, c), (dA, g) = jax.vmap(lambda w: jax.vmap(lambda t: jvp(w, t))(jnp.eye(2 * nu, dtype=dtype)))(
        jnp.asarray(_W_POINTS, dtype))
    return dict(A=A[0, 0], dA0=jnp.moveaxis(dA[0, :nu, :, :3], 0, -1), c=c[:, 0], g=jnp.moveaxis(g, 1, -1))


def _build_poly(model, gamma_nominal, small, dcm, hm_parts):
    ph = {k: np.asarray(v) for k, v in _poly_physical(model, gamma_nominal, small, dcm).items()}
    ph["c0"], ph["c1"], ph["c2"] = _quadratic(ph["c"])
    ph["g0"], ph["g1"], ph["g2"] = _quadratic(ph["g"])
    accel, rows, kin, kin_rhs, positions, rates = (np.asarray(hm_parts[k]) for k in
                                                   ("accel", "rows", "kin", "kin_rhs", "positions", "rates"))
    S = np.asarray(small, dtype=np.int64) + 2
    X = np.arange(3)

    def rowp(M):  # rows: omega0, then rows^T @ (small rows); M has leading axis n+3
        top = M[X]
        bot = np.tensordot(rows.T, M[S], axes=(1, 0))
        return np.concatenate([top, bot], 0)

    A = ph["A"]
    mat0 = np.concatenate([rowp(A[:, X]), rowp(A[:, S] @ accel)], 1)
    mat0[3:, 3:] += kin
    Pm = np.concatenate([positions, rates], 0)  # (2nu, m): [y; y'] = Pm s
    dmat = rowp(np.einsum("iaj,jm->iam", ph["dA0"], positions))
    g0 = rowp(ph["g0"] @ Pm)
    g0[3:] += kin_rhs
    g1 = rowp(np.einsum("ija,jm->ima", ph["g1"], Pm))
    g2 = rowp(np.einsum("ijab,jm->imab", ph["g2"], Pm))
    f = lambda x: jnp.asarray(x, gamma_nominal.dtype)
    u = accel.shape[1]
    return _Poly(mat0=f(mat0), dmat=f(dmat), c0=f(rowp(ph["c0"])), c1=f(rowp(ph["c1"])), c2=f(rowp(ph["c2"])),
                 g0=f(g0), g1=f(g1), g2=f(g2), xh=f(np.zeros((3, u))))


@full_precision
def hybrid_model(
    model: Model,
    small,
    n_modes: int | None = None,
    *,
    cutoff: float | None = None,
    omega0=None,
    gamma=None,
    dcm=None,
    damping=None,
    form: str | None = None,
    precompute: bool | None = None,
    attitude: str | AbstractAttitude = "quaternion",
    rtol: float = 1e-9,
) -> HybridModel:
    """The hybrid-coordinate equations of `model` with the hinges of `small` (the set A) in
    truncated large-deformation modal coordinates (Eqs. 105-123).

    **Arguments:**

    - `small`: the set A (hinge indices 1..n or body names), see :func:`jaxtree.linearize`;
    - `n_modes`: number of retained modes (pairs in the first-order form), the lowest
      frequencies first; default all; `cutoff`: retain only modes with ``sigma <= cutoff``
      (both may be given);
    - `omega0`, `gamma`, `dcm`: the nominal motion on which ``I, J, K`` and the modes are
      computed (:func:`jaxtree.linearize`: ``omega0`` constant, the other hinges held at
      `gamma`); the small hinges' entries of `gamma` are the expansion point of Eq. (29);
    - `damping`: modal damping ratios ``zeta`` (scalar or one per retained mode), added after
      the transformation as in Sec. III E;
    - `form`: ``"real"`` (Eq. 121, needs real modes) or ``"first_order"`` (Eq. 118); default
      real when :func:`jaxtree.modes` finds real modes, else first order;
    - `precompute`: evaluate the constant-coefficient polynomial form once (only possible when
      the large variables are omega0 alone: no large or prescribed hinge, no external loads);
      default: whenever possible;
    - `attitude`: attitude variables of b_0 in the state (``"quaternion"``, ``"dcm"``,
      ``"euler123"``).

    Rigid (zero-frequency) modes have no first-order eigenvectors (Sec. III E, all-small case):
    the first-order form leaves them out.

    **Returns:** :class:`HybridModel`.
    """
    S = resolve_hinges(model, small)
    L = tuple(k for k in model.unknown_hinges if k not in S)
    dtype = jnp.result_type(model.mass)
    lin = linearize(model, S, omega0=omega0, gamma=gamma, dcm=dcm)
    md = _modes(lin, rtol=rtol)
    nu = len(S)
    if form is None:
        form = "real" if md.kind == "real" else "first_order"
    if form not in ("real", "first_order"):
        raise ValueError(f"hybrid_model: form must be 'real' or 'first_order', got {form!r}")
    if form == "real" and md.kind != "real":
        raise ModalError(f"hybrid_model: form='real' needs real modes (J = 0, K symmetric); the modes of the set A "
                         f"are {md.kind!r}. Use form='first_order' (Eq. 118).")
    sigma = np.asarray(md.frequencies)
    rigid = np.asarray(md.rigid)
    cand = list(range(nu)) if form == "real" else [j for j in range(nu) if not rigid[j]]
    if cutoff is not None:
        cand = [j for j in cand if sigma[j] <= float(cutoff)]
    if n_modes is not None:
        n_modes = int(n_modes)
        if n_modes < 1:
            raise ValueError(f"hybrid_model: n_modes must be >= 1, got {n_modes}")
        if n_modes > len(cand):
            raise ValueError(f"hybrid_model: {n_modes} modes asked for, only {len(cand)} available "
                             f"({nu} small hinges" + (", rigid modes left out of the first-order form" if
                                                      form == "first_order" and rigid.any() else "")
                             + (f", cutoff {cutoff}" if cutoff is not None else "") + ")")
        cand = cand[:n_modes]
    if not cand:
        raise ValueError("hybrid_model: no mode retained (check cutoff)")
    k = len(cand)
    sig = sigma[cand]
    zeta = np.zeros(k) if damping is None else np.broadcast_to(np.asarray(damping, float), (k,)).copy()
    if damping is not None:
        if np.any(zeta < 0) or not np.all(np.isfinite(zeta)):
            raise ValueError(f"hybrid_model: modal damping ratios must be finite and >= 0, got {zeta.tolist()}")
        if md.kind == "general":
            raise ModalError("hybrid_model: modal damping (Sec. III E) applies to undamped real or gyroscopic "
                             "modes; the modes of this set A already have a general J")
    I = np.asarray(lin.I)
    Kmat = np.asarray(lin.K)
    Z = np.zeros((nu, k))
    if form == "real":
        phi = np.asarray(md.shapes).real[:, cand]  # Eq. (119), phi^T I phi = U
        positions = np.concatenate([phi, Z], 1)
        rates = np.concatenate([Z, phi], 1)
        accel = rows = phi  # Eq. (121)
        kin = np.zeros((k, k))
        kin_rhs = np.concatenate([np.zeros((k, k)), -np.diag(2.0 * zeta * sig)], 1)  # Eq. (104)
        Ip = phi.T @ I
        project = np.block([[Ip, np.zeros_like(Ip)], [np.zeros_like(Ip), Ip]])
    else:
        scale = max(float(np.abs(np.asarray(md.eigenvalues)).max()), 1e-300)
        T, V = _real_pairs(md, cand, 1e-9 * scale)
        W = np.concatenate([Kmat.T @ V[:nu], V[nu:]], 0)  # left vectors of the unscaled rows (30d)
        Pu = np.block([[np.eye(nu), np.zeros((nu, nu))], [np.zeros((nu, nu)), I]])
        G = W.T @ Pu @ T
        W = W @ np.linalg.inv(G).T  # W^T diag(U, I) T = U (Eqs. 116-117)
        positions, rates = T[:nu], T[nu:]
        accel = rates  # y'' = Gamma_2 Phi_r Y_r'
        rows = W[nu:]
        kin = W[:nu].T @ positions  # kinematic rows of (30d): U y' = y'
        kin_rhs = W[:nu].T @ rates - np.diag(np.concatenate([zeta * sig, zeta * sig]))
        project = W.T @ Pu
    eps = np.asarray(model.topology.path_elements)
    terminal = not any(eps[s - 1, l] for s in S for l in L + tuple(model.prescribed))  # Sec. III A
    if precompute is None:
        precompute = not L and not model.prescribed and model.loads is None
    if precompute and (L or model.prescribed or model.loads is not None):
        raise ValueError("hybrid_model: precompute=True needs omega0 as the only large variable (no large or "
                         "prescribed hinge, no external loads); the coefficients then are polynomials in omega0")
    f = lambda x: jnp.asarray(x, dtype)
    parts = dict(positions=positions, rates=rates, accel=accel, rows=rows, kin=kin, kin_rhs=kin_rhs)
    w_nom = jnp.zeros(3, dtype) if omega0 is None else jnp.asarray(omega0, dtype)
    g_nom = jnp.zeros(model.n, dtype) if gamma is None else jnp.asarray(gamma, dtype)
    C_nom = jnp.eye(3, dtype=dtype) if dcm is None else jnp.asarray(dcm, dtype)
    poly = _build_poly(model, g_nom, S, C_nom, parts) if precompute else None
    hm = HybridModel(
        model=model, gamma_nominal=g_nom, omega0_nominal=w_nom, inertia=f(I), frequencies=f(sig),
        damping_ratios=f(zeta), positions=f(positions), rates=f(rates), accel=f(accel), rows=f(rows),
        kin=f(kin), kin_rhs=f(kin_rhs), project=f(project), keep=jnp.ones(k, dtype),
        modal_inverse=f(np.eye(accel.shape[1])) if terminal else None, poly=poly,
        attitude=get_attitude(attitude), small=S, large=L, form=form, kind=md.kind, mode_index=tuple(cand),
    )
    return _with_inverse(hm)


# ----------------------------------------------------------------------------- simulation
class HybridSolution(eqx.Module):
    """Time histories of :func:`simulate_hybrid` (rows: saved times).

    `ts` (T,); `omega0` (T, 3); `dcm` (T, 3, 3); `gamma`, `gamma_dot` (T, n): all hinges, the
    small ones rebuilt from the modal coordinates (Eqs. 111-112), prescribed ones from the
    prescription; `modal` (T, m): the modal coordinates; `ys` (T, size): the flat states;
    `t_final` (where the run stopped: `t1` unless it failed), `result` (:class:`diffrax.RESULTS`),
    `stats` (diffrax's step counts), `hybrid`, and at `t_final` the physical
    :class:`~jaxtree.State` `final` and the modal coordinates `final_modal`.
    """

    ts: jax.Array
    omega0: jax.Array
    dcm: jax.Array
    gamma: jax.Array
    gamma_dot: jax.Array
    modal: jax.Array
    ys: jax.Array
    t_final: jax.Array
    result: Any
    stats: dict
    hybrid: HybridModel
    final: State | None = None
    final_modal: jax.Array | None = None

    @property
    def ok(self) -> bool:
        return bool(np.all(np.asarray(self.result == dfx.RESULTS.successful)))


def _failure_code(result):
    """0 for success, else the ``Solution.failure`` code of :func:`jaxtree.simulate`."""
    from .simulate import _result_code

    return jnp.where(result == dfx.RESULTS.successful, 0, _result_code(result))


def _hybrid_failure_message(code, t, state, modal):
    """The report of failed hybrid runs (batch index, time, physical state, modal coordinates),
    or None when every run succeeded."""
    from .simulate import _MESSAGES, _failure_report

    np.set_printoptions(precision=6, suppress=False, linewidth=120)

    def describe(kind, pick):
        lines = [f"jaxtree.simulate_hybrid: {_MESSAGES[kind]}.", f"  stopped at t = {float(pick(t)):.9g}",
                 f"  omega0 = {pick(state.omega0)}", f"  gamma = {pick(state.gamma)}",
                 f"  gamma_dot = {pick(state.gamma_dot)}", f"  C = {pick(state.dcm).tolist()}",
                 f"  modal coordinates = {pick(modal)}"]
        if not all(np.all(np.isfinite(pick(x))) for x in state):
            lines.append("  diagnosis: the state is not finite")
        return "\n".join(lines)

    return _failure_report(code, describe)


@eqx.filter_jit
def _solve_hybrid(hybrid, y0, t0, t1, ts, rtol, atol, dt0, solver, controller, max_steps, report):
    if controller is None:
        controller = dfx.PIDController(rtol=rtol, atol=atol, pcoeff=0.3, icoeff=0.3,
                                       dtmin=1e-12 * jnp.abs(t1 - t0), force_dtmin=False)
    saveat = dfx.SaveAt(subs=(dfx.SubSaveAt(ts=ts), dfx.SubSaveAt(t1=True)))
    sol = dfx.diffeqsolve(
        dfx.ODETerm(hybrid_rhs), solver, t0, t1, dt0, y0, args=hybrid, saveat=saveat,
        stepsize_controller=controller, max_steps=max_steps, throw=False,
    )
    from .simulate import _last_finite

    (ts_h, ts_f), (ys_h, ys_f) = sol.ts, sol.ys
    i = _last_finite(ts_f)
    t_final, y_final = ts_f[i], ys_f[i]
    states = jax.vmap(hybrid.state)(ts_h, ys_h)
    final = hybrid.state(t_final, y_final)
    out = HybridSolution(
        ts=ts_h, omega0=states.omega0, dcm=states.dcm, gamma=states.gamma, gamma_dot=states.gamma_dot,
        modal=jax.vmap(hybrid.modal)(ys_h), ys=ys_h, t_final=t_final, result=sol.result,
        stats=dict(sol.stats), hybrid=hybrid, final=final, final_modal=hybrid.modal(y_final),
    )
    if report:
        # Under a caller's jit/vmap: report failures from one host callback (for a whole batch).
        from .simulate import SimulationError, _report

        def host(code, t, state, modal):
            message = _hybrid_failure_message(code, t, state, modal)
            if message is not None:
                raise SimulationError(message)

        _report(host, jax.lax.stop_gradient((_failure_code(sol.result), t_final, final, out.final_modal)))
    return out


@full_precision
def simulate_hybrid(
    hybrid: HybridModel,
    t1,
    *,
    t0=0.0,
    y0: State | jax.Array | None = None,
    saveat=101,
    solver: dfx.AbstractSolver | None = None,
    stepsize_controller: dfx.AbstractStepSizeController | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt0=None,
    max_steps: int = 200_000,
    throw: bool = True,
) -> HybridSolution:
    """Integrate the hybrid-coordinate equations with diffrax.

    - `y0`: a physical :class:`~jaxtree.State` (default ``hybrid.model.initial``), projected on
      the retained modes by :meth:`HybridModel.pack`, or a flat hybrid state;
    - `saveat`: a number of evenly spaced save times (default 101) or an array of times;
    - `solver`: default :class:`diffrax.Dopri8`; `stepsize_controller`: default a PID controller
      with `rtol`, `atol` (as :func:`jaxtree.simulate`: default :func:`jaxtree.default_tolerance`
      of the model's dtype); `dt0`: default ``1e-3 |t1 - t0|``.

    Raises :class:`jaxtree.SimulationError` when the run fails and `throw` is set, naming the
    time, the physical state and the modal coordinates where it stopped: at once when called
    eagerly, from a host callback at run time under ``jax.jit`` or ``jax.vmap`` (one for a whole
    batch). Tolerances, controllers and solvers may be traced (a vmapped tolerance sweep).
    """
    from .simulate import (SimulationError, _check_state, _check_times, _check_tolerances, _is_traced,
                           _warn_below_roundoff, default_tolerance)

    dtype = jnp.result_type(hybrid.model.mass)
    rtol = default_tolerance(dtype) if rtol is None else rtol
    atol = default_tolerance(dtype) if atol is None else atol
    _check_tolerances("simulate_hybrid", rtol, atol, max_steps)
    if stepsize_controller is None:
        _warn_below_roundoff(rtol, dtype, stacklevel=3)  # the caller of full_precision's wrapper
    y0 = hybrid.model.initial if y0 is None else y0
    if isinstance(y0, State):
        _check_state("simulate_hybrid", hybrid.model, y0)
    y = hybrid.pack(y0) if isinstance(y0, State) else jnp.asarray(y0, dtype)
    if y.shape != (hybrid.size,):
        raise ValueError(f"simulate_hybrid: flat state of size {hybrid.size} expected, got {y.shape}")
    if isinstance(saveat, (int, np.integer)) and not isinstance(saveat, bool):
        ts = jnp.linspace(jnp.asarray(t0, dtype), jnp.asarray(t1, dtype), int(saveat))
    else:
        ts = jnp.asarray(saveat, dtype)
    _check_times("simulate_hybrid", t0, t1, ts)
    t0a, t1a = jnp.asarray(t0, dtype), jnp.asarray(t1, dtype)
    dt0 = 1e-3 * (t1a - t0a) if dt0 is None else jnp.asarray(dt0, dtype)
    solver = dfx.Dopri8() if solver is None else solver
    traced = _is_traced((hybrid, y, t0a, t1a, ts, rtol, atol, dt0, solver, stepsize_controller))
    sol = _solve_hybrid(hybrid, y, t0a, t1a, ts, jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), dt0,
                        solver, stepsize_controller, int(max_steps), bool(throw and traced))
    if throw and not traced:
        message = _hybrid_failure_message(_failure_code(sol.result), sol.t_final, sol.final, sol.final_modal)
        if message is not None:
            raise SimulationError(message)
    return sol
