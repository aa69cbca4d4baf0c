"""Tests of the finite-element appendages (jaxtree._src.appendage): the beam generator, the
held-interface modes, the modal invariants, the appendage's share of Eq. (30) and its geometric
stiffness.

Every expected number comes from outside the appendage code:

- the Euler-Bernoulli cantilever's frequencies (beta_n L = 1.8751, 4.6941, 7.8548, roots of
  ``cos x cosh x = -1``, found here by scipy) and the fixed-free bar's axial ones;
- the cantilever's modal effective masses and Southwell's coefficients of a beam spinning about
  its clamped end, by quadrature of the analytic mode shape (the Rayleigh quotient of the
  centrifugal tension ``rho A Omega^2 (L^2 - x^2) / 2``: the exact slope of ``omega^2`` in
  ``Omega^2`` at zero spin);
- a uniform beam's mass, first moment and inertia (integrals of rho A);
- a chain of point masses on hinges (the rigid-body Gauss function of
  :mod:`jaxtree._src.hybrid.substructure`, itself checked against Eq. 1): the rigid part of an
  appendage's Gauss function must equal it;
- central differences for derivatives.
"""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq

import jaxtree
from jaxtree._src.appendage import appendage, beam, held_interface_modes
from jaxtree._src.appendage.model import _appendage_terms
from jaxtree._src.hybrid import substructure as sub
from jaxtree._src.hybrid.substructure import held_base

DATA = pathlib.Path(__file__).parent / "data"

# Kane, Ryan and Banerjee's beam (notes/fe_appendages.md): 10 m, EI = 14 000 N m^2, rho A = 1.2 kg/m
LENGTH, E, RHO, AREA = 10.0, 7e10, 3000.0, 4e-4
EI = 14000.0
IY = EI / E
RHO_A = RHO * AREA


def _beta_l(n: int) -> float:
    """The n-th root (1-based) of cos x cosh x = -1: the cantilever's beta L."""
    f = lambda x: np.cos(x) * np.cosh(x) + 1.0
    guess = (n - 0.5) * np.pi
    return brentq(f, guess - 1.0, guess + 1.0, xtol=1e-14)


def _mode(bl: float):
    """The cantilever's analytic mode shape phi(x) on [0, 1] (x / L) and its slope."""
    s = (np.cosh(bl) + np.cos(bl)) / (np.sinh(bl) + np.sin(bl))
    phi = lambda x: np.cosh(bl * x) - np.cos(bl * x) - s * (np.sinh(bl * x) - np.sin(bl * x))
    dphi = lambda x: bl * (np.sinh(bl * x) + np.sin(bl * x) - s * (np.cosh(bl * x) - np.cos(bl * x)))
    return phi, dphi


@pytest.fixture(scope="module")
def kane_beam():
    """The beam in 40 elements, its sections unequal (Iz = 2 Iy) so that the two bending planes'
    frequencies are distinct."""
    return beam(LENGTH, 40, E=E, rho=RHO, area=AREA, Iy=IY, Iz=2 * IY)


def test_cantilever_frequencies_match_the_analytic_ones(kane_beam):
    w2, Phi = held_interface_modes(kane_beam, (0,))
    w = np.sqrt(np.asarray(w2))
    bending = []
    for EIp in (EI, 2 * EI):
        bending.append([_beta_l(n) ** 2 * np.sqrt(EIp / RHO_A) / LENGTH**2 for n in (1, 2, 3)])
    axial = np.pi / 2 * np.sqrt(E / RHO) / LENGTH
    for expected in [*np.ravel(bending), axial]:
        nearest = w[np.argmin(np.abs(w - expected))]
        assert abs(nearest - expected) <= 1e-4 * expected, (nearest, expected)
    # the modes are mass-normalized and zero at the clamp
    M = np.asarray(kane_beam.mass)
    P = np.asarray(Phi)
    np.testing.assert_allclose(P.T @ M @ P, np.eye(P.shape[1]), atol=1e-9)
    assert np.all(P[:6] == 0.0)


def test_rigid_invariants_and_effective_masses(kane_beam):
    ap = appendage(kane_beam, "hub", n_modes=12, geometric=False)
    m = RHO_A * LENGTH
    np.testing.assert_allclose(float(ap.mass), m, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(ap.first_moment), [m * LENGTH / 2, 0, 0], rtol=1e-12, atol=1e-9)
    bend = m * LENGTH**2 / 3  # integral of rho A x^2 (no rotary inertia in the Euler-Bernoulli element)
    np.testing.assert_allclose(np.asarray(ap.inertia)[1:, 1:], np.diag([bend, bend]), rtol=1e-12, atol=1e-9)
    # the first three bending modes in the x-y plane (translation y, index 4 of the six motions)
    eff = np.asarray(ap.effective_mass)[:, 4] / m
    plane = eff[eff > 1e-12][:3]
    for n, got in zip((1, 2, 3), plane):
        phi, _ = _mode(_beta_l(n))
        integral = quad(phi, 0, 1, epsabs=1e-13)[0]
        norm = quad(lambda x: phi(x) ** 2, 0, 1, epsabs=1e-13)[0]
        assert abs(got - integral**2 / norm) <= 1e-4 * got, (n, got, integral**2 / norm)


def test_auto_modes_follow_the_quasi_static_rule(kane_beam):
    loose = appendage(kane_beam, "hub", n_modes="auto", tol=1e-1, geometric=False)
    tight = appendage(kane_beam, "hub", n_modes="auto", tol=1e-3, geometric=False)
    assert 1 <= loose.n_modes < tight.n_modes
    np.testing.assert_allclose(np.asarray(tight.frequencies)[: loose.n_modes], np.asarray(loose.frequencies))


def _southwell(n: int = 1) -> float:
    """d omega^2 / d Omega^2 at zero spin of the n-th cantilever mode bending out of the plane of
    rotation: the Rayleigh quotient of the centrifugal tension (beam on the axis)."""
    phi, dphi = _mode(_beta_l(n))
    num = quad(lambda x: 0.5 * (1 - x * x) * dphi(x) ** 2, 0, 1, epsabs=1e-13)[0]
    den = quad(lambda x: phi(x) ** 2, 0, 1, epsabs=1e-13)[0]
    return num / den


def _spin_frequencies(ap, Om):
    """The held-base system of the appendage on a hub spinning at `Om` about z (held_base of the
    hybrid model, which hybrid_model takes the modes from): its frequencies and largest growth rate."""
    v = np.array([0.0, 0.0, Om, 0.0, 0.0, 0.0])
    I, J, K = held_base(ap.terms, v, np.zeros(6), np.asarray(ap.stiffness), np.zeros(ap.n_modes), xp=np)
    k = I.shape[0]
    A = np.block([[np.zeros((k, k)), np.eye(k)], [-np.linalg.solve(I, K), -np.linalg.solve(I, J)]])
    lam = np.linalg.eigvals(A)
    return np.sort(np.abs(lam.imag[lam.imag > 1e-9])), float(np.max(lam.real))


@pytest.fixture(scope="module")
def spin_beam():
    return beam(LENGTH, 40, E=E, rho=RHO, area=AREA, Iy=IY)


def test_geometric_stiffness_gives_southwells_coefficients(spin_beam):
    """Spun about z at its clamp, the beam (along x) stiffens out of the plane by Southwell's K1
    and in the plane by K1 - 1 (the centrifugal softening of the rotating frame); without the
    geometric stiffness the in-plane mode softens by Omega^2 and, above the first frequency, the
    held-base system is unstable."""
    K1 = _southwell(1)
    assert 1.19 < K1 < 1.20  # the textbook 1.193
    ap = appendage(spin_beam, "hub", n_modes=12)
    w1 = float(ap.frequencies[0])
    Om = 0.05
    w, growth = _spin_frequencies(ap, Om)
    slopes = (w[:2] ** 2 - w1**2) / Om**2
    np.testing.assert_allclose(slopes, [K1 - 1.0, K1], rtol=2e-3)
    assert growth < 1e-9
    w, growth = _spin_frequencies(ap, 6.0)
    assert growth < 1e-9 and w[0] > w1  # above the first frequency, stable and stiffer
    plain = appendage(spin_beam, "hub", n_modes=12, geometric=False)
    w, _ = _spin_frequencies(plain, Om)
    np.testing.assert_allclose((w[:2] ** 2 - w1**2) / Om**2, [-1.0, 0.0], atol=2e-3)
    _, growth = _spin_frequencies(plain, 6.0)
    assert growth > 1.0  # the premature linearization diverges


