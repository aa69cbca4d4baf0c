"""jaxtree's traced programs kept on disk, so that a second process skips tracing them.

JAX's persistent compilation cache (:mod:`jaxtree._src.cache`) keeps XLA's compiled programs, but
a process still traces every program (runs its Python: Eq. (1) under an integrator, its
Jacobians, the diagnostics) and lowers it before the cache can be asked: on fig4 ~1.4 s for a
solve and ~1 s for its diagnostics in every process, more on the large vehicles. Here a
top-level program of jaxtree's (:func:`jaxtree._src.numerics.program_jit`) is traced once,
exported (``jax.export``: StableHLO, serialized) and written beside the compilation cache; a
later process with the same key deserializes it and calls it, and XLA's compilation of that call
is a hit in the compilation cache. The first process calls the exported program too, so that the
compiled program it leaves in the cache is the one the next process asks for.

The key is the digest of everything the trace depends on, and nothing is read from disk without
a full match:

- the program (module and qualified name), jaxtree's source (a digest of every ``.py`` file of
  the installed package) and the versions of Python, jax, jaxlib, equinox, diffrax, lineax,
  optimistix and numpy;
- the arguments' static part (pickled: a scene's topology, solver objects, options) and their
  arrays' shapes and dtypes (weak types too);
- JAX's trace context (x64, matmul precision, promotion rules ...), the compile options, the
  backend and device kind, equinox's runtime-check mode and the ``JAXTREE_*`` / ``EQX_*``
  environment.

A program is not kept (it is traced in every process, as before) when its static part holds a
function or class of the user's (not of jaxtree, JAX, equinox, diffrax, lineax, optimistix,
numpy or the standard library): its code is not in the key, so a later edit could not be told
apart. Nor when the program has host callbacks (a progress meter) or anything else
``jax.export`` refuses: that is remembered on disk, so later processes do not try again.

Where: ``programs/`` in jaxtree's compilation-cache directory (``JAXTREE_CACHE_DIR``), only when
jaxtree turned that cache on. The number of devices is in the key, and a program sharded over
several (a campaign's chunk) is not kept: an exported program is bound to the devices it was
traced for. ``JAXTREE_PROGRAM_CACHE=0`` turns
this cache off alone. A process that rebinds a name of jaxtree's (a monkeypatch) keeps it off
while the name is rebound (see :func:`rebound`). Files are
written atomically (a temporary file renamed), so processes may share the directory; an entry
that cannot be read is ignored. Entries are unpickled: the directory is trusted as JAX's
compilation cache is (both hold code that runs). Beyond :data:`MAX_BYTES` the least recently used entries go.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import hashlib
import io
import os
import pickle
import sys
import tempfile
import time
import types
from typing import Any

import jax

from . import cache

FORMAT = 1
SUBDIR = "programs"
MAX_BYTES = 256 * 1024**2
MEMO_SIZE = 64
OFF = cache.OFF
# Top-level packages whose functions and classes may sit in a kept program's static part: their
# code is in the key (jaxtree's source digest, the others' versions).
TRUSTED = frozenset(
    {
        "jaxtree",
        "jax",
        "jaxlib",
        "equinox",
        "diffrax",
        "lineax",
        "optimistix",
        "numpy",
        "ml_dtypes",
        "jaxtyping",
        "builtins",
        "operator",
        "_operator",
        "functools",
        "_functools",
        "math",
        "enum",
        "types",
        "typing",
        "collections",
        "copyreg",
        "dataclasses",
        "abc",
    }
)


class Unkeyable(Exception):
    """The static part of a call cannot be keyed safely (a function of the user's, an object
    that does not pickle)."""


def directory() -> str | None:
    """The directory of kept programs, or None when off (jaxtree's compilation cache off or not
    jaxtree's, or ``JAXTREE_PROGRAM_CACHE`` off)."""
    if os.environ.get("JAXTREE_PROGRAM_CACHE", "").strip().lower() in OFF or not _can_serialize():
        return None
    base = cache.directory()
    if base is None or getattr(jax.config, "jax_compilation_cache_dir", None) != base:
        return None
    return os.path.join(base, SUBDIR)


@functools.cache
def _can_serialize() -> bool:
    """jax.export is there and can serialize (it needs the flatbuffers package)."""
    try:
        import jax.export  # noqa: F401
        from jax._src.export import serialization  # noqa: F401
    except ImportError:
        return False
    return True


@functools.cache
def _environment_digest() -> bytes:
    """jaxtree's source and the versions of what traces it."""
    import importlib.metadata as md
    import pathlib

    h = hashlib.sha256()
    h.update(sys.version.encode())
    for dist in ("jax", "jaxlib", "equinox", "diffrax", "lineax", "optimistix", "numpy"):
        try:
            h.update(f"{dist}={md.version(dist)};".encode())
        except md.PackageNotFoundError:
            h.update(f"{dist}=none;".encode())
    root = pathlib.Path(__file__).resolve().parent.parent  # the jaxtree package
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.digest()


class _KeyPickler(pickle.Pickler):
    def reducer_override(self, obj):  # pyright: ignore[reportIncompatibleMethodOverride]
        if isinstance(obj, (type, types.FunctionType, types.BuiltinFunctionType, types.MethodType)):
            module = (getattr(obj, "__module__", None) or "").split(".")[0]
            name = getattr(obj, "__qualname__", "")
            if module not in TRUSTED or "<lambda>" in name or "<locals>" in name:
                raise Unkeyable(f"{module}.{name}")
        return NotImplemented


def _pickle(obj) -> bytes:
    buf = io.BytesIO()
    pickler = _KeyPickler(buf, protocol=pickle.HIGHEST_PROTOCOL)
    # no memo: equal objects pickle alike whether or not they are one object (two equal strings
    # of a scene are one object in one process and two in the next: with the memo, the second
    # is a back-reference in one and a copy in the other, and the keys differed)
    pickler.fast = True
    try:
        pickler.dump(obj)
    except Unkeyable:
        raise
    except Exception as e:  # anything that does not pickle is not keyed
        raise Unkeyable(type(e).__name__) from None
    return buf.getvalue()


def _aval(x):
    return (tuple(x.shape), str(x.dtype), bool(getattr(x, "weak_type", False)))


def _trace_context() -> str:
    from jax._src import config as jc

    names = jc.trace_context_names() if hasattr(jc, "trace_context_names") else ()
    values = jc.trace_context()
    parts = []
    for i, v in enumerate(values):
        text = repr(v)
        if " at 0x" in text:  # an object (the axis environment, empty at top level): its type only
            text = type(v).__name__
        parts.append(f"{names[i] if i < len(names) else i}={text}")
    return ";".join(parts)


def key(fn, dyn, static, options) -> str:
    """The digest of one call (see the module's text); raises :class:`Unkeyable`."""
    if not (getattr(fn, "__module__", "") or "").startswith("jaxtree."):
        raise Unkeyable("not a program of jaxtree's")
    skeleton = jax.tree_util.tree_map(_aval, dyn)
    device = jax.devices()[0]
    env = sorted(
        (k, v) for k, v in os.environ.items() if k.startswith(("JAXTREE_", "EQX_")) and k != "JAXTREE_CACHE_DIR"
    )
    h = hashlib.sha256()
    h.update(_environment_digest())
    h.update(
        _pickle(
            (
                FORMAT,
                fn.__module__,
                fn.__qualname__,
                skeleton,
                static,
                sorted((options or {}).items()),
                device.platform,
                getattr(device, "device_kind", ""),
                jax.device_count(),
                cache.checks_state(),
                env,
            )
        )
    )
    h.update(_trace_context().encode())
    return h.hexdigest()


# ----------------------------------------------------------------------------- changed at run time
# The source digest is of the files; a process may rebind what they define (a test's monkeypatch, a
# user's experiment) and trace a program that the files do not describe. jaxtree's module and class
# namespaces are recorded when first seen (at `import jaxtree` for the modules it imports, see
# record()); while a recorded name is bound to another object, nothing is read from or written to
# disk and the program is traced as before. (An object mutated in place, a dict's items, is not
# seen; jaxtree's own modules rebind nothing at run time.)

_SEEN: dict[str, list[tuple[object, dict]]] = {}


def _namespaces(name: str, module) -> list[tuple[object, dict]]:
    names = vars(module).copy()
    spaces: list[tuple[object, dict]] = [(module, names)]
    for value in names.values():
        if isinstance(value, type) and value.__module__ == name:
            spaces.append((value, dict(vars(value))))
    return spaces


def record() -> None:
    """Record the namespaces of jaxtree's modules not yet seen. `sys.modules` is copied in one
    step (``dict.copy`` runs no Python code): ``list(sys.modules.items())`` allocates a tuple per
    module, an allocation may start a garbage collection whose finalizers let another thread run,
    and a thread that imports meanwhile (the command line's warm-up of the writers) changed the
    dict under the iteration (a RuntimeError in a test run)."""
    for name, module in sys.modules.copy().items():
        if module is not None and name not in _SEEN and (name == "jaxtree" or name.startswith("jaxtree.")):
            _SEEN[name] = _namespaces(name, module)


def rebound() -> str | None:
    """The first recorded name bound to another object now (``module.name`` or
    ``module.Class.name``), or None."""
    record()
    missing = object()
    for name, spaces in _SEEN.items():
        for owner, seen in spaces:
            now = vars(owner)
            for attr, value in seen.items():
                if now.get(attr, missing) is not value:
                    where = name if owner is sys.modules.get(name) else f"{name}.{getattr(owner, '__name__', '?')}"
                    return f"{where}.{attr}"
    return None


# ----------------------------------------------------------------------------- the entries
class _Entry:
    """A program ready to call: the jitted call of the exported program, and how to rebuild the
    output (its arrays' places, its static part)."""

    def __init__(self, name, exported, places, out_static, options):
        def program(*leaves):
            return exported.call(*leaves)

        program.__name__ = program.__qualname__ = name  # the program's name in JAX's logs and cache
        self.call = jax.jit(program, compiler_options=options) if options else jax.jit(program)
        self.compiled: Any = None  # compiled ahead of the first call (the key fixes the shapes)
        self.places = places
        self.out_static = out_static

    def prepare(self, leaves) -> None:
        """Compile (or read from the compilation cache) for the shapes of `leaves`."""
        self.compiled = self.call.lower(*leaves).compile()

    def __call__(self, leaves):
        import equinox as eqx

        if self.compiled is None:
            self.prepare(leaves)
        assert self.compiled is not None
        flat = self.compiled(*leaves)
        out = jax.tree_util.tree_map(lambda i: flat[i], self.places)
        return eqx.combine(out, self.out_static)


_MEMO: collections.OrderedDict[str, _Entry | None] = collections.OrderedDict()
# this process's counts by program name: "exported" (traced and written), "loaded" (read back),
# "refused" (not exportable: traced as before), "as before" (not keyable, rebound names, devices)
COUNTS: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)


