#!/usr/bin/env python3
"""Numerical stability on stiff and extreme cases (a report with figures, not a test).

Prints the machine and versions, then five studies; every accuracy figure is measured against
something independent of the code under test:

1. **A stiff hinge** (chain10 with the tip hinge's spring stiffened by s = 1 ... 1e6 and damped at a
   ratio of 0.7, the other hinges soft and lightly damped: time scales s^(1/2) apart, the fast
   one decaying, i.e. a stiff problem). Explicit Dopri8 against implicit Kvaerno5 (diffrax,
   passed straight through ``simulate``; its Newton iterations differentiate Eq. (1) by
   autodiff), both at rtol = atol = 1e-6 over 1 s: steps, run time after compile, and the
   error against a tight Dopri8 run (rtol 1e-11).
2. **Mass ratios** (chain10 with the segments' masses and inertias scaled by r = 1e3 ... 1e-9):
   the condition number of Eq. (1)'s matrix, its difference from the matrix of the
   independent Lagrange oracle (``tests/oracle.py``: kinetic energy from scratch, Hessian by
   autodiff), the backward error ``|A x - b| / (|A| |x| + |b|)`` of the solve, and the
   accelerations' difference from the oracle's (which solves by least squares).
3. **Near gimbal lock** (fig4_free, inner gimbal at 90 deg - delta): the same figures as
   delta -> 0.
4. **Fast spin** (fig4_free, rotor rate x 1, 10, 100, i.e. up to 3142 rad/s): 10 s at
   rtol = atol = 1e-10: steps, run time, relative drift of energy and of angular momentum (both
   conserved: no damping, no loads).
5. **Many bodies** (chain200): matrix and accelerations against the oracle at random states,
   and the energy and momentum drift of a 1 s run at rtol = atol = 1e-10 (the chain starts with
   no angular momentum: its drift is measured against ``sqrt(2 E I_max)``, the momentum of the
   vehicle turning rigidly with its energy).

Run:  python benchmarks/bench_stability.py [--quick] [--json results/bench_stability.json]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

from _common import machine, timed, write_json

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
from oracle import oracle_eom


def say(*a):
    print(*a, flush=True)


def tree_arrays(model):
    return (
        list(model.topology.parents),
        np.asarray(model.mass),
        np.asarray(model.inertia),
        np.asarray(model.axis),
        np.asarray(model.hinge_on_parent),
        np.asarray(model.hinge_on_body),
    )


def random_state(model, rng, scale=0.5):
    n = model.n
    return jaxtree.State(
        jnp.eye(3),
        jnp.asarray(rng.normal(0, scale, 3)),
        jnp.asarray(rng.normal(0, scale, n)),
        jnp.asarray(rng.normal(0, scale, n)),
    )


def against_oracle(model, state):
    """cond(A), |A - A_oracle| / |A|, backward error of the solve, |x - x_oracle| / |x_oracle|."""
    tau = np.asarray(jaxtree.hinge_torques(model, state.gamma, state.gamma_dot))
    A, b = (np.asarray(x) for x in jaxtree.rotational_equations(model, state))
    w, g = jax.jit(jaxtree.forward_dynamics)(model, state.dcm, state.omega0, state.gamma, state.gamma_dot)
    x = np.concatenate([np.asarray(w), np.asarray(g)])
    o = oracle_eom(
        *tree_arrays(model), np.asarray(state.omega0), np.asarray(state.gamma), np.asarray(state.gamma_dot), tau=tau
    )
    Ao = np.asarray(o["mass_matrix"])
    xo = np.concatenate([np.asarray(o["omega0_dot"]), np.asarray(o["gamma_ddot"])])
    norm = lambda v: np.abs(v).max()
    return dict(
        cond=float(np.linalg.cond(A)),
        matrix=float(norm(A - Ao) / norm(A)),
        backward=float(norm(A @ x - b) / (norm(A) * norm(x) + norm(b))),
        forward=float(norm(x - xo) / norm(xo)),
    )


def worst(rows):
    return {k: max(r[k] for r in rows) for k in rows[0]}


# ----------------------------------------------------------------------------- 1. stiff springs
def stiff_hinge(args, out):
    base = jaxtree.load_scene("chain10")
    n = base.n
    # moment of inertia of each segment about its own hinge axis (parallel axes), for damping ratios
    axis = np.asarray(base.axis)
    hob = np.asarray(base.hinge_on_body)
    I_h = np.einsum("ki,kij,kj->k", axis, np.asarray(base.inertia)[1:], axis) + np.asarray(base.mass)[1:] * np.sum(
        np.cross(axis, hob) ** 2, 1
    )
    k0 = np.asarray(base.stiffness)
    scales = (1.0, 1e3, 1e6) if args.quick else (1.0, 1e2, 1e4, 1e6)
    say(
        "\n1. one stiff, damped hinge in a soft chain: chain10, the tip hinge's spring x s (damping ratio 0.7), "
        "the others as in the scene (damping ratio 0.02); 1 s, rtol = atol = 1e-6"
    )
    say(f"   {'s':>6} {'f_max Hz':>9} {'solver':>9} {'steps':>7} {'rejected':>8} {'run ms':>8} {'error':>9}")
    rows = []
    for s in scales:
        k = k0.copy()
        k[-1] *= s
        zeta = np.full(n, 0.02)
        zeta[-1] = 0.7
        c = 2 * zeta * np.sqrt(k * I_h)
        model = eqx.tree_at(lambda m: (m.stiffness, m.damping), base, (jnp.asarray(k), jnp.asarray(c)))
        lin = jaxtree.linearize(model, small=tuple(range(1, n + 1)))
        f_max = float(
            np.sqrt(np.max(np.linalg.eigvals(np.linalg.solve(np.asarray(lin.I), np.asarray(lin.K))).real)) / (2 * np.pi)
        )
        ref = jaxtree.simulate(model, 1.0, saveat=11, rtol=1e-11, atol=1e-11, max_steps=2_000_000)
        for name, solver in (("Dopri8", dfx.Dopri8()), ("Kvaerno5", dfx.Kvaerno5())):
            fn = lambda: jaxtree.simulate(
                model, 1.0, saveat=11, solver=solver, rtol=1e-6, atol=1e-6, max_steps=1_000_000, throw=False
            )
            sol, first, best = timed(fn, args.repeats)
            err = float(np.abs(np.asarray(sol.gamma) - np.asarray(ref.gamma)).max()) if sol.ok else float("nan")
            row = dict(
                s=s,
                f_max_hz=f_max,
                solver=name,
                ok=bool(sol.ok),
                steps=int(sol.stats["num_accepted_steps"]),
                rejected=int(sol.stats["num_rejected_steps"]),
                first_call_s=first,
                run_s=best,
                error=err,
            )
            rows.append(row)
            say(
                f"   {s:6.0e} {f_max:9.3g} {name:>9} {row['steps']:7d} {row['rejected']:8d} {1e3 * best:8.1f} "
                f"{err:9.2e}{'' if sol.ok else '  FAILED: ' + str(sol.result)}"
            )
    out["stiff_hinge"] = rows


# ----------------------------------------------------------------------------- 2. mass ratios
def mass_ratios(args, out):
    base = jaxtree.load_scene("chain10")
    rng = np.random.default_rng(1)
    ratios = (1e3, 1.0, 1e-3, 1e-6, 1e-9)
    say(
        "\n2. mass ratios: chain10 with segment mass and inertia x r (hub 100 kg), random states; worst of "
        f"{args.states}"
    )
    say(f"   {'r':>6} {'cond(A)':>9} {'|A-Ao|/|A|':>11} {'backward':>9} {'|x-xo|/|xo|':>11}")
    rows = []
    for r in ratios:
        scale = jnp.asarray(np.r_[1.0, np.full(base.n, r)])
        model = eqx.tree_at(
            lambda m: (m.mass, m.inertia), base, (base.mass * scale, base.inertia * scale[:, None, None])
        )
        w = worst([against_oracle(model, random_state(model, rng)) for _ in range(args.states)])
        rows.append(dict(r=r, **w))
        say(f"   {r:6.0e} {w['cond']:9.2e} {w['matrix']:11.2e} {w['backward']:9.2e} {w['forward']:11.2e}")
    out["mass_ratios"] = rows


# ----------------------------------------------------------------------------- 3. gimbal lock
def gimbal_lock(args, out):
    model = jaxtree.load_scene("fig4_free")  # no prescribed hinge: A x = b on every row
    s = model.initial
    say("\n3. near gimbal lock: fig4_free, inner gimbal (hinge 3) at 90 deg - delta")
    say(f"   {'delta':>6} {'cond(A)':>9} {'|A-Ao|/|A|':>11} {'backward':>9} {'|x-xo|/|xo|':>11}")
    rows = []
    for delta in (1e-1, 1e-2, 1e-4, 1e-6):
        gamma = np.asarray(s.gamma, float).copy()
        gamma[2] = np.pi / 2 - delta
        w = against_oracle(model, s._replace(gamma=jnp.asarray(gamma)))
        rows.append(dict(delta=delta, **w))
        say(f"   {delta:6.0e} {w['cond']:9.2e} {w['matrix']:11.2e} {w['backward']:9.2e} {w['forward']:11.2e}")
    out["gimbal_lock"] = rows


# ----------------------------------------------------------------------------- 4. fast spin
def drift(model, sol):
    """Relative drift of the energy and of the angular momentum. The momentum's scale is |H(0)|,
    or, when the vehicle starts with none, ``sqrt(2 E I_max)``: the momentum of the whole vehicle
    turning rigidly with its energy E about the axis of its largest moment of inertia I_max (the
    omega0 block of Eq. (1)'s matrix is the vehicle's inertia about its mass center)."""
    E = np.asarray(sol.energy)
    H = np.asarray(sol.angular_momentum)
    dH = float(np.linalg.norm(H - H[0], axis=1).max())
    scale = float(np.linalg.norm(H[0]))
    if scale == 0.0:
        J = np.asarray(jaxtree.mass_matrix(model, model.initial.gamma))[:3, :3]
        scale = float(np.sqrt(2 * abs(E[0]) * np.linalg.eigvalsh(J).max()))
    return float(np.abs(E - E[0]).max() / abs(E[0])), dH / scale


def fast_spin(args, out):
    base = jaxtree.load_scene("fig4_free")
    say("\n4. fast spin: fig4_free, initial hinge rates (the rotor's) x f, 10 s, rtol = atol = 1e-10")
    say(f"   {'rate rad/s':>10} {'steps':>7} {'run ms':>8} {'energy drift':>13} {'momentum drift':>15}")
    rows = []
    for f in (1.0, 10.0, 100.0):
        y0 = base.initial._replace(gamma_dot=base.initial.gamma_dot * f)
        rate = float(np.abs(np.asarray(y0.gamma_dot)).max())
        fn = lambda: jaxtree.simulate(base, 10.0, y0=y0, rtol=1e-10, atol=1e-10, max_steps=1_000_000)
        sol, first, best = timed(fn, args.repeats)
        dE, dH = drift(base, sol)
        rows.append(
            dict(
                factor=f,
                rate=rate,
                steps=int(sol.stats["num_accepted_steps"]),
                run_s=best,
                energy_drift=dE,
                momentum_drift=dH,
            )
        )
        say(f"   {rate:10.1f} {rows[-1]['steps']:7d} {1e3 * best:8.1f} {dE:13.2e} {dH:15.2e}")
    out["fast_spin"] = rows


# ----------------------------------------------------------------------------- 5. many bodies
def many_bodies(args, out):
    model = jaxtree.load_scene("chain200")
    rng = np.random.default_rng(2)
    say(f"\n5. many bodies: chain200 (n = {model.n})")
    t = time.perf_counter()
    w = worst([against_oracle(model, random_state(model, rng, 0.05)) for _ in range(2)])
    say(
        f"   random states (angles and rates of scale 0.05): cond(A) {w['cond']:.2e}, |A-Ao|/|A| {w['matrix']:.2e}, "
        f"backward {w['backward']:.2e}, |x-xo|/|xo| {w['forward']:.2e} ({time.perf_counter() - t:.0f} s with the oracle)"
    )
    fn = lambda: jaxtree.simulate(model, 1.0, rtol=1e-10, atol=1e-10, max_steps=1_000_000)
    sol, first, best = timed(fn, 1)
    dE, dH = drift(model, sol)
    say(
        f"   1 s at rtol = atol = 1e-10: {int(sol.stats['num_accepted_steps'])} steps, compile+run {first:.1f} s, "
        f"run {best:.2f} s; energy drift {dE:.2e}, angular momentum drift {dH:.2e} (H(0) = 0: relative to "
        f"sqrt(2 E I_max))"
    )
    out["many_bodies"] = dict(
        w,
        steps=int(sol.stats["num_accepted_steps"]),
        first_call_s=first,
        run_s=best,
        energy_drift=dE,
        momentum_drift=dH,
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer cases and repeats")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    args.repeats = 1 if args.quick else 3
    args.states = 2 if args.quick else 5
    say("bench_stability: " + machine())
    out = {"machine": machine()}
    t = time.perf_counter()
    for study in (stiff_hinge, mass_ratios, gimbal_lock, fast_spin, many_bodies):
        study(args, out)
    say(f"\ntotal {time.perf_counter() - t:.0f} s")
    if args.json:
        write_json(args.json, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
