"""Plots (matplotlib): time histories, energy and momentum drift, mode shapes drawn as the
deformed tree, and work-precision diagrams.

Every function returns the :class:`matplotlib.figure.Figure` and, given a `path`, also writes
it as a PNG atomically (temporary file, then rename). Results are taken as a
:class:`jaxtree.Solution` or as the :class:`xarray.Dataset` of a result file
(:func:`jaxtree.load_result`). matplotlib is an optional dependency (``pip install
jaxtree[plot]``); it is imported when a plot is made.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from ..equations.dynamics import configuration
from ..vehicle.model import Model
from .files import atomic_write
from .results import model_of

# Every PNG written here: at 120 dpi a 9 pt label is 15 px high.
DPI = 120
# Curves in one panel with a legend; beyond it an appendage's hinges become a time-hinge heat map.
LEGEND_MAX = 12
# A relative energy or momentum change beyond this is drawn on a linear axis (work done, energy
# dissipated: its size is the point); below it, |drift| on a log axis (conservation to round-off:
# its order of magnitude is the point).
DRIFT_LINEAR = 1e-6
# One line style per run (one colour per quantity).
STYLES = ("-", "--", ":", "-.")
_RC = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 8,
    "figure.titlesize": 11,
}


def _style():
    """Font sizes that read at :data:`DPI` (matplotlib's rc settings for the figure being made)."""
    import matplotlib

    return matplotlib.rc_context(_RC)


def _figure(**kw):
    """A new figure outside pyplot's state (a plot made here never becomes pyplot's current
    figure, and nothing is left open in pyplot)."""
    try:
        import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3d projection)
        from matplotlib.figure import Figure
    except ImportError as e:
        raise ImportError("plots need matplotlib (pip install 'jaxtree[plot]')") from e
    return Figure(**kw)


def _save(fig, path):
    if path is None:
        return
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())


# the histories a plot reads: its key, and the name in a Solution or a result Dataset
_HISTORIES = dict(
    gamma="gamma", gamma_dot="gamma_dot", omega0="omega0", dcm="dcm", energy="energy", H="angular_momentum"
)


def _series(result) -> dict:
    """Arrays of a Solution or a result Dataset: t, gamma, gamma_dot, omega0, dcm, energy, H, names,
    and the model (None where a result does not carry its scene)."""
    if hasattr(result, "data_vars"):
        ds = result
        get = lambda k: ds[k].values if k in ds else None
        names = [str(s) for s in ds["hinge_name"].values] if "hinge_name" in ds.coords else None
        try:
            model = model_of(ds)
        except (ValueError, KeyError, TypeError):
            model = None
        out: dict[str, Any] = dict(
            t=ds["time"].values,
            **{key: get(name) for key, name in _HISTORIES.items()},
            names=names,
            title=str(ds.attrs.get("scene_name", "")),
            prescribed=tuple(int(k) for k in ds["prescribed_hinge"].values) if "prescribed_hinge" in ds.coords else (),
            model=model,
        )
        out["damped"] = model is not None and bool(np.any(np.asarray(model.damping) != 0))
        return out
    sol = result
    ts = np.asarray(sol.ts)
    keep = np.isfinite(ts)
    a = lambda x: None if x is None else np.asarray(x)[keep]
    model = sol.problem.model
    return dict(
        t=ts[keep],
        **{key: a(getattr(sol, name)) for key, name in _HISTORIES.items()},
        names=list(model.names[1:]),
        title=model.name,
        prescribed=tuple(model.prescribed),
        damped=bool(np.any(np.asarray(model.damping) != 0)),
        model=model,
    )


def _runs(result) -> dict[str, dict]:
    """``{run name: series}`` of one result (a Solution or Dataset) or a mapping of named ones."""
    if isinstance(result, Mapping) and not hasattr(result, "data_vars"):
        if not result:
            raise ValueError("plots: no runs given")
        return {str(k): _series(v) for k, v in result.items()}
    s = _series(result)
    return {s["title"] or "run": s}


