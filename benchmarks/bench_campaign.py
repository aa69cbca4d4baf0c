#!/usr/bin/env python3
"""Benchmark of `jaxtree.monte_carlo` (a benchmark, not a test): Monte Carlo throughput on fig4_free.

N runs (default 1000) of fig4_free over 10 s, each with its own initial body rate (N(0, 0.01)
rad/s per axis), panel hinge rates (N(0, 0.01) rad/s) and panel stiffness (x 1 + N(0, 10 %)),
saved at 101 times. Prints the machine and versions, then:

- the accuracy setting: on a subsample of members, the error of each method (max over the save
  times of the largest absolute error in (omega0, gamma)) against a tight jaxtree reference
  (rtol = atol = 1e-12) for a few tolerances; each method runs at the loosest one that reaches
  the error goal (1e-6);
- jaxtree in float64: compile time (a first campaign of one chunk) apart from run time, then
  the whole campaign: runs per second, simulated seconds per wall second, the chunks'
  efficiency (useful steps over the steps paid for by the vmapped chunk: the cost of waiting
  for each chunk's slowest member), and the same with ``order="pilot"`` (chunks filled in the
  order of a 10 % pilot's step counts) and with fixed steps;
- jaxtree in float32 (its default tolerance, 1e-4) and its error against the float64 reference;
- the peers: Pinocchio's ABA under scipy's DOP853, the members split over two processes
  (``multiprocessing``, its natural parallelization on this 2-core machine), at its own
  tolerance for the same error goal; MuJoCo's ``rollout`` (RK4, one thread per core, one
  ``MjModel`` per member for its stiffness) at the largest fixed step that reaches the error goal;
  the ratios of throughputs (goals: >= 15x Pinocchio, >= 5x MuJoCo; the campaigns issue, point 4;
  the batch issue had asked 20x Pinocchio).

With ``--scene flex95``, the flexible-vehicle campaign instead (the batch issue, point 3: goal
>= 10x Pinocchio + scipy Radau in two processes): N members (default 256) of bench_hybrid.py's
flex95 slew (10 s, 201 saves), each with the 90 wing hinges' stiffness scaled by its own factor
and the slew torque by another, both uniform in [0.9, 1.1] (numpy's ``default_rng(0)``: member
i's pair does not depend on N, and the subsample is the campaign's first members). Prints:

- the accuracy setting: a tight reference per subsample member (the full Eq. (1), Dopri8 at
  rtol = atol = 1e-10) and each candidate's error in bench_hybrid.py's measure (hub rate
  ``max |omega0 - ref| / max |omega0_ref|``, wing angles likewise; goal hub 1e-3, wings 1e-2) over
  a tolerance ladder: the hybrid model (3 modes per wing, rebuilt for each member's stiffness by
  ``jaxtree.hybrid_model(..., like=nominal)``) with jaxtree.Radau5 and with Dopri8, and the full
  Eq. (1) with both (``--no-full`` skips it); each at its loosest tolerance meeting the goal,
  the cheapest integration a member (the subsample's members one after another in one compiled
  program; the rebuild is timed in the campaign: its mass part, shared by every member, is
  evaluated once, when the members' program is traced) is the campaign's setting;
- jaxtree on the whole campaign with that setting: a single run of the nominal member, then the
  members in chunks of ``--chunk`` three ways: vmapped, one after another in one compiled
  program (``lax.map``), and that split over ``--devices`` host devices (two: the machine's
  cores); first chunk (compile + run, the persistent cache off unless ``--cache``) apart from
  the campaign's time, the members' rebuild
  (hybrid) apart from their integration, members per second, steps, Radau5's Jacobians and
  factorizations a member;
- the peer: Pinocchio's ABA under scipy's Radau (the forward-difference Jacobian of
  ``jaxtree.bench.peers.pinocchio_runner``, the torque in numpy as the free flyer's generalized
  force) at its loosest tolerance of the ladder meeting the same goal on the same subsample, the
  members split over two processes; the ratio of throughputs against the goal.

Run:  python benchmarks/bench_campaign.py [--runs 1000] [--chunk 128] [--json results/bench_campaign.json]
      python benchmarks/bench_campaign.py --scene flex95 [--runs 256] [--subsample 4] [--note TEXT] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

T1, SAVES, GOAL_ERROR = 10.0, 101, 1e-6


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="fig4_free", choices=["fig4_free", "flex95"])
    p.add_argument("--runs", type=int, help="members (default 1000; flex95 256)")
    p.add_argument("--chunk", type=int, default=128)
    p.add_argument("--subsample", type=int, help="members whose error is measured (default 8; flex95 4)")
    p.add_argument(
        "--tols",
        type=float,
        nargs="+",
        help="tolerances tried (default 1e-6 3e-7 1e-7 3e-8; flex95: the implicit ladder of jaxtree.Radau5 "
        "and scipy's Radau, 1e-4 5e-5 3e-5 2e-5 1e-5 1e-6)",
    )
    p.add_argument("--dt", type=float, nargs="+", default=[0.025, 0.02, 0.01], help="fixed steps tried")
    p.add_argument(
        "--mujoco-dt", type=float, nargs="+", default=[0.005, 0.0025, 0.002, 0.00125, 0.001], help="RK4 steps tried"
    )
    p.add_argument(
        "--explicit-tols",
        type=float,
        nargs="+",
        default=[1e-3, 1e-4, 1e-5, 1e-6],
        help="flex95: Dopri8's ladder",
    )
    p.add_argument("--no-full", action="store_true", help="flex95: leave the full Eq. (1) out of the choice")
    p.add_argument("--devices", type=int, default=2, help="flex95: host devices of the split sequential run")
    p.add_argument("--note", help="a line printed under the machine's (e.g. who else used it)")
    p.add_argument(
        "--cache", action="store_true", help="keep jaxtree's persistent compilation cache on (off by default here)"
    )
    p.add_argument("--no-peer", action="store_true")
    p.add_argument("--json")
    a = p.parse_args()
    flex = a.scene == "flex95"
    a.runs = a.runs or (256 if flex else 1000)
    a.subsample = a.subsample or (4 if flex else 8)
    a.tols = a.tols or ([1e-4, 5e-5, 3e-5, 2e-5, 1e-5, 1e-6] if flex else [1e-6, 3e-7, 1e-7, 3e-8])
    return a


ARGS = _args()
from _common import use_fast_cpu_flags

use_fast_cpu_flags()
if ARGS.scene == "flex95" and ARGS.devices > 1 and "host_platform_device_count" not in os.environ["XLA_FLAGS"]:
    # host devices for the split sequential run only (fig4_free's campaign keeps one device)
    os.environ["XLA_FLAGS"] += f" --xla_force_host_platform_device_count={ARGS.devices}"
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
if not ARGS.cache:  # a first chunk's compile is XLA's, not a read of what an earlier run left on disk
    os.environ.setdefault("JAXTREE_CACHE_DIR", "0")

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import dispersed_fig4 as sample
from _common import machine, timed, write_json
from _flex95 import FLEX_SAVES, FLEX_T1, Flex, flex_errors, flex_factors, flex_meets
from _flex95 import pulse as _pulse


def say(*a):
    print(*a, flush=True)


def campaign(model, n, **kw):
    kw.setdefault("chunk_size", min(n, ARGS.chunk))
    return jaxtree.monte_carlo(model, sample, n, T1, key=jax.random.key(0), saveat=SAVES, **kw)


def error(ds, ref):
    w = np.abs(ds.omega0.values - ref.omega0.values[: ds.sizes["run"]]).max(axis=(1, 2))
    g = np.abs(ds.gamma.values - ref.gamma.values[: ds.sizes["run"]]).max(axis=(1, 2))
    return float(np.max(np.maximum(w, g)))


# ----------------------------------------------------------------------------- the peer
def _peer_worker(job):
    """Pinocchio ABA + scipy DOP853 for a list of members: (omega0, gamma) histories, rhs counts."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from scipy.integrate import solve_ivp

    from _peers import pinocchio_initial, pinocchio_model, pinocchio_rhs

    model, members, tol = job
    built = pinocchio_model(model)
    n = model.n
    ts = np.linspace(0.0, T1, SAVES)
    out, nfev = [], 0
    for stiffness, omega0, gamma, gamma_dot in members:
        rhs = pinocchio_rhs(model, stiffness=stiffness, built=built)
        state = model.initial._replace(
            omega0=jnp.asarray(omega0), gamma=jnp.asarray(gamma), gamma_dot=jnp.asarray(gamma_dot)
        )
        x0 = pinocchio_initial(eqx.tree_at(lambda m: m.initial, model, state))
        r = solve_ivp(rhs, (0.0, T1), x0, method="DOP853", rtol=tol, atol=tol, t_eval=ts)
        out.append(r.y.T[:, : 3 + n])
        nfev += r.nfev
    return np.asarray(out), nfev


