"""JAX's persistent compilation cache, on by default for jaxtree's processes.

XLA's compilation of jaxtree's programs (Eq. (1) under an integrator, its Jacobians, Radau5's
stages) takes seconds to tens of seconds, and every process paid it again. JAX can keep compiled
programs on disk, keyed by the program, the compile options, the backend and the versions of jax
and jaxlib, so an entry of another version or of other XLA flags is never used. This module turns
that cache on at ``import jaxtree``:

- where: ``JAXTREE_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/jaxtree/xla`` (``~/.cache/...``);
- off: ``JAXTREE_CACHE_DIR=0`` (or ``off``, ``false``, ``no``);
- a cache directory set for JAX itself (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config.update("jax_compilation_cache_dir", ...)`` before the import) is left as it is;
- bounded: least recently used entries are evicted beyond :data:`MAX_BYTES`, and with eviction on
  JAX takes a file lock for every read and write, so processes may share the directory;
- only programs whose compilation took at least :data:`MIN_COMPILE_SECONDS` are written (unless
  ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` says otherwise).

Only XLA's compilation is cached here; jaxtree's own top-level programs are also kept traced
(exported) beside it, so that a later process skips their tracing too (:mod:`jaxtree._src.programs`).
"""

from __future__ import annotations

import contextlib
import os
import threading

import jax

OFF = ("0", "off", "false", "no", "none")
MAX_BYTES = 2 * 1024**3
MIN_COMPILE_SECONDS = 0.5


def directory() -> str | None:
    """The cache directory jaxtree would use, or None when ``JAXTREE_CACHE_DIR`` turns it off."""
    value = os.environ.get("JAXTREE_CACHE_DIR", "").strip()
    if value.lower() in OFF:
        return None
    if value:
        return os.path.abspath(os.path.expanduser(value))
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "jaxtree", "xla")


def enable() -> str | None:
    """Turn the cache on (see the module's text); returns its directory, or None when off or when
    JAX already has a cache directory of the user's."""
    path = directory()
    if (
        path is None
        or os.environ.get("JAX_COMPILATION_CACHE_DIR")
        or getattr(jax.config, "jax_compilation_cache_dir", None)
    ):
        return None
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:  # else the user's
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
    return path


# ----------------------------------------------------------------------------- host callbacks
# JAX never writes a program with host callbacks to the persistent cache ("Not writing persistent
# cache entry ... because it uses host callbacks"). equinox's runtime checks (`eqx.error_if`) are
# host callbacks: diffrax checks saveat's times and dt0's sign with them inside every solve, so
# `simulate`'s program was compiled again in every process. jaxtree checks those inputs before
# tracing (check_times, the dt0 check) and reports non-finite states and failed runs itself, so
# inside its own programs the checks may return NaN instead (equinox's on_error="nan", no
# callback). The switch is scoped: only programs traced inside `checks_without_callbacks()` get
# it, and the checks it makes carry on_error="nan" explicitly, so the compiled checks that
# equinox caches for everyone else (keyed on on_error="default") are not the ones changed here.
# One reach beyond: a function of yours that you jit yourself and that jaxtree's solve traces (a hinge
# law under jax.jit) is traced there with these checks, and JAX keeps that trace for its later calls.
# JAXTREE_EQX_CHECKS=raise (or EQX_ON_ERROR set to anything but "raise") keeps equinox's own.

# The scope is the thread's: the depth is thread-local, and equinox's branched_error_if is
# wrapped once (on first use) by a function that asks the calling thread's depth, so that a
# program traced on another thread at the same time (the main job's error-estimate runs) keeps
# equinox's checks, and its key (checks_state) says so.
_LOCAL = threading.local()
_INSTALLED: list = []


def _depth() -> int:
    return getattr(_LOCAL, "depth", 0)


def checks_state() -> tuple:
    """What decides how equinox's checks are traced on this thread: inside
    :func:`checks_without_callbacks` or not, ``JAXTREE_EQX_CHECKS`` and equinox's own mode (a
    part of the key of a kept program, :mod:`jaxtree._src.programs`)."""
    try:
        import equinox._errors as errors
    except ImportError:
        return (bool(_depth()), None, None)
    keep = os.environ.get("JAXTREE_EQX_CHECKS", "").strip().lower()
    return (bool(_depth()), keep, str(getattr(errors, "EQX_ON_ERROR", None)))


def _switched(errors) -> bool:
    """Inside the scope on this thread, and neither JAXTREE_EQX_CHECKS=raise nor another
    equinox mode asked for."""
    keep = os.environ.get("JAXTREE_EQX_CHECKS", "").strip().lower() == "raise"
    return bool(_depth()) and not keep and getattr(errors, "EQX_ON_ERROR", "raise") == "raise"


def _install(errors) -> None:
    """Wrap equinox's branched_error_if once (nothing where this equinox has none)."""
    with _INSTALL_LOCK:
        original = getattr(errors, "branched_error_if", None)
        if _INSTALLED or original is None:
            return

        def branched_error_if(x, pred, index, msgs, *, on_error="default"):
            if on_error == "default" and _switched(errors):
                on_error = "nan"
            return original(x, pred, index, msgs, on_error=on_error)

        errors.branched_error_if = branched_error_if
        _INSTALLED.append(original)


_INSTALL_LOCK = threading.Lock()


@contextlib.contextmanager
def checks_without_callbacks():
    """Within (on this thread): equinox runtime checks traced with ``on_error="nan"`` (see above)."""
    try:
        import equinox._errors as errors
    except ImportError:  # another equinox layout: leave its checks alone
        yield
        return
    _install(errors)
    _LOCAL.depth = _depth() + 1
    try:
        yield
    finally:
        _LOCAL.depth = _depth() - 1
