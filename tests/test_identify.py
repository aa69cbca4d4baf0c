"""jaxtree.identify: parameter identification through the simulation.

References: the sensors' readings against an autodiff derivative of each body's direction cosines
(omega^k from dC^k/dt = -tilde(omega^k) C^k) and the exact small-rotation formula; a noise-free
record must give the truth back; the standard errors against the Gauss-Newton covariance of a
central-difference Jacobian, and the estimate against a central-difference gradient of the
chi-square (zero at a least-squares minimum); a batch against its members' single fits; a
parameter that no sensor sees is named. The wings scene of examples/identify_wings.py."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.identify import fit as fit_module
from jaxtree._src.identify import sensors as sen
from jaxtree._src.identify.parameters import parameters

from helpers import random_state

FREE = {
    "k+": [f"wingp_{i}.stiffness" for i in range(1, 5)],
    "k-": [f"wingm_{i}.stiffness" for i in range(1, 5)],
    "c+": [f"wingp_{i}.damping" for i in range(1, 5)],
    "c-": [f"wingm_{i}.damping" for i in range(1, 5)],
    "m tip": ["wingp_4.mass"],
    "Iyy tip": ["wingp_4.inertia[1,1]"],
}
TRUTH = {"k+": 115.0, "k-": 85.0, "c+": 0.65, "c-": 0.40, "m tip": 5.6, "Iyy tip": 0.47}
SIGMA = {"hub.omega": 2e-6, "wingp_1.angle": 2e-5, "wingm_1.angle": 2e-5}
TS = np.linspace(0.0, 10.0, 101)
TOL = 1e-10


@pytest.fixture(scope="module")
def wings():
    return jaxtree.load_scene("wings")


def _true_model(model, truth=TRUTH):
    p = parameters(model, FREE)
    return p.apply(model, p.to_theta(jnp.asarray([truth[n] for n in p.names])))


def _record(model, noise_seed=None, truth=TRUTH):
    sol = jaxtree.simulate(_true_model(model, truth), TS[-1], saveat=jnp.asarray(TS), rtol=TOL, atol=TOL)
    clean = {
        "hub.omega": np.asarray(sol.omega0),
        "wingp_1.angle": np.asarray(sol.gamma[:, 0]),
        "wingm_1.angle": np.asarray(sol.gamma[:, 4]),
    }
    if noise_seed is None:
        return clean
    rng = np.random.default_rng(noise_seed)
    return {k: v + SIGMA[k] * rng.standard_normal(v.shape) for k, v in clean.items()}


@pytest.fixture(scope="module")
def noisy(wings):
    data = _record(wings, noise_seed=0)
    return data, jaxtree.identify(wings, FREE, TS, data, SIGMA, rtol=TOL, atol=TOL)


# ------------------------------------------------------------------------------------------- sensors
def test_body_rates_are_the_rates_of_each_body_s_direction_cosines():
    """omega^k in b^k from dC^k/dt = -tilde(omega^k) C^k, C^k = C^{k0} C, differentiated along the
    state's rates by forward mode (fig4: hinge axes in three directions, random states)."""
    model = jaxtree.load_scene("fig4")
    rng = np.random.default_rng(1)
    for _ in range(3):
        s = random_state(model, rng)
        rates = sen.body_rates(model, s.gamma, s.gamma_dot, s.omega0)
        dcm_dot = -jaxtree.tilde(s.omega0) @ s.dcm
        C, Cdot = jax.jvp(lambda g, c: sen.body_dcms(model, g, c), (s.gamma, s.dcm), (s.gamma_dot, dcm_dot))
        W = -jnp.einsum("kij,klj->kil", Cdot, C)  # tilde(omega^k)
        expected = jnp.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], -1)
        np.testing.assert_allclose(rates, expected, rtol=0, atol=1e-12 * float(jnp.abs(expected).max()))
        np.testing.assert_allclose(np.asarray(W + jnp.swapaxes(W, -1, -2)), 0.0, atol=1e-12)


