"""Helpers shared by the benchmark scripts: the machine line and first-call / median timing."""

import statistics
import time

import jax


def machine() -> str:
    """One line: OS, CPU model, cores, load average, Python and library versions, JAX backend
    (the work-precision report's line, :func:`jaxtree.bench.machine_line`)."""
    from jaxtree.bench import machine_line

    return machine_line()


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
    """Write `results` as JSON to `path` atomically (jaxtree._src.io.output.atomic_write); numpy
    scalars are written as floats."""
    import json

    from jaxtree._src.io.output import atomic_write

    with atomic_write(path, "w") as fh:
        json.dump(results, fh, indent=1, default=float)
        fh.write("\n")
