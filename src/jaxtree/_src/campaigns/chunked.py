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

The run's configuration (:func:`~jaxtree._src.campaigns.chunked_config.chunked_config`) is
stored in every part; a resumed run must have the same one. A part is run and made a dataset
by :mod:`jaxtree._src.campaigns.chunked_parts`. This module is the driver: the parts' grid,
resuming, the merge, the error estimate. It is the engine of ``jaxtree simulate``.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..integration.failures import KINDS
from ..io.result_files import ChunkedResult
from ..io.results import run_attrs
from ..vehicle.model import Model
from .chunked_config import ChunkedRunError
from .chunked_parts import HybridPart, PartRunner, part_dataset


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
        self.runner = PartRunner(model, cfg)
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
            if isinstance(part, HybridPart):
                self.truncation = [max(x, y) for x, y in zip(self.truncation, part.truncation)]
            ds = part_dataset(self.runner, part, count, c > 0, pattrs)
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
