"""A finite-element appendage on a body of the tree: its held-interface modes, its modal
invariants and its share of Eq. (30) in the frame of the body it is fixed to.

**Held-interface modes.** The appendage's interface nodes are rigidly fixed to a body ``b`` of the
tree. With ``b`` held, the free degrees of freedom ``f`` obey ``M_ff u'' + K_ff u = 0``; its modes
(mass-normalized, ``Phi^T M Phi = 1``, frequencies ``omega_j``) are Craig and Bampton's
fixed-interface normal modes. The interface's constraint modes are the appendage's six rigid
motions with ``b`` (every interface node rigidly joined to the body), so the appendage's motion is
``b``'s rigid motion plus ``Phi q``: the small set of Eq. (30) is the modal coordinates ``q``, and
the held-interface modes are Likins' held-base modes (Sec. III E) of the appendage.

**Its share of Eq. (30).** In ``b``'s frame, about its mass center O, a node at ``x = X + Phi_t q``
moves with the base's spatial velocity ``v = (w, v_O)`` and the deformation rates. Its
translational acceleration is ``a_O + w' x X + w x v_O + w x (w x x) + 2 w x x' + x''`` and its
rotation's ``w' + w x theta' + theta''``, so the accelerations of the degrees of freedom are
``B(q) [a_b; q''] + c(q, q', v)`` with ``B = [[-[x x], 1, Phi_t], [1, 0, Phi_r]]`` (rows by node). Gauss's
function ``1/2 acc^T M acc`` is the quadratic ``1/2 w^T A(q) w + w^T b`` of
:mod:`jaxtree._src.hybrid.substructure`, ``A = B^T M B``, ``b = B^T M c``; its Taylor
coefficients ``A0, A1, G0, G1, G2`` (:class:`~jaxtree._src.hybrid.substructure.Terms`) fill the
slots a rigid-chain substructure fills, with the modal stiffness ``omega_j^2`` and damping
``2 zeta_j omega_j`` in place of the hinge springs.

**Nodes or sample points.** ``1/2 acc^T M acc`` over the nodes is exact only for a mass matrix
that turns with the frame (a lumped mass, or the plate's, whose blocks are multiples of the unit
matrix). A consistent beam mass couples a node's translations with its neighbours' slopes and
is not invariant under the frame's rotation: the Gauss function over the nodes then lacks the
slopes of the rigid field's velocity products, and its linearization about a spin comes out
neither symmetric nor skew by the elements' length squared (a circulatory stiffness and a
damping-like Coriolis part, which make a spinning vehicle "general" for :func:`jaxtree.modes`).
A structure whose elements carry their mass (:meth:`.fe.Elements.samples`: the beams of
:func:`jaxtree.beam`) is taken instead as particles and rigid sections at four Gauss points per
element, the interpolated fields' own inertia (:func:`_sample_gauss`), whose sums reproduce the
consistent mass matrix exactly: a system of particles and rigid bodies, symmetric, skew and
conservative to round-off. A structure of matrices alone (a file, OP4, MatrixMarket) keeps the
nodes, with the rigid body's velocity products in the base rows
(:func:`_rigid_velocity_products`), the deformation's momentum (:func:`_momentum_slopes`) and
the symmetric and skew parts of the modal rows' velocity products
(:func:`_modal_velocity_products`).

**Geometric stiffness.** Linear kinematics (nodes move along straight lines) leave out the
shortening of a bent structure, which a chain of rigid panels has. Under the inertial preload of
the base's motion, ``f = -M acc_rigid`` (``acc_rigid`` the nodes' acceleration at ``q = 0``, linear
in ``a_b`` and quadratic in ``v``), the structure's elements carry axial forces, and their
geometric stiffness ``K_G`` adds ``Phi^T K_G Phi q`` to the modal rows: Eq. (30) keeps terms of
first order in ``q``, and these are of that order. Without it a beam spun above its first
frequency diverges (the premature linearization of Kane, Ryan and Banerjee, 1987); with it a
cantilever's frequencies on a spinning hub follow Southwell's ``omega^2 = omega_1^2 + K Omega^2``.
The preload's static response uses the held structure (``K_ff``): the quasi-static stress state
of the appendage under the base's motion. It enters the coefficients ``A1`` (the base's
acceleration) and ``G1`` (its velocity) of the modal rows.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.kinematics import tilde
from ..errors import SceneError
from ..hybrid.substructure import Terms, taylor_terms
from ..numerics import build_jit, host_or_traced, is_traced
from .fe import Elements, FEModel, Samples


class Appendage(eqx.Module):
    """A finite-element appendage reduced to its held-interface modes (module docstring), fixed to
    body `body` of a tree.

    Arrays in the body's frame; the rigid invariants about the interface point:

    - `point` (3,): the interface point, from the body's mass center; `frame` (3, 3): the
      appendage's frame in the body's (columns: its axes);
    - `frequencies` (k,): the retained held-interface modes' circular frequencies, ascending;
      `damping` (k,): their damping ratios;
    - `shapes` (N, k): the mode shapes (mass-normalized) over all the structure's degrees of
      freedom (zero at the interface), in the body's frame;
    - `nodes` (n_nodes, 3): the nodes' positions from the interface point, body's frame;
    - `mass`, `first_moment` (3,), `inertia` (3, 3): the rigid appendage about the interface point;
    - `participation` (k, 6): ``L_j = phi_j^T M T`` over the six rigid motions (rotations, then
      translations) about the interface point; `effective_mass` (property): ``L_j^2``, whose sum over
      all modes approaches the rigid mass;
    - `terms`: its share of Eq. (30) (:class:`Terms`, about the body's mass center), geometric
      stiffness included when `geometric` is True;
    - `outputs` (static): node indices whose motion results report; `all_frequencies`: every
      held-interface mode's frequency (retained or not), for the truncation estimate;
    - `edges` (static): node pairs that the 3D viewer joins (the elements' sides; empty for a
      structure of matrices alone, whose nodes it draws as points).
    """

    point: jax.Array
    frame: jax.Array
    frequencies: jax.Array
    damping: jax.Array
    shapes: jax.Array
    nodes: jax.Array
    mass: jax.Array
    first_moment: jax.Array
    inertia: jax.Array
    participation: jax.Array
    terms: Terms
    all_frequencies: jax.Array
    body: object = eqx.field(static=True)
    interface: tuple = eqx.field(static=True)
    outputs: tuple = eqx.field(static=True)
    dofs: int = eqx.field(static=True)
    geometric: bool = eqx.field(static=True)
    name: str = eqx.field(static=True, default="")
    edges: tuple = eqx.field(static=True, default=())

    @property
    def n_modes(self) -> int:
        return int(self.frequencies.shape[0])

    @property
    def effective_mass(self):
        """(k, 6): each mode's modal effective mass along the six rigid motions about the interface
        point (rotations: kg m^2; translations: kg)."""
        return self.participation**2

    @property
    def stiffness(self):
        """(k,): the modal stiffness ``omega_j^2`` (unit modal masses)."""
        return self.frequencies**2

    @property
    def modal_damping(self):
        """(k,): ``2 zeta_j omega_j``."""
        return 2.0 * self.damping * self.frequencies

    def displacement(self, q, node: int):
        """The six (or three) displacements of `node` for modal coordinates `q`, body's frame."""
        d = self.dofs
        return self.shapes[d * node : d * node + d] @ q


def _dof_index(dofs: int, nodes) -> np.ndarray:
    return (np.asarray(nodes, np.int64)[:, None] * dofs + np.arange(dofs)[None, :]).ravel()


def _rigid_modes(X, dofs: int, dtype):
    """(N, 6): the degrees of freedom of the six rigid motions (small rotation, translation) about
    the origin of the node positions `X` (n, 3)."""
    n = X.shape[0]
    eye = jnp.eye(3, dtype=dtype)
    skew_minus = -tilde(X)  # translation of a node under a rotation e: e x X = -[X x] e
    t_rows = jnp.concatenate([skew_minus, jnp.broadcast_to(eye, (n, 3, 3))], -1)  # (n, 3, 6)
    if dofs == 3:
        return t_rows.reshape(3 * n, 6)
    r_rows = jnp.concatenate([jnp.broadcast_to(eye, (n, 3, 3)), jnp.zeros((n, 3, 3), dtype)], -1)
    return jnp.concatenate([t_rows, r_rows], 1).reshape(6 * n, 6)


def held_interface_modes(fe: FEModel, interface):
    """``(omega2 (n_free,), Phi (N, n_free))``: every fixed-interface normal mode of `fe` with the
    degrees of freedom of the `interface` nodes held, mass-normalized, ascending; ``Phi`` is zero
    on the interface. By Cholesky reduction of ``K_ff phi = omega^2 M_ff phi`` to a symmetric
    eigenproblem, differentiable (JAX's eigenvector derivatives need distinct frequencies)."""
    N = fe.mass.shape[0]
    held = _dof_index(fe.dofs, interface)
    free = np.setdiff1d(np.arange(N), held)
    Mff = fe.mass[np.ix_(free, free)]
    Kff = fe.stiffness[np.ix_(free, free)]
    Lc = jnp.linalg.cholesky(Mff)
    tri = jax.scipy.linalg.solve_triangular
    C = tri(Lc, tri(Lc, Kff, lower=True).T, lower=True)
    C = 0.5 * (C + C.T)
    w2, V = jnp.linalg.eigh(C)
    phi = tri(Lc.T, V, lower=False)
    Phi = jnp.zeros((N, free.size), phi.dtype).at[free].set(phi)
    return w2, Phi


def _static_share(fe: FEModel, w2, Phi, R, extent: float):
    """The quasi-static rule of ``n_modes="auto"``, for each number of retained modes (n_free + 1,):
    under each of the base's six unit accelerations (the columns of the rigid motions `R`, N x 6;
    rotations scaled by the appendage's `extent`, so that each is a unit acceleration at its far
    end), the largest translation of the neglected modes' static response, over the largest
    translation of the whole response to any of them. One scale for all six keeps an axial load,
    whose response is tiny beside the bending's, from asking for every axial mode."""
    dofs = fe.dofs
    n = fe.n_nodes
    t = (np.arange(n)[:, None] * dofs + np.arange(3)[None, :]).ravel()
    scale = np.concatenate([np.full(3, extent), np.ones(3)])
    f = -(np.asarray(fe.mass) @ np.asarray(R)) * scale[None, :]  # (N, 6)
    Phi, w2 = np.asarray(Phi), np.asarray(w2)
    contrib = (Phi.T @ f) / w2[:, None]  # (n_free, 6): modal static amplitudes
    whole = Phi[t] @ contrib  # the full static response (a complete basis), translations
    top = float(np.max(np.abs(whole)))
    if top == 0.0:
        return np.zeros(w2.size + 1)
    share = np.zeros(w2.size + 1)
    rest = whole.copy()
    share[0] = 1.0
    for k in range(w2.size):
        rest -= np.outer(Phi[t, k], contrib[k])
        share[k + 1] = float(np.max(np.abs(rest))) / top
    return share


def _gauss(X, Phi, M, W, P, KgA, dofs: int, geometric: bool):
    """Gauss's function of the appendage (module docstring): ``gauss(q, q', v) -> (A, b)``."""
    n = X.shape[0]
    k = Phi.shape[1]
    dtype = Phi.dtype
    t = _dof_index(dofs, range(n)).reshape(n, dofs)[:, :3].ravel()
    r = _dof_index(dofs, range(n)).reshape(n, dofs)[:, 3:].ravel() if dofs == 6 else None
    Pt = Phi[t].reshape(n, 3, k)
    Pr = Phi[r].reshape(n, 3, k) if r is not None else None
    N = Phi.shape[0]

    def gauss(q, qd, v):
        w, vo = v[:3], v[3:]
        x = X + Pt @ q
        B = jnp.zeros((N, 6 + k), dtype)
        eye = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (n, 3, 3))
        Bt = jnp.concatenate([-tilde(x), eye, Pt], -1)  # (n, 3, 6+k)
        B = B.at[t].set(Bt.reshape(3 * n, 6 + k))
        xd = Pt @ qd
        ct = jnp.cross(w, vo)[None] + jnp.cross(w[None], jnp.cross(w[None], x)) + 2.0 * jnp.cross(w[None], xd)
        c = jnp.zeros((N,), dtype).at[t].set(ct.ravel())
        if Pr is not None:
            Br = jnp.concatenate([eye, jnp.zeros((n, 3, 3), dtype), Pr], -1)
            B = B.at[r].set(Br.reshape(3 * n, 6 + k))
            c = c.at[r].set(jnp.cross(w[None], Pr @ qd).ravel())
        A = B.T @ M @ B
        b = B.T @ (M @ c)
        if geometric:
            # the preload of the base's motion at q = 0: acc_rigid = B0[:, :6] a_b + c0(v); its
            # geometric stiffness on the modal rows, A (a_b part) and b (velocity part)
            A = A.at[6:, :6].add(jnp.einsum("aij,j->ia", KgA, q))
            x0 = X
            c0t = jnp.cross(w, vo)[None] + jnp.cross(w[None], jnp.cross(w[None], x0))
            c0 = jnp.zeros((N,), dtype).at[t].set(c0t.ravel())
            Nf = W @ c0  # axial forces of the velocity preload
            b = b.at[6:].add(jnp.einsum("e,eij,j->i", Nf, P, q))
        return A, b

    return gauss


