"""Plots of a simulation's time histories (matplotlib): the hinges grouped by the role they play
(branch, rotors, appendages), omega0 and the direction cosines (:func:`plot_histories`), and the
energy and angular-momentum change (:func:`plot_drift`).

Results are taken as a :class:`jaxtree.Solution` or as the :class:`xarray.Dataset` of a result
file (:func:`jaxtree.load_result`), or a mapping of run names to either. The figure, its style and
the PNG written are :mod:`.figures`'.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

from ..vehicle.model import Model
from .drift import drift_causes, near_zero
from .figures import new_figure, plot_style, save_png
from .result_files import model_of

# Curves in one panel with a legend; beyond it an appendage's hinges become a time-hinge heat map.
LEGEND_MAX = 12
# A relative energy or momentum change beyond this is drawn on a linear axis (work done, energy
# dissipated: its size is the point); below it, |drift| on a log axis (conservation to round-off:
# its order of magnitude is the point).
DRIFT_LINEAR = 1e-6
# a history of more oscillations than this is drawn as its amplitude over this many time spans
ENVELOPE_CYCLES = 100
ENVELOPE_BINS = 100
# One line style per run (one colour per quantity).
STYLES = ("-", "--", ":", "-.")


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


def _cycles(y) -> float:
    """The most oscillation cycles of any column of `y` (T, m): half its crossings of its mean."""
    if y.shape[0] < 3:
        return 0.0
    z = y - np.mean(y, axis=0)
    return float(np.max(np.sum(z[1:] * z[:-1] < 0, axis=0), initial=0)) / 2.0


def _amplitude(t, y, bins: int):
    """Per time bin (`bins` equal spans of `t`): the bins' centers, and each column's half range in
    it, its oscillation's amplitude (``(B,), (B, m)``)."""
    edges = np.linspace(t[0], t[-1], bins + 1)
    idx = np.unique(np.clip(np.searchsorted(t, edges[:-1], side="left"), 0, len(t) - 1))
    lo = np.minimum.reduceat(y, idx, axis=0)
    hi = np.maximum.reduceat(y, idx, axis=0)
    ends = np.append(idx[1:], len(t)) - 1
    return 0.5 * (t[idx] + t[ends]), 0.5 * (hi - lo)


def _curves(ax, runs, values, labels):
    """`values(series)` (T, m) against time, one colour per column and one style per run. A history
    of more than :data:`ENVELOPE_CYCLES` oscillations (many fast hinges over a long run: a solid
    band as curves) is drawn as its amplitude, the half range in each of :data:`ENVELOPE_BINS`
    time spans, and the panel says so."""
    colors = _colors(len(labels))
    dense = max(_cycles(np.asarray(values(s), float)) for s in runs.values()) > ENVELOPE_CYCLES
    for r, (run, s) in enumerate(runs.items()):
        y = np.asarray(values(s), float)
        t = np.asarray(s["t"], float)
        if dense:
            t, y = _amplitude(t, y, ENVELOPE_BINS)
        for j, lab in enumerate(labels):
            label = lab if r == 0 else f"_{lab} ({run})"
            ax.plot(t, y[:, j], ls=STYLES[r % len(STYLES)], color=colors[j], lw=1.1, label=label)
    if dense:
        ax.text(
            0.01,
            0.98,
            f"amplitude: half the range in each {ENVELOPE_BINS}th of the run",
            transform=ax.transAxes,
            va="top",
            fontsize=8,
            color="0.3",
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


def _causes(s, which) -> str:
    """Why the energy (or the angular momentum) may change, from the run's model
    (:func:`jaxtree._src.io.output.drift_causes`)."""
    if s["model"] is None:  # a result without its scene: what the result itself tells
        why = ["prescribed hinges do work"] if (which == "energy" and s["prescribed"]) else []
        why += ["dampers dissipate"] if (which == "energy" and s["damped"]) else []
    else:
        why = drift_causes(s["model"])[0 if which == "energy" else 1]
    return f"not conserved: {', '.join(why)}" if why else ""


def _change(s, which):
    """``(change (T,), initial value's size, history for the near-zero test, unit)``: ``E - E0``
    (J) or ``|H - H0|`` (N m s)."""
    if which == "energy":
        E = np.asarray(s["energy"], float)
        return E - E[0], abs(E[0]), E, E[0], "J"
    H = np.asarray(s["H"], float)
    return np.linalg.norm(H - H[0], axis=1), float(np.linalg.norm(H[0])), H, H[0], "N m s"


def _drift_panel(ax, runs, which):
    """Energy or angular-momentum change of every run, absolute (J, N m s) on a scale that shows its
    size: linear where it is large (beyond :data:`DRIFT_LINEAR` of the initial value, or the
    initial value is near zero: a run from rest), else ``|change|`` on a log axis. The title gives
    the change relative to the initial value where that is not near zero, and on a line of its
    own what may change it (laws, loads, prescribed hinges, dampers)."""
    import textwrap

    ch = {run: _change(s, which) for run, s in runs.items()}
    first = next(iter(ch.values()))
    change, size, history, initial, unit = first
    big = max(float(np.nanmax(np.abs(c[0]), initial=0.0)) for c in ch.values())
    rel = None if near_zero(history, initial) else big / size
    linear = big == 0.0 or rel is None or rel > DRIFT_LINEAR
    color = "C0" if which == "energy" else "C3"
    for r, (run, c) in enumerate(ch.items()):
        y = c[0] if linear else np.where(np.abs(c[0]) > 0, np.abs(c[0]), np.nan)
        label = run if len(runs) > 1 else f"_{run}"
        ax.plot(runs[run]["t"], y, ls=STYLES[r % len(STYLES)], color=color, lw=1.1, label=label)
    sym = "E - E_0" if which == "energy" else "|H - H_0|"
    name = "energy" if which == "energy" else "angular momentum"
    share = f" ({100 * rel:.3g} % of {'$|E_0|$' if which == 'energy' else '$|H_0|$'})" if rel is not None else ""
    if linear:
        ax.set_ylabel(f"${sym}$ ({unit})")
        end = float(change[-1])
        head = f"{name} change: {end:+.3g} {unit} at the end, {big:.3g} {unit} at most{share}"
        if rel is None:
            head += f", from {float(np.linalg.norm(initial)):.3g} {unit} (near zero)"
    else:
        ax.set_yscale("log")
        ax.set_ylabel(f"$|{sym.strip('|')}|$ ({unit}, log axis)")
        head = f"{name} conserved: change at most {big:.1e} {unit}{share}"
    note = _causes(runs[next(iter(runs))], which)
    ax.set_title("\n".join(textwrap.wrap(head, 58) + textwrap.wrap(note, 58)), fontsize="medium")
    ax.grid(alpha=0.3)
    if len(runs) > 1:
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, borderaxespad=0.0)


