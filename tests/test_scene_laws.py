"""Scenes that carry their loads and laws (the optional ``loads``, ``control`` and ``orbit`` keys of
``jaxtree-scene/1`` and the prescribed ramp, smooth step and table), against independent closed
forms: angular momentum under scheduled torques, a PD hinge as a damped oscillator, a PID's
integral action, the prescription profiles, the gravity-gradient torque as the sum of the central
body's pull on point masses; a scene with every key round-trips bit for bit; errors name the key
and the body; ``jaxtree check`` lists the laws; ``jaxtree simulate`` carries a PID across its parts.
"""

import contextlib
import copy
import io
import json
import math
import pathlib

import diffrax
import equinox as eqx
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicHermiteSpline

import jaxtree
from jaxtree._src import cli

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "slew_in_orbit.json"
TOL = 1e-10  # rtol = atol of the runs here
CLOSED_FORM = 1e-7  # a closed form against a run at TOL (global error of ~100 steps)
TIGHT = 1e-12  # rtol = atol of scipy's reference pendulum and of the orbit run
ROUNDOFF = 1e-12  # the Euler angles a rotation about z leaves at zero: round-off
PD_ARM = 1e-6  # the PD arm against its damped-oscillator closed form, run at TOL: observed 2e-8, with margin
# the overshoot read at the save times (every 0.25 s) against the closed form's peak: the samples miss the
# peak by 0.008 here
OVERSHOOT = 0.02
# the PID arm's end against its set point, and its integral against the load it balances: observed 3e-8
# and 2e-7, with margin
PID_END = 1e-4
PID_INTEGRAL = 1e-3
SETTLED = 0.01  # the docstring's bound: 1 % of the PD offset left after 6 s (observed 0.2 %)
PARTS = 1e-7  # the run in 4 parts against one call, both at TOL: their global errors, like CLOSED_FORM
# the prescriptions (O(1) numbers, absolute) and the orbit rate (relative) against their closed forms: a
# few ulps; the rates (and the table against scipy's spline, another evaluation order) tens, the table's
# rate a hundred
ULPS = 1e-15
ULPS_RATE = 1e-14
ULPS_TABLE_RATE = 1e-13
# the gravity-gradient torque against the central pull summed over point masses: the next term of the
# expansion, O(|rho| / R) = 2e-7 of the torque
GRADIENT_EXPANSION = 1e-6
# the mass center against the circular orbit over a tenth of an orbit at TIGHT: the integration error,
# relative to the radius
ORBIT = 1e-9
BIG = 1e8  # mass and inertia of a base that stays put (coupling to the arms ~ 1 / BIG)


def _scene(bodies, **keys):
    return {"format": "jaxtree-scene/1", "name": "t", "bodies": bodies, **keys}


def _arm(name, axis, on_parent, joint=None):
    """A 2 kg arm, its mass center 0.5 m from its hinge: inertia about the hinge 0.1 + 2 * 0.25."""
    return {
        "name": name,
        "mass": 2.0,
        "inertia": np.diag([0.1, 0.1, 0.1]).tolist(),
        "parent": 0,
        "axis": axis,
        "hinge_on_parent": on_parent,
        "hinge_on_body": [-0.5, 0.0, 0.0],
        "joint": joint or {"kind": "free"},
    }


J_ARM = 0.1 + 2.0 * 0.5**2


