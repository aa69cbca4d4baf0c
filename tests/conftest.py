"""Shared fixtures. Importing jaxtree turns on float64."""

import os

# XLA's CPU fusion emitters roughly double compile times for the many small programs of a
# test run (the ODE solves above all) with no gain in run time at these sizes; set before
# JAX starts its backend. jaxlib >= 0.11 has no older emitters and aborts on the flag (jaxtree's
# numerics.legacy_cpu_emitters; not imported here: importing jaxtree reads the cache directory
# set below).
import jaxlib

if tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) < (0, 11) and "xla_cpu_use_fusion_emitters" not in (
    os.environ.get("XLA_FLAGS", "")
):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()
# Most of the suite's time is XLA compiling programs that then run for milliseconds: at XLA's
# lowest backend optimization level they compile faster and the whole runs shorter even where a
# test runs long (six of the slowest tests, 497 -> 404 s on 2026-11-28; benchmarks/FINDINGS.md).
# The numbers are the same arithmetic (no fast math at any level); speed is the benchmarks' job.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=0").strip()

# The tests compile from scratch and leave no files behind, but a program is compiled once per
# run: the persistent compilation cache that `import jaxtree` turns on lives in a directory of
# this run alone, made by the first process (pytest's, before its xdist workers start: they
# inherit it) and removed at its end. The two workers then share what either compiled, and a
# program compiled again after its worker cleared JAX's caches (below) is read back.
# JAXTREE_TEST_CACHE=0 runs without it (each worker compiles all it needs); a JAXTREE_CACHE_DIR
# of yours wins. tests/test_cli.py checks the cache itself in fresh interpreters.
_RUN_CACHE = None
if "JAXTREE_CACHE_DIR" not in os.environ:
    if os.environ.get("JAXTREE_TEST_CACHE", "").strip().lower() in ("0", "off", "no", "false"):
        os.environ["JAXTREE_CACHE_DIR"] = "0"
    elif "JAXTREE_TEST_RUN_CACHE" in os.environ:  # an xdist worker: the controller's directory
        os.environ["JAXTREE_CACHE_DIR"] = os.environ["JAXTREE_TEST_RUN_CACHE"]
    else:
        import tempfile

        _RUN_CACHE = tempfile.mkdtemp(prefix="jaxtree-test-cache-")
        os.environ["JAXTREE_TEST_RUN_CACHE"] = os.environ["JAXTREE_CACHE_DIR"] = _RUN_CACHE
    # every program that took a tenth of a second to compile (jaxtree's default: half a second)
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.1")

import jax
import pytest

import jaxtree  # first: it sets the float64 and BLAS-thread defaults before JAX loads
from jaxtree._src import programs

jax.config.update("jax_enable_x64", True)

from helpers import scene_names


@pytest.fixture(scope="session")
def scenes():
    """Every bundled reference scene, loaded once."""
    return {name: jaxtree.load_scene(name) for name in scene_names()}


# ----------------------------------------------------------------------------- compiled programs
# A worker keeps every program it compiled (JAX's caches), and XLA:CPU maps each one's code into
# the process: test_truncation.py alone leaves ~6500 memory maps, and a worker that runs half of
# the suite approaches the kernel's limit (vm.max_map_count, 65530 here). Past it an mmap inside
# XLA's compiler fails and the worker dies of a segmentation fault in `backend_compile_and_load`
# (two full runs of 2026-11-27, both late in test_truncation.py; not reproduced in shorter runs).
# Between modules, once the maps pass 40 % of the limit, JAX's caches are cleared (that unmaps
# most: 6551 -> 1379 after test_truncation.py).
_MAPS = {"peak": 0, "clears": 0}


def _maps_and_limit():
    try:
        with open("/proc/self/maps") as fh:
            n = sum(1 for _ in fh)
        with open("/proc/sys/vm/max_map_count") as fh:
            return n, int(fh.read())
    except (OSError, ValueError):
        return 0, 0


