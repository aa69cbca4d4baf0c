"""jaxtree's Radau5 (Radau IIA of order 5 after Hairer & Wanner's RADAU5) as a diffrax solver.

Independent sources of the expected numbers: scipy's Radau implementation (its published T, T⁻¹,
eigenvalue and error constants, and `solve_ivp(method="Radau")` at rtol = 1e-10 as the reference
trajectory), `scipy.linalg.expm` for a linear problem, and the method's own defining properties
(order 5, interpolation through the stage values).
"""

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp
from scipy.integrate._ivp import radau as scipy_radau

from jaxtree._src.integration import lu, radau_collocation
from jaxtree._src.integration.radau import Radau5
from jaxtree._src.integration.radau_collocation import Radau5Interpolation

jax.config.update("jax_enable_x64", True)

MU = 1000.0  # Van der Pol stiffness of the adaptive runs
T_VDP = 1000.0
RTOL = ATOL = 1e-6  # rtol = atol of the adaptive runs
# the same solve done another way (vmapped, a hand-written Jacobian): round-off carried through
# the Newton iterations and the step-size control
SAME_RTOL, SAME_ATOL = 1e-9, 1e-12
# the adaptive runs' global error against scipy's reference, relative: a few RTOL at most (Van der Pol
# through its jump: observed 5e-8 and 3e-6, the latter on y2 ~ 1e-3, where it is 4e-9 absolute)
GLOBAL = 10 * RTOL
# Robertson at rtol = 1e-6, atol = 1e-10 against scipy's reference, relative: observed 6e-9, with margin
ROBERTSON = 1e-5
# Van der Pol (mu = 10) from three starts at RTOL, relative to 1 + |y|: observed 2e-7, with margin
VMAP_REFERENCE = 1e-4
FLOAT32 = 2e-3  # a float32 run at rtol = 1e-4 against the float64 reference: a few of its rtol
# the dense output between steps, in units of ATOL + RTOL |y|: observed 1.8 (global error included);
# linear interpolation would be off by ~1e3
DENSE = 10
# the same solve on a split (pytree) state: the same arithmetic, round-off only (atol for Robertson's
# small component)
SPLIT_RTOL, SPLIT_ATOL = 1e-12, 1e-18
# the method's constants against scipy's float64 values: equal or a few ulps of numbers up to 1 (ULPS: C,
# the eigenvalues, the rows of A) and 10 (ULPS_10: T, E), a hundred ulps of the inverse T^-1 (ULPS_100),
# round-off of the collocation polynomial (entries up to 26) and of T^-1 A^-1 T, products of them
# (ROUNDOFF); observed at most 5e-15
ULPS = 1e-15
ULPS_10 = 1e-14
ULPS_100 = 1e-13
ROUNDOFF = 1e-12
# the observed order from halving the constant step, h = 1/10 .. 1/40: the method's 5 (observed 4.97 and
# 4.99), within the pre-asymptotic spread
ORDER_LOW, ORDER_HIGH = 4.5, 5.6
# the interpolating polynomial at its nodes (t0 and the stages) and its increments, O(1) values: a few ulps
INTERP_ULPS = 1e-15
INTERP_STAGES = 1e-14


def vdp(t, y, mu):
    return jnp.stack([y[1], mu * (1.0 - y[0] ** 2) * y[1] - y[0]])


def vdp_jac(t, y, mu):
    return jnp.array([[0.0, 1.0], [-2.0 * mu * y[0] * y[1] - 1.0, mu * (1.0 - y[0] ** 2)]])


def vdp_np(t, y, mu):
    return np.array([y[1], mu * (1.0 - y[0] ** 2) * y[1] - y[0]])


def vdp_jac_np(t, y, mu):
    return np.array([[0.0, 1.0], [-2.0 * mu * y[0] * y[1] - 1.0, mu * (1.0 - y[0] ** 2)]])


def robertson(t, y, args):
    return jnp.stack(
        [
            -0.04 * y[0] + 1e4 * y[1] * y[2],
            0.04 * y[0] - 1e4 * y[1] * y[2] - 3e7 * y[1] ** 2,
            3e7 * y[1] ** 2,
        ]
    )


def robertson_np(t, y):
    return np.array(
        [-0.04 * y[0] + 1e4 * y[1] * y[2], 0.04 * y[0] - 1e4 * y[1] * y[2] - 3e7 * y[1] ** 2, 3e7 * y[1] ** 2]
    )


