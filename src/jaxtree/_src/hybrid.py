"""Hybrid-coordinate equations in truncated large-deformation modal coordinates: Sec. III E of
Likins (1972), Eqs. (105)-(123).

The vehicle is split as in Sec. III A-B: the set A of *small* hinges (the even groups
``gamma^2, gamma^4, ...`` of Eq. 30c; ``nu`` of them) and the *large* variables (``omega0`` and
the hinges not in A, the odd groups). Eq. (30), the partially linearized Eq. (1), keeps the
large variables unrestricted and the small ones to first order. The small hinges fall into
*substructures* (connected groups, e.g. one wing: :func:`jaxtree.substructure.substructures`);
their constant-coefficient equations ``I y'' + J y' + K y = 0`` (Eq. 42 = Eq. 105 per group) give
the modes (:func:`jaxtree.modes`, Eqs. 70-104) that define the *large-deformation modal
coordinates*; keeping only some modes (truncation) gives the hybrid-coordinate equations:

- **real modes** (``J = 0``, ``K`` symmetric; Eqs. 119-121): ``y = phi_r eta_r``; the small-hinge
  columns of Eq. (30c) are post-multiplied by ``phi_r`` and its rows premultiplied by
  ``phi_r^T``; second order in ``eta_r``; modal damping ``-2 zeta sigma eta_r'`` added to
  ``phi_r^T R`` (end of Sec. III E, Eq. 104);
- **first-order modes** (gyroscopic or general ``J``, ``K``; Eqs. 106-118): the first-order form
  (30d) of the small rows, ``Gamma = [y; y'] = Phi_r Y_r`` (Eq. 109), columns post-multiplied by
  ``Phi_r`` (Eq. 115), rows premultiplied by the left eigenvectors (Eq. 117), truncation
  (Eq. 118); modal damping ``-zeta sigma Y_r`` (the replacement ``i sigma -> -zeta sigma + i
  sigma`` of Sec. III E, spinning case).

**Which modes.** By default (``basis="substructure"``) each substructure has its own modes, on its
own held base (its base body moving on the nominal motion: cantilever modes, with centrifugal
stiffening and Coriolis coupling when the nominal spins; :func:`jaxtree.substructure.held_base`),
and the number kept is chosen per substructure, a group of repeated frequencies kept whole.
``basis="set"`` takes the modes of the whole set A with the large variables held (Eq. 42 for A,
:func:`jaxtree.linearize`), the seed's single-appendage reading. With all modes retained both are
Eq. (30) in other coordinates (exactly, to round-off); truncation removes the modes left out.

**How many modes, and the error of those left out** (not in the seed, which leaves the choice to
the analyst). A substructure's small rows, Eq. (42) on its held base, are ``I y'' + J y' + K y =
f``, with ``f`` the generalized force of its base's motion (``-A0[y'', a_b] a_b`` of
:mod:`jaxtree.substructure` for a base acceleration ``a_b``, velocity products, loads). In the
modal coordinates of Eqs. (79)-(90) every mode is a decoupled first-order equation ``q_j' =
lambda_j q_j + (left vector)_j . f``; the quasi-static response of mode ``j`` is ``-q_j = d_j . f /
lambda_j`` (real modes: ``phi_j phi_j^T f / sigma_j^2``), and summed over all flexible modes it is
``K^{-1} f``.

- ``n_modes="auto"`` keeps, per substructure, the fewest lowest modes for which the neglected
  modes' share of the quasi-static response to each of the base's six unit accelerations
  (columns of ``A0[y'', a_b]``) is at most `tol` of the whole, in the largest angle (a direction
  counts when its whole response is not negligible: above 1e-8 of the largest, rotations per
  radius of gyration). The residual modal effective mass, the usual rule of structural
  dynamics, measures the base's reaction force and converges far more slowly than the angles
  (flex95's wings: 9 % of the translational effective mass left out at 3 modes per wing, where
  the angles are within 0.4 %); the quasi-static share tracks the angle error of a slew
  (flex95: 9.2, 2.1, 0.8 % at 1, 2, 3 modes per wing against errors of 7.8, 1.2, 0.36 % of the
  peak wing angle).
- :func:`simulate_hybrid` reports the neglected modes' contribution to the small angles along
  the run (`truncation`, its largest entry per save time `truncation_error`): the generalized
  force that the hybrid motion leaves unbalanced on the small rows of Eq. (1) (the
  mode-acceleration method: the inertia loads of the base's and the retained modes' accelerations,
  springs, velocity products) drives each neglected mode's equation, solved exactly for that
  force interpolated linearly between the save times, from the start's content of the mode. For
  modes fast against the forcing this is the quasi-static (static-correction) response
  `truncation_static`; for slow ones, which a slew excites dynamically (a long boom), the
  quasi-static response is off by factors up to 12 where the dynamic one is within 20 %.

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

**Two ways to evaluate Eq. (30).**

- *Precomputed* (every substructure terminal, no external load on a small body; the default then):
  each substructure's share of Eq. (1) is summarized once, in its base's frame, by the Taylor
  coefficients of :mod:`jaxtree.substructure`, projected on the retained modes. A right side
  evaluates Eq. (1) over the large bodies only (a Newton-Euler form with the translation of b_0,
  eliminated at the end as in Eq. 1), adds each substructure through its base's velocity and
  acceleration, and costs ``O(n_L^3 + k^2)``: nothing of the size of the small set. Large hinges
  (free, sprung, prescribed), loads on large bodies and a spinning nominal keep this cost.
- *General* (an internal substructure: a large hinge outboard of a small one): the bar parts are
  Eq. (1) at the small hinges' nominal angles and the caret parts its directional derivative along
  the current small displacement (one forward-mode ``jax.jvp`` of Eq. 1 per right side).

Both give the same equations to round-off (tests/test_hybrid.py). When the modal block of the
projected system is constant (all substructures terminal and on one base body: ``a_bar`` of the
small hinges is then constant, note to Eq. 30c), the linear system is solved by a Schur complement
on the ``3 + n_L`` large unknowns with that block's inverse precomputed.
"""

from __future__ import annotations

import warnings
from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from . import substructure as _sub
from ._checks import SceneError, SceneTypeError, as_float, as_int, short, tolerance
from ._hinges import prescribed_motion, selector
from ._integrate import (
    DEFAULT_MAX_STEPS,
    MESSAGES,
    Failure,
    SimulationError,
    check_state,
    check_times,
    default_controller,
    failure_report,
    integrate,
    is_traced,
    progress_meter,
    report_failures,
    result_code,
    solver_statistics,
    tolerances,
)
from ._math import build_jit
from .attitude import AbstractAttitude, attitude_argument, get_attitude
from .dynamics import _unbalanced, configuration, mass_matrix, rotational_equations
from .kinematics import ancestor_sum, body_rotations, cross, full_precision, mm, mv
from .linearize import linearize, linearize_args, resolve_hinges
from .model import Model, State
from .modes import ModalError, _check_modal_damping
from .modes import modes as _modes
from .spatial import force_cross, inertia_apply, inertia_matrix, motion_cross
from .topology import Topology


# ----------------------------------------------------------------------------- the model
class _Precomputed(eqx.Module):
    """Each substructure's share of Eq. (30), projected on the retained modes (see
    :mod:`jaxtree.substructure`), stacked over the ``p`` substructures. Rows ``i``: the base's six
    (rotation, translation) then the substructure's ``uS`` modal rows (padded); ``m``: its ``mS``
    modal coordinates s (padded); ``a``: the base's spatial axes (6); ``l``: the features
    ``psi = [v_b v_c (b <= c: 21), v (6), c (6), 1]`` of the base's velocity v and
    velocity-product acceleration c.

    - bias: ``bias0 . psi`` (bar part) + ``bias1 . (psi (x) s)`` (caret part): the velocity
      products ``g0 : v v / 2 + (g1 . s) : v v / 2 + (g2 . s) . v``, the matrix's action on c, and
      the springs ``w0 + w1 . s`` of the modal rows, in one product each;
    - matrix, base columns: ``mat0 + mat1 . s`` (p, 6 + uS, 6); base rows, modal columns: ``aw0``
      (p, 6, uS); modal-modal, all substructures: ``ww0`` (u, u);
    - static: `mcols`, `ucols` (the substructure's modal coordinates and rows in the global
      ones; padding points one past the end), `bases` (the body each hangs from).
    """

    bias0: jax.Array
    bias1: jax.Array
    mat0: jax.Array
    mat1: jax.Array
    aw0: jax.Array
    ww0: jax.Array
    mcols: tuple = eqx.field(static=True)
    ucols: tuple = eqx.field(static=True)
    bases: tuple = eqx.field(static=True)


# the products v_b v_c (b <= c) of a base's spatial velocity, then v, c and 1: the features psi
_PAIRS = np.triu_indices(6)
_FEATURES = len(_PAIRS[0]) + 6 + 6 + 1


def _stacked_terms(t: dict, xp=np) -> dict:
    """The arrays of :class:`_Precomputed` from the per-term stacks of :func:`_build_pre`
    (numpy, leading axis p)."""
    p, uS, mS = t["w1"].shape
    z = lambda *shape: xp.zeros((p, *shape))
    iu, ju = _PAIRS

    def pairs(g):  # g : v v / 2 over the 21 products v_b v_c, b <= c
        return (
            0.5
            * (g[:, :, iu, ju] + g[:, :, ju, iu])
            * np.where(iu == ju, 0.5, 1.0).reshape((1, 1, -1) + (1,) * (g.ndim - 4))
        )

    a0 = xp.concatenate([pairs(t["g0a"]), z(6, 6), t["aa0"], z(6, 1)], 2)
    w0 = xp.concatenate([pairs(t["g0w"]), z(uS, 6), t["wa0"], t["w0"][:, :, None]], 2)
    a1 = xp.concatenate([pairs(t["g1a"]), t["g2a"], t["aa1"], z(6, 1, mS)], 2)
    w1 = xp.concatenate([pairs(t["g1w"]), t["g2w"], t["wa1"], t["w1"][:, :, None, :]], 2)
    return {
        "bias0": xp.concatenate([a0, w0], 1),
        "bias1": xp.concatenate([a1, w1], 1).reshape(p, 6 + uS, _FEATURES * mS),
        "mat0": xp.concatenate([t["aa0"], t["wa0"]], 1),
        "mat1": xp.concatenate([t["aa1"], t["wa1"]], 1),
        "aw0": t["aw0"],
    }


