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
import functools
import hashlib
import json
import math
import os
import shutil
import time as _time
from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.attitude import dcm_to_quaternion
from ..equations.dynamics import SINGULAR_CONDITION, batch_first_min
from ..integration.core import DEFAULT_MAX_STEPS, default_tolerance
from ..integration.failures import Failure, condition_jit
from ..integration.simulate import simulate
from ..io.files import atomic_write
from ..io.results import clean_attrs, versions
from ..numerics import program_jit
from ..vehicle.model import Model, State

# jaxtree's diagnosis of a failed member ("" for a run that reached t1)
FAILURES = (
    "",
    "max_steps",
    "dt_min",
    "singular_attitude",
    "other",
    "nonfinite_start",
    "singular_matrix",
    "nonfinite_state",
)


@functools.cache
def _result_names() -> tuple[str, ...]:
    """diffrax's result names by index (``RESULTS.max_steps_reached._value`` -> its name)."""
    items = dfx.RESULTS._name_to_item
    names = {int(item._value): name for name, item in items.items()}
    return tuple(names.get(i, f"result_{i}") for i in range(max(names) + 1))


# ----------------------------------------------------------------------------- one chunk
class _Config(NamedTuple):
    """Static choices of a campaign (hashable: part of the compilation key)."""

    n_save: int
    max_steps: int
    attitude: str
    dt: float | None  # fixed step, or None for the adaptive default of simulate
    t_pilot: float | None  # the pilot run's end (order="pilot"), or None


def _member(model: Model, ts, t1, rtol, atol, cfg: _Config):
    """One member: its histories and per-run figures (a dict of arrays)."""

    kw: dict[str, Any] = {}
    if cfg.dt is not None:
        kw = dict(stepsize_controller=dfx.ConstantStepSize(), dt0=jnp.asarray(cfg.dt, ts.dtype))
    sol = simulate(
        model,
        t1,
        y0=model.initial,
        saveat=ts,
        rtol=rtol,
        atol=atol,
        max_steps=cfg.max_steps,
        attitude=cfg.attitude,
        throw=False,
        **kw,
    )
    hist = dict(
        omega0=sol.omega0,
        gamma=sol.gamma,
        gamma_dot=sol.gamma_dot,
        attitude=dcm_to_quaternion(sol.dcm),
        energy=sol.energy,
        angular_momentum=sol.angular_momentum,
    )
    if model.prescribed:
        hist["hold_torque"] = sol.hold_torque
    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(v)) for v in hist.values()]))
    code = sol.failure  # an integration.failures.Failure code (the first five of FAILURES)
    state_ok = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in sol.final]))
    diagnosis = jnp.where(
        code > 0,
        jnp.where((code == FAILURES.index("nonfinite_start")) | state_ok, code, FAILURES.index("nonfinite_state")),
        jnp.where(finite, 0, FAILURES.index("nonfinite_state")),
    )
    ok = diagnosis == 0
    hist = {k: jnp.where(ok, v, jnp.nan) for k, v in hist.items()}
    # (whether a failed run's Eq. (1) matrix is singular where it stopped is decided on the host,
    # for the failed members only: see _diagnose_failures)
    # a start that cannot be integrated (not finite, or Eq. 1 singular there) never ran: its
    # integrator result is that of the vehicle at rest simulate integrated in its place

    started = (code != int(Failure.NONFINITE_START)) & (code != int(Failure.SINGULAR_START))
    return dict(
        hist,
        result=jnp.where(started, sol.result._value, -1),
        diagnosis=diagnosis,
        steps=sol.stats["num_steps"],
        rejected=sol.stats["num_rejected_steps"],
        rhs_evaluations=sol.stats["rhs_evaluations"],
        t_final=sol.t_final,
        final=tuple(sol.final),
    )


def _diagnose_failures(out: dict, models, model: Model) -> None:
    """Failed members that stopped at a finite state (step limit, step-size collapse): 'singular_matrix'
    when Eq. (1)'s matrix is singular or nearly so there (gimbal lock, a vanishing mass). One
    eager evaluation per failed member, on the host (batched LAPACK calls in the vmapped chunk
    would cost every member a decomposition, and can deadlock on the CPU, see _sharded)."""

    code = out["diagnosis"]
    suspects = np.flatnonzero(np.isin(code, [FAILURES.index(k) for k in ("max_steps", "dt_min", "other")]))
    for i in suspects:
        member = _take(models, i)
        state = State(*(np.asarray(x)[i] for x in out["final"]))
        cond, _ = condition_jit(member, state, np.asarray(out["t_final"])[i])
        cond = float(cond)
        if not np.isfinite(cond) or cond > SINGULAR_CONDITION:
            code[i] = FAILURES.index("singular_matrix")