class Stopwatch:
    """This process's time spent making programs ready to run: tracing, exporting, loading,
    compiling or reading them from the compilation cache (`seconds`), and the calls that went
    around the kept programs (`untimed`: traced and compiled inside the call, as before, so
    their preparation is not in `seconds`). The main job reads it to tell a first call's
    compilation from its run without running twice."""

    def __init__(self):
        self.seconds = 0.0
        self.untimed = 0
        self.exclusive = False

    @contextlib.contextmanager
    def timing(self):
        """Within: a program waits for its inputs before it is made ready, so that `seconds`
        does not include a previous program still running (XLA runs it while the next is
        traced and compiled); outside, the two overlap."""
        before, self.exclusive = self.exclusive, True
        try:
            yield self
        finally:
            self.exclusive = before

    def since(self, mark: tuple[float, int]) -> tuple[float, bool]:
        """``(seconds, complete)`` since ``mark`` (a :meth:`mark`); `complete` when every
        program called in between was timed."""
        return self.seconds - mark[0], self.untimed == mark[1]

    def mark(self) -> tuple[float, int]:
        return self.seconds, self.untimed


PREPARED = Stopwatch()


def _remember(k: str, entry: _Entry | None) -> None:
    _MEMO[k] = entry
    _MEMO.move_to_end(k)
    while len(_MEMO) > MEMO_SIZE:
        _MEMO.popitem(last=False)


