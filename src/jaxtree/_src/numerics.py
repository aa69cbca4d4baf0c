"""Small numerical helpers shared across the packages: the singularity test and the elimination
of Eq. (1)'s factorizations, the symmetric-positive-definite inverse of the derivative rule, the
compile options of one-off builds, and :func:`is_traced` (whether a value is known only at run
time, so that its checks are left to run time)."""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Iterator
from typing import ParamSpec, TypeVar, cast

import jax
import jax.numpy as jnp
import numpy as np
from jax.core import Tracer

_P = ParamSpec("_P")
_R = TypeVar("_R")

# Set while a Jacobian is traced that no derivative will ever be taken of (Radau5's J: its inputs
# and its value are cut from derivatives by `stop_gradient`): the derivative rule of Eq. (1) then
# gives its tangents directly instead of as a linear solve, whose product and transposed solve
# JAX traces up front for a transposition or a second derivative that cannot come (flex95: about
# half of the Jacobian's trace). A context variable: each thread starts without it. JAX caches the
# JVP of a jitted function's jaxpr whatever the context, so only what nothing differentiates is traced
# under it (a jaxpr differentiated here and transposed elsewhere would fail loudly: no transpose).
_FORWARD_ONLY = contextvars.ContextVar("jaxtree_forward_only", default=False)


@contextlib.contextmanager
def forward_only() -> Iterator[None]:
    """Trace the enclosed tangents of Eq. (1) for forward use only (see ``_FORWARD_ONLY``)."""
    token = _FORWARD_ONLY.set(True)
    try:
        yield
    finally:
        _FORWARD_ONLY.reset(token)


def is_forward_only() -> bool:
    """Whether the tangents traced now are for forward use only (:func:`forward_only`)."""
    return _FORWARD_ONLY.get()


# A pivot d_i^2 of the Cholesky factorization A = L L^T of Eq. (1)'s matrix is at round-off
# level when d_i^2 / A_ii < SINGULAR_PIVOT sqrt(m) eps (m rows, eps the unit roundoff). d_i^2 / A_ii
# are the pivots of the Jacobi-scaled matrix D^-1/2 A D^-1/2, so mass ratios do not enter. An
# exactly singular matrix (gimbal lock) may leave such a pivot instead of failing the
# factorization, and the solve would return finite garbage. Measured on this project's scenes
# (40 random states each, float64 and float32): exact gimbal locks give pivots of 1.5-114 eps or
# fail the factorization; regular states give at least 5e-5 (480 eps in float32, where the
# threshold is 200 eps).
SINGULAR_PIVOT = 20.0


def regular_pivots(pivots, A):
    """False when one of the k `pivots` of the LDL^T factorization of `A` (..., m, m; its first
    k rows, see :func:`eliminate`) is at round-off level: the test of :func:`regular`."""
    k = pivots.shape[-1]
    scaled = pivots / jnp.diagonal(A, axis1=-2, axis2=-1)[..., :k]
    tol = SINGULAR_PIVOT * float(np.sqrt(k)) * float(jnp.finfo(A.dtype).eps)
    return jnp.all(scaled > tol)  # NaN pivots fail too


def regular(L, A):
    """False when a pivot of the factor `L` of `A` (m x m, batched) is at round-off level."""
    m = A.shape[-1]
    pivot = jnp.diagonal(L, axis1=-2, axis2=-1) ** 2 / jnp.diagonal(A, axis1=-2, axis2=-1)
    tol = SINGULAR_PIVOT * float(np.sqrt(m)) * float(jnp.finfo(A.dtype).eps)
    return jnp.min(pivot) > tol  # a failed factorization (NaN) is singular too


# ----------------------------------------------------------------------------- small batched eliminations
# jaxlib 0.10's CPU LAPACK kernels (potrf, trsm) split a batch over XLA:CPU's intra-op thread pool
# and block one pool thread until the parts are done (``ParallelBatchMap``). Two such kernels that
# XLA runs concurrently (independent thunks of one program, e.g. a primal and a tangent solve under
# ``jax.jacfwd``) can hold every thread of a small pool while waiting for work queued behind each
# other: the articulated recursion of Eq. (1) hung that way on chain50 on a 2-core machine
# (benchmarks/FINDINGS.md). The stacks of small matrices of the block recursion are therefore
# eliminated here by unrolled rank-one updates vectorized over the stack: no library call, no
# thread pool.


