"""What the drivers share, :func:`jaxtree.simulate` (Eq. 1), :func:`jaxtree.simulate_hybrid`
(Eqs. 105-123) and the campaign runner: defaults of solver and step-size control, the checks of
times, tolerances and the initial state before tracing, and the loop with the layout of save
times (a history plus the final state) by :func:`diffrax.diffeqsolve` (:func:`integrate`, which
:mod:`.driver` runs for both drivers). Each formulation
supplies its vector field, its state packing and the text of its failure report
(:mod:`.failures`); the solvers are diffrax's, :mod:`.radau`'s and :mod:`.rk4`'s.
"""

from __future__ import annotations

import math
import typing
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..errors import SceneError, SceneTypeError, short
from ..numerics import is_traced
from ..values import as_float, as_int
from ..vehicle.model import Model, State
from .clip_floor import one_loop_floor
from .radau import Radau5

# Default rtol and atol of float64 runs; other dtypes: see default_tolerance.
DEFAULT_RTOL = 1e-9
DEFAULT_ATOL = 1e-9
DEFAULT_SAVE_POINTS = 101
# The smallest save grid an eager simulate compiles: the default 101 save points and a user's 501
# or 1001 run in one program (FINDINGS.md, "Save-time buckets").
FIRST_BUCKET = 1024
DEFAULT_MAX_STEPS = 200_000
# The default controller stops with `dt_min_reached` (a clear error) instead of shrinking the
# step forever when the motion becomes singular (gimbal lock, non-finite accelerations).
DTMIN_FRACTION = 1e-12
# PI step-size control (diffrax's suggested starting point for high-order solvers): on fig4_free
# it rejects ~5% of the steps instead of ~17% with pure integral control, for the same error.
PCOEFF = 0.3
ICOEFF = 0.3


def default_controller(rtol, atol, t0, t1) -> dfx.PIDController:
    """The step-size control of both formulations: PI with PCOEFF / ICOEFF and a minimum step of
    DTMIN_FRACTION of the span (without forcing it: a collapse is a `dt_min` failure)."""
    return dfx.PIDController(
        rtol=rtol, atol=atol, pcoeff=PCOEFF, icoeff=ICOEFF, dtmin=DTMIN_FRACTION * jnp.abs(t1 - t0), force_dtmin=False
    )


def _zero_field(t, y, args):
    return jnp.zeros_like(y)


def terms(solver, vector_field: Callable):
    """diffrax's terms for `solver`: the ODE term, or for an IMEX solver (``KenCarp3/4/5``,
    ``Sil3``: a pair of terms) a zero explicit part and the whole right side implicit. (Putting
    only the hinge springs and dampers in the implicit part would cost a second solve of
    Eq. (1) per stage.)"""
    term = dfx.ODETerm(vector_field)
    structure = getattr(solver, "term_structure", None)
    if typing.get_origin(structure) is dfx.MultiTerm or isinstance(structure, dfx.MultiTerm):
        return dfx.MultiTerm(dfx.ODETerm(_zero_field), term)
    return term


class Run(NamedTuple):
    """One integration: the history at the save times, the last state reached and diffrax's
    solution (stats, result, event mask)."""

    ts: jax.Array
    ys: jax.Array
    t_final: jax.Array
    y_final: jax.Array
    sol: Any