def _write(path: str, payload: bytes) -> None:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(path), prefix=".tmp-")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _evict(os.path.dirname(path))


def _evict(folder: str) -> None:
    """Remove the least recently used entries beyond :data:`MAX_BYTES`."""
    try:
        entries = [e for e in os.scandir(folder) if e.is_file() and not e.name.startswith(".tmp-")]
    except OSError:
        return
    total = sum(e.stat().st_size for e in entries)
    if total <= MAX_BYTES:
        return
    for e in sorted(entries, key=lambda e: e.stat().st_mtime):
        if total <= MAX_BYTES:
            break
        with contextlib.suppress(OSError):
            size = e.stat().st_size
            os.unlink(e.path)
            total -= size


def _load(path: str, name: str, options) -> tuple[bool, _Entry | None]:
    """``(found, entry)`` at `path`: entry None for a program remembered as not exportable;
    found False when absent or unreadable."""
    try:
        with open(path, "rb") as f:
            payload = f.read()
    except OSError:
        return False, None
    try:
        kind, blob, places, out_static = pickle.loads(payload)
        if kind == "refused":
            return True, None
        exported = jax.export.deserialize(bytearray(blob))
        entry = _Entry(name, exported, places, out_static, options)
    except Exception:  # a damaged or foreign entry: traced again and rewritten
        return False, None
    with contextlib.suppress(OSError):
        os.utime(path)  # recently used
    return True, entry