def eliminate(A, k: int):
    """Gauss-Jordan elimination of the first `k` pivots of the symmetric positive definite stack
    `A` (..., m, m) = ``[[A11, A12], [A21, A22]]`` (A11: k x k), without pivoting (SPD: the
    pivots are positive). Returns ``(G, S, pivots)``: ``G = A11^{-1} A12`` (..., k, m - k), the
    Schur complement ``S = A22 - A21 A11^{-1} A12`` (..., m - k, m - k) and the k pivots
    (..., k), those of A's LDL^T factorization (``d_i^2`` of its Cholesky factor)."""
    m = A.shape[-1]
    eye = np.eye(m)
    pivots = []
    for j in range(k):
        d = A[..., j, j]
        # row j / d, and every other row minus its multiple of it: one rank-one update
        A = (
            A
            - (A[..., :, j] - jnp.asarray(eye[j], A.dtype))[..., :, None] * (A[..., j, :] / d[..., None])[..., None, :]
        )
        pivots.append(d)
    return A[..., :k, k:], A[..., k:, k:], jnp.stack(pivots, -1)


def spd_inverse(A):
    """The inverse of the symmetric positive definite matrix `A` (m, m) by in-place Gauss-Jordan
    elimination without pivoting (SPD: positive pivots), in a ``fori_loop`` of m rank-one updates:
    no LAPACK call (see above), a compiled size independent of m, and batches under ``jax.vmap``.
    About 2 m^3 flops. Returns ``(inverse, pivots)``, the pivots those of A's LDL^T factorization
    (for :func:`regular_pivots`); a zero or negative pivot gives non-finite entries."""
    m = A.shape[-1]
    eye = jnp.eye(m, dtype=A.dtype)

    def step(j, carry):
        M, pivots = carry
        e = eye[j]
        d = M[j, j]
        row = M[j, :] / d
        col = M[:, j] - e  # column j of M with the pivot row's own entry removed
        M = M - col[:, None] * row[None, :]
        # column j of the inverse: -col / d off the pivot, 1 / d on it
        return M.at[:, j].set(jnp.where(e > 0, 1.0 / d, -col / d)), pivots.at[j].set(d)

    return jax.lax.fori_loop(0, m, step, (A, jnp.zeros((m,), A.dtype)))


# ----------------------------------------------------------------------------- jaxtree's own programs
# XLA:CPU's newer fusion emitters (its default) compile jaxtree's many small fused kernels about
# 1.5-2x slower and run vmapped batches of Eq. (1) up to 2x slower than the older LLVM emitters
# (chain50, 256 members: 19.4 against 11.4 us a member; Radau5's first call on flex95: XLA 13.5
# against 9.0 s; benchmarks/FINDINGS.md). The option is set per program, on the programs jaxtree
# compiles at the top level (a solve, its diagnostics, a campaign's chunk), so the process's XLA
# settings and the user's own programs are untouched; an XLA_FLAGS that names the option wins.
CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
# Added for the brief programs of ``program_jit(light=...)`` (benchmarks/FINDINGS.md, "Short
# programs at XLA's level 0").
LIGHT_COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}
# For programs whose numbers must not depend on the machine's core count or on how many devices
# share a batch (a campaign's chunk): XLA:CPU splits a program's LLVM module into parts that it
# compiles in parallel, and the parts were optimized differently in a program sharded over two
# devices and in the same program on one, so that a member's states differed by ~1e-9 between
# the two (benchmarks/FINDINGS.md, "Bit for bit across core counts"). One part: the same machine
# code for a member wherever it runs, for ~30 % more compilation of that program.
REPRODUCIBLE_OPTIONS = {"xla_cpu_parallel_codegen_split_count": 1}


def legacy_cpu_emitters() -> bool:
    """Whether this jaxlib's XLA:CPU still has its older LLVM emitters, and with them the option
    ``xla_cpu_use_fusion_emitters`` (jaxlib < 0.11). Read from the version, without starting
    JAX's backend, for the settings made before it starts: an ``XLA_FLAGS`` that names an option
    XLA does not know aborts the process (jaxlib 0.11.2: "Unknown flag in XLA_FLAGS")."""
    from jaxlib.version import __version__ as jaxlib_version

    try:
        major, minor = (int(x) for x in jaxlib_version.split(".")[:2])
    except ValueError:
        return False
    return (major, minor) < (0, 11)


def fast_cpu_flags() -> str:
    """The ``XLA_FLAGS`` entry that selects XLA:CPU's older emitters where it has them (see
    :data:`CPU_COMPILER_OPTIONS`), else the empty string: for a process's own settings, made before
    JAX starts its backend (``python -m jaxtree``, the test suite, the benchmarks)."""
    return "--xla_cpu_use_fusion_emitters=false" if legacy_cpu_emitters() else ""