def _sample_gauss(X, T, m, R, J, W, P, KgA, geometric: bool):
    """Gauss's function of the appendage as particles and rigid sections (:class:`Samples`):
    ``gauss(q, q', v) -> (A, b)``. Point ``p`` at ``x = X_p + T_p q`` (from the base's mass center,
    base's frame) of mass ``m_p`` accelerates as a node of the module docstring; its section,
    turned by ``phi = R_p q`` with inertia ``J_p`` (turned with it to first order), is a rigid
    body: ``1/2 alpha^T J alpha + alpha^T (Omega x J Omega)`` with ``Omega = w + phi'``,
    ``alpha = w' + w x phi' + phi''``. A system of particles and rigid bodies: its linearization
    about a steady spin is symmetric (stiffness) and skew (Coriolis) exactly, and it keeps energy
    and momentum."""
    n = X.shape[0]
    dtype = T.dtype
    eye = jnp.broadcast_to(jnp.eye(3, dtype=dtype), (n, 3, 3))
    zero = jnp.zeros((n, 3, 3), dtype)
    Br = jnp.concatenate([eye, zero, R], -1)  # (n, 3, 6 + k): the sections' angular accelerations

    def gauss(q, qd, v):
        w, vo = v[:3], v[3:]
        x = X + T @ q
        xd = T @ qd
        Bt = jnp.concatenate([-tilde(x), eye, T], -1)  # (n, 3, 6 + k)
        ct = jnp.cross(w, vo)[None] + jnp.cross(w[None], jnp.cross(w[None], x)) + 2.0 * jnp.cross(w[None], xd)
        A = jnp.einsum("p,pai,paj->ij", m, Bt, Bt)
        b = jnp.einsum("p,pai,pa->i", m, Bt, ct)
        phi, phid = R @ q, R @ qd
        Jc = J + tilde(phi) @ J - J @ tilde(phi)
        Om = w[None] + phid
        hr = jnp.einsum("pab,pb->pa", Jc, jnp.cross(w[None], phid)) + jnp.cross(Om, jnp.einsum("pab,pb->pa", Jc, Om))
        A = A + jnp.einsum("pai,pab,pbj->ij", Br, Jc, Br)
        b = b + jnp.einsum("pai,pa->i", Br, hr)
        if geometric:
            A = A.at[6:, :6].add(jnp.einsum("aij,j->ia", KgA, q))
            c0 = jnp.cross(w, vo)[None] + jnp.cross(w[None], jnp.cross(w[None], X))
            b = b.at[6:].add(jnp.einsum("e,eij,j->i", W @ c0.reshape(-1), P, q))
        return A, b

    return gauss