def _export(fn, dyn, static, in_tree, leaves, options):
    """Trace `fn` once through ``jax.export``; returns ``(entry, payload)``."""
    import equinox as eqx

    box = []

    def flat(*lv):
        args, kwargs = eqx.combine(jax.tree_util.tree_unflatten(in_tree, lv), static)
        out = fn(*args, **kwargs)
        out_dyn, out_static = eqx.partition(out, eqx.is_array)
        out_leaves, out_tree = jax.tree_util.tree_flatten(out_dyn)
        box.append((jax.tree_util.tree_unflatten(out_tree, list(range(len(out_leaves)))), out_static))
        return out_leaves

    flat.__name__ = flat.__qualname__ = fn.__name__
    exported = jax.export.export(jax.jit(flat))(*leaves)
    if exported.nr_devices != 1:  # sharded over the devices (a campaign's chunk): not kept
        raise Unkeyable("sharded over several devices")
    blob = bytes(exported.serialize())
    places, out_static = box[-1]
    payload = pickle.dumps(("program", blob, places, out_static), protocol=pickle.HIGHEST_PROTOCOL)
    # called as read back, as a later process calls it: the program compiled here is the one
    # the compilation cache then holds for that process (the exported object before its round
    # trip lowers to a module that differs in detail, a miss in the cache)
    exported = jax.export.deserialize(bytearray(blob))
    return _Entry(fn.__name__, exported, places, out_static, options), payload


def _on_the_default_device(x) -> bool:
    sharding = getattr(x, "sharding", None)
    if sharding is None:  # numpy
        return True
    devices = sharding.device_set
    return len(devices) == 1 and next(iter(devices)) == jax.devices()[0]


def call(fn, args, kwargs, options, fallback):
    """``fn(*args, **kwargs)`` through a kept program where one is (or can be) kept, else
    `fallback` ``(*args, **kwargs)`` (the program traced as before)."""
    import equinox as eqx

    folder = directory()
    if folder is None:
        PREPARED.untimed += 1
        return fallback(*args, **kwargs)
    if PREPARED.exclusive:
        jax.block_until_ready(args)
    start = time.perf_counter()
    counts = COUNTS[getattr(fn, "__name__", "?")]
    dyn, static = eqx.partition((args, kwargs), eqx.is_array)
    leaves, in_tree = jax.tree_util.tree_flatten(dyn)
    try:
        if not all(_on_the_default_device(x) for x in leaves):
            raise Unkeyable("sharded or placed by the caller")
        k = key(fn, dyn, static, options)
    except Unkeyable:
        counts["as before"] += 1
        PREPARED.untimed += 1
        return fallback(*args, **kwargs)
    if k in _MEMO:
        entry = _MEMO[k]
        _MEMO.move_to_end(k)
    elif rebound() is not None:
        counts["as before"] += 1
        PREPARED.untimed += 1
        return fallback(*args, **kwargs)
    else:
        path = os.path.join(folder, k)
        found, entry = _load(path, fn.__name__, options)
        if not found:
            try:
                entry, payload = _export(fn, dyn, static, in_tree, leaves, options)
            except Exception:  # host callbacks, a custom call export refuses ...
                entry, payload = None, pickle.dumps(("refused", None, None, None))
            with contextlib.suppress(OSError):
                _write(path, payload)
        counts["refused" if entry is None else "loaded" if found else "exported"] += 1
        _remember(k, entry)
    if entry is None:
        PREPARED.untimed += 1
        return fallback(*args, **kwargs)
    if entry.compiled is None:
        entry.prepare(leaves)
        PREPARED.seconds += time.perf_counter() - start
    return entry(leaves)


def clear_memory() -> None:
    """Forget the programs held in this process (the files stay)."""
    _MEMO.clear()
