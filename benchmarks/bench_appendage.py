#!/usr/bin/env python3
"""Benchmark: a finite-element appendage against the same structure as a rigid chain, to the same
tip-deflection accuracy (the finite-element issue, point 7). A benchmark, not a test.

The case is the tests' slew (tests/test_appendage.py): a hub (300 kg m^2) slewed by a torque
200 sin(2 pi t / 10) N m over 10 s, a 10 m beam (EI = 14 000 N m^2, rho A = 1.2 kg/m) clamped 1 m
from its center, 15 s. The error is the largest difference of the tip deflection (the hub's y)
from the reference, relative to its peak, over 61 save times; the reference is the chain of 32
and 64 segments extrapolated at second order (its lumping's order: springs EI / l, 2 EI / l at the
clamp).

Rows (each at its cheapest setting that reaches the target, the run's median of repeats, the
first call, compilation included, apart):

- ``fe hybrid``: ``jaxtree.beam`` (40 elements), ``appendage`` (12 held-interface modes),
  ``hybrid_model(..., 3 modes)``, ``simulate_hybrid`` with Dopri8 over a tolerance ladder;
- ``chain N, Eq. (1)``: the chain of N segments in the full Eq. (1) with Radau5 (the chain is
  stiff: its segments' frequencies reach thousands of rad/s), N doubled until the target is met;
- ``chain N, hybrid``: the same chain with its hinges in 3 held-base modes (hybrid_model), Dopri8.

Run:  python benchmarks/bench_appendage.py [--target 0.01] [--repeats 3] [--json PATH]
"""

from __future__ import annotations

import argparse
import sys


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--target", type=float, default=1e-2, help="tip-deflection error relative to its peak")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--json", default=None)
    return p.parse_args()


def main():
    args = _args()
    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxtree

    from _common import machine, timed, write_json

    L, E, RHO, AREA, EI = 10.0, 7e10, 3000.0, 4e-4, 14000.0
    IY = EI / E
    HUB_POINT, T0, T1 = 1.0, 200.0, 15.0
    profile = lambda t: jnp.where(t < 10.0, jnp.sin(2 * jnp.pi * t / 10.0), 0.0)
    torque = jaxtree.BodyTorque(0, [0.0, 0.0, T0], profile)
    hub = jaxtree.Body("hub", 100.0, np.diag([300.0] * 3))
    ts = jnp.linspace(0.0, T1, 61)

    def chain(N):
        l, m = L / N, RHO * AREA * L / N
        bodies = [hub]
        for k in range(N):
            J = np.diag([1e-6 * m * l * l, m * l * l / 12, m * l * l / 12])
            spring = jaxtree.SpringDamper((2.0 if k == 0 else 1.0) * EI / l, 0.0)
            on_parent = (HUB_POINT, 0.0, 0.0) if k == 0 else (l / 2, 0.0, 0.0)
            bodies.append(jaxtree.Body(f"s{k + 1}", m, J, k, (0, 0, 1), on_parent, (-l / 2, 0, 0), spring))
        return jaxtree.build_model(bodies).with_loads(torque)

    def chain_tip(gamma, N):
        return np.sum(L / N * np.sin(np.cumsum(np.asarray(gamma), 1)), 1)

    print(machine())
    print(f"jaxtree {jaxtree.__version__}, jax {jax.__version__}; target {args.target:g} of the peak tip deflection")

    def full(N, tol):
        model = chain(N)
        return lambda: jaxtree.simulate(
            model, T1, saveat=ts, solver=jaxtree.Radau5(), rtol=tol, atol=tol, max_steps=200_000
        )

    refs = []
    for N in (32, 64):
        sol = full(N, 1e-10)()
        refs.append(chain_tip(sol.gamma, N))
    ref = (4 * refs[1] - refs[0]) / 3
    peak = float(np.abs(ref).max())
    print(
        f"reference: chains of 32 and 64 segments extrapolated; peak tip deflection {peak:.4f} m "
        f"(the two chains differ by {np.abs(refs[0] - refs[1]).max() / peak:.2e} of it)"
    )

    rows = []

    def ladder(label, make, tip, tols):
        """The loosest tolerance that meets the target; the first call of the ladder (its
        compilation: the tolerance is traced, later rungs reuse it)."""
        compile_s = None
        for tol in tols:
            out, first, med = timed(make(tol), args.repeats)
            compile_s = first if compile_s is None else compile_s
            err = float(np.abs(tip(out) - ref).max() / peak)
            if err <= args.target:
                rows.append(dict(method=label, setting=f"{tol:g}", error=err, first_s=compile_s, run_ms=1e3 * med))
                return True
        rows.append(
            dict(
                method=label + " (target missed)",
                setting=f"{tols[-1]:g}",
                error=err,
                first_s=compile_s,
                run_ms=1e3 * med,
            )
        )
        return False

    vehicle = jaxtree.build_model([hub]).with_loads(torque)
    ap = jaxtree.appendage(
        jaxtree.beam(L, 40, E=E, rho=RHO, area=AREA, Iy=4 * IY, Iz=IY), "hub", point=(HUB_POINT, 0, 0),
        n_modes=12, outputs=(40,),
    )  # fmt: skip
    hm = jaxtree.hybrid_model(vehicle, (), 3, appendages=[ap])
    fe_tip = lambda sol: np.asarray(jax.vmap(lambda y: hm.appendage_displacement(y))(sol.ys))[:, 1]
    fe_run = lambda tol: lambda: jaxtree.simulate_hybrid(hm, T1, saveat=ts, rtol=tol, atol=tol, truncation_error=False)
    ladder("fe hybrid (40 elements, 3 modes), Dopri8", fe_run, fe_tip, (1e-4, 1e-5, 1e-6, 1e-7, 1e-8))
    for N in (8, 16, 32):
        if ladder(
            f"chain {N}, Eq. (1), Radau5",
            lambda tol, N=N: full(N, tol),
            lambda s, N=N: chain_tip(s.gamma, N),
            (1e-4, 1e-6, 1e-8),
        ):
            break
    for N in (8, 16, 32, 64):
        hmc = jaxtree.hybrid_model(chain(N), tuple(range(1, N + 1)), 3)
        run = lambda tol, hmc=hmc: (
            lambda: jaxtree.simulate_hybrid(hmc, T1, saveat=ts, rtol=tol, atol=tol, truncation_error=False)
        )
        if ladder(
            f"chain {N}, hybrid (3 modes), Dopri8", run, lambda s, N=N: chain_tip(s.gamma, N), (1e-4, 1e-6, 1e-8)
        ):
            break

    print(f"\n{'method':44s} {'setting':>8s} {'error':>9s} {'run (ms)':>10s} {'first call (s)':>15s}")
    for r in rows:
        print(f"{r['method']:44s} {r['setting']:>8s} {r['error']:9.2e} {r['run_ms']:10.1f} {r['first_s']:15.1f}")
    if args.json:
        write_json(args.json, dict(machine=machine(), target=args.target, peak=peak, rows=rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
