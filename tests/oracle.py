"""Independent reference ("oracle") equations of motion for a free-floating tree of
hinge-connected rigid bodies (Likins, JPL TR 32-1565 conventions).

Written from scratch, with no use of ``jaxtree``: the kinetic energy is built from
the positions and attitudes of every body, and the equations of motion come from it
by automatic differentiation.

Speeds u = [v (3), omega0 (3), gamma_dot (n)], where v is the inertial velocity of
body 0's mass center in {b^0} components. T(gamma, u) does not depend on the position
or attitude of body 0, so Hamel / Euler-Poincare (quasi-velocities v, omega0) plus
Lagrange (hinge angles) give

    d/dt dT/dv      + omega0 x dT/dv                 = F_v
    d/dt dT/domega0 + omega0 x dT/domega0 + v x dT/dv = M_0
    d/dt dT/dgd     - dT/dgamma                       = Q_gamma

where d/dt p(gamma, u) = dp/du u_dot + dp/dgamma gamma_dot. The generalized forces
are grad_u of the virtual power of the loads. Eliminating v_dot (Schur complement)
gives the rotational equations, which do not depend on the translation of the system
mass center. Everything is in {b^0} components; dcm is only used for H.

Conventions: C^{kN} = cos(g) U - sin(g) tilde(a) + (1 - cos(g)) a a^T with v_(k) = C^{kN} v_(N);
R_k = C^{0k} maps {b^k} components to {b^0} components: R_k = R_N C^{kN}^T.
"""

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)


def tilde(a):
    """Cross-product matrix: tilde(a) @ b == a x b."""
    return jnp.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def hinge_dcm(a, g):
    """C^{kN}: maps parent-frame components to child-frame components (rotation +g about a)."""
    return jnp.cos(g) * jnp.eye(3) - jnp.sin(g) * tilde(a) + (1.0 - jnp.cos(g)) * jnp.outer(a, a)


def _model(parents, mass, inertia, axis, hinge_on_parent, hinge_on_body):
    """Normalise the tree description. parents stays a static Python list."""
    parents = [int(p) for p in np.asarray(parents, dtype=int).reshape(-1)]
    n = len(parents)
    assert all(0 <= p < k + 1 for k, p in enumerate(parents)), "need parents[k-1] < k"
    f = lambda x, s: jnp.asarray(x, dtype=jnp.float64).reshape(s)
    return dict(
        parents=parents,
        n=n,
        mass=f(mass, (n + 1,)),
        inertia=f(inertia, (n + 1, 3, 3)),
        axis=f(axis, (n, 3)),
        hop=f(hinge_on_parent, (n, 3)),
        hob=f(hinge_on_body, (n, 3)),
    )


def _kinematics(m, gamma):
    """Attitudes R_k (body k -> body 0 components) and mass-center positions r_k
    relative to body 0's mass center, in {b^0} components. One pass over the tree in
    label order (parents first, Def. 4), as a scan so that compile time does not grow
    with the number of bodies."""
    n = m["n"]
    R0 = jnp.zeros((n + 1, 3, 3)).at[0].set(jnp.eye(3))
    r0 = jnp.zeros((n + 1, 3))
    if n == 0:
        return R0, r0

    def step(carry, k):
        R, r = carry
        N = jnp.asarray(m["parents"])[k - 1]
        Rk = R[N] @ hinge_dcm(m["axis"][k - 1], gamma[k - 1]).T
        rk = r[N] + R[N] @ m["hop"][k - 1] - Rk @ m["hob"][k - 1]
        return (R.at[k].set(Rk), r.at[k].set(rk)), None

    (R, r), _ = jax.lax.scan(step, (R0, r0), jnp.arange(1, n + 1))
    return R, r


def mass_center_velocities(m, gamma, u):
    """Inertial velocity of each mass center and inertial angular velocity of each
    body, both in {b^0} components, from the time derivative of the kinematics."""
    v, w0, gd = u[:3], u[3:6], u[6:]
    (R, r), (Rd, rd) = jax.jvp(lambda g: _kinematics(m, g), (gamma,), (gd,))
    vel = v + jnp.cross(w0, r) + rd  # transport theorem in rotating {b^0}
    W = jnp.einsum("kij,klj->kil", Rd, R)  # Rdot R^T = tilde(w_rel) in {b^0}
    omg = w0 + jnp.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]], axis=1)
    return R, r, vel, omg