def _sample_terms(samples: Samples, fe: FEModel, iface, Phi_s, Wneg, P, frame, point, geometric: bool, mass) -> Terms:
    """The appendage's :class:`Terms` from its sample points (:func:`_sample_gauss`), in the body's
    frame about its mass center (`point`: the interface point from it, `frame`: the structure's
    axes)."""
    idx = samples.dof_array
    to_body = lambda S: jnp.einsum("ab,pbk->pak", frame, jnp.einsum("pcd,pdk->pck", S, Phi_s[idx]))
    T, R = to_body(samples.translation), to_body(samples.rotation)
    X = (samples.positions - fe.nodes[iface[0]][None, :]) @ frame.T + point[None, :]
    J = jnp.einsum("ab,pbc,dc->pad", frame, samples.inertia, frame)
    # the preload per unit acceleration of each point (body's axes): forces -m_p on the points
    n = X.shape[0]
    W = Wneg @ (samples.matrix(fe.mass.shape[0]) * jnp.repeat(samples.mass, 3)[None, :])
    W = W @ jnp.kron(jnp.eye(n, dtype=W.dtype), frame).T
    return _sample_taylor(X, T, samples.mass, R, J, W, P, geometric, mass)


@build_jit
def _sample_taylor(X, T, m, R, J, W, P, geometric: bool, mass):
    n = X.shape[0]
    eye = jnp.broadcast_to(jnp.eye(3, dtype=X.dtype), (n, 3, 3))
    R0 = jnp.concatenate([-tilde(X), eye], -1).reshape(3 * n, 6)  # the points' rigid accelerations
    KgA = jnp.einsum("ea,eij->aij", W @ R0, P)
    return taylor_terms(_sample_gauss(X, T, m, R, J, W, P, KgA, geometric), T.shape[2], T.dtype, True, mass)


