"""The cases of the work-precision report (``jaxtree bench``): the solvers and tolerance ladders,
and the catalogue of scenes with their time spans, save times and error measures (the reference
scenes, flex95's slew, the stiff chains and the extreme cases; :func:`bench_case`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import diffrax as dfx
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from jaxtree._src.equations.loads import BodyTorque
from jaxtree._src.integration.radau import Radau5
from jaxtree._src.integration.rk4 import RK4
from jaxtree._src.scene.files import load_scene
from jaxtree._src.vehicle.model import Model

SOLVERS: dict[str, Callable[[], dfx.AbstractSolver]] = {
    "Tsit5": dfx.Tsit5,
    "Dopri5": dfx.Dopri5,
    "Dopri8": dfx.Dopri8,
    "Kvaerno3": dfx.Kvaerno3,
    "Kvaerno5": dfx.Kvaerno5,
    "KenCarp4": dfx.KenCarp4,
    "Radau5": Radau5,
    "RK4": RK4,
}
EXPLICIT = ("Tsit5", "Dopri5", "Dopri8")
IMPLICIT = ("Kvaerno3", "Kvaerno5", "KenCarp4", "Radau5")
# On the large trees one implicit solver shows the point (each implicit step evaluates a Jacobian
# of 100-200 states by forward differentiation of Eq. 1; compiling it takes minutes here).
LARGE_SOLVERS = ("Tsit5", "Dopri5", "Dopri8", "Kvaerno5", "RK4")
TOLERANCES = (1e-4, 1e-6, 1e-8, 1e-10)
# Implicit solvers on a case that is not stiff: a step costs 10-50 explicit ones, a compile 20-50 s
# here, and at 1e-8 and below their runs take minutes (20k steps on fig4 at 1e-10) without ever
# competing. Outside the stiff group they run at the tolerances from this one up, and only
# Kvaerno5 except on EVERY_SOLVER_CASES, where every solver runs.
IMPLICIT_TIGHTEST = 1e-6
# flex95's slew: its wing modes (to 433 rad/s) hold the explicit solvers to ~1000 steps (about 1 s
# a run here) at every tolerance; Radau5 is the stiff solver, Kvaerno5 5-10x its time (bench_stiff.py)
FLEX95_SOLVERS = ("Tsit5", "Dopri8", "Radau5")
NONSTIFF_SOLVERS = ("Tsit5", "Dopri5", "Dopri8", "Kvaerno5", "RK4")
EVERY_SOLVER_CASES = ("appendix_c", "wings")
QUICK_TOLERANCES = (1e-5, 1e-8)
REFERENCE_TOL = 1e-12
TARGETS = (1e-6, 1e-9)
# A run that needs more steps than this stops there: "stalled" in the report (the explicit
# solvers on the stiffest chains; their time to the end is the stall's time / fraction done).
STEP_CAP = 100_000
IMPLICIT_STEP_CAP = 20_000  # an implicit step (Newton iterations, a Jacobian) costs 10-50 explicit ones
# Goals of the work-precision report (time of jaxtree's best / the fastest peer's, at 1e-6 and 1e-9).
GOALS = {"wings": (1.0, 0.5)}


@dataclasses.dataclass(frozen=True)
class BenchCase:
    """One row group of the report: `model` run from 0 to `t1` with `n_save` save times.
    `group`: ``"reference"``, ``"stiff"`` or ``"extreme"``; `small`: the small hinges of the
    ``eq30`` / ``hybrid-k`` formulations (None: full only); `hybrid_modes`: the k of the
    ``hybrid-k`` rows; `solvers` / `tolerances`: restrictions for long cases (None: all);
    `references`: the two reference solvers (None: the group's, see :func:`_references`);
    `relative`: the hinges of a relative error, the larger of the hub rate's error over its
    peak and these hinges' angles' over theirs (None: the absolute error in omega0 and every
    gamma); `peer_torque`: ``t -> (3,)`` in numpy, the torque on body 0 (its axes) that the
    model's loads apply, for the peers, which take no jaxtree loads (Pinocchio as the free
    flyer's generalized force; a peer that takes no base torque is skipped with a note; None:
    a case with loads has no peers); `peer_methods`: scipy's methods for Pinocchio, each over the
    whole ladder, the first the cross-check (None: the group's, RK45 and Radau at their two
    loosest settings)."""

    name: str
    group: str
    description: str
    model: Model
    t1: float
    n_save: int = 101
    small: tuple[int, ...] | None = None
    hybrid_modes: tuple[int, ...] = ()
    solvers: tuple[str, ...] | None = None
    tolerances: tuple[float, ...] | None = None
    references: tuple[str, str] | None = None
    relative: tuple[int, ...] | None = None
    peer_torque: Callable[[float], np.ndarray] | None = None
    peer_methods: tuple[str, ...] | None = None


def _scene(name):

    return load_scene(name)


def _with(model: Model, **fields) -> Model:
    names = tuple(fields)
    return eqx.tree_at(lambda m: tuple(getattr(m, k) for k in names), model, tuple(fields.values()))


def _hinge_inertia(model: Model) -> np.ndarray:
    """Per hinge, its body's moment of inertia about the hinge line (parallel axes)."""
    axis, r = np.asarray(model.axis, float), np.asarray(model.hinge_on_body, float)
    inertia, mass = np.asarray(model.inertia, float)[1:], np.asarray(model.mass, float)[1:]
    return np.einsum("ki,kij,kj->k", axis, inertia, axis) + mass * np.sum(np.cross(axis, r) ** 2, 1)


