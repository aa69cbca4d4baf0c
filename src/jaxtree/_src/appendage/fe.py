"""A structure's finite-element model (mass and stiffness matrices on a node table) and
generators of its own for beams and plates.

The report's flexible appendages are chains of rigid panels; the structures engineers model are
finite-element models, and what a multibody tool takes in from them is a mass matrix ``M``, a
stiffness matrix ``K`` and the nodes they act on (:class:`FEModel`). Each node carries either six
degrees of freedom (three translations, then three small rotations: beams and shells) or three
(translations: solids), in the appendage's own frame.

:func:`beam` builds one: a straight 3D Euler-Bernoulli beam of two-node, twelve-degree-of-freedom
elements with the consistent mass matrix (Przemieniecki, *Theory of Matrix Structural Analysis*,
1968, Sec. 5.3 and 11.3), differentiable in its length, material and section (every argument a
JAX array may carry a tracer). Its elements are kept (:class:`Elements`) so that the geometric
stiffness of an axial preload can be formed (:func:`geometric_stiffness`): the centrifugal
stiffening of a spinning appendage (:mod:`.model`). :func:`plate` builds a flat rectangular
plate (a solar array's panel) of four-node shell elements: bilinear membrane, Reissner-Mindlin
bending with the transverse shear at the element's center (Hughes, *The Finite Element Method*,
1987, Sec. 5.6: selective reduced integration), consistent mass; its :class:`PlateElements` give
the geometric stiffness of in-plane stress.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError
from ..numerics import build_jit, host_or_traced, is_traced


class Elements(eqx.Module):
    """Two-node beam elements, for the geometric stiffness of an axial load: `nodes` (static,
    pairs of node indices), `frame` (ne, 3, 3: rows the element's local axes x, y, z in the
    appendage's frame), `length` (ne,), `axial` (ne,: EA / L); and, for the inertia of the
    interpolated fields (:meth:`samples`), `line_mass` (ne,: rho A) and `polar_mass` (ne,: the
    torsional rotary inertia per length, rho (Iy + Iz)), or None when unknown (a file of an older
    version: the appendage then weights the nodes by the mass matrix)."""

    frame: jax.Array
    length: jax.Array
    axial: jax.Array
    nodes: tuple = eqx.field(static=True)
    line_mass: jax.Array | None = None
    polar_mass: jax.Array | None = None

    def samples(self, positions) -> Samples | None:
        """The elements' mass as points and sections at four Gauss points per element
        (:class:`Samples`), whose weighted sums reproduce the consistent mass matrix exactly
        (tests/test_appendage.py); None without `line_mass`. `positions` (n_nodes, 3): the nodes."""
        if self.line_mass is None or self.polar_mass is None:
            return None
        xi, wq = np.polynomial.legendre.leggauss(4)
        xi, wq = (xi + 1.0) / 2.0, wq / 2.0  # on [0, 1], weights summing to 1
        dtype = self.length.dtype
        ne, ng = len(self.nodes), xi.size
        L = self.length[:, None]  # (ne, 1)
        x = jnp.asarray(xi, dtype)[None, :]
        H = [1 - 3 * x**2 + 2 * x**3, (x - 2 * x**2 + x**3) * L, 3 * x**2 - 2 * x**3, (-(x**2) + x**3) * L]
        dH = [(-6 * x + 6 * x**2) / L, 1 - 4 * x + 3 * x**2, (6 * x - 6 * x**2) / L, -2 * x + 3 * x**2]
        z = jnp.zeros((ne, ng), dtype)
        lin = [1 - x, x]

        def local(rows):  # rows[c][d]: (ne, ng) coefficient of local dof d in component c -> (ne, ng, 3, 12)
            return jnp.stack(
                [jnp.stack([jnp.broadcast_to(rows[c].get(d, z), (ne, ng)) for d in range(12)], -1) for c in range(3)],
                -2,
            )

        # translations (u, v, w) and the section's rotation: torsion linear, slopes of the Hermite fields
        # (v' = th_z, w' = -th_y: the element's sign convention)
        Nt = local(
            [
                {0: lin[0], 6: lin[1]},
                {1: H[0], 5: H[1], 7: H[2], 11: H[3]},
                {2: H[0], 4: -H[1], 8: H[2], 10: -H[3]},
            ]
        )
        Nr = local(
            [
                {3: lin[0], 9: lin[1]},
                {2: -dH[0], 4: dH[1], 8: -dH[2], 10: dH[3]},
                {1: dH[0], 5: dH[1], 7: dH[2], 11: dH[3]},
            ]
        )
        T = jax.vmap(element_rotation)(self.frame)  # (ne, 12, 12): structure -> local dofs
        F = self.frame  # (ne, 3, 3): rows the local axes
        glob = lambda Nl: jnp.einsum("eac,egad,edf->egcf", F, Nl, T)  # to the structure's frame
        a = np.asarray([p[0] for p in self.nodes], np.int64)
        X = positions[a][:, None, :] + (x[..., None] * L[..., None]) * F[:, None, 0, :]
        w = jnp.asarray(wq, dtype)[None, :] * self.length[:, None]  # (ne, ng): lengths
        Jl = jnp.zeros((3, 3), dtype).at[0, 0].set(1.0)
        J = jnp.einsum("eac,ab,ebd->ecd", F, Jl, F)  # the axis' projector, structure frame
        dofs = np.repeat(np.asarray(element_dofs(self.nodes), np.int64), ng, axis=0)
        return Samples(
            dofs=tuple(tuple(int(i) for i in row) for row in dofs),
            translation=glob(Nt).reshape(ne * ng, 3, 12),
            rotation=glob(Nr).reshape(ne * ng, 3, 12),
            positions=X.reshape(ne * ng, 3),
            mass=(self.line_mass[:, None] * w).reshape(-1),
            inertia=((self.polar_mass[:, None] * w)[..., None, None] * J[:, None]).reshape(ne * ng, 3, 3),
        )

    def stresses(self, u):
        """The preload's stress resultants (one per element: the axial force) in the static
        displacement `u` (N,), linear in it."""
        return axial_forces(self, u)

    def blocks(self):
        """``(dofs (E, 12), G (E, 12, 12))``: the geometric stiffness of a unit stress resultant,
        on the degrees of freedom it acts on, in the structure's frame."""
        Gl = jax.vmap(geometric_element)(self.length, jnp.ones_like(self.length))
        T = jax.vmap(element_rotation)(self.frame)
        return element_dofs(self.nodes), jnp.einsum("eba,ebc,ecd->ead", T, Gl, T)


class Samples(eqx.Module):
    """A structure's mass as particles and rigid sections at sample points (Gauss points of its
    elements): point ``p`` translates by ``translation[p] @ u[dofs[p]]`` and its section turns by
    ``rotation[p] @ u[dofs[p]]`` (u the degrees of freedom), at `positions` (P, 3), with `mass`
    (P,) and the section's `inertia` (P, 3, 3) about the point, in the structure's frame. The
    consistent mass matrix is ``sum_p mass_p T_p^T T_p + R_p^T inertia_p R_p``; unlike the mass
    matrix, these are the inertia of the interpolated fields in any rotating frame (the
    appendage's Gauss function, :mod:`.model`)."""

    dofs: tuple = eqx.field(static=True)
    translation: jax.Array
    rotation: jax.Array
    positions: jax.Array
    mass: jax.Array
    inertia: jax.Array

    @property
    def dof_array(self) -> np.ndarray:
        """(P, d): `dofs` as an integer array."""
        return np.asarray(self.dofs, np.int64)

    def matrix(self, N: int, which: str = "translation"):
        """``(N, 3 P)``: the degrees of freedom's loads per unit force on each point (the transpose
        of the points' `translation` maps), or of `which` ("rotation")."""
        S = getattr(self, which)  # (P, 3, d)
        P, d = S.shape[0], S.shape[2]
        cols = np.repeat(np.arange(3 * P).reshape(P, 3, 1), d, axis=2)
        rows = np.repeat(self.dof_array[:, None, :], 3, axis=1)
        return jnp.zeros((N, 3 * P), S.dtype).at[rows.ravel(), cols.ravel()].add(S.reshape(-1))


class PlateElements(eqx.Module):
    """Four-node plate elements of one flat plate, for the geometric stiffness of an in-plane
    preload: `nodes` (static, (ne, 4) node indices, counter-clockwise), `normal` (3,), `axes`
    (2, 3: the plate's in-plane axes x, y in the structure's frame), `dN` (ng, 2, 4: the shape
    functions' derivatives in x, y at each Gauss point), `weights` (ng,: the Gauss points' areas),
    `membrane` (3, 3: the membrane stiffness E t / (1 - nu^2) [[1, nu, 0], [nu, 1, 0], [0, 0,
    (1 - nu) / 2]]). The stress resultants are (N_xx, N_yy, N_xy) per element and Gauss point."""

    normal: jax.Array
    axes: jax.Array
    dN: jax.Array
    weights: jax.Array
    membrane: jax.Array
    nodes: tuple = eqx.field(static=True)

    def _translations(self, u):
        idx = 6 * np.asarray(self.nodes, np.int64)[:, :, None] + np.arange(3)  # (ne, 4, 3)
        return u[idx]

    def stresses(self, u):
        ut = self._translations(u)  # (ne, 4, 3)
        um = jnp.einsum("enc,ac->ena", ut, self.axes)  # in-plane (ne, 4, 2)
        ux = jnp.einsum("gn,ena->gea", self.dN[:, 0], um)  # d/dx of (u, v): (ng, ne, 2)
        uy = jnp.einsum("gn,ena->gea", self.dN[:, 1], um)
        strain = jnp.stack([ux[..., 0], uy[..., 1], ux[..., 1] + uy[..., 0]], -1)  # (ng, ne, 3)
        res = jnp.einsum("ij,gej->egi", self.membrane, strain)  # (ne, ng, 3)
        return res.reshape(-1)

    def blocks(self):
        ne, ng = len(self.nodes), self.dN.shape[0]
        nn = jnp.outer(self.normal, self.normal)
        gx, gy = self.dN[:, 0], self.dN[:, 1]  # (ng, 4)
        w = self.weights[:, None, None]
        xx = w * gx[:, :, None] * gx[:, None, :]
        yy = w * gy[:, :, None] * gy[:, None, :]
        xy = w * (gx[:, :, None] * gy[:, None, :] + gy[:, :, None] * gx[:, None, :])
        per = jnp.stack([xx, yy, xy], 1)  # (ng, 3, 4, 4): N_xx, N_yy, N_xy
        G = jnp.einsum("gcab,ij->gcaibj", per, nn).reshape(ng, 3, 12, 12)
        G = jnp.broadcast_to(G[None], (ne, ng, 3, 12, 12)).reshape(ne * ng * 3, 12, 12)
        idx = (6 * np.asarray(self.nodes, np.int64)[:, :, None] + np.arange(3)).reshape(ne, 12)
        dofs = np.repeat(idx[:, None, :], ng * 3, axis=1).reshape(ne * ng * 3, 12)
        return dofs, G


class FEModel(eqx.Module):
    """A structure's finite-element model.

    - `mass`, `stiffness` (N, N), symmetric, N = `dofs` x the number of nodes, ordered node by
      node (translations x, y, z, then, with ``dofs = 6``, small rotations about x, y, z);
    - `nodes` (n_nodes, 3): positions in the structure's frame;
    - `dofs` (static): 6 or 3 per node;
    - `elements`: the beam (:class:`Elements`) or plate (:class:`PlateElements`) elements when
      the model knows them (the geometric stiffness needs them), else None.
    """

    mass: jax.Array
    stiffness: jax.Array
    nodes: jax.Array
    elements: Elements | PlateElements | None = None
    dofs: int = eqx.field(static=True, default=6)

    def __check_init__(self):
        if is_traced((self.mass, self.stiffness, self.nodes)):
            return
        n_nodes = np.shape(self.nodes)[0]
        N = self.dofs * n_nodes
        for name in ("mass", "stiffness"):
            shape = np.shape(getattr(self, name))
            if shape != (N, N):
                raise SceneError(
                    f"FEModel.{name}: shape {shape}, expected ({N}, {N}) for {n_nodes} nodes of {self.dofs} dofs"
                )

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])