@build_jit
def _appendage_terms(X, Phi, M, W, P, R0, dofs: int, geometric: bool, mass):
    k = Phi.shape[1]
    KgA = jnp.einsum("ea,eij->aij", W @ R0, P)  # (6, k, k): the preload of each unit base acceleration
    gauss = _gauss(X, Phi, M, W, P, KgA, dofs, geometric)
    terms = taylor_terms(gauss, k, Phi.dtype, True, mass)
    A1, G2 = _momentum_slopes(terms)
    G0 = terms.G0.at[:6].set(_rigid_velocity_products(terms.A0[:6, :6]))
    G1 = terms.G1.at[:6].set(jnp.moveaxis(jax.vmap(_rigid_velocity_products, 2, 0)(A1[:6, :6]), 0, -1))
    G1, G2 = _modal_velocity_products(G1, G2)
    return eqx.tree_at(lambda tm: (tm.A1, tm.G0, tm.G1, tm.G2), terms, (A1, G0, G1, G2))


def _momentum_slopes(terms: Terms):
    """``A1`` and ``G2`` with the deformation's translational momentum exact: the slope of the
    rigid first moment in ``q_j`` (the coupling blocks ``-+[L_j x]`` of ``A1[:6, :6, j]``) and
    the Coriolis force ``2 w x L_j q_j'`` on the base's translation (``G2[3:6, :3, j]``), both with
    the participation ``L_j = T^T M phi_j`` of ``A0[3:6, 6:]``.

    The Gauss function moves the rigid rotation columns with the translations ``x = X + phi_t q``
    and leaves the nodes' rotations alone, so its slopes carry ``sum M_tt phi_t`` where the
    momentum is ``T^T M phi = M_tt phi_t + M_tr phi_r``: with a consistent mass the rotations'
    share is missing (7e-4 of ``L_1`` and 1.3e-2 of ``L_3`` with 20 beam elements, as the elements'
    length squared). The
    modal rows' coupling to the base's translation is ``L`` itself, so the two disagreed: the
    linearized stiffness of a free spinning vehicle came out unsymmetric (its modal block by 7e-5
    of the first modal stiffness, 20 elements), a circulatory force. With ``L`` in both places it is
    symmetric to round-off (tests/test_appendage.py)."""
    L = terms.A0[3:6, 6:]  # (3, k)
    Lx = jax.vmap(tilde, 1, -1)(L)  # (3, 3, k): [L_j x]
    A1 = terms.A1.at[3:6, 0:3].set(-Lx).at[0:3, 3:6].set(Lx)
    G2 = terms.G2.at[3:6, 0:3].set(-2.0 * Lx)  # column a: 2 e_a x L_j
    return A1, G2


