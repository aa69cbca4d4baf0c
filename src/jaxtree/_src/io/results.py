"""Result files: NetCDF (through xarray) with named dimensions, units and provenance.

A simulation result holds the time histories on the dimensions ``time``, ``hinge`` (1..n),
``body`` (0..n) and ``axis`` (1..3): hinge angles and rates, omega0, the direction cosines C of
Def. 9, the attitude variables that were integrated, the energy and angular momentum, the hold
torques of prescribed hinges, and the mass centers and hinge points of every body (from the
system mass center, {b0} components). Every variable has ``units`` and ``long_name``; the
attributes record the scene (its ``jaxtree-scene/1`` JSON), the solver, the tolerances, the
steps, the result code, where the run ended, the jaxtree/jax/diffrax/numpy/xarray versions and
the date. A modes result holds the frequencies, damping ratios, labels and shapes of
:func:`jaxtree.modes` with the matrices of Eq. (70).

Every file is written atomically: into a temporary file beside the target, flushed to disk,
then renamed over it, so a reader never sees half a file. :func:`load_result` gives a file
back as an :class:`xarray.Dataset`, a :class:`jaxtree.Solution` (simulations) or a
:class:`jaxtree.Modes` (modal analyses).

Long runs are written in *parts* (:class:`ChunkedResult`): ``RESULT.parts/part-00003.npz``, one
per chunk of the integration, each atomic and holding the exact state where its chunk ended;
:meth:`ChunkedResult.merge` joins them into ``RESULT`` at the end. Until then
:func:`load_result` of ``RESULT`` reads the parts written so far (a run that was interrupted or
killed is readable up to its last part). The run that writes them, and continues from the last
part after an interruption (``jaxtree simulate --resume``), is :mod:`jaxtree._src.campaigns.chunked`.

xarray and a NetCDF-4 backend (h5netcdf) are imported when a result is written or read, not by
``import jaxtree``.
"""

from __future__ import annotations

import datetime
import json
import os
import pathlib
import platform
import shutil
import sys
import tempfile
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike

from .. import VERSION
from ..equations.attitude import get_attitude
from ..equations.dynamics import configuration
from ..integration.failures import KINDS, failure_kind
from ..integration.problem import Problem
from ..integration.solution import Solution
from ..linear.modes import Modes
from ..numerics import program_jit
from ..scene.scene import scene_from_dict, scene_to_dict
from ..vehicle.model import Model, State
from .files import atomic_write

if TYPE_CHECKING:
    import xarray  # annotations only: xarray is imported when a result is written or read (xarray_module)

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
    (:func:`jaxtree._src.campaigns.chunked.chunked_config`): the scene's text
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


