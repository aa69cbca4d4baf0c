"""The ``jaxtree`` command line: subcommands, one-line errors, result files written in parts,
and an interrupted run that resumes to the same answer.

Most commands run in this process (``jaxtree._src.cli.main``), sharing compiled functions; the
interruption test runs the command in subprocesses and kills them."""

import concurrent.futures
import contextlib
import io
import json
import os
import pathlib
import signal
import subprocess
import sys
import time
import types
import warnings

import jax
import numpy as np
import pytest

import jaxtree
from jaxtree._src import cli

# one configuration shared by the in-process run and the interrupted subprocess runs
T1, POINTS, CHUNKS = "1", "21", "4"
# the run at the default rtol = atol = 1e-9: its reported error estimate (the difference from a run at 10x
# the tolerances) within a thousand times that, and its angular momentum (no loads) conserved to it
ESTIMATE = 1e-6
DRIFT = 1e-9
# float64 round-off: the damped run's energy never rises by more (relative), and the modes command's
# frequency against its closed form
ROUNDOFF = 1e-12
# --hybrid-small against the full Eq. (1): Eq. (30) drops terms of second order in the amplitude, with this
# coefficient (observed 4e-4 rad for amplitudes of 0.05-0.08 rad)
SECOND_ORDER = 0.5


def _args(out, *extra):
    return [
        "simulate",
        "wings",
        "--t1",
        T1,
        "--points",
        POINTS,
        "--chunks",
        CHUNKS,
        "--out",
        str(out),
        "--no-progress",
        *extra,
    ]


_PRINTED = {}  # what the module's runs printed


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """`jaxtree simulate` of wings over 1 s in 4 parts, in this process, with the CSV export,
    the plots and the error estimate."""
    folder = tmp_path_factory.mktemp("cli")
    out = folder / "wings.nc"
    with contextlib.redirect_stdout(io.StringIO()) as printed:
        rc = cli.main(_args(out, "--csv", str(folder / "wings.csv"), "--plot", str(folder / "wings")))
    assert rc == 0
    _PRINTED["run"] = printed.getvalue()
    return out, jaxtree.load_result(out, as_dataset=True)


def test_the_summary_names_what_the_dampers_took(run):
    """The energy line explains the drift by what happened: the wings' dampers took a share of the
    energy, the one the result's energy series shows (not a drift of the integrator)."""
    _, ds = run
    E = ds["energy"].values
    assert E[-1] < E[0]
    assert f"dampers dissipated {(E[0] - E[-1]) / E[0]:.1%} of it" in _PRINTED["run"]


def test_simulate_writes_a_complete_result_within_its_error_estimate(run):
    out, ds = run
    a = ds.attrs
    assert a["complete"] == 1 and a["parts"] == 4 and a["result"] == "ok" and ds.sizes["time"] == int(POINTS)
    assert not out.with_name(out.name + ".parts").exists()
    for key in (
        "solver",
        "rtol",
        "atol",
        "steps_accepted",
        "jaxtree_version",
        "jax_version",
        "diffrax_version",
        "date",
        "scene",
        "command",
    ):
        assert key in a, key
    assert a["solver"] == "Dopri8" and a["rtol"] == 1e-9
    # against an independent tight run: the error lies within the reported estimate (the
    # difference from a run at 10x the tolerances)
    model = jaxtree.load_scene("wings")
    ref = jaxtree.simulate(model, 1.0, saveat=int(POINTS), rtol=1e-12, atol=1e-12)
    err = np.abs(ds["gamma"].values - np.asarray(ref.gamma)).max()
    assert 0 < err <= a["error_estimate_gamma"] < ESTIMATE
    # physics: no external loads (angular momentum conserved), dampers only dissipate energy
    assert a["momentum_drift"] < DRIFT
    E = ds["energy"].values
    assert np.all(np.diff(E) <= ROUNDOFF * E[0]) and E[-1] < E[0]
    folder = out.parent
    assert np.loadtxt(folder / "wings.csv", delimiter=",", skiprows=1).shape[0] == int(POINTS)
    for name in ("wings_histories.png", "wings_drift.png"):
        assert (folder / name).read_bytes()[:4] == b"\x89PNG"


