"""Failures of a run and their one report: the failure kinds (:class:`Failure`), the host callback
that reports them (one call for a whole batch), the message of one failed member of Eq. (1)'s runs
(the time, the state and a diagnosis: a singular Eq. (1) matrix and the direction it loses, an
attitude singularity) and :class:`SimulationError`. :func:`jaxtree.simulate_hybrid` and the
campaigns report through the same :func:`failure_report` with their own text.
"""

from __future__ import annotations

import enum

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.dynamics import (
    SINGULAR_CONDITION,
    matrix_condition,
    null_direction_text,
    rotational_equations,
)
from ..vehicle.model import Model, State


class Failure(enum.IntEnum):
    """How a run ended: ``Solution.failure`` / ``HybridSolution.failure`` hold these codes (0 is
    success). The names, lower-cased, are the kinds result files and campaigns record."""

    NONE = 0
    MAX_STEPS = 1  # the solver's step limit
    DT_MIN = 2  # the step size collapsed below DTMIN_FRACTION of the span
    SINGULAR_ATTITUDE = 3  # the Euler angles' singularity guard (Eq. 24) fired
    OTHER = 4  # any other solver failure
    NONFINITE_START = 5  # the initial state is not finite: not integrated
    SINGULAR_START = 6  # Eq. (1) singular to working precision at the start: not integrated

    @property
    def kind(self) -> str:
        return self.name.lower()


# the failure kinds by code - 1 (the codes' names as result files and campaigns spell them)
KINDS = tuple(f.kind for f in Failure if f is not Failure.NONE)


MESSAGES = {
    "max_steps": "the maximum number of solver steps was reached (increase max_steps, or the motion became singular)",
    "dt_min": "the step size collapsed (the accelerations became singular or non-finite)",
    "singular_attitude": "the attitude angles approach their singularity (|cos theta_2| fell below the "
    "tolerance of Eq. 24); use attitude='quaternion' or 'dcm'",
    "other": "the solver failed",
    "nonfinite_start": "the initial state is not finite",
    "singular_start": "the Eq. (1) matrix is singular at the initial state to working precision (a pivot of its "
    "Cholesky factorization is at round-off level): the accelerations are undetermined",
}


def failure_kind(code) -> str | None:
    """The kind of the first failed member of a code (array), or None when all succeeded."""
    code = np.asarray(code).reshape(-1)
    bad = np.flatnonzero(code)
    return None if bad.size == 0 else KINDS[int(code[bad[0]]) - 1]


class SimulationError(RuntimeError):
    """A simulation stopped early: step-size collapse, max_steps, a singular Eq. (1) matrix,
    a non-finite state or an attitude singularity. The message gives the time and the state."""


def report_failures(host, failed, args, extra=None):
    """Call ``host(*args, *extra(args))`` on the host at run time when a run `failed`: one call
    for a whole ``jax.vmap`` batch, none when every run succeeded.

    ``jax.debug.callback`` alone is unrolled by vmap into one callback per batch member (a
    campaign of 4096 runs: 4096 host calls, and compile and run times that grow with the
    batch); this custom batching rule hands the batch to a single callback instead (`host`
    takes arrays with leading batch axes, as a batch of solutions has). The call, and `extra`
    (diagnostics that cost a decomposition, computed per run), sit behind a ``lax.cond`` on
    "some run failed", so a successful run pays neither (simulate's fixed cost per call). `args`
    carry no gradient (`stop_gradient`): reporting does not enter derivatives."""

    def call(failed, args):
        more = ()
        if extra is not None:
            fn = extra
            for _ in range(jnp.ndim(failed)):  # one vmap per batch axis
                fn = jax.vmap(fn)
            more = tuple(fn(*args))
        jax.debug.callback(host, *args, *more)

    @jax.custom_batching.custom_vmap
    def report(failed, args):
        jax.lax.cond(jnp.any(failed), call, lambda f, a: None, failed, args)
        return jnp.zeros((), jnp.int32)

    @report.def_vmap
    def _batched(axis_size, in_batched, failed, args):
        bf, ba = in_batched
        failed = failed if bf else jnp.broadcast_to(failed, (axis_size,) + jnp.shape(failed))
        args = jax.tree_util.tree_map(
            lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + jnp.shape(x)), args, ba
        )
        report(failed, args)
        return jnp.zeros((axis_size,), jnp.int32), True

    report(failed, args)


