"""Time histories of the full equations: :func:`simulate` integrates Eq. (1) with attitude (Eq. 3 or
23-24), prescribed hinges (Sec. II B), hinge laws and controllers, external loads and, optionally,
Eq. (2), in the first-order form of Eqs. (25)-(27) (:mod:`.problem`).

The function checks its arguments once, before tracing, builds the :class:`~.problem.Problem`,
picks the solver (given, or :mod:`.autosolver`), integrates with :func:`.core.integrate` (diffrax:
solvers, step-size controllers, adjoints, events and progress meters are diffrax objects, passed
to :func:`diffrax.diffeqsolve` unchanged), and returns a :class:`~.solution.Solution`; a run that
stops early is reported by :mod:`.failures` with the time, the state and a diagnosis.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np

from ..cache import checks_without_callbacks
from ..equations.attitude import AbstractAttitude, get_attitude
from ..equations.control import AbstractController, with_model_laws
from ..equations.dynamics import unknown_labels
from ..equations.kinematics import full_precision
from ..errors import SceneError, SceneTypeError, SceneWarning, short
from ..numerics import is_traced, program_jit
from ..values import as_float
from ..vehicle.model import Model, State
from ..vehicle.validate import check_model
from .autosolver import choose_checked, given
from .core import (
    DEFAULT_MAX_STEPS,
    DEFAULT_SAVE_POINTS,
    FIRST_BUCKET,
    check_state,
    check_times,
    cut_rows,
    grid_times,
    padded_times,
    progress_meter,
    solver_statistics,
    tolerances,
)
from .driver import Driven, drive, singular_after_failure
from .events import combine_events
from .failures import (
    Failure,
    SimulationError,
    attitude_margin,
    condition_at,
    format_failure,
    raise_failures,
)
from .problem import Problem, make_problem, packed_start, problem_field, with_jacobian
from .solution import Solution, check_solution, histories_of, report_from_callback, rhs_evaluations, run_diagnostics
from .spread import lapack_group, over_devices


def _check_arguments(model, t0, t1, dt0, translation, solver, stepsize_controller, adjoint, throw):
    """The other arguments of :func:`simulate`, before tracing: the model a valid
    :class:`~jaxtree.Model` (:func:`jaxtree.validate_model` when concrete), `dt0` finite and
    pointing from `t0` toward `t1`, `translation` a bool or ``(X0 (3,), X_dot0 (3,))``, and
    diffrax objects where diffrax objects go."""
    check_model("simulate", model)
    if getattr(model, "appendages", ()):
        warnings.warn(
            f"simulate: the scene's finite-element appendages ({', '.join(a.name for a in model.appendages)}) are "
            "not part of the full Eq. (1) and are left out; integrate them in hybrid coordinates: "
            "jaxtree.hybrid_model(model, small, appendages=jaxtree.scene_appendages(model))",
            SceneWarning,
            stacklevel=4,
        )
    if dt0 is not None and not is_traced((dt0, t0, t1)):
        h = float(as_float(dt0, "simulate: dt0", ()))
        direction = float(np.asarray(t1, float)) - float(np.asarray(t0, float))
        if h * direction < 0:
            raise SceneError(
                f"simulate: dt0 = {h:g} points away from t1 (t0 = {float(np.asarray(t0)):g}, "
                f"t1 = {float(np.asarray(t1)):g})"
            )
    if isinstance(translation, tuple):
        if len(translation) != 2:
            raise SceneError(
                f"simulate: translation must be True, False or (X0, X_dot0), got a tuple of {len(translation)}"
            )
        for label, x in zip(("X0", "X_dot0"), translation):
            if not is_traced(x):
                as_float(x, f"simulate: translation {label}", (3,))
            elif jnp.shape(x) != (3,):
                raise SceneError(f"simulate: translation {label} must have shape (3,), got {jnp.shape(x)}")
    elif not isinstance(translation, (bool, np.bool_)):
        raise SceneTypeError(f"simulate: translation must be True, False or (X0, X_dot0), got {short(translation)}")
    if isinstance(solver, str) and solver != "auto":
        raise SceneError(f"simulate: solver must be 'auto' or a diffrax solver, got {solver!r}")
    for label, value, kind in (
        ("solver", None if isinstance(solver, str) else solver, dfx.AbstractSolver),
        ("stepsize_controller", stepsize_controller, dfx.AbstractStepSizeController),
        ("adjoint", adjoint, dfx.AbstractAdjoint),
    ):
        if value is not None and not isinstance(value, kind):
            raise SceneTypeError(f"simulate: {label} must be a diffrax.{kind.__name__}, got {short(value)}")
    if not isinstance(throw, (bool, np.bool_)):
        raise SceneTypeError(f"simulate: throw must be True or False, got {short(throw)}")


def _initial_step(problem: Problem, y0, t0, t1):
    """A first step of about 0.01 rad of the fastest rotation (no vector-field evaluation, so
    nothing more to compile); the step-size controller corrects it within a few steps."""
    _, w, _, gd, _, _, _ = problem.unpack(y0)
    rate = jnp.max(jnp.abs(jnp.concatenate([w, gd, jnp.zeros((1,), y0.dtype)])))
    rate = jnp.where(jnp.isfinite(rate), rate, 0.0)  # a non-finite state fails on the first steps
    h = jnp.minimum(1e-2 / (1.0 + rate), jnp.abs(t1 - t0))
    return jnp.where(t1 >= t0, h, -h)


class _Options(NamedTuple):
    """Static choices of one simulation (hashable: part of the compilation key)."""

    has_guard: bool
    user_event: bool
    max_steps: int
    grid: int | None  # number of evenly spaced save times, or None
    user_saveat: bool
    report_in_callback: bool
    check_start: bool = True  # the test of a singular start (simulate's `diagnostics`)


class _Run(NamedTuple):
    """The inputs of one simulation that JAX may trace: the mass center's start (or None), the
    times, tolerances and first step (arrays or None), and the diffrax objects."""

    X0: Any
    Xd0: Any
    t0: Any
    t1: Any
    rtol: Any
    atol: Any
    dt0: Any
    solver: Any
    controller: Any
    saveat: Any
    adjoint: Any
    event: Any
    progress_meter: Any
    packed: Any = None  # (flat start, flat state at rest) packed before the solve, or None


@program_jit
def _solve(problem: Problem, y0: State, run: _Run, opts: _Options) -> dict:
    """The run's :class:`Solution` fields but its diagnostics (:func:`_fields`), by the shared
    integration (:func:`.driver.drive`)."""
    dtype = jnp.result_type(problem.model.mass)
    # an eager call packs the start and the state at rest in a small program of their own: the
    # quaternion from C is then no part of the solve's program
    y, rest = run.packed if run.packed is not None else (problem.pack(y0, None, run.X0, run.Xd0), None)
    if rest is None:
        rest = problem.pack(_at_rest(problem.model, dtype))
    ts = None
    if not opts.user_saveat:
        ts = jnp.linspace(run.t0, run.t1, opts.grid, dtype=dtype) if opts.grid is not None else run.saveat
    solver = with_jacobian(run.solver)
    driven = drive(
        problem_field,
        problem,
        y,
        run.t0,
        run.t1,
        solver=solver,
        controller=run.controller,
        rtol=run.rtol,
        atol=run.atol,
        dt0=run.dt0,
        rest=rest,
        max_steps=opts.max_steps,
        ts=ts,
        saveat=run.saveat if opts.user_saveat else None,
        adjoint=run.adjoint,
        event=run.event,
        guard=(opts.has_guard, opts.user_event),
        progress_meter=run.progress_meter,
        check_start=opts.check_start,
        first_step=lambda y: _initial_step(problem, y, run.t0, run.t1),
    )
    out = _fields(problem, solver, run.dt0 is not None or run.controller is None, driven)
    if opts.report_in_callback:
        report_from_callback(out["failure"], out["t_final"], out["final"], out["margin"], problem)
    return out


def _quiet(args):
    """:func:`_solve`'s arguments without its in-program failure report (for :func:`over_devices`)."""
    problem, y0, run, opts = args
    return problem, y0, run, opts._replace(report_in_callback=False)


