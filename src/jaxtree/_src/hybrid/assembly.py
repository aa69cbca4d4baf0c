"""The construction of a hybrid model, :func:`hybrid_model` (Likins 1972, Sec. III E,
Eqs. 105-123): from the vehicle and its set A to a :class:`~.model.HybridModel`.

The steps: the arguments checked and resolved (:mod:`.arguments`: the set A split into
substructures, :func:`.substructure.substructures`, the basis and whether to precompute,
:func:`.arguments.basis_and_precompute`, the nominal motion, each substructure's Taylor terms,
:func:`.substructure.terms`), the systems ``I y'' + J y' + K y = 0`` whose modes are taken (Eq. 42
= Eq. 105 per group), their modes (:func:`jaxtree.modes`, Eqs. 70-104) and the retained ones
(:mod:`.systems`, :mod:`.basis`), and the assembly (:func:`_assemble_model`): each system's modal
matrices placed in the global order of the modes (ascending frequency,
:func:`_global_modal_matrices`), the precomputed substructure terms projected on them
(:func:`_build_pre`, the arrays of :class:`~.model.Precomputed`), ``a_bar`` of the small hinges,
the truncation terms and the constant modal block's inverse.

:func:`physical_model` assembles Eq. (30) in the small coordinates themselves (unit "modal"
matrices), for the linearization of a vehicle with finite-element appendages (:mod:`.linear`) and
for the appendages' truncation estimate.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..equations.attitude import AbstractAttitude, get_attitude
from ..equations.kinematics import full_precision
from ..linear.linearize import resolve_hinges
from ..numerics import is_traced
from ..vehicle.model import Model
from . import substructure as _sub
from .arguments import (
    SmallSet,
    appendage_args,
    basis_and_precompute,
    hybrid_model_args,
    nominal_motion,
    resolve_form,
    resolve_options,
)
from .basis import modal_matrices, put, truncation_terms
from .model import PAIRS, HybridModel, Precomputed, with_inverse
from .systems import Retained, hybrid_systems, resolved_set, retained, substructure_systems, system_modes

# the features psi of :class:`~.model.Precomputed`: the 21 products v_b v_c (b <= c), v, c and 1
_FEATURES = len(PAIRS[0]) + 6 + 6 + 1


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
    appendages=None,
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
      when `tol` cannot be met below it). The docstring of :mod:`jaxtree._src.hybrid.basis` compares
      this rule with the residual modal effective mass;
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
      retained modes (indices in each substructure's modes, global order), basis, form,
      precomputation and the sign of each mode are kept, and `n_modes`, `cutoff`, `tol`, `basis`,
      `form`, `precompute` are ignored. This makes the build differentiable: under ``jax.grad`` (or ``jvp``) with
      respect to the model's parameters (stiffness, masses, geometry) or the nominal motion, the
      modes are recomputed from the traced matrices (``jnp``) with the selection fixed. Damped
      (general) modes are differentiated by JAX's eigenvector derivatives, which need every mode
      underdamped and distinct within its substructure (checked on `like`); rigid modes of the
      reference are not supported in a traced build. Where only the stiffness, damping, loads or
      initial state are traced (a campaign's members rebuilt from a known vehicle, the model's
      other leaves left as they are), the build's mass part (the substructures' Taylor terms and
      nominal frames) is evaluated when the caller's program is traced, by the programs of the
      reference build, and enters that program as values: a flex95 member's rebuild then costs
      3 instead of 232 Mflop.

    - `appendages`: finite-element appendages (:func:`jaxtree.appendage`), each fixed to a body
      of `model` (which stays a large body): their held-interface modal coordinates join the small
      set after the small hinges, each appendage a substructure of its own (its held-base modes
      at the nominal motion, with the geometric stiffness of the spin's preload; `n_modes`, `cutoff`
      and ``"auto"`` apply to it as to a substructure). `small` may then be empty (``()``). Needs
      the substructure basis and the precomputed terms. The truncation estimate covers the small
      hinges' substructures; `energy` and `angular_momentum` of :func:`simulate_hybrid` are the
      vehicle's, the appendages included. A model whose scene declares appendages needs the argument
      (``appendages=jaxtree.scene_appendages(model)``, or ``()`` to leave them out).

    Rigid (zero-frequency) modes have no first-order eigenvectors (Sec. III E, all-small case):
    the first-order form leaves them out.

    **Returns:** :class:`HybridModel`.
    """
    apps = appendage_args(model, appendages)
    no_hinges = apps and (small is None or (isinstance(small, (list, tuple)) and len(small) == 0))
    hybrid_model_args(
        model,
        None if no_hinges else small,
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
        extra=sum(ap.n_modes for ap in apps),
    )
    S = () if no_hinges else resolve_hinges(model, small)
    groups = _sub.substructures(model, S) if S else ()
    basis, precompute, form = resolve_options(
        model, S, groups, apps, like, (omega0, gamma, dcm), basis=basis, precompute=precompute, form=form
    )
    w_nom, g_nom, _ = nominal_motion(model, omega0, gamma, dcm)
    setup = resolved_set(model, S, groups, apps, w_nom, g_nom, with_terms=precompute or basis == "substructure")
    systems = hybrid_systems(setup, basis, omega0=omega0, gamma=gamma, dcm=dcm)
    mds = system_modes(systems, like, rtol)
    form = resolve_form(form, [md.kind for md in mds])
    kept = retained(
        setup, systems, mds, like, n_modes=n_modes, cutoff=cutoff, form=form, basis=basis, tol=tol, damping=damping
    )
    hm = _assemble_model(
        setup=setup,
        retained=kept,
        systems=systems,
        mds=mds,
        form=form,
        kind=mds[0].kind,
        precompute=precompute,
        basis=basis,
        attitude=attitude,
    )
    if apps:  # the appendages' unbalanced force, for their truncation estimate
        physical = _identity_model(setup, systems)
        physical = eqx.tree_at(lambda h: h.attitude, physical, hm.attitude)
        hm = eqx.tree_at(lambda h: h.physical, hm, physical, is_leaf=lambda x: x is None)
    return hm


