"""Helpers shared by the benchmark scripts: the machine line and first-call / median timing."""

import statistics
import time

import jax


def machine() -> str:
    """One line: OS, CPU model, cores, load average, Python and library versions, JAX backend
    (the work-precision report's line, :func:`jaxtree.bench.machine_line`)."""
    from jaxtree.bench import machine_line

    return machine_line()


def timed(fn, repeats, least=False):
    """(result, first-call time including compilation, median of `repeats` later calls; their
    least with `least`, for a run whose load only adds)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    return out, first, min(runs) if least else statistics.median(runs)


def write_json(path, results) -> None:
    """Write `results` as JSON to `path` atomically (jaxtree._src.io.output.atomic_write); numpy
    scalars are written as floats."""
    import json

    from jaxtree._src.io.output import atomic_write

    with atomic_write(path, "w") as fh:
        json.dump(results, fh, indent=1, default=float)
        fh.write("\n")


def dispersed_fig4(key, model):
    """The fig4_free campaign's member drawn from `key`: body rate, panel hinge rates and panel
    stiffness dispersed (bench_campaign.py, bench_gpu.py)."""
    import equinox as eqx
    import jax.numpy as jnp
    import numpy as np

    k = jax.random.split(key, 3)
    s = model.initial
    # Draws in float64 whatever the model's precision, cast below: the float32 campaign's members are
    # then the float64 reference's, rounded (draws in float32 from the same key are other numbers,
    # and its "error" compared different members: 0.92 on 2026-11-24).
    dtype = jnp.float64
    panels = np.asarray(model.sprung[1:]) - 1  # the panel chain (hinge 1 is the platform's)
    omega0 = s.omega0.astype(dtype) + 0.01 * jax.random.normal(k[0], (3,), dtype)
    gamma_dot = s.gamma_dot.astype(dtype).at[panels].add(0.01 * jax.random.normal(k[1], (len(panels),), dtype))
    spread = 1 + 0.1 * jax.random.normal(k[2], (len(panels),), dtype)
    stiffness = model.stiffness.astype(dtype).at[panels].multiply(spread)
    return eqx.tree_at(
        lambda m: (m.stiffness, m.initial),
        model,
        (
            stiffness.astype(model.stiffness.dtype),
            s._replace(omega0=omega0.astype(s.omega0.dtype), gamma_dot=gamma_dot.astype(s.gamma_dot.dtype)),
        ),
    )


def use_fast_cpu_flags(*, default_xla=False):
    """XLA:CPU's older LLVM emitters for this benchmark's process (``--xla_cpu_use_fusion_emitters=false``
    in ``XLA_FLAGS``), as ``python -m jaxtree`` sets them, unless `default_xla`, an XLA_FLAGS that
    names the option, or a jaxlib without them (>= 0.11, which aborts on the flag: jaxtree's
    ``numerics.legacy_cpu_emitters``, not imported here because importing jaxtree sets the
    process's CPU devices). Call it before JAX starts its backend."""
    import os

    import jaxlib

    current = os.environ.get("XLA_FLAGS", "")
    try:
        legacy = tuple(int(x) for x in jaxlib.__version__.split(".")[:2]) < (0, 11)
    except ValueError:
        legacy = False
    if legacy and not default_xla and "xla_cpu_use_fusion_emitters" not in current:
        os.environ["XLA_FLAGS"] = f"{current} --xla_cpu_use_fusion_emitters=false".strip()
