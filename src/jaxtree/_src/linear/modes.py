"""Modal analysis of ``I y'' + J y' + K y = 0``: Sec. III D of Likins (1972), Eqs. (70)-(104).

Three cases, as in the seed:

- **real** (``J = 0``, ``K`` symmetric; Eqs. 97-103): real mode shapes ``phi`` with
  ``phi^T I phi = U`` and ``phi^T K phi = sigma^2``, from the symmetric problem
  ``L^{-1} K L^{-T}`` (``I = L L^T``, Cholesky) solved by ``eigh``;
- **gyroscopic** (``J`` skew, ``K`` symmetric positive semidefinite; Eqs. 91-96):
  the first-order form ``P Gamma' = Q Gamma`` of Eq. (70) with ``P = diag(K, I)``
  symmetric and ``Q = [[0, K], [-K, -J]]`` skew. With ``K~ = L^{-1} K L^{-T} = R R^T``
  and ``J~ = L^{-1} J L^{-T}`` the variables ``z = [R^T L^T y; L^T y']`` obey
  ``z' = S z`` with the real skew matrix ``S = [[0, R^T], [-R, -J~]]`` (a
  Cholesky factor of P, as in the hint), so ``i S`` is Hermitian and ``eigh`` gives
  the purely imaginary eigenvalues and orthonormal eigenvectors; this is
  differentiable and works on every backend. The right eigenvectors ``Phi`` of
  Eq. (70) follow, normalized so that ``Phi'^T P Phi = U`` with the left
  eigenvectors ``Phi' = Phi*`` of Eq. (96);
- **general** (anything else, e.g. hinge dampers in ``J`` or load-dependent ``K``):
  the eigenvalues and right eigenvectors of ``B = P^{-1} Q`` (Eq. 71) by a general
  eigensolver, the left eigenvectors from ``Phi^{-1}``, normalized by Eq. (89),
  ``Phi'^T P Phi = U``, so that ``Phi'^T Q Phi = Lambda`` (Eq. 90). Concrete arrays are
  solved by numpy (with the checks below); traced ones (``kind="general"`` under
  ``jax.grad``) by JAX's ``eig`` with its eigenvector derivatives, valid for an underdamped
  system with distinct eigenvalues (no check is possible on traced values; CPU only).

Eigenvalues are ordered in pairs: ``eigenvalues[j]`` (``Im >= 0``) and
``eigenvalues[j + nu]`` (its conjugate), ``j`` by ascending frequency. Zero-frequency
(rigid-body) modes of a positive semidefinite ``K`` are reported with ``rigid`` set;
in the first-order form they are defective (``y = a + b t``), so their columns of
``right`` and ``left`` are zero; the seed discards them (Sec. III E, all-small case).

Modal damping (``damping = zeta``): Eq. (104), ``eta'' + 2 zeta sigma eta' + sigma^2 eta
= 0``, in the real case (eigenvalues ``-zeta sigma +- i sigma sqrt(1 - zeta^2)``), and in
the spinning case the replacement of ``+- i sigma`` by ``-zeta sigma +- i sigma`` in
``Lambda`` (end of Sec. III E). ``right``/``left`` are those of the undamped system
(damping is added after the transformation, as in the seed); ``B`` is the state
matrix ``Gamma' = B Gamma`` of the damped system.
"""

from __future__ import annotations

import functools
from collections import namedtuple
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError, SceneTypeError, short
from ..numerics import build_jit, is_traced
from ..values import as_float
from .linearize import LinearSystem, structure


def tolerance(name: str, rtol, label: str = "rtol") -> float:
    """A relative tolerance in [0, 1)."""
    r = float(as_float(rtol, f"{name}: {label}", ()))
    if not 0.0 <= r < 1.0:
        raise SceneError(f"{name}: {label} must be in [0, 1), got {r}")
    return r


def _matrices(I, J, K):
    """``(I, J, K)``, or those of a :class:`~jaxtree._src.linear.linearize.LinearSystem` given as `I` (or any object with its fields)."""
    if all(hasattr(I, field) for field in ("I", "J", "K", "coordinates", "hinges")):
        return I.I, I.J, I.K
    return I, J, K


