"""The solver choice of ``simulate(solver="auto")``, the fixed-step RK4 and IMEX solvers, and the
work-precision report behind ``jaxtree bench``.

Independent sources: the convergence order of RK4 (halving the step divides the error by
2^4), a second solver family (explicit Dopri8 against the implicit choice on the stiff chain),
the dissipation of a damped vehicle (its energy never rises), the conservation of angular
momentum without loads, two references by different solvers agreeing, and Pinocchio's ABA
driven by the same bus torque as flex95's slew.
"""

import csv
import dataclasses
import math
import re

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src import cli

STIFF = jaxtree.stiff_chain(1e8)
# the damped stiff chain run at rtol = atol = 1e-6: its energy may rise per save, and its angular momentum
# (zero at the start) drift, by the run's tolerance, relative to E0 and to _momentum_scale
DRIFT = 1e-6
# "auto" (Radau5) at 1e-9 against Dopri8 at 1e-11 over 20 ms, relative to max(1, peak): a thousand times
# the implicit run's tolerance
IMPLICIT_EXPLICIT = 1e-6
# the error ratio of RK4 when the step halves: 2^4 = 16 (12..20 from the simulate runs, 10..24 from the
# report's rows, whose errors are measured against a reference with its own floor)
RK4_LOW, RK4_HIGH = 12.0, 20.0
REPORT_RK4_LOW, REPORT_RK4_HIGH = 10.0, 24.0
KENCARP4 = 1e-4  # KenCarp4 at rtol = atol = 1e-6 against a run at 1e-13: a hundred times its tolerance
# the report on wings: its two references (at the report's REFERENCE_TOL = 1e-12) agree below
# REFERENCE_FLOOR; Dopri8 at the setting 1e-7 keeps its error within a hundred times the setting and its
# momentum drift within ten times
REFERENCE_FLOOR = 1e-9
DOPRI8_ERROR = 1e-5
MOMENTUM_DRIFT = 1e-6
FALLBACK_FLOOR = 1e-7  # the references at the fallback tolerance 1e-9 agree below a hundred times it
ROUNDOFF = 1e-12  # the peer's numpy torque against the model's load: the same formula, round-off
# flex95's first 2 s, relative to the peaks: Pinocchio + DOP853 against jaxtree's run at 1e-10 (the
# report's cross-check, at 1e-10 in a quick run too), and the peer's row at 1e-8 (a thousand times it)
CROSS_CHECK = 1e-7
PEER_ERROR = 1e-5


def _momentum_scale(model, sol):
    """|H| of the whole vehicle turning rigidly with its initial energy about its stiffest axis:
    the scale of a drift when the vehicle starts with no angular momentum."""
    J = np.asarray(jaxtree.mass_matrix(model, model.initial.gamma))[:3, :3]
    return math.sqrt(2 * float(sol.energy[0]) * np.linalg.eigvalsh(J).max())


def test_auto_picks_an_implicit_solver_for_the_stiffest_chain_and_finishes_in_a_few_hundred_steps():
    sol = jaxtree.simulate(STIFF, 1.0, saveat=jnp.linspace(0.0, 1.0, 21), rtol=1e-6, atol=1e-6)
    choice = sol.stats["solver"]
    assert isinstance(choice, jaxtree.SolverChoice) and choice.auto and choice.name == "Radau5", choice
    assert "stiff" in choice.reason and choice.explicit_steps > 1e5
    assert sol.ok and int(sol.stats["num_accepted_steps"]) < 500, sol.stats
    # a damped vehicle without loads: the energy never rises, the angular momentum (zero at the start) stays
    E = np.asarray(sol.energy)
    assert np.all(np.diff(E) <= DRIFT * E[0]) and E[-1] < E[0]
    H = np.linalg.norm(np.asarray(sol.angular_momentum), axis=1)
    assert H.max() <= DRIFT * _momentum_scale(STIFF, sol)


