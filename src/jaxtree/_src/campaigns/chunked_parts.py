"""One part of a chunked run: its integration and the dataset written for it.

:class:`PartRunner` runs the parts of one configuration
(:func:`~jaxtree._src.campaigns.chunked_config.chunked_config`): Eq. (1) through
:func:`jaxtree.simulate`, or the hybrid-coordinate equations of Eqs. (105)-(123) through
:func:`jaxtree.simulate_hybrid` (their model built from ``hybrid_small`` and the modal options).
A scene's controller and a hybrid run's neglected modes continue from part to part. A part's
histories and the exact state where it ended (the next part's start, as written) make its
dataset (:func:`part_dataset`); a hybrid part adds its modal coordinates, the appendages'
output nodes and the estimated error of the neglected modes (:class:`HybridPart`).
"""

from __future__ import annotations

from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ..errors import SceneError
from ..hybrid import hybrid_model, simulate_hybrid
from ..hybrid.model import appendage_body
from ..hybrid.rhs import hybrid_rhs
from ..integration.autosolver import choose_for_field
from ..integration.failures import MESSAGES, SimulationError, failure_kind
from ..integration.simulate import simulate
from ..io.results import body_positions, simulation_dataset
from ..linear.modes import ModalError
from ..scene.appendages import scene_appendages
from ..vehicle.model import State
from .chunked_config import ChunkedRunError, parse_hinges, solver_named


class PartRunner:
    """Runs the parts of one configuration: the full equations or the hybrid ones."""

    def __init__(self, model, cfg):
        self.model, self.cfg = model, cfg
        self.dtype = jnp.result_type(model.mass)
        self.hybrid = None if "hybrid_small" not in cfg else _hybrid_of(model, cfg, self.dtype)
        # a hybrid run's "auto": the rule on the hybrid equations at the start
        if cfg["solver"] == "auto" and self.hybrid is not None:
            y = self.hybrid.pack(model.initial)
            _, choice = choose_for_field(
                hybrid_rhs, self.hybrid, y, cfg["t0"], cfg["t1"], rtol=cfg["rtol"], atol=cfg["atol"],
                what="the hybrid equations linearized at the start",
            )  # fmt: skip
            cfg["solver"], cfg["solver_choice"] = choice.name, f"auto: {choice.reason}"
        self.solver = solver_named(cfg["solver"])
        self.truncation_state = None  # the neglected modes' state where the last hybrid part ended

        # a scene's controller (internal states) continues from part to part: its states where
        # the last part ended are the next part's z0 (always an array: one compiled program)
        self.control = None
        if model.controller is not None and hasattr(model.controller, "z0"):
            self.control = ravel_pytree(model.controller.initial())

    def initial(self):
        # the hybrid runs pack the physical start themselves, and see its neglected modes' content
        if self.control is not None:
            self.set_control(self.control[0])
        return self.model.initial

    def set_control(self, flat):
        """Start the next part's controller from the flat internal states `flat`."""
        assert self.control is not None
        z0 = self.control[1](jnp.asarray(flat, self.dtype))
        self.model = eqx.tree_at(lambda m: m.controller.z0, self.model, z0, is_leaf=lambda x: x is None)

    def state_from(self, ds):
        """The state where the part `ds` (as written) ended: the next part's start."""
        v = lambda k: jnp.asarray(ds[k].values, self.dtype)
        if self.hybrid is not None:
            if "resume_truncation" in ds:
                self.truncation_state = v("resume_truncation")
            return v("resume_flat")
        if "resume_control" in ds and self.control is not None:
            self.set_control(ds["resume_control"].values)
        return State(v("resume_dcm"), v("resume_omega0"), v("resume_gamma"), v("resume_gamma_dot"))

    def run(self, ts, y0, rtol, atol):
        """One part: integrate from ts[0] to ts[-1] saving at `ts` (padded: repeated end time)."""
        ts = jnp.asarray(ts, self.dtype)
        common: dict[str, Any] = dict(t0=ts[0], y0=y0, saveat=ts, solver=self.solver, rtol=rtol, atol=atol, throw=False)
        if self.hybrid is None:
            sol = simulate(self.model, ts[-1], attitude=self.cfg["attitude"], max_steps=self.cfg["max_steps"], **common)
            part = _FullPart(sol)
            if self.control is not None:  # the next part's controller continues from here
                self.set_control(part.end_state()["resume_control"][1])
            return part
        sol = simulate_hybrid(
            self.hybrid, ts[-1], max_steps=self.cfg["max_steps"], truncation_start=self.truncation_state, **common
        )
        self.truncation_state = sol.truncation_state
        return HybridPart(sol, self.hybrid)