def _modal_velocity_products(G1, G2):
    """The modal rows' velocity products made conservative: the centripetal stiffness
    ``1/2 G1[6+i, a, b, j] v_a v_b`` symmetric in ``(i, j)``, the Coriolis coefficients
    ``G2[6+i, a, j] v_a`` skew in ``(i, j)`` (their symmetric and skew parts kept).

    The nodes' accelerations carry ``w x (w x x)`` and ``2 w x x'`` at the translational degrees of
    freedom (and ``w x theta'`` at the rotational ones), weighted by the mass matrix. A lumped mass
    makes these blocks exactly symmetric and skew; a consistent one, which couples a node's
    translations with the slopes of its neighbours, does not: it is not invariant under the
    frame's rotation, and the slopes of the rotating field are missing (see
    :func:`_rigid_velocity_products`). The defect is of the order of the elements' length squared
    (10-element beam: 8e-3 of the Coriolis block symmetric and 4e-4 of the centripetal block skew;
    40 elements: 5e-4 and 3e-5) but of the wrong kind: a symmetric Coriolis part damps or drives
    the modes of a spinning appendage, and a skew centripetal part is a circulatory force; either
    makes a spinning vehicle's linearization "general" (jaxtree.modes) instead of gyroscopic. The
    parts kept are those of the continuum (no work by Coriolis forces, a potential for the
    centripetal ones); the part removed is discretization error."""
    m1 = G1[6:]  # (k, 6, 6, k)
    m2 = G2[6:]  # (k, 6, k)
    G1 = G1.at[6:].set(0.5 * (m1 + jnp.transpose(m1, (3, 1, 2, 0))))
    G2 = G2.at[6:].set(0.5 * (m2 - jnp.transpose(m2, (2, 1, 0))))
    return G1, G2


