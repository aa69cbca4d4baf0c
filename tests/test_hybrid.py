"""Tests of jaxtree.hybrid: the hybrid-coordinate equations of Likins (1972), Sec. III E, Eqs. 105-123.

Every expected number comes from outside the hybrid code:

- Eq. (30) from :func:`jaxtree.linearized_equations` (jacfwd of Eq. 1, validated against the
  Lagrange oracle in test_linearize.py), solved here for the accelerations and integrated by
  scipy's DOP853 in physical coordinates (the hybrid model with all modes is only a change of
  coordinates of Eq. 30);
- the full nonlinear Eq. (1) (:func:`jaxtree.forward_dynamics`, validated against the oracle in
  test_dynamics.py) integrated by scipy's DOP853, with the direction cosines of Eq. (3);
- eigenvalues of the first-order matrix B of Eq. (71) by scipy's general eigensolver;
- Appendix C: the printed equations C-70..C-73 written out by hand and integrated by scipy.

Tolerances. The integrations run at rtol = atol = 1e-11 (``TOL``). Two such integrations of the
same equations in different coordinates agree to their global error: a few hundred accepted steps
of an 8th-order method, each with a local error below TOL times the state size (states of order
1 to 30), observed at 1e-11 .. 2e-10 on these runs; ``SAME`` = 2e-8 leaves a margin of 100.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla
from scipy.integrate import solve_ivp

import jaxtree
from jaxtree import State
from jaxtree._src.equations.kinematics import tilde

from helpers import appendix_c

TOL = 1e-11  # rtol = atol of the reference integrations (module docstring)
SAME = 2e-8  # two TOL integrations of the same motion agree to this (observed <= 2e-10; module docstring)
# float64 identities of O(1) numbers (packing, mode shapes, energy, projection residual): round-off
ROUNDOFF = 1e-12
FD_JACOBIAN = 1e-7  # central differences (h = 1e-6) against an exact Jacobian, relative to its largest entry
# the precomputed substructure terms against the general form of Eq. (118), relative to the largest
# entry: round-off of two different summations over the bodies
ROUNDOFF_EQ118 = 1e-11
# against scipy's eigenvalues of B and the modal normalizations (Eqs. 89-90, 116): the conditioning
# of the non-symmetric first-order eigenproblem
EIGENSOLVER = 1e-9
# the same frequencies taken from another object (selected, retained): equal to a few ulps
SAME_NUMBERS = 1e-14
FIG4_SMALL = (5, 6, 7, 8, 9, 10)  # all panel hinges: a terminal appendage (Sec. III A, Fig. 4)
FIG4_SPIN = [0.0, 0.0, 0.3]  # nominal omega0 of the modes: spinning, so the modes are gyroscopic


# ----------------------------------------------------------------------------- references
@eqx.filter_jit
def eq1_rhs(model, t, x):
    """Full nonlinear Eq. (1) with Eq. (3): x = [C (9), omega0, gamma (n), gamma_dot (n)]."""
    n = model.n
    C, w, g, gd = x[:9].reshape(3, 3), x[9:12], x[12 : 12 + n], x[12 + n :]
    wd, gdd = jaxtree.forward_dynamics(model, C, w, g, gd, t)
    return jnp.concatenate([(-tilde(w) @ C).ravel(), wd, gd, gdd])


def eq30_accelerations(model, small, large, t, C, w, gL, gdL, y, yd):
    """Eq. (30) solved for [omega0_dot, gamma_ddot_L, y''] from jaxtree.linearized_equations: its
    residual is affine in the accelerations, so the matrix is r(e_i) - r(0)."""
    n = model.n
    S = np.asarray(small) - 1
    L = np.asarray(large, dtype=int) - 1
    G = np.asarray(model.prescribed, dtype=int) - 1
    gamma = jnp.zeros(n).at[L].set(gL)
    gamma_dot = jnp.zeros(n).at[L].set(gdL)
    gddG = jnp.zeros(len(G))
    if len(G):
        g, gd, gddG = model.prescription.derivatives(t)
        gamma, gamma_dot = gamma.at[G].set(g), gamma_dot.at[G].set(gd)
    nx = 3 + len(L) + len(S)
    rows = np.concatenate([np.arange(3), L + 3, S + 3])

    def residual(x):
        gdd = jnp.zeros(n).at[L].set(x[3 : 3 + len(L)]).at[G].set(gddG)
        lin = jaxtree.linearized_equations(
            model, small, State(C, w, gamma, gamma_dot), omega0_dot=x[:3], gamma_ddot=gdd, t=t
        )
        r = lin.residual + lin.accel @ x[3 + len(L) :] + lin.rate @ yd + lin.angle @ y
        return r[rows]

    r = jax.vmap(residual)(jnp.concatenate([jnp.zeros((1, nx)), jnp.eye(nx)]))
    return jnp.linalg.solve((r[1:] - r[0]).T, -r[0])


# One compilation per model structure and set A (pass t as an array: equinox makes Python floats static).
eq30_acc = eqx.filter_jit(eq30_accelerations)


def eq30_rhs(model, small, large):
    """Eq. (30) in physical coordinates for scipy: x = [C (9), omega0, gamma_L, gamma_dot_L, y, y']."""
    nl, nu = len(large), len(small)
    o = np.cumsum([0, 9, 3, nl, nl, nu, nu])

    def rhs(t, x):
        C, w, gL, gdL, y, yd = (x[o[i] : o[i + 1]] for i in range(6))
        C = C.reshape(3, 3)
        acc = np.asarray(eq30_acc(model, small, large, jnp.asarray(t), C, w, gL, gdL, y, yd))
        return np.concatenate([(-np.asarray(tilde(w)) @ C).ravel(), acc[:3], gdL, acc[3 : 3 + nl], yd, acc[3 + nl :]])

    return rhs


def integrate(fun, x0, T, ts):
    sol = solve_ivp(
        lambda t, x: np.asarray(fun(t, x)), (0.0, T), np.asarray(x0), t_eval=ts, method="DOP853", rtol=TOL, atol=TOL
    )
    assert sol.success, sol.message
    return sol.y.T


# ----------------------------------------------------------------------------- fixtures
def fig4_initial(model, amp):
    """Large motion (omega0, gimbal angles, the rotor at 10 pi rad/s, the prescribed platform) with
    the panels deflected by `amp` (angles) and 2 amp (rates) in a fixed pattern."""
    g0, gd0, _ = model.prescription.derivatives(jnp.asarray(0.0))
    gamma = np.zeros(model.n)
    gamma_dot = np.zeros(model.n)
    gamma[[1, 2]] = [0.25, -0.15]
    gamma_dot[[1, 2, 3]] = [0.1, -0.2, 10 * np.pi]
    gamma[0], gamma_dot[0] = float(g0[0]), float(gd0[0])
    S = np.asarray(FIG4_SMALL) - 1
    gamma[S] = amp * np.array([1.0, -0.6, 0.8, 0.3, -0.5, 0.7])
    gamma_dot[S] = 2 * amp * np.array([-0.4, 0.9, 0.2, -0.7, 0.5, 0.1])
    return State(jnp.eye(3), jnp.array([0.05, -0.04, 0.1]), jnp.asarray(gamma), jnp.asarray(gamma_dot))


@pytest.fixture(scope="module")
def fig4():
    """Fig. 4 with gamma_1 prescribed (Sec. III F), A = the six panel hinges (terminal), gimbal
    and rotor large: the general (jvp) path with gyroscopic first-order modes (Eq. 118).

    The platform's mass center is moved 0.25 m off its hinge axis (the scene has it on the axis),
    so that its prescribed acceleration couples to the panel angles at first order (the caret part
    of a_{.1} in the G terms of Eq. 30c)."""
    model = jaxtree.load_scene("fig4")
    model = eqx.tree_at(lambda m: m.hinge_on_body, model, model.hinge_on_body.at[0].set(jnp.array([0.25, 0, -0.3])))
    hm = jaxtree.hybrid_model(model, FIG4_SMALL, omega0=FIG4_SPIN, basis="set")
    assert hm.form == "first_order" and hm.kind == "gyroscopic" and hm.precomputed
    assert hm.large == (2, 3, 4) and hm.n_modes == 6
    return model, hm


@pytest.fixture(scope="module")
def appendix():
    """Fig. C-1 with both rod hinges small and omega0 the only large variable: the precomputed
    (polynomial) path with real modes (Eq. 121), modes on the nominal spin Omega b3."""
    model, p = appendix_c()
    hm = jaxtree.hybrid_model(model, (1, 2), omega0=[0.0, 0.0, 1.0], basis="set")
    assert hm.form == "real" and hm.precomputed and hm.n_modes == 2 and hm.large == ()
    return model, p, hm


T_FIG4, TS_FIG4 = 2.0, np.linspace(0.0, 2.0, 21)


@pytest.fixture(scope="module")
def fig4_run(fig4):
    """The all-mode hybrid run of Fig. 4 at panel amplitude 0.05 (shared by two tests)."""
    model, hm = fig4
    state = fig4_initial(model, 0.05)
    hyb, sol = hybrid_history(hm, state, T_FIG4, TS_FIG4)
    return state, hyb, sol


def full_history(model, state, T, ts):
    x0 = jnp.concatenate([state.dcm.ravel(), state.omega0, state.gamma, state.gamma_dot])
    X = integrate(lambda t, x: eq1_rhs(model, jnp.asarray(t), x), x0, T, ts)
    n = model.n
    return dict(dcm=X[:, :9].reshape(-1, 3, 3), omega0=X[:, 9:12], gamma=X[:, 12 : 12 + n])


def hybrid_history(hm, state, T, ts):
    sol = jaxtree.simulate_hybrid(hm, T, y0=state, saveat=ts, rtol=TOL, atol=TOL)
    return dict(dcm=np.asarray(sol.dcm), omega0=np.asarray(sol.omega0), gamma=np.asarray(sol.gamma)), sol


def max_diff(a, b, keys=("dcm", "omega0", "gamma"), cols=None):
    out = 0.0
    for k in keys:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        if k == "gamma" and cols is not None:
            x, y = x[:, cols], y[:, cols]
        out = max(out, float(np.abs(x - y).max()))
    return out


# ----------------------------------------------------------------------------- Eq. (30), right side
rhs_jit = eqx.filter_jit(jaxtree.hybrid_rhs)
equations_jit = eqx.filter_jit(jaxtree.hybrid_equations)


def modal_jacobian(h, y):
    """d(right side of Eq. 118)/d(modal state) at fixed large variables. Eq. (30) is linear in the small
    variables, so the right side is affine in s and differences with unit steps are exact."""
    off = h.attitude.size + 3 + 2 * len(h.large)
    r0 = equations_jit(h, 0.0, y)[1]
    cols = [equations_jit(h, 0.0, y.at[off + j].add(1.0))[1] - r0 for j in range(h.m)]
    return np.stack([np.asarray(c) for c in cols], 1)


def hybrid_physical_accelerations(hm, t, y):
    """[omega0_dot, gamma_ddot_L, y''] and the rebuilt y' from the hybrid right side."""
    dy = rhs_jit(t, y, hm)
    a, nl = hm.attitude.size, len(hm.large)
    ds = dy[a + 3 + 2 * nl :]
    if hm.form == "real":
        k = hm.n_modes
        ydd, yd = hm.accel @ ds[k:], hm.positions[:, :k] @ ds[:k]  # s = [eta; eta'], ds = [eta'; eta'']
    else:
        ydd, yd = hm.rates @ ds, hm.positions @ ds
    return jnp.concatenate([dy[a : a + 3], dy[a + 3 + nl : a + 3 + 2 * nl], ydd]), yd


def small_random_state(model, rng, scale=0.3):
    """A random state with hinge angles and rates of order `scale`: the hybrid model's regime of
    small deformations (``helpers.random_state`` draws angles over the full circle)."""
    q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    return State(
        jnp.asarray(q * np.sign(np.linalg.det(q))),
        jnp.asarray(rng.normal(size=3) * 0.5),
        jnp.asarray(rng.normal(size=model.n) * scale),
        jnp.asarray(rng.normal(size=model.n) * scale),
    )


mass_matrix_jvp = eqx.filter_jit(lambda m, g, dg: jax.jvp(lambda q: jaxtree.mass_matrix(m, q), (g,), (dg,)))


def check_rhs_against_eq30(hm, rng, trials=2):
    """At random states the hybrid right side, mapped back to physical accelerations, is the
    solution of Eq. (30) (all modes retained: the modal matrices are square and invertible).
    Returns the largest relative difference and, for a model with prescribed hinges, the size of
    the caret part of the prescribed-acceleration terms relative to the tolerance of the check."""
    model = hm.model
    worst, caret = 0.0, np.inf
    for _ in range(trials):
        t = jnp.asarray(rng.uniform(0, 3))  # an array: a Python float would be static under filter_jit
        y = hm.pack(small_random_state(model, rng))
        st = hm.state(t, y)
        got, yd = hybrid_physical_accelerations(hm, t, y)
        S = np.asarray(hm.small) - 1
        L = np.asarray(hm.large, dtype=int) - 1
        want = eq30_acc(
            model,
            hm.small,
            hm.large,
            t,
            st.dcm,
            st.omega0,
            st.gamma[L],
            st.gamma_dot[L],
            st.gamma[S] - hm.gamma_nominal[S],
            st.gamma_dot[S],
        )
        # Round-off of a solve with condition ~1e4 on O(100) entries: ~1e-11 of the largest entry.
        tol = 1e-10 * float(np.abs(want).max())
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=tol)
        # the kinematic rows of (30d) (first-order form): Gamma_1 Phi Y' = Gamma_2 Phi Y = y'
        np.testing.assert_allclose(np.asarray(yd), np.asarray(st.gamma_dot[S]), atol=ROUNDOFF)
        worst = max(worst, float(np.abs(got - want).max() / np.abs(want).max()))
        if model.prescribed:
            # Eq. (30c) prints the prescribed terms as -sum_G a_0k gamma_ddot_k; Eq. (30) needs bar + caret.
            # The caret part, (d a / d y . y) gamma_ddot_G, moves the accelerations by at least
            # |caret| / |[a]|: compare with the tolerance above.
            G = np.asarray(model.prescribed) - 1
            _, _, gdd = model.prescription.derivatives(t)
            bar = st.gamma.at[S].set(hm.gamma_nominal[S])
            A, dA = mass_matrix_jvp(model, bar, jnp.zeros(model.n).at[S].set(st.gamma[S] - hm.gamma_nominal[S]))
            rows = np.concatenate([np.arange(3), L + 3, S + 3])
            size = float(np.abs(np.asarray(dA[rows][:, G + 3] @ gdd)).max() / np.abs(np.asarray(A)).max())
            caret = min(caret, size / tol)
    return worst, caret


