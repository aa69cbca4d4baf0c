"""Tests of jaxtree.linearize (Likins 1972, Sec. III A-C, Eqs. 28-69, Appendix C).

Every expected value comes from outside the jacfwd code: central finite differences
of the nonlinear Eq. (1) residual of the independent Lagrange oracle (tests/oracle.py),
closed forms of the seed (Eqs. 36d, 51, 55c, 58b, 66-67) written out here, and the
printed Appendix C equations C-61..C-65 and C-70..C-74.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree import State
from jaxtree._src.equations.barycentric import barycentric

from helpers import appendix_c
from oracle import oracle_at
from trees import ALL, PARENTS, planar_model, principal_moments, sprung_tree

# jaxtree's jacfwd linearization against closed forms and the oracle, O(1) entries in float64: round-off
ROUNDOFF = 1e-12
# against central differences with h = 1e-5 on O(1) angles (fd_ijk): truncation ~ h^2 |r'''| ~ 1e-9 and
# round-off ~ 1e-16 |r| / h ~ 1e-10 of the matrix scale; this leaves a margin of 100
RTOL_FD = 1e-7


def oracle_residual(model, omega0, gamma, gamma_dot, acc):
    """Residual of Eq. (1), [a] x - rhs, from the independent Lagrange oracle (springs/dampers as tau)."""
    tau = -np.asarray(model.stiffness) * gamma - np.asarray(model.damping) * gamma_dot
    o = oracle_at(model, State(np.eye(3), omega0, gamma, gamma_dot), tau=tau)
    return np.asarray(o["mass_matrix"]) @ acc - np.asarray(o["rhs"])


def fd_ijk(model, small, omega0, gamma, h=1e-5):
    """I, J, K by central differences of the oracle residual, nominal motion held (Eq. 40):
    omega0 constant, omega0_dot = 0, the other angles at `gamma`, their rates and accelerations 0."""
    n = model.n
    rows = [3 + k - 1 for k in small]
    base = dict(g=np.array(gamma, float), gd=np.zeros(n), acc=np.zeros(n + 3))

    def r(which, k, step):
        g, gd, acc = base["g"].copy(), base["gd"].copy(), base["acc"].copy()
        {"y": g, "yd": gd, "ydd": acc[3:]}[which][k - 1] += step
        return oracle_residual(model, omega0, g, gd, acc)[rows]

    out = []
    for which in ("ydd", "yd", "y"):
        cols = [(r(which, k, h) - r(which, k, -h)) / (2 * h) for k in small]
        out.append(np.stack(cols, 1))
    return out


def dkj(model):
    return (
        np.asarray(barycentric(model).Dkj),
        float(barycentric(model).total_mass),
        np.asarray(barycentric(model).Phi_kk),
    )


def eps(model):
    """eps[s, k] for s = 1..n (row 0 unused), k = 0..n."""
    e = np.zeros((model.n + 1, model.n + 1))
    e[1:] = model.topology.path_elements
    return e


# ----------------------------------------------------------------------------- input checks
def test_bad_input_messages():
    model = jaxtree.load_scene("fig4")  # hinge 1 is prescribed
    with pytest.raises(ValueError, match="not in 1..10"):
        jaxtree.linearize(model, (0,))
    with pytest.raises(ValueError, match="not in 1..10"):
        jaxtree.linearize(model, (11,))
    with pytest.raises(ValueError, match="prescribed"):
        jaxtree.linearize(model, (1, 5))
    with pytest.raises(KeyError, match="no body named 'nope'"):
        jaxtree.linearize(model, ("nope",))
    with pytest.raises(ValueError, match="reference body"):
        jaxtree.linearize(model, ("bus",))
    with pytest.raises(ValueError, match="twice"):
        jaxtree.linearize(model, (5, "panel_root"))
    with pytest.raises(ValueError, match="empty"):
        jaxtree.linearize(model, ())
    with pytest.raises(TypeError):
        jaxtree.linearize(model, (True,))
    with pytest.raises(ValueError, match="shape"):
        jaxtree.linearize(model, (5,), omega0=[0.0, 1.0])
    # names and indices give the same system; coordinates in ascending hinge order
    model = jaxtree.load_scene("appendix_c")
    a = jaxtree.linearize(model, ("rod_minus", 1), omega0=[0.0, 0.0, 0.3])
    b = jaxtree.linearize(model, (2, 1), omega0=[0.0, 0.0, 0.3])
    assert a.coordinates == ("rod_plus", "rod_minus") and a.hinges == (1, 2)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# ----------------------------------------------------------------------------- finite differences
def test_ijk_against_finite_differences_of_oracle():
    """I, J, K (Eqs. 36d, 43, 44) equal central differences of the nonlinear Eq. (1) residual of the
    independent oracle, with the nominal motion held: spinning, large angles away from zero, springs and
    dampers (Eqs. 45-46), a set A that is not a terminal appendage."""
    rng = np.random.default_rng(7)
    model = sprung_tree(rng, PARENTS, damping=0.7)
    small = (2, 3, 4, 6)  # not a terminal appendage: hinge 5 (large) is outboard of hinge 4
    omega0 = rng.normal(size=3)
    gamma = rng.normal(size=model.n) * 0.6
    lin = jaxtree.linearize(model, small, omega0=omega0, gamma=gamma)
    I, J, K = (np.asarray(x) for x in lin)
    Ifd, Jfd, Kfd = fd_ijk(model, small, omega0, gamma)
    for a, b in ((I, Ifd), (J, Jfd), (K, Kfd)):
        np.testing.assert_allclose(a, b, atol=RTOL_FD * np.abs(b).max())
    # the bias is minus the residual of the rows of A on the nominal motion
    r0 = oracle_residual(model, omega0, gamma, np.zeros(model.n), np.zeros(model.n + 3))
    np.testing.assert_allclose(np.asarray(lin.bias), -r0[[3 + k - 1 for k in small]], atol=1e-10)
    # the damper gives J its symmetric part d_i delta_ij (Eq. 46); the rest of J is skew here
    np.testing.assert_allclose(0.5 * (J + J.T), np.diag(np.asarray(model.damping)[np.array(small) - 1]), atol=ROUNDOFF)


def test_external_loads_enter_through_the_derivative():
    """A follower torque on link 2 proportional to gamma_1 and a body-fixed (follower) force on link 3:
    K from jacfwd equals central differences of jaxtree's nonlinear Eq. (1) with the loads; K is then
    not symmetric and structure() says so."""
    rng = np.random.default_rng(3)
    base = sprung_tree(rng, [0, 1, 2])
    g2 = np.asarray(base.axis[1])

    def fn(t, state):
        F = jnp.stack([jnp.zeros(3), jnp.array([0.0, 0.0, 5.0])])
        T = jnp.stack([7.0 * state.gamma[0] * jnp.asarray(g2), jnp.zeros(3)])
        return F, T

    model = base.with_loads(jaxtree.FunctionLoads((2, 3), fn))
    small = (1, 2, 3)
    w0 = np.array([0.1, -0.2, 0.3])
    I, J, K = (np.asarray(x) for x in jaxtree.linearize(model, small, omega0=w0))

    @eqx.filter_jit
    def _res(model, g, gd, acc):
        A, rhs = jaxtree.rotational_equations(model, State(jnp.eye(3), jnp.asarray(w0), g, gd))
        return (A @ acc - rhs)[3:]

    res = lambda g, gd, acc: np.asarray(_res(model, jnp.asarray(g), jnp.asarray(gd), jnp.asarray(acc)))

    h = 1e-5
    Kfd = np.stack([(res(h * e, 0 * e, np.zeros(6)) - res(-h * e, 0 * e, np.zeros(6))) / (2 * h) for e in np.eye(3)], 1)
    np.testing.assert_allclose(
        K, Kfd, atol=RTOL_FD * np.abs(Kfd).max()
    )  # the same budget: central differences, h = 1e-5
    st = jaxtree.structure(I, J, K)
    assert not st.K_symmetric and st.kind == "general"


# ----------------------------------------------------------------------------- Sec. III C cases
def test_nonspinning_elastic_eq51_and_36d():
    """omega0 = 0, elastic hinges, no loads: J = 0 and K = diag(k_i) (Eq. 51), also with large angles
    away from zero; I from Eq. (36d) with all C_bar = U, written out with Defs. 35-36."""
    rng = np.random.default_rng(11)
    model = sprung_tree(rng, PARENTS)
    small = (2, 3, 4, 6)
    for gamma in (np.zeros(model.n), rng.normal(size=model.n) * (1 - np.isin(np.arange(1, 7), small))):
        I, J, K = (np.asarray(x) for x in jaxtree.linearize(model, small, gamma=gamma))
        assert np.abs(J).max() == 0.0
        np.testing.assert_allclose(K, np.diag(np.asarray(model.stiffness)[np.array(small) - 1]), atol=ROUNDOFF)
        st = jaxtree.structure(I, J, K)
        assert st.J_zero and st.K_symmetric and st.kind == "real"
    # Eq. (36d) at the nominal state gamma = 0 (C_bar = U)
    D, M, Phi = dkj(model)
    e = eps(model)
    g = np.vstack([np.zeros(3), np.asarray(model.axis)])
    P = range(1, model.n + 1)
    I36 = np.zeros((len(small), len(small)))
    for a, i in enumerate(small):
        for b, k in enumerate(small):
            v = sum(e[i, r] * e[k, r] * g[i] @ Phi[r] @ g[k] for r in P)
            v -= M * sum(
                e[i, r] * e[k, s] * g[i] @ ((D[s, r] @ D[r, s]) * np.eye(3) - np.outer(D[s, r], D[r, s])) @ g[k]
                for r in P
                for s in P
                if s != r
            )
            I36[a, b] = v
    I0 = np.asarray(jaxtree.linearize(model, small).I)
    np.testing.assert_allclose(I0, I36, rtol=ROUNDOFF, atol=ROUNDOFF * np.abs(I36).max())


def test_transverse_case_eqs_55_58():
    """All hinge axes parallel to g, omega0 = Omega g, geometry in 3-D (Figs. 8-10): J skew and equal to
    Eq. (55c), K symmetric and equal to Eq. (58b) plus the springs."""
    rng = np.random.default_rng(5)
    g = np.array([0.0, 0.0, 1.0])
    model = planar_model(rng, PARENTS, g, lambda k: (rng.normal(size=3), rng.normal(size=3)))
    Omega = 0.8
    small = ALL
    lin = jaxtree.linearize(model, small, omega0=Omega * g)
    I, J, K = (np.asarray(x) for x in lin)
    D, M, _ = dkj(model)
    e = eps(model)
    n = model.n
    P, B = range(1, n + 1), range(0, n + 1)
    gt = np.array([[0, -g[2], g[1]], [g[2], 0, -g[0]], [-g[1], g[0], 0]])
    J55 = np.zeros((n, n))
    K58 = np.diag(np.asarray(model.stiffness))
    for i in P:
        for j in P:
            J55[i - 1, j - 1] = (
                2 * M * Omega * sum(e[i, k] * e[j, s] * g @ np.cross(D[k, s], D[s, k]) for k in P for s in P if s != k)
            )
            K58[i - 1, j - 1] += (
                -M
                * Omega**2
                * sum(
                    e[i, k] * (e[j, s] - e[j, k]) * g @ np.cross(D[k, s], gt @ gt @ gt @ D[s, k])
                    for k in P
                    for s in B
                    if s != k
                )
            )
    scale = np.abs(K).max()
    np.testing.assert_allclose(J, J55, atol=ROUNDOFF * scale)
    np.testing.assert_allclose(K, K58, atol=ROUNDOFF * scale)
    st = jaxtree.structure(I, J, K)
    assert st.J_skew and not st.J_zero and st.K_symmetric and st.kind == "gyroscopic"
    assert np.abs(J).max() > 1e-3 * scale  # a genuinely gyroscopic case


def test_rectilinear_transverse_case_J_zero():
    """Transverse case with all D^{qr} parallel (Eq. 56: rectilinear, an equatorial boom): J = 0."""
    rng = np.random.default_rng(6)
    g = np.array([0.0, 0.0, 1.0])
    x = np.array([1.0, 0.0, 0.0])
    side = {1: 1, 2: 1, 3: 1, 4: -1, 5: -1, 6: 1}
    model = planar_model(
        rng, PARENTS, g, lambda k: (rng.uniform(0.3, 1.0) * x * side[k], -rng.uniform(0.3, 1.0) * x * side[k])
    )
    I, J, K = (np.asarray(x) for x in jaxtree.linearize(model, ALL, omega0=1.3 * g))
    st = jaxtree.structure(I, J, K)
    assert st.J_zero and st.K_symmetric and st.kind == "real"


def test_meridional_case_eqs_66_67():
    """Meridional case (Eqs. 59-67): g = b2 for all hinges, omega0 = Omega b1, all D along b3, principal
    axes along b1, b2, b3. J = 0, K symmetric; K equals Eq. (66) only with the extra term
    -M sum_s D_ks D_sk (EQUATIONS.md note; erratum), and I equals Eq. (67)."""
    rng = np.random.default_rng(9)
    b2, b3 = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
    parents = PARENTS
    sign = {1: 1, 2: 1, 3: 1, 4: -1, 5: -1, 6: 1}
    hop = [sign[k] * rng.uniform(0.2, 0.8) * b3 for k in range(1, 7)]
    hob = [-sign[k] * rng.uniform(0.2, 0.8) * b3 for k in range(1, 7)]
    inertia = [np.diag(principal_moments(rng)) for _ in range(7)]
    model = sprung_tree(rng, parents, axes=[b2] * 6, hinge_on_parent=hop, hinge_on_body=hob, inertia=inertia)
    Omega = 1.7
    I, J, K = (np.asarray(x) for x in jaxtree.linearize(model, ALL, omega0=[Omega, 0.0, 0.0]))
    st = jaxtree.structure(I, J, K)
    assert st.J_zero and st.K_symmetric and st.kind == "real"
    D, M, Phi = dkj(model)
    Dz = D[..., 2]
    e = eps(model)
    n = model.n
    P, B = range(1, n + 1), range(0, n + 1)
    k = np.asarray(model.stiffness)
    printed = np.diag(k).astype(float)
    corrected = np.diag(k).astype(float)
    I67 = np.zeros((n, n))
    for i in P:
        for j in P:
            printed[i - 1, j - 1] += Omega**2 * sum(e[i, q] * e[j, q] * (Phi[q, 0, 0] - Phi[q, 2, 2]) for q in P)
            corrected[i - 1, j - 1] += Omega**2 * sum(
                e[i, q] * e[j, q] * (Phi[q, 0, 0] - Phi[q, 2, 2] - M * sum(Dz[q, s] * Dz[s, q] for s in B if s != q))
                for q in P
            )
            I67[i - 1, j - 1] = sum(e[i, r] * e[j, r] * Phi[r, 1, 1] for r in P) - M * sum(
                e[i, r] * e[j, s] * Dz[s, r] * Dz[r, s] for r in P for s in P if s != r
            )
    scale = np.abs(K).max()
    np.testing.assert_allclose(K, corrected, atol=ROUNDOFF * scale)
    np.testing.assert_allclose(I, I67, atol=ROUNDOFF * np.abs(I67).max())
    # the printed Eq. (66) misses the -M sum D_ks D_sk term: off by far more than round-off
    assert np.abs(K - printed).max() > 1e-2 * scale


# ----------------------------------------------------------------------------- Appendix C
def _appendix_c_expected(p, w, wd):
    """C-61..C-65 as residual (left side minus right side), first order in gamma: returns
    residual (5,), accel (5, 2), rate (5, 2), angle (5, 2)."""
    M, R, J, c, r, k = p["M"], p["R"], p["J"], p["c"], p["r"], p["k"]
    I1, I2, I3 = p["I1"], p["I2"], p["I3"]
    w1, w2, w3 = w
    d1, d2, d3 = wd
    res = np.array(
        [
            I1 * d1 - (I2 - I3) * w2 * w3,  # C-61
            I2 * d2 - (I3 - I1) * w3 * w1,  # C-62
            I3 * d3 - (I1 - I2) * w1 * w2,  # C-63
            c * d1 + c * w2 * w3,  # C-64
            c * d1 + c * w2 * w3,
        ]
    )  # C-65
    acc = np.array([[c, c], [0, 0], [0, 0], [J - M * R**2, M * R**2], [M * R**2, J - M * R**2]])
    rate = np.array([[0, 0], [0, 0], [-2 * c * w2] * 2, [0, 0], [0, 0]])
    diag = -(J * (w2**2 - w3**2) - M * R**2 * (w1**2 + w2**2) - M * R * r * (w1**2 + w3**2)) + k
    off = -M * R**2 * (w1**2 + w2**2)
    ang = np.array(
        [[-c * (w2**2 - w3**2)] * 2, [-c * d3 + c * w1 * w2] * 2, [-c * d2 - c * w1 * w3] * 2, [diag, off], [off, diag]]
    )
    return res, acc, rate, ang


def test_appendix_c_linearized_equations_c61_c65():
    """Eq. (30) for Fig. C-1 with gamma_1, gamma_2 small and omega0 unrestricted reproduces C-61..C-65
    coefficient by coefficient (and with it C-53..C-60) at random omega0 and omega0_dot."""
    model, p = appendix_c()
    rng = np.random.default_rng(1)
    for _ in range(3):
        w, wd = rng.normal(size=3), rng.normal(size=3)
        lin = jaxtree.linearized_equations(
            model, (1, 2), State(jnp.eye(3), w, jnp.zeros(2), jnp.zeros(2)), omega0_dot=wd
        )
        exp = _appendix_c_expected(p, w, wd)
        for got, want in zip(lin, exp):
            np.testing.assert_allclose(np.asarray(got), want, atol=ROUNDOFF * max(1.0, np.abs(want).max()))


def test_appendix_c_transformation_c69_c74():
    """The transformation C-69 (gamma = T eta, rows C-64 +- C-65) gives the decoupled C-70..C-74."""
    model, p = appendix_c()
    M, R, J, c, r, k = p["M"], p["R"], p["J"], p["c"], p["r"], p["k"]
    I1, I2, I3 = p["I1"], p["I2"], p["I3"]
    T = 0.5 * np.array([[1.0, 1.0], [1.0, -1.0]])  # C-69a
    np.testing.assert_allclose(np.linalg.inv(T), [[1, 1], [1, -1]])  # C-69b
    rows = np.eye(5)
    rows[3:, 3:] = [[1, 1], [1, -1]]  # sum and difference of C-64, C-65
    rng = np.random.default_rng(2)
    w, wd = rng.normal(size=3), rng.normal(size=3)
    w1, w2, w3 = w
    d1, d2, d3 = wd
    lin = jaxtree.linearized_equations(model, (1, 2), State(jnp.eye(3), w, jnp.zeros(2), jnp.zeros(2)), omega0_dot=wd)
    res = rows @ np.asarray(lin.residual)
    acc, rate, ang = (rows @ np.asarray(x) @ T for x in (lin.accel, lin.rate, lin.angle))
    exp_res = [
        I1 * d1 - (I2 - I3) * w2 * w3,
        I2 * d2 - (I3 - I1) * w3 * w1,
        I3 * d3 - (I1 - I2) * w1 * w2,
        2 * c * d1 + 2 * c * w2 * w3,
        0.0,
    ]  # C-70..C-74
    exp_acc = [[c, 0], [0, 0], [0, 0], [J, 0], [0, J - 2 * M * R**2]]
    exp_rate = [[0, 0], [0, 0], [-2 * c * w2, 0], [0, 0], [0, 0]]
    exp_ang = [
        [-c * (w2**2 - w3**2), 0],
        [-c * d3 + c * w1 * w2, 0],
        [-c * d2 - c * w1 * w3, 0],
        [-(J * (w2**2 - w3**2) - M * R * r * (w1**2 + w3**2) - k), 0],
        [0, -(J * (w2**2 - w3**2) - 2 * M * R**2 * (w1**2 + w2**2) - M * R * r * (w1**2 + w3**2) - k)],
    ]
    for got, want in ((res, exp_res), (acc, exp_acc), (rate, exp_rate), (ang, exp_ang)):
        np.testing.assert_allclose(got, np.asarray(want, float), atol=ROUNDOFF * 100)


def test_appendix_c_structure_and_eq66_extra_term():
    """Fig. C-1 spinning about the cylinder axis is a meridional case: J = 0, K symmetric with the
    spin stiffness (J + M R r) Omega^2 of C-64 (not the (J - M R^2) Omega^2 of the printed Eq. 66)."""
    model, p = appendix_c()
    Om = 1.3
    I, J, K = (np.asarray(x) for x in jaxtree.linearize(model, (1, 2), omega0=[0.0, 0.0, Om]))
    st = jaxtree.structure(I, J, K)
    assert st.kind == "real" and st.J_zero and st.K_symmetric
    np.testing.assert_allclose(K, np.diag([p["k"] + p["c"] * Om**2] * 2), rtol=1e-13)
    assert abs(K[0, 0] - (p["k"] + (p["J"] - p["M"] * p["R"] ** 2) * Om**2)) > 1.0


def test_vehicle_linearization_structure_and_fd():
    """Full-system linearization (Sec. III B, omega0 perturbations included): I, K symmetric, J skew at a
    relative equilibrium (Eq. 69), and the rows equal central differences of the nonlinear Eq. (1) with
    omega0 = Omega + theta' + Omega x theta, omega0_dot = theta'' + Omega x theta'."""
    model, p = appendix_c()
    Om = np.array([0.0, 0.0, 0.9])
    lin = jaxtree.linearize_vehicle(model, omega0=Om)
    I, J, K = (np.asarray(x) for x in lin)
    assert lin.coordinates[:3] == ("cylinder.rotation_1", "cylinder.rotation_2", "cylinder.rotation_3")
    st = jaxtree.structure(I, J, K)
    assert st.kind == "gyroscopic" and st.K_semidefinite and not st.K_positive
    np.testing.assert_allclose(np.asarray(lin.bias), 0.0, atol=ROUNDOFF)

    @eqx.filter_jit
    def eq1(model, w, g, gd, acc):
        A, rhs = jaxtree.rotational_equations(model, State(jnp.eye(3), w, g, gd))
        return A @ acc - rhs

    def r(q, qd, qdd):
        w = Om + qd[:3] + np.cross(Om, q[:3])
        acc = np.concatenate([qdd[:3] + np.cross(Om, qd[:3]), qdd[3:]])
        return np.asarray(eq1(model, jnp.asarray(w), jnp.asarray(q[3:]), jnp.asarray(qd[3:]), jnp.asarray(acc)))

    h = 1e-5
    z = np.zeros(5)
    cols = {
        name: np.stack(
            [
                (r(*[(h * e if a == name else z) for a in "pvq"]) - r(*[(-h * e if a == name else z) for a in "pvq"]))
                / (2 * h)
                for e in np.eye(5)
            ],
            1,
        )
        for name in "pvq"
    }
    # "q" = accelerations, "v" = rates, "p" = angles; same FD budget as above
    for got, name in ((I, "q"), (J, "v"), (K, "p")):
        np.testing.assert_allclose(got, cols[name], atol=RTOL_FD * np.abs(cols[name]).max())
