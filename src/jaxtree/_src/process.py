"""What ``import jaxtree`` changes in the process, each with its opt-out (README, "What
``import jaxtree`` changes"). Imported first by :mod:`jaxtree`, before JAX.

- JAX's float64 mode (``jax_enable_x64``), unless ``JAXTREE_ENABLE_X64=0``.
- ``OPENBLAS_NUM_THREADS=1``, only where JAX's CPU backend runs the computations (jaxlib's CPU
  kernels call the LAPACK that scipy bundles, and a multi-threaded OpenBLAS on Eq. (1)'s small
  matrices spins threads against XLA's own: 10-100x slower on a busy machine), and never over a
  value the environment sets. Where the default backend is an accelerator (``JAX_PLATFORMS``
  naming one first, or, unset, a CUDA, ROCm or TPU plugin installed) the workaround is not
  needed and the variable is left alone.
- JAX's persistent compilation cache (:mod:`.cache`), unless ``JAXTREE_CACHE_DIR=0``.
"""

from __future__ import annotations

import importlib.util
import os

OFF = ("0", "false", "no", "off")
ACCELERATOR_PLUGINS = ("jax_cuda12_plugin", "jax_cuda13_plugin", "jax_rocm60_plugin", "jax_rocm7_plugin", "libtpu")


def runs_on_cpu() -> bool:
    """Whether JAX's default backend will be the CPU, judged without starting JAX: the first
    platform of ``JAX_PLATFORMS`` when set, else whether no accelerator plugin is installed."""
    platforms = os.environ.get("JAX_PLATFORMS", "").strip().lower()
    if platforms:
        return platforms.split(",")[0].strip() == "cpu"
    return not any(_installed(name) for name in ACCELERATOR_PLUGINS)


def _installed(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def limit_openblas_threads() -> bool:
    """Set ``OPENBLAS_NUM_THREADS=1`` where the CPU backend runs and the environment does not set
    it; returns whether it was set here. It takes effect only if nothing loaded OpenBLAS before."""
    if "OPENBLAS_NUM_THREADS" in os.environ or not runs_on_cpu():
        return False
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    return True


def enable_x64() -> bool:
    """Turn on JAX's float64 mode unless ``JAXTREE_ENABLE_X64`` says no; returns whether it did."""
    if os.environ.get("JAXTREE_ENABLE_X64", "1").strip().lower() in OFF:
        return False
    import jax

    jax.config.update("jax_enable_x64", True)
    return True