class _Truncation(eqx.Module):
    """Every flexible mode of the substructures (or of the set A), retained or not, as a decoupled
    complex first-order coordinate for the truncation estimate (:func:`_truncation_estimate`):
    ``q_j' = lam_j q_j + d_j . f`` under a generalized force `f` (nu,) on the small rows, with the
    small angles ``y = Re(c q)``. Axis ``N``: the modes (both members of a first-order pair).

    - `c` (nu, N), `d` (N, nu), `lam` (N,) complex; `d0` (N, 2nu): ``q = d0 [y; y']`` (the
      modal content of a small motion); stored as real and imaginary parts along a last axis of
      2 (diffrax warns about complex leaves in its arguments);
    - `owner` (N,) int: the mode's index among the retained modes (``HybridModel.keep``), or -1
      for a mode left out when the model was built.
    """

    c_parts: jax.Array
    d_parts: jax.Array
    lam_parts: jax.Array
    d0_parts: jax.Array
    owner: jax.Array

    @property
    def c(self):
        return jax.lax.complex(self.c_parts[..., 0], self.c_parts[..., 1])

    @property
    def d(self):
        return jax.lax.complex(self.d_parts[..., 0], self.d_parts[..., 1])

    @property
    def lam(self):
        return jax.lax.complex(self.lam_parts[..., 0], self.lam_parts[..., 1])

    @property
    def d0(self):
        return jax.lax.complex(self.d0_parts[..., 0], self.d0_parts[..., 1])

    def weights(self, keep):
        """1 for a neglected mode (left out, or masked by :meth:`HybridModel.retain`), else 0."""
        kp = jnp.concatenate([keep, jnp.zeros(1, keep.dtype)])
        return jnp.where(self.owner < 0, 1.0, 1.0 - kp[self.owner]).astype(keep.dtype)

    def static(self, keep):
        """``(nu, nu)``: the quasi-static flexibility of the neglected modes, ``y_n = G f``."""
        w = self.weights(keep)
        return jnp.real((self.c * (w / -self.lam)[None, :]) @ self.d)


class HybridModel(eqx.Module):
    """The hybrid-coordinate equations of a vehicle (built by :func:`hybrid_model`).

    Array leaves:

    - `model`: the vehicle; `gamma_nominal` (n,), `omega0_nominal` (3,): the nominal motion the
      modes were computed on (the small hinges' entries of `gamma_nominal` are the expansion
      point ``gamma_bar`` of Eq. 29);
    - `inertia` (nu, nu): ``a_bar`` of the small hinges at the nominal motion (Eq. 36d; ``I`` of
      Eq. 42 for the set A);
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
      modes included), present when that block is constant (all substructures terminal and on
      one base body); the linear system is then solved by a Schur complement on the large
      unknowns only;
    - `pre`: the precomputed substructure terms (:class:`_Precomputed`), or None (general path);
    - `truncation`: every flexible mode of the substructures (retained or not) as a decoupled
      coordinate, for the truncation estimate of :func:`simulate_hybrid` (:class:`_Truncation`).

    Static: `small` (the set A), `large` (the large hinges in the state), `form`
    (``"real"``: Eq. 121; ``"first_order"``: Eq. 118), `kind` (of :func:`jaxtree.modes`; of the
    first substructure's modes when there are several), `mode_index` (each retained mode's index
    among its substructure's modes, or among the set's for ``basis="set"``), `mode_group` (the
    substructure of each retained mode), `groups` (the substructures), `basis` and the
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
    pre: _Precomputed | None
    attitude: AbstractAttitude
    small: tuple[int, ...] = eqx.field(static=True)
    large: tuple[int, ...] = eqx.field(static=True)
    form: str = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    mode_index: tuple[int, ...] = eqx.field(static=True)
    mode_group: tuple[int, ...] = eqx.field(static=True, default=())
    groups: tuple = eqx.field(static=True, default=())
    basis: str = eqx.field(static=True, default="set")
    truncation: _Truncation | None = None

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
    def modes_per_substructure(self) -> tuple[int, ...]:
        """Number of retained modes (pairs in the first-order form) of each substructure
        (``basis="substructure"``), or the total as a 1-tuple (``basis="set"``); modes masked by
        :meth:`retain` still count."""
        if self.basis == "set":
            return (self.n_modes,)
        return tuple(sum(1 for g in self.mode_group if g == i) for i in range(len(self.groups)))

    @property
    def u(self) -> int:
        """Number of modal unknowns of the linear system (k real form, 2k first-order form)."""
        return self.accel.shape[1]

    @property
    def size(self) -> int:
        return self.attitude.size + 3 + 2 * len(self.large) + self.m

    @property
    def precomputed(self) -> bool:
        """Whether a right side uses the precomputed substructure terms (cost independent of the
        number of small hinges) rather than a derivative of the whole Eq. (1)."""
        return self.pre is not None

    def _keep_u(self):
        return self.keep if self.form == "real" else jnp.concatenate([self.keep, self.keep])

    def _keep_m(self):
        return jnp.concatenate([self.keep, self.keep])

    # ------------------------------------------------------------------ state
    def unpack(self, y):
        """``(attitude, omega0, gamma_L, gamma_dot_L, s)`` slices of a flat state."""
        a, nl = self.attitude.size, len(self.large)
        o = np.cumsum([0, a, 3, nl, nl, self.m])
        return tuple(y[o[i] : o[i + 1]] for i in range(5))

    def _selectors(self, dtype):
        n = self.model.n
        sel = lambda hs: selector(n, hs, dtype)
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
        motion = prescribed_motion(self.model, t, dtype)
        if motion is None:
            return gamma, gamma_dot, None
        g, gd, gdd = motion
        return gamma + EG @ g, gamma_dot + EG @ gd, gdd

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
        return jnp.concatenate(
            [
                self.attitude.from_dcm(jnp.asarray(state.dcm, dtype)),
                jnp.asarray(state.omega0, dtype),
                gamma[L],
                gamma_dot[L],
                s,
            ]
        )

    def projection_residual(self, state: State):
        """The part of the small motion of `state` outside the retained modes:
        ``|[y; y'] - [positions; rates] s| / |[y; y']|`` with ``s`` the projection of
        :meth:`pack` (0 when the motion lies in the retained modes)."""
        dtype = jnp.result_type(self.model.mass)
        S = np.asarray(self.small, dtype=np.int64) - 1
        x = jnp.concatenate(
            [
                jnp.asarray(state.gamma, dtype)[S] - self.gamma_nominal.astype(dtype)[S],
                jnp.asarray(state.gamma_dot, dtype)[S],
            ]
        )
        s = self.pack(state)[self.size - self.m :] * self._keep_m().astype(dtype)
        back = jnp.concatenate([self.positions @ s, self.rates @ s])
        norm = jnp.sqrt(jnp.sum(x * x))
        return jnp.sqrt(jnp.sum((x - back) ** 2)) / jnp.maximum(norm, jnp.finfo(dtype).tiny)

    def modal(self, y):
        """The modal coordinates ``s`` of a flat state."""
        return self.unpack(y)[4]

    # ------------------------------------------------------------------ truncation
    def retain(self, n_modes: int) -> HybridModel:
        """The same model with only the first `n_modes` of its modes active (the others are
        masked: their coordinates stay zero and their rows read ``eta'' = 0``). Mathematically the
        truncation of Eq. (118)/(121) to `n_modes`; the array shapes are unchanged, so a compiled
        simulation is reused. For smaller arrays build a new model with ``n_modes``."""
        k = self.n_modes
        if not 1 <= int(n_modes) <= k:
            raise ValueError(f"retain: n_modes must be in 1..{k}, got {n_modes}")
        keep = jnp.asarray(np.arange(k) < int(n_modes), self.keep.dtype)
        return _with_inverse(eqx.tree_at(lambda h: h.keep, self, keep))


def _modal_block(hm: HybridModel):
    """The constant modal block ``kin + rows^T I accel`` (masked), when the projected small-small
    block of Eq. (30) is constant."""
    xp = jnp if is_traced(hm) else np  # numpy for a concrete model (built once, eagerly)
    keep = xp.asarray(hm.keep)
    ku = keep if hm.form == "real" else xp.concatenate([keep, keep])
    H = xp.asarray(hm.kin) + xp.asarray(hm.rows).T @ xp.asarray(hm.inertia) @ xp.asarray(hm.accel)
    return H * ku[:, None] * ku[None, :] + xp.diag(1.0 - ku)


def _with_inverse(hm: HybridModel) -> HybridModel:
    """Recompute `modal_inverse` for the current mask (eager)."""
    if hm.modal_inverse is None:
        return hm
    block = _modal_block(hm)
    inverse = jnp.linalg.inv(block) if is_traced(block) else jnp.asarray(np.linalg.inv(np.asarray(block)))
    return eqx.tree_at(lambda h: h.modal_inverse, hm, inverse)


# ----------------------------------------------------------------------------- precomputed path
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
    gam, gamd = gcol[order], gdcol[order]
    hk = np.asarray(hinges, np.int64) - 1
    axis = model.axis[hk].astype(dtype)
    R = body_rotations(topo, axis, gam)
    par = np.asarray(parents, np.int64)
    zero3 = jnp.zeros((1, 3), dtype)
    to_h = mv(R[par], model.hinge_on_parent[hk].astype(dtype))
    r = ancestor_sum(topo, jnp.concatenate([zero3, to_h - mv(R[1:], model.hinge_on_body[hk].astype(dtype))], 0))
    g = mv(R[par], axis)
    S = jnp.concatenate([g, cross(r[par] + to_h, g)], 1)  # (nh, 6) hinge motions
    v0 = jnp.concatenate([w, jnp.zeros(3, dtype)]) if v0 is None else v0
    vel = ancestor_sum(topo, jnp.concatenate([v0[None], S * gamd[:, None]], 0))
    cw, cu = motion_cross(vel[par, :3], vel[par, 3:], S[:, :3] * gamd[:, None], S[:, 3:] * gamd[:, None])
    c = jnp.concatenate([cw, cu], 1)  # (the prescribed accelerations enter through their columns of z)
    cbar = ancestor_sum(topo, jnp.concatenate([jnp.zeros((1, 6), dtype), c], 0))
    bidx = np.asarray(bodies, np.int64)
    mass = model.mass[bidx].astype(dtype)
    Jc = mm(mm(R, model.inertia[bidx].astype(dtype)), jnp.swapaxes(R, -1, -2))
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
    E = jnp.swapaxes(R[lbs], -1, -2)
    rb = r[lbs]
    Jb = _to_base(E, rb, Jac[lbs])
    vb = _to_base(E, rb, vel[lbs][..., None])[..., 0]
    cb = _to_base(E, rb, cbar[lbs][..., None])[..., 0]
    return A, b, Jb, vb, cb, gddP


def _inverse(order):
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    return inv


def _loads_state(hm, t, dcm, w, gL, gdL):
    """The physical state for the loads' law (small hinges at their nominal angles; loads act on
    large bodies only, whose forces do not depend on the small angles to the order kept)."""
    gamma, gamma_dot, _ = hm._large_configuration(t, gL, gdL)
    return State(dcm, w, gamma, gamma_dot)


def _pre_blocks(hm: HybridModel, t, y, with_ww: bool = True):
    """Eq. (30) from the precomputed substructure terms, its modal rows and columns in
    substructure order (``P = p * uS`` of them: substructure j's rows at ``j * uS ...``, padding
    rows zero; :func:`_substructure_order` maps them to the global ones).

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
    att, w, gL, gdL, s = hm.unpack(y)
    dtype = y.dtype
    s_in = s * hm._keep_m().astype(dtype)
    pre = hm.pre
    assert pre is not None, "called for a model with precomputed terms only"
    A, b, Jb, vb, cb, gddP = _large_frame(hm, pre.bases, t, hm.attitude.to_dcm(att), w, gL, gdL)
    p, uS = len(pre.bases), len(pre.ucols[0])
    sS = jnp.concatenate([s_in, jnp.zeros((1,), dtype)])[np.asarray(pre.mcols, np.int64)]  # (p, mS)
    # the substructures' forces on their bases (rows :6) and modal rows (6:), bar and caret parts
    iu, ju = _PAIRS
    psi = jnp.concatenate([vb[:, iu] * vb[:, ju], vb, cb, jnp.ones((p, 1), dtype)], 1)
    f0 = jnp.einsum("pil,pl->pi", pre.bias0, psi)
    f1 = jnp.einsum("pil,pl->pi", pre.bias1, (psi[:, :, None] * sS[:, None, :]).reshape(p, -1))
    B = jnp.stack([pre.mat0, jnp.einsum("pijm,pm->pij", pre.mat1, sS)])  # (2, p, 6 + uS, 6)
    X = jnp.einsum("xpia,pak->xpik", B, Jb)  # (2, p, 6 + uS, nz): bar and caret, base and modal rows
    Azz = jnp.stack([A, jnp.zeros_like(A)]) + jnp.einsum("pak,xpal->xkl", Jb, X[:, :, :6])
    Awz = X[:, :, 6:].reshape(2, p * uS, -1)
    Azw = jnp.einsum("pak,pau->kpu", Jb, pre.aw0).reshape(-1, p * uS)  # bar only (Eq. 30c)
    bz = jnp.stack([b, jnp.zeros_like(b)]) + jnp.einsum("pak,xpa->xk", Jb, jnp.stack([f0[:, :6], f1[:, :6]]))
    bw = jnp.stack([f0[:, 6:], f1[:, 6:]]).reshape(2, p * uS)
    # rows: the kept z rows, then the modal ones; eliminate the translation of b_0 (z 3..5)
    nL, nP = len(hm.large), len(hm.model.prescribed)
    nz = A.shape[0]
    Rz = np.concatenate([np.arange(3), np.arange(6, 6 + nL)])
    T = np.arange(3, 6)
    Kc = np.concatenate([np.arange(3), np.arange(6, nz)])
    A0, A1 = (jnp.concatenate([Azz[x][Rz], Awz[x]], 0) for x in (0, 1))  # (rows, nz)
    b0, b1 = (jnp.concatenate([bz[x][Rz], bw[x]]) for x in (0, 1))
    minv = 1.0 / jnp.sum(hm.model.mass.astype(dtype))
    A0T, A1T = Azz[0][T], Azz[1][T]  # the translation rows (3, nz)
    AK = A0[:, Kc] + A1[:, Kc] - minv * (A0[:, T] @ A0T[:, Kc] + A1[:, T] @ A0T[:, Kc] + A0[:, T] @ A1T[:, Kc])
    rhs = -(b0 + b1 - minv * (A0[:, T] @ bz[0][T] + A1[:, T] @ bz[0][T] + A0[:, T] @ bz[1][T]))
    nx = 3 + nL
    if nP:
        assert gddP is not None, "_large_frame returns the prescribed accelerations when there are some"
        rhs = rhs - AK[:, nx:] @ gddP
    Mxw = Azw[Rz] - minv * A0[:nx, T] @ Azw[T]
    Pww = A0[nx:, T] @ Azw[T] if with_ww else None
    return AK[:nx, :nx], Mxw, AK[nx:, :nx], Pww, rhs[:nx], rhs[nx:]