def stiff_chain(scale: float) -> Model:
    """chain10 with the tip hinge's spring x `scale` and damped at a ratio of 0.7; the other
    hinges keep their springs, damped at a ratio of 0.02 (benchmarks/bench_stability.py)."""
    base = _scene("chain10")
    k = np.asarray(base.stiffness, float).copy()
    k[-1] *= scale
    zeta = np.full(base.n, 0.02)
    zeta[-1] = 0.7
    c = 2 * zeta * np.sqrt(k * _hinge_inertia(base))
    return _with(base, stiffness=jnp.asarray(k), damping=jnp.asarray(c))


def _fig4_state(**changes) -> Model:
    model = _scene("fig4_free")
    s = model.initial
    gamma, gamma_dot = np.asarray(s.gamma, float).copy(), np.asarray(s.gamma_dot, float).copy()
    omega0 = np.asarray(s.omega0, float).copy()
    if "rotor" in changes:
        gamma_dot[model.names.index("rotor") - 1] = changes["rotor"]
    if "inner" in changes:
        gamma[model.names.index("gimbal_inner") - 1] = changes["inner"]
    if "omega0" in changes:
        omega0 = np.asarray(changes["omega0"], float)
    state = s._replace(omega0=jnp.asarray(omega0), gamma=jnp.asarray(gamma), gamma_dot=jnp.asarray(gamma_dot))
    return _with(model, initial=state)


def _tiny_body() -> Model:
    model = _scene("fig4_free")
    k = model.names.index("panel_side")
    mass = np.asarray(model.mass, float).copy()
    inertia = np.asarray(model.inertia, float).copy()
    mass[k] = 1e-6 * mass[0]
    inertia[k] = 1e-6 * inertia[0]
    return _with(model, mass=jnp.asarray(mass), inertia=jnp.asarray(inertia))


def _panel_hinges(model: Model, prefix: str) -> tuple[int, ...]:
    return tuple(k for k in range(1, model.n + 1) if model.names[k].startswith(prefix))


FLEX95_TORQUE = (15.0, 9.0, 0.0)  # N m on the bus in flex95's slew


def _slew_pulse(t):
    """flex95's slew profile: on at 1 s, off at 3 s, tanh edges of ~0.2 s (0.1 s time constant)."""
    return 0.5 * (jnp.tanh((t - 1.0) / 0.1) - jnp.tanh((t - 3.0) / 0.1))


def _slew_torque_np(t) -> np.ndarray:
    """flex95's slew torque in numpy, for the peers' right sides (a JAX call per right side would
    add its dispatch to every Pinocchio evaluation and distort the peer's timing)."""
    return np.asarray(FLEX95_TORQUE) * (0.5 * (math.tanh((t - 1.0) / 0.1) - math.tanh((t - 3.0) / 0.1)))