def _pilot_member(model: Model, ts, t1, rtol, atol, cfg: _Config):
    """The pilot: steps of the first part of the flight (to order members by cost)."""

    sol = simulate(
        model,
        cfg.t_pilot,
        y0=model.initial,
        saveat=2,
        rtol=rtol,
        atol=atol,
        max_steps=cfg.max_steps,
        attitude=cfg.attitude,
        throw=False,
    )
    return dict(steps=sol.stats["num_steps"])


# jaxlib's CPU LAPACK kernels (potrf, trsm, syevd, ...) split a batch of matrices over XLA's
# intra-op thread pool when it is worth more than about 2e5 flops (jax::ParallelBatchMap), and
# block the calling pool thread until the parts are done. The executions of a program's device
# shards run on that same pool: two shards that both split a batch can hold every pool thread
# while their parts wait behind each other, and the process hangs (benchmarks/README.md has the
# reproduction). Below that size the kernel runs inline. So on the CPU each shard runs its
# members in vmapped groups small enough for Eq. (1)'s factorization to stay inline.
_LAPACK_INLINE_FLOPS = 2e5


def _cpu_group(model: Model) -> int:
    """Members per vmapped group on a CPU shard: the batched Cholesky of Eq. (1) (order n + 4
    with its border) stays under jaxlib's threshold for splitting a batch over the pool."""
    order = model.n + 4
    return max(1, int(_LAPACK_INLINE_FLOPS / (order**3 / 3.0)) - 1)


def _sharded(fn, n_devices, group):
    """`fn` over a batch (vmapped), split over the first `n_devices` local devices when more than
    one (``shard_map``: each device runs its own integration loop, so a device does not wait for
    the other's slowest member); `group` members at a time per device (None: all at once)."""
    one = lambda m, ts, t1, rtol, atol, cfg: fn(m, ts, t1, rtol, atol, cfg)

    def batched(models, ts, t1, rtol, atol, cfg):
        size = jax.tree_util.tree_leaves(models)[0].shape[0]
        if group is None or group >= size:
            return jax.vmap(one, in_axes=(0, None, None, None, None, None))(models, ts, t1, rtol, atol, cfg)
        return jax.lax.map(lambda m: one(m, ts, t1, rtol, atol, cfg), models, batch_size=group)

    if n_devices <= 1:
        return batched
    from jax.sharding import PartitionSpec as P

    mesh = _mesh(n_devices)

    def run(models, ts, t1, rtol, atol, cfg):
        dynamic, static = eqx.partition(models, eqx.is_array)
        inner = lambda d, ts, t1, rtol, atol: batched(eqx.combine(d, static), ts, t1, rtol, atol, cfg)
        return jax.shard_map(
            inner, mesh=mesh, in_specs=(P("run"), P(), P(), P(), P()), out_specs=P("run"), check_vma=False
        )(dynamic, ts, t1, rtol, atol)

    return run


def _mesh(n_devices: int):
    """The first `n_devices` local devices as a mesh with one axis, ``"run"``."""
    from jax.sharding import Mesh

    return Mesh(np.asarray(jax.local_devices()[:n_devices]), ("run",))


@program_jit
def _run_chunk_jit(models, ts, t1, rtol, atol, cfg: _Config, n_devices: int, group, pilot: bool):
    return _sharded(_pilot_member if pilot else _member, n_devices, group)(models, ts, t1, rtol, atol, cfg)


