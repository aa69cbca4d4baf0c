"""Benchmark: how Eq. (1) is solved at scale -- the dense and the articulated methods against
Pinocchio's ABA, on chains of 10 to 200 segments and on panels95, in one run.

For each tree and method it prints one evaluation of Eq. (1) (``forward_dynamics``) timed inside
a jitted ``lax.fori_loop`` (no per-call dispatch: the cost of the equations themselves) and as one
jitted call from Python (dispatch included), with the compile time of the loop apart; beside it
``pin.aba`` called from Python, and Pinocchio's per-call overhead measured on a one-body model
(``pin.aba`` of a lone free flyer). Then the log-log growth of the in-loop time from 50 to 200
bodies per method, and the compile time of ``simulate`` on chain200 per method.

Goals: in-loop evaluation at chain200 <= 2x ``pin.aba``'s call; growth from 50 to 200
no steeper than n^1.2; ``simulate`` compiles in <= 10 s at chain200.

Run: ``python benchmarks/bench_methods.py [--quick] [--json PATH]``.
"""

from __future__ import annotations

import argparse
import time

from _common import use_fast_cpu_flags

use_fast_cpu_flags()

import jax
import jax.numpy as jnp
import numpy as np
from bench_dynamics import chain_model

import jaxtree

from _common import machine, write_json

CHAINS = (10, 25, 50, 100, 200)


def model_of(name):
    if name.startswith("chain") and name[5:].isdigit() and int(name[5:]) not in (10, 50, 200):
        return chain_model(int(name[5:]))
    return jaxtree.load_scene(name)


def in_loop_us(model, calls, repeats):
    s = model.initial

    def loop(model, s):
        def body(i, acc):
            w, g = jaxtree.forward_dynamics(model, s.dcm, s.omega0, s.gamma + 1e-12 * acc, s.gamma_dot)
            return acc + g

        return jax.lax.fori_loop(0, calls, body, jnp.zeros(model.n))

    f = jax.jit(loop)
    t0 = time.perf_counter()
    jax.block_until_ready(f(model, s))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(f(model, s))
        times.append(time.perf_counter() - t0)
    one = jax.jit(jaxtree.forward_dynamics)
    jax.block_until_ready(one(model, s.dcm, s.omega0, s.gamma, s.gamma_dot))
    single = []
    for _ in range(repeats * 20):
        t0 = time.perf_counter()
        jax.block_until_ready(one(model, s.dcm, s.omega0, s.gamma, s.gamma_dot))
        single.append(time.perf_counter() - t0)
    return 1e6 * min(times) / calls, 1e6 * min(single), compile_s


def pin_us(model, calls, repeats):
    import pinocchio as pin

    import _peers

    pm, _, _, _, _ = _peers.pinocchio_model(model)
    data = pm.createData()
    q, v, tau = pin.neutral(pm), np.full(pm.nv, 0.1), np.zeros(pm.nv)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            pin.aba(pm, data, q, v, tau)
        best = min(best, (time.perf_counter() - t0) / calls)
    return 1e6 * best


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--json")
    args = ap.parse_args()
    print(machine())
    repeats = 3 if args.quick else 7
    names = [f"chain{n}" for n in CHAINS] + ["panels95", "fig4_free"]
    rows = []
    try:
        import pinocchio  # noqa: F401

        one_body = jaxtree.build_model([jaxtree.Body("b", 1.0, np.eye(3))])
        overhead = pin_us(one_body, 2000, repeats)
        print(f"pin.aba per-call floor (a lone free flyer, Python binding included): {overhead:.2f} us")
    except ImportError:
        overhead = None
        print("Pinocchio not installed (pip install -e .[peers]): no peer column")
    print(
        f"\n{'tree':10s} {'n':>4s} {'method':12s} {'in loop':>10s} {'one call':>10s} {'compile':>8s} {'pin.aba':>9s} "
        f"{'ratio':>6s}"
    )
    for name in names:
        model = model_of(name)
        calls = max(50, int(20000 / model.n))
        peer = pin_us(model, max(200, int(20000 / model.n)), repeats) if overhead is not None else None
        for method in ("dense", "articulated"):
            m = model.with_method(method)
            loop_us, one_us, comp = in_loop_us(m, calls, repeats)
            rows.append(
                dict(
                    tree=name,
                    n=model.n,
                    method=method,
                    in_loop_us=loop_us,
                    one_call_us=one_us,
                    compile_s=comp,
                    pin_aba_us=peer,
                )
            )
            ratio = f"{loop_us / peer:6.2f}" if peer else "     -"
            print(
                f"{name:10s} {model.n:4d} {method:12s} {loop_us:9.1f}us {one_us:9.1f}us {comp:7.2f}s "
                f"{(peer or float('nan')):8.1f}us {ratio}",
                flush=True,
            )
    print("\nlog-log growth of the in-loop time from 50 to 200 bodies:")
    for method in ("dense", "articulated"):
        a = next(r for r in rows if r["tree"] == "chain50" and r["method"] == method)
        b = next(r for r in rows if r["tree"] == "chain200" and r["method"] == method)
        slope = np.log(b["in_loop_us"] / a["in_loop_us"]) / np.log(b["n"] / a["n"])
        print(f"  {method:12s} n^{slope:.2f}  (goal <= 1.2)")
    c200 = [r for r in rows if r["tree"] == "chain200"]
    if overhead is not None:
        best = min(c200, key=lambda r: r["in_loop_us"])
        print(
            f"chain200: best in-loop {best['in_loop_us']:.1f} us ({best['method']}) = "
            f"{best['in_loop_us'] / best['pin_aba_us']:.2f} x pin.aba's call (goal <= 2)"
        )
    model = jaxtree.load_scene("chain200")
    for method in ("dense", "articulated"):
        m = model.with_method(method)
        t0 = time.perf_counter()
        jax.block_until_ready(jaxtree.simulate(m, 0.01, saveat=2, rtol=1e-6, atol=1e-6).gamma)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(jaxtree.simulate(m, 0.01, saveat=2, rtol=1e-6, atol=1e-6).gamma)
        again = time.perf_counter() - t0
        print(
            f"simulate on chain200 ({method}): first call {first:.2f} s, again {again:.3f} s: compile ~{first - again:.2f} s "
            "(goal <= 10 s)"
        )
        rows.append(dict(tree="chain200", method=method, simulate_compile_s=first - again))
    if args.json:
        write_json(args.json, dict(machine=machine(), rows=rows))


if __name__ == "__main__":
    main()