def reference(fun, t_span, y0, t_eval=None, jac=None, args=()):
    sol = solve_ivp(fun, t_span, y0, method="Radau", rtol=1e-10, atol=1e-12, t_eval=t_eval, jac=jac, args=args or None)
    assert sol.success
    return sol.y


def solve(solver, term, t1, y0, args=None, *, rtol=RTOL, atol=ATOL, dt0=None, saveat=None, pid=(0.0, 1.0)):
    return dfx.diffeqsolve(
        term,
        solver,
        0.0,
        t1,
        dt0,
        y0,
        args=args,
        stepsize_controller=dfx.PIDController(rtol=rtol, atol=atol, pcoeff=pid[0], icoeff=pid[1]),
        saveat=saveat or dfx.SaveAt(t1=True, solver_state=True),
        max_steps=20_000,
    )


@eqx.filter_jit
def vdp_solve(y0, solver=None):
    """Van der Pol, mu = 1000, over T_VDP = 1000 s (through the first relaxation jump, at t ~ 807)
    at rtol = atol = 1e-6."""
    return solve(Radau5() if solver is None else solver, dfx.ODETerm(vdp), T_VDP, y0, MU)


# ------------------------------------------------------------------------------------------
# constants


def test_constants_agree_with_scipy_radau():
    assert np.allclose(radau_collocation.C, scipy_radau.C, rtol=0, atol=ULPS)
    assert np.isclose(radau_collocation.GAMMA, scipy_radau.MU_REAL, rtol=ULPS)
    assert np.isclose(radau_collocation.ALPHA - 1j * radau_collocation.BETA, scipy_radau.MU_COMPLEX, rtol=ULPS)
    # the same eigenvectors; scipy takes the conjugate one (third column of opposite sign)
    assert np.allclose(radau_collocation.T * [1, 1, -1], scipy_radau.T, rtol=0, atol=ULPS_10)
    assert np.allclose(radau_collocation.T_INV * [[1], [1], [-1]], scipy_radau.TI, rtol=0, atol=ULPS_100)
    assert np.allclose(radau_collocation.E, scipy_radau.E, rtol=0, atol=ULPS_10)
    # scipy's P[i] holds the coefficients of tau, tau^2, tau^3 of the collocation polynomial
    assert np.allclose(radau_collocation.LAGRANGE[:, 2::-1], scipy_radau.P, rtol=0, atol=ROUNDOFF)
    assert np.allclose(radau_collocation.LAGRANGE[:, 3], 0.0)
    # the defining block form of the transformation
    block = radau_collocation.T_INV @ np.linalg.inv(radau_collocation.A) @ radau_collocation.T
    expected = np.array(
        [
            [radau_collocation.GAMMA, 0, 0],
            [0, radau_collocation.ALPHA, -radau_collocation.BETA],
            [0, radau_collocation.BETA, radau_collocation.ALPHA],
        ]
    )
    assert np.allclose(block, expected, rtol=0, atol=ROUNDOFF)
    assert np.allclose(radau_collocation.A.sum(axis=1), radau_collocation.C, atol=ULPS)


# ------------------------------------------------------------------------------------------
# order of convergence


def test_order_five_on_a_linear_problem_with_a_stiff_mode():
    """y' = A y, eigenvalues -1 ± 5i and -1000, constant steps h = 1/10, 1/20, 1/40 to t = 1.

    The stiff mode is damped to e^-1000 by the flow and to |R(-100)|^10 ~ 1e-16 (R the stability
    function, |R(-100)| = 0.025) by the method, so the global error at t = 1 is the order-5 error
    of the oscillatory pair (2e-5 .. 2e-8), far above rounding. With constant steps the Newton
    tolerances come from the root_finder.
    """
    s = np.array([[1.0, 0.3, -0.2], [0.1, 1.0, 0.4], [-0.3, 0.2, 1.0]])
    d = np.array([[-1.0, 5.0, 0.0], [-5.0, -1.0, 0.0], [0.0, 0.0, -1000.0]])
    a = s @ d @ np.linalg.inv(s)
    y0 = np.array([1.0, -0.5, 2.0])
    exact = scipy.linalg.expm(a) @ y0
    solver = Radau5(root_finder=dfx.VeryChord(rtol=1e-13, atol=1e-13, norm=optx.rms_norm))
    term = dfx.ODETerm(lambda t, y, args: jnp.asarray(a) @ y)

    @jax.jit
    def run(dt):
        sol = dfx.diffeqsolve(
            term, solver, 0.0, 1.0, dt, jnp.asarray(y0), stepsize_controller=dfx.ConstantStepSize(), max_steps=64
        )
        return sol.ys[-1], sol.stats["num_steps"]

    errors = []
    for n in (10, 20, 40):
        y1, steps = run(1.0 / n)
        assert int(steps) == n
        errors.append(np.linalg.norm(np.asarray(y1) - exact))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[-1] > 1e-10, errors
    assert np.all((orders > ORDER_LOW) & (orders < ORDER_HIGH)), (errors, orders)


