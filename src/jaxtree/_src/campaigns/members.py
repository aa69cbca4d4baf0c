"""One chunk of a Monte Carlo campaign: each member's run of Eq. (1) (:func:`jaxtree.simulate`), its
diagnosis, and the chunk split over the local devices (``jax.shard_map``), in vmapped groups small
enough for jaxlib's batched LAPACK calls to stay on the calling thread on a CPU."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.attitude import dcm_to_quaternion
from ..equations.dynamics import SINGULAR_CONDITION
from ..integration.failures import Failure, condition_jit
from ..integration.simulate import simulate
from ..integration.spread import lapack_group
from ..numerics import REPRODUCIBLE_OPTIONS, program_jit
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
def result_names() -> tuple[str, ...]:
    """diffrax's result names by index (``RESULTS.max_steps_reached._value`` -> its name)."""
    items = dfx.RESULTS._name_to_item
    names = {int(item._value): name for name, item in items.items()}
    return tuple(names.get(i, f"result_{i}") for i in range(max(names) + 1))


# ----------------------------------------------------------------------------- one chunk
class Config(NamedTuple):
    """Static choices of a campaign (hashable: part of the compilation key)."""

    n_save: int
    max_steps: int
    attitude: str
    dt: float | None  # fixed step, or None for the adaptive default of simulate
    t_pilot: float | None  # the pilot run's end (order="pilot"), or None
    solver: Any = None  # a diffrax solver for every member, or None for simulate's default


def _solver_kw(cfg: Config) -> dict[str, Any]:
    """`simulate`'s solver argument of the campaign: none for its default."""
    return {} if cfg.solver is None else dict(solver=cfg.solver)


def _implicit(cfg: Config) -> bool:
    """Whether the campaign's solver is implicit (its members then run one after another)."""
    return isinstance(cfg.solver, dfx.AbstractImplicitSolver)


def _euler_parameters(sol, cfg: Config):
    """The saved attitudes as Euler parameters (q0 >= 0, unit norm): the integrated ones normalized
    when the attitude variables are Euler parameters (no conversion from C in the program), else
    from C (Shepperd's method)."""
    if cfg.attitude != "quaternion":
        return dcm_to_quaternion(sol.dcm)
    q = sol.attitude
    sign = jnp.where(q[..., :1] < 0, -1.0, 1.0).astype(q.dtype)
    return sign * q / jnp.sqrt(jnp.sum(q * q, -1, keepdims=True))


def _member(model: Model, ts, t1, rtol, atol, cfg: Config):
    """One member: its histories and per-run figures (a dict of arrays)."""

    kw = _solver_kw(cfg)
    if cfg.dt is not None:
        kw.update(stepsize_controller=dfx.ConstantStepSize(), dt0=jnp.asarray(cfg.dt, ts.dtype))
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
        attitude=_euler_parameters(sol, cfg),
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
    # for the failed members only: see diagnose_failures)
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


def diagnose_failures(out: dict, models, model: Model) -> None:
    """Failed members that stopped at a finite state (step limit, step-size collapse): 'singular_matrix'
    when Eq. (1)'s matrix is singular or nearly so there (gimbal lock, a vanishing mass). One
    eager evaluation per failed member, on the host (batched LAPACK calls in the vmapped chunk
    would cost every member a decomposition, and can deadlock on the CPU, see _sharded)."""

    code = out["diagnosis"]
    suspects = np.flatnonzero(np.isin(code, [FAILURES.index(k) for k in ("max_steps", "dt_min", "other")]))
    for i in suspects:
        member = take(models, i)
        state = State(*(np.asarray(x)[i] for x in out["final"]))
        cond, _ = condition_jit(member, state, np.asarray(out["t_final"])[i])
        cond = float(cond)
        if not np.isfinite(cond) or cond > SINGULAR_CONDITION:
            code[i] = FAILURES.index("singular_matrix")


def _pilot_member(model: Model, ts, t1, rtol, atol, cfg: Config):
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
        **_solver_kw(cfg),
    )
    return dict(steps=sol.stats["num_steps"])


def _sharded(fn, n_devices, group):
    """`fn` over a batch (vmapped), split over the first `n_devices` local devices when more than
    one (``shard_map``: each device runs its own integration loop, so a device does not wait for
    the other's slowest member); `group` members at a time per device (None: all at once)."""
    one = lambda m, ts, t1, rtol, atol, cfg: fn(m, ts, t1, rtol, atol, cfg)

    vmapped = jax.vmap(one, in_axes=(0, None, None, None, None, None))

    def batched(models, ts, t1, rtol, atol, cfg):
        size = jax.tree_util.tree_leaves(models)[0].shape[0]
        if group is None or group >= size:
            if size > 1:
                return vmapped(models, ts, t1, rtol, atol, cfg)
            # a batch of one compiles to other machine code than wider ones (its batch axis folds
            # away): run it beside a copy, so that a member's numbers do not depend on how many
            # members share its device
            pair = jax.tree_util.tree_map(lambda x: jnp.concatenate([x, x]) if eqx.is_array(x) else x, models)
            return jax.tree_util.tree_map(lambda x: x[:1], vmapped(pair, ts, t1, rtol, atol, cfg))
        if group == 1:  # a plain loop over the members (lax.map's batch_size=1 vmaps each of them)
            return jax.lax.map(lambda m: one(m, ts, t1, rtol, atol, cfg), models)
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


# one LLVM module, compiled as one part: a member's numbers the same on any number of devices, in
# this process or a Dask worker's (numerics.REPRODUCIBLE_OPTIONS)
@program_jit(options=REPRODUCIBLE_OPTIONS)
def _run_chunk_jit(models, ts, t1, rtol, atol, cfg: Config, n_devices: int, group, pilot: bool):
    return _sharded(_pilot_member if pilot else _member, n_devices, group)(models, ts, t1, rtol, atol, cfg)


def run_chunk(models, ts, t1, rtol, atol, cfg: Config, pilot: bool = False, devices: int | None = None):
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
        group = lapack_group(models, size // devices)
    if _implicit(cfg):
        # one member after another on each device: under vmap an implicit solver's conditionals
        # (a new Jacobian, new factorizations) become selects, so every member would pay both
        # at every step, and every member would wait for the slowest; one by one, each member
        # costs its single run (64 stiff chains under Radau5 on one device: 62 single runs
        # against 128 vmapped; benchmarks/FINDINGS.md, "Implicit members one after another")
        group = 1
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


def take(models, idx):
    """The members `idx` of a batch of models (numpy leaves with a leading run axis)."""
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[idx] if eqx.is_array(x) else x, models)
