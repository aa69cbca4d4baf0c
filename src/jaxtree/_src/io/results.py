"""Result datasets: a simulation's or a modal analysis's numbers as an :class:`xarray.Dataset`
with named dimensions, units and provenance (the files they go to: :mod:`.result_files`).

A simulation result holds the time histories on the dimensions ``time``, ``hinge`` (1..n),
``body`` (0..n) and ``axis`` (1..3): hinge angles and rates, omega0, the direction cosines C of
Def. 9, the attitude variables that were integrated, the energy and angular momentum, the hold
torques of prescribed hinges, and the mass centers and hinge points of every body (from the
system mass center, {b0} components). Every variable has ``units`` and ``long_name``; the
attributes record the scene (its ``jaxtree-scene/1`` JSON), the solver, the tolerances, the
steps, the result code, where the run ended, the jaxtree/jax/diffrax/numpy/xarray versions and
the date. A modes result holds the frequencies, damping ratios, labels and shapes of
:func:`jaxtree.modes` with the matrices of Eq. (70).

xarray is imported when a dataset is made, not by ``import jaxtree``.
"""

from __future__ import annotations

import datetime
import json
import platform
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from .. import VERSION
from ..equations.dynamics import configuration
from ..integration.failures import failure_kind
from ..numerics import program_jit
from ..scene.files import scene_to_dict
from ..vehicle.model import Model

if TYPE_CHECKING:
    pass  # annotations only: xarray is imported when a result is written or read (xarray_module)

RESULT_FORMAT = "jaxtree-result/1"
ENGINE = "h5netcdf"


def xarray_module():
    try:
        import xarray as xr
    except ImportError as e:  # pragma: no cover - a declared dependency
        raise ImportError("jaxtree result files need xarray and h5netcdf (pip install xarray h5netcdf)") from e
    return xr


def versions() -> dict[str, str]:
    """Versions of jaxtree and the libraries that made a result, and the date (UTC)."""
    import diffrax
    import equinox

    out = {
        "jaxtree_version": VERSION,
        "jax_version": jax.__version__,
        "diffrax_version": diffrax.__version__,
        "equinox_version": equinox.__version__,
        "numpy_version": np.__version__,
        "python_version": platform.python_version(),
        "jax_backend": jax.default_backend(),
    }
    try:
        out["xarray_version"] = xarray_module().__version__
    except ImportError:  # pragma: no cover
        pass
    out["date"] = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    return out


def scene_json(model: Model) -> str:
    """The model as ``jaxtree-scene/1`` JSON; where its loads or laws are Python functions
    (no JSON form), the vehicle without them, said in its description (the plots and the 3D
    page need only the vehicle); "" for a model that has no JSON form (a prescription given by
    a Python function)."""
    try:
        return json.dumps(scene_to_dict(model))
    except (ValueError, TypeError):
        pass
    bare = eqx.tree_at(
        lambda m: (m.law, m.controller), model.with_loads(None), (None, None), is_leaf=lambda x: x is None
    )
    try:
        note = "the vehicle only: its loads and laws are Python functions, not stored"
        return json.dumps(scene_to_dict(bare, description=note))
    except (ValueError, TypeError):
        return ""


# the options of a chunked run that may be absent (None) or "auto": netCDF attributes hold neither,
# so the file stores an absent value as -1 and "auto" as -2 (all of them are >= 0 when given)
_ABSENT, _AUTO = -1, -2
_OPTIONAL = ("n_modes", "cutoff", "modal_damping")


def run_attrs(model: Model, config: dict) -> dict:
    """The attributes that a chunked run's result file stores for its configuration
    (:func:`jaxtree._src.campaigns.chunked_config.chunked_config`): the scene's text
    (:func:`scene_json`) and the options in a form netCDF keeps (no None, no mixed types)."""
    out = {"scene": scene_json(model), **config}
    for key in _OPTIONAL:
        if key in out:
            value = out[key]
            out[key] = _ABSENT if value is None else _AUTO if value == "auto" else value
    return out


