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
from typing import Any

import numpy as np

from .model import Model


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
    from .output import atomic_write

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())


def _scene_has_dampers(text: str) -> bool:
    """Whether the scene JSON stored in a result gives any hinge a damper."""
    import json

    try:
        bodies = json.loads(text)["bodies"] if text else []
    except (ValueError, KeyError, TypeError):
        return False
    return any(float((b.get("joint") or {}).get("damping", 0.0) or 0.0) != 0.0 for b in bodies)


def _series(result) -> dict:
    """Arrays of a Solution or a result Dataset: t, gamma, gamma_dot, omega0, dcm, energy, H, names."""
    if hasattr(result, "data_vars"):
        ds = result
        get = lambda k: ds[k].values if k in ds else None  # noqa: E731
        names = [str(s) for s in ds["hinge_name"].values] if "hinge_name" in ds.coords else None
        out: dict[str, Any] = dict(
            t=ds["time"].values,
            gamma=get("gamma"),
            gamma_dot=get("gamma_dot"),
            omega0=get("omega0"),
            dcm=get("dcm"),
            energy=get("energy"),
            H=get("angular_momentum"),
            names=names,
            title=str(ds.attrs.get("scene_name", "")),
            prescribed=tuple(ds["prescribed_hinge"].values) if "prescribed_hinge" in ds.coords else (),
        )
        out["damped"] = _scene_has_dampers(ds.attrs.get("scene", ""))
        return out
    sol = result
    ts = np.asarray(sol.ts)
    keep = np.isfinite(ts)
    a = lambda x: None if x is None else np.asarray(x)[keep]  # noqa: E731
    model = sol.problem.model
    return dict(
        t=ts[keep],
        gamma=a(sol.gamma),
        gamma_dot=a(sol.gamma_dot),
        omega0=a(sol.omega0),
        dcm=a(sol.dcm),
        energy=a(sol.energy),
        H=a(sol.angular_momentum),
        names=list(model.names[1:]),
        title=model.name,
        prescribed=model.prescribed,
        damped=bool(np.any(np.asarray(model.damping) != 0)),
    )


def _legend(ax, count, **kw):
    if count <= 12:
        ax.legend(fontsize=7, ncol=2 if count > 4 else 1, **kw)


def plot_histories(result, path=None, *, title: str | None = None):
    """Time histories: hinge angles and rates, omega0 and the direction cosines C_ii.

    Hinges that spin (|gamma| beyond 2 pi, e.g. a rotor) are left out of the angle panel and
    appear among the rates. Legends are drawn for up to 12 curves.
    """
    s = _series(result)
    t, n = s["t"], s["gamma"].shape[1]
    names = s["names"] or [f"{k}" for k in range(1, n + 1)]
    fig = _figure(figsize=(12, 8))
    axes = fig.subplots(2, 2, sharex=True)
    spinning = [k for k in range(n) if np.nanmax(np.abs(s["gamma"][:, k]), initial=0.0) > 2 * np.pi]
    shown = [k for k in range(n) if k not in spinning]
    for k in shown:
        axes[0, 0].plot(t, s["gamma"][:, k], lw=1, label=f"{k + 1} {names[k]}")
    for k in range(n):
        axes[0, 1].plot(t, s["gamma_dot"][:, k], lw=1, label=f"{k + 1} {names[k]}")
    for i in range(3):
        axes[1, 0].plot(t, s["omega0"][:, i], lw=1, label=f"$\\omega^0_{i + 1}$")
        axes[1, 1].plot(t, s["dcm"][:, i, i], lw=1, label=f"$C_{{{i + 1}{i + 1}}}$")
    axes[0, 0].set_title(
        "hinge angles $\\gamma_k$ (rad)"
        + (f"; spinning, see rates: {', '.join(names[k] for k in spinning)}" if spinning else "")
    )
    axes[0, 1].set_title("hinge rates $\\dot\\gamma_k$ (rad/s)")
    axes[1, 0].set_title("$\\omega^0$ of $b_0$ in $\\{b^0\\}$ (rad/s)")
    axes[1, 1].set_title("direction cosines $C_{ii}$ (Def. 9)")
    _legend(axes[0, 0], len(shown))
    _legend(axes[0, 1], n)
    axes[1, 0].legend(fontsize=7)
    axes[1, 1].legend(fontsize=7)
    for ax in axes[1]:
        ax.set_xlabel("t (s)")
    fig.suptitle(title if title is not None else s["title"])
    fig.tight_layout()
    _save(fig, path)
    return fig


def plot_drift(result, path=None, *, title: str | None = None):
    """Energy and angular-momentum drift, ``(E - E0) / |E0|`` and ``|H - H0| / |H0|``, over time.

    Without external loads the angular momentum about the mass center is conserved; the energy is
    too unless prescribed hinges do work or dampers dissipate (the panel title says so)."""
    s = _series(result)
    if s["energy"] is None or s["H"] is None:
        raise ValueError("plot_drift: the result has no energy or angular momentum")
    t, E, H = s["t"], s["energy"], s["H"]
    fig = _figure(figsize=(12, 4.2))
    axes = fig.subplots(1, 2, sharex=True)
    e0 = abs(E[0]) if E[0] else 1.0
    h0 = np.linalg.norm(H[0]) or 1.0
    axes[0].plot(t, (E - E[0]) / e0, lw=1)
    axes[1].plot(t, np.linalg.norm(H - H[0], axis=1) / h0, lw=1)
    note = []
    if s["prescribed"]:
        note.append("prescribed hinges do work")
    if s["damped"]:
        note.append("dampers dissipate")
    axes[0].set_title("energy drift $(E - E_0)/|E_0|$" + (f" ({', '.join(note)})" if note else ""))
    axes[1].set_title("angular-momentum drift $|H - H_0| / |H_0|$")
    for ax in axes:
        ax.set_yscale("symlog", linthresh=1e-15)
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
    fig.suptitle(title if title is not None else s["title"])
    fig.tight_layout()
    _save(fig, path)
    return fig


def tree_segments(model: Model, gamma) -> np.ndarray:
    """The tree as line segments at hinge angles `gamma` (n,): for each hinge k a polyline
    ``[mass center of the parent, hinge point h_k, mass center of body k]`` (n, 3, 3), from
    the system mass center in {b0} components (:func:`jaxtree.configuration`)."""
    import jax.numpy as jnp

    from .dynamics import configuration

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
    fig = _figure(figsize=(4.6 * cols, 4.4 * rows))
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
        ax.set_title(head, fontsize=8)
        ax.set_xlabel("x (m)", fontsize=7)
        ax.set_ylabel("y (m)", fontsize=7)
        ax.set_zlabel("z (m)", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.suptitle(
        title
        if title is not None
        else f"{model.name}: mode shapes (grey: nominal; blue/red: +/- {amplitude:g} rad at the largest hinge)"
    )
    fig.tight_layout()
    _save(fig, path)
    return fig


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
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    return fig
