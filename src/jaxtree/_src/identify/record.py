"""A record of sensor readings from a file: a CSV of sensor columns, or a jaxtree result file
whose histories the named sensors read (:func:`load_record`); and the residual plot of a fit
(:func:`plot_residuals`).

CSV: a header line, then one row per sample. A column ``time`` (or ``t``; seconds) and one
column per sensor component: ``hub.omega[0]``, ``hub.omega[1]``, ``hub.omega[2]``,
``wingp_1.angle``, ``hub.attitude[0]`` ... ``hub.attitude[3]`` (Euler parameters, scalar first)
or ``hub.attitude[i,j]`` (direction cosines). A unit in parentheses after a name is allowed
(``wingp_1.angle (rad)``); an empty cell or ``nan`` is a missing sample.
"""

from __future__ import annotations

import csv
import pathlib
import re

import numpy as np

from ..errors import SceneError
from ..vehicle.model import Model
from . import sensors as sen

_COLUMN = re.compile(r"^\s*(?P<name>[^\[\]()]+?)\s*(?:\[(?P<index>[0-9, ]+)\])?\s*(?:\(.*\))?\s*$")


def _read_csv(path: pathlib.Path) -> tuple[np.ndarray, dict]:
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    if len(rows) < 3:
        raise SceneError(f"{path}: a record needs a header line and at least two samples")
    header, body = rows[0], rows[1:]
    try:
        table = np.array([[float(x) if x.strip() else np.nan for x in row] for row in body], dtype=float)
    except ValueError as e:
        raise SceneError(f"{path}: not a number in the record ({e})") from None
    if table.ndim != 2 or table.shape[1] != len(header):
        raise SceneError(f"{path}: every row needs {len(header)} cells, one per column of the header")
    columns: dict[str, dict[tuple[int, ...], np.ndarray]] = {}
    times = None
    for j, title in enumerate(header):
        m = _COLUMN.match(title)
        if m is None:
            raise SceneError(f"{path}: column {j + 1} {title!r} is neither 'time' nor a sensor such as 'hub.omega[0]'")
        name = m.group("name")
        if name in ("time", "t"):
            times = table[:, j]
            continue
        index = tuple(int(i) for i in m.group("index").split(",")) if m.group("index") else ()
        columns.setdefault(name, {})[index] = table[:, j]
    if times is None:
        raise SceneError(f"{path}: no 'time' column")
    out = {}
    for name, parts in columns.items():
        keys = sorted(parts)
        if keys == [()]:
            out[name] = parts[()]
            continue
        shape = tuple(max(k[d] for k in keys) + 1 for d in range(len(keys[0])))
        if len(keys) != int(np.prod(shape)) or any(len(k) != len(shape) for k in keys):
            raise SceneError(f"{path}: sensor {name!r} has columns {keys}: every component needed, one column each")
        a = np.empty((len(times), *shape))
        for k, col in parts.items():
            a[(slice(None), *k)] = col
        out[name] = a
    return times, out


def load_record(path, model: Model, sensors=None) -> tuple[np.ndarray, dict]:
    """``(times, measurements)`` from a record file: a CSV of sensor columns (module docstring),
    or a result file of ``jaxtree simulate`` (``.nc``), which the named `sensors` read (what they
    would have measured, without noise; attitudes as direction cosines)."""
    path = pathlib.Path(path)
    if not path.exists():
        raise SceneError(f"{path}: no such record file")
    if path.suffix.lower() == ".csv":
        times, data = _read_csv(path)
        if sensors is not None:
            missing = [s for s in sensors if s not in data]
            if missing:
                raise SceneError(f"{path}: no column of sensor {missing[0]!r}; the record has {', '.join(data)}")
            data = {s: data[s] for s in sensors}
        return times, data
    from ..io.result_files import load_result

    try:
        sol = load_result(path)
    except (ValueError, OSError) as e:
        raise SceneError(f"{path}: neither a CSV record nor a jaxtree result file ({e})") from None
    if not hasattr(sol, "omega0"):
        raise SceneError(f"{path}: a modes result; a record is a simulation result or a CSV")
    if not sensors:
        raise SceneError(f"{path}: a result file: name the sensors it should read (their sigma)")
    resolved = tuple(
        sen.resolve(model, s, (1, *{"omega": (3,), "attitude": (3, 3)}.get(s.rpartition(".")[2], ())), False)
        for s in sensors
    )
    reads = sen.read(model, resolved, sol)
    return np.asarray(sol.ts), {k: np.asarray(v) for k, v in reads.items()}


def save_record_csv(path, times, measurements: dict) -> None:
    """Write `measurements` (dict sensor -> (T, ...)) at `times` as a CSV record (atomically)."""
    from ..atomic import atomic_write

    header, columns = ["time"], [np.asarray(times, float)]
    for name, a in measurements.items():
        a = np.asarray(a, float)
        if a.ndim == 1:
            header.append(name)
            columns.append(a)
            continue
        for idx in np.ndindex(*a.shape[1:]):
            header.append(f"{name}[{','.join(map(str, idx))}]")
            columns.append(a[(slice(None), *idx)])
    with atomic_write(path, "w") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in np.stack(columns, -1):
            w.writerow([repr(float(x)) for x in row])


def plot_residuals(fit, times, path=None, member: int = 0):
    """One panel per sensor: the residuals at the solution, in units of sigma, against time (a
    batch: member `member`), with the +-1 and +-3 sigma bands. Returns the matplotlib Figure and,
    given `path`, writes it as a PNG atomically."""
    import io

    from matplotlib.figure import Figure

    from ..atomic import atomic_write

    names = list(fit.residuals)
    fig = Figure(figsize=(8.0, 1.9 * len(names) + 0.6), layout="constrained")
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    t = np.asarray(times)
    for ax, name in zip(axes, names):
        r = np.asarray(fit.residuals[name])
        r = r[member] if fit.members else r
        r = r.reshape(len(t), -1)
        for c in range(r.shape[1]):
            label = f"[{c}]" if r.shape[1] > 1 else None
            ax.plot(t, r[:, c], ".", ms=2.5, label=label)
        for k, style in ((1, ":"), (3, "--")):
            ax.axhline(k, color="0.5", ls=style, lw=0.8)
            ax.axhline(-k, color="0.5", ls=style, lw=0.8)
        rms = float(np.sqrt(np.nanmean(r**2)))
        ax.set_ylabel("residual / sigma")
        ax.set_title(f"{name}: rms {rms:.2f} sigma", fontsize=9)
        if r.shape[1] > 1:
            ax.legend(loc="upper right", fontsize=7, ncols=r.shape[1])
    axes[-1].set_xlabel("time (s)")
    state = "converged" if np.all(fit.converged) else "not converged"
    chi2, dof = np.asarray(fit.chi2).reshape(-1)[member], np.asarray(fit.dof).reshape(-1)[member]
    fig.suptitle(f"identify: residuals at the solution ({state}; chi2/dof {float(chi2) / max(int(dof), 1):.3f})")
    if path is not None:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=120)
        with atomic_write(path) as fh:
            fh.write(buf.getvalue())
    return fig
