"""diffrax's end-of-interval floor in one loop instead of a hundred written-out operations.

At the start of its integration loop, diffrax (``diffrax._integrate.loop``, 0.6-0.7) computes the
number 100 ULPs below ``t1`` (the threshold from which a step is rounded to ``t1``) by applying
``equinox.internal.prevbefore`` a hundred times in Python. With ``t1`` traced, as jaxtree keeps it
(a new end time compiles nothing), these are 100 staged ``nextafter`` operations in every solve's
program, which cost a sixth of ``simulate(fig4_free)``'s first call (lowering and XLA: 0.30 s of
1.9 s; benchmarks/FINDINGS.md, "diffrax's end-time floor").

:func:`one_loop_floor` is a context manager around jaxtree's own ``diffeqsolve``: while it is
entered (in any thread), ``diffrax._integrate`` sees a view of ``equinox.internal`` whose
``prevbefore`` returns its argument for the first 99 calls of a run of 100 and, at the 100th, the
same number the 100 calls give (``prevbefore`` in a ``lax.fori_loop`` of 100 iterations: one
loop body to compile, the same value and the same derivative). ``prevbefore`` is called nowhere
else in that module, which is checked against diffrax's source once: where the source differs
(another diffrax version), nothing is replaced.
"""

from __future__ import annotations

import contextlib
import inspect
import threading
import types
from typing import Any

import equinox.internal as eqxi
import jax

_CHAIN = 100
_LOOP_SOURCE = f"for _ in range({_CHAIN}):\n        t1_clip_floor = eqxi.prevbefore(t1_clip_floor)"


def _module():
    """``diffrax._integrate`` when its only use of ``prevbefore`` is the loop of :data:`_LOOP_SOURCE`,
    else None."""
    try:
        import diffrax._integrate as integrate

        source = inspect.getsource(integrate)
    except (ImportError, OSError, TypeError):
        return None
    if source.count("prevbefore") != 1 or _LOOP_SOURCE not in source:
        return None
    if getattr(integrate, "eqxi", None) is not eqxi:
        return None
    return integrate


@jax.custom_jvp
def floor_below(x):
    """``x`` after :data:`_CHAIN` applications of ``equinox.internal.prevbefore``, in one loop."""
    return jax.lax.fori_loop(0, _CHAIN, lambda _, v: eqxi.prevbefore(v), x)


@floor_below.defjvp
def _floor_below_jvp(primals, tangents):  # prevbefore's own rule: the tangent passes through
    return floor_below(primals[0]), tangents[0]


class _Counting(types.ModuleType):
    """``equinox.internal`` as ``diffrax._integrate`` sees it while :func:`one_loop_floor` is entered:
    every attribute is equinox's, except ``prevbefore``, counted per thread."""

    def __init__(self):
        super().__init__("equinox.internal")
        self._calls = threading.local()

    def __getattr__(self, name):
        return getattr(eqxi, name)

    def prevbefore(self, x):
        count = getattr(self._calls, "n", 0) + 1
        if count < _CHAIN:
            self._calls.n = count
            return x
        self._calls.n = 0
        return floor_below(x)

    def reset(self):
        self._calls.n = 0


_integrate: Any = _module()  # (Any: diffrax does not export its name for equinox.internal)
_view = _Counting()
_lock = threading.Lock()
_entered = 0


@contextlib.contextmanager
def one_loop_floor():
    """Within: diffrax's end-time floor computed by :func:`floor_below` (see the module's text)."""
    global _entered
    if _integrate is None:
        yield
        return
    _view.reset()
    with _lock:
        _entered += 1
        _integrate.eqxi = _view
    try:
        yield
    finally:
        with _lock:
            _entered -= 1
            if _entered == 0:
                _integrate.eqxi = eqxi
