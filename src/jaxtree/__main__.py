"""``python -m jaxtree``: the sample problem of Sec. II E (Fig. 4) end to end.

With a subcommand (``simulate``, ``modes``, ``animate``, ``check``, ``plot``) this is the
``jaxtree`` command line of :mod:`jaxtree.cli`; with no subcommand it runs the sample problem.

Runs ``fig4`` (gamma_1 = sin 0.5 t prescribed, rotor at 10 pi rad/s, sprung panels) for 100 s,
once with the Euler angles of Eqs. (23)-(24) and once with quaternions, prints a summary (final
state, energy and momentum drift, steps, wall time), and writes the time histories (``.npz`` and
one ``.csv`` per run) and a plot into the output folder.
"""

from __future__ import annotations

import sys

from ._src.cli import main as main
from ._src.cli import sample as sample

if __name__ == "__main__":
    sys.exit(main())