def _kinetic_energy(m, gamma, u):
    """Total (inertial) kinetic energy: sum 1/2 m |v|^2 + 1/2 w_b^T I w_b."""
    R, _, vel, omg = mass_center_velocities(m, gamma, u)
    wb = jnp.einsum("kji,kj->ki", R, omg)  # angular velocity in own frame
    return 0.5 * jnp.sum(m["mass"] * jnp.sum(vel * vel, axis=1)) + 0.5 * jnp.sum(
        wb * jnp.einsum("kij,kj->ki", m["inertia"], wb)
    )


def _full_system(m, gamma, u, tau, F, T):
    """Full (n+6) system M u_dot = b in speeds u = [v, omega0, gamma_dot]."""
    ke = lambda g, uu: _kinetic_energy(m, g, uu)
    mom = lambda g, uu: jax.grad(ke, argnums=1)(g, uu)
    M = jax.jacfwd(mom, argnums=1)(gamma, u)  # p is linear in u: dp/du = M
    p = mom(gamma, u)
    _, p_q = jax.jvp(lambda g: mom(g, u), (gamma,), (u[6:],))  # dp/dgamma gamma_dot
    dT_dg = jax.grad(ke, argnums=0)(gamma, u)
    v, w0 = u[:3], u[3:6]
    pv, pw = p[:3], p[3:6]
    h = jnp.concatenate([jnp.cross(w0, pv), jnp.cross(w0, pw) + jnp.cross(v, pv), -dT_dg])
    # hinge torques as body torques: +tau a on body k, -tau a on the parent
    ta = tau[:, None] * m["axis"]
    Tl = jnp.asarray(T).at[1:].add(ta).at[jnp.asarray(m["parents"])].add(-ta)

    def power(uu):  # virtual power of all loads
        R, _, vel, omg = mass_center_velocities(m, gamma, uu)
        return jnp.sum(vel * jnp.einsum("kij,kj->ki", R, F)) + jnp.sum(omg * jnp.einsum("kij,kj->ki", R, Tl))

    Q = jax.grad(power)(u)
    return M, Q - p_q - h


def _reduced(m, gamma, omega0, gamma_dot, tau, F, T, v=None):
    """Eliminate v_dot from the full system (Schur complement). Result must not
    depend on the (arbitrary) reference translation speed v; default v = 0."""
    v = jnp.zeros(3) if v is None else jnp.asarray(v, dtype=jnp.float64)
    u = jnp.concatenate([v, omega0, gamma_dot])
    M, b = _full_system(m, gamma, u, tau, F, T)
    Mvv, Mvr, Mrv, Mrr = M[:3, :3], M[:3, 3:], M[3:, :3], M[3:, 3:]
    Mred = Mrr - Mrv @ jnp.linalg.solve(Mvv, Mvr)
    bred = b[3:] - Mrv @ jnp.linalg.solve(Mvv, b[:3])
    return Mred, bred, M, b


def _relative_quantities(m, gamma, omega0, gamma_dot, dcm):
    """KE relative to system CM and H about system CM (inertial components)."""
    u = jnp.concatenate([jnp.zeros(3), omega0, gamma_dot])
    R, r, vel, omg = mass_center_velocities(m, gamma, u)
    mt = jnp.sum(m["mass"])
    rc, vc = m["mass"] @ r / mt, m["mass"] @ vel / mt
    ke = _kinetic_energy(m, gamma, u) - 0.5 * mt * vc @ vc
    Ib = jnp.einsum("kij,kjl,kml->kim", R, m["inertia"], R)  # R I R^T
    H0 = jnp.sum(m["mass"][:, None] * jnp.cross(r - rc, vel - vc), axis=0) + jnp.sum(
        jnp.einsum("kij,kj->ki", Ib, omg), axis=0
    )
    return ke, dcm.T @ H0  # {b^0} = C {i}: x_i = C^T x_0


def _prep(parents, mass, inertia, axis, hinge_on_parent, hinge_on_body, gamma, tau, F, T, dcm):
    m = _model(parents, mass, inertia, axis, hinge_on_parent, hinge_on_body)
    n = m["n"]
    a = lambda x, s: jnp.zeros(s) if x is None else jnp.asarray(x, dtype=jnp.float64).reshape(s)
    return (
        m,
        a(gamma, (n,)),
        a(tau, (n,)),
        a(F, (n + 1, 3)),
        a(T, (n + 1, 3)),
        jnp.eye(3) if dcm is None else a(dcm, (3, 3)),
    )


