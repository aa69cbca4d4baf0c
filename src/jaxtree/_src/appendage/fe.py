"""A structure's finite-element model (mass and stiffness matrices on a node table) and a
generator of its own for beams.

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
stiffening of a spinning appendage (:mod:`.invariants`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import SceneError, is_traced


class Elements(eqx.Module):
    """Two-node beam elements, for the geometric stiffness of an axial load: `nodes` (static,
    pairs of node indices), `frame` (ne, 3, 3: rows the element's local axes x, y, z in the
    appendage's frame), `length` (ne,), `axial` (ne,: EA / L)."""

    frame: jax.Array
    length: jax.Array
    axial: jax.Array
    nodes: tuple = eqx.field(static=True)


class FEModel(eqx.Module):
    """A structure's finite-element model.

    - `mass`, `stiffness` (N, N), symmetric, N = `dofs` x the number of nodes, ordered node by
      node (translations x, y, z, then, with ``dofs = 6``, small rotations about x, y, z);
    - `nodes` (n_nodes, 3): positions in the structure's frame;
    - `dofs` (static): 6 or 3 per node;
    - `elements`: the beam elements (:class:`Elements`) when the model knows them (the
      geometric stiffness needs them), else None.
    """

    mass: jax.Array
    stiffness: jax.Array
    nodes: jax.Array
    elements: Elements | None = None
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
    f = lambda x: jnp.asarray(x, dtype)
    length, E, rho, area, Iy = (f(v) for v in (length, E, rho, area, Iy))
    Iz = Iy if Iz is None else f(Iz)
    J = Iy + Iz if J is None else f(J)
    G = E / 2.6 if G is None else f(G)
    direction, up, origin = f(direction), f(up), f(origin)
    if not is_traced((direction, up)):
        d, u = np.asarray(direction), np.asarray(up)
        if np.linalg.norm(np.cross(u, d)) < 1e-9 * np.linalg.norm(u) * np.linalg.norm(d):
            raise SceneError(f"beam: up {u.tolist()} is along direction {d.tolist()}")
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
        length=jnp.full((n,), L, dtype) if not is_traced(L) else jnp.broadcast_to(L, (n,)),
        axial=jnp.broadcast_to(E * area / L, (n,)),
        nodes=pairs,
    )
    return FEModel(mass=M, stiffness=K, nodes=nodes, elements=elements, dofs=6)


def axial_forces(elements: Elements, u):
    """Each element's axial force (tension positive) in the static displacement `u` (N,)."""
    dofs = element_dofs(elements.nodes)
    ue = u[dofs]  # (ne, 12)
    stretch = jnp.einsum("ea,ea->e", elements.frame[:, 0], ue[:, 6:9] - ue[:, 0:3])
    return elements.axial * stretch


def geometric_stiffness(fe: FEModel, u):
    """The geometric stiffness (N, N) of the preload whose static displacement is `u`: the sum of
    the elements' :func:`geometric_element` under their axial forces, in the structure's frame."""
    if fe.elements is None:
        raise SceneError("geometric_stiffness: the FEModel has no elements (give its preload's matrices instead)")
    el = fe.elements
    Nf = axial_forces(el, u)
    Gl = jax.vmap(geometric_element)(el.length, Nf)  # (ne, 12, 12)
    T = jax.vmap(element_rotation)(el.frame)
    Gg = jnp.einsum("eba,ebc,ecd->ead", T, Gl, T)
    dofs = element_dofs(el.nodes)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    N = fe.mass.shape[0]
    return jnp.zeros((N, N), Gg.dtype).at[rows, cols].add(Gg.reshape(-1))
