"""The same vehicle in the peers, for the benchmark scripts: a Pinocchio model and MuJoCo's MJCF.

Frames: body 0's at its mass center, body k's at hinge point k, all parallel to the body axes
(so parallel to each other at gamma = 0). Body 0 is a free flyer / free joint; hinge k a
revolute (hinge) joint about ``model.axis[k-1]``. No gravity. Imports only numpy: the scripts
set their environment (XLA and BLAS flags) before anything loads JAX.
"""

import sys

import numpy as np

MUJOCO_TINY_MASS, MUJOCO_TINY_INERTIA = 1e-9, 1e-12  # MuJoCo refuses massless bodies


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


def pinocchio_model(model):
    """``(pin_model, joint ids (n+1), q indices of the hinges, v indices of the hinges, com)``."""
    import pinocchio as pin

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


def mjcf(model, *, timestep, integrator=None, springs=False):
    """``(xml, tiny)``: the MJCF text (bodies ``b{k}``, joints ``h{k}``) and the massless bodies
    given ``MUJOCO_TINY_MASS`` / ``MUJOCO_TINY_INERTIA``. `springs`: the hinges' stiffness as joint
    springs (rest angle 0, no damping)."""
    axis, offsets, com = tree_frames(model)
    mass, inertia = np.asarray(model.mass, float), np.asarray(model.inertia, float)
    stiffness = np.asarray(model.stiffness, float)
    children = model.topology.children
    tiny = [k for k in range(model.n + 1) if mass[k] == 0.0]
    f = lambda v: " ".join(f"{x:.17g}" for x in v)  # noqa: E731

    def inertial(k):
        m, J = (MUJOCO_TINY_MASS, MUJOCO_TINY_INERTIA * np.eye(3)) if k in tiny else (mass[k], inertia[k])
        full = [J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]]
        return f'<inertial pos="{f(com[k])}" mass="{m:.17g}" fullinertia="{f(full)}"/>'

    def body(k):
        if k == 0:
            head = '<body name="b0"><freejoint name="root"/>'
        else:
            spring = f' stiffness="{stiffness[k - 1]:.17g}" springref="0" damping="0"' if springs else ""
            head = (
                f'<body name="b{k}" pos="{f(offsets[k - 1])}">'
                f'<joint name="h{k}" type="hinge" pos="0 0 0" axis="{f(axis[k - 1])}"{spring}/>'
            )
        return head + inertial(k) + "".join(body(c) for c in children[k]) + "</body>"

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * model.n + 1000))
    option = f'gravity="0 0 0" timestep="{timestep:.17g}"' + (f' integrator="{integrator}"' if integrator else "")
    return f'<mujoco model="jaxtree"><option {option}/><worldbody>{body(0)}</worldbody></mujoco>', tiny
