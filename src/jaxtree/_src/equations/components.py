"""The component algebra of the batch-first recursion (:mod:`.batched`): 3-vectors as tuples of
three arrays of one shape (bodies of a level, members), symmetric 6 x 6 matrices as their 21
entries ``{(i, j): array}`` over i <= j, and b_0's 6 x 6 articulated inertia factored as LDL^T,
all written out so that XLA's fused loops run along the members."""

from __future__ import annotations

import functools
import operator
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..numerics import SINGULAR_PIVOT

# A 3-vector is a tuple of three arrays of one shape (bodies of a level, members); a symmetric
# 6 x 6 matrix a dict {(i, j): array} over i <= j.


def total(terms: list):
    """The sum of `terms` in order, from the first (Python's ``sum`` starts from 0: one addition
    more in every traced sum); 0 when there are none."""
    return functools.reduce(operator.add, terms) if terms else 0


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def add(a, b):
    return tuple(x + y for x, y in zip(a, b))


def scale(a, s):
    return tuple(x * s for x in a)


def mv(R, x):
    """``R @ x`` for R a 3 x 3 tuple of rows."""
    return tuple(R[i][0] * x[0] + R[i][1] * x[1] + R[i][2] * x[2] for i in range(3))


def mm(A, B):
    return tuple(tuple(A[i][0] * B[0][j] + A[i][1] * B[1][j] + A[i][2] * B[2][j] for j in range(3)) for i in range(3))


PAIRS = tuple((i, j) for i in range(6) for j in range(i, 6))


def sym(M, i, j):
    return M[(i, j)] if i <= j else M[(j, i)]


def sym_apply(M, x):
    """``M @ x`` for a symmetric 6 x 6 M and a 6-tuple x."""
    return tuple(total([sym(M, i, j) * x[j] for j in range(6)]) for i in range(6))


def body_inertia(m, J, c):
    """The rigid-body inertia about O of a body of mass m, inertia J (symmetric 3 x 3 dict
    {(i, j)}, {b^0} components, about its mass center) and mass center c from O:
    ``[[J + m (|c|^2 U - c c^T), m c~], [-m c~, m U]]``."""
    M = {}
    cc = dot(c, c)
    for i in range(3):
        for j in range(i, 3):
            M[(i, j)] = J[(i, j)] + m * ((cc if i == j else 0.0) - c[i] * c[j])
    mc = scale(c, m)
    # m c~ : rows (0, -c3, c2), (c3, 0, -c1), (-c2, c1, 0), in the upper right block
    zero = jnp.zeros_like(m * c[0])
    tilde = ((zero, -mc[2], mc[1]), (mc[2], zero, -mc[0]), (-mc[1], mc[0], zero))
    for i in range(3):
        for j in range(3):
            M[(i, 3 + j)] = tilde[i][j]
    for i in range(3):
        for j in range(i, 3):
            M[(3 + i, 3 + j)] = m if i == j else zero
    return M


# XLA:CPU fuses a concatenation of at most 8 operands into one loop; a stage's stacked results
# are therefore chunks of at most 8 components (one loop each).
CHUNK = 8


def components_of(a):
    """The components of a stacked array or of a tuple of chunks (leading axes)."""
    if isinstance(a, (tuple, list)):
        return tuple(c for chunk in a for c in components_of(chunk))
    return tuple(jnp.unstack(a))  # one primitive (indexing each component traced two each)


def split_stacked(a, sizes):
    """Components of the stacked array (or chunks) `a` in groups of `sizes` (tuples of arrays)."""
    comps = components_of(a)
    out, i = [], 0
    for k in sizes:
        out.append(comps[i : i + k])
        i += k
    return out


def stacked(*groups):
    """The components of `groups` stacked along a new leading axis, in chunks of `CHUNK`."""
    comps = [c for g in groups for c in g]
    shape = jnp.broadcast_shapes(*[jnp.shape(z) for z in comps])
    comps = [jnp.broadcast_to(c, shape) for c in comps]
    return tuple(jnp.stack(comps[i : i + CHUNK]) for i in range(0, len(comps), CHUNK))


