"""The systems whose modes are taken in a hybrid model (Likins 1972, Sec. III E, Eqs. 105-123):
``I y'' + J y' + K y = 0`` (Eq. 42 = Eq. 105 per group), their modes (:func:`jaxtree.modes`,
Eqs. 70-104) and the retained ones (:mod:`.basis`, :class:`Retained`).

The systems follow the basis: one per substructure on its held base in the nominal spin
(:func:`substructure_systems`, with the finite-element appendages as substructures of their own
after the small hinges'), or the whole set A (:func:`hybrid_systems`). :func:`nominal_frames`
gives the bases' motion and ``a_bar`` of the small hinges (Eq. 36d) for them and for the assembly
(:mod:`.assembly`); with the substructures' Taylor terms it is the build's mass part
(:func:`resolved_set`, :func:`mass_part`), which a traced rebuild with new stiffness evaluates
once, when it is traced.

**Which modes.** By default (``basis="substructure"``) each substructure has its own modes, on its
own held base (its base body moving on the nominal motion: cantilever modes, with centrifugal
stiffening and Coriolis coupling when the nominal spins; :func:`.substructure.held_base`,
:func:`substructure_systems`), and the number kept is chosen per substructure, a group of
repeated frequencies kept whole. ``basis="set"`` takes the modes of the whole set A with the large
variables held (Eq. 42 for A, :func:`jaxtree.linearize`), the seed's single-appendage reading.
With all modes retained both are Eq. (30) in other coordinates (exactly, to round-off); truncation
removes the modes left out.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..equations.dynamics import configuration, mass_matrix
from ..equations.kinematics import cross, mv
from ..linear.linearize import linearize
from ..linear.modes import modes as _modes
from ..numerics import build_jit, is_traced
from ..vehicle.model import Model
from . import substructure as _sub
from .arguments import SmallSet, resolve_damping, small_set
from .basis import base_loads, retained_like, retained_modes
from .model import HybridModel


@build_jit
def nominal_frames(model: Model, g_nom, w_nom, bases: tuple, small: tuple, carriers: tuple = (), added=None):
    """The nominal vehicle at angles `g_nom` spinning at `w_nom` about its mass center, large and
    prescribed hinges held: each base's spatial velocity ``(p, 6)`` in its frame about its mass
    center (:func:`.precomputed._large_frame`'s convention), and ``a_bar`` of the small hinges
    (Eq. 36d, the small rows and columns of Eq. 1's matrix), in one compilation for the build.

    The vehicle's mass center includes the finite-element appendages fixed to the bodies
    `carriers`: `added` ``(mass (a,), first moment (a, 3))``, each about its body's mass center in
    the body's frame (the rigid appendage, modes at rest)."""
    cfg = configuration(model, g_nom)
    b = np.asarray(bases, np.int64)
    r = cfg.rho[b] - cfg.rho[0]  # the bases' mass centers from b_0's, {b^0}
    E = jnp.swapaxes(cfg.R[b], -1, -2)  # {b^0} -> the base's frame
    center = jnp.zeros(3, cfg.rho.dtype)  # the vehicle's mass center from the tree's, {b^0}
    if carriers:
        assert added is not None, "carriers come with their masses and first moments"
        c = np.asarray(carriers, np.int64)
        mass, first = added
        moment = jnp.sum(mass[:, None] * cfg.rho[c] + mv(cfg.R[c], first), 0)
        center = moment / (jnp.sum(model.mass.astype(mass.dtype)) + jnp.sum(mass))
    u0 = cross(center - cfg.rho[0], w_nom)  # b_0's mass center in the spin about the vehicle's
    vb = jnp.concatenate([mv(E, w_nom), mv(E, u0 + cross(w_nom, r))], -1)
    S = np.asarray(small, np.int64) + 2
    return vb, mass_matrix(model, g_nom)[np.ix_(S, S)], cfg.R[b]


def resolved_set(model: Model, S, groups, apps, w_nom, g_nom, with_terms: bool) -> SmallSet:
    """:func:`.arguments.small_set` with the nominal frames (:func:`nominal_frames`): the build's
    mass part, which depends on the vehicle's mass properties, geometry and nominal motion and not
    on its stiffness, damping or loads (:func:`mass_part`)."""

    def part(m):
        setup = small_set(m, S, groups, apps, w_nom, g_nom, with_terms)
        ra = setup.appendages
        carriers = tuple(r.body for r in ra)
        added = (jnp.stack([r.mass for r in ra]), jnp.stack([r.first_moment for r in ra])) if ra else None
        return setup.terms, nominal_frames(m, g_nom, w_nom, setup.bases, tuple(S), carriers, added)

    tms, frames = mass_part(part, model, (w_nom, g_nom, apps))
    return small_set(model, S, groups, apps, w_nom, g_nom, False)._replace(terms=tms, frames=frames)


def mass_part(fn, model: Model, others):
    """``fn(model)``, a function of the vehicle's mass properties, geometry and the arrays
    `others` only (not of its stiffness, damping, loads or initial state).

    In a build traced through those alone (a campaign member rebuilt with its own stiffness from a
    concrete nominal vehicle: ``hybrid_model(member, ..., like=nominal)`` inside ``jit``) its
    inputs are known: it is evaluated now, by the compiled programs of the concrete reference
    build (the traced leaves stood in by zeros of their shapes: the same programs), and enters the
    caller's program as values behind an optimization barrier, so that XLA neither recomputes it
    in every call (232 Mflop for flex95's six wings) nor folds the operations on it at compile
    time. Otherwise, and in a concrete build, ``fn(model)``."""
    fixed = (
        model.mass,
        model.inertia,
        model.axis,
        model.hinge_on_parent,
        model.hinge_on_body,
        model.prescription,
        model.law,
        model.controller,
        model.orbit,
        others,
    )
    if not is_traced(model) or is_traced(fixed):
        return fn(model)
    with jax.ensure_compile_time_eval():
        stand_in = jax.tree_util.tree_map(lambda x: jax.lax.full_like(x, 0) if is_traced(x) else x, model)
        out = fn(stand_in)
    return jax.lax.optimization_barrier(out)


def substructure_systems(setup: SmallSet) -> list:
    """Eq. (42) of each substructure on its held base in the nominal spin about the system mass
    center: ``(rows in A, I, J, K, coordinate names)`` per substructure, then per finite-element
    appendage (its rows after the small hinges', its modal stiffness and damping)."""
    model, S, groups, tms, apps = setup.model, setup.small, setup.groups, setup.terms, setup.appendages
    assert tms is not None, "computed for the substructure basis"
    vb = setup.frames[0]
    # numpy for a concrete model; jnp where a parameter is traced (a differentiable build)
    xp = jnp if is_traced((model, tms, vb, apps)) else np
    vb = xp.asarray(vb)
    sprung = np.zeros(model.n)
    sprung[np.asarray(model.sprung, np.int64) - 1] = 1.0
    stiffness, damping = xp.asarray(model.stiffness) * sprung, xp.asarray(model.damping) * sprung
    systems = []
    for grp, tm, vg in zip(groups, tms, vb):
        h = np.asarray(grp.hinges, np.int64) - 1
        # steady spin: no spatial acceleration of the base
        I, J, K = _sub.held_base(tm, vg, xp.zeros(6), stiffness[h], damping[h], xp=xp)
        rows = tuple(S.index(k) for k in grp.hinges)
        systems.append((rows, I, J, K, tuple(model.names[k] for k in grp.hinges)))
    for ra in apps:
        ap = ra.appendage
        I, J, K = _sub.held_base(
            ra.terms, vb[ra.system], xp.zeros(6), xp.asarray(ap.stiffness), xp.asarray(ap.modal_damping), xp=xp
        )
        systems.append((tuple(ra.rows), I, J, K, tuple(f"{ra.label}.q{j + 1}" for j in range(ra.n_modes))))
    return systems


def hybrid_systems(setup: SmallSet, basis: str, *, omega0, gamma, dcm) -> list:
    """The systems ``(rows in A, I, J, K, coordinate names)`` whose modes are taken: one per
    substructure and appendage (:func:`substructure_systems`), or with ``basis="set"`` the whole
    set A with the large variables held at the nominal motion ``(omega0, gamma, dcm)`` (Eq. 42
    for A, :func:`jaxtree.linearize`)."""
    if basis == "set":
        lin = linearize(setup.model, setup.small, omega0=omega0, gamma=gamma, dcm=dcm)
        xp = jnp if is_traced(lin) else np
        return [
            (tuple(range(len(setup.small))), xp.asarray(lin.I), xp.asarray(lin.J), xp.asarray(lin.K), lin.coordinates)
        ]
    return substructure_systems(setup)


def system_modes(systems, like: HybridModel | None, rtol) -> list:
    """The modes (:func:`jaxtree.modes`) of each system ``(rows, I, J, K, labels)``; in a traced
    build (a differentiable one, with a reference build `like`) of the kind of `like`'s modes."""
    if not is_traced(systems):
        return [_modes(I, J, K, labels=lab, rtol=rtol) for (_, I, J, K, lab) in systems]
    assert like is not None, "checked by hybrid_model"
    lam_ref = np.asarray(like.truncation.lam_parts) if like.truncation is not None else np.zeros((0, 2))
    if like.kind == "general" and np.any(np.abs(lam_ref[:, 1]) <= 1e-9 * np.abs(lam_ref).max(initial=1.0)):
        raise ValueError(
            "hybrid_model: a traced build of general (damped) modes needs every mode underdamped (complex "
            "pairs); the reference build has an overdamped mode (a pair of real eigenvalues)"
        )
    return [_modes(I, J, K, kind=like.kind, rtol=rtol) for (_, I, J, K, _lab) in systems]


class Retained(NamedTuple):
    """The retained modes: `blocks` ``(rows, sigma, indices, modes, I, K)`` of the systems that
    keep some and `picked` ``(system, indices)`` of each (:func:`.basis.retained_modes`), the
    global order of a reference build's modes, ``(_, block, local index)``
    (:func:`.basis.retained_like`; None: ascending frequency), and the modal damping ratios
    `zeta` in the global order; `reference`: the reference build's `positions` (their signs are
    kept, :func:`.basis.modal_matrices`), None without one."""

    blocks: list
    picked: list
    order: list | None
    zeta: np.ndarray
    reference: Any = None


def retained(setup: SmallSet, systems, mds, like, *, n_modes, cutoff, form, basis, tol, damping) -> Retained:
    """The retained modes of the systems and their modal damping: those of `like`, or chosen by
    `n_modes`, `cutoff` (``"auto"``: by the quasi-static share of the base loads, `tol`)."""
    model, S, groups, g_nom = setup.model, setup.small, setup.groups, setup.g_nom
    order = None
    if like is not None:
        blocks, picked, order = retained_like(like, systems, mds)
    else:
        loads = None
        if isinstance(n_modes, str):  # "auto"
            tms = setup.terms if setup.terms is not None else [_sub.terms(model, g, g_nom) for g in groups]
            loads = base_loads(model, S, groups, tms + [ra.terms for ra in setup.appendages], g_nom, basis)
        blocks, picked = retained_modes(model, groups, systems, mds, n_modes, cutoff, form, basis, loads, float(tol))
    kinds = [md.kind for md in mds]
    zeta = resolve_damping(
        damping,
        sum(len(b[1]) for b in blocks),
        kinds[0] if len(set(kinds)) == 1 else "general" if "general" in kinds else kinds[0],
    )
    return Retained(blocks, picked, order, zeta, None if like is None else like.positions)