class HingeRoles(NamedTuple):
    """Hinges (0-based) by the role they play in a plot: `branch` (angles and rates drawn as
    curves), `rotors` (spinning hinges: their rates), `appendages` (chains of sprung hinges, each
    a tuple from the root outward)."""

    branch: tuple[int, ...]
    rotors: tuple[int, ...]
    appendages: tuple[tuple[int, ...], ...]


def hinge_roles(model: Model | None, gamma=None, n: int | None = None) -> HingeRoles:
    """Classify the hinges of `model` for plotting.

    A hinge whose angle in `gamma` (T, n) travels more than a turn, and is not sprung, is a
    *rotor* (its angle grows without bound; its rate is what one reads). Sprung hinges form
    *appendages*: a sprung hinge whose parent body hangs on a sprung hinge joins that hinge's
    appendage (a panel chain, a boom, a wing). The others (free hinges, gimbals, prescribed
    hinges) are the *branch*. Without a model (a result that does not carry its scene) the
    hinges that are not rotors are the branch, or one appendage when there are more than
    :data:`LEGEND_MAX` of them.
    """
    if model is not None:
        n = model.n
    if n is None:
        raise ValueError("hinge_roles: give a model or the number of hinges")
    travel = (
        np.zeros(n)
        if gamma is None
        else np.nan_to_num(np.nanmax(gamma, axis=0) - np.nanmin(gamma, axis=0))
        if len(gamma)
        else np.zeros(n)
    )
    sprung = set() if model is None else {k - 1 for k in model.sprung}
    rotors = tuple(k for k in range(n) if k not in sprung and travel[k] > 2 * np.pi)
    if model is None:
        rest = tuple(k for k in range(n) if k not in rotors)
        if len(rest) > LEGEND_MAX:
            return HingeRoles((), rotors, (rest,))
        return HingeRoles(rest, rotors, ())
    parents = np.asarray(model.topology.parents)
    group: dict[int, int] = {}
    chains: list[list[int]] = []
    for k in range(n):
        if k not in sprung:
            continue
        p = int(parents[k]) - 1  # the parent body's hinge
        if p in group:
            group[k] = group[p]
            chains[group[p]].append(k)
        else:
            group[k] = len(chains)
            chains.append([k])
    branch = tuple(k for k in range(n) if k not in sprung and k not in rotors)
    return HingeRoles(branch, rotors, tuple(tuple(c) for c in chains))


def _colors(m):
    import matplotlib

    if m <= 10:
        return [f"C{j}" for j in range(m)]
    cmap = matplotlib.colormaps["tab20"]
    return [cmap(j % 20) for j in range(m)]


def _legend(ax, runs, handles=None):
    """The legend of a panel: every labelled curve (one colour per quantity), and the runs by
    line style when there are several; outside the panel, right."""
    from matplotlib.lines import Line2D

    handles = [ln for ln in ax.get_lines() if not ln.get_label().startswith("_")] if handles is None else handles
    if len(runs) > 1:
        handles = handles + [
            Line2D([], [], color="0.25", ls=STYLES[r % len(STYLES)], lw=1.2, label=name) for r, name in enumerate(runs)
        ]
    if handles:
        ax.legend(
            handles=handles,
            loc="upper left",
            bbox_to_anchor=(1.01, 1.0),
            frameon=False,
            ncol=2 if len(handles) > 9 else 1,
            borderaxespad=0.0,
            handlelength=2.2,
        )


def _curves(ax, runs, values, labels):
    """`values(series)` (T, m) against time, one colour per column and one style per run."""
    colors = _colors(len(labels))
    for r, (run, s) in enumerate(runs.items()):
        y = values(s)
        for j, lab in enumerate(labels):
            ax.plot(
                s["t"],
                y[:, j],
                ls=STYLES[r % len(STYLES)],
                color=colors[j],
                lw=1.1,
                label=lab if r == 0 else f"_{lab} ({run})",
            )
    ax.ticklabel_format(axis="y", useOffset=False)
    _legend(ax, runs)


