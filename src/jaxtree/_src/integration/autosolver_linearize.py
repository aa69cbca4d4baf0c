"""The run's right side linearized and sampled for ``solver="auto"`` (:mod:`.autosolver`): its
Jacobian at the initial state by central differences and the right side at :data:`SAMPLES`
times over the run, from one vmapped program each. :func:`jacobian_and_samples` for any
``field(t, y, args)`` (the hybrid model's), :func:`equation_jacobian_and_samples` for Eq. (1)'s
matrix and right side (no solve; its accelerations held). Returns numpy arrays.
"""

from __future__ import annotations

import jax
import numpy as np

from ..numerics import program_jit
from ..vehicle.model import State

# Times at which the right side is sampled over the run (the load's edges and its changes).
SAMPLES = 128


@program_jit
def _field_batch(field, ts, ys, args):
    return jax.vmap(lambda t, y: field(t, y, args))(ts, ys)


# relative step of the central differences (about eps^(1/3): truncation and round-off balanced)
FD_STEP = 2.0**-18


def _differences(y):
    """The states ``y +- h_i e_i`` (2n, n) of the central differences and the steps `h`. numpy
    on the host (y is concrete here): a handful of JAX operations called one by one would each
    be compiled, in every process."""
    y = np.asarray(y)
    h = FD_STEP * np.maximum(np.abs(y), 1.0)
    return np.concatenate([y + np.diag(h), y - np.diag(h)]), np.asarray(h, float)


def jacobian_and_samples(field, t0, y, ts, args):
    """``d f / d y`` at ``(t0, y)`` by central differences and ``f(t_j, y)`` at the times `ts`,
    all from one vmapped program of the right side `field(t, y, args)` (cheaper to compile than a
    forward-mode Jacobian, and free of host callbacks, so the persistent cache keeps it). numpy."""
    n = np.shape(y)[0]
    ys, h = _differences(y)
    ts = np.asarray(ts)
    ys = np.concatenate([ys, np.broadcast_to(np.asarray(y), (ts.shape[0], n))])
    tt = np.concatenate([np.full(2 * n, t0, ts.dtype), ts])
    out = np.asarray(_field_batch(field, tt, ys, args), float)
    A = (out[:n] - out[n : 2 * n]).T / (2 * h)[None, :]
    return A, out[2 * n :]


def _equation_parts(t, y, problem):
    """At a flat state of `problem`: the attitude variables' rates, and Eq. (1)'s matrix and right
    side on the rows of ``omega0`` and the unknown hinges (prescribed accelerations moved to the
    right side; the hinge law's torque included). No solve."""
    import jax.numpy as jnp

    from ..equations.dynamics import rotational_equations
    from ..vehicle import hinges

    model = problem.model
    att, w, g_u, gd_u, z, _, _ = problem.unpack(y)
    gamma, gamma_dot, gdd_p = hinges.from_free(model, t, g_u, gd_u)
    state = State(problem.attitude.to_dcm(att), w, gamma, gamma_dot)
    tau = problem.torque(t, state, problem._unravel_control(z))
    M, rhs = rotational_equations(model, state, t, None if tau is None else jnp.asarray(tau, gamma.dtype))
    if gdd_p is not None:
        cols = 3 + np.asarray(model.prescribed, np.int64) - 1
        rhs = rhs - M[:, cols] @ gdd_p
    rows = np.concatenate([np.arange(3), 3 + np.asarray(model.unknown_hinges, np.int64) - 1])
    return problem.attitude.rate(att, w), M[np.ix_(rows, rows)], rhs[rows]


@program_jit
def _parts_batch(ts, ys, problem, base: int):
    kin, M, rhs = jax.vmap(lambda t, y: _equation_parts(t, y, problem))(ts, ys)
    return kin, M[base:], rhs


def equation_jacobian_and_samples(problem, t0, y, ts):
    """``(A, F)``: the Jacobian of `problem`'s right side at ``(t0, y)`` and the right side at
    ``y`` at the times `ts`, from one vmapped program of Eq. (1)'s matrix and right side (no
    solve; central differences of the right side). The rows of the accelerations are
    ``M^-1 d(rhs)/dy``: Eq. (1) with its current accelerations held, without ``-M^-1 (dM/dy)
    M^-1 rhs``. That term linearizes a vehicle that starts far from equilibrium (a preloaded stiff
    spring gives real eigenvalues of either sign, which the spring's snap erases within
    microseconds); Eq. (42) leaves it out too. The rows of a controller's states and of Eq. (2)
    are left zero. numpy."""
    n = np.shape(y)[0]
    m = len(ts)
    ys, h = _differences(y)
    ts = np.asarray(ts)
    ys = np.concatenate([ys, np.broadcast_to(np.asarray(y), (m, n))])
    tt = np.concatenate([np.full(2 * n, t0, ts.dtype), ts])
    kin, M, rhs = (np.asarray(x, float) for x in _parts_batch(tt, ys, problem, 2 * n))
    two_h = (2 * h)[None, :]
    o = problem._offsets()
    nu = problem.n_unknown
    acc_rows = np.concatenate([np.arange(o[1], o[2]), o[3] + hinges_free_positions(problem)])
    A = np.zeros((n, n))
    A[o[0] : o[1]] = (kin[:n] - kin[n : 2 * n]).T / two_h
    A[acc_rows] = np.linalg.solve(M[0], (rhs[:n] - rhs[n : 2 * n]).T / two_h)
    A[np.arange(o[2], o[3]), np.arange(o[3], o[3] + nu)] = 1.0
    F = np.zeros((m, n))
    F[:, o[0] : o[1]] = kin[2 * n :]
    F[:, o[2] : o[3]] = np.asarray(y, float)[o[3] : o[4]]
    F[:, acc_rows] = np.linalg.solve(M, rhs[2 * n :][..., None])[..., 0]
    return A, F


def hinges_free_positions(problem) -> np.ndarray:
    """Positions of the unknown hinges among the problem's free hinges (its state's hinges)."""
    free = list(problem.free_hinges)
    return np.asarray([free.index(k) for k in problem.model.unknown_hinges], np.int64)


def sample_times(t0: float, t1: float, dtype) -> np.ndarray:
    return np.linspace(t0, t1, SAMPLES).astype(dtype)
