"""The plots (jaxtree.plot_histories, plot_drift, plot_mode_shapes, plot_work_precision) rendered
with the Agg backend and checked for what a reader relies on: no empty panel, every labelled curve
in its panel's legend (a heat map with its colour bar), one colour per quantity and one line style
per run, fig4's rotor shown as a rate, drift on a scale that shows its size, PNGs at the stated
resolution, and the default save points dense enough for the fastest hinge's oscillation."""

import argparse

import matplotlib
import numpy as np
import pytest
from PIL import Image

import jaxtree
from jaxtree._src import cli
from jaxtree._src.integration import save_grid
from jaxtree._src.io import figures, history_plots, mode_plots, work_precision_plot
from jaxtree._src.io.results import simulation_dataset

matplotlib.use("Agg")

# smallest legible sizes at figures.DPI (points)
LEAST_TITLE_PT, LEAST_TICK_PT = 9.0, 8.0


@pytest.fixture(scope="module")
def fig4_runs():
    """fig4 over 2 s (the rotor turns ten times) with two attitude variables."""
    model = jaxtree.load_scene("fig4")
    return {att: jaxtree.simulate(model, 2.0, saveat=81, attitude=att) for att in ("euler123", "quaternion")}


def _synthetic(model, t, gamma, energy, momentum):
    """A result Dataset of `model` with the given histories (the rest held still)."""
    T = len(t)
    return simulation_dataset(
        model,
        t,
        gamma,
        np.gradient(gamma, t, axis=0),
        np.tile([0.0, 0.02, 0.0], (T, 1)),
        np.tile(np.eye(3), (T, 1, 1)),
        energy=energy,
        angular_momentum=momentum,
        positions=False,
        attrs={"scene_name": model.name},
    )


def check_figure(fig, png):
    """No empty panel; every labelled curve in its panel's legend; images with a colour bar;
    legible titles and ticks; the PNG at figures.DPI."""
    for ax in fig.axes:
        if ax.get_label() == "<colorbar>":
            continue
        assert ax.lines or ax.images or ax.collections, f"empty panel {ax.get_title()!r}"
        assert ax.get_title() or ax.get_ylabel(), "a panel without a title"
        assert ax.title.get_fontsize() >= LEAST_TITLE_PT
        assert all(t.get_fontsize() >= LEAST_TICK_PT for t in ax.get_yticklabels())
        labelled = {ln.get_label() for ln in ax.get_lines() if not ln.get_label().startswith("_")}
        if labelled:
            legend = ax.get_legend()
            assert legend is not None, f"{ax.get_title()!r}: curves {sorted(labelled)} without a legend"
            assert labelled <= {t.get_text() for t in legend.get_texts()}, ax.get_title()
        for im in ax.images:
            assert im.colorbar is not None, f"{ax.get_title()!r}: an image without a colour bar"
    # nothing clipped: every title and axis label (3D ones too) and the figure's title on the page
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    W, H = fig.bbox.width, fig.bbox.height
    texts = [t for t in fig.texts if t.get_text()] + ([fig._suptitle] if fig._suptitle is not None else [])
    for ax in fig.axes:
        texts += [ax.title, ax.xaxis.label, ax.yaxis.label] + ([ax.zaxis.label] if hasattr(ax, "zaxis") else [])
    for t in texts:
        if not t.get_text() or not t.get_visible():
            continue
        bb = t.get_window_extent(renderer)
        assert bb.x0 >= -1 and bb.y0 >= -1 and bb.x1 <= W + 1 and bb.y1 <= H + 1, f"clipped: {t.get_text()!r}"
    with Image.open(png) as im:
        w, h = im.size
        dpi = im.info.get("dpi", (0, 0))[0]
    assert round(dpi) == figures.DPI >= 120
    # matplotlib truncates the size in inches x dpi to whole pixels
    assert abs(w - fig.get_figwidth() * figures.DPI) < 1 and abs(h - fig.get_figheight() * figures.DPI) < 1


def _panel(fig, text):
    (ax,) = [ax for ax in fig.axes if text in ax.get_title()]
    return ax


