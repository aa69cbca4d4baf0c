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
- One CPU device per core this process may use (:func:`use_every_core`), so that a campaign's
  chunks run on every core; only while JAX's backend has not started, where the CPU is JAX's
  default backend and nothing else sets the count. ``JAXTREE_HOST_DEVICES=1`` (or ``0``) keeps
  JAX's one device, ``JAXTREE_HOST_DEVICES=N`` asks for N.
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


def cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def use_every_core() -> int | None:
    """Give JAX's CPU backend one device per core (``jax_num_cpu_devices``), so that
    :func:`jaxtree.monte_carlo` can shard its chunks over them; returns the count set, or None
    where nothing was changed.

    XLA:CPU runs one program's loops on one thread: a batch of members vmapped in one program uses
    one core however many the machine has. With a device per core a chunk is split over the
    devices (``shard_map``) and each runs its share on its own core (``benchmarks/FINDINGS.md``,
    "Every core by default": 512 fig4_free runs 2.3x as fast on two cores). A program of one
    member runs on the first device as before, at the same speed.

    Left alone (None): ``JAXTREE_HOST_DEVICES`` set to 0, 1 or off; a count already set
    (``XLA_FLAGS=--xla_force_host_platform_device_count``, or ``jax_num_cpu_devices``); an
    accelerator as JAX's default backend; JAX's backend already started (the count is read when
    it starts: import jaxtree before computing with JAX); one core."""
    setting = os.environ.get("JAXTREE_HOST_DEVICES", "").strip().lower()
    if setting in OFF + ("1",):
        return None
    if "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "") or not runs_on_cpu():
        return None
    if setting:
        try:
            count = int(setting)
        except ValueError:
            raise ValueError(f"JAXTREE_HOST_DEVICES must be a whole number or off, got {setting!r}") from None
    else:
        count = cores()
    import jax
    from jax._src import xla_bridge

    if (
        count <= 1
        or xla_bridge.backends_are_initialized()
        or getattr(jax.config, "jax_num_cpu_devices", -1) not in (-1, None)
    ):
        return None
    jax.config.update("jax_num_cpu_devices", count)
    return count
