"""Parameter identification: the weighted least-squares fit of named model parameters to a
record of sensor readings, through the simulation (:func:`identify`).

The residuals are the sensors' readings of a simulation (:mod:`.sensors`) minus the record, in
units of each sensor's noise standard deviation. They are minimized by Levenberg-Marquardt
(Madsen, Nielsen & Tingleff, *Methods for non-linear least squares problems*, 2004, Sec. 3.2:
Marquardt's scaling by the running largest diagonal of J^T J, Nielsen's damping update). Each
iteration evaluates the residuals and their Jacobian together at its trial point: one
simulation with one tangent per parameter (forward mode; ``jacobian="reverse"``: one cotangent
per residual). A rejected trial costs that simulation; an accepted one brings the
Jacobian the next step needs, and the last one accepted gives the Gauss-Newton covariance
``(J^T J)^-1`` at the solution without another simulation. The loop is one ``lax.while_loop``
in one compiled program per problem shape: a second fit of a record of the same shape (other
data, other start, other model numbers) compiles nothing.

While the fit is far from its answer the simulations run at a coarse tolerance (`coarse_tol`,
1e-6), where the integration error is far below what a step needs; once the Gauss-Newton step
left is :data:`SWITCH` standard errors, the point is evaluated again at the fit's own tolerances
and the fit finishes there, so that the estimate and its covariance are those of `rtol`, `atol`.

The fit stops when the Gauss-Newton step left would move the parameters by less than `tol`
standard errors (its Mahalanobis length ``|J dtheta_GN|``), when a step changes no parameter
by more than `xtol` relative, when that step would lower the chi-square by less than `ftol` of
it, or after `max_steps` simulations.

Many records or vehicles at once: a measurement array with a leading members axis fits each
member by the single-record program, the members shared among threads on the cores (each
estimate is its single fit's, and a member that has converged costs nothing more).

This is not an equation of the seed: it is the use of Eq. (1) its users named first.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import os
import warnings
from collections.abc import Mapping
from typing import Any

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError, SceneTypeError
from ..integration.simulate import simulate
from ..numerics import program_jit
from ..vehicle.model import Model
from . import sensors as sen
from .parameters import Parameters, parameters, start_values

# stop codes of the loop (Fit.reason)
REASONS = (
    "running",
    "the Gauss-Newton step left is below tol standard errors",
    "the step changes no parameter by more than xtol",
    "max_steps simulations without meeting tol",
    "the simulation at the start failed",
    "the damping grew without bound: no step lowers the residuals",
    "the decrease of chi-square left is below ftol of it (the simulations' resolution)",
)
CORRELATED = 0.99  # |correlation| above which two parameters are named as not told apart
SINGULAR = 1e-10  # smallest over largest singular value of the column-scaled Jacobian


class IdentifiabilityWarning(UserWarning):
    """The record cannot tell some parameters apart (see ``Fit.unidentifiable``)."""


class ConvergenceWarning(UserWarning):
    """A fit stopped without meeting its tolerance (see ``Fit.converged``, ``Fit.reason``)."""


@dataclasses.dataclass(frozen=True)
class Fit:
    """The result of :func:`identify`.

    - `values`, `stderr`: dicts by parameter name (numbers, or arrays over the members);
      standard errors from the Gauss-Newton covariance at the solution, first order in the
      physical units (a parameter fitted as a logarithm: value times the logarithm's error);
    - `covariance` (P, P) (members first), `correlation`, in the order of `names`;
    - `steps` (simulations run), `converged`, `reason` (why it stopped);
    - `residuals`: dict by sensor, (T, ...) in units of sigma at the solution (NaN where a sample
      was missing); `chi2` their sum of squares, `dof` the samples used less the parameters;
    - `model`: the model with the estimates (leaves with a leading members axis for a batch);
    - `unidentifiable`: the parameters the record cannot tell apart (correlation above 0.99, or
      a direction of the information matrix it cannot see), also named in a warning;
    - `theta`, `log`: the fitted coordinates and which are logarithms; `members`: the batch's
      size or None.
    """

    names: tuple[str, ...]
    values: dict
    stderr: dict
    covariance: np.ndarray
    correlation: np.ndarray
    steps: Any
    converged: Any
    reason: Any
    residuals: dict
    chi2: Any
    dof: Any
    model: Model
    unidentifiable: tuple[str, ...]
    theta: np.ndarray
    log: tuple[bool, ...]
    members: int | None

    def table(self, truth: Mapping | None = None) -> str:
        """The estimates with their standard errors (the first member of a batch), one a line."""
        pick = (lambda x: np.asarray(x)[0]) if self.members else (lambda x: np.asarray(x))
        head = f"{'parameter':24s} {'estimate':>14s} {'std error':>10s} {'rel':>8s}"
        if truth:
            head += f" {'truth':>12s} {'off (sigma)':>11s}"
        lines = [head]
        for name in self.names:
            v, s = float(pick(self.values[name])), float(pick(self.stderr[name]))
            line = f"{name:24s} {v:14.8g} {s:10.3g} {s / abs(v) if v else np.inf:8.1e}"
            if truth and name in truth:
                line += f" {truth[name]:12.6g} {(v - truth[name]) / s:11.2f}"
            lines.append(line)
        state = "converged" if np.all(self.converged) else "NOT converged"
        lines.append(f"{state} after {int(np.max(self.steps))} simulations: {pick(self.reason)}")
        ratio = float(pick(self.chi2)) / max(int(pick(self.dof)), 1)
        note = ""
        if ratio > 2:  # far outside chi-square's spread for any record of more than a few samples
            note = (
                f": the residuals are {np.sqrt(ratio):.3g} times sigma; the model does not fit the record to its noise "
                "(or sigma is too small), and the standard errors are that much too small"
            )
        lines.append(f"chi2/dof {ratio:.4g}{note}")
        return "\n".join(lines)


@dataclasses.dataclass(frozen=True)
class _Spec:
    """The static part of a fit: what compiles."""

    params: Parameters
    sensors: tuple[sen.Sensor, ...]
    samples: int
    reverse: bool
    progress: bool


def _residual_fn(spec: _Spec, model: Model, times, data, weights, mask):
    """(theta, rtol, atol) -> (flat weighted residuals (M,), ok): one simulation."""
    adjoint = dfx.RecursiveCheckpointAdjoint() if spec.reverse else dfx.ForwardMode()

    def residuals(theta, rtol, atol):
        m = spec.params.apply(model, theta)
        sol = simulate(
            m,
            times[-1],
            t0=times[0],
            saveat=times,
            rtol=rtol,
            atol=atol,
            adjoint=adjoint,
            throw=False,
            solver=dfx.Dopri8(),
            diagnostics=False,  # the states alone: no energy histories, no second factorization at the start
        )
        parts = sen.readings(m, spec.sensors, sol, data)
        flat = jnp.concatenate([(parts[s.name] * weights[s.name]).reshape(-1) for s in spec.sensors])
        flat = jnp.where(mask, flat, 0.0)
        ok = (sol.failure == 0) & jnp.all(jnp.isfinite(flat))
        return flat, ok

    return residuals


# The coarse phase ends when the Gauss-Newton step left is this many standard errors or fewer
SWITCH = 1.0


def _loop(spec: _Spec, residuals, theta0, tols, max_steps):
    """Levenberg-Marquardt (module docstring): returns the accepted theta, r, J and the counts.

    Two phases: the simulations run at the coarse tolerances until the fit nears its solution
    (the Gauss-Newton step left is :data:`SWITCH` standard errors or less, or the coarse fit
    stops), then at the fit's own tolerances from the point reached (re-evaluated there
    first), so that the estimate, its residuals and its covariance are those of the fit's
    tolerances. Where the coarse tolerances are no coarser, the loop starts in the second phase."""
    rtol, atol, coarse_rtol, coarse_atol, tol, xtol, ftol = tols
    P = theta0.shape[0]

    def evaluate(theta, phase):
        """Residuals, their Jacobian and whether the simulation ran, from one simulation."""
        rt, at = jnp.where(phase == 0, coarse_rtol, rtol), jnp.where(phase == 0, coarse_atol, atol)
        with_aux = lambda th: (lambda out: (out[0], out))(residuals(th, rt, at))
        J, (r, ok) = (jax.jacrev if spec.reverse else jax.jacfwd)(with_aux, has_aux=True)(theta)
        return r, J, ok

    def propose(theta, r, J, lam, scale):
        A, g = J.T @ J, J.T @ r
        scale = jnp.maximum(scale, jnp.diag(A))
        delta = -jnp.linalg.solve(A + lam * jnp.diag(jnp.maximum(scale, 1e-300)), g)
        predicted = -(g @ delta) - 0.5 * delta @ (A @ delta)
        # the Gauss-Newton step left, in standard errors: |J dtheta_GN| (least squares: J may be singular)
        gn = jnp.linalg.lstsq(J, -r)[0]
        left = jnp.linalg.norm(J @ gn)
        return delta, predicted, scale, left

    def body(c):
        r_t, J_t, ok = evaluate(c["trial"], c["phase"])
        cost_t = jnp.where(ok, 0.5 * r_t @ r_t, jnp.inf)
        fresh = c["fresh"]  # the start, or the same point at the fit's own tolerances: accepted as it is
        rho = (c["cost"] - cost_t) / jnp.maximum(c["predicted"], 1e-300)
        accept = fresh | (jnp.isfinite(cost_t) & (rho > 1e-4))
        theta = jnp.where(accept, c["trial"], c["theta"])
        r = jnp.where(accept, r_t, c["r"])
        J = jnp.where(accept, J_t, c["J"])
        cost = jnp.where(accept, cost_t, c["cost"])
        lam = jnp.where(
            c["step"] == 0,
            1e-3,  # relative to the scaling: 1e-3 of the largest diagonal of J^T J
            jnp.where(
                fresh,
                c["lam"],
                jnp.where(accept, c["lam"] * jnp.maximum(1 / 3, 1 - (2 * rho - 1) ** 3), c["lam"] * c["nu"]),
            ),
        )
        nu = jnp.where(accept, 2.0, 2 * c["nu"])
        delta, predicted, scale, left = propose(theta, r, J, lam, c["scale"])
        step = c["step"] + 1
        # why it stops, in order of precedence (0: it goes on); codes as in REASONS
        reason = jnp.select(
            [
                fresh & ~ok,
                left <= tol,
                jnp.all(jnp.abs(delta) <= xtol * (jnp.abs(theta) + xtol)),
                0.5 * left**2 <= ftol * cost,  # the Gauss-Newton step's own predicted decrease
                lam > 1e30,
                step >= max_steps,
            ],
            [4, 1, 2, 6, 5, 3],
            0,
        )
        near = (reason == 1) | (reason == 2) | (reason == 5) | (reason == 6) | (left <= SWITCH)
        switch = (c["phase"] == 0) & near & (reason != 4) & (step < max_steps)
        if spec.progress:
            jax.debug.callback(_report, step, cost, lam, left, accept, c["phase"], ordered=True)
        return dict(
            trial=jnp.where(switch, theta, theta + delta), theta=theta, r=r, J=J, cost=cost, predicted=predicted,
            lam=lam, nu=nu, scale=scale, step=step, reason=jnp.where(switch, 0, reason).astype(jnp.int32),
            left=left, phase=jnp.where(switch, 1, c["phase"]).astype(jnp.int32), fresh=switch,
        )  # fmt: skip

    M = spec.samples
    dtype = theta0.dtype
    coarser = (coarse_rtol > rtol) | (coarse_atol > atol)
    init = dict(
        trial=theta0, theta=theta0, r=jnp.zeros(M, dtype), J=jnp.zeros((M, P), dtype), cost=jnp.asarray(jnp.inf, dtype),
        predicted=jnp.ones((), dtype), lam=jnp.ones((), dtype), nu=jnp.asarray(2.0, dtype),
        scale=jnp.zeros(P, dtype), step=jnp.zeros((), jnp.int32), reason=jnp.zeros((), jnp.int32),
        left=jnp.asarray(jnp.inf, dtype), phase=jnp.where(coarser, 0, 1).astype(jnp.int32), fresh=jnp.asarray(True),
    )  # fmt: skip
    out = jax.lax.while_loop(lambda c: c["reason"] == 0, body, init)
    return out["theta"], out["r"], out["J"], out["step"], out["reason"]


def _report(step, cost, lam, left, accept, phase):
    print(
        f"identify: simulation {int(step)}{' (coarse)' if int(phase) == 0 else ''}: chi2 {2 * float(cost):.6g}, damping {float(lam):.2g}, "
        f"Gauss-Newton step left {float(left):.3g} std errors{'' if bool(accept) else ' (rejected)'}",
        flush=True,
    )


@program_jit
def _fit(spec: _Spec, model, times, data, weights, mask, theta0, tols, max_steps):
    residuals = _residual_fn(spec, model, times, data, weights, mask)
    return _loop(spec, residuals, theta0, tols, max_steps)


def _members(spec: _Spec, args, tols, limit, members: int, workers: int | None):
    """Each member's fit by the single-record program, the members shared among `workers` threads
    (XLA releases Python's lock while a program runs): a member that has converged costs nothing
    more, and each estimate is its single fit's, bit for bit. (A vmapped loop cost 7.8 times the
    single fits of 16 wings records on a 2-core CPU: every iteration ran every member to the
    slowest member's step count, and XLA:CPU runs a batch of 16 such solves no faster per member
    than one; benchmarks/FINDINGS.md.)"""
    model, times, data, weights, mask, theta0 = args

    def one(i):
        member = (model, times, {k: v[i] for k, v in data.items()}, weights, mask[i], theta0[i])
        return jax.device_get(_fit(spec, *member, tols, limit))

    first = one(0)  # compiles (or loads) the program once, before the threads share it
    if workers is None:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, min(int(workers), members - 1))) as pool:
        rest = list(pool.map(one, range(1, members)))
    return tuple(np.stack([np.asarray(x[k]) for x in (first, *rest)]) for k in range(5))


def _check_times(times) -> np.ndarray:
    try:
        ts = np.asarray(times, dtype=float)
    except (TypeError, ValueError):
        raise SceneTypeError(f"identify: times must be an array of numbers, got {type(times).__name__}") from None
    if ts.ndim != 1 or ts.size < 2:
        raise SceneError(f"identify: times must be 1-D with at least 2 samples, got shape {ts.shape}")
    if not np.all(np.isfinite(ts)):
        raise SceneError("identify: times are not all finite")
    if np.any(np.diff(ts) <= 0):
        i = int(np.flatnonzero(np.diff(ts) <= 0)[0])
        raise SceneError(f"identify: times must increase; times[{i}] = {ts[i]:g} is followed by {ts[i + 1]:g}")
    return ts


def _check_measurements(model, measurements, sigma, T):
    """Resolved sensors, data arrays (NaN kept), sigmas, and the members count (None: one record)."""
    if not isinstance(measurements, Mapping) or not measurements:
        raise SceneTypeError("identify: measurements must be a non-empty dict sensor -> array (T, ...)")
    if not isinstance(sigma, Mapping):
        raise SceneTypeError("identify: sigma must be a dict sensor -> noise standard deviation")
    missing = [name for name in measurements if name not in sigma]
    if missing:
        raise SceneError(f"identify: sigma has no entry for sensor {missing[0]!r}")
    extra = [name for name in sigma if name not in measurements]
    if extra:
        raise SceneError(f"identify: sigma names sensor {extra[0]!r}, which has no measurements")
    members = None
    sensors, data, sigmas = [], {}, {}
    base = {"omega": 2, "angle": 1, "rate": 1}
    for name, y in measurements.items():
        try:
            a = np.asarray(y, dtype=float)
        except (TypeError, ValueError):
            raise SceneTypeError(f"identify: measurements[{name!r}] must be an array of numbers") from None
        kind = name.rpartition(".")[2] if isinstance(name, str) else ""
        ndim = base.get(kind, None)
        if kind == "attitude":
            ndim = 3 if a.shape[-2:] == (3, 3) else 2
        batched = ndim is not None and a.ndim == ndim + 1
        this = a.shape[0] if batched else None
        if members is None and batched:
            members = this
        if (members is not None) != batched or (batched and this != members):
            raise SceneError(
                f"identify: measurements[{name!r}] has shape {a.shape}: every sensor needs the same leading members "
                f"axis, or none"
            )
        per = a[0] if batched else a
        if per.ndim == 0 or per.shape[0] != T:
            raise SceneError(
                f"identify: measurements[{name!r}] has {per.shape[0] if per.ndim else 0} samples; times has {T}"
            )
        s = sen.resolve(model, name, per.shape, batched)
        sensors.append(s)
        data[name] = a
        sigmas[name] = sen.check_sigma(name, sigma[name], s)
    return tuple(sensors), data, sigmas, members


def identify(
    model: Model,
    free,
    times,
    measurements: Mapping,
    sigma: Mapping,
    *,
    start: Mapping | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-8,
    max_steps: int = 100,
    log: Mapping | None = None,
    tol: float = 1e-4,
    xtol: float = 1e-10,
    ftol: float = 1e-10,
    coarse_tol: float | None = 1e-6,
    jacobian: str = "auto",
    progress: bool = False,
    warn: bool = True,
    workers: int | None = None,
) -> Fit:
    """Estimate the parameters `free` of `model` from sensor `measurements` sampled at `times`.

    **Arguments:**

    - `model`: the vehicle (:func:`jaxtree.load_scene`); the simulation starts at ``times[0]``
      from ``model.initial`` (whose numbers may be parameters too).
    - `free`: the parameters, by name: a list of quantities (each its own parameter) or a dict
      ``parameter name -> list of quantities set together``. Quantities (see
      :mod:`jaxtree._src.identify.quantities`): ``"<body>.mass"``, ``"<body>.inertia[i,j]"``
      (kept symmetric), ``"<body>.stiffness"``, ``"<body>.damping"``,
      ``"<body>.hinge_on_parent[i]"``, ``"<body>.hinge_on_body[i]"``, ``"<body>.initial_angle"``,
      ``"<body>.initial_rate"``, or any array leaf by path and index (``"initial.omega0[2]"``,
      ``"loads.torque[0]"``, ``"law.kp[1]"``).
    - `times` (T,): the sample times, increasing.
    - `measurements`: dict ``sensor -> array (T, ...)``: ``"<body>.omega"`` (T, 3) the body's
      inertial rate in its frame (a gyro), ``"<body>.angle"`` / ``"<body>.rate"`` (T,) its hinge,
      ``"<body>.attitude"`` (T, 3, 3) or (T, 4) (a star tracker; :mod:`.sensors`). NaN marks a
      missing sample. A leading members axis on every array fits that many records at once.
    - `sigma`: dict ``sensor -> noise standard deviation`` (a scalar or one per component).
    - `start`: dict ``parameter -> starting value`` (one per member for a batch); default the
      model's value (the mean over a parameter's quantities).
    - `rtol`, `atol`: the simulation's tolerances (Dopri8).
    - `max_steps`: the most simulations (Levenberg-Marquardt trials) per fit.
    - `log`: dict ``parameter -> bool``: fit it as its logarithm or not (default: masses, diagonal
      inertias, stiffnesses and dampings as logarithms, the rest as themselves).
    - `tol`: stop when the Gauss-Newton step left is shorter than `tol` standard errors; `xtol`:
      or when a step changes every fitted coordinate by less than `xtol` relative; or when the
      Gauss-Newton step left would lower the chi-square by less than `ftol` of it (a model that
      cannot fit the record down to its noise: the simulations' own error then decides the last
      steps, which are rejected one after another).
    - `coarse_tol`: the simulations' tolerance (relative and absolute) while the fit is far from
      its solution, where `rtol` and `atol` are tighter; the last steps, the estimate and its
      covariance are at `rtol`, `atol` (None: `rtol`, `atol` throughout).
    - `jacobian`: ``"forward"`` (one tangent per parameter), ``"reverse"`` (one cotangent per
      residual) or ``"auto"`` (forward unless the parameters outnumber the residuals).
    - `progress`: print each simulation's chi-square and damping (a host callback: such a program
      is not kept in the compilation cache).
    - `warn`: warn when the fit does not converge or some parameters are not identifiable.
    - `workers`: threads that share a batch's members (default: the cores this process may use).

    **Returns:** a :class:`Fit`.

    Every argument is checked before anything is traced; a mistake raises a
    :class:`~jaxtree.SceneError` naming the quantity, the sensor or the argument.
    """
    if not isinstance(model, Model):
        raise SceneTypeError(f"identify: model must be a jaxtree Model, got {type(model).__name__}")
    ts = _check_times(times)
    params = parameters(model, free, log)
    sensors, data, sigmas, members = _check_measurements(model, measurements, sigma, ts.size)
    values0 = start_values(model, params, start, members)
    checked = (
        ("rtol", rtol),
        ("atol", atol),
        ("tol", tol),
        ("xtol", xtol),
        ("ftol", ftol),
        ("coarse_tol", coarse_tol or 1.0),
    )
    for label, x in checked:
        if not isinstance(x, (int, float)) or not np.isfinite(x) or x <= 0:
            raise SceneError(f"identify: {label} must be a positive number, got {x!r}")
    if not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise SceneError(f"identify: max_steps must be a positive integer, got {max_steps!r}")
    if jacobian not in ("auto", "forward", "reverse"):
        raise SceneError(f"identify: jacobian must be 'auto', 'forward' or 'reverse', got {jacobian!r}")

    dtype = jnp.result_type(model.mass)
    filled, mask = _filled_and_mask(sensors, data, ts.size, members, dtype)
    samples = mask.shape[-1]
    used = mask.sum(-1)
    if np.any(used < params.size):
        raise SceneError(f"identify: {int(np.min(used))} samples for {params.size} parameters: the record is too short")
    reverse = jacobian == "reverse" or (jacobian == "auto" and params.size > samples)
    spec = _Spec(params, sensors, samples, reverse, bool(progress))
    weights = {s.name: jnp.asarray(1.0 / sigmas[s.name], dtype) for s in sensors}
    theta0 = jnp.asarray(params.to_theta(jnp.asarray(values0, dtype)), dtype)
    args = (model, jnp.asarray(ts, dtype), filled, weights, jnp.asarray(mask), theta0)
    coarse = rtol if coarse_tol is None else coarse_tol
    tols = tuple(jnp.asarray(x, dtype) for x in (rtol, atol, max(rtol, coarse), max(atol, coarse), tol, xtol, ftol))
    limit = jnp.asarray(max_steps, jnp.int32)
    if not members:
        out = jax.device_get(_fit(spec, *args, tols, limit))
    else:
        out = _members(spec, args, tols, limit, members, workers)
    theta, r, J, steps, reason = out
    return _result(spec, model, theta, r, J, steps, reason, mask, members, warn)


def _filled_and_mask(sensors, data, T: int, members, dtype):
    """The measurements with each missing sample filled by a harmless value (0, or the identity
    attitude), and the mask of the flat residuals that are kept (sensor by sensor, (T, width)
    each; an attitude sample is kept or dropped whole)."""
    lead = (members,) if members else ()
    filled, masks = {}, []
    for s in sensors:
        a = data[s.name]
        missing = np.isnan(a)
        fill = np.where(missing, 0.0, a)
        if s.kind == "attitude" and s.form == "quaternion":
            fill = np.where(missing.any(-1, keepdims=True), np.array([1.0, 0, 0, 0]), fill)
        elif s.kind == "attitude":
            fill = np.where(missing.any((-1, -2), keepdims=True), np.eye(3), fill)
        filled[s.name] = jnp.asarray(fill, dtype)
        if s.kind == "attitude":
            comp = np.repeat(missing.reshape(*lead, T, -1).any(-1)[..., None], 3, -1)
        else:
            comp = missing.reshape(*lead, T, -1)
        masks.append(~comp.reshape(*lead, -1))
    return filled, np.concatenate(masks, -1)


def _unidentifiable(names, J, corr) -> tuple[str, ...]:
    """The parameters a record cannot tell apart: those in a correlation above
    :data:`CORRELATED`, or in a direction the column-scaled Jacobian does not see (a singular
    value below :data:`SINGULAR` of the largest); every member of a batch."""
    P = len(names)
    bad: set[str] = set()
    Js = J / np.maximum(np.linalg.norm(J, axis=-2, keepdims=True), 1e-300)
    sv, vt = np.linalg.svd(Js, full_matrices=False)[1:]
    flat_sv, flat_vt, flat_corr = sv.reshape(-1, P), vt.reshape(-1, P, P), corr.reshape(-1, P, P)
    for m in range(flat_sv.shape[0]):
        for k in np.flatnonzero(flat_sv[m] < SINGULAR * max(flat_sv[m, 0], 1e-300)):
            bad.update(names[i] for i in np.flatnonzero(np.abs(flat_vt[m, k]) > 0.3))
        hi = np.abs(np.nan_to_num(flat_corr[m])) > CORRELATED
        np.fill_diagonal(hi, False)
        bad.update(names[i] for i in np.flatnonzero(hi.any(-1)))
    return tuple(n for n in names if n in bad)


def _by_sensor(sensors, r, mask, members) -> dict:
    """The flat residuals split by sensor, (T, width) or (T,), NaN where a sample was missing."""
    lead = (members,) if members else ()
    out, at = {}, 0
    T = r.shape[-1] // sum(sen.width(x) for x in sensors)
    for s in sensors:
        w = sen.width(s)
        block = np.where(mask[..., at : at + T * w], r[..., at : at + T * w], np.nan).reshape(*lead, T, w)
        out[s.name] = block if w > 1 else block[..., 0]
        at += T * w
    return out


def _result(spec: _Spec, model, theta, r, J, steps, reason, mask, members, warn) -> Fit:
    params = spec.params
    P = params.size
    theta, r, J = np.asarray(theta), np.asarray(r), np.asarray(J)
    info = np.einsum("...mi,...mj->...ij", J, J)
    cov_theta = np.linalg.pinv(info, hermitian=True)
    rate = np.asarray(params.value_rates(theta))
    cov = cov_theta * rate[..., :, None] * rate[..., None, :]
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / (sd[..., :, None] * sd[..., None, :])
    values = np.asarray(params.to_values(theta))
    unidentifiable = _unidentifiable(params.names, J, corr)
    residuals = _by_sensor(spec.sensors, r, mask, members)
    chi2 = np.sum(np.where(mask, r, 0.0) ** 2, -1)
    dof = mask.sum(-1) - P
    converged = np.isin(reason, (1, 2, 6))
    reasons = np.vectorize(lambda c: REASONS[int(c)], otypes=[object])(reason)
    reason_out = reasons if members else str(reasons)
    if members:
        fitted = jax.vmap(params.apply, in_axes=(None, 0))(model, jnp.asarray(theta))
    else:
        fitted = params.apply(model, jnp.asarray(theta))
    fit = Fit(
        names=params.names,
        values={n: values[..., p] if members else float(values[p]) for p, n in enumerate(params.names)},
        stderr={n: sd[..., p] if members else float(sd[p]) for p, n in enumerate(params.names)},
        covariance=cov,
        correlation=corr,
        steps=steps if members else int(steps),
        converged=converged if members else bool(converged),
        reason=reason_out,
        residuals=residuals,
        chi2=chi2 if members else float(chi2),
        dof=dof if members else int(dof),
        model=fitted,
        unidentifiable=unidentifiable,
        theta=theta,
        log=params.log,
        members=members,
    )
    if warn and not np.all(converged):
        which = "" if not members else f" ({int(np.sum(~converged))} of {members} members)"
        first = reasons.reshape(-1)[int(np.flatnonzero(~converged.reshape(-1))[0])]
        warnings.warn(f"identify: the fit did not converge{which}: {first}", ConvergenceWarning, stacklevel=3)
    if warn and unidentifiable:
        warnings.warn(
            f"identify: the record cannot tell these parameters apart: {', '.join(unidentifiable)} "
            f"(correlation above {CORRELATED} or a direction the Jacobian does not see)",
            IdentifiabilityWarning,
            stacklevel=3,
        )
    return fit
