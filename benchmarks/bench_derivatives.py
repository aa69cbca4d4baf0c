#!/usr/bin/env python3
"""Benchmark of the derivatives of Eq. (1)'s accelerations (a benchmark, not a test).

For each tree: the Jacobian of the accelerations with respect to (omega0, gamma, gamma_dot) by
``jax.jacfwd``, (a) through the implicit-function rule (jaxtree's path:
``jaxtree._src.equations.dynamics._solve_completed_jvp``) and (b) through the operations of the plain solve
(``_solve_plain``, what jacfwd did before the rule), one VJP of the accelerations, and one
forward call; each in a jitted ``fori_loop`` of N calls (per-call time, compile time apart).
The peer in the same run: Pinocchio's ``computeABADerivatives`` and ``aba`` on the same tree
(free-flyer base, revolute hinges; ``jaxtree.bench.peers.pinocchio_model``). Goals:
Jacobian <= 3x Pinocchio's derivatives on panels95, chain50 and random 60-body trees; VJP <= 3x
one forward call.

Run:  python benchmarks/bench_derivatives.py [--scenes fig4_free chain50 panels95 random60] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", default=["fig4_free", "chain50", "panels95", "flex95", "random60"])
    p.add_argument("--loop", type=int, default=50, help="calls per jitted loop")
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--json")
    return p.parse_args()


ARGS = _args()
from _common import use_fast_cpu_flags

use_fast_cpu_flags()

import jax
import jax.numpy as jnp
import numpy as np

import jaxtree
from jaxtree._src.equations import dynamics

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
from _common import machine, write_json
from _peers import pinocchio_model
from trees import deep_and_wide, random_tree


def say(*a):
    print(*a, flush=True)


def loop_time(fn, args):
    """(microseconds per call, compile seconds) of `fn(*args)` in a jitted fori_loop of
    ARGS.loop calls, the arguments shifted by the loop index so that nothing is hoisted."""

    @jax.jit
    def loop(args):
        def body(i, c):
            a = jax.tree_util.tree_map(lambda x: x + i * 1e-12, args)
            return c + sum(jnp.sum(o) for o in jax.tree_util.tree_leaves(fn(*a)))

        return jax.lax.fori_loop(0, ARGS.loop, body, 0.0)

    t = time.perf_counter()
    jax.block_until_ready(loop(args))
    first = time.perf_counter() - t
    runs = []
    for _ in range(ARGS.repeats):
        t = time.perf_counter()
        jax.block_until_ready(loop(args))
        runs.append(time.perf_counter() - t)
    return statistics.median(runs) / ARGS.loop * 1e6, first


def pinocchio_times(model, state):
    """(computeABADerivatives, aba) in microseconds per call, or None without Pinocchio."""
    try:
        import pinocchio as pin  # pyright: ignore[reportMissingImports]
    except ImportError:
        return None
    pm, _, iq, iv, _ = pinocchio_model(model)
    data = pm.createData()
    q = pin.neutral(pm)
    q[iq] = np.asarray(state.gamma)
    v = np.zeros(pm.nv)
    v[3:6], v[iv] = np.asarray(state.omega0), np.asarray(state.gamma_dot)
    tau = np.zeros(pm.nv)
    out = []
    for fn in (pin.computeABADerivatives, pin.aba):
        fn(pm, data, q, v, tau)
        runs = []
        for _ in range(ARGS.repeats):
            t = time.perf_counter()
            for _ in range(200):
                fn(pm, data, q, v, tau)
            runs.append((time.perf_counter() - t) / 200)
        out.append(statistics.median(runs) * 1e6)
    return tuple(out)


def tree(name):
    if name.startswith("random"):
        rng = np.random.default_rng(60)
        return random_tree(rng, deep_and_wide(rng, int(name[6:]) - 1))
    return jaxtree.load_scene(name)


def one(name):
    model = tree(name)
    rng = np.random.default_rng(1)
    state = jaxtree.State(
        model.initial.dcm,
        jnp.asarray(rng.normal(size=3) * 0.3),
        jnp.asarray(rng.uniform(-0.5, 0.5, model.n)),
        jnp.asarray(rng.normal(size=model.n) * 0.3),
    )

    def acc(w, g, gd):
        a = dynamics.solve_unchecked(model, jaxtree.State(state.dcm, w, g, gd), 0.0, None)
        return a.omega0_dot, a.gamma_ddot

    def acc_plain(w, g, gd):
        s = jaxtree.State(state.dcm, w, g, gd)
        a = dynamics._solve_plain(model, s, jnp.asarray(0.0), None, None)
        return a.omega0_dot, a.gamma_ddot

    cot = (jnp.ones(3), jnp.ones(model.n))

    def vjp(w, g, gd):
        return jax.vjp(acc, w, g, gd)[1](cot)

    args = (state.omega0, state.gamma, state.gamma_dot)
    row = {"scene": name, "n": model.n, "method": jaxtree.resolve_method(model)}
    for key, fn in (
        ("call", acc),
        ("jacobian_rule", jax.jacfwd(acc, argnums=(0, 1, 2))),
        ("jacobian_plain", jax.jacfwd(acc_plain, argnums=(0, 1, 2))),
        ("vjp", vjp),
    ):
        row[key + "_us"], row[key + "_compile_s"] = loop_time(fn, args)
    pin = pinocchio_times(model, state)
    if pin is not None:
        row["pinocchio_derivatives_us"], row["pinocchio_aba_us"] = pin
    return row


def main():
    say(f"# bench_derivatives: {machine()}")
    say(f"# per call in a jitted fori_loop of {ARGS.loop} calls, median of {ARGS.repeats}; compile apart")
    say(
        f"{'scene':10s} {'n':>4s} {'method':11s} {'call':>8s} {'jac rule':>9s} {'x call':>7s} {'jac plain':>10s} "
        f"{'vjp':>8s} {'x call':>7s} {'pin deriv':>10s} {'pin aba':>8s} {'rule/pin':>9s} {'compile rule':>13s}"
    )
    rows = []
    for name in ARGS.scenes:
        r = one(name)
        rows.append(r)
        pin = r.get("pinocchio_derivatives_us", float("nan"))
        say(
            f"{r['scene']:10s} {r['n']:4d} {r['method']:11s} {r['call_us']:8.1f} {r['jacobian_rule_us']:9.1f} "
            f"{r['jacobian_rule_us'] / r['call_us']:7.1f} {r['jacobian_plain_us']:10.1f} {r['vjp_us']:8.1f} "
            f"{r['vjp_us'] / r['call_us']:7.1f} {pin:10.1f} {r.get('pinocchio_aba_us', float('nan')):8.1f} "
            f"{r['jacobian_rule_us'] / pin:9.2f} {r['jacobian_rule_compile_s']:12.1f}s"
        )
    if ARGS.json:
        write_json(ARGS.json, {"machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()