# ------------------------------------------------------------------------------------------
# stiff adaptive solves, reuse of the Jacobian and the factorizations


@pytest.fixture(scope="module")
def vdp_reference():
    return reference(vdp_np, (0.0, T_VDP), [2.0, 0.0], t_eval=[T_VDP], jac=vdp_jac_np, args=(MU,))[:, -1]


def test_van_der_pol_stiff_against_scipy(vdp_reference):
    sol = vdp_solve(jnp.array([2.0, 0.0]))
    assert sol.result == dfx.RESULTS.successful
    y = np.asarray(sol.ys[-1])
    rel = np.abs(y - vdp_reference) / np.abs(vdp_reference)
    assert np.all(rel < GLOBAL), rel  # the global error through the jump
    stats = {k: int(v) for k, v in sol.solver_state.stats.items()}
    accepted = int(sol.stats["num_accepted_steps"])
    assert 0 < stats["num_jac"] < accepted
    assert stats["num_lu"] <= accepted + 1
    assert stats["num_newton"] >= accepted
    # three per Newton iteration, f(t0, y0) unless it came with a Jacobian, and the second error
    # estimates
    assert 3 * stats["num_newton"] <= stats["num_rhs"] <= 3 * stats["num_newton"] + 2 * accepted


def test_robertson_reuses_jacobian_and_factorizations():
    """Robertson's kinetics to t = 1e5 (steps from 1e-6 to 1e4). With RADAU5's setting for costly
    Jacobians (THET = 0.1), J is evaluated for fewer than a third of the steps, and fewer matrices
    are factored than steps are taken; the answer stays at the tolerance."""
    t1 = 1e5
    ref = reference(lambda t, y: robertson_np(t, y), (0.0, t1), [1.0, 0.0, 0.0], t_eval=[t1])[:, -1]
    sol = solve(Radau5(jac_refresh=0.1), dfx.ODETerm(robertson), t1, jnp.array([1.0, 0.0, 0.0]), rtol=1e-6, atol=1e-10)
    assert sol.result == dfx.RESULTS.successful
    rel = np.abs(np.asarray(sol.ys[-1]) - ref) / np.abs(ref)
    assert np.all(rel < ROBERTSON), rel
    steps = int(sol.stats["num_steps"])
    stats = {k: int(v) for k, v in sol.solver_state.stats.items()}
    assert stats["num_jac"] <= steps / 3, (stats, steps)
    assert stats["num_lu"] < steps / 1.5, (stats, steps)


# ------------------------------------------------------------------------------------------
# states, precisions, transformations


def test_pytree_state_matches_flat_vector():
    def split(t, y, args):
        f = robertson(t, jnp.concatenate(y), args)
        return f[:1], f[1:]

    y0 = jnp.array([1.0, 0.0, 0.0])
    flat = solve(Radau5(), dfx.ODETerm(robertson), 100.0, y0, atol=1e-10)
    tree = solve(Radau5(), dfx.ODETerm(split), 100.0, (y0[:1], y0[1:]), atol=1e-10)
    assert int(tree.stats["num_steps"]) == int(flat.stats["num_steps"])
    np.testing.assert_allclose(
        np.concatenate([tree.ys[0][-1], tree.ys[1][-1]]), flat.ys[-1], rtol=SPLIT_RTOL, atol=SPLIT_ATOL
    )
    assert int(tree.solver_state.num_jac) == int(flat.solver_state.num_jac)