def test_fig4_histories_group_hinges_show_the_rotor_and_style_the_runs(fig4_runs, tmp_path):
    fig = history_plots.plot_histories(fig4_runs, tmp_path / "h.png", drift=True)
    check_figure(fig, tmp_path / "h.png")
    sol = fig4_runs["euler123"]
    # the rotor (hinge 4) as its spin rate, in a panel of its own and its legend
    rotor = _panel(fig, "rotor")
    assert [t.get_text() for t in rotor.get_legend().get_texts()][0] == "4 rotor"
    np.testing.assert_array_equal(rotor.lines[0].get_ydata(), np.asarray(sol.gamma_dot)[:, 3])
    # branch hinges (platform, gimbals) apart from the six sprung panels
    angles = _panel(fig, "branch: hinge angles")
    assert [ln.get_label() for ln in angles.lines[:3]] == [
        "1 platform (prescribed)",
        "2 gimbal_outer",
        "3 gimbal_inner",
    ]
    panels = _panel(fig, "appendage")
    assert len([ln for ln in panels.lines if not ln.get_label().startswith("_")]) == 6
    # every hinge appears somewhere (nothing silently left out)
    shown = {ln.get_label().split()[0] for ax in fig.axes for ln in ax.lines if not ln.get_label().startswith("_")}
    assert {str(k) for k in range(1, 11)} <= shown
    # one colour per quantity, one style per run: the second run's curve of a quantity has the
    # first's colour, another style, and the legend names both runs by style
    for ax in fig.axes[:6]:
        first = {ln.get_label(): ln for ln in ax.lines if not ln.get_label().startswith("_")}
        for ln in ax.lines:
            if ln.get_label().endswith("(quaternion)"):
                twin = first[ln.get_label()[1:].rsplit(" (", 1)[0]]
                assert ln.get_color() == twin.get_color() and ln.get_linestyle() != twin.get_linestyle()
        assert {"euler123", "quaternion"} <= {t.get_text() for t in ax.get_legend().get_texts()}
    # the main job's figure is this one
    assert jaxtree.save_plot(tmp_path / "job.png", fig4_runs, title="fig4")
    with Image.open(tmp_path / "job.png") as im:
        assert im.size == (w := round(13 * figures.DPI), im.size[1]) and w >= 1560


def test_many_appendage_hinges_become_a_heat_map_with_a_colour_bar(tmp_path):
    model = jaxtree.load_scene("chain50")
    t = np.linspace(0.0, 5.0, 201)
    gamma = 0.1 * np.sin(np.outer(t, 1.0 + np.arange(model.n) / 10))
    E = np.full_like(t, 10.0) * (1 + 1e-13 * np.sin(t))
    H = np.tile([0.0, 3.0, 0.0], (len(t), 1))
    ds = _synthetic(model, t, gamma, E, H)
    roles = history_plots.hinge_roles(model, gamma)
    assert roles.branch == () and roles.rotors == () and roles.appendages == (tuple(range(model.n)),)
    fig = history_plots.plot_histories(ds, tmp_path / "h.png")
    check_figure(fig, tmp_path / "h.png")
    heat = _panel(fig, "appendage")
    np.testing.assert_array_equal(heat.images[0].get_array(), gamma.T)


def test_drift_is_drawn_on_the_scale_that_shows_its_size(tmp_path):
    """Dissipation (29 % of the energy) on a linear axis in J, the title with the share of E0 and
    its cause; momentum conserved to round-off as |drift| on a log axis (N m s); each title says
    which and how much. A run from rest (E0 = 0, H0 = 0) has its changes in J and N m s, and no
    relative figure."""
    model = jaxtree.load_scene("wings")
    t = np.linspace(0.0, 20.0, 401)
    gamma = 0.05 * np.cos(np.outer(t, np.full(model.n, 7.7)))
    E = 2.0 * (1 - 0.29 * (1 - np.exp(-t / 5)) / (1 - np.exp(-4)))
    H = np.tile([0.0, 3.0, 0.0], (len(t), 1)) + 1e-15 * np.sin(np.outer(t, [1.0, 2.0, 3.0]))
    fig = history_plots.plot_drift(_synthetic(model, t, gamma, E, H), tmp_path / "d.png")
    check_figure(fig, tmp_path / "d.png")
    energy, momentum = fig.axes
    title = energy.get_title().replace("\n", " ")
    assert energy.get_yscale() == "linear" and "-0.58 J at the end" in title and "(29 % of" in title
    assert "dampers dissipate" in title and "(J)" in energy.get_ylabel()
    np.testing.assert_allclose(energy.lines[0].get_ydata(), E - E[0])
    assert momentum.get_yscale() == "log" and "conserved" in momentum.get_title() and "N m s" in momentum.get_ylabel()
    y = np.asarray(momentum.lines[0].get_ydata())
    assert np.nanmax(y) < 3e-15 and np.all(np.isnan(y) | (y > 0))
    # from rest: absolute only
    rest_E, rest_H = 0.5 * (1 - np.cos(t)), np.outer(np.sin(t), [0.0, 0.0, 2.0])
    fig = history_plots.plot_drift(_synthetic(model, t, gamma, rest_E, rest_H), tmp_path / "r.png")
    energy, momentum = fig.axes
    title = energy.get_title().replace("\n", " ")
    assert energy.get_yscale() == "linear" and "%" not in title and "near zero" in title
    np.testing.assert_allclose(momentum.lines[0].get_ydata(), 2.0 * np.abs(np.sin(t)), atol=1e-12)