def _report_batch(args, rerun, out) -> None:
    """The failure report of a batch split over the devices (:func:`.spread.over_devices`), made
    on the host from the whole batch, as a vmapped run's callback makes it: only where a member
    failed and the run reports (a traced run with ``throw``); the diagnosis (the condition of
    Eq. 1 at the failure) computed for the batch only then."""
    problem, _, _, opts = args
    code = np.asarray(out["failure"])
    if not opts.report_in_callback or not np.any(code):
        return
    condition, direction = rerun(
        lambda problem, y0, run, opts, o: condition_at(problem.model, o["final"], o["t_final"])
    )
    raise_failures(
        code,
        np.asarray(out["t_final"]),
        jax.tree_util.tree_map(np.asarray, out["final"]),
        np.asarray(condition),
        np.asarray(out["margin"]),
        problem.attitude.name,
        direction=np.asarray(direction),
        labels=unknown_labels(problem.model),
    )


def _group(args, share: int):
    """Members per vmapped group of a device's `share` of a split batch: one after another for an
    implicit solver (each member then takes its single run's steps), small groups where the
    dense method's factorization calls LAPACK (:func:`.spread.lapack_group`), else all at once."""
    problem, _, run, _ = args
    if isinstance(run.solver, dfx.AbstractImplicitSolver):
        return 1
    return lapack_group(problem.model, share)