def _attr(value):
    """A value NetCDF can hold as an attribute (no None, no bool, no nested lists)."""
    if isinstance(value, (bool, np.bool_)):
        return int(value)
    if isinstance(value, (list, tuple)):
        return np.asarray(value)
    if isinstance(value, (jax.Array, np.ndarray, np.generic)):
        a = np.asarray(value)
        return a.item() if a.ndim == 0 else a
    return value


def clean_attrs(attrs: dict) -> dict:
    return {k: _attr(v) for k, v in attrs.items() if v is not None}


# ----------------------------------------------------------------------------- geometry
@program_jit
def _positions(model, gamma):
    cfg = jax.vmap(lambda g: configuration(model, g))(gamma)
    return cfg.rho, cfg.hinge


def body_positions(model: Model, gamma):
    """Mass centers (T, n+1, 3) and hinge points (T, n, 3) from the system mass center, {b0}
    components, at the hinge angles `gamma` (T, n) (:func:`jaxtree.configuration`)."""
    rho, hinge = _positions(model, jnp.asarray(gamma, jnp.result_type(model.mass)))
    return np.asarray(rho), np.asarray(hinge)


# ----------------------------------------------------------------------------- datasets
def _var(dims, data, units, long_name, **extra):
    return (dims, np.asarray(data), {"units": units, "long_name": long_name, **extra})


def _base_coords(model: Model, T_times):
    n = model.n
    return {
        "time": ("time", np.asarray(T_times, float), {"units": "s", "long_name": "time", "axis": "T"}),
        "hinge": ("hinge", np.arange(1, n + 1), {"long_name": "hinge index k (joins body k to its parent)"}),
        "body": ("body", np.arange(n + 1), {"long_name": "body index (0: the reference body b0)"}),
        "axis": ("axis", np.arange(1, 4), {"long_name": "vector component"}),
        "hinge_name": (
            "hinge",
            np.asarray(model.names[1:], dtype=object),
            {"long_name": "name of the body outboard of the hinge"},
        ),
        "body_name": ("body", np.asarray(model.names, dtype=object), {"long_name": "body name"}),
    }


# the optional histories of a simulation dataset: name, dimensions, units, long name
_HISTORIES = (
    ("energy", ("time",), "J", "kinetic energy about the system mass center plus hinge-spring energy"),
    (
        "angular_momentum",
        ("time", "axis"),
        "kg m2 s-1",
        "angular momentum about the system mass center, inertial components",
    ),
    ("attitude", ("time", "attitude_variable"), "1", "integrated attitude variables of b0"),
    (
        "hold_torque",
        ("time", "prescribed_hinge"),
        "N m",
        "torque holding each prescribed hinge on its prescription (Sec. II B)",
    ),
    ("orthogonality", ("time",), "1", "max |C C^T - U| (drift of Eq. 3)"),
    ("modal", ("time", "modal_coordinate"), "1", "modal coordinates of the hybrid equations (Eqs. 111-112)"),
)


def _state_variables(model: Model, gamma, gamma_dot, omega0, dcm) -> dict:
    """The state's histories and the model's mass properties and axes, as dataset variables."""
    return {
        "gamma": _var(("time", "hinge"), gamma, "rad", "hinge angle gamma_k (Def. 21)"),
        "gamma_dot": _var(("time", "hinge"), gamma_dot, "rad s-1", "hinge rate d(gamma_k)/dt"),
        "omega0": _var(
            ("time", "axis"), omega0, "rad s-1", "inertial angular velocity of the reference body b0, {b0} components"
        ),
        "dcm": _var(
            ("time", "row", "column"),
            dcm,
            "1",
            "direction cosines C of Def. 9, {b0} = C {i} (row: b0 axis, column: inertial axis)",
        ),
        "body_mass": _var(("body",), np.asarray(model.mass, float), "kg", "body mass"),
        "body_inertia": _var(
            ("body", "axis", "axis_2"),
            np.asarray(model.inertia, float),
            "kg m2",
            "inertia about the body's mass center, body components",
        ),
        "hinge_axis": _var(
            ("hinge", "axis"),
            np.asarray(model.axis, float),
            "1",
            "unit hinge axis g^k, in the parent's frame at gamma = 0",
        ),
    }