def test_the_implicit_choice_agrees_with_an_explicit_run_on_the_stiff_chain():
    # over 20 ms Dopri8 needs ~1e4 steps, which a test can afford; "auto" still finds the run stiff
    ts = jnp.linspace(0.0, 0.02, 21)  # the same layout as above: one compilation
    auto = jaxtree.simulate(STIFF, 0.02, saveat=ts, rtol=1e-9, atol=1e-9)
    assert auto.stats["solver"].name == "Radau5"
    explicit = jaxtree.simulate(STIFF, 0.02, saveat=ts, solver=dfx.Dopri8(), rtol=1e-11, atol=1e-11, max_steps=100_000)
    assert int(explicit.stats["num_accepted_steps"]) > 5000  # the stability limit of ~1.5e6 rad/s
    for field in ("gamma", "gamma_dot", "omega0"):
        a, b = np.asarray(getattr(auto, field)), np.asarray(getattr(explicit, field))
        assert np.abs(a - b).max() <= IMPLICIT_EXPLICIT * max(1.0, np.abs(b).max()), field


def test_auto_keeps_dopri8_on_fig4_free_and_records_the_choice():
    model = jaxtree.load_scene("fig4_free")
    solver, choice = jaxtree.choose_solver(model, 10.0)
    assert isinstance(solver, dfx.Dopri8) and choice.name == "Dopri8" and choice.auto
    sol = jaxtree.simulate(model, 0.05, saveat=3)
    assert sol.stats["solver"].name == "Dopri8" and sol.stats["solver"].auto
    given = jaxtree.simulate(jaxtree.stiff_chain(1e2), 0.01, saveat=3, solver=dfx.Tsit5())
    assert given.stats["solver"].name == "Tsit5" and not given.stats["solver"].auto


def test_auto_leaves_fast_undamped_modes_to_an_explicit_solver():
    base = jaxtree.load_scene("chain10")
    stiff = eqx.tree_at(lambda m: m.stiffness, base, base.stiffness * 1e6)  # undamped: nothing decays
    _, choice = jaxtree.choose_solver(stiff, 1.0, rtol=1e-6)
    assert choice.name == "Dopri8", choice
    # the chain starts bent: its fast undamped modes ring far above the tolerance, so Radau5 would
    # have to follow them as well, at more steps than Dopri8's stability needs
    ringing = float(re.search(r"ring above the tolerance \(to ([0-9.e+]+) rad/s\)", choice.reason).group(1))
    assert ringing > 1e3 * 49.0 and choice.implicit_steps > choice.explicit_steps, choice
    # the linearization saw the chain's fastest mode, above the screen's single-hinge estimate
    assert choice.fastest > 1e3 * 49.0


def test_auto_under_tracing_is_the_explicit_default():
    def run(scale):
        model = eqx.tree_at(lambda m: m.stiffness, STIFF, STIFF.stiffness * scale)
        return jaxtree.simulate(model, 1.0, saveat=2).stats["solver"]

    choice = jax.eval_shape(run, 1.0)
    assert choice.name == "Dopri8" and "traced" in choice.reason


def test_rk4_is_fourth_order():
    model = jaxtree.load_scene("appendix_b")
    ts = jnp.linspace(0.0, 2.0, 5)
    ref = jaxtree.simulate(model, 2.0, saveat=ts, rtol=1e-13, atol=1e-13)

    def error(h):
        sol = jaxtree.simulate(
            model, 2.0, saveat=ts, solver=jaxtree.RK4(), stepsize_controller=dfx.ConstantStepSize(), dt0=h
        )
        assert int(sol.stats["num_accepted_steps"]) == round(2.0 / h)
        return np.abs(np.asarray(sol.gamma) - np.asarray(ref.gamma)).max()

    e1, e2 = error(0.02), error(0.01)
    assert RK4_LOW < e1 / e2 < RK4_HIGH, (e1, e2)  # 2^4 = 16