def _heat_map(fig, ax, s, hinges, chains, labels):
    """Hinge angles of an appendage as a time-hinge image (a colour bar gives the scale)."""
    g = s["gamma"][:, hinges]
    t = s["t"]
    a = float(np.nanmax(np.abs(g))) if g.size else 1.0
    im = ax.imshow(
        g.T,
        aspect="auto",
        origin="lower",
        interpolation="nearest",
        cmap="RdBu_r",
        vmin=-(a or 1.0),
        vmax=a or 1.0,
        extent=(float(t[0]), float(t[-1]), 0.5, len(hinges) + 0.5),
    )
    # rows are the appendages' hinges in order: ticks name hinge numbers; a line and the root's
    # name mark where each appendage starts
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    ax.yaxis.set_major_locator(MaxNLocator(nbins=8, integer=True))
    ax.yaxis.set_major_formatter(
        FuncFormatter(lambda y, _: str(hinges[int(y) - 1] + 1) if 1 <= int(y) <= len(hinges) else "")
    )
    row = 1
    for c in chains:
        if row > 1:
            ax.axhline(row - 0.5, color="k", lw=0.6)
        ax.text(0.01, row - 0.5, f" {labels[c[0]]}", transform=ax.get_yaxis_transform(), va="bottom", fontsize=8)
        row += len(c)
    ax.set_ylabel("hinge $k$")
    fig.colorbar(im, ax=ax, label="$\\gamma_k$ (rad)", pad=0.01)


def _energy_note(s) -> str:
    """Why the energy may change: prescribed hinges work, dampers dissipate."""
    note = (["prescribed hinges do work"] if s["prescribed"] else []) + (["dampers dissipate"] if s["damped"] else [])
    return f" ({', '.join(note)})" if note else ""


def _relative_change(s, which):
    if which == "energy":
        E = s["energy"]
        return (E - E[0]) / (abs(E[0]) if E[0] else 1.0)
    H = s["H"]
    return np.linalg.norm(H - H[0], axis=1) / (np.linalg.norm(H[0]) or 1.0)


def _drift_panel(ax, runs, which, note=""):
    """Energy or angular-momentum change of every run, on a scale that shows its size: linear
    where it exceeds :data:`DRIFT_LINEAR` (relative, in percent), else ``|change|`` on a log axis."""
    from matplotlib.ticker import PercentFormatter

    rel = {run: _relative_change(s, which) for run, s in runs.items()}
    big = max(float(np.nanmax(np.abs(v), initial=0.0)) for v in rel.values())
    linear = big > DRIFT_LINEAR or big == 0.0
    color = "C0" if which == "energy" else "C3"
    for r, (run, v) in enumerate(rel.items()):
        y = v if linear else np.where(np.abs(v) > 0, np.abs(v), np.nan)
        label = run if len(runs) > 1 else f"_{run}"
        ax.plot(runs[run]["t"], y, ls=STYLES[r % len(STYLES)], color=color, lw=1.1, label=label)
    first = next(iter(rel.values()))
    sym = "(E - E_0)/|E_0|" if which == "energy" else "|H - H_0|/|H_0|"
    name = "energy" if which == "energy" else "angular momentum"
    if linear:
        ax.yaxis.set_major_formatter(PercentFormatter(xmax=1.0, decimals=None))
        ax.set_ylabel(f"${sym}$ (%)")
        ax.set_title(f"{name} change: {100 * float(first[-1]):+.3g} % at the end, {100 * big:.3g} % at most{note}")
    else:
        ax.set_yscale("log")
        ax.set_ylabel(f"${'|E - E_0|/|E_0|' if which == 'energy' else sym}$ (log axis)")
        ax.set_title(f"{name} conserved: relative change at most {big:.1e}{note}")
    ax.grid(alpha=0.3)
    if len(runs) > 1:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0.0)