def _local_frame(direction, up):
    """Rows: the unit axis, the unit y axis (``up x axis`` normalized) and z = x cross y."""
    x = direction / jnp.linalg.norm(direction)
    y = jnp.cross(up, x)
    y = y / jnp.linalg.norm(y)
    z = jnp.cross(x, y)
    return jnp.stack([x, y, z])


def _element_matrices(L, EA, GJ, EIy, EIz, rhoA, rhoJ):
    """Local 12x12 stiffness and consistent mass of an Euler-Bernoulli beam element (local x
    along the element), degrees of freedom (u, v, w, th_x, th_y, th_z) at node 1 then node 2."""
    dtype = jnp.result_type(L)
    K = jnp.zeros((12, 12), dtype)
    M = jnp.zeros((12, 12), dtype)
    ax = np.array([0, 6])
    tw = np.array([3, 9])
    K = K.at[np.ix_(ax, ax)].set(EA / L * jnp.array([[1.0, -1.0], [-1.0, 1.0]], dtype))
    K = K.at[np.ix_(tw, tw)].set(GJ / L * jnp.array([[1.0, -1.0], [-1.0, 1.0]], dtype))
    M = M.at[np.ix_(ax, ax)].set(rhoA * L / 6.0 * jnp.array([[2.0, 1.0], [1.0, 2.0]], dtype))
    M = M.at[np.ix_(tw, tw)].set(rhoJ * L / 6.0 * jnp.array([[2.0, 1.0], [1.0, 2.0]], dtype))
    for idx, EI, s in (((1, 5, 7, 11), EIz, 1.0), ((2, 4, 8, 10), EIy, -1.0)):
        # bending in the x-y plane (v, th_z): w' = th_z; in the x-z plane (w, th_y): w' = -th_y,
        # so the coupling terms change sign (s)
        k = jnp.array(
            [
                [12.0, 6 * s * L, -12.0, 6 * s * L],
                [6 * s * L, 4 * L**2, -6 * s * L, 2 * L**2],
                [-12.0, -6 * s * L, 12.0, -6 * s * L],
                [6 * s * L, 2 * L**2, -6 * s * L, 4 * L**2],
            ]
        )
        m = jnp.array(
            [
                [156.0, 22 * s * L, 54.0, -13 * s * L],
                [22 * s * L, 4 * L**2, 13 * s * L, -3 * L**2],
                [54.0, 13 * s * L, 156.0, -22 * s * L],
                [-13 * s * L, -3 * L**2, -22 * s * L, 4 * L**2],
            ]
        )
        i = np.asarray(idx)
        K = K.at[np.ix_(i, i)].set(EI / L**3 * k)
        M = M.at[np.ix_(i, i)].set(rhoA * L / 420.0 * m)
    return K, M