def _assemble_model(
    *,
    setup: SmallSet,
    retained: Retained,
    systems,
    mds,
    form: str,
    kind: str,
    precompute: bool,
    basis: str,
    attitude,
    truncation: bool = True,
):
    """The :class:`HybridModel` of the retained modes: their modal matrices assembled over the set
    A in ascending frequency (or in `retained.order`, ``(_, block, local index)``, that of a
    reference build), the modal damping `retained.zeta` (in that order), the precomputed terms, and
    the truncation terms of the `systems` and their modes `mds` unless `truncation` is False."""
    model, S, groups, apps = setup.model, setup.small, setup.groups, setup.appendages
    blocks, picked, zeta, order = retained.blocks, retained.picked, retained.zeta, retained.order
    nu = len(S) + sum(ra.n_modes for ra in apps)
    dtype = jnp.result_type(model.mass)
    xp = jnp if is_traced((blocks, apps)) else np
    # modal damping follows the global (frequency) order of the modes: split it by group afterwards
    if order is None:
        order = sorted(((float(sig[j]), g, j) for g, (_, sig, *_r) in enumerate(blocks) for j in range(len(sig))))
    zg = [np.zeros(len(b[1])) for b in blocks]
    for q, (_, g, j) in enumerate(order):
        zg[g][j] = zeta[q]
    ref = _reference_blocks(retained.reference, blocks, order)
    parts_g = [
        (rows, sig, modal_matrices(md, I, K, cand, form, zg[g], xp, ref[g]))
        for g, (rows, sig, cand, md, I, K) in enumerate(blocks)
    ]
    parts, mode_order, mmaps, umaps = _global_modal_matrices(parts_g, nu, form, order)
    mode_index = tuple(int(blocks[g][2][j]) for g, j in mode_order)
    group_of = [picked[g][0] for g in range(len(blocks))]
    owners = {(group_of[g], int(blocks[g][2][j])): q for q, (g, j) in enumerate(mode_order)}
    f = lambda x: jnp.asarray(x, dtype)
    u = parts["accel"].shape[1]
    pre = _precomputed_terms(setup, parts, group_of, mmaps, umaps, basis) if precompute else None
    one_base = len(set(setup.bases)) == 1
    _, inertia, R_bases = setup.frames
    if apps:
        inertia = _with_appendages(setup, xp.asarray(inertia), xp.asarray(R_bases), xp)
    app_systems = [ra.system for ra in apps]
    hinge_systems = [s for s in range(len(systems)) if s not in app_systems]
    hm = HybridModel(
        model=model,
        gamma_nominal=setup.g_nom,
        omega0_nominal=setup.w_nom,
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
        truncation=_truncation(systems, mds, hinge_systems, owners, form, len(S), dtype) if truncation else None,
        appendages=tuple(ra.appendage for ra in apps),
        appendage_truncation=_truncation(systems, mds, app_systems, owners, form, nu - len(S), dtype, len(S))
        if (truncation and apps)
        else None,
    )
    return with_inverse(hm)


