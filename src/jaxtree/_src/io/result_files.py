"""Result files: NetCDF files of the datasets of :mod:`.results`, written atomically and read
back; a long run's result written in parts.

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

import json
import os
import pathlib
import shutil
import sys
import tempfile
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from ..atomic import atomic_write
from ..equations.attitude import get_attitude
from ..integration.failures import KINDS
from ..integration.problem import Problem
from ..integration.solution import Solution
from ..linear.modes import Modes
from ..scene.files import scene_from_dict
from ..vehicle.model import Model, State
from .results import (
    ENGINE,
    RESULT_FORMAT,
    clean_attrs,
    solution_to_dataset,
    xarray_module,
)

if TYPE_CHECKING:
    import xarray  # annotations only: xarray is imported when a result is written or read (xarray_module)


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
        ds.attrs.update(clean_attrs(attrs or {}))
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
        ds.attrs.update(clean_attrs(attrs or {}))
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
