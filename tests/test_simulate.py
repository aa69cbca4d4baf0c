"""jaxtree.simulate: conservation laws, closed forms, the independent Lagrange oracle integrated
by scipy, and the bookkeeping of prescribed hinges, controllers, loads, events and failures.

Every expected number comes from an independent source: conservation of energy and angular
momentum, closed-form solutions of a two-body "coaxial" vehicle (both mass centers on the hinge
axis, so the motion is a planar rotation with the reduced inertia I0 I1 / (I0 + I1)), scipy's
expm and DOP853 with tests/oracle.py, and the prescription's own inverse function.
"""

import contextlib
import dataclasses
import io
import re
import sys
import time

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

import jaxtree
from jaxtree import State, simulate
from jaxtree._src.equations import rules
from jaxtree._src.equations.control import hinge_torque_vector
from jaxtree._src.integration.problem import with_jacobian

from helpers import count_equations, primitive_names, random_state
from oracle import oracle_at
from trees import chain, sprung_tree

# Conservation over 100 s of fig4_free at rtol = atol = 1e-12 (the requirement).
DRIFT_100S = 1e-9
# Two integrations of the same motion at rtol = atol = TIGHT agree to their global error:
# tens of times the local tolerance over a few thousand steps (observed 1e-11 .. 3e-10).
TIGHT = 1e-12
GLOBAL = 1e-8
# rtol = atol of the runs checked against closed forms, event times and one another below
RUN_TOL = 1e-11
# Closed forms against a run at rtol = atol = RUN_TOL over a few periods (observed ~1e-11).
CLOSED = 1e-9
# Newton root finding of events on the dense output (tolerance 1e-10 on the time).
EVENT_TIME = 1e-9
# O(1) numbers a run passes through (its save times, a prescription's sine, the given C): a few ulps
ULPS = 1e-15
ORTHOGONAL = 1e-14  # C of the quaternion and Euler-angle runs, orthogonal by construction: round-off
# C integrated by Eq. (3) at RUN_TOL over 10 s drifts from orthogonality by its global error (as CLOSED)
DCM_DRIFT = 1e-9
# relative energy drift of a conservative run at RUN_TOL over 2 s: its global error (as CLOSED)
DRIFT = 1e-9
DRIFT_LOOSE = 1e-6  # the same at rtol = atol = 1e-8 over 0.5 s
# the Euler-angle attitude's default singularity_tol (runs stop where |cos theta_2| falls below it), and
# the time from t = pi/2 within which that happens for b = 0.005 (closed form, docstring)
EULER_STOP = 0.01
STOP_WINDOW = 0.0087
# GravityGradient against inverse-square gravity on point masses: the next term of the expansion,
# O(size / R) ~ 1e-7 of w^2 |J| (torque) and w^2 m (tidal force), with margin
GRADIENT_EXPANSION = 1e-5
# a run's error against the closed form in units of its own tolerance, over a sweep of tolerances:
# observed at most 0.03, with margin
PER_TOLERANCE = 100
GRADIENT = 1e-7  # d gamma(T) / dk through a run at RUN_TOL against its closed form: observed 1e-13, with margin
# a float32 run at rtol = atol = 1e-5 against the closed form: observed 2e-6, with margin
FLOAT32_CLOSED = 1e-4
# a float32 run at its default rtol = 1e-4 over 10 s against float64 at 1e-9: 6e-4 measured
FLOAT32 = 2e-3
# runs at rtol = atol = 1e-6 (explicit, Kvaerno5, Radau5) against one at 1e-10: ten times their tolerance
STIFF_GLOBAL = 1e-5
FD_JACOBIAN = 1e-7  # central differences (h = 1e-6) against an exact Jacobian, relative to its largest entry

I0 = np.diag([2.0, 3.0, 4.0])
I1 = np.diag([0.5, 0.6, 0.7])
I_EFF = I0[2, 2] * I1[2, 2] / (I0[2, 2] + I1[2, 2])


def coaxial(joint=None, gamma0=0.0, omega0=(0.0, 0.0, 0.0), loads=None):
    """Base and arm on a hinge along z through both mass centers: gamma_ddot = tau / I_EFF."""
    joint = jaxtree.Free() if joint is None else joint
    bodies = [
        jaxtree.Body("base", 10.0, I0),
        jaxtree.Body("arm", 2.0, I1, 0, [0.0, 0.0, 1.0], [0.0, 0.0, 0.5], [0.0, 0.0, -0.5], joint),
    ]
    return jaxtree.build_model(bodies, {"gamma": [gamma0], "omega0": list(omega0)}, loads=loads)


def free_copy(model, hinge):
    """`model` with hinge `hinge` made free (same bodies, initial state and order)."""
    d = jaxtree.scene_to_dict(model)
    d["bodies"][hinge]["joint"] = {"kind": "free"}
    return jaxtree.scene_from_dict(d)


def state_row(sol, i):
    return State(sol.dcm[i], sol.omega0[i], sol.gamma[i], sol.gamma_dot[i])


def maxdiff(a, b):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


# ----------------------------------------------------------------------------- conservation
def test_energy_and_momentum_are_conserved_over_100s(scenes):
    sol = simulate(scenes["fig4_free"], 100.0, rtol=TIGHT, atol=TIGHT)
    assert sol.ok and float(sol.t_final) == 100.0
    assert float(sol.energy_drift()) <= DRIFT_100S
    assert float(sol.momentum_drift()) <= DRIFT_100S
    # the rotor really spins and the panels really move (the test is not vacuous)
    assert float(sol.gamma[-1, 3]) > 300.0
    assert np.ptp(np.asarray(sol.gamma[:, 5])) > 0.1


def test_forward_then_backward_returns_to_the_start(scenes):
    model = scenes["fig4_free"]
    fwd = simulate(model, 10.0, rtol=TIGHT, atol=TIGHT)
    back = simulate(model, 0.0, t0=10.0, y0=fwd.final, rtol=TIGHT, atol=TIGHT)
    assert float(back.t_final) == 0.0
    for got, want in zip(back.final, model.initial):
        assert maxdiff(got, want) < GLOBAL


