"""The work-precision report of ``jaxtree bench``: :class:`BenchReport` (the rows of every run, the
text, CSV and JSON forms, the best run per error target, the figure) and the machine line that
heads it. The cases are :mod:`.cases`; the runs that fill it are :mod:`.runs`."""

from __future__ import annotations

import csv
import dataclasses
import io
import json
import math
import os
import platform
from collections.abc import Sequence

import jax
import numpy as np

from jaxtree._src.atomic import atomic_write
from jaxtree._src.io.work_precision_plot import plot_work_precision
from jaxtree.bench.cases import CASES, GOALS, IMPLICIT, IMPLICIT_STEP_CAP, REFERENCE_TOL, STEP_CAP, TARGETS


@dataclasses.dataclass
class BenchReport:
    """The rows of a work-precision run (one dict per run: case, group, formulation, engine,
    solver, method, setting, error, time_s, compile_s, steps, rejected, rhs, energy_drift,
    momentum_drift, status, note) with the machine line, the references' floors per case, the
    solver that ``"auto"`` picks per case, and the peers' cross-checks."""

    rows: list[dict]
    machine: str
    date: str
    references: dict[str, dict]
    auto: dict[str, str]
    cross_checks: dict[str, dict]
    settings: dict

    COLUMNS = (
        "case", "group", "formulation", "engine", "solver", "method", "setting", "status", "error",
        "time_s", "compile_s", "steps", "rejected", "rhs", "energy_drift", "momentum_drift", "note",
    )  # fmt: skip

    def best(self, case: str, target: float) -> dict[str, dict]:
        """Per method, its cheapest row of `case` that reaches `target`."""
        out: dict[str, dict] = {}
        for r in self.rows:
            if r["case"] != case or not (r["error"] <= target) or r["status"] != "ok":
                continue
            if r["method"] not in out or r["time_s"] < out[r["method"]]["time_s"]:
                out[r["method"]] = r
        return out

    def to_csv(self) -> str:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=self.COLUMNS, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        for r in self.rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
        return buf.getvalue()

    def cases(self) -> list[str]:
        return list(dict.fromkeys(r["case"] for r in self.rows))

    def summary(self, case: str) -> list[str]:
        """Markdown lines: time to each target per method, fastest first, with the ratio to the
        fastest peer."""
        lines = []
        for target in TARGETS:
            best = sorted(self.best(case, target).values(), key=lambda r: r["time_s"])
            if not best:
                lines.append(f"- to {target:g}: no run reached it")
                continue
            peers = [r for r in best if r["engine"] != "jaxtree"]
            ours = [r for r in best if r["engine"] == "jaxtree"]
            part = ", ".join(f"{r['method']} {_ms(r['time_s'])}" for r in best[:6])
            ratio = ""
            if peers and ours:
                x = ours[0]["time_s"] / peers[0]["time_s"]
                ratio = f" — jaxtree's best ({ours[0]['method']}) / fastest peer ({peers[0]['method']}): **{x:.2f}x**"
                if case in GOALS:
                    goal = GOALS[case][TARGETS.index(target)]
                    ratio += f" (goal <= {goal:g}x: {'met' if x <= goal else 'not met'})"
            lines.append(f"- to {target:g}: {part}{ratio}")
        return lines

    def _fastest(self, case: str, target: float, engine: str | None, formulation: str | None = "full"):
        """The cheapest row of `case` reaching `target`: jaxtree's (`engine` "jaxtree"), the
        peers' (`engine` None) or any; `formulation` None admits every formulation."""
        best = [
            r
            for r in self.best(case, target).values()
            if (engine is None and r["engine"] != "jaxtree") or engine in (r["engine"], "any")
            if formulation is None or r["formulation"] == formulation
        ]
        return min(best, key=lambda r: r["time_s"]) if best else None

    def findings(self) -> list[str]:
        """Markdown lines drawn from the rows: the fastest settings per case and target, where
        explicit solvers stall, what float32 and the modal formulations give, and the solver
        that the data recommends per group of cases. Regenerated with the report."""
        out, wins = self._fastest_table()
        out.append("")
        out += self._stall_lines()
        out += self._failure_lines()
        out.append("")
        out += self._float32_lines()
        out += self._modal_lines()
        out += self._win_lines(wins)
        return out

    def _fastest_table(self) -> tuple[list[str], dict[str, dict[str, int]]]:
        """The findings' table of the fastest runs per case and target, jaxtree's and the peers',
        with the solver of each of jaxtree's fastest runs counted per group of cases."""
        out = [
            "## Findings (drawn from the rows below)",
            "",
            "| case | group | `auto` picks | jaxtree fastest to 1e-6 | to 1e-9 | fastest peer to 1e-6 | to 1e-9 |",
            "|---|---|---|---|---|---|---|",
        ]

        def cell(r):
            return "-" if r is None else f"{r['method'].removeprefix('jaxtree ')} {_ms(r['time_s'])}"

        wins: dict[str, dict[str, int]] = {}
        for case in self.cases():
            group = next(r["group"] for r in self.rows if r["case"] == case)
            ours = [self._fastest(case, t, "jaxtree") for t in TARGETS]
            peers = [self._fastest(case, t, None) for t in TARGETS]
            auto = self.auto.get(case, "-").split(" (")[0]
            out.append(
                f"| {case} | {group} | {auto} | {cell(ours[0])} | {cell(ours[1])} | {cell(peers[0])} | {cell(peers[1])} |"
            )
            for r in ours:
                if r is not None:
                    tally = wins.setdefault(group, {})
                    tally[r["solver"]] = tally.get(r["solver"], 0) + 1
        return out, wins

    def _stall_lines(self) -> list[str]:
        """The findings' lines on jaxtree's runs that stalled at the step cap, collapsed or were
        left unrun as unstable, per case; none when there are no such runs."""
        stalls = [
            r for r in self.rows if r["engine"] == "jaxtree" and r["status"] in ("stalled", "collapsed", "unstable")
        ]
        if not stalls:
            return []
        out = [
            f"Runs held at the step cap ({STEP_CAP} explicit, {IMPLICIT_STEP_CAP} implicit steps: *stalled*), "
            "whose step size collapsed below the minimum step (*collapsed*) or beyond RK4's stability region "
            "(*unstable*, not run):"
        ]
        by_case: dict[str, list[str]] = {}
        for r in stalls:
            kind = "implicit" if r["solver"] in IMPLICIT else "explicit"
            form = "" if r["formulation"] == "full" else f" [{r['formulation']}]"
            by_case.setdefault(r["case"], []).append(f"{r['solver']}{form} ({kind}) {setting_text(r)} {r['status']}")
        out += [f"- {c}: " + ", ".join(v) for c, v in by_case.items()]
        out.append("")
        return out

    def _failure_lines(self) -> list[str]:
        """The findings' lines naming the failed runs (or none) and the runs that ``simulate``
        refused for a singular initial state."""
        failed = [r for r in self.rows if r["status"] == "failed"]
        out = [
            "Failed runs: "
            + (", ".join(f"{r['case']} {r['method']} {setting_text(r)} ({r['note']})" for r in failed) or "none")
            + "."
        ]
        refused = [r for r in self.rows if r["status"] == "refused"]
        if refused:
            out.append(
                "Refused by `simulate`'s checks of the initial state (singular to working precision): "
                + ", ".join(f"{r['case']} {r['method']} {setting_text(r)}" for r in refused)
                + "."
            )
        return out

    def _float32_lines(self) -> list[str]:
        """The findings' line on the float32 runs: the smallest error reached per case, with its
        setting and time; none when no float32 run succeeded."""
        f32 = [r for r in self.rows if r["formulation"] == "float32" and r["status"] == "ok"]
        if not f32:
            return []
        parts = []
        for case in dict.fromkeys(r["case"] for r in f32):
            rs = [r for r in f32 if r["case"] == case]
            best = min(rs, key=lambda r: r["error"])
            parts.append(f"{case} {best['error']:.1e} ({setting_text(best)}, {_ms(best['time_s'])})")
        return [
            "Float32 (the model cast; error against the float64 reference, smallest reached): "
            + ", ".join(parts)
            + ".",
            "",
        ]

    def _modal_lines(self) -> list[str]:
        """The findings' lines on the modal formulations: the cheapest run of each per case, set
        against the full Eq. (1) run by the same solver at the same setting; none without them."""
        modal = [r for r in self.rows if r["formulation"] not in ("full", "float32") and r["status"] == "ok"]
        if not modal:
            return []
        out = [
            "Modal formulations (their error is the model's, against the full Eq. 1: it stays as the tolerance "
            "tightens), cheapest run of each against the full Eq. (1) by the same solver at the same tolerance:"
        ]
        for case in dict.fromkeys(r["case"] for r in modal):
            parts = []
            for form in dict.fromkeys(r["formulation"] for r in modal if r["case"] == case):
                rs = [r for r in modal if r["case"] == case and r["formulation"] == form]
                r = min(rs, key=lambda r: r["time_s"])
                full = [
                    x for x in self.rows
                    if x["case"] == case and x["formulation"] == "full" and x["solver"] == r["solver"]
                    and x["setting"] == r["setting"] and x["status"] == "ok"
                ]  # fmt: skip
                vs = f" (full: {_ms(full[0]['time_s'])}, {full[0].get('steps', '')} steps)" if full else ""
                parts.append(f"{form} error {r['error']:.1e}, {_ms(r['time_s'])}, {r.get('steps', '')} steps{vs}")
            out.append(f"- {case}: " + "; ".join(parts))
        out.append("")
        return out

    @staticmethod
    def _win_lines(wins: dict[str, dict[str, int]]) -> list[str]:
        """The findings' lines ranking the solvers of jaxtree's fastest runs per group of cases,
        as counted by :meth:`_fastest_table`; none when it counted nothing."""
        if not wins:
            return []
        out = ["The solver of jaxtree's fastest run to 1e-6 and 1e-9, counted per group of cases:"]
        for group, tally in wins.items():
            ranked = sorted(tally.items(), key=lambda kv: -kv[1])
            out.append(f"- {group}: " + ", ".join(f"{k} {v}" for k, v in ranked))
        out.append("")
        return out

    def to_markdown(self, plots: dict[str, str] | None = None) -> str:
        s = self.settings
        out = [
            "# Work-precision report",
            "",
            f"Generated by `{s.get('command', 'jaxtree bench')}` on {self.date}"
            + (f", merging {s['parts']}." if s.get("parts") else "."),
            "",
            f"Machine: {self.machine}",
            "",
            "Error: the largest absolute error over the save times in omega0 (rad/s) and gamma (rad), "
            f"against a reference at rtol = atol = {REFERENCE_TOL:g} by a different solver (the floor column: the two "
            "references' difference; a case that names a relative error, as flex95, takes the hub rate's error over "
            "its peak and its wing angles' over theirs). Time: the median of repeated calls after the first, compile time apart "
            "(jaxtree only). Peers run only on the scenes they can represent, cross-checked first. "
            f"A run stopped at the step cap ({STEP_CAP} steps) is *stalled*; its note says how far it got.",
            "",
        ]
        out += self.findings()
        for case in self.cases():
            rows = [r for r in self.rows if r["case"] == case]
            ref = self.references.get(case, {})
            out += [f"## {case} ({rows[0]['group']})", ""]
            if ref:
                out.append(
                    f"{ref.get('description', '')}. References {ref['primary']}{reference_note(ref, 'primary')} / "
                    f"{ref['secondary']}{reference_note(ref, 'secondary')}, floor "
                    f'{ref["floor"]:.1e}. `solver="auto"` picks: {self.auto.get(case, "-")}.'
                )
            checks = self.cross_checks.get(case, {})
            if checks:
                out.append(
                    "Peers' cross-check at their tightest setting: "
                    + ", ".join(f"{k} {v:.1e}" for k, v in checks.items())
                    + "."
                )
            idle: dict[str, list[str]] = {}  # the peers' skipped methods by reason
            for r in rows:
                if r["engine"] != "jaxtree" and r["status"] == "skipped":
                    methods = idle.setdefault(r["note"], [])
                    methods += [r["method"]] if r["method"] not in methods else []
            if idle:
                out.append("Peers not timed: " + "; ".join(f"{', '.join(m)}: {why}" for why, m in idle.items()) + ".")
            out.append("")
            out += self.summary(case)
            if plots and case in plots:
                out += ["", f"![{case}]({plots[case]})"]
            out += [
                "",
                "| method | setting | status | error | time (ms) | compile (s) | steps | rejected | energy drift | momentum drift |",
                "|---|---|---|---|---|---|---|---|---|---|",
            ]
            for r in rows:
                out.append(
                    f"| {r['method']} | {setting_text(r)} | {r['status']} | {_e(r['error'])} | {_ms(r['time_s'], False)} | "
                    f"{_f(r['compile_s'])} | {r.get('steps', '')} | {r.get('rejected', '')} | "
                    f"{_e(r.get('energy_drift', math.nan))} | {_e(r.get('momentum_drift', math.nan))} |"
                )
            out.append("")
        return "\n".join(out) + "\n"

    def plot(self, case: str, path=None):

        methods: dict[str, tuple[list, list]] = {}
        for r in self.rows:
            if r["case"] == case and r["status"] == "ok":
                e, t = methods.setdefault(r["method"], ([], []))
                e.append(r["error"])
                t.append(r["time_s"])
        return plot_work_precision(methods, path, title=f"{case}: error against run time", error_label="max error")

    def save(self, directory, *, stem: str = "work_precision", plots: bool = True) -> dict[str, str]:
        """Write ``<stem>.csv``, ``<stem>.md`` and one ``<stem>_<case>.png`` per case into
        `directory` (each atomically); returns the paths."""

        os.makedirs(directory, exist_ok=True)
        paths = {"csv": os.path.join(directory, f"{stem}.csv"), "md": os.path.join(directory, f"{stem}.md")}
        figs: dict[str, str] = {}
        if plots:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt

            for case in self.cases():
                name = f"{stem}_{case}.png"
                fig = self.plot(case, os.path.join(directory, name))
                plt.close(fig)
                figs[case] = name
                paths[case] = os.path.join(directory, name)
        paths["json"] = os.path.join(directory, f"{stem}.json")
        with atomic_write(paths["json"], "w") as fh:
            json.dump(dataclasses.asdict(self), fh, indent=1)
        with atomic_write(paths["csv"], "w") as fh:
            fh.write(self.to_csv())
        with atomic_write(paths["md"], "w") as fh:
            fh.write(self.to_markdown(figs))
        return paths

    @classmethod
    def load(cls, path) -> BenchReport:
        """A report saved by :meth:`save` (its ``.json``; a folder: its ``work_precision.json``)."""
        if os.path.isdir(path):
            path = os.path.join(path, "work_precision.json")
        with open(path) as fh:
            return cls(**json.load(fh))

    @classmethod
    def merge(cls, reports: Sequence[BenchReport], command: str = "") -> BenchReport:
        """One report of several run apart (e.g. two halves of the cases in two processes): rows in
        the order of :data:`CASES`, each part's machine line and command kept."""
        rank = {c: i for i, c in enumerate(CASES)}
        rows = sorted((r for rep in reports for r in rep.rows), key=lambda r: rank.get(r["case"], len(rank)))
        merged: dict[str, dict] = {"references": {}, "auto": {}, "cross_checks": {}}
        for rep in reports:
            for key in merged:
                merged[key].update(getattr(rep, key))
        machines = list(dict.fromkeys(rep.machine for rep in reports))
        # a merged report brings its own parts along (merges of merges keep every run's command)
        parts = "; ".join(
            rep.settings.get("parts") or f"`{rep.settings.get('command', '')}` ({rep.date})" for rep in reports
        )
        settings = dict(reports[0].settings, command=command or "jaxtree bench --merge", parts=parts)
        return cls(rows, " | ".join(machines), max(rep.date for rep in reports), settings=settings, **merged)


