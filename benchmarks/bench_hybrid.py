"""Benchmark: the hybrid-coordinate equations (Sec. III E) in a slew, against the full Eq. (1)
and Pinocchio's ABA under scipy's DOP853, all in one run.

Scenes (``--scene``):

- ``flex95`` (default): the flexible vehicle of the slew, panels95 with stiff latched bending
  hinges (held-wing modes 0.94-433 rad/s); the slew of the issue: the scene's bus spin, the
  rotor at 10 pi rad/s, wings straight, (15, 9, 0) N m on the bus from 1 s to 3 s (tanh edges of
  ~0.2 s); the 90 wing hinges small. The full Eq. (1) also with jaxtree.Radau5, the peers
  Pinocchio + scipy DOP853 and Radau;
- ``panels95``: the seed's 95-body vehicle (Fig. 2/3c); panels at rest, the bus
  spinning as in the scene, the rotor at 10 pi rad/s, a smooth torque pulse on the bus
  (5 N m about b_1, 3 N m about b_2, on at 1 s, off at 3 s, tanh edges of ~0.2 s); the 90
  wing hinges small (six substructures on the bus), platform, gimbals and rotor large;
- ``chain200``: a hub and a boom of 200 sprung segments, all boom hinges small (one
  substructure), a torque pulse on the hub.

For each method it prints the compile time apart from the run time (median of repeats after
compilation), accepted steps (the peers: right sides) and the errors against a tight full Eq. (1) run (rtol = atol =
1e-10, Dopri8): the hub rate ``max |omega0 - ref| / max |omega0_ref|`` and the small hinges'
angles ``max |gamma_S - ref| / max |gamma_S,ref|``; for the hybrid models also the build time
(modes and precomputation, first call and again), the truncation estimate of
`simulate_hybrid` (a separate call: the timed runs pass ``truncation_error=False``) and the cost
of one hybrid right side in a jitted loop (goal: <= 10 us at 3 modes per wing on flex95,
<= 15 us at 6, <= 2x from 6 to 36 modes in all). The summary gives the cheapest setting of each
method that reaches the goal accuracy (hub 1e-3, small angles 1e-2) and the time ratios.

Run: ``python benchmarks/bench_hybrid.py [--scene flex95|panels95|chain200] [--quick] [--json PATH]``.
"""

from __future__ import annotations

import argparse
import time

from _common import use_fast_cpu_flags

use_fast_cpu_flags()

import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

from _common import machine, timed, write_json

HUB_GOAL, SMALL_GOAL = 1e-3, 1e-2


def scenario(name, torque_scale):
    model = jaxtree.load_scene(name)
    pulse = lambda t: jaxtree._src.equations.loads.thruster_pulse(t, 1.0, 2.0, rise=0.1)
    if name in ("panels95", "flex95"):
        torque = np.array([15.0, 9.0, 0.0] if name == "flex95" else [5.0, 3.0, 0.0])
        small = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    else:
        torque = np.array([0.0, 400.0, 150.0])
        small = tuple(range(1, model.n + 1))
    model = model.with_loads(jaxtree.BodyTorque(0, torque * torque_scale, pulse))
    gd = np.zeros(model.n)
    if "rotor" in model.names:
        gd[model.names.index("rotor") - 1] = 10 * np.pi
    state = model.initial._replace(gamma=jnp.zeros(model.n), gamma_dot=jnp.asarray(gd))
    return model, small, state, torque * torque_scale


def errors(omega0, gamma, ref, S):
    hub = float(np.abs(np.asarray(omega0) - ref["omega0"]).max() / np.abs(ref["omega0"]).max())
    small = float(np.abs(np.asarray(gamma)[:, S] - ref["gamma"][:, S]).max() / np.abs(ref["gamma"][:, S]).max())
    return hub, small


def pinocchio_rows(model, state, torque, ts, ref, S, tols, methods, repeats):
    """Pinocchio's ABA under scipy (``jaxtree.bench.peers.pinocchio_runner``, from `state`, the
    torque on the bus as the free flyer's generalized force)."""
    import equinox as eqx

    from jaxtree.bench.peers import pinocchio_runner

    model = eqx.tree_at(lambda m: m.initial, model.with_loads(None), state)
    # the scenario's pulse in numpy (a JAX call per right side would slow the peer by its dispatch)
    pulse = lambda t: 0.5 * (np.tanh((t - 1.0) / 0.1) - np.tanh((t - 3.0) / 0.1))
    run = pinocchio_runner(model, np.asarray(ts), base_torque=lambda t: torque * pulse(t))
    rows = []
    for method in methods:
        for tol in tols:
            w, g, wall, calls = run(method, tol, tol)
            wall = min([wall] + [run(method, tol, tol)[2] for _ in range(repeats - 1)])
            rows.append(
                dict(
                    method=f"Pinocchio + {method}",
                    setting=f"rtol {tol:g}",
                    compile=0.0,
                    run=wall,
                    steps=calls,
                    errors=errors(w, g, ref, S),
                )
            )
            print(rows[-1], flush=True)
    return rows