def _substructure_order(hm: HybridModel):
    """Static: ``(order (P,), partition)``: the global modal row of each substructure-ordered row
    (u, one past the end, for padding), and whether each global row belongs to one substructure
    (the substructure basis: the order is a permutation, see :func:`_solve`); with the set basis
    the substructures share the modes and their rows add up."""
    pre = hm.pre
    assert pre is not None
    order = np.asarray(pre.ucols, np.int64).reshape(-1)
    real = order[order < hm.u]
    return order, len(set(real.tolist())) == len(real)


def _pre_system(hm: HybridModel, t, y):
    """Eq. (118)/(121) from the precomputed substructure terms (:func:`_pre_blocks`) in the
    global order: ``(matrix, rhs)`` as :func:`_project` returns them from the general form."""
    Mxx, Mxw, Mwx, Pww, rx, rw = _pre_blocks(hm, t, y)
    order, _ = _substructure_order(hm)
    dtype = y.dtype
    U = np.zeros((len(order), hm.u + 1))
    U[np.arange(len(order)), order] = 1.0
    U = jnp.asarray(U[:, : hm.u], dtype)  # substructure rows -> global rows (summed)
    minv = 1.0 / jnp.sum(hm.model.mass.astype(dtype))
    s_in = hm.unpack(y)[4] * hm._keep_m().astype(dtype)
    assert hm.pre is not None and Pww is not None
    Mww = hm.pre.ww0 - minv * U.T @ Pww @ U + hm.kin
    mat = jnp.concatenate([jnp.concatenate([Mxx, Mxw @ U], 1), jnp.concatenate([U.T @ Mwx, Mww], 1)], 0)
    return mat, jnp.concatenate([rx, U.T @ rw + hm.kin_rhs @ s_in])


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


def _schur_solve(hinv, Mxx, Mxh, Mhx, rx, rh, xh=None):
    """Solve ``[[Mxx, Mxh], [Mhx, H]] [x; a] = [rx; rh]`` with ``H^{-1} = hinv`` known: a system of
    the size of the large unknowns only."""
    xh = Mxh @ hinv if xh is None else xh
    x = jnp.linalg.solve(Mxx - xh @ Mhx, rx - xh @ rh)
    return x, hinv @ (rh - Mhx @ x)


@full_precision
def hybrid_equations(hybrid: HybridModel, t, y):
    """The linear system of Eq. (118) (first-order form) or Eq. (121) (real form) at ``(t, y)``:
    ``(matrix, rhs)`` for the unknowns ``[omega0_dot, gamma_ddot_L, modal]`` (modal: ``eta_r''``
    or ``Y_r'``), masked modes included as ``1 * x = 0`` rows. For inspection and tests; the
    right-hand side :func:`hybrid_rhs` solves the same system."""
    if hybrid.pre is not None:
        mat, rhs = _pre_system(hybrid, t, y)
    else:
        att, w, gL, gdL, s = hybrid.unpack(y)
        s_in = s * hybrid._keep_m().astype(y.dtype)
        dcm = hybrid.attitude.to_dcm(att)
        Ml, Ms, R = _eq30(hybrid, t, dcm, w, gL, gdL, hybrid.positions @ s_in, hybrid.rates @ s_in)
        mat, rhs = _project(hybrid, Ml, Ms, R, s_in)
    return _mask(hybrid, mat, rhs)


def _solve(hm: HybridModel, t, y):
    """``(omega0_dot, gamma_ddot_L, modal accelerations)`` of Eq. (118)/(121)."""
    nx = 3 + len(hm.large)
    if hm.modal_inverse is None:
        mat, rhs = hybrid_equations(hm, t, y)
        x = jnp.linalg.solve(mat, rhs)
        return x[:3], x[3:nx], x[nx:]
    # constant modal block: a Schur complement on the large unknowns
    ku = hm._keep_u().astype(y.dtype)
    if hm.pre is not None and _substructure_order(hm)[1]:
        # in substructure order (no scatter of the substructures' rows): permute the constant
        # inverse and the spring rows instead, and the modal accelerations back
        Mxx, Mxw, Mwx, _, rx, rw = _pre_blocks(hm, t, y, with_ww=False)
        order, _ = _substructure_order(hm)
        pos = np.zeros(hm.u, np.int64)
        pos[order[order < hm.u]] = np.nonzero(order < hm.u)[0]
        s_in = hm.unpack(y)[4] * hm._keep_m().astype(y.dtype)
        pad = lambda v: jnp.concatenate([v, jnp.zeros((1,), y.dtype)])
        kp = pad(ku)[order]
        Hinv = jnp.pad(hm.modal_inverse, ((0, 1), (0, 1)))[np.ix_(order, order)]
        rw = (rw + pad(hm.kin_rhs @ s_in)[order]) * kp
        x, acc = _schur_solve(Hinv, Mxx, Mxw * kp[None, :], Mwx * kp[:, None], rx, rw)
        return x[:3], x[3:], acc[pos]
    if hm.pre is not None:
        mat, rhs = _pre_system(hm, t, y)
    else:
        att, w, gL, gdL, s = hm.unpack(y)
        s_in = s * hm._keep_m().astype(y.dtype)
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
    wd, gddL, acc = _solve(hm, t, y)
    if hm.form == "real":
        k = hm.n_modes
        ds = jnp.concatenate([s_in[k:], acc * hm.keep.astype(y.dtype)])
    else:
        ds = acc * km
    dy = jnp.concatenate([hm.attitude.rate(att, w), wd, gdL, gddL, ds])
    big = jnp.asarray(np.sqrt(np.finfo(np.dtype(y.dtype)).max), y.dtype)
    return jnp.where(jnp.isfinite(dy), dy, big)


# ----------------------------------------------------------------------------- construction
def _put(xp, a, idx, v, add: bool = False):
    """``a[idx] = v`` (or ``+=``) for numpy in place, for JAX as a functional update."""
    if xp is np:
        if add:
            a[idx] += v
        else:
            a[idx] = v
        return a
    return a.at[idx].add(v) if add else a.at[idx].set(v)


def _real_pairs(md, picked, tol, xp=np):
    """Real bases ``(right, left)`` (2nu, 2k) of the retained pairs: ``[Re Phi^j ..., Im Phi^j ...]``
    for complex pairs, ``[Phi^j ..., Phi^{j+nu} ...]`` for pairs of real eigenvalues. Traced
    (`xp` jnp, a differentiable build of real or gyroscopic modes): every pair is complex."""
    nu = md.nu
    R, Lf = xp.asarray(md.right), xp.asarray(md.left)
    lam = None if xp is jnp else np.asarray(md.eigenvalues)
    a_r, b_r, a_l, b_l = [], [], [], []
    for j in picked:
        if lam is None or abs(np.imag(lam[j])) > tol:
            a_r.append(xp.real(R[:, j]))
            b_r.append(xp.imag(R[:, j]))
            a_l.append(xp.real(Lf[:, j]))
            b_l.append(xp.imag(Lf[:, j]))
        else:
            a_r.append(xp.real(R[:, j]))
            b_r.append(xp.real(R[:, j + nu]))
            a_l.append(xp.real(Lf[:, j]))
            b_l.append(xp.real(Lf[:, j + nu]))
    return xp.stack(a_r + b_r, 1), xp.stack(a_l + b_l, 1)


# Frequencies within this relative distance of each other count as one repeated frequency: a
# truncation keeps or drops such a group whole (six identical wings give six-fold repeats that
# differ in the last digits; a cut inside them would pick members at random).
DEGENERATE_RTOL = 1e-6


def _time_scale(md, sigma: np.ndarray) -> np.ndarray:
    """Per mode, the rate that truncation ranks it by: its frequency, or for damped (complex) modes
    the largest ``|lambda|`` of its pair of eigenvalues. A damped mode's frequency ``|Im lambda|``
    alone would rank an overdamped pair (two real eigenvalues, frequency 0) first however fast it
    decays: a near-rigid, damped hinge's ``lambda = -1.5e5`` kept as the "lowest" mode made the
    truncated equations as stiff as the full ones (benchmarks/results/work_precision.md, stiff_1e6)."""
    lam = np.asarray(md.eigenvalues)
    nu = len(sigma)
    if md.kind != "general" or lam.shape != (2 * nu,):
        return sigma
    return np.maximum(np.abs(lam[:nu]), np.abs(lam[nu:]))


