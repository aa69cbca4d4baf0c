"""Benchmark: the hybrid-coordinate equations (Sec. III E) in a slew, against the full Eq. (1)
and Pinocchio's ABA under scipy's DOP853, all in one run.

Scenes (``--scene``):

- ``panels95`` (default): the seed's 95-body vehicle (Fig. 2/3c); panels at rest, the bus
  spinning as in the scene, the rotor at 10 pi rad/s, a smooth torque pulse on the bus
  (5 N m about b_1, 3 N m about b_2, on at 1 s, off at 3 s, tanh edges of ~0.2 s); the 90
  wing hinges small (six substructures on the bus), platform, gimbals and rotor large;
- ``chain200``: a hub and a boom of 200 sprung segments, all boom hinges small (one
  substructure), a torque pulse on the hub.

For each method it prints the compile time apart from the run time (median of repeats after
compilation), accepted steps and the errors against a tight full Eq. (1) run (rtol = atol =
1e-10, Dopri8): the hub rate ``max |omega0 - ref| / max |omega0_ref|`` and the small hinges'
angles ``max |gamma_S - ref| / max |gamma_S,ref|``; for the hybrid models also the build time
(modes and precomputation, first call and again). The summary gives the cheapest setting of each
method that reaches the goal accuracy (hub 1e-3, small angles 1e-2) and the time ratios.

Run: ``python benchmarks/bench_hybrid.py [--scene panels95|chain200] [--quick] [--json PATH]``.
"""

from __future__ import annotations

import argparse
import os
import time

if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxtree  # noqa: E402

from _common import machine, timed, write_json  # noqa: E402

HUB_GOAL, SMALL_GOAL = 1e-3, 1e-2


def scenario(name, torque_scale):
    model = jaxtree.load_scene(name)
    pulse = lambda t: jaxtree._src.loads.thruster_pulse(t, 1.0, 2.0, rise=0.1)  # noqa: E731
    if name == "panels95":
        torque = np.array([5.0, 3.0, 0.0])
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


def pinocchio_rows(model, state, torque, t1, ts, ref, S, tols, repeats):
    import pinocchio as pin
    from scipy.integrate import solve_ivp

    import _peers

    pm, _, iq, iv, _ = _peers.pinocchio_model(model)
    data = pm.createData()
    n = model.n
    k = np.zeros(n)
    d = np.zeros(n)
    sp = np.asarray(model.sprung, int) - 1
    k[sp], d[sp] = np.asarray(model.stiffness)[sp], np.asarray(model.damping)[sp]
    q, v, tau = pin.neutral(pm), np.zeros(pm.nv), np.zeros(pm.nv)
    fext = [pin.Force.Zero() for _ in range(pm.njoints)]

    def rhs(t, x):
        w, g, gd, lin = x[:3], x[3 : 3 + n], x[3 + n : 3 + 2 * n], x[3 + 2 * n :]
        q[iq] = g
        v[:3], v[3:6], v[iv] = lin, w, gd
        tau[iv] = -k * g - d * gd
        p = 0.5 * (np.tanh((t - 1.0) / 0.1) - np.tanh((t - 3.0) / 0.1))
        fext[1] = pin.Force(np.zeros(3), torque * p)
        a = pin.aba(pm, data, q, v, tau, fext)
        return np.concatenate([a[3:6], gd, a[iv], a[:3]])

    x0 = np.concatenate([np.asarray(state.omega0), np.asarray(state.gamma), np.asarray(state.gamma_dot), np.zeros(3)])
    rows = []
    for tol in tols:
        run = lambda tol=tol: solve_ivp(rhs, (0.0, t1), x0, method="DOP853", rtol=tol, atol=tol, t_eval=ts)  # noqa
        r = run()
        wall = min(_wall(run) for _ in range(repeats))
        Y = r.y.T
        rows.append(
            dict(
                method="Pinocchio + DOP853",
                setting=f"rtol {tol:g}",
                compile=0.0,
                run=wall,
                steps=int(r.nfev),
                errors=errors(Y[:, :3], Y[:, 3 : 3 + n], ref, S),
            )
        )
    return rows


def _wall(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="panels95", choices=["panels95", "chain200"])
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
    for tol in full_tols:
        sol, first, run = timed(
            lambda: jaxtree.simulate(model, args.t1, y0=state, saveat=ts, rtol=tol, atol=tol), args.repeats
        )
        rows.append(
            dict(
                method="jaxtree full Eq. (1)",
                setting=f"rtol {tol:g}",
                compile=first - run,
                run=run,
                steps=int(sol.stats["num_accepted_steps"]),
                errors=errors(sol.omega0, sol.gamma, ref, S),
            )
        )
        print(rows[-1], flush=True)
    ks = (1, 2, 3, 4) if args.quick else (1, 2, 3, 4, 6, 8)
    hyb_tols = (1e-4, 1e-5) if args.quick else (1e-3, 1e-4, 1e-5, 1e-6)
    for k in ks:
        t0 = time.perf_counter()
        hm = jaxtree.hybrid_model(model, small, k, omega0=state.omega0)
        build1 = time.perf_counter() - t0
        t0 = time.perf_counter()
        hm = jaxtree.hybrid_model(model, small, k, omega0=state.omega0)
        build2 = time.perf_counter() - t0
        for tol in hyb_tols:
            sol, first, run = timed(
                lambda: jaxtree.simulate_hybrid(hm, args.t1, y0=state, saveat=ts, rtol=tol, atol=tol), args.repeats
            )
            rows.append(
                dict(
                    method="jaxtree hybrid",
                    setting=f"{k} modes per substructure ({hm.n_modes}), rtol {tol:g}",
                    compile=first - run,
                    run=run,
                    steps=int(sol.stats["num_accepted_steps"]),
                    errors=errors(sol.omega0, sol.gamma, ref, S),
                    build=(build1, build2),
                )
            )
            print(rows[-1], flush=True)
    if not args.no_peers:
        try:
            rows += pinocchio_rows(
                model,
                state,
                torque,
                args.t1,
                np.asarray(ts),
                ref,
                S,
                (1e-5, 1e-6) if args.quick else (1e-4, 1e-5, 1e-6, 1e-7),
                args.repeats,
            )
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
    h, f, p = best.get("jaxtree hybrid"), best.get("jaxtree full Eq. (1)"), best.get("Pinocchio + DOP853")
    if h and f:
        print(f"hybrid / full Eq. (1): {f['run'] / h['run']:.1f}x faster (goal 20x)")
    if h and p:
        print(f"hybrid / Pinocchio + DOP853: {p['run'] / h['run']:.1f}x faster (goal 10x)")
    if h:
        print(
            f"build of the chosen hybrid model: {h['build'][0]:.2f} s first call, {h['build'][1]:.2f} s again "
            "(goal: under 2 s after compilation)"
        )
    if args.json:
        write_json(args.json, dict(machine=machine(), scene=args.scene, rows=rows))


if __name__ == "__main__":
    main()