def use_fast_cpu_flags() -> None:
    """Adds :func:`fast_cpu_flags` to ``XLA_FLAGS`` unless it names the option already. Effective
    only before JAX starts its backend, which importing jaxtree does not do."""
    import os

    current = os.environ.get("XLA_FLAGS", "")
    if fast_cpu_flags() and "xla_cpu_use_fusion_emitters" not in current:
        os.environ["XLA_FLAGS"] = f"{current} {fast_cpu_flags()}".strip()


def _accepted(name: str) -> bool:
    """Whether this XLA has the compile option `name` (an unknown one fails the compilation: XLA
    drops options between releases). Only the emitters' option is known to have gone."""
    return name != "xla_cpu_use_fusion_emitters" or legacy_cpu_emitters()


def _program_options(*more: dict | None) -> dict | None:
    """The XLA options of a top-level program on a CPU: :data:`CPU_COMPILER_OPTIONS` and `more`,
    less any option that ``XLA_FLAGS`` names (the user's choice, process-wide) and any this XLA
    does not have; None elsewhere."""
    import inspect
    import os

    if "compiler_options" not in inspect.signature(jax.jit).parameters or jax.default_backend() != "cpu":
        return None
    flags = os.environ.get("XLA_FLAGS", "")
    merged = {k: v for o in (CPU_COMPILER_OPTIONS, *more) for k, v in (o or {}).items()}
    return {k: v for k, v in merged.items() if k not in flags and _accepted(k)} or None


def program_jit(fn=None, *, light=None, options=None):
    """``equinox.filter_jit`` of one of jaxtree's top-level programs, compiled on a CPU with
    :data:`CPU_COMPILER_OPTIONS`. Called with traced arguments (inside the user's ``jax.jit``,
    ``vmap`` or ``grad``) it is the plain ``filter_jit``: it is then part of the caller's program,
    whose compilation options are the caller's (JAX takes options only on a top-level jit).

    `light` (``@program_jit(light=...)``): True, or a function of the call's arguments, for a
    program whose run is brief beside its compilation (a start packed; the diagnostics of a few
    hundred saved states): such a call is compiled on a CPU at XLA's backend optimization level 0
    as well (:data:`LIGHT_COMPILER_OPTIONS`), which cuts its compilation 2-3x and runs it 5-8x
    slower (benchmarks/FINDINGS.md, "Short programs at XLA's level 0"). The choice is static (a
    shape, an option): each choice is its own compiled program.

    `options`: more XLA options for this program on a CPU (e.g. :data:`REPRODUCIBLE_OPTIONS`)."""
    if fn is None:
        return lambda f: program_jit(f, light=light, options=options)
    import functools

    import equinox as eqx

    from . import programs

    plain = eqx.filter_jit(fn)
    tuned = {}

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if any(isinstance(x, Tracer) for x in jax.tree_util.tree_leaves((args, kwargs))):
            return plain(*args, **kwargs)
        short = bool(light(*args, **kwargs)) if callable(light) else bool(light)
        if short not in tuned:
            chosen = _program_options(LIGHT_COMPILER_OPTIONS if short else None, options)
            # (equinox passes jax.jit's keywords through; its typed overloads do not list them)
            tuned[short] = (eqx.filter_jit(fn, compiler_options=chosen) if chosen else plain, chosen)  # pyright: ignore[reportCallIssue]
        jitted, chosen = tuned[short]
        # traced once across processes where the program can be kept (jaxtree._src.programs)
        return programs.call(fn, args, kwargs, chosen, jitted)

    return wrapper


# ----------------------------------------------------------------------------- one-time construction
# XLA options for functions run once while a model is built (substructure terms, the nominal
# configuration of a hybrid model): the backend's optimization passes dominate their compile
# time (the substructure terms of a flex95 wing: 3.8 s at the default level, 1.7 s at level 0)
# and buy nothing for a single run of a few milliseconds.
BUILD_COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}


def build_jit(fn):
    """``equinox.filter_jit`` for one-time construction: arrays traced, everything else static
    (hashed), compiled with :data:`BUILD_COMPILER_OPTIONS` (plain jit where the installed JAX
    does not take ``compiler_options``). Called with known arrays outside a trace or under
    ``jax.ensure_compile_time_eval`` it runs its compiled executable, kept per static part and
    argument types: a traced hybrid build evaluates its mass part by the reference build's
    programs (:func:`jaxtree._src.hybrid.systems.mass_part`) without tracing them again."""
    return _static_jit(fn, BUILD_COMPILER_OPTIONS, numbers_traced=False, executables=True)


