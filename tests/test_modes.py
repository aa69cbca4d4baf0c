"""Tests of jaxtree.modes (Likins 1972, Sec. III D-E, Eqs. 70-104).

Expected values come from closed forms (a spring-hinged rod on a massive base, the
Appendix C modes written from C-70..C-74, a spinning rigid body), from an independent
general eigensolver (scipy) applied to Eqs. (70)-(71), from finite differences, and from
small-amplitude simulations of the free nonlinear model.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg as sla
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import jaxtree
from jaxtree import Body, SpringDamper

from helpers import appendix_c
from trees import ALL, PARENTS, planar_model, sprung_tree

# modal identities (phi^T I phi = U, phi^T K phi = sigma^2) and closed forms, O(1) numbers in float64: round-off
ROUNDOFF = 1e-12
# one closed-form frequency or eigenvalue against jaxtree's: a few hundred ulps
ROUNDOFF_SCALAR = 1e-13
# against an independent eigensolver (numpy / scipy on B, Eq. 71, or the hand-built C-70..C-74 system):
# the conditioning of the non-symmetric first-order eigenproblem
EIGENSOLVER = 1e-9


def check_biorthogonality(md, tol=1e-10):
    """Eqs. (89)-(90): Phi'^T P Phi = U and Phi'^T Q Phi = Lambda (the undamped Lambda)."""
    R, Lf = np.asarray(md.right), np.asarray(md.left)
    P, Q = np.asarray(md.P), np.asarray(md.Q)
    keep = ~np.concatenate([np.asarray(md.rigid)] * 2)
    E = Lf.T @ P @ R
    F = Lf.T @ Q @ R
    lam = np.diag(F)[keep]
    np.testing.assert_allclose(E[np.ix_(keep, keep)], np.eye(keep.sum()), atol=tol)
    np.testing.assert_allclose(F[np.ix_(keep, keep)], np.diag(lam), atol=tol * max(1.0, np.abs(lam).max()))
    return lam


def rod_on_base(m0=50.0, m=2.0, L=1.5, r=0.8, k=30.0):
    """A uniform thin rod (mass m, length 2L) hinged at its end, axis b1, to a rim point r b2 of a base."""
    rod = np.diag([m * (2 * L) ** 2 / 12, 0.0, m * (2 * L) ** 2 / 12])
    return jaxtree.build_model(
        [
            Body("base", m0, np.diag([10.0, 12.0, 14.0])),
            Body(
                "rod",
                m,
                rod,
                parent=0,
                axis=[1, 0, 0],
                hinge_on_parent=[0, r, 0],
                hinge_on_body=[0, -L, 0],
                joint=SpringDamper(k),
            ),
        ]
    )


# ----------------------------------------------------------------------------- closed forms
def test_rod_on_massive_base_closed_form():
    """Base on its nominal motion (not rotating, free to translate): I = J - M R^2 with J = 4/3 m L^2,
    R = m L / M (C-3, C-47, C-48, C-59 for one rod); at rest K = k (Eq. 51); spinning about b3 (meridional)
    K = k + Omega^2 (J - M R^2 + (M - m) R r), the corrected Eq. (66) with D^{10} = -R b2 and
    D^{01} = (1 - m/M) r b2 (Defs. 33, 35; the base is not at the system mass center with one rod).
    A very massive base gives the clamped rod, sigma^2 = k / J."""
    m0, m, L, r, k = 50.0, 2.0, 1.5, 0.8, 30.0
    M, J = m0 + m, 4.0 / 3.0 * m * L**2
    R = m * L / M
    model = rod_on_base(m0, m, L, r, k)
    for Om in (0.0, 0.7):
        md = jaxtree.modes(jaxtree.linearize(model, ("rod",), omega0=[0, 0, Om]))
        assert md.kind == "real"
        np.testing.assert_allclose(
            md.frequencies,
            [np.sqrt((k + (J - M * R**2 + (M - m) * R * r) * Om**2) / (J - M * R**2))],
            rtol=ROUNDOFF_SCALAR,
        )
        assert md.labels == ("rod 100%",)
    heavy = rod_on_base(1e9, m, L, r, k)
    np.testing.assert_allclose(
        jaxtree.modes(jaxtree.linearize(heavy, (1,))).frequencies, [np.sqrt(k / J)], rtol=1e-8
    )  # the base mass 1e9 leaves m/M ~ 1e-9


def test_appendix_c_modes_held_base():
    """C-73/C-74 with omega0 held at Omega b3: eta1 = gamma1 + gamma2 (rods in phase) has
    sigma^2 = (k + (J + M R r) Omega^2) / J, eta2 (antiphase) has (k + (J + M R r) Omega^2) / (J - 2 M R^2).
    Real modes: phi^T I phi = U, phi^T K phi = sigma^2 (Eqs. 101-103)."""
    model, p = appendix_c()
    for Om in (0.0, 1.0):
        lin = jaxtree.linearize(model, (1, 2), omega0=[0, 0, Om])
        md = jaxtree.modes(lin)
        assert md.kind == "real"
        s1 = np.sqrt((p["k"] + p["c"] * Om**2) / p["J"])
        s2 = np.sqrt((p["k"] + p["c"] * Om**2) / (p["J"] - 2 * p["M"] * p["R"] ** 2))
        order = np.argsort([s1, s2])
        np.testing.assert_allclose(md.frequencies, np.array([s1, s2])[order], rtol=ROUNDOFF_SCALAR)
        phi = np.asarray(md.shapes)
        I, J, K = (np.asarray(x) for x in lin)
        np.testing.assert_allclose(phi.T @ I @ phi, np.eye(2), atol=1e-13)
        np.testing.assert_allclose(phi.T @ K @ phi, np.diag(np.asarray(md.frequencies) ** 2), atol=ROUNDOFF)
        sym = int(np.flatnonzero(order == 0)[0])  # the eta1 mode
        assert abs(phi[0, sym] - phi[1, sym]) < ROUNDOFF and abs(phi[0, 1 - sym] + phi[1, 1 - sym]) < ROUNDOFF
        assert " + " in md.labels[sym] and " - " in md.labels[1 - sym]
        check_biorthogonality(md)


def _dw_system(p, Om):
    """The omega0-perturbation system of C-70..C-74 about omega0 = Omega b3, by hand:
    x = [dw1, dw2, dw3, eta1, eta2, eta1', eta2'], E x' = F x. Returns its frequencies |Im lambda|."""
    M, R, J, c, r, k = p["M"], p["R"], p["J"], p["c"], p["r"], p["k"]
    I1, I2, I3 = p["I1"], p["I2"], p["I3"]
    E = np.eye(7)
    F = np.zeros((7, 7))
    E[0, 0], E[0, 5] = I1, c  # C-70: I1 dw1' + c eta1'' = (I2 - I3) Om dw2 - c Om^2 eta1
    F[0, 1], F[0, 3] = (I2 - I3) * Om, -c * Om**2
    E[1, 1] = I2  # C-71: I2 dw2' = (I3 - I1) Om dw1
    F[1, 0] = (I3 - I1) * Om
    E[2, 2] = I3  # C-72: I3 dw3' = 0 (to first order)
    F[3, 5] = F[4, 6] = 1.0
    E[5, 5], E[5, 0] = J, 2 * c  # C-73
    F[5, 1], F[5, 3] = -2 * c * Om, -(J + M * R * r) * Om**2 - k
    E[6, 6] = J - 2 * M * R**2  # C-74
    F[6, 4] = -(J + M * R * r) * Om**2 - k
    lam = np.linalg.eigvals(np.linalg.solve(E, F))
    assert np.abs(lam.real).max() < 1e-10
    return np.sort(np.abs(lam.imag))


