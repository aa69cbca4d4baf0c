#!/usr/bin/env python3
"""Benchmark: stiff hinges and stiff appendages, jaxtree's implicit integrators against Pinocchio +
scipy's Radau in the same run (a benchmark, not a test; its goals).

Cases:
- ``stiff``: ``jaxtree.stiff_chain(1e6)`` (chain10 with a near-rigid, damped tip hinge) over 2 s;
  error: the largest difference of omega0 and gamma from a tight Kvaerno5 run (rtol 1e-11) at 101
  save times; target 1e-6.
- ``flex95``: the slew on the bundled ``flex95`` vehicle (rotor at 10 pi rad/s, the
  scene's spin, a bus torque of (15, 9, 0) N m on at 1 s and off at 3 s with 0.2 s tanh edges,
  10 s); errors: the hub rate relative to its peak and the wing angles relative to theirs,
  against a tight Dopri8 run (rtol 1e-11) at 201 save times; targets hub 1e-3, wings 1e-2.

Each method runs over a ladder of tolerances; the figure is the fastest run that meets the
target (median of repeats, compile time apart). Pinocchio's right side is ``pin.aba`` with the
torque on the free flyer, its Jacobian by forward differences (``jaxtree bench``'s peer,
``jaxtree.bench.peers.pinocchio_runner``).

``--batch N`` runs instead the batch issue's point 5: N stiff chains (``stiff_chain(1e6)``, 2 s,
rtol = atol = 1e-6) with the tip stiffness dispersed by 10 %, vmapped under ``jaxtree.Radau5``,
against single runs of the same members: the batch's time in single runs (goal <= 16 for 64),
each member's steps, Jacobians and factorizations, and the largest difference from its single
run; one member started at a NaN rate must fail alone.

Run:  python benchmarks/bench_stiff.py [--cases stiff flex95] [--batch 64] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", nargs="+", default=["stiff", "flex95"])
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--batch", type=int, default=0, help="run the stiff batch of this many members instead")
    p.add_argument("--json")
    return p.parse_args()


ARGS = _args()
from _common import use_fast_cpu_flags

use_fast_cpu_flags()

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np

import jaxtree
from jaxtree.bench.peers import pinocchio_runner

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import machine, write_json

TORQUE = np.array([15.0, 9.0, 0.0])


def say(*a):
    print(*a, flush=True)


def profile(t):
    return jaxtree.thruster_pulse(t, 1.0, 2.0, 0.2)


def profile_np(t):
    """:func:`profile` in numpy, for the peer's right side (a JAX call per right side would add
    tens of microseconds of dispatch to every Pinocchio evaluation)."""
    return 0.5 * (np.tanh((t - 1.0) / 0.2) - np.tanh((t - 3.0) / 0.2))


def case(name):
    """(model, span, save times, error function from (omega0, gamma), targets, ladder of rtol)."""
    if name == "stiff":
        model, span = jaxtree.stiff_chain(1e6), 2.0
        ts = np.linspace(0.0, span, 101)
        ref = jaxtree.simulate(model, span, saveat=jnp.asarray(ts), solver=dfx.Kvaerno5(), rtol=1e-11, atol=1e-11)
        W, G = np.asarray(ref.omega0), np.asarray(ref.gamma)

        def errors(w, g):
            return (max(np.abs(w - W).max(), np.abs(g - G).max()),)

        return model, span, ts, errors, (1e-6,), (1e-4, 3e-5, 1e-5, 3e-6, 1e-6, 3e-7, 1e-7)
    base = jaxtree.load_scene("flex95")
    model = base.with_loads(jaxtree.BodyTorque(0, jnp.asarray(TORQUE), profile))
    span = 10.0
    ts = np.linspace(0.0, span, 201)
    ref = jaxtree.simulate(model, span, saveat=jnp.asarray(ts), solver=dfx.Dopri8(), rtol=1e-11, atol=1e-11)
    wings = np.asarray([k for k in range(1, model.n + 1) if model.names[k].startswith("wing")]) - 1
    W, G = np.asarray(ref.omega0), np.asarray(ref.gamma)[:, wings]

    def errors(w, g):
        return np.abs(w - W).max() / np.abs(W).max(), np.abs(np.asarray(g)[:, wings] - G).max() / np.abs(G).max()

    return model, span, ts, errors, (1e-3, 1e-2), (1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6)


def jaxtree_run(model, span, ts, solver, rtol):
    def call():
        return jaxtree.simulate(model, span, saveat=jnp.asarray(ts), solver=solver, rtol=rtol, atol=rtol)

    t = time.perf_counter()
    sol = call()
    jax.block_until_ready(sol.gamma)
    first = time.perf_counter() - t
    runs = []
    for _ in range(ARGS.repeats):
        t = time.perf_counter()
        sol = call()
        jax.block_until_ready(sol.gamma)
        runs.append(time.perf_counter() - t)
    st = sol.stats
    work = f"{int(st['num_accepted_steps'])} steps"
    if "jacobians" in st:
        work += f", {int(st['jacobians'])} Jacobians, {int(st['factorizations'])} LU"
    return np.asarray(sol.omega0), np.asarray(sol.gamma), statistics.median(runs), first, work


def pinocchio_run(model, ts, rtol):
    loaded = model.loads is not None
    run = pinocchio_runner(model, ts, base_torque=(lambda t: TORQUE * profile_np(t)) if loaded else None)
    walls = []
    for _ in range(ARGS.repeats):
        w, g, wall, rhs = run("Radau", rtol, rtol)
        walls.append(wall)
    return w, g, statistics.median(walls), 0.0, f"{rhs} right sides (Jacobians by forward differences included)"


def batch(size):
    """The stiff batch: `size` dispersed stiff chains vmapped under Radau5 against single runs."""
    import equinox as eqx

    model, span = jaxtree.stiff_chain(1e6), 2.0
    ts = jnp.linspace(0.0, span, 101)

    def run(k, w0):
        m = eqx.tree_at(
            lambda m: (m.stiffness, m.initial), model, (model.stiffness * k, model.initial._replace(omega0=w0))
        )
        sol = jaxtree.simulate(m, span, saveat=ts, solver=jaxtree.Radau5(), rtol=1e-6, atol=1e-6, throw=False)
        st = sol.stats
        return sol.gamma, sol.failure, st["num_accepted_steps"], st["jacobians"], st["factorizations"]

    rng = np.random.default_rng(0)
    ks = jnp.asarray(1 + 0.1 * rng.standard_normal(size))
    w0 = jnp.broadcast_to(model.initial.omega0, (size, 3)).at[size - 1, 0].set(jnp.nan)  # the last member fails
    single, many = jax.jit(run), jax.jit(jax.vmap(run))
    t = time.perf_counter()
    jax.block_until_ready(single(ks[0], w0[0]))
    first_1 = time.perf_counter() - t
    singles, walls = [], []
    for i in range(size):
        t = time.perf_counter()
        singles.append(jax.block_until_ready(single(ks[i], w0[i])))
        walls.append(time.perf_counter() - t)
    t = time.perf_counter()
    jax.block_until_ready(many(ks, w0))
    first_b = time.perf_counter() - t
    best = np.inf
    for _ in range(ARGS.repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(many(ks, w0))
        best = min(best, time.perf_counter() - t)
    g, result, steps, jacs, lus = (np.asarray(x) for x in out)
    one = statistics.median(walls[:-1])
    good = slice(0, size - 1)
    diff = max(float(np.max(np.abs(g[i] - np.asarray(singles[i][0])))) for i in range(size - 1))
    say(f"# bench_stiff --batch: {machine()}")
    say(f"stiff_chain(1e6), 2 s, Radau5 rtol = atol = 1e-6, {size} members (stiffness x 1 + N(0, 10 %))")
    say(f"single run: {one * 1e3:.1f} ms (median of {size - 1}; first call {first_1:.1f} s)")
    say(
        f"jax.vmap of {size}: {best:.2f} s (first call {first_b:.1f} s) = {best / one:.1f} single runs "
        f"(goal <= {size / 2:g}); steps {steps[good].min()}-{steps[good].max()}, Jacobians "
        f"{jacs[good].min()}-{jacs[good].max()}, factorizations {lus[good].min()}-{lus[good].max()} per member"
    )
    say(f"largest difference from the member's single run: {diff:.1e} rad")
    failed = [i for i in range(size) if result[i] != 0]
    say(
        f"failed members: {failed} (planted: [{size - 1}]); results of the others {'finite' if np.isfinite(g[good]).all() else 'NOT finite'}"
    )
    camp = _campaign(model, span, ts, size, one)
    return dict(
        size=size,
        single_s=one,
        batch_s=best,
        ratio=best / one,
        first_single_s=first_1,
        first_batch_s=first_b,
        difference=diff,
        failed=failed,
        campaign=camp,
    )


def _campaign(model, span, ts, size, one):
    """`size` members dispersed alike run by `jaxtree.monte_carlo` under Radau5: each device's
    members one after another (the campaign's rule for an implicit solver)."""
    import equinox as eqx

    def sample(key, m):
        return eqx.tree_at(lambda m: m.stiffness, m, m.stiffness * (1 + 0.1 * jax.random.normal(key)))

    def run():
        return jaxtree.monte_carlo(
            model, sample, size, span, key=jax.random.key(0), saveat=np.asarray(ts), rtol=1e-6, atol=1e-6,
            solver=jaxtree.Radau5(),
        )  # fmt: skip

    t = time.perf_counter()
    run()
    first = time.perf_counter() - t
    best = np.inf
    for _ in range(ARGS.repeats):
        t = time.perf_counter()
        ds = run()
        best = min(best, time.perf_counter() - t)
    devices = len(jax.local_devices())
    say(
        f"monte_carlo of {size} (solver=Radau5, {devices} devices, each device's members one after another): "
        f"{best:.2f} s (first call {first:.1f} s) = {best / one:.1f} single runs (goal <= {size / 2:g}); "
        f"steps {int(ds.steps.min())}-{int(ds.steps.max())}, failures {int((ds.failure != '').sum())}"
    )
    return dict(batch_s=best, ratio=best / one, first_s=first, devices=devices)


def main():
    if ARGS.batch:
        res = batch(ARGS.batch)
        if ARGS.json:
            write_json(ARGS.json, {"machine": machine(), "batch": res})
        return
    say(f"# bench_stiff: {machine()}")
    results = {"machine": machine(), "cases": {}}
    for name in ARGS.cases:
        model, span, ts, errors, targets, ladder = case(name)
        say(f"\n## {name}: targets {targets}")
        methods = {
            "jaxtree Radau5": lambda r: jaxtree_run(model, span, ts, jaxtree.Radau5(), r),
            "jaxtree Kvaerno5": lambda r: jaxtree_run(model, span, ts, dfx.Kvaerno5(), r),
            "Pinocchio + scipy Radau": lambda r: pinocchio_run(model, ts, r),
        }
        best = {}
        rows = []
        for label, fn in methods.items():
            for rtol in ladder:
                w, g, wall, first, work = fn(rtol)
                err = errors(w, g)
                ok = all(e <= t for e, t in zip(err, targets))
                rows.append(dict(method=label, rtol=rtol, errors=err, wall=wall, first=first, work=work, ok=ok))
                say(
                    f"{label:24s} rtol {rtol:7.0e} errors {' '.join(f'{e:.2e}' for e in err)} "
                    f"{'meets' if ok else '     '} {wall * 1e3:8.1f} ms (first {first:5.1f} s) {work}"
                )
                if ok:
                    best[label] = min(best.get(label, np.inf), wall)
                    break
        peer = best.get("Pinocchio + scipy Radau", np.nan)
        for label, wall in best.items():
            say(f"best {label:24s} {wall * 1e3:8.1f} ms  ({wall / peer:.2f}x Pinocchio + Radau)")
        results["cases"][name] = {"rows": rows, "best_s": best}
    if ARGS.json:
        write_json(ARGS.json, results)


if __name__ == "__main__":
    main()
