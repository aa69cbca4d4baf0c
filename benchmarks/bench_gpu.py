#!/usr/bin/env python3
"""Batch throughput of jaxtree on an accelerator (a benchmark, not a test; runs on a CPU too).

The users this targets run vmapped Monte Carlo batches: many states or many initial
conditions at once, in float64 or float32. For the default JAX backend it prints

- the machine line (device kind, versions);
- ``forward_dynamics`` (Eq. 1) vmapped over batches of random states for fig4, chain50,
  panels95 and chain200, in float64 and float32: compile time (``lower`` + ``compile``,
  kept apart), run time per batch (median of repeated calls), throughput (states/s and
  ns/state), and the float32 error: ``max |a32 - a64| / max |a64|`` over the batch, per scene;
- ``simulate`` of fig4_free for 10 s vmapped over batches of initial conditions (random
  body rate and hinge rates): compile time, run time, trajectories per second, the largest
  number of steps in the batch, and in float32 (at its default tolerance,
  ``jaxtree.default_tolerance``: 1e-4) the largest difference of the final (omega0, gamma)
  from the float64 run (rtol = atol = 1e-8).

Batches whose matrices alone would pass ``--max-gib`` are skipped (printed).

Run:  python benchmarks/bench_gpu.py [--quick] [--json results/bench_gpu.json]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import machine, timed, write_json

SCENES = ("fig4", "chain50", "panels95", "chain200")
BATCHES = (1024, 8192, 65536)
SIM_BATCHES = (1, 256, 4096)
SIM_T = 10.0


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="small batches and few repetitions (CPU check)")
    p.add_argument("--scenes", nargs="+", default=list(SCENES))
    p.add_argument("--batches", nargs="+", type=int, default=None)
    p.add_argument("--sim-batches", nargs="+", type=int, default=None)
    p.add_argument("--max-gib", type=float, default=8.0, help="skip batches whose (n+3)^2 matrices exceed this")
    p.add_argument("--json", help="also write the figures to this JSON file (atomically)")
    return p.parse_args()


def say(*a):
    print(*a, flush=True)


def _states(model, batch, seed=0):
    rng = np.random.default_rng(seed)
    n = model.n
    return (
        np.broadcast_to(np.eye(3), (batch, 3, 3)).copy(),
        rng.normal(scale=0.3, size=(batch, 3)),
        rng.normal(scale=0.5, size=(batch, n)),
        rng.normal(scale=0.5, size=(batch, n)),
    )


def bench_forward(scenes, batches, max_gib, repeats):
    say("\nforward_dynamics, vmapped over random states")
    say(
        f"  {'scene':<9} {'dtype':<8} {'batch':>7} {'compile s':>10} {'batch ms':>10} {'ns/state':>10} {'states/s':>11}"
    )
    fd = lambda m, C, w, q, qd: jaxtree.forward_dynamics(m, C, w, q, qd)
    vf = jax.vmap(fd, in_axes=(None, 0, 0, 0, 0))
    rows = []
    for name in scenes:
        m64 = jaxtree.load_scene(name)
        models = {"float64": m64, "float32": m64.astype(jnp.float32)}
        for batch in batches:
            gib = batch * (m64.n + 3) ** 2 * 8 / 2**30
            if gib > max_gib:
                say(f"  {name:<9} {'':<8} {batch:>7}  skipped: matrices alone {gib:.1f} GiB > {max_gib} GiB")
                continue
            host = _states(m64, batch)
            out = {}
            for dtype, model in models.items():
                args = tuple(jnp.asarray(x, dtype) for x in host)
                t0 = time.perf_counter()
                compiled = jax.jit(vf).lower(model, *args).compile()
                compile_s = time.perf_counter() - t0
                _, _, run = timed(lambda: compiled(model, *args), repeats)
                out[dtype] = np.concatenate([np.asarray(a, np.float64) for a in compiled(model, *args)], 1)
                row = dict(
                    scene=name,
                    n=m64.n,
                    dtype=dtype,
                    batch=batch,
                    compile_s=compile_s,
                    batch_s=run,
                    ns_per_state=run / batch * 1e9,
                    states_per_s=batch / run,
                )
                rows.append(row)
                say(
                    f"  {name:<9} {dtype:<8} {batch:>7} {compile_s:>10.2f} {run * 1e3:>10.3f} "
                    f"{row['ns_per_state']:>10.1f} {row['states_per_s']:>11.3g}"
                )
            rows[-1].update(_float32_error(name, m64, host, out["float64"], out["float32"]))
    return rows


def _float32_error(name, model, host, a64, a32, sample=256):
    """Per-state relative error of the float32 accelerations, and the float64 condition numbers
    of Eq. (1)'s matrix on a sample of the states (the error of a Cholesky solve grows with it)."""
    err = np.max(np.abs(a32 - a64), 1) / np.max(np.abs(a64), 1)
    finite = np.isfinite(err)
    k = min(sample, len(err))
    A = jax.jit(jax.vmap(lambda q: jaxtree.mass_matrix(model, q)))(jnp.asarray(host[2][:k]))
    cond = np.linalg.cond(np.asarray(A))
    stats = dict(
        float32_error_median=float(np.median(err[finite])) if finite.any() else float("nan"),
        float32_error_p99=float(np.percentile(err[finite], 99)) if finite.any() else float("nan"),
        float32_nonfinite=int(np.sum(~finite)),
        cond_median=float(np.median(cond)),
        cond_max=float(np.max(cond)),
    )
    say(
        f"  {name:<9} float32: relative error median {stats['float32_error_median']:.1e}, 99th percentile "
        f"{stats['float32_error_p99']:.1e}, non-finite {stats['float32_nonfinite']} of {len(err)}; "
        f"cond(A) median {stats['cond_median']:.1e}, max {stats['cond_max']:.1e} (first {k} states)"
    )
    return stats


