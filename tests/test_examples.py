"""The user-facing examples that are cheap enough to run here (fig4_sample_problem runs as the
README main job): a vmapped Monte Carlo campaign and the panel deployment with its latch event.
examples/identify_wings.py runs in notebooks/identify_wings.ipynb (tests/test_notebooks.py), which
checks its fit."""

import importlib.util
import pathlib

import jax
import numpy as np

import jaxtree

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"

# relative drift of a conserved angular momentum: the runs' global error; observed <= 1e-8 in the
# campaign (default rtol = atol = 1e-9, 2 s) and 3e-9 after the latch (rtol = atol = 1e-10, 20 s)
DRIFT = 1e-7
# a row of the vmapped campaign against the same vehicle run alone, both at the default rtol = atol = 1e-9:
# the batched evaluation rounds differently and the step controller carries it; observed 2e-11, bounded
# by the runs' tolerance
SAME_RUN = 1e-9
# the latch event time against the inverse of the sweep: the event's root finding runs at 1e-10
EVENT_TIME = 1e-9


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
    assert np.all(np.asarray(out["momentum_drift"]) < DRIFT)
    assert np.ptp(np.asarray(out["peak_motor_torque"])) > 1e-3  # the dispersions do change the runs
    r = 2
    alone = jax.tree_util.tree_map(lambda x, a: x if a is None else x[r], models, in_axes, is_leaf=lambda x: x is None)
    s = alone.initial
    panels = np.asarray(model.sprung) - 1
    y0 = s._replace(omega0=s.omega0 + d["omega0"][r], gamma_dot=s.gamma_dot.at[panels].add(d["panel_rate"][r]))
    sol = jaxtree.simulate(alone, duration, y0=y0, saveat=21)
    np.testing.assert_allclose(
        float(out["peak_bus_rate"][r]), float(np.linalg.norm(sol.omega0, axis=1).max()), rtol=SAME_RUN
    )
    np.testing.assert_allclose(float(out["peak_motor_torque"][r]), float(np.abs(sol.hold_torque).max()), rtol=SAME_RUN)


def test_deploy_latch_example_latches_at_the_inverse_of_its_sweep(tmp_path, monkeypatch):
    """examples/deploy_latch.py end to end: the latch event time equals the inverse of the
    prescribed sweep (closed form), the vehicle's angular momentum is conserved after the latch
    (internal torques only), and the result files are written."""
    import runpy

    import matplotlib

    matplotlib.use("Agg")
    monkeypatch.setattr("sys.argv", ["deploy_latch.py", str(tmp_path)])
    ns = runpy.run_path(str(EXAMPLES / "deploy_latch.py"), run_name="__main__")
    assert abs(ns["t_latch"] - ns["exact"]) < EVENT_TIME
    after = ns["after"]
    assert after.ok and float(after.t_final) == ns["t_latch"] + 20.0
    H = np.asarray(after.angular_momentum)
    assert np.abs(H - H[0]).max() / np.abs(H[0]).max() < DRIFT
    for name in ("deploy_latch.npz", "deploy_latch_deploying.csv", "deploy_latch_latched.csv", "deploy_latch.png"):
        assert (tmp_path / name).stat().st_size > 0