def integrate(
    vector_field: Callable,
    solver,
    t0,
    t1,
    dt0,
    y0,
    args,
    *,
    ts=None,
    saveat: dfx.SaveAt | None = None,
    controller,
    adjoint=None,
    event=None,
    max_steps: int,
    progress_meter=None,
    start_ok=None,
    rest=None,
) -> Run:
    """Integrate ``dy/dt = vector_field(t, y, args)`` from `t0` to `t1` with diffrax.

    Save times: `ts` (the history) and the final state, as two sub-saves; with
    :class:`diffrax.BacksolveAdjoint`, which takes one ``SaveAt(ts=...)``, `t1` is appended to
    `ts` instead. A user's `saveat` is used as is (its last row is the final state). The final
    state is the last finite save (a failed run stops early and pads with inf).

    A start that cannot be integrated (``start_ok`` False: not finite, or singular) is replaced
    by `rest`, so that the solver runs its normal course instead of rejecting NaN steps until
    `max_steps` (a vmapped batch would wait for its worst member); its history is NaN and its
    final state the given start at `t0`.
    """
    y_start = y0
    if start_ok is not None:
        assert rest is not None, "integrate: start_ok needs rest"
        y0 = jnp.where(start_ok, y0, rest)
    single = saveat is None and isinstance(adjoint, dfx.BacksolveAdjoint)
    if saveat is None:
        assert ts is not None, "integrate: give ts or saveat"
        if single:
            saveat = dfx.SaveAt(ts=jnp.concatenate([ts, jnp.reshape(t1, (1,)).astype(ts.dtype)]))
        else:
            saveat = dfx.SaveAt(subs=(dfx.SubSaveAt(ts=ts), dfx.SubSaveAt(t1=True)))
    if keeps_statistics(solver):
        saveat = eqx.tree_at(lambda s: s.solver_state, saveat, True)  # its counters (Radau5)
    assert saveat is not None
    with one_loop_floor():  # diffrax's floor below t1 in one loop (clip_floor.py)
        sol = dfx.diffeqsolve(
            terms(solver, vector_field),
            solver,
            t0,
            t1,
            dt0,
            y0,
            args=args,
            saveat=saveat,
            stepsize_controller=controller,
            adjoint=dfx.RecursiveCheckpointAdjoint() if adjoint is None else adjoint,
            event=event,
            max_steps=max_steps,
            throw=False,
            progress_meter=dfx.NoProgressMeter() if progress_meter is None else progress_meter,
        )
    assert sol.ts is not None and sol.ys is not None  # something is always saved
    sol_ts, sol_ys = sol.ts, sol.ys
    if isinstance(saveat.subs, (tuple, list)):
        ts_h, ys_h = sol_ts[0], sol_ys[0]
        ts_f, ys_f = sol_ts[-1], sol_ys[-1]
    elif single:
        ts_h, ys_h = sol_ts[:-1], sol_ys[:-1]
        ts_f, ys_f = sol_ts, sol_ys
    else:
        ts_h, ys_h = sol_ts, sol_ys
        ts_f, ys_f = sol_ts, sol_ys
    i = last_finite(ts_f)
    t_final, y_final = ts_f[i], ys_f[i]
    if start_ok is not None:
        t_final = jnp.where(start_ok, t_final, t0)
        y_final = jnp.where(start_ok, y_final, y_start)
        ys_h = jnp.where(start_ok, ys_h, jnp.nan)
    return Run(ts_h, ys_h, t_final, y_final, sol)


def keeps_statistics(solver) -> bool:
    """Whether `solver` counts its Jacobians, factorizations and Newton iterations in its state
    (:class:`jaxtree.Radau5`): then the final solver state is saved and the counts reported."""
    return isinstance(solver, Radau5)


def solver_statistics(solver, sol) -> dict:
    """The counts of a solver that keeps them (:func:`keeps_statistics`), for ``sol.stats``:
    ``jacobians``, ``factorizations``, ``newton_iterations`` and ``rhs_evaluations`` (right sides
    outside the Jacobians plus one per Jacobian; accepted step attempts only: diffrax discards
    a rejected attempt's state); empty for other solvers."""
    if not keeps_statistics(solver) or sol.solver_state is None:
        return {}
    st = sol.solver_state
    return {
        "jacobians": st.num_jac,
        "factorizations": st.num_lu,
        "newton_iterations": st.num_newton,
        "rhs_evaluations": st.num_rhs + st.num_jac,
    }


def default_tolerance(dtype) -> float:
    """Default ``rtol`` and ``atol`` of :func:`simulate` for a model of floating `dtype`.

    1e-9 in float64. In lower precisions the error estimate of a high-order solver meets
    roundoff: Dopri8 in float32 on fig4_free over 10 s takes 217 steps at 1e-4, 762 at 1e-5,
    and at 1e-9 it runs into max_steps (200k steps, 27 s). The default is therefore the power
    of ten nearest to ``1000 * eps`` when that is larger: 1e-4 in float32.
    """
    eps = float(jnp.finfo(dtype).eps)
    return max(DEFAULT_RTOL, 10.0 ** round(math.log10(1e3 * eps)))