def run_chunk(models, ts, t1, rtol, atol, cfg: _Config, pilot: bool = False, devices: int | None = None):
    """Run one chunk (a batch of models with a leading run axis) in this process: numpy outputs.

    Public for Dask workers (:func:`monte_carlo` submits it). The chunk is split over `devices`
    local devices (default all of them; fewer if the chunk does not divide evenly)."""
    leaves = [x for x in jax.tree_util.tree_leaves(models) if eqx.is_array(x)]
    size = leaves[0].shape[0]
    devices = len(jax.local_devices()) if devices is None else int(devices)
    devices = max(1, min(devices, len(jax.local_devices())))
    while size % devices:
        devices -= 1
    group = None
    if devices > 1 and jax.default_backend() == "cpu":
        group = _cpu_group(models)
    dtype = jnp.result_type(models.mass)
    if devices > 1:  # each device's members placed on it (a sharded program is not kept on disk)
        from jax.sharding import NamedSharding
        from jax.sharding import PartitionSpec as P

        dynamic, static = eqx.partition(models, eqx.is_array)
        models = eqx.combine(jax.device_put(dynamic, NamedSharding(_mesh(devices), P("run"))), static)
    out = _run_chunk_jit(
        models,
        jnp.asarray(ts, dtype),
        jnp.asarray(t1, dtype),
        jnp.asarray(rtol, dtype),
        jnp.asarray(atol, dtype),
        cfg,
        devices,
        group,
        pilot,
    )
    return jax.tree_util.tree_map(np.asarray, out)


# ----------------------------------------------------------------------------- the dataset
_LEAF_DIMS = {
    "mass": ("body",),
    "inertia": ("body", "axis", "axis_j"),
    "axis": ("hinge", "axis"),
    "hinge_on_parent": ("hinge", "axis"),
    "hinge_on_body": ("hinge", "axis"),
    "stiffness": ("hinge",),
    "damping": ("hinge",),
    "initial.dcm": ("axis", "axis_j"),
    "initial.omega0": ("axis",),
    "initial.gamma": ("hinge",),
    "initial.gamma_dot": ("hinge",),
}
_HISTORY_DIMS = {
    "omega0": ("time", "axis"),
    "gamma": ("time", "hinge"),
    "gamma_dot": ("time", "hinge"),
    "attitude": ("time", "quaternion"),
    "energy": ("time",),
    "angular_momentum": ("time", "axis"),
    "hold_torque": ("time", "prescribed"),
}
_ATTRS = {
    "omega0": ("rad/s", "angular velocity of b_0 in {b^0} components"),
    "gamma": ("rad", "hinge angles"),
    "gamma_dot": ("rad/s", "hinge rates"),
    "attitude": ("", "Euler parameters (q0 >= 0) of C, {b^0} = C {i} (Def. 9)"),
    "energy": ("J", "kinetic energy about the system mass center plus hinge-spring energy"),
    "angular_momentum": ("N m s", "angular momentum about the system mass center, inertial components"),
    "hold_torque": ("N m", "torque holding each prescribed hinge (Sec. II B)"),
    "status": ("", "diffrax's result of the run, named"),
    "failure": ("", "jaxtree's diagnosis of a failed run ('' when it reached t1)"),
    "steps": ("", "solver steps (accepted and rejected)"),
    "rejected": ("", "rejected solver steps"),
    "rhs_evaluations": ("", "evaluations of Eq. (1)"),
    "t_final": ("s", "where the run ended (t1, or the time of a failure)"),
}


def _leaf_name(path) -> str:
    parts = []
    for p in path:
        name = getattr(p, "name", None) or getattr(p, "key", None)
        parts.append(str(name if name is not None else getattr(p, "idx", p)))
    return ".".join(parts)


def _dispersed(models, n) -> dict[str, np.ndarray]:
    """The array leaves of the batch of models that differ between runs, by dotted name."""
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(models):
        if not eqx.is_array(leaf) or not jnp.issubdtype(leaf.dtype, jnp.number):
            continue
        x = np.asarray(leaf)
        if x.shape[:1] == (n,) and n > 1 and np.any(x != x[:1]):
            out[_leaf_name(path)] = x
    return out


