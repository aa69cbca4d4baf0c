"""The batch: Eq. (1) vmapped over B members, time per member, against the same batch vmapped
through the single-member solve and MuJoCo's threaded rollout, in one run.

For each case it prints the time per member of

- ``batch-first``: ``jax.vmap`` of :func:`jaxtree.forward_dynamics` as the engine runs it (from
  ``batch_first_min(model)`` members on, the batch-first recursion of
  ``jaxtree._src.equations.batched``);
- ``vmap single``: the single-member solve (dense or blocked articulated; ``solve.solve_one``,
  called explicitly) batched by ``vmap``;
- ``batch-first (<stage>)`` with ``--stages``: the recursion called explicitly
  (``solve.batch_first``) with the stages cut another way;
- ``batch-first, N devices``: the batch split over the host devices (``shard_map``), each
  device's share as one ``jax.vmap`` (the engine runs more than ``solve.BATCH_GROUP`` members
  group after group), or with `--group` in ``lax.map`` groups of that many;
- ``MuJoCo rollout``: ``mujoco.rollout`` with one thread per core, RK4, time per member and per
  right side (a step is four), where the scene is representable (massless bodies get a tiny mass);

with compile time apart, XLA's flop count per member (of one group's batch-first program with every
level unrolled: a ``lax.scan`` body is counted once) and the GFLOP/s it reaches. Timings: the batch
evaluated in a jitted ``fori_loop`` of `--loop` calls (arguments shifted by the loop index, so
nothing is hoisted), minimum of `--repeats`. The flex95 hybrid right side (3 modes per wing) is
vmapped as it is today (no batch-first form yet).

Goals (issue: the batch pays), per member, float64, this 2-core machine: fig4_free <= 1.0 us at
B = 1024; flex95 full Eq. (1) <= 5 us at B = 256; flex95 hybrid right side <= 3 us at B = 256;
a 60-body random tree <= 4 us at B = 256.

With ``--tangents K`` it times instead the JVP of Eq. (1) along K directions of the state per
member, by the two forms the engine's derivative rule takes, each called explicitly whatever the
tree's size (no module constant overwritten): the batch-first tangents (``jax.jvp`` of
``solve.batch_first``) against the single-member implicit-function rule (``rules.member_jvp``)
under ``vmap``; it prints how far the two differ.

Run:  python benchmarks/bench_batch.py [--cases fig4_free flex95 random60 hybrid] [--tangents K] [--json PATH]
"""

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxtree
from jaxtree._src.equations import batched, rules, solve

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
from _common import machine, write_json
from trees import deep_and_wide, random_tree

CASES = {"fig4_free": 1024, "flex95": 256, "random60": 256, "hybrid": 256}


def _args():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    p.add_argument("--sizes", nargs="+", type=int, default=None, help="batch sizes (default: each case's goal size)")
    p.add_argument("--loop", type=int, default=8, help="batched calls per timed loop")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--mujoco-steps", type=int, default=200)
    p.add_argument(
        "--stages",
        nargs="+",
        default=None,
        choices=("barrier", "none"),
        help="also time the batch-first program with its stages cut these ways (solve.batch_first)",
    )
    p.add_argument(
        "--tangents",
        type=int,
        default=0,
        help="time instead the JVP with this many tangents on the state (the derivative rule in a batch)",
    )
    p.add_argument(
        "--group",
        type=int,
        nargs="+",
        default=None,
        help="members per lax.map group of a device's share in the devices' row (default: the share as one vmap, "
        "which the engine runs in groups of at most solve.BATCH_GROUP)",
    )
    p.add_argument("--json", default=os.path.join(HERE, "results", "bench_batch.json"))
    return p.parse_args()


def say(*a):
    print(*a, flush=True)


def model_of(name):
    if name == "random60":
        rng = np.random.default_rng(60)
        return random_tree(rng, deep_and_wide(rng, 59))
    return jaxtree.load_scene("flex95" if name == "hybrid" else name)


def batch_states(model, size, seed=0):
    rng = np.random.default_rng(seed)
    w = jnp.asarray(0.2 * rng.normal(size=(size, 3)))
    g = jnp.asarray(0.3 * rng.normal(size=(size, model.n)))
    gd = jnp.asarray(0.3 * rng.normal(size=(size, model.n)))
    return w, g, gd


def loop_timing(fn, args, loop, repeats):
    """(seconds per batched call, compile seconds, flops of one call) of `fn(*args)`."""

    @jax.jit
    def run(*args):
        def body(i, acc):
            shifted = [a + 1e-12 * i for a in args]
            out = fn(*shifted)
            return acc + sum(jnp.sum(o) for o in jax.tree_util.tree_leaves(out))

        return jax.lax.fori_loop(0, loop, body, 0.0)

    t0 = time.perf_counter()
    compiled = run.lower(*args).compile()
    jax.block_until_ready(compiled(*args))
    first = time.perf_counter() - t0
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        best = min(best, time.perf_counter() - t0)
    return best / loop, first