def _hinge_panels(runs, roles, labels) -> list:
    """The panels of the hinges by role (:func:`hinge_roles`): the branch's angles and rates, the rotors' spin
    rates and the appendages' angles (curves, or past :data:`LEGEND_MAX` hinges a heat map per run); each a
    title and its drawing function."""
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
    return panels


def _panel_figure(panels, runs, title):
    """The figure of `panels` (a title and a drawing function each), two a row on one time axis, headed by
    `title` or else by the runs."""
    rows = (len(panels) + 1) // 2
    with plot_style():
        fig = new_figure(figsize=(13, 2.7 * rows + 0.5), layout="constrained")
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
    return fig


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
    panels = _hinge_panels(runs, roles, labels)
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
        panels.append((None, lambda ax: _drift_panel(ax, runs, "energy")))
        panels.append((None, lambda ax: _drift_panel(ax, runs, "momentum")))
    fig = _panel_figure(panels, runs, title)
    save_png(fig, path)
    return fig


def _heading(runs):
    s0 = next(iter(runs.values()))
    head = s0["title"] or "jaxtree run"
    return head + (": " + " vs ".join(runs) if len(runs) > 1 else "")


def plot_drift(result, path=None, *, title: str | None = None):
    """Energy and angular-momentum change, ``E - E0`` (J) and ``|H - H0|`` (N m s), over time.

    Each on the scale that shows its size: a change beyond :data:`DRIFT_LINEAR` of the initial
    value (dissipation, work of prescribed hinges), or any change from an initial value near zero
    (a run from rest), on a linear axis, a conserved quantity's round-off drift as ``|change|`` on
    a log axis; the panel's title says which, how large, relative to the initial value where that
    is not near zero, and what may change it (prescribed hinges, control laws, external loads,
    dampers). `result` as in :func:`plot_histories` (several runs: one line style each)."""
    runs = _runs(result)
    for s in runs.values():
        if s["energy"] is None or s["H"] is None:
            raise ValueError("plot_drift: the result has no energy or angular momentum")
    with plot_style():
        fig = new_figure(figsize=(13, 3.6), layout="constrained")
        axes = fig.subplots(1, 2, sharex=True)
        _drift_panel(axes[0], runs, "energy")
        _drift_panel(axes[1], runs, "momentum")
        for ax in axes:
            ax.set_xlabel("t (s)")
        fig.suptitle(title if title is not None else _heading(runs))
    save_png(fig, path)
    return fig
