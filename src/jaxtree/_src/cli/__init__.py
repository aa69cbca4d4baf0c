"""The ``jaxtree`` command line: from a scene file to results, plots and an animation.

Subcommands (``jaxtree SUBCOMMAND --help`` for each):

- ``simulate SCENE --t1 T``: integrate Eq. (1) (or the hybrid-coordinate equations with
  ``--hybrid-small``) and write a NetCDF result, written in parts as the run goes (``--resume``
  continues an interrupted run), with a summary: steps, an error estimate, energy and momentum
  drift;
- ``modes SCENE --small ...``: the modes of the linearized small hinges (Eqs. 40-104): a
  frequency table with labels and damping, a modes result file and a mode-shape plot;
- ``animate RESULT -o page.html``: an HTML page animating a simulation, or one mode (``--mode``)
  of a modes result;
- ``check SCENE``: validate a scene; its tree, the seed's Tables 1-2, masses and the condition
  number of Eq. (1) at the initial state;
- ``plot RESULT``: the plots of a result file;
- ``identify SCENE RECORD --free ... --sigma ...``: estimate named parameters from a record of
  sensor readings (:func:`jaxtree.identify`; :mod:`~jaxtree._src.identify.command`);
- ``bench [CASE ...]``: error against run time for each solver, formulation and peer: a CSV,
  a Markdown report and one work-precision plot per case (:func:`jaxtree.work_precision`);
- ``sample`` (also: no subcommand at all): the seed's sample problem (``python -m jaxtree``).

A user's mistake (a missing file, an invalid scene, a bad option) prints one line naming what
is wrong and exits with status 2; a run that fails numerically prints its diagnosis (time,
state) and exits with status 1; an interrupted run (Ctrl-C, SIGTERM) keeps what it computed and
exits with status 130.

The package, one module per verb over the shared ones: :mod:`.common` (exit statuses,
:class:`UserError`, argument types, loading scenes and results), :mod:`.parser` (the argparse
parser of every subcommand), :mod:`.dispatch` (:func:`main`); :mod:`.simulation` (``simulate``),
:mod:`.modes`, :mod:`.animate` (``animate`` and ``plot``), :mod:`.check` (``check``, and
``identify``, whose work is in :mod:`jaxtree._src.identify.command`), :mod:`.bench` and
:mod:`.sample_problem` (``sample``). The modules of ``main``, ``simulate`` and ``sample`` are named
otherwise: ``cli.main``, ``cli.simulate`` and ``cli.sample`` are functions, which a submodule of
the same name would replace when first imported.
"""

from __future__ import annotations

from ..campaigns.chunked_config import solver_named
from ..integration.simulate import simulate
from .common import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_USAGE, SOLVERS, SUBCOMMANDS, UserError
from .dispatch import main, one_line_warnings
from .sample_problem import elapsed, sample
from .simulation import CHUNK_DELAY_ENV, save_points_of

__all__ = [
    "CHUNK_DELAY_ENV",
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_USAGE",
    "SOLVERS",
    "SUBCOMMANDS",
    "UserError",
    "main",
    "sample",
    "simulate",
    "solver_named",
]

# the names the tests have used since the command line was one module, cli.py
_elapsed = elapsed
_one_line_warnings = one_line_warnings
_save_points = save_points_of