def test_appendix_c_vehicle_modes():
    """All-small vehicle (omega0 perturbations included). At rest: three rigid modes, eta2 unchanged,
    and eta1 coupled to the base roll: sigma^2 = k / (J - 2 (J + M R r)^2 / I1) (C-70, C-73).
    Spinning about b3: the nonzero frequencies are those of C-70..C-74 linearized about Omega b3,
    plus Omega itself (a tilt of the spin axis seen in the spinning frame) and one rigid mode."""
    model, p = appendix_c()
    md = jaxtree.modes(jaxtree.linearize_vehicle(model))
    assert md.kind == "real"
    s_eta1 = np.sqrt(p["k"] / (p["J"] - 2 * p["c"] ** 2 / p["I1"]))
    s_eta2 = np.sqrt(p["k"] / (p["J"] - 2 * p["M"] * p["R"] ** 2))
    np.testing.assert_allclose(md.frequencies, [0, 0, 0] + sorted([s_eta1, s_eta2]), atol=ROUNDOFF, rtol=ROUNDOFF)
    assert list(np.asarray(md.rigid)) == [True, True, True, False, False]
    assert all(lab.startswith("rigid body") for lab in md.labels[:3])
    Om = 1.0
    md = jaxtree.modes(jaxtree.linearize_vehicle(model, omega0=[0, 0, Om]))
    assert md.kind == "gyroscopic"
    dw = _dw_system(p, Om)  # seven values: 0 (dw3), and three pairs
    expected = np.sort(np.concatenate([[0.0, Om], np.unique(np.round(dw[1:], 12))]))
    np.testing.assert_allclose(md.frequencies, expected, atol=EIGENSOLVER)
    assert list(np.asarray(md.rigid)) == [True, False, False, False, False]
    assert md.labels[0].startswith("rigid body: cylinder.rotation_3")
    check_biorthogonality(md)


