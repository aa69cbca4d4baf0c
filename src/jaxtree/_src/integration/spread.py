"""A user's ``jax.vmap`` of :func:`jaxtree.simulate` or :func:`jaxtree.simulate_hybrid` on every
core: the batch of members split over the host devices.

XLA:CPU runs one program's batch on one core, and ``import jaxtree`` gives JAX one CPU device per
core (:mod:`jaxtree._src.process`). :func:`jaxtree.monte_carlo` shards its chunks over them; a
user's own eager ``jax.vmap(lambda y0: jaxtree.simulate(model, t1, y0=y0))(y0s)`` would run its
whole batch on the first device. :func:`over_devices` gives the run's program a batching rule
(``jax.custom_batching.custom_vmap``) that, for a batch of concrete values (an eager ``vmap``,
not inside the user's ``jit`` or a derivative), runs the members split over the devices
(``jax.shard_map``), each device's share as :func:`jaxtree.monte_carlo` runs a chunk's share:
vmapped, in small groups where jaxlib's LAPACK kernels must stay on the calling thread, one after
another for an implicit solver. Inside the user's ``jit`` the batch stays the user's program, and
under a derivative the plain ``vmap`` runs (a ``custom_vmap`` has no transpose).

The failure report that a vmapped run makes from a host callback is made after the run instead,
from the whole batch, so that the failed members keep their indices in the user's batch.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

from ..equations.articulated import resolve_method
from ..equations.solve import batch_first_min
from ..numerics import program_jit

try:  # the tracer of a jax.vmap; without it (another JAX), nothing is spread
    from jax._src.interpreters.batching import BatchTracer
except ImportError:  # pragma: no cover
    BatchTracer = None


# jaxlib's CPU LAPACK kernels (potrf, trsm, syevd, ...) split a batch of matrices over XLA's
# intra-op thread pool when it is worth more than about 2e5 flops (jax::ParallelBatchMap), and
# block the calling pool thread until the parts are done. The executions of a program's device
# shards run on that same pool: two shards that both split a batch can hold every pool thread
# while their parts wait behind each other, and the process hangs (benchmarks/README.md has the
# reproduction). Below that size the kernel runs inline. A member's program calls LAPACK only in
# the dense method's factorization of Eq. (1) member by member, below batch_first_min(model) members
# (the batch-first recursion, the articulated method and the test of a singular start eliminate in
# JAX). So on the CPU a shard of such members runs them in vmapped groups small enough for the
# factorization to stay inline, and any other shard runs its members vmapped all at once.
LAPACK_INLINE_FLOPS = 2e5


def lapack_group(model, members: int) -> int | None:
    """Members per vmapped group on a CPU shard of `members` members: None (all at once) where no
    LAPACK call is batched (the batch-first recursion from :func:`batch_first_min` members on, or
    the articulated method), else a group whose batched Cholesky of Eq. (1) (order n + 4 with its
    border) stays under jaxlib's threshold for splitting a batch over the pool."""
    if members >= batch_first_min(model) or resolve_method(model) == "articulated":
        return None
    return inline_group(model.n + 4)


def inline_group(order: int) -> int:
    """Members per vmapped group whose batched dense factorization of order `order` stays under
    jaxlib's threshold for splitting a batch over the thread pool (:data:`LAPACK_INLINE_FLOPS`)."""
    return max(1, int(LAPACK_INLINE_FLOPS / (order**3 / 3.0)) - 1)


def host_devices() -> int:
    """The local devices a batch can be spread over: the CPU's host devices, else 1."""
    return len(jax.local_devices()) if jax.default_backend() == "cpu" else 1


def batched_eagerly(tree) -> bool:
    """True when `tree`'s traced leaves are all the tracers of one eager ``jax.vmap`` over concrete
    values (no ``jit``, no derivative, no second ``vmap`` around or inside it)."""
    traced = [x for x in jax.tree_util.tree_leaves(tree) if isinstance(x, Tracer)]
    if not traced or BatchTracer is None:
        return False
    if not all(type(x) is BatchTracer and not isinstance(x.val, Tracer) for x in traced):
        return False
    return len({id(getattr(x, "_trace", None)) for x in traced}) == 1