# ----------------------------------------------------------------------------- body torques
def test_scheduled_torques_and_force_on_a_rigid_body_follow_their_integrals():
    """Constant, pulse and table torques all about the body's z axis (a principal axis; from rest
    the body turns about it only): H_z(t) = tau_c t + tau_p P(t) + tau_t A(t) with P, A the
    integrals of the tanh pulse and of the piecewise-linear table; omega_z = H_z / I_zz; a constant
    force along z moves the mass center as F t^2 / (2 M) (Eq. 2)."""
    tc, tp, tt, F, M, Izz = 0.3, 1.5, -0.8, 2.0, 50.0, 7.0
    start, dur, rise = 0.5, 1.0, 0.05
    times, values = [0.0, 1.0, 2.5], [0.0, 1.0, 0.25]
    model = jaxtree.scene_from_dict(
        _scene(
            [{"name": "sat", "mass": M, "inertia": np.diag([5.0, 6.0, Izz]).tolist()}],
            loads=[
                {"kind": "torque", "body": "sat", "vector": [0, 0, tc]},
                {
                    "kind": "torque",
                    "body": 0,
                    "vector": [0, 0, tp],
                    "profile": {"kind": "pulse", "start": start, "duration": dur, "rise": rise},
                },
                {
                    "kind": "torque",
                    "body": "sat",
                    "vector": [0, 0, tt],
                    "profile": {"kind": "table", "times": times, "values": values},
                },
                {"kind": "force", "body": "sat", "vector": [0, 0, F], "profile": {"kind": "constant"}},
            ],
        )
    )
    ts = np.linspace(0.0, 3.0, 13)
    sol = jaxtree.simulate(model, 3.0, saveat=ts, rtol=TOL, atol=TOL, translation=True)

    lc = lambda x: np.logaddexp(x, -x) - math.log(2)
    P = (
        0.5
        * rise
        * (lc((ts - start) / rise) - lc(-start / rise) - lc((ts - start - dur) / rise) + lc((-start - dur) / rise))
    )
    # the table's integral: trapezoids up to t (linear between the points, held after the last)
    fine = np.linspace(0.0, 3.0, 300001)
    A = np.interp(
        ts,
        fine,
        np.concatenate(
            [[0.0], np.cumsum(np.diff(fine) * 0.5 * (lambda v: v[1:] + v[:-1])(np.interp(fine, times, values)))]
        ),
    )
    H = tc * ts + tp * P + tt * A
    np.testing.assert_allclose(np.asarray(sol.angular_momentum[:, 2]), H, atol=CLOSED_FORM)
    np.testing.assert_allclose(np.asarray(sol.angular_momentum[:, :2]), 0.0, atol=CLOSED_FORM)
    np.testing.assert_allclose(np.asarray(sol.omega0[:, 2]), H / Izz, atol=CLOSED_FORM)
    assert sol.X is not None
    np.testing.assert_allclose(np.asarray(sol.X[:, 2]), F * ts**2 / (2 * M), atol=CLOSED_FORM)


def test_attitude_pd_slews_the_bus_as_its_pendulum_equation():
    """About the z axis of a body with equal moments J, from rest 0.8 rad from the set point (Euler
    1-2-3 angles (0, 0, 0.3)): J theta'' = -kp sin(theta) - kd theta' (scipy's solve_ivp)."""
    J, kp, kd = 20.0, 30.0, 25.0
    model = jaxtree.scene_from_dict(
        _scene(
            [{"name": "bus", "mass": 100.0, "inertia": (J * np.eye(3)).tolist()}],
            initial={
                "attitude_dcm": np.asarray(
                    jaxtree._src.equations.attitude.euler123_to_dcm(np.array([0, 0, 1.1]))
                ).tolist()
            },
            control=[{"kind": "attitude_pd", "kp": kp, "kd": [kd, kd, kd], "euler123": [0.0, 0.0, 0.3]}],
        )
    )
    ts = np.linspace(0.0, 8.0, 17)
    sol = jaxtree.simulate(model, 8.0, saveat=ts, rtol=TOL, atol=TOL)
    ref = solve_ivp(
        lambda t, y: [y[1], (-kp * np.sin(y[0]) - kd * y[1]) / J], (0, 8), [0.8, 0.0], t_eval=ts, rtol=TIGHT, atol=TIGHT
    )
    psi = np.asarray(jaxtree._src.equations.attitude.dcm_to_euler123(sol.dcm))
    np.testing.assert_allclose(psi[:, 2] - 0.3, ref.y[0], atol=CLOSED_FORM)
    np.testing.assert_allclose(np.asarray(sol.omega0[:, 2]), ref.y[1], atol=CLOSED_FORM)
    np.testing.assert_allclose(psi[:, :2], 0.0, atol=ROUNDOFF)