def test_rhs_reproduces_eq30(fig4, appendix):
    """All modes retained: the hybrid right side, mapped back to physical accelerations, equals
    Eq. (30) solved directly, for (a) the general path with gyroscopic first-order modes
    (Eq. 118), a prescribed hinge (with bar + caret coefficients, errata_hybrid.md #2) and large
    gimbal/rotor hinges (Fig. 4, A = 5..10), with the Schur-complement solve of a terminal
    appendage and with the dense solve of the general case; (b) the
    precomputed polynomial path (Appendix C, omega0 the only large variable) with real modes
    (Eq. 121) and (c) with the first-order form forced (Eqs. 122-123)."""
    rng = np.random.default_rng(3)
    _, hm = fig4
    errs, caret = {}, {}
    errs["fig4 A=5..10 first-order (precomputed)"], caret["fig4"] = check_rhs_against_eq30(hm, rng)
    general = jaxtree.hybrid_model(hm.model, FIG4_SMALL, omega0=FIG4_SPIN, basis="set", precompute=False)
    assert not general.precomputed
    errs["fig4 A=5..10 first-order (general)"], _ = check_rhs_against_eq30(general, rng)
    # a coefficient a_01 without its caret part (the OCR's reading of Eq. 30c) would miss by far more
    assert caret["fig4"] > 100.0, caret
    # the dense solve of Eq. (118) (used when A is not a terminal appendage) on the same system
    dense = eqx.tree_at(lambda h: h.modal_inverse, hm, None, is_leaf=lambda x: x is None)
    errs["fig4 A=5..10 first-order, dense solve"], _ = check_rhs_against_eq30(dense, rng)
    app, _, h = appendix
    errs["appendix C real (precomputed)"], _ = check_rhs_against_eq30(h, rng)
    hf = jaxtree.hybrid_model(app, (1, 2), omega0=[0.0, 0.0, 1.0], form="first_order", basis="set")
    assert hf.precomputed and hf.form == "first_order"
    errs["appendix C first-order (precomputed)"], _ = check_rhs_against_eq30(hf, rng)
    print("max relative difference from Eq. (30):", errs)
    print("caret part of the prescribed-acceleration terms / tolerance:", caret)