def test_rigid_gauss_function_equals_the_hinged_point_masses():
    """Two point masses on a chain of two hinges against the same masses as a three-dof-per-node
    structure whose two 'modes' are the hinges' small rotations: the Gauss functions agree in every
    coefficient that does not involve the hinges' second-order kinematics (which a linear structure
    lacks and its geometric stiffness replaces): A0, G0, G2, and the base rows of A1 and G1."""
    rng = np.random.default_rng(3)
    hop = [rng.normal(size=3), rng.normal(size=3)]
    hob = [rng.normal(size=3), rng.normal(size=3)]
    axes = [v / np.linalg.norm(v) for v in rng.normal(size=(2, 3))]
    masses = [1.7, 2.9]
    bodies = [jaxtree.Body("base", 50.0, np.diag([3.0, 4.0, 5.0]))]
    for k in range(2):
        bodies.append(
            jaxtree.Body(f"m{k + 1}", masses[k], np.zeros((3, 3)), k, axes[k], hop[k], hob[k], jaxtree.Free())
        )
    model = jaxtree.build_model(bodies)
    grp = sub.substructures(model, (1, 2))[0]
    want = sub.terms(model, grp, np.zeros(2))
    # the same masses as nodes (from the base's mass center) and the hinges as modes
    h1 = hop[0]
    x1 = h1 - hob[0]
    h2 = x1 + hop[1]
    x2 = h2 - hob[1]
    X = np.stack([x1, x2])
    Phi = np.zeros((6, 2))
    Phi[0:3, 0] = np.cross(axes[0], x1 - h1)
    Phi[3:6, 0] = np.cross(axes[0], x2 - h1)
    Phi[3:6, 1] = np.cross(axes[1], x2 - h2)
    M = np.diag(np.repeat(masses, 3))
    R0 = np.concatenate([np.stack([-np.cross(np.eye(3), x).T for x in X])[:, :, :], np.tile(np.eye(3), (2, 1, 1))], -1)
    got = _appendage_terms(
        jnp.asarray(X),
        jnp.asarray(Phi),
        jnp.asarray(M),
        jnp.zeros((0, 6)),
        jnp.zeros((0, 2, 2)),
        jnp.asarray(R0.reshape(6, 6)),
        3,
        False,
        jnp.asarray(sum(masses)),
    )
    scale = max(float(np.max(np.abs(np.asarray(want.A0)))), 1.0)
    for name, sl in (("A0", ...), ("G0", ...), ("G2", ...), ("A1", np.s_[:6, :6]), ("G1", np.s_[:6])):
        a, b = np.asarray(getattr(got, name))[sl], np.asarray(getattr(want, name))[sl]
        np.testing.assert_allclose(a, b, atol=1e-12 * scale, err_msg=name)


def test_frequency_derivative_in_the_section_and_material():
    """d omega_1 / d(E, rho, Iy) through the generator and the eigensolver. The first mode bends
    in the x-z plane alone, so its frequency is ``c sqrt(E Iy / (rho A))`` at any mesh: d omega / d E
    = omega / (2 E), d omega / d Iy = omega / (2 Iy), d omega / d rho = -omega / (2 rho), exactly
    (the second bending plane and the torsion, which Iy also moves, must not leak in)."""

    def first(E_, rho_, Iy_):
        fe = beam(LENGTH, 12, E=E_, rho=rho_, area=AREA, Iy=Iy_, Iz=2 * Iy_)
        w2, _ = held_interface_modes(fe, (0,))
        return jnp.sqrt(w2[0])

    args = (jnp.asarray(E), jnp.asarray(RHO), jnp.asarray(IY))
    w = float(first(*args))
    dE, drho, dI = jax.grad(first, argnums=(0, 1, 2))(*args)
    np.testing.assert_allclose(float(dE), w / (2 * E), rtol=1e-8)
    np.testing.assert_allclose(float(drho), -w / (2 * RHO), rtol=1e-8)
    np.testing.assert_allclose(float(dI), w / (2 * IY), rtol=1e-8)


