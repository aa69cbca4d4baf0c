"""Kinematics of the tree: Eqs. (3)-(5) and (21)-(22) of Likins (1972).

Direction cosines follow the seed: ``{b^r} = C^{rj} {b^j}``, so components of a
vector transform as ``v_(r) = C^{rj} v_(j)``. Throughout jaxtree the matrices
``R_k = C^{0k}`` (body-k components to body-0 components) are the working set;
``C^{rj} = C^{r0} C^{0j}`` (Eq. 22 telescoped) gives any pair.

The products along paths of Eq. (22) and the sums over path elements are
computed by pointer jumping: ``ceil(log2(depth + 1))`` vectorized steps over all
bodies at once, so neither run time nor compile time has a Python loop over
bodies, and no work is spent on pairs whose path element is zero.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import ParamSpec, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import eager_jit
from ..vehicle.topology import Topology

_P = ParamSpec("_P")
_R = TypeVar("_R")


def full_precision(fn: Callable[_P, _R]) -> Callable[_P, _R]:
    """Trace `fn` with every matrix product at full precision of its dtype.

    On GPUs JAX's default lets float32 products run in reduced precision (TF32 on NVIDIA
    Ampere and later: about 1e-3 relative), which is far too coarse for Eq. (1): with the
    condition numbers of these mass matrices (1e3 to 1e8) it turned float32 accelerations
    into noise and stalled float32 simulations (benchmarks/README.md, GPU figures). Public
    entry points that trace products are wrapped in this; float64, and CPUs, are unaffected.
    """

    @functools.wraps(fn)
    def wrapper(*args: _P.args, **kwargs: _P.kwargs) -> _R:
        with jax.default_matmul_precision("highest"):
            return fn(*args, **kwargs)

    return wrapper


# Small 3-vector / 3x3 algebra on stacks (leading axes are batch axes), written as elementwise
# products and sums that XLA:CPU fuses into one loop: a batched 3x3 dot (einsum, matmul) or a
# reduction over an axis of length 3 runs several times slower on these small stacks
# (FINDINGS.md). The components are taken as slices that keep their axis (``a[..., 0:1]``), not
# as components (``unstack`` lowers to a slice and a reshape per component, ``stack`` to a
# reshape per component and a concatenation): a program's tracing, lowering and compilation pay
# per operation. The same arithmetic in the same order as an entry-by-entry sum, and measured as
# fast (FINDINGS.md, "Fewer operations per product"); a cyclic shift of whole vectors (one
# concatenation) or a gather gives fewer operations still but made fig4_free's run ~7 % slower.


def mv(A, x):
    """``A @ x`` for stacks of 3x3 matrices and 3-vectors: the products ``A_ij x_j`` at once,
    then the three columns summed in order (9 operations in the lowered program)."""
    t = A * x[..., None, :]
    return (t[..., 0:1] + t[..., 1:2] + t[..., 2:3])[..., 0]


def mm(A, B):
    """``A @ B`` for stacks of 3x3 matrices: three outer products of A's columns and B's rows,
    summed in order (17 operations in the lowered program)."""
    return A[..., :, 0:1] * B[..., 0:1, :] + A[..., :, 1:2] * B[..., 1:2, :] + A[..., :, 2:3] * B[..., 2:3, :]


def cross(a, b):
    """``a x b`` for stacks of 3-vectors: the components as slices that keep their axis, joined
    by one concatenation (16 operations in the lowered program for operands of one shape)."""
    a1, a2, a3 = a[..., 0:1], a[..., 1:2], a[..., 2:3]
    b1, b2, b3 = b[..., 0:1], b[..., 1:2], b[..., 2:3]
    return jnp.concatenate([a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1], -1)


def dot(a, b):
    return jnp.sum(a * b, -1)


def tilde(v):
    """Cross-product matrix of Def. 24: ``tilde(v) @ w == cross(v, w)``; batches over leading axes.

    Its nine entries row by row, ``0, -v3, v2, v3, 0, -v1, -v2, v1, 0``, are one concatenation of
    slices of ``v`` and ``-v`` (``v2, v3`` and ``-v1, -v2`` adjacent), then a reshape."""
    z = jnp.zeros_like(v[..., :1])
    n = -v
    flat = jnp.concatenate([z, n[..., 2:3], v[..., 1:3], z, n[..., 0:2], v[..., 0:1], z], -1)
    return flat.reshape(v.shape[:-1] + (3, 3))


def hinge_rotation(axis, gamma):
    """``C^{k N_k}`` of Eq. (4) for unit axes ``axis`` (..., 3) and angles ``gamma`` (...).

    The transpose is Eq. (5), ``C^{N_k k}``.
    """
    c = jnp.cos(gamma)[..., None, None]
    s = jnp.sin(gamma)[..., None, None]
    eye = jnp.eye(3, dtype=axis.dtype)
    ggT = axis[..., :, None] * axis[..., None, :]
    return eye * c - tilde(axis) * s + ggT * (1 - c)


def take_rows(x, idx):
    """``x[idx]`` for a static index of non-negative rows (a numpy array or tuple): one gather.

    Indexing with an integer array first normalizes negative indices (a comparison, an addition
    and a selection on the index), which a static, non-negative index does not need: five
    operations in the lowered program become one, on every one of the tree's parent and jump-table
    lookups."""
    idx = np.asarray(idx, dtype=np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= x.shape[0]):
        raise IndexError(f"row index out of range for {x.shape[0]} rows: {idx.tolist()}")
    if idx.size == 0:
        return jnp.zeros((0,) + x.shape[1:], x.dtype)
    dn = jax.lax.GatherDimensionNumbers(
        offset_dims=tuple(range(1, x.ndim)), collapsed_slice_dims=(0,), start_index_map=(0,)
    )
    return jax.lax.gather(
        x,
        idx.astype(np.int32)[:, None],
        dn,
        slice_sizes=(1,) + tuple(x.shape[1:]),
        indices_are_sorted=bool(np.all(np.diff(idx) >= 0)),
        unique_indices=bool(len(np.unique(idx)) == idx.size),
        mode=jax.lax.GatherScatterMode.PROMISE_IN_BOUNDS,
    )


def _pad(x, fill):
    """Append one row (the "no body" slot of the jump tables) to ``x``: zeros by one pad, else
    `fill` broadcast to a row."""
    if isinstance(fill, (int, float)) and fill == 0:
        return jax.lax.pad(x, jnp.zeros((), x.dtype), [(0, 1, 0)] + [(0, 0, 0)] * (x.ndim - 1))
    return jnp.concatenate([x, jnp.broadcast_to(fill, (1,) + x.shape[1:]).astype(x.dtype)], 0)


def body_rotations(topology: Topology, axis, gamma):
    """``R[k] = C^{0k}`` for every body (Eqs. 4, 5, 21, 22); ``R[0] = U``.

    **Arguments:** `axis` (n, 3) unit hinge axes; `gamma` (n,) hinge angles.
    **Returns:** (n + 1, 3, 3).
    """
    dtype = jnp.result_type(axis, gamma)
    eye = jnp.eye(3, dtype=dtype)
    local = jnp.swapaxes(hinge_rotation(axis.astype(dtype), gamma.astype(dtype)), -1, -2)  # C^{N_k k}
    R = jnp.concatenate([eye[None], local], 0)
    # Invariant: R[k] = C^{a k} with a the current jump target of k (initially the parent).
    for table in topology.jump_tables:
        R = mm(take_rows(_pad(R, eye), table[:-1]), R)
    return R


def relative_rotations(R):
    """``C^{rj}`` for all pairs (Eq. 21), from ``R = body_rotations(...)``: ``C^{rj} = C^{r0} C^{0j}``."""
    return jnp.einsum("rij,sil->rsjl", R, R)  # (R_r^T R_s)_{jl} = sum_i R_r[i,j] R_s[i,l]


def ancestor_sum(topology: Topology, x):
    """``y[k] = sum of x[j] over j = k and every body between b_0 and b_k``.

    With ``x[0]`` the root term and ``x[s]`` the term of hinge ``s``, this is the
    path-element sum ``y[k] = x[0] + sum_s epsilon_{sk} x[s]`` (Def. 27).
    """
    for table in topology.jump_tables:
        x = x + take_rows(_pad(x, 0), table[:-1])
    return x


def subtree_sum(topology: Topology, x, bodies=None):
    """``y[s] = sum of x over the bodies outboard of hinge s, s included``; ``y[0]`` sums all bodies.

    That is ``y[s] = sum_k epsilon_{sk} x[k]`` (Def. 27), computed as one product with
    the static 0/1 matrix ``topology.descendants``. If `bodies` (a static index
    tuple) is given, `x` holds rows for those bodies only, and the others are
    left out of the sum altogether (massless bodies, bodies without loads).

    A product with a constant matrix vectorizes and batches far better than
    scatter-adds on CPUs and GPUs for the trees this package targets (up to a
    few hundred bodies); its cost is ``(n + 1) * len(bodies)`` multiply-adds per
    column of `x`.
    """
    E = topology.descendants if bodies is None else topology.descendants[:, np.asarray(bodies)]
    return jnp.tensordot(jnp.asarray(E, x.dtype), x, axes=1)


@eager_jit
def dcm_rate(dcm, omega0):
    """Eq. (3): ``dC/dt = -tilde(omega0) C``."""
    return -mm(tilde(omega0), dcm)