@jax.jit
def _eom_core(parents, mass, inertia, axis, hop, hob, omega0, gamma, gamma_dot, tau, F, T, dcm):
    # parents is a traced integer array here (validated by oracle_eom), so one compilation
    # serves every tree with the same number of bodies
    n = axis.shape[0]
    m = dict(parents=parents, n=n, mass=mass, inertia=inertia, axis=axis, hop=hop, hob=hob)
    Mred, bred, M, b = _reduced(m, gamma, omega0, gamma_dot, tau, F, T)
    acc = jnp.linalg.lstsq(Mred, bred)[0]
    ke, H = _relative_quantities(m, gamma, omega0, gamma_dot, dcm)
    R = _kinematics(m, gamma)[0]
    return dict(
        omega0_dot=acc[:3],
        gamma_ddot=acc[3:],
        mass_matrix=Mred,
        rhs=bred,
        kinetic_energy=ke,
        angular_momentum=H,
        full_mass_matrix=M,
        full_rhs=b,
        cm_acceleration=jnp.einsum("kij,kj->i", R, F) / jnp.sum(m["mass"]),
    )


def oracle_eom(
    parents,
    mass,
    inertia,
    axis,
    hinge_on_parent,
    hinge_on_body,
    omega0,
    gamma,
    gamma_dot,
    tau=None,
    F=None,
    T=None,
    dcm=None,
):
    """Rotational equations of motion of the free tree (system CM translation removed).

    Returns dict: omega0_dot (3,), gamma_ddot (n,), mass_matrix (n+3, n+3), rhs (n+3,)
    with mass_matrix @ [omega0_dot; gamma_ddot] = rhs, kinetic_energy (relative to the
    system CM), angular_momentum (about the system CM, inertial components), plus
    full_mass_matrix / full_rhs (n+6 system in [v, omega0, gamma_dot], v = 0) and
    cm_acceleration (inertial acceleration of the system CM, {b^0} components).
    The reduced system is solved by least squares, so a singular mass matrix
    (massless leaf bodies) yields the minimum-norm accelerations instead of NaN.
    Compiled once per number of bodies.
    """
    m, gamma, tau, F, T, dcm = _prep(
        parents, mass, inertia, axis, hinge_on_parent, hinge_on_body, gamma, tau, F, T, dcm
    )
    omega0 = jnp.asarray(omega0, dtype=jnp.float64).reshape(3)
    gamma_dot = jnp.asarray(gamma_dot, dtype=jnp.float64).reshape(m["n"])
    return _eom_core(
        jnp.asarray(m["parents"], dtype=jnp.int32).reshape(m["n"]),
        m["mass"],
        m["inertia"],
        m["axis"],
        m["hop"],
        m["hob"],
        omega0,
        gamma,
        gamma_dot,
        tau,
        F,
        T,
        dcm,
    )


def oracle_body_states(parents, mass, axis, hinge_on_parent, hinge_on_body, gamma, omega0=None, gamma_dot=None):
    """Per-body kinematics in {b^0} components.

    R (n+1,3,3): C^{0k}, v_(0) = R[k] @ v_(k).  r (n+1,3): mass-center positions relative
    to the system mass center.  r_body0 (n+1,3): relative to body 0's mass center.
    If omega0 and gamma_dot are given, also omega (n+1,3): inertial angular velocities and
    v (n+1,3): inertial velocities relative to the system CM velocity.
    """
    mass = np.asarray(mass, dtype=float)
    m = _model(parents, mass, np.zeros((mass.size, 3, 3)), axis, hinge_on_parent, hinge_on_body)
    gamma = jnp.asarray(gamma, dtype=jnp.float64).reshape(m["n"])
    w0 = jnp.zeros(3) if omega0 is None else jnp.asarray(omega0, dtype=jnp.float64)
    gd = jnp.zeros(m["n"]) if gamma_dot is None else jnp.asarray(gamma_dot, dtype=jnp.float64)
    R, r, vel, omg = mass_center_velocities(m, gamma, jnp.concatenate([jnp.zeros(3), w0, gd]))
    mt = jnp.sum(m["mass"])
    out = dict(R=R, r=r - m["mass"] @ r / mt, r_body0=r)
    if omega0 is not None and gamma_dot is not None:
        out.update(omega=omg, v=vel - m["mass"] @ vel / mt)
    return out


