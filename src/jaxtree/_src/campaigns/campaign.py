"""Monte Carlo campaigns: many dispersed runs of Eq. (1) (:func:`jaxtree.simulate`) as one dataset.

:func:`monte_carlo` draws `n` dispersed vehicles from a user's ``sample(key, model) -> model``
(any array leaf: mass properties, hinge geometry, joint laws, load parameters, the initial
state), runs them in chunks (one ``jax.vmap`` per chunk, compiled once), and returns an
``xarray.Dataset`` with dimensions ``run``, ``time``, ``hinge``, ``axis`` (and ``quaternion``):
omega0, gamma, gamma_dot, the attitude of b_0 (Euler parameters), energy and angular momentum (the conserved
quantities of a vehicle without loads or damping: a check on every run), the dispersed
parameters themselves, and per run the integrator's named result, a diagnosis of failures and
the step count.

Failures do not raise. A member that fails (a singular Eq. 1 matrix such as gimbal lock, the
step limit, a non-finite state) gets its status and NaN histories; its chunk-mates are computed
by the same vmapped program and are untouched (a vmapped diffrax loop masks finished members).

Where the chunks run:

- in this process (default): each chunk is split over all local JAX devices with
  ``jax.shard_map`` (each device runs its own integration loop, so a device does not wait for
  the other's slowest member);
- on a Dask cluster (``client=distributed.Client(...)``): one task per chunk; every worker
  compiles the chunk program once and keeps it for the next chunks;
- ``out=`` a Zarr store (``*.zarr``) or a NetCDF file (``*.nc``): each finished chunk is written
  as it completes, and a rerun with the same `out` skips the chunks already there (a killed
  campaign resumes).

The cost of a vmapped chunk is its slowest member's: every member steps until the last one is
done. :func:`monte_carlo` reports the efficiency of each chunk (useful steps over the steps paid
for, ``sum(steps) / (size * max(steps))``) in the dataset's attributes and offers two
mitigations: ``order="pilot"`` runs every member over a short first part of the flight,
sorts the members by its step count and fills the chunks in that order (members of alike
cost run together), and ``dt=`` integrates with fixed steps (no waiting at all, at an error
the user then owns).
"""

from __future__ import annotations

import errno
import math
import os
import time as _time
from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.dynamics import batch_first_min
from ..integration.core import DEFAULT_MAX_STEPS, default_tolerance
from ..io.results import versions
from ..numerics import program_jit
from ..vehicle.model import Model
from .dataset import chunk_dataset, dispersed
from .members import Config, diagnose_failures, run_chunk, take
from .store import Store, fingerprint, template


