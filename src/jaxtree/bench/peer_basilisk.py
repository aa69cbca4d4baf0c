"""Basilisk as a peer of the work-precision benchmark: a jaxtree model as a Basilisk spacecraft.

The hub is a ``spacecraft.Spacecraft`` (its mass center at the body-frame origin B,
``r_BcB_B = 0``); every chain of hinges that leaves the hub is one
``spinningBodyNDOFStateEffector`` (J. Vaz Carneiro, C. Allard and H. Schaub, "Effector Dynamics
for Sequentially Rotating Rigid Body Spacecraft Components", AAS/AIAA Astrodynamics Specialist
Conference, 2023), a chain of single-axis spinning bodies. No gravity, no external loads: the system's mass center moves
uniformly, so only the rotational motion (Eq. 1 of Likins 1972) is compared.

Conventions, from Basilisk's ``spinningBodyNDOFStateEffector.cpp``:

- ``dcm_S0S = PRV2C(-theta * sHat_S)``: spin angle theta is a right-handed rotation of body S
  about ``sHat`` relative to its zero-angle frame S0, as jaxtree's gamma_k is of body k relative
  to its parent; jaxtree's frames are all parallel at gamma = 0, so ``dcm_S0P = I`` and
  ``sHat_S = axis`` and ``theta_k = gamma_k``.
- ``r_SP_P``: hinge point S of a body from the point P of its parent, parent frame; P is the
  hub's origin B (= the hub mass center) for the first body of a chain, the parent's hinge
  point for the others. So ``r_SP_P = hinge_on_parent[k-1]`` on the hub and
  ``hinge_on_parent[k-1] - hinge_on_body[parent-1]`` along the chain.
- ``r_ScS_S``: the body's mass center from its hinge point, ``-hinge_on_body[k-1]``.
- ``ISPntSc_S``: inertia about the body's mass center, body frame (``model.inertia[k]``).
- spring and damper: ``-k (theta - thetaRef) - c thetaDot`` with ``thetaRef = 0``.
- ``sigma_BNInit``: the MRPs of [BN], which is jaxtree's ``dcm`` C ({b^0} = C {i});
  ``omega_BN_BInit`` is ``omega0`` (hub axes).

Imports only numpy at import time; Basilisk (pip package ``bsk``) is imported by the functions.
"""

from __future__ import annotations

import time as _time

import numpy as np

INTEGRATORS = ("rk4", "rkf45", "rkf78")


def basilisk_available() -> bool:
    """Whether Basilisk (pip package ``bsk``) can be imported."""
    try:
        import Basilisk.simulation.spinningBodyNDOFStateEffector  # noqa: F401  # pyright: ignore[reportMissingImports]  (optional: bsk)
    except ImportError:
        return False
    return True


def _chains(model) -> list[list[int]] | str:
    """The hinge chains leaving the hub (lists of body indices, hub side first), or a reason why
    the tree is not a set of such chains."""
    children = model.topology.children
    chains = []
    for first in children[0]:
        chain, k = [first], first
        while children[k]:
            if len(children[k]) > 1:
                names = ", ".join(model.names[c] for c in children[k])
                return (
                    f"body {k} ({model.names[k]}) has {len(children[k])} children ({names}): "
                    "Basilisk's spinningBodyNDOFStateEffector is a chain of single-child bodies"
                )
            k = children[k][0]
            chain.append(k)
        chains.append(chain)
    return chains


def basilisk_supports(model) -> str | None:
    """None if `model` can be represented in Basilisk (a hub with chains of spinning bodies,
    free or spring-damper hinges, no loads), else a one-line reason."""
    if model.prescribed:
        return f"hinges {list(model.prescribed)} are prescribed: the spinning-body effector has no prescribed angle law"
    if model.loads is not None:
        return "the model has external loads: not mapped onto Basilisk dynamic effectors"
    for k, joint in enumerate(model.joints, start=1):
        if joint not in ("free", "spring_damper"):
            return f"hinge {k} ({model.names[k]}): joint kind {joint!r} is not a spring-damper or free hinge"
    chains = _chains(model)
    if isinstance(chains, str):
        return chains
    mass = np.asarray(model.mass, float)
    for chain in chains:
        if mass[chain[-1]] <= 0.0:
            k = chain[-1]
            return f"body {k} ({model.names[k]}) ends a chain with zero mass: Basilisk needs the last spinning body massive"
    return None


def _integrator(name, sc, rtol, atol):
    from Basilisk.simulation import svIntegrators  # pyright: ignore[reportMissingImports]  (optional: bsk)

    if name == "rk4":
        return svIntegrators.svIntegratorRK4(sc)
    if rtol is None or atol is None:
        raise ValueError(f"integrator {name!r} is adaptive: give rtol and atol")
    integ = svIntegrators.svIntegratorRKF45(sc) if name == "rkf45" else svIntegrators.svIntegratorRKF78(sc)
    integ.relTol = float(rtol)
    integ.absTol = float(atol)
    return integ