def test_an_imex_solver_runs_with_the_whole_right_side_implicit():
    model = jaxtree.load_scene("appendix_b")
    ts = jnp.linspace(0.0, 0.5, 5)
    ref = jaxtree.simulate(model, 0.5, saveat=ts, rtol=1e-13, atol=1e-13)
    sol = jaxtree.simulate(model, 0.5, saveat=ts, solver=dfx.KenCarp4(), rtol=1e-6, atol=1e-6)
    assert sol.stats["solver"].name == "KenCarp4" and sol.stats["rhs_evaluations"] == -1
    assert np.abs(np.asarray(sol.gamma) - np.asarray(ref.gamma)).max() < KENCARP4


def test_work_precision_measures_error_against_an_independent_reference(tmp_path):
    report = jaxtree.work_precision(
        [jaxtree.bench_case("wings")],
        solvers=["Dopri8", "RK4"],
        tolerances=[1e-7],
        formulations=["full"],
        peers=False,
        repeats=1,
        progress=False,
    )
    ref = report.references["wings"]
    assert ref["primary"] == "Dopri8" and ref["secondary"] == "Tsit5" and ref["floor"] < REFERENCE_FLOOR
    assert report.auto["wings"].startswith("Dopri8 (auto)")
    rows = {(r["solver"], r["setting"]): r for r in report.rows}
    assert all(r["status"] == "ok" and r["time_s"] > 0 for r in rows.values())
    dopri = rows["Dopri8", 1e-7]
    assert ref["floor"] < dopri["error"] < DOPRI8_ERROR and dopri["steps"] > 0 and dopri["compile_s"] >= 0
    # RK4 at fixed steps: the error falls as h^4 (8 -> 16 steps per save interval: 16x)
    assert REPORT_RK4_LOW < rows["RK4", 8]["error"] / rows["RK4", 16]["error"] < REPORT_RK4_HIGH
    # no damping-free energy on a damped scene; the momentum is conserved to the tolerance
    assert math.isnan(dopri["energy_drift"]) and dopri["momentum_drift"] < MOMENTUM_DRIFT
    paths = report.save(tmp_path)
    with open(paths["csv"]) as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == len(report.rows) and {r["solver"] for r in table} == {"Dopri8", "RK4"}
    with open(paths["md"]) as fh:  # closed: an open file is a ResourceWarning, an error in the suite
        text = fh.read()
    assert "## wings (reference)" in text and "floor" in text and "wings.png" in text
    # the findings drawn from the rows: wings' fastest jaxtree run to 1e-6 is Dopri8 (the only adaptive solver here)
    assert "## Findings" in text and "| wings | reference | Dopri8 | Dopri8 " in text
    assert (tmp_path / "work_precision_wings.png").stat().st_size > 1000


def test_bench_command_mistakes_print_one_line(capsys):
    for argv, needle in (
        (["bench", "nosuchcase"], "unknown bench case"),
        (["bench", "--solvers", "rk99"], "rk99"),
        (["bench", "--tols", "-1"], "--tols"),
    ):
        rc = cli.main(argv)
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
        assert rc == cli.EXIT_USAGE and len(err) == 1 and needle in err[0], (argv, err)
    with pytest.raises(SystemExit) as e:
        cli.main(["bench", "--help"])
    assert e.value.code == 0 and "stiff_1e8" in capsys.readouterr().out