def _ms(seconds, unit=True) -> str:
    if not (seconds == seconds):
        return "-"
    return f"{1e3 * seconds:.3g} ms" if unit else f"{1e3 * seconds:.3g}"


def _e(x) -> str:
    return "-" if x is None or not (x == x) else f"{x:.1e}"


def _f(x) -> str:
    return "-" if x is None or not (x == x) else f"{x:.2f}"


def setting_text(r) -> str:
    if r["solver"] in ("RK4", "RK4 (MuJoCo)") or r["engine"] == "mujoco":
        return f"{r['setting']:g} steps/save"
    return f"tol {r['setting']:g}"


def machine_line() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    from importlib.metadata import version

    def v(name):
        try:
            return version(name)
        except Exception:
            return "-"

    load = "load average {:.1f} {:.1f} {:.1f}; ".format(*os.getloadavg()) if hasattr(os, "getloadavg") else ""
    return (
        f"{platform.system()} {platform.release()}, {cpu}, {os.cpu_count()} cores, {load}python {platform.python_version()}, "
        f"jax {jax.__version__}, diffrax {v('diffrax')}, equinox {v('equinox')}, numpy {np.__version__}, "
        f"jaxtree {v('jaxtree')}, pin {v('pin')}, mujoco {v('mujoco')}, scipy {v('scipy')}; "
        f"backend {jax.default_backend()}"
    )


def reference_note(ref: dict, which: str) -> str:
    """`` (rtol 1e-11)`` where a reference ran looser than :data:`REFERENCE_TOL`."""
    tol = ref.get(f"{which}_tol", REFERENCE_TOL)
    return "" if tol == REFERENCE_TOL else f" (rtol {tol:g})"
