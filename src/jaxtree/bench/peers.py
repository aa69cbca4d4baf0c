"""The same vehicle in the peers (Pinocchio's ABA under scipy, MuJoCo), for the work-precision
report (:func:`jaxtree.work_precision`) and the benchmark scripts.

Frames: body 0's at its mass center, body k's at hinge point k, all parallel to the body axes
(so parallel to each other at gamma = 0). Body 0 is a free flyer / free joint; hinge k a
revolute (hinge) joint about ``model.axis[k-1]``. No gravity. The peers are optional (the
``peers`` extra); this module imports them inside the functions that use them.

What the peers can represent (:func:`peer_support`): free and spring-damper hinges, no
prescribed hinges, no external loads. Observables for comparison: ``omega0`` (T, 3), the
angular velocity of b_0 in its own axes, and ``gamma`` (T, n), at the save times.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np

from jaxtree._src.equations.dynamics import configuration_and_rates, mass_center_velocities
from jaxtree._src.scene.scene import build_model

MUJOCO_TINY_MASS, MUJOCO_TINY_INERTIA = 1e-9, 1e-12  # MuJoCo refuses massless bodies


def _pinocchio() -> Any:
    """The ``pinocchio`` module (optional: the peers extra), typed Any: its names come from a
    compiled extension, which pyright cannot read."""
    import pinocchio  # pyright: ignore[reportMissingImports]

    return pinocchio


def peer_support(model) -> str | None:
    """None when the peers can represent `model`, else the reason in a few words."""
    if model.prescribed:
        return "prescribed hinges"
    if model.loads is not None:
        return "external loads"
    return None


def tree_frames(model):
    """``(axis (n, 3), offsets (n, 3), com (n+1, 3))``: per hinge the axis and the offset of the
    hinge point from the parent frame's origin; per body its mass center in its own frame."""
    hop = np.asarray(model.hinge_on_parent, float)
    hob = np.asarray(model.hinge_on_body, float)
    parents = model.topology.parents
    origin = np.vstack([np.zeros(3), hob])  # frame origin from the mass center, per body (hinge point)
    # from the parent frame's origin: (parent mass center -> hinge) - (parent mass center -> parent origin)
    offsets = [hop[k - 1] - origin[parents[k - 1]] for k in range(1, model.n + 1)]
    com = np.vstack([np.zeros(3), -hob])
    return np.asarray(model.axis, float), np.asarray(offsets).reshape(-1, 3), com


def _laws(model):
    """Per hinge the spring stiffness and damping (zero on free hinges)."""
    sprung = np.asarray(model.sprung, int) - 1
    stiffness, damping = np.zeros(model.n), np.zeros(model.n)
    stiffness[sprung] = np.asarray(model.stiffness, float)[sprung]
    damping[sprung] = np.asarray(model.damping, float)[sprung]
    return stiffness, damping


def base_velocity(model, state=None) -> np.ndarray:
    """Velocity of b_0's mass center relative to the system mass center (b_0 axes): the peers
    integrate b_0's translation, which moves whenever the rest of the vehicle does."""

    s = model.initial if state is None else state
    cfg, omega = configuration_and_rates(model, s.gamma, s.omega0, s.gamma_dot)
    return np.asarray(mass_center_velocities(model, cfg, omega)[0], float)


def base_velocities(model, omega0, gamma, gamma_dot) -> np.ndarray:
    """:func:`base_velocity` of many states at once (leading axis of the three arrays; one
    compiled call)."""
    import jax

    def one(w, g, gd):
        cfg, omega = configuration_and_rates(model, g, w, gd)
        return mass_center_velocities(model, cfg, omega)[0]

    return np.asarray(jax.jit(jax.vmap(one))(omega0, gamma, gamma_dot), float)


