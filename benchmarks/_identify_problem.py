"""The identification problem of benchmarks/bench_identify.py (the example's: examples/identify_wings.py)
and its finite-difference peer: scipy's Levenberg-Marquardt over Pinocchio's ABA integrated by
scipy's DOP853, the route of a user without a differentiable engine."""

import time

import numpy as np

SCENE = "wings"
DURATION, RATE = 20.0, 10.0  # s, Hz
TOL = 1e-10  # the record's and the fit's integration tolerance
SIGMA = {"hub.omega": 2e-6, "wingp_1.angle": 2e-5, "wingm_1.angle": 2e-5}  # rad/s, rad
FREE6 = {
    "k+": [f"wingp_{i}.stiffness" for i in range(1, 5)],
    "k-": [f"wingm_{i}.stiffness" for i in range(1, 5)],
    "c+": [f"wingp_{i}.damping" for i in range(1, 5)],
    "c-": [f"wingm_{i}.damping" for i in range(1, 5)],
    "m tip": ["wingp_4.mass"],
    "Iyy tip": ["wingp_4.inertia[1,1]"],
}
TRUTH6 = {"k+": 115.0, "k-": 85.0, "c+": 0.65, "c-": 0.40, "m tip": 5.6, "Iyy tip": 0.47}


def dispersed(truth, rng, spread=0.1):
    """`truth` with each value dispersed by `spread` (one standard deviation), the tip panel's
    I_yy kept above 0.42 kg m^2: with I_xx 0.267 and I_zz 0.683 a smaller one breaks the
    triangle inequality of the principal moments (no mass distribution has it)."""
    out = {n: v * (1 + spread * rng.standard_normal()) for n, v in truth.items()}
    out["Iyy tip"] = max(out["Iyy tip"], 0.42)
    return out


def free24(model):
    """Every hinge's stiffness and damping and every panel's mass."""
    bodies = model.names[1:]
    return [f"{b}.stiffness" for b in bodies] + [f"{b}.damping" for b in bodies] + [f"{b}.mass" for b in bodies]


def times():
    return np.linspace(0.0, DURATION, int(DURATION * RATE) + 1)


def with_values(model, free, values):
    """`model` with the parameters `free` set to `values` (dict by name), concretely."""
    import jax.numpy as jnp

    from jaxtree._src.identify.parameters import parameters

    p = parameters(model, free)
    return p.apply(model, p.to_theta(jnp.asarray([float(values[n]) for n in p.names])))


def record(model, free, truth, seed=0, noise=True):
    """The flight record of the vehicle with the `truth` values: dict sensor -> (T, ...)."""
    import jax.numpy as jnp

    import jaxtree

    ts = times()
    sol = jaxtree.simulate(with_values(model, free, truth), ts[-1], saveat=jnp.asarray(ts), rtol=TOL, atol=TOL)
    clean = {
        "hub.omega": np.asarray(sol.omega0),
        "wingp_1.angle": np.asarray(sol.gamma[:, 0]),
        "wingm_1.angle": np.asarray(sol.gamma[:, 4]),
    }
    if not noise:
        return clean
    rng = np.random.default_rng(seed)
    return {k: v + SIGMA[k] * rng.standard_normal(v.shape) for k, v in clean.items()}


def peer_fit(model, free, data, start=None):
    """scipy.optimize.least_squares (method "lm", its default forward-difference Jacobian) over
    Pinocchio's ABA + scipy DOP853 at TOL; parameters as logarithms, residuals in units of sigma,
    the same sensors (the hub's rate in its own frame, the two root hinge angles) and start.
    Returns (values dict, standard errors dict, simulations, wall seconds)."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import least_squares

    from jaxtree._src.identify.parameters import parameters, start_values
    from jaxtree.bench.peers import pinocchio_initial, pinocchio_rhs

    p = parameters(model, free)
    names = list(p.names)
    x0 = np.log(start_values(model, p, start, None))
    ts = times()
    n = model.n
    y = np.concatenate(
        [
            (data["hub.omega"] / SIGMA["hub.omega"]).ravel(),
            data["wingp_1.angle"] / SIGMA["wingp_1.angle"],
            data["wingm_1.angle"] / SIGMA["wingm_1.angle"],
        ]
    )
    count = [0]

    def residuals(x):
        m = with_values(model, free, dict(zip(names, np.exp(x))))
        r = solve_ivp(pinocchio_rhs(m), (ts[0], ts[-1]), pinocchio_initial(m), "DOP853", t_eval=ts, rtol=TOL, atol=TOL)
        count[0] += 1
        w, g = r.y[:3].T, r.y[3 : 3 + n].T
        model_y = np.concatenate(
            [(w / SIGMA["hub.omega"]).ravel(), g[:, 0] / SIGMA["wingp_1.angle"], g[:, 4] / SIGMA["wingm_1.angle"]]
        )
        return model_y - y

    t0 = time.perf_counter()
    out = least_squares(residuals, x0, method="lm")
    wall = time.perf_counter() - t0
    J = out.jac
    cov = np.linalg.inv(J.T @ J)
    values = np.exp(out.x)
    stderr = values * np.sqrt(np.diag(cov))
    return dict(zip(names, values)), dict(zip(names, stderr)), count[0], wall