def eager_jit(fn: Callable[_P, _R]) -> Callable[_P, _R]:
    """One compiled program for an eager call of a public function of arrays (Eq. 1's
    accelerations, its matrix, the energy, the hybrid right side), instead of JAX running its
    operations one by one: each of those compiles on its own the first time, hundreds for one
    call of Eq. (1) (seconds), and each later call dispatches them one by one (milliseconds).
    Called inside a trace (the user's ``jit``, ``vmap``, ``grad``, or jaxtree's own programs) it
    is the function itself, part of the caller's program. Compiled as jaxtree's programs are on
    a CPU (:data:`CPU_COMPILER_OPTIONS`) at XLA's lowest optimization level (such calls are few:
    compile time dominates). A number passed as an argument (a time ``t=0.5``) is traced, not
    keyed on: a loop over times compiles once. Static parts that cannot be hashed (a model
    holding an unhashable callable) fall back to the eager operations."""
    return cast(Callable[_P, _R], _static_jit(fn, None, numbers_traced=True))


_STATIC_JIT_KEEP = 256  # programs kept per function (the oldest dropped first)


def _static_jit(fn, options, *, numbers_traced, executables=False):
    import functools
    import inspect

    import equinox as eqx

    takes_options = "compiler_options" in inspect.signature(jax.jit).parameters
    compiled = {}
    kept = {}  # with `executables`: the compiled executables by static part and argument types

    def as_array(x):
        if isinstance(x, np.number):
            x = x.item()  # weakly typed, like the Python number: one program for both
        if isinstance(x, (float, int, complex)) and not isinstance(x, bool):
            return jnp.asarray(x)
        return x

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if numbers_traced:
            args = tuple(as_array(a) for a in args)
            kwargs = {k: as_array(v) for k, v in kwargs.items()}
        dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
        if any(isinstance(x, Tracer) for x in jax.tree_util.tree_leaves(dynamic)):
            return fn(*args, **kwargs)  # inside a trace (grad, jit): part of the caller's program
        leaves, treedef = jax.tree_util.tree_flatten(static)
        try:
            key = (treedef, tuple(leaves))
            hash(key)
        except TypeError:  # an unhashable static leaf
            return fn(*args, **kwargs) if numbers_traced else eqx.filter_jit(fn)(*args, **kwargs)
        if key not in compiled:
            if len(compiled) >= _STATIC_JIT_KEEP:  # new static parts on every call (a lambda made in a loop)
                compiled.pop(next(iter(compiled)))

            def run(dyn, _static=static):
                a, kw = eqx.combine(dyn, _static)
                return fn(*a, **kw)

            opts = options
            if opts is None:
                opts = {**(_program_options() or {}), **BUILD_COMPILER_OPTIONS} if takes_options else None
            compiled[key] = jax.jit(run, compiler_options=opts) if (opts and takes_options) else jax.jit(run)
        if executables and _evaluating():
            # its executable, kept: also called under `jax.ensure_compile_time_eval` inside a
            # trace (a traced hybrid build's mass part, hybrid.systems.mass_part), where
            # `jax.jit` would trace and compile the program again
            dyn_leaves, dyn_def = jax.tree_util.tree_flatten(dynamic)
            exe_key = (key, dyn_def, tuple(jax.typeof(x) for x in dyn_leaves))
            exe = kept.get(exe_key)
            if exe is None:
                if len(kept) >= _STATIC_JIT_KEEP:
                    kept.pop(next(iter(kept)))
                exe = kept[exe_key] = compiled[key].lower(dynamic).compile()
            try:
                return exe(dynamic)
            except ValueError:  # arrays placed elsewhere than the executable's device
                pass
        try:
            return compiled[key](dynamic)
        except ValueError as err:  # compiler options are refused on a jit nested in another trace
            if "compiler_options" not in str(err):
                raise
            return fn(*args, **kwargs)

    return wrapper


def _evaluating() -> bool:
    """True outside any trace, and under ``jax.ensure_compile_time_eval`` inside one: where a
    program called with known arrays runs now (not under ``jax.disable_jit``: operation by
    operation there)."""
    try:
        from jax._src import config, core

        if config.disable_jit.value:
            return False
        return bool(config.eager_constant_folding.value) or isinstance(core.trace_ctx.trace, core.EvalTrace)
    except (ImportError, AttributeError):  # another JAX: jit's own path
        return False


def is_traced(tree) -> bool:
    """True when any leaf of `tree` is a JAX tracer (inside jit, vmap or grad): its value is
    known only at run time, so checks on values are left to run time."""
    return any(isinstance(x, Tracer) for x in jax.tree_util.tree_leaves(tree))


def host_or_traced(x, dtype):
    """`x` as a numpy array of `dtype` when its value is known (a builder's checks and host-side
    work then run no eager JAX operation, each of which would compile on its own), as a JAX array
    when it is traced."""
    return jnp.asarray(x, dtype) if is_traced(x) else np.asarray(x, dtype)
