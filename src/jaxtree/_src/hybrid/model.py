"""The hybrid model: :class:`HybridModel`, the arrays of Eqs. (111)-(121) that a right side
needs, and its state layout (Likins 1972, Sec. III E).

The flat ODE state is ``[attitude of b_0, omega0 (3), gamma_L, gamma_dot_L, s]`` with ``gamma_L``
the large hinges that are unknowns of Eq. (1) (prescribed hinges follow their prescription and
leave the state, as in Eq. 25) and ``s`` the modal coordinates: ``[eta_r; eta_r']`` (real form,
Eq. 119) or the ``2 k`` real coordinates of ``Y_r`` (first-order form, Eq. 109; ``k`` retained
pairs). :meth:`HybridModel.state` rebuilds the physical state by Eqs. (111)-(112),
:meth:`HybridModel.pack` projects a physical one on the retained modes.

Also here: :class:`Precomputed`, each substructure's share of Eq. (30) projected on the modes
(filled by :mod:`.assembly`, read by :mod:`.precomputed`), and :class:`Truncation`, every flexible
mode as a decoupled coordinate (filled by :mod:`.basis`, read by :mod:`.solution`). This module
imports nothing else of the subpackage.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.attitude import AbstractAttitude
from ..numerics import eager_jit, is_traced
from ..vehicle.hinges import prescribed_motion, selector
from ..vehicle.model import Model, State


class Precomputed(eqx.Module):
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
    added_mass: jax.Array | None = None  # the finite-element appendages' mass (not in the tree's)


# the products v_b v_c (b <= c) of a base's spatial velocity (the first 21 features psi of
# :class:`Precomputed`, then v, c and 1)
PAIRS = np.triu_indices(6)


class Truncation(eqx.Module):
    """Every flexible mode of the substructures (or of the set A), retained or not, as a decoupled
    complex first-order coordinate for the truncation estimate
    (:func:`.truncation.truncation_estimate`): ``q_j' = lam_j q_j + d_j . f`` under a generalized
    force `f` (nu,) on the small rows, with the small angles ``y = Re(c q)``. Axis ``N``: the modes (both members of a first-order pair).

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
    - `pre`: the precomputed substructure terms (:class:`Precomputed`), or None (general path);
    - `truncation`: every flexible mode of the substructures (retained or not) as a decoupled
      coordinate, for the truncation estimate of :func:`simulate_hybrid` (:class:`Truncation`);
    - with finite-element appendages, `appendage_truncation`: the same for every flexible mode of
      the appendages' held-base systems (over their held-interface coordinates), and `physical`:
      Eq. (30) in the small coordinates themselves (:func:`.assembly.physical_model`), whose rows
      give the appendages' unbalanced force that drives their neglected modes.

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
    pre: Precomputed | None
    attitude: AbstractAttitude
    small: tuple[int, ...] = eqx.field(static=True)
    large: tuple[int, ...] = eqx.field(static=True)
    form: str = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    mode_index: tuple[int, ...] = eqx.field(static=True)
    mode_group: tuple[int, ...] = eqx.field(static=True, default=())
    groups: tuple = eqx.field(static=True, default=())
    basis: str = eqx.field(static=True, default="set")
    truncation: Truncation | None = None
    appendages: tuple = ()
    appendage_truncation: Truncation | None = None
    physical: HybridModel | None = None

    # ------------------------------------------------------------------ sizes
    @property
    def nu(self) -> int:
        """Number of small hinges."""
        return len(self.small)

    @property
    def n_small(self) -> int:
        """Number of small coordinates: the small hinges, then each finite-element appendage's
        held-interface modal coordinates (:mod:`jaxtree._src.appendage`)."""
        return self.positions.shape[0]

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
        n = len(self.groups) + len(self.appendages)
        return tuple(sum(1 for g in self.mode_group if g == i) for i in range(n))

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

    def keep_u(self):
        return self.keep if self.form == "real" else jnp.concatenate([self.keep, self.keep])

    def keep_m(self):
        return jnp.concatenate([self.keep, self.keep])

    # ------------------------------------------------------------------ state
    def unpack(self, y):
        """``(attitude, omega0, gamma_L, gamma_dot_L, s)`` slices of a flat state."""
        a, nl = self.attitude.size, len(self.large)
        o = np.cumsum([0, a, 3, nl, nl, self.m])
        return tuple(y[o[i] : o[i + 1]] for i in range(5))

    def selectors(self, dtype):
        n = self.model.n
        sel = lambda hs: selector(n, hs, dtype)
        return sel(self.small), sel(self.large), sel(self.model.prescribed)

    def _base(self, dtype):
        """Nominal angles with the large and prescribed entries zeroed (they are added back)."""
        mask = np.ones(self.model.n)
        idx = [k - 1 for k in self.large + self.model.prescribed]
        mask[idx] = 0.0
        return self.gamma_nominal.astype(dtype) * jnp.asarray(mask, dtype)

    def large_configuration(self, t, gL, gdL):
        """All n angles and rates with the small hinges at their nominal angles (the bar state),
        and the prescribed accelerations."""
        dtype = gL.dtype
        ES, EL, EG = self.selectors(dtype)
        gamma = self._base(dtype) + EL @ gL
        gamma_dot = EL @ gdL
        motion = prescribed_motion(self.model, t, dtype)
        if motion is None:
            return gamma, gamma_dot, None
        g, gd, gdd = motion
        return gamma + EG @ g, gamma_dot + EG @ gd, gdd

    @eager_jit
    def state(self, t, y) -> State:
        """The physical :class:`~jaxtree.State` (all n hinges) of a flat hybrid state:
        ``gamma_A = gamma_bar_A + Gamma_1 Phi_r Y_r``, ``gamma_dot_A = Gamma_2 Phi_r Y_r``
        (Eqs. 111-112), prescribed hinges from the prescription at `t`."""
        att, w, gL, gdL, s = self.unpack(y)
        gamma, gamma_dot, _ = self.large_configuration(t, gL, gdL)
        ES, _, _ = self.selectors(y.dtype)
        s = s * self.keep_m().astype(y.dtype)
        nu = self.nu
        gamma = gamma + ES @ (self.positions[:nu] @ s)
        gamma_dot = gamma_dot + ES @ (self.rates[:nu] @ s)
        return State(self.attitude.to_dcm(att), w, gamma, gamma_dot)

    @eager_jit
    def appendage_coordinates(self, y):
        """Each finite-element appendage's held-interface modal coordinates and their rates in the
        flat state `y`: a list of ``(q (k,), q' (k,))``, in the order of ``appendages``."""
        s = self.unpack(y)[4] * self.keep_m().astype(y.dtype)
        out, o = [], self.nu
        for ap in self.appendages:
            k = ap.n_modes
            out.append((self.positions[o : o + k] @ s, self.rates[o : o + k] @ s))
            o += k
        return out

    def appendage_displacement(self, y, index: int = 0, node: int | None = None):
        """The displacement (translations, then small rotations; body's frame) of `node` of
        appendage `index` (default: its first output node) in the flat state `y`."""
        ap = self.appendages[index]
        if node is None:
            if not ap.outputs:
                raise ValueError("appendage_displacement: the appendage has no output nodes; pass node=")
            node = ap.outputs[0]
        q, _ = self.appendage_coordinates(y)[index]
        return ap.displacement(q, node)

    def _small_vector(self, y, yd):
        """``[y; y']`` of the small hinges padded with the appendages' coordinates at rest."""
        z = jnp.zeros(self.n_small - self.nu, y.dtype)
        return jnp.concatenate([y, z, yd, z])

    @eager_jit
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
        s = self.project @ self._small_vector(y, gamma_dot[S]) * self.keep_m().astype(dtype)
        return jnp.concatenate(
            [
                self.attitude.from_dcm(jnp.asarray(state.dcm, dtype)),
                jnp.asarray(state.omega0, dtype),
                gamma[L],
                gamma_dot[L],
                s,
            ]
        )

    @eager_jit
    def projection_residual(self, state: State):
        """The part of the small motion of `state` outside the retained modes:
        ``|[y; y'] - [positions; rates] s| / |[y; y']|`` with ``s`` the projection of
        :meth:`pack` (0 when the motion lies in the retained modes)."""
        dtype = jnp.result_type(self.model.mass)
        S = np.asarray(self.small, dtype=np.int64) - 1
        x = self._small_vector(
            jnp.asarray(state.gamma, dtype)[S] - self.gamma_nominal.astype(dtype)[S],
            jnp.asarray(state.gamma_dot, dtype)[S],
        )
        s = self.pack(state)[self.size - self.m :] * self.keep_m().astype(dtype)
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
        return with_inverse(eqx.tree_at(lambda h: h.keep, self, keep))


