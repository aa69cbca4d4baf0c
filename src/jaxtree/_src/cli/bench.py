"""``jaxtree bench``: the work-precision report (:func:`jaxtree.work_precision`) from the command
line, or the merge of reports saved by runs of parts of its cases."""

from __future__ import annotations

import time

from ...bench import SOLVERS as BENCH_SOLVERS
from ...bench import BenchReport, bench_case, work_precision
from .common import UserError, say, use_matplotlib


def cmd_bench(args) -> int:
    cases = []
    for name in args.cases:
        try:
            cases.append(bench_case(name))
        except ValueError as e:
            raise UserError(str(e)) from None
    by_lower = {k.lower(): k for k in BENCH_SOLVERS}
    solvers = None
    if args.solvers:
        bad = [s for s in args.solvers if s.lower() not in by_lower]
        if bad:
            raise UserError(f"unknown solver(s) {', '.join(bad)}; known: {', '.join(BENCH_SOLVERS)}")
        solvers = [by_lower[s.lower()] for s in args.solvers]
    if not args.no_plots:
        use_matplotlib()
    command = "jaxtree " + " ".join(getattr(args, "argv", ["bench"]))
    if args.merge:
        parts = []
        for d in args.merge:
            try:
                parts.append(BenchReport.load(d))
            except (OSError, ValueError, TypeError) as e:
                raise UserError(f"--merge: no report in {d!r} ({e})") from None
        report = BenchReport.merge(parts, command=command.strip())
        paths = report.save(args.out, plots=not args.no_plots)
        say(f"wrote {paths['csv']}, {paths['md']} ({len(report.rows)} runs from {len(parts)} reports)")
        return 0
    t = time.perf_counter()
    report = work_precision(
        cases or None,
        solvers=solvers,
        tolerances=args.tols,
        peers=not args.no_peers,
        quick=args.quick,
        repeats=args.repeats,
        progress=not args.no_progress,
        command=command.strip(),
        on_case=lambda partial: partial.save(args.out, plots=not args.no_plots),
    )
    paths = report.save(args.out, plots=not args.no_plots)
    for case in report.cases():
        print(f"{case}:")
        for line in report.summary(case):
            print("  " + line.removeprefix("- "))
    failed = [r for r in report.rows if r["status"] == "failed"]
    say(f"wrote {paths['csv']}, {paths['md']} ({len(report.rows)} runs, {time.perf_counter() - t:.0f} s)")
    if failed:
        say(f"{len(failed)} runs failed: see the report's notes")
    return 0
