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


# Small 3-vector / 3x3 algebra on stacks (leading axes are batch axes), written out by
# components: XLA on CPU fuses these elementwise forms, while a batched 3x3 dot (einsum,
# matmul) or a reduction over an axis of length 3 runs several times slower.
# The 3x3 algebra below is written by components, as sums of elementwise products that XLA:CPU
# fuses into one loop (a dot_general or einsum runs slower on these small stacks: FINDINGS.md),
# and each operand is split into its components once (one `unstack` each): the same arithmetic
# in the same order as an entry-by-entry sum, in about a tenth of the primitives, which is what
# a program's tracing, lowering and compilation pay for.


def mv(A, x):
    """``A @ x`` for stacks of 3x3 matrices and 3-vectors."""
    a0, a1, a2 = jnp.unstack(A, axis=-1)  # the columns
    x0, x1, x2 = jnp.unstack(x[..., None, :], axis=-1)
    return a0 * x0 + a1 * x1 + a2 * x2


def mm(A, B):
    """``A @ B`` for stacks of 3x3 matrices."""
    a0, a1, a2 = jnp.unstack(A[..., :, :, None], axis=-2)  # the columns, (..., 3, 1)
    b0, b1, b2 = jnp.unstack(B[..., :, None, :], axis=-3)  # the rows, (..., 1, 3)
    return a0 * b0 + a1 * b1 + a2 * b2


def cross(a, b):
    """``a x b`` for stacks of 3-vectors."""
    a1, a2, a3 = jnp.unstack(a, axis=-1)
    b1, b2, b3 = jnp.unstack(b, axis=-1)
    return jnp.stack([a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1], -1)


def dot(a, b):
    return jnp.sum(a * b, -1)


def tilde(v):
    """Cross-product matrix of Def. 24: ``tilde(v) @ w == cross(v, w)``; batches over leading axes."""
    v1, v2, v3 = v[..., 0], v[..., 1], v[..., 2]
    z = jnp.zeros_like(v1)
    return jnp.stack([jnp.stack([z, -v3, v2], -1), jnp.stack([v3, z, -v1], -1), jnp.stack([-v2, v1, z], -1)], -2)


def hinge_rotation(axis, gamma):
    """``C^{k N_k}`` of Eq. (4) for unit axes ``axis`` (..., 3) and angles ``gamma`` (...).

    The transpose is Eq. (5), ``C^{N_k k}``.
    """
    c = jnp.cos(gamma)[..., None, None]
    s = jnp.sin(gamma)[..., None, None]
    eye = jnp.eye(3, dtype=axis.dtype)
    ggT = axis[..., :, None] * axis[..., None, :]
    return eye * c - tilde(axis) * s + ggT * (1 - c)


def _pad(x, fill):
    """Append one row (the "no body" slot of the jump tables) to ``x``."""
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
        R = mm(_pad(R, eye)[table[:-1]], R)
    return R


def relative_rotations(R):
    """``C^{rj}`` for all pairs (Eq. 21), from ``R = body_rotations(...)``: ``C^{rj} = C^{r0} C^{0j}``."""
    return jnp.einsum("rij,sil->rsjl", R, R)  # (R_r^T R_s)_{jl} = sum_i R_r[i,j] R_s[i,l]


def ancestor_sum(topology: Topology, x):
    """``y[k] = sum of x[j] over j = k and every body between b_0 and b_k``.

    With ``x[0]`` the root term and ``x[s]`` the term of hinge ``s``, this is the
    path-element sum ``y[k] = x[0] + sum_s epsilon_{sk} x[s]`` (Def. 27).
    """
    zero = jnp.zeros((), x.dtype)
    for table in topology.jump_tables:
        x = x + _pad(x, zero)[table[:-1]]
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