def _select(sigma, candidates, n, cutoff, where):
    """Indices of the retained modes among `candidates` (ascending rate, :func:`_time_scale`): those up to
    `cutoff`, the first `n` of them, and the rest of a repeated frequency the n-th belongs to."""
    cand = [j for j in candidates if cutoff is None or sigma[j] <= float(cutoff)]
    if n is not None:
        n = int(n)
        if n < 1:
            raise ValueError(f"hybrid_model: n_modes must be >= 1, got {n}")
        if n > len(cand):
            raise ValueError(
                f"hybrid_model: {n} modes asked for{where}, only {len(cand)} available"
                + (f" (cutoff {cutoff})" if cutoff is not None else "")
            )
        last = sigma[cand[n - 1]]
        while n < len(cand) and abs(sigma[cand[n]] - last) <= DEGENERATE_RTOL * max(abs(last), 1e-300):
            n += 1
        cand = cand[:n]
    return cand


def _modal_rep(md, I, K, idx, form, xp=np):
    """The modes `idx` (indices below nu, no rigid mode) as decoupled complex coordinates
    ``q' = lam q + d . f``, ``y = Re(c q)`` under a generalized force `f` on the rows of
    ``I y'' + J y' + K y = f``: ``(c (nu, N), d (N, nu), lam (N,), d0 (N, 2nu))`` with ``q = d0 [y;
    y']``.

    Real modes (``phi^T I phi = U``, Eq. 119): ``q = eta' + i sigma eta``, so ``q' = i sigma q +
    phi^T f`` and ``y = phi Im(q) / sigma``. First-order modes (Eqs. 70-90, ``Phi'^T P Phi = U``,
    ``Phi'^T Q Phi = Lambda``): ``Gamma = Phi Y``, ``Y' = Lambda Y + Phi'^T [0; f]``, both members
    of a pair kept (their sum is real)."""
    idx = np.asarray(idx, np.int64)
    nu = I.shape[0]
    if form == "real":
        phi = xp.real(xp.asarray(md.shapes))[:, idx]
        sig = xp.asarray(md.frequencies)[idx]
        d0 = xp.concatenate([1j * sig[:, None] * (phi.T @ I), phi.T @ I], 1)
        return -1j * phi / sig, phi.T.astype(complex), 1j * sig, d0
    jj = np.concatenate([idx, idx + nu])
    R, L = xp.asarray(md.right), xp.asarray(md.left)
    P = xp.block([[K, xp.zeros_like(K)], [xp.zeros_like(K), I]])
    return R[:nu, jj], L[nu:, jj].T, xp.asarray(md.eigenvalues)[jj], L[:, jj].T @ P


def _flexible(md):
    """The modes that have a static response (not rigid), in the order of :func:`jaxtree.modes`
    (all of them for a traced build, whose reference build had no rigid mode)."""
    if is_traced(md.rigid):
        return list(range(md.nu))
    rigid = np.asarray(md.rigid)
    return [j for j in range(md.nu) if not rigid[j]]


def _static_shares(md, I, K, modes, form, loads):
    """Per mode of `modes`: its quasi-static response ``(len(modes), nu, c)`` to the columns of
    `loads` (nu, c) (generalized forces on the rows; the pair of a first-order mode summed)."""
    if not modes:
        return np.zeros((0,) + loads.shape)
    c, d, lam, _ = _modal_rep(md, I, K, modes, form)
    per = np.real(np.einsum("iN,N,Nc->Nic", c, -1.0 / lam, d @ loads))
    if form != "real":
        per = per[: len(modes)] + per[len(modes) :]
    return per


def _auto_count(md, I, K, order, form, loads, scale, tol, where):
    """The fewest modes of `order` (ascending rate, cutoff applied) for which the neglected part of
    the quasi-static response to each base acceleration is at most `tol` of the whole (see
    :func:`hybrid_model`): a load column counts when its whole response, times `scale`, exceeds
    1e-8 of the largest. A repeated frequency is completed by :func:`_select`."""
    flex = _flexible(md)
    if not order:
        return 0
    shares = _static_shares(md, I, K, flex, form, loads)  # (F, nu, c)
    whole = np.abs(shares.sum(0)).max(0)  # (c,)
    size = whole * scale
    counted = size > 1e-8 * max(float(size.max()), 1e-300)
    if not counted.any():
        return 1
    pos = {j: i for i, j in enumerate(flex)}
    kept = np.zeros_like(shares[0])
    rest = shares.sum(0)
    for n, j in enumerate(order, start=1):
        if j in pos:
            kept = kept + shares[pos[j]]
        residual = np.abs(rest - kept).max(0)[counted] / whole[counted]
        if residual.max() <= tol:
            return n
    warnings.warn(
        f"hybrid_model: n_modes='auto' keeps all {len(order)} modes{where} below the cutoff; their "
        f"neglected quasi-static share is {residual.max():.2g} > tol {tol:g}",
        stacklevel=4,
    )
    return len(order)


def _base_loads(model, S, groups, tms, g_nom, basis):
    """Per system, the generalized forces on its small rows per unit acceleration of the base(s)
    (``A0[y'', a_b]`` of :mod:`jaxtree.substructure`: (nu_s, 6) per substructure, (nu, 6 p) for the
    set) and the columns' scales (rotations per radius of gyration of the substructure about
    its base, translations 1), so that the responses compare in angle per (m/s^2)."""
    out = []
    for tm in tms:
        A0 = np.asarray(tm.A0)
        mass = max(float(np.asarray(tm.mass)), 1e-300)
        rho = np.sqrt(max(float(np.trace(A0[:3, :3])) / (2.0 * mass), 1e-300))
        out.append((A0[6:, :6], np.concatenate([np.full(3, 1.0 / rho), np.ones(3)])))
    if basis == "substructure":
        return out
    nu = len(S)
    B = np.zeros((nu, 6 * len(groups)))
    for gi, (grp, (b, _)) in enumerate(zip(groups, out)):
        B[np.asarray([S.index(k) for k in grp.hinges], np.int64), 6 * gi : 6 * gi + 6] = b
    return [(B, np.concatenate([sc for _, sc in out]))]


def _truncation_terms(systems, mds, form, owners, nu, dtype) -> _Truncation:
    """:class:`_Truncation` of every flexible mode of the systems; `owners[(system, mode)]` is a
    retained mode's global index."""
    xp = jnp if is_traced(mds) else np
    cs, ds, lams, d0s, own = [], [], [], [], []
    for si, ((rows, I, _J, K, _), md) in enumerate(zip(systems, mds)):
        flex = _flexible(md)
        if not flex:
            continue
        c, d, lam, d0 = _modal_rep(md, I, K, flex, form, xp)
        r = np.asarray(rows, np.int64)
        C = _put(xp, xp.zeros((nu, len(lam)), complex), r, c)
        D = _put(xp, xp.zeros((len(lam), nu), complex), (slice(None), r), d)
        D0 = _put(xp, xp.zeros((len(lam), 2 * nu), complex), (slice(None), np.concatenate([r, nu + r])), d0)
        o = [owners.get((si, j), -1) for j in flex]
        cs.append(C)
        ds.append(D)
        lams.append(lam)
        d0s.append(D0)
        own.extend(o if form == "real" else o + o)
    f = lambda x: jnp.asarray(xp.stack([xp.real(x), xp.imag(x)], -1), dtype)
    if not cs:
        return _Truncation(
            f(np.zeros((nu, 0))), f(np.zeros((0, nu))), f(np.zeros(0)), f(np.zeros((0, 2 * nu))), jnp.zeros(0, int)
        )
    return _Truncation(
        c_parts=f(xp.concatenate(cs, 1)),
        d_parts=f(xp.concatenate(ds, 0)),
        lam_parts=f(xp.concatenate(lams)),
        d0_parts=f(xp.concatenate(d0s, 0)),
        owner=jnp.asarray(np.asarray(own, np.int64)),
    )


def _basis(md, I, K, cand, form, zeta, xp=np):
    """Modal matrices of the retained modes `cand` of one set of coordinates (module docstring):
    ``positions, rates (nu, m), accel, rows (nu, u), kin (u, u), kin_rhs (u, m), project (m, 2nu)``."""
    nu, k = I.shape[0], len(cand)
    sig = xp.asarray(md.frequencies)[np.asarray(cand, np.int64)]
    Z = xp.zeros((nu, k))
    if form == "real":
        phi = xp.real(xp.asarray(md.shapes))[:, np.asarray(cand, np.int64)]  # Eq. (119), phi^T I phi = U
        Ip = phi.T @ I
        return dict(
            positions=xp.concatenate([phi, Z], 1),
            rates=xp.concatenate([Z, phi], 1),
            accel=phi,
            rows=phi,
            kin=xp.zeros((k, k)),
            kin_rhs=xp.concatenate([xp.zeros((k, k)), -xp.diag(2.0 * zeta * sig)], 1),  # Eq. (104)
            project=xp.block([[Ip, xp.zeros_like(Ip)], [xp.zeros_like(Ip), Ip]]),
        )
    tol = 0.0 if xp is jnp else 1e-9 * max(float(np.abs(np.asarray(md.eigenvalues)).max()), 1e-300)
    T, V = _real_pairs(md, cand, tol, xp)
    W = xp.concatenate([K.T @ V[:nu], V[nu:]], 0)  # left vectors of the unscaled rows (30d)
    Pu = xp.block([[xp.eye(nu), xp.zeros((nu, nu))], [xp.zeros((nu, nu)), I]])
    W = W @ xp.linalg.inv(W.T @ Pu @ T).T  # W^T diag(U, I) T = U (Eqs. 116-117)
    positions, rates = T[:nu], T[nu:]
    return dict(
        positions=positions,
        rates=rates,
        accel=rates,
        rows=W[nu:],
        kin=W[:nu].T @ positions,
        kin_rhs=W[:nu].T @ rates - xp.diag(xp.concatenate([zeta * sig, zeta * sig])),
        project=W.T @ Pu,
    )


def _zeta(damping, k, kind):
    if damping is not None and np.ndim(damping) and np.shape(damping) != (k,):
        raise ValueError(
            f"hybrid_model: damping has {np.size(damping)} ratios for {k} retained modes "
            "(give a scalar or one per retained mode)"
        )
    zeta = np.zeros(k) if damping is None else np.broadcast_to(np.asarray(damping, float), (k,)).copy()
    if damping is not None:
        _check_modal_damping(zeta, kind, "hybrid_model", "Sec. III E", "the modes of this set A already have")
    return zeta