def check_times(name, t0, t1, ts=None):
    """Concrete start, end and save times, checked before tracing: numbers, finite, and the save
    times ordered along the integration and within it (diffrax's own checks fire inside the
    compiled solve, under a long traceback). Traced values are left to run time."""
    values = [("t0", t0), ("t1", t1)] + ([] if ts is None else [("saveat", ts)])
    concrete = {label: x for label, x in values if not is_traced(x)}
    for label, x in concrete.items():
        a = as_float(x, f"{name}: {label}", finite=False)
        if label != "saveat" and a.shape != ():
            raise SceneError(f"{name}: {label} must be a scalar time, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise SceneError(f"{name}: {label} is not finite ({a.tolist()})")
    if len(concrete) < len(values) or ts is None:
        return
    a, b = (float(np.asarray(x)) for x in (t0, t1))
    ts = np.asarray(ts, float)
    step = np.diff(ts) * (1.0 if b >= a else -1.0)
    if np.any(step < 0):
        i = int(np.flatnonzero(step < 0)[0])
        raise SceneError(
            f"{name}: saveat times must run from t0 toward t1 ({'increasing' if b >= a else 'decreasing'}); "
            f"saveat[{i}] = {ts[i]:g} is followed by {ts[i + 1]:g}"
        )
    lo, hi = min(a, b), max(a, b)
    outside = np.flatnonzero((ts < lo) | (ts > hi))
    if outside.size:
        i = int(outside[0])
        raise SceneError(f"{name}: saveat[{i}] = {ts[i]:g} lies outside the integration from t0 = {a:g} to t1 = {b:g}")


def save_bucket(n: int, first: int = DEFAULT_SAVE_POINTS) -> int:
    """The number of save times compiled for a request of `n`: `first` doubled until it holds
    `n`. An eager run pads its save grid to this size (repeating the last time) and cuts the
    histories back (:func:`padded_times`, :func:`cut_rows`), so that a user who changes the
    number of save points or the times themselves reuses the compiled run within a bucket.
    :func:`jaxtree.simulate` starts at :data:`FIRST_BUCKET` (its work per padded row is a
    dense-output evaluation and a decoded state: microseconds; its diagnostics skip them),
    :func:`jaxtree.simulate_hybrid` at the default number of save points (its truncation estimate
    evaluates Eq. 1 on every row)."""
    size = first
    while size < n:
        size *= 2
    return size


def grid_times(t0, t1, n: int, dtype) -> np.ndarray:
    """`n` evenly spaced times from `t0` to `t1` on the host, by :func:`jax.numpy.linspace`'s
    formula (an eager ``jnp.linspace`` compiles a program per `n`)."""
    a, b = np.asarray(t0, dtype), np.asarray(t1, dtype)
    step = np.arange(n, dtype=dtype) / np.asarray(max(n - 1, 1), dtype)
    return np.where(step < 1, a * (1 - step) + b * step, b).astype(dtype)


def padded_times(ts, first: int = DEFAULT_SAVE_POINTS) -> jax.Array:
    """Save times `ts` (concrete, 1-D, not empty) padded with their last to :func:`save_bucket`."""
    ts = np.asarray(ts)
    padded = np.concatenate([ts, np.full(save_bucket(ts.shape[0], first) - ts.shape[0], ts[-1], ts.dtype)])
    return jax.device_put(padded)  # (jnp.asarray would compile a copy per shape)


def cut_rows(tree, size: int, n: int):
    """The leaves of `tree` with `size` rows cut to their first `n`, copied through the host so
    that no program is compiled for `n` (a history saved on a padded grid, :func:`save_bucket`)."""

    def cut(x):
        if getattr(x, "shape", ())[:1] != (size,):
            return x
        return jax.device_put(np.asarray(x)[:n])

    return jax.tree.map(cut, tree)


def check_state(name, model: Model, state: State):
    """A concrete initial :class:`~jaxtree.State`, checked before tracing: numeric fields of the
    shapes for the model's n hinges (JAX would clamp out-of-range indices silently), and ``dcm``
    a rotation matrix (orthonormal, determinant +1). Traced fields are left alone; non-finite
    values are a failed run (``nonfinite_start``), not an input error."""
    if not isinstance(state, State):
        raise SceneTypeError(f"{name}: y0 must be a jaxtree.State, got {type(state).__name__}")
    need = {"dcm": (3, 3), "omega0": (3,), "gamma": (model.n,), "gamma_dot": (model.n,)}
    for field, shape in need.items():
        x = getattr(state, field)
        got = jnp.shape(x) if is_traced(x) else as_float(x, f"{name}: y0.{field}", finite=False).shape
        if got != shape:
            raise SceneError(
                f"{name}: y0.{field} has shape {got}; the model '{model.name}' with {model.n} hinges needs {shape}"
            )
    C = state.dcm
    if is_traced(C):
        return
    C = np.asarray(C, float)
    if not np.all(np.isfinite(C)):
        return  # reported as a non-finite start
    dtype = jnp.result_type(model.mass)
    tol = max(1e-6, 1e3 * float(jnp.finfo(dtype).eps))
    err, det = float(np.abs(C @ C.T - np.eye(3)).max()), float(np.linalg.det(C))
    if err > tol or det < 0:
        raise SceneError(
            f"{name}: y0.dcm is not a rotation matrix (max |C C^T - I| = {err:.3g}, "
            f"det C = {det:.6g}); give the direction cosines of Def. 9, {{b0}} = C {{i}}"
        )


def check_tolerances(name, rtol, atol, max_steps):
    """Concrete tolerances non-negative, atol not zero, and at least one step allowed."""
    as_int(max_steps, f"{name}: max_steps", minimum=1)
    values = {"rtol": rtol, "atol": atol}
    if is_traced(list(values.values())):
        return
    for label, x in values.items():
        v = as_float(x, f"{name}: {label}", finite=False)
        if not np.all(np.isfinite(v)) or np.any(v < 0):
            raise SceneError(f"{name}: {label} must be finite and non-negative, got {v.tolist()}")
    if np.all(np.asarray(rtol, float) == 0) and np.all(np.asarray(atol, float) == 0):
        raise SceneError(f"{name}: rtol and atol are both zero: no step would ever be accepted")
    if np.all(np.asarray(atol, float) == 0):
        # pure relative control: the error allowed in a state component that passes through zero (a
        # hinge angle, a rate, a direction cosine) goes to zero with it, and the steps collapse there
        raise SceneError(
            f"{name}: atol is zero: a purely relative tolerance allows no error where a state component "
            f"passes through zero (hinge angles, rates and direction cosines do), and the steps collapse "
            f"there; give atol > 0 (the default: 1e-9 in float64, 1e-4 in float32)"
        )


def tolerances(name, rtol, atol, max_steps, dtype, stepsize_controller, stacklevel) -> tuple:
    """``(rtol, atol)`` of a run of the public function `name`: :func:`default_tolerance` of
    `dtype` where None, checked with `max_steps` (:func:`check_tolerances`), and the warning of
    :func:`warn_below_roundoff` when the default step-size controller will use `rtol`
    (`stacklevel` as seen from the caller of this function)."""
    rtol = default_tolerance(dtype) if rtol is None else rtol
    atol = default_tolerance(dtype) if atol is None else atol
    check_tolerances(name, rtol, atol, max_steps)
    if stepsize_controller is None:
        warn_below_roundoff(rtol, dtype, stacklevel + 1)
    return rtol, atol


def warn_below_roundoff(rtol, dtype, stacklevel):
    """Warn when a concrete `rtol` is too small for `dtype`: below ~50 unit roundoffs the steps
    pile up (fig4_free in float32 over 10 s: 762 steps at 1e-5, 2759 at 3e-6, 7834 at 1e-6 with
    a larger error than at 1e-5, max_steps at 3e-7)."""
    if is_traced(rtol):
        return
    try:
        value = float(np.min(np.asarray(rtol)))
    except (TypeError, ValueError):
        return
    eps = float(jnp.finfo(dtype).eps)
    if value < 50 * eps:
        warnings.warn(
            f"rtol={value:g} is below 50 x the unit roundoff of {jnp.dtype(dtype).name} ({eps:.2g}): the "
            f"solver's error estimate is dominated by roundoff and the steps pile up (toward max_steps). "
            f"Use rtol >= {default_tolerance(dtype):g} (the default for {jnp.dtype(dtype).name}), or float64.",
            stacklevel=stacklevel + 1,
        )


def last_finite(ts):
    idx = jnp.arange(ts.shape[0])
    return jnp.maximum(jnp.max(jnp.where(jnp.isfinite(ts), idx, -1)), 0)


def progress_meter(progress):
    if progress is False or progress is None:
        return dfx.NoProgressMeter()
    if progress is True:
        try:
            import tqdm  # noqa: F401

            return dfx.TqdmProgressMeter()
        except ImportError:
            return dfx.TextProgressMeter()
    if isinstance(progress, dfx.AbstractProgressMeter):
        return progress
    raise SceneTypeError(f"simulate: progress must be a bool or a diffrax progress meter, got {short(progress)}")
