"""``jaxtree.bench``: error against run time, beside the engine rather than in it.

The work-precision report of ``jaxtree bench``, by stage: :mod:`jaxtree.bench.cases` (the
scenes, the solvers and the tolerance ladders), :mod:`jaxtree.bench.runs` (the timed runs against
two references, :func:`work_precision`) and :mod:`jaxtree.bench.report` (the report's forms) and the same vehicles in the peer packages that a
spacecraft dynamicist would compare with (:mod:`jaxtree.bench.peers`: Pinocchio's ABA under
scipy, MuJoCo; :mod:`jaxtree.bench.peer_basilisk`: Basilisk's spinning-body effectors). The
peers are optional (the ``peers`` extra); a case a peer cannot represent, or a peer that is not
installed, is skipped with the reason in the report. Nothing in :mod:`jaxtree`'s engine imports
this package.

What lives where: this package is what users run (``jaxtree bench``, shipped with jaxtree);
the repository's ``benchmarks/`` holds the developers' scripts, one goal each, with their
results and findings (not installed).
"""

from .cases import CASES as CASES
from .cases import SOLVERS as SOLVERS
from .cases import BenchCase as BenchCase
from .cases import bench_case as bench_case
from .cases import stiff_chain as stiff_chain
from .report import BenchReport as BenchReport
from .report import machine_line as machine_line
from .runs import work_precision as work_precision

__all__ = [
    "CASES",
    "SOLVERS",
    "BenchCase",
    "BenchReport",
    "bench_case",
    "machine_line",
    "stiff_chain",
    "work_precision",
]