def _at_rest(model: Model, dtype, xp=jnp) -> State:
    """The vehicle at rest in its reference configuration (`xp`: numpy outside a trace, where
    each jax.numpy constructor would compile a program of its own)."""
    n, z3 = model.n, xp.zeros(3, dtype)
    return State(xp.eye(3, dtype=dtype), z3, xp.zeros(n, dtype), xp.zeros(n, dtype))


def _fields(problem: Problem, solver, dt0_given: bool, driven: Driven) -> dict:
    """The fields of the run's :class:`Solution` from the shared integration's `driven`, all but
    the energy, momentum and hold torques (a program of their own, :func:`_finished`)."""
    hist = histories_of(problem, driven.ts, driven.ys)
    _, _, _, _, _, Xf, Xdf = problem.unpack(driven.y_final)
    sol = driven.sol
    stats = dict(sol.stats)
    stats["rhs_evaluations"] = rhs_evaluations(solver, sol.stats, dt0_given)
    stats.update(solver_statistics(solver, sol))
    histories = ("gamma", "gamma_dot", "omega0", "dcm", "attitude", "control_state", "X", "X_dot", "orthogonality")
    return dict(
        ts=driven.ts,
        **{k: hist[k] for k in histories},
        t_final=driven.t_final,
        final=problem.state(driven.t_final, driven.y_final),
        final_control_state=problem.control_state(driven.y_final),
        final_X=Xf,
        final_X_dot=Xdf,
        result=sol.result,
        event_mask=driven.event_mask,
        singular=driven.singular,
        margin=attitude_margin(problem, driven.y_final),
        failure=driven.failure,
        stats=stats,
        raw=sol,
        problem=problem,
    )