def _assemble(blocks, nu, form, order=None):
    """Global modal matrices from per-group blocks ``(rows of the set A, sigma, parts)``: the modes
    of all groups ordered by frequency (or as `order` gives, ``(_, group, local index)``: a traced
    build keeps its reference build's order); returns the matrices, the order ``(group, local
    index)`` and each group's global modal coordinates and rows."""
    xp = jnp if is_traced(blocks) else np
    if order is None:
        order = sorted(((float(sig[j]), g, j) for g, (_, sig, _) in enumerate(blocks) for j in range(len(sig))))
    k = len(order)
    u = k if form == "real" else 2 * k
    pos = {(g, j): q for q, (_, g, j) in enumerate(order)}
    out = dict(
        positions=xp.zeros((nu, 2 * k)),
        rates=xp.zeros((nu, 2 * k)),
        accel=xp.zeros((nu, u)),
        rows=xp.zeros((nu, u)),
        kin=xp.zeros((u, u)),
        kin_rhs=xp.zeros((u, 2 * k)),
        project=xp.zeros((2 * k, 2 * nu)),
    )
    mmaps, umaps = [], []
    for g, (rows, sig, p) in enumerate(blocks):
        kg = len(sig)
        q = np.asarray([pos[(g, j)] for j in range(kg)], np.int64)
        mm_ = np.concatenate([q, k + q])
        um = q if form == "real" else mm_
        r = np.asarray(rows, np.int64)
        at = {
            "positions": np.ix_(r, mm_),
            "rates": np.ix_(r, mm_),
            "accel": np.ix_(r, um),
            "rows": np.ix_(r, um),
            "kin": np.ix_(um, um),
            "kin_rhs": np.ix_(um, mm_),
            "project": np.ix_(mm_, np.concatenate([r, nu + r])),
        }
        for key, idx in at.items():
            out[key] = _put(xp, out[key], idx, p[key])
        mmaps.append(mm_)
        umaps.append(um)
    return out, [(g, j) for _, g, j in order], mmaps, umaps


def _build_pre(model, groups, tms, small, gamma_nominal, parts, mmaps, umaps, u, m):
    """The precomputed substructure terms (:class:`_Precomputed`), projected on the modes."""
    xp = jnp if is_traced((model, tms, parts)) else np
    ms, us = max(len(x) for x in mmaps), max(len(x) for x in umaps)
    keys = ("aa0", "aa1", "wa0", "wa1", "aw0", "g0a", "g1a", "g2a", "g0w", "g1w", "g2w", "w0", "w1")
    acc = {k: [] for k in keys}
    ww0 = xp.zeros((u, u))
    sprung = np.zeros(model.n)
    sprung[np.asarray(model.sprung, np.int64) - 1] = 1.0
    stiff = xp.asarray(model.stiffness) * sprung
    damp = xp.asarray(model.damping) * sprung
    for grp, tm, mc, uc in zip(groups, tms, mmaps, umaps):
        idx = np.asarray([small.index(k) for k in grp.hinges], np.int64)
        P = parts["positions"][np.ix_(idx, mc)]
        Q = parts["rates"][np.ix_(idx, mc)]
        Acc = parts["accel"][np.ix_(idx, uc)]
        Rw = parts["rows"][np.ix_(idx, uc)]
        A0, A1, G0, G1, G2 = (xp.asarray(x) for x in (tm.A0, tm.A1, tm.G0, tm.G1, tm.G2))
        h = np.asarray(grp.hinges, np.int64) - 1
        gbar = xp.asarray(gamma_nominal)[h]
        pad_m = lambda x: xp.concatenate([x, xp.zeros(x.shape[:-1] + (ms - x.shape[-1],))], -1)

        def pad_u(x, axis=0):
            width = [(0, 0)] * x.ndim
            width[axis] = (0, us - x.shape[axis])
            return xp.pad(x, width)

        acc["aa0"].append(A0[:6, :6])
        acc["aa1"].append(pad_m(A1[:6, :6] @ P))
        acc["wa0"].append(pad_u(Rw.T @ A0[6:, :6]))
        acc["wa1"].append(pad_u(pad_m(xp.einsum("ju,jak,km->uam", Rw, A1[6:, :6], P))))
        acc["aw0"].append(pad_u(A0[:6, 6:] @ Acc, 1))
        acc["g0a"].append(G0[:6])
        acc["g1a"].append(pad_m(G1[:6] @ P))
        acc["g2a"].append(pad_m(G2[:6] @ Q))
        acc["g0w"].append(pad_u(xp.einsum("ju,jbc->ubc", Rw, G0[6:])))
        acc["g1w"].append(pad_u(pad_m(xp.einsum("ju,jbck,km->ubcm", Rw, G1[6:], P))))
        acc["g2w"].append(pad_u(pad_m(xp.einsum("ju,jbk,km->ubm", Rw, G2[6:], Q))))
        acc["w0"].append(pad_u(Rw.T @ (stiff[h] * gbar)))  # -tau_S at y = 0 (a spring preload)
        acc["w1"].append(pad_u(pad_m(Rw.T @ (stiff[h][:, None] * P + damp[h][:, None] * Q))))
        ww0 = _put(xp, ww0, np.ix_(uc, uc), Rw.T @ A0[6:, 6:] @ Acc, add=True)
    dtype = jnp.result_type(model.mass)
    pad_idx = lambda x, n, width: tuple(tuple(int(i) for i in c) + (n,) * (width - len(c)) for c in x)
    return _Precomputed(
        **{k: jnp.asarray(v, dtype) for k, v in _stacked_terms({k: xp.stack(v) for k, v in acc.items()}, xp).items()},
        ww0=jnp.asarray(ww0, dtype),
        mcols=pad_idx(mmaps, m, ms),
        ucols=pad_idx(umaps, u, us),
        bases=tuple(g.base for g in groups),
    )


def _nominal_motion(model, omega0, gamma, dcm):
    dtype = jnp.result_type(model.mass)
    # numpy defaults: an eager jnp.zeros compiles a program on a build's first call
    w = np.zeros(3, dtype) if omega0 is None else omega0
    g = np.zeros(model.n, dtype) if gamma is None else gamma
    C = np.eye(3, dtype=dtype) if dcm is None else dcm
    return tuple(x.astype(dtype) if is_traced(x) else jnp.asarray(np.asarray(x, dtype)) for x in (w, g, C))


def _hybrid_model_args(
    model,
    small,
    n_modes=None,
    *,
    cutoff=None,
    omega0=None,
    gamma=None,
    dcm=None,
    damping=None,
    form=None,
    precompute=None,
    attitude: object = "quaternion",
    rtol=1e-9,
    basis=None,
    tol=1e-2,
):
    """Arguments of :func:`jaxtree.hybrid_model`, checked before the linearization is traced."""
    name = "hybrid_model"
    linearize_args(name, model, small, omega0=omega0, gamma=gamma, dcm=dcm)
    if getattr(model, "law", None) is not None or getattr(model, "controller", None) is not None:
        raise SceneError(
            f"{name}: the model carries hinge control laws (model.law / model.controller, from its scene's "
            "'control'), which the hybrid equations do not include; drop them with model.with_control(None, None)"
        )
    if basis is not None and basis not in ("substructure", "set"):
        raise SceneError(f"{name}: basis must be 'substructure', 'set' or None, got {short(basis)}")
    t = float(as_float(tol, f"{name}: tol", ()))
    if not t > 0.0:
        raise SceneError(f"{name}: tol must be positive (the neglected share of the quasi-static response), got {t}")
    if isinstance(n_modes, str):
        if n_modes != "auto":
            raise SceneError(
                f"{name}: n_modes must be an integer, a sequence of integers, 'auto' or None, got {short(n_modes)}"
            )
    elif n_modes is not None:
        if isinstance(n_modes, (list, tuple)):  # one number per substructure
            if not n_modes:
                raise SceneError(f"{name}: n_modes is an empty sequence")
            for i, m in enumerate(n_modes):
                as_int(m, f"{name}: n_modes[{i}]", minimum=1)
        else:
            as_int(n_modes, f"{name}: n_modes", minimum=1)
    if cutoff is not None:
        c = float(as_float(cutoff, f"{name}: cutoff", ()))
        if c < 0:
            raise SceneError(f"{name}: cutoff must be >= 0 (a frequency in rad/s), got {c}")
    if damping is not None:
        z = as_float(damping, f"{name}: damping")
        nu = len((small,) if isinstance(small, (str, int, np.integer)) else list(small))
        # at most one mode per small hinge is retained (the exact number is known after the modes)
        if z.ndim > 1 or (z.ndim == 1 and z.shape[0] != 1 and z.shape[0] > nu):
            raise SceneError(
                f"{name}: damping must be a scalar or one ratio per retained mode (at most {nu}), got shape {z.shape}"
            )
        if np.any(z < 0):
            raise SceneError(f"{name}: modal damping ratios must be >= 0, got {z.tolist()}")
    if form is not None and form not in ("real", "first_order"):
        raise SceneError(f"{name}: form must be 'real', 'first_order' or None, got {short(form)}")
    if precompute is not None and not isinstance(precompute, (bool, np.bool_)):
        raise SceneTypeError(f"{name}: precompute must be True, False or None, got {short(precompute)}")
    attitude_argument(name, attitude)
    tolerance(name, rtol)