# ----------------------------------------------------------------------------- hinge laws
@pytest.fixture(scope="module")
def arms():
    """A base that stays put, arm 1 under a PD law to a set point, arm 2 under a PID law against
    a constant torque on it; the scene and its 12 s run (one compiled program for the module)."""
    data = _scene(
        [
            {"name": "base", "mass": BIG, "inertia": (BIG * np.eye(3)).tolist()},
            _arm("pd_arm", [0, 0, 1], [1.0, 0, 0]),
            _arm("pid_arm", [0, 0, 1], [-1.0, 0, 0]),
        ],
        loads=[{"kind": "torque", "body": "pid_arm", "vector": [0, 0, 0.3]}],
        control=[
            {"kind": "hinge_pd", "hinge": "pd_arm", "kp": 4.0 * J_ARM, "kd": 2 * 0.3 * 2.0 * J_ARM, "set_point": 0.4},
            # (s + 2)^3 J: kd = 6 J, kp = 12 J, ki = 8 J; a fast rate filter
            {
                "kind": "hinge_pid",
                "hinge": 2,
                "kp": 12 * J_ARM,
                "ki": 8 * J_ARM,
                "kd": 6 * J_ARM,
                "filter_time": 0.02,
                "set_point": -0.25,
            },
        ],
    )
    model = jaxtree.scene_from_dict(data)
    ts = np.linspace(0.0, 12.0, 49)
    sol = jaxtree.simulate(model, 12.0, saveat=ts, rtol=TOL, atol=TOL)
    return data, model, ts, sol


def test_pd_law_is_a_damped_oscillator_with_the_damping_ratio_of_its_gains(arms):
    """J g'' + kd g' + kp (g - r) = 0 from rest at 0: wn = sqrt(kp / J) = 2 rad/s, zeta = kd /
    (2 sqrt(kp J)) = 0.3; g(t) = r [1 - e^{-zeta wn t} (cos wd t + zeta / sqrt(1 - zeta^2) sin wd t)]."""
    _, model, ts, sol = arms
    assert isinstance(model.law, jaxtree.HingePD) and model.law.hinges == (1,)
    wn, zeta, r = 2.0, 0.3, 0.4
    wd = wn * math.sqrt(1 - zeta**2)
    g = r * (1 - np.exp(-zeta * wn * ts) * (np.cos(wd * ts) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * ts)))
    np.testing.assert_allclose(np.asarray(sol.gamma[:, 0]), g, atol=PD_ARM)
    overshoot = float(np.max(np.asarray(sol.gamma[:, 0]))) / r - 1
    assert overshoot == pytest.approx(math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2)), abs=OVERSHOOT)  # 37 %


def test_pid_law_removes_the_offset_of_a_constant_torque(arms):
    """A PD law would settle 0.3 / kp = 0.042 rad off the set point; the integral takes it away
    (a triple pole at -2 rad/s: 1 % of that offset left after 6 s)."""
    _, model, ts, sol = arms
    assert isinstance(model.controller, jaxtree.HingePID)
    g = np.asarray(sol.gamma[:, 1])
    assert abs(g[-1] - (-0.25)) < PID_END
    assert np.max(np.abs(g[ts > 6] - (-0.25))) < SETTLED * 0.3 / (12 * J_ARM)
    z = sol.control_state
    # at rest at the set point the integral balances the load: ki * integral = 0.3
    assert float(z["integral"][-1, 0]) * 8 * J_ARM == pytest.approx(0.3, rel=PID_INTEGRAL)


def test_cli_simulate_carries_the_pid_states_across_parts(arms, tmp_path):
    """`jaxtree simulate` in 4 parts ends where one simulate call does (a PID restarted at each
    part would lose its integral and leave the arm off its set point)."""
    data, model, ts, sol = arms
    path = tmp_path / "arms.json"
    path.write_text(json.dumps(data))
    out = tmp_path / "arms.nc"
    args = ["simulate", str(path), "--t1", "12", "--points", "49", "--chunks", "4", "--out", str(out)]
    args += ["--rtol", str(TOL), "--atol", str(TOL), "--no-progress", "--no-plot", "--no-error-estimate"]
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(args) == 0
    ds = jaxtree.load_result(out, as_dataset=True)
    np.testing.assert_allclose(ds["gamma"].values, np.asarray(sol.gamma), atol=PARTS)