def test_the_attitude_residual_is_the_rotation_from_model_to_measurement():
    """C_meas = expm(-tilde(phi)) C: the residual is sin|phi| phi/|phi| (exact), in direction
    cosines and in Euler parameters of either sign."""
    from jaxtree._src.equations.attitude import dcm_to_quaternion

    model = jaxtree.load_scene("fig4")
    s = random_state(model, np.random.default_rng(2))
    phi = np.array([0.01, -0.02, 0.015])
    C_meas = jax.scipy.linalg.expm(-jaxtree.tilde(jnp.asarray(phi))) @ s.dcm

    class Sol:
        dcm = s.dcm[None]
        gamma = s.gamma[None]
        omega0 = s.omega0[None]
        gamma_dot = s.gamma_dot[None]

    angle = np.linalg.norm(phi)
    expected = np.sin(angle) / angle * phi
    q = dcm_to_quaternion(C_meas)
    for form, y in (("dcm", C_meas[None]), ("quaternion", q[None]), ("quaternion", -q[None])):
        sensor = sen.Sensor("hub.attitude", 0, "attitude", form)
        got = sen.readings(model, (sensor,), Sol, {"hub.attitude": y})["hub.attitude"][0]
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-14)


# -------------------------------------------------------------------------------------------- fits
def test_a_noise_free_record_gives_the_truth_back(wings):
    """Every sensor kind (a star tracker's quaternions, a panel's gyro, hinge angles and rates),
    a few samples missing (NaN): the truth to 1e-6 relative, the residuals at the solution tiny."""
    true = _true_model(wings)
    sol = jaxtree.simulate(true, TS[-1], saveat=jnp.asarray(TS), rtol=TOL, atol=TOL)
    panel = sen.body_rates(true, sol.gamma[40], sol.gamma_dot[40], sol.omega0[40])[4]
    rates = jax.vmap(lambda g, gd, w: sen.body_rates(true, g, gd, w)[4])(sol.gamma, sol.gamma_dot, sol.omega0)
    np.testing.assert_allclose(rates[40], panel)
    angle = np.asarray(sol.gamma[:, 0]).copy()
    angle[[3, 50, 77]] = np.nan
    data = {
        "hub.attitude": -np.asarray(sol.attitude),  # quaternions, the opposite sign
        "wingp_4.omega": np.asarray(rates),
        "wingp_1.angle": angle,
        "wingm_1.rate": np.asarray(sol.gamma_dot[:, 4]),
    }
    sigma = {"hub.attitude": 1e-5, "wingp_4.omega": 1e-5, "wingp_1.angle": 2e-5, "wingm_1.rate": [2e-5]}
    fit = jaxtree.identify(wings, FREE, TS, data, sigma, rtol=TOL, atol=TOL)
    assert fit.converged and fit.unidentifiable == ()
    for name, truth in TRUTH.items():
        assert abs(fit.values[name] / truth - 1) < 1e-6, (name, fit.values[name], truth)
    assert np.all(np.isnan(fit.residuals["wingp_1.angle"][[3, 50, 77]]))
    assert fit.dof == 101 * 8 - 3 - 6
    assert np.nanmax(np.abs(fit.residuals["wingp_4.omega"])) < 1e-3
    # the model carries the estimates
    assert float(fit.model.stiffness[0]) == pytest.approx(fit.values["k+"], rel=1e-15)
    assert float(fit.model.inertia[4, 1, 1]) == pytest.approx(fit.values["Iyy tip"], rel=1e-15)