@full_precision
def simulate(
    model: Model,
    t1,
    *,
    t0: float | jax.Array = 0.0,
    y0: State | None = None,
    saveat=None,
    solver: dfx.AbstractSolver | str | None = "auto",
    stepsize_controller: dfx.AbstractStepSizeController | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt0=None,
    max_steps: int = DEFAULT_MAX_STEPS,
    attitude: str | AbstractAttitude = "quaternion",
    adjoint: dfx.AbstractAdjoint | None = None,
    event: dfx.Event | Callable | None = None,
    progress: bool | dfx.AbstractProgressMeter = False,
    diagnostics: bool = True,
    law: Callable | None = None,
    controller: AbstractController | None = None,
    params: Any = None,
    translation: bool | tuple = False,
    throw: bool = True,
) -> Solution:
    """Integrate the equations of motion of `model` from `t0` to `t1`.

    Implements the first-order form of Eqs. (25)-(27) of Likins (1972): Eq. (1) with the
    prescribed hinges of Sec. II B moved to the right side, the attitude kinematics of Eq. (3)
    or Eqs. (23)-(24), and Eq. (2) when `translation` is set.

    **Arguments:**

    - `model`: the vehicle (:func:`jaxtree.load_scene`, :func:`jaxtree.build_model`); its
      joint laws, prescription and external loads (``model.loads``) are used.
    - `t1`, `t0`: end and start times (``t1 < t0`` integrates backward).
    - `y0`: initial :class:`~jaxtree.State` (default ``model.initial``); entries of prescribed
      hinges are ignored (they follow the prescription). Field shapes and a proper rotation
      ``dcm`` are checked before tracing.
    - `saveat`: a :class:`diffrax.SaveAt` (used as is; the final state is its last saved row),
      a number of evenly spaced save times (default 101), or an array of times (from `t0`
      toward `t1`, within the run; checked before tracing, as are finite `t0` and `t1`). An
      eager call compiles its run for a bucket of save times (up to 1024, 2048, 4096, ...: the
      grid is padded with its last time and the histories cut back), so that another number of
      save points or other times in the same bucket compile nothing. Values
      between steps come from the solver's dense output; Dopri8's (a degree-6 polynomial)
      is 2-3x less accurate than the steps at tight tolerances (fig4_free over 10 s at rtol =
      atol = 2e-10: 1.2e-9 at the save times, 3.9e-10 at the steps). For step accuracy at
      the save times let the steps land on them, ``stepsize_controller=
      diffrax.PIDController(rtol=..., atol=..., step_ts=ts)``, at 2-3 more steps per save time.
    - `solver`: a diffrax solver, used as is; or ``"auto"`` (the default; None too):
      :func:`jaxtree.choose_solver` picks Dopri8 or :class:`jaxtree.Radau5`, whichever is
      predicted to reach `rtol`, `atol` in less run time from the run's own right side linearized
      at `y0` and sampled over the run (Radau5 where fast modes that hold Dopri8 by stability
      ring below the tolerance: a stiff latch, a fast rotor's nutation, a preloaded stiff spring;
      a screen of the scene's hinge laws and rates skips the linearization when nothing is close
      to stiff), and Dopri8 whenever the inputs are traced. ``sol.stats["solver"]`` (a :class:`~jaxtree.SolverChoice`) says what ran and why;
      with Radau5, ``sol.stats`` also counts its ``jacobians``, ``factorizations`` and
      ``newton_iterations``. IMEX solvers (``diffrax.KenCarp4`` ...) get the whole right side as
      their implicit part.
    - `stepsize_controller`: a diffrax step-size controller (used as is); default a
      :class:`diffrax.PIDController` with `rtol`, `atol`, PI coefficients 0.3 / 0.3 and a
      minimum step of 1e-12 |t1 - t0| (and an initial step from the largest rate in `y0`).
    - `rtol`, `atol`: tolerances of the default controller; default
      :func:`default_tolerance` of the model's dtype (1e-9 in float64, 1e-4 in float32). A
      concrete `rtol` below 50 x the dtype's unit roundoff gives a warning.
    - `dt0`: initial step (default: chosen by the controller).
    - `max_steps`: step limit (the run fails with a :class:`SimulationError` beyond it).
    - `attitude`: ``"quaternion"``, ``"dcm"`` (Eq. 3), ``"euler123"`` (Eqs. 23-24) or an
      :class:`~jaxtree._src.equations.attitude.AbstractAttitude`.
    - `adjoint`: a diffrax adjoint (default :class:`diffrax.RecursiveCheckpointAdjoint` under a trace,
      :class:`diffrax.ForwardMode` in an eager call, which nothing differentiates).
    - `event`: a :class:`diffrax.Event` (its functions get ``(t, y, args)`` with ``args`` the
      :class:`Problem`; ``args.state(t, y)`` is the :class:`~jaxtree.State`), or a function
      ``(t, state) -> scalar`` (see :func:`state_event`, :func:`hinge_angle_event`).
    - `progress`: show diffrax's progress meter (tqdm when installed, else text), or a diffrax
      progress meter.
    - `diagnostics`: the energy, angular momentum and hold-torque histories, and the test of a
      singular start (True). False, for a caller that needs the states alone (an identification's
      simulations, traced many times): those three histories are NaN, and a start where Eq. (1)
      is singular is not looked for (its run then fails as non-finite, or returns what the
      factorization gave); the states are the same to the bit. A program less to trace and compile.
    - `law`: hinge law ``tau(t, state, params) -> (n,)`` added to the joint laws (and to the
      model's own ``model.law``, from its scene's ``control``).
    - `controller`: an :class:`~jaxtree.control.AbstractController` whose internal states are
      appended to the ODE state (beside those of ``model.controller``: then ``control_state``
      is a pair, the model's first).
    - `params`: pytree passed to `law` and `controller` (traced; differentiable).
    - `translation`: integrate Eq. (2) for the mass center: True (start at rest at the origin,
      or on ``model.orbit`` at `t0` where the model has one) or ``(X0, X_dot0)`` in inertial
      components. With ``model.orbit`` Eq. (2) has the central body's attraction ``-mu M X /
      |X|^3`` beside the loads' net force.
    - `throw`: raise :class:`SimulationError` (time, state, diagnosis) if the run fails: at
      once when called eagerly, from a host callback at run time under ``jax.jit`` or
      ``jax.vmap``. With False, inspect ``sol.result`` / call ``sol.check()``.

    **Returns:** a :class:`Solution`.

    Pure: jittable, vmappable over initial states and model parameters, and differentiable (through
    the diffrax adjoint); an eager ``jax.vmap`` splits its members over the cores (``spread.py``).
    """
    _check_arguments(model, t0, t1, dt0, translation, solver, stepsize_controller, adjoint, throw)
    if not isinstance(diagnostics, (bool, np.bool_)):
        raise SceneTypeError(f"simulate: diagnostics must be True or False, got {short(diagnostics)}")
    att = _check_attitude_and_laws(attitude, controller, law)
    law, controller = with_model_laws(model, law, controller)  # a scene's own laws first
    dtype = jnp.result_type(model.mass)
    # (stacklevel 3: the caller of full_precision's wrapper)
    rtol, atol = tolerances("simulate", rtol, atol, max_steps, dtype, stepsize_controller, stacklevel=3)
    y0 = model.initial if y0 is None else y0
    check_state("simulate", model, y0)
    saveat, grid, user_saveat = _check_saveat(saveat, t0, t1)
    ev, has_guard, user_event = combine_events(event, att)
    meter = progress_meter(progress)
    # every argument is checked: from here on JAX may trace
    if not (grid is not None or user_saveat):
        saveat = jnp.asarray(saveat, dtype) if is_traced(saveat) else np.asarray(saveat, dtype)
    translation, X0, Xd0 = _mass_center_start(model, translation, t0, dtype)
    problem = make_problem(model, att, law, controller, params, translation)
    y_flat = None
    if solver is None or isinstance(solver, str):
        y_flat = packed_start(problem, y0, X0, Xd0)
        solver, choice = choose_checked(
            model, t1, t0=t0, y0=y0, rtol=rtol, atol=atol, law=law, params=params, problem=problem, y=y_flat
        )
    else:
        choice = given(solver)
    inputs = (model, y0, t0, t1, params, controller, law, saveat, ev, translation, X0, Xd0)
    traced = is_traced((*inputs, rtol, atol, dt0, solver, stepsize_controller, adjoint))
    if adjoint is None:
        # an eager run is never differentiated: its loops plain while loops (diffrax.ForwardMode),
        # without the checkpointing that reverse mode needs (a smaller program to trace)
        adjoint = dfx.RecursiveCheckpointAdjoint() if traced else dfx.ForwardMode()
    if not traced and throw:
        _check_finite_start(y0, X0, Xd0, t0, att)
    saveat, grid, n_saved = _bucketed(saveat, grid, user_saveat or traced, t0, t1, dtype)
    # an eager run tests for a singular start only when it failed there (_singular_start_after): the
    # test is no part of its program; a traced run (a vmapped batch) tests every start in-program
    check_start = bool(diagnostics) and traced
    opts = _Options(has_guard, user_event, int(max_steps), grid, user_saveat, bool(throw and traced), check_start)

    dev = lambda x: _on_device(x, dtype)
    arrays = (dev(X0), dev(Xd0), dev(t0), dev(t1), dev(rtol), dev(atol), dev(dt0))
    packed = None
    if not traced:
        y_flat = packed_start(problem, y0, X0, Xd0) if y_flat is None else y_flat
        packed = (y_flat, packed_start(problem, jax.device_put(_at_rest(model, np.dtype(dtype), np)), None, None))
    run = _Run(*arrays, solver, stepsize_controller, saveat, adjoint, ev, meter, packed)
    with checks_without_callbacks():  # diffrax's checks checked above; over_devices: spread.py
        fields = over_devices(_solve, (problem, y0, run, opts), quiet=_quiet, report=_report_batch, group=_group)
    if diagnostics and packed is not None:  # (an eager run)
        fields = _singular_start_after(fields, problem, packed[0], arrays[2])
    fields["stats"] = dict(fields["stats"], solver=choice)
    sol = _finished(fields, model, law, controller, params, diagnostics, n_saved)
    if throw and not traced:
        check_solution(sol)
    return sol


