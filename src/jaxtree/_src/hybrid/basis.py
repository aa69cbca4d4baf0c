"""The retained modes and their modal matrices (Likins 1972, Sec. III E, Eqs. 106-123): which
modes of each system ``I y'' + J y' + K y = 0`` (Eq. 42 = Eq. 105 per group) are kept, the
matrices that change coordinates to them, and every flexible mode as a decoupled coordinate for
the truncation estimate.

- **real modes** (``J = 0``, ``K`` symmetric; Eqs. 119-121): ``y = phi_r eta_r``; the small-hinge
  columns of Eq. (30c) are post-multiplied by ``phi_r`` and its rows premultiplied by
  ``phi_r^T``; second order in ``eta_r``; modal damping ``-2 zeta sigma eta_r'`` added to
  ``phi_r^T R`` (end of Sec. III E, Eq. 104);
- **first-order modes** (gyroscopic or general ``J``, ``K``; Eqs. 106-118): the first-order form
  (30d) of the small rows, ``Gamma = [y; y'] = Phi_r Y_r`` (Eq. 109), columns post-multiplied by
  ``Phi_r`` (Eq. 115), rows premultiplied by the left eigenvectors (Eq. 117), truncation
  (Eq. 118); modal damping ``-zeta sigma Y_r`` (the replacement ``i sigma -> -zeta sigma + i
  sigma`` of Sec. III E, spinning case).

:func:`modal_matrices` builds them per system, :func:`retained_modes` (or :func:`retained_like`,
a reference build's choice) picks the modes, :func:`truncation_terms` writes every flexible mode
as ``q' = lam q + d . f``.

**How many modes** (not in the seed, which leaves the choice to the analyst). A substructure's
small rows, Eq. (42) on its held base, are ``I y'' + J y' + K y = f``, with ``f`` the generalized
force of its base's motion (``-A0[y'', a_b] a_b`` of :mod:`.substructure` for a base acceleration
``a_b``, velocity products, loads). In the modal coordinates of Eqs. (79)-(90) every mode is a
decoupled first-order equation ``q_j' = lambda_j q_j + (left vector)_j . f``; the quasi-static
response of mode ``j`` is ``-q_j = d_j . f / lambda_j`` (real modes: ``phi_j phi_j^T f /
sigma_j^2``), and summed over all flexible modes it is ``K^{-1} f``. ``n_modes="auto"`` keeps,
per substructure, the fewest lowest modes for which the neglected modes' share of the quasi-static
response to each of the base's six unit accelerations (columns of ``A0[y'', a_b]``,
:func:`base_loads`) is at most `tol` of the whole, in the largest angle (a direction counts when
its whole response is not negligible: above 1e-8 of the largest, rotations per radius of
gyration). The residual modal effective mass, the usual rule of structural dynamics, measures the
base's reaction force and converges far more slowly than the angles (flex95's wings: 9 % of the
translational effective mass left out at 3 modes per wing, where the angles are within 0.4 %);
the quasi-static share tracks the angle error of a slew (flex95: 9.2, 2.1, 0.8 % at 1, 2, 3 modes
per wing against errors of 7.8, 1.2, 0.36 % of the peak wing angle).

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
"""

from __future__ import annotations

import warnings

import jax.numpy as jnp
import numpy as np

from ..numerics import is_traced
from ..vehicle.model import Model
from .model import HybridModel, Truncation


def put(xp, a, idx, v, add: bool = False):
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


def base_loads(model, S, groups, tms, g_nom, basis):
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


def truncation_terms(systems, mds, form, owners, nu, dtype) -> Truncation:
    """:class:`~.model.Truncation` of every flexible mode of the systems; `owners[(system, mode)]` is a
    retained mode's global index."""
    xp = jnp if is_traced(mds) else np
    cs, ds, lams, d0s, own = [], [], [], [], []
    for si, ((rows, I, _J, K, _), md) in enumerate(zip(systems, mds)):
        flex = _flexible(md)
        if not flex:
            continue
        c, d, lam, d0 = _modal_rep(md, I, K, flex, form, xp)
        r = np.asarray(rows, np.int64)
        C = put(xp, xp.zeros((nu, len(lam)), complex), r, c)
        D = put(xp, xp.zeros((len(lam), nu), complex), (slice(None), r), d)
        D0 = put(xp, xp.zeros((len(lam), 2 * nu), complex), (slice(None), np.concatenate([r, nu + r])), d0)
        o = [owners.get((si, j), -1) for j in flex]
        cs.append(C)
        ds.append(D)
        lams.append(lam)
        d0s.append(D0)
        own.extend(o if form == "real" else o + o)
    f = lambda x: jnp.asarray(xp.stack([xp.real(x), xp.imag(x)], -1), dtype)
    if not cs:
        return Truncation(
            f(np.zeros((nu, 0))), f(np.zeros((0, nu))), f(np.zeros(0)), f(np.zeros((0, 2 * nu))), jnp.zeros(0, int)
        )
    return Truncation(
        c_parts=f(xp.concatenate(cs, 1)),
        d_parts=f(xp.concatenate(ds, 0)),
        lam_parts=f(xp.concatenate(lams)),
        d0_parts=f(xp.concatenate(d0s, 0)),
        owner=jnp.asarray(np.asarray(own, np.int64)),
    )


