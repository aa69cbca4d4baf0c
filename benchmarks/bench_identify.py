"""Parameter identification: `jaxtree.identify` against the finite-difference route, in the same run.

The problem is examples/identify_wings.py's: the `wings` vehicle; six parameters (each wing's hinge
stiffness and damping, the tip panel's mass and I_yy), fitted as logarithms from the nominal
scene; a 20 s record at 10 Hz of the hub's rate (noise 2e-6 rad/s) and the two root hinge
angles (2e-5 rad); integration tolerance 1e-10 for the record and the fits.

- jaxtree, in a fresh process with JAX's persistent cache off (`JAXTREE_CACHE_DIR=0`): the first
  `identify` call (compilation included; JAX's trace, lowering and XLA seconds and programs from
  `jax.monitoring`), the same call again, a noise-free record, 24 parameters (every hinge's
  stiffness and damping and every panel's mass: the time of one simulation with its Jacobian
  against the 6-parameter fit's), and 16 vehicles at once (their true parameters dispersed 10 %)
  against single fits.
- The peer, in this process: `scipy.optimize.least_squares` (method "lm", forward-difference
  Jacobians) over Pinocchio's ABA integrated by scipy's DOP853 at the same tolerance, same
  record, same start, same sensors (benchmarks/_identify_problem.py).

    python benchmarks/bench_identify.py [--members 16] [--singles 16] [--skip-peer]

Writes benchmarks/results/bench_identify.{txt,json}.
"""

import argparse
import json
import os
import pathlib
import subprocess
import sys

from _common import machine, write_json

HERE = pathlib.Path(__file__).resolve().parent

_CHILD = r"""
import collections, json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
import jax, jax.numpy as jnp
from jax import monitoring

events = collections.defaultdict(lambda: [0.0, 0])


def listen(name, secs, **kw):
    events[name.rsplit("/", 1)[-1]][0] += secs
    events[name.rsplit("/", 1)[-1]][1] += 1


monitoring.register_event_duration_secs_listener(listen)
import warnings
import jaxtree
import _identify_problem as P

members, singles = int(sys.argv[2]), int(sys.argv[3])
out = {}
model = jaxtree.load_scene(P.SCENE)
ts = P.times()
t0 = time.perf_counter()
data = P.record(model, P.FREE6, P.TRUTH6)
out["record_s"] = time.perf_counter() - t0
np.savez(sys.argv[4], **data)
events.clear()


def fit(free, data, **kw):
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        f = jaxtree.identify(model, free, ts, data, P.SIGMA, rtol=P.TOL, atol=P.TOL, **kw)
    return f, time.perf_counter() - t0


f, out["first_s"] = fit(P.FREE6, data)
out["first_events"] = {k: list(v) for k, v in events.items()}
f, out["again_s"] = fit(P.FREE6, data)
out["steps"] = f.steps
out["values"], out["stderr"], out["converged"] = f.values, f.stderr, f.converged
# a noise-free record gives the truth back
clean = P.record(model, P.FREE6, P.TRUTH6, noise=False)
h, _ = fit(P.FREE6, clean)
out["noise_free_rel"] = max(abs(h.values[n] / P.TRUTH6[n] - 1) for n in P.FREE6)
# 24 parameters: every hinge's stiffness and damping and every panel's mass; the time of one
# simulation with its Jacobian at the fit's tolerance (no coarse phase), the least of three fits of
# four simulations, against the 6-parameter fit's measured the same way
free24 = P.free24(model)
rng = np.random.default_rng(5)
truth24 = {}
for q in free24:
    nominal = {"stiffness": 100.0, "damping": 0.5, "mass": 5.0}[q.rsplit(".", 1)[1]]
    truth24[q] = nominal * (1 + 0.1 * rng.standard_normal())
data24 = P.record(model, free24, truth24)
k, first24 = fit(free24, data24, coarse_tol=None, max_steps=4)
walls = [fit(free24, data24, coarse_tol=None, max_steps=4) for _ in range(3)]
out["per_simulation_24_s"], out["first_24_s"] = min(w / f.steps for f, w in walls), first24
walls = [fit(P.FREE6, data, coarse_tol=None, max_steps=4) for _ in range(3)]
out["per_simulation_6_s"] = min(w / f.steps for f, w in walls)
# many vehicles at once against single fits
if members:
    thetas = []
    recs = []
    for i in range(members):
        r = np.random.default_rng(100 + i)
        truth = P.dispersed(P.TRUTH6, r)
        thetas.append(truth)
        recs.append(P.record(model, P.FREE6, truth, seed=100 + i))
    batch = {s: np.stack([rec[s] for rec in recs]) for s in P.SIGMA}
    b, out["batch_first_s"] = fit(P.FREE6, batch)
    b, out["batch_s"] = fit(P.FREE6, batch)
    out["batch_steps"] = [int(x) for x in np.asarray(b.steps)]
    walls, offs = [], []
    for i in range(singles):
        one, wall = fit(P.FREE6, recs[i])
        walls.append(wall)
        offs.append(max(abs(b.values[n][i] - one.values[n]) / one.stderr[n] for n in P.FREE6))
    out["single_mean_s"] = float(np.mean(walls))
    out["batch_vs_single_off_sigma"] = float(max(offs))
print(json.dumps(out, default=float))
"""