def test_noisy_fit_is_a_least_squares_minimum_with_the_gauss_newton_covariance(wings, noisy):
    """At the estimate the chi-square's central-difference gradient vanishes (to 1e-4 of one
    parameter's standard error times the information), and the standard errors and correlations
    equal those of (J^T J)^-1 with J by central differences of the simulated record."""
    data, fit = noisy
    assert fit.converged and fit.unidentifiable == ()
    p = parameters(wings, FREE)
    names = list(p.names)
    theta = np.asarray(fit.theta)

    @jax.jit
    def residuals(th):
        m = p.apply(wings, th)
        sol = jaxtree.simulate(m, TS[-1], saveat=jnp.asarray(TS), rtol=1e-12, atol=1e-12)
        return jnp.concatenate(
            [
                ((sol.omega0 - data["hub.omega"]) / SIGMA["hub.omega"]).ravel(),
                (sol.gamma[:, 0] - data["wingp_1.angle"]) / SIGMA["wingp_1.angle"],
                (sol.gamma[:, 4] - data["wingm_1.angle"]) / SIGMA["wingm_1.angle"],
            ]
        )

    h = 1e-5
    E = np.eye(len(names))
    columns = jax.vmap(lambda e: (residuals(theta + h * e) - residuals(theta - h * e)) / (2 * h))(jnp.asarray(E))
    J = np.asarray(columns).T
    r = np.asarray(residuals(jnp.asarray(theta)))
    # chi-square at its minimum: J^T r = 0; in standard errors, the Gauss-Newton step left
    step = np.linalg.solve(J.T @ J, -J.T @ r)
    assert np.linalg.norm(J @ step) < 1e-3
    cov = np.linalg.inv(J.T @ J)
    rate = np.where(p.log, np.exp(theta), 1.0)
    sd = np.sqrt(np.diag(cov)) * rate
    for i, n in enumerate(names):
        assert fit.stderr[n] == pytest.approx(sd[i], rel=1e-4), n
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    np.testing.assert_allclose(fit.correlation, corr, atol=1e-4)
    # the estimates within a few standard errors of the truth (the record's noise, seed 0)
    off = [abs(fit.values[n] - TRUTH[n]) / fit.stderr[n] for n in names]
    assert max(off) < 4.5, off
    assert fit.chi2 == pytest.approx(float(r @ r), rel=1e-6)
    assert fit.dof == 101 * 5 - 6
    # the coarse phase changes where the fit ends by much less than a standard error: without it
    # (the same compiled loop: tolerances are numbers of the program)
    fine = jaxtree.identify(wings, FREE, TS, data, SIGMA, rtol=TOL, atol=TOL, coarse_tol=None)
    assert fine.converged and fine.steps != fit.steps
    for n in names:
        assert abs(fine.values[n] - fit.values[n]) < 1e-3 * fit.stderr[n], n


def test_many_records_at_once_equal_their_single_fits(wings, noisy):
    """Two vehicles (other true parameters, other noise, other starts) in one call: each estimate
    is its own single fit's, to the bit (the same program), with one worker thread and two."""
    data0, _ = noisy
    truth1 = dict(TRUTH, **{"k+": 105.0, "c-": 0.45})
    data1 = _record(wings, noise_seed=1, truth=truth1)
    batch = {k: np.stack([data0[k], data1[k]]) for k in data0}
    start = {"k+": np.array([100.0, 110.0]), "m tip": np.array([5.0, 5.2])}
    fit1 = jaxtree.identify(wings, FREE, TS, data1, SIGMA, rtol=TOL, atol=TOL, start={"k+": 110.0, "m tip": 5.2})
    fit0 = jaxtree.identify(wings, FREE, TS, data0, SIGMA, rtol=TOL, atol=TOL, start={"k+": 100.0, "m tip": 5.0})
    for workers in (1, 2):
        fits = jaxtree.identify(wings, FREE, TS, batch, SIGMA, rtol=TOL, atol=TOL, start=start, workers=workers)
        assert fits.members == 2 and np.all(fits.converged)
        for i, single in enumerate((fit0, fit1)):
            for n in FREE:
                assert fits.values[n][i] == single.values[n] and fits.stderr[n][i] == single.stderr[n], (i, n)
            assert fits.steps[i] == single.steps
            np.testing.assert_array_equal(fits.residuals["hub.omega"][i], single.residuals["hub.omega"])
    # and the estimates are the vehicles' own: within a few standard errors of each truth
    for i, truth in enumerate((TRUTH, truth1)):
        assert max(abs(fits.values[n][i] - truth[n]) / fits.stderr[n][i] for n in FREE) < 4.5
    assert fits.model.stiffness.shape == (2, wings.n)
    assert float(fits.model.stiffness[1, 0]) == fits.values["k+"][1]


def test_a_parameter_no_sensor_sees_is_named(wings):
    """The wings move in their plane (every hinge about y, the hub spinning about y): a tip
    panel's I_xx changes no reading, and the fit says so."""
    data = _record(wings)
    free = {"k+": FREE["k+"], "Ixx tip": ["wingp_4.inertia[0,0]"]}
    with pytest.warns(jaxtree.IdentifiabilityWarning, match="Ixx tip"):
        fit = jaxtree.identify(wings, free, TS[:51], {k: v[:51] for k, v in data.items()}, SIGMA, rtol=1e-8, atol=1e-8)
    assert fit.unidentifiable == ("Ixx tip",)