def oracle_at(model, state, tau=None, F=None, T=None):
    """``oracle_eom`` for a jaxtree model at a state: the tree (parents, masses, inertias, hinge
    axes and points) read from `model`, the speeds and the attitude from `state` (anything with
    ``dcm``, ``omega0``, ``gamma``, ``gamma_dot``, e.g. ``jaxtree.State``; the attitude enters only
    the angular momentum). Springs and dampers are not read: pass their torques in `tau`. Duck-typed,
    so this file still does not import jaxtree."""
    return oracle_eom(
        model.topology.parents,
        np.asarray(model.mass),
        np.asarray(model.inertia),
        np.asarray(model.axis),
        np.asarray(model.hinge_on_parent),
        np.asarray(model.hinge_on_body),
        np.asarray(state.omega0),
        np.asarray(state.gamma),
        np.asarray(state.gamma_dot),
        tau=tau,
        F=F,
        T=T,
        dcm=np.asarray(state.dcm),
    )


# ---------------------------------------------------------------------------------
# Self-check: python3 tests/oracle.py
# ---------------------------------------------------------------------------------
def _random_tree(rng, parents):
    n = len(parents)
    A = rng.normal(size=(n + 1, 3, 3))
    ax = rng.normal(size=(n, 3))
    return dict(
        parents=parents,
        mass=rng.uniform(0.5, 2.0, n + 1),
        inertia=A @ A.transpose(0, 2, 1) + 0.3 * np.eye(3),
        axis=ax / np.linalg.norm(ax, axis=1, keepdims=True),
        hinge_on_parent=rng.normal(size=(n, 3)),
        hinge_on_body=rng.normal(size=(n, 3)),
    )