def plot_histories(result, path=None, *, title: str | None = None, drift: bool = False):
    """Time histories, hinges grouped by their role (:func:`hinge_roles`).

    `result`: a :class:`jaxtree.Solution`, a result :class:`xarray.Dataset`, or a mapping of run
    names to either (the same vehicle, e.g. two attitude variables): one colour per quantity, one
    line style per run, every curve in its panel's legend. Panels: the branch's hinge angles and
    rates; the rotors' spin rates; the appendages' hinge angles (curves, or a time-hinge heat map
    when there are more than :data:`LEGEND_MAX`); omega0; the direction cosines C_ii; with
    `drift`, the energy and angular-momentum change (as :func:`plot_drift`).
    """
    runs = _runs(result)
    s0 = next(iter(runs.values()))
    n = s0["gamma"].shape[1]
    names = s0["names"] or [f"hinge {k}" for k in range(1, n + 1)]
    pres = set(s0["prescribed"])
    labels = [f"{k + 1} {names[k]}" + (" (prescribed)" if k + 1 in pres else "") for k in range(n)]
    roles = hinge_roles(s0["model"], s0["gamma"], n)
    panels: list = []
    if roles.branch:
        b = list(roles.branch)
        panels.append(
            (
                "branch: hinge angles $\\gamma_k$ (rad)",
                lambda ax: _curves(ax, runs, lambda s: s["gamma"][:, b], [labels[k] for k in b]),
            )
        )
        panels.append(
            (
                "branch: hinge rates $\\dot\\gamma_k$ (rad/s)",
                lambda ax: _curves(ax, runs, lambda s: s["gamma_dot"][:, b], [labels[k] for k in b]),
            )
        )
    if roles.rotors:
        rr = list(roles.rotors)
        panels.append(
            (
                "rotors: spin rates $\\dot\\gamma_k$ (rad/s)",
                lambda ax: _curves(ax, runs, lambda s: s["gamma_dot"][:, rr], [labels[k] for k in rr]),
            )
        )
    app = [k for c in roles.appendages for k in c]
    if app and len(app) <= LEGEND_MAX:
        what = "appendage" if len(roles.appendages) == 1 else f"{len(roles.appendages)} appendages"
        panels.append(
            (
                f"{what}: hinge angles $\\gamma_k$ (rad)",
                lambda ax: _curves(ax, runs, lambda s: s["gamma"][:, app], [labels[k] for k in app]),
            )
        )
    elif app:
        for run, s in runs.items():
            tag = f" ({run})" if len(runs) > 1 else ""

            def heat(ax, fig=None, s=s):
                _heat_map(fig, ax, s, app, roles.appendages, labels)

            panels.append((f"appendages: hinge angles, {len(app)} hinges{tag}", ("heat", heat)))
    panels.append(
        (
            "$\\omega^0$ of $b_0$ in $\\{b^0\\}$ (rad/s)",
            lambda ax: _curves(ax, runs, lambda s: s["omega0"], [f"$\\omega^0_{i + 1}$" for i in range(3)]),
        )
    )
    panels.append(
        (
            "direction cosines $C_{ii}$ (Def. 9)",
            lambda ax: _curves(
                ax, runs, lambda s: s["dcm"][:, [0, 1, 2], [0, 1, 2]], [f"$C_{{{i}{i}}}$" for i in (1, 2, 3)]
            ),
        )
    )
    if drift:
        note = _energy_note(s0)
        panels.append((None, lambda ax: _drift_panel(ax, runs, "energy", note)))
        panels.append((None, lambda ax: _drift_panel(ax, runs, "momentum")))
    rows = (len(panels) + 1) // 2
    with _style():
        fig = _figure(figsize=(13, 2.7 * rows + 0.5), layout="constrained")
        first = None
        for i, (head, draw) in enumerate(panels):
            ax = fig.add_subplot(rows, 2, i + 1, sharex=first)
            first = first or ax
            if isinstance(draw, tuple):
                draw[1](ax, fig=fig)
            else:
                draw(ax)
            if head:
                ax.set_title(head)
            ax.grid(alpha=0.25)
            if i >= len(panels) - 2:
                ax.set_xlabel("t (s)")
        fig.suptitle(title if title is not None else _heading(runs))
    _save(fig, path)
    return fig