def test_float32():
    """A float32 state (and float32 times, otherwise diffrax promotes the state to the time dtype)
    at rtol = 1e-4 stays finite and within a few rtol of the float64 reference."""
    mu = 100.0
    t1 = 200.0
    ref = reference(vdp_np, (0.0, t1), [2.0, 0.0], t_eval=[t1], jac=vdp_jac_np, args=(mu,))[:, -1]
    sol = dfx.diffeqsolve(
        dfx.ODETerm(vdp),
        Radau5(),
        jnp.float32(0.0),
        jnp.float32(t1),
        None,
        jnp.array([2.0, 0.0], dtype=jnp.float32),
        args=jnp.float32(mu),
        stepsize_controller=dfx.PIDController(rtol=1e-4, atol=1e-4),
        max_steps=20_000,
    )
    assert sol.result == dfx.RESULTS.successful
    ys = sol.ys
    assert ys is not None and ys.dtype == jnp.float32
    y = np.asarray(ys[-1], dtype=np.float64)
    assert np.all(np.isfinite(y))
    rel = np.abs(y - ref) / np.maximum(np.abs(ref), 1e-3)
    assert np.all(rel < FLOAT32), (y, ref)


def test_bit_identical_rerun():
    y0 = jnp.array([2.0, 0.0])
    a, b = vdp_solve(y0), vdp_solve(y0)
    assert np.array_equal(np.asarray(a.ys), np.asarray(b.ys))
    assert int(a.stats["num_steps"]) == int(b.stats["num_steps"])
    for k in a.solver_state.stats:
        assert int(a.solver_state.stats[k]) == int(b.solver_state.stats[k])


def test_vmap_over_initial_conditions():
    """Under vmap the conditionals become selects; every member still gets its own answer."""
    mu = 10.0
    y0s = jnp.array([[2.0, 0.0], [1.0, 1.0], [-0.5, 3.0]])

    @jax.jit
    def batch(y0s):
        return jax.vmap(lambda y0: solve(Radau5(), dfx.ODETerm(vdp), 10.0, y0, mu).ys[-1])(y0s)

    ys = np.asarray(batch(y0s))
    for y0, y in zip(np.asarray(y0s), ys):
        ref = reference(vdp_np, (0.0, 10.0), y0, t_eval=[10.0], jac=vdp_jac_np, args=(mu,))[:, -1]
        assert np.all(np.abs(y - ref) <= VMAP_REFERENCE * (1 + np.abs(ref))), (y0, y, ref)
    single = np.asarray(solve(Radau5(), dfx.ODETerm(vdp), 10.0, y0s[1], mu).ys[-1])
    np.testing.assert_allclose(ys[1], single, rtol=SAME_RTOL, atol=SAME_ATOL)


# ------------------------------------------------------------------------------------------
# dense output


def test_interpolation_passes_through_the_stages():
    t0, h = 2.0, 0.5
    y0 = jnp.array([1.0, -2.0])
    zs = jnp.array([[0.1, 0.2], [0.3, -0.1], [0.5, 0.4]])
    interp = Radau5Interpolation(t0=t0, t1=t0 + h, y0=y0, zs=zs)
    np.testing.assert_allclose(interp.evaluate(t0), y0, atol=INTERP_ULPS)
    for c, z in zip(radau_collocation.C, zs):
        np.testing.assert_allclose(interp.evaluate(t0 + c * h), y0 + z, atol=INTERP_STAGES)
    np.testing.assert_allclose(
        interp.evaluate(t0 + 0.2 * h, t0 + 0.7 * h),
        interp.evaluate(t0 + 0.7 * h) - interp.evaluate(t0 + 0.2 * h),
        atol=INTERP_ULPS,
    )


def test_dense_output_between_steps():
    """SaveAt(ts=...) at 201 points of Van der Pol (mu = 10) over 20 s, all but the ends between
    step points: the collocation polynomial (order 3) is within a few tolerances of the reference."""
    mu, t1 = 10.0, 20.0
    ts = np.linspace(0.0, t1, 201)
    ref = reference(vdp_np, (0.0, t1), [2.0, 0.0], t_eval=ts, jac=vdp_jac_np, args=(mu,))
    sol = solve(Radau5(), dfx.ODETerm(vdp), t1, jnp.array([2.0, 0.0]), mu, saveat=dfx.SaveAt(ts=jnp.asarray(ts)))
    assert sol.result == dfx.RESULTS.successful
    ys = np.asarray(sol.ys).T
    scale = ATOL + RTOL * np.abs(ref)
    assert np.max(np.abs(ys - ref) / scale) < DENSE, np.max(np.abs(ys - ref) / scale)