def bench_simulate(batches, repeats):
    say(f"\nsimulate fig4_free for {SIM_T:g} s (Dopri8, PI control, 101 saves), vmapped over initial conditions")
    say(f"  {'dtype':<8} {'rtol':>6} {'batch':>6} {'compile s':>10} {'batch s':>9} {'traj/s':>9} {'max steps':>10}")
    m64 = jaxtree.load_scene("fig4_free")
    settings = {"float64": (m64, 1e-8), "float32": (m64.astype(jnp.float32), jaxtree.default_tolerance(jnp.float32))}
    rows = []
    for batch in batches:
        rng = np.random.default_rng(1)
        dw = rng.normal(scale=0.05, size=(batch, 3))
        dg = rng.normal(scale=0.05, size=(batch, m64.n))
        finals = {}
        for dtype, (model, tol) in settings.items():

            def run(dw, dg, model=model, tol=tol):
                y0 = model.initial._replace(omega0=model.initial.omega0 + dw, gamma_dot=model.initial.gamma_dot + dg)
                sol = jaxtree.simulate(model, SIM_T, y0=y0, rtol=tol, atol=tol, throw=False)
                return sol.final.omega0, sol.final.gamma, sol.stats["num_steps"], sol.result._value

            f = jax.jit(jax.vmap(run))
            args = (jnp.asarray(dw, model.mass.dtype), jnp.asarray(dg, model.mass.dtype))
            t0 = time.perf_counter()
            compiled = f.lower(*args).compile()
            compile_s = time.perf_counter() - t0
            say(f"  ({dtype}, batch {batch}: compiled in {compile_s:.1f} s)")
            _, _, t = timed(lambda: compiled(*args), repeats)
            w, g, steps, result = compiled(*args)
            ok = int(np.sum(np.asarray(result) == 0))
            finals[dtype] = np.concatenate([np.asarray(w, np.float64), np.asarray(g, np.float64)], 1)
            row = dict(
                dtype=dtype,
                rtol=tol,
                batch=batch,
                compile_s=compile_s,
                batch_s=t,
                traj_per_s=batch / t,
                max_steps=int(np.max(steps)),
                successful=ok,
            )
            rows.append(row)
            say(
                f"  {dtype:<8} {tol:>6.0e} {batch:>6} {compile_s:>10.2f} {t:>9.3f} {batch / t:>9.3g} "
                f"{row['max_steps']:>10}{'' if ok == batch else f'  ({batch - ok} runs failed)'}"
            )
        diff = float(np.max(np.abs(finals["float32"] - finals["float64"])))
        rows[-1]["float32_final_difference"] = diff
        say(f"  float32 vs float64: largest final |d(omega0, gamma)| = {diff:.2e} (batch {batch})")
    return rows


def main():
    args = _args()
    say(machine())
    say("devices: " + ", ".join(str(d) for d in jax.devices()))
    quick = args.quick
    batches = args.batches or ((256, 1024) if quick else BATCHES)
    sim_batches = args.sim_batches or ((1, 64) if quick else SIM_BATCHES)
    repeats = 3 if quick else 10
    fwd = bench_forward(args.scenes, batches, args.max_gib, repeats) if batches != [0] else []
    sim = bench_simulate(sim_batches, 1) if sim_batches != [0] else []
    if args.json:
        write_json(
            args.json, dict(machine=machine(), backend=jax.default_backend(), forward_dynamics=fwd, simulate=sim)
        )
        say(f"wrote {args.json}")


if __name__ == "__main__":
    main()
