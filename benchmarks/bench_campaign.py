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
  the ratios of throughputs (goals: >= 20x Pinocchio, >= 5x MuJoCo; the batch issue, point 3).

Run:  python benchmarks/bench_campaign.py [--runs 1000] [--chunk 128] [--json results/bench_campaign.json]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

T1, SAVES, GOAL_ERROR = 10.0, 101, 1e-6


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--chunk", type=int, default=128)
    p.add_argument("--subsample", type=int, default=8, help="members whose error is measured")
    p.add_argument("--tols", type=float, nargs="+", default=[1e-6, 3e-7, 1e-7, 3e-8])
    p.add_argument("--dt", type=float, nargs="+", default=[0.02, 0.01], help="fixed steps tried")
    p.add_argument(
        "--mujoco-dt", type=float, nargs="+", default=[0.005, 0.0025, 0.002, 0.00125, 0.001], help="RK4 steps tried"
    )
    p.add_argument("--no-peer", action="store_true")
    p.add_argument("--json")
    return p.parse_args()


ARGS = _args()
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import dispersed_fig4 as sample
from _common import machine, write_json


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


def main():
    results = {"machine": machine(), "runs": ARGS.runs, "t1": T1, "saves": SAVES}
    say(results["machine"])
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
            f"(goal >= 20x): {'met' if ratio >= 20 else 'NOT met'}"
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


if __name__ == "__main__":
    main()
