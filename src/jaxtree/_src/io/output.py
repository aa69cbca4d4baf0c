"""Result files and summaries of simulations: time histories as ``.npz`` and ``.csv``, a plot
(matplotlib, optional) and a text summary. Every file is written atomically (a temporary file
in the same folder, then a rename), so a crash never leaves a half-written result.
"""

from __future__ import annotations

import functools
import io
from typing import Any, cast

import jax
import numpy as np

from ..atomic import atomic_write as atomic_write
from ..integration.solution import Solution
from .drift import change_text, drift_causes
from .history_plots import plot_histories


def histories(sol: Solution) -> dict[str, np.ndarray]:
    """The saved rows of a solution as numpy arrays (rows after an early stop are dropped)."""
    ts = np.asarray(sol.ts)
    keep = np.isfinite(ts)
    out = {
        "t": ts,
        "gamma": sol.gamma,
        "gamma_dot": sol.gamma_dot,
        "omega0": sol.omega0,
        "dcm": sol.dcm,
        "attitude": sol.attitude,
        "energy": sol.energy,
        "angular_momentum": sol.angular_momentum,
        "hold_torque": sol.hold_torque,
        "orthogonality": sol.orthogonality,
    }
    if sol.X is not None:
        out.update(X=sol.X, X_dot=sol.X_dot)
    return {k: np.asarray(v)[keep] for k, v in out.items()}


def save_npz(path, runs: dict[str, Solution]) -> None:
    """One ``.npz`` with the histories of several runs, keys ``"<run>/<field>"``."""
    arrays = {f"{name}/{k}": v for name, sol in runs.items() for k, v in histories(sol).items()}
    buf = io.BytesIO()
    # cast: pyright matches the unpacked arrays against savez_compressed's keyword allow_pickle; the
    # keys are "<run>/<field>", never that keyword
    np.savez_compressed(buf, **cast(dict[str, Any], arrays))
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())


# units of the attitude variables (Eq. 3: Euler angles; Eqs. 23-24: quaternion, direction cosines)
_ATTITUDE_UNITS = {"euler123": "rad", "quaternion": "1", "dcm": "1"}


def save_csv(path, sol: Solution) -> None:
    """One row per saved time: t, gamma_k, gamma_dot_k, omega0_i, C_ij, attitude variables,
    energy, H_i, hold torques. One header line, each column as ``name [unit]``; hinges, axes and
    attitude variables numbered from 1 as in the seed (``gamma_1`` is hinge 1)."""
    h = histories(sol)
    n = h["gamma"].shape[1]
    cols, names = [h["t"][:, None]], ["t [s]"]
    for key, unit in (("gamma", "rad"), ("gamma_dot", "rad/s")):
        cols.append(h[key])
        names += [f"{key}_{k} [{unit}]" for k in range(1, n + 1)]
    cols.append(h["omega0"])
    names += [f"omega0_{i} [rad/s]" for i in (1, 2, 3)]
    cols.append(h["dcm"].reshape(-1, 9))
    names += [f"C_{i}{j} [1]" for i in range(1, 4) for j in range(1, 4)]
    cols.append(h["attitude"])
    att = sol.problem.attitude.name
    names += [f"{att}_{i} [{_ATTITUDE_UNITS.get(att, '1')}]" for i in range(1, h["attitude"].shape[1] + 1)]
    cols.append(h["energy"][:, None])
    names.append("energy [J]")
    cols.append(h["angular_momentum"])
    names += [f"H_{i} [N m s]" for i in (1, 2, 3)]
    cols.append(h["hold_torque"])
    names += [f"hold_torque_{k} [N m]" for k in sol.problem.model.prescribed]
    table = np.concatenate(cols, 1)
    buf = io.StringIO()
    np.savetxt(buf, table, delimiter=",", header=",".join(names), comments="", fmt="%.17g")
    with atomic_write(path, "w") as fh:
        fh.write(buf.getvalue())


def save_plot(path, runs: dict[str, Solution], title: str = "") -> bool:
    """The histories of several runs of one vehicle in one PNG (:func:`jaxtree.plot_histories`
    with its drift panels): hinges by role, one colour per quantity and one line style per run.

    Returns False (and writes nothing) when matplotlib is not installed.
    """
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return False
    plot_histories(runs, path, title=title or None, drift=True)
    return True