# ----------------------------------------------------------------------------- gyroscopic
@pytest.fixture(scope="module")
def transverse():
    """A spinning transverse-deformation tree (Figs. 8-10): J skew and nonzero, K positive definite."""
    rng = np.random.default_rng(5)
    g = np.array([0.0, 0.0, 1.0])
    model = planar_model(rng, PARENTS, g, lambda k: (rng.normal(size=3), rng.normal(size=3)))
    return model, jaxtree.linearize(model, ALL, omega0=0.8 * g)


def test_gyroscopic_modes_left_eigenvectors_eq96(transverse):
    """Eqs. (79)-(96): purely imaginary eigenvalues equal to those of an independent general eigensolver
    on B (Eq. 71); Phi'^T P Phi = U, Phi'^T Q Phi = Lambda; the left eigenvectors of (70) computed
    independently (scipy, generalized problem Q - lambda P) are the conjugates of the right ones (Eq. 96)."""
    _, lin = transverse
    md = jaxtree.modes(lin)
    assert md.kind == "gyroscopic"
    nu = lin.nu
    lam = np.asarray(md.eigenvalues)
    assert np.abs(lam.real).max() == 0.0
    np.testing.assert_allclose(lam[nu:], np.conj(lam[:nu]))
    P, Q, B = (np.asarray(x) for x in jaxtree.first_order(*lin))
    ref = np.linalg.eigvals(B)
    np.testing.assert_allclose(np.sort(np.abs(ref.imag))[1::2], md.frequencies, rtol=EIGENSOLVER)
    check_biorthogonality(md)
    w, vl, vr = sla.eig(Q, P, left=True, right=True)
    right = np.asarray(md.right)
    for j in range(2 * nu):
        i = np.argmin(np.abs(w - lam[j]))
        # Phi'^j = conj(Phi^j) <=> the scipy left eigenvector (vl^H (Q - lambda P) = 0, i.e. Phi' = conj(vl))
        # is parallel to Phi^j
        a, b = vl[:, i], right[:, j]
        assert abs(abs(np.vdot(a, b)) - np.linalg.norm(a) * np.linalg.norm(b)) < 1e-8 * np.linalg.norm(b)
    # Eq. (70) holds for each right eigenvector: (Q - lambda P) Phi = 0
    np.testing.assert_allclose((Q @ right) - (P @ right) * lam[None, :], 0, atol=EIGENSOLVER)


