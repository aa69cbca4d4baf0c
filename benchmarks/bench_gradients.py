#!/usr/bin/env python3
"""Benchmark of reverse-mode gradients through `jaxtree.simulate` (a benchmark, not a test).

fig4_free (with damping 0.05 N m s/rad on the sprung hinges), a loss over the whole trajectory
(a weighted sum of omega0, gamma, gamma_dot, energy and angular momentum at 101 save times),
its gradient with respect to every array leaf of the model (``jax.grad``, diffrax's default
``RecursiveCheckpointAdjoint``). For a 10 s and a 100 s flight at the default tolerance
(rtol = atol = 1e-9): compile time apart, run time of the loss and of its gradient (median of
a few calls), their ratio (goal <= 5), and memory: XLA's static allocation of each compiled
program (``memory_analysis``: arguments, outputs and temporaries, which hold the checkpoints)
for the default number of checkpoints and for fewer. Then where the time goes: one evaluation
of the right side of Eq. (1) against its VJP and its JVP, in a jitted loop.

Run:  python benchmarks/bench_gradients.py [--horizons 10 100] [--checkpoints 64 16] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--horizons", type=float, nargs="+", default=[10.0, 100.0])
    p.add_argument("--checkpoints", type=int, nargs="*", default=[64])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json")
    return p.parse_args()


ARGS = _args()
from _common import use_fast_cpu_flags

use_fast_cpu_flags()

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import machine, write_json

SAVES = 101


def say(*a):
    print(*a, flush=True)


def timed(fn, *args, repeats):
    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t
    runs = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - t)
    return out, first, statistics.median(runs)


def memory(fn, *args):
    """MiB of XLA's static allocation of the compiled program (arguments + outputs + temporaries)."""
    m = jax.jit(fn).lower(*args).compile().memory_analysis()
    if m is None:
        return float("nan"), float("nan")
    total = m.argument_size_in_bytes + m.output_size_in_bytes + m.temp_size_in_bytes
    return total / 2**20, m.temp_size_in_bytes / 2**20


def main():
    results = {"machine": machine()}
    say(results["machine"])
    model = jaxtree.load_scene("fig4_free")
    sprung = np.asarray(model.sprung) - 1
    model = eqx.tree_at(lambda m: m.damping, model, model.damping.at[sprung].set(0.05))
    params, static = eqx.partition(model, eqx.is_inexact_array)
    rng = np.random.default_rng(0)
    W = {
        k: rng.standard_normal(s)
        for k, s in [
            ("omega0", (SAVES, 3)),
            ("gamma", (SAVES, 10)),
            ("gamma_dot", (SAVES, 10)),
            ("energy", (SAVES,)),
            ("angular_momentum", (SAVES, 3)),
        ]
    }

    for T in ARGS.horizons:

        def loss(p, adjoint=None):
            sol = jaxtree.simulate(eqx.combine(p, static), T, saveat=SAVES, adjoint=adjoint)
            return sum(jnp.sum(W[k] * getattr(sol, k)) for k in W), sol.stats["num_steps"]

        fwd = jax.jit(lambda p: loss(p)[0])
        steps = int(jax.jit(lambda p: loss(p)[1])(params))
        _, f_first, f_run = timed(fwd, params, repeats=ARGS.repeats)
        say(
            f"\n[{T:g} s] {steps} steps; loss: first call {f_first:.2f} s, run {f_run * 1e3:.1f} ms; "
            f"memory {memory(lambda p: loss(p)[0], params)[0]:.2f} MiB"
        )
        row = {"steps": steps, "forward_s": f_run, "forward_first_s": f_first, "gradient": {}}
        for checkpoints in [None] + list(ARGS.checkpoints):
            adjoint = dfx.RecursiveCheckpointAdjoint(checkpoints=checkpoints)
            g = jax.jit(jax.grad(lambda p: loss(p, adjoint)[0]))
            out, g_first, g_run = timed(g, params, repeats=ARGS.repeats)
            finite = all(bool(np.all(np.isfinite(np.asarray(x)))) for x in jax.tree_util.tree_leaves(out))
            total, temp = memory(jax.grad(lambda p: loss(p, adjoint)[0]), params)
            label = "default (sqrt(2 max_steps) = 631)" if checkpoints is None else str(checkpoints)
            say(
                f"  gradient, checkpoints {label}: first call {g_first:.1f} s, run {g_run * 1e3:.1f} ms = "
                f"{g_run / f_run:.1f}x the loss (goal <= 5x); memory {total:.2f} MiB (temporaries {temp:.2f}); "
                f"finite {finite}"
            )
            row["gradient"][label] = {
                "run_s": g_run,
                "first_s": g_first,
                "ratio": g_run / f_run,
                "memory_mib": total,
                "temp_mib": temp,
            }
        results[f"T={T:g}"] = row

    say("\n[where the time goes] one right side of Eq. (1) for fig4_free, in a jitted loop of 2000")
    from jaxtree._src.equations.attitude import Quaternion
    from jaxtree._src.integration.problem import Problem

    prob = Problem(model, Quaternion(), None, None, None, False, 0)
    y = prob.pack(model.initial)
    N = 2000

    def loop(body):
        return eqx.filter_jit(
            lambda prob, y: jax.lax.fori_loop(0, N, lambda i, c: body(prob, y + c, c), jnp.zeros_like(y))
        )

    f = loop(lambda prob, y, c: c + 1e-9 * prob.vector_field(0.0, y))
    vjp = loop(lambda prob, y, c: c + 1e-9 * jax.vjp(lambda p, yy: p.vector_field(0.0, yy), prob, y)[1](y)[1])
    jvp = loop(lambda prob, y, c: c + 1e-9 * jax.jvp(lambda yy: prob.vector_field(0.0, yy), (y,), (y,))[1])
    per = {}
    for name, fn in (("f", f), ("vjp", vjp), ("jvp", jvp)):
        _, first, run = timed(fn, prob, y, repeats=ARGS.repeats)
        per[name] = run / N
        say(f"  {name:4s} compile {first - run:.1f} s, {run / N * 1e6:.2f} us per evaluation")
    say(f"  VJP / f = {per['vjp'] / per['f']:.1f}, JVP / f = {per['jvp'] / per['f']:.1f}")
    results["rhs_us"] = {k: v * 1e6 for k, v in per.items()}
    if ARGS.json:
        write_json(ARGS.json, results)


if __name__ == "__main__":
    main()