# ----------------------------------------------------------------------------- prescriptions
def test_ramp_smooth_step_and_table_prescriptions_equal_their_closed_forms():
    base = {"name": "base", "mass": 10.0, "inertia": np.eye(3).tolist()}
    times, angles = [0.0, 1.0, 2.0, 4.0], [0.0, 0.3, -0.1, 0.2]
    model = jaxtree.scene_from_dict(
        _scene(
            [
                base,
                _arm(
                    "ramp",
                    [0, 0, 1],
                    [1, 0, 0],
                    {
                        "kind": "prescribed",
                        "function": "ramp",
                        "initial": 0.1,
                        "final": 0.7,
                        "start": 1.0,
                        "duration": 2.0,
                    },
                ),
                _arm(
                    "step",
                    [0, 1, 0],
                    [-1, 0, 0],
                    {"kind": "prescribed", "function": "smooth_step", "final": -0.5, "duration": 4.0},
                ),
                _arm(
                    "table",
                    [1, 0, 0],
                    [0, 1, 0],
                    {"kind": "prescribed", "function": "table", "times": times, "angles": angles},
                ),
            ]
        )
    )
    pres = model.prescription
    assert pres is not None
    # slopes of the table: centred differences inside, zero at the ends (the documented rule)
    t_, a_ = np.asarray(times), np.asarray(angles)
    m = np.zeros(4)
    m[1:-1] = (a_[2:] - a_[:-2]) / (t_[2:] - t_[:-2])
    spline = CubicHermiteSpline(t_, a_, m)
    for t in (-0.5, 0.0, 0.7, 1.0, 1.5, 2.2, 2.999, 3.0, 3.7, 4.0, 5.0):
        g, gd, _ = pres.derivatives(t)
        got = dict(zip(pres.hinges, np.asarray(g)))
        rate = dict(zip(pres.hinges, np.asarray(gd)))
        s = min(max((t - 1.0) / 2.0, 0.0), 1.0)
        assert got[1] == pytest.approx(0.1 + 0.6 * s, abs=ULPS)
        if 1.0 < t < 3.0:
            assert rate[1] == pytest.approx(0.3, abs=ULPS_RATE)
        u = min(max(t / 4.0, 0.0), 1.0)
        assert got[2] == pytest.approx(-0.5 * (10 * u**3 - 15 * u**4 + 6 * u**5), abs=ULPS)
        assert rate[2] == pytest.approx(-0.5 * 30 * u**2 * (1 - u) ** 2 / 4.0, abs=ULPS_RATE)
        tc = min(max(t, 0.0), 4.0)
        assert got[3] == pytest.approx(float(spline(tc)), abs=ULPS_RATE)
        if 0.0 < t < 4.0:
            assert rate[3] == pytest.approx(float(spline(tc, 1)), abs=ULPS_TABLE_RATE)