def geometric_element(L, N):
    """Local 12x12 geometric stiffness of a beam element under the axial force `N` (tension
    positive): the consistent matrix of the Hermite element for the transverse deflections
    (Przemieniecki Sec. 15.2), in the element's local axes."""
    dtype = jnp.result_type(L, N)
    G = jnp.zeros((12, 12), dtype)
    for idx, s in (((1, 5, 7, 11), 1.0), ((2, 4, 8, 10), -1.0)):
        g = jnp.array(
            [
                [36.0, 3 * s * L, -36.0, 3 * s * L],
                [3 * s * L, 4 * L**2, -3 * s * L, -(L**2)],
                [-36.0, -3 * s * L, 36.0, -3 * s * L],
                [3 * s * L, -(L**2), -3 * s * L, 4 * L**2],
            ]
        )
        i = np.asarray(idx)
        G = G.at[np.ix_(i, i)].set(N / (30.0 * L) * g)
    return G


def element_rotation(frame):
    """The 12x12 block diagonal of the element's frame (global -> local components)."""
    return jnp.kron(jnp.eye(4, dtype=frame.dtype), frame)


def element_dofs(nodes) -> np.ndarray:
    """(ne, 12) global degree-of-freedom indices of two-node six-dof elements."""
    a = np.asarray(nodes, np.int64)
    base = 6 * a  # (ne, 2)
    return (base[:, :, None] + np.arange(6)[None, None, :]).reshape(len(a), 12)


