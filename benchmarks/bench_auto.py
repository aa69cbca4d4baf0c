"""Benchmark: does ``solver="auto"`` pick the faster of Dopri8 and Radau5 at the user's accuracy?

For each case, Dopri8 and :class:`jaxtree.Radau5` run over a ladder of tolerances (rtol = atol);
each run's error is measured against a tight reference and its run time is the least of five
calls after the first (compile time apart; the least, since this machine's load only adds). ``solver="auto"`` at a tolerance runs whichever of the
two it picks there (its prediction of both step counts is printed), so its point is that run: its
*ratio* is its time over the least time of any run of either method whose error is at most its
error (the faster method "to the same error"). Goal: ratio <= 1.3 everywhere.

Cases (``jaxtree.bench.bench_case``): fig4_free, wings, the stiff chains (chain10 with the tip
spring x 1e2 ... 1e8), the fast rotor (fig4_free with the rotor at 1000 pi rad/s), flex95's slew
and wings4's slew (a hub and four wings of 20 stiff latched panels), all in the full Eq. (1); with
``--hybrid``, also flex95 and wings4 in hybrid coordinates (``simulate_hybrid``'s default against
Dopri8 and Radau5), and Pinocchio + scipy's Radau on flex95 and wings4 (the flexible-vehicle
goals: the hybrid model's default >= 1.5x faster than Pinocchio + Radau, the full model's default
<= 3x its time, each at the goal accuracy hub 1e-3 / wings 1e-2 of bench_hybrid.py).

Run: ``python benchmarks/bench_auto.py [--cases a,b] [--tols 1e-3,1e-4,...] [--hybrid] [--json PATH]``.
"""

from __future__ import annotations

import argparse
import math
import time

from _common import use_fast_cpu_flags

use_fast_cpu_flags()

import diffrax as dfx
import jax.numpy as jnp
import numpy as np

import jaxtree
from jaxtree.bench.cases import bench_case

from _common import machine, timed, write_json

CASES = ("fig4_free", "wings", "stiff_1e2", "stiff_1e4", "stiff_1e6", "stiff_1e8", "rotor_1000pi", "flex95", "wings4")
TOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8)
EXPLICIT_CAP, IMPLICIT_CAP = 100_000, 20_000
HUB_GOAL, WING_GOAL = 1e-3, 1e-2


def errors(omega0, gamma, ref, relative):
    """``(error, hub, wings)``: the bench's error (the larger of the two relative ones with
    `relative` hinges, else the largest absolute error in omega0 and gamma) and, with `relative`,
    the hub rate's error over its peak and those hinges' angles' over theirs (else NaN)."""
    w, g = np.asarray(omega0, float), np.asarray(gamma, float)
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(g))):
        return math.nan, math.nan, math.nan
    if relative is None:
        return float(max(np.abs(w - ref[0]).max(), np.abs(g - ref[1]).max())), math.nan, math.nan
    cols = np.asarray(relative) - 1
    gr = ref[1][:, cols]
    hub = float(np.abs(w - ref[0]).max() / np.abs(ref[0]).max())
    wings = float(np.abs(g[:, cols] - gr).max() / np.abs(gr).max())
    return max(hub, wings), hub, wings


def run_time(call, repeats=5):
    return timed(call, repeats, least=True)


def reference(case, ts):
    stiff = case.group == "stiff" and not case.name.startswith(("flex95", "wings4"))
    solver = jaxtree.Radau5() if stiff else dfx.Dopri8()
    sol = jaxtree.simulate(case.model, case.t1, saveat=ts, solver=solver, rtol=1e-11, atol=1e-11, max_steps=400_000)
    return np.asarray(sol.omega0, float), np.asarray(sol.gamma, float)


