"""Benchmark: linearize + modes for panels95 with all 90 panel hinges small (Sec. III C-D).

Prints the machine and versions, then for the non-spinning and the spinning nominal motion:
compile time (first call, tracing + XLA) separately from the steady run time (median of
repeats) of ``jaxtree.linearize`` and of ``jaxtree.modes``. The scene's hinges carry dampers
(d = 0.05), so the modes take the general path (non-skew J); the same runs with the
dampers removed exercise the real (non-spinning) and gyroscopic (spinning) paths.

Run: ``python benchmarks/bench_modes.py [--repeats N]``.
"""

from __future__ import annotations

import argparse

import equinox as eqx
import jax.numpy as jnp

import jaxtree

from _common import machine, timed


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    print(machine())
    model = jaxtree.load_scene("panels95")
    small = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    assert len(small) == 90
    undamped = eqx.tree_at(lambda m: m.damping, model, jnp.zeros_like(model.damping))
    print(f"panels95: n = {model.n} hinges, set A = {len(small)} panel hinges")
    print(
        f"{'case':34s} {'kind':>10s} {'lin compile':>12s} {'lin run':>10s} {'modes 1st':>10s} "
        f"{'modes run':>10s}  lowest sigma"
    )
    for label, m in (("scene (dampers d = 0.05)", model), ("dampers removed", undamped)):
        for spin in (0.0, 0.05):
            w = [0.0, 0.0, spin]
            lin, c_lin, r_lin = timed(lambda: jaxtree.linearize(m, small, omega0=w), args.repeats)
            md, c_md, r_md = timed(lambda: jaxtree.modes(lin), args.repeats)
            name = f"{label}, omega0 = {spin}"
            print(
                f"{name:34s} {md.kind:>10s} {c_lin:11.2f}s {1e3 * r_lin:8.1f}ms {c_md:9.2f}s "
                f"{1e3 * r_md:8.1f}ms  {float(md.frequencies[0]):.4f}"
            )


if __name__ == "__main__":
    main()