def modes_args(I, J=None, K=None, damping=None, kind=None, labels=None, rtol=1e-9):
    """Arguments of :func:`jaxtree.modes`: I, J, K square float matrices of one size (finite
    when concrete), `damping` a non-negative scalar or one per coordinate, `kind` known,
    `labels` one string per coordinate, `rtol` in [0, 1)."""
    name = "modes"
    I, J, K = _matrices(I, J, K)
    if J is None or K is None:
        raise SceneTypeError(f"{name}: give I, J, K (or a LinearSystem)")
    sizes = []
    for label, M in (("I", I), ("J", J), ("K", K)):
        shape = np.shape(M) if is_traced(M) else as_float(M, f"{name}: {label}", finite=True).shape
        if len(shape) != 2 or shape[0] != shape[1]:
            raise SceneError(f"{name}: {label} must be a square matrix, got shape {shape}")
        sizes.append(shape[0])
    if len(set(sizes)) != 1:
        raise SceneError(f"{name}: I, J, K must have one size, got {sizes[0]}, {sizes[1]}, {sizes[2]}")
    nu = sizes[0]
    if nu == 0:
        raise SceneError(f"{name}: I, J, K are empty (no coordinate)")
    if kind is not None and kind not in ("real", "gyroscopic", "general"):
        raise SceneError(f"{name}: kind must be 'real', 'gyroscopic', 'general' or None, got {short(kind)}")
    if damping is not None and not is_traced(damping):
        z = as_float(damping, f"{name}: damping")
        if z.ndim > 1 or (z.ndim == 1 and z.shape != (nu,)):
            raise SceneError(
                f"{name}: damping must be a scalar or one ratio per coordinate ({nu}), got shape {z.shape}"
            )
        if np.any(z < 0):
            raise SceneError(f"{name}: modal damping ratios must be >= 0, got {z.tolist()}")
    if labels is not None:
        if isinstance(labels, str):
            raise SceneTypeError(f"{name}: labels must be a sequence of {nu} names, got the string {labels!r}")
        try:
            labels = list(labels)
        except TypeError:
            raise SceneTypeError(f"{name}: labels must be a sequence of {nu} names, got {short(labels)}") from None
        if len(labels) != nu:
            raise SceneError(f"{name}: {len(labels)} labels for {nu} coordinates")
    tolerance(name, rtol)


class ModalError(ValueError):
    """The matrices do not describe an acceptable vehicle for modal analysis."""


class UnstableError(ModalError):
    """An eigenvalue has a positive real part (or sigma^2 < 0): the null solution is unstable."""


class DefectiveError(ModalError):
    """The first-order system is not diagonalizable (secular growth t^k e^{lambda t})."""


class Modes(eqx.Module):
    """Result of :func:`modes` (see the module docstring for conventions).

    - `eigenvalues` (2nu,) complex: ``lambda_j`` (Im >= 0) for j < nu, conjugates after;
    - `frequencies` (nu,): ``sigma_j >= 0`` ascending (undamped values when `damping` is given);
    - `damping_ratios` (nu,): ``zeta_j`` (the given modal damping, or ``-Re lambda/|lambda|``);
    - `shapes` (nu, nu): column j is the mode shape ``phi^j`` (real, ``phi^T I phi = U``, in the
      real case; the ``y`` part of ``Phi^j`` otherwise);
    - `right`, `left` (2nu, 2nu) complex: ``Phi`` and ``Phi'`` of Eqs. (79)-(90);
    - `P`, `Q` (2nu, 2nu): Eq. (70); `B` (2nu, 2nu): the state matrix of the (damped) system;
    - `rigid` (nu,) bool: zero-frequency (rigid-body) modes;
    - `participation` (nu, nu): share of coordinate i in mode j (``|phi_ij|^2 I_ii``, columns sum to 1);
    - static: `kind`, `coordinates`, `labels` (one string per mode: the coordinates that dominate it).
    """

    eigenvalues: jax.Array
    frequencies: jax.Array
    damping_ratios: jax.Array
    shapes: jax.Array
    right: jax.Array
    left: jax.Array
    P: jax.Array
    Q: jax.Array
    B: jax.Array
    rigid: jax.Array
    participation: jax.Array
    kind: str = eqx.field(static=True)
    coordinates: tuple[str, ...] = eqx.field(static=True, default=())
    labels: tuple[str, ...] = eqx.field(static=True, default=())

    @property
    def nu(self) -> int:
        return self.frequencies.shape[0]

    def summary(self) -> str:
        """A table: mode, frequency, damping ratio, label."""
        lines = [f"{'mode':>4}  {'sigma':>12}  {'zeta':>8}  dominated by"]
        f = np.asarray(self.frequencies)
        z = np.asarray(self.damping_ratios)
        for j in range(self.nu):
            lab = self.labels[j] if self.labels else ""
            lines.append(f"{j:4d}  {f[j]:12.6g}  {z[j]:8.4f}  {lab}")
        return "\n".join(lines)