def flex95_slew() -> Model:
    """flex95 (the scene: rotor at 10 pi rad/s, the bus spinning, wings straight) with the slew
    torque of the slew on the bus: :data:`FLEX95_TORQUE` times :func:`_slew_pulse`."""

    return _scene("flex95").with_loads(BodyTorque(0, jnp.asarray(FLEX95_TORQUE), _slew_pulse))


def _plate(m: float, a: float, b: float, c: float) -> np.ndarray:
    """Inertia of a uniform a x b x c box about its center."""
    return np.diag([m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12])


WINGS4_TORQUE = (40.0, 25.0, 0.0)  # N m on the hub in wings4's slew


def wings4(panels: int = 20, k: float = 2000.0, d: float = 0.3) -> Model:
    """A flexible vehicle of four wings: a 1500 kg hub and four wings of `panels` panels (2 kg,
    0.1 x 1.0 m plates) latched by stiff, lightly damped bending hinges (`k` N m/rad, `d` N m s/rad;
    a held wing's modes span ~1-600 rad/s), wings straight, the hub at rest, slewed by
    :data:`WINGS4_TORQUE` on the hub from 1 s to 3 s with flex95's tanh edges. No scene file
    holds it: it is the issue's "4-wing, 80-panel flexible vehicle", built here."""
    from jaxtree._src.scene.scene import build_model

    bodies: list[dict] = [
        {"name": "hub", "mass": 1500.0, "inertia": [[1200.0, 5.0, 0.0], [5.0, 1400.0, 0.0], [0.0, 0.0, 1000.0]]}
    ]
    for w in range(4):
        ang = 0.5 * math.pi * w + 0.25 * math.pi
        rot = np.array([[math.cos(ang), -math.sin(ang), 0.0], [math.sin(ang), math.cos(ang), 0.0], [0.0, 0.0, 1.0]])
        out = rot[:, 0]
        seg = rot @ _plate(2.0, 0.1, 1.0, 0.02) @ rot.T
        for s in range(panels):
            bodies.append(
                {
                    "name": f"wing{w}_p{s}",
                    "mass": 2.0,
                    "inertia": seg.tolist(),
                    "parent": 0 if s == 0 else len(bodies) - 1,
                    "axis": (rot @ np.array([0.0, 1.0, 0.0])).tolist(),
                    "hinge_on_parent": (1.0 * out if s == 0 else 0.05 * out).tolist(),
                    "hinge_on_body": (-0.05 * out).tolist(),
                    "joint": {"kind": "spring_damper", "stiffness": k, "damping": d},
                }
            )
    model = build_model(bodies, name="wings4")
    return model.with_loads(BodyTorque(0, jnp.asarray(WINGS4_TORQUE), _slew_pulse))


def _wings4_torque_np(t) -> np.ndarray:
    return np.asarray(WINGS4_TORQUE) * (0.5 * (math.tanh((t - 1.0) / 0.1) - math.tanh((t - 3.0) / 0.1)))