def _history_variables(histories: dict, pick, attitude_name) -> dict:
    """The optional histories that were given (None: left out), as dataset variables."""
    v = {}
    for name, dims, units, long_name in _HISTORIES:
        if histories[name] is None:
            continue
        if name == "attitude":
            v[name] = _var(
                dims, pick(histories[name]), units, f"{long_name} ({attitude_name})", attitude_name=attitude_name or ""
            )
        else:
            v[name] = _var(dims, pick(histories[name]), units, long_name)
    return v


def _add_appendage_outputs(v: dict, coords: dict, displacement, names, site) -> None:
    """The appendages' output-node displacements, their names and (with `site`) the bodies and
    undeformed places of the nodes, added to the variables `v` and the coordinates `coords`."""
    v["appendage_displacement"] = _var(
        ("time", "appendage_output", "dof"),
        displacement,
        "m or rad",
        "displacement of a finite-element appendage's output node (translations x, y, z, then small rotations), "
        "its body's frame",
    )
    coords["appendage_output"] = (
        "appendage_output",
        np.asarray(list(names or ()), dtype=object),
        {"long_name": "appendage name and output node"},
    )
    if site is not None:
        coords["appendage_output_body"] = (
            "appendage_output",
            np.asarray(site["body"], np.int64),
            {"long_name": "index of the body the appendage is fixed to"},
        )
        v["appendage_output_position"] = _var(
            ("appendage_output", "axis"),
            np.asarray(site["position"], float),
            "m",
            "undeformed place of the output node from its body's mass center, the body's frame",
        )


def simulation_dataset(
    model: Model,
    ts,
    gamma,
    gamma_dot,
    omega0,
    dcm,
    *,
    energy=None,
    angular_momentum=None,
    attitude=None,
    attitude_name: str | None = None,
    hold_torque=None,
    orthogonality=None,
    modal=None,
    appendage_output=None,
    appendage_output_name=None,
    appendage_output_site=None,
    positions: bool | tuple[ArrayLike, ArrayLike] = True,
    attrs: dict | None = None,
):
    """The :class:`xarray.Dataset` of a simulation's histories (see the module docstring).

    `ts` (T,); `gamma`, `gamma_dot` (T, n); `omega0` (T, 3); `dcm` (T, 3, 3); optional `energy`
    (T,), `angular_momentum` (T, 3), `attitude` (T, size) with its `attitude_name`,
    `hold_torque` (T, len(model.prescribed)), `orthogonality` (T,), `modal` (T, m) hybrid modal
    coordinates, `appendage_output` (T, P, 6) (the variable ``appendage_displacement`` over the
    dimension ``appendage_output``) the displacements (translations, small rotations; the
    body's frame) of the finite-element appendages' output nodes, named by `appendage_output_name`
    (P,: ``"appendage:node"``), at `appendage_output_site` ``{"body": (P,), "position": (P, 3)}``:
    the body each is fixed to and its undeformed place from that body's mass center (body's
    frame), for the 3D viewer; `positions` adds the mass centers and hinge points of every body
    (:func:`body_positions`, or given as that function's pair of arrays); `attrs`
    are stored as global attributes (with the format, the scene JSON and :func:`versions`).
    """
    xr = xarray_module()
    ts = np.asarray(ts, float)
    keep = np.isfinite(ts)
    pick = lambda x: None if x is None else np.asarray(x)[keep]
    ts = ts[keep]
    gamma, gamma_dot, omega0, dcm = (pick(x) for x in (gamma, gamma_dot, omega0, dcm))
    coords = _base_coords(model, ts)
    v = _state_variables(model, gamma, gamma_dot, omega0, dcm)
    histories = dict(
        energy=energy,
        angular_momentum=angular_momentum,
        attitude=attitude,
        hold_torque=hold_torque if hold_torque is not None and np.shape(hold_torque)[-1] > 0 else None,
        orthogonality=orthogonality,
        modal=modal,
    )
    v.update(_history_variables(histories, pick, attitude_name))
    if appendage_output is not None and np.shape(appendage_output)[1] > 0:
        site = appendage_output_site
        _add_appendage_outputs(v, coords, pick(appendage_output), appendage_output_name, site)
    if histories["hold_torque"] is not None:
        coords["prescribed_hinge"] = (
            "prescribed_hinge",
            np.asarray(model.prescribed),
            {"long_name": "index of a kinematically prescribed hinge"},
        )
    if positions is not False and len(ts):
        if isinstance(positions, tuple):
            rho, hinge = (np.asarray(x)[keep] for x in positions)
        else:
            rho, hinge = body_positions(model, gamma)
        v["body_position"] = _var(
            ("time", "body", "axis"), rho, "m", "mass center of each body from the system mass center, {b0} components"
        )
        v["hinge_position"] = _var(
            ("time", "hinge", "axis"), hinge, "m", "hinge point h_k from the system mass center, {b0} components"
        )
    base = {
        "format": RESULT_FORMAT,
        "kind": "simulation",
        "scene_name": model.name,
        "scene": scene_json(model),
        "n_hinges": model.n,
        **versions(),
    }
    ds = xr.Dataset(v, coords=coords, attrs=clean_attrs({**base, **(attrs or {})}))
    return ds