# Memory: XLA:CPU keeps every compiled program in the process (a Radau5 program of a few bodies
# holds ~0.1 GiB) and compiling takes hundreds of MB of heap that glibc keeps once freed; a worker
# grew to 7-8.6 GiB over a full run (2026-11-27), most of it programs that no later test calls.
# After each test the free heap goes back to the system (malloc_trim). A worker drops its compiled
# programs and their traces (JAX's caches) between modules once over RELEASE_BETWEEN_MODULES of
# resident memory, and after a test once over RELEASE_IN_MODULE (the programs a module's tests
# share are then traced again: the in-module threshold is the higher one). The run's persistent
# cache gives a dropped program back without compiling it again. Dropping only the executables
# and keeping the traces does not do: the traces of these programs are as large. Measured on
# test_appendage.py + test_batched.py, 2 workers: peak 5.0 / 5.3 GiB without, 2.6 / 3.0 GiB with the
# thresholds at 1.0 / 2.0 GiB (4 + 3 clears), 465 against 486 s; at 1.0 / 1.5 GiB 2.0 / 2.2 GiB
# (7 + 4 clears), 465 s. The full suite at 1.0 / 1.75 GiB: 2.87 / 2.77 GiB, 27:24 (2026-11-28).
RELEASE_BETWEEN_MODULES = 1.0 * 2**30
RELEASE_IN_MODULE = 1.5 * 2**30


def _trim():
    global _LIBC
    if _LIBC is None:
        import ctypes
        import ctypes.util

        try:
            _LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
        except (OSError, AttributeError):  # not glibc: nothing to trim
            _LIBC = False
    if _LIBC:
        _LIBC(0)


_LIBC = None


def _resident_bytes():
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _release():
    import gc

    jax.clear_caches()
    programs.clear_memory()  # the kept programs' calls held in the process (their files stay)
    gc.collect()
    _trim()
    _MAPS["clears"] += 1


@pytest.fixture(autouse=True)
def _return_free_memory():
    yield
    _trim()
    if _resident_bytes() > RELEASE_IN_MODULE:
        _release()


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    yield
    n, limit = _maps_and_limit()
    _MAPS["peak"] = max(_MAPS["peak"], n)
    if (limit and n > 0.4 * limit) or _resident_bytes() > RELEASE_BETWEEN_MODULES:
        _release()


# ----------------------------------------------------------------------------- peak memory
# Each process's peak resident memory (ru_maxrss: kB on Linux, bytes on macOS), reported after
# the run beside the ten slowest tests: a worker holds every program it compiled.


def _peak_bytes():
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024


_PEAKS = {}
_WORKER_MAPS = {}


def pytest_unconfigure(config):
    if _RUN_CACHE is not None:  # the process that made the run's cache directory removes it
        import shutil

        shutil.rmtree(_RUN_CACHE, ignore_errors=True)


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: its figure goes to the controller
        workeroutput["peak_bytes"] = _peak_bytes()
        workeroutput["maps"] = (_MAPS["peak"], _MAPS["clears"])


def pytest_testnodedown(node, error):
    peak = getattr(node, "workeroutput", {}).get("peak_bytes")
    if peak is not None:
        _PEAKS[node.gateway.id] = peak
    maps = getattr(node, "workeroutput", {}).get("maps")
    if maps is not None:
        _WORKER_MAPS[node.gateway.id] = maps


def pytest_terminal_summary(terminalreporter):
    peaks = dict(_PEAKS) or {"this process": _peak_bytes()}
    text = ", ".join(f"{name} {peak / 2**30:.2f} GiB" for name, peak in sorted(peaks.items()))
    terminalreporter.write_line(f"peak memory: {text}")
    maps = dict(_WORKER_MAPS) or {"this process": (_MAPS["peak"], _MAPS["clears"])}
    text = ", ".join(f"{name} {m} (caches cleared {c}x)" for name, (m, c) in sorted(maps.items()))
    terminalreporter.write_line(f"memory maps at a module's end, most: {text}")
