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