def pinocchio_model(model):
    """``(pin_model, joint ids (n+1), q indices of the hinges, v indices of the hinges, com)``."""
    pin = _pinocchio()

    axis, offsets, com = tree_frames(model)
    mass, inertia = np.asarray(model.mass, float), np.asarray(model.inertia, float)
    pm = pin.Model()
    pm.gravity = pin.Motion.Zero()
    jid = [pm.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root")]
    pm.appendBodyToJoint(jid[0], pin.Inertia(mass[0], com[0], inertia[0]), pin.SE3.Identity())
    for k in range(1, model.n + 1):
        placement = pin.SE3(np.eye(3), offsets[k - 1])
        j = pm.addJoint(
            jid[model.topology.parents[k - 1]], pin.JointModelRevoluteUnaligned(axis[k - 1]), placement, f"h{k}"
        )
        pm.appendBodyToJoint(j, pin.Inertia(mass[k], com[k], inertia[k]), pin.SE3.Identity())
        jid.append(j)
    iq = np.array([pm.joints[j].idx_q for j in jid[1:]])
    iv = np.array([pm.joints[j].idx_v for j in jid[1:]])
    return pm, jid, iq, iv, com


_PIN_AXES = {"RX": (1.0, 0.0, 0.0), "RY": (0.0, 1.0, 0.0), "RZ": (0.0, 0.0, 1.0)}


def from_pinocchio(pin_model, *, initial=None, name: str = "", method: str = "auto"):
    """A jaxtree :class:`~jaxtree.Model` of a Pinocchio model of a tree of revolute joints on a
    free flyer (e.g. ``pinocchio.buildSampleModelHumanoid()`` or a URDF loaded with a
    ``JointModelFreeFlyer`` root): body 0 is the free flyer's body, hinge k the k-th revolute
    joint (``JointModelRX/RY/RZ`` or ``JointModelRevoluteUnaligned``) in Pinocchio's order.
    Gravity is left out (jaxtree has none). Other joint kinds raise ValueError naming the joint.

    jaxtree's body axes are parallel at gamma = 0 (Def. 4), so every body's axes are taken
    parallel to the world at Pinocchio's neutral configuration: axes and inertias are rotated
    by the joint frames' orientation there, and the hinge vectors run between the mass centers
    and the joint origins in those axes. `initial` as for :func:`jaxtree.build_model`.
    """

    joints = [pin_model.joints[j].shortname() for j in range(pin_model.njoints)]
    if pin_model.njoints < 2 or joints[1] != "JointModelFreeFlyer" or pin_model.parents[1] != 0:
        raise ValueError("from_pinocchio: joint 1 must be a JointModelFreeFlyer on the universe (body 0)")
    rot, pos = [np.eye(3)] * pin_model.njoints, [np.zeros(3)] * pin_model.njoints
    bodies = []
    for j in range(1, pin_model.njoints):
        kind, parent = joints[j], int(pin_model.parents[j])
        if j > 1 and parent < 1:
            raise ValueError(f"from_pinocchio: joint {j} ({pin_model.names[j]!r}) hangs from the universe")
        placement = pin_model.jointPlacements[j]
        rot[j] = rot[parent] @ np.asarray(placement.rotation)
        pos[j] = pos[parent] + rot[parent] @ np.asarray(placement.translation)
        inertia = pin_model.inertias[j]
        R = rot[j]
        body = {
            "name": str(pin_model.names[j]),
            "mass": float(inertia.mass),
            "inertia": R @ np.asarray(inertia.inertia) @ R.T,
        }
        com = pos[j] + R @ np.asarray(inertia.lever)
        if j > 1:
            if kind in ("JointModelRX", "JointModelRY", "JointModelRZ"):
                axis = np.asarray(_PIN_AXES[kind[-2:]])
            elif kind == "JointModelRevoluteUnaligned":
                axis = np.asarray(pin_model.joints[j].extract().axis, float)
            else:
                raise ValueError(
                    f"from_pinocchio: joint {j} ({pin_model.names[j]!r}) is a {kind}; jaxtree takes revolute "
                    "joints on a free flyer"
                )
            parent_com = bodies[parent - 1]["_com"]
            body.update(
                parent=parent - 1,
                axis=R @ axis,
                hinge_on_parent=pos[j] - parent_com,
                hinge_on_body=pos[j] - com,
            )
        body["_com"] = com
        bodies.append(body)
    for b in bodies:
        b.pop("_com")
    return build_model(bodies, initial, name=name, method=method)


def pinocchio_rhs(model, base_torque=None, *, stiffness=None, built=None):
    """``rhs(t, x)``: Pinocchio's ABA as the right side of a first-order system in
    ``x = (omega0, gamma, gamma_dot, v)`` (:func:`pinocchio_initial`): omega0 and v the angular
    and linear velocity of the free flyer (body 0's mass center) in its own frame, whose
    derivatives ABA returns. Without gravity nothing depends on the position or attitude of body 0,
    so they are not integrated. `base_torque`: optional ``t -> (3,)``, a torque on body 0 in its
    own axes (the free flyer's generalized force); the model's own loads are not translated.
    `stiffness`: optional (n,) hinge stiffnesses in place of the model's (a dispersed member);
    `built`: :func:`pinocchio_model` of `model` already built, shared by such members."""
    pin = _pinocchio()

    pm, _, iq, iv, _ = pinocchio_model(model) if built is None else built
    data = pm.createData()
    laws = _laws(model)
    stiffness, damping = (laws[0] if stiffness is None else np.asarray(stiffness, float)), laws[1]
    n = model.n
    q = pin.neutral(pm)
    v = np.zeros(pm.nv)
    tau = np.zeros(pm.nv)
    aba = pin.aba

    def rhs(t, x):
        w, g, gd, lin = x[:3], x[3 : 3 + n], x[3 + n : 3 + 2 * n], x[3 + 2 * n :]
        q[iq] = g
        v[:3], v[3:6], v[iv] = lin, w, gd
        tau[iv] = -stiffness * g - damping * gd
        if base_torque is not None:
            tau[3:6] = base_torque(t)
        a = aba(pm, data, q, v, tau)
        return np.concatenate([a[3:6], gd, a[iv], a[:3]])

    return rhs


def pinocchio_initial(model) -> np.ndarray:
    """The state ``x`` of :func:`pinocchio_rhs` at the model's initial state: v is body 0's
    velocity relative to the system mass center (:func:`base_velocity`)."""
    s = model.initial
    return np.concatenate([np.asarray(s.omega0), np.asarray(s.gamma), np.asarray(s.gamma_dot), base_velocity(model)])


def forward_difference_jacobian(rhs):
    """``jac(t, x)`` of a right side ``rhs(t, x)`` for scipy's implicit solvers: forward differences
    with the usual step ``sqrt(eps) max(1, |x_i|)``. scipy's own estimate (``num_jac``) grows its step
    for columns the right side does not depend on (a rotor's angle) until it overflows: Radau failed
    on the spinning bus with NaNs in its Jacobian."""

    def jac(t, x):
        f0 = rhs(t, x)
        cols = np.empty((x.size, x.size))
        for i in range(x.size):
            dx = 1.5e-8 * max(1.0, abs(x[i]))
            xp = x.copy()
            xp[i] += dx
            cols[:, i] = (rhs(t, xp) - f0) / dx
        return cols

    return jac


def pinocchio_runner(model, ts, base_torque=None):
    """``run(method, rtol, atol) -> (omega0 (T, 3), gamma (T, n), wall seconds, right sides)``:
    Pinocchio's ABA (:func:`pinocchio_rhs`) integrated by ``scipy.integrate.solve_ivp``
    (``"DOP853"``, ``"RK45"``, ``"Radau"`` ...) over the save times `ts`. The time is that of
    ``solve_ivp`` alone. `base_torque`: optional ``t -> (3,)``, a torque on body 0 in its own axes
    (the free flyer's generalized force), for a slew; the model's own loads are not translated."""
    from scipy.integrate import solve_ivp

    rhs, x0 = pinocchio_rhs(model, base_torque), pinocchio_initial(model)
    n = model.n
    ts = np.asarray(ts, float)

    jac = forward_difference_jacobian(rhs)

    def run(method, rtol, atol):
        implicit = method in ("Radau", "BDF", "LSODA")
        options: dict[str, Any] = {"jac": jac} if implicit else {}
        t = time.perf_counter()
        r = solve_ivp(
            rhs,
            (ts[0], ts[-1]),
            x0,
            method=method,
            rtol=rtol,
            atol=atol,
            t_eval=ts,
            **options,
        )
        wall = time.perf_counter() - t
        if r.status != 0 or r.y.shape[1] != ts.size:
            raise RuntimeError(f"scipy {method}: {r.message}")
        Y = r.y.T
        rhs_calls = int(r.nfev) + (int(r.njev) * (x0.size + 1) if implicit else 0)
        return Y[:, :3], Y[:, 3 : 3 + n], wall, rhs_calls

    return run


def mjcf(model, *, timestep, integrator=None, springs=False):
    """``(xml, tiny)``: the MJCF text (bodies ``b{k}``, joints ``h{k}``) and the massless bodies
    given ``MUJOCO_TINY_MASS`` / ``MUJOCO_TINY_INERTIA``. `springs`: the hinges' stiffness and
    damping as joint springs and dampers (rest angle 0)."""
    axis, offsets, com = tree_frames(model)
    mass, inertia = np.asarray(model.mass, float), np.asarray(model.inertia, float)
    stiffness, damping = _laws(model)
    children = model.topology.children
    tiny = [k for k in range(model.n + 1) if mass[k] == 0.0]
    f = lambda v: " ".join(f"{x:.17g}" for x in v)

    def inertial(k):
        m, J = (MUJOCO_TINY_MASS, MUJOCO_TINY_INERTIA * np.eye(3)) if k in tiny else (mass[k], inertia[k])
        full = [J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]]
        return f'<inertial pos="{f(com[k])}" mass="{m:.17g}" fullinertia="{f(full)}"/>'

    def body(k):
        if k == 0:
            head = '<body name="b0"><freejoint name="root"/>'
        else:
            spring = (
                f' stiffness="{stiffness[k - 1]:.17g}" springref="0" damping="{damping[k - 1]:.17g}"' if springs else ""
            )
            head = (
                f'<body name="b{k}" pos="{f(offsets[k - 1])}">'
                f'<joint name="h{k}" type="hinge" pos="0 0 0" axis="{f(axis[k - 1])}"{spring}/>'
            )
        return head + inertial(k) + "".join(body(c) for c in children[k]) + "</body>"

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * model.n + 1000))
    option = f'gravity="0 0 0" timestep="{timestep:.17g}"' + (f' integrator="{integrator}"' if integrator else "")
    return f'<mujoco model="jaxtree"><option {option}/><worldbody>{body(0)}</worldbody></mujoco>', tiny