def test_mode_shapes_and_work_precision_render(tmp_path):
    model = jaxtree.load_scene("wings")
    shapes = np.eye(model.n)[:, :3]
    fig = mode_plots.plot_mode_shapes(model, shapes, [1.0, 2.0, 3.0], tmp_path / "m.png")
    check_figure(fig, tmp_path / "m.png")
    fig = work_precision_plot.plot_work_precision(
        {"a": ([1e-6, 1e-9], [0.1, 0.3]), "b": ([1e-5], [0.2])}, tmp_path / "w.png"
    )
    check_figure(fig, tmp_path / "w.png")


def test_default_save_points_resolve_the_fastest_hinge(capsys):
    """20 save points per period of the fastest sprung hinge that still rings, at least 101; a
    note when --points gives fewer than 8 (the wings' 101 points over 20 s gave 4)."""
    wings = jaxtree.load_scene("wings")
    points, rate = save_grid.save_points(wings, 20.0)
    assert 7.0 < rate < 8.0  # the wing panels' spring against their inertia (7.74 rad/s)
    assert save_grid.samples_per_period(points, 20.0, rate) >= save_grid.SAMPLES_PER_PERIOD
    assert save_grid.save_points(jaxtree.load_scene("appendix_b"), 10.0) == (101, 0.0)  # no spring: 101

    def args(points):
        return argparse.Namespace(t0=0.0, t1=20.0, points=points)

    assert cli._save_points(args(None), wings) == points and capsys.readouterr().err == ""
    assert cli._save_points(args(101), wings) == 101
    err = capsys.readouterr().err
    assert "jagged" in err and f"default here is {points}" in err


def test_many_fast_hinges_over_a_long_run_are_drawn_as_their_amplitude(tmp_path):
    """Six appendage hinges ringing at 30 rad/s for 100 s (about 480 cycles: a solid band as curves)
    are drawn as their amplitude, the half range in each hundredth of the run: a sine of
    amplitude a decaying as exp(-t / 50) reads a exp(-t / 50) (to the decay within a bin)."""
    model = jaxtree.load_scene("fig4")
    t = np.linspace(0.0, 100.0, 20001)
    roles = history_plots.hinge_roles(model, np.zeros((2, model.n)))
    app = [k for c in roles.appendages for k in c]
    amp = 0.1 * (1 + np.arange(len(app)))
    gamma = np.zeros((len(t), model.n))
    gamma[:, app] = amp * np.exp(-t / 50)[:, None] * np.sin(30.0 * t[:, None] + np.arange(len(app)))
    E = np.full_like(t, 10.0)
    H = np.tile([0.0, 3.0, 0.0], (len(t), 1))
    fig = history_plots.plot_histories(_synthetic(model, t, gamma, E, H), tmp_path / "h.png")
    check_figure(fig, tmp_path / "h.png")
    ax = _panel(fig, "appendage")
    assert any("amplitude" in tx.get_text() for tx in ax.texts)
    for j, line in enumerate(ax.lines[: len(app)]):
        tc, a = np.asarray(line.get_xdata()), np.asarray(line.get_ydata())
        assert len(a) == history_plots.ENVELOPE_BINS
        np.testing.assert_allclose(a, amp[j] * np.exp(-tc / 50), rtol=2e-2)