def beam(
    length,
    n_elements: int,
    *,
    E,
    rho,
    area,
    Iy,
    Iz=None,
    J=None,
    G=None,
    direction=(1.0, 0.0, 0.0),
    up=(0.0, 0.0, 1.0),
    origin=(0.0, 0.0, 0.0),
) -> FEModel:
    """A straight, uniform Euler-Bernoulli beam of `n_elements` equal elements (node 0 at
    `origin`, the last at ``origin + length * direction``).

    - `E` Young's modulus, `rho` density, `area` the section's area; `Iy`, `Iz` its second
      moments about the element's local y and z axes (bending in the x-z and x-y planes; `Iz`
      defaults to `Iy`); `J` the torsion constant (default ``Iy + Iz``), `G` the shear modulus
      (default ``E / 2.6``, Poisson's ratio 0.3). The rotary inertia of the section is in the
      torsion only (``rho (Iy + Iz)``), as in the Euler-Bernoulli element;
    - `direction`: the beam's axis (local x); `up`: a vector not along it, from which the local
      y axis is ``up x direction`` (normalized) and z completes the frame.

    Every numeric argument may be a JAX array (traced under ``jax.grad`` or ``jax.vmap``): the
    model is differentiable in them. **Returns:** :class:`FEModel` with its :class:`Elements`.
    """
    n = int(n_elements)
    if n < 1:
        raise SceneError(f"beam: n_elements must be a positive integer, got {n_elements!r}")
    values = dict(length=length, E=E, rho=rho, area=area, Iy=Iy)
    for name, v in values.items():
        if not is_traced(v) and not (np.ndim(v) == 0 and float(v) > 0):
            raise SceneError(f"beam: {name} must be a positive number, got {v!r}")
    dtype = jnp.result_type(float)
    f = functools.partial(host_or_traced, dtype=dtype)
    length, E, rho, area, Iy = (f(v) for v in (length, E, rho, area, Iy))
    Iz, J, G = (None if v is None else f(v) for v in (Iz, J, G))
    direction, up, origin = f(direction), f(up), f(origin)
    if not is_traced((direction, up)):
        d, u = np.asarray(direction), np.asarray(up)
        if np.linalg.norm(np.cross(u, d)) < 1e-9 * np.linalg.norm(u) * np.linalg.norm(d):
            raise SceneError(f"beam: up {u.tolist()} is along direction {d.tolist()}")
    return _beam(n, length, E, rho, area, Iy, Iz, J, G, direction, up, origin)