def test_real_solution_eq95(transverse):
    """Eq. (94)-(95): y = a phi e^(lambda t) + c.c. solves I y'' + J y' + K y = 0 and equals
    2 e^(alpha t) {Re phi [c cos - d sin] - Im phi [d cos + c sin]}; the printed (95), without the 2 and
    with the other signs, does not (erratum)."""
    _, lin = transverse
    I, J, K = (np.asarray(x) for x in lin)
    md = jaxtree.modes(lin)
    j = 2
    lam, phi = complex(md.eigenvalues[j]), np.asarray(md.shapes[:, j])
    a = 0.3 - 0.7j
    c, d, al, s = a.real, a.imag, lam.real, lam.imag
    for t in (0.0, 0.37, 2.1):
        y = 2 * (a * phi * np.exp(lam * t)).real
        yd = 2 * (a * lam * phi * np.exp(lam * t)).real
        ydd = 2 * (a * lam**2 * phi * np.exp(lam * t)).real
        np.testing.assert_allclose(I @ ydd + J @ yd + K @ y, 0, atol=1e-10 * np.abs(K @ y).max())
        fixed = (
            2
            * np.exp(al * t)
            * (phi.real * (c * np.cos(s * t) - d * np.sin(s * t)) - phi.imag * (d * np.cos(s * t) + c * np.sin(s * t)))
        )
        printed = np.exp(al * t) * (
            phi.real * (c * np.cos(s * t) + d * np.sin(s * t)) + phi.imag * (d * np.cos(s * t) - c * np.sin(s * t))
        )
        np.testing.assert_allclose(fixed, y, atol=1e-14 * np.abs(y).max() + 1e-15)
        assert np.abs(printed - y).max() > 0.1 * np.abs(y).max()


def test_general_case_with_dampers():
    """Hinge dampers make J non-skew: the general path. Eigenvalues equal an independent eigensolver's,
    Phi'^T P Phi = U and Phi'^T Q Phi = Lambda (Eqs. 89-90), 0 < zeta < 1."""
    rng = np.random.default_rng(7)
    model = sprung_tree(rng, PARENTS, damping=0.7)
    lin = jaxtree.linearize(model, (2, 3, 4, 6), omega0=[0.2, -0.1, 0.5])
    md = jaxtree.modes(lin)
    assert md.kind == "general"
    lam = check_biorthogonality(md)
    P, Q, B = (np.asarray(x) for x in jaxtree.first_order(*lin))
    ref = np.sort_complex(np.linalg.eigvals(B))
    np.testing.assert_allclose(np.sort_complex(np.asarray(md.eigenvalues)), ref, atol=EIGENSOLVER * np.abs(ref).max())
    np.testing.assert_allclose(lam, md.eigenvalues, atol=EIGENSOLVER * np.abs(ref).max())
    z = np.asarray(md.damping_ratios)
    assert np.all((z > 0) & (z < 1))
    np.testing.assert_allclose(z, -np.asarray(md.eigenvalues[:4]).real / np.abs(np.asarray(md.eigenvalues[:4])))
    assert np.all(np.diff(np.asarray(md.frequencies)) >= 0) and len(md.labels) == 4


def test_minor_axis_spin_is_stable_with_indefinite_K():
    """A rigid body spinning about its minor axis: in the spinning frame (theta small, Euler's equations,
    omega = Omega b3 + theta' + Omega x theta) I = diag(I1, I2), J = Omega (I3 - I1 - I2) [[0, 1], [-1, 0]],
    K = Omega^2 diag(I3 - I2, I3 - I1) is negative definite, yet the motion is stable (gyroscopic
    stabilization): frequencies Omega and Omega sqrt((I1 - I3)(I2 - I3) / (I1 I2)). The seed's statement
    after Eq. (95) that I, K not both semidefinite means instability is too strong (erratum)."""
    I1, I2, I3, Om = 5.0, 4.0, 2.0, 1.5
    I = np.diag([I1, I2])
    J = Om * (I3 - I1 - I2) * np.array([[0.0, 1.0], [-1.0, 0.0]])
    K = Om**2 * np.diag([I3 - I2, I3 - I1])
    md = jaxtree.modes(I, J, K)
    assert md.kind == "general"  # K indefinite: no Hermitian form, but stable
    np.testing.assert_allclose(
        md.frequencies, sorted([Om, Om * np.sqrt((I1 - I3) * (I2 - I3) / (I1 * I2))]), rtol=1e-10
    )
    assert np.abs(np.asarray(md.eigenvalues).real).max() < 1e-10
    check_biorthogonality(md)


