"""Shared fixtures. Importing jaxtree turns on float64."""

import os

# XLA's CPU fusion emitters roughly double compile times for the many small programs of a
# test run (the ODE solves above all) with no gain in run time at these sizes; set before
# JAX starts its backend.
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()

# The tests compile from scratch and leave no files behind: the persistent compilation cache
# that `import jaxtree` turns on is off here (tests/test_cli.py checks it in fresh interpreters).
os.environ.setdefault("JAXTREE_CACHE_DIR", "0")

import jax
import pytest

import jaxtree  # first: it sets the float64 and BLAS-thread defaults before JAX loads

jax.config.update("jax_enable_x64", True)

from helpers import scene_names


@pytest.fixture(scope="session")
def scenes():
    """Every bundled reference scene, loaded once."""
    return {name: jaxtree.load_scene(name) for name in scene_names()}


# ----------------------------------------------------------------------------- peak memory
# Each process's peak resident memory (ru_maxrss: kB on Linux, bytes on macOS), reported after
# the run beside the ten slowest tests: a worker holds every program it compiled.


def _peak_bytes():
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else peak * 1024


_PEAKS = {}


def pytest_sessionfinish(session):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: its figure goes to the controller
        workeroutput["peak_bytes"] = _peak_bytes()


def pytest_testnodedown(node, error):
    peak = getattr(node, "workeroutput", {}).get("peak_bytes")
    if peak is not None:
        _PEAKS[node.gateway.id] = peak


def pytest_terminal_summary(terminalreporter):
    peaks = dict(_PEAKS) or {"this process": _peak_bytes()}
    text = ", ".join(f"{name} {peak / 2**30:.2f} GiB" for name, peak in sorted(peaks.items()))
    terminalreporter.write_line(f"peak memory: {text}")