def _wait_for_parts(parts_dir, count, proc, timeout=300):
    start = time.time()
    while time.time() - start < timeout:
        if parts_dir.is_dir() and len(list(parts_dir.glob("part-*.npz"))) >= count:
            return
        if proc.poll() is not None:
            raise AssertionError(f"the run ended before writing {count} parts: {proc.communicate()}")
        time.sleep(0.05)
    raise AssertionError("no part written in time")


def test_killed_and_interrupted_runs_are_readable_and_resume_to_the_same_answer(run, tmp_path):
    """SIGKILL after the first part: the part computed so far reads back. --resume, then SIGINT
    after its first part: exit status 130 and a readable partial file. --resume again finishes.
    Every part starts from the exact state the previous part wrote (float64 stored as is), and
    the same compiled program runs each part, so the result equals the uninterrupted run of the
    same chunking bit for bit."""
    _, full = run
    out = tmp_path / "k.nc"
    parts_dir = tmp_path / "k.nc.parts"
    cmd = [sys.executable, "-m", "jaxtree"] + _args(out, "--no-plot", "--no-error-estimate")
    slow = dict(os.environ, **{cli.CHUNK_DELAY_ENV: "1.5"})
    keys = ("gamma", "gamma_dot", "omega0", "dcm", "energy", "angular_momentum", "attitude", "body_position")

    p = subprocess.Popen(cmd, env=slow, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _wait_for_parts(parts_dir, 1, p)
    p.kill()
    p.communicate()  # waits, and closes the pipes (an unclosed one is a ResourceWarning, an error here)
    assert p.returncode == -signal.SIGKILL
    part = jaxtree.load_result(out, as_dataset=True)
    assert part.attrs["complete"] == 0 and part.sizes["time"] == 6  # grid points 0..5 of 21
    for k in keys:
        np.testing.assert_array_equal(part[k].values, full[k].values[:6], err_msg=k)

    p = subprocess.Popen(cmd + ["--resume"], env=slow, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    _wait_for_parts(parts_dir, 2, p)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=120)
    assert p.returncode == cli.EXIT_INTERRUPTED, err
    assert b"--resume" in err and b"Traceback" not in err
    part = jaxtree.load_result(out, as_dataset=True)
    assert part.attrs["complete"] == 0 and part.sizes["time"] == 11

    done = subprocess.run(cmd + ["--resume"], capture_output=True, timeout=300)
    assert done.returncode == 0, done.stderr
    ds = jaxtree.load_result(out, as_dataset=True)
    assert ds.attrs["complete"] == 1 and not parts_dir.exists()
    for k in keys:
        np.testing.assert_array_equal(ds[k].values, full[k].values, err_msg=k)
    assert ds.attrs["steps_accepted"] == full.attrs["steps_accepted"]


def _bad_scene(tmp_path):
    data = json.loads(jaxtree.scene_path("wings").read_text())
    data["bodies"][3]["mass"] = -1.0
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    return path


def test_user_mistakes_print_one_line_and_exit_nonzero(tmp_path, capsys):
    bad = _bad_scene(tmp_path)
    (tmp_path / "broken.json").write_text("{ not json")
    (tmp_path / "garbage.nc").write_text("not a netcdf file")
    cases = [
        (["check", str(tmp_path / "missing.json")], "does not exist"),
        (["check", "nosuchscene"], "no bundled scene"),
        (["check", str(bad)], "body 3 ('wingp_3'): field 'mass'"),
        (["check", str(tmp_path / "broken.json")], "not valid JSON"),
        (["simulate", "wings"], "--t1"),
        (["simulate", "wings", "--t1", "x"], "--t1"),
        (["simulate", "wings", "--t1", "1", "--rtol", "-1"], "--rtol"),
        # a negative number in exponent form is a value, refused by the option's own check
        (["simulate", "wings", "--t1", "1", "--rtol", "-1e-6"], "must be a positive number"),
        (["simulate", "wings", "--t1", "1", "--atol", "-.5E+2"], "--atol"),
        (["simulate", "wings", "--t1", "1", "--attitude", "euler"], "--attitude"),
        (["simulate", "wings", "--t1", "1", "--solver", "rk99"], "--solver"),
        (["simulate", "wings", "--t1", "0"], "--t1 equals --t0"),
        (["simulate", "wings", "--t1", "1", "--modes", "2"], "--hybrid-small"),
        (["simulate", "wings", "--t1", "1", "--hybrid-small", "99", "--out", str(tmp_path / "h.nc")], "99"),
        (["simulate", "wings", "--t1", "1", "--resume", "--out", str(tmp_path / "none.nc")], "no interrupted run"),
        (["simulate", str(bad), "--t1", "1"], "field 'mass'"),
        (["modes", "wings", "--small", "nosuch"], "nosuch"),
        (["modes", "fig4", "--small", "1"], "prescribed"),
        (["animate", str(tmp_path / "missing.nc"), "-o", str(tmp_path / "x.html")], "does not exist"),
        (["animate", str(tmp_path / "garbage.nc"), "-o", str(tmp_path / "x.html")], "cannot be read"),
        (["plot", str(tmp_path / "missing.nc")], "does not exist"),
        (["frobnicate"], "invalid choice"),
        (["sample", "--scene", str(tmp_path / "missing.json")], "does not exist"),
        (["--duration", "x"], "--duration"),
    ]
    for argv, needle in cases:
        rc = cli.main(argv)
        captured = capsys.readouterr()
        lines = [ln for ln in captured.err.splitlines() if ln.strip()]
        assert rc == cli.EXIT_USAGE, (argv, captured.err)
        assert len(lines) == 1 and needle in lines[0] and "error" in lines[0], (argv, captured.err)
        assert "Traceback" not in captured.err + captured.out
    assert not (tmp_path / "h.nc").exists() and not (tmp_path / "x.html").exists()


def test_help_of_every_subcommand(capsys):
    for sub in ("simulate", "modes", "animate", "check", "plot", "identify", "bench"):
        with pytest.raises(SystemExit) as e:
            cli.main([sub, "--help"])
        assert e.value.code == 0
        assert f"jaxtree {sub}" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    assert all(s in out for s in ("simulate", "modes", "animate", "check", "identify", "sample problem"))
    # the sample problem's own help names the command it was reached by (not `python -m jaxtree`)
    with pytest.raises(SystemExit):
        cli.main(["sample", "--help"])
    assert capsys.readouterr().out.startswith("usage: jaxtree sample")


def test_a_backward_interval_is_refused_in_one_line(capsys):
    assert cli.main(["simulate", "wings", "--t1", "-3"]) == cli.EXIT_USAGE
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--t1 -3 is before --t0 0" in err


def test_no_subcommand_runs_the_sample_problem(monkeypatch):
    """`python -m jaxtree` (no arguments) and its options-only forms still run the sample problem."""
    import jaxtree.__main__ as entry
    from jaxtree._src.cli import dispatch  # main looks `sample` up there

    calls = []
    monkeypatch.setattr(dispatch, "sample", lambda argv: calls.append(list(argv)) or 0)
    assert entry.main([]) == 0 and cli.main(["--duration", "5", "--no-plot"]) == 0 and cli.main(["sample"]) == 0
    assert calls == [[], ["--duration", "5", "--no-plot"], []]


def test_check_command_prints_tree_tables_masses_and_condition(capsys):
    assert cli.main(["check", "fig4"]) == 0
    out = capsys.readouterr().out
    for text in (
        "Table 1: network elements",
        "Table 2: path elements",
        "`-- 4 rotor",
        "total 1130 kg",
        "condition number of Eq. (1)",
    ):
        assert text in out, text
    c = jaxtree.condition(jaxtree.load_scene("fig4"))
    assert f"{float(c.number):.3g}" in out


@pytest.fixture(scope="module")
def modes_run(tmp_path_factory):
    """`jaxtree modes` of a hub with one offset panel (a scene file written here)."""
    folder = tmp_path_factory.mktemp("modes")
    hub = jaxtree.Body("hub", 100.0, np.diag([30.0, 40.0, 50.0]))
    panel = jaxtree.Body(
        "panel",
        4.0,
        np.diag([0.2, 0.5, 0.6]),
        parent="hub",
        axis=[0, 1, 0],
        hinge_on_parent=[1.0, 0.0, 0.0],
        hinge_on_body=[-0.5, 0.0, 0.0],
        joint=jaxtree.SpringDamper(50.0),
    )
    scene = folder / "hub_panel.json"
    jaxtree.save_scene(jaxtree.build_model([hub, panel], name="hub_panel"), scene)
    out = folder / "m.nc"
    rc = cli.main(["modes", str(scene), "--small", "panel", "--out", str(out), "--plot", str(folder / "m.png")])
    assert rc == 0
    return out


def test_modes_command_matches_the_closed_form(modes_run, capsys):
    """Hub held in attitude (Eq. 40), free to translate: the panel turns about its hinge with
    inertia B2 + mu d^2 (mu the reduced mass, d = 0.5 m), sigma^2 = k / (B2 + mu d^2)."""
    ds = jaxtree.load_result(modes_run, as_dataset=True)
    mu = 100.0 * 4.0 / 104.0
    sigma = np.sqrt(50.0 / (0.5 + mu * 0.25))
    np.testing.assert_allclose(ds["frequency"].values, [sigma], rtol=ROUNDOFF)
    np.testing.assert_array_equal(ds["hinge_shape"].values != 0, [[True]])
    assert ds.attrs["kind"] == "modes" and ds["frequency"].attrs["units"] == "rad s-1"
    assert (modes_run.parent / "m.png").read_bytes()[:4] == b"\x89PNG"


def _stand_in_viewer(monkeypatch):
    calls = []

    def write_animation(path, model, ts, dcm, gamma, *, title=None, appendages=None):
        assert not appendages  # the wings run has no finite-element appendage
        calls.append(("trajectory", path, model, ts, dcm, gamma, title))

    def write_mode_animation(path, model, shape, frequency, *, gamma=None, amplitude=None, title=None):
        calls.append(("mode", path, model, shape, frequency, gamma, amplitude, title))

    fake = types.ModuleType("jaxtree._src.io.viewer")
    fake.write_animation, fake.write_mode_animation = write_animation, write_mode_animation
    monkeypatch.setitem(sys.modules, "jaxtree._src.io.viewer", fake)
    monkeypatch.setattr(jaxtree._src.io, "viewer", fake, raising=False)
    return calls


def test_animate_passes_the_result_to_the_viewer(run, modes_run, tmp_path, monkeypatch, capsys):
    """animate calls the viewer's API with the result's arrays and the model of its scene (a
    stand-in records the calls; the viewer itself has its own tests)."""
    out, ds = run
    calls = _stand_in_viewer(monkeypatch)
    assert cli.main(["animate", str(out), "-o", str(tmp_path / "a.html")]) == 0
    kind, path, model, ts, dcm, gamma, title = calls[-1]
    assert kind == "trajectory" and path == str(tmp_path / "a.html") and model.name == "wings"
    np.testing.assert_array_equal(ts, ds["time"].values)
    np.testing.assert_array_equal(dcm, ds["dcm"].values)
    np.testing.assert_array_equal(gamma, ds["gamma"].values)
    assert (
        cli.main(["animate", str(modes_run), "-o", str(tmp_path / "m.html"), "--mode", "1", "--amplitude", "0.2"]) == 0
    )
    kind, path, model, shape, freq, gamma0, amplitude, title = calls[-1]
    md = jaxtree.load_result(modes_run, as_dataset=True)
    assert kind == "mode" and model.name == "hub_panel" and amplitude == 0.2 and "mode 1" in title
    np.testing.assert_array_equal(shape, md["hinge_shape"].values[:, 0])
    assert freq == float(md["frequency"].values[0]) and np.all(gamma0 == 0)
    assert cli.main(["animate", str(modes_run), "-o", str(tmp_path / "m.html"), "--mode", "2"]) == cli.EXIT_USAGE
    assert cli.main(["animate", str(out), "-o", str(tmp_path / "a.html"), "--mode", "1"]) == cli.EXIT_USAGE
    capsys.readouterr()


def test_plot_command_writes_the_plots_of_a_result(run, modes_run, tmp_path, capsys):
    out, _ = run
    assert cli.main(["plot", str(out), "-o", str(tmp_path / "r")]) == 0
    assert cli.main(["plot", str(modes_run), "-o", str(tmp_path / "m")]) == 0
    for name in ("r_histories.png", "r_drift.png", "m_shapes.png"):
        assert (tmp_path / name).read_bytes()[:4] == b"\x89PNG"
    assert "overwrote" not in capsys.readouterr().out
    # again: the same files, now said to be overwritten
    assert cli.main(["plot", str(modes_run), "-o", str(tmp_path / "m")]) == 0
    assert f"(overwrote {tmp_path / 'm_shapes.png'})" in capsys.readouterr().out


def test_a_failed_run_keeps_what_it_computed_and_reports_where_it_stopped(tmp_path, capsys):
    """A step limit stops the run in its first part: exit status 1, the diagnosis (time and state)
    on stderr, and a result file with the rows before the stop and the result code."""
    out = tmp_path / "f.nc"
    rc = cli.main(_args(out, "--max-steps", "3", "--no-plot"))
    captured = capsys.readouterr()
    assert rc == cli.EXIT_FAILED
    assert "maximum number of solver steps" in captured.err and "stopped at t =" in captured.err
    ds = jaxtree.load_result(out, as_dataset=True)
    assert ds.attrs["result"] == "max_steps" and ds.attrs["complete"] == 1
    t_final = ds.attrs["t_final"]
    assert 0 < t_final < float(T1) and ds["time"].values[-1] <= t_final
    sol = jaxtree.load_result(out)
    assert not sol.ok
    with pytest.raises(jaxtree.SimulationError, match="maximum number of solver steps"):
        sol.check()


def test_hybrid_simulation_follows_the_full_equations_at_small_amplitude(tmp_path, capsys):
    """--hybrid-small with every mode kept integrates Eq. (30) (Eq. 1 linearized in the small
    hinges): for wings' 0.05-0.08 rad panel motion it follows the full Eq. (1) to second order
    in the amplitude (observed 4e-4 rad), part after part."""
    out = tmp_path / "h.nc"
    rc = cli.main(
        [
            "simulate",
            "wings",
            "--t1",
            "0.5",
            "--points",
            "11",
            "--chunks",
            "2",
            "--hybrid-small",
            "1-4",
            "--out",
            str(out),
            "--no-plot",
            "--no-error-estimate",
            "--no-progress",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    ds = jaxtree.load_result(out, as_dataset=True)
    assert ds.attrs["hybrid_small"] == "1-4" and ds["modal"].dims == ("time", "modal_coordinate")
    ref = jaxtree.simulate(jaxtree.load_scene("wings"), 0.5, saveat=11)
    amplitude = np.abs(np.asarray(ref.gamma)).max()
    assert np.abs(ds["gamma"].values - np.asarray(ref.gamma)).max() < SECOND_ORDER * amplitude**2
    assert np.abs(ds["omega0"].values - np.asarray(ref.omega0)).max() < SECOND_ORDER * amplitude**2
    capsys.readouterr()


# the order of each method, from its authors (Hairer & Wanner; Kennedy & Carpenter; Kvaerno;
# Tsitouras; Bogacki & Shampine)
_ORDERS = {"Dopri8": 8, "Dopri5": 5, "Tsit5": 5, "Bosh3": 3, "Heun": 2, "Kvaerno3": 3, "Kvaerno4": 4,
           "Kvaerno5": 5, "KenCarp4": 4, "Radau5": 5}  # fmt: skip


def test_every_solver_name_builds_that_method():
    """`--solver NAME` (and "auto"'s choice, Radau5 on stiff scenes) builds the method of that
    name, of the order its authors give, on the terms `simulate` hands it."""
    from jaxtree._src.cli import SOLVERS, solver_named
    from jaxtree._src.integration.core import terms

    assert set(SOLVERS.values()) - {"auto"} == set(_ORDERS)
    for flag, name in SOLVERS.items():
        if name == "auto":
            continue
        solver = solver_named(name)
        assert type(solver).__name__ == name and flag == name.lower(), (flag, solver)
        assert solver.order(terms(solver, lambda t, y, args: -y)) == _ORDERS[name], name
    assert isinstance(solver_named("Radau5"), jaxtree.Radau5)


def test_what_import_changes_and_its_opt_outs():
    """`import jaxtree` turns on JAX's x64 mode and sets OPENBLAS_NUM_THREADS=1, each with the
    opt-out the README documents: JAXTREE_ENABLE_X64=0 leaves x64 off, a user's thread count wins,
    and with an accelerator as JAX's default platform the thread setting is not made (its
    workaround serves the CPU backend's LAPACK). Fresh interpreters, so this process's settings do
    not leak in."""
    probe = "import os, jax, jaxtree; print(jax.config.jax_enable_x64, os.environ.get('OPENBLAS_NUM_THREADS', 'unset'))"
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("JAXTREE_ENABLE_X64", "OPENBLAS_NUM_THREADS", "JAX_ENABLE_X64", "JAX_PLATFORMS")
    }

    def run(**extra):
        out = subprocess.run(
            [sys.executable, "-c", probe], env={**env, **extra}, capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 0, out.stderr
        return out.stdout.split()

    assert run(JAX_PLATFORMS="cpu") == ["True", "1"]
    assert run(JAXTREE_ENABLE_X64="0", OPENBLAS_NUM_THREADS="3") == ["False", "3"]
    assert run(JAX_PLATFORMS="cuda") == ["True", "unset"]


def test_import_gives_the_cpu_a_device_per_core_unless_told_otherwise():
    """On the CPU, `import jaxtree` gives JAX one device per core the process may use (so that a
    campaign's chunks run on every core), JAXTREE_HOST_DEVICES sets another count or keeps one, a
    count set in XLA_FLAGS wins, and a backend already started is left as it is. Fresh
    interpreters: the count is read when JAX's backend starts."""
    env = {k: v for k, v in os.environ.items() if k not in ("JAXTREE_HOST_DEVICES", "JAX_PLATFORMS")}
    env["XLA_FLAGS"] = env.get("XLA_FLAGS", "").replace("--xla_force_host_platform_device_count", "--unused")

    def count(code="import jax, jaxtree", **extra):
        probe = code + "; print(len(jax.devices()))"
        out = subprocess.run(
            [sys.executable, "-c", probe], env={**env, **extra}, capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 0, out.stderr
        return int(out.stdout.split()[-1])

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    assert count() == cores
    assert count(JAXTREE_HOST_DEVICES="1") == 1
    assert count(JAXTREE_HOST_DEVICES="off") == 1
    assert count(JAXTREE_HOST_DEVICES="3") == 3
    flags = env["XLA_FLAGS"] + " --xla_force_host_platform_device_count=3"
    assert count(XLA_FLAGS=flags, JAXTREE_HOST_DEVICES="2") == 3
    assert count("import jax; jax.devices(); import jaxtree") == 1


def test_own_programs_take_the_cpu_compiler_options():
    """jaxtree's top-level programs (a solve, its diagnostics) compile on a CPU with XLA's older
    fusion emitters, set per program: not in a process whose XLA_FLAGS names the option, and not
    for a call inside the user's trace (JAX takes options only on a top-level jit), where the
    program is the plain one. The results agree either way. Fresh interpreters (the suite's own
    XLA_FLAGS name the option)."""
    probe = (
        "import jax, jax.numpy as jnp, jaxtree; from jaxtree._src import numerics; "
        "f = numerics.program_jit(lambda x, k: jnp.sin(x) * k); x = jnp.linspace(0, 1, 4); "
        "top = f(x, 2.0); inner = jax.jit(lambda x: f(x, 2.0))(x); v = jax.vmap(lambda x: f(x, 2.0))(x); "
        "g = jax.grad(lambda x: f(x, 2.0).sum())(x); "
        "print(numerics._program_options(), bool(jnp.allclose(top, inner) & jnp.allclose(top, v) "
        "& jnp.allclose(g, 2.0 * jnp.cos(x)) & jnp.allclose(top, 2.0 * jnp.sin(x))))"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_PLATFORMS")}

    def run(**extra):
        out = subprocess.run(
            [sys.executable, "-c", probe], env={**env, **extra}, capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 0, out.stderr
        return out.stdout.strip()

    from jaxtree._src.numerics import legacy_cpu_emitters

    if legacy_cpu_emitters():
        assert run() == "{'xla_cpu_use_fusion_emitters': False} True"
        assert run(XLA_FLAGS="--xla_cpu_use_fusion_emitters=true") == "None True"
    else:  # jaxlib >= 0.11: the option is gone (and the flag would abort the process)
        assert run() == "None True"


def test_compiler_options_only_where_xla_has_them(monkeypatch):
    """jaxlib >= 0.11 has no ``xla_cpu_use_fusion_emitters``: a program compiled with it fails
    ("No such compile option") and an XLA_FLAGS naming it aborts the process at the backend's
    start. Without the older emitters jaxtree neither passes the option nor sets the flag."""
    from jaxtree._src import numerics
    from jaxtree._src.cli.common import fast_cpu_compiler

    monkeypatch.setattr(numerics, "legacy_cpu_emitters", lambda: False)
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=0")
    assert numerics._program_options() is None
    assert numerics._program_options(numerics.LIGHT_COMPILER_OPTIONS) is None  # named by XLA_FLAGS
    assert numerics._program_options(numerics.REPRODUCIBLE_OPTIONS) == numerics.REPRODUCIBLE_OPTIONS
    assert numerics.fast_cpu_flags() == ""
    fast_cpu_compiler()
    assert os.environ["XLA_FLAGS"] == "--xla_backend_optimization_level=0"
    monkeypatch.setattr(numerics, "legacy_cpu_emitters", lambda: True)
    monkeypatch.setenv("XLA_FLAGS", "")
    assert numerics._program_options() == numerics.CPU_COMPILER_OPTIONS
    fast_cpu_compiler()
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_use_fusion_emitters=false"


def test_persistent_compilation_cache(tmp_path):
    """`import jaxtree` turns on JAX's persistent compilation cache: a second process finds there
    what a first compiled. JAXTREE_CACHE_DIR moves it or (0) turns it off; a directory set for
    JAX itself wins. Fresh interpreters; JAX's own threshold of compile time lowered to 0 so that
    a small program is written."""
    probe = (
        "import jax, jaxtree; hits = []; "
        "jax.monitoring.register_event_listener(lambda e, **k: hits.append(e) if 'cache_hits' in e else None); "
        "jax.jit(lambda x: jax.numpy.sin(x) * 2.0 + x)(1.0).block_until_ready(); "
        "print(jax.config.jax_compilation_cache_dir, len(hits))"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAXTREE_CACHE", "JAX_COMPILATION_CACHE"))}
    env["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] = "0"

    def run(**extra):
        out = subprocess.run(
            [sys.executable, "-c", probe], env={**env, **extra}, capture_output=True, text=True, timeout=120
        )
        assert out.returncode == 0, out.stderr
        return out.stdout.split()

    where = str(tmp_path / "cache")
    assert run(JAXTREE_CACHE_DIR=where) == [where, "0"]  # compiled and written
    assert any(pathlib.Path(where).iterdir())
    assert run(JAXTREE_CACHE_DIR=where) == [where, "1"]  # read back
    assert run(JAXTREE_CACHE_DIR="0") == ["None", "0"]
    mine = str(tmp_path / "mine")
    assert run(JAXTREE_CACHE_DIR=where, JAX_COMPILATION_CACHE_DIR=mine)[0] == mine
    base = str(tmp_path / "xdg")
    assert run(XDG_CACHE_HOME=base)[0] == os.path.join(base, "jaxtree", "xla")


def test_equinox_checks_inside_jaxtrees_solves_have_no_host_callback():
    """Inside `checks_without_callbacks` an `eqx.error_if` traces to a select (NaN on error), not
    a host callback, so JAX may cache the program; outside, and after, equinox's own check (a
    callback that raises) is back. (Each trace its own function: JAX keeps a function's trace.)"""
    import equinox as eqx

    from jaxtree._src.cache import checks_without_callbacks

    def check():
        return lambda x: eqx.error_if(x, x < 0, "negative")

    def callbacks(fn):
        return str(jax.make_jaxpr(fn)(1.0)).count("callback")

    before = callbacks(check())
    with checks_without_callbacks():
        inside = callbacks(check())
        assert np.isnan(float(jax.jit(check())(-1.0)))
        # the scope is this thread's: another thread tracing meanwhile keeps equinox's checks
        # (the main job traces its error-estimate runs on worker threads)
        with concurrent.futures.ThreadPoolExecutor(1) as pool:
            elsewhere = pool.submit(lambda: callbacks(check())).result()
    assert before > 0 and inside == 0 and elsewhere == before and callbacks(check()) == before
    with pytest.raises(Exception, match="negative"):
        jax.block_until_ready(jax.jit(check())(-1.0))


def test_the_simulation_program_is_written_to_the_persistent_cache(tmp_path):
    """A second process reads `simulate`'s program back from the cache instead of compiling it
    (it used to be compiled in every process: equinox's checks inside diffrax were host
    callbacks). Fresh interpreters; a 0.2 s run of appendix_c."""
    probe = (
        "import jax, jaxtree; hits = []; "
        "jax.monitoring.register_event_listener(lambda e, **k: hits.append(e) if 'cache_hits' in e else None); "
        "jaxtree.simulate(jaxtree.load_scene('appendix_c'), 0.2, saveat=3, rtol=1e-6, atol=1e-6); "
        "print(len(hits))"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAXTREE_CACHE", "JAX_COMPILATION_CACHE"))}
    env.update(JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0", JAXTREE_CACHE_DIR=str(tmp_path / "cache"))

    def run():
        out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        return int(out.stdout.split()[-1])

    assert run() == 0
    solve = [p for p in (tmp_path / "cache").iterdir() if "_solve" in p.name]
    assert solve, sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert run() >= len(solve)


def test_solver_lists_agree_with_the_code(capsys):
    """`--solver`'s choices, its help and the guide's list name the same solvers, and both say
    what "auto" picks between (the classes autosolver returns: Dopri8 or Radau5)."""
    import pathlib

    from jaxtree._src.integration import autosolver

    with pytest.raises(SystemExit):
        cli.main(["simulate", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    guide = (pathlib.Path(__file__).parents[1] / "docs" / "guide.md").read_text()
    sentence = " ".join(guide[guide.index("`--solver` (") :].split(")")[0].split())
    stiff = autosolver.Radau5.__name__.lower()
    explicit = type(autosolver.choose_solver(jaxtree.load_scene("appendix_c"), 1.0)[0]).__name__.lower()
    for name in sorted(cli.SOLVERS):
        assert name in sentence, name
    assert f"auto: {explicit} or {stiff}, whichever" in help_text and f"{explicit} or {stiff}, whichever" in sentence
    assert "kvaerno3/4/5" in help_text and "kencarp4" in help_text and "radau5," in help_text


def test_a_warning_is_one_line_without_a_source_location(capsys):
    """A warning reaches the terminal as one line, ``jaxtree check: warning: ...``, not Python's
    three lines naming the launcher script; Python's own display comes back afterwards."""
    before = warnings.showwarning
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # the suite turns warnings into errors; a user's shell does not
        with cli._one_line_warnings("jaxtree check"):
            warnings.warn("a value was\n  clipped", UserWarning, stacklevel=1)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert err == ["jaxtree check: warning: a value was clipped"], err
    assert warnings.showwarning is before


def test_an_unknown_scene_key_is_an_error_of_one_line(tmp_path, capsys):
    """A misspelt top-level key ('intial') is refused, naming the key and the nearest known one,
    before anything runs (it used to warn and simulate the vehicle at rest, exit 0)."""
    data = json.loads(jaxtree.scene_path("wings").read_text())
    data["intial"] = data.pop("initial")
    path = tmp_path / "typo.json"
    path.write_text(json.dumps(data))
    assert cli.main(["simulate", str(path), "--t1", "1", "--out", str(tmp_path / "r.nc")]) == cli.EXIT_USAGE
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "unknown key 'intial'" in err[0] and "did you mean 'initial'" in err[0], err
    assert not (tmp_path / "r.nc").exists()