def _clean_attrs(attrs: dict) -> dict:
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
    v = {
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
    histories = dict(
        energy=energy,
        angular_momentum=angular_momentum,
        attitude=attitude,
        hold_torque=hold_torque if hold_torque is not None and np.shape(hold_torque)[-1] > 0 else None,
        orthogonality=orthogonality,
        modal=modal,
    )
    for name, dims, units, long_name in _HISTORIES:
        if histories[name] is None:
            continue
        if name == "attitude":
            v[name] = _var(
                dims, pick(attitude), units, f"{long_name} ({attitude_name})", attitude_name=attitude_name or ""
            )
        else:
            v[name] = _var(dims, pick(histories[name]), units, long_name)
    if appendage_output is not None and np.shape(appendage_output)[1] > 0:
        v["appendage_displacement"] = _var(
            ("time", "appendage_output", "dof"),
            pick(appendage_output),
            "m or rad",
            "displacement of a finite-element appendage's output node (translations x, y, z, then small rotations), "
            "its body's frame",
        )
        coords["appendage_output"] = (
            "appendage_output",
            np.asarray(list(appendage_output_name or ()), dtype=object),
            {"long_name": "appendage name and output node"},
        )
        if appendage_output_site is not None:
            bodies, places = appendage_output_site["body"], appendage_output_site["position"]
            coords["appendage_output_body"] = (
                "appendage_output",
                np.asarray(bodies, np.int64),
                {"long_name": "index of the body the appendage is fixed to"},
            )
            v["appendage_output_position"] = _var(
                ("appendage_output", "axis"),
                np.asarray(places, float),
                "m",
                "undeformed place of the output node from its body's mass center, the body's frame",
            )
    if histories["hold_torque"] is not None:
        coords["prescribed_hinge"] = (
            "prescribed_hinge",
            np.asarray(model.prescribed),
            {"long_name": "index of a kinematically prescribed hinge"},
        )
    if isinstance(positions, tuple):
        rho, hinge = (np.asarray(x)[keep] for x in positions)
    elif positions and len(ts):
        rho, hinge = body_positions(model, gamma)
    if positions is not False and len(ts):
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
    ds = xr.Dataset(v, coords=coords, attrs=_clean_attrs({**base, **(attrs or {})}))
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
    return xr.Dataset(v, coords=coords, attrs=_clean_attrs({**base, **(attrs or {})}))


# ----------------------------------------------------------------------------- writing
def write_netcdf(ds, path) -> pathlib.Path:
    """Write `ds` to `path` atomically: a temporary file beside it, flushed, then renamed."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        ds.to_netcdf(tmp, engine=ENGINE, invalid_netcdf=False)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


def save_result(path, result, attrs: dict | None = None) -> pathlib.Path:
    """Write a :class:`jaxtree.Solution` (or an :class:`xarray.Dataset` made here) to a NetCDF
    file, atomically. `attrs` are added to the global attributes."""
    if isinstance(result, Solution):
        ds = solution_to_dataset(result, attrs)
    elif hasattr(result, "to_netcdf"):
        ds = result.copy()
        ds.attrs.update(_clean_attrs(attrs or {}))
    else:
        raise TypeError(f"save_result: expected a jaxtree.Solution or an xarray.Dataset, got {type(result).__name__}")
    return write_netcdf(ds, path)


# ----------------------------------------------------------------------------- chunks
class ChunkedResult:
    """A result written in numbered parts as a run goes, merged at the end.

    Parts live in ``<path>.parts/part-NNNNN.npz`` (:func:`write_part_file`); each holds the rows of one chunk of the
    integration (the first chunk includes t0) and, as ``resume_*`` variables, the exact state
    where the chunk ended. :meth:`merge` concatenates them into `path` (atomically) and, for a
    complete run, removes the parts.
    """

    def __init__(self, path):
        self.path = pathlib.Path(path)
        self.parts_dir = self.path.with_name(self.path.name + ".parts")

    def parts(self) -> list[pathlib.Path]:
        if not self.parts_dir.is_dir():
            return []
        # .npz: parts written here; .nc: parts of a run interrupted under jaxtree <= 0.1.0
        return sorted([*self.parts_dir.glob("part-*.npz"), *self.parts_dir.glob("part-*.nc")], key=lambda q: q.stem)

    def clear(self):
        if self.parts_dir.exists():
            shutil.rmtree(self.parts_dir)

    def write_part(self, index: int, ds) -> pathlib.Path:
        return write_part_file(ds, self.parts_dir / f"part-{index:05d}.npz")

    def load_parts(self) -> list[xarray.Dataset]:
        return [read_part_file(p) for p in self.parts()]

    def last_part(self):
        parts = self.parts()
        if not parts:
            return None
        return read_part_file(parts[-1])

    def merged(
        self, complete: bool = False, attrs: dict | None = None, parts: Iterable[xarray.Dataset] | None = None
    ) -> xarray.Dataset | None:
        """The parts joined along ``time`` (resume variables dropped), or None without parts.
        `parts`: the part datasets when the caller holds them (default: read from disk)."""
        xr = xarray_module()
        parts = self.load_parts() if parts is None else list(parts)
        if not parts:
            return None
        parts = [p.drop_vars([k for k in p.data_vars if str(k).startswith("resume_")]) for p in parts]
        ds = xr.concat(
            parts,
            dim="time",
            data_vars="minimal",
            coords="minimal",
            compat="override",
            join="outer",
            combine_attrs="override",
        )
        last = parts[-1].attrs
        ds.attrs = dict(parts[0].attrs)
        for key in ("steps_accepted", "steps_rejected", "rhs_evaluations"):
            vals = [p.attrs.get(key) for p in parts]
            known = [v for v in vals if v is not None]
            if len(known) == len(vals):
                ds.attrs[key] = int(sum(int(v) for v in known))
        for key in ("result", "result_code", "t_final"):
            if key in last:
                ds.attrs[key] = last[key]
        for key in ("chunk", "chunk_t0", "chunk_t1"):
            ds.attrs.pop(key, None)
        ds.attrs["parts"] = len(parts)
        ds.attrs["complete"] = int(complete)
        ds.attrs.update(_clean_attrs(attrs or {}))
        if "energy" in ds:
            e = ds["energy"].values
            ds.attrs["energy_drift"] = float(np.nanmax(np.abs(e - e[0])) / abs(e[0])) if len(e) and e[0] else 0.0
        if "angular_momentum" in ds:
            H = ds["angular_momentum"].values
            h0 = np.linalg.norm(H[0]) if len(H) else 0.0
            ds.attrs["momentum_drift"] = float(np.nanmax(np.linalg.norm(H - H[0], axis=1)) / h0) if h0 else 0.0
        return ds

    def merge(self, complete: bool = True, attrs: dict | None = None, parts=None):
        """Write the merged parts to `path` (atomically); remove the parts when `complete`."""
        ds = self.merged(complete, attrs, parts)
        if ds is None:
            return None
        write_netcdf(ds, self.path)
        if complete:
            self.clear()
        return ds


# A part is the run's own intermediate file, read back only by jaxtree (a resumed run, the
# merge, load_result of a run not merged yet): numpy's .npz of the dataset's arrays and a JSON
# header with their dimensions and attributes, ~10 ms to write where NetCDF-4 through xarray and
# h5netcdf takes ~0.4 s (h5netcdf looks its dimensions up again for every variable). The arrays
# round-trip bit for bit; no pickles (object arrays are stored as strings).
PART_FORMAT = "jaxtree-part/1"


def _json_attr(value):
    if isinstance(value, np.ndarray):
        return {"__array__": value.tolist(), "dtype": value.dtype.str}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _attr_of_json(value):
    if isinstance(value, dict) and "__array__" in value:
        return np.asarray(value["__array__"], dtype=np.dtype(value["dtype"]))
    return value


def write_part_file(ds, path) -> pathlib.Path:
    """Write the dataset `ds` to `path` (.npz) atomically, flushed to disk before the rename."""
    path = pathlib.Path(path)
    arrays, variables = {}, []
    for i, (name, var) in enumerate([*ds.coords.items(), *ds.data_vars.items()]):
        data = np.asarray(var.values)
        if data.dtype == object:
            data = data.astype(str)
        arrays[f"v{i}"] = data
        variables.append(
            {
                "name": str(name),
                "dims": [str(d) for d in var.dims],
                "coord": name in ds.coords,
                "attrs": {k: _json_attr(v) for k, v in var.attrs.items()},
            }
        )
    header = {"format": PART_FORMAT, "variables": variables, "attrs": {k: _json_attr(v) for k, v in ds.attrs.items()}}
    arrays["header"] = np.asarray(json.dumps(header))
    with atomic_write(path) as fh:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    return path


def read_part_file(path) -> xarray.Dataset:
    """A part as written by :func:`write_part_file` (or, from an older jaxtree, a NetCDF part)."""
    xr = xarray_module()
    path = pathlib.Path(path)
    if path.suffix == ".nc":
        return xr.load_dataset(path, engine=ENGINE, decode_timedelta=False, decode_times=False)
    with np.load(path, allow_pickle=False) as f:
        header = json.loads(str(f["header"]))
        if header.get("format") != PART_FORMAT:
            raise ValueError(f"{path}: not a part of a jaxtree run (format {header.get('format')!r})")
        coords, data_vars = {}, {}
        for i, v in enumerate(header["variables"]):
            entry = (tuple(v["dims"]), f[f"v{i}"], {k: _attr_of_json(a) for k, a in v["attrs"].items()})
            (coords if v["coord"] else data_vars)[v["name"]] = entry
    return xr.Dataset(data_vars, coords=coords, attrs={k: _attr_of_json(a) for k, a in header["attrs"].items()})


# ----------------------------------------------------------------------------- reading
def _open(path):
    xr = xarray_module()
    path = pathlib.Path(path)
    chunked = ChunkedResult(path)
    if path.is_file():
        ds = xr.load_dataset(path, engine=ENGINE, decode_timedelta=False, decode_times=False)
        if int(ds.attrs.get("complete", 1)) or not chunked.parts():
            return ds
    if chunked.parts():
        ds = chunked.merged(complete=False)
        assert ds is not None, "there are parts"
        return ds
    if path.exists():
        raise IsADirectoryError(f"{path}: is a folder, not a result file")
    raise FileNotFoundError(f"no result file {str(path)!r}" + (" (nor parts of an interrupted run)"))


def model_of(ds) -> Model:
    text = ds.attrs.get("scene", "")
    if not text:
        raise ValueError(
            "load_result: this result does not carry its scene (a model with a Python-function "
            "prescription); load it with as_dataset=True"
        )
    return scene_from_dict(json.loads(text))


_NOT_STORED = (
    "control_state",
    "X",
    "X_dot",
    "final_control_state",
    "final_X",
    "final_X_dot",
    "result",
    "event_mask",
    "raw",
)


def to_solution(ds):
    import diffrax as dfx  # noqa: F401  (Solution's field types)

    model = model_of(ds)
    dtype = jnp.result_type(model.mass)
    f = lambda name: jnp.asarray(ds[name].values, dtype)
    T = ds.sizes["time"]
    att_name = str(ds.attrs.get("attitude", "quaternion"))
    att = get_attitude(att_name)
    problem = Problem(model, att, None, None, None, False, 0)
    gamma, gamma_dot, omega0, dcm = f("gamma"), f("gamma_dot"), f("omega0"), f("dcm")
    nan = lambda *shape: jnp.full(shape, jnp.nan, dtype)
    energy = f("energy") if "energy" in ds else nan(T)
    H = f("angular_momentum") if "angular_momentum" in ds else nan(T, 3)
    hold = f("hold_torque") if "hold_torque" in ds else jnp.zeros((T, len(model.prescribed)), dtype)
    attitude = f("attitude") if "attitude" in ds else jax.vmap(att.from_dcm)(dcm)
    ortho = f("orthogonality") if "orthogonality" in ds else jnp.zeros(T, dtype)
    i = T - 1
    final = State(dcm[i], omega0[i], gamma[i], gamma_dot[i])
    result = str(ds.attrs.get("result", "ok"))
    failure = 0 if result in ("ok", "") or result not in KINDS else KINDS.index(result) + 1
    stats = {
        "num_accepted_steps": int(ds.attrs.get("steps_accepted", -1)),
        "num_rejected_steps": int(ds.attrs.get("steps_rejected", -1)),
        "num_steps": int(ds.attrs.get("steps_accepted", -1)) + int(ds.attrs.get("steps_rejected", 0)),
        "rhs_evaluations": int(ds.attrs.get("rhs_evaluations", -1)),
    }
    stats = {k: jnp.asarray(v) for k, v in stats.items()}
    return Solution(
        ts=jnp.asarray(ds["time"].values, dtype),
        gamma=gamma,
        gamma_dot=gamma_dot,
        omega0=omega0,
        dcm=dcm,
        attitude=attitude,
        hold_torque=hold,
        energy=energy,
        angular_momentum=H,
        orthogonality=ortho,
        t_final=jnp.asarray(ds.attrs.get("t_final", ds["time"].values[i]), dtype),
        final=final,
        singular=jnp.asarray(False),
        margin=jnp.asarray(jnp.nan, dtype),
        failure=jnp.asarray(failure),
        stats=stats,
        problem=problem,
        # what a file does not hold: the controller's states, the translation, the raw solution
        **dict.fromkeys(_NOT_STORED),
    )


def _to_modes(ds):
    c = lambda a, b: jnp.asarray(ds[a].values + 1j * ds[b].values)
    kind = str(ds.attrs.get("modes_kind", "real"))
    shapes = c("shape_real", "shape_imag")
    if kind == "real":
        shapes = shapes.real
    labels = tuple(str(s) for s in ds["mode_label"].values)
    return Modes(
        eigenvalues=c("eigenvalue_real", "eigenvalue_imag"),
        frequencies=jnp.asarray(ds["frequency"].values),
        damping_ratios=jnp.asarray(ds["damping_ratio"].values),
        shapes=shapes,
        right=c("right_real", "right_imag"),
        left=c("left_real", "left_imag"),
        P=jnp.asarray(ds["P"].values),
        Q=jnp.asarray(ds["Q"].values),
        B=jnp.asarray(ds["B"].values),
        rigid=jnp.asarray(ds["rigid"].values.astype(bool)),
        participation=jnp.asarray(ds["participation"].values),
        kind=kind,
        coordinates=tuple(str(s) for s in ds["coordinate_name"].values),
        labels=labels if any(labels) else (),
    )


def load_result(path, *, as_dataset: bool = False) -> Any:
    """Read a result file written by jaxtree (``jaxtree simulate``, ``jaxtree modes``,
    :func:`save_result`).

    Returns the :class:`xarray.Dataset` with `as_dataset`, else a :class:`jaxtree.Solution`
    for a simulation (the model rebuilt from the scene stored in the file; ``raw`` is None, so
    no dense output; a hybrid run comes back with its physical histories, its modal coordinates
    are in the dataset) or a :class:`jaxtree.Modes` for a modal analysis. A run that was
    interrupted or killed while writing its parts reads back up to its last part (attribute
    ``complete`` 0). Raises ``FileNotFoundError`` for a missing file and ``ValueError`` for a
    file that is not a jaxtree result.
    """
    ds = _open(path)
    if ds.attrs.get("format") != RESULT_FORMAT:
        raise ValueError(
            f"{path}: not a jaxtree result file (format attribute {ds.attrs.get('format')!r}, "
            f"expected {RESULT_FORMAT!r})"
        )
    if as_dataset:
        return ds
    kind = ds.attrs.get("kind")
    if kind == "modes":
        return _to_modes(ds)
    return to_solution(ds)


def command_line() -> str:
    """The command that is running (for the ``command`` attribute of result files)."""
    return " ".join([os.path.basename(sys.argv[0]) or "python"] + sys.argv[1:])