def test_nominal_modal_block_and_left_eigenvector_scaling(fig4):
    """Eqs. (116)-(117): at the nominal motion the projected small-hinge block is U, and the modal
    rows of the hybrid equations, with the large accelerations held at zero, have exactly the
    eigenvalues +-i sigma of the retained modes (scipy's eig of B, Eq. 71). The left eigenvectors
    Phi' of jaxtree.modes (normalized with P = diag(K, I), Eq. 89) do NOT give U with the nominal
    A_kk = diag(U, I) of (30d) that Eq. (116) names; diag(K, U) Phi' does (errata_hybrid.md #1)."""
    model, hm = fig4
    lin = jaxtree.linearize(model, FIG4_SMALL, omega0=FIG4_SPIN)
    I, J, K = (np.asarray(x) for x in lin)
    md = jaxtree.modes(lin)
    nu = len(FIG4_SMALL)
    B = np.block([[np.zeros((nu, nu)), np.eye(nu)], [-np.linalg.solve(I, K), -np.linalg.solve(I, J)]])
    sigma = np.sort(np.abs(sla.eigvals(B).imag))[::2]
    np.testing.assert_allclose(np.asarray(hm.frequencies), sigma, rtol=EIGENSOLVER)
    np.testing.assert_allclose(
        np.asarray(hm.frequencies), np.asarray(md.frequencies)[list(hm.mode_index)], rtol=SAME_NUMBERS
    )
    # Eq. (116) as printed: Phi'^T A_kk Phi with the nominal A_kk = diag(U, a_bar) of (30d)
    R, Lf = np.asarray(md.right), np.asarray(md.left)
    Pu = sla.block_diag(np.eye(nu), I)
    printed = Lf.T @ Pu @ R
    assert np.abs(printed - np.eye(2 * nu)).max() > 0.4
    np.testing.assert_allclose(Lf.T @ sla.block_diag(K, I) @ R, np.eye(2 * nu), atol=EIGENSOLVER)
    scaled = sla.block_diag(K.T, np.eye(nu)) @ Lf
    np.testing.assert_allclose(scaled.T @ Pu @ R, np.eye(2 * nu), atol=EIGENSOLVER)
    # the hybrid equations at the nominal motion (large variables at their nominal values; the
    # platform held, as in jaxtree.linearize: prescription amplitude zero)
    nominal = State(jnp.eye(3), jnp.asarray(FIG4_SPIN), jnp.zeros(model.n), jnp.zeros(model.n))
    held = eqx.tree_at(lambda m: m.prescription.amplitude, model, jnp.zeros(1))
    for k in (6, 3):
        h = eqx.tree_at(lambda h: h.model, hm.retain(k), held)
        y = h.pack(nominal)
        mat, _ = equations_jit(h, 0.0, y)
        jac = modal_jacobian(h, y)
        nx = 3 + len(h.large)
        act = np.concatenate([np.arange(k), h.n_modes + np.arange(k)])  # the active modal rows and columns
        Mmm = np.asarray(mat)[nx:, nx:][np.ix_(act, act)]
        np.testing.assert_allclose(Mmm, np.eye(2 * k), atol=EIGENSOLVER)
        lam = sla.eigvals(np.linalg.solve(Mmm, jac[nx:][np.ix_(act, act)]))
        np.testing.assert_allclose(np.abs(lam.real).max(), 0.0, atol=1e-8)
        np.testing.assert_allclose(np.sort(np.abs(lam.imag))[::2], sigma[:k], rtol=EIGENSOLVER)
    # modal damping (end of Sec. III E, spinning case): i sigma -> -zeta sigma + i sigma
    zeta = 0.02
    hd = jaxtree.hybrid_model(held, FIG4_SMALL, omega0=FIG4_SPIN, damping=zeta, basis="set")
    y = hd.pack(nominal)
    jac = modal_jacobian(hd, y)
    nx = 6
    mat = np.asarray(equations_jit(hd, 0.0, y)[0])[nx:, nx:]
    lam = sla.eigvals(np.linalg.solve(mat, jac[nx:]))
    lam = lam[np.argsort(np.abs(lam.imag))][::2]
    np.testing.assert_allclose(lam.real, -zeta * sigma, rtol=1e-7)
    np.testing.assert_allclose(np.abs(lam.imag), sigma, rtol=EIGENSOLVER)


# ----------------------------------------------------------------------------- Eq. (30), integrated
def test_all_modes_reproduce_integrated_eq30(fig4, fig4_run):
    """With all modes retained the hybrid simulation (diffrax, modal coordinates) reproduces the
    direct integration of Eq. (30) (scipy, physical coordinates) to integration tolerance: b_0
    attitude and rate, gimbal and rotor angles, panel angles."""
    model, hm = fig4
    T, ts = T_FIG4, TS_FIG4
    state, hyb, sol = fig4_run
    S = np.asarray(FIG4_SMALL) - 1
    L = np.asarray(hm.large) - 1
    x0 = jnp.concatenate(
        [state.dcm.ravel(), state.omega0, state.gamma[L], state.gamma_dot[L], state.gamma[S], state.gamma_dot[S]]
    )
    X = integrate(eq30_rhs(model, FIG4_SMALL, hm.large), x0, T, ts)
    nl = len(L)
    ref = dict(dcm=X[:, :9].reshape(-1, 3, 3), omega0=X[:, 9:12], gamma=np.zeros((ts.size, model.n)))
    ref["gamma"][:, L] = X[:, 12 : 12 + nl]
    ref["gamma"][:, S] = X[:, 12 + 2 * nl : 12 + 2 * nl + len(S)]
    cols = np.concatenate([L, S])
    d = max_diff(hyb, ref, cols=cols)
    print(
        f"hybrid (all modes) vs integrated Eq. (30): max difference {d:.3g} "
        f"({int(sol.stats['num_accepted_steps'])} steps)"
    )
    assert d < SAME
    # the motion is not trivial: the panels move by their amplitude, the gimbal by much more
    assert np.abs(ref["gamma"][:, S]).max() > 0.04 and np.ptp(ref["gamma"][:, L[0]]) > 0.05


# ----------------------------------------------------------------------------- Eq. (1)
def quiet_initial(model, amp):
    """Only the rotor moves (10 pi rad/s about its axis, gimbal at zero: a steady motion of Eq. 1),
    plus the panel deflection `amp`: every other motion (omega0, gimbal, bus attitude) is the
    response to the panels, through the rotor's gyroscopic coupling."""
    gamma, gamma_dot = np.zeros(model.n), np.zeros(model.n)
    gamma_dot[3] = 10 * np.pi
    S = np.asarray(FIG4_SMALL) - 1
    gamma[S] = amp * np.array([1.0, -0.6, 0.8, 0.3, -0.5, 0.7])
    gamma_dot[S] = 2 * amp * np.array([-0.4, 0.9, 0.2, -0.7, 0.5, 0.1])
    return State(jnp.eye(3), jnp.zeros(3), jnp.asarray(gamma), jnp.asarray(gamma_dot))


def test_small_amplitude_approaches_nonlinear_eq1(fig4):
    """The hybrid simulation (all modes) tends to the full nonlinear simulation of Eq. (1) as the
    panel amplitude shrinks.

    (a) Order of the error. Platform prescription set to zero (same compiled model), rotor spinning,
    everything else excited by the panels only: the terms Eq. (30) drops are quadratic in the small
    variables, so halving the amplitude divides the error of the large variables (omega0, attitude,
    gimbal and rotor angles) by 4 (3.2 .. 4.8 allowed for the cubic terms) and that of the panel
    angles by at least that (their quadratic terms happen to be smaller: observed ratio ~6).

    (b) Large motion (prescribed platform swinging 1 rad, gimbal and bus rotating): the large motion
    also forces the panels, so the small variables are ``y_f + amp y_p`` with a forced part ``y_f``
    that does not shrink with amp, and the error ~ (y_f + amp y_p)^2 tends to a floor: it still
    shrinks (observed ratio 2.6 per halving; more than 1.5 required) and stays a small fraction of
    the amplitude."""
    model, hm = fig4
    T, ts = T_FIG4, TS_FIG4
    S = np.asarray(FIG4_SMALL) - 1
    L = np.asarray(hm.large) - 1
    quiet = eqx.tree_at(lambda m: m.prescription.amplitude, model, jnp.zeros(1))
    hq = eqx.tree_at(lambda h: h.model, hm, quiet)
    large, small = [], []
    for amp in (0.02, 0.01):
        state = quiet_initial(model, amp)
        hyb, _ = hybrid_history(hq, state, T, ts)
        full = full_history(quiet, state, T, ts)
        large.append(max_diff(hyb, full, keys=("dcm", "omega0", "gamma"), cols=L))
        small.append(max_diff(hyb, full, keys=("gamma",), cols=S))
        assert np.abs(full["gamma"][:, L[:2]]).max() > 0.2 * amp  # the gimbal does respond
    print(
        f"(a) hybrid vs Eq. (1), amplitude 0.02 / 0.01: large variables {large[0]:.3g} / {large[1]:.3g} "
        f"(ratio {large[0] / large[1]:.2f}), panels {small[0]:.3g} / {small[1]:.3g} "
        f"(ratio {small[0] / small[1]:.2f})"
    )
    assert 3.2 < large[0] / large[1] < 4.8
    assert small[0] / small[1] > 3.2
    assert max(large[1], small[1]) < 0.01 * 0.01
    errs = []
    for amp in (0.02, 0.01):
        state = fig4_initial(model, amp)
        hyb, _ = hybrid_history(hm, state, T, ts)
        full = full_history(model, state, T, ts)
        errs.append(max_diff(hyb, full, cols=np.concatenate([L, S])))
        assert errs[-1] < 0.05 * amp
    print(f"(b) with the large motion: {errs[0]:.3g} / {errs[1]:.3g} (ratio {errs[0] / errs[1]:.2f})")
    assert errs[0] / errs[1] > 1.5


