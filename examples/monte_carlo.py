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

The same campaign through the API, `jaxtree.monte_carlo` (the default of `main`): a JAX
`sample(key, model)` draws each vehicle, the runs come back as an xarray Dataset (failed runs
named, with NaN outputs), and the script prints summary statistics of the platform's pointing
error (the angle between its boresight, the platform's x axis, and where it would point with
the bus holding still), writes the dataset (`--out campaign.zarr` or `.nc`, resumable) and plots
the error's envelope over the campaign (`--plot pointing.png`). `--manual` runs the hand-made
`jax.vmap` version above instead.

Run:  python examples/monte_carlo.py [--runs N] [--seed S] [--duration T] [--float32] [--out PATH] [--plot PNG] [--manual]
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
    in_axes = eqx.tree_at(
        dispersed, jax.tree_util.tree_map(lambda _: None, model), (0, 0, 0), is_leaf=lambda x: x is None
    )
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
        models, jnp.asarray(d["omega0"], dtype), jnp.asarray(d["panel_rate"], dtype)
    )


UNITS = {
    "peak_bus_rate": "rad/s",
    "attitude_excursion": "rad",
    "peak_motor_torque": "N m",
    "panel_excursion": "rad",
    "momentum_drift": "",
    "steps": "",
}


def sample(key, model):
    """One dispersed fig4 vehicle (the dispersions of `dispersions`, drawn with jax.random)."""
    k = jax.random.split(key, 5)
    dtype = model.mass.dtype
    panels = np.asarray(model.sprung[1:]) - 1 if model.prescribed else np.asarray(model.sprung) - 1
    w, V = jnp.linalg.eigh(model.inertia[0])
    factors = 1 + SIGMA["bus_inertia"] * jax.random.normal(k[0], (3,), dtype)
    inertia = model.inertia.at[0].set((V * (w * factors)) @ V.T)
    mass = model.mass.at[0].multiply(1 + SIGMA["bus_mass"] * jax.random.normal(k[1], (), dtype))
    stiffness = model.stiffness.at[panels].multiply(
        1 + SIGMA["stiffness"] * jax.random.normal(k[2], (len(panels),), dtype)
    )
    s = model.initial
    y0 = s._replace(
        omega0=s.omega0 + SIGMA["bus_rate"] * jax.random.normal(k[3], (3,), dtype),
        gamma_dot=s.gamma_dot.at[panels].add(SIGMA["panel_rate"] * jax.random.normal(k[4], (len(panels),), dtype)),
    )
    return eqx.tree_at(lambda m: (m.mass, m.inertia, m.stiffness, m.initial), model, (mass, inertia, stiffness, y0))


def pointing_error(ds, model):
    """Angle (run, time) between the platform's boresight (its x axis) and where it would point
    with the bus holding still: C(t)^T R_1(gamma_1) e_1 against R_1(gamma_1) e_1 (inertial)."""
    q = ds.attitude.values
    q0, v = q[..., :1, None], q[..., 1:]
    vx = np.cross(np.eye(3), v[..., None, :])  # tilde(v)
    C = (q0**2 - np.sum(v * v, -1)[..., None, None]) * np.eye(3) + 2 * v[..., :, None] * v[..., None, :] - 2 * q0 * vx
    R1 = np.asarray(jaxtree.hinge_rotation(model.axis[0], ds.gamma.values[..., 0]))  # C^{1 0} (Eq. 4)
    b_body = np.swapaxes(R1, -1, -2)[..., :, 0]  # boresight e_1 of b_1 in {b^0}
    actual = np.einsum("...ji,...j->...i", C, b_body)  # {i} components: C^T
    return np.arccos(np.clip(np.sum(actual * b_body, -1) / np.linalg.norm(actual, axis=-1), -1.0, 1.0))