def _rigid_velocity_products(inertia):
    """The base rows of ``G0`` for the appendage as one rigid body of spatial inertia `inertia`
    (6 x 6 about the base's mass center, rotations first): the Hessian of ``v x* (I v)`` in ``v``.

    The nodes' accelerations of the Gauss function carry the rigid field's velocity products at
    the translational degrees of freedom only. Where the mass matrix has rotational entries (a
    consistent beam or plate mass: the slopes of the interpolated translations), the slopes of that
    field (``w x (w x x)`` is linear in ``x``) are missing, and so is a part of the rigid body's
    gyroscopic moment ``w x J w``: a term that does no work, so the energy is kept, but turns the
    angular momentum (2e-4 of it over 20 s on a spinning hub with a 10-element beam). The rigid
    body's own products, from its inertia (exact for a consistent mass), replace them."""

    def products(v):
        h = inertia @ v
        w, u, hw, hu = v[:3], v[3:], h[:3], h[3:]
        return jnp.concatenate([jnp.cross(w, hw) + jnp.cross(u, hu), jnp.cross(w, hu)])

    return jax.hessian(products)(jnp.zeros(6, inertia.dtype))


def _preload_maps(fe: FEModel, interface, Phi):
    """``W (E, N)``: the elements' stress resultants per unit *negative* force on each degree of
    freedom (the static response of the held structure to ``f = -1``; times the mass matrix, or
    the sample points' masses, it is the response to the inertial preload ``-M acc``), and
    ``P (E, k, k)``: the geometric stiffness of each unit resultant, projected on the modes."""
    el = fe.elements
    assert el is not None, "checked by appendage()"
    N = fe.mass.shape[0]
    held = _dof_index(fe.dofs, interface)
    free = np.setdiff1d(np.arange(N), held)
    Kff = fe.stiffness[np.ix_(free, free)]
    comp = jnp.zeros((N, N), fe.mass.dtype).at[np.ix_(free, free)].set(jnp.linalg.inv(Kff))
    W = jax.vmap(el.stresses, in_axes=1, out_axes=1)(-comp)  # (E, N)
    dofs, G = el.blocks()
    Pe = Phi[dofs]  # (E, d, k)
    P = jnp.einsum("eak,eab,ebl->ekl", Pe, G, Pe)
    return W, P