def monte_carlo(
    model: Model,
    sample: Callable[[jax.Array, Model], Model],
    n: int,
    t1,
    *,
    key: jax.Array,
    saveat=101,
    rtol: float | None = None,
    atol: float | None = None,
    chunk_size: int | None = None,
    client: Any = None,
    out: str | os.PathLike | None = None,
    order: str | None = None,
    pilot_fraction: float = 0.1,
    dt: float | None = None,
    max_steps: int | None = None,
    attitude: str = "quaternion",
    devices: int | None = None,
    progress: bool = False,
    solver=None,
):
    """Run `n` dispersed copies of `model` from t = 0 to `t1` and collect them in a dataset.

    **Arguments:**

    - `model`: the nominal vehicle.
    - `sample`: ``sample(key, model) -> model``, one dispersed vehicle: any array leaf may
      change (mass properties, hinge axes and points, stiffness, damping, load parameters,
      ``model.initial``, the initial state of the run), the structure may not. It is vmapped
      over the members' keys, so it must be written in JAX (``jax.random``).
    - `n`: number of runs; `t1`: end time of every run.
    - `key`: a ``jax.random`` key; member i gets ``jax.random.split(key, n)[i]``, so its
      vehicle does not depend on the chunking, the ordering or where it runs. Nor do its
      numbers, to the bit, on one machine type: the chunk's program is compiled as one LLVM part
      and a device's lone member runs beside a copy, so that the chunk size and the number of
      devices change no member's arithmetic, as long as every device's share stays on the same
      side of :func:`batch_first_min` members (64, or 16 for trees of 48 hinges and more; below
      it a member's Eq. (1) is the single-member solve, from it on the batch-first recursion:
      the same to round-off, not to the bit; and below it, on several devices, a dense-method
      tree of 18 hinges or more runs in small groups for jaxlib's LAPACK kernels).
    - `saveat`: a number of evenly spaced save times from 0 to t1 (default 101) or an array
      of times.
    - `rtol`, `atol`: tolerances of :func:`jaxtree.simulate` (default
      :func:`jaxtree.default_tolerance` of the model's dtype).
    - `chunk_size`: members per vmapped chunk (default :func:`default_chunk`: on each device up to
      the members from which Eq. (1)'s batch-first recursion pays, 64 on a CPU, within a share of
      the memory); a chunk is compiled once
      and every chunk has this size (the last one is padded).
    - `client`: a Dask ``distributed.Client``: the chunks run as tasks on its workers (each
      worker compiles once). None (default): in this process.
    - `out`: a Zarr store (``*.zarr``) or NetCDF file (``*.nc``) written chunk by chunk as they
      finish, with the campaign's settings and the versions that ran it as attributes; a rerun
      with the same `out` skips the finished chunks (a different campaign in that place is
      refused). A disk that fills stops the campaign with an ``OSError`` that names the store;
      the chunks written before are kept for the rerun. With a store, finished chunks are not
      kept in memory, and a Zarr store's dataset is returned unread (its arrays read when
      used): a campaign larger than memory streams through it. A NetCDF file is assembled in
      memory at the end.
    - `order`: None (members in index order) or ``"pilot"``: a pilot run over the first
      `pilot_fraction` of the flight counts each member's steps, and the chunks are filled in
      that order, so that members of alike cost wait for each other.
    - `dt`: integrate with this fixed step (diffrax's ``ConstantStepSize``; tolerances unused):
      every member takes the same steps, so nobody waits.
    - `max_steps`: step limit per run (simulate's default; ``ceil(t1 / dt) + 1`` with `dt`).
    - `attitude`: the attitude variables integrated (see :func:`jaxtree.simulate`).
    - `devices`: local devices a chunk is split over (default all: on a CPU, one per core, which
      ``import jaxtree`` sets up when JAX has not started yet; ``JAXTREE_HOST_DEVICES`` or
      ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` set another count). On the CPU,
      where a device's members factor Eq. (1) with LAPACK (the dense method, fewer than
      :func:`batch_first_min` members a device), it runs them in vmapped groups small enough
      that jaxlib's batched LAPACK calls stay on the calling thread (larger batches are split
      over XLA's thread pool, and two device shards doing that at once can deadlock; see
      benchmarks/README.md); otherwise all at once.
    - `solver`: a diffrax solver for every member (default: :func:`jaxtree.simulate`'s default
      for a batch, ``diffrax.Dopri8``), e.g. :class:`jaxtree.Radau5` for stiff vehicles. An
      implicit solver's members run one after another on each device rather than vmapped: in
      lockstep every member would pay a Jacobian and two factorizations at every step, and wait
      for the slowest member's steps.
    - `progress`: print one line per finished chunk: its time, the chunks run so far and an
      estimate of the time left (from the chunks after the first, which compiles).

    **Returns:** an ``xarray.Dataset`` with dimensions ``run`` (member index), ``time``,
    ``hinge`` (1..n), ``axis`` (1..3), ``quaternion`` (0..3) and ``body``: ``omega0``,
    ``gamma``, ``gamma_dot``, ``attitude`` (Euler parameters of b_0), ``energy``,
    ``angular_momentum`` (and ``hold_torque`` with prescribed hinges), NaN for failed runs;
    per run ``status`` (diffrax's result, named: ``"successful"``, ``"max_steps_reached"``,
    ``"dt_min_reached"``, ..., or ``"not_started"`` for a start that cannot be integrated), ``failure`` (jaxtree's diagnosis, one of :data:`FAILURES`:
    ``"singular_matrix"``, ``"nonfinite_state"``, ``"max_steps"``, ...; ``""`` for a success),
    ``steps``, ``rejected``, ``rhs_evaluations``, ``t_final``; ``param.<leaf>`` for every
    leaf that the dispersion changed (e.g. ``param.inertia``, ``param.initial.omega0``).
    Attributes: the settings, the versions of jaxtree and its libraries, the wall time, and the chunks' efficiencies
    (``sum(steps) / (size * max(steps))``: the share of the vmapped work that was not spent
    waiting for a chunk's slowest member).
    """
    start = _time.perf_counter()
    s = _settings(model, sample, n, t1, saveat, rtol, atol, chunk_size, order, dt, max_steps, attitude, devices)
    models = _draw(model, sample, s.n, key)
    t_pilot = s.t1 * float(pilot_fraction) if order == "pilot" else None
    if solver is not None and not isinstance(solver, dfx.AbstractSolver):
        raise TypeError(f"monte_carlo: solver must be a diffrax solver (e.g. jaxtree.Radau5()), got {solver!r}")
    cfg = Config(len(s.ts), s.max_steps, attitude, s.dt, t_pilot, solver)
    store = None
    settings = {
        "model": model.name,
        "t1": s.t1,
        "rtol": s.rtol,
        "atol": s.atol,
        "n": s.n,
        "chunk_size": s.chunk_size,
        "chunks": s.n_chunks,
        "max_steps": s.max_steps,
        "order": order or "index",
        "fixed_step": s.dt if s.dt is not None else "none",
        "attitude": str(attitude),
        "solver": "default" if solver is None else type(solver).__name__,
        "dtype": jnp.dtype(s.dtype).name,
        "where": "dask" if client is not None else f"in-process ({jax.default_backend()})",
        "devices": len(jax.local_devices()) if devices is None else int(devices),
    }
    if out is not None:
        campaign_id = fingerprint(models, s.ts, s.t1, s.rtol, s.atol, cfg, s.chunk_size)
        store = Store(out, campaign_id, s.n_chunks, {**settings, **versions()})
    runs = _Chunks(model, models, s, cfg, client=client, devices=devices, store=store, progress=progress)
    finished = set() if store is None else store.done()
    pilot_s = runs.pilot(finished) if order == "pilot" else 0.0
    runs.run([k for k in range(s.n_chunks) if k not in finished])
    ds = runs.dataset()
    ds.attrs.update(
        {
            **settings,
            **versions(),
            "chunks_run": len(runs.stats),
            "chunk_efficiency": [runs.stats[k]["efficiency"] for k in sorted(runs.stats)],
            "chunk_wall_s": [runs.stats[k]["wall_s"] for k in sorted(runs.stats)],
            "pilot_s": pilot_s,
            "wall_s": _time.perf_counter() - start,
        }
    )
    ds.attrs.pop("jaxtree_campaign", None)
    return ds