# ----------------------------------------------------------------------------- oracle
def test_trajectory_matches_the_lagrange_oracle_with_scipy_dop853(scenes):
    """The independent oracle of tests/oracle.py integrated by scipy's DOP853 (1 s of fig4_free)."""
    model = scenes["fig4_free"]
    n = model.n
    k = np.asarray(model.stiffness)

    def rhs(t, x):
        C, w, g, gd = x[:9].reshape(3, 3), x[9:12], x[12 : 12 + n], x[12 + n :]
        o = oracle_at(model, State(C, w, g, gd), tau=-k * g)
        Cdot = -np.cross(w, C, axisa=0, axisb=0, axisc=0)  # Eq. (3), column by column
        return np.concatenate([Cdot.ravel(), np.asarray(o["omega0_dot"]), gd, np.asarray(o["gamma_ddot"])])

    s = model.initial
    x0 = np.concatenate([np.ravel(s.dcm), s.omega0, s.gamma, s.gamma_dot])
    ts = np.linspace(0.0, 1.0, 101)
    ref = solve_ivp(rhs, (0.0, 1.0), x0, method="DOP853", rtol=TIGHT, atol=TIGHT, t_eval=ts).y.T
    sol = simulate(model, 1.0, rtol=TIGHT, atol=TIGHT)  # 101 evenly spaced save times
    assert np.allclose(np.asarray(sol.ts), ts, rtol=0, atol=ULPS)
    assert maxdiff(sol.dcm, ref[:, :9].reshape(-1, 3, 3)) < GLOBAL
    assert maxdiff(sol.omega0, ref[:, 9:12]) < GLOBAL
    assert maxdiff(sol.gamma, ref[:, 12 : 12 + n]) < GLOBAL
    assert maxdiff(sol.gamma_dot, ref[:, 12 + n :]) < GLOBAL


# ----------------------------------------------------------------------------- attitude
# fig4 runs save 101 times and the dense output: the hold-torque test reuses the compiled quaternion run
FIG4_SAVE = dict(saveat=dfx.SaveAt(ts=jnp.linspace(0.0, 10.0, 101), dense=True), max_steps=4096)


def test_quaternion_dcm_and_euler_runs_agree_on_the_sample_problem(scenes):
    model = scenes["fig4"]
    sols = {
        a: simulate(model, 10.0, attitude=a, rtol=RUN_TOL, atol=RUN_TOL, **FIG4_SAVE)
        for a in ("quaternion", "dcm", "euler123")
    }
    q = sols["quaternion"]
    for name in ("dcm", "euler123"):
        s = sols[name]
        assert maxdiff(s.gamma, q.gamma) < GLOBAL
        assert maxdiff(s.omega0, q.omega0) < GLOBAL
        assert maxdiff(s.dcm, q.dcm) < GLOBAL
    # C of the quaternion and Euler runs is orthogonal by construction; Eq. (3) drifts a little
    assert float(q.orthogonality.max()) < ORTHOGONAL and float(sols["euler123"].orthogonality.max()) < ORTHOGONAL
    assert 0 < float(sols["dcm"].orthogonality.max()) < DCM_DRIFT
    # Euler angles and C agree with Eq. (23)
    assert maxdiff(jaxtree._src.equations.attitude.euler123_to_dcm(sols["euler123"].attitude), q.dcm) < GLOBAL


def spheres(k=3.0):
    """Two bodies with isotropic inertia joined at their mass centers: any spin is steady."""
    E = np.eye(3)
    bodies = [
        jaxtree.Body("a", 10.0, 2 * E),
        jaxtree.Body("b", 2.0, 0.5 * E, 0, [0.0, 0.0, 1.0], [0.0] * 3, [0.0] * 3, jaxtree.SpringDamper(k)),
    ]
    return jaxtree.build_model(bodies)


def test_euler_angles_stop_with_an_error_near_their_singularity():
    """Steady spin about a = (0, cos b, sin b) (inertial) from C = U: the body 1-axis is
    (cos t, sin t sin b, -sin t cos b), so sin theta_2 = sin t cos b and |cos theta_2| falls below
    0.01 within 0.0087 s of t = pi/2 (b = 0.005), where P of Eq. (24) grows like 1 / cos theta_2."""
    model = spheres()
    b = 0.005
    y0 = model.initial._replace(omega0=jnp.asarray([0.0, np.cos(b), np.sin(b)]))
    with pytest.raises(jaxtree.SimulationError, match="(?s)singularity.*stopped at t = "):
        simulate(model, 3.0, y0=y0, attitude="euler123")
    sol = simulate(model, 3.0, y0=y0, attitude="euler123", throw=False)
    assert not sol.ok and bool(sol.singular)
    C = np.asarray(sol.final.dcm)
    assert np.sqrt(1 - C[0, 2] ** 2) < EULER_STOP and abs(float(sol.t_final) - np.pi / 2) < STOP_WINDOW
    # a step that jumps across the singular set (b = 0: theta_2 = t, P stays bounded) stops too
    y0 = model.initial._replace(omega0=jnp.asarray([0.0, 1.0, 0.0]))
    sol = simulate(model, 3.0, y0=y0, attitude="euler123", throw=False)
    assert bool(sol.singular) and np.pi / 2 - STOP_WINDOW < float(sol.t_final) < 3.0
    # the quaternion run goes through the same motion: C = C_2(t) of Eq. (23)
    sol = simulate(model, 3.0, y0=y0, attitude="quaternion")
    assert maxdiff(sol.dcm[-1], jaxtree._src.equations.attitude.euler123_to_dcm(jnp.asarray([0.0, 3.0, 0.0]))) < CLOSED


# ----------------------------------------------------------------------------- prescribed hinges
def test_diagnostics_looped_and_vmapped_agree_row_by_row(scenes, monkeypatch):
    """On a CPU the diagnostics loop over the saved times (lax.map: 11.5 s of XLA compilation for
    fig4's vmapped ones); elsewhere they are vmapped. The two forms agree, each row is its own
    state's (the loop takes times, states and controller states in step), and a vehicle with no
    held hinge gets an empty hold-torque column. (The values themselves are checked against
    conservation laws and the free model elsewhere in this file.)"""
    from jaxtree._src.equations.dynamics import energy_and_momentum
    from jaxtree._src.integration import solution

    model = scenes["fig4"]
    sol = simulate(model, 2.0, saveat=7)
    states = State(sol.dcm, sol.omega0, sol.gamma, sol.gamma_dot)
    args = (model, sol.problem.law, sol.problem.controller, sol.problem.params, sol.ts, states, sol.control_state)
    looped = solution.run_diagnostics(*args)
    monkeypatch.setattr(solution.jax, "default_backend", lambda: "gpu")
    vmapped = jax.jit(solution.run_diagnostics.__wrapped__)(*args)  # traced anew, the vmapped form
    monkeypatch.undo()
    for a, b in zip(looped, vmapped, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=1e-12)
    for i in (0, 3, 6):
        state = jax.tree_util.tree_map(lambda x: x[i], states)
        kinetic, H = energy_and_momentum(model, state)
        energy = kinetic + 0.5 * jnp.sum(model.stiffness * state.gamma**2)
        np.testing.assert_allclose(float(looped[0][i]), float(energy), rtol=1e-13)
        # round-off on the scale of |H| (29.7 N m s): the small components differ in their last digits
        np.testing.assert_allclose(
            np.asarray(looped[1][i]), np.asarray(H), rtol=1e-12, atol=1e-13 * float(jnp.linalg.norm(H))
        )
    assert looped[2].shape == (7, len(model.prescribed))
    free = scenes["wings"]  # no held hinge: an empty column, made outside the loop
    fsol = simulate(free, 0.2, saveat=3)
    fstates = State(fsol.dcm, fsol.omega0, fsol.gamma, fsol.gamma_dot)
    assert solution.run_diagnostics(free, None, None, None, fsol.ts, fstates, None)[2].shape == (3, 0)