def first_order(I, J, K):
    """``(P, Q, B)`` of Eqs. (70)-(71): ``P = diag(K, I)``, ``Q = [[0, K], [-K, -J]]``,
    ``B = [[0, U], [-I^{-1} K, -I^{-1} J]]`` (``Q = P B`` holds even for singular K).
    Concrete matrices are combined in numpy (no eager JAX operations to compile)."""
    xp = jnp if is_traced((I, J, K)) else np
    I, J, K = (xp.asarray(x) for x in (I, J, K))
    nu = I.shape[0]
    Z = xp.zeros((nu, nu), I.dtype)
    U = xp.eye(nu, dtype=I.dtype)
    P = xp.block([[K, Z], [Z, I]])
    Q = xp.block([[Z, K], [-K, -J]])
    B = xp.block([[Z, U], [-xp.linalg.solve(I, K), -xp.linalg.solve(I, J)]])
    return jnp.asarray(P), jnp.asarray(Q), jnp.asarray(B)


# ----------------------------------------------------------------------------- real modes
@jax.jit
def _real_core(I, K):
    """Eqs. (97)-(103): ``sigma^2`` ascending and ``phi`` with ``phi^T I phi = U``."""
    L = jnp.linalg.cholesky(0.5 * (I + I.T))
    X = jax.scipy.linalg.solve_triangular(L, 0.5 * (K + K.T), lower=True)
    Kt = jax.scipy.linalg.solve_triangular(L, X.T, lower=True)  # L^{-1} K L^{-T}
    s2, V = jnp.linalg.eigh(0.5 * (Kt + Kt.T))
    phi = jax.scipy.linalg.solve_triangular(L.T, V, lower=False)
    return s2, phi


# ----------------------------------------------------------------------------- gyroscopic
@functools.partial(jax.jit, static_argnames="definite")
def _gyro_core(I, J, K, definite):
    """Hermitian form of Eq. (70): eigenvalues mu of ``i S`` (ascending) and eigenvectors."""
    nu = I.shape[0]
    L = jnp.linalg.cholesky(0.5 * (I + I.T))
    inv = lambda X: jax.scipy.linalg.solve_triangular(
        L, jax.scipy.linalg.solve_triangular(L, X, lower=True).T, lower=True
    )  # L^{-1} X^T L^{-T}, transposed twice
    Kt = inv(0.5 * (K + K.T))
    Kt = 0.5 * (Kt + Kt.T)
    Jt = inv(J.T)  # L^{-1} J L^{-T}
    Jt = 0.5 * (Jt - Jt.T)
    if definite:
        R = jnp.linalg.cholesky(Kt)  # K~ = R R^T
        k_evals = jnp.linalg.eigvalsh(Kt)
        k_vecs = jnp.zeros_like(Kt)
    else:  # positive semidefinite: symmetric square root (not differentiable at zero eigenvalues)
        k_evals, k_vecs = jnp.linalg.eigh(Kt)
        R = (k_vecs * jnp.sqrt(jnp.clip(k_evals, 0.0))) @ k_vecs.T
    Z = jnp.zeros((nu, nu), I.dtype)
    S = jnp.block([[Z, R.T], [-R, -Jt]])
    mu, V = jnp.linalg.eigh(1j * S)
    return L, mu, V, k_evals, k_vecs


def _gyroscopic(I, J, K, definite):
    nu = I.shape[0]
    L, mu, V, k_evals, k_vecs = _gyro_core(I, J, K, definite)
    # S v = lambda v with lambda = -i mu; the nu most negative mu are lambda = i sigma, sigma >= 0.
    low = V[:, :nu][:, ::-1]
    sigma = -mu[:nu][::-1]
    sigma = jnp.clip(sigma, 0.0)
    return L, sigma, low, k_evals, k_vecs