def peer_members(model, ds):
    n = ds.sizes["run"]
    stiffness = ds["param.stiffness"].values if "param.stiffness" in ds else np.tile(model.stiffness, (n, 1))
    s = model.initial
    omega0 = ds["param.initial.omega0"].values
    gamma_dot = ds["param.initial.gamma_dot"].values
    return [(stiffness[i], omega0[i], np.asarray(s.gamma), gamma_dot[i]) for i in range(n)]


def peer(model, members, tol, processes):
    import multiprocessing as mp

    chunks = [members[i::processes] for i in range(processes)]
    t = time.perf_counter()
    if processes == 1:
        results = [_peer_worker((model, chunks[0], tol))]
    else:
        with mp.get_context("fork").Pool(processes) as pool:
            results = pool.map(_peer_worker, [(model, c, tol) for c in chunks])
    wall = time.perf_counter() - t
    hist = np.empty((len(members), SAVES, 3 + model.n))
    for p, (h, _) in enumerate(results):
        hist[p::processes] = h
    return hist, wall, sum(nf for _, nf in results)


def mujoco_campaign(model, members, dt, threads):
    """MuJoCo RK4 at the fixed step `dt` through ``mujoco.rollout`` with `threads` threads, one
    ``MjModel`` per member (its panel stiffness): ((omega0, gamma) histories (n, SAVES, 3 + n), wall
    seconds of the rollouts). The members' initial states are built before the clock starts."""
    import copy

    import mujoco  # pyright: ignore[reportMissingImports]
    from mujoco import rollout  # pyright: ignore[reportMissingImports]

    from jaxtree.bench.peers import base_velocities, mjcf

    xml, _ = mjcf(model, timestep=dt, integrator="RK4", springs=True)
    base = mujoco.MjModel.from_xml_string(xml)
    jnt = [mujoco.mj_name2id(base, mujoco.mjtObj.mjOBJ_JOINT, f"h{k}") for k in range(1, model.n + 1)]
    iq, iv = base.jnt_qposadr[jnt], base.jnt_dofadr[jnt]
    sprung = np.asarray(model.sprung, int) - 1
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    d = mujoco.MjData(base)
    models, initial = [], np.zeros((len(members), mujoco.mj_stateSize(base, spec)))
    v0 = base_velocities(model, *(jnp.asarray(np.stack([mb[j] for mb in members])) for j in (1, 2, 3)))
    for i, (stiffness, omega0, gamma, gamma_dot) in enumerate(members):
        m = copy.deepcopy(base)
        m.jnt_stiffness[np.asarray(jnt)[sprung]] = np.asarray(stiffness)[sprung]
        models.append(m)
        mujoco.mj_resetData(m, d)
        d.qpos[3] = 1.0
        d.qpos[iq] = np.asarray(gamma)
        d.qvel[0:3] = v0[i]
        d.qvel[3:6] = np.asarray(omega0)
        d.qvel[iv] = np.asarray(gamma_dot)
        mujoco.mj_getState(m, d, initial[i], spec)
    datas = [mujoco.MjData(base) for _ in range(threads)]
    per_save = round(T1 / (SAVES - 1) / dt)
    qpos0, qvel0 = 1, 1 + base.nq  # offsets in the full-physics state (time first)
    hist = np.empty((len(members), SAVES, 3 + model.n))
    t = time.perf_counter()
    x = initial
    for k in range(SAVES):
        hist[:, k, :3] = x[:, qvel0 + 3 : qvel0 + 6]
        hist[:, k, 3:] = x[:, qpos0 + iq]
        if k < SAVES - 1:
            x = rollout.rollout(models, datas, x, nstep=per_save, persistent_pool=True)[0][:, -1, :]
    return hist, time.perf_counter() - t