def appendage(
    fe: FEModel,
    body,
    *,
    interface=(0,),
    point=(0.0, 0.0, 0.0),
    frame=None,
    n_modes: int | str = "auto",
    tol: float = 1e-2,
    damping=0.0,
    outputs=(),
    geometric: bool = True,
    name: str = "",
) -> Appendage:
    """A finite-element appendage fixed to `body` (a body's name or index of the tree it will join).

    - `fe`: the structure (:class:`FEModel`, e.g. from :func:`jaxtree.beam` or a file);
    - `interface`: the node or nodes rigidly fixed to the body (their degrees of freedom are held
      for the modes); the first is the interface point, placed at `point` (from the body's mass
      center, body's frame) with the structure's axes along the columns of `frame` (default: the
      body's own);
    - `n_modes`: the held-interface modes retained, lowest first: a number, or ``"auto"``: the
      fewest whose neglected part of the quasi-static response to the base's six unit
      accelerations (rotations times the appendage's extent) is at most `tol` of the largest
      response (translations, the largest over the structure and the six);
    - `damping`: modal damping ratios (scalar or one per retained mode);
    - `outputs`: node indices whose motion the results report (tip, corners);
    - `name`: a label for results and messages;
    - `geometric`: add the geometric stiffness of the base's inertial preload (module
      docstring; needs the structure's elements). On by default: without it a spinning appendage
      is wrong above its first frequency.

    Differentiable in `fe`'s arrays, `point` and `frame` (the number of modes fixed).
    """
    if not isinstance(fe, FEModel):
        raise SceneError(f"appendage: fe must be a jaxtree.FEModel, got {type(fe).__name__}")
    iface = tuple(int(i) for i in np.atleast_1d(np.asarray(interface)))
    for i in iface:
        if not 0 <= i < fe.n_nodes:
            raise SceneError(f"appendage: interface node {i} is not a node of the structure (0..{fe.n_nodes - 1})")
    outs = tuple(int(i) for i in outputs)
    for i in outs:
        if not 0 <= i < fe.n_nodes:
            raise SceneError(f"appendage: output node {i} is not a node of the structure (0..{fe.n_nodes - 1})")
    if geometric and fe.elements is None:
        raise SceneError(
            "appendage: geometric=True needs the structure's elements (FEModel.elements), for the geometric "
            "stiffness of the spin's preload; pass geometric=False only for an appendage that does not spin"
        )
    dtype = fe.mass.dtype
    as_array = functools.partial(host_or_traced, dtype=dtype)
    frame = None if frame is None else as_array(frame)
    point = as_array(point)
    w2, Phi_all = _held_modes(fe, iface)
    n_free = int(w2.shape[0])
    if isinstance(n_modes, str):
        if n_modes != "auto":
            raise SceneError(f"appendage: n_modes must be a number or 'auto', got {n_modes!r}")
        if is_traced((fe, w2)):
            raise SceneError("appendage: n_modes='auto' needs concrete matrices; give a number under jax transforms")
        X_s = np.asarray(fe.nodes) - np.asarray(fe.nodes)[iface[0]]  # from the interface point
        extent = float(np.max(np.linalg.norm(X_s, axis=1))) or 1.0
        share = _static_share(fe, w2, Phi_all, _rigid_modes_at(X_s, fe.dofs), extent)
        k = int(np.argmax(share <= tol)) if (share <= tol).any() else n_free
        k = max(k, 1)
    else:
        k = int(n_modes)
        if not 1 <= k <= n_free:
            raise SceneError(f"appendage: n_modes must be 1..{n_free} (the free degrees of freedom), got {n_modes!r}")
    return _assemble(fe, w2, Phi_all, frame, point, damping, body, iface, outs, k, bool(geometric), str(name))


