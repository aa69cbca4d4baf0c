"""Jacobians by forward passes over groups of parts: :func:`jacobian_by_parts`, with which
:class:`~.problem.Problem` and the hybrid equations form the Jacobian they give
:class:`~.radau.Radau5`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

__all__ = ["jacobian_by_parts"]


def jacobian_by_parts(fn, parts, groups) -> Array:
    """``d fn(*parts) / d [parts]`` as one matrix, its columns in the order of `parts`, by one
    ``jax.jacfwd`` pass per group of parts (tuples of indices; parts that are None or empty are
    left out). In a pass the other parts carry no tangent, so what depends on them alone is
    evaluated once, not once per column: the Jacobians that :func:`jaxtree.simulate` and
    :func:`jaxtree.simulate_hybrid` give :class:`~.radau.Radau5` (the configuration, then the rates; the
    large variables, then the modal coordinates)."""
    columns = {}
    for group in groups:
        idx = tuple(i for i in group if parts[i] is not None and parts[i].size > 0)
        if not idx:
            continue

        def field(*chosen, idx=idx):
            p = list(parts)
            for i, v in zip(idx, chosen):
                p[i] = v
            return fn(*p)

        blocks = jax.jacfwd(field, argnums=tuple(range(len(idx))))(*(parts[i] for i in idx))
        columns.update(zip(idx, blocks))
    return jnp.concatenate([columns[i] for i in sorted(columns)], axis=1)