def test_reports_run_in_parts_merge_in_case_order(tmp_path):
    """Two parts saved apart (JSON beside CSV and Markdown) load back and merge: rows in the order
    of jaxtree's case list, references and the solver choices of both parts, both commands named."""
    from jaxtree.bench import BenchReport

    def part(case, command):
        row = dict(case=case, group="reference", formulation="full", engine="jaxtree", solver="Dopri8",
                   method="jaxtree Dopri8", setting=1e-6, status="ok", error=2e-7, time_s=0.01, compile_s=1.0,
                   steps=10, rejected=0, rhs=130, energy_drift=math.nan, momentum_drift=1e-12, note="")  # fmt: skip
        ref = dict(primary="Dopri8", secondary="Tsit5", floor=1e-11, description=case)
        return BenchReport([row], "machine", "2026-11-24 17:00 UTC", {case: ref}, {case: "Dopri8 (auto)"}, {},
                           dict(command=command))  # fmt: skip

    part("wings", "jaxtree bench wings").save(tmp_path / "b", plots=False)
    part("fig4", "jaxtree bench fig4").save(tmp_path / "a", plots=False)
    loaded = [BenchReport.load(tmp_path / d) for d in ("b", "a")]
    assert math.isnan(loaded[0].rows[0]["energy_drift"]) and loaded[0].rows[0]["steps"] == 10
    merged = BenchReport.merge(loaded, command="jaxtree bench --merge b a")
    assert merged.cases() == ["fig4", "wings"] and set(merged.auto) == {"fig4", "wings"}
    text = merged.to_markdown()
    assert "`jaxtree bench wings`" in text and "`jaxtree bench fig4`" in text and "## fig4 (reference)" in text
    rc = cli.main(
        ["bench", "--merge", str(tmp_path / "a"), str(tmp_path / "b"), "--no-plots", "--out", str(tmp_path / "m")]
    )
    assert rc == 0 and BenchReport.load(tmp_path / "m").cases() == ["fig4", "wings"]


@pytest.mark.filterwarnings("ignore:rtol=1e-30 is below")  # the impossible tolerance is the point
def test_a_reference_that_cannot_meet_its_tolerance_runs_looser_and_a_singular_start_is_refused(monkeypatch):
    """A reference solver whose steps collapse at the reference tolerance (Kvaerno5 at 1e-12 on
    the 1e8-stiff chain; here every solver at an impossible 1e-30) runs at the fallback, and the
    report names it; a float32 run from a start that is singular in float32 (gimbal frames 1e-3
    rad from lock) is *refused* and a run whose step size collapses is *collapsed*, not *failed*,
    and the findings say there were no failed runs."""
    from jaxtree.bench import BenchCase, report, runs

    for module in (runs, report):  # the runs ask for it, the report names it
        monkeypatch.setattr(module, "REFERENCE_TOL", 1e-30)
    monkeypatch.setattr(runs, "REFERENCE_FALLBACK", (1e-9,))
    base = jaxtree.bench_case("gimbal_lock")
    case = BenchCase("gimbal_lock", "extreme", base.description, base.model, 0.5, n_save=6)
    report = jaxtree.work_precision(
        [case], solvers=["Dopri8"], tolerances=[1e-30], formulations=["full", "float32"], peers=False, repeats=1,
        progress=False,
    )  # fmt: skip
    ref = report.references["gimbal_lock"]
    assert ref["primary_tol"] == ref["secondary_tol"] == 1e-9 and ref["floor"] < FALLBACK_FLOOR
    text = report.to_markdown()
    assert "References Dopri8 (rtol 1e-09) / Tsit5 (rtol 1e-09)" in text
    rows = {}
    for r in report.rows:  # each formulation's first (loosest) setting; float32's second is skipped after it
        rows.setdefault(r["formulation"], r)
    # Dopri8 cannot meet 1e-30: its controller rejects steps down to the minimum step
    assert rows["full"]["status"] == "collapsed" and "collapsed" in rows["full"]["note"], rows["full"]
    assert rows["float32"]["status"] == "refused" and "singular" in rows["float32"]["note"], rows["float32"]
    assert report.rows[-1]["status"] == "skipped" and "refused" in report.rows[-1]["note"]
    assert "Failed runs: none." in text and "Refused by `simulate`'s checks" in text and "(*collapsed*)" in text