# ----------------------------------------------------------------------------- repeated, defective, unstable
def test_repeated_eigenvalues():
    """Repeated frequencies with independent eigenvectors, in the real, gyroscopic and general paths."""
    rng = np.random.default_rng(4)
    A = rng.normal(size=(3, 3))
    I = A @ A.T + 3 * np.eye(3)
    L = np.linalg.cholesky(I)
    V = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    phi0 = np.linalg.solve(L.T, V)  # I-orthonormal
    K = I @ phi0 @ np.diag([1.0, 1.0, 4.0]) @ phi0.T @ I
    md = jaxtree.modes(I, np.zeros((3, 3)), K)
    np.testing.assert_allclose(md.frequencies, [1, 1, 2], rtol=ROUNDOFF)
    phi = np.asarray(md.shapes)
    np.testing.assert_allclose(phi.T @ I @ phi, np.eye(3), atol=ROUNDOFF)
    np.testing.assert_allclose(phi.T @ K @ phi, np.diag([1, 1, 4]), atol=ROUNDOFF)
    check_biorthogonality(md)
    # two identical gyroscopic blocks, mixed by a congruence: repeated pairs
    Ib, Jb, Kb = np.diag([2.0, 3.0]), np.array([[0.0, 1.5], [-1.5, 0.0]]), np.diag([5.0, 7.0])
    T = rng.normal(size=(4, 4)) + 3 * np.eye(4)
    blk = lambda X: T.T @ sla.block_diag(X, X) @ T
    Ig, Jg, Kg = blk(Ib), blk(Jb), blk(Kb)
    md = jaxtree.modes(Ig, Jg, Kg)
    assert md.kind == "gyroscopic"
    f = np.asarray(md.frequencies)
    np.testing.assert_allclose(f[0], f[1], rtol=1e-10)
    np.testing.assert_allclose(f[2], f[3], rtol=1e-10)
    check_biorthogonality(md)
    md = jaxtree.modes(Ig, Jg + 0.1 * Ig, Kg)  # proportional damping: general path, still repeated
    assert md.kind == "general"
    check_biorthogonality(md, tol=EIGENSOLVER)


def test_rejected_systems_have_clear_messages():
    one = lambda x: np.array([[x]])
    with pytest.raises(jaxtree.UnstableError, match="sigma"):
        jaxtree.modes(one(1.0), one(0.0), one(-2.0))
    with pytest.raises(jaxtree.UnstableError, match="positive real part"):
        jaxtree.modes(one(1.0), one(-0.3), one(2.0))  # negative damping
    with pytest.raises(jaxtree.DefectiveError, match="defective"):
        jaxtree.modes(one(1.0), one(2.0), one(1.0))  # critical damping: lambda = -1 twice, one eigenvector
    with pytest.raises(jaxtree.ModalError, match="positive definite"):
        jaxtree.modes(one(-1.0), one(0.0), one(1.0))
    with pytest.raises(jaxtree.ModalError, match="modal damping"):
        jaxtree.modes(one(1.0), one(0.1), one(1.0), damping=0.02)
    with pytest.raises(ValueError, match="kind"):
        jax.grad(lambda k: jaxtree.modes(one(1.0), one(0.0), k * one(1.0)).frequencies[0])(1.0)


# ----------------------------------------------------------------------------- modal damping
def test_modal_damping_real_and_spinning(transverse):
    """Eq. (104) in the real case: eigenvalues -zeta sigma +- i sigma sqrt(1 - zeta^2) and the damped state
    matrix has phi^T C phi = 2 zeta sigma; spinning: i sigma -> -zeta sigma +- i sigma (Sec. III E), and the
    real damped state matrix B has exactly these eigenvalues (independent eigensolver)."""
    model, p = appendix_c()
    lin = jaxtree.linearize(model, (1, 2))
    zeta = np.array([0.02, 0.05])
    md0 = jaxtree.modes(lin)
    md = jaxtree.modes(lin, damping=zeta)
    s = np.asarray(md0.frequencies)
    np.testing.assert_allclose(md.frequencies, s)
    up = -zeta * s + 1j * s * np.sqrt(1 - zeta**2)
    np.testing.assert_allclose(md.eigenvalues, np.concatenate([up, up.conj()]), rtol=ROUNDOFF_SCALAR)
    B = np.asarray(md.B)
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(B)), np.sort_complex(np.asarray(md.eigenvalues)), rtol=1e-10
    )
    I = np.asarray(lin.I)
    C = -I @ B[2:, 2:]
    phi = np.asarray(md.shapes)
    np.testing.assert_allclose(phi.T @ C @ phi, np.diag(2 * zeta * s), atol=ROUNDOFF)
    # spinning (gyroscopic)
    _, lin = transverse
    zeta = np.linspace(0.01, 0.05, lin.nu)
    md = jaxtree.modes(lin, damping=zeta)
    s = np.asarray(md.frequencies)
    up = (-zeta + 1j) * s
    np.testing.assert_allclose(md.eigenvalues, np.concatenate([up, up.conj()]), rtol=ROUNDOFF_SCALAR)
    B = np.asarray(md.B)
    assert B.dtype.kind == "f"
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(B)), np.sort_complex(np.asarray(md.eigenvalues)), rtol=EIGENSOLVER
    )