def _has_mujoco():
    try:
        from mujoco import rollout  # pyright: ignore[reportMissingImports]  # noqa: F401
    except ImportError:
        return False
    return True


def peer_error(hist, ref, n):
    w = np.abs(hist[:, :, :3] - ref.omega0.values[:n]).max()
    g = np.abs(hist[:, :, 3:] - ref.gamma.values[:n]).max()
    return float(max(w, g))


def main_fig4():
    results = {"machine": machine(), "runs": ARGS.runs, "t1": T1, "saves": SAVES}
    say(results["machine"])
    say(f"jaxtree's persistent compilation cache: {'on' if ARGS.cache else 'off'}")
    if ARGS.note:
        say(ARGS.note)
    try:
        import pinocchio

        say(f"pinocchio {pinocchio.__version__}, scipy {__import__('scipy').__version__}")
    except ImportError:
        pinocchio = None
    model = jaxtree.load_scene("fig4_free")
    m = ARGS.subsample

    say(f"\n[accuracy] reference: {m} members at rtol = atol = 1e-12")
    ref = campaign(model, m, rtol=1e-12, atol=1e-12, chunk_size=m)
    chosen = None
    for tol in sorted(ARGS.tols, reverse=True):
        ds = campaign(model, m, rtol=tol, atol=tol, chunk_size=m)
        e = error(ds, ref)
        say(f"  jaxtree rtol = atol = {tol:g}: error {e:.2e}, mean steps {ds.steps.values.mean():.0f}")
        if chosen is None and e <= GOAL_ERROR:
            chosen = tol
    chosen = chosen or min(ARGS.tols)
    fixed = None
    for dt in sorted(ARGS.dt, reverse=True):
        ds = campaign(model, m, dt=dt, chunk_size=m)
        e = error(ds, ref)
        say(f"  jaxtree fixed dt = {dt:g} (Dopri8): error {e:.2e}, steps {int(ds.steps.values.max())}")
        if fixed is None and e <= GOAL_ERROR:
            fixed = dt
    results["jaxtree_tol"], results["fixed_dt"] = chosen, fixed

    peer_tol = None
    if pinocchio is not None and not ARGS.no_peer:
        members = peer_members(model, ref)
        for tol in sorted(ARGS.tols, reverse=True):
            hist, _, nfev = peer(model, members, tol, 1)
            e = peer_error(hist, ref, m)
            say(f"  Pinocchio + DOP853 rtol = atol = {tol:g}: error {e:.2e}, rhs {nfev / m:.0f} per run")
            if peer_tol is None and e <= GOAL_ERROR:
                peer_tol = tol
        peer_tol = peer_tol or min(ARGS.tols)
        results["peer_tol"] = peer_tol

    mj_dt = None
    threads = os.cpu_count() or 1
    if _has_mujoco() and not ARGS.no_peer:
        members = peer_members(model, ref)
        for dt in sorted(ARGS.mujoco_dt, reverse=True):
            hist, _ = mujoco_campaign(model, members, dt, threads)
            e = peer_error(hist, ref, m)
            say(f"  MuJoCo rollout RK4 dt = {dt:g}: error {e:.2e}, {round(T1 / dt)} steps")
            if mj_dt is None and e <= GOAL_ERROR:
                mj_dt = dt
        mj_dt = mj_dt or min(ARGS.mujoco_dt)
        results["mujoco_dt"] = mj_dt

    n, chunk = ARGS.runs, min(ARGS.runs, ARGS.chunk)
    say(f"\n[jaxtree float64] {n} runs of {T1:g} s, chunks of {chunk}, rtol = atol = {chosen:g}")
    rows = {}

    def run_variant(label, **kw):
        t = time.perf_counter()
        campaign(model, chunk, rtol=chosen, atol=chosen, **kw)  # compiles the chunk (and the pilot)
        first = time.perf_counter() - t
        t = time.perf_counter()
        ds = campaign(model, n, rtol=chosen, atol=chosen, **kw)
        wall = time.perf_counter() - t
        eff = np.asarray(ds.attrs["chunk_efficiency"])
        ok = int((ds.status.values == "successful").sum())
        row = {
            "wall_s": wall,
            "first_chunk_s": first,
            "runs_per_s": n / wall,
            "sim_s_per_s": n * T1 / wall,
            "efficiency_mean": float(eff.mean()),
            "efficiency_min": float(eff.min()),
            "steps_mean": float(ds.steps.values.mean()),
            "steps_max": int(ds.steps.values.max()),
            "pilot_s": ds.attrs["pilot_s"],
            "successful": ok,
        }
        rows[label] = row
        say(
            f"  {label:12s} first chunk (compile + run) {first:6.1f} s; campaign {wall:6.1f} s: {n / wall:7.1f} runs/s, "
            f"{n * T1 / wall:8.0f} simulated s/s; chunk efficiency mean {eff.mean():.3f} min {eff.min():.3f}; "
            f"steps mean {ds.steps.values.mean():.0f} max {ds.steps.values.max()}; {ok}/{n} successful"
            + (f"; pilot {ds.attrs['pilot_s']:.1f} s" if kw.get("order") else "")
        )
        return ds

    ds_index = run_variant("index order")
    run_variant("pilot order", order="pilot")
    if fixed is not None:
        rows_fixed = run_variant(f"fixed dt={fixed:g}", dt=fixed)
        del rows_fixed
    results["jaxtree_float64"] = rows

    say("\n[jaxtree float32] default tolerance (1e-4)")
    m32 = model.astype(jnp.float32)
    ds32 = campaign(m32, m, chunk_size=m)
    e32 = error(ds32, ref)
    t = time.perf_counter()
    campaign(m32, chunk)
    first32 = time.perf_counter() - t
    t = time.perf_counter()
    ds32 = campaign(m32, n)
    wall32 = time.perf_counter() - t
    say(
        f"  error {e32:.2e} (subsample); first chunk {first32:.1f} s; campaign {wall32:.1f} s: {n / wall32:.1f} runs/s, "
        f"{n * T1 / wall32:.0f} simulated s/s; chunk efficiency mean {np.mean(ds32.attrs['chunk_efficiency']):.3f}"
    )
    results["jaxtree_float32"] = {"error": e32, "wall_s": wall32, "runs_per_s": n / wall32, "first_chunk_s": first32}

    best = max(r["runs_per_s"] for r in rows.values())
    if peer_tol is not None:
        say(f"\n[peer] Pinocchio ABA + scipy DOP853, rtol = atol = {peer_tol:g}, two processes")
        members = peer_members(model, ds_index)  # the same dispersed members
        _, wall, nfev = peer(model, members, peer_tol, 2)
        say(f"  {wall:.1f} s: {n / wall:.1f} runs/s, {n * T1 / wall:.0f} simulated s/s, {nfev / n:.0f} rhs per run")
        results["peer"] = {"wall_s": wall, "runs_per_s": n / wall, "tol": peer_tol}
        ratio = best / (n / wall)
        say(
            f"\n[goal] jaxtree float64 best {best:.1f} runs/s against Pinocchio's {n / wall:.1f}: {ratio:.2f}x "
            f"(goal >= 15x): {'met' if ratio >= 15 else 'NOT met'}"
        )
        results["ratio"] = ratio
    if mj_dt is not None:
        say(f"\n[peer] MuJoCo rollout, RK4 at dt = {mj_dt:g}, {threads} threads (one per core)")
        members = peer_members(model, ds_index)
        _, wall = mujoco_campaign(model, members, mj_dt, threads)
        say(f"  {wall:.1f} s: {n / wall:.1f} runs/s, {n * T1 / wall:.0f} simulated s/s")
        results["mujoco"] = {"wall_s": wall, "runs_per_s": n / wall, "dt": mj_dt, "threads": threads}
        ratio = best / (n / wall)
        say(
            f"[goal] jaxtree float64 best {best:.1f} runs/s against MuJoCo's {n / wall:.1f}: {ratio:.2f}x "
            f"(goal >= 5x): {'met' if ratio >= 5 else 'NOT met'}"
        )
        results["ratio_mujoco"] = ratio
    if ARGS.json:
        write_json(ARGS.json, results)