class _Settings(NamedTuple):
    """A campaign's checked settings (:func:`_settings`)."""

    n: int
    t1: float
    ts: np.ndarray
    rtol: float
    atol: float
    dt: float | None
    max_steps: int
    chunk_size: int
    n_chunks: int
    dtype: Any


def _settings(
    model, sample, n, t1, saveat, rtol, atol, chunk_size, order, dt, max_steps, attitude, devices=None
) -> _Settings:
    """monte_carlo's arguments checked, with their defaults filled in."""

    n = int(n)
    if n < 1:
        raise ValueError(f"monte_carlo: n must be at least 1, got {n}")
    if not callable(sample):
        raise TypeError(f"monte_carlo: sample must be a function (key, model) -> model, got {sample!r}")
    if order not in (None, "pilot"):
        raise ValueError(f"monte_carlo: order must be None or 'pilot', got {order!r}")
    dtype = jnp.result_type(model.mass)
    rtol = default_tolerance(dtype) if rtol is None else float(rtol)
    atol = default_tolerance(dtype) if atol is None else float(atol)
    t1 = float(t1)
    if not np.isfinite(t1) or t1 <= 0:
        raise ValueError(f"monte_carlo: t1 must be finite and positive, got {t1}")
    if isinstance(saveat, (int, np.integer)) and not isinstance(saveat, bool):
        if saveat < 2:
            raise ValueError(f"monte_carlo: saveat needs at least 2 save points, got {saveat}")
        ts = np.linspace(0.0, t1, int(saveat))
    else:
        ts = np.asarray(saveat, float)
        if ts.ndim != 1 or ts.size < 1 or np.any(np.diff(ts) < 0) or ts[0] < 0 or ts[-1] > t1:
            raise ValueError("monte_carlo: saveat must be a count or increasing times within [0, t1]")
    if dt is not None:
        dt = float(dt)
        if not dt > 0:
            raise ValueError(f"monte_carlo: dt must be positive, got {dt}")
        max_steps = int(math.ceil(t1 / dt)) + 1 if max_steps is None else int(max_steps)
    max_steps = DEFAULT_MAX_STEPS if max_steps is None else int(max_steps)
    chunk_size = default_chunk(model, n, len(ts), devices) if chunk_size is None else int(chunk_size)
    if chunk_size < 1:
        raise ValueError(f"monte_carlo: chunk_size must be at least 1, got {chunk_size}")
    if isinstance(attitude, str) is False:
        raise TypeError("monte_carlo: attitude must be a name ('quaternion', 'dcm', 'euler123')")
    return _Settings(n, t1, ts, rtol, atol, dt, max_steps, chunk_size, -(-n // chunk_size), dtype)


# A chunk's members per device by default: the batch-first recursion of Eq. (1) pays from
# batch_first_min() members on (its program's cost per call amortized over the members), and more
# gained nothing measurable while the first chunk (compile and run) and the wait for a chunk's
# slowest member grew: 512 fig4_free runs on two devices in chunks of 128 / 256 / 512, 6.55 / 6.49 /
# 7.49 s, first calls 17.4 / 19.2 / 23.2 s; in chunks of 64 (32 a device, under the threshold) 2.4x
# slower (benchmarks/FINDINGS.md, "Chunks sized by cost"). A chunk's histories stay within
# CHUNK_MEMORY of the machine's memory (each member's saved states held about three times over: the
# solve's saves, its histories, the host's copy).
CHUNK_MEMORY = 1 / 16


def default_chunk(model: Model, n: int, saves: int, devices: int | None = None) -> int:
    """The default chunk size of a campaign of `n` members with `saves` save times: per device
    (`devices`, default all local ones) up to :func:`batch_first_min` members, fewer where a
    chunk's histories would pass :data:`CHUNK_MEMORY` of the physical memory; at most `n`
    rounded up to the devices."""
    devices = len(jax.local_devices()) if devices is None else max(1, int(devices))
    per_device = min(-(-n // devices), batch_first_min())
    itemsize = jnp.dtype(jnp.result_type(model.mass)).itemsize
    member = 3 * saves * (2 * model.n + 11 + len(model.prescribed)) * itemsize  # bytes of histories
    try:
        memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        memory = 8 * 1024**3
    per_device = max(1, min(per_device, int(CHUNK_MEMORY * memory / (member * devices))))
    return per_device * devices


@program_jit(light=True)
def _sampled(sample, n: int, key, model: Model):
    """``sample`` over the members' keys, compiled as one program (run eagerly, each random
    operation of a sample compiles on its own: 0.8 s of a 64-run campaign's first call), at XLA's
    level 0: the draws run once, and their random bits' rounds compiled at the default level took
    0.56 s of a 64-run campaign's first call (benchmarks/FINDINGS.md)."""
    return eqx.filter_vmap(sample, in_axes=(0, None))(jax.random.split(key, n), model)


def _draw(model: Model, sample, n: int, key):
    """The `n` dispersed vehicles: ``sample`` vmapped over the members' keys, every array leaf
    as a numpy array with a leading run axis (a leaf the sample did not touch repeated)."""
    models = _sampled(sample, n, key, model)
    if jax.tree_util.tree_structure(jax.tree_util.tree_map(lambda x: None, models)) != jax.tree_util.tree_structure(
        jax.tree_util.tree_map(lambda x: None, model)
    ):
        raise ValueError(
            "monte_carlo: sample(key, model) must return a model of the same structure (same tree, "
            "joints, prescription and loads); only array values may change"
        )
    models = jax.tree_util.tree_map(lambda x: np.asarray(x) if eqx.is_array(x) else x, models)
    return jax.tree_util.tree_map(
        lambda x: np.broadcast_to(x, (n,) + x.shape).copy() if eqx.is_array(x) and x.shape[:1] != (n,) else x, models
    )


class _Chunks:
    """A campaign's chunks: the members each one holds (in the order of the members, by index or
    by the pilot's steps), where they run, and what they gave (datasets, efficiencies, the store)."""

    def __init__(self, model: Model, models, s: _Settings, cfg: Config, *, client, devices, store, progress):
        self.model, self.models, self.s, self.cfg = model, models, s, cfg
        self.client, self.devices, self.store, self.progress = client, devices, store, progress
        self.n_chunks = s.n_chunks
        self.params = dispersed(models, s.n)
        self.order = np.arange(s.n)
        self.template = None
        self.results: dict[int, Any] = {}
        self.stats: dict[int, dict] = {}
        self.started = _time.perf_counter()
        self.todo = s.n_chunks

    def members(self, k):
        """Chunk k's members, and the same padded to the chunk size (with its first member)."""
        size = self.s.chunk_size
        idx = self.order[k * size : (k + 1) * size]
        return idx, np.concatenate([idx, np.full(size - len(idx), idx[0])])

    def submit(self, k, pilot=False):
        """Run chunk k (the pilot's part of the flight with `pilot`): its outputs, or a Dask future."""
        s = self.s
        args = (take(self.models, self.members(k)[1]), s.ts, s.t1, s.rtol, s.atol, self.cfg, pilot, self.devices)
        if self.client is None:
            return run_chunk(*args)
        return self.client.submit(run_chunk, *args, pure=False)

    def pilot(self, finished) -> float:
        """order="pilot": the members ordered by the steps of the first part of the flight (unless
        every chunk is done already); the pilot's wall time."""
        if len(finished) >= self.n_chunks:
            return 0.0
        t = _time.perf_counter()
        jobs = [self.submit(k, pilot=True) for k in range(self.n_chunks)]
        if self.client is not None:
            jobs = self.client.gather(jobs)
        steps = np.concatenate([np.asarray(j["steps"])[: len(self.members(k)[0])] for k, j in enumerate(jobs)])
        self.order = np.argsort(steps, kind="stable")
        return _time.perf_counter() - t

    def run(self, todo) -> None:
        """Run the chunks `todo`, each finished as it completes."""
        self.started, self.todo = _time.perf_counter(), len(todo)
        if self.client is None:
            for k in todo:
                t = _time.perf_counter()
                res = self.submit(k)
                self.finish(k, res, _time.perf_counter() - t)
            return
        from distributed import as_completed

        t = _time.perf_counter()
        futures = {self.submit(k): k for k in todo}
        for future in as_completed(list(futures)):
            self.finish(futures[future], future.result(), _time.perf_counter() - t)

    def finish(self, k, res, wall) -> None:
        """Chunk k's outputs as a dataset (its failures diagnosed), kept and written to the store."""
        s = self.s
        idx, _ = self.members(k)
        res = jax.tree_util.tree_map(lambda v: np.array(v)[: len(idx)], res)
        diagnose_failures(res, take(self.models, idx), self.model)
        ds = chunk_dataset(
            res,
            np.arange(k * s.chunk_size, k * s.chunk_size + len(idx)),
            {name: x[idx] for name, x in self.params.items()},
            s.ts,
            self.model,
        )
        ds = ds.assign(member=(("run",), idx.astype(np.int64)))
        steps = res["steps"].astype(float)
        self.stats[k] = dict(efficiency=float(steps.sum() / (s.chunk_size * max(steps.max(), 1))), wall_s=wall)
        if self.store is not None:
            if self.template is None:
                self.template = template(ds, s.n)
            try:
                self.store.write(k, ds, self.template)
            except OSError as e:
                if e.errno not in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
                    raise
                raise OSError(
                    e.errno,
                    f"monte_carlo: no space left for the store {self.store.path!r} while writing chunk "
                    f"{k + 1} of {self.n_chunks}; the chunks written before it are kept: "
                    "free some space and run the same call again to resume from them",
                ) from e
        else:  # (with a store the chunks are read back from it: memory bounded by a chunk)
            self.results[k] = ds
        if self.progress:
            print(self.progress_line(k, wall), flush=True)

    def progress_line(self, k, wall) -> str:
        """One line on chunk k: its time and efficiency, the chunks run so far in this call, and the
        time left, estimated from the chunks after the first (the first compiles: before a second
        chunk the estimate is an upper bound)."""
        done, left = len(self.stats), self.todo - len(self.stats)
        elapsed = _time.perf_counter() - self.started
        line = (
            f"monte_carlo: chunk {k + 1}/{self.n_chunks} done in {wall:.2f} s "
            f"(efficiency {self.stats[k]['efficiency']:.2f}); {done}/{self.todo} run in {elapsed:.1f} s"
        )
        if left <= 0:
            return line
        if done == 1:
            return f"{line}, at most {elapsed * left:.0f} s left"
        first = self.stats[min(self.stats)]["wall_s"] if self.client is None else 0.0
        return f"{line}, about {(elapsed - first) / (done - 1) * left:.0f} s left"

    def dataset(self):
        """The campaign's dataset, runs by member index: the store's, or the chunks' concatenated."""
        import xarray as xr

        if self.store is not None:
            ds = self.store.read()
        else:
            ds = xr.concat(
                [self.results[k] for k in sorted(self.results)],
                dim="run",
                data_vars="minimal",
                coords="minimal",
                compat="override",
                join="override",
            )
        ds = ds.assign_coords(run=np.asarray(ds["member"].values, np.int64)).drop_vars("member").sortby("run")
        return ds.drop_vars([v for v in list(ds.data_vars) if v == "chunk_done"])