def _reference_blocks(reference, blocks, order) -> list:
    """Each block's modes in a reference build's `positions` (its rows, the columns of its modes in
    the global `order`, a complex pair's two), for :func:`.basis.modal_matrices`' signs; Nones
    without a reference."""
    if reference is None:
        return [None] * len(blocks)
    k = len(order)
    pos = {(g, j): q for q, (_, g, j) in enumerate(order)}
    out = []
    for g, (rows, _sig, cand, *_rest) in enumerate(blocks):
        q = np.asarray([pos[(g, j)] for j in range(len(cand))], np.int64)
        out.append(reference[np.ix_(np.asarray(rows, np.int64), np.concatenate([q, k + q]))])
    return out


def _truncation(systems, mds, which, owners, form, nu, dtype, first=0):
    """:func:`.basis.truncation_terms` of the systems `which` (indices in `systems`: the
    substructures of the small hinges, or the appendages), `nu` small coordinates from the
    `first` (the appendages' coordinates follow the small hinges': their terms are over the
    appendages' coordinates alone); `owners[(system, mode)]` is a retained mode's global index."""
    local = {s: i for i, s in enumerate(which)}
    picked = [systems[s] for s in which]
    if first:
        picked = [(np.asarray(rows, np.int64) - first, *rest) for rows, *rest in picked]
    return truncation_terms(
        picked,
        [mds[s] for s in which],
        form,
        {(local[key[0]], key[1]): q for key, q in owners.items() if key[0] in local},
        nu,
        dtype,
    )


class _Identity(NamedTuple):
    """The "modes" of a system in its own coordinates (:func:`physical_model`): unit shapes."""

    frequencies: np.ndarray
    shapes: np.ndarray


def physical_model(model: Model, S: tuple[int, ...], apps, w_nom, g_nom) -> HybridModel:
    """Eq. (30) of the set A and the appendages' held-interface coordinates in those coordinates
    themselves: a :class:`HybridModel` in the real form whose "modal" matrices are unit matrices
    (every coordinate retained, none transformed), from the precomputed substructure terms. Its
    modal coordinates are the small coordinates in substructure order (``positions`` is that
    permutation). For the linearization of a vehicle with finite-element appendages
    (:mod:`.linear`), which Eq. (1) cannot carry. Needs every substructure terminal and no
    external load on a small body (ValueError otherwise). :func:`hybrid_model` reuses its own
    substructures, terms and systems (:func:`_identity_model`)."""
    groups = _sub.substructures(model, S) if S else ()
    basis_and_precompute(model, S, groups, "substructure", True)
    setup = resolved_set(model, S, groups, apps, w_nom, g_nom, with_terms=True)
    return _identity_model(setup, substructure_systems(setup))