def failure_report(code, describe):
    """The message for the failed members of a (batch of) run(s), or None if none failed.

    `code` holds ``KINDS`` indices + 1 (0: success), with the batch's leading axes; for the
    first three failed members ``describe(kind, pick)`` gives the lines of one report, where
    ``pick(x)`` takes that member's entry of an array with the same leading axes."""
    code = np.asarray(code)
    flat = code.reshape(-1)
    bad = np.flatnonzero(flat)
    if bad.size == 0:
        return None
    msgs = []
    for b in bad[:3]:
        idx = np.unravel_index(b, code.shape) if code.ndim else ()
        pick = lambda x, idx=idx: np.asarray(x)[idx]
        prefix = f"[batch index {tuple(int(i) for i in idx)}] " if code.ndim else ""
        msgs.append(prefix + describe(KINDS[int(flat[b]) - 1], pick))
    if bad.size > 3:
        msgs.append(f"... and {bad.size - 3} more failed batch members")
    return "\n".join(msgs)


def result_code(result, singular: bool | jax.Array = False):
    """The :class:`Failure` code of a failed diffrax result (whatever it is; success is masked
    by the caller): step limit, step-size collapse, a singular attitude (`singular`), or other."""
    R = dfx.RESULTS
    return jnp.where(
        result == R.max_steps_reached,
        int(Failure.MAX_STEPS),
        jnp.where(
            result == R.dt_min_reached,
            int(Failure.DT_MIN),
            jnp.where(singular, int(Failure.SINGULAR_ATTITUDE), int(Failure.OTHER)),
        ),
    )


# ----------------------------------------------------------------------------- Eq. (1)'s report
def condition_at(model: Model, state: State, t):
    """Condition number and near-null direction of the Eq. (1) matrix at a state
    (:func:`jaxtree._src.equations.dynamics.matrix_condition`)."""
    return matrix_condition(model, rotational_equations(model, state, t)[0])


condition_jit = eqx.filter_jit(condition_at)


def attitude_margin(problem, y):
    m = problem.attitude.margin(problem.unpack(y)[0])
    return jnp.asarray(jnp.nan, y.dtype) if m is None else m


def format_failure(
    kind, t, state: State, condition, margin, attitude_name, result_message="", direction=None, labels=None
):
    np.set_printoptions(precision=6, suppress=False, linewidth=120)
    lines = [f"jaxtree.simulate: {MESSAGES[kind]}."]
    if result_message:
        lines.append(f"  diffrax: {result_message}")
    lines.append(f"  stopped at t = {float(t):.9g}")
    lines.append(f"  omega0 = {np.asarray(state.omega0)}")
    lines.append(f"  gamma = {np.asarray(state.gamma)}")
    lines.append(f"  gamma_dot = {np.asarray(state.gamma_dot)}")
    lines.append(f"  C = {np.asarray(state.dcm).tolist()}")
    finite = all(np.all(np.isfinite(np.asarray(x))) for x in state)
    if not finite:
        lines.append("  diagnosis: the state is not finite")
    c = float(condition)
    if np.isnan(c):
        pass
    elif not np.isfinite(c) or c > SINGULAR_CONDITION:
        where = (
            null_direction_text(direction, labels)
            if direction is not None and labels is not None and np.all(np.isfinite(np.asarray(direction)))
            else "for a gimbal this is gimbal lock"
        )
        lines.append(f"  diagnosis: the Eq. (1) matrix is singular or nearly so (condition number {c:.3g}); {where}")
    if attitude_name == "euler123" and np.isfinite(float(margin)):
        lines.append(f"  attitude ({attitude_name}) singularity margin |cos theta_2| - tol = {float(margin):.3g}")
    return "\n".join(lines)


def raise_failures(code, t, state, condition, margin, attitude_name, direction=None, labels=None):
    def describe(kind, pick):
        return format_failure(
            kind,
            pick(t),
            State(*(pick(x) for x in state)),
            pick(condition),
            pick(margin),
            str(attitude_name),
            direction=None if direction is None else pick(direction),
            labels=labels,
        )

    message = failure_report(code, describe)
    if message is not None:
        raise SimulationError(message)
