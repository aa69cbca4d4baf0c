"""Identify the hinge stiffness and damping of two solar wings, and a panel's mass and inertia, from a
gyro and hinge-angle record, with `jaxtree.identify`.

The bundled `wings` scene is a 500 kg hub with two wings of four hinged panels each (spring-damper
hinges, 100 N m/rad and 0.5 N m s/rad in the scene). Here the "flight" wings differ from the
nominal ones: each wing has its own stiffness and damping (all four hinges of a wing alike), and
the tip panel of wing + is heavier than built (its mass and its moment of inertia about its hinge
axis, the y axis, differ from the scene's). A record of 20 s is simulated with those true values --
the hub's angular rate (a gyro, 10 Hz, noise 2e-6 rad/s) and the two root hinge angles
(potentiometers, noise 2e-5 rad) -- and the six parameters are estimated from the nominal ones.

`jaxtree.identify` takes the parameters and the sensors by name, fits the positive ones as
logarithms by Levenberg-Marquardt through the simulation (forward-mode Jacobians: one tangent per
parameter, all riding one simulation) and returns the estimates with their standard errors from
the Gauss-Newton covariance, the correlations, and the residuals in units of each sensor's sigma.

With ``--batch N`` it fits N vehicles at once instead (a members axis on the record), each with
its own true parameters (TRUTH's dispersed by 10 %) and noisy record, and compares the time and
the estimates with single fits of the first ``--singles`` of them.

Run:  python examples/identify_wings.py [--noise-free] [--seed N] [--plot residuals.png] [--batch 16 [--singles 4]]
"""

from __future__ import annotations

import argparse
import time

import jax.numpy as jnp
import numpy as np

import jaxtree

SCENE = "wings"
DURATION, RATE = 20.0, 10.0  # s, Hz
SIGMA = {"hub.omega": 2e-6, "wingp_1.angle": 2e-5, "wingm_1.angle": 2e-5}  # a gyro (rad/s), potentiometers (rad)
# the parameters, by name: each wing's hinges share one stiffness and one damping
FREE = {
    "stiffness wing +": [f"wingp_{i}.stiffness" for i in range(1, 5)],
    "stiffness wing -": [f"wingm_{i}.stiffness" for i in range(1, 5)],
    "damping wing +": [f"wingp_{i}.damping" for i in range(1, 5)],
    "damping wing -": [f"wingm_{i}.damping" for i in range(1, 5)],
    "tip panel mass": ["wingp_4.mass"],
    "tip panel I_yy": ["wingp_4.inertia[1,1]"],
}
TRUTH = {
    "stiffness wing +": 115.0,
    "stiffness wing -": 85.0,
    "damping wing +": 0.65,
    "damping wing -": 0.40,
    "tip panel mass": 5.6,
    "tip panel I_yy": 0.47,
}
TOL = 1e-10  # integration tolerance of the record and of the fit


def flight_model(model, truth=TRUTH):
    """The vehicle that flew: `model` with the `truth` values set, quantity by quantity."""
    return jaxtree.with_quantities(model, {q: truth[name] for name, qs in FREE.items() for q in qs})


def record(model, ts, noise: bool = True, seed: int = 0, truth=TRUTH):
    """The flight record: dict sensor -> readings at `ts`, with the sensors' noise or without."""
    sol = jaxtree.simulate(flight_model(model, truth), ts[-1], saveat=jnp.asarray(ts), rtol=TOL, atol=TOL)
    clean = {
        "hub.omega": np.asarray(sol.omega0),  # the hub's rate in its own frame (body 0: omega0)
        "wingp_1.angle": np.asarray(sol.gamma[:, model.names.index("wingp_1") - 1]),
        "wingm_1.angle": np.asarray(sol.gamma[:, model.names.index("wingm_1") - 1]),
    }
    if not noise:
        return clean
    rng = np.random.default_rng(seed)
    return {k: v + SIGMA[k] * rng.standard_normal(v.shape) for k, v in clean.items()}