# ----------------------------------------------------------------------------- truncation
def test_truncation_error_decreases(fig4, fig4_run):
    """Truncation (Eq. 118): keeping the k lowest modes of the panels, the error against the
    all-mode model (= Eq. 30, previous tests) falls as k grows and vanishes for k = 6; the
    retained frequencies are the k lowest of jaxtree.modes. The retain() mask equals a model
    built with n_modes=k (smaller arrays)."""
    model, hm = fig4
    T, ts = T_FIG4, TS_FIG4
    state, ref, _ = fig4_run
    S = np.asarray(FIG4_SMALL) - 1
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))
    panels, rates = [], []
    for k in range(1, 6):
        out, _ = hybrid_history(hm.retain(k), state, T, ts)
        panels.append(rms(out["gamma"][:, S] - ref["gamma"][:, S]))
        rates.append(rms(out["omega0"] - ref["omega0"]))
    panels.append(0.0), rates.append(0.0)  # k = 6: all modes, the reference itself
    print("frequencies:", np.asarray(hm.frequencies))
    print("rms error of the panel angles, k = 1..6:", [f"{e:.3g}" for e in panels])
    print("rms error of omega0,           k = 1..6:", [f"{e:.3g}" for e in rates])
    # (The maximum error is not monotone: k = 3 adds a 4.9 rad/s mode whose truncated partner
    # errors peak at other times; the rms over the run is.)
    for errs in (panels, rates):
        assert all(errs[i + 1] < errs[i] for i in range(5)), errs
    assert panels[0] > 1e-2 and panels[4] < 0.2 * panels[0] and rates[4] < 0.02 * rates[0]
    # a model built with fewer modes is the masked one
    small3 = jaxtree.hybrid_model(model, FIG4_SMALL, 3, omega0=FIG4_SPIN, basis="set")
    np.testing.assert_allclose(np.asarray(small3.frequencies), np.asarray(hm.frequencies)[:3], rtol=SAME_NUMBERS)
    act = np.concatenate([np.arange(3), 6 + np.arange(3)])  # active columns of the masked model
    for a, b in (
        (small3.positions, hm.positions[:, act]),
        (small3.rates, hm.rates[:, act]),
        (small3.rows, hm.rows[:, act]),
        (small3.kin, hm.kin[np.ix_(act, act)]),
        (small3.kin_rhs, hm.kin_rhs[np.ix_(act, act)]),
        (small3.project, hm.project[act]),
    ):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=ROUNDOFF * float(np.abs(np.asarray(b)).max()))
    # a frequency cutoff keeps the modes below it
    cut = jaxtree.hybrid_model(model, FIG4_SMALL, cutoff=12.0, omega0=FIG4_SPIN, basis="set")
    assert cut.n_modes == int(np.sum(np.asarray(hm.frequencies) <= 12.0)) == 4


# ----------------------------------------------------------------------------- Appendix C
def c70_c73(p, w0, eta0, etad0, T, ts):
    """The printed C-70..C-73 (eta_1 = gamma_1 + gamma_2, C-69b) integrated by scipy."""
    M, R, J, c, r, k = p["M"], p["R"], p["J"], p["c"], p["r"], p["k"]
    I1, I2, I3 = p["I1"], p["I2"], p["I3"]

    def rhs(t, x):
        w1, w2, w3, e, ed = x
        E = np.array([[I1, 0, 0, c], [0, I2, -c * e, 0], [0, -c * e, I3, 0], [2 * c, 0, 0, J]])
        F = np.array(
            [
                (I2 - I3) * w2 * w3 + c * (w2**2 - w3**2) * e,
                (I3 - I1) * w3 * w1 - c * w1 * w2 * e,
                (I1 - I2) * w1 * w2 + 2 * c * w2 * ed + c * w1 * w3 * e,
                -2 * c * w2 * w3 + (J * (w2**2 - w3**2) - M * R * r * (w1**2 + w3**2) - k) * e,
            ]
        )
        a = np.linalg.solve(E, F)
        return [a[0], a[1], a[2], ed, a[3]]

    sol = solve_ivp(rhs, (0, T), [*w0, eta0, etad0], t_eval=ts, method="DOP853", rtol=TOL, atol=TOL)
    return sol.y.T


def test_appendix_c_eta2_decouples(appendix):
    """Appendix C (Fig. C-1), omega0 unrestricted, both rod hinges small, spin about b3: the modes
    are eta_1 (rods in phase, C-69) and eta_2 (antiphase); eta_2 enters only C-74, so truncating to
    eta_1 leaves the rotation of b_0 unchanged (C-70..C-73). Checked three ways: the b_0 motion of
    the truncated model equals that of the full-mode model while eta_2 oscillates, both equal the
    printed C-70..C-73 integrated by scipy, and the retained mode shape is C-69a's [1, 1]."""
    model, p, hm = appendix
    phi = np.asarray(hm.positions)[:, :2]
    assert abs(phi[0, 0] - phi[1, 0]) < ROUNDOFF and abs(phi[0, 1] + phi[1, 1]) < ROUNDOFF  # C-69a
    T, ts = 12.0, np.linspace(0.0, 12.0, 61)
    gamma0, gdot0 = np.array([0.03, -0.01]), np.array([0.02, 0.05])
    state = State(jnp.eye(3), jnp.array([0.05, -0.03, 1.0]), jnp.asarray(gamma0), jnp.asarray(gdot0))
    full = jaxtree.simulate_hybrid(hm, T, y0=state, saveat=ts, rtol=TOL, atol=TOL)
    trunc = jaxtree.simulate_hybrid(hm.retain(1), T, y0=state, saveat=ts, rtol=TOL, atol=TOL)
    # eta_2 is present in the full model ...
    diff = np.asarray(full.gamma[:, 0] - full.gamma[:, 1])
    assert np.abs(diff).max() > 0.03
    # ... and has no effect on b_0
    d = max(float(np.abs(full.omega0 - trunc.omega0).max()), float(np.abs(full.dcm - trunc.dcm).max()))
    print(f"b_0 motion, truncated vs full modes: {d:.3g}")
    assert d < SAME
    # the sum gamma_1 + gamma_2 = eta_1 (C-69b) is the same in both
    s_full = np.asarray(full.gamma.sum(1))
    s_trunc = np.asarray(trunc.gamma.sum(1))
    np.testing.assert_allclose(s_trunc, s_full, atol=SAME)
    # the printed C-70..C-73
    X = c70_c73(p, [0.05, -0.03, 1.0], gamma0.sum(), gdot0.sum(), T, ts)
    e = max(float(np.abs(np.asarray(trunc.omega0) - X[:, :3]).max()), float(np.abs(s_trunc - X[:, 3]).max()))
    print(f"truncated hybrid vs C-70..C-73: {e:.3g}")
    assert e < SAME
    assert np.ptp(X[:, 0]) > 1e-3 and np.ptp(X[:, 3]) > 0.01  # omega_1 and eta_1 do move


# ----------------------------------------------------------------------------- input checks
def test_bad_input_messages(fig4):
    model, _ = fig4
    with pytest.raises(ValueError, match="only 6 available"):
        jaxtree.hybrid_model(model, FIG4_SMALL, 7, omega0=FIG4_SPIN)
    with pytest.raises(ValueError, match="no mode retained"):
        jaxtree.hybrid_model(model, FIG4_SMALL, cutoff=0.1, omega0=FIG4_SPIN)
    with pytest.raises(jaxtree.ModalError, match="form='real' needs real modes"):
        jaxtree.hybrid_model(model, FIG4_SMALL, omega0=FIG4_SPIN, form="real")
    with pytest.raises(ValueError, match="precompute=True"):  # the gimbal hinge has large hinges outboard
        jaxtree.hybrid_model(model, (2,), precompute=True)
    with pytest.raises(ValueError, match="prescribed"):
        jaxtree.hybrid_model(model, (1, 5))
    with pytest.raises(ValueError, match="retain"):
        jaxtree.hybrid_model(model, FIG4_SMALL, omega0=FIG4_SPIN).retain(0)