def test_invariants_survive_a_file_and_matrices_a_round_trip(kane_beam, tmp_path):
    """The appendage computed from the matrices equals the one written as precomputed invariants
    and read back, bit for bit; the structure written dense, as triangular coordinate entries and
    as MatrixMarket files gives the same held-interface modes."""
    import scipy.io
    import scipy.sparse

    from jaxtree._src.appendage import load_appendage, load_fe, read_matrix_market, save_appendage, save_fe

    ap = appendage(kane_beam, "hub", n_modes=4, outputs=(40,), damping=0.01)
    save_appendage(tmp_path / "wing.npz", ap)
    back = load_appendage(tmp_path / "wing.npz")
    for a, b in zip(jax.tree_util.tree_leaves(ap), jax.tree_util.tree_leaves(back)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert (back.body, back.interface, back.outputs, back.dofs) == ("hub", (0,), (40,), 6)

    save_fe(tmp_path / "beam.npz", kane_beam)
    dense = load_fe(tmp_path / "beam.npz")
    M, K = np.asarray(kane_beam.mass), np.asarray(kane_beam.stiffness)
    r, c = np.nonzero(np.triu(K))
    rm, cm = np.nonzero(np.triu(M))
    np.savez(
        tmp_path / "coo.npz", format="jaxtree-fe/1", nodes=np.asarray(kane_beam.nodes), dofs=6, triangle="upper",
        size=K.shape[0], stiffness_rows=r, stiffness_cols=c, stiffness_values=K[r, c],
        mass_rows=rm, mass_cols=cm, mass_values=M[rm, cm],
    )  # fmt: skip
    coo = load_fe(tmp_path / "coo.npz")
    scipy.io.mmwrite(str(tmp_path / "m.mtx"), scipy.sparse.coo_matrix(M), symmetry="symmetric")
    scipy.io.mmwrite(str(tmp_path / "k.mtx"), scipy.sparse.coo_matrix(K), symmetry="symmetric")
    mtx = read_matrix_market(tmp_path / "m.mtx", tmp_path / "k.mtx", np.asarray(kane_beam.nodes))
    want = np.asarray(held_interface_modes(kane_beam, (0,))[0])[:6]
    for fe in (dense, coo, mtx):
        np.testing.assert_allclose(np.asarray(held_interface_modes(fe, (0,))[0])[:6], want, rtol=1e-12)


def test_bad_files_and_arguments_are_named(kane_beam, tmp_path):
    from jaxtree._src.appendage import load_fe

    M, K = np.asarray(kane_beam.mass), np.asarray(kane_beam.stiffness).copy()
    K[0, 7] += 1.0  # not symmetric
    np.savez(tmp_path / "bad.npz", format="jaxtree-fe/1", nodes=np.asarray(kane_beam.nodes), mass=M, stiffness=K)
    with pytest.raises(jaxtree.SceneError, match="stiffness is not symmetric"):
        load_fe(tmp_path / "bad.npz")
    np.savez(tmp_path / "other.npz", format="something", nodes=np.zeros((2, 3)))
    with pytest.raises(jaxtree.SceneError, match="format 'something'"):
        load_fe(tmp_path / "other.npz")
    with pytest.raises(jaxtree.SceneError, match="interface node 99"):
        appendage(kane_beam, "hub", interface=(99,))
    with pytest.raises(jaxtree.SceneError, match="beam: area must be a positive number"):
        beam(1.0, 4, E=1.0, rho=1.0, area=-1.0, Iy=1.0)
    with pytest.raises(jaxtree.SceneError, match="FEModel.mass: shape"):
        jaxtree._src.appendage.FEModel(jnp.zeros((5, 5)), jnp.zeros((12, 12)), jnp.zeros((2, 3)))


# --------------------------------------------------------------------------------------------
# In the hybrid model: against the same beam as a chain of rigid segments in the full Eq. (1)
#
# The chain: N equal segments (mass rho A l, a rod's inertia) on hinges about z with springs of
# EI over the distance between the centers they join (l between segments, l / 2 at the clamp),
# which converges at second order in 1/N (first frequency 0.46 / 0.11 / 0.03 % low at N = 10 / 20
# / 40, where EI / l at the clamp converges at first order: 9 / 4.8 / 2.4 %); two chains are
# extrapolated, y = (4 y(2N) - y(N)) / 3. Large rotations of rigid segments carry the centrifugal
# stiffening exactly, which makes the chain the reference (notes/fe_appendages.md).

CHAIN_N = (8, 16)
HUB_POINT = 1.0  # the slew's clamp, 1 m from the hub's mass center
HUB_INERTIA = 300.0


def _chain(N, base_bodies, parent0, root_point):
    l = LENGTH / N
    m = RHO_A * l
    bodies = list(base_bodies)
    for k in range(N):
        J = np.diag([1e-6 * m * l * l, m * l * l / 12, m * l * l / 12])
        on_parent = root_point if k == 0 else (l / 2, 0.0, 0.0)
        spring = jaxtree.SpringDamper((2.0 if k == 0 else 1.0) * EI / l, 0.0)
        parent = parent0 if k == 0 else len(bodies) - 1
        bodies.append(jaxtree.Body(f"s{k + 1}", m, J, parent, (0, 0, 1), on_parent, (-l / 2, 0, 0), spring))
    return jaxtree.build_model(bodies)


def _chain_tip(model, N, t1, ts, first):
    """The extrapolated chain's tip deflection across the beam (the hub's y), from the angles of
    the segment hinges (from index `first` of gamma)."""
    sol = jaxtree.simulate(model, t1, saveat=ts, solver=jaxtree.Radau5(), rtol=1e-9, atol=1e-9)
    g = np.asarray(sol.gamma)[:, first:]
    return np.sum(LENGTH / N * np.sin(np.cumsum(g, 1)), 1)


def _extrapolated(tips):
    return (4.0 * tips[1] - tips[0]) / 3.0


def _fe_tip(hm, ts, t1, **kw):
    sol = jaxtree.simulate_hybrid(hm, t1, saveat=ts, rtol=1e-9, atol=1e-9, truncation_error=False, **kw)
    return np.asarray(jax.vmap(lambda y: hm.appendage_displacement(y))(sol.ys))[:, 1], sol


def _wide_beam(n=20):
    # bending in the plane of the motion (local y) with EI, out of it 4 EI: distinct frequencies
    return beam(LENGTH, n, E=E, rho=RHO, area=AREA, Iy=4 * IY, Iz=IY)


def test_slew_follows_the_rigid_chain_in_full_equations():
    """A hub (300 kg m^2) slewed by a torque sin(2 pi t / 10) over 10 s, the beam clamped 1 m from
    its center: the tip deflection of the hybrid model with 3 retained modes of the finite-element
    beam within 1 % of its peak of the chain's (measured 0.2 %; the chains of 8 and 16 segments differ by 3.5 %); without the geometric stiffness
    of the spin's preload the error is several times larger (measured 8.0 %)."""
    T0, t1 = 200.0, 15.0
    profile = lambda t: jnp.where(t < 10.0, jnp.sin(2 * jnp.pi * t / 10.0), 0.0)
    torque = jaxtree.BodyTorque(0, [0.0, 0.0, T0], profile)
    hub = jaxtree.Body("hub", 100.0, np.diag([HUB_INERTIA] * 3))
    ts = np.linspace(0.0, t1, 61)
    tips = [_chain_tip(_chain(N, [hub], 0, (HUB_POINT, 0.0, 0.0)).with_loads(torque), N, t1, ts, 0) for N in CHAIN_N]
    ref = _extrapolated(tips)
    peak = np.max(np.abs(ref))
    assert peak > 0.1  # 0.22 m: the beam bends
    vehicle = jaxtree.build_model([hub]).with_loads(torque)
    errors = {}
    for geometric in (True, False):
        ap = appendage(_wide_beam(), "hub", point=(HUB_POINT, 0, 0), n_modes=12, outputs=(20,), geometric=geometric)
        hm = jaxtree.hybrid_model(vehicle, (), 3, appendages=[ap])
        tip, _ = _fe_tip(hm, ts, t1)
        errors[geometric] = np.max(np.abs(tip - ref)) / peak
    assert errors[True] <= 1e-2, errors
    assert errors[False] > 3 * errors[True], errors


def _spin_up(Ws, Ts=15.0):
    """Kane, Ryan and Banerjee's hub angle: rate (Ws / Ts)(t - (Ts / 2 pi) sin(2 pi t / Ts)) to Ts,
    then Ws."""
    c = (Ts / (2 * np.pi)) ** 2

    def angle(t):
        ramp = Ws / Ts * (t * t / 2 + c * (jnp.cos(2 * jnp.pi * t / Ts) - 1.0))
        return jnp.where(t < Ts, ramp, Ws * Ts / 2 + Ws * (t - Ts))

    return angle


def _spinning_bodies(angle):
    big = 1e9  # an inertial frame: the hub turns on it at the prescribed angle
    return [
        jaxtree.Body("ground", big, np.diag([big] * 3)),
        jaxtree.Body("hub", 1.0, np.eye(3), 0, (0, 0, 1), (0, 0, 0), (0, 0, 0), jaxtree.Prescribed(angle)),
    ]


def test_spin_up_above_the_first_frequency_needs_the_geometric_stiffness():
    """Kane, Ryan and Banerjee's spin-up to 6 rad/s (above the beam's first frequency, 3.80 rad/s),
    the beam clamped on the hub's axis: with the geometric stiffness the hybrid model (3 modes)
    stays bounded and follows the chain to 2 % of its peak over 20 s (measured 0.5 %); without it
    the held-base stiffness turns negative and the run diverges. At 1 rad/s the two models agree
    (to the Omega^2 / omega_1^2 = 7 % of the stiffness that the premature linearization misses)."""
    t1 = 20.0
    ts = np.linspace(0.0, t1, 81)
    angle = _spin_up(6.0)
    tips = [_chain_tip(_chain(N, _spinning_bodies(angle), 1, (0.0, 0.0, 0.0)), N, t1, ts, 1) for N in CHAIN_N]
    ref = _extrapolated(tips)
    peak = np.max(np.abs(ref))
    assert peak > 0.3
    vehicle = jaxtree.build_model(_spinning_bodies(angle))
    beam_ = _wide_beam()
    ap = appendage(beam_, "hub", n_modes=12, outputs=(20,))
    tip, _ = _fe_tip(jaxtree.hybrid_model(vehicle, (), 3, appendages=[ap]), ts, t1)
    assert np.max(np.abs(tip - ref)) <= 2e-2 * peak, np.max(np.abs(tip - ref)) / peak
    plain = appendage(beam_, "hub", n_modes=12, outputs=(20,), geometric=False)
    hm = jaxtree.hybrid_model(vehicle, (), 3, appendages=[plain])
    sol = jaxtree.simulate_hybrid(hm, t1, saveat=ts, rtol=1e-9, atol=1e-9, truncation_error=False, throw=False)
    bad = not np.all(np.isfinite(np.asarray(sol.ys))) or float(sol.t_final) < t1
    grown = np.nanmax(np.abs(np.asarray(jax.vmap(lambda y: hm.appendage_displacement(y))(sol.ys))[:, 1]))
    assert bad or grown > 10 * peak, (float(sol.t_final), grown)
    # 1 rad/s: both bounded, and they differ by the missed stiffness only
    slow = jaxtree.build_model(_spinning_bodies(_spin_up(1.0)))
    with_g, _ = _fe_tip(jaxtree.hybrid_model(slow, (), 3, appendages=[ap]), ts, t1)
    without, _ = _fe_tip(jaxtree.hybrid_model(slow, (), 3, appendages=[plain]), ts, t1)
    scale = np.max(np.abs(with_g))
    assert 0.05 < scale < 0.2
    assert np.max(np.abs(without - with_g)) <= 0.1 * scale


def test_slew_gradient_through_the_structure():
    """d/d(E, rho) of a slew's tip-deflection loss through the beam's matrices, its held-interface
    modes, the invariants, the hybrid model (built under the trace with `like`) and the simulation
    (reverse mode), against central differences (h = 1e-4) to 1e-5 relative."""
    profile = lambda t: jnp.where(t < 10.0, jnp.sin(2 * jnp.pi * t / 10.0), 0.0)
    hub = jaxtree.Body("hub", 100.0, np.diag([HUB_INERTIA] * 3))
    vehicle = jaxtree.build_model([hub]).with_loads(jaxtree.BodyTorque(0, [0.0, 0.0, 200.0], profile))
    t1 = 6.0
    ts = jnp.linspace(0.0, t1, 13)

    def build(e, r):
        fe = beam(LENGTH, 10, E=E * e, rho=RHO * r, area=AREA, Iy=4 * IY, Iz=IY)
        return appendage(fe, "hub", point=(HUB_POINT, 0, 0), n_modes=8, outputs=(10,))

    ref = jaxtree.hybrid_model(vehicle, (), 3, appendages=[build(1.0, 1.0)])

    @jax.jit
    def loss(p):
        hm = jaxtree.hybrid_model(vehicle, (), 3, appendages=[build(p[0], p[1])], like=ref)
        sol = jaxtree.simulate_hybrid(hm, t1, saveat=ts, rtol=1e-12, atol=1e-12, truncation_error=False)
        return jnp.sum(jax.vmap(lambda y: hm.appendage_displacement(y))(sol.ys)[:, 1] ** 2)

    p = jnp.array([1.0, 1.0])
    g = np.asarray(jax.jit(jax.grad(loss))(p))
    h = 1e-4
    fd = np.array([(float(loss(p.at[i].add(h))) - float(loss(p.at[i].add(-h)))) / (2 * h) for i in range(2)])
    assert np.all(np.abs(fd) > 1e-2)  # both parameters move the tip
    np.testing.assert_allclose(g, fd, rtol=1e-5)


def test_scene_appendages_by_file_and_by_beam(tmp_path, kane_beam):
    """A scene's ``appendages`` (a structure file, a precomputed-modes file, the beam generator)
    give the appendages the Python calls give, bit for bit; the scene is written back and read
    again; the full Eq. (1) warns that it leaves them out, and hybrid_model asks for them."""
    import json

    from jaxtree._src.appendage import save_appendage, save_fe

    save_fe(tmp_path / "boom.npz", kane_beam)
    direct = appendage(kane_beam, "hub", point=(1.0, 0, 0), n_modes=4, outputs=(40,))
    save_appendage(tmp_path / "boom_modes.npz", direct)
    spec = dict(length=LENGTH, elements=10, E=E, rho=RHO, area=AREA, Iy=IY, up=[0, 1, 0])
    scene = {
        "format": "jaxtree-scene/1",
        "name": "hub_and_booms",
        "bodies": [{"name": "hub", "mass": 100.0, "inertia": np.diag([300.0] * 3).tolist()}],
        "appendages": [
            {"name": "a", "body": "hub", "file": "boom.npz", "point": [1, 0, 0], "modes": 4, "outputs": [40]},
            {"name": "b", "body": "hub", "file": "boom_modes.npz"},
            {"name": "c", "body": 0, "beam": spec, "frame": [[-1, 0, 0], [0, -1, 0], [0, 0, 1]], "modes": "auto"},
        ],
    }
    (tmp_path / "s.json").write_text(json.dumps(scene))
    model = jaxtree.load_scene(tmp_path / "s.json")
    a, b, c = jaxtree.scene_appendages(model)
    for got in (a, b):
        for x, y in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(direct)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    spec_args = {k: v for k, v in spec.items() if k not in ("length", "elements")}
    want = appendage(beam(LENGTH, 10, **spec_args), 0, frame=np.diag([-1.0, -1.0, 1.0]), n_modes="auto", name="c")
    np.testing.assert_array_equal(np.asarray(c.terms.A0), np.asarray(want.terms.A0))
    assert (a.name, b.name, c.name) == ("a", "b", "c")
    report = str(jaxtree.check_scene(model))  # a hub alone: no hinge tables; the appendages listed
    assert "Tables 1-2: none" in report and "a: on 'hub' at [1.0, 0.0, 0.0]" in report
    jaxtree.save_scene(model, tmp_path / "again.json")
    again = jaxtree.load_scene(tmp_path / "again.json")
    assert again.appendages == model.appendages
    with pytest.raises(jaxtree.SceneError, match="appendages=jaxtree.scene_appendages"):
        jaxtree.hybrid_model(model, ())
    hm = jaxtree.hybrid_model(model, (), 2, appendages=jaxtree.scene_appendages(model))
    assert hm.modes_per_substructure == (2, 2, 2)
    with pytest.warns(jaxtree.SceneWarning, match="left out"):
        jaxtree.simulate(model, 0.1, saveat=2)


@pytest.mark.parametrize(
    "entry, message",
    [
        ({"body": "hub"}, "exactly one of 'file'"),
        ({"body": "nose", "beam": {}}, "names no body"),
        ({"body": "hub", "beam": {"length": 1.0}}, "needs elements, E, rho, area, Iy"),
        ({"body": "hub", "file": "missing.npz"}, "no such file"),
        ({"body": "hub", "beam": {"length": 1.0}, "colour": 1}, "colour"),
        ({"body": "hub", "file": "modes.npz", "point": [0, 0, 1]}, "precomputed modes"),
        (
            {"body": "hub", "beam": dict(length=1.0, elements=2, E=1.0, rho=1.0, area=1.0, Iy=1.0), "modes": 0},
            "'modes'",
        ),
        ({"body": "hub", "beam": dict(length=-1.0, elements=2, E=1.0, rho=1.0, area=1.0, Iy=1.0)}, "beam.length"),
    ],
)
def test_scene_appendage_errors_name_the_field(tmp_path, kane_beam, entry, message):
    from jaxtree._src.appendage import save_appendage

    if entry.get("file") == "modes.npz":
        save_appendage(tmp_path / "modes.npz", appendage(kane_beam, "hub", n_modes=2))
    scene = {
        "format": "jaxtree-scene/1",
        "bodies": [{"name": "hub", "mass": 100.0, "inertia": np.eye(3).tolist()}],
        "appendages": [entry],
    }
    with pytest.raises(jaxtree.SceneError, match=message):
        jaxtree._src.scene.files.scene_from_dict(scene, tmp_path)


def test_command_line_runs_a_scene_with_an_appendage(tmp_path, capsys):
    """``jaxtree simulate SCENE --hybrid-small none``: the scene's beam appendage alone in modal
    coordinates, on a spinning hub under a torque, run in two parts; the result file holds its output node's displacement, equal to
    simulate_hybrid's of the same hybrid model."""
    import json

    from jaxtree._src import cli

    scene = {
        "format": "jaxtree-scene/1",
        "name": "hub_boom",
        "bodies": [{"name": "hub", "mass": 100.0, "inertia": np.diag([HUB_INERTIA] * 3).tolist()}],
        "initial": {"omega0": [0.0, 0.0, 0.2]},
        "loads": [{"kind": "torque", "body": "hub", "vector": [0.0, 0.0, 50.0]}],
        "appendages": [
            {
                "name": "boom",
                "body": "hub",
                "point": [1.0, 0.0, 0.0],
                "beam": dict(length=LENGTH, elements=10, E=E, rho=RHO, area=AREA, Iy=4 * IY, Iz=IY),
                "modes": 6,
                "outputs": [10],
            }
        ],
    }
    path = tmp_path / "hub_boom.json"
    path.write_text(json.dumps(scene))
    out = tmp_path / "r.nc"
    args = ["simulate", str(path), "--t1", "1.0", "--points", "11", "--chunks", "2", "--hybrid-small", "none"]
    args += ["--modes", "2", "--rtol", "1e-10", "--atol", "1e-10"]
    args += ["--out", str(out), "--no-plot", "--no-error-estimate", "--no-progress"]
    assert cli.main(args) == 0, capsys.readouterr().err
    ds = jaxtree.load_result(out, as_dataset=True)
    assert list(ds["appendage_displacement"].coords["appendage_output"].values) == ["boom:10"]
    model = jaxtree.load_scene(path)
    # the command line's modes are those about the scene's initial spin (its --spin default)
    hm = jaxtree.hybrid_model(model, (), 2, omega0=model.initial.omega0, appendages=jaxtree.scene_appendages(model))
    sol = jaxtree.simulate_hybrid(hm, 1.0, saveat=11, rtol=1e-10, atol=1e-10, truncation_error=False)
    want = np.asarray(jax.vmap(lambda y: hm.appendage_displacement(y))(sol.ys))
    got = ds["appendage_displacement"].values[:, 0]
    assert np.abs(want[:, 1]).max() > 1e-3  # the hub's torque bends the boom
    np.testing.assert_allclose(got, want, atol=1e-8)  # two runs at 1e-10 (in two parts, and in one)
    # `jaxtree modes`: the boom's held-interface coordinates on the hub spinning at 0.2 rad/s (held)
    # `jaxtree animate`: the output node drawn on the hub at 10 times its displacement
    page = tmp_path / "a.html"
    assert cli.main(["animate", str(out), "-o", str(page), "--scale", "10"]) == 0
    data = _page_data(page.read_text())
    (drawn,) = data["appendages"]
    assert drawn["name"] == "boom:10" and drawn["body"] == 0 and drawn["n"] == 1 and drawn["edges"] == []
    points = _f32(drawn["points"]).reshape(len(data["times"]), 1, 3)
    tip = np.array([1.0 + LENGTH, 0.0, 0.0])  # node 10 of the 10 m beam clamped 1 m out
    np.testing.assert_allclose(points[:, 0], tip + 10 * want[:, :3], atol=1e-5 * LENGTH)  # float32 on the page
    assert data["radius"] > 0.5 * LENGTH  # the view holds the boom
    capsys.readouterr()
    mout = tmp_path / "m.nc"
    assert cli.main(["modes", str(path), "--small", "none", "--spin", "0.2", "--out", str(mout), "--no-plot"]) == 0
    printed = capsys.readouterr().out
    assert "appendages' held-interface modal coordinates: boom (6)" in printed, printed
    md = jaxtree.load_result(mout, as_dataset=True)
    assert list(md["coordinate_hinge"].values) == [-1] * 6
    lin = jaxtree.linearize(model, (), omega0=jnp.asarray([0.0, 0.0, 0.2]), appendages=jaxtree.scene_appendages(model))
    np.testing.assert_allclose(md["frequency"].values, np.asarray(jaxtree.modes(lin).frequencies), rtol=1e-12)


# --------------------------------------------------------------------------------------------
# Plates


def test_plate_strip_bends_as_the_beam():
    """A narrow cantilever strip (nu = 0: no anticlastic coupling) of the plate elements has the
    Euler-Bernoulli beam's frequencies E t^2 / 12 rho (beta L)^4 / L^4: the first to 1e-4, the next
    two to 0.5 % at 40 x 2 elements (bilinear elements converge at second order; 20 x 2: 2e-4,
    0.6 %, 1.7 %)."""
    from jaxtree import plate, plate_edge

    Ep, rho, t, L = 7e10, 2700.0, 0.01, 1.0
    fe = plate(L, 0.1, 40, 2, E=Ep, rho=rho, thickness=t, nu=0.0)
    w = np.sqrt(np.asarray(held_interface_modes(fe, plate_edge(40, 2))[0]))
    want = [_beta_l(n) ** 2 * np.sqrt(Ep * t**2 / (12 * rho)) / L**2 for n in (1, 2, 3)]
    bending = [w[np.argmin(np.abs(w - x))] for x in want]
    np.testing.assert_allclose(bending[0], want[0], rtol=1e-4)
    np.testing.assert_allclose(bending[1:], want[1:], rtol=5e-3)


def test_square_cantilever_plate_against_leissa():
    """A square plate clamped along one edge (nu = 0.3): the frequency parameters omega a^2
    sqrt(rho t / D) of its first five modes within 1 % of Leissa's (1973) Ritz values 3.492,
    8.525, 21.43, 27.33, 31.11 at 16 x 16 elements (measured 0.6 % at most; a Ritz solution of 36
    terms is an upper bound, and the finite-element values converge slightly below it)."""
    from jaxtree import plate, plate_edge

    Ep, nu, rho, t, a = 7e10, 0.3, 2700.0, 0.01, 1.0
    D = Ep * t**3 / (12 * (1 - nu**2))
    fe = plate(a, a, 16, 16, E=Ep, rho=rho, thickness=t, nu=nu)
    lam = np.sqrt(np.asarray(held_interface_modes(fe, plate_edge(16, 16))[0][:5])) * a * a * np.sqrt(rho * t / D)
    np.testing.assert_allclose(lam, [3.492, 8.525, 21.43, 27.33, 31.11], rtol=1e-2)


def test_plate_geometric_stiffness_gives_southwells_coefficient(tmp_path):
    """The strip (in the x-y plane, clamped at x = 0) spun about z: its bending along its normal,
    out of the plane of rotation, stiffens by Southwell's K1 through the plate elements' geometric
    stiffness of the centrifugal in-plane tension, as the beam's does (20 x 2 elements: within
    1e-3); the strip written as a jaxtree-fe/1 file and read back gives
    the same appendage."""
    from jaxtree import plate, plate_edge
    from jaxtree._src.appendage import load_fe, save_fe

    fe = plate(1.0, 0.1, 20, 2, E=7e10, rho=2700.0, thickness=0.01, nu=0.0)
    ap = appendage(fe, "hub", interface=plate_edge(20, 2), n_modes=6)
    w1 = float(ap.frequencies[0])
    w, growth = _spin_frequencies(ap, 0.5)
    assert growth < 1e-9
    np.testing.assert_allclose((w[0] ** 2 - w1**2) / 0.25, _southwell(1), rtol=1e-3)
    save_fe(tmp_path / "strip.npz", fe)
    back = appendage(load_fe(tmp_path / "strip.npz"), "hub", interface=plate_edge(20, 2), n_modes=6)
    np.testing.assert_allclose(np.asarray(back.terms.A1), np.asarray(ap.terms.A1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(back.terms.G1), np.asarray(ap.terms.G1), rtol=0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# The vehicle's energy and angular momentum, appendages included


def test_the_vehicles_energy_and_momentum_include_the_appendage():
    """simulate_hybrid's energy and angular momentum are the vehicle's, its finite-element appendage
    included. With the modes at rest (q = q' = 0) they equal those of the tree with the appendage
    as one rigid body of its mass, first moment and inertia, evaluated by Eq. (1)'s own energy
    and momentum. After a torque pulse the free vehicle (an undamped sprung panel and undamped
    modes, spinning about three axes) keeps both up to the hybrid model's error, which is of
    second order in the modal amplitude: a beam 100 times stiffer (amplitudes ~100 times smaller)
    keeps them to 1e-7 (measured 2.6e-9 and 2.4e-9 with the beam's inertia at its sample points; with
    the nodes' own velocity products in the base rows, which missed the rotational entries' share of
    the gyroscopic moment, the momentum turned by 2e-4 at any stiffness), the flexible beam to 2e-5
    (measured 4.7e-6 and 6.8e-6), while the
    tree's own kinetic energy trades tens of percent with the panel and the beam."""
    from jaxtree._src.hybrid.solution import _energy_and_momentum

    hub = jaxtree.Body("hub", 100.0, np.diag([300.0, 250.0, 200.0]))
    panel = jaxtree.Body(
        "panel",
        20.0,
        np.diag([5.0, 3.0, 4.0]),
        0,
        (0, 1, 0),
        (0, -1.0, 0.2),
        (0, 1.0, 0),
        jaxtree.SpringDamper(50.0, 0.0),
    )
    point = np.array([1.0, 0.2, 0.0])
    start = {"omega0": [0.05, -0.03, 0.1], "gamma": [0.3], "gamma_dot": [0.02]}
    vehicle = jaxtree.build_model([hub, panel], start)
    pulse = lambda t: jnp.where(t < 2.0, jnp.sin(jnp.pi * t / 2.0) ** 2, 0.0)
    pushed = vehicle.with_loads(jaxtree.BodyTorque(0, [0.0, 20.0, 60.0], pulse))
    ts = np.concatenate([[0.0], np.linspace(2.0, 20.0, 91)])  # free from t = 2 s on
    runs = {}
    for stiffer in (1.0, 100.0):
        ap = appendage(
            beam(LENGTH, 10, E=stiffer * E, rho=RHO, area=AREA, Iy=4 * IY, Iz=IY), "hub", point=tuple(point), n_modes=4
        )
        if stiffer == 1.0:
            # the modes at rest: the appendage is a rigid body on the hub (a hinge at its mass center)
            hm = jaxtree.hybrid_model(vehicle, (), 4, appendages=[ap])
            m = float(ap.mass)
            c = np.asarray(ap.first_moment) / m
            J = np.asarray(ap.inertia) - m * (c @ c * np.eye(3) - np.outer(c, c))
            rigid = jaxtree.Body("beam", m, J, 0, (0, 0, 1), tuple(point + c), (0, 0, 0))
            three = jaxtree.build_model([hub, panel, rigid], {**start, "gamma": [0.3, 0.0], "gamma_dot": [0.02, 0.0]})
            y = hm.pack(vehicle.initial)
            T, H = _energy_and_momentum(hm, hm.state(0.0, y), hm.appendage_coordinates(y))
            spring = 0.5 * 50.0 * 0.3**2
            np.testing.assert_allclose(
                float(T), float(jaxtree.kinetic_energy(three, three.initial)) + spring, rtol=1e-12
            )
            np.testing.assert_allclose(
                np.asarray(H), np.asarray(jaxtree.angular_momentum(three, three.initial)), rtol=1e-12
            )
        hm = jaxtree.hybrid_model(pushed, (), 4, appendages=[ap])
        sol = jaxtree.simulate_hybrid(hm, 20.0, saveat=ts, rtol=1e-11, atol=1e-11, truncation_error=False)
        energy, momentum = np.asarray(sol.energy)[1:], np.asarray(sol.angular_momentum)[1:]
        # jitted: an eager vmap would run (and compile) each operation on its own
        q = np.asarray(jax.jit(jax.vmap(lambda y, hm=hm: hm.appendage_coordinates(y)[0][0]))(sol.ys))
        states = jax.jit(jax.vmap(hm.state))(sol.ts, sol.ys)
        tree = np.asarray(jax.jit(jax.vmap(lambda s: jaxtree.kinetic_energy(vehicle, s)))(states))[1:]
        runs[stiffer] = (
            np.abs(q).max(),
            np.ptp(energy) / energy.mean(),
            np.abs(momentum - momentum[0]).max() / np.linalg.norm(momentum[0]),
            np.ptp(tree) / tree.mean(),
        )
    (q_flex, e_flex, h_flex, trade), (q_stiff, e_stiff, h_stiff, _) = runs[1.0], runs[100.0]
    assert q_flex > 0.01 and q_flex > 50 * q_stiff, runs  # 0.017 after the pulse
    assert e_stiff <= 1e-7 and h_stiff <= 1e-7, runs
    assert e_flex <= 2e-5 and h_flex <= 2e-5, runs
    assert trade > 0.1, runs


# --------------------------------------------------------------------------------------------
# NASTRAN OP4 matrices


def _op4_text(matrices, per=3, width=23, digits=16):
    """A formatted OP4 file of real matrices, written here from the format's description (MSC
    Nastran's OUTPUT4): header ``NCOL NROW NF NTYPE NAME FMT`` (I8 fields, A8 name), then each
    column's nonzero span as ``ICOL IROW NW`` and NW values in fields of `width`, then the closing
    record ``NCOL+1 1 1`` and one value."""
    out = []
    for name, (form, A) in matrices.items():
        nrow, ncol = A.shape
        out.append(f"{ncol:8d}{nrow:8d}{form:8d}{2:8d}{name:<8s}1P,{per}E{width}.{digits}")
        for j in range(ncol):
            nz = np.flatnonzero(A[:, j])
            if nz.size == 0:
                continue
            a, b = nz[0], nz[-1]
            vals = A[a : b + 1, j]
            out.append(f"{j + 1:8d}{a + 1:8d}{vals.size:8d}")
            for k in range(0, vals.size, per):
                out.append("".join(f"{v:{width}.{digits}E}" for v in vals[k : k + per]))
        out.append(f"{ncol + 1:8d}{1:8d}{1:8d}")
        out.append(f"{1.0:{width}.{digits}E}")
    return "\n".join(out) + "\n"


def test_op4_matrices_make_the_same_appendage(tmp_path, kane_beam):
    """read_op4 reads NASTRAN's formatted OP4: a file written by pyNastran 1.4.1
    (tests/data/tridiagonal.op4, a symmetric 3 x 3 of form 6) gives its matrix; the beam's mass and
    stiffness written as OP4 (double precision, and single precision's 5E16.9 fields) and read back
    make the appendage of the arrays (frequencies to 1e-12, and to the single-precision fields'
    rounding), and in the binary form; sparse, complex and broken files are refused with the reason."""
    read = jaxtree.read_op4(DATA / "tridiagonal.op4")
    np.testing.assert_array_equal(read["KAA"], [[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 2.0]])

    fe = beam(LENGTH, 8, E=E, rho=RHO, area=AREA, Iy=4 * IY, Iz=IY)
    M, K = np.asarray(fe.mass), np.asarray(fe.stiffness)
    base = appendage(fe, 0, n_modes=4, geometric=False)
    for per, width, digits, tol in ((3, 23, 16, 1e-12), (5, 16, 9, 1e-7)):
        path = tmp_path / f"beam{width}.op4"
        path.write_text(_op4_text({"MAA": (6, M), "KAA": (6, K)}, per, width, digits))
        mats = jaxtree.read_op4(path)
        assert set(mats) == {"MAA", "KAA"}
        np.testing.assert_allclose(mats["MAA"], M, rtol=10**-digits * 10, atol=0)
        fe2 = jaxtree.FEModel(jnp.asarray(mats["MAA"]), jnp.asarray(mats["KAA"]), fe.nodes, None, fe.dofs)
        ap = appendage(fe2, 0, n_modes=4, geometric=False)
        np.testing.assert_allclose(np.asarray(ap.frequencies), np.asarray(base.frequencies), rtol=tol)

    bad = {
        "sparse": "       3      -3       6       2KAA     1P,3E23.16\n",
        "complex": "       3       3       6       4KAA     1P,3E23.16\n",
        "header": "not an op4 file\n",
        "short": "       3       3       6       2KAA     1P,3E23.16\n       1       1       1\n 1.0E+00\n",
    }
    for what, text in bad.items():
        path = tmp_path / f"{what}.op4"
        path.write_text(text)
        with pytest.raises(
            jaxtree.SceneError,
            match={"sparse": "BIGMAT", "complex": "complex", "header": "header", "short": "before its closing"}[what],
        ):
            jaxtree.read_op4(path)
    # the binary form (Fortran records), both byte orders, double and single precision: the same
    # matrices as the text form that pyNastran wrote, and the beam's
    kaa = jaxtree.read_op4(DATA / "tridiagonal.op4")["KAA"]
    for order in "<>":
        for ntype, tol in ((2, 0.0), (1, 1e-7)):
            path = tmp_path / f"beam{order == '<'}{ntype}.op4"
            path.write_bytes(_op4_binary({"KAA": (6, kaa), "MAA": (6, M)}, order, ntype))
            mats = jaxtree.read_op4(path)
            np.testing.assert_array_equal(mats["KAA"], kaa)
            np.testing.assert_allclose(mats["MAA"], M, rtol=tol, atol=tol * np.abs(M).max())
    broken = _op4_binary({"KAA": (6, kaa)}, "<", 2)
    for what, raw, message in (
        ("cut", broken[:-30], "ends inside|broken record"),
        ("noise", bytes(range(128, 256)) * 4, "neither a text"),
        ("sparse", _op4_binary({"KAA": (6, kaa)}, "<", 2, sparse=True), "sparse"),
    ):
        path = tmp_path / f"{what}.op4"
        path.write_bytes(raw)
        with pytest.raises(jaxtree.SceneError, match=message):
            jaxtree.read_op4(path)


def _op4_binary(matrices, order, ntype, sparse=False):
    """A binary OP4 file written here from the format's description (MSC Nastran's OUTPUT4): per
    matrix a Fortran record of the header ``NCOL NROW NF NTYPE`` and the 8-byte NAME, then one
    record per column with a nonzero, ``ICOL IROW NW`` (NW four-byte words) and the values from
    IROW to the last nonzero, and a closing record ``NCOL + 1, 1, per`` with one value; every
    record between four-byte lengths. `sparse`: the first column as a sparse string (IROW = 0)."""
    import struct

    kind, per = ("f", 1) if ntype == 1 else ("d", 2)

    def rec(body):
        return struct.pack(f"{order}i", len(body)) + body + struct.pack(f"{order}i", len(body))

    out = b""
    for name, (form, A) in matrices.items():
        nrow, ncol = A.shape
        out += rec(struct.pack(f"{order}4i", ncol, nrow, form, ntype) + name.ljust(8).encode())
        for j in range(ncol):
            nz = np.nonzero(A[:, j])[0]
            if nz.size == 0:
                continue
            vals = A[nz[0] : nz[-1] + 1, j]
            row = 0 if (sparse and j == 0) else nz[0] + 1
            out += rec(
                struct.pack(f"{order}3i", j + 1, row, per * vals.size) + struct.pack(f"{order}{vals.size}{kind}", *vals)
            )
        out += rec(struct.pack(f"{order}3i", ncol + 1, 1, per) + struct.pack(f"{order}{kind}", 1.0))
    return out


def test_the_nominal_spin_is_about_the_vehicles_mass_center(spin_beam):
    """A light hub (1 kg) carrying the beam (12 kg) at its center spins about the vehicle's mass
    center, 12 / 13 of the way to the beam's own center (d = 4.62 m out along the beam): the
    centrifugal tension is ``rho A Omega^2 [(L^2 - x^2) / 2 - d (L - x)]``, and the held-base modes
    of the hybrid model stiffen by its Rayleigh quotient (by quadrature of the analytic mode), out
    of the plane by K and in it by K - 1, not by the hub-centered Southwell coefficients."""
    Om = 0.05
    ap = appendage(spin_beam, "hub", n_modes=12)
    m = float(ap.mass)
    d = m * LENGTH / 2 / (1.0 + m)
    phi, dphi = _mode(_beta_l(1))
    den = quad(lambda x: phi(x) ** 2, 0, 1, epsabs=1e-13)[0]
    offset = quad(lambda x: (1 - x) * dphi(x) ** 2, 0, 1, epsabs=1e-13)[0] / den
    K = _southwell(1) - d / LENGTH * offset
    assert K < 0.8  # well away from the hub-centered 1.193
    hub = jaxtree.Body("hub", 1.0, np.diag([0.1, 0.1, 0.1]))
    vehicle = jaxtree.build_model([hub], {"omega0": [0.0, 0.0, Om]})
    hm = jaxtree.hybrid_model(vehicle, (), 2, appendages=[ap], omega0=jnp.asarray([0.0, 0.0, Om]))
    w1 = float(ap.frequencies[0])
    slopes = (np.sort(np.asarray(hm.frequencies))[:2] ** 2 - w1**2) / Om**2
    np.testing.assert_allclose(slopes, [K - 1.0, K], rtol=5e-3)


# --------------------------------------------------------------------------------------------
# The inertia of the interpolated fields, and the linearization about a spin


def test_beam_samples_reproduce_the_consistent_mass():
    """The beam's mass as particles and torsional sections at four Gauss points per element
    (fe.Samples, the appendage's Gauss function) sums to the consistent mass matrix of the
    elements exactly, for a beam along a general direction with unequal sections."""
    fe = beam(LENGTH, 6, E=E, rho=RHO, area=AREA, Iy=IY, Iz=3 * IY, direction=(1.0, 2.0, 0.5), up=(0.3, 0.0, 1.0))
    s = fe.elements.samples(fe.nodes)
    N = fe.mass.shape[0]
    T, R = np.asarray(s.matrix(N)), np.asarray(s.matrix(N, "rotation"))
    P = len(s.mass)
    J = np.zeros((3 * P, 3 * P))
    for p in range(P):
        J[3 * p : 3 * p + 3, 3 * p : 3 * p + 3] = np.asarray(s.inertia[p])
    M = (T * np.repeat(np.asarray(s.mass), 3)) @ T.T + R @ J @ R.T
    np.testing.assert_allclose(M, np.asarray(fe.mass), rtol=0, atol=1e-13 * np.abs(np.asarray(fe.mass)).max())
    np.testing.assert_allclose(np.sum(np.asarray(s.mass)), RHO_A * LENGTH, rtol=1e-14)


def test_linearization_through_eq30_equals_eq1():
    """jaxtree.linearize_vehicle with appendages differentiates Eq. (30) in the small coordinates
    themselves (the precomputed substructure terms); without appendages it must give Eq. (1)'s own
    linearization (jacfwd of Eq. 1) on a spinning vehicle with prescribed rotors (fig4) and with
    two sprung wings (wings), to round-off."""
    from jaxtree._src.hybrid.linear import appendage_linearization
    from jaxtree._src.linear.linearize import linearize_vehicle

    w = jnp.asarray([0.01, -0.02, 0.3])
    for name in ("fig4", "wings"):
        model = jaxtree.load_scene(name)
        a = linearize_vehicle(model, omega0=w)
        b = appendage_linearization(model, (), model.unknown_hinges, attitude=True, omega0=w)
        assert a.coordinates == b.coordinates and a.hinges == b.hinges
        for x, y in ((a.I, b.I), (a.J, b.J), (a.K, b.K), (a.bias, b.bias)):
            x, y = np.asarray(x), np.asarray(y)
            np.testing.assert_allclose(y, x, rtol=0, atol=1e-12 * np.abs(x).max())


def _u_chain(N, hub, EIy, EIz):
    """The beam as a chain of N rigid segments on two-axis joints (a massless body turning about the
    z axis, then the segment about y), springs EI / l between segments and 2 EI / l at the clamp
    (second order in l), the segments' line mass, their own inertia m l^2 / 12 across and the
    beam's torsional rotary inertia along."""
    l = LENGTH / N
    m = RHO_A * l
    bodies = [hub]
    for k in range(N):
        on_parent = (HUB_POINT, 0.0, 0.0) if k == 0 else (l / 2, 0.0, 0.0)
        f = 2.0 if k == 0 else 1.0
        z = jaxtree.SpringDamper(f * EIz / l, 0.0)
        y = jaxtree.SpringDamper(f * EIy / l, 0.0)
        parent = 0 if k == 0 else len(bodies) - 1
        bodies.append(jaxtree.Body(f"u{k + 1}", 0.0, np.zeros((3, 3)), parent, (0, 0, 1), on_parent, (0, 0, 0), z))
        J = np.diag([RHO * (EIy + EIz) / E * l, m * l * l / 12, m * l * l / 12])
        bodies.append(jaxtree.Body(f"s{k + 1}", m, J, len(bodies) - 1, (0, 1, 0), (0, 0, 0), (-l / 2, 0, 0), y))
    return jaxtree.build_model(bodies)


def test_spinning_vehicle_modes_with_a_beam_match_the_chain():
    """A free hub (100 kg) spinning at 2 rad/s about z with the beam (bending stiffness 1 : 1.5 in
    and out of the spin plane) clamped 1 m out along x: jaxtree.linearize_vehicle with the
    finite-element appendage (40 elements, 6 held-interface modes) is a relative equilibrium
    (no bias), gyroscopic (K symmetric, J skew: exactly, the appendage's inertia is that of its
    interpolated fields), and its frequencies (nutation, the coupled bending pairs) equal those of
    the full Eq. (1) of the beam as a chain of rigid segments on two-axis joints, extrapolated in
    the number of segments from 16 and 32, to 1e-4 (measured 2.2e-5; the extrapolations from 16/32
    and 32/64 agree to 8e-6; the chain of 32 alone differs by 1.5e-3). With the consistent mass weighting the nodes (before the sample
    points) the same vehicle was "general" (K unsymmetric by 7e-5 of the first modal stiffness), and
    jaxtree.modes refused it as defective."""
    Om = 2.0
    w = jnp.asarray([0.0, 0.0, Om])
    hub = jaxtree.Body("hub", 100.0, np.diag([300.0, 250.0, 400.0]))
    EIy, EIz = EI, 1.5 * EI
    freqs = {}
    for N in (16, 32):
        md = jaxtree.modes(jaxtree.linearize_vehicle(_u_chain(N, hub, EIy, EIz), omega0=w))
        assert md.kind == "gyroscopic"
        freqs[N] = np.sort(np.asarray(md.frequencies))[:7]
    chain = (4.0 * freqs[32] - freqs[16]) / 3.0
    ap = appendage(
        beam(LENGTH, 40, E=E, rho=RHO, area=AREA, Iy=EIy / E, Iz=EIz / E), "hub", point=(HUB_POINT, 0, 0), n_modes=6
    )
    lin = jaxtree.linearize_vehicle(jaxtree.build_model([hub]), omega0=w, appendages=[ap])
    assert lin.coordinates[3:] == tuple(f"hub.appendage0.q{j}" for j in range(1, 7)) and lin.hinges[3:] == (-1,) * 6
    I, J, K = (np.asarray(x) for x in lin)
    assert np.abs(np.asarray(lin.bias)).max() < 1e-9 * np.abs(K).max()
    assert np.abs(K - K.T).max() < 1e-12 * np.abs(K).max() and np.abs(J + J.T).max() < 1e-12 * np.abs(J).max()
    md = jaxtree.modes(lin)
    assert md.kind == "gyroscopic"
    fe = np.sort(np.asarray(md.frequencies))[:7]
    assert fe[0] == 0.0 and abs(fe[2] - Om) < 1e-9  # the spin axis' rotation, and the rigid mode at the spin rate
    flex = np.asarray([1, 3, 4, 5, 6])  # the nutation and two coupled pairs of bending modes
    np.testing.assert_allclose(fe[flex], chain[flex], rtol=1e-4)
    assert np.max(np.abs(freqs[32][flex] / chain[flex] - 1)) > 5e-4  # the chain's own error, above the tolerance


def _page_data(text):
    """The data block of a viewer page (tests/test_viewer.py reads it the same way)."""
    import json
    import re

    m = re.search(r'<script type="application/json" class="jt-data">(.*?)</script>', text, re.S)
    assert m is not None
    return json.loads(m.group(1))


def _f32(b64):
    import base64

    return np.frombuffer(base64.b64decode(b64), dtype="<f4").astype(float)


def test_the_viewer_draws_the_deformed_appendage():
    """HybridSolution.appendage_motion: every node of the beam on the hub, displaced by the mode
    shapes times the modal coordinates (times a scale), its output node's displacement that of
    HybridModel.appendage_displacement; write_animation embeds the nodes and the elements' sides."""
    from jaxtree._src.io.viewer import animation_html

    hub = jaxtree.Body("hub", 100.0, np.diag([HUB_INERTIA] * 3))
    torque = jaxtree.BodyTorque(0, [0.0, 0.0, 200.0])
    ap = appendage(_wide_beam(10), "hub", point=(HUB_POINT, 0, 0), n_modes=4, outputs=(10,), name="boom")
    hm = jaxtree.hybrid_model(jaxtree.build_model([hub]).with_loads(torque), (), 3, appendages=[ap])
    sol = jaxtree.simulate_hybrid(hm, 2.0, saveat=9, truncation_error=False)
    (motion,) = sol.appendage_motion(scale=5.0)
    assert motion["body"] == 0 and motion["edges"] == tuple((i, i + 1) for i in range(10))
    np.testing.assert_allclose(motion["nodes"][10], [HUB_POINT + LENGTH, 0.0, 0.0], atol=1e-12)
    tip = np.asarray(jax.vmap(lambda y: hm.appendage_displacement(y))(sol.ys))[:, :3]
    assert np.abs(tip[:, 1]).max() > 1e-3  # the torque bends the beam
    np.testing.assert_allclose(motion["displacement"][:, 10], 5.0 * tip, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(motion["displacement"][:, 0], 0.0, atol=1e-15)  # the clamped node
    data = _page_data(animation_html(hm.model, sol.ts, sol.dcm, sol.gamma, appendages=[motion]))
    (drawn,) = data["appendages"]
    assert drawn["n"] == 11 and drawn["edges"] == [[i, i + 1] for i in range(10)]
    points = _f32(drawn["points"]).reshape(9, 11, 3)
    np.testing.assert_allclose(points, motion["nodes"][None] + motion["displacement"], atol=1e-5 * LENGTH)
    with pytest.raises(ValueError, match="displacement"):
        animation_html(
            hm.model, sol.ts, sol.dcm, sol.gamma, appendages=[{**motion, "displacement": np.zeros((3, 11, 3))}]
        )


def test_truncation_estimate_of_the_appendages_neglected_modes():
    """simulate_hybrid's appendage_truncation: the held-base modes of the beam left out of the hybrid
    model (12 held-interface coordinates, 1 or 3 retained), driven by the appendage's unbalanced
    force (Eq. 30 in those coordinates). Against the true error, the same slew with all 12 modes
    kept minus the truncated one at the beam's tip: nothing with every mode kept; with 3 kept
    within a factor 3 of the true error over the whole run (tests/test_truncation.py's bound for
    the hinges' estimate; measured 0.70 of it); with 1 kept within that factor while the torque
    acts (measured 0.46) but not after it: the neglected modes' flexibility shifts the coupled
    frequency of the retained one, whose phase then drifts, which a driven estimate does not see
    (0.31 of the error over the whole run)."""
    T0, t1 = 200.0, 15.0
    profile = lambda t: jnp.where(t < 10.0, jnp.sin(2 * jnp.pi * t / 10.0), 0.0)
    torque = jaxtree.BodyTorque(0, [0.0, 0.0, T0], profile)
    hub = jaxtree.Body("hub", 100.0, np.diag([HUB_INERTIA] * 3))
    vehicle = jaxtree.build_model([hub]).with_loads(torque)
    ap = appendage(_wide_beam(), "hub", point=(HUB_POINT, 0, 0), n_modes=12, outputs=(20,))
    ts = np.linspace(0.0, t1, 121)
    tips, est = {}, {}
    for k in (1, 3, 12):
        hm = jaxtree.hybrid_model(vehicle, (), k, appendages=[ap])
        sol = jaxtree.simulate_hybrid(hm, t1, saveat=ts, rtol=1e-10, atol=1e-10)
        tips[k] = np.asarray(jax.vmap(lambda y, hm=hm: hm.appendage_displacement(y))(sol.ys))[:, 1]
        est[k] = np.asarray(sol.appendage_truncation_at())[:, 1]
        assert sol.appendage_truncation.shape == (len(ts), 12)
    assert np.abs(est[12]).max() < 1e-12 * np.abs(tips[12]).max()
    true = {k: tips[12] - tips[k] for k in (1, 3)}
    ratio = np.abs(est[3]).max() / np.abs(true[3]).max()
    assert 1 / 3 < ratio < 3, ratio
    forced = ts <= 10.0
    ratio = np.abs(est[1][forced]).max() / np.abs(true[1][forced]).max()
    assert 1 / 3 < ratio < 3, ratio
    assert np.abs(true[1]).max() > 10 * np.abs(true[3]).max()  # the error falls as modes are added


def test_small_hinges_and_an_appendage_in_one_hybrid_model():
    """A hybrid model with small hinges and a finite-element appendage together (the truncation
    terms of the appendage were filled at its place among all small coordinates, past the end of
    its own: an IndexError). It builds, and the neglected-mode terms are complete on their own
    coordinates: every flexible mode of a system is in them, so taking a small motion's modal
    content and rebuilding the coordinates from it gives the motion back, ``Re(c d0) = [U, 0]``,
    for the appendage's coordinates and for the small hinges'; the run's estimate is finite."""
    vehicle = jaxtree.load_scene("wings")
    fe = jaxtree.beam(1.7, 6, E=7e10, rho=2700.0, area=1e-4, Iy=1e-8)
    ap = appendage(fe, "hub", n_modes=2)
    hm = jaxtree.hybrid_model(vehicle, tuple(range(1, 9)), 2, appendages=[ap])
    for tr, nu in ((hm.appendage_truncation, 2), (hm.truncation, 8)):
        assert tr is not None
        c = np.asarray(tr.c_parts[..., 0]) + 1j * np.asarray(tr.c_parts[..., 1])
        d0 = np.asarray(tr.d0_parts[..., 0]) + 1j * np.asarray(tr.d0_parts[..., 1])
        assert c.shape[0] == nu
        whole = np.concatenate([np.eye(nu), np.zeros((nu, nu))], 1)
        np.testing.assert_allclose(np.real(c @ d0), whole, rtol=0, atol=1e-9)
    sol = jaxtree.simulate_hybrid(hm, 0.5, saveat=6)
    assert sol.appendage_truncation is not None and np.all(np.isfinite(sol.appendage_truncation))