def warm_writers(*, netcdf: bool = True, plot: bool = True) -> None:
    """Pay the first-use costs of the result writers once: the imports (xarray, h5netcdf and h5py,
    and whatever xarray loads on its first Dataset, dask where it is installed; matplotlib with its
    Agg backend and 3-d projection) and the first figure's fonts and mathtext parser. 2-4 s of
    Python on this machine that a run can spend while XLA integrates: the main job and `jaxtree
    simulate` call this on a thread beside their integration (XLA releases Python's lock) and wait
    for it before they write. Nothing is left behind (a NetCDF file in a temporary folder,
    removed; a figure drawn into memory)."""
    if netcdf:
        import os
        import tempfile

        from .result_files import write_netcdf
        from .results import xarray_module

        xr = xarray_module()
        ds = xr.Dataset({"x": ("t", np.zeros(2))}, coords={"t": np.arange(2.0)}, attrs={"warm": "up"})
        with tempfile.TemporaryDirectory(prefix="jaxtree-warm-") as folder:
            write_netcdf(ds, os.path.join(folder, "warm.nc"))
    if plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            return
        from .figures import DPI, new_figure, plot_style

        with plot_style():
            fig = new_figure(figsize=(3, 2), layout="constrained")
            ax = fig.add_subplot(1, 2, 1)
            ax.plot([0.0, 1.0], [0.0, 1.0], label="$\\omega^0_1$")
            ax.set_title("$\\dot\\gamma_k$ (rad/s)")
            ax.set_yscale("log")
            ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0))
            fig.suptitle("warm")
        fig.savefig(io.BytesIO(), format="png", dpi=DPI)


def _causes(why: list[str]) -> str:
    return f" (not conserved: {', '.join(why)})" if why else ""


def summary(
    name: str,
    sol: Solution,
    wall: float | None = None,
    first: float | None = None,
    estimate: dict | None = None,
) -> str:
    """A few lines: final state (with units), energy and momentum drift (absolute, and relative
    where the initial value is not near zero), steps, the integration error estimate (`estimate`:
    ``{"gamma", "rates", "dcm"}``, differences from a run at 10x the tolerances) and times."""
    st = {k: int(np.asarray(v)) for k, v in sol.stats.items() if isinstance(v, (jax.Array, np.ndarray, int))}
    f = sol.final
    fmt = functools.partial(np.array2string, precision=6, suppress_small=True, max_line_width=150)
    lines = [
        f"[{name}] t_final = {float(sol.t_final):.6g} s, result: {'ok' if sol.ok else 'FAILED'}",
        f"  gamma     = {fmt(np.asarray(f.gamma))} rad",
        f"  gamma_dot = {fmt(np.asarray(f.gamma_dot))} rad/s",
        f"  omega0    = {fmt(np.asarray(f.omega0))} rad/s (in {{b0}})",
        f"  C         = {fmt(np.asarray(f.dcm).ravel())} (row-major)",
        f"  energy: E0 = {float(sol.energy[0]):.9g} J, {change_text(sol.energy, float(sol.energy[0]), 'J')}"
        + _causes(drift_causes(sol.problem.model)[0]),
        f"  angular momentum: |H0| = {float(np.linalg.norm(np.asarray(sol.angular_momentum[0]))):.9g} N m s, "
        f"{change_text(sol.angular_momentum, np.asarray(sol.angular_momentum[0], float), 'N m s')}"
        + _causes(drift_causes(sol.problem.model)[1]),
        f"  steps: {st['num_accepted_steps']} accepted, {st['num_rejected_steps']} rejected, "
        f"{st['rhs_evaluations']} right-hand sides",
    ]
    if estimate is not None:
        lines.append(
            f"  integration error estimate (difference from a run at 10x the tolerances): angles "
            f"{estimate['gamma']:.2e} rad, rates {estimate['rates']:.2e} rad/s, C {estimate['dcm']:.2e}"
        )
    if first is not None or wall is not None:
        parts = []
        if first is not None:
            prepare = "" if wall is None else f": programs traced, compiled or loaded {max(first - wall, 0.0):.2f} s"
            parts.append(f"first call {first:.2f} s{prepare}")
        if wall is not None:
            parts.append(f"run {wall:.3f} s")
        lines.append("  wall time: " + ", ".join(parts))
    return "\n".join(lines)