def _steps(t1, ts, dt):
    """``(task step ns, save interval ns, number of steps)``, all exact integers."""
    ts = np.asarray(ts, float)
    if ts.ndim != 1 or ts.size < 2 or ts[0] != 0.0 or not np.isclose(ts[-1], t1, rtol=0, atol=1e-9):
        raise ValueError(f"ts: expected evenly spaced save times from 0 to t1 = {t1}, got {ts!r}")
    h = (ts[-1] - ts[0]) / (ts.size - 1)
    if not np.allclose(np.diff(ts), h, rtol=0, atol=1e-9):
        raise ValueError("ts: save times must be evenly spaced")
    dt_ns = round(float(dt) * 1e9)
    save_ns = round(h * 1e9)
    if dt_ns <= 0 or save_ns % dt_ns or abs(dt_ns * 1e-9 - dt) > 1e-12:
        raise ValueError(
            f"dt = {dt}: the save interval {h} must be a whole number of task steps (a whole number of nanoseconds)"
        )
    return dt_ns, save_ns, (save_ns // dt_ns) * (ts.size - 1)


def basilisk_run(
    model,
    t1,
    ts,
    *,
    integrator: str,
    dt: float | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    diagnostics: bool = False,
) -> dict:
    """Integrate `model` in Basilisk from 0 to `t1`, saving at `ts` (evenly spaced, 0 to t1).

    `integrator`: ``"rk4"`` (svIntegratorRK4, fixed step `dt`) or ``"rkf45"`` / ``"rkf78"``
    (svIntegratorRKF45 / RKF78, adaptive with ``relTol = rtol``, ``absTol = atol``; `dt` the
    task step, within which Basilisk starts each integration with the full step; default the
    save interval). The save interval must be a whole number of task steps.

    Returns a dict: ``omega0`` (T, 3) hub angular velocity in hub axes, ``gamma`` and
    ``gamma_dot`` (T, n) in jaxtree's hinge order, ``time`` (wall seconds of
    ``ExecuteSimulation`` only), ``setup_time`` (wall seconds to build and initialize), and
    with `diagnostics` Basilisk's ``energy`` (T,) (kinetic energy about the system mass center
    plus spring energy) and ``angular_momentum`` (T, 3) (about the system mass center, inertial
    components).
    """
    if integrator not in INTEGRATORS:
        raise ValueError(f"integrator: expected one of {INTEGRATORS}, got {integrator!r}")
    reason = basilisk_supports(model)
    if reason is not None:
        raise ValueError(f"model {model.name!r} cannot be run in Basilisk: {reason}")
    ts = np.asarray(ts, float)
    if dt is None:
        if integrator == "rk4":
            raise ValueError("integrator 'rk4' needs a fixed step dt")
        dt = float(ts[1] - ts[0])
    dt_ns, save_ns, nsteps = _steps(float(t1), ts, dt)

    t_setup = _time.perf_counter()
    from Basilisk.utilities import SimulationBaseClass  # pyright: ignore[reportMissingImports]  (optional: bsk)

    sim = SimulationBaseClass.SimBaseClass()
    proc = sim.CreateNewProcess("dynamics")
    proc.addTask(sim.CreateNewTask("task", dt_ns))
    sc = _spacecraft(model)
    chains = _chains(model)
    assert not isinstance(chains, str)
    effectors, keep = _effectors(model, chains)  # keep: the spinning bodies, alive while the run needs them
    for eff in effectors:
        sc.addStateEffector(eff)
    sc.setIntegrator(_integrator(integrator, sc, rtol, atol))

    # the spacecraft first: the effectors then write the angles it has just integrated to
    sim.AddModelToTask("task", sc)
    for eff in effectors:
        sim.AddModelToTask("task", eff)
    rec_sc = sc.scStateOutMsg.recorder(save_ns)
    sim.AddModelToTask("task", rec_sc)
    recs = []
    for eff, chain in zip(effectors, chains):
        for i in range(len(chain)):
            r = eff.spinningBodyOutMsgs[i].recorder(save_ns)
            sim.AddModelToTask("task", r)
            recs.append(r)
    log = None
    if diagnostics:
        log = sc.logger(["totRotEnergy", "totRotAngMomPntC_N"], save_ns)
        sim.AddModelToTask("task", log)
    sim.InitializeSimulation()
    sim.ConfigureStopTime(nsteps * dt_ns)
    setup_time = _time.perf_counter() - t_setup

    t0 = _time.perf_counter()
    sim.ExecuteSimulation()
    run_time = _time.perf_counter() - t0

    out = _records(model, ts, save_ns, chains, rec_sc, recs)
    out.update(time=run_time, setup_time=setup_time)
    if log is not None:
        out["energy"] = np.asarray(log.totRotEnergy)
        out["angular_momentum"] = np.asarray(log.totRotAngMomPntC_N)
    return out


def _col(v):
    """A column vector, as Basilisk's setters take them."""
    return [[float(x)] for x in v]


def _spacecraft(model):
    """The hub: a ``spacecraft.Spacecraft`` with body 0's mass properties and initial state."""
    from Basilisk.simulation import spacecraft  # pyright: ignore[reportMissingImports]  (optional: bsk)
    from Basilisk.utilities import RigidBodyKinematics  # pyright: ignore[reportMissingImports]  (optional: bsk)

    init = model.initial
    sc = spacecraft.Spacecraft()
    sc.ModelTag = "jaxtree"
    sc.hub.mHub = float(np.asarray(model.mass, float)[0])
    sc.hub.r_BcB_B = _col(np.zeros(3))
    sc.hub.IHubPntBc_B = np.asarray(model.inertia, float)[0].tolist()
    sc.hub.r_CN_NInit = _col(np.zeros(3))
    sc.hub.v_CN_NInit = _col(np.zeros(3))
    sc.hub.sigma_BNInit = _col(RigidBodyKinematics.C2MRP(np.asarray(init.dcm, float)))
    sc.hub.omega_BN_BInit = _col(np.asarray(init.omega0, float))
    return sc


def _effectors(model, chains):
    """One ``SpinningBodyNDOFStateEffector`` per chain, and its spinning bodies (to be kept alive)."""
    from Basilisk.simulation import spinningBodyNDOFStateEffector  # pyright: ignore[reportMissingImports]  (optional: bsk)

    mass = np.asarray(model.mass, float)
    inertia = np.asarray(model.inertia, float)
    axis = np.asarray(model.axis, float)
    hop = np.asarray(model.hinge_on_parent, float)
    hob = np.asarray(model.hinge_on_body, float)
    stiffness = np.asarray(model.stiffness, float)
    damping = np.asarray(model.damping, float)
    sprung = set(model.sprung)
    gamma0 = np.asarray(model.initial.gamma, float)
    gamma_dot0 = np.asarray(model.initial.gamma_dot, float)
    parents = model.topology.parents
    effectors, keep = [], []
    for c, chain in enumerate(chains):
        eff = spinningBodyNDOFStateEffector.SpinningBodyNDOFStateEffector()
        eff.ModelTag = f"chain{c}"
        eff.setNameOfThetaState(f"theta{c}")
        eff.setNameOfThetaDotState(f"thetaDot{c}")
        for k in chain:
            p = parents[k - 1]
            body = spinningBodyNDOFStateEffector.SpinningBody()
            body.setMass(float(mass[k]))
            body.setISPntSc_S(inertia[k].tolist())
            body.setDCM_S0P(np.eye(3).tolist())
            body.setR_SP_P(_col(hop[k - 1] if p == 0 else hop[k - 1] - hob[p - 1]))
            body.setR_ScS_S(_col(-hob[k - 1]))
            body.setSHat_S(_col(axis[k - 1]))
            body.setThetaInit(float(gamma0[k - 1]))
            body.setThetaDotInit(float(gamma_dot0[k - 1]))
            if k in sprung:
                body.setK(float(stiffness[k - 1]))
                body.setC(float(damping[k - 1]))
            eff.addSpinningBody(body)
            keep.append(body)
        effectors.append(eff)
    return effectors, keep


def _records(model, ts, save_ns, chains, rec_sc, recs) -> dict:
    """``omega0``, ``gamma`` and ``gamma_dot`` from the recorders (hinges in jaxtree's order),
    after a check that they recorded at every save time."""
    T = ts.size
    times = np.asarray(rec_sc.times())
    expected = np.arange(T, dtype=np.int64) * save_ns
    if times.shape != (T,) or not np.array_equal(times, expected):
        raise RuntimeError(f"Basilisk recorded at {times[:5]}... ns, expected every {save_ns} ns ({T} records)")
    order = [k for chain in chains for k in chain]
    gamma = np.empty((T, model.n))
    gamma_dot = np.empty((T, model.n))
    for k, r in zip(order, recs):
        gamma[:, k - 1] = np.asarray(r.theta)
        gamma_dot[:, k - 1] = np.asarray(r.thetaDot)
    return {"omega0": np.asarray(rec_sc.omega_BN_B), "gamma": gamma, "gamma_dot": gamma_dot}
