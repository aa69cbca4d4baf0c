"""What every verb of the ``jaxtree`` command shares: the exit statuses, the user's mistake
(:class:`UserError`) and the parser that raises it, the argparse types of numbers and vectors,
and the loading of scenes and result files with one-line errors."""

from __future__ import annotations

import argparse
import contextlib
import math
import pathlib
import re
import sys
import threading

from ..campaigns.chunked_config import parse_hinges
from ..errors import SceneError
from ..io import output
from ..io.result_files import load_result
from ..io.result_files import model_of as result_model
from ..scene.files import list_scenes, load_scene

SUBCOMMANDS = ("simulate", "modes", "animate", "check", "plot", "identify", "bench", "sample")
EXIT_USAGE, EXIT_FAILED, EXIT_INTERRUPTED = 2, 1, 130

SOLVERS = {
    "auto": "auto",
    "dopri8": "Dopri8",
    "dopri5": "Dopri5",
    "tsit5": "Tsit5",
    "bosh3": "Bosh3",
    "heun": "Heun",
    "kvaerno3": "Kvaerno3",
    "kvaerno4": "Kvaerno4",
    "kvaerno5": "Kvaerno5",
    "kencarp4": "KenCarp4",
    "radau5": "Radau5",
}
ATTITUDES = ("quaternion", "dcm", "euler123")


class UserError(Exception):
    """A mistake in the command: printed as one line, exit status 2."""

    def __init__(self, message, prog=None):
        super().__init__(message)
        self.prog = prog


class Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # argparse takes "-1e-6" for an option (its pattern of negative numbers has no exponent),
        # so "--rtol -1e-6" failed as "expected one argument": a number in any float syntax is a
        # value, which the option's own check then accepts or refuses
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.I)

    def error(self, message):
        raise UserError(f"{message} (see '{self.prog} --help')", prog=self.prog)


def fast_cpu_compiler():
    # XLA:CPU's older LLVM emitters compile these many small fusions about twice as fast as the
    # default fusion emitters, with the same run time; jaxlib >= 0.11 has only the latter, and
    # aborts on the option (numerics.fast_cpu_flags). Only effective before JAX starts its CPU
    # backend, which importing jaxtree does not do; an explicit XLA_FLAGS setting wins.
    from ..numerics import use_fast_cpu_flags

    use_fast_cpu_flags()


def say(*args):
    print(*args, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- argument types
def number(convert, ok, need):
    """An argparse type: the number `convert` reads from the text, where `ok` holds of it."""
    kind = "an integer" if convert is int else "a number"

    def parse(text):
        try:
            x = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {kind}, got {text!r}") from None
        if not ok(x):
            raise argparse.ArgumentTypeError(f"must be {need}, got {x if convert is int else repr(text)}")
        return x

    return parse


def positive():
    return number(float, lambda x: math.isfinite(x) and x > 0, "a positive number")


def finite():
    return number(float, math.isfinite, "finite")


def count(least=1):
    return number(int, lambda x: x >= least, f"at least {least}")


def modes_arg(text):
    """``--modes``: a count (at least 1) or 'auto'."""
    if text.strip().lower() == "auto":
        return "auto"
    return count()(text)


def vector3():
    def parse(text):
        parts = [p for p in text.replace(" ", ",").split(",") if p]
        try:
            v = [float(p) for p in parts]
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be numbers, got {text!r}") from None
        if len(v) == 1:
            v = [0.0, 0.0, v[0]]
        if len(v) != 3 or not all(math.isfinite(x) for x in v):
            raise argparse.ArgumentTypeError(
                f"must be one number (about b0's axis 3) or three finite numbers wx,wy,wz, got {text!r}"
            )
        return v

    return parse


def hinges(model, text, option):
    """Hinges named in `text`: 'all', or comma-separated indices 1..n, body names or ranges a-b."""
    try:
        return parse_hinges(model, text)
    except ValueError as e:
        raise UserError(f"{option}: {e}") from None


# ----------------------------------------------------------------------------- files
def open_scene(path):
    """The scene of a file or a bundled scene's name; a mistake as one :class:`UserError`."""
    p = pathlib.Path(path)
    try:
        return load_scene(path)
    except FileNotFoundError:
        if p.suffix == "" and p.parent == pathlib.Path("."):
            raise UserError(
                f"scene {path!r}: no such file, and no bundled scene of that name (bundled: {', '.join(list_scenes())})"
            ) from None
        raise UserError(f"scene file {str(path)!r} does not exist") from None
    except IsADirectoryError:
        raise UserError(f"scene {str(path)!r} is a folder, not a scene file") from None
    except PermissionError:
        raise UserError(f"scene file {str(path)!r} cannot be read (permission denied)") from None
    except UnicodeDecodeError:
        raise UserError(f"scene file {str(path)!r} is not a text (JSON) file") from None
    except SceneError as e:
        text = str(e)
        raise UserError(text if text.startswith(str(p)) else f"invalid scene {str(path)!r}: {text}") from None


def open_result(path):
    """A result file as a dataset; a mistake as one :class:`UserError`."""
    try:
        return load_result(path, as_dataset=True)
    except FileNotFoundError:
        raise UserError(f"result file {str(path)!r} does not exist") from None
    except IsADirectoryError:
        raise UserError(f"result {str(path)!r} is a folder, not a result file") from None
    except ValueError as e:
        raise UserError(str(e)) from None
    except OSError as e:
        raise UserError(f"result file {str(path)!r} cannot be read as NetCDF ({e.__class__.__name__}: {e})") from None


def model_of(ds, path):
    """The model stored in a result dataset read from `path`."""
    try:
        return result_model(ds)
    except (ValueError, KeyError) as e:
        raise UserError(f"{path}: {e}") from None


def use_matplotlib():
    """Whether matplotlib is installed; if so, with its non-interactive backend."""
    try:
        import matplotlib  # optional (jaxtree[plot]) and slow to import: only where a plot is drawn

        matplotlib.use("Agg")
        return True
    except ImportError:
        return False


def wrote(paths, existed) -> str:
    """``wrote a, b`` with the files that were there before named as overwritten."""
    over = [str(q) for q in paths if str(q) in existed]
    return f"wrote {', '.join(str(q) for q in paths)}" + (f" (overwrote {', '.join(over)})" if over else "")


def existing(paths) -> set[str]:
    return {str(q) for q in paths if pathlib.Path(q).exists()}


def start_warming(plot: bool) -> threading.Thread:
    """:func:`output.warm_writers` started on a thread of its own (join it before writing). Its
    failure is not the run's: the writers themselves then import and fail (or not) with their own
    message. A daemon: an interrupted run does not wait for it."""

    def warm():
        with contextlib.suppress(Exception):
            output.warm_writers(plot=plot)

    thread = threading.Thread(target=warm, name="jaxtree-warm-writers", daemon=True)
    thread.start()
    return thread
