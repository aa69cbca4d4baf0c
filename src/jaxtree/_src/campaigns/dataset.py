"""A campaign's chunk as an ``xarray.Dataset``: the members' histories, per-run figures and the
dispersed parameters, with their dimensions, units and names."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..vehicle.model import Model
from .members import FAILURES, result_names

_LEAF_DIMS = {
    "mass": ("body",),
    "inertia": ("body", "axis", "axis_j"),
    "axis": ("hinge", "axis"),
    "hinge_on_parent": ("hinge", "axis"),
    "hinge_on_body": ("hinge", "axis"),
    "stiffness": ("hinge",),
    "damping": ("hinge",),
    "initial.dcm": ("axis", "axis_j"),
    "initial.omega0": ("axis",),
    "initial.gamma": ("hinge",),
    "initial.gamma_dot": ("hinge",),
}
_HISTORY_DIMS = {
    "omega0": ("time", "axis"),
    "gamma": ("time", "hinge"),
    "gamma_dot": ("time", "hinge"),
    "attitude": ("time", "quaternion"),
    "energy": ("time",),
    "angular_momentum": ("time", "axis"),
    "hold_torque": ("time", "prescribed"),
}
_ATTRS = {
    "omega0": ("rad/s", "angular velocity of b_0 in {b^0} components"),
    "gamma": ("rad", "hinge angles"),
    "gamma_dot": ("rad/s", "hinge rates"),
    "attitude": ("", "Euler parameters (q0 >= 0) of C, {b^0} = C {i} (Def. 9)"),
    "energy": ("J", "kinetic energy about the system mass center plus hinge-spring energy"),
    "angular_momentum": ("N m s", "angular momentum about the system mass center, inertial components"),
    "hold_torque": ("N m", "torque holding each prescribed hinge (Sec. II B)"),
    "status": ("", "diffrax's result of the run, named"),
    "failure": ("", "jaxtree's diagnosis of a failed run ('' when it reached t1)"),
    "steps": ("", "solver steps (accepted and rejected)"),
    "rejected": ("", "rejected solver steps"),
    "rhs_evaluations": ("", "evaluations of Eq. (1)"),
    "t_final": ("s", "where the run ended (t1, or the time of a failure)"),
}


def _leaf_name(path) -> str:
    parts = []
    for p in path:
        name = getattr(p, "name", None) or getattr(p, "key", None)
        parts.append(str(name if name is not None else getattr(p, "idx", p)))
    return ".".join(parts)


def dispersed(models, n) -> dict[str, np.ndarray]:
    """The array leaves of the batch of models that differ between runs, by dotted name."""
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(models):
        if not eqx.is_array(leaf) or not jnp.issubdtype(leaf.dtype, jnp.number):
            continue
        x = np.asarray(leaf)
        if x.shape[:1] == (n,) and n > 1 and np.any(x != x[:1]):
            out[_leaf_name(path)] = x
    return out


def chunk_dataset(out: dict, runs: np.ndarray, params: dict, ts, model: Model):
    """An xarray Dataset of one chunk's outputs (runs `runs`)."""
    import xarray as xr

    names = result_names()
    data = {}
    for k, dims in _HISTORY_DIMS.items():
        if k in out:
            data[k] = (("run",) + dims, out[k])
    data["status"] = (
        ("run",),
        np.asarray([names[int(i)] if i >= 0 else "not_started" for i in out["result"]], dtype="U32"),
    )
    data["failure"] = (("run",), np.asarray([FAILURES[int(i)] for i in out["diagnosis"]], dtype="U32"))
    for k in ("steps", "rejected", "rhs_evaluations"):
        data[k] = (("run",), np.asarray(out[k], np.int64))
    data["t_final"] = (("run",), np.asarray(out["t_final"], float))
    for name, x in params.items():
        dims = _LEAF_DIMS.get(name, tuple(f"{name}_{i}" for i in range(x.ndim - 1)))
        data[f"param.{name}"] = (("run",) + dims, x)
    coords = {
        "run": runs,
        "time": np.asarray(ts, float),
        "hinge": np.arange(1, model.n + 1),
        "axis": np.arange(1, 4),
        "quaternion": np.arange(4),
        "body": np.arange(model.n + 1),
    }
    if model.prescribed:
        coords["prescribed"] = np.asarray(model.prescribed)
    ds = xr.Dataset(data, coords=coords)
    for k, (unit, text) in _ATTRS.items():
        if k in ds:
            ds[k].attrs.update(units=unit, long_name=text)
    return ds
