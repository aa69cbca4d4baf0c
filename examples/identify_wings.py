"""Identify the hinge stiffness and damping of two solar wings, and a panel's mass and inertia, from a
gyro and hinge-angle record.

Gradient-based parameter identification through the simulation. The bundled `wings` scene is a
500 kg hub with two wings of four hinged panels each (spring-damper hinges, 100 N m/rad and
0.5 N m s/rad in the scene). Here the "flight" wings differ from the nominal ones: each wing has
its own stiffness and damping (all four hinges of a wing alike), and the tip panel of wing + is
heavier than built (its mass and its moment of inertia about its hinge axis, the y axis, differ
from the scene's). A record of 20 s is simulated
with those true values -- the hub's angular rate (a gyro, 10 Hz, noise 2e-6 rad/s) and the two
root hinge angles (potentiometers, noise 2e-5 rad) -- and the six parameters are then estimated
from the nominal ones by Levenberg-Marquardt (optimistix) on the weighted residuals. The
Jacobian of the residuals is taken by forward-mode differentiation through diffrax
(``adjoint=diffrax.ForwardMode()``: six parameters, one tangent each). The estimates are
printed with their standard errors from the Gauss-Newton covariance ``(J^T J)^-1`` at the
solution, and how many standard errors each lies from the truth.

Parameters are fitted as logarithms, so they stay positive and are scaled alike.

With ``--batch N`` it fits N vehicles at once instead (``fit_many``: one compiled
Levenberg-Marquardt over the vmapped residuals), each with its own true parameters (TRUTH's
dispersed by 10 %) and noisy record, and compares the time and the estimates with single fits
of the first ``--singles`` of them.

Run:  python examples/identify_wings.py [--noise-free] [--seed N] [--batch 32 [--singles 8]]
"""

from __future__ import annotations

import argparse
import time

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import jaxtree

SCENE = "wings"
DURATION, RATE = 20.0, 10.0  # s, Hz
SIGMA_GYRO, SIGMA_ANGLE = 2e-6, 2e-5  # rad/s, rad
TRUTH = {
    "stiffness": (115.0, 85.0),
    "damping": (0.65, 0.40),  # (wing +, wing -)
    "tip": (5.6, 0.47),
}  # mass (kg) and I_yy (kg m^2) of the tip panel of wing +
NAMES = ("stiffness wing +", "stiffness wing -", "damping wing +", "damping wing -", "tip panel mass", "tip panel I_yy")
TOL = 1e-10  # integration tolerance of the record and of the fit


def wing_hinges(model) -> tuple[np.ndarray, np.ndarray]:
    """0-based hinge indices of the two wings: the outboard sets of the hub's two children."""
    eps = model.topology.path_elements  # eps[s-1, k] = 1 when body k is outboard of hinge s
    roots = [k for k in range(1, model.n + 1) if model.topology.parents[k - 1] == 0]
    if len(roots) != 2:
        raise ValueError(f"expected two wings on the hub, found {len(roots)}")
    return tuple(np.flatnonzero(eps[r - 1, 1:]) for r in roots)


def tip_body(model) -> int:
    """The outermost panel of wing + (the body of its last hinge)."""
    plus, _ = wing_hinges(model)
    return int(plus[-1]) + 1


def with_parameters(model, theta):
    """`model` with ``exp(theta)``: theta = log [k+, k-, c+, c-, m_tip, I_yy tip] (per-wing
    stiffness and damping, the mass and the moment of inertia about its hinge axis of wing +'s tip
    panel)."""
    plus, minus = wing_hinges(model)
    k, c, tip = jnp.exp(theta[:2]), jnp.exp(theta[2:4]), jnp.exp(theta[4:6])
    stiffness = model.stiffness.at[plus].set(k[0]).at[minus].set(k[1])
    damping = model.damping.at[plus].set(c[0]).at[minus].set(c[1])
    b = tip_body(model)
    mass = model.mass.at[b].set(tip[0])
    inertia = model.inertia.at[b, 1, 1].set(tip[1])
    return eqx.tree_at(
        lambda m: (m.stiffness, m.damping, m.mass, m.inertia), model, (stiffness, damping, mass, inertia)
    )


