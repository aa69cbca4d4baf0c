"""The arguments of :func:`~.assembly.hybrid_model` (Likins 1972, Sec. III E, Eqs. 105-123),
checked and resolved: the set A and its substructures (:func:`.substructure.substructures`), the
finite-element appendages (:func:`appendage_args`; resolved once into :class:`ResolvedAppendage`),
the basis and whether to precompute (:func:`basis_and_precompute`), the form of the equations
(Eq. 118 or 121), the modal damping (Sec. III E), the nominal motion and a reference build `like`.

What they resolve to travels as one record, :class:`SmallSet`: the vehicle, the set A, its
substructures and their Taylor terms (:func:`.substructure.terms`), the appendages, the nominal
motion.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..equations.attitude import attitude_argument
from ..errors import SceneError, SceneTypeError, short
from ..linear.linearize import linearize_args
from ..linear.modes import ModalError, check_modal_damping, tolerance
from ..numerics import is_traced
from ..values import as_float, as_int
from ..vehicle.model import Model
from . import substructure as _sub
from .model import HybridModel, appendage_body


class ResolvedAppendage(NamedTuple):
    """A finite-element appendage of :func:`~.assembly.hybrid_model`, resolved once
    (:func:`resolve_appendages`): the body it is fixed to, its rigid invariants about that body's
    mass center (the rigid appendage, modes at rest), and its place among the small coordinates
    (after the small hinges') and among the systems whose modes are taken (after the hinge
    substructures')."""

    appendage: Any  # the jaxtree.Appendage (duck-typed, see appendage_args)
    body: int  # the body it is fixed to (appendage_body)
    mass: Any  # its mass
    first_moment: Any  # its first moment about the body's mass center, in the body's frame
    rows: range  # its modal coordinates among the small coordinates
    system: int  # its system (a substructure of its own)
    label: str  # "<body>.appendage<i>": the prefix of its coordinates' names

    @property
    def n_modes(self) -> int:
        return self.appendage.n_modes

    @property
    def terms(self):
        """Its Taylor terms (:class:`~.substructure.Terms`) in its body's frame."""
        return self.appendage.terms


class SmallSet(NamedTuple):
    """The set A of :func:`~.assembly.hybrid_model` resolved: the vehicle, its small hinges, their
    substructures and Taylor terms, the finite-element appendages and the nominal motion."""

    model: Model
    small: tuple[int, ...]  # the small hinges, ascending (S)
    groups: tuple  # their substructures (substructure.Substructure)
    terms: list | None  # each substructure's Taylor terms; None where neither basis nor precomputation needs them
    appendages: tuple[ResolvedAppendage, ...]
    w_nom: Any  # omega0 of the nominal motion
    g_nom: Any  # the hinge angles of the nominal motion
    frames: Any = None  # :func:`.systems.nominal_frames`: the bases' velocities, a_bar, the bases' frames

    @property
    def bases(self) -> tuple[int, ...]:
        """The base body of each substructure, then the body of each appendage."""
        return tuple(g.base for g in self.groups) + tuple(ra.body for ra in self.appendages)


def small_set(model: Model, S, groups, apps, w_nom, g_nom, with_terms: bool) -> SmallSet:
    """The :class:`SmallSet` of the checked arguments: the substructures' Taylor terms at the
    nominal angles when `with_terms`, the appendages `apps` resolved."""
    tms = [_sub.terms(model, g, g_nom) for g in groups] if with_terms else None
    return SmallSet(model, tuple(S), tuple(groups), tms, resolve_appendages(model, S, groups, apps), w_nom, g_nom)


def appendage_args(model, appendages, name: str = "hybrid_model") -> tuple:
    """`appendages` of :func:`~.assembly.hybrid_model` (or of the function `name`) as a tuple,
    each fixed to a body of `model`; or the error that a scene's declared appendages were not
    passed."""
    if appendages is None and getattr(model, "appendages", ()):
        raise SceneError(
            f"{name}: the scene declares finite-element appendages "
            f"({', '.join(a.name for a in model.appendages)}); pass appendages=jaxtree.scene_appendages(model) "
            "to include them, or appendages=() to leave them out"
        )
    # (duck-typed: the appendage package builds on this one, not the other way round)
    apps = tuple(appendages or ())
    for i, ap in enumerate(apps):
        if not all(hasattr(ap, a) for a in ("terms", "frequencies", "modal_damping", "body", "mass")):
            raise SceneTypeError(f"{name}: appendages[{i}] must be a jaxtree.Appendage, got {type(ap).__name__}")
        b = ap.body
        if isinstance(b, str):
            if b not in model.names:
                raise SceneError(f"{name}: appendages[{i}] is fixed to {b!r}, which is not a body: {model.names}")
        elif not (isinstance(b, (int, np.integer)) and 0 <= int(b) <= model.n):
            raise SceneError(f"{name}: appendages[{i}] is fixed to body {short(b)}, not in 0..{model.n}")
    return apps


def resolve_appendages(model: Model, S, groups, apps) -> tuple[ResolvedAppendage, ...]:
    """The appendages `apps` (checked by :func:`appendage_args`) of the set `S` of substructures
    `groups`: each one's body, rigid invariants, small coordinates after the hinges' and system
    after the substructures'."""
    out, o = [], len(S)
    for i, ap in enumerate(apps):
        body, k = appendage_body(model, ap), ap.n_modes
        first = ap.first_moment + ap.mass * ap.point
        label = f"{model.names[body]}.appendage{i}"
        out.append(ResolvedAppendage(ap, body, ap.mass, first, range(o, o + k), len(groups) + i, label))
        o += k
    return tuple(out)


def nominal_motion(model, omega0, gamma, dcm):
    dtype = jnp.result_type(model.mass)
    # numpy defaults: an eager jnp.zeros compiles a program on a build's first call
    w = np.zeros(3, dtype) if omega0 is None else omega0
    g = np.zeros(model.n, dtype) if gamma is None else gamma
    C = np.eye(3, dtype=dtype) if dcm is None else dcm
    # a known value stays known inside a trace (a traced build's mass part, systems.mass_part)
    with jax.ensure_compile_time_eval():
        return tuple(x.astype(dtype) if is_traced(x) else jnp.asarray(np.asarray(x, dtype)) for x in (w, g, C))


def hybrid_model_args(
    model,
    small,
    n_modes=None,
    *,
    cutoff=None,
    omega0=None,
    gamma=None,
    dcm=None,
    damping=None,
    form=None,
    precompute=None,
    attitude: object = "quaternion",
    rtol=1e-9,
    basis=None,
    tol=1e-2,
    extra: int = 0,
):
    """Arguments of :func:`jaxtree.hybrid_model`, checked before the linearization is traced
    (`extra`: the appendages' modal coordinates, small coordinates beside the hinges)."""
    name = "hybrid_model"
    linearize_args(name, model, small, omega0=omega0, gamma=gamma, dcm=dcm)
    if getattr(model, "law", None) is not None or getattr(model, "controller", None) is not None:
        raise SceneError(
            f"{name}: the model carries hinge control laws (model.law / model.controller, from its scene's "
            "'control'), which the hybrid equations do not include; drop them with model.with_control(None, None)"
        )
    if basis is not None and basis not in ("substructure", "set"):
        raise SceneError(f"{name}: basis must be 'substructure', 'set' or None, got {short(basis)}")
    t = float(as_float(tol, f"{name}: tol", ()))
    if not t > 0.0:
        raise SceneError(f"{name}: tol must be positive (the neglected share of the quasi-static response), got {t}")
    if isinstance(n_modes, str):
        if n_modes != "auto":
            raise SceneError(
                f"{name}: n_modes must be an integer, a sequence of integers, 'auto' or None, got {short(n_modes)}"
            )
    elif n_modes is not None:
        if isinstance(n_modes, (list, tuple)):  # one number per substructure
            if not n_modes:
                raise SceneError(f"{name}: n_modes is an empty sequence")
            for i, m in enumerate(n_modes):
                as_int(m, f"{name}: n_modes[{i}]", minimum=1)
        else:
            as_int(n_modes, f"{name}: n_modes", minimum=1)
    if cutoff is not None:
        c = float(as_float(cutoff, f"{name}: cutoff", ()))
        if c < 0:
            raise SceneError(f"{name}: cutoff must be >= 0 (a frequency in rad/s), got {c}")
    if damping is not None:
        z = as_float(damping, f"{name}: damping")
        nu = extra + (
            0 if small is None else len((small,) if isinstance(small, (str, int, np.integer)) else list(small))
        )
        # at most one mode per small hinge is retained (the exact number is known after the modes)
        if z.ndim > 1 or (z.ndim == 1 and z.shape[0] != 1 and z.shape[0] > nu):
            raise SceneError(
                f"{name}: damping must be a scalar or one ratio per retained mode (at most {nu}), got shape {z.shape}"
            )
        if np.any(z < 0):
            raise SceneError(f"{name}: modal damping ratios must be >= 0, got {z.tolist()}")
    if form is not None and form not in ("real", "first_order"):
        raise SceneError(f"{name}: form must be 'real', 'first_order' or None, got {short(form)}")
    if precompute is not None and not isinstance(precompute, (bool, np.bool_)):
        raise SceneTypeError(f"{name}: precompute must be True, False or None, got {short(precompute)}")
    attitude_argument(name, attitude)
    tolerance(name, rtol)


def resolve_options(model: Model, S, groups, apps, like, nominal, *, basis, precompute, form) -> tuple[str, bool, Any]:
    """The basis, whether to precompute, and the form asked for (None: chosen from the modes),
    from `like` when given, checked against the set A, its substructures `groups` and the
    appendages `apps`; a traced model or nominal motion ``(omega0, gamma, dcm)`` needs `like`."""
    if like is not None:
        check_like(like, S, groups, apps)
        basis, precompute, form = like.basis, like.precomputed, like.form
    elif is_traced((model, *nominal)):
        raise ValueError(
            "hybrid_model: the model or the nominal motion is traced (jax.grad, jvp, vmap): pass "
            "like=<hybrid_model of the same vehicle built from concrete values> to fix the retained modes"
        )
    basis, precompute = basis_and_precompute(model, S, groups, basis, precompute)
    if apps and (basis != "substructure" or not precompute):
        raise SceneError(
            "hybrid_model: finite-element appendages need basis='substructure' and the precomputed terms "
            "(every substructure terminal, no external load on a small body)"
        )
    if form not in (None, "real", "first_order"):
        raise ValueError(f"hybrid_model: form must be 'real' or 'first_order', got {form!r}")
    return basis, precompute, form


def resolve_damping(damping, k, kind):
    """The modal damping ratios ``zeta`` of the `k` retained modes (in their global order)."""
    if damping is not None and np.ndim(damping) and np.shape(damping) != (k,):
        raise ValueError(
            f"hybrid_model: damping has {np.size(damping)} ratios for {k} retained modes "
            "(give a scalar or one per retained mode)"
        )
    zeta = np.zeros(k) if damping is None else np.broadcast_to(np.asarray(damping, float), (k,)).copy()
    if damping is not None:
        check_modal_damping(zeta, kind, "hybrid_model", "Sec. III E", "the modes of this set A already have")
    return zeta


def resolve_form(form: str | None, kinds: list) -> str:
    """The form of the equations: `form`, or by default real when every system's modes are real."""
    if form is None:
        return "real" if all(kd == "real" for kd in kinds) else "first_order"
    if form == "real" and any(kd != "real" for kd in kinds):
        bad = next(kd for kd in kinds if kd != "real")
        raise ModalError(
            f"hybrid_model: form='real' needs real modes (J = 0, K symmetric); the modes of the set A "
            f"are {bad!r}. Use form='first_order' (Eq. 118)."
        )
    return form


def check_like(like, S, groups, apps=()) -> None:
    """`like` of :func:`~.assembly.hybrid_model` describes the same set A, substructures and
    appendages."""
    if not isinstance(like, HybridModel):
        raise TypeError(f"hybrid_model: like must be a HybridModel, got {type(like).__name__}")
    if [a.n_modes for a in like.appendages] != [a.n_modes for a in apps]:
        raise ValueError("hybrid_model: like was built with other appendages (their number or modes differ)")
    if tuple(like.small) != tuple(S) or tuple(like.groups) != tuple(groups):
        raise ValueError(
            f"hybrid_model: like was built for the small hinges {like.small}, not {tuple(S)} (or other substructures)"
        )


def basis_and_precompute(model: Model, S, groups, basis: str | None, precompute: bool | None) -> tuple[str, bool]:
    """The modal basis and whether to precompute the substructure terms (defaults and checks)."""
    terminal = all(g.terminal for g in groups)
    small_bodies = set(S)
    loads_small = model.loads is not None and any(int(b) in small_bodies for b in model.loads.bodies)
    if basis is None:
        basis = "substructure" if terminal else "set"
    if basis not in ("substructure", "set"):
        raise ValueError(f"hybrid_model: basis must be 'substructure' or 'set', got {basis!r}")
    if basis == "substructure" and not terminal:
        raise ValueError(
            "hybrid_model: basis='substructure' needs every substructure terminal (no large or "
            "prescribed hinge outboard of a small one); use basis='set'"
        )
    possible = terminal and not loads_small
    if precompute is None:
        precompute = possible
    if precompute and not possible:
        raise ValueError(
            "hybrid_model: precompute=True needs every substructure terminal (no large or prescribed "
            "hinge outboard of a small one) and no external load on a small body"
            + ("; the loads act on small bodies" if loads_small else "")
        )
    return basis, precompute