def fleet(model, ts, size: int, seed: int = 0):
    """`size` vehicles whose true parameters are TRUTH's dispersed by 10 % (one standard
    deviation; the tip panel's I_yy kept physical), and their noisy records stacked on a leading
    members axis: (truths, record)."""
    rng = np.random.default_rng(seed)
    truths = [{k: v * (1 + 0.1 * rng.standard_normal()) for k, v in TRUTH.items()} for _ in range(size)]
    for t in truths:  # I_yy >= 0.42: with I_xx 0.267 and I_zz 0.683 the principal moments' triangle inequality
        t["tip panel I_yy"] = max(t["tip panel I_yy"], 0.42)
    records = [record(model, ts, seed=seed + 1 + i, truth=t) for i, t in enumerate(truths)]
    return truths, {s: np.stack([r[s] for r in records]) for s in SIGMA}


def batch_main(model, ts, size: int, singles: int, seed: int):
    """Fit `size` vehicles at once and `singles` of them one by one; compare times and estimates."""
    truths, data = fleet(model, ts, size, seed)
    t = time.perf_counter()
    fits = jaxtree.identify(model, FREE, ts, data, SIGMA, rtol=TOL, atol=TOL)
    first = time.perf_counter() - t
    t = time.perf_counter()
    fits = jaxtree.identify(model, FREE, ts, data, SIGMA, rtol=TOL, atol=TOL)
    wall_b = time.perf_counter() - t
    singles = min(singles, size)
    one = [jaxtree.identify(model, FREE, ts, {s: v[0] for s, v in data.items()}, SIGMA, rtol=TOL, atol=TOL)]
    t = time.perf_counter()
    one = [
        jaxtree.identify(model, FREE, ts, {s: v[i] for s, v in data.items()}, SIGMA, rtol=TOL, atol=TOL)
        for i in range(singles)
    ]
    wall_1 = (time.perf_counter() - t) / singles
    off = max(abs(fits.values[n][i] - one[i].values[n]) / one[i].stderr[n] for i in range(singles) for n in FREE)
    miss = [abs(fits.values[n][i] - truths[i][n]) / fits.stderr[n][i] for i in range(size) for n in FREE]
    print(f"{SCENE}: {size} vehicles, parameters dispersed 10 %, record {DURATION:g} s at {RATE:g} Hz with noise")
    print(
        f"batch of {size}: {wall_b:.2f} s ({first:.1f} s the first call, compile included); "
        f"simulations {int(np.min(fits.steps))}-{int(np.max(fits.steps))}"
    )
    print(
        f"single fit: {wall_1:.2f} s each (mean of {singles}); {size} single fits {size * wall_1:.1f} s: "
        f"the batch takes {wall_b / (size * wall_1):.3f} of their time"
    )
    print(f"batch against single fits: largest difference {off:.1e} standard errors (first {singles} members)")
    print(f"estimates against the truths: median {np.median(miss):.2f}, largest {np.max(miss):.2f} standard errors")
    return dict(batch_s=wall_b, first_s=first, single_s=wall_1, ratio=wall_b / (size * wall_1), off=off)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--noise-free", action="store_true", help="fit a record without sensor noise")
    ap.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    ap.add_argument("--plot", metavar="PNG", help="write the residual plot")
    ap.add_argument("--batch", type=int, default=0, help="fit this many dispersed vehicles at once instead")
    ap.add_argument("--singles", type=int, default=4, help="with --batch: members also fitted one by one")
    args = ap.parse_args()

    model = jaxtree.load_scene(SCENE)
    ts = np.linspace(0.0, DURATION, int(DURATION * RATE) + 1)
    if args.batch:
        batch_main(model, ts, args.batch, args.singles, args.seed)
        return
    data = record(model, ts, noise=not args.noise_free, seed=args.seed)
    t = time.perf_counter()
    fit = jaxtree.identify(model, FREE, ts, data, SIGMA, rtol=TOL, atol=TOL)
    wall = time.perf_counter() - t
    print(
        f"{SCENE}: {model.n} hinges; record {DURATION:g} s at {RATE:g} Hz, "
        f"{'no noise' if args.noise_free else 'noise ' + ', '.join(f'{k} {v:g}' for k, v in SIGMA.items())}"
    )
    print(f"jaxtree.identify: {fit.steps} simulations, {wall:.1f} s (compile included)")
    print(fit.table(truth=TRUTH))
    if args.plot:
        jaxtree.plot_residuals(fit, ts, args.plot)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