def truth():
    """The true log-parameters."""
    return jnp.log(jnp.asarray(TRUTH["stiffness"] + TRUTH["damping"] + TRUTH["tip"]))


def measure(model, ts):
    """What the sensors see: hub rate (times x 3) and the two root hinge angles (times x 2),
    flattened and divided by their noise levels."""
    roots = [w[0] for w in wing_hinges(model)]
    sol = jaxtree.simulate(model, ts[-1], saveat=ts, rtol=TOL, atol=TOL, adjoint=dfx.ForwardMode())
    return jnp.concatenate([sol.omega0.ravel() / SIGMA_GYRO, sol.gamma[:, roots].ravel() / SIGMA_ANGLE])


def record(model, ts, noise: bool, seed: int = 0):
    """The flight record of the true wings, with sensor noise (in units of its sigma) or without."""
    clean = measure(with_parameters(model, truth()), ts)
    if not noise:
        return clean
    return clean + np.random.default_rng(seed).standard_normal(clean.shape)


def _fit(model, ts, data, theta0, max_steps: int = 50):
    """Levenberg-Marquardt on the weighted residuals; returns (theta, standard errors, steps)."""

    def residuals(theta, data):
        return measure(with_parameters(model, theta), ts) - data

    # Stop when a step changes the log-parameters by < 1e-8 relative and no residual by more
    # than 1e-4 of its noise: the integration tolerance (1e-10 on angles of ~0.05 rad) leaves
    # the simulated record that much jitter from one parameter set to the next.
    solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-4)
    sol = optx.least_squares(residuals, solver, theta0, args=data, max_steps=max_steps, throw=True)
    J = jax.jacfwd(residuals)(sol.value, data)
    covariance = jnp.linalg.inv(J.T @ J)  # residuals in units of their noise: the Fisher information
    return sol.value, jnp.sqrt(jnp.diag(covariance)), sol.stats["num_steps"]


fit = eqx.filter_jit(_fit)


@eqx.filter_jit
def fit_many(model, ts, data, theta0, max_steps: int = 50):
    """`fit` of many records at once (leading axis of `data` and `theta0`): one compiled
    Levenberg-Marquardt over the vmapped residuals. Each member keeps its own iterates, damping
    and stopping test (``vmap`` of the solver's loop runs until the last member stops and
    freezes the others), so each estimate is its single fit's."""
    return jax.vmap(lambda d, t: _fit(model, ts, d, t, max_steps))(data, theta0)


def fleet(model, ts, size: int, seed: int = 0):
    """`size` vehicles whose true log-parameters are TRUTH's dispersed by 10 % (one standard
    deviation), and their records with sensor noise: (true thetas, records)."""
    rng = np.random.default_rng(seed)
    thetas = truth()[None, :] + jnp.log1p(0.1 * jnp.asarray(rng.standard_normal((size, 6))))
    clean = jax.jit(jax.vmap(lambda th: measure(with_parameters(model, th), ts)))(thetas)
    return thetas, clean + rng.standard_normal(clean.shape)


