"""The shared figure helpers of every plot (matplotlib): the resolution of the PNGs written
(:data:`DPI`), the font sizes that read at it (:func:`plot_style`), a figure outside pyplot's state
(:func:`new_figure`) and the atomic PNG write (:func:`save_png`).

Every plot function (:mod:`.history_plots`, :mod:`.mode_plots`, :mod:`.work_precision_plot`)
returns the :class:`matplotlib.figure.Figure` and, given a `path`, also writes it as a PNG
atomically (temporary file, then rename). matplotlib is an optional dependency (``pip install
jaxtree[plot]``); it is imported when a plot is made.
"""

from __future__ import annotations

import io

from ..atomic import atomic_write

# Every PNG written here: at 120 dpi a 9 pt label is 15 px high.
DPI = 120
_RC = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
    "legend.fontsize": 8,
    "figure.titlesize": 11,
}


def plot_style():
    """Font sizes that read at :data:`DPI` (matplotlib's rc settings for the figure being made)."""
    import matplotlib

    return matplotlib.rc_context(_RC)


def new_figure(**kw):
    """A new figure outside pyplot's state (a plot made here never becomes pyplot's current
    figure, and nothing is left open in pyplot)."""
    try:
        import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3d projection)
        from matplotlib.figure import Figure
    except ImportError as e:
        raise ImportError("plots need matplotlib (pip install 'jaxtree[plot]')") from e
    return Figure(**kw)


def save_png(fig, path):
    """Write `fig` as a PNG at :data:`DPI` to `path`, atomically; nothing when `path` is None."""
    if path is None:
        return
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())