# ----------------------------------------------------------------------------- flex95
FLEX_GOAL = 10.0
_FLEX_PEER: dict = {}  # the peer's numpy side, set before the worker processes fork


def flex_runner(flex, form, solver, mode):
    """``run(factors (B, 2), tol) -> (omega0 (B, T, 3), gamma (B, T, n), counts (B, 3), build s, run s)``
    for a chunk of members (counts: accepted steps, Jacobians and factorizations; -1 where the
    solver keeps none). `form`: "hybrid" or "full"; `mode`: "vmap" (the members vmapped),
    "sequence" (one after another in one compiled program, ``lax.map``) or "devices" (the
    sequence split over the host devices by ``shard_map``). Two compiled programs: the members'
    models (a hybrid model rebuilt per member, by ``lax.map``: vmapped, the build's batched complex
    LU deadlocked in jaxlib's LAPACK pool here; with "devices" split over the devices as well) and
    their integration."""
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    def sim(x, tol):
        kw = dict(y0=flex.state, saveat=flex.ts, rtol=tol, atol=tol, solver=solver)
        if form == "hybrid":
            sol = jaxtree.simulate_hybrid(x, FLEX_T1, truncation_error=False, **kw)
        else:
            sol = jaxtree.simulate(x, FLEX_T1, **kw)
        none = jnp.asarray(-1, jnp.int32)
        counts = [
            sol.stats["num_accepted_steps"],
            sol.stats.get("jacobians", none),
            sol.stats.get("factorizations", none),
        ]
        return sol.omega0, sol.gamma, jnp.stack([jnp.asarray(c, jnp.int32) for c in counts])

    one = flex.hybrid if form == "hybrid" else flex.member
    members = lambda f: jax.lax.map(lambda x: one(x[0], x[1]), f)
    build = jax.jit(members)
    sharding = None
    if mode == "vmap":
        integrate = jax.jit(jax.vmap(sim, in_axes=(0, None)))
    elif mode == "sequence":
        integrate = jax.jit(lambda xs, tol: jax.lax.map(lambda x: sim(x, tol), xs))
    else:
        mesh = Mesh(np.array(jax.devices()[: ARGS.devices]), ("m",))
        sharding = NamedSharding(mesh, P("m"))
        # the members' models built on the devices too, each its share one after another
        build = jax.jit(jax.shard_map(members, mesh=mesh, in_specs=P("m"), out_specs=P("m"), check_vma=False))
        integrate = jax.jit(
            jax.shard_map(
                lambda xs, tol: jax.lax.map(lambda x: sim(x, tol), xs),
                mesh=mesh,
                in_specs=(P("m"), P()),
                out_specs=P("m"),
                check_vma=False,
            )
        )

    def run(factors, tol):
        t = time.perf_counter()
        f = jnp.asarray(factors) if sharding is None else jax.device_put(jnp.asarray(factors), sharding)
        xs = jax.block_until_ready(build(f))
        t_build = time.perf_counter() - t
        t = time.perf_counter()
        w, g, counts = jax.block_until_ready(integrate(xs, jnp.asarray(tol, float)))
        return np.asarray(w), np.asarray(g), np.asarray(counts), t_build, time.perf_counter() - t

    return run


