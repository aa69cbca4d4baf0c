"""Barycentric quantities (Defs. 30-37) and the printed form of Eq. (1) (Defs. 38-41).

Everything is computed in JAX from the model's arrays, so it can be
differentiated with respect to masses, inertias and geometry. Index tables
(network elements, path elements) are static numpy data of the topology.

:func:`seed_equations` evaluates Defs. 38-41 term by term, with dense
``(n+1) x (n+1)`` block arrays. It is the reference that the fast assembly of
:mod:`jaxtree._src.equations.dynamics` is tested against, and a readable statement of the
seed's formulas (with the corrections recorded in ``docs/errata.md``); its
cost grows like n^3, so use :func:`jaxtree.rotational_equations` for work.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import eager_jit
from ..vehicle.model import Model, State
from .assembly import complete_state, external_loads, hinge_torques
from .kinematics import body_rotations, full_precision, relative_rotations


class Barycentric(NamedTuple):
    """Constant mass geometry of Defs. 30-36 (body-frame components)."""

    total_mass: jax.Array  # Def. 30, M
    branch_mass: jax.Array  # Def. 31, (n+1, n+1): M_kj for j in B_k, 0 elsewhere
    L: jax.Array  # Def. 32, (n+1, n+1, 3): L^{kr}
    D: jax.Array  # Def. 33, (n+1, 3): D^k
    Dkj: jax.Array  # Def. 35, (n+1, n+1, 3): D^{kj}
    Phi_kk: jax.Array  # Def. 36, (n+1, 3, 3)


@functools.lru_cache(maxsize=64)
def _port_index(topology):
    """Static table: ``idx[k, r]`` selects L^{kr} = p^{k N_kr} from [0; p^{k N_k} (n); p^{N_c c} (n)]."""
    n = topology.n
    N = topology.network_elements
    idx = np.zeros((n + 1, n + 1), dtype=np.int32)
    for k in range(n + 1):
        for r in range(n + 1):
            j = N[k, r]
            if r == k:
                idx[k, r] = 0
            elif k > 0 and j == topology.parents[k - 1]:
                idx[k, r] = k  # hinge k, seen from b_k: p^{k N_k}
            else:
                idx[k, r] = n + j  # hinge j (a child of k), seen from b_k: p^{k j}
    onehot = (N[:, :, None] == np.arange(n + 1)[None, None, :]) & ~np.eye(n + 1, dtype=bool)[:, :, None]
    return idx, onehot.astype(np.float64)


@full_precision
@eager_jit
def barycentric(model: Model) -> Barycentric:
    """Defs. 30-36: total and branch masses, L^{kr}, D^k, D^{kj} and Phi^{kk}."""
    dtype = model.mass.dtype
    idx, onehot = _port_index(model.topology)
    ports = jnp.concatenate(
        [jnp.zeros((1, 3), dtype), model.hinge_on_body.astype(dtype), model.hinge_on_parent.astype(dtype)], 0
    )
    L = ports[idx]  # (n+1, n+1, 3)
    m = model.mass
    M = jnp.sum(m)
    branch = jnp.einsum("krj,r->kj", jnp.asarray(onehot, dtype), m)  # Def. 31
    D = -jnp.einsum("krx,r->kx", L, m) / M  # Def. 33
    Dkj = D[:, None, :] + L  # Def. 35 (D^{kk} = D^k since L^{kk} = 0)
    eye = jnp.eye(3, dtype=dtype)
    # Def. 36: the particles M_kj at the connection points are the masses m_r at D^{k N_kr} = D^{kr}
    # (r = k gives the body's own term m_k D^{kk}).
    sq = jnp.einsum("krx,krx->kr", Dkj, Dkj)[..., None, None] * eye - Dkj[..., :, None] * Dkj[..., None, :]
    Phi_kk = model.inertia + jnp.einsum("r,krij->kij", m, sq)
    return Barycentric(M, branch, L, D, Dkj, Phi_kk)


@full_precision
@eager_jit
def coupling_inertia(model: Model, gamma, bary: Barycentric | None = None):
    """Def. 37: ``Phi[k, j]`` = matrix of the dyadic Phi^{kj} ({b^k} left, {b^j} right), with
    Phi^{kk} of Def. 36 on the diagonal. Shape (n+1, n+1, 3, 3)."""
    bary = barycentric(model) if bary is None else bary
    R = body_rotations(model.topology, model.axis, gamma)
    C = relative_rotations(R)  # C[r, j] = C^{rj}
    D = bary.Dkj
    # Phi^{kj} = -M ( (D^{jk}.D^{kj}) U - D^{jk} D^{kj} ),  D^{jk} fixed in b_j, D^{kj} fixed in b_k:
    # in matrices, -M ( (D^{jkT} C^{jk} D^{kj}) U - C^{kj} D^{jk} D^{kjT} ) C^{kj}.
    Djk_in_k = jnp.einsum("kjab,jkb->kja", C, D)  # C^{kj} D^{jk}
    dot = jnp.einsum("kja,kja->kj", Djk_in_k, D)
    eye = jnp.eye(3, dtype=D.dtype)
    inner = dot[..., None, None] * eye - Djk_in_k[..., :, None] * D[..., None, :]
    Phi = -bary.total_mass * jnp.einsum("kjab,kjbc->kjac", inner, C)
    n1 = model.n + 1
    diag = np.arange(n1)
    return Phi.at[diag, diag].set(bary.Phi_kk)


@full_precision
@eager_jit
def seed_equations(model: Model, state: State, t=0.0, tau=None):
    """Eq. (1) from Defs. 38-41 as printed (with the errata applied): ``(A, rhs)``.

    Same signature and result as :func:`jaxtree.rotational_equations`, except that
    prescribed hinges are filled in from the prescription first.
    """
    state, _ = complete_state(model, t, state)
    gamma, gdot, w0 = state.gamma, state.gamma_dot, state.omega0
    n = model.n
    bary = barycentric(model)
    M = bary.total_mass
    eps = jnp.asarray(model.topology.path_elements, model.mass.dtype)  # (n, n+1): eps[s-1, k]
    R = body_rotations(model.topology, model.axis, gamma)
    C = relative_rotations(R)  # C^{rj}
    Phi = coupling_inertia(model, gamma, bary)
    g = model.axis
    hinge = np.arange(1, n + 1)

    # ---- Defs. 38-40 --------------------------------------------------------------------
    # Psi^{rs} = C^{0r} Phi^{rs} C^{s0};  g^k in {b^0}: C^{0k} g^k.
    Psi = jnp.einsum("rab,rsbc,sdc->rsad", R, Phi, R)
    g0 = jnp.einsum("kab,kb->ka", R[hinge], g)
    a00 = jnp.sum(Psi, axis=(0, 1))
    a0k = jnp.einsum("kj,rjab,kb->ak", eps, Psi, g0)  # Def. 39 with eps_{kj} (errata)
    akj = jnp.einsum("ka,kr,js,rsab,jb->kj", g0, eps, eps, Psi, g0)  # Def. 40
    A = jnp.block([[a00, a0k], [a0k.T, akj]])

    # ---- Def. 41 --------------------------------------------------------------------------
    # omega^k in {b^k}: C^{k0} omega0 + sum_r eps_{rk} gamma_dot_r C^{kr} g^r
    Ck_hinge = C[:, hinge]  # C^{kr}, r = 1..n
    w = jnp.einsum("kab,b->ka", C[:, 0], w0) + jnp.einsum("rk,r,krab,rb->ka", eps, gdot, Ck_hinge, g)
    # omega^r x g^r in {b^r} for r = 1..n
    wxg = jnp.cross(w[hinge], g)
    # sum_r eps_{rk} gamma_dot_r (omega^r x g^r), in {b^k}
    spin = jnp.einsum("rk,r,krab,rb->ka", eps, gdot, Ck_hinge, wxg)
    Phikk = bary.Phi_kk
    line1 = -jnp.einsum("kab,kb->ka", Phikk, spin)
    line2 = -jnp.cross(w, jnp.einsum("kab,kb->ka", Phikk, w))
    D = bary.Dkj  # D[k, j] = D^{kj}
    offdiag = 1.0 - jnp.eye(n + 1, dtype=D.dtype)
    # (omega~^j)^2 D^{jk} in {b^j}
    ww = jnp.cross(w[None, :, :], jnp.cross(w[None, :, :], jnp.swapaxes(D, 0, 1)))  # [k, j] -> j frame
    ww_in_k = jnp.einsum("kjab,kjb->kja", C, ww)
    line3 = M * jnp.einsum("kj,kja->ka", offdiag, jnp.cross(D, ww_in_k))
    line4 = -jnp.einsum("kj,kjab,jb->ka", offdiag, Phi, spin)
    Ak = line1 + line2 + line3 + line4
    loads = external_loads(model, t, state, _LoadFrames(R))
    if loads is not None:
        bodies, F0, T0 = loads  # {b^0} components
        F = jnp.zeros((n + 1, 3), D.dtype).at[bodies].set(F0)
        T = jnp.zeros((n + 1, 3), D.dtype).at[bodies].set(T0)
        Fk = jnp.einsum("kba,kb->ka", R, F)  # back to each body's frame
        Tk = jnp.einsum("kba,kb->ka", R, T)
        Ak = Ak + Tk + jnp.cross(D, jnp.einsum("kjab,jb->kja", C, Fk)).sum(1)

    # ---- Eq. (1) right side -------------------------------------------------------------------
    torque = hinge_torques(model, gamma, gdot) + (0.0 if tau is None else tau)
    rhs0 = jnp.einsum("kab,kb->a", C[0], Ak)
    rhsk = jnp.einsum("ka,kj,kjab,jb->k", g, eps, C[hinge], Ak) + torque
    return A, jnp.concatenate([rhs0, rhsk])


class _LoadFrames(NamedTuple):
    R: jax.Array