def _heading(runs):
    s0 = next(iter(runs.values()))
    head = s0["title"] or "jaxtree run"
    return head + (": " + " vs ".join(runs) if len(runs) > 1 else "")


def plot_drift(result, path=None, *, title: str | None = None):
    """Energy and angular-momentum change, ``(E - E0) / |E0|`` and ``|H - H0| / |H0|``, over time.

    Each on the scale that shows its size: a change beyond :data:`DRIFT_LINEAR` (dissipation,
    work of prescribed hinges) in percent on a linear axis, a conserved quantity's round-off drift
    as ``|change|`` on a log axis; the panel's title says which and how large. `result` as in
    :func:`plot_histories` (several runs: one line style each). Without external loads the
    angular momentum about the mass center is conserved; the energy is too unless prescribed
    hinges do work or dampers dissipate (the figure's title says so)."""
    runs = _runs(result)
    for s in runs.values():
        if s["energy"] is None or s["H"] is None:
            raise ValueError("plot_drift: the result has no energy or angular momentum")
    s0 = next(iter(runs.values()))
    with _style():
        fig = _figure(figsize=(13, 3.6), layout="constrained")
        axes = fig.subplots(1, 2, sharex=True)
        _drift_panel(axes[0], runs, "energy", _energy_note(s0))
        _drift_panel(axes[1], runs, "momentum")
        for ax in axes:
            ax.set_xlabel("t (s)")
        fig.suptitle(title if title is not None else _heading(runs))
    _save(fig, path)
    return fig


def tree_segments(model: Model, gamma) -> np.ndarray:
    """The tree as line segments at hinge angles `gamma` (n,): for each hinge k a polyline
    ``[mass center of the parent, hinge point h_k, mass center of body k]`` (n, 3, 3), from
    the system mass center in {b0} components (:func:`jaxtree.configuration`)."""
    import jax.numpy as jnp

    cfg = configuration(model, jnp.asarray(gamma, jnp.result_type(model.mass)))
    rho, hinge = np.asarray(cfg.rho), np.asarray(cfg.hinge)
    par = np.asarray(model.topology.parents)
    return np.stack([rho[par], hinge, rho[1:]], axis=1)


def _draw_tree(ax, segments, rho0, **kw):
    for seg in segments:
        ax.plot(seg[:, 0], seg[:, 1], seg[:, 2], **kw)
    ax.scatter([rho0[0]], [rho0[1]], [rho0[2]], color=kw.get("color", "k"), s=18)


def _equal_box(ax, pts):
    lo, hi = pts.min(0), pts.max(0)
    mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-9)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.set_box_aspect((1, 1, 1))