def _identity_model(setup: SmallSet, systems) -> HybridModel:
    """:func:`physical_model` of the resolved set `setup` and its `systems`."""
    blocks, picked, order = [], [], []
    for gi, (rows, I, _J, K, _labels) in enumerate(systems):
        k = len(rows)
        md = _Identity(np.zeros(k), np.eye(k))
        blocks.append((rows, md.frequencies, list(range(k)), md, I, K))
        picked.append((gi, list(range(k))))
        order.extend((0.0, gi, j) for j in range(k))
    return _assemble_model(
        setup=setup,
        retained=Retained(blocks, picked, order, np.zeros(len(order))),
        systems=systems,
        mds=None,
        form="real",
        kind="real",
        precompute=True,
        basis="substructure",
        attitude="quaternion",
        truncation=False,
    )


def _stacked_terms(t: dict, xp=np) -> dict:
    """The arrays of :class:`Precomputed` from the per-term stacks of :func:`_build_pre`
    (numpy, leading axis p)."""
    p, uS, mS = t["w1"].shape
    z = lambda *shape: xp.zeros((p, *shape))
    iu, ju = PAIRS

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


def _global_modal_matrices(blocks, nu, form, order=None):
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
            out[key] = put(xp, out[key], idx, p[key])
        mmaps.append(mm_)
        umaps.append(um)
    return out, [(g, j) for _, g, j in order], mmaps, umaps


def _build_pre(setup: SmallSet, parts, mmaps, umaps, u, m):
    """The precomputed substructure terms (:class:`Precomputed`), projected on the modes: the
    substructures of the small hinges, then the finite-element appendages (their rows of the small
    coordinates after the hinges', their modal stiffness and damping in place of the hinge
    springs)."""
    model, small, groups, apps = setup.model, setup.small, setup.groups, setup.appendages
    assert setup.terms is not None, "computed for the precomputed terms"
    xp = jnp if is_traced((model, setup.terms, parts, apps)) else np
    ms, us = max(len(x) for x in mmaps), max(len(x) for x in umaps)
    keys = ("aa0", "aa1", "wa0", "wa1", "aw0", "g0a", "g1a", "g2a", "g0w", "g1w", "g2w", "w0", "w1")
    acc = {k: [] for k in keys}
    ww0 = xp.zeros((u, u))
    sprung = np.zeros(model.n)
    sprung[np.asarray(model.sprung, np.int64) - 1] = 1.0
    stiff = xp.asarray(model.stiffness) * sprung
    damp = xp.asarray(model.damping) * sprung
    entries = []  # (rows of the small coordinates, stiffness, damping, preload angles, Taylor terms)
    for grp, tm in zip(groups, setup.terms):
        h = np.asarray(grp.hinges, np.int64) - 1
        entries.append(([small.index(k) for k in grp.hinges], stiff[h], damp[h], xp.asarray(setup.g_nom)[h], tm))
    for ra in apps:
        ap = ra.appendage
        entries.append(
            (list(ra.rows), xp.asarray(ap.stiffness), xp.asarray(ap.modal_damping), xp.zeros(ra.n_modes), ra.terms)
        )
    for (rows, k_s, d_s, gbar, tm), mc, uc in zip(entries, mmaps, umaps):
        idx = np.asarray(rows, np.int64)
        P = parts["positions"][np.ix_(idx, mc)]
        Q = parts["rates"][np.ix_(idx, mc)]
        Acc = parts["accel"][np.ix_(idx, uc)]
        Rw = parts["rows"][np.ix_(idx, uc)]
        A0, A1, G0, G1, G2 = (xp.asarray(x) for x in (tm.A0, tm.A1, tm.G0, tm.G1, tm.G2))
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
        acc["w0"].append(pad_u(Rw.T @ (k_s * gbar)))  # -tau_S at y = 0 (a spring preload)
        acc["w1"].append(pad_u(pad_m(Rw.T @ (k_s[:, None] * P + d_s[:, None] * Q))))
        ww0 = put(xp, ww0, np.ix_(uc, uc), Rw.T @ A0[6:, 6:] @ Acc, add=True)
    dtype = jnp.result_type(model.mass)
    pad_idx = lambda x, n, width: tuple(tuple(int(i) for i in c) + (n,) * (width - len(c)) for c in x)
    return Precomputed(
        **{k: jnp.asarray(v, dtype) for k, v in _stacked_terms({k: xp.stack(v) for k, v in acc.items()}, xp).items()},
        ww0=jnp.asarray(ww0, dtype),
        mcols=pad_idx(mmaps, m, ms),
        ucols=pad_idx(umaps, u, us),
        bases=setup.bases,
        added_mass=jnp.asarray(sum(xp.asarray(ra.mass) for ra in apps), dtype) if apps else None,
    )