def ladder(label, make_call, tols, ref, relative, predicted_cap=None):
    """Rows of one method over the tolerances; `make_call(tol)` returns a zero-argument call
    giving a solution; runs predicted past the step cap are skipped."""
    rows = []
    for tol in tols:
        if predicted_cap is not None and predicted_cap(tol):
            rows.append(dict(method=label, tol=tol, status="skipped: predicted past the step cap"))
            print(rows[-1], flush=True)
            continue
        try:
            sol, first, wall = run_time(make_call(tol))
        except Exception as exc:  # a stalled run: recorded, not fatal
            rows.append(dict(method=label, tol=tol, status=f"failed: {type(exc).__name__}"))
            print(rows[-1], flush=True)
            continue
        err, hub, wings = errors(sol.omega0, sol.gamma, ref, relative)
        rows.append(
            dict(
                method=label,
                tol=tol,
                status="ok",
                error=err,
                hub=hub,
                wings=wings,
                run=wall,
                compile=first - wall,
                steps=int(sol.stats["num_accepted_steps"]),
            )
        )
        print(rows[-1], flush=True)
    return rows


def best_to(rows, err):
    """The least run time among `rows` whose error is at most `err` (inf if none)."""
    ok = [r["run"] for r in rows if r.get("status") == "ok" and r["error"] <= err * (1 + 1e-9)]
    return min(ok, default=math.inf)


def auto_rows(label, choices, rows, tols):
    """For each tolerance: what auto picks, that run, and its ratio to the faster method to its error."""
    out = []
    by = {(r["method"], r["tol"]): r for r in rows}
    for tol in tols:
        choice = choices[tol]
        run = by.get((f"{label} {choice.name}", tol))
        if run is None or run.get("status") != "ok":
            out.append(dict(case=label, tol=tol, pick=choice.name, status="its run is missing"))
            continue
        best = best_to(rows, run["error"])
        out.append(
            dict(
                case=label, tol=tol, pick=choice.name, error=run["error"], run=run["run"], best=best,
                ratio=run["run"] / best, predicted=(choice.explicit_steps, choice.implicit_steps), reason=choice.reason,
            )
        )  # fmt: skip
        print(out[-1], flush=True)
    return out


def full_case(name, tols):
    case = bench_case(name)
    ts = jnp.linspace(0.0, case.t1, case.n_save)
    ref = reference(case, ts)
    choices = {}
    for tol in tols:
        t0 = time.perf_counter()
        choices[tol] = jaxtree.choose_solver(case.model, case.t1, rtol=tol, atol=tol)[1]
        print(f"{name} auto at {tol:g}: {choices[tol]} ({time.perf_counter() - t0:.2f} s)", flush=True)

    def call(solver, tol, cap):
        return lambda: jaxtree.simulate(
            case.model, case.t1, saveat=ts, solver=solver, rtol=tol, atol=tol, max_steps=cap, throw=False
        )

    def too_long(tol):
        c = choices[tol]
        return not math.isnan(c.explicit_steps) and c.explicit_steps > 2 * EXPLICIT_CAP

    rows = ladder(
        f"{name} Dopri8", lambda tol: call(dfx.Dopri8(), tol, EXPLICIT_CAP), tols, ref, case.relative, too_long
    )
    rows += ladder(f"{name} Radau5", lambda tol: call(jaxtree.Radau5(), tol, IMPLICIT_CAP), tols, ref, case.relative)
    return rows, auto_rows(name, choices, rows, tols), case, ts, ref


def hybrid_case(name, tols, case, ts, ref):
    small = tuple(k for k in range(1, case.model.n + 1) if case.model.names[k].startswith("wing"))
    hm = jaxtree.hybrid_model(case.model, small, n_modes="auto")
    choices = {}
    for tol in tols:
        sol = jaxtree.simulate_hybrid(hm, case.t1, saveat=ts, rtol=tol, atol=tol, truncation_error=False)
        choices[tol] = sol.stats["solver"]
        print(f"{name} hybrid auto at {tol:g}: {choices[tol]}", flush=True)

    def call(solver, tol):
        return lambda: jaxtree.simulate_hybrid(
            hm, case.t1, saveat=ts, solver=solver, rtol=tol, atol=tol, truncation_error=False, throw=False
        )

    label = f"{name} hybrid"
    rows = ladder(f"{label} Dopri8", lambda tol: call(dfx.Dopri8(), tol), tols, ref, case.relative)
    rows += ladder(f"{label} Radau5", lambda tol: call(jaxtree.Radau5(), tol), tols, ref, case.relative)
    return rows, auto_rows(label, choices, rows, tols)