# ----------------------------------------------------------------------------- gradients
def _freq_fn(model, small, omega0, kind):
    def f(p):
        m = eqx.tree_at(
            lambda m: (m.stiffness, m.mass, m.hinge_on_body),
            model,
            (model.stiffness.at[0].set(p[0]), model.mass.at[1].set(p[1]), model.hinge_on_body.at[0, 1].set(p[2])),
        )
        I, J, K = jaxtree.linearize(m, small, omega0=omega0)
        return jaxtree.modes(I, J, K, kind=kind).frequencies

    return f


@pytest.mark.parametrize("case", ["real", "gyroscopic"])
def test_frequency_gradients_match_finite_differences(case, transverse):
    """d sigma / d (stiffness k_1, mass m_1, hinge geometry p^{1 0}_y) by forward-mode AD through
    linearize and modes equals central differences, for real and gyroscopic modes."""
    if case == "real":
        model, _ = appendix_c()
        small, w = (1, 2), jnp.zeros(3)
    else:
        model, lin = transverse
        small, w = ALL, jnp.array([0.0, 0.0, 0.8])
    f = _freq_fn(model, small, w, case)  # eager: reuses the compiled linearization of the other tests
    p0 = jnp.array([float(model.stiffness[0]), float(model.mass[1]), float(model.hinge_on_body[0, 1])])
    ad = np.asarray(jax.jit(jax.jacfwd(f))(p0))
    h = 1e-5 * np.maximum(np.abs(np.asarray(p0)), 1.0)
    fd = np.stack(
        [(np.asarray(f(p0.at[i].add(h[i]))) - np.asarray(f(p0.at[i].add(-h[i])))) / (2 * h[i]) for i in range(3)], 1
    )
    # central differences with h = 1e-5 relative: truncation ~ h^2 ~ 1e-10, round-off ~ 1e-16 / h ~ 1e-11
    # relative to sigma; 1e-7 of the largest sensitivity leaves a wide margin.
    np.testing.assert_allclose(ad, fd, atol=1e-7 * np.abs(fd).max())
    assert np.abs(fd).min(axis=0).max() > 0  # every parameter matters to some mode


# ----------------------------------------------------------------------------- simulation
@pytest.fixture(scope="module")
def dynamics():
    model, _ = appendix_c()
    f = eqx.filter_jit(lambda m, C, w, g, gd: jaxtree.forward_dynamics(m, C, w, g, gd))
    return model, f


def _simulate(model, f, C0, w0, g0, gd0, T, ts):
    def rhs(t, x):
        C, w, g, gd = x[:9].reshape(3, 3), x[9:12], x[12:14], x[14:16]
        wd, gdd = f(model, C, w, g, gd)
        return np.concatenate(
            [
                (-jaxtree_tilde(w) @ C).ravel(),  # Eq. (3)
                np.asarray(wd),
                gd,
                np.asarray(gdd),
            ]
        )

    x0 = np.concatenate([C0.ravel(), w0, g0, gd0])
    return solve_ivp(rhs, (0, T), x0, t_eval=ts, method="DOP853", rtol=1e-12, atol=1e-13).y


def jaxtree_tilde(w):
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