def _precomputed_terms(setup: SmallSet, parts, group_of, mmaps, umaps, basis):
    """:func:`_build_pre` with each substructure's modal columns: every substructure (and
    appendage), also one with no retained mode (its mass still moves with its base)."""
    u, m = parts["accel"].shape[1], parts["positions"].shape[1]
    gm, gu = [], []
    for gi in range(len(setup.groups) + len(setup.appendages)):
        if gi in group_of:
            gm.append(mmaps[group_of.index(gi)])
            gu.append(umaps[group_of.index(gi)])
        else:
            gm.append(np.zeros(0, np.int64))
            gu.append(np.zeros(0, np.int64))
    if basis == "set":  # the set's modes span every substructure
        gm = [np.arange(m)] * len(setup.groups)
        gu = [np.arange(u)] * len(setup.groups)
    return _build_pre(setup, parts, gm, gu, u, m)


def _with_appendages(setup: SmallSet, a_bar, R_bases, xp):
    """The small coordinates' inertia (Eq. 36d's ``a_bar``, the small rows and columns of Eq. 1's
    matrix) with the appendages' modal coordinates after the hinges: each substructure's own block
    (``A0`` of its Taylor terms) less ``p p^T / M`` of the translational momenta ``p`` (in {b^0})
    over the vehicle's mass M, the elimination of b_0's translation as in Eq. (1). The hinges'
    block is Eq. (1)'s, with the tree's mass replaced by the vehicle's."""
    model, S, apps = setup.model, setup.small, setup.appendages
    assert setup.terms is not None, "computed for the precomputed terms"
    nh = len(S)
    nu = nh + sum(ra.n_modes for ra in apps)
    m_tree = xp.sum(xp.asarray(model.mass))
    m_all = m_tree + sum(xp.asarray(ra.mass) for ra in apps)
    P = xp.zeros((nu, 3))
    own = xp.zeros((nu, nu))
    for i, (grp, tm) in enumerate(zip(setup.groups, setup.terms)):
        rows = np.asarray([S.index(k) for k in grp.hinges], np.int64)
        P = put(xp, P, rows, (R_bases[i] @ xp.asarray(tm.A0)[3:6, 6:]).T)
    for ra in apps:
        A0 = xp.asarray(ra.terms.A0)
        rows = np.asarray(ra.rows, np.int64)
        own = put(xp, own, np.ix_(rows, rows), A0[6:, 6:])
        P = put(xp, P, rows, (R_bases[ra.system] @ A0[3:6, 6:]).T)
    hinge_block = xp.zeros((nu, nu))
    hinge_block = put(xp, hinge_block, np.ix_(np.arange(nh), np.arange(nh)), a_bar + (P[:nh] @ P[:nh].T) / m_tree)
    return hinge_block + own - (P @ P.T) / m_all
