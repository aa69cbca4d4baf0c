"""The linearization of a vehicle that carries finite-element appendages: Eqs. (40)-(44) and the
vehicle modes of Sec. III B, with the appendages' held-interface modal coordinates among the small
coordinates.

Eq. (1) has only rigid bodies, so :func:`jaxtree._src.linear.linearize.linearize` cannot carry an
appendage. Eq. (30) can: an appendage is a substructure of the small set whose coordinates are its
held-interface modal coordinates (:mod:`jaxtree._src.appendage`). Here Eq. (30) is written in
those coordinates themselves, untransformed (:func:`.assembly.physical_model`: a hybrid model
whose modal matrices are unit matrices), the hinges that carry an appendage, a load or a
prescribed hinge outboard of them held large (Eq. 30 is exact in the large variables), and its
residual differentiated by ``jax.jacfwd`` about the nominal motion as
:func:`~jaxtree._src.linear.linearize.linearize_vehicle` differentiates Eq. (1): three small
attitude angles of b_0 relative to a frame spinning steadily at ``omega0``, every hinge and every
appendage coordinate perturbed. To first order Eq. (30) and Eq. (1) agree, so without appendages
the result is Eq. (1)'s (tests/test_appendage.py). :func:`linearize` keeps the rows and columns of
the set A and the appendages (the rest held on the nominal motion), :func:`linearize_vehicle`
adds the attitude angles and every free hinge.

The public :func:`jaxtree.linearize` and :func:`jaxtree.linearize_vehicle` are the functions of
this module: without appendages they are those of :mod:`jaxtree._src.linear.linearize`.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..equations.kinematics import cross, full_precision, tilde
from ..linear import linearize as _lin
from ..linear.linearize import LinearSystem, linearize_args, nominal_state, small_jacobian
from ..vehicle.model import Model
from .arguments import appendage_args
from .assembly import physical_model
from .model import HybridModel, appendage_body, held_prescription
from .rhs import equations_of_parts


def _held_large(model: Model, apps) -> tuple[int, ...]:
    """The free hinges that Eq. (30) keeps large: those on the path to a body that carries an
    appendage or a load or that is prescribed (the small set's substructures must be terminal
    and unloaded, :func:`.arguments.basis_and_precompute`)."""
    parents = model.topology.parents
    ends = {appendage_body(model, ap) for ap in apps} | set(model.prescribed)
    if model.loads is not None:
        ends |= {int(b) for b in model.loads.bodies}
    large: set[int] = set()
    for b in ends:
        while b > 0:
            large.add(b)
            b = int(parents[b - 1])
    return tuple(k for k in model.unknown_hinges if k in large)


@eqx.filter_jit
def _vehicle(hm: HybridModel, dcm, omega0, t):
    """``(I, J, K, bias)`` of Eq. (30) of `hm` (:func:`.assembly.physical_model`) about the
    nominal spin: coordinates ``[theta (3), the large hinges, the small coordinates]``."""
    nL, ns = len(hm.large), hm.n_small
    m = 3 + nL + ns
    dtype = dcm.dtype
    P = hm.positions[:, :ns]  # the small coordinates from the "modal" ones: a permutation
    L = np.asarray(hm.large, np.int64) - 1

    def residual(z):
        q, qd, qdd = z[:m], z[m : 2 * m], z[2 * m :]
        th, thd, thdd = q[:3], qd[:3], qdd[:3]
        w = omega0 + thd + cross(omega0, th)
        wd = thdd + cross(omega0, thd)
        att = hm.attitude.from_dcm((jnp.eye(3, dtype=dtype) - tilde(th)) @ dcm)
        gL = hm.gamma_nominal[L] + q[3 : 3 + nL]
        s = jnp.concatenate([P.T @ q[3 + nL :], P.T @ qd[3 + nL :]])
        mat, rhs = equations_of_parts(hm, t, (att, w, gL, qd[3 : 3 + nL], s))
        r = mat @ jnp.concatenate([wd, qdd[3 : 3 + nL], P.T @ qdd[3 + nL :]]) - rhs
        return jnp.concatenate([r[: 3 + nL], P @ r[3 + nL :]])

    value, jac = small_jacobian(residual, 3 * m)
    return jac[:, 2 * m :], jac[:, m : 2 * m], jac[:, :m], -value


@full_precision
def appendage_linearization(
    model: Model, apps, hinges, *, attitude: bool, omega0=None, gamma=None, dcm=None, t=0.0
) -> LinearSystem:
    """``I y'' + J y' + K y = bias`` of the vehicle with the finite-element appendages `apps`
    (module docstring), coordinates ``y = [theta (with `attitude`), the hinges of `hinges`
    ascending, each appendage's modal coordinates]``; arguments checked by the caller."""
    w, g, C = nominal_state(model, omega0, gamma, dcm)
    large = _held_large(model, apps)
    S = tuple(k for k in model.unknown_hinges if k not in large)
    hm = held_prescription(physical_model(model, S, apps, w, g))
    I, J, K, bias = _vehicle(hm, C, w, jnp.asarray(t, g.dtype))
    # to [theta, hinges ascending, appendage coordinates]
    at = {k: 3 + i for i, k in enumerate(hm.large)} | {k: 3 + len(hm.large) + i for i, k in enumerate(S)}
    o = 3 + len(hm.large) + len(S)
    keep = ([0, 1, 2] if attitude else []) + [at[k] for k in hinges]
    keep += list(range(o, 3 + len(hm.large) + hm.n_small))
    idx = np.asarray(keep, np.int64)
    sel = lambda a: a[np.ix_(idx, idx)]
    b0 = model.names[0]
    coords = tuple(f"{b0}.rotation_{a}" for a in (1, 2, 3)) if attitude else ()
    coords += tuple(model.names[k] for k in hinges)
    for i, ap in enumerate(apps):
        label = ap.name or f"{model.names[appendage_body(model, ap)]}.appendage{i}"
        coords += tuple(f"{label}.q{j + 1}" for j in range(ap.n_modes))
    n_app = hm.n_small - len(S)
    codes = ((0, 0, 0) if attitude else ()) + tuple(hinges) + (-1,) * n_app
    return LinearSystem(sel(I), sel(J), sel(K), bias[idx], coords, codes)


def linearize(model: Model, small, *, omega0=None, gamma=None, dcm=None, t=0.0, appendages=None) -> LinearSystem:
    """Eqs. (40)-(44): ``I y'' + J y' + K y = 0`` for the small hinges of the set A, the rest of the
    vehicle on its nominal motion (:func:`jaxtree._src.linear.linearize.linearize`, whose text
    applies).

    - `appendages`: finite-element appendages (:func:`jaxtree.appendage`) on bodies of `model`:
      their held-interface modal coordinates join the small coordinates after the hinges (named
      ``"<name>.q1"`` ..., hinge index -1 in :attr:`LinearSystem.hinges`), their bodies' hinges
      held; `small` may then be empty. From Eq. (30) in those coordinates (:mod:`.linear`), the
      appendages' geometric stiffness in the nominal spin included. A model whose scene declares
      appendages needs the argument (``jaxtree.scene_appendages(model)``, or ``()``).

    About a steady spin the result is gyroscopic (``K`` symmetric, ``J`` skew) to round-off when
    each appendage's inertia is that of its elements' fields (:func:`jaxtree.beam`,
    :func:`jaxtree.plate`, or a file that carries the elements' masses); an appendage of matrices
    alone (OP4, MatrixMarket) is symmetric and skew only to its discretization error (1.6e-5 of
    ``K`` and 1e-5 of ``J`` for a beam of 40 elements, :mod:`jaxtree._src.appendage.model`): give
    :func:`jaxtree.modes` an `rtol` of that size, or it takes the system as general.
    """
    apps = appendage_args(model, appendages, "linearize")
    if not apps:
        return _lin.linearize(model, small, omega0=omega0, gamma=gamma, dcm=dcm, t=t)
    empty = small is None or (isinstance(small, (list, tuple)) and len(small) == 0)
    hinges = linearize_args("linearize", model, None if empty else small, omega0=omega0, gamma=gamma, dcm=dcm, t=t)
    return appendage_linearization(model, apps, hinges or (), attitude=False, omega0=omega0, gamma=gamma, dcm=dcm, t=t)


def linearize_vehicle(
    model: Model, *, omega0=None, gamma=None, dcm=None, t=0.0, small=None, appendages=None
) -> LinearSystem:
    """The all-small "vehicle normal mode" case of Sec. III B
    (:func:`jaxtree._src.linear.linearize.linearize_vehicle`, whose text applies): three small
    attitude angles of b_0 about a frame spinning at ``omega0``, every free hinge (or those of
    `small`), and the held-interface modal coordinates of `appendages` (see :func:`linearize`)."""
    apps = appendage_args(model, appendages, "linearize_vehicle")
    if not apps:
        return _lin.linearize_vehicle(model, omega0=omega0, gamma=gamma, dcm=dcm, t=t, small=small)
    hinges = linearize_args("linearize_vehicle", model, small, omega0=omega0, gamma=gamma, dcm=dcm, t=t)
    if hinges is None:
        hinges = model.unknown_hinges
    return appendage_linearization(model, apps, hinges, attitude=True, omega0=omega0, gamma=gamma, dcm=dcm, t=t)