def _self_check():
    from scipy.integrate import solve_ivp

    rng = np.random.default_rng(0)
    I0 = np.array([[3.0, 0.2, -0.1], [0.2, 2.0, 0.3], [-0.1, 0.3, 1.5]])
    w, Tq = rng.normal(size=3), rng.normal(size=3)
    euler = np.linalg.solve(I0, Tq - np.cross(w, I0 @ w))
    # 1a. n = 0: single rigid body, Euler's equations (force at CM must not matter)
    o = oracle_eom(
        [], [2.0], [I0], np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), w, [], [], F=[[1.0, 2.0, 3.0]], T=[Tq]
    )
    print("1a Euler n=0 err:", np.abs(o["omega0_dot"] - euler).max())
    # 1b. n = 1 with massless, inertia-free child (hinge effectively locked)
    o = oracle_eom(
        [0],
        [2.0, 0.0],
        [I0, np.zeros((3, 3))],
        [[0, 0, 1.0]],
        [[1, 0, 0.0]],
        [[0, 1, 0.0]],
        w,
        [0.7],
        [1.3],
        F=[[1.0, 2.0, 3.0], [0, 0, 0]],
        T=[Tq, [0, 0, 0]],
    )
    print(
        "1b Euler n=1 massless child err:",
        np.abs(o["omega0_dot"] - euler).max(),
        "gamma_ddot:",
        np.asarray(o["gamma_ddot"]),
    )
    # 2. body + point mass m on massless rod of length L hinged (axis z) at body CM
    m0, mp, L, g = 2.0, 0.5, 1.5, 0.4
    mu, rr, ez = m0 * mp / (m0 + mp), L * np.array([np.cos(g), np.sin(g), 0.0]), np.eye(3)[2]
    J = mu * (L * L * np.eye(3) - np.outer(rr, rr))
    Mhand = np.block([[I0 + J, (J @ ez)[:, None]], [(ez @ J)[None, :], np.array([[mu * L * L]])]])
    args2 = ([0], [m0, mp], [I0, np.zeros((3, 3))], [ez], [[0, 0, 0.0]], [[-L, 0, 0.0]])
    o = oracle_eom(*args2, rng.normal(size=3), [g], [0.8])
    print("2  two-body mass matrix err vs hand:", np.abs(o["mass_matrix"] - Mhand).max())
    o = oracle_eom(*args2, [0, 0, 1.1], [g], [0.8], tau=[0.6])  # planar: M const, rhs=[0,tau]
    print("2  planar rhs (z, gamma) vs (0, 0.6):", np.asarray(o["rhs"][2:]))

    # random tree checks
    tree = _random_tree(rng, [0, 0, 1])
    m = _model(
        tree["parents"], tree["mass"], tree["inertia"], tree["axis"], tree["hinge_on_parent"], tree["hinge_on_body"]
    )
    n = m["n"]
    targs = (
        tree["parents"],
        tree["mass"],
        tree["inertia"],
        tree["axis"],
        tree["hinge_on_parent"],
        tree["hinge_on_body"],
    )
    gam, w0, gd = rng.normal(size=n), rng.normal(size=3), rng.normal(size=n)
    tau, F, T = rng.normal(size=n), rng.normal(size=(n + 1, 3)), rng.normal(size=(n + 1, 3))
    # 4. independence of the (arbitrary) reference translation speed v
    a1 = _reduced(m, gam, w0, gd, tau, F, T)
    a2 = _reduced(m, gam, w0, gd, tau, F, T, v=rng.normal(size=3))
    print("4  v-independence: dM", np.abs(a1[0] - a2[0]).max(), " drhs", np.abs(a1[1] - a2[1]).max())
    # 5. mass matrix == Hessian of KE relative to system CM
    ker = lambda s: _relative_quantities(m, gam, s[:3], s[3:], jnp.eye(3))[0]
    Hs = jax.hessian(ker)(jnp.concatenate([w0, gd]))
    print("5  Schur complement vs Hessian of relative KE:", np.abs(Hs - a1[0]).max())
    # 6. power / torque balance with loads: dKE_rel/dt and dH/dt (inertial) at an instant
    C = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    o = oracle_eom(*targs, w0, gam, gd, tau=tau, F=F, T=T, dcm=C)
    acc = jnp.concatenate([o["omega0_dot"], o["gamma_ddot"]])
    Cd = -tilde(w0) @ C
    rel = jax.jit(lambda Cm, g, s: _relative_quantities(m, g, s[:3], s[3:], Cm))
    _, (dke, dH) = jax.jvp(rel, (C, gam, jnp.concatenate([w0, gd])), (Cd, gd, acc))
    st = oracle_body_states(
        tree["parents"], tree["mass"], tree["axis"], tree["hinge_on_parent"], tree["hinge_on_body"], gam, w0, gd
    )
    F0, T0 = np.einsum("kij,kj->ki", st["R"], F), np.einsum("kij,kj->ki", st["R"], T)
    P = np.sum(F0 * st["v"]) + np.sum(T0 * st["omega"]) + tau @ gd
    Hd = C.T @ (np.cross(st["r"], F0).sum(0) + T0.sum(0))
    print("6  dKE/dt - power:", abs(dke - P), "  |dH/dt - moment|:", np.abs(dH - Hd).max())

    # 3. conservation, free motion of a random 4-body tree
    @jax.jit
    def rhs(y):
        Cm, g, s = y[:9].reshape(3, 3), y[9 : 9 + n], y[9 + n :]
        Mr, br, _, _ = _reduced(m, g, s[:3], s[3:], jnp.zeros(n), jnp.zeros((n + 1, 3)), jnp.zeros((n + 1, 3)))
        return jnp.concatenate([(-tilde(s[:3]) @ Cm).ravel(), s[3:], jnp.linalg.solve(Mr, br)])

    y0 = np.concatenate([np.eye(3).ravel(), gam, 2 * w0, 2 * gd])
    sol = solve_ivp(
        lambda t, y: np.asarray(rhs(jnp.asarray(y))),
        (0, 5.0),
        y0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        dense_output=False,
    )
    inv = [rel(y[:9].reshape(3, 3), y[9 : 9 + n], y[9 + n :]) for y in sol.y.T]
    ke = np.array([float(k) for k, _ in inv])
    H = np.array([np.asarray(h) for _, h in inv])
    print(
        f"3  free motion {len(sol.t)} steps, t=5: rel KE drift {np.abs(ke / ke[0] - 1).max():.2e}"
        f", |H| drift {np.abs(H - H[0]).max() / np.linalg.norm(H[0]):.2e}"
        f", gamma moved {np.abs(sol.y[9 : 9 + n, -1] - gam).max():.2f} rad, KE {ke[0]:.3f}"
    )


if __name__ == "__main__":
    _self_check()