# ----------------------------------------------------------------------------- gravity gradient
def test_gravity_gradient_torque_is_the_central_pull_on_the_mass_distribution():
    """3 n^2 r x (I r) against the torque of -mu m_i (R + rho_i) / |R + rho_i|^3 summed over six
    point masses with the body's inertia (agreement to O(|rho| / R))."""
    mu, R, phase, t = 3.986004418e14, 7.0e6, 0.3, 40.0
    pts = []
    for axis, half, mass in ((0, 1.5, 3.0), (1, 1.0, 5.0), (2, 0.6, 4.0)):
        for sign in (1.0, -1.0):
            p = np.zeros(3)
            p[axis] = sign * half
            pts.append((mass, p))
    I = sum(m * (p @ p * np.eye(3) - np.outer(p, p)) for m, p in pts)
    M = sum(m for m, _ in pts)
    model = jaxtree.scene_from_dict(
        _scene(
            [{"name": "sat", "mass": M, "inertia": I.tolist()}],
            orbit={"mu": mu, "radius": R, "phase": phase},
            loads=[{"kind": "gravity_gradient"}],
        )
    )
    assert model.orbit is not None
    n = math.sqrt(mu / R**3)
    assert float(model.orbit.rate) == pytest.approx(n, rel=ULPS)
    # an attitude with no principal axis along the radius: C = Rz(0.7) Ry(-0.4) Rx(1.1)
    c, s = np.cos, np.sin
    Rx = lambda a: np.array([[1, 0, 0], [0, c(a), s(a)], [0, -s(a), c(a)]])
    Ry = lambda a: np.array([[c(a), 0, -s(a)], [0, 1, 0], [s(a), 0, c(a)]])
    Rz = lambda a: np.array([[c(a), s(a), 0], [-s(a), c(a), 0], [0, 0, 1]])
    C = Rz(0.7) @ Ry(-0.4) @ Rx(1.1)  # {b} = C {i}
    state = jaxtree.State(C, np.zeros(3), np.zeros(0), np.zeros(0))
    assert model.loads is not None
    F, T = model.loads(t, state)
    a = n * t + phase
    X = R * np.array([np.cos(a), np.sin(a), 0.0])
    torque_i = np.zeros(3)
    for m, p in pts:
        rho = C.T @ p  # inertial
        torque_i += np.cross(rho, -mu * m * (X + rho) / np.linalg.norm(X + rho) ** 3)
    expected = C @ torque_i
    assert np.abs(expected).max() > 1e-7  # a torque worth comparing
    np.testing.assert_allclose(np.asarray(T[0]), expected, rtol=0, atol=GRADIENT_EXPANSION * np.abs(expected).max())
    np.testing.assert_allclose(np.asarray(F[0]), 0.0, atol=1e-300)  # about its own mass center


def test_translation_in_orbit_follows_the_circular_orbit_of_eq_2_with_the_central_body():
    """simulate(translation=True) on a scene with an orbit: Eq. (2) with -mu M X / |X|^3 from the
    orbit's position and velocity at t0; with no other force the mass center stays on the closed
    form X(t) = radius (cos(n t + phase), sin(n t + phase), 0) (to the integration error, 1e-9 of
    the radius over a tenth of an orbit)."""
    mu, R, phase = 3.986004418e14, 6.8e6, 0.4
    sat = {"name": "sat", "mass": 50.0, "inertia": np.diag([4.0, 5.0, 6.0]).tolist()}
    model = jaxtree.scene_from_dict(_scene([sat], orbit={"mu": mu, "radius": R, "phase": phase}))
    n = math.sqrt(mu / R**3)
    T = 0.2 * math.pi / n
    ts = np.linspace(0.0, T, 5)
    sol = jaxtree.simulate(model, T, saveat=ts, translation=True, rtol=TIGHT, atol=TIGHT)
    a = n * ts + phase
    X = R * np.stack([np.cos(a), np.sin(a), 0.0 * a], -1)
    np.testing.assert_allclose(np.asarray(sol.X), X, rtol=0, atol=ORBIT * R)
    # the attraction is in the equations: without it the start velocity would carry the mass
    # center along the tangent, 1 / cos(0.2 pi) - 1 = 24 % of the radius off the circle at the end
    assert abs(np.linalg.norm(np.asarray(sol.X[-1])) - R) < ORBIT * R


# ----------------------------------------------------------------------------- round trip, check
def test_a_scene_with_every_key_round_trips_to_the_same_simulation_bit_for_bit(tmp_path):
    data = json.loads(EXAMPLE.read_text())
    assert {"loads", "control", "orbit"} <= set(data)
    kinds = {e["kind"] for e in data["loads"]} | {e["kind"] for e in data["control"]}
    kinds |= {e["profile"]["kind"] for e in data["loads"] if "profile" in e}
    kinds |= {b["joint"].get("function") for b in data["bodies"][1:]}
    assert {
        "torque",
        "force",
        "gravity_gradient",
        "hinge_pd",
        "hinge_pid",
        "attitude_pd",
        "constant",
        "pulse",
        "table",
    } <= kinds
    assert {"ramp", "smooth_step", "table"} <= kinds
    model = jaxtree.load_scene(EXAMPLE)
    path = tmp_path / "again.json"
    jaxtree.save_scene(model, path)
    again = jaxtree.load_scene(path)
    assert jaxtree.scene_to_dict(again) == jaxtree.scene_to_dict(model)
    d = jaxtree.scene_to_dict(model)
    assert d["orbit"] == data["orbit"] and len(d["loads"]) == len(data["loads"])
    assert len(d["control"]) == len(data["control"])
    run = lambda m: jaxtree.simulate(m, 2.0, saveat=5, solver=diffrax.Tsit5(), rtol=1e-7, atol=1e-7)
    a, b = run(model), run(again)
    for field in ("gamma", "gamma_dot", "omega0", "dcm", "hold_torque", "energy"):
        x, y = np.asarray(getattr(a, field)), np.asarray(getattr(b, field))
        assert np.all(x == y), field
    assert np.all(np.asarray(a.control_state["integral"]) == np.asarray(b.control_state["integral"]))
    # the laws act: the wing moves toward its set point, the antenna toward its own
    assert float(a.gamma[-1, 0]) > 0.05 and float(a.gamma[-1, 1]) < -0.02