@full_precision
def hybrid_model(
    model: Model,
    small,
    n_modes=None,
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
    basis: str | None = None,
    tol: float = 1e-2,
    like: HybridModel | None = None,
) -> HybridModel:
    """The hybrid-coordinate equations of `model` with the hinges of `small` (the set A) in
    truncated large-deformation modal coordinates (Eqs. 105-123).

    **Arguments:**

    - `small`: the set A (hinge indices 1..n or body names), see :func:`jaxtree.linearize`;
      it is split into substructures (connected groups of small hinges, e.g. one wing);
    - `basis`: ``"substructure"`` (default when every substructure is terminal): each
      substructure's own modes on its held base; ``"set"`` (default otherwise): the modes of the
      whole set A with the large variables held (Eq. 42 for A);
    - `n_modes`: modes retained, the lowest frequencies first: a number per substructure (an
      int for each, or a sequence with one entry per substructure) with the substructure basis,
      the total with the set basis; default all; `cutoff`: retain only modes with
      ``sigma <= cutoff``. A repeated frequency is kept whole;
    - ``n_modes="auto"``: per substructure (per set with ``basis="set"``) the fewest lowest modes
      whose neglected part of the quasi-static response to the base's motion is at most `tol`
      (default 1e-2): for each of the six unit accelerations of the base (rotations and
      translations of the body it hangs from, ``A0[y'', a_b]`` of
      :mod:`jaxtree.substructure`) that moves it, the largest angle of the neglected modes'
      static response (``sum_j phi_j phi_j^T f / sigma_j^2``, the first-order modes of Eqs.
      79-90 likewise) over the largest angle of the whole (``K^{-1} f``, Eq. 42 on the held
      base). Rigid modes are kept when they rank first; a cutoff limits the choice (a warning
      when `tol` cannot be met below it). The module docstring compares this rule with the
      residual modal effective mass;
    - `omega0`, `gamma`, `dcm`: the nominal motion on which the modes are computed (``omega0``
      constant, the other hinges held at `gamma`, a steady spin about the system mass center);
      the small hinges' entries of `gamma` are the expansion point of Eq. (29);
    - `damping`: modal damping ratios ``zeta`` (scalar or one per retained mode), added after
      the transformation as in Sec. III E;
    - `form`: ``"real"`` (Eq. 121, needs real modes) or ``"first_order"`` (Eq. 118); default
      real when every substructure's modes are real, else first order;
    - `precompute`: evaluate Eq. (30) from the precomputed substructure terms (a right side's
      cost independent of the number of small hinges); possible when every substructure is
      terminal and no external load acts on a small body; default: whenever possible;
    - `attitude`: attitude variables of b_0 in the state (``"quaternion"``, ``"dcm"``,
      ``"euler123"``).

    - `like`: a hybrid model of the same vehicle and set A (built from concrete values): its
      retained modes (indices in each substructure's modes, global order), basis, form and
      precomputation are kept, and `n_modes`, `cutoff`, `tol`, `basis`, `form`, `precompute`
      are ignored. This makes the build differentiable: under ``jax.grad`` (or ``jvp``) with
      respect to the model's parameters (stiffness, masses, geometry) or the nominal motion, the
      modes are recomputed from the traced matrices (``jnp``) with the selection fixed. Damped
      (general) modes are differentiated by JAX's eigenvector derivatives, which need every mode
      underdamped and distinct within its substructure (checked on `like`); rigid modes of the
      reference are not supported in a traced build.

    Rigid (zero-frequency) modes have no first-order eigenvectors (Sec. III E, all-small case):
    the first-order form leaves them out.

    **Returns:** :class:`HybridModel`.
    """
    _hybrid_model_args(
        model,
        small,
        n_modes,
        cutoff=cutoff,
        omega0=omega0,
        gamma=gamma,
        dcm=dcm,
        damping=damping,
        form=form,
        precompute=precompute,
        attitude=attitude,
        rtol=rtol,
        basis=basis,
        tol=tol,
    )
    S = resolve_hinges(model, small)
    groups = _sub.substructures(model, S)
    traced = is_traced((model, omega0, gamma, dcm))
    if like is not None:
        _check_like(like, S, groups)
        basis, precompute, form = like.basis, like.precomputed, like.form
    elif traced:
        raise ValueError(
            "hybrid_model: the model or the nominal motion is traced (jax.grad, jvp, vmap): pass "
            "like=<hybrid_model of the same vehicle built from concrete values> to fix the retained modes"
        )
    basis, precompute = _basis_and_precompute(model, S, groups, basis, precompute)
    if form not in (None, "real", "first_order"):
        raise ValueError(f"hybrid_model: form must be 'real' or 'first_order', got {form!r}")
    w_nom, g_nom, _ = _nominal_motion(model, omega0, gamma, dcm)
    tms = [_sub.terms(model, g, g_nom) for g in groups] if (precompute or basis == "substructure") else None
    if basis == "set":
        lin = linearize(model, S, omega0=omega0, gamma=gamma, dcm=dcm)
        xp = jnp if is_traced(lin) else np
        systems = [(tuple(range(len(S))), xp.asarray(lin.I), xp.asarray(lin.J), xp.asarray(lin.K), lin.coordinates)]
    else:
        assert tms is not None, "computed for the substructure basis"
        systems = _substructure_systems(model, S, groups, tms, g_nom, w_nom)
    if is_traced(systems):
        assert like is not None, "checked above"
        lam_ref = np.asarray(like.truncation.lam_parts) if like.truncation is not None else np.zeros((0, 2))
        if like.kind == "general" and np.any(np.abs(lam_ref[:, 1]) <= 1e-9 * np.abs(lam_ref).max(initial=1.0)):
            raise ValueError(
                "hybrid_model: a traced build of general (damped) modes needs every mode underdamped (complex "
                "pairs); the reference build has an overdamped mode (a pair of real eigenvalues)"
            )
        mds = [_modes(I, J, K, kind=like.kind, rtol=rtol) for (_, I, J, K, _lab) in systems]
    else:
        mds = [_modes(I, J, K, labels=lab, rtol=rtol) for (_, I, J, K, lab) in systems]
    kinds = [md.kind for md in mds]
    if form is None:
        form = "real" if all(kd == "real" for kd in kinds) else "first_order"
    if form == "real" and any(kd != "real" for kd in kinds):
        bad = next(kd for kd in kinds if kd != "real")
        raise ModalError(
            f"hybrid_model: form='real' needs real modes (J = 0, K symmetric); the modes of the set A "
            f"are {bad!r}. Use form='first_order' (Eq. 118)."
        )
    order = None
    if like is not None:
        blocks, picked, order = _retained_like(like, systems, mds)
    else:
        loads = None
        if isinstance(n_modes, str):  # "auto"
            tms_all = tms if tms is not None else [_sub.terms(model, g, g_nom) for g in groups]
            loads = _base_loads(model, S, groups, tms_all, g_nom, basis)
        blocks, picked = _retained_modes(model, groups, systems, mds, n_modes, cutoff, form, basis, loads, float(tol))
    zeta = _zeta(
        damping,
        sum(len(b[1]) for b in blocks),
        kinds[0] if len(set(kinds)) == 1 else "general" if "general" in kinds else kinds[0],
    )
    return _assemble_model(
        model,
        S,
        groups,
        tms,
        w_nom,
        g_nom,
        blocks,
        picked,
        zeta,
        form,
        kinds[0],
        precompute,
        basis,
        attitude,
        systems,
        mds,
        order,
    )


def _check_like(like, S, groups) -> None:
    """`like` of :func:`hybrid_model` describes the same set A and substructures."""
    if not isinstance(like, HybridModel):
        raise TypeError(f"hybrid_model: like must be a HybridModel, got {type(like).__name__}")
    if tuple(like.small) != tuple(S) or tuple(like.groups) != tuple(groups):
        raise ValueError(
            f"hybrid_model: like was built for the small hinges {like.small}, not {tuple(S)} (or other substructures)"
        )


def _retained_like(like: HybridModel, systems, mds):
    """The retained modes of a reference build `like` (:func:`_retained_modes`' blocks and picks)
    and its global order of the modes, ``(_, block, local index)`` (see :func:`_assemble_model`)."""
    per: dict[int, list[int]] = {}
    for gi, j in zip(like.mode_group, like.mode_index):
        per.setdefault(int(gi), []).append(int(j))
    blocks, picked = [], []
    for gi in sorted(per):
        rows, I, _J, K, _ = systems[gi]
        md = mds[gi]
        cand = sorted(per[gi])
        xp = jnp if is_traced(md) else np
        blocks.append((rows, xp.asarray(md.frequencies)[np.asarray(cand, np.int64)], cand, md, I, K))
        picked.append((gi, cand))
    position = {gi: b for b, (gi, _) in enumerate(picked)}
    order = [
        (q, position[int(gi)], picked[position[int(gi)]][1].index(int(j)))
        for q, (gi, j) in enumerate(zip(like.mode_group, like.mode_index))
    ]
    return blocks, picked, order


def _basis_and_precompute(model: Model, S, groups, basis: str | None, precompute: bool | None) -> tuple[str, bool]:
    """The modal basis and whether to precompute the substructure terms (defaults and checks)."""
    terminal = all(g.terminal for g in groups)
    small_bodies = set(S)
    loads_small = model.loads is not None and any(int(b) in small_bodies for b in model.loads.bodies)
    if basis is None:
        basis = "substructure" if terminal else "set"
    if basis not in ("substructure", "set"):
        raise ValueError(f"hybrid_model: basis must be 'substructure' or 'set', got {basis!r}")
    if basis == "substructure" and not terminal:
        raise ValueError(
            "hybrid_model: basis='substructure' needs every substructure terminal (no large or "
            "prescribed hinge outboard of a small one); use basis='set'"
        )
    possible = terminal and not loads_small
    if precompute is None:
        precompute = possible
    if precompute and not possible:
        raise ValueError(
            "hybrid_model: precompute=True needs every substructure terminal (no large or prescribed "
            "hinge outboard of a small one) and no external load on a small body"
            + ("; the loads act on small bodies" if loads_small else "")
        )
    return basis, precompute


@build_jit
def _nominal_frames(model: Model, g_nom, w_nom, bases: tuple, small: tuple):
    """The nominal vehicle at angles `g_nom` spinning at `w_nom` about its mass center, large and
    prescribed hinges held: each base's spatial velocity ``(p, 6)`` in its frame about its mass
    center (:func:`_large_frame`'s convention), and ``a_bar`` of the small hinges (Eq. 36d, the
    small rows and columns of Eq. 1's matrix), in one compilation for the build."""
    cfg = configuration(model, g_nom)
    b = np.asarray(bases, np.int64)
    r = cfg.rho[b] - cfg.rho[0]  # the bases' mass centers from b_0's, {b^0}
    E = jnp.swapaxes(cfg.R[b], -1, -2)  # {b^0} -> the base's frame
    u0 = cross(-cfg.rho[0], w_nom)  # b_0's mass center in the spin about the system's
    vb = jnp.concatenate([mv(E, w_nom), mv(E, u0 + cross(w_nom, r))], -1)
    S = np.asarray(small, np.int64) + 2
    return vb, mass_matrix(model, g_nom)[np.ix_(S, S)]


def _substructure_systems(model: Model, S, groups, tms, g_nom, w_nom) -> list:
    """Eq. (42) of each substructure on its held base in the nominal spin about the system mass
    center: ``(rows in A, I, J, K, coordinate names)`` per substructure."""
    vb, _ = _nominal_frames(model, g_nom, w_nom, tuple(g.base for g in groups), tuple(S))
    # numpy for a concrete model; jnp where a parameter is traced (a differentiable build)
    xp = jnp if is_traced((model, tms, vb)) else np
    vb = xp.asarray(vb)
    sprung = np.zeros(model.n)
    sprung[np.asarray(model.sprung, np.int64) - 1] = 1.0
    stiffness, damping = xp.asarray(model.stiffness) * sprung, xp.asarray(model.damping) * sprung
    systems = []
    for grp, tm, vg in zip(groups, tms, vb):
        h = np.asarray(grp.hinges, np.int64) - 1
        # steady spin: no spatial acceleration of the base
        I, J, K = _sub.held_base(tm, vg, xp.zeros(6), stiffness[h], damping[h], xp=xp)
        rows = tuple(S.index(k) for k in grp.hinges)
        systems.append((rows, I, J, K, tuple(model.names[k] for k in grp.hinges)))
    return systems


def _retained_modes(
    model: Model, groups, systems, mds, n_modes, cutoff, form: str, basis: str, loads=None, tol: float = 1e-2
):
    """The retained modes of each system (:func:`_select`; :func:`_auto_count` for ``n_modes =
    "auto"`` with the systems' base `loads`): ``blocks`` of ``(rows, sigma, indices, modes, I, K)``
    for the systems that keep some, and ``picked``, ``(system, indices)`` of each."""
    auto = isinstance(n_modes, str)
    if basis == "substructure" and n_modes is not None and not auto and not isinstance(n_modes, (int, np.integer)):
        per = list(n_modes)
        if len(per) != len(groups):
            raise ValueError(f"hybrid_model: n_modes has {len(per)} entries for {len(groups)} substructures")
    else:
        per = [n_modes] * len(mds)
    blocks, picked = [], []
    for gi, ((rows, I, _J, K, _), md, n) in enumerate(zip(systems, mds, per)):
        sigma = np.asarray(md.frequencies)
        rigid = np.asarray(md.rigid)
        cands = list(range(len(sigma))) if form == "real" else [j for j in range(len(sigma)) if not rigid[j]]
        where = "" if basis == "set" else f" for substructure {gi} (from hinge {model.names[groups[gi].hinges[0]]!r})"
        if form == "first_order" and rigid.any():
            where += " (rigid modes left out of the first-order form)"
        rank = _time_scale(md, sigma)
        if auto:
            assert loads is not None, "the base loads are computed for n_modes='auto'"
            order = [j for j in sorted(cands, key=lambda j: rank[j]) if cutoff is None or rank[j] <= float(cutoff)]
            B, scale = loads[gi]
            n = _auto_count(md, I, K, order, form, B, scale, tol, where)
        cand = sorted(_select(rank, sorted(cands, key=lambda j: rank[j]), n, cutoff, where))
        if not cand:
            continue
        picked.append((gi, cand))
        blocks.append((rows, sigma[cand], cand, md, I, K))
    if not blocks:
        raise ValueError("hybrid_model: no mode retained (check cutoff)")
    return blocks, picked