def _hybrid_of(model, cfg, dtype):
    """The hybrid model of the configuration (its ``hybrid_small`` and modal options)."""
    if model.law is not None or model.controller is not None:
        raise ChunkedRunError(
            "hybrid_small", "the scene's 'control' laws are not part of the hybrid equations; run the full equations"
        )
    try:
        small = parse_hinges(model, cfg["hybrid_small"])
    except ValueError as e:
        raise ChunkedRunError("hybrid_small", str(e)) from None
    try:
        appendages = scene_appendages(model)
    except SceneError as e:
        raise ChunkedRunError("hybrid_small", f"the scene's appendages: {e}") from None
    if not small and not appendages:
        raise ChunkedRunError(
            "hybrid_small", "'none' leaves nothing in modal coordinates (the scene has no appendages)"
        )
    try:
        return hybrid_model(
            model,
            small,
            cfg["n_modes"],
            appendages=appendages,
            tol=cfg.get("modes_tol", 1e-2),
            cutoff=cfg["cutoff"],
            omega0=jnp.asarray(cfg["spin"], dtype),
            damping=cfg["modal_damping"],
            attitude=cfg["attitude"],
        )
    except ModalError as e:
        raise ChunkedRunError("hybrid_small", str(e)) from None
    except ValueError as e:
        raise ChunkedRunError("hybrid_small/modes", str(e).removeprefix("hybrid_model: ")) from None


def _take(x, count):
    return np.asarray(x)[:count]


class _FullPart:
    def __init__(self, sol):
        self.sol = sol
        self.kind = failure_kind(sol.failure)
        self.message = None
        if self.kind is not None:
            try:
                sol.check()
            except SimulationError as e:
                self.message = str(e)
        st = sol.stats
        self.steps = (
            int(np.asarray(st["num_accepted_steps"])),
            int(np.asarray(st["num_rejected_steps"])),
            int(np.asarray(st["rhs_evaluations"])),
        )
        self.t_final = float(np.asarray(sol.t_final))

    def rows(self, count):
        s = self.sol
        return dict(
            **_kinematic_rows(s, count),
            energy=_take(s.energy, count),
            angular_momentum=_take(s.angular_momentum, count),
            attitude=_take(s.attitude, count),
            attitude_name=s.problem.attitude.name,
            hold_torque=_take(s.hold_torque, count),
            orthogonality=_take(s.orthogonality, count),
        )

    def next_start(self):
        """The state the next part starts from (as computed)."""
        return self.sol.final

    def end_state(self):
        """The state the next part starts from (exactly as written to the part)."""
        f = self.sol.final
        out = {
            "resume_dcm": (("row", "column"), np.asarray(f.dcm)),
            "resume_omega0": (("axis",), np.asarray(f.omega0)),
            "resume_gamma": (("hinge",), np.asarray(f.gamma)),
            "resume_gamma_dot": (("hinge",), np.asarray(f.gamma_dot)),
        }
        z = self.sol.final_control_state  # the controller's internal states at the end (flat)
        if z is not None:
            out["resume_control"] = (("control_state",), np.asarray(ravel_pytree(z)[0]))
        return out


def _kinematic_rows(s, count):
    """The first `count` rows of the histories every part has."""
    return {k: _take(getattr(s, k), count) for k in ("ts", "gamma", "gamma_dot", "omega0", "dcm")}


# diffrax's result of a hybrid run, as the failure kinds of jaxtree.simulate (else "other")
_HYBRID_KINDS = (
    (diffrax.RESULTS.successful, None),
    (diffrax.RESULTS.max_steps_reached, "max_steps"),
    (diffrax.RESULTS.dt_min_reached, "dt_min"),
)