def _chunk_dataset(out: dict, runs: np.ndarray, params: dict, ts, model: Model):
    """An xarray Dataset of one chunk's outputs (runs `runs`)."""
    import xarray as xr

    names = _result_names()
    data = {}
    for k, dims in _HISTORY_DIMS.items():
        if k in out:
            data[k] = (("run",) + dims, out[k])
    data["status"] = (
        ("run",),
        np.asarray([names[int(i)] if i >= 0 else "not_started" for i in out["result"]], dtype="U32"),
    )
    data["failure"] = (("run",), np.asarray([FAILURES[int(i)] for i in out["diagnosis"]], dtype="U32"))
    for k in ("steps", "rejected", "rhs_evaluations"):
        data[k] = (("run",), np.asarray(out[k], np.int64))
    data["t_final"] = (("run",), np.asarray(out["t_final"], float))
    for name, x in params.items():
        dims = _LEAF_DIMS.get(name, tuple(f"{name}_{i}" for i in range(x.ndim - 1)))
        data[f"param.{name}"] = (("run",) + dims, x)
    coords = {
        "run": runs,
        "time": np.asarray(ts, float),
        "hinge": np.arange(1, model.n + 1),
        "axis": np.arange(1, 4),
        "quaternion": np.arange(4),
        "body": np.arange(model.n + 1),
    }
    if model.prescribed:
        coords["prescribed"] = np.asarray(model.prescribed)
    ds = xr.Dataset(data, coords=coords)
    for k, (unit, text) in _ATTRS.items():
        if k in ds:
            ds[k].attrs.update(units=unit, long_name=text)
    return ds


# ----------------------------------------------------------------------------- stores
class _Store:
    """Where finished chunks go: a Zarr store (one region per chunk, a ``done`` flag per chunk
    written after its data) or a NetCDF file (one part file per chunk, written atomically, and
    the whole file assembled atomically at the end). `fingerprint` identifies the campaign: a
    store made by a different one is refused."""

    def __init__(self, path, fingerprint: str, n_chunks: int, attrs: dict | None = None):
        self.path = os.fspath(path)
        self.attrs = clean_attrs(attrs or {})  # the campaign's settings and versions, kept in the file
        self.zarr = self.path.rstrip("/").endswith(".zarr")
        self.fingerprint = fingerprint
        self.n_chunks = n_chunks
        self.parts = self.path + ".parts"
        if not self.zarr and not self.path.endswith((".nc", ".nc4", ".netcdf")):
            raise ValueError(f"out: expected a Zarr store (*.zarr) or a NetCDF file (*.nc), got {self.path!r}")

    def _check(self, attrs):
        got = attrs.get("jaxtree_campaign")
        if got is not None and got != self.fingerprint:
            raise ValueError(
                f"out: {self.path!r} holds a different campaign (another model, sample, n, key, times, "
                f"tolerances or chunk size); remove it or choose another path"
            )

    def done(self) -> set[int]:
        if self.zarr:
            if not os.path.exists(self.path):
                return set()
            import zarr

            group = zarr.open_group(self.path, mode="r")
            self._check(dict(group.attrs))
            if "chunk_done" not in group:
                return set()
            chunk_done = group["chunk_done"]
            assert isinstance(chunk_done, zarr.Array), "write() makes chunk_done an array"
            return {int(i) for i in np.flatnonzero(np.asarray(chunk_done[:]))}
        if os.path.exists(self.path):
            import xarray as xr

            with xr.open_dataset(self.path) as ds:
                self._check(ds.attrs)
            return set(range(self.n_chunks))
        if not os.path.isdir(self.parts):
            return set()
        meta = os.path.join(self.parts, "campaign.json")
        if os.path.exists(meta):
            with open(meta) as fh:
                self._check(json.load(fh))
        return {int(f[6:12]) for f in os.listdir(self.parts) if f.startswith("chunk_") and f.endswith(".nc")}

    def write(self, index: int, ds, template) -> None:
        if self.zarr:
            import zarr

            if not os.path.exists(self.path):
                tmp = self.path + f".tmp{os.getpid()}"
                shutil.rmtree(tmp, ignore_errors=True)
                template = template.assign(chunk_done=(("chunk",), np.zeros(self.n_chunks, bool)))
                template.attrs.update(self.attrs)
                template.attrs["jaxtree_campaign"] = self.fingerprint
                template.to_zarr(tmp, mode="w", compute=False, consolidated=False, zarr_format=2)
                os.replace(tmp, self.path)
            region = {"run": slice(int(ds.run[0]), int(ds.run[-1]) + 1)}
            ds.drop_vars([v for v in ds.coords if "run" not in ds[v].dims]).to_zarr(
                self.path, region=region, consolidated=False
            )
            chunk_done = zarr.open_group(self.path, mode="r+")["chunk_done"]
            assert isinstance(chunk_done, zarr.Array), "made an array with the template above"
            chunk_done[index] = True
            return

        os.makedirs(self.parts, exist_ok=True)
        meta = os.path.join(self.parts, "campaign.json")
        if not os.path.exists(meta):
            with atomic_write(meta, "w") as fh:
                json.dump({"jaxtree_campaign": self.fingerprint}, fh)
        final = os.path.join(self.parts, f"chunk_{index:06d}.nc")
        tmp = final + f".tmp{os.getpid()}"
        ds.to_netcdf(tmp)
        os.replace(tmp, final)

    def read(self):
        import xarray as xr

        if self.zarr:  # read lazily: a campaign larger than memory stays on disk until read
            ds = xr.open_zarr(self.path, consolidated=False, chunks=None)
            return ds.drop_vars("chunk_done")
        if os.path.exists(self.path):
            return xr.load_dataset(self.path)
        files = sorted(
            os.path.join(self.parts, f) for f in os.listdir(self.parts) if f.startswith("chunk_") and f.endswith(".nc")
        )
        ds = xr.concat(
            [xr.load_dataset(f) for f in files],
            dim="run",
            data_vars="minimal",
            coords="minimal",
            compat="override",
            join="override",
        )
        tmp = self.path + f".tmp{os.getpid()}"
        ds.attrs.update(self.attrs)
        ds.attrs["jaxtree_campaign"] = self.fingerprint
        ds.to_netcdf(tmp)
        os.replace(tmp, self.path)
        shutil.rmtree(self.parts, ignore_errors=True)
        return ds