def test_failures_are_reported_with_time_and_state_and_tolerances_may_be_traced(appendix):
    """A run that exhausts max_steps raises SimulationError naming where it stopped (time,
    physical state, modal coordinates): at once when called eagerly, from a host callback under
    jit. A vmapped tolerance sweep (traced rtol/atol) runs, and its errors against a TOL run fall
    with the tolerance."""
    _, _, hm = appendix
    state = State(jnp.eye(3), jnp.array([0.05, -0.03, 1.0]), jnp.array([0.03, -0.01]), jnp.array([0.02, 0.05]))
    pattern = r"(?s)simulate_hybrid: the maximum number of solver steps.*stopped at t = .*modal coordinates"
    with pytest.raises(jaxtree.SimulationError, match=pattern):
        jaxtree.simulate_hybrid(hm, 12.0, y0=state, max_steps=5)
    with pytest.raises(ValueError, match=r"simulate_hybrid: saveat\[1\] = 13 lies outside"):
        jaxtree.simulate_hybrid(hm, 12.0, y0=state, saveat=[0.0, 13.0])
    sol = jaxtree.simulate_hybrid(hm, 12.0, y0=state, max_steps=5, throw=False)
    assert not sol.ok and 0.0 < float(sol.t_final) < 12.0
    assert np.all(np.isfinite(np.asarray(sol.final.gamma))) and sol.final_modal.shape == sol.modal.shape[1:]
    with pytest.raises(Exception, match="maximum number of solver steps"):
        jax.block_until_ready(jax.jit(lambda s: jaxtree.simulate_hybrid(hm, 12.0, y0=s, max_steps=5).gamma)(state))

    ref = jaxtree.simulate_hybrid(hm, 12.0, y0=state, saveat=2, rtol=TOL, atol=TOL)
    assert float(ref.t_final) == 12.0
    tols = jnp.asarray([1e-5, 1e-8])
    ends = jax.vmap(lambda tol: jaxtree.simulate_hybrid(hm, 12.0, y0=state, saveat=2, rtol=tol, atol=tol).gamma[-1])(
        tols
    )
    err = np.abs(np.asarray(ends) - np.asarray(ref.gamma[-1])).max(1)
    assert np.all(err < 1e3 * np.asarray(tols)) and err[1] < err[0]


# ------------------------------------------------------------------------------------ substructures
def _wings(damping=True):
    model = jaxtree.load_scene("wings")
    if not damping:
        model = eqx.tree_at(lambda m: m.damping, model, jnp.zeros_like(model.damping))
    return model


def test_precomputed_equals_general_with_loads_moving_platform_and_several_bases(fig4):
    """The precomputed substructure terms give the same Eq. (118) as the general form (one jvp of
    the whole Eq. 1 per right side) to round-off, at random large states: Fig. 4 with its
    prescribed (moving) platform, gimbals, spinning rotor and a torque on the bus; and the wings with
    each wing's outer hinges small, hanging from two different large bodies that move."""
    rng = np.random.default_rng(12)
    model, _ = fig4
    loaded = model.with_loads(jaxtree.BodyTorque(0, [3.0, -2.0, 1.0], lambda t: jnp.sin(2.0 * t)))
    cases = [(loaded, FIG4_SMALL, dict(omega0=FIG4_SPIN)), (_wings(), (2, 3, 4, 6, 7, 8), dict(omega0=[0.1, 0.0, 0.4]))]
    for model, small, kw in cases:
        pre = jaxtree.hybrid_model(model, small, **kw)
        gen = jaxtree.hybrid_model(model, small, precompute=False, **kw)
        assert pre.precomputed and not gen.precomputed and pre.basis == "substructure"
        for _ in range(3):
            y = pre.pack(small_random_state(model, rng))
            t = jnp.asarray(rng.uniform(0, 3))
            m1, r1 = equations_jit(pre, t, y)
            m2, r2 = equations_jit(gen, t, y)
            np.testing.assert_allclose(np.asarray(m1), np.asarray(m2), atol=ROUNDOFF_EQ118 * float(np.abs(m2).max()))
            np.testing.assert_allclose(np.asarray(r1), np.asarray(r2), atol=ROUNDOFF_EQ118 * float(np.abs(r2).max()))
    assert len({g.base for g in pre.groups}) == 2 and pre.modal_inverse is None  # two moving bases


def test_substructure_modes_with_all_modes_reproduce_eq30(fig4):
    """Each substructure's own held-base modes, all retained, are Eq. (30) in other coordinates:
    Fig. 4's panels (gyroscopic, spinning) and the two damped wings (general first-order modes)."""
    rng = np.random.default_rng(21)
    model, _ = fig4
    for hm in (
        jaxtree.hybrid_model(model, FIG4_SMALL, omega0=FIG4_SPIN),
        jaxtree.hybrid_model(_wings(), tuple(range(1, 9)), omega0=[0.0, 0.0, 0.3]),
    ):
        assert hm.basis == "substructure"
        worst, _ = check_rhs_against_eq30(hm, rng)
        assert worst < 1e-10


def test_held_base_modes_are_the_cantilever_modes():
    """A wing's modes on its held base equal the set-A modes of the same wing on a hub made a
    billion times heavier (jaxtree.linearize, checked against the Lagrange oracle elsewhere): the
    base then does not move. Non-spinning and spinning nominal; frequencies to 1e-6."""
    model = _wings(damping=False)
    heavy = eqx.tree_at(
        lambda m: (m.mass, m.inertia), model, (model.mass.at[0].multiply(1e9), model.inertia.at[0].multiply(1e9))
    )
    for spin in ([0.0, 0.0, 0.0], [0.0, 0.0, 0.4]):
        hm = jaxtree.hybrid_model(model, (1, 2, 3, 4), omega0=spin)
        ref = jaxtree.modes(jaxtree.linearize(heavy, (1, 2, 3, 4), omega0=spin))
        np.testing.assert_allclose(np.sort(np.asarray(hm.frequencies)), np.sort(np.asarray(ref.frequencies)), rtol=1e-6)


def test_truncation_under_a_slew_falls_as_modes_are_added():
    """A slew of the wings' hub by a smooth torque pulse, panels at rest: the error of the
    truncated model against the all-mode one falls as modes are added per wing and vanishes with
    all of them; a repeated frequency (the two identical wings) is never split."""
    model = _wings(damping=False).with_loads(
        jaxtree.BodyTorque(
            0, [0.0, 8.0, 3.0], lambda t: jaxtree._src.equations.loads.thruster_pulse(t, 0.5, 1.0, rise=0.1)
        )
    )
    state = model.initial._replace(gamma=jnp.zeros(model.n), gamma_dot=jnp.zeros(model.n))
    small = tuple(range(1, 9))
    full = jaxtree.hybrid_model(model, small)
    assert full.n_modes == 8 and len(full.groups) == 2
    ts = np.linspace(0.0, 4.0, 41)
    ref = jaxtree.simulate_hybrid(full, 4.0, y0=state, saveat=ts, rtol=TOL, atol=TOL)
    S = np.arange(8)
    assert np.abs(np.asarray(ref.gamma)[:, S]).max() > 1e-3  # the wings do bend
    errs = []
    for k in (1, 2, 3):
        hm = jaxtree.hybrid_model(model, small, k)
        assert hm.n_modes == 2 * k  # k per wing
        sol = jaxtree.simulate_hybrid(hm, 4.0, y0=state, saveat=ts, rtol=TOL, atol=TOL)
        errs.append(float(np.sqrt(np.mean((np.asarray(sol.gamma) - np.asarray(ref.gamma)) ** 2))))
    print("rms wing-angle error of k = 1, 2, 3 modes per wing:", errs)
    assert errs[0] > errs[1] > errs[2] > 0
    # energy and angular momentum of the rebuilt vehicle: the torque changes H; after the pulse
    # both stay constant up to the linearization error
    after = ts > 2.0
    H = np.asarray(ref.angular_momentum)[after]
    assert np.abs(H - H[0]).max() < 1e-3 * np.abs(H[0]).max()
    # the hybrid model's energy at t = 0 is the vehicle's (kinetic energy + springs)
    e0 = float(
        jaxtree.kinetic_energy(
            model, ref.final._replace(gamma=state.gamma, gamma_dot=state.gamma_dot, omega0=state.omega0, dcm=state.dcm)
        )
    )
    assert abs(float(ref.energy[0]) - e0) < ROUNDOFF * max(1.0, abs(e0))