def plot_mode_shapes(
    model: Model,
    shapes,
    frequencies=None,
    path=None,
    *,
    gamma=None,
    modes: Sequence[int] | None = None,
    amplitude: float = 0.3,
    labels: Sequence[str] | None = None,
    title: str | None = None,
):
    """Mode shapes drawn as the deformed tree (3D line drawings), one panel per mode.

    - `shapes` (n, k): each column a mode's hinge angles on all n hinges (zero off the small
      set), e.g. ``hinge_shape`` of a modes result, or a :class:`xarray.Dataset` of a modes
      result (then `frequencies`, `gamma`, `labels` come from it);
    - `frequencies` (k,) rad/s; `gamma` (n,): the nominal angles (default zero); `modes`: which
      columns to draw (default the first six); `amplitude`: the largest hinge angle of a drawn
      shape, in rad.

    Each panel shows the nominal tree in grey and ``gamma + amplitude * shape / max|shape|``
    and ``gamma - ...`` in colour (the two extremes of the oscillation).
    """
    if hasattr(shapes, "data_vars"):
        ds = shapes
        frequencies = ds["frequency"].values if frequencies is None else frequencies
        gamma = ds["gamma_nominal"].values if gamma is None else gamma
        labels = [str(s) for s in ds["mode_label"].values] if labels is None else labels
        shapes = ds["hinge_shape"].values
    shapes = np.real(np.asarray(shapes))
    n, k = shapes.shape
    if n != model.n:
        raise ValueError(f"plot_mode_shapes: shapes has {n} rows, the model has {model.n} hinges")
    g0 = np.zeros(n) if gamma is None else np.asarray(gamma, float)
    modes = list(range(min(k, 6))) if modes is None else [int(j) for j in modes]
    cols = min(3, len(modes))
    rows = (len(modes) + cols - 1) // cols
    with _style():
        fig = _figure(figsize=(4.6 * cols, 4.4 * rows))
        _draw_modes(fig, model, shapes, g0, modes, rows, cols, amplitude, frequencies, labels)
        fig.suptitle(
            title
            if title is not None
            else f"{model.name}: mode shapes (grey: nominal; blue/red: +/- {amplitude:g} rad at the largest hinge)"
        )
        fig.tight_layout()
    _save(fig, path)
    return fig


def _draw_modes(fig, model, shapes, g0, modes, rows, cols, amplitude, frequencies, labels):
    n = model.n
    nominal = tree_segments(model, g0)
    for i, j in enumerate(modes):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        phi = shapes[:, j]
        scale = amplitude / max(float(np.abs(phi).max()), 1e-300)
        pts = [nominal.reshape(-1, 3)]
        _draw_tree(ax, nominal, nominal[0, 0] if n else np.zeros(3), color="0.6", lw=1.2)
        for sign, color in ((1.0, "C0"), (-1.0, "C3")):
            seg = tree_segments(model, g0 + sign * scale * phi)
            _draw_tree(ax, seg, seg[0, 0] if n else np.zeros(3), color=color, lw=1.4)
            pts.append(seg.reshape(-1, 3))
        _equal_box(ax, np.concatenate(pts))
        head = f"mode {j + 1}"
        if frequencies is not None:
            f = float(np.asarray(frequencies)[j])
            head += f": {f:.4g} rad/s ({f / (2 * np.pi):.4g} Hz)"
        if labels is not None and j < len(labels) and labels[j]:
            head += "\n" + str(labels[j])
        ax.set_title(head, fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")


def plot_work_precision(
    methods: Mapping[str, Any],
    path=None,
    *,
    title: str = "work-precision",
    error_label: str = "error",
    time_label: str = "run time (s)",
):
    """Error against run time, one line per method (log-log).

    `methods` maps a method's name to its points, either ``(errors, times)`` (two arrays of one
    length, e.g. one point per tolerance) or a mapping with keys ``"error"`` and ``"time"``.
    Points are joined in order of increasing time. Non-positive or non-finite points are skipped.
    """
    with _style():
        fig = _figure(figsize=(7, 5))
        ax = fig.subplots()
        markers = "osD^v<>ph*"
        for i, (name, pts) in enumerate(methods.items()):
            if isinstance(pts, Mapping):
                err, tim = pts["error"], pts["time"]
            else:
                err, tim = pts
            err, tim = np.asarray(err, float).ravel(), np.asarray(tim, float).ravel()
            if err.shape != tim.shape:
                raise ValueError(f"plot_work_precision: {name!r} has {err.size} errors and {tim.size} times")
            ok = np.isfinite(err) & np.isfinite(tim) & (err > 0) & (tim > 0)
            order = np.argsort(tim[ok])
            ax.loglog(tim[ok][order], err[ok][order], marker=markers[i % len(markers)], lw=1.2, ms=5, label=str(name))
        ax.set_xlabel(time_label)
        ax.set_ylabel(error_label)
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        fig.tight_layout()
    _save(fig, path)
    return fig