def _assemble_model(
    model,
    S,
    groups,
    tms,
    w_nom,
    g_nom,
    blocks,
    picked,
    zeta,
    form,
    kind,
    precompute,
    basis,
    attitude,
    systems,
    mds,
    order=None,
):
    """The :class:`HybridModel` of the retained modes: their modal matrices assembled over the set
    A in ascending frequency (or in `order`, ``(_, block, local index)``, that of a reference
    build), the modal damping `zeta` (in that order), the precomputed terms."""
    nu = len(S)
    dtype = jnp.result_type(model.mass)
    xp = jnp if is_traced(blocks) else np
    # modal damping follows the global (frequency) order of the modes: split it by group afterwards
    if order is None:
        order = sorted(((float(sig[j]), g, j) for g, (_, sig, *_r) in enumerate(blocks) for j in range(len(sig))))
    zg = [np.zeros(len(b[1])) for b in blocks]
    for q, (_, g, j) in enumerate(order):
        zg[g][j] = zeta[q]
    parts_g = [
        (rows, sig, _basis(md, I, K, cand, form, zg[g], xp)) for g, (rows, sig, cand, md, I, K) in enumerate(blocks)
    ]
    parts, mode_order, mmaps, umaps = _assemble(parts_g, nu, form, order)
    mode_index = tuple(int(blocks[g][2][j]) for g, j in mode_order)
    group_of = [picked[g][0] for g in range(len(blocks))]
    owners = {(group_of[g], int(blocks[g][2][j])): q for q, (g, j) in enumerate(mode_order)}
    f = lambda x: jnp.asarray(x, dtype)
    u = parts["accel"].shape[1]
    pre = _precomputed_terms(model, groups, tms, S, g_nom, parts, group_of, mmaps, umaps, basis) if precompute else None
    one_base = len({g.base for g in groups}) == 1
    _, inertia = _nominal_frames(model, g_nom, w_nom, tuple(g.base for g in groups), tuple(S))
    hm = HybridModel(
        model=model,
        gamma_nominal=g_nom,
        omega0_nominal=w_nom,
        inertia=f(inertia),
        frequencies=f(xp.stack([blocks[g][1][j] for g, j in mode_order])),
        damping_ratios=f(np.asarray([zg[g][j] for g, j in mode_order])),
        positions=f(parts["positions"]),
        rates=f(parts["rates"]),
        accel=f(parts["accel"]),
        rows=f(parts["rows"]),
        kin=f(parts["kin"]),
        kin_rhs=f(parts["kin_rhs"]),
        project=f(parts["project"]),
        keep=jnp.ones(len(mode_index), dtype),
        modal_inverse=f(np.eye(u)) if (all(g.terminal for g in groups) and one_base) else None,
        pre=pre,
        attitude=get_attitude(attitude),
        small=S,
        large=tuple(k for k in model.unknown_hinges if k not in S),
        form=form,
        kind=kind,
        mode_index=mode_index,
        mode_group=tuple(int(group_of[g]) for g, _ in mode_order),
        groups=groups,
        basis=basis,
        truncation=_truncation_terms(systems, mds, form, owners, nu, dtype),
    )
    return _with_inverse(hm)


def _precomputed_terms(model, groups, tms, S, g_nom, parts, group_of, mmaps, umaps, basis):
    """:func:`_build_pre` with each substructure's modal columns: every substructure, also one
    with no retained mode (its mass still moves with its base)."""
    u, m = parts["accel"].shape[1], parts["positions"].shape[1]
    gm, gu = [], []
    for gi in range(len(groups)):
        if gi in group_of:
            gm.append(mmaps[group_of.index(gi)])
            gu.append(umaps[group_of.index(gi)])
        else:
            gm.append(np.zeros(0, np.int64))
            gu.append(np.zeros(0, np.int64))
    if basis == "set":  # the set's modes span every substructure
        gm = [np.arange(m)] * len(groups)
        gu = [np.arange(u)] * len(groups)
    return _build_pre(model, groups, tms, S, g_nom, parts, gm, gu, u, m)


class _HeldPrescription(eqx.Module):
    """A prescription that holds its hinges at fixed angles (rates and accelerations zero)."""

    hinges: tuple = eqx.field(static=True)
    value: jax.Array

    def derivatives(self, t):
        z = jnp.zeros_like(self.value)
        return self.value, z, z


def _held_prescription(hm: HybridModel) -> HybridModel:
    """The same hybrid model with its prescribed hinges held at their nominal angles, as
    :func:`jaxtree.linearize` holds them for the modes."""
    model = hm.model
    if model.prescription is None:
        return hm
    values = hm.gamma_nominal[np.asarray(model.prescribed, np.int64) - 1]
    held = eqx.tree_at(lambda m: m.prescription, model, _HeldPrescription(model.prescribed, values))
    return eqx.tree_at(lambda h: h.model, hm, held)


# ----------------------------------------------------------------------------- simulation
class HybridSolution(eqx.Module):
    """Time histories of :func:`simulate_hybrid` (rows: saved times).

    `ts` (T,); `omega0` (T, 3); `dcm` (T, 3, 3); `gamma`, `gamma_dot` (T, n): all hinges, the
    small ones rebuilt from the modal coordinates (Eqs. 111-112), prescribed ones from the
    prescription; `modal` (T, m): the modal coordinates; `ys` (T, size): the flat states;
    `t_final` (where the run stopped: `t1` unless it failed), `result` (:class:`diffrax.RESULTS`),
    `stats` (diffrax's step counts; with :class:`~jaxtree.Radau5` also its `jacobians`,
    `factorizations`, `newton_iterations` and `rhs_evaluations`), `hybrid`, and at `t_final` the physical
    :class:`~jaxtree.State` `final` and the modal coordinates `final_modal`.

    For drift checks, at the saved times: `energy` (T,), the kinetic energy relative to the
    system mass center of the physical state plus the potential energy of the hinge springs, and
    `angular_momentum` (T, 3) about the system mass center in inertial components (both of the
    full vehicle rebuilt from the modal coordinates: constant for a free vehicle without damping
    up to the linearization and truncation errors). `projection_residual`: the part of the
    initial small motion outside the retained modes, ``|[y; y'] - [positions; rates] s| /
    |[y; y']|`` (0 when the start lies in the retained modes; NaN for a flat start).

    Truncation (:func:`simulate_hybrid`; None with ``truncation_error=False``): `truncation`
    (T, nu), the estimated contribution of the neglected modes to the small angles (full minus
    hybrid), `truncation_static` (T, nu) its quasi-static part, `truncation_error` (T,) the
    largest entry of `truncation` in magnitude per save time (rad); `truncation_state` (N, 2):
    the neglected modes' coordinates at the last save time (real and imaginary parts), to
    continue the estimate in a next run (``simulate_hybrid(..., truncation_start=...)``).
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
    energy: jax.Array | None = None
    angular_momentum: jax.Array | None = None
    projection_residual: jax.Array | None = None
    failure: jax.Array | None = None
    truncation: jax.Array | None = None
    truncation_static: jax.Array | None = None
    truncation_error: jax.Array | None = None
    truncation_state: jax.Array | None = None

    @property
    def ok(self) -> bool:
        return bool(np.all(np.asarray(self.failure == 0)))

    def max_truncation_error(self):
        """``max_t truncation_error``: the estimated largest error of the small angles (rad) from
        the neglected modes over the run (per run of a batch)."""
        return jnp.max(jnp.asarray(self.truncation_error), -1)

    def energy_drift(self):
        """``max |E - E_0| / |E_0|`` over the saved times."""
        e = jnp.asarray(self.energy)
        return jnp.max(jnp.abs(e - e[0])) / jnp.maximum(jnp.abs(e[0]), jnp.finfo(e.dtype).tiny)

    def momentum_drift(self):
        """``max |H - H_0| / |H_0|`` over the saved times."""
        h = jnp.asarray(self.angular_momentum)
        norm = lambda x: jnp.sqrt(jnp.sum(x * x, -1))
        return jnp.max(norm(h - h[0])) / jnp.maximum(norm(h[0]), jnp.finfo(h.dtype).tiny)


def _failure_code(result):
    """0 for success, else the ``Solution.failure`` code of :func:`jaxtree.simulate`."""
    return jnp.where(result == dfx.RESULTS.successful, 0, result_code(result))


def _hybrid_failure_message(code, t, state, modal):
    """The report of failed hybrid runs (batch index, time, physical state, modal coordinates),
    or None when every run succeeded."""
    np.set_printoptions(precision=6, suppress=False, linewidth=120)

    def describe(kind, pick):
        lines = [
            f"jaxtree.simulate_hybrid: {MESSAGES[kind]}.",
            f"  stopped at t = {float(pick(t)):.9g}",
            f"  omega0 = {pick(state.omega0)}",
            f"  gamma = {pick(state.gamma)}",
            f"  gamma_dot = {pick(state.gamma_dot)}",
            f"  C = {pick(state.dcm).tolist()}",
            f"  modal coordinates = {pick(modal)}",
        ]
        if not all(np.all(np.isfinite(pick(x))) for x in state):
            lines.append("  diagnosis: the state is not finite")
        return "\n".join(lines)

    return failure_report(code, describe)


def _energy_and_momentum(model, state):
    """Kinetic energy plus the hinge springs' potential energy, and the angular momentum."""
    from .dynamics import _energy_and_momentum as em

    T, H = em(model, state)
    if model.sprung:
        k = np.asarray(model.sprung, np.int64) - 1
        T = T + 0.5 * jnp.sum(model.stiffness[k] * state.gamma[k] ** 2)
    return T, H


def _small_unbalanced(hm: HybridModel, t, y):
    """The generalized force on the small rows left unbalanced by the hybrid motion at ``(t, y)``:
    ``rhs - A x`` of Eq. (1) at the physical state and the hybrid's accelerations (the inertia
    loads of the base's motion and of the retained modes, springs, velocity products, loads). Its
    part along the retained modes is balanced by their equations (to second order); the rest
    drives the neglected modes (mode-acceleration method)."""
    model = hm.model
    wd, gddL, acc = _solve(hm, t, y)
    _, _, gL, gdL, _ = hm.unpack(y)
    _, _, gddP = hm._large_configuration(t, gL, gdL)
    dtype = y.dtype
    gdd = jnp.zeros(model.n, dtype)
    gdd = gdd.at[np.asarray(hm.large, np.int64) - 1].set(gddL)
    gdd = gdd.at[np.asarray(hm.small, np.int64) - 1].set(hm.accel @ (acc * hm._keep_u().astype(dtype)))
    if gddP is not None:
        gdd = gdd.at[np.asarray(model.prescribed, np.int64) - 1].set(gddP)
    f = _unbalanced(model, hm.state(t, y), t, None, wd, gdd)
    return f[np.asarray(hm.small, np.int64) + 2]