def test_projection_residual_of_the_initial_state():
    """The start is projected on the retained modes, and the part left out is reported: zero for
    all modes; for a truncated model, zero for a motion built from the retained mode shapes (whose
    coordinates pack gives back), and for a random start at least its least-squares distance from
    their span (numpy's lstsq: no projection leaves less out)."""
    model = _wings(damping=False)
    small = tuple(range(1, 9))
    rng = np.random.default_rng(4)
    g = np.zeros(model.n)
    g[:8] = rng.normal(size=8) * 0.01
    state = model.initial._replace(gamma=jnp.asarray(g), gamma_dot=jnp.zeros(model.n))
    full = jaxtree.hybrid_model(model, small)
    assert float(full.projection_residual(state)) < ROUNDOFF
    one = jaxtree.hybrid_model(model, small, 1)
    nominal = np.asarray(one.gamma_nominal)
    B = np.concatenate([np.asarray(one.positions), np.asarray(one.rates)])  # [y; y'] = B s
    s0 = rng.normal(size=B.shape[1]) * 0.01
    x = B @ s0
    inside = model.initial._replace(
        gamma=jnp.asarray(nominal + np.concatenate([x[:8], np.zeros(model.n - 8)])),
        gamma_dot=jnp.asarray(np.concatenate([x[8:], np.zeros(model.n - 8)])),
    )
    assert float(one.projection_residual(inside)) < ROUNDOFF
    np.testing.assert_allclose(np.asarray(one.pack(inside))[-B.shape[1] :], s0, rtol=1e-9, atol=1e-14)
    start = np.concatenate([g[:8] - nominal[:8], np.zeros(8)])
    least = np.linalg.norm(start - B @ np.linalg.lstsq(B, start, rcond=None)[0]) / np.linalg.norm(start)
    r = float(one.projection_residual(state))
    assert least > 0.1  # one mode per wing leaves much of a random start out
    assert least * (1 - 1e-9) <= r <= 1.0, (least, r)
    sol = jaxtree.simulate_hybrid(one, 0.5, y0=state, saveat=3)
    assert abs(float(sol.projection_residual) - r) < ROUNDOFF


def test_held_base_frequencies_are_differentiable_in_the_stiffness():
    """d sigma / d k of a wing's held-base modes (substructure terms, held_base, modes traced with
    kind='real') against central finite differences."""
    from jaxtree._src.hybrid import substructure as sub

    model = _wings(damping=False)
    grp = sub.substructures(model, (1, 2, 3, 4))[0]

    def frequencies(stiffness):
        m = eqx.tree_at(lambda m: m.stiffness, model, stiffness)
        tm = sub.terms(m, grp, jnp.zeros(m.n))
        I, J, K = sub.held_base(tm, jnp.zeros(6), jnp.zeros(6), stiffness[:4], jnp.zeros(4))
        return jaxtree.modes(I, J, K, kind="real").frequencies

    k0 = model.stiffness
    jac = jax.jacrev(frequencies)(k0)
    for i in range(4):
        h = 1e-5 * float(k0[i])
        fd = (frequencies(k0.at[i].add(h)) - frequencies(k0.at[i].add(-h))) / (2 * h)
        np.testing.assert_allclose(np.asarray(jac[:, i]), np.asarray(fd), rtol=1e-6, atol=1e-9)


def test_gross_deformation_of_a_chain_limits_eq30():
    """The report's claim (Abstract, Sec. I B) that the modal coordinates of Eq. (30) allow large
    gross deformations with small local ones, tried on the sprung 50-segment chain: 25 hinges bent
    by theta/25 each (local angles <= 0.08 rad, the tip turned by theta relative to the root),
    released, 2 s, against the full Eq. (1). Eq. (30) with every mode retained (the hybrid model
    adds only truncation to it) has a relative error that grows like theta^2, the gross rotation:
    a few 1e-3 at theta = 0.25 rad, about 10 % at theta = 1 rad, where the all-linear
    vehicle-normal-mode model (Eq. 42, Sec. III B, integrated by scipy) is *more* accurate, not less
    (docs/errata_hybrid.md #8)."""
    from scipy.integrate import solve_ivp

    model = jaxtree.load_scene("chain50")
    n = model.n
    yh = np.flatnonzero(np.abs(np.asarray(model.axis)[:, 1]) > 0.5)  # the 25 hinges about b_2
    ts = np.linspace(0.0, 2.0, 41)
    hm = jaxtree.hybrid_model(model, tuple(range(1, n + 1)))
    lin = jaxtree.linearize_vehicle(model)
    I, J, K = (np.asarray(x) for x in lin)
    Ii = np.linalg.inv(I)
    out = {}
    for theta in (0.25, 1.0):
        g = np.zeros(n)
        g[yh] = theta / len(yh)
        s = model.initial._replace(gamma=jnp.asarray(g), gamma_dot=jnp.zeros(n), omega0=jnp.zeros(3))
        ref = jaxtree.simulate(model, 2.0, y0=s, saveat=ts, rtol=1e-10, atol=1e-10)
        G = np.asarray(ref.gamma)
        assert np.abs(G).max() < 0.08 and np.abs(G[:, yh].sum(1)).max() >= 0.99 * theta
        hyb = jaxtree.simulate_hybrid(hm, 2.0, y0=s, saveat=ts, rtol=1e-10, atol=1e-10)
        nu = I.shape[0]  # three attitude angles, then the hinges
        x0 = np.concatenate([np.zeros(3), g, np.zeros(nu)])
        r = solve_ivp(
            lambda t, x: np.concatenate([x[nu:], -Ii @ (J @ x[nu:] + K @ x[:nu])]),
            (0.0, 2.0),
            x0,
            t_eval=ts,
            rtol=1e-10,
            atol=1e-10,
            method="DOP853",
        )
        scale = np.abs(G).max()
        out[theta] = (
            float(np.abs(np.asarray(hyb.gamma) - G).max() / scale),
            float(np.abs(r.y[3:nu].T - G).max() / scale),
        )
    print("relative error of the hinge angles (Eq. 30, all-linear):", out)
    (e30_small, _), (e30_big, lin_big) = out[0.25], out[1.0]
    assert e30_small < 0.02 and e30_big > 0.05
    assert 8.0 < e30_big / e30_small < 32.0  # ~ (1 / 0.25)^2: governed by the gross rotation
    assert lin_big < e30_big


def test_a_nonfinite_start_fails_at_once_under_jit(appendix):
    """A NaN in the initial state stops a jitted hybrid run at t0 with the 'not finite' failure,
    instead of running to max_steps; a damping vector of the wrong length is named."""
    model, _, hm = appendix
    state = State(jnp.eye(3), jnp.array([0.05, -0.03, 1.0]), jnp.array([jnp.nan, -0.01]), jnp.array([0.02, 0.05]))
    sol = jax.jit(lambda s: jaxtree.simulate_hybrid(hm, 12.0, y0=s, throw=False))(state)
    assert not sol.ok and float(sol.t_final) == 0.0 and int(sol.stats["num_steps"]) < 10
    with pytest.raises(jaxtree.SimulationError, match="initial state is not finite"):
        jaxtree.simulate_hybrid(hm, 12.0, y0=state)
    with pytest.raises(ValueError, match="damping has 2 ratios for 1 retained modes"):
        jaxtree.hybrid_model(model, (1, 2), 1, omega0=[0.0, 0.0, 1.0], basis="set", damping=[0.1, 0.2])


def test_a_singular_start_is_reported_as_simulate_reports_it(fig4):
    """The hybrid run checks its start as jaxtree.simulate does (one integration for both): at an
    exact gimbal lock among the large hinges (gamma_3 = pi/2: the rotor's axis along the outer
    gimbal's; numpy's condition number of Eq. (1) there above 1e15) the run fails at t0 as
    "singular_start" with NaN histories, eagerly (tested once it failed) and under jit and vmap
    (tested in the program) beside a regular member that runs to t1; the eager report says so."""
    model, hm = fig4
    start = fig4_initial(model, 0.05)
    locked = start._replace(gamma=start.gamma.at[2].set(np.pi / 2))
    assert np.linalg.cond(np.asarray(jaxtree.rotational_equations(model, locked)[0])) > 1e15
    sol = jaxtree.simulate_hybrid(hm, 0.5, y0=locked, saveat=3, throw=False)
    assert int(sol.failure) == int(jaxtree.Failure.SINGULAR_START) and float(sol.t_final) == 0.0
    assert np.all(np.isnan(np.asarray(sol.gamma))) and np.all(np.isnan(np.asarray(sol.energy)))
    both = jax.tree.map(lambda a, b: jnp.stack([a, b]), locked, start)
    run = jax.jit(jax.vmap(lambda y: jaxtree.simulate_hybrid(hm, 0.5, y0=y, saveat=3, throw=False)))
    sols = run(both)
    assert list(np.asarray(sols.failure)) == [int(jaxtree.Failure.SINGULAR_START), 0]
    assert list(np.asarray(sols.t_final)) == [0.0, 0.5] and np.all(np.isfinite(np.asarray(sols.gamma[1])))
    with pytest.raises(jaxtree.SimulationError, match="singular at the initial state"):
        jaxtree.simulate_hybrid(hm, 0.5, y0=locked, saveat=3)