def batch_main(model, ts, size: int, singles: int, seed: int):
    """Fit `size` vehicles at once and `singles` of them one by one; compare times and estimates."""
    thetas, data = fleet(model, ts, size, seed)
    theta0 = jnp.broadcast_to(nominal(model), thetas.shape)
    t = time.perf_counter()
    jax.block_until_ready(fit_many(model, ts, data, theta0))
    first = time.perf_counter() - t
    t = time.perf_counter()
    theta_b, stderr_b, steps_b = jax.block_until_ready(fit_many(model, ts, data, theta0))
    wall_b = time.perf_counter() - t
    jax.block_until_ready(fit(model, ts, data[0], theta0[0]))  # compiles the single fit
    singles = min(singles, size)
    t = time.perf_counter()
    one = [jax.block_until_ready(fit(model, ts, data[i], theta0[i])) for i in range(singles)]
    wall_1 = (time.perf_counter() - t) / singles
    # difference from each member's own single fit, in its standard errors
    off = max(float(jnp.max(jnp.abs(theta_b[i] - one[i][0]) / one[i][1])) for i in range(singles))
    miss = np.abs(np.asarray(theta_b - thetas) / np.asarray(stderr_b))
    print(f"{SCENE}: {size} vehicles, parameters dispersed 10 %, record {DURATION:g} s at {RATE:g} Hz with noise")
    print(
        f"batch of {size}: {wall_b:.2f} s ({first:.1f} s the first call, compile included); "
        f"Levenberg-Marquardt steps {int(jnp.min(steps_b))}-{int(jnp.max(steps_b))}"
    )
    print(
        f"single fit: {wall_1:.2f} s each (mean of {singles}); {size} single fits {size * wall_1:.1f} s: "
        f"the batch takes {wall_b / (size * wall_1):.3f} of their time (goal <= 1/8 = 0.125)"
    )
    print(f"batch against single fits: largest difference {off:.1e} standard errors (first {singles} members)")
    print(f"estimates against the truths: median {np.median(miss):.2f}, largest {np.max(miss):.2f} standard errors")
    return dict(batch_s=wall_b, first_s=first, single_s=wall_1, ratio=wall_b / (size * wall_1), off=off)


def nominal(model):
    """Log-parameters of the scene's own wings (the starting guess): all hinges alike there."""
    plus, _ = wing_hinges(model)
    b = tip_body(model)
    return jnp.log(
        jnp.stack(
            [model.stiffness[plus[0]]] * 2 + [model.damping[plus[0]]] * 2 + [model.mass[b], model.inertia[b, 1, 1]]
        )
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--noise-free", action="store_true", help="fit a record without sensor noise")
    ap.add_argument("--seed", type=int, default=0, help="seed of the sensor noise")
    ap.add_argument("--batch", type=int, default=0, help="fit this many dispersed vehicles at once instead")
    ap.add_argument("--singles", type=int, default=8, help="with --batch: members also fitted one by one")
    args = ap.parse_args()

    model = jaxtree.load_scene(SCENE)
    ts = jnp.linspace(0.0, DURATION, int(DURATION * RATE) + 1)
    if args.batch:
        batch_main(model, ts, args.batch, args.singles, args.seed)
        return
    data = record(model, ts, noise=not args.noise_free, seed=args.seed)
    theta0 = nominal(model)
    t = time.perf_counter()
    theta, stderr_log, steps = fit(model, ts, data, theta0)
    wall = time.perf_counter() - t

    names = NAMES
    truth_ = np.exp(np.asarray(truth()))
    start, est = np.exp(np.asarray(theta0)), np.exp(np.asarray(theta))
    stderr = est * np.asarray(stderr_log)  # first order: d exp(theta) = exp(theta) d theta
    print(
        f"{SCENE}: {model.n} hinges; record {DURATION:g} s at {RATE:g} Hz, "
        f"{'no noise' if args.noise_free else f'noise {SIGMA_GYRO:g} rad/s (gyro), {SIGMA_ANGLE:g} rad (angles)'}"
    )
    print(f"Levenberg-Marquardt: {int(steps)} steps, {wall:.1f} s (compile included)")
    print(f"{'parameter':18s} {'start':>10s} {'estimate':>12s} {'std error':>10s} {'truth':>10s} {'off (sigma)':>11s}")
    for name, s0, e, se, tr in zip(names, start, est, stderr, truth_):
        print(f"{name:18s} {s0:10.4g} {e:12.8g} {se:10.2g} {tr:10.4g} {(e - tr) / se:11.2f}")


if __name__ == "__main__":
    main()