@build_jit
def _beam(n: int, length, E, rho, area, Iy, Iz, J, G, direction, up, origin) -> FEModel:
    """:func:`beam`'s matrices once its arguments are checked: one program for concrete ones."""
    dtype = length.dtype
    Iz = Iy if Iz is None else Iz
    J = Iy + Iz if J is None else J
    G = E / 2.6 if G is None else G
    frame = _local_frame(direction, up)
    L = length / n
    s = jnp.arange(n + 1, dtype=dtype) * L
    nodes = origin[None, :] + s[:, None] * frame[0][None, :]
    Kl, Ml = _element_matrices(L, E * area, G * J, E * Iy, E * Iz, rho * area, rho * (Iy + Iz))
    T = element_rotation(frame)
    Kg, Mg = T.T @ Kl @ T, T.T @ Ml @ T
    pairs = tuple((i, i + 1) for i in range(n))
    dofs = element_dofs(pairs)
    N = 6 * (n + 1)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    K = jnp.zeros((N, N), dtype).at[rows, cols].add(jnp.tile(Kg.ravel(), n))
    M = jnp.zeros((N, N), dtype).at[rows, cols].add(jnp.tile(Mg.ravel(), n))
    elements = Elements(
        frame=jnp.broadcast_to(frame, (n, 3, 3)),
        length=jnp.broadcast_to(L, (n,)),
        axial=jnp.broadcast_to(E * area / L, (n,)),
        nodes=pairs,
        line_mass=jnp.broadcast_to(rho * area, (n,)),
        polar_mass=jnp.broadcast_to(rho * (Iy + Iz), (n,)),
    )
    return FEModel(mass=M, stiffness=K, nodes=nodes, elements=elements, dofs=6)


