"""A notebook's first cells: eager calls (outside any `jax.jit`) in a fresh process.

Builds a beam and a plate, their appendages (one with `n_modes="auto"`), and evaluates Eq. (1)
and the energy of `wings`, each step timed on its first call in a fresh process with JAX's
persistent cache off (`JAXTREE_CACHE_DIR=0`): what a new user waits for. The peer, in the same
run, is the same process under `jax.disable_jit()`: JAX runs every operation on its own, compiling
each the first time it meets its shapes (how jaxtree's eager calls ran before they became one
program each; `jax.disable_jit` also takes jaxtree's own build programs apart, so the peer is a
little slower than that code was). The processes alternate; the best of `--repeats` per step.

    python benchmarks/bench_first_calls.py [--repeats 2]
"""

import argparse
import json
import os
import subprocess
import sys

from _common import machine, write_json

STEPS = ("beam", "plate", "appendage auto", "appendage 4", "plate appendage", "solve_accelerations", "energy")

_CHILD = r"""
import contextlib, json, sys, time
import jax
import jaxtree

ctx = jax.disable_jit() if sys.argv[1] == "op by op" else contextlib.nullcontext()
out = {}


def step(name, fn):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    out[name] = time.perf_counter() - t0


with ctx:
    jax.block_until_ready(jax.numpy.zeros(3) + 1.0)  # the backend started, outside the timings
    fe = {}
    step("beam", lambda: fe.setdefault("beam", jaxtree.beam(2.0, 10, E=7e10, rho=2700.0, area=1e-4, Iy=1e-8)).mass)
    step("plate", lambda: fe.setdefault("plate", jaxtree.plate(1.0, 0.5, 4, 2, E=7e10, rho=2700.0, thickness=1e-3)).mass)
    step("appendage auto", lambda: jaxtree.appendage(fe["beam"], 0, n_modes="auto").terms.A0)
    step("appendage 4", lambda: jaxtree.appendage(fe["beam"], 0, n_modes=4).terms.A0)
    edge = jaxtree.plate_edge(4, 2)
    step("plate appendage", lambda: jaxtree.appendage(fe["plate"], 0, interface=edge, n_modes=3).terms.A0)
    model = jaxtree.load_scene("wings")
    s = model.initial
    step("solve_accelerations", lambda: jaxtree.solve_accelerations(model, s).gamma_ddot)
    step("energy", lambda: (jaxtree.kinetic_energy(model, s), jaxtree.angular_momentum(model, s)))
print(json.dumps(out))
"""


def run(mode: str) -> dict:
    env = dict(os.environ, JAXTREE_CACHE_DIR="0")
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, mode], env=env, capture_output=True, text=True, check=True, timeout=900
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "bench_first_calls.json"))
    args = parser.parse_args()
    modes = ("one program", "op by op")
    best = {m: {} for m in modes}
    for _ in range(args.repeats):
        for mode in modes:
            for k, v in run(mode).items():
                best[mode][k] = min(v, best[mode].get(k, float("inf")))
    print(machine())
    print("first calls in a fresh process, s (best of", args.repeats, "processes each; persistent cache off)")
    print(f"{'step':22s} {'one program':>12s} {'op by op':>10s}")
    for k in STEPS:
        print(f"{k:22s} {best['one program'][k]:12.2f} {best['op by op'][k]:10.2f}")
    totals = {m: sum(best[m].values()) for m in modes}
    print(f"{'total':22s} {totals['one program']:12.2f} {totals['op by op']:10.2f}")
    write_json(args.out, {"machine": machine(), "best": best, "totals": totals})


if __name__ == "__main__":
    main()
