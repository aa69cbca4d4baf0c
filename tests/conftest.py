"""Shared fixtures. Importing jaxtree turns on float64."""

import os
import pathlib

# XLA's CPU fusion emitters roughly double compile times for the many small programs of a
# test run (the ODE solves above all) with no gain in run time at these sizes; set before
# JAX starts its backend.
if "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()

import jaxtree  # first: it sets the float64 and BLAS-thread defaults before JAX loads

import jax
import numpy as np
import pytest

jax.config.update("jax_enable_x64", True)

SHARED_SCENES = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "scenes"


def scene_names():
    return jaxtree.list_scenes()


@pytest.fixture(scope="session")
def scenes():
    """Every bundled reference scene, loaded once."""
    return {name: jaxtree.load_scene(name) for name in scene_names()}


def random_state(model, rng, scale=1.0):
    """A random state of `model`: angles over the full circle, rates of order `scale`."""
    n = model.n
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    dcm = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)],
        [2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x)],
        [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)],
    ])
    return jaxtree.State(
        jax.numpy.asarray(dcm),
        jax.numpy.asarray(scale * rng.normal(size=3)),
        jax.numpy.asarray(rng.uniform(-np.pi, np.pi, size=n)),
        jax.numpy.asarray(scale * rng.normal(size=n)),
    )