def rhs_us(hm, calls=2000, repeats=5):
    """One hybrid right side in a jitted ``fori_loop`` (no dispatch), microseconds."""
    y = hm.pack(hm.model.initial)

    @jax.jit
    def loop(y):
        return jax.lax.fori_loop(0, calls, lambda i, c: c + 1e-9 * jaxtree.hybrid_rhs(0.0, c, hm), y)

    jax.block_until_ready(loop(y))
    return 1e6 * min(_wall(lambda: jax.block_until_ready(loop(y))) for _ in range(repeats)) / calls


def _wall(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="flex95", choices=["flex95", "panels95", "chain200"])
    ap.add_argument("--t1", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--torque-scale", type=float, default=1.0)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-peers", action="store_true")
    ap.add_argument("--json")
    args = ap.parse_args()
    print(machine())
    model, small, state, torque = scenario(args.scene, args.torque_scale)
    S = np.asarray(small) - 1
    ts = jnp.linspace(0.0, args.t1, 201)
    t0 = time.perf_counter()
    ref_sol = jaxtree.simulate(model, args.t1, y0=state, saveat=ts, rtol=1e-10, atol=1e-10)
    ref = dict(omega0=np.asarray(ref_sol.omega0), gamma=np.asarray(ref_sol.gamma))
    print(
        f"{args.scene}: n = {model.n}, {len(small)} small hinges; slew torque {torque.tolist()} N m from 1 s to 3 s; "
        f"reference (full Eq. 1, Dopri8, 1e-10): {int(ref_sol.stats['num_accepted_steps'])} steps, "
        f"{time.perf_counter() - t0:.1f} s; peak hub rate {np.abs(ref['omega0']).max():.4g} rad/s, peak small angle "
        f"{np.abs(ref['gamma'][:, S]).max():.4g} rad"
    )
    rows = []
    full_tols = (1e-5, 1e-6) if args.quick else (1e-4, 1e-5, 1e-6, 1e-7)
    # the implicit runs (jaxtree's Radau5, full and hybrid, and scipy's Radau) share one finer
    # ladder: near the goal a factor 3 in tolerance is a factor ~1.5 in time, for every method
    implicit_tols = (1e-4, 3e-5) if args.quick else (1e-4, 5e-5, 3e-5, 2e-5, 1e-5, 1e-6)
    solvers = [("auto", "jaxtree full Eq. (1)")]
    if args.scene in ("flex95", "chain200"):
        solvers.append((jaxtree.Radau5(), "jaxtree full, Radau5"))
    runs = [(x, tol) for x in solvers for tol in (implicit_tols if x[1].endswith("Radau5") else full_tols)]
    for (solver, label), tol in runs:
        sol, first, run = timed(
            lambda: jaxtree.simulate(model, args.t1, y0=state, saveat=ts, rtol=tol, atol=tol, solver=solver),
            args.repeats,
        )
        rows.append(
            dict(
                method=label,
                setting=f"rtol {tol:g}" + ("" if label.endswith("Radau5") else f" ({sol.stats['solver'].name})"),
                compile=first - run,
                run=run,
                steps=int(sol.stats["num_accepted_steps"]),
                errors=errors(sol.omega0, sol.gamma, ref, S),
            )
        )
        print(rows[-1], flush=True)
    ks = (1, 2, 3, 4) if args.quick else ("auto", 1, 2, 3, 4, 6, 8)
    hyb_tols = (1e-4, 1e-5) if args.quick else (1e-3, 1e-4, 1e-5, 1e-6)
    # the hybrid model with the implicit integrator too: its explicit steps are bound by the
    # rotor-gimbal nutation (~56 rad/s), not by the wings (125 Dopri8 steps at any tolerance)
    radau_ks = (3,) if args.quick else ("auto", 2, 3, 4)
    radau_tols = implicit_tols
    for k in ks:
        t0 = time.perf_counter()
        hm = jaxtree.hybrid_model(model, small, k, omega0=state.omega0)
        build1 = time.perf_counter() - t0
        t0 = time.perf_counter()
        hm = jaxtree.hybrid_model(model, small, k, omega0=state.omega0)
        build2 = time.perf_counter() - t0
        per = hm.modes_per_substructure
        label = f"auto ({'/'.join(map(str, per))})" if k == "auto" else str(k)
        est = jaxtree.simulate_hybrid(hm, args.t1, y0=state, saveat=ts, rtol=hyb_tols[-1], atol=hyb_tols[-1])
        cost = rhs_us(hm)
        truncation = float(est.max_truncation_error()) / float(np.abs(ref["gamma"][:, S]).max())
        print(
            f"{label} modes per substructure: right side {cost:.1f} us; truncation estimate {truncation:.2e} of the "
            f"peak; build {build1:.2f} s first call, {build2:.2f} s again"
        )
        runs = [(None, "jaxtree hybrid", tol) for tol in hyb_tols]
        if k in radau_ks:
            runs += [(jaxtree.Radau5(), "jaxtree hybrid, Radau5", tol) for tol in radau_tols]
        for solver, method, tol in runs:
            kw = {} if solver is None else dict(solver=solver)
            sol, first, run = timed(
                lambda: jaxtree.simulate_hybrid(
                    hm, args.t1, y0=state, saveat=ts, rtol=tol, atol=tol, truncation_error=False, **kw
                ),
                args.repeats,
            )
            rows.append(
                dict(
                    method=method,
                    setting=f"{label} modes per substructure ({hm.n_modes}), rtol {tol:g}",
                    compile=first - run,
                    run=run,
                    steps=int(sol.stats["num_accepted_steps"]),
                    errors=errors(sol.omega0, sol.gamma, ref, S),
                    build=(build1, build2),
                    rhs_us=cost,
                    truncation=truncation,
                )
            )
            print(rows[-1], flush=True)
    if not args.no_peers:
        try:
            methods = ("DOP853", "Radau")
            tols = tuple(sorted(set(implicit_tols) | {1e-7}, reverse=True)) if not args.quick else (1e-5, 1e-6)
            rows += pinocchio_rows(model, state, torque, ts, ref, S, tols, methods, args.repeats)
        except ImportError as e:
            print(f"Pinocchio not installed ({e}): pip install -e .[peers]")
    print(
        f"\n{'method':22s} {'setting':44s} {'compile':>8s} {'run':>9s} {'steps':>6s} {'hub err':>9s} {'small err':>9s}"
    )
    for r in rows:
        print(
            f"{r['method']:22s} {r['setting']:44s} {r['compile']:7.2f}s {1e3 * r['run']:7.1f}ms {r['steps']:6d} "
            f"{r['errors'][0]:9.2e} {r['errors'][1]:9.2e}"
        )
    best = {}
    for r in rows:
        if r["errors"][0] <= HUB_GOAL and r["errors"][1] <= SMALL_GOAL:
            if r["method"] not in best or r["run"] < best[r["method"]]["run"]:
                best[r["method"]] = r
    print(f"\ncheapest setting reaching hub {HUB_GOAL:g} and small angles {SMALL_GOAL:g}:")
    for m, r in best.items():
        print(f"  {m:22s} {r['setting']:44s} {1e3 * r['run']:8.1f} ms")
    hybrids = [best[m] for m in ("jaxtree hybrid", "jaxtree hybrid, Radau5") if m in best]
    h = min(hybrids, key=lambda r: r["run"]) if hybrids else None
    fulls = [best[m] for m in ("jaxtree full Eq. (1)", "jaxtree full, Radau5") if m in best]
    f = min(fulls, key=lambda r: r["run"]) if fulls else None
    if h and f:
        print(f"best hybrid / best full Eq. (1): {f['run'] / h['run']:.1f}x faster (goal: >= 3x)")
    peers = [best[p] for p in ("Pinocchio + DOP853", "Pinocchio + Radau") if p in best]
    if h and peers:
        p = min(peers, key=lambda r: r["run"])
        print(f"best hybrid / better Pinocchio run ({p['method']}): {p['run'] / h['run']:.1f}x faster (goal: >= 5x)")
    costs = {r["setting"].split(" modes")[0]: r["rhs_us"] for r in rows if "rhs_us" in r}
    if costs:
        print(
            "hybrid right side in a jitted loop: "
            + ", ".join(f"{k} per substructure {c:.1f} us" for k, c in costs.items())
        )
        if "1" in costs and "6" in costs:
            print(
                f"  from 1 to 6 modes per substructure: {costs['6'] / costs['1']:.2f}x "
                "(goal: <= 2x from 6 to 36 in all)"
            )
    builds = [r["build"][0] for r in rows if "build" in r]
    if builds:
        print(
            f"build of the first hybrid model: {builds[0]:.2f} s on its first call in this process "
            "(goal: <= 5 s compile included, <= 1 s after)"
        )
    if h:
        print(f"build of the chosen hybrid model again: {h['build'][1]:.2f} s")
    if args.json:
        write_json(args.json, dict(machine=machine(), scene=args.scene, rows=rows))


if __name__ == "__main__":
    main()