def mujoco_runner(model, ts):
    """``run(integrator, steps_per_save) -> (omega0 (T, 3), gamma (T, n), wall seconds, right
    sides)``: MuJoCo (``"RK4"``, ``"implicitfast"``, ``"Euler"``) at a fixed step of the save
    interval over `steps_per_save`, `ts` evenly spaced. Massless bodies get
    ``MUJOCO_TINY_MASS`` / ``MUJOCO_TINY_INERTIA``. The time is that of the stepping loop."""
    import mujoco as _mujoco  # pyright: ignore[reportMissingImports]  (optional: the peers extra)

    mujoco: Any = _mujoco  # (its names come from compiled extensions, which pyright cannot read)
    ts = np.asarray(ts, float)
    interval = float(ts[1] - ts[0])
    s = model.initial
    v0 = base_velocity(model)
    built = {}

    def build(integrator, dt):
        if (integrator, dt) not in built:
            xml, _ = mjcf(model, timestep=dt, integrator=integrator, springs=True)
            m = mujoco.MjModel.from_xml_string(xml)
            jnt = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, f"h{k}") for k in range(1, model.n + 1)]
            built[integrator, dt] = (m, mujoco.MjData(m), m.jnt_qposadr[jnt], m.jnt_dofadr[jnt])
        return built[integrator, dt]

    def run(integrator, steps_per_save):
        m, d, iq, iv = build(integrator, interval / steps_per_save)
        t = time.perf_counter()
        mujoco.mj_resetData(m, d)
        d.qpos[3] = 1.0
        d.qpos[iq] = np.asarray(s.gamma)
        d.qvel[0:3] = v0
        d.qvel[3:6] = np.asarray(s.omega0)
        d.qvel[iv] = np.asarray(s.gamma_dot)
        W, G = [np.array(d.qvel[3:6])], [np.array(d.qpos[iq])]
        for _ in range(ts.size - 1):
            mujoco.mj_step(m, d, nstep=steps_per_save)
            W.append(np.array(d.qvel[3:6]))
            G.append(np.array(d.qpos[iq]))
        wall = time.perf_counter() - t
        stages = 4 if integrator == "RK4" else 1
        return np.asarray(W), np.asarray(G), wall, stages * steps_per_save * (ts.size - 1)

    return run
