"""Radau IIA of order 5 for stiff ODEs, after the RADAU5 code: a diffrax solver that keeps its
Jacobian and LU factorizations between steps.

Method
------
The 3-stage Radau IIA collocation method of Hairer & Wanner, *Solving Ordinary Differential
Equations II* (2nd ed., Springer 1996), Sec. IV.8, as implemented in their Fortran code RADAU5.
Its nodes are the Radau right points

    c = ((4 - √6)/10, (4 + √6)/10, 1),

with the Butcher matrix

    A = [[(88 - 7√6)/360,     (296 - 169√6)/1800, (-2 + 3√6)/225],
         [(296 + 169√6)/1800, (88 + 7√6)/360,     (-2 - 3√6)/225],
         [(16 - √6)/36,       (16 + √6)/36,       1/9           ]],

and b = the last row of A (stiffly accurate: y1 = Y3). The method has order 5 (stage order 3)
and is L-stable.

Each step solves the stage equations for Z_i = Y_i - y0, Z = h (A ⊗ I) F(Z), by simplified Newton
iteration in the variables W = (T⁻¹ ⊗ I) Z, where T brings A⁻¹ to the block form

    T⁻¹ A⁻¹ T = diag(γ, [[α, -β], [β, α]]),
    γ = 3 + 3^(2/3) - 3^(1/3) ≈ 3.6378,  α = 3 + (3^(1/3) - 3^(2/3))/2 ≈ 2.6811,
    β = (3^(5/6) + 3^(7/6))/2 ≈ 3.0504.

T's columns are the real eigenvector of A⁻¹ and the real and imaginary parts of the eigenvector of
α - iβ, each scaled to a last component of 1 (this is scipy's Radau T with its third column
negated, as the tests check; any scaling of the columns gives the same method). The 3n×3n Newton system then splits into one real system with
the matrix (γ/h) I - J and one complex system with ((α + iβ)/h) I - J, J = ∂f/∂y. The iteration
stops as RADAU5 does: with the contraction rate θ of the last two increments and
η = θ/(1 - θ) (RADAU5's FACCON, carried from step to step), when η ‖ΔW‖ ≤ κ; it fails on
divergence (θ ≥ 0.99), when the rate predicts that `max_newton` iterations will not reach κ,
after `max_newton` iterations, or on a non-finite value. ‖·‖ is the step-size controller's norm
(RMS by default) of ΔW / (atol + rtol |y0|). The starting values are the previous step's
collocation polynomial extrapolated to the new stage times (RADAU5 with STARTN = .FALSE.), or zero
on the first step and after a jump.

Error estimate (RADAU5's subroutine ESTRAD; Hairer & Wanner IV.8, "Error estimation")::

    err = ((γ/h) I - J)⁻¹ [f(t0, y0) + (e1 Z1 + e2 Z2 + e3 Z3)/h],
    e = (-(13 + 7√6)/3, (-13 + 7√6)/3, -1/3),

the difference of the solution and an embedded method of order 3 (local error O(h⁴); hence
`error_order` is 4, which gives the controller RADAU5's exponent 1/4), filtered through the
real Newton matrix. On the first step, after a jump and on a retried step, when this estimate
fails the controller's test it is replaced, as RADAU5 does, by
((γ/h) I - J)⁻¹ [f(t0, y0 + err) + (e·Z)/h], which stays bounded for very stiff components.

What is reused and when
-----------------------
The solver state (:class:`Radau5State`) holds J, the LU factors of both Newton matrices (the
complex one in complex dtype, through `jax.scipy.linalg.lu_factor`), the step size h_LU they were
factored for, and the time J was evaluated at. As in RADAU5:

* J is evaluated (by `jax.jacfwd` of the vector field, or the `jacobian` option) at the start of
  a step only when the previous step's Newton iteration converged slowly (θ > `jac_refresh`,
  RADAU5's THET; 0.1 here, its advice for costly Jacobians), after a jump (`made_jump`), or when
  the step looks like a retry (below). The first step evaluates it at (t0, y0) (not `init`: the
  compiled program then holds one Jacobian). J carries no derivative: its value and its inputs
  are cut by `stop_gradient` (a derivative of the run does not trace J's own), and Eq. (1)'s
  derivative rule inside it is traced for forward use only (`numerics.forward_only`).
* The two matrices are factored again only when J was refreshed or the step size left the window
  `factor_window` = [quot1, quot2] around h_LU (h/h_LU < quot1 or > quot2, with a relative slack
  of 64 ε of the time dtype, since t1 - t0 reproduces h_LU only up to rounding). Inside the
  window the iteration keeps the old matrices and only the right-hand sides use the new h (RADAU5
  instead keeps h itself; here the step-size controller chooses h); the error estimate is rescaled
  by h/h_LU, so that it is the filter (I - h_LU γ⁻¹ J)⁻¹ applied to the same difference of the two
  methods.

The skipped work is skipped with `jax.lax.cond` (under `jax.vmap` the conditionals become selects
and both branches run, so a batched solve pays for a Jacobian and two factorizations every step).

Rejected steps: diffrax discards the state a rejected step returns (`integration/core.py` keeps
`state.solver_state` wherever the controller did not keep the step), so nothing learned in a
failed attempt survives it. RADAU5 evaluates J again after every rejection (unless J is already
current). Here a retry is recognised by its step size instead: diffrax's `PIDController` never
shrinks the step after an accepted step, so a step shorter than 0.99 times the last accepted
one is taken to be a retry (or the last, clipped step of the interval, where one more Jacobian
costs little), and J is evaluated again at (t0, y0). A retry whose step is still longer than the
last accepted one (after a large increase proposed by the controller) keeps the old J and only
refactors; if its Newton iteration fails as well, the next, shorter retry refreshes J.

Failed Newton iterations are signalled the diffrax way: `y_error` is infinite and the result is
`RESULTS.nonlinear_divergence` / `nonlinear_max_steps_reached` / `nonfinite`. An adaptive
controller then rejects the step and shrinks it by its `factormin` (0.2 by default) and discards
the result; with a constant step size the failure ends the solve.

Tolerances of the Newton iteration: the solver is an `AbstractImplicitSolver` whose `root_finder`
only carries rtol, atol and norm; by default diffeqsolve copies them from the adaptive step-size
controller (as for Kvaerno5). With `ConstantStepSize`, pass them explicitly, e.g.
``Radau5(root_finder=diffrax.VeryChord(rtol=1e-8, atol=1e-8, norm=optimistix.rms_norm))``.
The default κ is RADAU5's FNEWT, max(10 ε/rtol, min(0.03, √rtol)) (ε the unit roundoff); diffrax
compares the error estimate directly with rtol, which plays the part of RADAU5's internally
transformed tolerance.

Dense output
------------
:class:`~.radau_collocation.Radau5Interpolation` evaluates the collocation polynomial, the cubic
through (t0, y0) and (t0 + c_i h, y0 + Z_i): order 3 between the step points (local error O(h⁴)).

Statistics
----------
`Radau5State` counts Jacobian evaluations (`num_jac`, including the first step's), factorization
events (`num_lu`, each factoring both matrices), Newton iterations (`num_newton`) and evaluations
of the vector field outside the Jacobian (`num_rhs`; three per Newton iteration). Read them from
``diffeqsolve(..., saveat=diffrax.SaveAt(..., solver_state=True)).solver_state.stats``. Because
diffrax rolls the state back on rejected steps, they count the work of the accepted step attempts
only; ``sol.stats["num_rejected_steps"]`` says how many attempts were discarded (each cost at most
one Jacobian, one factorization and `max_newton` iterations).

Where the parts live
--------------------
This module holds the solver (:class:`Radau5State`, :class:`Radau5`: the Newton iteration, the
error estimate, the reuse of J and its factors). The method's coefficients and its collocation
polynomial (the dense output) are in :mod:`.radau_collocation`; the LU factorizations, which stay
inline under ``vmap`` on a CPU, in :mod:`.lu`; the Jacobians that :func:`jaxtree.simulate` and
:func:`jaxtree.simulate_hybrid` give the solver, by parts, in :mod:`.jacobian`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import diffrax as dfx
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax import Array
from jax.flatten_util import ravel_pytree

from ..numerics import forward_only
from .lu import lu_factor, lu_solve
from .radau_collocation import ALPHA, BETA, GAMMA, T_INV, C, E, Radau5Interpolation, T, lagrange_weights

__all__ = ["Radau5", "Radau5Interpolation", "Radau5State"]


def _mix(m: np.ndarray | Array, z: Array) -> Array:
    """`m @ z` for a 3×3 coefficient matrix and a (3, n) block of stage vectors, at full precision."""
    return jnp.dot(jnp.asarray(m, dtype=z.dtype), z, precision=jax.lax.Precision.HIGHEST)


class Radau5State(eqx.Module):
    """Solver state of :class:`Radau5`, carried from step to step (see the module docstring).

    `stats` gathers the four counters.
    """

    jac: Array  # (n, n) ∂f/∂y at (t_jac, y(t_jac))
    t_jac: Array  # the time J was evaluated at
    lu_real: Array  # LU factors of (γ/h_lu) I - J
    piv_real: Array
    lu_complex: Array  # LU factors of ((α + iβ)/h_lu) I - J, complex dtype
    piv_complex: Array
    h_lu: Array  # the step size the factors belong to (NaN: none yet)
    h_last: Array  # the last accepted step size (in `init`: the first step size)
    zs: Array  # (3, n) stage increments Z_i of the last accepted step
    started: Array  # whether `zs` and `h_last` describe an accepted step
    refresh_jac: Array  # the last step converged slowly (θ > jac_refresh): evaluate J next step
    theta: Array  # the Newton contraction rate of the last step
    faccon: Array  # RADAU5's FACCON, η = θ/(1 - θ) of the last step
    num_jac: Array
    num_lu: Array
    num_newton: Array
    num_rhs: Array

    @property
    def stats(self) -> dict[str, Array]:
        """Jacobian evaluations, factorizations, Newton iterations and vector-field evaluations."""
        return {
            "num_jac": self.num_jac,
            "num_lu": self.num_lu,
            "num_newton": self.num_newton,
            "num_rhs": self.num_rhs,
        }


def _with_tols():
    return dfx.with_stepsize_controller_tols(dfx.VeryChord)()


# the marker diffeqsolve replaces by the step-size controller's rtol, atol and norm
_FROM_CONTROLLER = _with_tols().rtol


class Radau5(dfx.AbstractImplicitSolver[Radau5State], dfx.AbstractAdaptiveSolver[Radau5State]):
    """Radau IIA of order 5 (Hairer & Wanner's RADAU5) with Jacobian and LU reuse across steps.

    **Arguments** (all optional):

    - `newton_tol`: κ of the Newton stopping test η ‖ΔW‖ ≤ κ (scaled norm). Default `None`:
      RADAU5's max(10 ε/rtol, min(0.03, √rtol)).
    - `max_newton`: the most Newton iterations per step (RADAU5's NIT, 7).
    - `jac_refresh`: evaluate J again at the next step when the contraction rate θ exceeded this
      (RADAU5's THET). Default 0.1, the value Hairer and Wanner advise when a Jacobian is costly
      (RADAU5's own default, 0.001, suits cheap ones): a Jacobian of Eq. (1) costs tens of right
      sides (flex95's slew: 5 Jacobians instead of 9, to the same accuracy at 0.8x the time,
      benchmarks/FINDINGS.md). A negative value refreshes J every step.
    - `jac_iterations`: ... and only when the Newton iteration took at least this many steps
      (2: RADAU5, where θ exists from the second iteration on; 3: scipy's Radau, lazier).
    - `factor_window`: (quot1, quot2); the Newton matrices are factored again only when J was
      refreshed or h/h_LU leaves this interval (RADAU5's QUOT1, QUOT2: 1.0, 1.2).
    - `jacobian`: optional `(t, y, args) -> J`, J the (n, n) derivative of the raveled vector field
      with respect to the raveled state (`jax.flatten_util.ravel_pytree` order); replaces
      `jax.jacfwd` of the vector field.
    - `root_finder`: carries only the rtol, atol and norm of the Newton test; by default taken
      from the adaptive step-size controller (as for diffrax's Kvaerno solvers). With a constant
      step size pass e.g. `diffrax.VeryChord(rtol=..., atol=..., norm=optimistix.rms_norm)`.

    Only ODE terms (`diffrax.ODETerm`, control t1 - t0) are supported. Use with
    `diffrax.PIDController`; `error_order` is 4 (the embedded estimate is of order 3), `order` 5.
    """

    term_structure: ClassVar = dfx.AbstractTerm
    interpolation_cls: ClassVar[Callable[..., Radau5Interpolation]] = Radau5Interpolation

    newton_tol: float | None = eqx.field(default=None, static=True)
    max_newton: int = eqx.field(default=7, static=True)
    jac_refresh: float = eqx.field(default=0.1, static=True)
    jac_iterations: int = eqx.field(default=2, static=True)
    factor_window: tuple[float, float] = eqx.field(default=(1.0, 1.2), static=True)
    jacobian: Callable[..., Array] | None = None
    root_finder: optx.AbstractRootFinder = eqx.field(default_factory=_with_tols)

    @property
    def root_find_max_steps(self) -> int:  # pyright: ignore[reportIncompatibleVariableOverride]
        return self.max_newton

    def order(self, terms: Any) -> int:
        return 5

    def error_order(self, terms: Any) -> float:
        return 4

    # ---------------------------------------------------------------------------------------
    # helpers

    def _tols(self):
        rtol = getattr(self.root_finder, "rtol", None)
        atol = getattr(self.root_finder, "atol", None)
        norm = getattr(self.root_finder, "norm", None)
        if not (callable(norm) and rtol is not None and atol is not None) or any(
            x is _FROM_CONTROLLER for x in (rtol, atol, norm)
        ):
            raise ValueError(
                "Radau5 needs the tolerances of its Newton iteration: use an adaptive step-size "
                "controller (diffrax.PIDController(rtol=..., atol=...)) or pass "
                "root_finder=diffrax.VeryChord(rtol=..., atol=..., norm=optimistix.rms_norm)."
            )
        return rtol, atol, norm

    @staticmethod
    def _unit(terms, dtype):
        # d(control)/dt: +1, or -1 when diffeqsolve integrates backward (WrapTerm)
        return jnp.asarray(terms.contr(jnp.zeros((), dtype), jnp.ones((), dtype)), dtype=dtype)

    def _rhs(self, terms, args, unravel, dtype, unit):
        def fun(t, y_flat):
            out = terms.vf_prod(t, unravel(y_flat), args, unit)
            return ravel_pytree(out)[0].astype(dtype)

        return fun

    def _jacobian(self, terms, t, y_flat, unravel, args, unit):
        """J at ``(t, y)``: `jacobian`, or ``jax.jacfwd`` of the vector field. J carries no
        derivative, and neither do its inputs: a derivative of the run would otherwise trace J's
        own derivative (second derivatives of the vector field) only to drop it; and the tangents
        of Eq. (1) inside are traced for forward use only (:func:`jaxtree._src.numerics.forward_only`)."""
        dtype = y_flat.dtype
        t, y_flat, unit = jax.lax.stop_gradient((t, y_flat, unit))
        dyn, static = eqx.partition((terms, args), eqx.is_array)
        terms, args = eqx.combine(jax.lax.stop_gradient(dyn), static)
        with forward_only():
            if self.jacobian is None:
                fun = self._rhs(terms, args, unravel, dtype, unit)
                jac = jax.jacfwd(lambda y: fun(t, y))(y_flat)
            else:
                jac = jnp.asarray(self.jacobian(t * unit, unravel(y_flat), args), dtype=dtype) * unit
        return jax.lax.stop_gradient(jac.reshape(y_flat.size, y_flat.size))

    @staticmethod
    def _factor(jac, h, dtype):
        n = jac.shape[0]
        eye = jnp.eye(n, dtype=dtype)
        cdtype = jnp.promote_types(dtype, jnp.complex64)
        lu_r, piv_r = lu_factor((GAMMA / h) * eye - jac)
        shift = jnp.asarray(ALPHA + 1j * BETA, dtype=cdtype) / h.astype(cdtype)
        lu_c, piv_c = lu_factor(shift * eye.astype(cdtype) - jac.astype(cdtype))
        return jax.lax.stop_gradient((lu_r, piv_r, lu_c, piv_c))

    # ---------------------------------------------------------------------------------------

    def init(self, terms, t0, t1, y0, args) -> Radau5State:
        y_flat, _ = ravel_pytree(y0)
        dtype = y_flat.dtype
        if not jnp.issubdtype(dtype, jnp.floating):
            raise TypeError(f"Radau5 needs a floating-point state, got {dtype}")
        n = y_flat.size
        tdtype = jnp.result_type(t0, t1)
        cdtype = jnp.promote_types(dtype, jnp.complex64)
        i32 = lambda v: jnp.asarray(v, dtype=jnp.int32)
        # no Jacobian here: the first step evaluates it (refresh_jac), so that the compiled
        # program holds the Jacobian once (it is the largest part of the compile time)
        return Radau5State(
            jac=jnp.zeros((n, n), dtype),
            t_jac=jnp.asarray(jnp.nan, dtype=tdtype),
            lu_real=jnp.zeros((n, n), dtype),
            piv_real=jnp.zeros((n,), jnp.int32),
            lu_complex=jnp.zeros((n, n), cdtype),
            piv_complex=jnp.zeros((n,), jnp.int32),
            h_lu=jnp.asarray(jnp.nan, dtype=tdtype),
            h_last=jnp.asarray(t1, dtype=tdtype) - jnp.asarray(t0, dtype=tdtype),
            zs=jnp.zeros((3, n), dtype),
            started=jnp.asarray(False),
            refresh_jac=jnp.asarray(True),
            theta=jnp.asarray(self.jac_refresh, dtype=dtype),
            faccon=jnp.asarray(1.0, dtype=dtype),
            num_jac=i32(0),
            num_lu=i32(0),
            num_newton=i32(0),
            num_rhs=i32(0),
        )

    def _reuse(self, st, terms, t0, h_t, y_flat, unravel, args, unit, made_jump):
        """The Jacobian and the factorizations of this step: kept from the state, or new when
        Newton asked for it, after a rejected step or a jump, or when h left the factor window."""
        dtype = y_flat.dtype
        retry = h_t < 0.99 * st.h_last  # see the module docstring: rejected attempts are forgotten
        jac_current = (st.t_jac == t0) & ~made_jump
        new_jac = (st.refresh_jac | retry | made_jump) & ~jac_current
        jac = jax.lax.cond(new_jac, lambda: self._jacobian(terms, t0, y_flat, unravel, args, unit), lambda: st.jac)
        quot1, quot2 = self.factor_window
        ratio = h_t / st.h_lu
        slack = 64 * jnp.finfo(h_t.dtype).eps  # h recomputed as t1 - t0 differs from h_lu by roundoff
        new_lu = new_jac | ~((ratio >= quot1 * (1 - slack)) & (ratio <= quot2 * (1 + slack)))  # NaN: factor
        lus = jax.lax.cond(
            new_lu,
            lambda: self._factor(jac, h_t.astype(dtype), dtype),
            lambda: (st.lu_real, st.piv_real, st.lu_complex, st.piv_complex),
        )
        return jac, new_jac, lus, new_lu, retry

    def _newton(self, fun, stage_t, h, y_flat, z_start, faccon0, lus, rtol, atol, norm):
        """The simplified Newton iteration on the collocation system (Hairer and Wanner IV.8):
        ``(k, z, theta, faccon, status)``, status 1 converged, 2 non-finite, 3 diverged or too
        slow, 4 out of iterations."""
        dtype = y_flat.dtype
        cdtype = jnp.promote_types(dtype, jnp.complex64)
        eps = jnp.finfo(dtype).eps
        lu_r, piv_r, lu_c, piv_c = lus
        scale = atol + rtol * jnp.abs(y_flat)
        if self.newton_tol is None:
            kappa = jnp.maximum(10 * eps / rtol, jnp.minimum(0.03, jnp.sqrt(rtol)))
        else:
            kappa = self.newton_tol
        kappa = jnp.asarray(kappa, dtype=dtype)
        nit = self.max_newton
        gamma_h = GAMMA / h
        shift_h = jnp.asarray(ALPHA + 1j * BETA, dtype=cdtype) / h.astype(cdtype)

        def body(carry):
            k, w, z, dynold, thqold, theta, faccon, _ = carry
            fs = jax.vmap(fun)(stage_t, y_flat + z)
            rhs = _mix(T_INV, fs)
            d_real = lu_solve((lu_r, piv_r), rhs[0] - gamma_h * w[0])
            d_cplx = lu_solve(
                (lu_c, piv_c), (rhs[1] + 1j * rhs[2]).astype(cdtype) - shift_h * (w[1] + 1j * w[2]).astype(cdtype)
            )
            dw = jnp.stack([d_real, d_cplx.real, d_cplx.imag])
            dyno = jnp.asarray(norm(dw / scale), dtype=dtype)
            k = k + 1
            check = (k > 1) & (k < nit)
            thq = dyno / dynold
            theta_k = jnp.where(k == 2, thq, jnp.sqrt(thq * thqold))
            theta = jnp.where(check, theta_k, theta)
            thqold = jnp.where(check, thq, thqold)
            diverged = check & ~(theta < 0.99)
            faccon = jnp.where(check & ~diverged, theta / (1 - theta), faccon)
            dyth = faccon * dyno * theta ** (nit - 1 - k) / kappa
            too_slow = check & ~diverged & (dyth >= 1)
            dynold = jnp.maximum(dyno, eps)
            w = w + dw
            z = _mix(T, w)
            nonfinite = ~jnp.isfinite(dyno)
            converged = (faccon * dyno <= kappa) & ~diverged & ~too_slow & ~nonfinite
            exhausted = (k >= nit) & ~converged
            status = jnp.select(
                [converged, nonfinite, diverged | too_slow, exhausted],
                [1, 2, 3, 4],
                0,
            ).astype(jnp.int32)
            return k, w, z, dynold, thqold, theta, faccon, status

        def not_done(carry):
            return carry[7] == 0

        zero = jnp.zeros((), dtype)
        init = (
            jnp.asarray(0, jnp.int32),
            _mix(T_INV, z_start),
            z_start,
            zero,
            zero,
            jnp.asarray(abs(self.jac_refresh), dtype=dtype),
            jnp.maximum(faccon0, eps) ** 0.8,
            jnp.asarray(0, jnp.int32),
        )
        k, _, z, _, _, theta, faccon, status = eqxi.while_loop(not_done, body, init, max_steps=nit, kind="checkpointed")
        return k, z, theta, faccon, status

    @staticmethod
    def _error(fun, t0, y_flat, z, h, h_lu, lus, again, scaled):
        """The error estimate ``(err, right sides used)``: ``err = (h / h_lu) (gamma / h - J)^{-1}
        (f(t0, y0) + ez)``; where `again` says so (a first step or a retry whose estimate fails),
        once more with ``f(t0, y0 + err)`` (Hairer-Wanner IV.8). One loop of one or two passes, so
        that the compiled step holds the vector field once here, not twice."""
        lu_r, piv_r = lus[0], lus[1]
        ez = _mix(E[None, :], z)[0] / h
        fix = h / h_lu  # the matrix was factored for h_lu (see the module docstring)

        def err_body(carry):
            i, _, x = carry
            e = fix * lu_solve((lu_r, piv_r), fun(t0, x) + ez)
            return i + 1, e, y_flat + e

        def err_more(carry):
            i, e, _ = carry
            return (i == 0) | ((i == 1) & again & ~(scaled(e) < 1))

        nf_err, err, _ = eqxi.while_loop(
            err_more,
            err_body,
            (jnp.asarray(0, jnp.int32), jnp.zeros_like(y_flat), y_flat),
            max_steps=2,
            kind="checkpointed",
        )
        return err, nf_err

    def step(self, terms, t0, t1, y0, args, solver_state: Radau5State, made_jump):
        st = solver_state
        rtol, atol, norm = self._tols()
        y_flat, unravel = ravel_pytree(y0)
        dtype = y_flat.dtype
        unit = self._unit(terms, dtype)
        fun = self._rhs(terms, args, unravel, dtype, unit)
        tdtype = st.h_last.dtype
        t0 = jnp.asarray(t0, dtype=tdtype)
        h_t = jnp.asarray(t1, dtype=tdtype) - t0
        h = h_t.astype(dtype)
        made_jump = jnp.asarray(made_jump, dtype=bool)
        fresh_start = made_jump | ~st.started
        jac, new_jac, lus, new_lu, retry = self._reuse(st, terms, t0, h_t, y_flat, unravel, args, unit, made_jump)
        h_lu_t = jnp.where(new_lu, h_t, st.h_lu)

        # starting values: the last collocation polynomial, extrapolated
        c = jnp.asarray(C, dtype=dtype)
        weights = lagrange_weights(1.0 + c * (h_t / st.h_last).astype(dtype))  # (3 new stages, 3 old)
        z_extrap = _mix(weights, st.zs) - st.zs[2]
        z_start = jnp.where(fresh_start, jnp.zeros_like(st.zs), z_extrap)
        stage_t = t0 + jnp.asarray(C, dtype=tdtype) * h_t
        k, z, theta, faccon, status = self._newton(fun, stage_t, h, y_flat, z_start, st.faccon, lus, rtol, atol, norm)
        ok = status == 1

        # solution and error estimate
        y1_flat = y_flat + z[2]

        def scaled(e):
            y_max = jnp.maximum(jnp.abs(y_flat), jnp.abs(y1_flat))
            return jnp.asarray(norm(e / (atol + rtol * y_max)))

        again = (fresh_start | retry) & ok
        err, nf_err = self._error(fun, t0, y_flat, z, h, h_lu_t.astype(dtype), lus, again, scaled)
        err = jnp.where(ok, err, jnp.inf)
        failure = dfx.RESULTS.where(
            status == 4,
            dfx.RESULTS.promote(optx.RESULTS.nonlinear_max_steps_reached),
            dfx.RESULTS.promote(optx.RESULTS.nonlinear_divergence),
        )
        failure = dfx.RESULTS.where(status == 2, dfx.RESULTS.promote(optx.RESULTS.nonfinite), failure)
        result = dfx.RESULTS.where(ok, dfx.RESULTS.successful, failure)

        lu_r, piv_r, lu_c, piv_c = lus
        new_state = Radau5State(
            jac=jac,
            t_jac=jnp.where(new_jac, t0, st.t_jac),
            lu_real=lu_r,
            piv_real=piv_r,
            lu_complex=lu_c,
            piv_complex=piv_c,
            h_lu=h_lu_t,
            h_last=h_t,
            zs=z,
            started=jnp.asarray(True),
            refresh_jac=((theta > self.jac_refresh) & (k >= self.jac_iterations)) | ~ok,
            theta=theta,
            faccon=faccon,
            num_jac=st.num_jac + new_jac.astype(jnp.int32),
            num_lu=st.num_lu + new_lu.astype(jnp.int32),
            num_newton=st.num_newton + k,
            num_rhs=st.num_rhs + 3 * k + nf_err,
        )
        dense_info = dict(y0=y0, zs=jax.vmap(unravel)(z))
        return unravel(y1_flat), unravel(err), dense_info, new_state, result

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)


def with_jacobian(solver, jacobian):
    """`solver`; a :class:`Radau5` without a Jacobian of its own gets `jacobian` (``jacobian(t, y,
    args)``: the driver's structured one, :meth:`~jaxtree.Problem.jacobian` or
    :func:`jaxtree.hybrid_jacobian`)."""
    if isinstance(solver, Radau5) and solver.jacobian is None:
        return eqx.tree_at(lambda s: s.jacobian, solver, jacobian, is_leaf=lambda x: x is None)
    return solver
