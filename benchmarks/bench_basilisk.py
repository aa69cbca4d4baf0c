#!/usr/bin/env python3
"""Work-precision of Basilisk on `wings` over 10 s (a benchmark, not a test).

Basilisk (pip package ``bsk``, the ``peers`` extra) integrates the scene as a spacecraft hub with
one spinningBodyNDOFStateEffector per wing (:mod:`jaxtree.bench.peer_basilisk`):

- svIntegratorRK4 at fixed steps dt = 0.02, 0.01, 0.005, 0.002 s;
- svIntegratorRKF45 and svIntegratorRKF78 at relTol = absTol = 1e-4 ... 1e-10, task step (the
  sampling step, within which Basilisk starts each integration with the full step) 0.1 s.

Error = max over 101 evenly spaced save times of the largest absolute error in (omega0, gamma),
against jaxtree (Dopri8, rtol = atol = 1e-12); the reference is itself compared with Basilisk's
RKF78 at 1e-13 (printed). Time = wall time of Basilisk's ExecuteSimulation only (best of
`--repeats` runs; the build and initialization are printed apart). For scale, jaxtree's own
default solver at a few tolerances is timed in the same run (compiled once, by the reference's
call: its first-call time is printed apart; the tolerances are traced, not static). The summary
prints the fastest Basilisk run that reaches 1e-6 and 1e-9.

Run:  python benchmarks/bench_basilisk.py [--repeats 3] [--json results/bench_basilisk.json]
"""

from __future__ import annotations

import argparse
import sys
import time

T_END = 10.0
N_SAVE = 101
TARGETS = (1e-6, 1e-9)
RK4_STEPS = (0.02, 0.01, 0.005, 0.002)
TOLS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
TASK_STEP = 0.1  # the adaptive integrators' task (sampling) step: the save interval
REFERENCE_TOL = 1e-12
JAXTREE_TOLS = (1e-6, 1e-8, 1e-10)


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=3, help="runs per setting; the best time is kept")
    p.add_argument("--json", help="also write the figures to this JSON file")
    return p.parse_args()


ARGS = _args()
from _common import use_fast_cpu_flags

use_fast_cpu_flags()

import jax
import numpy as np

import jaxtree
from jaxtree.bench.peer_basilisk import basilisk_available, basilisk_run, basilisk_supports

from _common import machine, timed, write_json


def say(*a):
    print(*a, flush=True)


def error(out, ref):
    return max(np.abs(out["omega0"] - ref["omega0"]).max(), np.abs(out["gamma"] - ref["gamma"]).max())


def main():
    say(machine())
    if not basilisk_available():
        say("Basilisk is not installed (pip install bsk, or the peers extra): nothing to measure")
        return 1
    from importlib.metadata import version

    say(f"bsk {version('bsk')}")
    model = jaxtree.load_scene("wings")
    reason = basilisk_supports(model)
    if reason is not None:
        say(f"wings cannot be run in Basilisk: {reason}")
        return 1
    ts = np.linspace(0.0, T_END, N_SAVE)
    say(f"scene wings (n = {model.n}), {T_END:g} s, {N_SAVE} save times; error = max |.| of (omega0, gamma)")

    t0 = time.perf_counter()
    sol = jaxtree.simulate(model, T_END, saveat=jax.numpy.asarray(ts), rtol=REFERENCE_TOL, atol=REFERENCE_TOL)
    jax.block_until_ready(sol.gamma)
    first_call = time.perf_counter() - t0
    ref = {"omega0": np.asarray(sol.omega0), "gamma": np.asarray(sol.gamma)}
    check = basilisk_run(model, T_END, ts, integrator="rkf78", dt=0.01, rtol=1e-13, atol=1e-13)
    say(
        f"reference: jaxtree Dopri8 at rtol = atol = {REFERENCE_TOL:g}; against Basilisk RKF78 at 1e-13 "
        f"(task step 0.01 s): {error(check, ref):.2e}; jaxtree's first call (compile and run) {first_call:.1f} s"
    )

    rows = []

    def run(integrator, label, **kw):
        best, setup, out = np.inf, [], None
        for _ in range(max(1, ARGS.repeats)):
            out = basilisk_run(model, T_END, ts, integrator=integrator, **kw)
            best = min(best, out["time"])
            setup.append(out["setup_time"])
        err = error(out, ref)
        rows.append({"solver": f"basilisk {integrator}", "setting": label, "error": err, "time": best})
        say(f"{'basilisk ' + integrator:18s} {label:16s} {err:10.2e} {best * 1e3:10.2f} {np.median(setup) * 1e3:10.1f}")

    say(f"\n{'solver':18s} {'setting':16s} {'max error':>10s} {'run ms':>10s} {'setup ms':>10s}")
    for dt in RK4_STEPS:
        run("rk4", f"dt {dt:g}", dt=dt)
    for integrator in ("rkf45", "rkf78"):
        for tol in TOLS:
            run(integrator, f"tol {tol:.0e}", dt=TASK_STEP, rtol=tol, atol=tol)

    for tol in JAXTREE_TOLS:
        fn = lambda: jaxtree.simulate(model, T_END, saveat=jax.numpy.asarray(ts), rtol=tol, atol=tol)
        s, _, run_time = timed(fn, max(1, ARGS.repeats))  # compiled by the reference's call
        err = error({"omega0": np.asarray(s.omega0), "gamma": np.asarray(s.gamma)}, ref)
        rows.append({"solver": "jaxtree dopri8", "setting": f"tol {tol:.0e}", "error": err, "time": run_time})
        say(f"{'jaxtree dopri8':18s} {f'tol {tol:.0e}':16s} {err:10.2e} {run_time * 1e3:10.2f}")

    say("\nfastest run to each target (Basilisk over all its integrators; jaxtree for scale):")
    summary = {}
    for target in TARGETS:
        for who in ("basilisk", "jaxtree"):
            ok = [r for r in rows if r["solver"].startswith(who) and r["error"] <= target]
            if not ok:
                say(f"  {target:.0e}  {who:9s} not reached in its ladder")
                continue
            best = min(ok, key=lambda r: r["time"])
            summary[f"{who} {target:.0e}"] = best
            say(
                f"  {target:.0e}  {who:9s} {best['time'] * 1e3:8.2f} ms  "
                f"({best['solver']}, {best['setting']}, error {best['error']:.1e})"
            )
    if ARGS.json:
        write_json(ARGS.json, {"machine": machine(), "rows": rows, "summary": summary})
    return 0


if __name__ == "__main__":
    sys.exit(main())