def test_hold_torque_fed_to_the_free_model_recovers_the_trajectory(scenes):
    model = scenes["fig4"]  # gamma_1 = sin(0.5 t) prescribed
    ts = FIG4_SAVE["saveat"].subs.ts
    pres = simulate(model, 10.0, rtol=TIGHT, atol=TIGHT, **FIG4_SAVE)
    assert pres.gamma.shape == (101, model.n) and pres.hold_torque.shape == (101, 1)
    assert maxdiff(pres.gamma[:, 0], np.sin(0.5 * np.asarray(ts))) < ULPS  # the prescription itself
    free = free_copy(model, 1)

    def hold(t, state, params):
        tau = jaxtree.solve_accelerations(model, pres.evaluate(t), t).hold_torque
        return hinge_torque_vector(free.n, (1,), tau)

    sol = simulate(free, 10.0, y0=state_row(pres, 0), law=hold, saveat=ts, rtol=TIGHT, atol=TIGHT)
    assert maxdiff(sol.gamma[:, 0], np.sin(0.5 * np.asarray(ts))) < GLOBAL
    assert maxdiff(sol.gamma, pres.gamma) < GLOBAL
    assert maxdiff(sol.gamma_dot, pres.gamma_dot) < GLOBAL
    assert maxdiff(sol.omega0, pres.omega0) < GLOBAL


# ----------------------------------------------------------------------------- events
def test_event_time_on_a_free_hinge_matches_the_closed_form():
    """gamma(t) = 0.4 cos(w t) with w^2 = k / I_EFF crosses 0.2 downward at t = pi / (3 w)."""
    k = 3.0
    model = coaxial(jaxtree.SpringDamper(k), gamma0=0.4)
    sol = simulate(model, 5.0, event=jaxtree.hinge_angle_event(1, 0.2, direction=False), rtol=RUN_TOL, atol=RUN_TOL)
    w = np.sqrt(k / I_EFF)
    assert sol.ok and sol.result == dfx.RESULTS.event_occurred
    assert sol.X is None and sol.control_state is None  # Eq. (2) only when asked for
    assert abs(float(sol.t_final) - np.pi / (3 * w)) < EVENT_TIME
    assert abs(float(sol.final.gamma[0]) - 0.2) < EVENT_TIME
    # saved times after the event are not filled with motion
    assert not np.all(np.isfinite(np.asarray(sol.ts)))


def test_latch_event_on_a_prescribed_deployment_and_release(scenes):
    """Hinge 5 deploys by gamma_5(t) = a + b (1 - cos(pi t / T)) / 2, latches at gamma_L (time from
    the inverse of the prescription), and is released to its spring from the latch state."""
    a, b, T, latch = -0.8, 1.2, 4.0, 0.2
    d = jaxtree.scene_to_dict(scenes["fig4_free"])
    bodies = [jaxtree.Body(**body) for body in d["bodies"]]
    profile = lambda t: a + b * (1 - jnp.cos(np.pi * t / T)) / 2
    bodies[5] = dataclasses.replace(bodies[5], joint=jaxtree.Prescribed(profile))
    deploy = jaxtree.build_model(bodies, d["initial"])
    sol = simulate(deploy, 10.0, event=jaxtree.hinge_angle_event(5, latch), rtol=RUN_TOL, atol=RUN_TOL)
    t_latch = T / np.pi * np.arccos(1 - 2 * (latch - a) / b)
    assert abs(float(sol.t_final) - t_latch) < EVENT_TIME
    released = jaxtree.scene_from_dict(d)  # hinge 5 back on its spring
    after = simulate(released, float(sol.t_final) + 2.0, t0=sol.t_final, y0=sol.final, rtol=RUN_TOL, atol=RUN_TOL)
    assert maxdiff(after.gamma[0], sol.final.gamma) == 0.0 and maxdiff(after.gamma_dot[0], sol.final.gamma_dot) == 0.0
    assert float(after.energy_drift()) < DRIFT  # free again: energy conserved after the release


# ----------------------------------------------------------------------------- hinge laws and controllers
def test_pd_law_matches_the_closed_form_and_rhs_evaluations_are_counted():
    """A stateless hinge law; the law also counts its calls at run time (one per right side)."""
    kp, kd, r = 2.0, 0.5, 0.2
    pd = jaxtree.HingePD(1, (1,), kp, kd, reference=jnp.asarray([r]))
    calls = []

    def law(t, state, params):
        jax.debug.callback(lambda: calls.append(1))
        return pd(t, state, params)

    # an explicit solver given: "auto" would evaluate the law once more, for its Jacobian
    sol = simulate(coaxial(gamma0=0.5), 6.0, law=law, rtol=RUN_TOL, atol=RUN_TOL, solver=dfx.Dopri8())
    A = np.array([[0.0, 1.0], [-kp / I_EFF, -kd / I_EFF]])
    x = np.stack([scipy.linalg.expm(A * t) @ [0.5 - r, 0.0] for t in np.asarray(sol.ts)])
    assert maxdiff(sol.gamma[:, 0] - r, x[:, 0]) < CLOSED
    assert maxdiff(sol.gamma_dot[:, 0], x[:, 1]) < CLOSED
    jax.effects_barrier()
    stats = {k: int(v) for k, v in sol.stats.items() if k != "solver"}
    assert stats["num_steps"] == stats["num_accepted_steps"] + stats["num_rejected_steps"] > 10
    assert stats["rhs_evaluations"] == len(calls)


def test_pid_controller_states_match_expm():
    """Integrator and first-order rate filter appended to the state: a 4-state linear system."""
    kp, ki, kd, tf = 2.0, 0.7, 0.5, 0.1
    ctrl = jaxtree.HingePID(1, (1,), kp, ki, kd, tf)
    sol = simulate(coaxial(gamma0=0.5), 6.0, controller=ctrl, rtol=RUN_TOL, atol=RUN_TOL)
    # x = (gamma, gamma_dot, integral, filtered rate)
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [-kp / I_EFF, 0.0, -ki / I_EFF, -kd / I_EFF],
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0 / tf, 0.0, -1.0 / tf],
        ]
    )
    x = np.stack([scipy.linalg.expm(A * t) @ [0.5, 0.0, 0.0, 0.0] for t in np.asarray(sol.ts)])
    assert maxdiff(sol.gamma[:, 0], x[:, 0]) < CLOSED
    assert maxdiff(sol.gamma_dot[:, 0], x[:, 1]) < CLOSED
    assert maxdiff(sol.control_state["integral"][:, 0], x[:, 2]) < CLOSED
    assert maxdiff(sol.control_state["rate"][:, 0], x[:, 3]) < CLOSED