def _modal_block(hm: HybridModel):
    """The constant modal block ``kin + rows^T I accel`` (masked), when the projected small-small
    block of Eq. (30) is constant."""
    xp = jnp if is_traced(hm) else np  # numpy for a concrete model (built once, eagerly)
    keep = xp.asarray(hm.keep)
    ku = keep if hm.form == "real" else xp.concatenate([keep, keep])
    H = xp.asarray(hm.kin) + xp.asarray(hm.rows).T @ xp.asarray(hm.inertia) @ xp.asarray(hm.accel)
    return H * ku[:, None] * ku[None, :] + xp.diag(1.0 - ku)


def with_inverse(hm: HybridModel) -> HybridModel:
    """Recompute `modal_inverse` for the current mask (eager)."""
    if hm.modal_inverse is None:
        return hm
    block = _modal_block(hm)
    inverse = jnp.linalg.inv(block) if is_traced(block) else jnp.asarray(np.linalg.inv(np.asarray(block)))
    return eqx.tree_at(lambda h: h.modal_inverse, hm, inverse)


class _HeldPrescription(eqx.Module):
    """A prescription that holds its hinges at fixed angles (rates and accelerations zero)."""

    hinges: tuple = eqx.field(static=True)
    value: jax.Array

    def derivatives(self, t):
        z = jnp.zeros_like(self.value)
        return self.value, z, z


def held_prescription(hm: HybridModel) -> HybridModel:
    """The same hybrid model with its prescribed hinges held at their nominal angles, as
    :func:`jaxtree.linearize` holds them for the modes."""
    model = hm.model
    if model.prescription is None:
        return hm
    values = hm.gamma_nominal[np.asarray(model.prescribed, np.int64) - 1]
    held = eqx.tree_at(lambda m: m.prescription, model, _HeldPrescription(model.prescribed, values))
    return eqx.tree_at(lambda h: h.model, hm, held)


def appendage_body(model, ap) -> int:
    """The index of the body that the finite-element appendage `ap` is fixed to (its name or index;
    checked by :func:`jaxtree.hybrid_model`)."""
    return model.names.index(ap.body) if isinstance(ap.body, str) else int(ap.body)
