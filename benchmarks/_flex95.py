"""The flex95 slew campaign's members, shared by bench_campaign.py (``--scene flex95``, against
Pinocchio + scipy Radau on the CPU) and bench_gpu_campaign.py (against MJX on an accelerator):
bench_hybrid.py's flex95 slew (10 s, 201 saves), each member with the 90 wing hinges' stiffness
scaled by its own factor and the slew torque by another, both uniform in [0.9, 1.1]."""

import time

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import jaxtree

FLEX_T1, FLEX_SAVES = 10.0, 201


def flex_factors(n):
    """(n, 2): each member's wing stiffness and slew torque factors, uniform in [0.9, 1.1]."""
    return np.random.default_rng(0).uniform(0.9, 1.1, (n, 2))


class Flex:
    """bench_hybrid.py's flex95 slew, its wing hinges, save times and nominal hybrid model."""

    def __init__(self):
        from bench_hybrid import scenario

        self.model, small, self.state, self.torque = scenario("flex95", 1.0)
        self.small = small
        self.wings = np.asarray(small) - 1
        self.ts = jnp.linspace(0.0, FLEX_T1, FLEX_SAVES)
        t = time.perf_counter()
        self.hm0 = jaxtree.hybrid_model(self.model, small, 3, omega0=self.state.omega0)
        self.build0_s = time.perf_counter() - t

    def member(self, ks, kt):
        """The member's full model: wing stiffness x ks, slew torque x kt."""
        m = self.model
        return eqx.tree_at(
            lambda m: (m.stiffness, m.loads.torque),
            m,
            (m.stiffness.at[self.wings].multiply(ks), m.loads.torque * kt),
        )

    def hybrid(self, ks, kt):
        """The member's hybrid model, rebuilt from its stiffness with the nominal model's retained
        modes; without the truncation estimate's terms, which the timed runs do not use."""
        hm = jaxtree.hybrid_model(self.member(ks, kt), self.small, 3, omega0=self.state.omega0, like=self.hm0)
        return eqx.tree_at(lambda h: h.truncation, hm, None)


def flex_errors(w, g, ref, S):
    """The largest (hub, wings) error of bench_hybrid.py over the members of (w, g) against `ref`."""
    from bench_hybrid import errors

    e = [errors(w[i], g[i], dict(omega0=ref[0][i], gamma=ref[1][i]), S) for i in range(len(w))]
    return max(x[0] for x in e), max(x[1] for x in e)


def flex_meets(e):
    from bench_hybrid import HUB_GOAL, SMALL_GOAL

    return e[0] <= HUB_GOAL and e[1] <= SMALL_GOAL


def pulse(t):
    """bench_hybrid.py's slew pulse in numpy (on at 1 s, off at 3 s, tanh edges)."""
    return 0.5 * (np.tanh((t - 1.0) / 0.1) - np.tanh((t - 3.0) / 0.1))