def test_truncation_ranks_damped_modes_by_their_rate_so_an_overdamped_fast_pair_is_left_out():
    """chain10 with a near-rigid, damped tip hinge: the first-order modes of the boom on its held
    hub include an overdamped pair (two real eigenvalues near -1e5, frequency 0). Truncation keeps
    the modes slowest by |lambda| (numpy's eigenvalues of the first-order matrix of the linearized
    I, J, K of the same chain on a hub 1e9 times heavier, i.e. held, computed here apart), and the
    truncated equations are no longer stiff: a handful of Dopri8 steps over 1 s where the full
    equations need ~3e4."""
    model = jaxtree.stiff_chain(1e6)
    small = tuple(range(1, model.n + 1))
    held = eqx.tree_at(
        lambda m: (m.mass, m.inertia), model, (model.mass.at[0].multiply(1e9), model.inertia.at[0].multiply(1e9))
    )
    lin = jaxtree.linearize(held, small)
    I, J, K = (np.asarray(x, float) for x in (lin.I, lin.J, lin.K))
    nu = I.shape[0]
    A = np.block([[np.zeros((nu, nu)), np.eye(nu)], [-np.linalg.solve(I, K), -np.linalg.solve(I, J)]])
    lam = np.linalg.eigvals(A)
    real = lam[np.abs(lam.imag) < 1e-9 * np.abs(lam)]
    assert real.size == 2 and real.real.max() < -1e4  # the overdamped fast pair
    pairs = lam[lam.imag > 0]
    slowest = pairs[np.argsort(np.abs(pairs))][:2]
    hyb = jaxtree.hybrid_model(model, small, 2)
    np.testing.assert_allclose(np.sort(np.asarray(hyb.frequencies)), np.sort(slowest.imag), rtol=1e-6)
    sol = jaxtree.simulate_hybrid(hyb, 1.0, saveat=2, rtol=1e-6, atol=1e-6)  # Dopri8
    assert sol.ok and int(sol.stats["num_accepted_steps"]) < 100, sol.stats


# --------------------------------------------------------------------- the slew's modal damping
def test_real_form_modal_damping_gives_the_damped_eigenvalues_of_eq_104():
    """Eq. (121) with the modal damping 2 zeta sigma of Eq. (104), a vehicle at rest: the
    eigenvalues of the hybrid model's linearization (jacfwd of its right side, eigenvalues by
    scipy) are -zeta sigma +- i sigma sqrt(1 - zeta^2) for every retained mode, and zero for the
    rigid hub. The hub is made 1e9 times heavier so that the held-base modes are the vehicle's (as
    in test_held_base_modes_are_the_cantilever_modes); each mode gets its own ratio. A 10 % change
    of the ratios moves the eigenvalues far beyond the tolerance (the check can fail)."""
    model = _wings(damping=False)
    heavy = eqx.tree_at(
        lambda m: (m.mass, m.inertia), model, (model.mass.at[0].multiply(1e9), model.inertia.at[0].multiply(1e9))
    )
    small = tuple(range(1, 9))
    zeta = np.array([0.02, 0.05, 0.1, 0.3, 0.6, 0.9])
    hm = jaxtree.hybrid_model(heavy, small, 3, damping=zeta)
    assert hm.form == "real" and hm.n_modes == 6
    sigma = np.asarray(hm.frequencies)
    np.testing.assert_array_equal(np.asarray(hm.damping_ratios), zeta)
    rest = heavy.initial._replace(
        omega0=jnp.zeros(3), gamma=jnp.zeros(heavy.n), gamma_dot=jnp.zeros(heavy.n), dcm=jnp.eye(3)
    )
    y0 = hm.pack(rest)
    ev = sla.eigvals(np.asarray(jax.jacfwd(lambda y: jaxtree.hybrid_rhs(0.0, y, hm))(y0)))

    def expected(z):
        up = -z * sigma + 1j * sigma * np.sqrt(1.0 - z**2)
        return np.concatenate([up, np.conj(up)])

    def mismatch(lam):  # the worst relative distance of an expected eigenvalue to the computed ones
        return max(np.abs(ev - lv).min() / abs(lv) for lv in lam)

    print(
        "worst relative eigenvalue mismatch", mismatch(expected(zeta)), "with 1.1 zeta", mismatch(expected(1.1 * zeta))
    )
    assert mismatch(expected(zeta)) < 1e-7
    modal = np.abs(ev) > 1e-6 * sigma.min()
    assert modal.sum() == 2 * len(sigma)  # the rest are the rigid hub's zeros
    assert mismatch(expected(1.1 * zeta)) > 1e-3


def test_precomputed_equals_general_on_flex95_with_loads_large_hinges_and_spin():
    """The precomputed substructure terms against the general form (one jvp of the whole Eq. 1 per
    right side) on flex95: six stiff damped wings (first-order modes) on one bus, the large gimbals
    and rotor moving, a time-varying torque on the bus and a spinning nominal; random large states
    with the wings deflected. Matrix and right side of Eq. (118) agree to round-off."""
    rng = np.random.default_rng(95)
    model = jaxtree.load_scene("flex95")
    model = model.with_loads(jaxtree.BodyTorque(0, [15.0, 9.0, -4.0], lambda t: jnp.cos(0.7 * t)))
    small = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    kw = dict(omega0=[0.02, -0.01, 0.2])
    pre = jaxtree.hybrid_model(model, small, 2, **kw)
    gen = jaxtree.hybrid_model(model, small, 2, precompute=False, **kw)
    assert pre.precomputed and not gen.precomputed and pre.form == "first_order" and len(pre.large) == 4
    for _ in range(2):
        y = pre.pack(small_random_state(model, rng, scale=0.05))
        t = jnp.asarray(rng.uniform(0, 3))
        m1, r1 = equations_jit(pre, t, y)
        m2, r2 = equations_jit(gen, t, y)
        np.testing.assert_allclose(np.asarray(m1), np.asarray(m2), atol=ROUNDOFF_EQ118 * float(np.abs(m2).max()))
        np.testing.assert_allclose(np.asarray(r1), np.asarray(r2), atol=ROUNDOFF_EQ118 * float(np.abs(r2).max()))


def test_gradient_through_hybrid_model_and_simulate_hybrid_against_central_differences():
    """jax.grad of a loss of a 10 s hybrid trajectory (a slew of the damped wings'
    spinning hub, two modes per wing: general first-order modes, Eq. 118) w.r.t. a scale of the
    wing stiffness, through hybrid_model (modes recomputed from the traced matrices by JAX's
    eigenvector derivatives, the selection fixed by `like`) and simulate_hybrid, against central
    finite differences of the same loss (h = 1e-4: truncation error ~h^2 ~ 1e-8 relative,
    integration at 1e-12); and a traced build without `like` is refused in one line."""
    model = _wings().with_loads(
        jaxtree.BodyTorque(
            0, [0.0, 8.0, 3.0], lambda t: jaxtree._src.equations.loads.thruster_pulse(t, 0.5, 1.0, rise=0.1)
        )
    )
    small = tuple(range(1, 9))
    state = model.initial._replace(gamma=jnp.zeros(model.n), gamma_dot=jnp.zeros(model.n))
    spin = [0.0, 0.0, 0.3]
    hm0 = jaxtree.hybrid_model(model, small, 2, omega0=spin)
    assert hm0.kind == "general" and hm0.form == "first_order"
    wing = jnp.asarray(np.isin(np.arange(model.n), np.asarray(small) - 1))
    ts = jnp.linspace(0.0, 10.0, 11)

    def loss(scale):
        m = eqx.tree_at(lambda m: m.stiffness, model, model.stiffness * jnp.where(wing, scale, 1.0))
        hm = jaxtree.hybrid_model(m, small, like=hm0, omega0=spin)
        sol = jaxtree.simulate_hybrid(hm, 10.0, y0=state, saveat=ts, rtol=1e-12, atol=1e-12, truncation_error=False)
        return jnp.sum(sol.gamma[:, np.asarray(small) - 1] ** 2) + jnp.sum(sol.omega0**2)

    grad = float(jax.grad(loss)(1.0))
    h = 1e-4
    fd = float((loss(1.0 + h) - loss(1.0 - h)) / (2 * h))
    print("d loss / d stiffness scale:", grad, "central differences:", fd)
    assert abs(grad - fd) <= 1e-5 * abs(fd)
    with pytest.raises(ValueError, match="like="):
        jax.grad(lambda k: jaxtree.hybrid_model(eqx.tree_at(lambda m: m.stiffness, model, k), small, 2).frequencies[0])(
            model.stiffness
        )