def _flex_peer_worker(job):
    """Pinocchio ABA + scipy Radau for a list of (wing factor, torque factor) members:
    ((omega0, gamma) histories or None, right sides, Jacobians)."""
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from scipy.integrate import solve_ivp

    from jaxtree.bench.peers import forward_difference_jacobian

    from _peers import pinocchio_rhs

    members, tol, keep = job
    p = _FLEX_PEER
    n, x0, ts = p["model"].n, p["x0"], p["ts"]
    out, nfev, njev = [], 0, 0
    for ks, kt in members:
        stiffness = p["stiffness"].copy()
        stiffness[p["wings"]] *= ks
        torque = p["torque"] * kt
        rhs = pinocchio_rhs(p["model"], lambda t, T=torque: T * _pulse(t), stiffness=stiffness, built=p["built"])

        jac = forward_difference_jacobian(rhs)  # pinocchio_runner's (scipy's own overflows on the rotor's angle)
        r = solve_ivp(rhs, (0.0, FLEX_T1), x0, method="Radau", rtol=tol, atol=tol, t_eval=ts, jac=jac)
        if r.status != 0 or r.y.shape[1] != ts.size:
            raise RuntimeError(f"scipy Radau: {r.message}")
        if keep:
            out.append((r.y[:3].T, r.y[3 : 3 + n].T))
        nfev += int(r.nfev) + int(r.njev) * (x0.size + 1)
        njev += int(r.njev)
    return out, nfev, njev