def main_api(args):
    model = jaxtree.load_scene("fig4")
    if args.float32:
        model = model.astype(jnp.float32)
    t = time.perf_counter()
    ds = jaxtree.monte_carlo(
        model,
        sample,
        args.runs,
        args.duration,
        key=jax.random.key(args.seed),
        saveat=301,
        chunk_size=min(args.runs, 64),
        out=args.out,
    )
    wall = time.perf_counter() - t
    ok = ds.status.values == "successful"
    print(
        f"fig4 Monte Carlo (jaxtree.monte_carlo): {args.runs} runs of {args.duration:g} s, {ok.sum()} successful, "
        f"{wall:.1f} s (compile included); chunk efficiency {np.round(ds.attrs['chunk_efficiency'], 3).tolist()}"
    )
    for status in sorted(set(ds.status.values[~ok])):
        print(f"  {np.sum(ds.status.values == status)} runs ended with {status}")
    err = pointing_error(ds, model)[ok]
    peak = err.max(axis=1)
    print(
        f"platform pointing error, peak per run (mrad): mean {1e3 * peak.mean():.4g}, std {1e3 * peak.std():.4g}, "
        f"median {1e3 * np.median(peak):.4g}, 99th percentile {1e3 * np.percentile(peak, 99):.4g}, "
        f"max {1e3 * peak.max():.4g}"
    )
    H = ds.angular_momentum.values[ok]
    drift = np.linalg.norm(H - H[:, :1], axis=-1).max(axis=1) / np.linalg.norm(H[:, 0], axis=-1)
    print(f"angular momentum drift (no loads: conserved), largest over the runs: {drift.max():.2e}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        ts = ds.time.values
        fig, ax = plt.subplots(figsize=(7, 3.5))
        for lo, hi, a in ((0, 100, 0.2), (5, 95, 0.35), (25, 75, 0.5)):
            ax.fill_between(
                ts,
                1e3 * np.percentile(err, lo, 0),
                1e3 * np.percentile(err, hi, 0),
                color="C0",
                alpha=a,
                lw=0,
                label=f"{lo}-{hi} %",
            )
        ax.plot(ts, 1e3 * np.median(err, 0), "C0", lw=1, label="median")
        ax.set_xlabel("t (s)"), ax.set_ylabel("pointing error (mrad)"), ax.legend(fontsize=8)
        ax.set_title(f"fig4: platform pointing error over {ok.sum()} dispersed runs")
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")
    return ds


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=30.0, help="seconds of flight per run")
    ap.add_argument("--float32", action="store_true", help="run the campaign in float32 (GPU batches)")
    ap.add_argument("--out", help="write the dataset to this Zarr store (*.zarr) or NetCDF file (*.nc); resumable")
    ap.add_argument("--plot", help="plot the pointing error's envelope to this PNG")
    ap.add_argument(
        "--manual", action="store_true", help="the hand-made jax.vmap campaign instead of jaxtree.monte_carlo"
    )
    args = ap.parse_args()
    if not args.manual:
        return main_api(args)

    model = jaxtree.load_scene("fig4")
    if args.float32:
        model = model.astype(jnp.float32)
    d = dispersions(model, args.runs, args.seed)
    models, in_axes = dispersed_models(model, d)
    jaxtree.validate_model(models)  # every run's vehicle, before anything is traced
    t = time.perf_counter()
    out = jax.block_until_ready(campaign(models, in_axes, d, args.duration))
    wall = time.perf_counter() - t
    print(
        f"fig4 Monte Carlo: {args.runs} runs of {args.duration:g} s ({jax.default_backend()}, "
        f"{'float32' if args.float32 else 'float64'}), {wall:.1f} s for the campaign (compile included)"
    )
    print(f"{'figure':20s} {'mean':>11s} {'std':>11s} {'min':>11s} {'max':>11s}  unit")
    for k, v in out.items():
        v = np.asarray(v, float)
        print(f"{k:20s} {v.mean():11.4g} {v.std():11.4g} {v.min():11.4g} {v.max():11.4g}  {UNITS[k]}")


if __name__ == "__main__":
    main()
