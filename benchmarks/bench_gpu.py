#!/usr/bin/env python3
"""The batch on an accelerator: Eq. (1) of fig4_free and flex95 in batches up to 65 536 members,
float64 and float32, through the single-member solve vmapped and through the batch-first
recursion; MJX on the same card; the fig4_free campaign. A benchmark, not a test; it runs on a
CPU too (``--quick``), where it checks itself.

It prints, for the default JAX backend:

- the machine line and the devices;
- ``forward``: Eq. (1) (its accelerations) over a batch of random states, by method: ``vmap
  single`` (the single-member solve batched by ``vmap``, ``solve.solve_one``: the engine's path
  on a GPU below ``BATCH_FIRST_MIN_ACCELERATOR``), ``batch-first/<stage>`` (the recursion of
  ``jaxtree._src.equations.batched`` with the members as the contiguous axis, its stages cut as
  ``none`` or ``barrier``: ``solve.batch_first``); compile time (``lower`` + ``compile``) apart from the run time (median of
  repeated calls), ns per member, XLA's flop count per member and the GFLOP/s reached, and the
  largest deviation from the float64 ``vmap single`` accelerations (relative to their largest
  magnitude): round-off for float64, the float32 error for float32;
- ``MJX``: ``mujoco.mjx.step`` (RK4, the jax implementation) vmapped over the same batch sizes,
  per member and right side (a step is four), float32 and float64, where ``mujoco.mjx`` imports;
- ``campaign``: 1000 fig4_free runs of 10 s through :func:`jaxtree.monte_carlo` in one chunk
  (the members of bench_campaign.py), float64 at rtol = atol = 1e-7 and at a fixed step of
  0.02 s (Dopri8), float32 at its default tolerance: wall time (first call, with compilation,
  apart) and the error of a subsample against rtol = atol = 1e-12.

The sections run in the order of their value and stop when ``--budget`` seconds have passed
(a lent device is held for minutes; compilation takes most of it); after each row the figures are
written to ``--json``. Order: both paths at 65 536 members (fig4_free, then flex95; every stage
mode in float64, the fastest in float32), MJX fig4_free at 65 536, the campaign, MJX flex95 at
8192, then the smaller batches. ``--rest`` runs what a first call's budget left out: the campaign
through the batch-first path, then the smaller batches.

Run:  python benchmarks/bench_gpu.py [--quick] [--rest] [--budget 420] [--json results/bench_gpu.json]
(on a GPU machine without an install: ``PYTHONPATH=src``; MJX from the ``mujoco-mjx`` wheel whose
version matches ``mujoco``'s). Figures of 2026-11-27, NVIDIA H200: results/bench_gpu.txt.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

import jaxtree
from jaxtree._src.equations import solve

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import dispersed_fig4, machine, timed, write_json

T1, SAVES = 10.0, 101
START = time.perf_counter()


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="small batches, few repetitions (a CPU check)")
    p.add_argument("--budget", type=float, default=420.0, help="seconds after which no new row starts")
    p.add_argument("--runs", type=int, default=1000, help="members of the campaign")
    p.add_argument(
        "--rest", action="store_true", help="the campaign with the batch-first path, then the smaller batches"
    )
    p.add_argument("--json", help="write the figures to this JSON file (atomically, after each row)")
    return p.parse_args()


ARGS = _args()
RESULTS: dict = {"machine": machine(), "backend": jax.default_backend(), "forward": [], "mjx": [], "campaign": []}


def say(*a):
    print(f"[{time.perf_counter() - START:6.1f} s]", *a, flush=True)


def save():
    if ARGS.json:
        write_json(ARGS.json, RESULTS)


def over_budget(what):
    if time.perf_counter() - START > ARGS.budget:
        say(f"  budget of {ARGS.budget:g} s spent: {what} skipped")
        return True
    return False


# ------------------------------------------------------------------------------------- forward
def method(model, how):
    """Eq. (1)'s accelerations of a batch ``(omega0, gamma, gamma_dot)`` by `how`: "vmap single"
    or "batch-first/<stage>" (each path called explicitly, whatever the batch's size)."""
    dcm = model.initial.dcm
    if how == "vmap single":
        one = lambda w, g, gd: solve.solve_one(model, jaxtree.State(dcm, w, g, gd), 0.0, None, None)
        return jax.vmap(one)
    stages = how.split("/")[1]

    def batch(w, g, gd):
        dcms = jnp.broadcast_to(dcm, (w.shape[0], 3, 3))
        return solve.batch_first(model, jaxtree.State(dcms, w, g, gd), 0.0, stages=stages)

    return batch


def states(model, size, seed=0):
    rng = np.random.default_rng(seed)
    return (
        0.2 * rng.normal(size=(size, 3)),
        0.3 * rng.normal(size=(size, model.n)),
        0.3 * rng.normal(size=(size, model.n)),
    )


def flat(out):
    return np.concatenate([np.asarray(x, np.float64) for x in out], 1)


REFERENCE: dict = {}  # (scene, size) -> float64 accelerations of vmap single


def forward(name, size, dtype, how, repeats):
    """One row: Eq. (1) of scene `name` for `size` random states by `how` in `dtype`."""
    m64 = jaxtree.load_scene(name)
    model = m64 if dtype == "float64" else m64.astype(jnp.float32)
    host = states(m64, size)
    args = tuple(jnp.asarray(a, dtype) for a in host)
    fn = jax.jit(method(model, how))
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    fl = float((cost or {}).get("flops", np.nan)) / size
    out, _, run = timed(lambda: compiled(*args), repeats)
    a = flat(out)
    key = (name, size)
    if how == "vmap single" and dtype == "float64":
        REFERENCE[key] = a
    ref = REFERENCE.get(key)
    dev = float(np.max(np.abs(a - ref)) / np.max(np.abs(ref))) if ref is not None else np.nan
    ns = run / size * 1e9
    row = dict(
        scene=name,
        n=m64.n,
        dtype=dtype,
        batch=size,
        method=how,
        compile_s=compile_s,
        batch_s=run,
        ns_per_member=ns,
        kflop_per_member=fl / 1e3,
        gflops=fl / ns,
        deviation=dev,
        nonfinite=int(np.sum(~np.isfinite(a))),
    )
    RESULTS["forward"].append(row)
    save()
    say(
        f"  {name:9s} {dtype:7s} B={size:6d} {how:20s} compile {compile_s:6.1f} s  {run * 1e3:9.3f} ms  "
        f"{ns:9.1f} ns/member  {fl / 1e3:7.1f} kflop  {fl / ns:7.1f} GFLOP/s  dev {dev:.1e}"
        + (f"  NON-FINITE {row['nonfinite']}" if row["nonfinite"] else "")
    )
    return row


def forward_largest(name, size, modes, repeats):
    """vmap single and the batch-first stage `modes` at batch `size` in float64, then the faster
    path of each kind in float32; returns the fastest batch-first method."""
    say(f"Eq. (1) of {name}, {size} random states")
    rows = {}
    for how in ["vmap single", *[f"batch-first/{m}" for m in modes]]:
        if over_budget(f"{name} {how}"):
            return None
        rows[how] = forward(name, size, "float64", how, repeats)
    best = min((r for k, r in rows.items() if k != "vmap single"), key=lambda r: r["batch_s"])["method"]
    for how in ("vmap single", best):
        if over_budget(f"{name} float32 {how}"):
            return best
        forward(name, size, "float32", how, repeats)
    return best


def forward_sweep(name, sizes, best, repeats):
    """Both paths at the smaller batch sizes, float64 then float32."""
    say(f"Eq. (1) of {name}, smaller batches")
    for dtype in ("float64", "float32"):
        for size in sizes:
            for how in ("vmap single", best):
                if over_budget(f"{name} {dtype} B={size} {how}"):
                    return
                forward(name, size, dtype, how, repeats)


# ------------------------------------------------------------------------------------------ MJX
def mjx_scene(name, sizes, repeats):
    try:
        import mujoco  # pyright: ignore[reportMissingImports]
        from mujoco import mjx  # pyright: ignore[reportMissingImports]

        from jaxtree.bench.peers import mjcf
    except ImportError as e:
        say(f"  MJX not available ({e}): skipped")
        return
    model = jaxtree.load_scene(name)
    xml, _ = mjcf(model, timestep=1e-3, integrator="RK4", springs=True)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_resetData(m, d)
    for dtype in ("float32", "float64"):
        # MJX takes its precision from JAX's: float32 with 64-bit types off
        with jax.enable_x64(dtype == "float64"):
            for size in sorted(sizes, reverse=True):
                if over_budget(f"MJX {name} {dtype} B={size}"):
                    return
                mjx_row(mjx, m, d, name, dtype, size, repeats)


def mjx_row(mjx, m, d, name, dtype, size, repeats):
    mx = mjx.put_model(m, impl="jax")
    dx = mjx.put_data(m, d, impl="jax")
    rng = np.random.default_rng(0)
    qvel = jnp.asarray(0.1 * rng.normal(size=(size, m.nv)), dtype)
    qpos = jnp.broadcast_to(dx.qpos, (size, m.nq))
    step = jax.jit(jax.vmap(lambda q, v: mjx.step(mx, dx.replace(qpos=q, qvel=v)).qvel))
    t0 = time.perf_counter()
    compiled = step.lower(qpos, qvel).compile()
    compile_s = time.perf_counter() - t0
    out, _, run = timed(lambda: compiled(qpos, qvel), repeats)
    ns = run / size / 4 * 1e9
    row = dict(
        scene=name,
        dtype=dtype,
        precision=str(out.dtype),
        batch=size,
        compile_s=compile_s,
        step_s=run,
        ns_per_member_rhs=ns,
        finite=bool(np.all(np.isfinite(np.asarray(out)))),
    )
    RESULTS["mjx"].append(row)
    save()
    say(
        f"  MJX {name:9s} {str(out.dtype):7s} B={size:6d} RK4 step compile {compile_s:6.1f} s  {run * 1e3:9.3f} ms  "
        f"{ns:9.1f} ns/member/rhs" + ("" if row["finite"] else "  NON-FINITE")
    )


# ------------------------------------------------------------------------------------- campaign
def campaign(n, quick):
    model = jaxtree.load_scene("fig4_free")
    sub = 8

    def run(model, size, **kw):
        kw.setdefault("chunk_size", size)
        return jaxtree.monte_carlo(
            model, dispersed_fig4, size, T1, key=jax.random.key(0), saveat=SAVES, progress=False, **kw
        )

    def err(ds, ref):
        w = np.abs(ds.omega0.values[:sub] - ref.omega0.values).max(axis=(1, 2))
        g = np.abs(ds.gamma.values[:sub] - ref.gamma.values).max(axis=(1, 2))
        return float(np.max(np.maximum(w, g)))

    say(f"campaign: {n} fig4_free runs of {T1:g} s in one chunk (members of bench_campaign.py)")
    if over_budget("campaign reference"):
        return
    t0 = time.perf_counter()
    ref = run(model, sub, rtol=1e-12, atol=1e-12)
    say(f"  reference: {sub} members at rtol = atol = 1e-12 in {time.perf_counter() - t0:.1f} s")
    variants = [
        ("float64 rtol 1e-7", model, dict(rtol=1e-7, atol=1e-7)),
        ("float64 dt 0.02", model, dict(dt=0.02)),
        ("float32 default tol", model.astype(jnp.float32), {}),
    ]
    for label, m, kw in variants:
        if over_budget(f"campaign {label}"):
            return
        t0 = time.perf_counter()
        run(m, n, **kw)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        ds = run(m, n, **kw)
        wall = time.perf_counter() - t0
        e = err(ds, ref)
        ok = int((ds.status.values == "successful").sum())
        row = dict(
            variant=label,
            runs=n,
            first_s=first,
            wall_s=wall,
            runs_per_s=n / wall,
            error=e,
            successful=ok,
            steps_max=int(ds.steps.values.max()),
        )
        RESULTS["campaign"].append(row)
        save()
        say(
            f"  {label:20s} first call {first:6.1f} s; campaign {wall:7.2f} s: {n / wall:8.1f} runs/s; "
            f"error {e:.1e} (first {sub} members); steps max {row['steps_max']}; {ok}/{n} successful"
        )


def main():
    say(RESULTS["machine"])
    RESULTS["devices"] = [f"{d} ({d.device_kind})" for d in jax.devices()]
    say("devices: " + ", ".join(RESULTS["devices"]))
    quick = ARGS.quick
    big, small = (512, (128,)) if quick else (65536, (1024, 8192))
    repeats = 3 if quick else 5
    if ARGS.rest:
        campaign(ARGS.runs, quick)
        forward_sweep("fig4_free", small, "batch-first/none", repeats)
        forward_sweep("flex95", small, "batch-first/none", repeats)
        say("done")
        return
    best4 = forward_largest("fig4_free", big, ("none", "barrier"), repeats) or "batch-first/barrier"
    # flex95 written as one expression ("none") was ten times the flops on a CPU: the barrier, and
    # fig4_free's fastest mode if it is another
    modes95 = tuple(dict.fromkeys(("barrier", best4.split("/")[1])))
    best95 = forward_largest("flex95", big, modes95, repeats) or "batch-first/barrier"
    mjx_scene("fig4_free", (big,), repeats)
    campaign(64 if quick else ARGS.runs, quick)
    mjx_scene("flex95", (small[-1],), repeats)
    forward_sweep("fig4_free", small, best4, repeats)
    forward_sweep("flex95", small, best95, repeats)
    mjx_scene("fig4_free", small, repeats)
    say("done")


if __name__ == "__main__":
    main()
