"""The ``jaxtree`` command's entry, :func:`main`: warnings as one line, the subcommand's
function called with the parsed options (the sample problem without a subcommand), and a
user's mistake printed as one line with exit status 2."""

from __future__ import annotations

import contextlib
import sys
import warnings

from ..io.results import versions
from .animate import cmd_animate, cmd_plot
from .bench import cmd_bench
from .check import cmd_check, cmd_identify
from .common import EXIT_USAGE, SUBCOMMANDS, UserError, fast_cpu_compiler, say
from .modes import cmd_modes
from .parser import parser
from .sample_problem import sample
from .simulation import cmd_simulate


@contextlib.contextmanager
def one_line_warnings(command: str):
    """Warnings printed as one line, ``<command>: warning: <message>``, without Python's source
    location (which named the ``jaxtree`` launcher script, not the user's mistake)."""
    saved = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        print(f"{command}: warning: {text}", file=file or sys.stderr, flush=True)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = saved


def main(argv=None) -> int:
    """The ``jaxtree`` command: a subcommand, else the sample problem (:func:`sample`)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    name = f"jaxtree {argv[0]}" if argv and argv[0] in SUBCOMMANDS else "jaxtree"
    with one_line_warnings(name):
        return _main(argv)


def _main(argv) -> int:
    if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version")):
        argv = ["sample"] + argv
    if argv[0] == "sample":
        try:
            return sample(argv[1:])
        except UserError as e:
            say(f"{e.prog or 'python -m jaxtree'}: error: {e}")
            return EXIT_USAGE
    command = f"jaxtree {argv[0]}" if argv[0] in SUBCOMMANDS else "jaxtree"
    try:
        args = parser().parse_args(argv)
        args.argv = argv
        if args.version:
            fast_cpu_compiler()
            print(
                " ".join(f"{k.removesuffix('_version')} {v}" for k, v in versions().items() if k.endswith("_version"))
            )
            return 0
        if args.command is None:
            parser().print_help()
            return EXIT_USAGE
        fast_cpu_compiler()
        return {
            "simulate": cmd_simulate,
            "modes": cmd_modes,
            "animate": cmd_animate,
            "check": cmd_check,
            "plot": cmd_plot,
            "identify": cmd_identify,
            "bench": cmd_bench,
        }[args.command](args)
    except UserError as e:
        say(f"{e.prog or command}: error: {e}")
        return EXIT_USAGE
