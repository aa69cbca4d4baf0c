"""Public diagnostics (jaxtree.condition, jaxtree.check_scene), result files (NetCDF through
xarray, jaxtree.load_result) and plots (jaxtree.plots)."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.io import result_files, results

from helpers import TABLE_1, TABLE_2, table

# the condition number and the smallest singular value against numpy's SVD of the same matrix (condition
# 5e3): observed 1e-14 and 3e-14, with margin
CONDITION = 1e-9
SMALLEST = 1e-8
# O(1) float64 identities (a unit direction's norm, the vmapped condition number, the mass-weighted
# positions from the mass center relative to the total mass): round-off
ROUNDOFF = 1e-12
# the near-null direction of the singular matrix at gimbal lock: its hinge entries 2**-0.5 and the massive
# bodies' angular velocities it gives, zero in exact arithmetic; observed 1.5e-13 and 2e-13, with margin
NULL_DIRECTION = 1e-6
NULL_RATES = 1e-7
ROUNDOFF_SEGMENTS = 1e-13  # the drawn segments against the closed form, O(1) positions: round-off


# ----------------------------------------------------------------------------- condition
def test_condition_is_the_2norm_condition_of_eq1_in_its_unknowns():
    """For fig4 at t = 0.7 (hinge 1 prescribed: its angle from the prescription), the number
    equals numpy's SVD condition number of the public Eq. (1) matrix restricted to omega0 and
    the unknown hinges; the direction is a unit vector that the matrix shrinks most."""
    model = jaxtree.load_scene("fig4")
    t = 0.7
    s = model.initial
    c = jaxtree.condition(model, s, t)
    gamma = np.asarray(s.gamma).copy()
    gamma[0] = np.sin(0.5 * t)  # fig4's prescription: gamma_1 = sin(0.5 t)
    A = np.asarray(jaxtree.mass_matrix(model, jnp.asarray(gamma)))
    rows = np.concatenate([np.arange(3), np.asarray(model.unknown_hinges) + 2])
    Au = A[np.ix_(rows, rows)]
    np.testing.assert_allclose(float(c.number), np.linalg.cond(Au), rtol=CONDITION)
    v = np.asarray(c.direction)
    assert abs(np.linalg.norm(v) - 1) < ROUNDOFF
    np.testing.assert_allclose(np.linalg.norm(Au @ v), np.linalg.svd(Au, compute_uv=False)[-1], rtol=SMALLEST)
    assert c.labels[:3] == ("omega0x", "omega0y", "omega0z") and len(c.labels) == len(rows)
    assert not c.singular


def test_condition_names_the_gimbal_lock_direction_that_moves_no_mass():
    """fig4 with the inner gimbal at 90 degrees: the outer gimbal and rotor axes align, Eq. (1)
    is singular, and its near-null direction is the combination of hinges 2 and 4 whose rates
    give every massive body zero angular velocity (kinematics, not the matrix)."""
    model = jaxtree.load_scene("fig4")
    s = model.initial
    gamma = s.gamma.at[2].set(np.pi / 2)
    c = jaxtree.condition(model, s._replace(gamma=gamma))
    assert c.singular and float(c.number) > 1e12
    named = dict(c.named_direction())
    assert set(named) == {"hinge 2 (gimbal_outer)", "hinge 4 (rotor)"}
    np.testing.assert_allclose(abs(named["hinge 2 (gimbal_outer)"]), 2**-0.5, rtol=NULL_DIRECTION)
    v = np.asarray(c.direction)
    rates = np.zeros(model.n)
    rates[np.asarray(model.unknown_hinges) - 1] = v[3:]
    cfg = jaxtree.configuration(model, gamma)
    from jaxtree._src.equations.dynamics import body_angular_velocities

    w = np.asarray(body_angular_velocities(model, cfg, jnp.asarray(v[:3]), jnp.asarray(rates)))
    assert np.abs(w[list(model.massive)]).max() < NULL_RATES
    assert "hinge 2 (gimbal_outer)" in c.describe() and "hinge 4 (rotor)" in c.describe()


def test_condition_is_a_pytree_under_vmap():
    model = jaxtree.load_scene("wings")
    s = model.initial
    gammas = jnp.stack([s.gamma, 0.5 * s.gamma, jnp.zeros_like(s.gamma)])
    nums = jax.vmap(lambda g: jaxtree.condition(model, s._replace(gamma=g)).number)(gammas)
    for g, x in zip(gammas, np.asarray(nums)):
        np.testing.assert_allclose(x, float(jaxtree.condition(model, s._replace(gamma=g)).number), rtol=ROUNDOFF)


# ----------------------------------------------------------------------------- check_scene
def test_check_scene_gives_the_seeds_tables_1_and_2_for_fig4():
    """The tables check_scene prints for fig4 are the seed's Tables 1 and 2 (read from its text)."""
    report = jaxtree.check_scene("fig4")
    text = str(report)
    np.testing.assert_array_equal(report.network_elements, table(TABLE_1))
    np.testing.assert_array_equal(report.path_elements, table(TABLE_2))

    def printed(title):
        lines = text.split(title, 1)[1].splitlines()[3:]
        rows = []
        for line in lines:
            if "|" not in line:
                break
            rows.append([int(x) for x in line.split("|")[1].split()])
        return np.array(rows)

    np.testing.assert_array_equal(printed("Table 1:"), table(TABLE_1))
    np.testing.assert_array_equal(printed("Table 2:"), table(TABLE_2))
    assert report.total_mass == pytest.approx(1000 + 50 + 20 + 6 * 10)
    assert "gimbal_outer  (0 kg, massless)" in text and "prescribed gamma = 1 sin(0.5 t + 0)" in text


