"""The one integration of jaxtree's two drivers, :func:`jaxtree.simulate` (Eq. 1 in the first-order
form of Eqs. 25-27) and :func:`jaxtree.simulate_hybrid` (Eqs. 118 and 121): a problem goes in, a
run comes out, as in diffrax's ``diffeqsolve`` (each driver makes its choices before: the
attitude variables, the solver, the save times; and builds its solution after). Both check the
same things, in this order:

1. the start: finite, and Eq. (1)'s matrix regular in the vehicle's configuration there (one
   elimination of its unknown rows in JAX, :func:`singular_configuration`); a start that fails either
   cannot be integrated (NaN error estimates give NaN steps until ``max_steps``; an exactly
   singular matrix can even give finite garbage), so the vehicle at rest is integrated in its
   place (a vmapped batch does not wait for it) and the run reports ``nonfinite_start`` or
   ``singular_start`` with NaN histories. An eager run leaves the matrix out of its program and
   tests it only when the run failed (:func:`singular_after_failure`): such a start fails within
   a few rejected steps;
2. the default step-size controller (:func:`.core.default_controller`) and, where the driver has
   one, its first step;
3. the loop (:func:`.core.integrate`: the history at the save times and the final state);
4. the failure code (:class:`.failures.Failure`: 0 for a run that reached t1 or a user's event).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..equations.dynamics import mass_matrix, unknown_rows
from ..numerics import regular_pivots, spd_inverse
from .core import default_controller, integrate
from .events import guard_any
from .failures import Failure, result_code


class Driven(NamedTuple):
    """A run of :func:`drive`: the history (`ts`, `ys`), where it ended, diffrax's solution, the
    failure code, whether the attitude angles reached their singularity, and the user's event
    mask (None without one)."""

    ts: jax.Array
    ys: jax.Array
    t_final: jax.Array
    y_final: jax.Array
    sol: dfx.Solution
    failure: jax.Array
    singular: jax.Array
    event_mask: Any


def singular_configuration(model, gamma):
    """True when Eq. (1)'s matrix in the configuration `gamma` is singular to working precision
    (a pivot of its unknown rows' LDL^T factorization at round-off level, or a failed one:
    :func:`~jaxtree._src.numerics.regular_pivots`): one elimination, no eigenvalues, no rates or
    loads. The elimination is :func:`~jaxtree._src.numerics.spd_inverse`'s, in JAX: no LAPACK call,
    whose batched form splits over XLA's thread pool and can deadlock two device shards (so a
    campaign's members can stay vmapped on every device)."""
    A = mass_matrix(model, gamma)
    u = unknown_rows(model)
    A = A[np.ix_(u, u)]
    return ~regular_pivots(spd_inverse(A)[1], A)


def singular_start(args, t0, y) -> jax.Array:
    """True when the flat start `y` at `t0` of a problem `args` (a :class:`~jaxtree.Problem` or a
    :class:`~jaxtree.HybridModel`: its ``model`` and the physical ``state(t, y)``) is finite and
    singular (:func:`singular_configuration`; a start that is not finite is reported as such)."""
    return jnp.all(jnp.isfinite(y)) & singular_configuration(args.model, args.state(t0, y).gamma)


@eqx.filter_jit
def singular_after_failure(args, t0, y) -> jax.Array:
    """:func:`singular_start` as one small program: what an eager run asks once it has failed."""
    return singular_start(args, t0, y)


def drive(
    field: Callable,
    args,
    y,
    t0,
    t1,
    *,
    solver,
    controller,
    rtol,
    atol,
    dt0,
    rest,
    max_steps: int,
    ts=None,
    saveat=None,
    adjoint=None,
    event=None,
    guard: tuple[bool, bool] = (False, False),
    progress_meter=None,
    check_start: bool = False,
    first_step: Callable | None = None,
) -> Driven:
    """Integrate ``dy/dt = field(t, y, args)`` from the flat start `y` (steps 1-4 above).

    `args`: the problem (with `check_start`, its ``model`` and physical ``state(t, y)`` give the
    test of a singular start, :func:`singular_start`); `rest`: the flat state integrated in place
    of a start that cannot be; `controller`: None for the default, whose
    first step is `dt0` or else ``first_step(y)`` (None: diffrax's); `guard`: ``(has_guard,
    user_event)``, whether the event includes the attitude angles' singularity guard and a user's
    event (the guard's mask after the user's); `ts`, `saveat`, `adjoint`, `event`, `max_steps`,
    `progress_meter`: those of :func:`.core.integrate`."""
    finite_start = jnp.all(jnp.isfinite(y))
    singular = jnp.zeros((), bool)
    if check_start:
        singular = singular_start(args, t0, jax.lax.stop_gradient(y))
    start_ok = finite_start & ~singular
    if controller is None:
        controller = default_controller(rtol, atol, t0, t1)
        if dt0 is None and first_step is not None:
            # a choice of the discretization, not a function to differentiate (BacksolveAdjoint
            # refuses a first step that carries a tangent)
            dt0 = jax.lax.stop_gradient(first_step(jnp.where(start_ok, y, rest)))
    ts_h, ys_h, t_final, y_final, sol = integrate(
        field,
        solver,
        t0,
        t1,
        dt0,
        y,
        args,
        ts=ts,
        saveat=saveat,
        controller=controller,
        adjoint=adjoint,
        event=event,
        max_steps=max_steps,
        progress_meter=progress_meter,
        start_ok=start_ok,
        rest=rest,
    )
    mask, singular_attitude = sol.event_mask, jnp.asarray(False)
    has_guard, user_event = guard
    if has_guard:
        mask, guard_mask = mask if user_event else (None, mask)
        singular_attitude = guard_any(guard_mask)
    R = dfx.RESULTS
    ok = (sol.result == R.successful) | ((sol.result == R.event_occurred) & ~singular_attitude)
    failure = jnp.where(
        start_ok,
        jnp.where(ok, 0, result_code(sol.result, singular_attitude)),
        jnp.where(singular, int(Failure.SINGULAR_START), int(Failure.NONFINITE_START)),
    )
    return Driven(ts_h, ys_h, t_final, y_final, sol, failure, singular_attitude, mask)