def ldl6(M21):
    """Stage: the LDL^T factors of the symmetric 6 x 6 matrix (21 entries): L's 15 entries below
    the diagonal (column by column) and the pivots d (6)."""
    M = dict(zip(PAIRS, M21))
    L, d = {}, []
    for j in range(6):
        s = sym(M, j, j) - total([L[(j, k)] * L[(j, k)] * d[k] for k in range(j)])
        d.append(s)
        for i in range(j + 1, 6):
            L[(i, j)] = (sym(M, i, j) - total([L[(i, k)] * L[(j, k)] * d[k] for k in range(j)])) / s
    return stacked(tuple(L[(i, j)] for j in range(6) for i in range(j + 1, 6)), tuple(d))


def ldl6_solve(Ld, b, diag):
    """Stage: ``M^{-1} b`` from :func:`ldl6`'s factors."""
    names = [(i, j) for j in range(6) for i in range(j + 1, 6)]
    Lc, d = split_stacked(Ld, (15, 6))
    L = dict(zip(names, Lc))
    y = []
    for i in range(6):
        y.append(b[i] - total([L[(i, k)] * y[k] for k in range(i)]))
    x: list[Any] = [None] * 6
    for i in reversed(range(6)):
        x[i] = y[i] / d[i] - total([L[(k, i)] * x[k] for k in range(i + 1, 6)])
    tol = SINGULAR_PIVOT * float(np.sqrt(6.0)) * float(jnp.finfo(d[0].dtype).eps)
    ok = functools.reduce(jnp.logical_and, [d[i] > tol * diag[i] for i in range(6)])
    return stacked(tuple(jnp.where(ok, xi, jnp.nan) for xi in x))


# ----------------------------------------------------------------------------- cos and sin

# XLA:CPU evaluates cos and sin by a call of the C library's scalar functions per element: on
# flex95's batch of 64 they took about an eighth of the recursion's samples (perf), and with the
# polynomials below, which vectorize like the rest of a stage, the recursion ran 4-5 % faster
# (benchmarks/FINDINGS.md, "Eq. (1) in groups of members"). fdlibm's kernels on [-pi/4, pi/4]
# (k_sin.c, k_cos.c) after a reduction by the nearest multiple n of pi/2, with pi/2 in two parts
# (e_rem_pio2.c's first step: n * _PIO2_HI exact for |n| < 2^20); an array with a larger angle
# goes to jnp.cos and jnp.sin as a whole.
_PIO2_HI = 1.57079632673412561417e00  # the first 33 bits of pi/2
_PIO2_LO = 6.07710050650619224932e-11  # pi/2 - _PIO2_HI
_REDUCE_MAX = 2.0**19 * np.pi  # |q| below this: n < 2^20
_S = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
      2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)  # fmt: skip
_C = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
      -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)  # fmt: skip


def _horner(coeffs, z):
    acc = coeffs[-1]
    for c in coeffs[-2::-1]:
        acc = c + z * acc
    return acc


def _cos_sin_reduced(q):
    n = jnp.round(q * (2.0 / np.pi))
    r = (q - n * _PIO2_HI) - n * _PIO2_LO
    z = r * r
    s = r + r * z * _horner(_S, z)
    c = 1.0 - (0.5 * z - z * z * _horner(_C, z))
    k = n - 4.0 * jnp.floor(0.25 * n)  # the quadrant, 0 ... 3
    odd = (k == 1.0) | (k == 3.0)
    cos = jnp.where(odd, s, c) * jnp.where((k == 1.0) | (k == 2.0), -1.0, 1.0)
    sin = jnp.where(odd, c, s) * jnp.where(k >= 2.0, -1.0, 1.0)
    return cos, sin


@jax.custom_jvp
def cos_sin(q):
    """``(cos q, sin q)`` elementwise by vectorizable polynomials, within 1.2e-16 of ``jnp.cos``
    and ``jnp.sin`` (float64; other types, and an array holding any |q| >= 2^19 pi, by
    ``jnp.cos`` and ``jnp.sin``)."""
    q = jnp.asarray(q)
    if q.dtype != jnp.float64:
        return jnp.cos(q), jnp.sin(q)
    small = jnp.all(jnp.abs(q) < _REDUCE_MAX)
    return jax.lax.cond(small, _cos_sin_reduced, lambda x: (jnp.cos(x), jnp.sin(x)), q)


@cos_sin.defjvp
def _cos_sin_jvp(primals, tangents):
    (q,), (dq,) = primals, tangents
    c, s = cos_sin(q)
    return (c, s), (-s * dq, c * dq)