def test_bad_input_is_named_before_anything_is_traced(wings, monkeypatch):
    """Each mistake one line naming it; the compiled fit is never reached."""

    def never(*args, **kwargs):
        raise AssertionError("traced")

    monkeypatch.setattr(fit_module, "_fit", never)
    data = {k: np.zeros((101, 3)) if k == "hub.omega" else np.zeros(101) for k in SIGMA}
    cases = [
        (dict(free=["wingp_9.mass"]), "no body 'wingp_9'"),
        (dict(free=["hub.stifness"]), "unknown quantity 'hub.stifness'"),
        (dict(free=["hub.stiffness"]), "is the base; it has no hinge"),
        (dict(free=["hub.inertia[0]"]), "takes two indices"),
        (dict(free=["hub.mass", "hub.mass"]), "named twice"),
        (dict(free={"a": ["hub.mass"], "b": ["hub.mass"]}), "already set by 'hub.mass'"),
        (dict(free={"a": ["hub.inertia[0,1]"], "b": ["hub.inertia[1,0]"]}), "already set"),
        (dict(measurements={**data, "hub.gyro": np.zeros((101, 3))}), "unknown sensor 'hub.gyro'"),
        (dict(measurements={**data, "wingp_1.angle": np.zeros(100)}), "has 100 samples; times has 101"),
        (dict(sigma={**SIGMA, "hub.omega": 0.0}), r"sigma\['hub.omega'\] must be positive"),
        (dict(sigma={**SIGMA, "hub.omega": [1, 2]}), "a scalar or 3 components"),
        (dict(sigma={"hub.omega": 1.0}), "sigma has no entry for sensor 'wingp_1.angle'"),
        (dict(times=TS[::-1]), "times must increase"),
        (dict(start={"hub.mass": -1.0}), "fitted as a logarithm but starts at -1"),
        (dict(start={"nope": 1.0}), "start: no parameter named 'nope'"),
        (dict(measurements={**data, "hub.attitude": np.zeros((101, 2))}), "an attitude is"),
    ]
    base = dict(free=["hub.mass"], times=TS, measurements=data, sigma=SIGMA)
    for change, message in cases:
        kw = {**base, **change}
        if "measurements" in change and "sigma" not in change:
            kw["sigma"] = {**SIGMA, **{k: 1.0 for k in change["measurements"] if k not in SIGMA}}
        with pytest.raises(jaxtree.SceneError, match=message) as info:
            jaxtree.identify(wings, kw.pop("free"), kw.pop("times"), kw.pop("measurements"), kw.pop("sigma"), **kw)
        assert "\n" not in str(info.value)