# ----------------------------------------------------------------------------- loads and Eq. (2)
def test_body_torque_and_force_with_eq2_match_the_closed_forms():
    """Torque T about z and force F along z on the base: H_z = T t, gamma_ddot = -k gamma / I_EFF
    - T / I0z, and the mass center moves as X = X0 + V0 t + F t^2 / (2 M) (Eq. 2)."""
    k, T, F, M = 3.0, 0.3, 0.6, 12.0
    push = jaxtree.PerBodyLoads({0: lambda t, s: (jnp.asarray([0.0, 0.0, F]), jnp.zeros(3))})
    loads = jaxtree.combine_loads(jaxtree.BodyTorque(0, [0.0, 0.0, T]), push)
    X0, V0 = np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.0, -0.2])
    model = coaxial(jaxtree.SpringDamper(k), gamma0=0.4, loads=loads)
    sol = simulate(model, 4.0, translation=(X0, V0), rtol=RUN_TOL, atol=RUN_TOL)
    t = np.asarray(sol.ts)
    H = np.asarray(sol.angular_momentum)
    assert np.abs(H[:, 2] - T * t).max() < CLOSED and np.abs(H[:, :2]).max() < CLOSED
    w = np.sqrt(k / I_EFF)
    g_eq = -T * I_EFF / (I0[2, 2] * k)
    assert maxdiff(sol.gamma[:, 0], g_eq + (0.4 - g_eq) * np.cos(w * t)) < CLOSED
    acc = np.array([0.0, 0.0, F / M])
    assert maxdiff(sol.X, X0 + V0 * t[:, None] + 0.5 * acc * t[:, None] ** 2) < CLOSED
    assert maxdiff(sol.X_dot, V0 + acc * t[:, None]) < CLOSED


def test_loads_are_not_traced_when_absent(scenes):
    model = scenes["fig4_free"]
    zero = jaxtree.PerBodyLoads({0: lambda t, s: (jnp.zeros(3), jnp.zeros(3))})

    def count(m):
        problem = jaxtree.Problem(m, jaxtree.Quaternion(), None, None, None, False, 0)
        y = problem.pack(m.initial)
        return count_equations(jax.make_jaxpr(problem.vector_field)(0.0, y).jaxpr)

    assert count(model) < count(model.with_loads(zero))


def test_gravity_gradient_matches_point_masses():
    """Torque and tidal force of GravityGradient against exact inverse-square gravity on point
    masses with each body's mass and inertia (six points per body); they agree to O(size / R)."""
    mu, R = 3.986e14, 7.0e6
    model = coaxial(gamma0=0.7)
    rng = np.random.default_rng(0)
    C = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    C *= np.sign(np.linalg.det(C))
    state = State(jnp.asarray(C), jnp.zeros(3), jnp.asarray([0.7]), jnp.zeros(1))
    t = 1234.0
    gg = jaxtree.GravityGradient(model, mu=mu, radius=R)
    F, T = (np.asarray(x) for x in gg(t, state))
    w = np.sqrt(mu / R**3)
    r_hat = np.array([np.cos(w * t), np.sin(w * t), 0.0])
    cfg = jaxtree.configuration(model, state.gamma)
    for i, k in enumerate(gg.bodies):
        m, J = float(model.mass[k]), np.asarray(model.inertia[k])
        half = 3 * (np.trace(J) - 2 * np.diag(J)) / (2 * m)  # squared half-lengths along the axes
        pts = np.concatenate([np.diag(np.sqrt(half)), -np.diag(np.sqrt(half))])  # body frame
        Rk = C.T @ np.asarray(cfg.R[k])  # body k -> inertial
        center = R * r_hat + C.T @ np.asarray(cfg.rho[k])
        pos = center + pts @ Rk.T
        f = -mu * (m / 6) * pos / np.linalg.norm(pos, axis=1, keepdims=True) ** 3
        torque = Rk.T @ np.sum(np.cross(pts @ Rk.T, f), 0)
        tidal = Rk.T @ (np.sum(f, 0) + m * mu / R**2 * r_hat)
        scale_T = w**2 * np.abs(J).max()
        assert np.abs(T[i] - torque).max() < GRADIENT_EXPANSION * scale_T
        assert np.abs(F[i] - tidal).max() < GRADIENT_EXPANSION * w**2 * m


# ----------------------------------------------------------------------------- failures
def test_gimbal_lock_is_reported_with_time_and_state(scenes):
    model = scenes["fig4_free"]
    gamma = np.asarray(model.initial.gamma).copy()
    gamma[2] = np.pi / 2  # hinge 4 parallel to hinge 2: the Eq. (1) matrix is singular
    locked = model.initial._replace(gamma=jnp.asarray(gamma))
    # the diagnosis names the two aligned hinges (the near-null direction of the matrix); the start
    # itself is singular to working precision, so the run stops before its first step
    named = (
        r"(?s)singular at the initial state.*stopped at t = 0.*hinge 2 \(gimbal_outer\) [-+]0\.707, "
        r"hinge 4 \(rotor\).*gimbal lock"
    )
    with pytest.raises(jaxtree.SimulationError, match=named):
        simulate(model, 1.0, y0=locked)
    with pytest.raises(Exception, match=named):  # the same from the host callback under jit
        jax.block_until_ready(jax.jit(lambda y0: simulate(model, 1.0, y0=y0).gamma)(locked))
    # a non-finite state is reported as such, not passed on as NaNs
    with pytest.raises(jaxtree.SimulationError, match="(?s)stopped at t = .*the state is not finite"):
        simulate(model, 1.0, y0=model.initial._replace(omega0=jnp.asarray([0.0, np.nan, 0.0])))