def child(members, singles, record_path):
    env = dict(os.environ, JAXTREE_CACHE_DIR="0", JAXTREE_PROGRAM_CACHE="0")
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, str(HERE), str(members), str(singles), record_path],
        env=env,
        capture_output=True,
        text=True,
        timeout=3000,
    )
    if done.returncode != 0:
        raise RuntimeError(done.stderr[-4000:])
    return json.loads(done.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--members", type=int, default=16, help="vehicles fitted at once (0: none)")
    ap.add_argument(
        "--singles", type=int, default=16, help="of them, fitted one by one for the comparison (default all)"
    )
    ap.add_argument("--skip-peer", action="store_true", help="leave the finite-difference peer out")
    args = ap.parse_args()

    import tempfile

    import numpy as np

    record_path = os.path.join(tempfile.mkdtemp(prefix="bench-identify-"), "record.npz")
    ours = child(args.members, args.singles, record_path)
    lines = ["# bench_identify: jaxtree.identify against scipy least_squares + Pinocchio ABA + DOP853", machine(), ""]
    ev = ours["first_events"]
    get = lambda k: ev.get(k, [0.0, 0])
    lines.append(
        f"jaxtree first call (fresh process, no cache): {ours['first_s']:.1f} s (XLA {get('backend_compile_duration')[0]:.1f} s "
        f"in {get('backend_compile_duration')[1]} programs, trace {get('jaxpr_trace_duration')[0]:.1f} s, lowering "
        f"{get('jaxpr_to_mlir_module_duration')[0]:.1f} s); the record before it {ours['record_s']:.1f} s"
    )
    lines.append(f"jaxtree again: {ours['again_s']:.2f} s, {ours['steps']} simulations")
    lines.append(
        f"one simulation with its Jacobian at tol {1e-10:g}: 6 parameters {ours['per_simulation_6_s'] * 1e3:.0f} ms, "
        f"24 parameters {ours['per_simulation_24_s'] * 1e3:.0f} ms: {ours['per_simulation_24_s'] / ours['per_simulation_6_s']:.2f}x "
        f"(goal <= 2x; 24-parameter first call {ours['first_24_s']:.1f} s)"
    )
    lines.append(
        f"noise-free record: largest relative error of the estimates {ours['noise_free_rel']:.1e} (goal <= 1e-6)"
    )
    result = {"machine": machine(), "jaxtree": ours}
    if args.members:
        sixteen = args.members * ours["single_mean_s"]
        lines.append(
            f"{args.members} vehicles at once: {ours['batch_s']:.1f} s (first call {ours['batch_first_s']:.1f} s; simulations "
            f"{min(ours['batch_steps'])}-{max(ours['batch_steps'])}); {args.members} single fits {sixteen:.1f} s "
            f"({'all' if args.singles >= args.members else f'mean of {args.singles}'}: {ours['single_mean_s']:.2f} s each): {ours['batch_s'] / sixteen:.3f} of their time (goal <= 0.25; the members on threads over the cores); "
            f"batch against single fits {ours['batch_vs_single_off_sigma']:.1e} standard errors"
        )
    if not args.skip_peer:
        sys.path.insert(0, str(HERE))
        import _identify_problem as P

        import jaxtree

        model = jaxtree.load_scene(P.SCENE)
        data = dict(np.load(record_path))
        values, stderr, sims, wall = P.peer_fit(model, P.FREE6, data)
        off = max(abs(ours["values"][n] - values[n]) / ours["stderr"][n] for n in values)
        lines.append(f"peer: {wall:.1f} s, {sims} simulations ({wall / sims * 1e3:.0f} ms each)")
        lines.append(
            f"jaxtree against the peer: first call {ours['first_s'] / wall:.2f}x (goal <= 0.5), again "
            f"{ours['again_s'] / wall:.3f}x (goal <= 0.1); estimates differ by {off:.1e} standard errors at most (goal <= 1e-3)"
        )
        result["peer"] = {"wall_s": wall, "simulations": sims, "values": values, "stderr": stderr, "off_sigma": off}
    text = "\n".join(lines)
    print(text)
    results = HERE / "results"
    results.mkdir(exist_ok=True)
    from jaxtree._src.atomic import atomic_write

    with atomic_write(results / "bench_identify.txt", "w") as fh:
        fh.write(text + "\n")
    write_json(results / "bench_identify.json", result)


if __name__ == "__main__":
    main()