def test_a_fit_that_runs_out_of_steps_says_so(wings, noisy):
    """max_steps=2: not converged, a warning naming why; warn=False keeps quiet; a model that
    cannot fit the record stops at the simulations' resolution and says so; reverse-mode
    Jacobians take the same steps."""
    data, _ = noisy
    with pytest.warns(jaxtree.ConvergenceWarning, match="max_steps"):
        fit = jaxtree.identify(
            wings, ["wingp_1.stiffness"], TS[:21], {k: v[:21] for k, v in data.items()}, SIGMA, max_steps=2
        )
    assert not fit.converged and fit.steps == 2
    # run to its end, the one-parameter model cannot fit a record of six changed numbers: it stops
    # when the chi-square's decrease left is below the simulations' resolution, and says the misfit
    whole = jaxtree.identify(wings, ["wingp_1.stiffness"], TS[:21], {k: v[:21] for k, v in data.items()}, SIGMA)
    assert whole.converged and "ftol" in whole.reason and whole.steps < 20
    assert whole.chi2 / whole.dof > 1e4 and "does not fit the record" in whole.table()
    # the Jacobian by reverse mode (one cotangent per residual) takes the same two steps
    back = jaxtree.identify(
        wings, ["wingp_1.stiffness"], TS[:21], {k: v[:21] for k, v in data.items()}, SIGMA, max_steps=2,
        jacobian="reverse", warn=False,
    )  # fmt: skip
    assert back.values["wingp_1.stiffness"] == pytest.approx(fit.values["wingp_1.stiffness"], rel=1e-10)
    assert back.stderr["wingp_1.stiffness"] == pytest.approx(fit.stderr["wingp_1.stiffness"], rel=1e-8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        jaxtree.identify(
            wings, ["wingp_1.stiffness"], TS[:21], {k: v[:21] for k, v in data.items()}, SIGMA, max_steps=2, warn=False
        )


def test_the_command_line_fits_a_csv_record_and_reads_a_result_file(wings, noisy, tmp_path, capsys):
    """`jaxtree identify` on a CSV record (a unit after a name, a missing cell): the estimates of
    jaxtree.identify on the same data, a residual plot and a JSON file; a result file read by the
    named sensors gives the simulation's own histories; a mistake is one line and status 2."""
    from PIL import Image

    from jaxtree._src.cli import main
    from jaxtree._src.identify.record import load_record, save_record_csv

    data, _ = noisy
    short = {k: v[:21].copy() for k, v in data.items()}
    short["wingp_1.angle"][7] = np.nan
    csv_path = tmp_path / "record.csv"
    save_record_csv(csv_path, TS[:21], short)
    text = csv_path.read_text().replace("wingp_1.angle", "wingp_1.angle (rad)", 1)
    csv_path.write_text(text)
    direct = jaxtree.identify(wings, ["wingp_1.stiffness"], TS[:21], short, SIGMA)
    argv = ["identify", "wings", str(csv_path), "--free", "wingp_1.stiffness"]
    argv += [f"--sigma={k}={v}" for k, v in SIGMA.items()]
    argv += ["--plot", str(tmp_path / "res.png"), "-o", str(tmp_path / "fit.json")]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "wingp_1.stiffness" in out and "converged" in out
    import json

    doc = json.loads((tmp_path / "fit.json").read_text())
    assert doc["values"]["wingp_1.stiffness"] == pytest.approx(direct.values["wingp_1.stiffness"], rel=1e-12)
    assert doc["stderr"]["wingp_1.stiffness"] == pytest.approx(direct.stderr["wingp_1.stiffness"], rel=1e-9)
    assert doc["dof"] == 21 * 5 - 1 - 1
    with Image.open(tmp_path / "res.png") as png:
        assert png.size[0] > 500
    # a result file, read by the sensors
    sol = jaxtree.simulate(wings, 2.0, saveat=jnp.asarray(TS[:21]), rtol=TOL, atol=TOL)
    jaxtree.save_result(tmp_path / "run.nc", sol)
    ts, reads = load_record(tmp_path / "run.nc", wings, ["hub.omega", "wingm_1.rate"])
    np.testing.assert_allclose(ts, TS[:21], rtol=0, atol=1e-15)
    np.testing.assert_allclose(reads["hub.omega"], sol.omega0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(reads["wingm_1.rate"], sol.gamma_dot[:, 4], rtol=0, atol=1e-15)
    # a mistake: one line, status 2
    assert main(["identify", "wings", str(csv_path), "--free", "wingp_1.stiffnes", "--sigma", "hub.omega=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown quantity 'wingp_1.stiffnes'" in err[0]


def test_quantities_by_name_set_the_numbers_they_name():
    """with_quantities (identify's names): an inertia product sets both entries, a hinge's initial
    rate, a leaf by its path (the base's initial rate, the prescription's amplitude of fig4); the
    rest of the model untouched; traced values too (a derivative through the name)."""
    model = jaxtree.load_scene("fig4")
    names = model.names
    values = {
        f"{names[0]}.inertia[0,1]": 3.5,
        f"{names[3]}.initial_rate": 0.25,
        "initial.omega0[2]": -0.125,
        "prescription.amplitude[0]": 0.75,
        f"{names[2]}.hinge_on_body[1]": 0.5,
    }
    m = jaxtree.with_quantities(model, values)
    assert float(m.inertia[0, 0, 1]) == 3.5 and float(m.inertia[0, 1, 0]) == 3.5
    assert float(m.initial.gamma_dot[2]) == 0.25 and float(m.initial.omega0[2]) == -0.125
    assert float(m.prescription.amplitude[0]) == 0.75 and float(m.hinge_on_body[1, 1]) == 0.5
    changed = {(0, 0, 1), (0, 1, 0)}
    diff = np.argwhere(np.asarray(m.inertia) != np.asarray(model.inertia))
    assert {tuple(int(i) for i in d) for d in diff} == changed
    np.testing.assert_array_equal(m.mass, model.mass)
    np.testing.assert_array_equal(m.stiffness, model.stiffness)
    d = jax.grad(lambda x: jaxtree.with_quantities(model, {f"{names[1]}.mass": x}).mass.sum())(2.0)
    assert float(d) == 1.0
    with pytest.raises(jaxtree.SceneError, match="leaf 'initial.omega0' has shape"):
        jaxtree.with_quantities(model, {"initial.omega0[3]": 1.0})