def axial_forces(elements: Elements, u):
    """Each element's axial force (tension positive) in the static displacement `u` (N,)."""
    dofs = element_dofs(elements.nodes)
    ue = u[dofs]  # (ne, 12)
    stretch = jnp.einsum("ea,ea->e", elements.frame[:, 0], ue[:, 6:9] - ue[:, 0:3])
    return elements.axial * stretch


def geometric_stiffness(fe: FEModel, u):
    """The geometric stiffness (N, N) of the preload whose static displacement is `u`: each
    element's geometric stiffness under its stress resultants, in the structure's frame."""
    if fe.elements is None:
        raise SceneError("geometric_stiffness: the FEModel has no elements (give its preload's matrices instead)")
    el = fe.elements
    dofs, G = el.blocks()
    S = el.stresses(u)
    d = dofs.shape[1]
    rows = np.repeat(dofs, d, axis=1).ravel()
    cols = np.tile(dofs, (1, d)).ravel()
    N = fe.mass.shape[0]
    return jnp.zeros((N, N), G.dtype).at[rows, cols].add((S[:, None, None] * G).reshape(-1))


_GAUSS2 = np.array([-1.0, 1.0]) / np.sqrt(3.0)
_CORNERS = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])


def _shape(xi, eta):
    """Bilinear shape functions (4,) and their derivatives in (xi, eta) (2, 4)."""
    N = 0.25 * (1 + _CORNERS[:, 0] * xi) * (1 + _CORNERS[:, 1] * eta)
    d = np.stack(
        [0.25 * _CORNERS[:, 0] * (1 + _CORNERS[:, 1] * eta), 0.25 * _CORNERS[:, 1] * (1 + _CORNERS[:, 0] * xi)]
    )
    return N, d