def test_check_lists_the_loads_and_laws(capsys):
    assert cli.main(["check", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    for text in (
        "loads and laws (applied by jaxtree simulate):",
        "prescribed hinge 3 ('scan_mirror'): smooth step 0 -> 0.4 rad from t = 2 s over 8 s",
        "prescribed hinge 4 ('shutter'): ramp 0 -> 1.2 rad",
        "prescribed hinge 5 ('camera'): table of 5 points",
        "load: torque [0, 0, 2] N m on body 0 ('bus'), pulse from t = 1 s for 2 s",
        "load: force [0, 0, 0.0001] N on body 1 ('wing'), times a table of 3 points",
        "load: gravity gradient at the orbit's rate 0.00113137 rad/s",
        "control: hinge 1 ('wing') PD to 0.3 rad, kp 60 N m/rad, kd 170 N m s/rad",
        "control: hinge 2 ('antenna') PID to -0.2 rad",
        "control: body 0 ('bus') attitude PD to Euler 1-2-3 angles [0, 0, 0.1] rad, kp [100, 90, 75] N m/rad",
        "orbit: circular, radius 6.77814e+06 m",
    ):
        assert text in out, text


# ----------------------------------------------------------------------------- validation
def _with(change):
    data = json.loads(EXAMPLE.read_text())
    change(data)
    return data


def _set(path, value):
    def change(d):
        target = d
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value

    return change


@pytest.mark.parametrize(
    "change, message",
    [
        (
            _set(["loads", 0, "body"], "nobody"),
            r"loads\[0\] \(torque\): field 'body' names 'nobody', which is not a body",
        ),
        (_set(["loads", 2, "vector"], [0, 1]), r"loads\[2\] \(force on body 1 \('wing'\)\): field 'vector' must have"),
        (
            _set(["loads", 0, "profile", "rise"], 0),
            r"loads\[0\] \(torque on body 0 \('bus'\)\): field 'profile' \(pulse\): field 'rise' must be > 0",
        ),
        (
            _set(["loads", 2, "profile", "times"], [0, 20, 10]),
            r"loads\[2\] \(force on body 1 \('wing'\)\): field 'profile.times' must be strictly increasing",
        ),
        (_set(["loads", 0, "kind"], "torqe"), r"loads\[0\]: unknown kind 'torqe'"),
        (lambda d: d.pop("orbit"), r"loads\[3\] \(gravity_gradient\): needs the scene's 'orbit'"),
        (_set(["orbit", "radius"], -1.0), r"orbit: field 'radius' must be > 0"),
        (
            _set(["control", 0, "kd"], -1.0),
            r"control\[0\] \(hinge_pd on hinge 1, body 1 \('wing'\)\): field 'kd' must be >= 0",
        ),
        (
            _set(["control", 1, "hinge"], "wing"),
            r"control\[1\] \(hinge_pid on hinge 1, body 1 \('wing'\)\): the hinge already has a law",
        ),
        (
            _set(["control", 0, "hinge"], "camera"),
            r"control\[0\] \(hinge_pd on hinge 5, body 5 \('camera'\)\): the hinge is prescribed",
        ),
        (_set(["control", 0, "hinge"], "bus"), r"control\[0\] \(hinge_pd\): field 'hinge' must name a hinge body"),
        (
            lambda d: d["control"][1].pop("filter_time"),
            r"control\[1\] \(hinge_pid on hinge 2, body 2 \('antenna'\)\): field 'filter_time' is missing",
        ),
        (
            _set(["bodies", 3, "joint", "duration"], 0.0),
            r"body 3 \('scan_mirror'\): field 'joint.duration' must be > 0",
        ),
        (_set(["bodies", 5, "joint", "angles"], [0, 1]), r"body 5 \('camera'\): field 'joint.angles' must have"),
        (
            _set(["bodies", 4, "joint", "function"], "cosine"),
            r"body 4 \('shutter'\): field 'joint.function' must be 'sine', 'ramp'",
        ),
        (lambda d: d["bodies"][4]["joint"].pop("final"), r"body 4 \('shutter'\): field 'joint.final' is missing"),
        (
            _set(["control", 2, "kp"], [1, 2]),
            r"control\[2\] \(attitude_pd on body 0 \('bus'\)\): field 'kp' must be a number or 3",
        ),
        (
            _set(["control", 2, "attitude_dcm"], np.eye(3).tolist()),
            r"control\[2\] \(attitude_pd on body 0 \('bus'\)\): give the set point once",
        ),
    ],
)
def test_errors_name_the_key_and_the_body(change, message):
    with pytest.raises(jaxtree.SceneError, match=message):
        jaxtree.scene_from_dict(_with(change))


def test_unknown_keys_in_the_new_entries_are_refused_with_the_nearest_known_key():
    data = _with(lambda d: d["control"][0].update(kpp=1.0))
    with pytest.raises(jaxtree.SceneError, match=r"control\[0\] \(hinge_pd\): unknown key 'kpp'"):
        jaxtree.scene_from_dict(data)
    data = _with(lambda d: d["loads"][0]["profile"].update(ris=1.0))
    with pytest.raises(jaxtree.SceneError, match=r"unknown key 'ris' \(did you mean 'rise'\?"):
        jaxtree.scene_from_dict(data)
    # a key of the user's own: read past, and not written back
    data = _with(lambda d: d["control"][0].update({"x-note": "tuned 2026-11"}))
    model = jaxtree.scene_from_dict(data)
    assert model.law is not None
    assert "x-note" not in json.dumps(jaxtree.scene_to_dict(model))


def test_models_without_a_json_form_say_so():
    model = jaxtree.load_scene(EXAMPLE)
    pd = jaxtree.HingePD(model.n, [1], 1.0, 1.0, reference=lambda t: 0.1 * t)
    with pytest.raises(ValueError, match="model.law"):
        jaxtree.scene_to_dict(model.with_control(pd, None))
    with pytest.raises(ValueError, match="PerBodyLoads"):
        jaxtree.scene_to_dict(model.with_loads(jaxtree.PerBodyLoads({0: lambda t, s: (np.zeros(3), np.zeros(3))})))
    # a gravity-gradient load built in Python saves its orbit
    plain = jaxtree.load_scene("fig4_free")
    gg = jaxtree.GravityGradient(plain, radius=7.2e6)
    d = jaxtree.scene_to_dict(plain.with_loads(gg))
    assert d["orbit"]["radius"] == 7.2e6 and d["loads"] == [{"kind": "gravity_gradient"}]
    assert copy.deepcopy(d) == jaxtree.scene_to_dict(jaxtree.scene_from_dict(d))


def test_validate_model_checks_the_new_leaves_and_hybrid_model_refuses_laws():
    model = jaxtree.load_scene(EXAMPLE)
    assert jaxtree.validate_model(model) is model
    shapes = model.prescription.parts[0]  # the ramp and smooth-step hinges (3, 4)
    bad = eqx.tree_at(lambda m: m.prescription.parts[0].duration, model, shapes.duration.at[1].set(-1.0))
    with pytest.raises(jaxtree.SceneError, match=r"body 4 \('shutter'\): field 'joint.duration' must be > 0"):
        jaxtree.validate_model(bad)
    with pytest.raises(jaxtree.SceneError, match=r"hybrid_model: the model carries hinge control laws"):
        jaxtree.hybrid_model(model, [1, 2])
