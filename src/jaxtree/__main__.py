"""``python -m jaxtree``: the sample problem of Sec. II E (Fig. 4) end to end.

With a subcommand (``simulate``, ``modes``, ``animate``, ``check``, ``plot``) this is the
``jaxtree`` command line of :mod:`jaxtree.cli`; with no subcommand it runs the sample problem.

Runs ``fig4`` (gamma_1 = sin 0.5 t prescribed, rotor at 10 pi rad/s, sprung panels) for 100 s,
once with the Euler angles of Eqs. (23)-(24) and once with quaternions, prints a summary (final
state, energy and momentum drift, steps, wall time), and writes the time histories (``.npz`` and
one ``.csv`` per run) and a plot into the output folder.
"""

from __future__ import annotations

import gc
import sys

from ._src.cli import main as main
from ._src.cli import sample as sample


def command() -> int:
    """The ``jaxtree`` console script and ``python -m jaxtree``: :func:`main` with the process's
    arguments. Once it has returned, every object still alive is left to the operating system
    (``gc.freeze``): the interpreter's shutdown would otherwise search the modules of JAX, XLA
    and matplotlib for garbage cycles, 0.7-1.0 s on this machine, for nothing. Exit handlers
    still run, and every file was closed (written atomically) before :func:`main` returned."""
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    gc.freeze()
    return code


if __name__ == "__main__":
    sys.exit(command())
