"""Mode shapes drawn as the deformed tree (matplotlib, 3D line drawings): the tree as line
segments at given hinge angles (:func:`tree_segments`) and one panel per mode
(:func:`plot_mode_shapes`). The figure, its style and the PNG written are :mod:`.figures`'.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..equations.dynamics import configuration
from ..vehicle.model import Model
from .figures import new_figure, plot_style, save_png


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
    ax.set_box_aspect((1, 1, 1), zoom=0.82)  # room inside the axes for the tick and axis labels


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
    with plot_style():
        fig = new_figure(figsize=(4.6 * cols, 4.6 * rows + 0.5))
        _draw_modes(fig, model, shapes, g0, modes, rows, cols, amplitude, frequencies, labels)
        fig.suptitle(
            title
            if title is not None
            else f"{model.name}: mode shapes (grey: nominal; blue/red: +/- {amplitude:g} rad at the largest hinge)"
        )
        # tight_layout does not measure 3D axes' labels: the margins by hand, the drawings shrunk
        # inside their axes (_equal_box), a row's titles clear of the row above
        top = 1.0 - 1.0 / (4.6 * rows + 0.5)
        fig.subplots_adjust(left=0.01, right=0.97, bottom=0.02, top=top, wspace=0.05, hspace=0.12)
    save_png(fig, path)
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