def test_traced_rebuild_equals_the_eager_build_with_its_mass_part_evaluated_once():
    """A member's hybrid model rebuilt inside ``jit`` with `like` equals the eager build of the same
    member (frequencies, and the projector on the retained modes ``positions @ project``, which a
    mode's sign or phase does not change), both when only the stiffness is traced (the build's
    mass part, the substructures' Taylor terms and nominal frames, is then evaluated when the
    program is traced and enters it as values) and when a mass is traced too (the mass part in the
    program). The stiffness-only program holds none of the mass part: its jaxpr is a fraction of
    the other's (StableHLO lines). And each mode's sign, which its normalization leaves free, is the
    reference's: a reference with a mode turned over gives rebuilds with that mode turned over."""
    model = _wings()
    small = tuple(range(1, 9))
    spin = [0.0, 0.0, 0.3]
    hm0 = jaxtree.hybrid_model(model, small, 2, omega0=spin)
    wing = jnp.asarray(np.isin(np.arange(model.n), np.asarray(small) - 1))

    def member(ks, km=None):  # the other leaves stay the model's own (known) arrays
        m = eqx.tree_at(lambda m: m.stiffness, model, model.stiffness * jnp.where(wing, ks, 1.0))
        return m if km is None else eqx.tree_at(lambda m: m.mass, m, m.mass.at[3].multiply(km))

    def rebuild_stiffness(ks):
        return jaxtree.hybrid_model(member(ks), small, like=hm0, omega0=spin)

    def rebuild_both(ks, km):
        return jaxtree.hybrid_model(member(ks, km), small, like=hm0, omega0=spin)

    def invariants(hm):  # the modes' signs are the reference's (below): positions compared as well
        return np.asarray(hm.frequencies), np.asarray(hm.positions @ hm.project), np.asarray(hm.positions)

    for built, eager in (
        (jax.jit(rebuild_stiffness)(1.3), jaxtree.hybrid_model(member(1.3), small, like=hm0, omega0=spin)),
        (jax.jit(rebuild_both)(0.8, 1.2), jaxtree.hybrid_model(member(0.8, 1.2), small, like=hm0, omega0=spin)),
    ):
        for a, b in zip(invariants(built), invariants(eager)):
            np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-9 * np.abs(b).max())
    assert not np.allclose(invariants(jax.jit(rebuild_stiffness)(1.3))[0], invariants(hm0)[0])
    size = lambda f, *a: len(jax.jit(f).lower(*a).as_text().splitlines())
    print("StableHLO lines:", size(rebuild_stiffness, 1.3), size(rebuild_both, 0.8, 1.2))
    assert size(rebuild_stiffness, 1.3) < 0.5 * size(rebuild_both, 0.8, 1.2)
    # a mode's sign is free (phi^T I phi = U, Eq. 89): a rebuild takes the reference's, traced or
    # not; here a reference with its first mode turned over (both columns of its complex pair)
    k = hm0.n_modes
    assert hm0.form == "first_order" and hm0.positions.shape[1] == 2 * k
    turned = hm0.positions.at[:, np.asarray([0, k])].multiply(-1.0)
    ref = eqx.tree_at(lambda h: h.positions, hm0, turned)
    for hm in (
        jax.jit(lambda ks: jaxtree.hybrid_model(member(ks), small, like=ref, omega0=spin))(1.0),
        jaxtree.hybrid_model(model, small, like=ref, omega0=spin),
    ):
        np.testing.assert_allclose(
            np.asarray(hm.positions), np.asarray(turned), atol=1e-9 * float(np.abs(turned).max())
        )


def test_simulate_hybrid_takes_radau5_and_reports_its_counters():
    """jaxtree.Radau5 in simulate_hybrid: the damped wings' slew (two modes per
    wing, first-order form) at 1e-8 against Dopri8 at 1e-12 on the same hybrid model, and
    ``sol.stats`` counts the Radau5 work (Jacobians, factorizations, Newton iterations)."""
    model = _wings().with_loads(
        jaxtree.BodyTorque(
            0, [0.0, 8.0, 3.0], lambda t: jaxtree._src.equations.loads.thruster_pulse(t, 0.5, 1.0, rise=0.1)
        )
    )
    state = model.initial._replace(gamma=jnp.zeros(model.n), gamma_dot=jnp.zeros(model.n))
    hm = jaxtree.hybrid_model(model, tuple(range(1, 9)), 2)
    ts = jnp.linspace(0.0, 3.0, 7)
    ref = jaxtree.simulate_hybrid(hm, 3.0, y0=state, saveat=ts, rtol=1e-12, atol=1e-12, truncation_error=False)
    sol = jaxtree.simulate_hybrid(
        hm, 3.0, y0=state, saveat=ts, rtol=1e-8, atol=1e-8, solver=jaxtree.Radau5(), truncation_error=False
    )
    assert np.abs(np.asarray(ref.gamma)).max() > 1e-3  # the wings bend
    np.testing.assert_allclose(np.asarray(sol.gamma), np.asarray(ref.gamma), atol=1e-6)
    np.testing.assert_allclose(np.asarray(sol.omega0), np.asarray(ref.omega0), atol=1e-6)
    assert int(sol.stats["jacobians"]) >= 1 and int(sol.stats["factorizations"]) >= 1
    assert int(sol.stats["newton_iterations"]) >= int(sol.stats["num_accepted_steps"])


def test_structured_jacobian_equals_jacfwd_and_central_differences(fig4, appendix):
    """jaxtree.hybrid_jacobian (the Jacobian simulate_hybrid gives Radau5: the large variables'
    columns and the modal ones in two forward passes) against jax.jacfwd of hybrid_rhs over the flat
    state (round-off) and against central differences (h = 1e-6: error ~h^2 times the third
    derivative, observed ~1e-9 relative): Fig. 4 precomputed and general (first-order modes,
    prescribed platform, large gimbals and rotor) and Appendix C (real modes, Eq. 121), at random
    small-deformation states."""
    rng = np.random.default_rng(23)
    model, hm = fig4
    general = jaxtree.hybrid_model(model, FIG4_SMALL, omega0=FIG4_SPIN, basis="set", precompute=False)
    cases = [(model, hm), (model, general), (appendix[0], appendix[2])]
    rhs = eqx.filter_jit(jaxtree.hybrid_rhs)
    for m, h in cases:
        y = h.pack(small_random_state(m, rng, scale=0.1))
        t = jnp.asarray(rng.uniform(0.0, 2.0))
        J = np.asarray(eqx.filter_jit(jaxtree.hybrid_jacobian)(t, y, h))
        ref = np.asarray(eqx.filter_jit(jax.jacfwd(jaxtree.hybrid_rhs, argnums=1))(t, y, h))
        assert J.shape == (h.size, h.size)
        np.testing.assert_allclose(J, ref, atol=ROUNDOFF * np.abs(ref).max())
        step = 1e-6
        fd = np.stack(
            [
                (np.asarray(rhs(t, y + step * e, h)) - np.asarray(rhs(t, y - step * e, h))) / (2 * step)
                for e in np.eye(h.size)
            ],
            1,
        )
        np.testing.assert_allclose(J, fd, atol=FD_JACOBIAN * np.abs(fd).max())


def test_substructure_terms_by_one_batch_and_by_parts_agree_with_nested_jacfwd():
    """The Taylor coefficients of a substructure (jaxtree.substructure, Sec. III E) by the
    polarization of the quadratic velocity terms, in one batch (small substructures) and by parts
    (large ones, memory), against nested jacfwd / hessian of the same Gauss function at a bent
    nominal: the second derivatives of b in (y', v) and (v, v) and their derivative in y."""
    from jaxtree._src.hybrid import substructure as sub
    from jaxtree._src.vehicle.topology import Topology

    model = _wings()
    grp = sub.substructures(model, (1, 2, 3, 4))[0]
    topo = Topology(sub._local_topology(model, grp).parents)
    d = sub._bodies(model, grp)
    gbar = jnp.asarray([0.1, -0.2, 0.15, 0.05])
    zn, z6 = jnp.zeros(4), jnp.zeros(6)
    b = lambda y, yd, v: sub._gauss(topo, d, gbar + y, yd, v)[1]
    hess_v = lambda y: jax.hessian(lambda v: b(y, zn, v))(z6)
    ref = dict(
        A0=sub._gauss(topo, d, gbar, zn, z6)[0],
        A1=jax.jacfwd(lambda y: sub._gauss(topo, d, gbar + y, zn, z6)[0])(zn),
        G0=hess_v(zn),
        G1=jax.jacfwd(hess_v)(zn),
        G2=jax.jacfwd(lambda yd: jax.jacfwd(lambda v: b(zn, yd, v))(z6))(zn),
    )
    for one_batch in (True, False):
        tm = sub._terms(topo, d, gbar, one_batch)
        for key, value in ref.items():
            np.testing.assert_allclose(
                np.asarray(getattr(tm, key)), np.asarray(value), rtol=0, atol=ROUNDOFF * float(np.abs(value).max())
            )