# ------------------------------------------------------------------------------------------
# options and failures


def test_custom_jacobian_matches_jacfwd():
    y0 = jnp.array([2.0, 0.0])
    auto = vdp_solve(y0)
    custom = vdp_solve(y0, Radau5(jacobian=vdp_jac))
    np.testing.assert_allclose(custom.ys, auto.ys, rtol=SAME_RTOL, atol=SAME_ATOL)
    assert int(custom.solver_state.num_jac) == int(auto.solver_state.num_jac)


def test_newton_failure_rejects_the_step_and_the_solve_recovers(vdp_reference):
    term = dfx.ODETerm(vdp)
    y0 = jnp.array([2.0, 0.0])
    # one step of 1000 s from the start: the simplified Newton iteration diverges
    solver = Radau5(root_finder=dfx.VeryChord(rtol=RTOL, atol=ATOL, norm=optx.rms_norm))

    @jax.jit
    def one_step(y0):
        state = solver.init(term, 0.0, 1000.0, y0, MU)
        return solver.step(term, 0.0, 1000.0, y0, MU, state, False)

    _, y_error, _, _, result = one_step(y0)
    assert result != dfx.RESULTS.successful
    assert np.all(np.isinf(np.asarray(y_error)))
    # diffeqsolve starting with that step: rejected (y_error = inf), shrunk, and then completed
    sol = solve(Radau5(), term, T_VDP, y0, MU, dt0=1000.0)
    assert sol.result == dfx.RESULTS.successful
    assert int(sol.stats["num_rejected_steps"]) >= 1
    rel = np.abs(np.asarray(sol.ys[-1]) - vdp_reference) / np.abs(vdp_reference)
    assert np.all(rel < GLOBAL), rel


def test_constant_steps_need_newton_tolerances():
    with pytest.raises(ValueError, match="tolerances"):
        dfx.diffeqsolve(dfx.ODETerm(vdp), Radau5(), 0.0, 1.0, 0.1, jnp.array([2.0, 0.0]), args=MU)


def test_vmapped_factorizations_run_in_inline_groups():
    """Under vmap on a CPU the LU factorizations run in groups whose batched LAPACK
    call stays under jaxlib's threading threshold (~2e5 flops): a larger batch is split over XLA's
    pool and two such calls at once deadlocked a vmapped Radau5 run of 64 stiff chains. Results
    against scipy's LAPACK, matrix by matrix."""
    rng = np.random.default_rng(3)
    n, size = 24, 200
    a = rng.standard_normal((size, n, n)) + 1j * rng.standard_normal((size, n, n)) + 5 * np.eye(n)
    b = rng.standard_normal((size, n)) + 1j * rng.standard_normal((size, n))
    solve = jax.jit(jax.vmap(lambda a, b: lu.lu_solve(lu.lu_factor(a), b)))
    x = np.asarray(solve(jnp.asarray(a), jnp.asarray(b)))
    expected = np.stack([scipy.linalg.lu_solve(scipy.linalg.lu_factor(a[i]), b[i]) for i in range(size)])
    np.testing.assert_allclose(x, expected, rtol=1e-12, atol=1e-12)
    if jax.default_backend() == "cpu":
        group = lu.inline_group(jnp.asarray(a), 2.0 * n**3 / 3.0)
        assert 1 <= group < size
        jaxpr = jax.make_jaxpr(jax.vmap(lu.lu_factor))(jnp.asarray(a)).jaxpr
        shapes = [e.invars[0].aval.shape for e in _equations(jaxpr) if e.primitive.name == "lu"]
        assert shapes and all(s[0] <= group for s in shapes), shapes


def _equations(jaxpr):
    """The equations of `jaxpr` and of every jaxpr nested in their parameters."""
    for e in jaxpr.eqns:
        yield e
        for p in e.params.values():
            for q in p if isinstance(p, (tuple, list)) else (p,):
                inner = getattr(q, "jaxpr", q)
                if hasattr(inner, "eqns"):
                    yield from _equations(inner)