def _plate_element(a, b, E, nu, rho, t, dtype):
    """Local 24 x 24 stiffness and consistent mass of a flat a x b rectangular shell element (dofs
    u, v, w, th_x, th_y, th_z per node, corners counter-clockwise from (-a/2, -b/2)): bilinear
    membrane (plane stress), Reissner-Mindlin bending with the shear integrated at the center
    (selective reduced integration, free of shear locking for thin plates), a drilling stiffness
    and inertia that keep the in-plane rotations out of the low modes; and the Gauss points' shape
    derivatives in (x, y) (4, 2, 4) and areas (4,)."""
    J = jnp.stack([a / 2, b / 2])  # d(x, y) / d(xi, eta), a rectangle
    Dm = E * t / (1 - nu**2) * jnp.array([[1.0, nu, 0.0], [nu, 1.0, 0.0], [0.0, 0.0, (1 - nu) / 2]], dtype)
    Db = Dm * t**2 / 12.0
    ks = 5.0 / 6.0 * E / (2 * (1 + nu)) * t
    K = jnp.zeros((24, 24), dtype)
    M = jnp.zeros((24, 24), dtype)
    dNs, ws = [], []
    area = a * b
    u = np.arange(4) * 6
    for xi in _GAUSS2:
        for eta in _GAUSS2:
            N, d = _shape(xi, eta)
            dN = jnp.asarray(d) / J[:, None]  # (2, 4) in x, y
            w = area / 4.0
            dNs.append(dN)
            ws.append(w)
            Bm = jnp.zeros((3, 24), dtype)
            Bm = Bm.at[0, u + 0].set(dN[0]).at[1, u + 1].set(dN[1]).at[2, u + 0].set(dN[1]).at[2, u + 1].set(dN[0])
            # bending: kappa = (th_y,x, -th_x,y, th_y,y - th_x,x)
            Bb = jnp.zeros((3, 24), dtype)
            Bb = Bb.at[0, u + 4].set(dN[0]).at[1, u + 3].set(-dN[1]).at[2, u + 4].set(dN[1]).at[2, u + 3].set(-dN[0])
            K = K + w * (Bm.T @ Dm @ Bm + Bb.T @ Db @ Bb)
            Nm = jnp.asarray(N, dtype)
            for c, inertia in ((0, t), (1, t), (2, t), (3, t**3 / 12), (4, t**3 / 12), (5, t**3 / 12)):
                M = M.at[np.ix_(u + c, u + c)].add(w * rho * inertia * jnp.outer(Nm, Nm))
    # transverse shear at the center: gamma = (w,x + th_y, w,y - th_x)
    N0, d0 = _shape(0.0, 0.0)
    dN0 = jnp.asarray(d0) / J[:, None]
    Bs = jnp.zeros((2, 24), dtype)
    Bs = Bs.at[0, u + 2].set(dN0[0]).at[0, u + 4].set(jnp.asarray(N0, dtype))
    Bs = Bs.at[1, u + 2].set(dN0[1]).at[1, u + 3].set(-jnp.asarray(N0, dtype))
    K = K + area * ks * Bs.T @ Bs
    # drilling: a stiffness of the membrane's order on each node's in-plane rotation
    K = K.at[u + 5, u + 5].add(1e-3 * E * t * area / 4)
    return K, M, jnp.stack(dNs), jnp.stack(ws) * jnp.ones(4, dtype)