def _mass_center_start(model: Model, translation, t0, dtype):
    """``(integrated, X0, X_dot0)`` of simulate's `translation`: given as a pair, on the scene's
    orbit at `t0`, at rest at the origin (None, None), or not integrated."""
    if isinstance(translation, tuple):
        return True, *translation
    if translation and model.orbit is not None:  # start on the scene's orbit
        t = jnp.asarray(t0, dtype)
        return True, model.orbit.position(t), model.orbit.velocity(t)
    return bool(translation), None, None


def _on_device(x, dtype):
    """`x` as an array of `dtype` (None stays None); a Python or numpy number is put on the device,
    so that no program compiles for it."""
    if x is None:
        return None
    if isinstance(x, (int, float, np.number, np.ndarray)):
        return jax.device_put(np.asarray(x, dtype))
    return jnp.asarray(x, dtype)


def _finished(fields: dict, model: Model, law, controller, params, diagnostics: bool, n_saved) -> Solution:
    """The :class:`Solution` of the run's `fields` (:func:`_fields`) and its energy, momentum and
    hold-torque histories (NaN without `diagnostics`), cut to the `n_saved` rows asked for where
    the save grid was padded to its bucket."""
    if diagnostics:
        energy, momentum, hold = _diagnostics(fields, model, law, controller, params, n_saved)
    else:
        T, dtype = fields["ts"].shape[0], fields["omega0"].dtype
        nan = lambda *shape: jnp.full(shape, jnp.nan, dtype)
        energy, momentum, hold = nan(T), nan(T, 3), nan(T, len(model.prescribed))
    fields = dict(fields, energy=energy, angular_momentum=momentum, hold_torque=hold)
    return Solution(**(fields if n_saved is None else _cut(fields, n_saved)))


