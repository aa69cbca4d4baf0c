"""The user-facing examples that are cheap enough to run here (fig4_sample_problem runs as the
README main job): a vmapped Monte Carlo campaign, gradient-based identification, the panel
deployment with its latch event, and the exploration notebook."""

import importlib.util
import pathlib

import jax
import numpy as np

import jaxtree

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def load_example(name):
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_monte_carlo_campaign_runs_each_dispersed_vehicle_as_alone():
    """Each row of the vmapped campaign (a batch of models with in_axes on the dispersed leaves)
    is the run of that vehicle alone, and each conserves its angular momentum (no loads act)."""
    MC = load_example("monte_carlo")
    model = jaxtree.load_scene("fig4")
    d = MC.dispersions(model, 3, seed=1)
    models, in_axes = MC.dispersed_models(model, d)
    jaxtree.validate_model(models)
    duration = 2.0
    out = MC.campaign(models, in_axes, d, duration, saves=21)
    assert np.all(np.asarray(out["momentum_drift"]) < 1e-7)
    assert np.ptp(np.asarray(out["peak_motor_torque"])) > 1e-3  # the dispersions do change the runs
    r = 2
    alone = jax.tree_util.tree_map(lambda x, a: x if a is None else x[r], models, in_axes, is_leaf=lambda x: x is None)
    s = alone.initial
    panels = np.asarray(model.sprung) - 1
    y0 = s._replace(omega0=s.omega0 + d["omega0"][r], gamma_dot=s.gamma_dot.at[panels].add(d["panel_rate"][r]))
    sol = jaxtree.simulate(alone, duration, y0=y0, saveat=21)
    np.testing.assert_allclose(
        float(out["peak_bus_rate"][r]), float(np.linalg.norm(sol.omega0, axis=1).max()), rtol=1e-9
    )
    np.testing.assert_allclose(float(out["peak_motor_torque"][r]), float(np.abs(sol.hold_torque).max()), rtol=1e-9)


def test_levenberg_marquardt_through_simulate_recovers_the_true_wings():
    """Gradient-based identification (examples/identify_wings.py): fitting a noise-free record
    from the scene's nominal wings returns the true stiffness, damping, tip-panel mass and inertia
    that made it; fitting a noisy record (seeded) lands within 3 Gauss-Newton standard deviations
    of the truth."""
    W = load_example("identify_wings")
    model = jaxtree.load_scene(W.SCENE)
    ts = np.linspace(0.0, W.DURATION, int(W.DURATION * W.RATE) + 1)  # the example's record
    theta0 = W.nominal(model)
    truth = np.exp(np.asarray(W.truth()))
    assert np.all(np.abs(np.exp(np.asarray(theta0)) / truth - 1) > 0.05)  # the start is off in every parameter
    data = W.record(model, ts, noise=False)
    theta, stderr, _ = W.fit(model, ts, data, theta0)
    # integration tolerance 1e-10 on angles of 0.05 rad: parameters to ~1e-8
    np.testing.assert_allclose(np.exp(np.asarray(theta)), truth, rtol=1e-6)
    assert np.all(np.isfinite(np.asarray(stderr))) and np.all(np.asarray(stderr) > 0)
    noisy = W.record(model, ts, noise=True, seed=0)
    theta, stderr_log, _ = W.fit(model, ts, noisy, theta0)  # the same compiled fit
    off = (np.asarray(theta) - np.log(truth)) / np.asarray(stderr_log)  # in standard deviations (log scale)
    assert np.all(np.abs(off) < 3), off
    assert np.all(np.asarray(stderr_log) < 0.05)  # and the record does inform every parameter (5 %)


def test_the_notebook_runs_and_its_simulation_conserves_energy_and_momentum():
    """The code cells of notebooks/explore_fig4.ipynb run in order (plots go to a non-interactive
    backend), and the fig4_free run they make conserves energy and angular momentum to the
    integration tolerance (no damping, no loads)."""
    import json

    import matplotlib

    matplotlib.use("Agg")
    path = EXAMPLES.parent / "notebooks" / "explore_fig4.ipynb"
    cells = [c for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]
    namespace = {"__name__": "explore_fig4"}
    for i, cell in enumerate(cells):
        exec(compile("".join(cell["source"]), f"{path.name} code cell {i + 1}", "exec"), namespace)
    E, H = np.asarray(namespace["E"]), np.asarray(namespace["H"])
    # rtol = atol = 1e-9 over 10 s: observed 6e-10 (energy) and 2e-8 (momentum, relative to its largest component)
    assert abs(E - E[0]).max() / E[0] < 1e-7 and np.abs(H - H[0]).max() / np.abs(H[0]).max() < 1e-7
    assert np.all(np.asarray(namespace["steps"]) > 0)


def test_deploy_latch_example_latches_at_the_inverse_of_its_sweep(tmp_path, monkeypatch):
    """examples/deploy_latch.py end to end: the latch event time equals the inverse of the
    prescribed sweep (closed form), the vehicle's angular momentum is conserved after the latch
    (internal torques only), and the result files are written."""
    import runpy

    import matplotlib

    matplotlib.use("Agg")
    monkeypatch.setattr("sys.argv", ["deploy_latch.py", str(tmp_path)])
    ns = runpy.run_path(str(EXAMPLES / "deploy_latch.py"), run_name="__main__")
    assert abs(ns["t_latch"] - ns["exact"]) < 1e-9  # the event's root finding runs at 1e-10
    after = ns["after"]
    assert after.ok and float(after.t_final) == ns["t_latch"] + 20.0
    H = np.asarray(after.angular_momentum)
    assert np.abs(H - H[0]).max() / np.abs(H[0]).max() < 1e-7  # observed 3e-9 at rtol = atol = 1e-10
    for name in ("deploy_latch.npz", "deploy_latch_deploying.csv", "deploy_latch_latched.csv", "deploy_latch.png"):
        assert (tmp_path / name).stat().st_size > 0