def flops(fn, args):
    """XLA's flop count of one call of `fn(*args)` (a ``lax.scan`` body counted once)."""
    cost = jax.jit(fn).lower(*args).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    return float(cost.get("flops", np.nan))


def batch_first(model, stages=None, scan_min=batched.SCAN_MIN):
    """The batch-first recursion called explicitly (``scan_min`` above the depth: every level
    unrolled, for the flop count)."""
    dcm = model.initial.dcm

    def fn(w, g, gd):
        state = jaxtree.State(jnp.broadcast_to(dcm, (w.shape[0], 3, 3)), w, g, gd)
        return solve.batch_first(model, state, stages=stages, scan_min=scan_min)

    return fn


def vmap_single(model):
    dcm = model.initial.dcm
    return jax.vmap(lambda w, g, gd: solve.solve_one(model, jaxtree.State(dcm, w, g, gd), 0.0, None, None))


def eq1(model):
    dcm = model.initial.dcm
    return jax.vmap(lambda w, g, gd: jaxtree.forward_dynamics(model, dcm, w, g, gd))


def eq1_on_devices(model, size, group=None):
    """Eq. (1) of a batch split over the local devices (``shard_map``: the CPU's cores, one device
    per core as ``import jaxtree`` sets up), each device's share vmapped, by default as one
    ``jax.vmap`` (the engine then runs it in groups of ``solve.member_groups``, at most
    ``BATCH_GROUP`` = 64 members), with `group` in ``lax.map`` groups of `group` members as
    ``jaxtree.monte_carlo`` splits a chunk; None with one device."""
    from jax.sharding import Mesh
    from jax.sharding import PartitionSpec as P

    devices = jax.local_devices()
    if len(devices) < 2 or size % len(devices):
        return None
    dcm = model.initial.dcm
    one = lambda w, g, gd: jaxtree.forward_dynamics(model, dcm, w, g, gd)
    group = size // len(devices) if group is None else min(group, size // len(devices))
    share = lambda w, g, gd: jax.lax.map(lambda a: one(*a), (w, g, gd), batch_size=group)
    mesh = Mesh(np.asarray(devices), ("members",))
    spec = P("members")
    return jax.shard_map(share, mesh=mesh, in_specs=(spec, spec, spec), out_specs=spec, check_vma=False)


