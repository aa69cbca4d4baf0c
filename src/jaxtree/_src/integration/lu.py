"""LU factorizations that stay inline under ``jax.vmap`` on a CPU: :func:`lu_factor` and
:func:`lu_solve`, those of ``jax.scipy.linalg``, for :class:`~.radau.Radau5`'s Newton matrices.

jaxlib's CPU LAPACK kernels split a large batch into tasks on XLA's intra-op pool, and two such
calls running at once can deadlock (below); under ``vmap`` on a CPU :func:`lu_factor` therefore
factors the batch in groups of members small enough to run inline (:func:`inline_group` members a
group, by ``lax.map``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

__all__ = ["inline_group", "lu_factor", "lu_solve"]


# jaxlib's CPU LAPACK kernels split a batch worth more than ~2e5 flops into tasks on XLA's
# intra-op pool and block the calling pool thread until they finish; two such calls running at
# once (Radau5's real and complex factorizations are independent, and XLA:CPU runs independent
# operations concurrently) can each hold a pool thread while their tasks wait: a vmapped Radau5
# run of 64 stiff chains hung so on 2 cores (benchmarks/FINDINGS.md, "Two host devices: the LAPACK
# deadlock"). Under vmap on a CPU the factorizations therefore run in groups small
# enough to stay inline (``lax.map`` over groups of members).
_LAPACK_INLINE_FLOPS = 2e5


def inline_group(a, flops_per_member):
    """How many members of the batch `a` one LAPACK call takes inline: those of `flops_per_member`
    flops each (four times as many for a complex `a`) below the threshold above."""
    return max(1, int(_LAPACK_INLINE_FLOPS / (flops_per_member * (4 if jnp.iscomplexobj(a) else 1))))


def _grouped(fn, flops):
    """`fn` whose ``vmap`` on a CPU runs the members by ``lax.map`` in inline-sized groups."""

    @jax.custom_batching.custom_vmap
    def call(*args):
        return fn(*args)

    @call.def_vmap
    def _rule(axis_size, in_batched, *args):
        args = [a if b else jnp.broadcast_to(a, (axis_size, *a.shape)) for a, b in zip(args, in_batched)]
        if jax.default_backend() == "cpu":
            out = jax.lax.map(lambda xs: fn(*xs), args, batch_size=inline_group(args[0], flops(args[0])))
        else:
            out = jax.vmap(fn)(*args)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return call


_lu_factor_grouped = _grouped(jsl.lu_factor, lambda a: 2.0 * a.shape[-1] ** 3 / 3.0)


def lu_factor(a):
    """``jax.scipy.linalg.lu_factor`` of a matrix that carries no derivative (the iteration
    matrices are ``stop_gradient``-ed: ``custom_vmap`` has no transpose)."""
    return _lu_factor_grouped(jax.lax.stop_gradient(a))


lu_solve = jsl.lu_solve