def plate(
    length,
    width,
    n_length: int,
    n_width: int,
    *,
    E,
    rho,
    thickness,
    nu=0.3,
    direction=(1.0, 0.0, 0.0),
    across=(0.0, 1.0, 0.0),
    origin=(0.0, 0.0, 0.0),
) -> FEModel:
    """A flat rectangular plate (a solar array's panel) of `n_length` x `n_width` four-node shell
    elements: `length` along `direction` from `origin` (node 0), `width` along `across` (made
    orthogonal to `direction`). Nodes row by row along the length: node ``i + (n_length + 1) j`` at
    ``origin + i a direction + j b across``; the edge ``i = 0`` (nodes ``(n_length + 1) j``) is
    where a panel is usually held (:func:`plate_edge`).

    Bilinear membrane and Reissner-Mindlin bending (shear at the element center: no locking for
    thin plates), consistent mass with the rotary inertia ``rho t^3 / 12``, six degrees of freedom
    per node (the in-plane rotation with a drilling stiffness); `E`, `rho`, `thickness`, `nu` may
    be JAX arrays (differentiable). **Returns:** :class:`FEModel` with its :class:`PlateElements`
    (the geometric stiffness of in-plane stress)."""
    na, nb = int(n_length), int(n_width)
    if na < 1 or nb < 1:
        raise SceneError(f"plate: n_length and n_width must be positive integers, got {n_length!r}, {n_width!r}")
    for name, v in dict(length=length, width=width, E=E, rho=rho, thickness=thickness).items():
        if not is_traced(v) and not (np.ndim(v) == 0 and float(v) > 0):
            raise SceneError(f"plate: {name} must be a positive number, got {v!r}")
    dtype = jnp.result_type(float)
    f = functools.partial(host_or_traced, dtype=dtype)
    if not is_traced((direction, across)):
        d, c = np.asarray(direction, float), np.asarray(across, float)
        d = d / np.linalg.norm(d)
        if float(np.linalg.norm(c - np.dot(c, d) * d)) < 1e-9:
            raise SceneError(f"plate: across {list(across)} is along direction {list(direction)}")
    args = (f(v) for v in (length, width, E, rho, thickness, nu, direction, across, origin))
    return _plate(na, nb, *args)


@build_jit
def _plate(na: int, nb: int, length, width, E, rho, t, nu, direction, across, origin) -> FEModel:
    """:func:`plate`'s matrices once its arguments are checked: one program for concrete ones."""
    dtype = length.dtype
    f = lambda x: jnp.asarray(x, dtype)
    d = direction / jnp.linalg.norm(direction)
    c = across - jnp.dot(across, d) * d
    c = c / jnp.linalg.norm(c)
    n = jnp.cross(d, c)
    R = jnp.stack([d, c, n])  # rows: local x, y, z
    a, b = length / na, width / nb
    Kl, Ml, dN, ws = _plate_element(a, b, E, nu, rho, t, dtype)
    T = jnp.kron(jnp.eye(8, dtype=dtype), R)
    Kg, Mg = T.T @ Kl @ T, T.T @ Ml @ T
    ii, jj = np.meshgrid(np.arange(na + 1), np.arange(nb + 1), indexing="xy")
    nodes = f(origin)[None] + (ii.ravel()[:, None] * a) * d[None] + (jj.ravel()[:, None] * b) * c[None]
    node = lambda i, j: i + (na + 1) * j
    quads = tuple(
        (node(i, j), node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)) for j in range(nb) for i in range(na)
    )
    q = np.asarray(quads, np.int64)
    dofs = (6 * q[:, :, None] + np.arange(6)).reshape(len(quads), 24)
    N = 6 * (na + 1) * (nb + 1)
    rows = np.repeat(dofs, 24, axis=1).ravel()
    cols = np.tile(dofs, (1, 24)).ravel()
    K = jnp.zeros((N, N), dtype).at[rows, cols].add(jnp.tile(Kg.ravel(), len(quads)))
    M = jnp.zeros((N, N), dtype).at[rows, cols].add(jnp.tile(Mg.ravel(), len(quads)))
    Dm = E * t / (1 - nu**2) * jnp.array([[1.0, nu, 0.0], [nu, 1.0, 0.0], [0.0, 0.0, (1 - nu) / 2]], dtype)
    elements = PlateElements(normal=n, axes=R[:2], dN=dN, weights=ws, membrane=Dm, nodes=quads)
    return FEModel(mass=M, stiffness=K, nodes=nodes, elements=elements, dofs=6)


def plate_edge(n_length: int, n_width: int, at: str = "start") -> tuple[int, ...]:
    """The nodes of a :func:`plate`'s edge across its width: ``"start"`` (``i = 0``, default) or
    ``"end"`` (``i = n_length``), e.g. the interface of a panel held along its root."""
    i = 0 if at == "start" else int(n_length)
    return tuple(i + (int(n_length) + 1) * j for j in range(int(n_width) + 1))