def flex_peer_setup(flex):
    from _peers import pinocchio_initial, pinocchio_model

    model = eqx.tree_at(lambda m: m.initial, flex.model.with_loads(None), flex.state)
    model_np = jax.tree_util.tree_map(np.asarray, model)
    sprung = np.asarray(model.sprung, int) - 1
    stiffness = np.zeros(model.n)
    stiffness[sprung] = np.asarray(model.stiffness, float)[sprung]
    _FLEX_PEER.update(
        model=model_np,
        built=pinocchio_model(model_np),
        x0=pinocchio_initial(model),
        ts=np.asarray(flex.ts, float),
        torque=np.asarray(flex.torque, float),
        stiffness=stiffness,
        wings=flex.wings,
    )


def flex_peer(factors, tol, processes, keep=False):
    """The members over `processes` processes: (histories in member order or None, wall s, right sides, Jacobians)."""
    import multiprocessing as mp

    members = [tuple(map(float, f)) for f in factors]
    chunks = [members[i::processes] for i in range(processes)]
    t = time.perf_counter()
    if processes == 1:
        results = [_flex_peer_worker((chunks[0], tol, keep))]
    else:
        with mp.get_context("fork").Pool(processes) as pool:
            results = pool.map(_flex_peer_worker, [(c, tol, keep) for c in chunks])
    wall = time.perf_counter() - t
    hist = None
    if keep:
        hist = [None] * len(members)
        for p, (h, _, _) in enumerate(results):
            hist[p::processes] = h
        hist = (np.stack([h[0] for h in hist]), np.stack([h[1] for h in hist]))
    return hist, wall, sum(r[1] for r in results), sum(r[2] for r in results)