def _truncation_estimate(hm: HybridModel, t0, ts, ys, q_start):
    """``(dynamic (T, nu), static (T, nu), q at the last save time (N, 2))``: the neglected modes'
    contribution to the small angles at the save times, driven by :func:`_small_unbalanced` (see
    :func:`simulate_hybrid`). The force is interpolated linearly between save times (held at its
    first value from `t0` to the first save time) and each neglected mode's equation solved
    exactly on that interpolation, from `q_start` (N, 2) (real and imaginary parts: the
    start's content of each mode, :func:`_truncation_start`, or a previous run's end)."""
    tr = hm.truncation
    assert tr is not None, "called for a model built by hybrid_model"
    dtype = ys.dtype
    f = jax.vmap(lambda t, y: _small_unbalanced(hm, t, y))(ts, ys)  # (T, nu)
    w = tr.weights(hm.keep.astype(dtype))
    lam = tr.lam
    g = f.astype(lam.dtype) @ tr.d.T  # (T, N) modal forces
    static = jnp.real((g * (w / -lam)) @ tr.c.T)
    times = jnp.concatenate([jnp.reshape(t0, (1,)).astype(dtype), ts])
    G = jnp.concatenate([g[:1], g], 0)
    h = jnp.diff(times)[:, None].astype(lam.dtype)  # (T, 1)
    z = lam * h
    small = jnp.abs(z) < 1e-3
    safe_lam = jnp.where(small, 1.0, lam)
    safe_z = jnp.where(small, 1.0, z)
    e = jnp.exp(z)
    p1 = jnp.where(small, h * (1 + z / 2 + z * z / 6), (e - 1) / safe_lam)  # int_0^h e^{lam (h-s)} ds
    p2 = jnp.where(small, h * (0.5 + z / 6 + z * z / 24), (e - 1 - z) / (safe_lam * safe_z))  # ... s / h ds

    def step(q, k):
        e_k, a_k, b_k, g0, g1 = k
        q = e_k * q + g0 * a_k + (g1 - g0) * b_k
        return q, q

    q0 = jax.lax.complex(q_start[:, 0], q_start[:, 1])
    q_end, qs = jax.lax.scan(step, q0, (e, p1, p2, G[:-1], G[1:]))
    dynamic = jnp.real((qs * w) @ tr.c.T)
    return dynamic, static, jnp.stack([jnp.real(q_end), jnp.imag(q_end)], -1)


@eqx.filter_jit
def _solve_hybrid(
    hybrid,
    y0,
    t0,
    t1,
    ts,
    rtol,
    atol,
    dt0,
    solver,
    controller,
    max_steps,
    report,
    residual,
    meter,
    truncation,
    q_start,
):
    # A non-finite start cannot be integrated (NaN error estimates give NaN steps until max_steps):
    # integrate the vehicle at rest in its place, report "nonfinite_start" and return NaN histories.
    finite_start = jnp.all(jnp.isfinite(y0))
    dtype = y0.dtype
    model = hybrid.model
    rest = hybrid.pack(
        State(
            jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype), hybrid.gamma_nominal.astype(dtype), jnp.zeros(model.n, dtype)
        )
    )
    if controller is None:
        controller = default_controller(rtol, atol, t0, t1)
    ts_h, ys_h, t_final, y_final, sol = integrate(
        hybrid_rhs,
        solver,
        t0,
        t1,
        dt0,
        y0,
        hybrid,
        ts=ts,
        controller=controller,
        max_steps=max_steps,
        progress_meter=meter,
        start_ok=finite_start,
        rest=rest,
    )
    code = jnp.where(finite_start, _failure_code(sol.result), int(Failure.NONFINITE_START))
    states = jax.vmap(hybrid.state)(ts_h, ys_h)
    final = hybrid.state(t_final, y_final)
    energy, momentum = jax.vmap(lambda st: _energy_and_momentum(hybrid.model, st))(states)
    dyn = stat = q_end = None
    if truncation and hybrid.truncation is not None:
        dyn, stat, q_end = _truncation_estimate(hybrid, t0, ts_h, ys_h, q_start)
    out = HybridSolution(
        ts=ts_h,
        omega0=states.omega0,
        dcm=states.dcm,
        gamma=states.gamma,
        gamma_dot=states.gamma_dot,
        modal=jax.vmap(hybrid.modal)(ys_h),
        ys=ys_h,
        t_final=t_final,
        result=sol.result,
        stats=dict(sol.stats, **solver_statistics(solver, sol)),
        hybrid=hybrid,
        final=final,
        final_modal=hybrid.modal(y_final),
        energy=energy,
        angular_momentum=momentum,
        projection_residual=residual,
        failure=code,
        truncation=dyn,
        truncation_static=stat,
        truncation_error=None if dyn is None else jnp.max(jnp.abs(dyn), -1),
        truncation_state=q_end,
    )
    if report:
        # Under a caller's jit/vmap: report failures from one host callback (for a whole batch).
        def host(code, t, state, modal):
            message = _hybrid_failure_message(code, t, state, modal)
            if message is not None:
                raise SimulationError(message)

        report_failures(host, code != 0, jax.lax.stop_gradient((code, t_final, final, out.final_modal)))
    return out


@eqx.filter_jit
def _pack_with_residual(hybrid: HybridModel, y0: State):
    # One compiled call: op by op (eagerly) the projection took ~50 ms of dispatches, more than
    # a whole 10 s run of wings in hybrid coordinates.
    dtype = jnp.result_type(hybrid.model.mass)
    S = np.asarray(hybrid.small, np.int64) - 1
    y = jnp.asarray(y0.gamma, dtype)[S] - hybrid.gamma_nominal.astype(dtype)[S]
    x0 = jnp.concatenate([y, jnp.asarray(y0.gamma_dot, dtype)[S]])
    return hybrid.pack(y0), hybrid.projection_residual(y0), _truncation_start(hybrid, x0)


def _truncation_start(hybrid: HybridModel, x0):
    """Every mode's content ``d0 x0`` of a small motion ``x0 = [y; y']`` (real and imaginary
    parts, (N, 2)), or None for a model without truncation terms."""
    if hybrid.truncation is None:
        return None
    q = hybrid.truncation.d0 @ x0.astype(hybrid.truncation.lam.dtype)
    return jnp.stack([jnp.real(q), jnp.imag(q)], -1)


@full_precision
def simulate_hybrid(
    hybrid: HybridModel,
    t1,
    *,
    t0: float | jax.Array = 0.0,
    y0: State | jax.Array | None = None,
    saveat: int | ArrayLike = 101,
    solver: dfx.AbstractSolver | None = None,
    stepsize_controller: dfx.AbstractStepSizeController | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt0=None,
    max_steps: int = DEFAULT_MAX_STEPS,
    throw: bool = True,
    progress: bool | dfx.AbstractProgressMeter = False,
    truncation_error: bool = True,
    truncation_start: ArrayLike | None = None,
) -> HybridSolution:
    """Integrate the hybrid-coordinate equations with diffrax.

    - `y0`: a physical :class:`~jaxtree.State` (default ``hybrid.model.initial``), projected on
      the retained modes by :meth:`HybridModel.pack`, or a flat hybrid state;
    - `saveat`: a number of evenly spaced save times (default 101) or an array of times;
    - `solver`: default :class:`diffrax.Dopri8`; `stepsize_controller`: default a PID controller
      with `rtol`, `atol` (as :func:`jaxtree.simulate`: default :func:`jaxtree.default_tolerance`
      of the model's dtype); `dt0`: default ``1e-3 |t1 - t0|``;
    - `progress`: diffrax's progress meter, as in :func:`jaxtree.simulate`;
    - `truncation_error`: estimate the small angles' error from the neglected modes (default;
      ``False`` saves its cost: one evaluation of Eq. 1 per save time, and its compilation);
      `truncation_start`: a previous run's ``truncation_state``, for a run that continues it
      (default: the neglected modes' content of `y0`, none for a flat state).

    **Truncation error.** ``sol.truncation`` (T, nu) estimates the neglected modes' part of the
    small angles at the save times, i.e. the full model's small angles minus the hybrid ones
    (``sol.gamma[:, small] + sol.truncation`` is a corrected history), ``sol.truncation_error``
    (T,) its largest magnitude per save time (rad), ``sol.max_truncation_error()`` the largest
    over the run; ``sol.truncation_static`` the quasi-static part alone (static correction).
    The neglected modes (left out, or masked by :meth:`HybridModel.retain`) are driven by the
    generalized force that the hybrid motion leaves unbalanced on the small rows of Eq. (1),
    interpolated linearly between save times: save times that resolve the slowest neglected
    modes' forcing are needed (those of a 0.2 s edge: 101 over 10 s suffice). It is the
    one-way response: the neglected modes' reaction on the large motion is left out, as is the
    linearization error of Eq. (30) and the integration error.

    The integration is :func:`jaxtree.simulate`'s (:mod:`jaxtree._integrate`): the same
    step-size control, save-time layout, failure kinds and failure report.

    Raises :class:`jaxtree.SimulationError` when the run fails and `throw` is set, naming the
    time, the physical state and the modal coordinates where it stopped: at once when called
    eagerly, from a host callback at run time under ``jax.jit`` or ``jax.vmap`` (one for a whole
    batch). Tolerances, controllers and solvers may be traced (a vmapped tolerance sweep).
    """

    dtype = jnp.result_type(hybrid.model.mass)
    # (stacklevel 3: the caller of full_precision's wrapper)
    rtol, atol = tolerances("simulate_hybrid", rtol, atol, max_steps, dtype, stepsize_controller, stacklevel=3)
    y0 = hybrid.model.initial if y0 is None else y0
    if isinstance(y0, State):
        check_state("simulate_hybrid", hybrid.model, y0)
    if isinstance(y0, State):
        y, residual, q_start = _pack_with_residual(hybrid, y0)
    else:  # a flat state holds the retained modes only: the neglected ones start at rest
        y, residual = jnp.asarray(y0, dtype), jnp.asarray(np.nan, dtype)
        q_start = None if hybrid.truncation is None else jnp.zeros(hybrid.truncation.lam_parts.shape, dtype)
    if truncation_start is not None:
        q_start = jnp.asarray(truncation_start, dtype)
    if y.shape != (hybrid.size,):
        raise ValueError(f"simulate_hybrid: flat state of size {hybrid.size} expected, got {y.shape}")
    if isinstance(saveat, (int, np.integer)) and not isinstance(saveat, bool):
        ts = jnp.linspace(jnp.asarray(t0, dtype), jnp.asarray(t1, dtype), int(saveat))
    else:
        ts = jnp.asarray(saveat, dtype)
    check_times("simulate_hybrid", t0, t1, ts)
    t0a, t1a = jnp.asarray(t0, dtype), jnp.asarray(t1, dtype)
    dt0 = 1e-3 * (t1a - t0a) if dt0 is None else jnp.asarray(dt0, dtype)
    solver = dfx.Dopri8() if solver is None else solver
    traced = is_traced((hybrid, y, t0a, t1a, ts, rtol, atol, dt0, solver, stepsize_controller))
    sol = _solve_hybrid(
        hybrid,
        y,
        t0a,
        t1a,
        ts,
        jnp.asarray(rtol, dtype),
        jnp.asarray(atol, dtype),
        dt0,
        solver,
        stepsize_controller,
        int(max_steps),
        bool(throw and traced),
        residual,
        progress_meter(progress),
        bool(truncation_error),
        q_start,
    )
    if throw and not traced:
        message = _hybrid_failure_message(sol.failure, sol.t_final, sol.final, sol.final_modal)
        if message is not None:
            raise SimulationError(message)
    return sol