def mujoco_rollout(model, size, steps):
    """Seconds per member and right side of ``mujoco.rollout`` (RK4, one thread per core), or None."""
    try:
        import mujoco  # pyright: ignore[reportMissingImports]
        from mujoco import rollout  # pyright: ignore[reportMissingImports]

        from jaxtree.bench.peers import mjcf
    except ImportError:
        return None
    xml, _ = mjcf(model, timestep=1e-3, integrator="RK4", springs=True)
    m = mujoco.MjModel.from_xml_string(xml)
    threads = os.cpu_count() or 1
    datas = [mujoco.MjData(m) for _ in range(threads)]
    d = datas[0]
    mujoco.mj_resetData(m, d)
    d.qpos[3] = 1.0
    state = np.zeros(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    initial = np.tile(state, (size, 1))
    rng = np.random.default_rng(0)
    initial[:, 1 + m.nq : 1 + m.nq + m.nv] = 0.1 * rng.normal(size=(size, m.nv))
    rollout.rollout(m, datas, initial, nstep=2)
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        rollout.rollout(m, datas, initial, nstep=steps)
        best = min(best, time.perf_counter() - t0)
    return best / (size * steps * 4)


def hybrid_case(model, size, args):
    pulse = lambda t: jaxtree._src.equations.loads.thruster_pulse(t, 1.0, 2.0, rise=0.1)
    model = model.with_loads(jaxtree.BodyTorque(0, np.array([15.0, 9.0, 0.0]), pulse))
    small = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    hm = jaxtree.hybrid_model(model, small, 3)
    y = hm.pack(hm.model.initial)
    ys = jnp.asarray(y)[None, :] + 1e-3 * jnp.asarray(np.random.default_rng(1).normal(size=(size, y.size)))
    fn = jax.vmap(lambda y: jaxtree.hybrid_rhs(0.0, y, hm))
    per, first = loop_timing(fn, (ys,), args.loop, args.repeats)
    return [("hybrid rhs, vmapped", per / size, first, flops(fn, (ys,)) / size)]


def tangents_case(model, size, args):
    """The JVP of Eq. (1) along `args.tangents` random directions of the state, vmapped over the
    batch, by the two forms the engine's derivative rule takes, called explicitly: the batch-first
    tangents (``jax.jvp`` of ``solve.batch_first``: the rule's form for trees of
    ``rules.BATCH_FIRST_DERIVATIVES_MIN`` bodies and more) against the single-member
    implicit-function rule (``rules.member_jvp``, its form below) batched by ``vmap``."""
    xs = batch_states(model, size)
    rng = np.random.default_rng(2)
    dirs = tuple(jnp.asarray(rng.normal(size=(size, args.tangents) + x.shape[1:])) for x in xs)
    dcm = model.initial.dcm
    untangled = jax.tree_util.tree_map(lambda _: None, model)

    def batch_first(w, g, gd, *d):  # the batch's recursion differentiated forward, per direction
        f = lambda w, g, gd: solve.batch_first(model, jaxtree.State(jnp.broadcast_to(dcm, (size, 3, 3)), w, g, gd))
        return jax.vmap(lambda *t: jax.jvp(f, (w, g, gd), t)[1].gamma_ddot, in_axes=1, out_axes=1)(*d)

    def member(w, g, gd, dw, dg, dgd):  # one member's rule along one direction
        primals = (model, jaxtree.State(dcm, w, g, gd), 0.0, None, None)
        tangents = (untangled, jaxtree.State(None, dw, dg, dgd), None, None, None)
        return rules.member_jvp(primals, tangents)[2].gamma_ddot

    members = jax.vmap(lambda w, g, gd, *d: jax.vmap(lambda *t: member(w, g, gd, *t))(*d))
    a, b = jax.jit(batch_first)(*xs, *dirs), jax.jit(members)(*xs, *dirs)
    print(
        f"  {args.tangents} tangents: the two forms differ by {float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))):.1e}"
    )
    rows = []
    for label, fn in (("tangents, batch-first", batch_first), ("tangents, rule vmapped", members)):
        per, first = loop_timing(fn, xs + dirs, args.loop, args.repeats)
        rows.append((f"{args.tangents} {label}", per / size, first, flops(fn, xs + dirs) / size))
    return rows


def case(name, size, args):
    model = model_of(name)
    if args.tangents and name != "hybrid":
        rows = tangents_case(model, size, args)
    elif name == "hybrid":
        rows = hybrid_case(model, size, args)
    else:
        xs = batch_states(model, size)
        fn = eq1(model)
        per, first = loop_timing(fn, xs, args.loop, args.repeats)
        unrolled = batch_first(model, scan_min=10**9)
        each = solve.member_groups(size)[1]  # a batch of more runs group after group: one group's flops
        group_xs = tuple(x[:each] for x in xs)
        rows = [(f"batch-first ({batched.default_stages()})", per / size, first, flops(unrolled, group_xs) / each)]
        for mode in args.stages or ():
            if mode == batched.default_stages():
                continue
            per, first = loop_timing(batch_first(model, stages=mode), xs, args.loop, args.repeats)
            fl = flops(batch_first(model, mode, 10**9), group_xs) / each
            rows.append((f"batch-first ({mode})", per / size, first, fl))
        per, first = loop_timing(vmap_single(model), xs, args.loop, args.repeats)
        rows.append(("vmap single", per / size, first, flops(vmap_single(model), xs) / size))
        for group in args.group or [None]:
            sharded = eq1_on_devices(model, size, group)
            if sharded is not None:
                per, first = loop_timing(sharded, xs, args.loop, args.repeats)
                label = f"batch-first, {jax.device_count()} devices" + ("" if group is None else f", groups of {group}")
                rows.append((label, per / size, first, np.nan))
        mj = mujoco_rollout(model, size, args.mujoco_steps)
        if mj is not None:
            rows.append(("MuJoCo rollout RK4", mj, np.nan, np.nan))
    out = []
    for label, t, first, fl in rows:
        gf = fl / t / 1e9 if np.isfinite(fl) else np.nan
        say(
            f"{name:10s} B={size:5d} {label:34s} {t * 1e6:9.2f} us/member  compile {first:6.1f} s  "
            f"{fl / 1e3:8.1f} kflop/member  {gf:5.1f} GFLOP/s"
        )
        out.append(dict(case=name, size=size, method=label, us=t * 1e6, compile_s=first, kflop=fl / 1e3, gflops=gf))
    return out


def main():
    args = _args()
    say(machine())
    say(
        f"jax {jax.__version__}, float64, batch-first from {solve.BATCH_FIRST_MIN} members "
        f"({solve.BATCH_FIRST_MIN_LARGE} for trees of {solve.LARGE_TREE_HINGES} hinges and more)"
    )
    results = []
    for name in args.cases:
        for size in args.sizes or [CASES[name]]:
            results.extend(case(name, size, args))
    if args.json:
        write_json(args.json, dict(machine=machine(), rows=results))


if __name__ == "__main__":
    main()