def _fingerprint(models, ts, t1, rtol, atol, cfg, chunk_size) -> str:
    h = hashlib.sha256()
    for leaf in jax.tree_util.tree_leaves(models):
        if eqx.is_array(leaf):
            h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    h.update(
        repr(
            (
                np.asarray(ts).tolist(),
                float(t1),
                float(rtol),
                float(atol),
                tuple(cfg),
                chunk_size,
                str(jax.tree_util.tree_structure(models)),
            )
        ).encode()
    )
    return h.hexdigest()[:32]


# ----------------------------------------------------------------------------- the campaign
def _take(models, idx):
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[idx] if eqx.is_array(x) else x, models)


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
      vehicle does not depend on the chunking, the ordering or where it runs.
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
      ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` set another count). On the CPU
      each device runs its members in vmapped groups small enough that jaxlib's batched
      LAPACK calls stay on the calling thread (larger batches are split over XLA's thread
      pool, and two device shards doing that at once can deadlock; see benchmarks/README.md).
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
    cfg = _Config(len(s.ts), s.max_steps, attitude, s.dt, t_pilot)
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
        "dtype": jnp.dtype(s.dtype).name,
        "where": "dask" if client is not None else f"in-process ({jax.default_backend()})",
        "devices": len(jax.local_devices()) if devices is None else int(devices),
    }
    if out is not None:
        fingerprint = _fingerprint(models, s.ts, s.t1, s.rtol, s.atol, cfg, s.chunk_size)
        store = _Store(out, fingerprint, s.n_chunks, {**settings, **versions()})
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
# 7.49 s, first calls 17.4 / 19.2 / 23.2 s; in chunks of 64 (32 a device, under the threshold) 2.5x
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


@eqx.filter_jit
def _sampled(sample, n: int, key, model: Model):
    """``sample`` over the members' keys, compiled as one program (run eagerly, each random
    operation of a sample compiles on its own: 0.8 s of a 64-run campaign's first call)."""
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

    def __init__(self, model: Model, models, s: _Settings, cfg: _Config, *, client, devices, store, progress):
        self.model, self.models, self.s, self.cfg = model, models, s, cfg
        self.client, self.devices, self.store, self.progress = client, devices, store, progress
        self.n_chunks = s.n_chunks
        self.params = _dispersed(models, s.n)
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
        args = (_take(self.models, self.members(k)[1]), s.ts, s.t1, s.rtol, s.atol, self.cfg, pilot, self.devices)
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
        _diagnose_failures(res, _take(self.models, idx), self.model)
        ds = _chunk_dataset(
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
                self.template = _template(ds, s.n)
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


def _template(ds, n):
    """A lazily filled dataset of the whole campaign's shape (for the Zarr store's layout)."""
    import xarray as xr

    size = ds.sizes["run"]
    reps = -(-n // size)
    full = xr.concat(
        [ds] * reps, dim="run", data_vars="minimal", coords="minimal", compat="override", join="override"
    ).isel(run=slice(0, n))
    return full.assign_coords(run=np.arange(n)).chunk({"run": size})