def solution_attrs(sol) -> dict:
    """Attributes of a :class:`jaxtree.Solution`: attitude, result, where it ended, steps, drift."""
    # the step counts, and the solver's record (a SolverChoice: which solver ran and why)
    st = {k: int(np.asarray(x)) for k, x in sol.stats.items() if isinstance(x, (jax.Array, np.ndarray, int))}
    kind = failure_kind(sol.failure)
    choice = sol.stats.get("solver")
    extra = {} if choice is None else {"solver": choice.name, "solver_choice": str(choice)}
    return {
        **extra,
        "attitude": sol.problem.attitude.name,
        "result": "ok" if kind is None else kind,
        "result_code": int(np.asarray(sol.failure)),
        "t_final": float(np.asarray(sol.t_final)),
        "steps_accepted": st.get("num_accepted_steps"),
        "steps_rejected": st.get("num_rejected_steps"),
        "rhs_evaluations": st.get("rhs_evaluations"),
    }


def solution_to_dataset(sol, attrs: dict | None = None):
    """The dataset of a :class:`jaxtree.Solution` (:func:`simulation_dataset` of its fields)."""
    model = sol.problem.model
    return simulation_dataset(
        model,
        sol.ts,
        sol.gamma,
        sol.gamma_dot,
        sol.omega0,
        sol.dcm,
        energy=sol.energy,
        angular_momentum=sol.angular_momentum,
        attitude=sol.attitude,
        attitude_name=sol.problem.attitude.name,
        hold_torque=sol.hold_torque,
        orthogonality=sol.orthogonality,
        attrs={**solution_attrs(sol), **(attrs or {})},
    )