# ----------------------------------------------------------------------------- general
def _pair_general(lam, tol):
    """Indices (upper, lower) pairing the 2nu eigenvalues: complex conjugates, then real ones."""
    lam = np.asarray(lam)
    idx = np.arange(lam.size)
    cplx = idx[np.imag(lam) > tol]
    neg = list(idx[np.imag(lam) < -tol])
    real = idx[np.abs(np.imag(lam)) <= tol]
    upper, lower = [], []
    for j in cplx[np.argsort(np.imag(lam)[cplx])]:
        k = min(neg, key=lambda i: abs(lam[i] - np.conj(lam[j])))
        neg.remove(k)
        upper.append(j)
        lower.append(k)
    if len(real) % 2 or neg:
        raise DefectiveError("modes: eigenvalues do not come in conjugate or real pairs: " + str(lam))
    real = real[np.argsort(np.real(lam)[real])]
    rp = [(real[2 * i], real[2 * i + 1]) for i in range(len(real) // 2)]
    upper = [a for a, _ in rp] + upper
    lower = [b for _, b in rp] + lower
    return np.asarray(upper, dtype=int), np.asarray(lower, dtype=int)


# Numerical tolerances of the modal analysis, relative to the largest eigenvalue (or frequency):
# eigenvalues (and sigma^2) this close to zero are round-off: rigid modes, conjugate-pair
# matching, and a negative sigma^2 that is not a divergence (float64 eigensolvers leave ~1e-12).
ROUNDOFF_RTOL = 1e-9
# a real part above this counts as an unstable mode (10x the round-off band, so that round-off
# in an undamped gyroscopic system is never called unstable)
UNSTABLE_RTOL = 1e-8
# condition number of the normalized eigenvector matrix beyond which the first-order matrix of
# Eq. (71) is taken as defective (a Jordan block: secular growth, rejected by the seed)
DEFECTIVE_CONDITION = 1e10
# gyroscopic frequencies are square roots: round-off of ~1e-12 in K~ shows as ~1e-6 in sigma
RIGID_SIGMA_RTOL = 1e-6


def _general(I, J, K, name):
    I, J, K = (np.asarray(x, dtype=float) for x in (I, J, K))
    nu = I.shape[0]
    P, Q, B = (np.asarray(x) for x in first_order(I, J, K))
    lam, Phi = np.linalg.eig(B)
    scale = max(np.abs(lam).max(initial=0.0), 1e-300)
    tol = ROUNDOFF_RTOL * scale
    bad = np.real(lam) > UNSTABLE_RTOL * scale
    if np.any(bad):
        raise UnstableError(
            f"modes: unstable {name} system, eigenvalues with positive real part {lam[bad].tolist()}; "
            "the seed rejects such a vehicle (Sec. III D)"
        )
    up, lo = _pair_general(lam, tol)
    order = np.concatenate([up, lo])
    lam = lam[order]
    Phi = Phi[:, order]
    cplx = np.abs(np.imag(lam[:nu])) > tol
    # exact conjugate pairs (real solutions, Eq. 94)
    Phi[:, nu:][:, cplx] = np.conj(Phi[:, :nu][:, cplx])
    Phi = Phi / np.linalg.norm(Phi, axis=0, keepdims=True)
    cond = np.linalg.cond(Phi)
    if not np.isfinite(cond) or cond > DEFECTIVE_CONDITION:
        raise DefectiveError(
            f"modes: the first-order matrix of Eq. (71) is defective or nearly so (condition number of the "
            f"eigenvector matrix {cond:.3g}); a nondiagonal Jordan form means secular growth t^k e^(lambda t), "
            "which the seed rejects (Sec. III D). Zero-frequency modes with a non-gyroscopic J are of this kind."
        )
    try:
        Pinv_T = np.linalg.inv(P).T
    except np.linalg.LinAlgError:
        raise DefectiveError(
            "modes: K is singular, so P = diag(K, I) of Eq. (70) has no inverse "
            "and the left eigenvectors of Eq. (89) do not exist"
        ) from None
    Psi = np.linalg.inv(Phi)  # rows: left eigenvectors of B with Psi Phi = U (Eq. 72)
    left = Pinv_T @ Psi.T  # Phi'^T P = Psi  (Eqs. 85, 89)
    return lam, Phi, left, P, Q, B


def _general_modes_traced(I, J, K) -> _Solved:
    """:func:`_general_modes` for traced matrices of an underdamped system (every eigenvalue one
    of a complex pair, all distinct: e.g. a substructure with light hinge dampers): JAX's general
    eigensolver with its eigenvector derivatives (first-order perturbation theory, valid for
    distinct eigenvalues; CPU only), the ``Im > 0`` members by ascending frequency, then their
    conjugates; left eigenvectors from ``Phi^{-1}`` (Eqs. 85, 89). No check is made on the
    values (they are traced): the caller knows the kind from a concrete solve."""
    nu = I.shape[0]
    P, _, B = first_order(I, J, K)
    lam, vr = jax.lax.linalg.eig(B, compute_left_eigenvectors=False, enable_eigvec_derivs=True)
    up = jnp.argsort(jnp.where(jnp.imag(lam) > 0, jnp.imag(lam), jnp.inf))[:nu]
    lam_up, phi_up = lam[up], vr[:, up]
    Phi = jnp.concatenate([phi_up, jnp.conj(phi_up)], 1)
    Phi = Phi / jnp.linalg.norm(Phi, axis=0, keepdims=True)
    lam = jnp.concatenate([lam_up, jnp.conj(lam_up)])
    left = jnp.linalg.inv(P).T.astype(Phi.dtype) @ jnp.linalg.inv(Phi).T
    sigma = jnp.abs(jnp.imag(lam_up))
    zeta = -jnp.real(lam_up) / jnp.abs(lam_up)
    y = Phi[:nu, :nu]
    ph = y[jnp.argmax(jnp.abs(y), axis=0), jnp.arange(nu)]
    shapes = y * (jnp.abs(ph) / ph)[None, :]
    return _Solved(lam, sigma, zeta, shapes, Phi, left, B, jnp.zeros(nu, bool))


# ----------------------------------------------------------------------------- entry point
def _labels(shapes, part, coords, rigid, hinges_of):
    """One string per mode: the coordinates with the largest share, with ``+`` for motion in
    phase with the dominant coordinate and ``-`` for motion in antiphase."""
    labels = []
    for j in range(part.shape[1]):
        share = part[:, j]
        order = np.argsort(share)[::-1]
        picked, total = [], 0.0
        for i in order:
            if picked and (share[i] < 0.1 or len(picked) >= 3 or total >= 0.9):
                break
            picked.append(i)
            total += share[i]
        ref = shapes[picked[0], j]
        text = f"{coords[picked[0]]} {100 * share[picked[0]]:.0f}%"
        for i in picked[1:]:
            sign = "-" if (shapes[i, j] * np.conj(ref)).real < 0 else "+"
            text += f" {sign} {coords[i]} {100 * share[i]:.0f}%"
        att = sum(share[i] for i in range(len(coords)) if hinges_of and hinges_of[i] == 0)
        if rigid[j]:
            text = "rigid body: " + text
        elif att >= 0.5:
            text = "rigid-body attitude: " + text
        labels.append(text)
    return tuple(labels)


def modes(
    I, J=None, K=None, *, damping=None, kind: str | None = None, labels: Sequence[str] | None = None, rtol: float = 1e-9
) -> Modes:
    """Modes of ``I y'' + J y' + K y = 0`` (Eqs. 70-104).

    **Arguments:**

    - `I`, `J`, `K` (nu, nu), or a :class:`~jaxtree._src.linear.linearize.LinearSystem` as the first
      argument (its coordinate names then label the modes);
    - `damping`: modal damping ratios ``zeta`` (scalar or (nu,)), Eq. (104) / Sec. III E;
    - `kind`: ``"real"``, ``"gyroscopic"`` or ``"general"``; detected with
      :func:`jaxtree.structure` when omitted (required when the matrices are traced,
      e.g. under ``jax.grad``: then no check is made and no labels are produced);
    - `labels`: names of the coordinates (default ``y1..ynu``).

    Raises :class:`UnstableError` for an unstable system (``sigma^2 < 0``, or an eigenvalue
    with a positive real part) and :class:`DefectiveError` for a nondiagonalizable one,
    the two kinds of vehicle the seed rejects. Repeated eigenvalues with independent
    eigenvectors are fine. In the real and gyroscopic cases the result is
    differentiable (``jax.grad`` of `frequencies`) for distinct nonzero frequencies.
    """
    modes_args(I, J, K, damping, kind, labels, rtol)
    I, J, K, coords, hinges_of = _system(I, J, K, labels)
    dtype = I.dtype
    nu = I.shape[0]
    traced = is_traced((I, J, K, damping))
    kind, definite = _kind(I, J, K, kind, traced, rtol)
    zeta = _modal_damping(damping, nu, dtype, kind, traced)
    P, Q, B0 = first_order(I, J, K)
    cdtype = jnp.result_type(dtype, jnp.complex64)
    if kind == "real":
        m = _real_modes(I, K, zeta, traced, cdtype)
    elif kind == "gyroscopic":
        m = _gyroscopic_modes(I, J, K, P, B0, zeta, definite, traced, cdtype)
    else:
        m = _general_modes_traced(I, J, K) if traced else _general_modes(I, J, K)

    # participation: |phi_ij|^2 I_ii, normalized per mode (numpy when concrete: no eager dispatch)
    xp = jnp if traced else np
    w = xp.abs(xp.asarray(m.shapes)) ** 2 * xp.diag(xp.asarray(I))[:, None]
    tot = xp.sum(w, axis=0, keepdims=True)
    part = jnp.asarray(w / xp.where(tot > 0, tot, 1.0))
    labs = () if traced else _labels(np.asarray(m.shapes), np.asarray(part), coords, np.asarray(m.rigid), hinges_of)
    cast = lambda x, dt: jnp.asarray(xp.asarray(x).astype(dt))
    return Modes(
        eigenvalues=cast(m.eigenvalues, cdtype),
        frequencies=m.frequencies,
        damping_ratios=cast(m.damping_ratios, dtype),
        shapes=m.shapes,
        right=cast(m.right, cdtype),
        left=cast(m.left, cdtype),
        P=P,
        Q=Q,
        B=m.B,
        rigid=m.rigid,
        participation=part,
        kind=kind,
        coordinates=coords,
        labels=labs,
    )


def _system(I, J, K, labels) -> tuple[jax.Array, jax.Array, jax.Array, tuple[str, ...], tuple[int, ...]]:
    """``I, J, K`` of one float dtype (at least float32; from a :class:`LinearSystem` given as
    `I`), the coordinate names and the hinge of each coordinate (empty unless a LinearSystem)."""
    hinges_of = ()
    if isinstance(I, LinearSystem):
        lin = I
        I, J, K = lin
        labels = lin.coordinates if labels is None else labels
        hinges_of = lin.hinges
    if J is None or K is None:
        raise TypeError("modes: give I, J, K (or a LinearSystem)")
    I, J, K = (jnp.asarray(x) for x in (I, J, K))
    dtype = jnp.result_type(I, J, K, jnp.float32)
    I, J, K = (x.astype(dtype) for x in (I, J, K))
    nu = I.shape[0]
    if I.shape != (nu, nu) or J.shape != (nu, nu) or K.shape != (nu, nu):
        raise ValueError(f"modes: I, J, K must be square of one size, got {I.shape}, {J.shape}, {K.shape}")
    coords = tuple(labels) if labels is not None else tuple(f"y{i + 1}" for i in range(nu))
    if len(coords) != nu:
        raise ValueError(f"modes: {len(coords)} labels for {nu} coordinates")
    return I, J, K, coords, hinges_of


def _kind(I, J, K, kind: str | None, traced: bool, rtol: float) -> tuple[str, bool]:
    """The case to solve (`kind` given, or detected by :func:`structure` on concrete matrices,
    which are checked against it) and whether K is positive definite (assumed when traced)."""
    definite = True
    if traced:
        if kind is None:
            raise ValueError(
                "modes: pass kind='real', 'gyroscopic' or 'general' when I, J, K are traced (e.g. under jax.grad)"
            )
    else:
        st = structure(I, J, K, rtol=rtol)
        if not st.I_symmetric or not st.I_positive:
            raise ModalError("modes: I must be symmetric positive definite (Eq. 42: a nonsingular inertia matrix)")
        if kind is None:
            kind = st.kind
        if kind == "real" and not (st.J_zero and st.K_symmetric):
            raise ModalError(f"modes: kind='real' needs J = 0 and K symmetric ({st.describe()})")
        if kind == "gyroscopic" and not (st.J_skew and st.K_symmetric):
            raise ModalError(f"modes: kind='gyroscopic' needs J skew and K symmetric ({st.describe()})")
        if kind == "gyroscopic" and not st.K_semidefinite:
            kind = "general"  # indefinite K: P is indefinite, no Hermitian form (gyroscopic stabilization possible)
        definite = st.K_positive
    if kind not in ("real", "gyroscopic", "general"):
        raise ValueError(f"modes: unknown kind {kind!r}")
    return kind, definite


def _modal_damping(damping, nu: int, dtype, kind: str, traced: bool) -> jax.Array:
    """The modal damping ratios zeta (nu,) of Eq. (104): zero when `damping` is None."""
    if damping is None:
        return jnp.asarray(np.zeros(nu, dtype))
    zeta = jnp.broadcast_to(jnp.asarray(damping, dtype), (nu,))
    if not traced and damping is not None:
        check_modal_damping(np.asarray(zeta), kind, "modes", "Eq. 104 / Sec. III E", "this system already has")
    return zeta


def check_modal_damping(zeta: np.ndarray, kind: str, who: str, where: str, system: str) -> None:
    """Modal damping ratios (`where` in the report) are finite and >= 0, and apply to undamped real
    or gyroscopic modes only: not to those of a `system` with a general J (errors from `who`)."""
    if np.any(zeta < 0) or not np.all(np.isfinite(zeta)):
        raise ValueError(f"{who}: modal damping ratios must be finite and >= 0, got {zeta.tolist()}")
    if kind == "general":
        raise ModalError(
            f"{who}: modal damping ({where}) applies to undamped real or gyroscopic modes; {system} a general J"
        )


# What each case computes: the fields of :class:`Modes` that it fills (before the dtype casts).
_Solved = namedtuple("_Solved", "eigenvalues frequencies damping_ratios shapes right left B rigid")


def _real_modes(I, K, zeta, traced: bool, cdtype) -> _Solved:
    """Eqs. (97)-(103), with the modal damping of Eq. (104)."""
    nu = I.shape[0]
    s2, phi = _real_core(I, K)
    rigid = np.zeros(nu, bool) if traced else _real_rigid(np.asarray(s2))
    return _real_fields(I, K, zeta, s2, phi, rigid, cdtype)


@build_jit
def _real_fields(I, K, zeta, s2, phi, rigid, cdtype) -> _Solved:
    """:func:`_real_modes` once the rigid modes are known: one program for a concrete system."""
    nu = I.shape[0]
    sigma = jnp.sqrt(jnp.clip(s2, 0.0))
    safe = jnp.where(rigid, 1.0, sigma)
    up = jnp.concatenate([phi, 1j * safe * phi], 0) / (jnp.sqrt(2.0) * safe)
    up = jnp.where(rigid[None, :], 0.0, up).astype(cdtype)
    right = jnp.concatenate([up, jnp.conj(up)], 1)
    left = jnp.conj(right)
    root = jnp.sqrt((1.0 - zeta**2).astype(cdtype))  # Eq. (104): eta = exp(lambda t)
    lam_up = -zeta * sigma + 1j * sigma * root
    lam = jnp.concatenate([lam_up, jnp.conj(lam_up)])
    C = (I @ phi) * (2.0 * zeta * sigma) @ (phi.T @ I)  # J equivalent to Eq. (104)
    B = jnp.block([[jnp.zeros_like(I), jnp.eye(nu, dtype=I.dtype)], [-jnp.linalg.solve(I, K), -jnp.linalg.solve(I, C)]])
    return _Solved(lam, sigma, zeta, phi, right, left, B, rigid)


def _real_rigid(s2: np.ndarray) -> np.ndarray:
    """The rigid (zero-frequency) modes among the eigenvalues ``sigma^2``; a negative one beyond
    round-off is a divergence (:class:`UnstableError`)."""
    scale = max(np.abs(s2).max(initial=0.0), 1e-300)
    if s2[0] < -ROUNDOFF_RTOL * scale:
        bad = s2[s2 < -ROUNDOFF_RTOL * scale]
        raise UnstableError(
            f"modes: sigma^2 < 0 ({bad.tolist()}): divergent (statically unstable) modes; "
            "the seed rejects such a vehicle (Sec. III D)"
        )
    return s2 <= ROUNDOFF_RTOL * scale


def _gyroscopic_modes(I, J, K, P, B0, zeta, definite: bool, traced: bool, cdtype) -> _Solved:
    """Eqs. (91)-(96) by the Hermitian form of Eq. (70), with the modal damping of Sec. III E."""
    nu = I.shape[0]
    L, sigma, low, k_evals, k_vecs = _gyroscopic(I, J, K, definite)
    if not traced and not definite:
        scale = max(float(np.max(np.abs(np.asarray(sigma)))), 1e-300)
        rigid_np = np.asarray(sigma) <= RIGID_SIGMA_RTOL * scale
    else:
        rigid_np = np.zeros(nu, bool) if not traced else None
    rigid = jnp.asarray(rigid_np) if rigid_np is not None else jnp.zeros(nu, bool)
    sigma = jnp.where(rigid, 0.0, sigma)  # square roots of round-off in K~ (about 1e-8) are zero
    safe = jnp.where(rigid, 1.0, sigma)
    v2 = low[nu:]
    Linv_T = lambda X: jax.scipy.linalg.solve_triangular(L.T, X, lower=False)
    ydot = Linv_T(v2.astype(cdtype))
    y = ydot / (1j * safe)
    up = jnp.concatenate([y, ydot], 0)
    up = jnp.where(rigid[None, :], 0.0, up)
    right = jnp.concatenate([up, jnp.conj(up)], 1)
    left = jnp.conj(right)  # Eq. (96)
    lam_up = (-zeta + 1j) * sigma  # Sec. III E: i sigma -> -zeta sigma + i sigma
    lam = jnp.concatenate([lam_up, jnp.conj(lam_up)])
    shapes = y
    if rigid_np is not None and rigid_np.any():
        # rigid-body shapes: the I-orthonormal null vectors of K (smallest eigenvalues of K~)
        nr = int(rigid_np.sum())
        null = Linv_T(k_vecs[:, :nr]).astype(cdtype)
        shapes = shapes.at[:, np.flatnonzero(rigid_np)].set(null)
    # damped state matrix: B + Phi (Lambda_d - Lambda) Phi'^T P (elastic columns only)
    dl = jnp.concatenate([-zeta * sigma, -zeta * sigma]).astype(cdtype)
    B = (B0 + (right * dl) @ (left.T @ P)).real
    return _Solved(lam, sigma, zeta, shapes, right, left, B, rigid)


def _general_modes(I, J, K) -> _Solved:
    """Eqs. (70)-(90) by a general eigensolver (concrete arrays), modes by ascending frequency;
    the damping ratios are ``-Re lambda / |lambda|``."""
    nu = I.shape[0]
    lam, right, left, _, _, B = _general(I, J, K, "general")  # numpy throughout
    sigma = np.abs(np.imag(lam[:nu]))
    absl = np.abs(lam[:nu])
    zeta = np.where(absl > 0, -np.real(lam[:nu]) / np.where(absl > 0, absl, 1.0), 0.0)
    # shapes: y part of Phi, scaled so that the largest entry is real and positive
    y = right[:nu, :nu]
    k = np.argmax(np.abs(y), axis=0)
    ph = y[k, np.arange(nu)]
    shapes = y * (np.abs(ph) / np.where(ph == 0, 1.0, ph))[None, :]
    rigid = absl <= ROUNDOFF_RTOL * max(float(np.max(absl)), 1e-300)
    order = np.argsort(sigma, kind="stable")
    if np.any(order != np.arange(nu)):
        sel = np.concatenate([order, order + nu])
        lam, right, left = lam[sel], right[:, sel], left[:, sel]
        sigma, zeta, shapes, rigid = sigma[order], zeta[order], shapes[:, order], rigid[order]
    return _Solved(*(jnp.asarray(x) for x in (lam, sigma, zeta, shapes, right, left, B, rigid)))