def test_flex95_slew_case_drives_jaxtree_and_the_pinocchio_peer_with_the_same_bus_torque():
    """flex95 is a bench case: the slew's torque on the bus, relative errors over the
    wing hinges, Radau5 among the solvers. The peer's numpy torque equals the model's load at every
    time; over the first 2 s (the pulse's rise and top) Pinocchio + DOP853 with it follows jaxtree's
    run to 1e-7 of the hub rate's and wing angles' peaks (at 1e-10), while the same peer without it
    misses by more than 10 %; the peers that take no base torque are rows skipped with the reason."""
    from jaxtree.bench import cases, runs
    from jaxtree.bench.peers import pinocchio_runner

    case = jaxtree.bench_case("flex95")
    assert "flex95" in cases.CASES and case.group == "stiff" and "Radau5" in (case.solvers or ())
    wings = [k for k in range(1, case.model.n + 1) if case.model.names[k].startswith("wing")]
    assert case.relative == tuple(wings) and len(wings) == 90 and case.references == ("Dopri8", "Tsit5")
    assert any(s == "Radau5" for _, s, _ in runs._plan(case, None, None, True, None))  # a quick run keeps it
    loads, torque = case.model.loads, case.peer_torque
    assert loads is not None and torque is not None
    for t in (0.0, 0.9, 1.0, 1.5, 2.95, 3.2, 9.0):
        _, T = loads(jnp.asarray(t), case.model.initial)
        np.testing.assert_allclose(torque(t), np.asarray(T)[0], rtol=ROUNDOFF, atol=ROUNDOFF)
    assert np.allclose(torque(2.0), [15.0, 9.0, 0.0])

    short = dataclasses.replace(case, t1=2.0)
    ts = np.linspace(0.0, 2.0, 11)
    sol = jaxtree.simulate(case.model, 2.0, saveat=jnp.asarray(ts), solver=dfx.Dopri8(), rtol=1e-10, atol=1e-10)
    W = np.asarray(sol.omega0)
    # the torque turns the hub about b_1 and b_2 in the pulse: 1e-2 rad/s at 2 s, 2e-5 before it (the rotor's coupling)
    assert np.linalg.norm(W[-1, :2]) > 100 * np.linalg.norm(W[4, :2]) and np.linalg.norm(W[-1, :2]) > 0.1 * W[0, 2]
    ref = (W, np.asarray(sol.gamma))

    class Steps:
        def step(self, label, n=1):
            pass

    rows, checks = runs._peer_runs(short, ts, ref, True, 1, 0.0, Steps())
    by = {(r["method"], r["setting"]): r for r in rows}
    tight = by["pinocchio scipy DOP853", 1e-8]
    assert checks["pinocchio scipy DOP853"] < CROSS_CHECK, checks
    assert tight["status"] == "ok" and tight["error"] < PEER_ERROR, tight
    free = pinocchio_runner(case.model.with_loads(None), ts)("DOP853", 1e-8, 1e-8)
    assert runs._error(free[0], free[1], ref, case.relative) > 0.1
    skipped = [r for r in rows if r["engine"] in ("mujoco", "basilisk")]
    assert skipped and all(r["status"] == "skipped" and "no bus torque" in r["note"] for r in skipped)


def test_bench_lives_outside_the_engine_and_its_names_still_resolve():
    """``jaxtree.bench`` is not imported by ``import jaxtree`` (a fresh interpreter), its names are
    outside the engine's ``__all__``, and the old spellings ``jaxtree.work_precision`` ... resolve
    to the same objects on first use."""
    import subprocess
    import sys

    from jaxtree import bench

    code = "import sys, jaxtree; print(sorted(m for m in sys.modules if m.startswith('jaxtree.bench')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
    for old, new in [("work_precision", "work_precision"), ("BENCH_CASES", "CASES"), ("stiff_chain", "stiff_chain")]:
        assert old not in jaxtree.__all__ and old in dir(jaxtree)
        assert getattr(jaxtree, old) is getattr(bench, new)
    with pytest.raises(AttributeError):
        jaxtree.no_such_name  # noqa: B018
