"""A long simulation written to a result file in parts as it runs, resumable after an interruption.

:func:`simulate_to_file` integrates Eq. (1), or the hybrid-coordinate equations of Eqs.
(105)-(123) with ``hybrid_small``, over evenly spaced save times in ``chunks`` parts. Every part
is one call of :func:`jaxtree.simulate` (:func:`jaxtree.simulate_hybrid`) padded to the same
number of save times, so one compiled program runs them all. A part is written atomically as
``RESULT.parts/part-NNNNN.npz`` (:class:`~jaxtree._src.io.result_files.ChunkedResult`) with the exact
state where it ended, and the next part starts from that state as written: a run that was
interrupted or killed reads back up to its last part, and ``resume=True`` continues it to the
answer of the uninterrupted run, bit for bit. At the end the parts are merged into RESULT with
an error estimate (the same run at 10x the tolerances) and, for a hybrid run, the estimated
error of the neglected modes.

The run's configuration (:func:`chunked_config`) is stored in every part; a resumed run must
have the same one. This is the engine of ``jaxtree simulate``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ..appendage.files import scene_appendages
from ..errors import SceneError
from ..hybrid import hybrid_model, simulate_hybrid
from ..hybrid.model import appendage_body
from ..hybrid.rhs import hybrid_rhs
from ..integration.autosolver import choose_for_field, choose_solver, save_points
from ..integration.core import default_tolerance
from ..integration.failures import KINDS, MESSAGES, SimulationError, failure_kind
from ..integration.radau import Radau5
from ..integration.simulate import simulate
from ..io.result_files import ChunkedResult
from ..io.results import body_positions, run_attrs, simulation_dataset
from ..linear.linearize import resolve_hinges
from ..linear.modes import ModalError
from ..vehicle.model import Model, State


class ChunkedRunError(ValueError):
    """A configuration that cannot run, or a resume that does not fit the parts on disk:
    `option` names the argument at fault (``"resume"``, ``"hybrid_small"``, ...; two joined by
    "/" where either may be), `reason` says what is wrong."""

    def __init__(self, option: str, reason: str):
        super().__init__(f"{option}: {reason}")
        self.option, self.reason = option, reason


class RunInterrupted(KeyboardInterrupt):
    """:func:`simulate_to_file` was interrupted (Ctrl-C, or a signal handler that raises
    KeyboardInterrupt): `dataset` is what it had written, merged into RESULT with attribute
    ``complete`` 0, or None where no part was written."""

    def __init__(self, dataset):
        super().__init__()
        self.dataset = dataset


@dataclasses.dataclass
class ChunkedRun:
    """What :func:`simulate_to_file` did."""

    dataset: Any  # the merged result (xarray.Dataset), as written to RESULT
    config: dict  # the run's configuration (chunked_config)
    hybrid: Any  # the HybridModel of a hybrid run, else None
    failure: str | None  # why the run stopped before t1 (its diagnosis); None where it reached t1
    compile_time: float | None  # seconds of the first part run here, compilation included

    @property
    def ok(self) -> bool:
        return self.failure is None


def solver_named(name: str):
    """A new solver of the class `name` (``"Radau5"`` for jaxtree's :class:`~jaxtree.Radau5`,
    else a diffrax solver class such as ``"Dopri8"``)."""
    return Radau5() if name == "Radau5" else getattr(diffrax, name)()


def parse_hinges(model: Model, spec) -> tuple[int, ...]:
    """The hinges that `spec` names, ascending: ``"all"`` (every hinge that is neither
    prescribed nor inert), text of comma-separated indices 1..n, body names and ranges ``a-b``,
    or a sequence of indices and names. Raises ``ValueError`` saying what is wrong."""
    if isinstance(spec, str) and spec.strip() == "none":
        return ()
    if isinstance(spec, str) and spec.strip() == "all":
        if not model.unknown_hinges:
            raise ValueError("the scene has no hinge that can be small")
        return tuple(model.unknown_hinges)
    if isinstance(spec, (int, np.integer)):
        spec = [spec]
    items: list[Any] = []
    for part in [p.strip() for p in spec.split(",")] if isinstance(spec, str) else list(spec):
        if isinstance(part, str) and "-" in part and all(s.strip().isdigit() for s in part.split("-", 1)):
            a, b = (int(s) for s in part.split("-", 1))
            items += list(range(a, b + 1))
        elif isinstance(part, str) and part.isdigit():
            items.append(int(part))
        elif part != "":
            items.append(part)
    if not items:
        raise ValueError("no hinge given")
    try:
        return resolve_hinges(model, items)
    except (ValueError, KeyError, TypeError) as e:
        msg = str(e.args[0]) if e.args else str(e)
        raise ValueError(msg.removeprefix("linearize: ")) from None


def chunked_config(
    model: Model,
    t1: float,
    *,
    t0: float = 0.0,
    points: int | None = None,
    chunks: int = 10,
    solver: str = "auto",
    rtol: float | None = None,
    atol: float | None = None,
    attitude: str = "quaternion",
    max_steps: int = 200_000,
    hybrid_small: str | Sequence[int | str] | None = None,
    modes: int | str | None = None,
    modes_tol: float | None = None,
    cutoff: float | None = None,
    spin: Sequence[float] | None = None,
    modal_damping: float | None = None,
) -> dict:
    """The configuration of a run of :func:`simulate_to_file`, as stored in each part.

    `points` evenly spaced save times from `t0` to `t1` (default: 20 per period of the fastest
    sprung hinge that still rings, at least 101) in `chunks` parts; `solver` a class name of
    diffrax or ``"Radau5"``, or ``"auto"`` (:func:`jaxtree.choose_solver` picks one for the scene);
    `rtol`, `atol` default to the dtype's (1e-9 in float64); `max_steps` is the step limit of
    each part. `hybrid_small` (text such as ``"1-4"`` or ``"all"``, see :func:`parse_hinges`, or a
    sequence of hinges) integrates the hybrid-coordinate equations with those hinges in modal
    coordinates: `modes` per substructure (a count, or ``"auto"``: the fewest whose neglected
    share is at most `modes_tol`, default 0.01; default all), up to the frequency `cutoff`,
    about the nominal spin `spin` (default the initial omega0) with `modal_damping`.
    """
    if not t1 > t0:
        raise ChunkedRunError("t1", f"{t1:g} is not after t0 = {t0:g}: a chunked run integrates forward in time")
    hybrid_options = dict(modes=modes, modes_tol=modes_tol, cutoff=cutoff, spin=spin, modal_damping=modal_damping)
    given = [k for k, v in hybrid_options.items() if v is not None]
    if hybrid_small is None and given:
        raise ChunkedRunError(given[0], "needs hybrid_small (the hinges in modal coordinates)")
    if modes_tol is not None and modes != "auto":
        raise ChunkedRunError("modes_tol", 'needs modes="auto"')
    tol = default_tolerance(jnp.result_type(model.mass))
    rtol, atol = rtol or tol, atol or tol
    why = "given"
    if solver == "auto" and hybrid_small is None:  # a hybrid run chooses on its own equations (_Runner)
        _, choice = choose_solver(model, t1, t0=t0, rtol=rtol, atol=atol)
        solver, why = choice.name, f"auto: {choice.reason}"
    cfg: dict[str, Any] = {
        "t0": float(t0),
        "t1": float(t1),
        "points": int(save_points(model, float(t1 - t0))[0] if points is None else points),
        "chunks": int(chunks),
        "solver": solver,
        "solver_choice": why,
        "rtol": float(rtol),
        "atol": float(atol),
        "attitude": attitude,
        "max_steps": int(max_steps),
    }
    if hybrid_small is not None:
        cfg.update(
            hybrid_small=hybrid_small if isinstance(hybrid_small, str) else ",".join(map(str, hybrid_small)),
            n_modes=None if modes is None else "auto" if modes == "auto" else int(modes),
            cutoff=None if cutoff is None else float(cutoff),
            modal_damping=None if modal_damping is None else float(modal_damping),
            spin=list(map(float, spin if spin is not None else model.initial.omega0)),
        )
        if modes == "auto":
            cfg["modes_tol"] = 1e-2 if modes_tol is None else float(modes_tol)
    return cfg


def simulate_to_file(
    path,
    model: Model,
    config: dict,
    *,
    resume: bool = False,
    error_estimate: bool = True,
    attrs: dict | None = None,
    log: Callable[[str], Any] | None = None,
    progress: Callable[[float, float], Any] | None = None,
) -> ChunkedRun:
    """Integrate `model` as `config` (:func:`chunked_config`) says, writing the result file
    `path` in parts as the run goes (see the module docstring); returns a :class:`ChunkedRun`.

    `resume` continues the interrupted run whose parts lie beside `path` (its configuration must
    be `config`); without it, parts of an interrupted run there are an error. `error_estimate`
    runs everything again at 10x the tolerances and stores the largest differences.
    `attrs` are added to each part's attributes (for instance the ``command``). `log(message)`
    hears what is about to happen (the start, the error estimate); `progress(done, total)`
    hears the simulated seconds done, before the first part and after each part.

    Raises :class:`ChunkedRunError` for a configuration that cannot run (before anything is
    written) and :class:`RunInterrupted` when interrupted, having merged the parts written.
    A run that fails numerically (a step limit, a singular motion) is no exception: the parts
    up to its stop are merged and :attr:`ChunkedRun.failure` says why.
    """
    run = _Chunked(path, model, config, resume)
    return run.go(error_estimate, attrs or {}, log or (lambda message: None), progress)


# ----------------------------------------------------------------------------- the run
def _chunk_bounds(points, chunks):
    """Save-grid index ranges [a, b] of the parts, and the rows of a padded part."""
    intervals = points - 1
    per = max(1, math.ceil(intervals / chunks))
    bounds = [(a, min(a + per, intervals)) for a in range(0, intervals, per)]
    return bounds, per + 1


class _Chunked:
    """One call of :func:`simulate_to_file`: the grid, the parts, the runner."""

    def __init__(self, path, model, cfg, resume):
        self.model, self.cfg = model, cfg
        self.writer = ChunkedResult(path)
        self.bounds, self.rows = _chunk_bounds(cfg["points"], cfg["chunks"])
        self.grid = np.linspace(cfg["t0"], cfg["t1"], cfg["points"])
        # the part datasets: read back when resuming, then as written
        self.parts = self._resumed_parts() if resume else self._no_parts()
        self.runner = _Runner(model, cfg)
        self.compile_time: float | None = None
        self.truncation = [0.0, 0.0, 0.0]  # hybrid runs: estimate, its quasi-static part, peak small angle

    def _no_parts(self):
        if self.writer.parts():
            raise ChunkedRunError(
                "resume",
                f"not asked for, but {self.writer.parts_dir} holds the parts of an interrupted run: "
                "continue it, or remove that folder",
            )
        return []

    def _resumed_parts(self):
        parts = self.writer.load_parts()
        if not parts:
            if self.writer.path.is_file():
                why = f"{self.writer.path} is a finished run (no parts of an interrupted run beside it)"
            else:
                why = f"no interrupted run to continue ({self.writer.parts_dir} does not exist)"
            raise ChunkedRunError("resume", why)
        saved = parts[0].attrs
        for key, value in run_attrs(self.model, self.cfg).items():
            have = saved.get(key)
            same = (
                np.allclose(np.asarray(have, float), np.asarray(value, float), rtol=0, atol=0)
                if isinstance(value, (int, float, list)) and have is not None
                else have == value
            )
            if not same:
                what = "the scene" if key == "scene" else key
                raise ChunkedRunError(
                    "resume",
                    f"{what} differs from the interrupted run "
                    f"({'changed' if key == 'scene' else f'{have!r} there, {value!r} here'})",
                )
        if int(parts[-1].attrs.get("result_code", 0)) != 0:
            raise ChunkedRunError(
                "resume", f"the interrupted run had failed at t = {parts[-1].attrs.get('t_final')}; nothing to continue"
            )
        return parts

    def go(self, error_estimate, attrs, log, progress):
        start, cfg = len(self.parts), self.cfg
        what = "hybrid equations" if self.runner.hybrid is not None else "Eq. (1)"
        log(
            f"{self.model.name or 'the model'}, {what}, t = {cfg['t0']:g} .. {cfg['t1']:g} s in "
            f"{len(self.bounds)} parts" + (f", resuming after part {start}" if start else "") + " (compiling first)"
        )
        try:
            failed = self._run_parts(start, {**run_attrs(self.model, cfg), **attrs, "complete": 0}, progress)
            extra: dict[str, Any] = {}
            if failed is None and error_estimate:
                log("error estimate (the run again at 10x the tolerances)")
                extra = self._error_estimate(self.writer.merged(parts=self.parts))
            if self.runner.hybrid is not None:
                extra.update(self._truncation_attrs(resumed=start > 0))
            # complete: the run ended (a failed run too: its result code says how)
            ds = self.writer.merge(complete=True, attrs=extra, parts=self.parts)
        except KeyboardInterrupt:
            raise RunInterrupted(self.writer.merge(complete=False, parts=self.parts)) from None
        failure = None if failed is None else failed.message or "the run failed"
        return ChunkedRun(ds, cfg, self.runner.hybrid, failure, self.compile_time)

    def _part_times(self, c):
        """The save times of part `c`, padded with its end time to the rows of every part."""
        a, b = self.bounds[c]
        return np.concatenate([self.grid[a : b + 1], np.full(self.rows - (b - a + 1), self.grid[b])])

    def _run_parts(self, start, attrs, progress):
        """Run and write the parts from `start` on; the part that failed, or None."""
        cfg, grid, total = self.cfg, self.grid, abs(self.cfg["t1"] - self.cfg["t0"])
        y0 = self.runner.initial() if start == 0 else self.runner.state_from(self.parts[-1])
        if progress is not None:
            progress(abs(grid[self.bounds[start - 1][1]] - cfg["t0"]) if start else 0.0, total)
        for c in range(start, len(self.bounds)):
            a, b = self.bounds[c]
            t_start = time.perf_counter()
            part = self.runner.run(self._part_times(c), y0, cfg["rtol"], cfg["atol"])
            if self.compile_time is None:
                self.compile_time = time.perf_counter() - t_start
            count = b - a + 1
            if part.kind is not None:
                count = int(np.sum(np.isfinite(np.asarray(part.rows(count)["ts"]))))
            pattrs = {
                **attrs,
                "chunk": c,
                "chunk_t0": float(grid[a]),
                "chunk_t1": float(grid[b]),
                "steps_accepted": part.steps[0],
                "steps_rejected": part.steps[1],
                "rhs_evaluations": part.steps[2],
                "result": "ok" if part.kind is None else part.kind,
                "result_code": 0 if part.kind is None else 1 + KINDS.index(part.kind),
                "t_final": part.t_final,
            }
            if isinstance(part, _HybridPart):
                self.truncation = [max(x, y) for x, y in zip(self.truncation, part.truncation)]
            ds = _part_dataset(self.runner, part, count, c > 0, pattrs)
            self.writer.write_part(c, ds)
            self.parts.append(ds)
            if part.kind is not None:
                return part
            # the next part starts from the state as written (float64 round-trips exactly), as a
            # resumed run does
            y0 = self.runner.state_from(ds)
            if progress is not None:
                progress(abs(grid[b] - cfg["t0"]), total)
        return None

    def _error_estimate(self, ds):
        """Differences between this run and the same run at 10x the tolerances, over all saved
        times: an estimate of the looser run's global error, hence an upper estimate of this
        run's (the error of an adaptive run falls with its tolerance)."""
        runner = self.runner
        y = runner.initial()
        runner.truncation_state = None
        rows: dict[str, list] = {"gamma": [], "gamma_dot": [], "omega0": [], "dcm": []}
        for c, (a, b) in enumerate(self.bounds):
            part = runner.run(self._part_times(c), y, 10 * self.cfg["rtol"], 10 * self.cfg["atol"])
            if part.kind is not None:
                return {"error_estimate": "unavailable: the run at 10x the tolerances failed"}
            r = part.rows(b - a + 1)
            for k in rows:
                rows[k].append(r[k][1:] if c else r[k])
            y = part.next_start()
        d = {k: float(np.max(np.abs(np.concatenate(v) - ds[k].values))) for k, v in rows.items()}
        return {
            "error_estimate_gamma": d["gamma"],
            "error_estimate_rates": max(d["gamma_dot"], d["omega0"]),
            "error_estimate_dcm": d["dcm"],
            "error_estimate": "max differences from the same run at 10x the tolerances (rad, rad/s, 1)",
        }

    def _truncation_attrs(self, resumed):
        estimate, static, peak = self.truncation
        return dict(
            truncation_error=estimate,
            truncation_error_static=static,
            truncation_peak_small_angle=peak,
            truncation_error_meaning="estimated largest error of the small angles from the neglected modes "
            "(their response to the unbalanced force of the hybrid motion; rad)"
            + (", parts before --resume not included" if resumed else ""),
        )


# ----------------------------------------------------------------------------- one part
class _Runner:
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
        return _HybridPart(sol, self.hybrid)


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


class _HybridPart:
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


def _part_dataset(runner, part, count, skip_first, attrs):
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