@build_jit
def _held_modes(fe: FEModel, iface: tuple):
    """:func:`held_interface_modes`, one program for a concrete structure (eagerly, its
    operations would each compile on a first build)."""
    return held_interface_modes(fe, iface)


@build_jit
def _rigid_modes_at(X, dofs: int):
    """:func:`_rigid_modes` of concrete positions, for the host-side rule of ``n_modes="auto"``."""
    return _rigid_modes(X, dofs, X.dtype)


@build_jit
def _assemble(fe: FEModel, w2, Phi_all, frame, point, damping, body, iface, outs, k: int, geometric: bool, name: str):
    """:func:`appendage` once its interface and number of modes are fixed: the modes and their
    terms in the body's frame, one program for a concrete structure."""
    dtype = fe.mass.dtype
    frame = jnp.eye(3, dtype=dtype) if frame is None else frame
    X_s = fe.nodes - fe.nodes[iface[0]]  # from the interface point, structure's frame
    R_s = _rigid_modes(X_s, fe.dofs, dtype)
    Phi_s = Phi_all[:, :k]
    omega = jnp.sqrt(jnp.maximum(w2, 0.0))
    zeta = jnp.broadcast_to(jnp.asarray(damping, dtype), (k,))
    # to the body's frame: every node's translation (and rotation) block turns by `frame`
    nb = fe.n_nodes * fe.dofs // 3
    Cbig = jnp.kron(jnp.eye(nb, dtype=dtype), frame)
    Phi = Cbig @ Phi_s
    M = Cbig @ fe.mass @ Cbig.T
    X = X_s @ frame.T  # from the interface point
    R = Cbig @ R_s @ jnp.kron(jnp.eye(2, dtype=dtype), frame.T)  # rigid motions in body-frame axes
    Mr = R.T @ M @ R
    mass = Mr[3, 3]
    first = jnp.stack([Mr[2, 4], Mr[0, 5], Mr[1, 3]])  # m c from the coupling block -[m c x]
    inertia = Mr[:3, :3]
    L = Phi.T @ M @ R
    samples = fe.elements.samples(fe.nodes) if isinstance(fe.elements, Elements) else None
    Xo = X + point[None, :]  # from the body's mass center
    if geometric:
        Wneg, P = _preload_maps(fe, iface, Phi_s)
    else:
        Wneg, P = jnp.zeros((0, M.shape[0]), dtype), jnp.zeros((0, k, k), dtype)
    if samples is None:
        W = Wneg @ fe.mass @ Cbig.T  # per unit acceleration of each degree of freedom, body's axes
        Ro = _rigid_modes(Xo, fe.dofs, dtype)
        terms = _appendage_terms(Xo, Phi, M, W, P, Ro, fe.dofs, geometric, mass)
    else:
        terms = _sample_terms(samples, fe, iface, Phi_s, Wneg, P, frame, point, geometric, mass)
    return Appendage(
        point=point,
        frame=frame,
        frequencies=omega[:k],
        damping=zeta,
        shapes=Phi,
        nodes=X,
        mass=mass,
        first_moment=first,
        inertia=inertia,
        participation=L,
        terms=terms,
        all_frequencies=omega,
        body=body,
        interface=iface,
        outputs=outs,
        dofs=fe.dofs,
        geometric=geometric,
        name=name,
        edges=_edges(fe),
    )


def _edges(fe: FEModel) -> tuple:
    """The node pairs joined by the structure's elements (beam elements, the plate's quadrilateral
    sides once each), for drawing."""
    el = fe.elements
    if el is None:
        return ()
    if isinstance(el, Elements):
        return tuple((int(a), int(b)) for a, b in el.nodes)
    sides = set()
    for quad in el.nodes:
        for i in range(len(quad)):
            a, b = int(quad[i]), int(quad[(i + 1) % len(quad)])
            sides.add((min(a, b), max(a, b)))
    return tuple(sorted(sides))