class HybridPart:
    def __init__(self, sol, hybrid):
        self.sol, self.hybrid = sol, hybrid
        self.kind = next((kind for r, kind in _HYBRID_KINDS if sol.result == r), "other")
        self.t_final = float(np.asarray(sol.t_final))
        self.message = None
        if self.kind is not None:
            f = sol.final
            self.message = (
                f"jaxtree.simulate_hybrid: {MESSAGES[self.kind]}.\n  stopped at t = {self.t_final:.9g}\n"
                f"  omega0 = {np.asarray(f.omega0)}\n  gamma = {np.asarray(f.gamma)}\n"
                f"  modal coordinates = {np.asarray(sol.final_modal)}"
            )
        st = sol.stats
        acc, rej = int(np.asarray(st["num_accepted_steps"])), int(np.asarray(st["num_rejected_steps"]))
        self.steps = (acc, rej, -1)
        # the vehicle's, finite-element appendages included (simulate_hybrid's diagnostics)
        self.energy, self.H = sol.energy, sol.angular_momentum
        S = np.asarray(hybrid.small, int) - 1
        ok = np.isfinite(np.asarray(sol.ts))
        self.truncation = (
            float(np.max(np.asarray(sol.truncation_error)[ok], initial=0.0)),
            float(np.max(np.abs(np.asarray(sol.truncation_static)[ok]), initial=0.0)),
            float(np.max(np.abs(np.asarray(sol.gamma)[ok][:, S] - np.asarray(hybrid.gamma_nominal)[S]), initial=0.0)),
        )

    def rows(self, count):
        s = self.sol
        return dict(
            **_kinematic_rows(s, count),
            energy=_take(self.energy, count),
            angular_momentum=_take(self.H, count),
            attitude=np.asarray(s.ys)[:count, : self.hybrid.attitude.size],
            attitude_name=self.hybrid.attitude.name,
            modal=_take(s.modal, count),
            **_appendage_rows(self.hybrid, s.ys, count),
        )

    def next_start(self):
        return self.sol.ys[-1]

    def end_state(self):
        out: dict[str, tuple[tuple[str, ...], Any]] = {"resume_flat": (("flat_state",), np.asarray(self.sol.ys)[-1])}
        if self.sol.truncation_state is not None:
            out["resume_truncation"] = (("truncation_coordinate", "re_im"), np.asarray(self.sol.truncation_state))
        return out


def _appendage_rows(hybrid, ys, count) -> dict:
    """The finite-element appendages' output nodes: displacements (T, P, 6) and names (P,)."""
    outs = [(i, node) for i, ap in enumerate(hybrid.appendages) for node in ap.outputs]
    if not outs:
        return {}
    ys = np.asarray(ys)[:count]
    rows = np.stack(
        [
            np.asarray(jax.vmap(lambda y, i=i, node=node: hybrid.appendage_displacement(y, i, node))(ys))
            for i, node in outs
        ],
        1,
    )
    names = [f"{hybrid.appendages[i].name or f'appendage{i}'}:{node}" for i, node in outs]
    aps = hybrid.appendages
    bodies = [appendage_body(hybrid.model, aps[i]) for i, _ in outs]
    places = [np.asarray(aps[i].nodes[node] + aps[i].point) for i, node in outs]
    return {
        "appendage_output": rows,
        "appendage_output_name": names,
        "appendage_output_site": {"body": bodies, "position": places},
    }


def part_dataset(runner, part, count, skip_first, attrs):
    """The dataset of one part: its rows `count` (the first left out after the first part: the
    previous part's last), and the state where it ended."""
    r = part.rows(None)  # every row of the (padded) part: one shape, one compiled geometry
    r["positions"] = body_positions(runner.model, r["gamma"])
    first = 1 if skip_first else 0
    r: dict[str, Any] = {
        k: (
            v[first:count]
            if isinstance(v, np.ndarray)
            else tuple(x[first:count] for x in v)
            if isinstance(v, tuple)
            else v
        )
        for k, v in r.items()
    }
    ts = r.pop("ts")
    ds = simulation_dataset(
        runner.model, ts, r.pop("gamma"), r.pop("gamma_dot"), r.pop("omega0"), r.pop("dcm"), **r, attrs=attrs
    )
    for name, (dims, data) in part.end_state().items():
        ds[name] = (dims, data, {"long_name": "state where this part ended (to resume from)"})
    return ds