def main_flex():
    import diffrax as dfx
    from bench_hybrid import HUB_GOAL, SMALL_GOAL

    results = {"machine": machine(), "scene": "flex95", "runs": ARGS.runs, "t1": FLEX_T1, "saves": FLEX_SAVES}
    say(results["machine"])
    say(f"jaxtree's persistent compilation cache: {'on' if ARGS.cache else 'off'}")
    if ARGS.note:
        say(ARGS.note)
        results["note"] = ARGS.note
    try:
        import pinocchio

        say(f"pinocchio {pinocchio.__version__}, scipy {__import__('scipy').__version__}")
    except ImportError:
        pinocchio = None
    say(f"host devices: {jax.device_count()} ({jax.default_backend()})")
    flex = Flex()
    S, m, n = flex.wings, ARGS.subsample, ARGS.runs
    factors = flex_factors(n)
    sub = factors[:m]
    say(
        f"flex95 slew: {FLEX_T1:g} s, {FLEX_SAVES} saves, torque {flex.torque.tolist()} N m from 1 s to 3 s; "
        f"{n} members, wing stiffness and torque each x U(0.9, 1.1) (member 0: {factors[0][0]:.4f}, "
        f"{factors[0][1]:.4f}); nominal hybrid model ({flex.hm0.n_modes} modes, {flex.hm0.form}) built in "
        f"{flex.build0_s:.2f} s"
    )

    say(f"\n[accuracy] reference: {m} members, full Eq. (1), Dopri8, rtol = atol = 1e-10 (one after another)")
    runners = {}

    def runner(form, solver_name, mode):
        key = (form, solver_name, mode)
        if key not in runners:
            solver = jaxtree.Radau5() if solver_name == "Radau5" else dfx.Dopri8()
            runners[key] = flex_runner(flex, form, solver, mode)
            runners[key].solver = solver
        return runners[key]

    t = time.perf_counter()
    w, g, counts, _, _ = runner("full", "Dopri8", "sequence")(sub, 1e-10)
    ref, steps = (w, g), counts[:, 0]
    say(f"  {time.perf_counter() - t:.1f} s with its compile; steps {steps.min()}-{steps.max()}")
    candidates = [("hybrid", "Radau5", ARGS.tols), ("hybrid", "Dopri8", ARGS.explicit_tols)]
    if not ARGS.no_full:
        candidates += [("full", "Radau5", ARGS.tols), ("full", "Dopri8", ARGS.explicit_tols)]
    say(
        f"  each candidate on the {m} members one after another (lax.map): hub / wings error (goal {HUB_GOAL:g} / "
        f"{SMALL_GOAL:g}), steps, integration time a member (the members' models apart: their build in "
        "one call of the subsample's members)"
    )
    rows = []
    for form, solver_name, tols in candidates:
        run = runner(form, solver_name, "sequence")
        t = time.perf_counter()
        run(sub, max(tols))  # compiles
        say(f"  {form} {solver_name}: first call (compile + run) {time.perf_counter() - t:.1f} s")
        for tol in sorted(tols, reverse=True):
            w, g, counts, tb, tr = run(sub, tol)
            steps = counts[:, 0]
            e = flex_errors(w, g, ref, S)
            row = dict(
                form=form,
                solver=solver_name,
                tol=tol,
                hub=e[0],
                wings=e[1],
                steps_mean=float(steps.mean()),
                member_ms=1e3 * tr / m,
                models_ms=1e3 * tb,
                ok=flex_meets(e),
            )
            rows.append(row)
            say(
                f"    rtol = atol = {tol:g}: hub {e[0]:.2e}, wings {e[1]:.2e}{' (meets)' if row['ok'] else ''}, "
                f"steps {steps.min()}-{steps.max()}, {row['member_ms']:.1f} ms a member "
                f"(the {m} members' models {row['models_ms']:.0f} ms)"
            )
            if row["ok"]:
                break  # the loosest tolerance that meets the goal: tighter ones cost more
    results["accuracy"] = rows
    ok = [r for r in rows if r["ok"]]
    if not ok:
        say("no candidate meets the goal on the subsample: extend the ladders")
        return
    best = min(ok, key=lambda r: r["member_ms"])
    form, solver_name, tol = best["form"], best["solver"], best["tol"]
    say(
        "  loosest setting meeting the goal: "
        + "; ".join(f"{r['form']} {r['solver']} {r['tol']:g} {r['member_ms']:.1f} ms" for r in ok)
        + f"\n  chosen (cheapest a member): {form} {solver_name} at rtol = atol = {tol:g}"
    )
    full_dopri = [r for r in ok if r["form"] == "full" and r["solver"] == "Dopri8"]
    if full_dopri:
        # a vmapped Dopri8 over >= 64 members takes the batch-first Eq. (1): bench_batch.py's 13.45 us a member
        # and right side (flex95, B = 256, 2026-11-27) bounds it from below, integrator's work aside
        r = full_dopri[0]
        say(
            f"  (full Dopri8 vmapped in a large chunk: at least {r['steps_mean']:.0f} steps x 13 right sides x "
            f"13.45 us = {r['steps_mean'] * 13 * 13.45e-3:.0f} ms a member; bench_batch.py's batch-first Eq. (1))"
        )
    results["setting"] = dict(form=form, solver=solver_name, tol=tol)

    chunk = min(ARGS.chunk, n)
    chunk += -chunk % max(ARGS.devices, 1)
    padded = np.concatenate([factors, np.repeat(factors[-1:], -n % chunk, axis=0)])
    say(
        f"\n[jaxtree] {n} members, {form} {solver_name} at {tol:g}, chunks of {chunk}"
        + (f" ({len(padded) - n} padding members in the last)" if len(padded) > n else "")
    )
    modes = [("vmap", "vmapped"), ("sequence", "one after another")]
    if ARGS.devices > 1 and jax.device_count() >= ARGS.devices:
        modes.append(("devices", f"one after another on {ARGS.devices} host devices"))
    solver = runners[(form, solver_name, "sequence")].solver
    sim_kw = dict(y0=flex.state, saveat=flex.ts, rtol=tol, atol=tol, solver=solver)
    if form == "hybrid":
        single = lambda: jaxtree.simulate_hybrid(flex.hm0, FLEX_T1, truncation_error=False, **sim_kw)
    else:
        single = lambda: jaxtree.simulate(flex.model, FLEX_T1, **sim_kw)
    sol, first, once = timed(single, 3)
    say(
        f"  a single run of the nominal member (jitted call): first {first:.1f} s, then {1e3 * once:.1f} ms "
        f"(median of 3); {int(sol.stats['num_accepted_steps'])} steps"
    )
    rows = {"single": dict(first_s=first, ms_a_member=1e3 * once, members_per_s=1.0 / once)}
    for mode, label in modes:
        run = runner(form, solver_name, mode)
        t = time.perf_counter()
        run(padded[:chunk], tol)
        first = time.perf_counter() - t
        tb = tr = 0.0
        counts, first_w, first_g = [], None, None
        t = time.perf_counter()
        for c in range(0, len(padded), chunk):
            w, g, cn, b, r = run(padded[c : c + chunk], tol)
            tb, tr = tb + b, tr + r
            counts.append(cn)
            if c == 0:
                first_w, first_g = w[:m], g[:m]
        wall = time.perf_counter() - t
        counts = np.concatenate(counts)[:n]
        steps = counts[:, 0]
        e = flex_errors(first_w, first_g, ref, S)
        rows[mode] = dict(
            label=label,
            first_chunk_s=first,
            wall_s=wall,
            build_s=tb,
            integrate_s=tr,
            members_per_s=n / wall,
            ms_a_member=1e3 * wall / n,
            steps_mean=float(steps.mean()),
            steps_max=int(steps.max()),
            jacobians_mean=float(counts[:, 1].mean()),
            factorizations_mean=float(counts[:, 2].mean()),
            hub=e[0],
            wings=e[1],
        )
        say(
            f"  {label:40s} first chunk (compile + run) {first:6.1f} s; campaign {wall:6.1f} s = {n / wall:6.1f} "
            f"members/s ({1e3 * wall / n:.1f} ms a member: models {1e3 * tb / n:.1f}, integration "
            f"{1e3 * tr / n:.1f}); steps mean {steps.mean():.1f} max {steps.max()}"
            + (
                f", Jacobians {counts[:, 1].mean():.1f}, factorizations {counts[:, 2].mean():.1f} a member"
                if counts[0, 1] >= 0
                else ""
            )
            + f"; subsample error hub {e[0]:.1e} wings {e[1]:.1e}"
        )
    results["jaxtree"] = rows
    best_mode = max((k for k in rows if k != "single"), key=lambda k: rows[k]["members_per_s"])
    best_rate = rows[best_mode]["members_per_s"]

    if pinocchio is None or ARGS.no_peer:
        if ARGS.json:
            write_json(ARGS.json, results)
        return
    flex_peer_setup(flex)
    say(f"\n[peer] Pinocchio ABA + scipy Radau on the {m} members (one process)")
    peer_tol = None
    for tol_p in sorted(ARGS.tols, reverse=True):
        hist, wall, nfev, njev = flex_peer(sub, tol_p, 1, keep=True)
        e = flex_errors(hist[0], hist[1], ref, S)
        say(
            f"  rtol = atol = {tol_p:g}: hub {e[0]:.2e}, wings {e[1]:.2e}{' (meets)' if flex_meets(e) else ''}, "
            f"{nfev / m:.0f} right sides ({njev / m:.1f} Jacobians) a member, {1e3 * wall / m:.1f} ms a member"
        )
        if flex_meets(e):
            peer_tol = tol_p
            break
    if peer_tol is None:
        say("  the peer meets the goal at no tolerance of the ladder")
        return
    say(f"  {n} members, rtol = atol = {peer_tol:g}, two processes")
    _, wall, nfev, njev = flex_peer(factors, peer_tol, 2)
    say(
        f"  {wall:.1f} s = {n / wall:.1f} members/s ({1e3 * wall / n:.1f} ms a member), {nfev / n:.0f} right sides a member"
    )
    results["peer"] = dict(tol=peer_tol, wall_s=wall, members_per_s=n / wall, rhs_a_member=nfev / n)
    ratio = best_rate / (n / wall)
    results["ratio"] = ratio
    say(
        f"\n[goal] jaxtree best ({rows[best_mode]['label']}, {form} {solver_name} {tol:g}) {best_rate:.1f} members/s "
        f"against Pinocchio + scipy Radau's {n / wall:.1f} in two processes: {ratio:.2f}x "
        f"(goal >= {FLEX_GOAL:g}x): {'met' if ratio >= FLEX_GOAL else 'NOT met'}"
    )
    say("load average at the end: " + " ".join(f"{x:.1f}" for x in os.getloadavg()))
    if ARGS.json:
        write_json(ARGS.json, results)


def main():
    if ARGS.scene == "flex95":
        main_flex()
    else:
        main_fig4()


if __name__ == "__main__":
    main()