def gimbal_pair(outer_axis=(0.0, 1.0, 0.0), inner_axis=(0.0, 1.0, 0.0)):
    """A bus with a rotor in two massless gimbal frames; with parallel gimbal axes (the default)
    the Eq. (1) matrix is singular in every state (two hinges turn the rotor alike)."""
    z = np.zeros((3, 3))
    return jaxtree.build_model(
        [
            jaxtree.Body("bus", 100.0, np.diag([30.0, 40.0, 50.0])),
            jaxtree.Body("outer", 0.0, z, 0, list(outer_axis), [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]),
            jaxtree.Body("inner", 0.0, z, 1, list(inner_axis), [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
            jaxtree.Body("rotor", 5.0, np.diag([0.5, 0.5, 0.9]), 2, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]),
        ]
    )


def test_exact_gimbal_lock_under_jit_is_a_failure_at_the_start(scenes):
    """An exactly singular Eq. (1) matrix can leave its Cholesky factorization a pivot at
    round-off level instead of failing it, and the solve then returns finite garbage (for half
    of these states). Under jit and vmap such starts fail at once, at t0, as "singular_start",
    without disturbing the regular members; before, the degenerate gimbal pair ran up to
    max_steps (200k steps) on garbage accelerations."""
    rng = np.random.default_rng(5)
    fig4 = scenes["fig4_free"]
    locked = [random_state(fig4, rng, 0.3) for _ in range(4)]
    locked = [s._replace(gamma=s.gamma.at[2].set(np.pi / 2)) for s in locked]  # hinge 4 parallel to hinge 2
    regular = [random_state(fig4, rng, 0.3) for _ in range(2)]
    states = jax.tree.map(lambda *x: jnp.stack(x), *(locked + regular))
    # the premise, from numpy's eigenvalues: condition numbers of the locked and the regular states
    cond = [np.linalg.cond(np.asarray(jaxtree.rotational_equations(fig4, s)[0])) for s in locked + regular]
    assert min(cond[:4]) > 1e15 and max(cond[4:]) < 1e9
    run = jax.jit(jax.vmap(lambda y0: simulate(fig4, 0.5, y0=y0, saveat=2, rtol=1e-8, atol=1e-8, throw=False)))
    sol = run(states)
    assert list(np.asarray(sol.failure)) == [6, 6, 6, 6, 0, 0]
    assert np.all(np.asarray(sol.t_final[:4]) == 0.0) and np.all(np.isnan(np.asarray(sol.gamma[:4, 1:])))
    assert np.all(np.asarray(sol.t_final[4:]) == 0.5)
    energy = np.asarray(sol.energy[4:])  # the regular members run as usual: energy conserved
    assert np.all(np.abs(energy[:, -1] - energy[:, 0]) < DRIFT_LOOSE * np.abs(energy[:, 0]))
    # an eager run tests its start only after failing there (no test in its program): the same report
    for i in (0, 1):
        alone = simulate(fig4, 0.5, y0=locked[i], saveat=2, rtol=1e-8, atol=1e-8, throw=False)
        assert int(alone.failure) == 6 and float(alone.t_final) == 0.0, i
        assert np.all(np.isnan(np.asarray(alone.gamma[1:]))) and np.all(np.isnan(np.asarray(alone.energy[1:])))

    pair = gimbal_pair()
    starts = jax.tree.map(lambda *x: jnp.stack(x), *(random_state(pair, rng) for _ in range(4)))
    sol = jax.jit(jax.vmap(lambda y0: simulate(pair, 0.5, y0=y0, saveat=2, throw=False)))(starts)
    assert list(np.asarray(sol.failure)) == [6, 6, 6, 6]
    assert int(np.max(np.asarray(sol.stats["num_steps"]))) < 20
    with pytest.raises(jaxtree.SimulationError, match=r"(?s)singular at the initial state.*hinge 1 \(outer\)"):
        simulate(pair, 0.5, y0=jax.tree.map(lambda x: x[0], starts))


def test_without_diagnostics_the_states_are_the_same(scenes):
    """diagnostics=False (an identification's simulations): the states of the default run to the
    bit, the same steps, the energy, momentum and hold-torque histories NaN in their shapes; a
    value that is not a bool is named."""
    fig4 = scenes["fig4"]
    a = simulate(fig4, 2.0, saveat=11)
    b = simulate(fig4, 2.0, saveat=11, diagnostics=False)
    for field in ("gamma", "gamma_dot", "omega0", "dcm", "ts"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert int(a.stats["num_steps"]) == int(b.stats["num_steps"]) and b.ok
    for field in ("energy", "angular_momentum", "hold_torque"):
        assert getattr(b, field).shape == getattr(a, field).shape and np.all(np.isnan(getattr(b, field)))
    assert np.all(np.isfinite(a.energy))
    with pytest.raises(TypeError, match="diagnostics must be True or False"):
        simulate(fig4, 2.0, diagnostics="no")


def test_max_steps_is_reported_eagerly_and_under_jit():
    model = coaxial(jaxtree.SpringDamper(3.0), gamma0=0.4)
    with pytest.raises(jaxtree.SimulationError, match="(?s)maximum number of solver steps.*stopped at t = "):
        simulate(model, 10.0, max_steps=8)
    sol = simulate(model, 10.0, max_steps=8, throw=False)
    assert not sol.ok and sol.result == dfx.RESULTS.max_steps_reached and 0 < float(sol.t_final) < 10.0
    with pytest.raises(Exception, match="maximum number of solver steps"):
        jax.block_until_ready(jax.jit(lambda m: simulate(m, 10.0, max_steps=8).gamma)(model))


def test_nonfinite_start_under_vmap_fails_at_once_and_alone():
    """A NaN initial state in a vmapped batch: that member reports nonfinite_start with NaN
    histories, the batch does not run to max_steps, and the other members match lone runs."""
    model = coaxial(jaxtree.SpringDamper(3.0), gamma0=0.4)
    run = lambda g: simulate(model, 3.0, y0=model.initial._replace(gamma=g[None]), throw=False)
    g0 = jnp.asarray([0.1, np.nan, 0.3])
    sol = jax.jit(jax.vmap(run))(g0)
    assert list(np.asarray(sol.failure)) == [0, 5, 0]
    assert np.all(np.isnan(np.asarray(sol.gamma[1]))) and np.all(np.isfinite(np.asarray(sol.gamma[::2])))
    assert int(np.max(np.asarray(sol.stats["num_steps"]))) < 10_000  # max_steps is 200_000
    clean = jax.jit(jax.vmap(run))(jnp.asarray([0.1, 0.2, 0.3]))
    assert maxdiff(sol.gamma[::2], clean.gamma[::2]) == 0.0  # the NaN member disturbs nothing
    # alone and eager, without throw: the same kind (not taken for a singular Eq. 1 at the start)
    assert int(run(g0[1]).failure) == int(jaxtree.Failure.NONFINITE_START)
    with pytest.raises(Exception, match="initial state is not finite"):
        jax.block_until_ready(
            jax.jit(lambda g: simulate(model, 3.0, y0=model.initial._replace(gamma=g[None])).gamma)(
                jnp.asarray([np.nan])[0]
            )
        )


def test_failures_of_a_vmapped_batch_are_reported_by_one_host_callback():
    """Under vmap the failure report is one host callback for the whole batch (jax.debug.callback
    alone is unrolled into one per member: compile and run times grow with the batch), and it
    names the failed members by their batch index."""
    model = coaxial(jaxtree.SpringDamper(3.0), gamma0=0.4)

    def run(g, max_steps):
        return simulate(model, 10.0, y0=model.initial._replace(gamma=g[None]), max_steps=max_steps).gamma

    def callbacks(batch):  # host callbacks in the lowered program (diffrax has a few of its own)
        hlo = jax.jit(jax.vmap(lambda g: run(g, 10_000))).lower(batch).as_text()
        return len(re.findall(r"custom_call @xla(_ffi)?_python_\w*callback", hlo))

    batch = jnp.linspace(0.1, 0.4, 64)
    assert callbacks(batch) == callbacks(batch[:2])
    with pytest.raises(
        Exception,
        match=r"(?s)\[batch index \(0,\)\].*maximum number of solver steps.*"
        r"and 61 more failed batch members",
    ):
        jax.block_until_ready(jax.jit(jax.vmap(lambda g: run(g, 8)))(batch))


# ----------------------------------------------------------------------------- transformations
def test_vmap_over_initial_states_and_parameters_matches_closed_forms():
    """One batch over initial angles and spring stiffnesses: gamma = g0 cos(sqrt(k / I_EFF) t)."""
    model = coaxial(jaxtree.SpringDamper(3.0), gamma0=0.4)
    g0 = jnp.asarray([0.1, 0.3, -0.2])
    ks = jnp.asarray([1.0, 3.0, 8.0])

    def run(g, k):
        m = eqx.tree_at(lambda m: m.stiffness, model, k[None])
        return simulate(m, 3.0, y0=m.initial._replace(gamma=g[None]), rtol=RUN_TOL, atol=RUN_TOL).gamma[:, 0]

    out = jax.vmap(run)(g0, ks)
    t = np.linspace(0.0, 3.0, 101)
    expected = np.asarray(g0)[:, None] * np.cos(np.sqrt(np.asarray(ks) / I_EFF)[:, None] * t[None])
    assert maxdiff(out, expected) < CLOSED


def test_bad_times_are_named_before_tracing():
    """Non-finite start or end times and save times out of order or outside the run raise a
    ValueError naming the argument (diffrax's own checks fire inside the compiled solve)."""
    model = coaxial(jaxtree.SpringDamper(3.0), gamma0=0.4)
    cases = [
        (dict(t1=float("nan")), "t1 is not finite"),
        (dict(t1=1.0, t0=float("-inf")), "t0 is not finite"),
        (dict(t1=3.0, saveat=[0.0, 2.0, 1.0]), r"saveat\[1\] = 2 is followed by 1"),
        (dict(t1=-1.0, saveat=[0.0, -1.0, -0.5]), r"\(decreasing\); saveat\[1\] = -1"),
        (dict(t1=3.0, saveat=[0.0, 5.0]), r"saveat\[1\] = 5 lies outside the integration from t0 = 0 to t1 = 3"),
    ]
    for kwargs, message in cases:
        t1 = kwargs.pop("t1")
        with pytest.raises(ValueError, match=message):
            simulate(model, t1, **kwargs)
    sol = simulate(model, -1.0, saveat=[0.0, -0.5, -1.0], rtol=1e-8, atol=1e-8)  # backward, in order
    assert list(np.asarray(sol.ts)) == [0.0, -0.5, -1.0]


def test_bad_initial_states_and_tolerances_are_named_before_tracing():
    """Wrong field shapes (JAX would clamp the indices and run), a dcm that is not a rotation,
    negative or all-zero tolerances, a zero atol and max_steps < 1 raise a ValueError naming the field."""
    model = coaxial(jaxtree.SpringDamper(3.0), gamma0=0.4)
    s = model.initial
    c, d = np.cos(0.3), np.sin(0.3)
    cases = [
        (
            dict(y0=s._replace(gamma=jnp.zeros(2))),
            r"y0.gamma has shape \(2,\); the model .* with 1 hinges needs \(1,\)",
        ),
        (dict(y0=s._replace(omega0=jnp.zeros(2))), r"y0.omega0 has shape \(2,\)"),
        (dict(y0=s._replace(dcm=jnp.eye(2))), r"y0.dcm has shape \(2, 2\)"),
        (dict(y0=s._replace(dcm=1.01 * jnp.eye(3))), r"y0.dcm is not a rotation matrix \(max \|C C\^T - I\| = 0.0201"),
        (dict(y0=s._replace(dcm=jnp.diag(jnp.array([1.0, 1.0, -1.0])))), r"not a rotation matrix .* det C = -1"),
        (dict(rtol=-1e-6), "rtol must be finite and non-negative"),
        (dict(rtol=0.0, atol=0.0), "rtol and atol are both zero"),
        (dict(atol=0.0), "atol is zero: a purely relative tolerance"),
        (dict(max_steps=0), "max_steps must be at least 1"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ValueError, match=message):
            simulate(model, 1.0, **kwargs)
    rotated = jnp.array([[c, d, 0.0], [-d, c, 0.0], [0.0, 0.0, 1.0]])
    sol = simulate(model, 1.0, y0=s._replace(dcm=rotated), saveat=2)
    assert maxdiff(sol.dcm[0], rotated) < ULPS


def test_tolerances_and_step_controllers_may_be_traced():
    """A work-precision sweep vmapped over rtol/atol, and a diffrax controller built from a traced
    tolerance under jit: each run meets the closed form to about its tolerance (the failure check
    must go to the host callback when only these arguments are traced)."""
    k, g0 = 3.0, 0.4
    model = coaxial(jaxtree.SpringDamper(k), gamma0=g0)
    expected = g0 * np.cos(np.sqrt(k / I_EFF) * 3.0)
    tols = jnp.asarray([1e-6, 1e-9, 1e-11])
    final = jax.jit(jax.vmap(lambda tol: simulate(model, 3.0, saveat=2, rtol=tol, atol=tol).gamma[-1, 0]))(tols)
    err = np.abs(np.asarray(final) - expected)
    assert np.all(err < PER_TOLERANCE * np.asarray(tols)) and err[2] < err[0]

    def with_controller(tol):
        controller = dfx.PIDController(rtol=tol, atol=tol, pcoeff=0.3, icoeff=0.3)
        return simulate(model, 3.0, saveat=2, stepsize_controller=controller, dt0=0.01).gamma[-1, 0]

    assert abs(float(jax.jit(with_controller)(jnp.asarray(1e-10))) - expected) < CLOSED


def test_gradient_through_simulate_matches_the_closed_form():
    """d gamma(T) / dk of gamma = g0 cos(sqrt(k / I_EFF) T)."""
    g0, T, k = 0.4, 2.0, 3.0
    model = coaxial(jaxtree.SpringDamper(k), gamma0=g0)

    def final_angle(stiffness):
        m = eqx.tree_at(lambda m: m.stiffness, model, stiffness)
        return simulate(m, T, saveat=2, rtol=RUN_TOL, atol=RUN_TOL).gamma[-1, 0]

    grad = jax.grad(final_angle)(jnp.asarray([k]))
    w = np.sqrt(k / I_EFF)
    expected = -g0 * np.sin(w * T) * T / (2 * np.sqrt(k * I_EFF))
    assert abs(float(grad[0]) - expected) < GRADIENT


def test_float32_models_simulate():
    k = 3.0
    model = coaxial(jaxtree.SpringDamper(k), gamma0=0.4).astype(jnp.float32)
    sol = simulate(model, 3.0, rtol=1e-5, atol=1e-5)
    assert sol.gamma.dtype == jnp.float32
    t = np.asarray(sol.ts, dtype=float)
    assert maxdiff(sol.gamma[:, 0], 0.4 * np.cos(np.sqrt(k / I_EFF) * t)) < FLOAT32_CLOSED


def test_float32_runs_take_float32_default_tolerances(scenes):
    """A float32 model gets rtol = atol = 1e-4 by default. With float64's 1e-9, Dopri8's error
    estimate is all roundoff: fig4_free ran into max_steps (200k steps, 27 s) before the
    default depended on the dtype; now such an rtol also warns."""
    assert jaxtree.default_tolerance(jnp.float64) == 1e-9
    assert jaxtree.default_tolerance(jnp.float32) == 1e-4
    m64 = scenes["fig4_free"]
    m32 = m64.astype(jnp.float32)
    ref = simulate(m64, 10.0)
    sol = simulate(m32, 10.0, max_steps=2000)
    assert sol.gamma.dtype == jnp.float32 and int(sol.stats["num_steps"]) < 1000
    assert maxdiff(sol.gamma, ref.gamma) < FLOAT32 and maxdiff(sol.omega0, ref.omega0) < FLOAT32
    with pytest.warns(UserWarning, match="roundoff"):
        tight = simulate(m32, 10.0, rtol=1e-9, atol=1e-9, max_steps=2000, throw=False)
    assert not tight.ok  # the steps pile up: max_steps


def test_implicit_solver_passes_through_on_a_stiff_hinge(scenes):
    """A near-rigid, damped tip hinge (1.3 kHz) in chain10's soft chain: diffrax's Kvaerno5 goes
    straight through simulate (its Newton iterations differentiate Eq. 1), agrees with a tight
    Dopri8 run, and needs a fraction of Dopri8's stability-limited steps."""
    base = scenes["chain10"]
    k = np.asarray(base.stiffness).copy()
    c = np.asarray(base.damping).copy()
    k[-1] *= 1e4
    tip = base.n  # the tip segment's inertia about its own hinge (parallel-axis theorem)
    g, r = np.asarray(base.axis[tip - 1]), np.asarray(base.hinge_on_body[tip - 1])
    J = np.asarray(base.inertia[tip]) + float(base.mass[tip]) * (r @ r * np.eye(3) - np.outer(r, r))
    c[-1] = 2 * 0.7 * np.sqrt(k[-1] * (g @ J @ g))  # damping ratio 0.7 for the tip alone
    model = eqx.tree_at(lambda m: (m.stiffness, m.damping), base, (jnp.asarray(k), jnp.asarray(c)))
    ref = simulate(model, 1.0, saveat=11, rtol=1e-10, atol=1e-10)
    explicit = simulate(model, 1.0, saveat=11, rtol=1e-6, atol=1e-6, solver=dfx.Dopri8())
    implicit = simulate(model, 1.0, saveat=11, rtol=1e-6, atol=1e-6, solver=dfx.Kvaerno5())
    assert maxdiff(implicit.gamma, ref.gamma) < STIFF_GLOBAL and maxdiff(explicit.gamma, ref.gamma) < STIFF_GLOBAL
    steps = lambda sol: int(sol.stats["num_steps"])
    assert steps(implicit) * 5 < steps(explicit)
    # jaxtree's Radau IIA keeps its Jacobian (of Eq. 1 by the implicit-function rule) over steps
    radau = simulate(model, 1.0, saveat=11, rtol=1e-6, atol=1e-6, solver=jaxtree.Radau5())
    assert maxdiff(radau.gamma, ref.gamma) < STIFF_GLOBAL and steps(radau) * 5 < steps(explicit)
    st = radau.stats
    assert int(st["jacobians"]) * 3 < int(st["num_accepted_steps"]) and int(st["factorizations"]) > 0, st
    assert int(st["newton_iterations"]) >= int(st["num_accepted_steps"])


def test_radau_jacobian_by_parts_equals_jacfwd_and_central_differences(scenes):
    """The Jacobian simulate gives jaxtree.Radau5 (Problem.jacobian: the configuration, then the
    rates, in two forward passes) against jax.jacfwd of the vector field over the flat state
    (round-off) and central differences (h = 1e-6), on Fig. 4 with its prescribed platform at a
    random state with a torque law on the hinges."""
    model = scenes["fig4"]
    law = lambda t, st, params: -2.0 * st.gamma - 0.3 * st.gamma_dot
    problem = jaxtree.Problem(model, jaxtree.Quaternion(), law, None, None, False, 0)
    rng = np.random.default_rng(7)
    y = problem.pack(random_state(model, rng))
    t = jnp.asarray(0.37)
    J = np.asarray(eqx.filter_jit(lambda t, y, p: p.jacobian(t, y))(t, y, problem))
    ref = np.asarray(eqx.filter_jit(lambda t, y, p: jax.jacfwd(lambda z: p.vector_field(t, z))(y))(t, y, problem))
    assert J.shape == (y.size, y.size) and model.prescribed
    np.testing.assert_allclose(J, ref, atol=TIGHT * np.abs(ref).max())
    f = eqx.filter_jit(lambda t, y, p: p.vector_field(t, y))
    h = 1e-6
    fd = np.stack(
        [
            (np.asarray(f(t, y + h * e, problem)) - np.asarray(f(t, y - h * e, problem))) / (2 * h)
            for e in np.eye(y.size)
        ],
        1,
    )
    np.testing.assert_allclose(J, fd, atol=FD_JACOBIAN * np.abs(fd).max())


def test_radau_jacobian_is_traced_for_forward_use_only(monkeypatch):
    """Radau5's J carries no derivative (its inputs and its value are cut), so Eq. (1)'s derivative
    rule inside it gives its tangents directly (``numerics.forward_only``), not as a linear solve
    whose product and transposed solve JAX would trace up front for nothing (flex95's first Radau5
    call: its trace halved). With the rule that trees of BATCH_FIRST_DERIVATIVES_MIN bodies
    and more take (forced here on a two-hinge chain), the Jacobian traced alone holds a linear
    solve and Radau5's program none; Radau5's J against jacfwd and central differences: above."""
    monkeypatch.setattr(rules, "BATCH_FIRST_DERIVATIVES_MIN", 1)
    model = sprung_tree(np.random.default_rng(1), chain(2), damping=0.5)
    problem = jaxtree.Problem(model, jaxtree.Quaternion(), None, None, None, False, 0)
    y = problem.pack(random_state(model, np.random.default_rng(5)))
    alone = jax.make_jaxpr(lambda y: problem.jacobian(jnp.asarray(0.2), y))(y)
    assert "custom_linear_solve" in primitive_names(alone.jaxpr)
    term = dfx.ODETerm(lambda t, y, p: p.vector_field(t, y))
    controller = dfx.PIDController(rtol=1e-6, atol=1e-6)
    solver = with_jacobian(jaxtree.Radau5())
    run = lambda y: dfx.diffeqsolve(term, solver, 0.0, 0.1, 0.01, y, args=problem, stepsize_controller=controller).ys
    names = primitive_names(jax.make_jaxpr(run)(y).jaxpr)
    assert "custom_jvp_call" in names and "custom_linear_solve" not in names


def test_simulate_validates_its_model_once(scenes, monkeypatch):
    """simulate validates the model once: its automatic solver choice linearizes the checked
    model (choose_solver -> linearize_vehicle) without validating it again, while the public
    choose_solver, called alone, still validates it."""
    from jaxtree._src.vehicle import validate as validation

    calls = []
    validate = validation.validate_model
    monkeypatch.setattr(validation, "validate_model", lambda model: calls.append(model) or validate(model))
    model = scenes["fig4"]
    law = lambda t, state, params: 0.0 * state.gamma  # a hinge law: the solver choice linearizes
    sol = simulate(model, 0.05, saveat=3, law=law)
    assert "linearized" in sol.stats["solver"].reason and len(calls) == 1
    jaxtree.choose_solver(model, 0.05, law=law)
    assert len(calls) == 2


# ----------------------------------------------------------------------------- command line
def test_command_line_runs_the_sample_problem(tmp_path, monkeypatch, capsys):
    from jaxtree.__main__ import main

    monkeypatch.setenv("XLA_FLAGS", "")  # restored afterwards; main() may add its compiler flag
    code = main(["--duration", "1", "--points", "11", "--attitudes", "quaternion", "--no-plot", "--out", str(tmp_path)])
    captured = capsys.readouterr()
    out = captured.out
    assert code == 0
    # the elapsed time only on a terminal (here stderr is captured: no redraws in a log)
    assert "elapsed" not in captured.err + out and "\r" not in captured.err
    assert "angular momentum" in out and "accepted" in out and "wall time" in out
    # the summary with units and the error estimate of a run at 10x the tolerances
    assert " J, max change " in out and " N m s, max change " in out and "] rad/s (in {b0})" in out
    estimate = [ln for ln in out.splitlines() if "integration error estimate" in ln]
    assert len(estimate) == 1 and " rad, rates " in estimate[0], out
    data = np.load(tmp_path / "fig4_histories.npz")
    assert data["quaternion/gamma"].shape == (11, 10)
    assert maxdiff(data["quaternion/gamma"][:, 0], np.sin(0.5 * np.linspace(0.0, 1.0, 11))) < ULPS
    header = (tmp_path / "fig4_quaternion.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == ["t [s]", "gamma_1 [rad]"] and "hold_torque_1 [N m]" in header
    assert all(h.endswith("]") for h in header)  # every column with its unit
    assert [h for h in header if h.startswith("quaternion_")][0] == "quaternion_1 [1]"  # numbered from 1
    # the result file of `jaxtree simulate` beside the CSV: the same run, read back by load_result
    back = jaxtree.load_result(tmp_path / "fig4_quaternion.nc")
    np.testing.assert_array_equal(np.asarray(back.gamma), data["quaternion/gamma"])
    assert "fig4_quaternion.nc" in out


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_sample_problem_on_a_terminal_times_its_runs_outside_the_integration(tmp_path, monkeypatch):
    """On a terminal the main job redraws each run's elapsed time from a thread of its own and
    gives the integration no progress meter: a meter inside it is a host callback, and a program
    with one is neither exported nor kept in the compilation cache (every process would trace
    and compile it again, ~12 s of fig4's)."""
    from jaxtree.__main__ import main
    from jaxtree._src import cli
    from jaxtree._src.cli import sample_problem  # the sample problem looks `simulate` up there

    calls = []
    real = sample_problem.simulate
    monkeypatch.setattr(sample_problem, "simulate", lambda *a, **kw: calls.append(kw) or real(*a, **kw))
    monkeypatch.setenv("XLA_FLAGS", "")
    err = _Terminal()
    monkeypatch.setattr(sys, "stderr", err)
    args = ["--duration", "0.5", "--points", "3", "--attitudes", "quaternion", "--no-plot", "--out", str(tmp_path)]
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(args) == 0
    assert calls and all(kw.get("progress", False) is False for kw in calls)
    assert err.getvalue().endswith("\r\033[K")  # the line erased when the run ended

    shown = _Terminal()
    with cli._elapsed("quaternion", True):
        monkeypatch.setattr(sys, "stderr", shown)
        time.sleep(1.2)
    # drawn every half second (the count itself depends on how busy the machine is), then erased
    assert re.search(r"\r   quaternion: \d+ s elapsed", shown.getvalue()), shown.getvalue()
    assert shown.getvalue().endswith("\r\033[K")
    hidden = _Terminal()
    monkeypatch.setattr(sys, "stderr", hidden)
    with cli._elapsed("quaternion", False):
        time.sleep(0.6)
    assert hidden.getvalue() == ""


def test_drift_is_absolute_and_relative_only_away_from_zero():
    """The summary's drift: absolute always; relative only where the initial value is not near
    zero (a run from rest would read as a change of millions of percent)."""
    from jaxtree._src.io.drift import change_text as _change

    assert _change([10.0, 10.1, 9.95], 10.0, "J") == "max change 1.000e-01 J (1.000e-02 of the initial value)"
    assert _change([0.0, 2e-3, 1e-3], 0.0, "J") == "max change 2.000e-03 J"
    assert _change([1e-12, 5.0], 1e-12, "J") == "max change 5.000e+00 J"  # from (numerically) rest
    H = np.array([[0.0, 3.0, 4.0], [0.0, 3.0, 4.1]])
    assert _change(H, H[0], "N m s") == "max change 1.000e-01 N m s (2.000e-02 of the initial value)"