def pinocchio_case(case, ts, ref, tols):
    from jaxtree.bench.peers import pinocchio_runner

    run = pinocchio_runner(case.model.with_loads(None), np.asarray(ts), base_torque=case.peer_torque)
    rows = []
    for tol in tols:
        w, g, wall, calls = run("Radau", tol, tol)
        wall = min(wall, run("Radau", tol, tol)[2])

        err, hub, wings = errors(w, g, ref, case.relative)
        rows.append(
            dict(
                method=f"{case.name} Pinocchio + Radau", tol=tol, status="ok", error=err, hub=hub, wings=wings,
                run=wall, steps=calls,
            )
        )  # fmt: skip
        print(rows[-1], flush=True)
    return rows


def at_goal(row) -> bool:
    """bench_hybrid.py's goal accuracy: the hub rate within 1e-3 of its peak, the wings within 1e-2."""
    return row.get("status") == "ok" and row["hub"] <= HUB_GOAL and row["wings"] <= WING_GOAL


def goal_time(rows) -> float:
    """The least run time among `rows` at the goal accuracy (inf if none)."""
    return min((r["run"] for r in rows if at_goal(r)), default=math.inf)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--tols", default=",".join(f"{t:g}" for t in TOLS))
    ap.add_argument("--hybrid", action="store_true", help="also the hybrid models and Pinocchio + Radau")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    tols = tuple(float(x) for x in args.tols.split(","))
    print(machine(), flush=True)
    results = dict(machine=machine(), rows=[], auto=[], flexible=[])
    for name in args.cases.split(","):
        rows, autos, case, ts, ref = full_case(name, tols)
        results["rows"] += rows
        results["auto"] += autos
        if args.hybrid and name in ("flex95", "wings4"):
            hrows, hautos = hybrid_case(name, tols, case, ts, ref)
            prows = pinocchio_case(case, ts, ref, tols)
            results["rows"] += hrows + prows
            results["auto"] += hautos
            pin = goal_time(prows)
            by = {(r["method"], r["tol"]): r for r in rows + hrows}
            full_t = goal_time([by[(f"{name} {a['pick']}", a["tol"])] for a in autos if "ratio" in a])
            hyb_t = goal_time([by[(f"{name} hybrid {a['pick']}", a["tol"])] for a in hautos if "ratio" in a])
            line = dict(case=name, pinocchio_radau=pin, full_auto=full_t, hybrid_auto=hyb_t,
                        full_over_pinocchio=full_t / pin, pinocchio_over_hybrid=pin / hyb_t)  # fmt: skip
            results["flexible"].append(line)
            print(line, flush=True)
    print("\nsummary: auto's time over the faster method's to the same error")
    for a in results["auto"]:
        if "ratio" in a:
            flag = "" if a["ratio"] <= 1.3 else "  <-- over 1.3"
            print(
                f"  {a['case']:22s} tol {a['tol']:8.0e} {a['pick']:7s} error {a['error']:9.2e} {a['run'] * 1e3:9.1f} ms, best {a['best'] * 1e3:9.1f} ms, ratio {a['ratio']:5.2f}{flag}"
            )
        else:
            print(f"  {a['case']:22s} tol {a['tol']:8.0e} {a['pick']:7s} {a['status']}")
    for f in results["flexible"]:
        print(
            f"  {f['case']}: at hub 1e-3, Pinocchio + Radau {f['pinocchio_radau'] * 1e3:.1f} ms; full default "
            f"{f['full_auto'] * 1e3:.1f} ms ({f['full_over_pinocchio']:.2f}x, goal <= 3); hybrid default "
            f"{f['hybrid_auto'] * 1e3:.1f} ms (Pinocchio / hybrid {f['pinocchio_over_hybrid']:.2f}, goal >= 1.5)"
        )
    if args.json:
        write_json(args.json, results)


if __name__ == "__main__":
    main()
