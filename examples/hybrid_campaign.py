"""A Monte Carlo campaign of a flexible spacecraft in hybrid coordinates: dispersed wing stiffness.

The vehicle is the bundled `wings` scene (a hub with two wings of four hinged panels; `--scene
flex95` for the 95-body vehicle of the seed's Fig. 2/3c with its six stiff wings, a spinning rotor
and gimbals). The hub fires a slew torque pulse from 1 s to 3 s; the wing hinges are the small set
of the hybrid-coordinate equations (Likins 1972, Eqs. 105-123), two modes per wing (three on
flex95).

Each member scales the stiffness of all wing hinges by its own factor 1 + N(0, 10 %) and the slew
torque by 1 + N(0, 5 %), all from one seed. The nominal hybrid model is built once, from concrete
values; each member's model is rebuilt from its stiffness inside the campaign's compiled program
(``jaxtree.hybrid_model(member, ..., like=nominal)``: the nominal's retained modes, their signs,
form and precomputation, the modes recomputed from the member's matrices). Only the stiffness and
the loads change, so the build's mass part (the substructures' Taylor terms and the nominal
frames) is evaluated once, when the program is traced: a member pays its own eigenproblems and
projections. The members run one after another (``jax.lax.map``) on each of the host's devices
(``jax.shard_map``; jaxtree gives a CPU one device per core), each integrated by
`jaxtree.Radau5` with the hybrid model's structured Jacobian.

The script prints, over the campaign, the statistics of the first mode's frequency, the hub's
peak rate and the residual wing vibration after the slew (the largest wing hinge angle over the
last quarter of the run), and each member's integration steps.

Run:  python examples/hybrid_campaign.py [--scene wings|flex95] [--runs N] [--seed S] [--duration T]
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

SIGMA = {"stiffness": 0.10, "torque": 0.05}
TORQUE = {"wings": [0.0, 8.0, 3.0], "flex95": [15.0, 9.0, 0.0]}  # N m on the hub, in {b0}
MODES = {"wings": 2, "flex95": 3}  # retained per wing


def vehicle(scene: str):
    """The slew: `scene` with the hub's torque pulse, its wing hinges (the small set), the start
    (at rest, flex95's rotor spinning at 10 pi rad/s) and the nominal spin of the modes."""
    model = jaxtree.load_scene(scene)
    model = model.with_loads(
        jaxtree.BodyTorque(0, TORQUE[scene], lambda t: jaxtree.thruster_pulse(t, 1.0, 2.0, rise=0.1))
    )
    wings = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    rates = np.zeros(model.n)
    if "rotor" in model.names:
        rates[model.names.index("rotor") - 1] = 10 * np.pi
    state = model.initial._replace(gamma=jnp.zeros(model.n), gamma_dot=jnp.asarray(rates))
    return model, wings, state, jnp.asarray(state.omega0)


def factors(runs: int, seed: int):
    """(runs, 2): each member's wing stiffness and slew torque factors (numpy, float64)."""
    rng = np.random.default_rng(seed)
    return np.stack(
        [1 + SIGMA["stiffness"] * rng.standard_normal(runs), 1 + SIGMA["torque"] * rng.standard_normal(runs)], 1
    )


def member(model, wings, ks, kt):
    """The member's vehicle: the wing hinges' stiffness times `ks`, the hub torque times `kt`; every
    other leaf is the nominal's own array (so a rebuild leaves the mass part out of its program)."""
    w = np.asarray(wings) - 1
    return eqx.tree_at(
        lambda m: (m.stiffness, m.loads.torque), model, (model.stiffness.at[w].multiply(ks), model.loads.torque * kt)
    )


def campaign(model, wings, state, spin, nominal, f, duration, saves=101, tol=1e-6):
    """Run the members of `f` (runs, 2); returns per member the first mode's frequency, the hub's
    peak rate, the residual wing angle over the last quarter and the accepted steps (numpy)."""
    from jax.sharding import Mesh, NamedSharding
    from jax.sharding import PartitionSpec as P

    ts = jnp.linspace(0.0, duration, saves)
    w = np.asarray(wings) - 1
    late = np.asarray(ts) >= 0.75 * duration

    def one(x):
        hm = jaxtree.hybrid_model(member(model, wings, x[0], x[1]), wings, like=nominal, omega0=spin)
        hm = eqx.tree_at(lambda h: h.truncation, hm, None)  # no truncation estimate in this campaign
        sol = jaxtree.simulate_hybrid(
            hm, duration, y0=state, saveat=ts, rtol=tol, atol=tol, solver=jaxtree.Radau5(), truncation_error=False
        )
        return (
            hm.frequencies[0],
            jnp.max(jnp.linalg.norm(sol.omega0, axis=1)),
            jnp.max(jnp.abs(sol.gamma[late][:, w])),
            jnp.asarray(sol.stats["num_accepted_steps"], jnp.int32),
        )

    run = lambda xs: jax.lax.map(one, xs)
    devices = jax.devices()
    n_dev = len(devices) if len(f) % len(devices) == 0 else 1
    xs = jnp.asarray(f)
    if n_dev > 1:  # each device its share of the members, one after another
        mesh = Mesh(np.array(devices[:n_dev]), ("m",))
        run = jax.shard_map(run, mesh=mesh, in_specs=P("m"), out_specs=P("m"), check_vma=False)
        xs = jax.device_put(xs, NamedSharding(mesh, P("m")))
    out = jax.jit(run)(xs)
    return {k: np.asarray(v) for k, v in zip(("frequency", "peak_hub_rate", "residual_wing_angle", "steps"), out)}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", default="wings", choices=["wings", "flex95"])
    p.add_argument("--runs", type=int, default=32)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=10.0)
    a = p.parse_args()
    model, wings, state, spin = vehicle(a.scene)
    t = time.perf_counter()
    nominal = jaxtree.hybrid_model(model, wings, MODES[a.scene], omega0=spin)
    print(
        f"{a.scene}: {len(wings)} wing hinges, nominal hybrid model of {nominal.n_modes} modes ({nominal.form}) "
        f"built in {time.perf_counter() - t:.1f} s"
    )
    f = factors(a.runs, a.seed)
    t = time.perf_counter()
    out = campaign(model, wings, state, spin, nominal, f, a.duration)
    print(f"{a.runs} members over {a.duration:g} s in {time.perf_counter() - t:.1f} s (compilation included)")
    rows = [
        ("first mode's frequency", out["frequency"], "rad/s"),
        ("hub's peak rate", out["peak_hub_rate"], "rad/s"),
        ("wing angle, last quarter", out["residual_wing_angle"], "rad"),
    ]
    for name, x, unit in rows:
        print(f"  {name:26s} mean {x.mean():.5g}  std {x.std():.3g}  min {x.min():.5g}  max {x.max():.5g} {unit}")
    print(f"  Radau5 steps a member: {int(out['steps'].min())}-{int(out['steps'].max())}")


if __name__ == "__main__":
    main()