def test_check_scene_rejects_an_invalid_scene_naming_the_body_and_field():
    data = json.loads(jaxtree.scene_path("wings").read_text())
    data["bodies"][3]["mass"] = -1.0
    with pytest.raises(jaxtree.SceneError, match=r"body 3 \('wingp_3'\): field 'mass'"):
        jaxtree.check_scene(data)


# ----------------------------------------------------------------------------- result files
@pytest.fixture(scope="module")
def short_run():
    model = jaxtree.load_scene("fig4")
    return jaxtree.simulate(model, 0.5, saveat=11)


def test_result_file_round_trip_with_units_dimensions_and_provenance(short_run, tmp_path):
    sol = short_run
    path = tmp_path / "run.nc"
    jaxtree.save_result(path, sol, attrs={"solver": "Dopri8", "rtol": 1e-9, "atol": 1e-9})
    ds = jaxtree.load_result(path, as_dataset=True)
    assert {"time", "hinge", "body", "axis"} <= set(ds.dims)
    for name, var in ds.data_vars.items():
        assert "units" in var.attrs and var.attrs.get("long_name"), name
    assert ds["gamma"].dims == ("time", "hinge") and ds["body_position"].dims == ("time", "body", "axis")
    assert ds["gamma"].attrs["units"] == "rad" and ds["energy"].attrs["units"] == "J"
    a = ds.attrs
    for key in (
        "scene",
        "solver",
        "rtol",
        "atol",
        "steps_accepted",
        "result",
        "jaxtree_version",
        "jax_version",
        "diffrax_version",
        "date",
    ):
        assert key in a, key
    assert a["result"] == "ok" and a["steps_accepted"] == int(sol.stats["num_accepted_steps"])
    # the scene attribute rebuilds the model
    model2 = jaxtree.scene_from_dict(json.loads(a["scene"]))
    for f in ("mass", "inertia", "axis", "hinge_on_parent", "hinge_on_body", "stiffness"):
        np.testing.assert_array_equal(np.asarray(getattr(model2, f)), np.asarray(getattr(sol.problem.model, f)))
    # as a Solution: the same histories, bit for bit, and its methods work
    back = jaxtree.load_result(path)
    assert isinstance(back, jaxtree.Solution) and back.ok
    for f in ("ts", "gamma", "gamma_dot", "omega0", "dcm", "energy", "angular_momentum", "hold_torque", "attitude"):
        np.testing.assert_array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(sol, f)), err_msg=f)
    assert float(back.momentum_drift()) == float(sol.momentum_drift())
    # the mass centers from the system mass center average to zero (mass-weighted)
    rho = ds["body_position"].values
    m = ds["body_mass"].values
    assert np.abs(np.einsum("b,tbi->ti", m, rho)).max() < ROUNDOFF * m.sum()
    # CSV stays as an export
    from jaxtree._src.io import output

    output.save_csv(tmp_path / "run.csv", back)
    table = np.loadtxt(tmp_path / "run.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(table[:, 0], np.asarray(sol.ts))


def test_result_writes_are_atomic(short_run, tmp_path, monkeypatch):
    """A write that fails half way leaves the previous file as it was and no temporary file."""
    import xarray as xr

    path = tmp_path / "run.nc"
    jaxtree.save_result(path, short_run)
    before = path.read_bytes()
    real = xr.Dataset.to_netcdf

    def broken(self, target, *args, **kw):
        real(self, target, *args, **kw)
        with open(target, "r+b") as fh:
            fh.truncate(100)
        raise OSError("disk full")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", broken)
    with pytest.raises(OSError, match="disk full"):
        jaxtree.save_result(path, short_run, attrs={"note": "second"})
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["run.nc"]


def test_a_part_file_round_trips_bit_for_bit_as_the_netcdf_file_does(short_run, tmp_path):
    """A run's part (.npz with a JSON header, written atomically) reads back as the dataset that
    was written, arrays bit for bit, attributes of every type alike; the same dataset through
    NetCDF-4 (the result file) reads back with the same values. A file that is not a part is
    refused, and a part of an older jaxtree (.nc) still reads."""
    ds = results.solution_to_dataset(short_run, {"solver": "Dopri8", "rtol": 1e-9, "small": np.arange(3)})
    ds["resume_gamma"] = ("hinge", np.asarray(short_run.gamma[-1]))
    part = result_files.write_part_file(ds, tmp_path / "p" / "part-00000.npz")
    assert [q.name for q in part.parent.iterdir()] == ["part-00000.npz"]  # no temporary file left
    back = result_files.read_part_file(part)
    nc = result_files.write_netcdf(ds, tmp_path / "p.nc")
    via_nc = result_files.read_part_file(nc)
    assert set(back.coords) == set(ds.coords) and set(back.data_vars) == set(ds.data_vars)
    for name in [*ds.coords, *ds.data_vars]:
        assert back[name].dims == ds[name].dims, name
        np.testing.assert_array_equal(back[name].values, ds[name].values, err_msg=str(name))
        np.testing.assert_array_equal(back[name].values, via_nc[name].values, err_msg=str(name))
        assert back[name].attrs.keys() == ds[name].attrs.keys(), name
    assert back.attrs.keys() == ds.attrs.keys()
    for k, v in ds.attrs.items():
        np.testing.assert_array_equal(back.attrs[k], v, err_msg=k)
        assert type(back.attrs[k]) is type(v) or isinstance(v, np.ndarray), k
    np.savez(tmp_path / "other.npz", header=np.asarray('{"format": "x"}'))
    with pytest.raises(ValueError, match="not a part of a jaxtree run"):
        result_files.read_part_file(tmp_path / "other.npz")


def test_load_result_reports_missing_and_foreign_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        jaxtree.load_result(tmp_path / "nothing.nc")
    import xarray as xr

    xr.Dataset({"x": ("t", np.arange(3.0))}).to_netcdf(tmp_path / "other.nc", engine="h5netcdf")
    with pytest.raises(ValueError, match="not a jaxtree result"):
        jaxtree.load_result(tmp_path / "other.nc")


def test_modes_result_round_trip(tmp_path):
    model = jaxtree.load_scene("fig4")
    small = (5, 6, 7, 8, 9, 10)
    md = jaxtree.modes(jaxtree.linearize(model, small, omega0=jnp.array([0.0, 0.0, 0.2])))
    result_files.write_netcdf(results.modes_dataset(model, md, small=small, omega0=[0, 0, 0.2]), tmp_path / "m.nc")
    back = jaxtree.load_result(tmp_path / "m.nc")
    assert isinstance(back, jaxtree.Modes) and back.kind == md.kind == "gyroscopic"
    for f in ("eigenvalues", "frequencies", "damping_ratios", "shapes", "right", "left", "P", "Q", "B"):
        np.testing.assert_array_equal(np.asarray(getattr(back, f)), np.asarray(getattr(md, f)), err_msg=f)
    assert back.labels == md.labels
    ds = jaxtree.load_result(tmp_path / "m.nc", as_dataset=True)
    shape = ds["hinge_shape"].values
    assert np.all(shape[:4] == 0) and np.all(np.abs(shape[4:]).max(0) > 0)


# ----------------------------------------------------------------------------- plots
def _hub_and_panel(offset=True):
    hub = jaxtree.Body("hub", 100.0, np.diag([30.0, 40.0, 50.0]))
    panel = jaxtree.Body(
        "panel",
        4.0,
        np.diag([0.2, 0.5, 0.6]),
        parent="hub",
        axis=[0, 1, 0],
        hinge_on_parent=[1.0, 0.0, 0.2] if offset else [0, 0, 0],
        hinge_on_body=[-0.5, 0.0, 0.0] if offset else [0, 0, 0],
        joint=jaxtree.SpringDamper(50.0),
    )
    return jaxtree.build_model([hub, panel], name="hub_panel")


def test_tree_segments_of_a_hinged_panel_match_the_closed_form():
    """Hub and one panel hinged about b2: the panel's mass center sits at p + R_2(a) (0.5, 0, 0)
    from the hub's, and the drawing is measured from the system mass center."""
    from jaxtree._src.io.mode_plots import tree_segments

    model = _hub_and_panel()
    a = 0.4
    seg = tree_segments(model, jnp.array([a]))
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    p, q = np.array([1.0, 0.0, 0.2]), np.array([0.5, 0.0, 0.0])
    d = p + R @ q
    hub = -4.0 / 104.0 * d
    np.testing.assert_allclose(seg[0], np.stack([hub, hub + p, hub + d]), atol=ROUNDOFF_SEGMENTS)


def test_plots_draw_the_given_data(short_run, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    from jaxtree._src.io import history_plots, mode_plots, work_precision_plot

    sol = short_run
    fig = history_plots.plot_histories(sol, tmp_path / "h.png")
    line = fig.axes[0].lines[0]
    np.testing.assert_array_equal(line.get_ydata(), np.asarray(sol.gamma)[:, 0])
    fig = history_plots.plot_drift(sol, tmp_path / "d.png")
    E = np.asarray(sol.energy)
    np.testing.assert_allclose(fig.axes[0].lines[0].get_ydata(), E - E[0])  # J
    fig = work_precision_plot.plot_work_precision(
        {"a": ([1e-6, 1e-3, 1e-9], [0.2, 0.1, 0.4]), "b": {"error": [1e-4], "time": [0.3]}}, tmp_path / "w.png"
    )
    ax = fig.axes[0]
    assert ax.get_xscale() == "log" and ax.get_yscale() == "log"
    np.testing.assert_array_equal(ax.lines[0].get_xdata(), [0.1, 0.2, 0.4])
    np.testing.assert_array_equal(ax.lines[0].get_ydata(), [1e-3, 1e-6, 1e-9])
    model = _hub_and_panel()
    fig = mode_plots.plot_mode_shapes(model, np.array([[1.0]]), [7.0], tmp_path / "s.png", amplitude=0.3)
    blue = [ln for ln in fig.axes[0].lines if ln.get_color() == "C0"][0]
    seg = mode_plots.tree_segments(model, jnp.array([0.3]))[0]
    np.testing.assert_allclose(np.stack(blue.get_data_3d(), 1), seg, atol=ROUNDOFF_SEGMENTS)
    for name in ("h.png", "d.png", "w.png", "s.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