def _singular_start_after(fields: dict, problem: Problem, y, t0) -> dict:
    """The `fields` of an eager run, reported as a singular start (:attr:`Failure.SINGULAR_START`,
    t_final `t0`, NaN histories, as the in-program test of a traced run reports it) where it
    failed and Eq. (1) is singular at its start (:func:`.driver.singular_after_failure`)."""
    if int(fields["failure"]) == 0:
        return fields
    if not bool(singular_after_failure(problem, t0, y)):
        return fields
    nan = lambda a: None if a is None else jnp.full_like(a, jnp.nan)
    states = ("gamma", "gamma_dot", "omega0", "dcm", "attitude", "control_state", "X", "X_dot", "orthogonality")
    failure = jnp.asarray(int(Failure.SINGULAR_START), jnp.result_type(fields["failure"]))
    start = problem.state(t0, y)
    return dict(fields, failure=failure, t_final=t0, final=start, **{k: nan(fields[k]) for k in states})


def _check_attitude_and_laws(attitude, controller, law) -> AbstractAttitude:
    """The attitude variables of `attitude`, once `controller` and `law` are checked too."""
    try:
        att = get_attitude(attitude)
    except ValueError as e:
        raise SceneError(f"simulate: {e}") from None
    if controller is not None and not isinstance(controller, AbstractController):
        raise SceneTypeError(f"simulate: controller must be an AbstractController, got {short(controller)}")
    if law is not None and not callable(law):
        raise SceneTypeError(f"simulate: law must be a callable tau(t, state, params), got {short(law)}")
    return att