@pytest.mark.parametrize("Om", [0.0, 1.0])
def test_vehicle_modes_against_nonlinear_simulation(Om, dynamics):
    """Free vehicle of Fig. C-1: start the nonlinear model on a sum of two elastic modal solutions of the
    full-system linearization, y = Re sum a_j phi^j e^(lambda_j t) with amplitude eps; the simulated
    attitude (relative to the steadily spinning frame) and hinge angles follow the modal prediction with an
    error that shrinks like eps^2 (two amplitudes)."""
    model, f = dynamics
    W = np.array([0.0, 0.0, Om])
    lin = jaxtree.linearize_vehicle(model, omega0=W)
    md = jaxtree.modes(lin)
    nu = lin.nu
    picked = [j for j in range(nu) if not md.rigid[j]][-2:]  # the two highest elastic modes
    lam = np.asarray(md.eigenvalues)[picked]
    phi = np.asarray(md.shapes)[:, picked]
    coef = np.array([1.0, 0.6 - 0.4j])
    coef = coef / np.abs(phi * coef).max()  # unit peak amplitude
    T = 2 * 2 * np.pi / np.abs(lam.imag).min()
    ts = np.linspace(0, T, 200)
    lin_y = lambda t: (phi @ (coef[:, None] * np.exp(lam[:, None] * t[None, :]))).real
    lin_yd = lambda t: (phi @ (coef[:, None] * lam[:, None] * np.exp(lam[:, None] * t[None, :]))).real
    errs = []
    for eps in (2e-3, 1e-3):
        y0, yd0 = eps * lin_y(np.zeros(1))[:, 0], eps * lin_yd(np.zeros(1))[:, 0]
        th0 = y0[:3]
        C0 = Rotation.from_rotvec(th0).as_matrix().T  # C_theta = exp(-tilde(theta))
        w0 = yd0[:3] + C0 @ W
        X = _simulate(model, f, C0, w0, y0[3:], yd0[3:], T, ts)
        th = np.empty((3, ts.size))
        for i, t in enumerate(ts):
            Cf = sla.expm(-jaxtree_tilde(W) * t)
            Cth = X[:9, i].reshape(3, 3) @ Cf.T
            th[:, i] = Rotation.from_matrix(Cth.T).as_rotvec()
        sim = np.vstack([th, X[12:14]])
        errs.append(np.abs(sim - eps * lin_y(ts)).max() / eps)
    print("error / eps:", errs)
    # The modal solution is right to first order: the error relative to eps is small and halving eps
    # at least halves it (the absolute error shrinks like eps^2; the bounds allow 20% for the eps^3 terms).
    assert errs[0] < 0.05
    if Om == 0.0:
        # At rest the motion of Fig. C-1 is planar (all hinge axes along b1, base rolling about b1); the
        # mass matrix is then even in the angles, the quadratic terms vanish and the error falls like eps^3.
        assert 3.2 < errs[0] / errs[1] < 4.8, errs
    else:
        assert 1.6 < errs[0] / errs[1] < 2.4, errs


def test_traced_general_modes_match_finite_differences():
    """kind='general' under jax.jacfwd (a damped, underdamped 3-dof chain): the derivatives of
    the eigenvalues, and of the basis-free quantity Phi diag(lambda) Phi'^T P (= B, Eqs. 85-90),
    w.r.t. a stiffness against central differences of the concrete (numpy) solve."""
    I = np.array([[3.0, 1.0, 0.2], [1.0, 2.0, 0.5], [0.2, 0.5, 1.5]])
    J = np.diag([0.05, 0.08, 0.02])

    def K(k):
        return jnp.array([[k + 2.0, -2.0, 0.0], [-2.0, 5.0, -3.0], [0.0, -3.0, 3.0]])

    def out(k, traced=True):
        md = jaxtree.modes(I, J, K(k), kind="general" if traced else None)
        rebuilt = (md.right * md.eigenvalues) @ md.left.T @ md.P
        return jnp.concatenate([md.eigenvalues, rebuilt.ravel()])

    k0, h = 4.0, 1e-5
    jac = jax.jacfwd(out)(k0)
    fd = (out(k0 + h, traced=False) - out(k0 - h, traced=False)) / (2 * h)
    np.testing.assert_allclose(np.asarray(jac), np.asarray(fd), rtol=1e-6, atol=1e-8)