def modes_dataset(model: Model, md, *, small=(), omega0=None, gamma=None, attrs: dict | None = None, hinges=None):
    """The dataset of a modal analysis (:class:`jaxtree.Modes` of the hinges `small` of `model`,
    linearized about the spin `omega0` and the angles `gamma`; `hinges`: the hinge index of each
    coordinate when they are not the hinges `small` alone, as :attr:`jaxtree.LinearSystem.hinges`
    gives them: 0 for an attitude angle, -1 for a finite-element appendage's modal coordinate).

    Dimensions: ``mode`` (nu, ascending frequency), ``coordinate`` (the small hinges), ``hinge``
    (all n), ``state``/``state_mode``/``state_2`` (2 nu, the first-order form of Eq. 70).
    ``hinge_shape`` (hinge, mode) is each mode's shape on all hinges, zero off the small set,
    real (complex shapes turned so that their largest entry is real and positive).
    """
    xr = xarray_module()
    n, nu = model.n, md.nu
    small = tuple(int(k) for k in small)
    shapes = np.asarray(md.shapes)
    big = np.argmax(np.abs(shapes), axis=0)
    phase = shapes[big, np.arange(nu)]
    turned = shapes * (np.abs(phase) / np.where(phase == 0, 1.0, phase))[None, :]
    codes = np.asarray(hinges if hinges is not None else (small if small else [0] * nu), np.int64)
    full = np.zeros((n, nu))
    rows = np.nonzero(codes > 0)[0]
    full[codes[rows] - 1] = np.real(turned[rows])
    w = np.zeros(3) if omega0 is None else np.asarray(omega0, float)
    g = np.zeros(n) if gamma is None else np.asarray(gamma, float)
    c = lambda x: np.asarray(x, np.complex128)
    coords = {
        "mode": ("mode", np.arange(1, nu + 1), {"long_name": "mode number (ascending frequency)"}),
        "coordinate": ("coordinate", np.arange(1, nu + 1), {"long_name": "small coordinate"}),
        "coordinate_name": (
            "coordinate",
            np.asarray(md.coordinates or [f"y{i + 1}" for i in range(nu)], dtype=object),
            {"long_name": "name of the small coordinate"},
        ),
        "coordinate_hinge": (
            "coordinate",
            codes,
            {"long_name": "hinge index of the small coordinate (-1: a finite-element appendage's modal coordinate)"},
        ),
        "hinge": ("hinge", np.arange(1, n + 1), {"long_name": "hinge index k"}),
        "hinge_name": ("hinge", np.asarray(model.names[1:], dtype=object), {"long_name": "name of the body outboard"}),
        "mode_label": (
            "mode",
            np.asarray(md.labels or [""] * nu, dtype=object),
            {"long_name": "coordinates that dominate the mode"},
        ),
    }
    v = {
        "frequency": _var(("mode",), np.asarray(md.frequencies), "rad s-1", "modal frequency sigma_j"),
        "frequency_hz": _var(("mode",), np.asarray(md.frequencies) / (2 * np.pi), "Hz", "modal frequency"),
        "damping_ratio": _var(("mode",), np.asarray(md.damping_ratios), "1", "modal damping ratio zeta_j (Eq. 104)"),
        "rigid": _var(("mode",), np.asarray(md.rigid).astype(np.int8), "1", "1 for a zero-frequency mode"),
        "eigenvalue_real": _var(("state_mode",), c(md.eigenvalues).real, "s-1", "real part of lambda_j"),
        "eigenvalue_imag": _var(("state_mode",), c(md.eigenvalues).imag, "rad s-1", "imaginary part of lambda_j"),
        "shape_real": _var(("coordinate", "mode"), c(md.shapes).real, "rad", "mode shape phi^j (real part)"),
        "shape_imag": _var(("coordinate", "mode"), c(md.shapes).imag, "rad", "mode shape phi^j (imaginary part)"),
        "hinge_shape": _var(("hinge", "mode"), full, "rad", "mode shape on all hinges (zero off the small set)"),
        "participation": _var(
            ("coordinate", "mode"), np.asarray(md.participation), "1", "share of each coordinate in each mode"
        ),
        "right_real": _var(("state", "state_mode"), c(md.right).real, "1", "right eigenvectors Phi (real part)"),
        "right_imag": _var(("state", "state_mode"), c(md.right).imag, "1", "right eigenvectors Phi (imaginary part)"),
        "left_real": _var(("state", "state_mode"), c(md.left).real, "1", "left eigenvectors Phi' (real part)"),
        "left_imag": _var(("state", "state_mode"), c(md.left).imag, "1", "left eigenvectors Phi' (imaginary part)"),
        "P": _var(("state", "state_2"), np.asarray(md.P), "1", "P of Eq. (70)"),
        "Q": _var(("state", "state_2"), np.asarray(md.Q), "1", "Q of Eq. (70)"),
        "B": _var(("state", "state_2"), np.asarray(md.B), "s-1", "state matrix of the (damped) first-order system"),
        "gamma_nominal": _var(("hinge",), g, "rad", "hinge angles of the nominal motion"),
        "omega0_nominal": _var(("axis",), w, "rad s-1", "nominal spin of b0, {b0} components"),
    }
    coords["axis"] = ("axis", np.arange(1, 4), {"long_name": "vector component"})
    base = {
        "format": RESULT_FORMAT,
        "kind": "modes",
        "modes_kind": md.kind,
        "scene_name": model.name,
        "scene": scene_json(model),
        "n_hinges": n,
        "small_hinges": np.asarray(small, dtype=np.int64),
        **versions(),
    }
    return xr.Dataset(v, coords=coords, attrs=clean_attrs({**base, **(attrs or {})}))
