"""Deploy the panel chain of Fig. 4, latch it, and release it to its springs (events).

The seed's Fig. 2 motivation: appendages that change configuration in flight. Phase 1 drives
the panel root hinge (hinge 5) by a prescribed motion (Sec. II B), a smooth sweep from the
stowed angle to beyond the deployed one, while the outer panels swing on their springs; the
motor torque that holds the prescription is an output. A diffrax event with root finding
stops the run when hinge 5 reaches the latch angle. Phase 2 starts from that state with the
latch engaged: hinge 5 is no longer prescribed but held by a stiff, damped latch spring, and
the vehicle moves freely.

Run:  python examples/deploy_latch.py [output folder]
"""

import dataclasses
import pathlib
import sys

import jax.numpy as jnp
import numpy as np

import jaxtree

out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "results")
STOWED, OVERSHOOT, SWEEP = -1.2, 0.1, 8.0  # rad, rad, s
LATCH = 0.0  # rad: the deployed angle
K_LATCH, D_LATCH = 2000.0, 20.0  # latch spring (N m/rad) and damper (N m s/rad)

scene = jaxtree.scene_to_dict(jaxtree.load_scene("fig4"))
bodies = [jaxtree.Body(**b) for b in scene["bodies"]]
initial = dict(scene["initial"])
initial["gamma"] = list(initial["gamma"])
initial["gamma"][4] = STOWED


def sweep(t):
    """gamma_5(t): STOWED -> OVERSHOOT with zero rate at both ends (then held)."""
    s = jnp.clip(t / SWEEP, 0.0, 1.0)
    return STOWED + (OVERSHOOT - STOWED) * (1 - jnp.cos(jnp.pi * s)) / 2


deploying = jaxtree.build_model(
    [dataclasses.replace(b, joint=jaxtree.Prescribed(sweep)) if k == 5 else b for k, b in enumerate(bodies)],
    initial,
    name="fig4_deploying",
)
latched = jaxtree.build_model(
    [
        dataclasses.replace(b, joint=jaxtree.SpringDamper(K_LATCH, D_LATCH)) if k == 5 else b
        for k, b in enumerate(bodies)
    ],
    initial,
    name="fig4_latched",
)

# Phase 1: deploy until hinge 5 crosses the latch angle (upward)
latch_event = jaxtree.hinge_angle_event(5, LATCH, direction=True)
deploy = jaxtree.simulate(deploying, 2 * SWEEP, event=latch_event, saveat=401, rtol=1e-10, atol=1e-10)
t_latch = float(deploy.t_final)
exact = SWEEP / np.pi * np.arccos(1 - 2 * (LATCH - STOWED) / (OVERSHOOT - STOWED))
print(
    f"latched at t = {t_latch:.12f} s (inverse of the sweep: {exact:.12f} s, difference {abs(t_latch - exact):.1e} s)"
)
print(
    f"  hinge 5 at the latch: angle {float(deploy.final.gamma[4]):+.3e} rad, "
    f"rate {float(deploy.final.gamma_dot[4]):.4f} rad/s"
)
hold = np.asarray(deploy.hold_torque)
print(
    f"  deployment motor torque (hold torque of hinge 5): max |tau_5| = {np.nanmax(np.abs(hold[:, 1])):.3f} N m; "
    f"platform hinge 1: {np.nanmax(np.abs(hold[:, 0])):.3f} N m"
)

# Phase 2: latched, released to the springs, from the latch state
after = jaxtree.simulate(
    latched, t_latch + 20.0, t0=deploy.t_final, y0=deploy.final, saveat=401, rtol=1e-10, atol=1e-10
)
print(jaxtree.summary("after the latch", after))
print(
    f"  hinge 5 settles: |gamma_5| at the end {abs(float(after.final.gamma[4])):.2e} rad; "
    f"panel hinges 6-10 at the end {np.round(np.asarray(after.final.gamma[5:]), 4)}"
)

runs = {"deploying": deploy, "latched": after}
jaxtree.save_npz(out / "deploy_latch.npz", runs)
for name, sol in runs.items():
    jaxtree.save_csv(out / f"deploy_latch_{name}.csv", sol)
try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for name, sol in runs.items():
        h = jaxtree.histories(sol)
        for k in range(4, 10):
            axes[0].plot(
                h["t"],
                h["gamma"][:, k],
                color=colors[k % len(colors)],
                lw=1,
                label=f"$\\gamma_{{{k + 1}}}$" if name == "deploying" else None,
            )
    h1, h2 = jaxtree.histories(deploy), jaxtree.histories(after)
    axes[1].plot(h1["t"], h1["hold_torque"][:, -1], "k", lw=1, label="motor (hold torque of the prescription)")
    axes[1].plot(
        h2["t"],
        -(K_LATCH * h2["gamma"][:, 4] + D_LATCH * h2["gamma_dot"][:, 4]),
        "r",
        lw=1,
        label="latch spring and damper",
    )
    for ax in axes:
        ax.axvline(t_latch, color="r", ls="--", lw=0.8)
    axes[0].set_title("panel hinge angles (rad); red: latch")
    axes[0].legend(ncol=6, fontsize=8)
    axes[1].set_title("torque on hinge 5 (N m)")
    axes[1].legend(fontsize=8)
    axes[1].set_xlabel("t (s)")
    fig.tight_layout()
    with jaxtree.atomic_write(out / "deploy_latch.png") as fh:
        fig.savefig(fh, format="png", dpi=110)
    print(f"plot: {out / 'deploy_latch.png'}")
except ImportError:
    print("matplotlib is not installed: no plot")
print(f"results in {out.resolve()}")
