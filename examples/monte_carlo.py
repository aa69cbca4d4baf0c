"""A Monte Carlo campaign on the Fig. 4 spacecraft: dispersed mass properties, stiffness and rates.

One `jax.vmap` runs the whole campaign: a batch of *models* (their array leaves carry a batch
axis; the topology and every structural choice stay static and shared) and a batch of initial
states go through `jaxtree.simulate` at once. Each run is the seed's sample problem (Sec. II E)
for 30 s: the platform follows gamma_1 = sin 0.5 t, the rotor spins at 10 pi rad/s on its
massless gimbals and the panel chain swings on its springs, with

- the bus inertia scaled by 1 + N(0, 3 %) on each principal value (the products of inertia
  kept), and the bus mass by 1 + N(0, 2 %);
- each panel hinge stiffness scaled by 1 + N(0, 10 %);
- an initial bus rate N(0, 2e-3 rad/s) per axis and panel rates N(0, 1e-2 rad/s);

all from one seed. The script prints, over the campaign, the statistics of the bus's peak rate,
its attitude excursion (rotation angle of C(t) away from C(0)), the peak torque of the platform
motor that holds the prescription, the largest panel hinge excursion, and the largest relative
drift of the angular momentum (a check: no external loads act, so it is conserved in every run).
Dispersions too wide for a valid vehicle are caught before anything runs (`jaxtree.SceneError`
names the run, the body and the field).

Run:  python examples/monte_carlo.py [--runs N] [--seed S] [--duration T] [--float32]
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

SIGMA = {"bus_inertia": 0.03, "bus_mass": 0.02, "stiffness": 0.10, "bus_rate": 2e-3, "panel_rate": 1e-2}


def dispersions(model, runs: int, seed: int):
    """Per-run factors and initial rates (numpy, float64), drawn from one seed."""
    rng = np.random.default_rng(seed)
    panels = np.asarray(model.sprung) - 1
    return {
        "inertia": 1 + SIGMA["bus_inertia"] * rng.standard_normal((runs, 3)),
        "mass": 1 + SIGMA["bus_mass"] * rng.standard_normal(runs),
        "stiffness": 1 + SIGMA["stiffness"] * rng.standard_normal((runs, len(panels))),
        "omega0": SIGMA["bus_rate"] * rng.standard_normal((runs, 3)),
        "panel_rate": SIGMA["panel_rate"] * rng.standard_normal((runs, len(panels))),
    }


def _bus_inertia(J, factors):
    """Scale the principal values of the bus inertia J by `factors` (runs x 3), keeping its
    principal axes: (runs, 3, 3)."""
    w, V = np.linalg.eigh(J)
    return (V * (w * factors)[:, None, :]) @ V.T


def dispersed_models(model, d):
    """A batch of models whose `mass`, `inertia` and `stiffness` carry a leading run axis, and
    the matching `in_axes` for `jax.vmap` (0 on those leaves, None on every other leaf)."""
    runs, panels = len(d["mass"]), np.asarray(model.sprung) - 1
    mass = np.tile(np.asarray(model.mass), (runs, 1))
    mass[:, 0] *= d["mass"]
    inertia = np.tile(np.asarray(model.inertia), (runs, 1, 1, 1))
    inertia[:, 0] = _bus_inertia(inertia[0, 0], d["inertia"])
    stiffness = np.tile(np.asarray(model.stiffness), (runs, 1))
    stiffness[:, panels] *= d["stiffness"]
    dispersed = lambda m: (m.mass, m.inertia, m.stiffness)
    models = eqx.tree_at(dispersed, model, tuple(jnp.asarray(x, model.mass.dtype) for x in (mass, inertia, stiffness)))
    in_axes = eqx.tree_at(dispersed, jax.tree_util.tree_map(lambda _: None, model), (0, 0, 0),
                          is_leaf=lambda x: x is None)
    return models, in_axes


def campaign(models, in_axes, d, duration: float, saves: int = 301):
    """All runs at once: a dict of per-run figures (arrays with a leading run axis)."""

    def one(m, omega0, panel_rate):
        panels = np.asarray(m.sprung) - 1
        s = m.initial
        y0 = s._replace(omega0=s.omega0 + omega0, gamma_dot=s.gamma_dot.at[panels].add(panel_rate))
        sol = jaxtree.simulate(m, duration, y0=y0, saveat=saves)
        # attitude excursion: rotation angle of C(t) C(0)^T
        R = jnp.einsum("tij,kj->tik", sol.dcm, sol.dcm[0])
        angle = jnp.arccos(jnp.clip((jnp.trace(R, axis1=1, axis2=2) - 1) / 2, -1.0, 1.0))
        H = sol.angular_momentum
        return {
            "peak_bus_rate": jnp.max(jnp.linalg.norm(sol.omega0, axis=1)),
            "attitude_excursion": jnp.max(angle),
            "peak_motor_torque": jnp.max(jnp.abs(sol.hold_torque)),
            "panel_excursion": jnp.max(jnp.abs(sol.gamma[:, panels] - sol.gamma[0, panels])),
            "momentum_drift": jnp.max(jnp.linalg.norm(H - H[0], axis=1)) / jnp.linalg.norm(H[0]),
            "steps": sol.stats["num_steps"],
        }

    dtype = models.mass.dtype
    return jax.jit(jax.vmap(one, in_axes=(in_axes, 0, 0)))(
        models, jnp.asarray(d["omega0"], dtype), jnp.asarray(d["panel_rate"], dtype))


UNITS = {"peak_bus_rate": "rad/s", "attitude_excursion": "rad", "peak_motor_torque": "N m",
         "panel_excursion": "rad", "momentum_drift": "", "steps": ""}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of flight per run")
    ap.add_argument("--float32", action="store_true", help="run the campaign in float32 (GPU batches)")
    args = ap.parse_args()

    model = jaxtree.load_scene("fig4")
    if args.float32:
        model = model.astype(jnp.float32)
    d = dispersions(model, args.runs, args.seed)
    models, in_axes = dispersed_models(model, d)
    jaxtree.validate_model(models)  # every run's vehicle, before anything is traced
    t = time.perf_counter()
    out = jax.block_until_ready(campaign(models, in_axes, d, args.duration))
    wall = time.perf_counter() - t
    print(f"fig4 Monte Carlo: {args.runs} runs of {args.duration:g} s ({jax.default_backend()}, "
          f"{'float32' if args.float32 else 'float64'}), {wall:.1f} s for the campaign (compile included)")
    print(f"{'figure':20s} {'mean':>11s} {'std':>11s} {'min':>11s} {'max':>11s}  unit")
    for k, v in out.items():
        v = np.asarray(v, float)
        print(f"{k:20s} {v.mean():11.4g} {v.std():11.4g} {v.min():11.4g} {v.max():11.4g}  {UNITS[k]}")


if __name__ == "__main__":
    main()