def _check_saveat(saveat, t0, t1):
    """``(saveat, grid, user_saveat)``: a SaveAt (used as is), a number of evenly spaced save
    times (`grid`; saveat None) or an array of times, checked with `t0` and `t1`."""
    grid, user_saveat = None, False
    if isinstance(saveat, dfx.SaveAt):
        if saveat.subs is None:
            raise SceneError("simulate: saveat: the SaveAt must save at least one time (t0, t1, ts or steps)")
        user_saveat = True
    elif saveat is None or (isinstance(saveat, (int, np.integer)) and not isinstance(saveat, bool)):
        grid = DEFAULT_SAVE_POINTS if saveat is None else int(saveat)
        if grid < 2:
            raise SceneError(f"simulate: saveat: need at least 2 save points, got {grid}")
        saveat = None
    else:
        shape = jnp.shape(saveat) if is_traced(saveat) else as_float(saveat, "simulate: saveat", finite=False).shape
        if len(shape) != 1:
            raise SceneError(
                f"simulate: saveat: expected a number of save points or a 1-D array of times, got shape {shape}"
            )
    check_times("simulate", t0, t1, None if grid is not None or user_saveat else saveat)
    return saveat, grid, user_saveat


def _bucketed(saveat, grid, exact: bool, t0, t1, dtype):
    """``(saveat, grid, n)``: the save times of an eager run (a number of evenly spaced ones made
    on the host, :func:`.core.grid_times`, or the user's array) padded with the last to their
    :func:`.core.save_bucket`, and `n` the number asked for: one program for grids and arrays of times
    alike. With `exact` (a user's SaveAt, or traced inputs: the caller's program is compiled for
    its shapes anyway) nothing changes and `n` is None."""
    if exact:
        return saveat, grid, None
    ts = grid_times(t0, t1, grid, np.dtype(dtype)) if grid is not None else np.asarray(saveat, dtype)
    if ts.shape[0] == 0:
        return saveat, grid, None
    return padded_times(ts, FIRST_BUCKET), None, ts.shape[0]


_HISTORIES = (
    "ts", "gamma", "gamma_dot", "omega0", "dcm", "attitude", "control_state", "X", "X_dot",
    "hold_torque", "energy", "angular_momentum", "orthogonality",
)  # fmt: skip


def _cut(fields: dict, n: int) -> dict:
    """The histories of `fields` and its diffrax solution's saves cut to their first `n` rows."""
    size = fields["ts"].shape[0]
    raw = fields["raw"]
    if raw is not None:
        raw = dataclasses.replace(raw, ts=cut_rows(raw.ts, size, n), ys=cut_rows(raw.ys, size, n))
    return dict(fields, raw=raw, **{k: cut_rows(fields[k], size, n) for k in _HISTORIES})


def _check_finite_start(y0: State, X0, Xd0, t0, att: AbstractAttitude) -> None:
    """Raise SimulationError for a concrete start that is not finite."""
    start = [np.asarray(x, float) for x in (*y0, *(() if X0 is None else (X0, Xd0)))]
    if not all(np.all(np.isfinite(x)) for x in start):
        # (under jit the solver would reject every step until max_steps: NaN step sizes)
        raise SimulationError(format_failure("nonfinite_start", t0, y0, np.nan, np.nan, att.name))


def _diagnostics(fields: dict, model: Model, law, controller, params, count=None) -> tuple[Any, Any, Any]:
    """``(energy, angular momentum, hold torques)`` of the run's `fields` (see
    :func:`run_diagnostics`); of their first `count` rows alone when given (a padded save grid)."""
    needs_law = model.prescription is not None
    out = run_diagnostics(
        model,
        law if needs_law else None,
        controller if needs_law else None,
        params if needs_law else None,
        fields["ts"],
        State(fields["dcm"], fields["omega0"], fields["gamma"], fields["gamma_dot"]),
        fields["control_state"] if needs_law else None,
        count=None if count is None else jax.device_put(np.asarray(count, np.int32)),
    )
    return out[0], out[1], out[2]
