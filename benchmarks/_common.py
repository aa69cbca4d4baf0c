"""Helpers shared by the benchmark scripts: the machine line and first-call / median timing."""

import os
import platform
import statistics
import time

import diffrax
import equinox as eqx
import jax
import numpy as np


def machine() -> str:
    """One line: OS, CPU model, cores, load average, Python and library versions, JAX backend."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    load = ", load average {:.2f} {:.2f} {:.2f}".format(*os.getloadavg()) if hasattr(os, "getloadavg") else ""
    return (
        f"{platform.system()} {platform.release()}, {cpu}, {os.cpu_count()} cores{load}; "
        f"python {platform.python_version()}, jax {jax.__version__}, diffrax {diffrax.__version__}, "
        f"equinox {eqx.__version__}, numpy {np.__version__}; backend {jax.default_backend()} "
        f"{jax.devices()[0].device_kind}"
    )


def timed(fn, repeats):
    """(result, first-call time including compilation, median of `repeats` later calls)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    return out, first, statistics.median(runs)


def write_json(path, results) -> None:
    """Write `results` as JSON to `path` atomically (jaxtree._src.output.atomic_write); numpy
    scalars are written as floats."""
    import json

    from jaxtree._src.output import atomic_write

    with atomic_write(path, "w") as fh:
        json.dump(results, fh, indent=1, default=float)
        fh.write("\n")
