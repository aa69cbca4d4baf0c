"""Benchmark: hybrid-coordinate equations (Sec. III E, Eqs. 105-123) against the full Eq. (1).

For a scene with many small hinges (default chain50: a hub and a boom of 50 sprung segments, all
50 hinges small, so omega0 is the only large variable and the hybrid equations have constant
modal coefficients; or panels95: the 90 wing-panel hinges small, platform/gimbal/rotor large,
general path) it prints the machine and versions, then:

- the build time of the hybrid model (linearize + modes + precomputation, first call and again);
- one right-hand side call, full Eq. (1) (``simulate``'s vector field) and hybrid, jitted;
- for the full model at a few tolerances and for the hybrid model with k = 5, 10, 20 and all
  modes: compile time (first call minus a second call), run time after compile (median of
  repeats), accepted steps, and the error against a tight full-model reference (rtol = atol =
  1e-12): the maximum over the saved times of |gamma - gamma_ref| (all hinges) and of
  |omega0 - omega0_ref|.

The hybrid error has three parts: integration error, linearization error (Eq. 30 drops terms
quadratic in the small angles, here ~amplitude^2) and truncation error (the modes left out).
On chain50 the hub's roll rate (axis 1, along the boom) is excited by Eq. (1) only at second
order, and Eq. (30) gets it wrong at that order (docs/errata_hybrid.md #7): compare the omega0
errors per axis with the reference's omega0.

Run: ``python benchmarks/bench_hybrid.py [--scene chain50|panels95] [--t1 T] [--repeats N]``.
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import jaxtree
from _common import machine, timed


def errors(gamma, omega0, ref):
    """max |gamma - gamma_ref| over all hinges and saved times, and max |omega0 - omega0_ref| per axis."""
    return (float(np.abs(np.asarray(gamma) - ref[0]).max()), np.abs(np.asarray(omega0) - ref[1]).max(0))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", default="chain50", choices=["chain50", "panels95", "chain10", "wings"])
    ap.add_argument("--t1", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rtol", type=float, default=1e-8, help="tolerance of the hybrid runs")
    ap.add_argument("--amplitude", type=float, default=0.1,
                    help="factor on the scene's initial angles of the small hinges (chain50: 0.02 rad each)")
    args = ap.parse_args()
    print(machine())
    model = jaxtree.load_scene(args.scene)
    if args.scene == "panels95":
        small = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    else:
        small = model.unknown_hinges
    S = np.asarray(small) - 1
    state = model.initial
    state = state._replace(gamma=jnp.asarray(state.gamma).at[S].multiply(args.amplitude),
                           gamma_dot=jnp.asarray(state.gamma_dot).at[S].multiply(args.amplitude))
    nom = jnp.asarray(state.omega0)
    print(f"{args.scene}: n = {model.n} hinges, set A = {len(small)} small hinges, nominal omega0 = "
          f"{np.asarray(nom).tolist()}, t1 = {args.t1} s, initial panel angles up to "
          f"{float(np.abs(np.asarray(state.gamma)[np.asarray(small) - 1]).max()):.3g} rad")
    ts = jnp.linspace(0.0, args.t1, 201)

    # ---------------------------------------------------------------- build
    t0 = time.perf_counter()
    hm = jaxtree.hybrid_model(model, small, omega0=nom)
    build_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    jaxtree.hybrid_model(model, small, omega0=nom)
    build_again = time.perf_counter() - t0
    print(f"hybrid model: form {hm.form!r} ({hm.kind} modes), precomputed polynomial form: {hm.precomputed}, "
          f"large hinges {len(hm.large)}; build {build_first:.2f} s first call, {build_again:.2f} s again")
    f = np.asarray(hm.frequencies)
    print("modal frequencies (rad/s): lowest " + ", ".join(f"{x:.3g}" for x in f[:5]) + f" ... highest {f[-1]:.4g}")

    # ---------------------------------------------------------------- one right-hand side
    problem = jaxtree.Problem(model, jaxtree.Quaternion(), None, None, None, False, 0)
    y_full = problem.pack(state)
    full_vf = eqx.filter_jit(lambda p, y: p.vector_field(0.0, y))
    hyb_vf = eqx.filter_jit(lambda h, y: jaxtree.hybrid_rhs(0.0, y, h))
    _, c1, r1 = timed(lambda: full_vf(problem, y_full), 200)
    y_hyb = hm.pack(state)
    _, c2, r2 = timed(lambda: hyb_vf(hm, y_hyb), 200)
    print(f"one right-hand side (jitted call, median): full Eq. (1) {1e6 * r1:.1f} us, hybrid (all modes) "
          f"{1e6 * r2:.1f} us")

    # ---------------------------------------------------------------- full model, then reference
    rows, sols = [], []
    for tol in (1e-6, 1e-8, 1e-10):
        sol, first, run = timed(lambda: jaxtree.simulate(model, args.t1, y0=state, saveat=ts, rtol=tol, atol=tol),
                                args.repeats)
        rows.append([f"full Eq. (1), rtol {tol:g}", first - run, run, int(sol.stats["num_accepted_steps"])])
        sols.append(sol)
    t0 = time.perf_counter()
    ref_sol = jaxtree.simulate(model, args.t1, y0=state, saveat=ts, rtol=1e-12, atol=1e-12)
    ref = (np.asarray(ref_sol.gamma), np.asarray(ref_sol.omega0))
    print(f"reference: full Eq. (1), Dopri8, rtol = atol = 1e-12: {int(ref_sol.stats['num_accepted_steps'])} "
          f"steps, {time.perf_counter() - t0:.2f} s; max |gamma| {np.abs(ref[0][:, S]).max():.3g} rad "
          f"(small hinges), max |omega0| per axis {np.abs(ref[1]).max(0)}")
    for row, sol in zip(rows, sols):
        row += errors(sol.gamma, sol.omega0, ref)
    ks = [k for k in (5, 10, 20) if k < hm.n_modes] + [hm.n_modes]
    for k in ks:
        h = hm if k == hm.n_modes else jaxtree.hybrid_model(model, small, k, omega0=nom)
        sol, first, run = timed(
            lambda: jaxtree.simulate_hybrid(h, args.t1, y0=state, saveat=ts, rtol=args.rtol, atol=args.rtol),
            args.repeats)
        label = f"hybrid k = {k}" + (" (all)" if k == hm.n_modes else "") + f", rtol {args.rtol:g}"
        rows.append((label, first - run, run, int(sol.stats["num_accepted_steps"]),
                     *errors(sol.gamma, sol.omega0, ref)))
    print(f"\n{'run':34s} {'compile':>9s} {'run':>10s} {'steps':>7s} {'max|dgamma|':>12s}  max|domega0| (axes 1, 2, 3)")
    for label, comp, run, steps, eg, ew in rows:
        print(f"{label:34s} {comp:8.2f}s {1e3 * run:8.1f}ms {steps:7d} {eg:12.3g}  "
              + " ".join(f"{x:9.2g}" for x in ew))
    full_best = min(r[2] for r in rows if r[0].startswith("full"))
    print("\nspeed-up of the hybrid runs over the fastest full run: " +
          ", ".join(f"{r[0].split(',')[0]}: {full_best / r[2]:.1f}x" for r in rows if r[0].startswith("hybrid")))


if __name__ == "__main__":
    main()