def _case(name: str) -> BenchCase:
    if name.startswith("stiff_"):
        try:
            scale = float(name.split("_", 1)[1])
        except ValueError:
            raise ValueError(f"bench case {name!r}: expected stiff_<scale>, e.g. stiff_1e6") from None
        model = stiff_chain(scale)
        return BenchCase(
            name,
            "stiff",
            f"chain10, tip hinge's spring x {scale:g} (damping ratio 0.7), 1 s",
            model,
            1.0,
            # every hinge small: Eq. (30) keeps the fast tip mode, the hybrid model's 2 modes leave it out
            small=tuple(range(1, model.n + 1)),
            hybrid_modes=(2,),
        )
    if name in ("fig4", "fig4_free"):
        what = {"fig4": "the seed's Fig. 4 (platform prescribed)", "fig4_free": "Fig. 4, platform free"}
        return BenchCase(name, "reference", what[name] + ", 10 s", _scene(name), 10.0)
    if name == "chain50":
        what = "hub and a sprung boom of 50 segments, 10 s"
        return BenchCase(name, "reference", what, _scene(name), 10.0, solvers=LARGE_SOLVERS)
    if name == "appendix_c":
        m = _scene(name)
        return BenchCase(name, "reference", "the seed's Appendix C, 10 s", m, 10.0, small=(1, 2), hybrid_modes=(1,))
    if name == "wings":
        m = _scene(name)
        return BenchCase(
            name, "reference", "hub and two wings of 4 sprung panels, 10 s", m, 10.0,
            small=tuple(range(1, m.n + 1)), hybrid_modes=(1, 2),
        )  # fmt: skip
    if name == "panels95":
        m = _scene(name)
        return BenchCase(
            name, "reference", "the 95-body vehicle of Fig. 2/3c, 10 s", m, 10.0,
            small=_panel_hinges(m, "wing"), hybrid_modes=(2,), solvers=LARGE_SOLVERS,
        )  # fmt: skip
    if name == "flex95":
        m = flex95_slew()
        return BenchCase(
            name, "stiff",
            "flex95's slew (wing modes to 433 rad/s; rotor at 10 pi rad/s, the scene's bus spin, (15, 9, 0) N m on "
            "the bus from 1 s to 3 s, 0.2 s tanh edges), 10 s; error: the hub rate relative to its peak and the "
            "wing angles relative to theirs, the larger",
            m, 10.0, solvers=FLEX95_SOLVERS, references=("Dopri8", "Tsit5"), relative=_panel_hinges(m, "wing"),
            peer_torque=_slew_torque_np, peer_methods=("DOP853", "Radau"),
        )  # fmt: skip
    if name == "wings4":
        m = wings4()
        return BenchCase(
            name, "stiff",
            "a hub and four wings of 20 panels on stiff, lightly damped latched hinges, slewed by (40, 25, 0) N m on "
            "the hub from 1 s to 3 s (0.2 s tanh edges), 10 s; error: the hub rate relative to its peak and the "
            "wing angles relative to theirs, the larger",
            m, 10.0, solvers=FLEX95_SOLVERS, references=("Dopri8", "Tsit5"), relative=_panel_hinges(m, "wing"),
            peer_torque=_wings4_torque_np, peer_methods=("DOP853", "Radau"),
        )  # fmt: skip
    extreme = {
        "rotor_10pi": (lambda: _fig4_state(rotor=10 * math.pi), "fig4_free, rotor at 10 pi rad/s, 10 s", 10.0),
        "rotor_1000pi": (lambda: _fig4_state(rotor=1000 * math.pi), "fig4_free, rotor at 1000 pi rad/s, 10 s", 10.0),
        "bus_spin": (lambda: _fig4_state(omega0=(0.0, 0.0, 10.0)), "fig4_free, bus spinning at 10 rad/s, 10 s", 10.0),
        "gimbal_lock": (
            lambda: _fig4_state(inner=math.pi / 2 - 1e-3),
            "fig4_free, inner gimbal 1e-3 rad from lock, 10 s",
            10.0,
        ),
        "tiny_body": (_tiny_body, "fig4_free, panel_side with 1e-6 of the bus's mass and inertia, 10 s", 10.0),
    }
    if name in extreme:
        build, what, t1 = extreme[name]
        return BenchCase(name, "extreme", what, build(), t1)
    if name == "long_run":
        return BenchCase(
            name, "extreme", "fig4_free over 1000 s (drift against time)", _scene("fig4_free"), 1000.0,
            n_save=201, solvers=("Tsit5", "Dopri8", "Kvaerno5"), tolerances=(1e-6, 1e-8, 1e-10),
        )  # fmt: skip
    raise ValueError(f"unknown bench case {name!r}; known: {', '.join(CASES)}")


CASES = (
    "fig4",
    "fig4_free",
    "appendix_c",
    "wings",
    "chain50",
    "panels95",
    "flex95",
    "wings4",
    "stiff_1e2",
    "stiff_1e4",
    "stiff_1e6",
    "stiff_1e8",
    "rotor_10pi",
    "rotor_1000pi",
    "bus_spin",
    "gimbal_lock",
    "tiny_body",
    "long_run",
)
QUICK_CASES = ("wings",)
QUICK_SOLVERS = ("Tsit5", "Dopri8", "Kvaerno5", "RK4")


def bench_case(name: str) -> BenchCase:
    """The case `name` of :data:`CASES` (``"stiff_1e8"`` etc. for any scale)."""
    return _case(name)