def over_devices(fn: Callable, args: tuple, *, quiet: Callable, report: Callable, group: Callable) -> Any:
    """``fn(*args)``; under an eager ``jax.vmap`` on several host devices, its batch split over them.

    - `quiet(args)`: the arguments of the split run, with the run's own failure report turned off;
    - `report(args, rerun, out)`: the failure report of the whole batch, given its arguments, the
      split run's concrete outputs `out` and ``rerun(g)``, which evaluates ``g(*args, out)``
      vmapped as `fn` was (on the default device);
    - `group(args, share)`: members per vmapped group of a device's `share` (None: all at once,
      1: one after another)."""
    devices = host_devices()
    if devices < 2 or not batched_eagerly(args):
        return fn(*args)
    dyn, static = eqx.partition(args, eqx.is_array)
    leaves, tree = jax.tree_util.tree_flatten(dyn)
    rebuild = lambda leaves: eqx.combine(jax.tree_util.tree_unflatten(tree, list(leaves)), static)
    kept = {}  # the outputs' parts that are not arrays (a custom_vmap returns arrays alone)

    def arrays(out):
        dyn_out, kept["static"] = eqx.partition(out, eqx.is_array)
        return dyn_out

    @jax.custom_batching.custom_vmap
    def run(leaves):
        return arrays(fn(*rebuild(leaves)))

    @run.def_vmap
    def _rule(size, in_batched, leaves):
        (flags,) = in_batched
        axes = [0 if f else None for f in flags]
        if any(isinstance(x, Tracer) for x in leaves) or size < 2:  # (not reached from an eager vmap)
            out = jax.vmap(lambda *ls: arrays(fn(*rebuild(ls))), in_axes=axes, axis_size=size)(*leaves)
            return out, jax.tree_util.tree_map(lambda _: True, out)
        n = min(devices, size)
        share = -(-size // n)
        out = arrays(
            _split(fn, quiet(rebuild(leaves)), tuple(bool(f) for f in flags), size, n, group(rebuild(leaves), share))
        )
        whole = lambda o: eqx.combine(o, kept["static"])

        def rerun(g):
            return jax.jit(jax.vmap(lambda ls, o: g(*rebuild(ls), whole(o)), in_axes=(axes, 0)))(leaves, out)

        report(rebuild(leaves), rerun, whole(out))
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return eqx.combine(run(leaves), kept["static"])


def _split(fn, args, flags, size, devices, group):
    """``fn`` over the members of `args` (batched leaves flagged in `flags`, in the order of
    ``eqx.partition``'s array leaves), split over the first `devices` local devices: the batch
    padded with copies of its last member to a multiple of them, each device's members placed on
    it, the outputs back on the default device as uncommitted arrays."""
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    dyn, static = eqx.partition(args, eqx.is_array)
    leaves, tree = jax.tree_util.tree_flatten(dyn)
    pad = (-size) % devices
    mesh = Mesh(np.asarray(jax.local_devices()[:devices]), ("members",))
    placed = []
    for x, f in zip(leaves, flags):
        if f and pad:
            x = jnp.concatenate([x, jnp.repeat(x[-1:], pad, axis=0)])
        placed.append(jax.device_put(x, NamedSharding(mesh, P("members") if f else P())))
    dyn = jax.tree_util.tree_unflatten(tree, placed)
    out = _split_jit(fn, flags, devices, group, eqx.combine(dyn, static))
    return jax.tree_util.tree_map(lambda x: jnp.asarray(np.asarray(x)[:size]) if eqx.is_array(x) else x, out)


@program_jit
def _split_jit(fn, flags, devices, group, args):
    from jax.sharding import Mesh
    from jax.sharding import PartitionSpec as P

    dyn, static = eqx.partition(args, eqx.is_array)
    leaves, tree = jax.tree_util.tree_flatten(dyn)
    axes = [0 if f else None for f in flags]
    one = lambda *ls: fn(*eqx.combine(jax.tree_util.tree_unflatten(tree, list(ls)), static))

    kept = {}  # the outputs' parts that are not arrays (a shard_map returns arrays alone)

    def arrays(out):
        dyn_out, kept["static"] = eqx.partition(out, eqx.is_array)
        return dyn_out

    def share(*ls):
        size = next(x.shape[0] for x, f in zip(ls, flags) if f)
        if group is None or group >= size:
            return jax.vmap(lambda *m: arrays(one(*m)), in_axes=axes)(*ls)
        batched = [x for x, f in zip(ls, flags) if f]

        def member(b):
            it = iter(b)
            return arrays(one(*(next(it) if f else x for x, f in zip(ls, flags))))

        if group == 1:  # a plain loop over the members (lax.map's batch_size=1 vmaps each of them)
            return jax.lax.map(member, batched)
        return jax.lax.map(member, batched, batch_size=group)

    mesh = Mesh(np.asarray(jax.local_devices()[:devices]), ("members",))
    specs = tuple(P("members") if f else P() for f in flags)
    out = jax.shard_map(share, mesh=mesh, in_specs=specs, out_specs=P("members"), check_vma=False)(*leaves)
    return eqx.combine(out, kept["static"])