def _signs(x, ref, xp):
    """+-1 per column of `x` (a mode's real basis vectors), -1 where its inner product with the same
    column of the reference `ref` is negative."""
    return xp.where(xp.sum(x * xp.asarray(ref), 0) < 0, -1.0, 1.0)


def modal_matrices(md, I, K, cand, form, zeta, xp=np, ref=None):
    """Modal matrices of the retained modes `cand` of one set of coordinates (module docstring):
    ``positions, rates (nu, m), accel, rows (nu, u), kin (u, u), kin_rhs (u, m), project (m, 2nu)``.

    `ref`: the `positions` of the same modes in a reference build (`like`): each mode's sign,
    which its normalization leaves free (``phi^T I phi = U``; Eq. 89 for first-order modes) and
    two eigensolvers may pick differently, is then the reference's, so that the modal coordinates
    of a rebuilt member and of its reference mean the same (a complex pair's real and imaginary
    parts turn together)."""
    nu, k = I.shape[0], len(cand)
    sig = xp.asarray(md.frequencies)[np.asarray(cand, np.int64)]
    Z = xp.zeros((nu, k))
    if form == "real":
        phi = xp.real(xp.asarray(md.shapes))[:, np.asarray(cand, np.int64)]  # Eq. (119), phi^T I phi = U
        if ref is not None:
            phi = phi * _signs(phi, ref[:, :k], xp)
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
    if ref is not None:  # a complex pair turns as a whole; a pair of real eigenvalues column by column
        lam = None if xp is jnp else np.asarray(md.eigenvalues)
        paired = np.asarray([lam is None or abs(np.imag(lam[j])) > tol for j in cand] * 2)
        prod = T[:nu] * xp.asarray(ref)
        whole = xp.sum(prod[:, :k] + prod[:, k:], 0)
        d = xp.where(paired, xp.concatenate([whole, whole]), xp.sum(prod, 0))
        T = T * xp.where(d < 0, -1.0, 1.0)  # the left vectors W follow T (normalized against it below)
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


def retained_like(like: HybridModel, systems, mds):
    """The retained modes of a reference build `like` (:func:`retained_modes`' blocks and picks)
    and its global order of the modes, ``(_, block, local index)`` (see
    :func:`.assembly._assemble_model`)."""
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


def retained_modes(
    model: Model, groups, systems, mds, n_modes, cutoff, form: str, basis: str, loads=None, tol: float = 1e-2
):
    """The retained modes of each system (:func:`_select`; :func:`_auto_count` for ``n_modes =
    "auto"`` with the systems' base `loads`): ``blocks`` of ``(rows, sigma, indices, modes, I, K)``
    for the systems that keep some, and ``picked``, ``(system, indices)`` of each."""
    auto = isinstance(n_modes, str)
    if basis == "substructure" and n_modes is not None and not auto and not isinstance(n_modes, (int, np.integer)):
        per = list(n_modes)
        if len(per) != len(systems):
            raise ValueError(f"hybrid_model: n_modes has {len(per)} entries for {len(systems)} substructures")
    else:
        per = [n_modes] * len(mds)
    blocks, picked = [], []
    for gi, ((rows, I, _J, K, _), md, n) in enumerate(zip(systems, mds, per)):
        sigma = np.asarray(md.frequencies)
        rigid = np.asarray(md.rigid)
        cands = list(range(len(sigma))) if form == "real" else [j for j in range(len(sigma)) if not rigid[j]]
        where = "" if basis == "set" else f" for substructure {gi} (from hinge {systems[gi][4][0]!r})"
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
