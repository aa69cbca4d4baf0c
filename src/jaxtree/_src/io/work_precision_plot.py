"""Work-precision diagrams (matplotlib): error against run time, one line per method
(:func:`plot_work_precision`). The figure, its style and the PNG written are :mod:`.figures`'.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .figures import new_figure, plot_style, save_png


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
    with plot_style():
        fig = new_figure(figsize=(7, 5))
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
    save_png(fig, path)
    return fig
