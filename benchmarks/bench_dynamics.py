#!/usr/bin/env python3
"""Benchmark of `jaxtree.forward_dynamics` on this CPU (a benchmark, not a test).

For the scenes fig4, chain50, panels95 and chain200 it prints

- the machine and the versions (CPU, cores, python, jax/jaxlib, equinox, numpy,
  the JAX devices and, when installed, pinocchio and mujoco);
- compile time, kept apart from run time: the first call of a fresh ``jax.jit``
  (trace + lower + compile + one run) and, separately, ``lower()`` and
  ``compile()`` of another fresh function;
- run time: one call at a time (median latency after warm-up, with the model
  passed as an argument and with the model closed over), one jitted batch of
  1024 states through ``jax.vmap`` (per batch and per state), and the cost of
  one evaluation inside a jitted ``lax.map`` (no dispatch per call);
- the FLOP count of XLA's cost analysis without and with external loads (a
  constant torque on body 0 and a constant force on the last body);
- the growth with n of a chain (10 -> 200 bodies): log-log slopes of the
  per-call time, of the FLOPs, and of the two halves of a call (assembling
  Eq. (1) and solving it);
- Pinocchio's ABA and MuJoCo's ``mj_forward`` on the same trees, one call at a
  time in a Python loop, when those packages are installed (the optional
  ``peers`` extra), with a cross-check of their accelerations against jaxtree's.

Run:  python benchmarks/bench_dynamics.py [--quick] [--json results/bench.json]

Timings on a shared machine are noisy: every figure is a median, and the
header prints the load average at the start and the end.

BLAS threads. jaxlib's CPU Cholesky and triangular solves call the LAPACK of
scipy's bundled OpenBLAS, which starts its own threads beside XLA's; on a
small, busy machine the two pools oversubscribe the cores and a 200 x 200
Cholesky can take milliseconds instead of a fraction of one. The header prints
the BLAS thread settings; ``--blas-threads N`` sets ``OPENBLAS_NUM_THREADS``
(and ``OMP_NUM_THREADS``) before jax is imported, to compare.

XLA flag. Unless XLA_FLAGS already says otherwise, the script sets
``--xla_cpu_use_fusion_emitters=false`` before JAX starts, as ``python -m jaxtree`` and
bench_simulate.py do (``--default-xla`` keeps XLA's defaults): with XLA:CPU's older emitters
the vmapped batches run 10-17 % faster (fig4, paired runs 2026-11-23) and compile faster.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import pathlib
import platform
import subprocess
import sys
import time


def _blas_threads_from_argv(argv):
    """``--blas-threads N`` must act before numpy, scipy and jax load OpenBLAS."""
    for i, a in enumerate(argv):
        value = (
            a.split("=", 1)[1]
            if a.startswith("--blas-threads=")
            else (argv[i + 1] if a == "--blas-threads" and i + 1 < len(argv) else None)
        )
        if value is not None:
            os.environ["OPENBLAS_NUM_THREADS"] = os.environ["OMP_NUM_THREADS"] = value


def _cpu_emitters_from_argv(argv):
    """XLA:CPU's older emitters unless ``--default-xla`` (must act before JAX starts its backend)."""
    from _common import use_fast_cpu_flags

    use_fast_cpu_flags(default_xla="--default-xla" in argv)


if __name__ == "__main__":
    _blas_threads_from_argv(sys.argv[1:])
    _cpu_emitters_from_argv(sys.argv[1:])

import jax
import jax.numpy as jnp
import numpy as np

import jaxtree

from _common import write_json
from _peers import MUJOCO_TINY_MASS, mjcf, pinocchio_model

SCENES = ("fig4", "chain50", "panels95", "chain200")
GROWTH = (10, 25, 50, 100, 200)
BATCH = 1024
# Anchors measured on this machine (from the requirement), used when the peers are not installed.
ANCHORS = {
    "pinocchio": {"fig4": 4.0, "panels95": 30.0, "chain200": 64.0},
    "mujoco": {"fig4": 3.0, "panels95": 15.0, "chain200": 324.0},
}
GOALS = {"compile_s": {"fig4": 5.0, "chain200": 20.0}, "vmap_vs_pinocchio": 2.0, "slope": 2.0}


def say(*args):
    print(*args, flush=True)


# ----------------------------------------------------------------------------- machine and versions
def _cpu_model():
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(module_name):
    try:
        mod = __import__(module_name)
    except ImportError:
        return None
    return str(getattr(mod, "__version__", "?"))


def _git_commit():
    try:
        here = pathlib.Path(__file__).resolve().parent
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
        )
        return out.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "") if out.returncode == 0 else None
    except (OSError, subprocess.SubprocessError):
        return None


def machine_info():
    import equinox

    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = None
    info = {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": affinity,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": jax.lib.__version__ if hasattr(jax.lib, "__version__") else _version("jaxlib"),
        "equinox": equinox.__version__,
        "numpy": np.__version__,
        "jaxtree": jaxtree.__version__,
        "jaxtree_commit": _git_commit(),
        "devices": [str(d) for d in jax.devices()],
        "x64": bool(jax.config.read("jax_enable_x64")),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "blas_threads": {
            k: os.environ.get(k, "unset") for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
        },
        "scipy": _version("scipy"),
        "pinocchio": _version("pinocchio"),
        "mujoco": _version("mujoco"),
        "loadavg_start": os.getloadavg() if hasattr(os, "getloadavg") else None,
    }
    return info


# ----------------------------------------------------------------------------- timing helpers
def _stats(seconds):
    a = np.asarray(seconds, float)
    return {"median": float(np.median(a)), "min": float(a.min()), "p90": float(np.percentile(a, 90)), "count": len(a)}


def time_calls(fn, *, budget_s, min_calls, max_calls=100_000):
    """Latency of `fn()` (which must block until its result is ready), call by call."""
    ts = []
    start = time.perf_counter()
    while len(ts) < min_calls or (len(ts) < max_calls and time.perf_counter() - start < budget_s):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return _stats(ts)


def time_loop(fn, *, calls, budget_s, min_repeats):
    """Mean time of `fn()` over `calls` back-to-back calls in a Python loop; median over repeats."""
    ts = []
    start = time.perf_counter()
    while len(ts) < min_repeats or time.perf_counter() - start < budget_s:
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        ts.append((time.perf_counter() - t0) / calls)
    return _stats(ts)


def flops_of(compiled):
    """FLOPs (and bytes accessed) of XLA's cost analysis; it is a dict or, in older jax, a list of dicts."""
    try:
        ca = compiled.cost_analysis()
    except Exception:  # some backends do not implement it
        return math.nan, math.nan
    if isinstance(ca, (list, tuple)):
        ca = ca[0] if ca else {}
    if not ca:
        return math.nan, math.nan
    return float(ca.get("flops", math.nan)), float(ca.get("bytes accessed", math.nan))


def _block(x):
    return jax.block_until_ready(x)


# ----------------------------------------------------------------------------- models and states
def _plate(m, a, b, c):
    return np.diag([m * (b * b + c * c) / 12, m * (a * a + c * c) / 12, m * (a * a + b * b) / 12])


def chain_model(n, k=400.0, length=0.5, mass=2.0, angle=0.02):
    """The bundled ``chainN`` scenes for any n (make_scenes.py's ``chain``): hub + n sprung segments."""
    name = f"chain{n}"
    if name in jaxtree.list_scenes():
        return jaxtree.load_scene(name)
    seg = _plate(mass, length, 0.1, 0.02)
    bodies = [jaxtree.Body("hub", 100.0, np.diag([30.0, 40.0, 50.0]))]
    for i in range(1, n + 1):
        bodies.append(
            jaxtree.Body(
                f"seg_{i}",
                mass,
                seg,
                parent=i - 1,
                axis=[0, 1, 0] if i % 2 else [0, 0, 1],
                hinge_on_parent=[0.6, 0, 0] if i == 1 else [length / 2, 0, 0],
                hinge_on_body=[-length / 2, 0, 0],
                joint=jaxtree.SpringDamper(k, 0.0),
            )
        )
    initial = {"gamma": [angle] * n, "gamma_dot": [0.0] * n, "omega0": [0.0, 0.0, 0.0]}
    return jaxtree.build_model(bodies, initial, name=name)


def load_model(name):
    return chain_model(int(name[5:])) if name.startswith("chain") else jaxtree.load_scene(name)


def _constant_loads(t, state):
    """A constant torque on body 0 and a constant force on the last body (body frames)."""
    dtype = state.omega0.dtype
    force = jnp.asarray([[0.0, 0.0, 0.0], [1.0, 0.5, -0.2]], dtype)
    torque = jnp.asarray([[0.3, -0.2, 0.1], [0.0, 0.0, 0.0]], dtype)
    return force, torque


def with_loads(model):
    return model.with_loads(jaxtree.FunctionLoads(bodies=(0, model.n), fn=_constant_loads))


def initial_args(model, t=0.0):
    s = model.initial
    return tuple(jnp.asarray(x) for x in (s.dcm, s.omega0, s.gamma, s.gamma_dot, t))


def batch_args(model, size, seed=0):
    """`size` states scattered about the scene's initial state."""
    rng = np.random.default_rng(seed)
    s = model.initial
    n = model.n
    gamma = np.asarray(s.gamma) + 0.05 * rng.standard_normal((size, n))
    gamma_dot = np.asarray(s.gamma_dot) + 0.05 * rng.standard_normal((size, n))
    omega0 = np.asarray(s.omega0) + 0.01 * rng.standard_normal((size, 3))
    dcm = np.broadcast_to(np.asarray(s.dcm), (size, 3, 3))
    return tuple(jnp.asarray(x) for x in (dcm, omega0, gamma, gamma_dot))


def completed_state(model, t=0.0):
    """Initial state as numpy arrays with the prescribed hinges filled in from the prescription at t."""
    s = model.initial
    gamma, gamma_dot = np.array(s.gamma, float), np.array(s.gamma_dot, float)
    if model.prescription is not None:
        g, gd, _ = model.prescription.derivatives(t)
        idx = np.asarray(model.prescription.hinges) - 1
        gamma[idx], gamma_dot[idx] = np.asarray(g), np.asarray(gd)
    return np.asarray(s.dcm, float), np.asarray(s.omega0, float), gamma, gamma_dot


def reference_solution(model, t=0.0):
    """jaxtree's accelerations at the initial state and the hinge torques that produce them
    (joint laws plus, on prescribed hinges, the torque that holds the prescription)."""
    dcm, omega0, gamma, gamma_dot = completed_state(model, t)
    acc = jaxtree.solve_accelerations(model, jaxtree.State(dcm, omega0, gamma, gamma_dot), t)
    tau = np.array(jaxtree.hinge_torques(model, gamma, gamma_dot), float)
    if model.prescribed:
        tau[np.asarray(model.prescribed) - 1] += np.asarray(acc.hold_torque)
    return (dcm, omega0, gamma, gamma_dot), tau, np.asarray(acc.omega0_dot), np.asarray(acc.gamma_ddot)


# ----------------------------------------------------------------------------- jaxtree measurements
def _fresh_forward():
    # A new function object per measurement: jax caches traces and executables per function,
    # so a fresh one is traced, lowered and compiled from scratch.
    def forward(model, dcm, omega0, gamma, gamma_dot, t):
        return jaxtree.forward_dynamics(model, dcm, omega0, gamma, gamma_dot, t)

    return forward


def _lower_compile(fn, *args):
    """``(compiled, lower_s, compile_s)`` of a fresh ``jax.jit(fn)``."""
    t0 = time.perf_counter()
    lowered = jax.jit(fn).lower(*args)
    t1 = time.perf_counter()
    compiled = lowered.compile()
    t2 = time.perf_counter()
    return compiled, t1 - t0, t2 - t1


def _first_call(fn, *args):
    """``(jitted, seconds)``: a fresh ``jax.jit(fn)`` and the time of its first call (trace, lower,
    compile, run); the jitted function is warm afterwards, and ``.lower(...).compile()`` on it is a
    cache hit."""
    f = jax.jit(fn)
    t0 = time.perf_counter()
    _block(f(*args))
    return f, time.perf_counter() - t0


def _latency_us(fn, cfg, scale=1.0):
    return time_calls(fn, budget_s=cfg.budget * scale, min_calls=cfg.min_calls)["median"] * 1e6


def _batch_time(fn, first_run_s, cfg):
    """Median seconds of a batch call; batches that take seconds are timed fewer times."""
    few = first_run_s * cfg.min_batches > 4 * cfg.budget_batch
    return time_calls(fn, budget_s=cfg.budget_batch, min_calls=1 if few else cfg.min_batches)


def lapack_flops(model):
    """Multiply-adds and adds of the dense Cholesky factorization and two triangular solves of Eq. (1):
    XLA's cost analysis does not count LAPACK custom calls, so this is added apart."""
    N = model.n + 3 - len(model.prescribed)
    return N**3 / 3 + 2 * N**2


def _assemble(model, dcm, omega0, gamma, gamma_dot, t):
    return jaxtree.rotational_equations(model, jaxtree.State(dcm, omega0, gamma, gamma_dot), t)


def _cholesky_solve(A, b):
    return jaxtree._src.equations.dynamics._cholesky_solve(A, b)  # what forward_dynamics runs (bordered Cholesky)


def bench_scene(name, cfg):
    wall = time.perf_counter()
    model = load_model(name)
    loaded = with_loads(model)
    n = model.n
    args = initial_args(model)
    r = {"scene": name, "n": n, "bodies": n + 1, "massive": len(model.massive), "prescribed": len(model.prescribed)}
    say(f"\n== {name}: {n + 1} bodies, {n} hinges ({len(model.massive)} massive, {len(model.prescribed)} prescribed)")

    # -- compile time, kept apart from run time; FLOPs
    compiled, r["lower_s"], r["compile_s"] = _lower_compile(_fresh_forward(), model, *args)
    r["flops"], r["bytes"] = flops_of(compiled)
    r["lapack_flops_est"] = lapack_flops(model)
    f_arg, r["first_call_s"] = _first_call(_fresh_forward(), model, *args)
    r["single_us"] = _latency_us(lambda: _block(f_arg(model, *args)), cfg)
    f_loads, r["first_call_loads_s"] = _first_call(_fresh_forward(), loaded, *args)
    r["flops_loads"], r["bytes_loads"] = flops_of(f_loads.lower(loaded, *args).compile())
    r["single_loads_us"] = _latency_us(lambda: _block(f_loads(loaded, *args)), cfg)
    say(
        f"  compile: first call of a fresh jit {r['first_call_s']:.2f} s; measured apart, lower {r['lower_s']:.2f} s "
        f"+ compile {r['compile_s']:.2f} s; first call with loads {r['first_call_loads_s']:.2f} s"
    )
    say(
        f"  XLA cost analysis: {r['flops']:.4g} FLOPs without loads, {r['flops_loads']:.4g} with loads "
        f"({r['bytes']:.3g} / {r['bytes_loads']:.3g} bytes accessed); not counted there, the LAPACK Cholesky "
        f"and triangular solves: ~{r['lapack_flops_est']:.4g} FLOPs"
    )

    # -- one call at a time
    f_clo = jax.jit(lambda *a: jaxtree.forward_dynamics(model, *a))
    _block(f_clo(*args))
    r["single_closure_us"] = _latency_us(lambda: _block(f_clo(*args)), cfg)
    say(
        f"  single call (median latency): {r['single_us']:.1f} us with the model as an argument, "
        f"{r['single_closure_us']:.1f} us with the model closed over, {r['single_loads_us']:.1f} us with loads "
        f"(model as an argument)"
    )

    # -- vmapped over a batch, and where the batch spends its time
    bargs = batch_args(model, cfg.batch)
    t = args[-1]
    B = cfg.batch
    vfun = jax.vmap(jaxtree.forward_dynamics, in_axes=(None, 0, 0, 0, 0, None))
    cv, lo_s, co_s = _lower_compile(vfun, model, *bargs, t)
    r["vmap_compile_s"] = lo_s + co_s
    r["vmap_flops"], _ = flops_of(cv)
    t0 = time.perf_counter()
    _block(cv(model, *bargs, t))
    r["vmap_first_run_s"] = time.perf_counter() - t0
    st = _batch_time(lambda: _block(cv(model, *bargs, t)), r["vmap_first_run_s"], cfg)
    r["vmap_batch_ms"], r["vmap_us_per_state"], r["vmap_stats"] = st["median"] * 1e3, st["median"] * 1e6 / B, st
    say(
        f"  vmap over {B} states: compile {r['vmap_compile_s']:.2f} s; {r['vmap_batch_ms']:.2f} ms per batch "
        f"= {r['vmap_us_per_state']:.2f} us per state ({st['count']} batches); "
        f"{r['vmap_flops'] / B:.4g} FLOPs per state"
    )
    if cfg.breakdown:
        va = jax.jit(jax.vmap(_assemble, in_axes=(None, 0, 0, 0, 0, None)))
        t0 = time.perf_counter()
        A, b = _block(va(model, *bargs, t))
        first = time.perf_counter() - t0
        st = _batch_time(lambda: _block(va(model, *bargs, t)), first, cfg)
        r["vmap_assembly_us_per_state"] = st["median"] * 1e6 / B
        vs = jax.jit(jax.vmap(_cholesky_solve))
        _block(vs(A, b))
        r["vmap_solve_us_per_state"] = _batch_time(lambda: _block(vs(A, b)), 0.0, cfg)["median"] * 1e6 / B
        say(
            f"    of which: assembling Eq. (1) {r['vmap_assembly_us_per_state']:.2f} us per state, Cholesky solve "
            f"{r['vmap_solve_us_per_state']:.2f} us per state (all hinges free; timed apart)"
        )

    # -- inside a jitted loop: the cost of an evaluation without per-call dispatch
    r.update(in_loop(model, bargs, t, r["single_closure_us"], cfg))
    say(
        f"  inside lax.map ({r['loop_length']} evaluations per call): {r['loop_us']:.1f} us per evaluation "
        f"(compile {r['loop_compile_s']:.2f} s)"
    )
    r["wall_s"] = time.perf_counter() - wall
    say(f"  ({r['wall_s']:.0f} s for this scene)")
    return r


def in_loop(model, bargs, t, single_us, cfg):
    """Cost of one evaluation inside a jitted ``lax.map`` over k states (no dispatch per evaluation)."""
    k = min(int(np.clip(cfg.loop_s / max(single_us * 1e-6, 1e-7), 8, 256)), bargs[0].shape[0])
    largs = tuple(x[:k] for x in bargs)

    def loop(model, dcm, omega0, gamma, gamma_dot, t):
        return jax.lax.map(lambda s: jaxtree.forward_dynamics(model, *s, t), (dcm, omega0, gamma, gamma_dot))

    cl, lo_s, co_s = _lower_compile(loop, model, *largs, t)
    t0 = time.perf_counter()
    _block(cl(model, *largs, t))
    st = _batch_time(lambda: _block(cl(model, *largs, t)), time.perf_counter() - t0, cfg)
    return {"loop_us": st["median"] * 1e6 / k, "loop_length": k, "loop_compile_s": lo_s + co_s}


def bench_growth(n, cfg, cached=None):
    """Per-call cost of a chain of n segments, whole and split into assembly and solve."""
    model = chain_model(n)
    args = initial_args(model)
    r = {"n": n, "lapack_flops_est": lapack_flops(model)}
    if cached is not None:
        r.update(single_closure_us=cached["single_closure_us"], flops=cached["flops"], loop_us=cached["loop_us"])
    else:
        f = jax.jit(lambda *a: jaxtree.forward_dynamics(model, *a))
        r["flops"], _ = flops_of(f.lower(*args).compile())
        _block(f(*args))
        r["single_closure_us"] = _latency_us(lambda: _block(f(*args)), cfg)
        r["loop_us"] = in_loop(model, batch_args(model, 256), args[-1], r["single_closure_us"], cfg)["loop_us"]
    # the two halves of a call: assembling Eq. (1), and the Cholesky solve
    asm = jax.jit(lambda *a: _assemble(model, *a))
    r["assembly_flops"], _ = flops_of(asm.lower(*args).compile())
    A, b = _block(asm(*args))
    r["assembly_us"] = _latency_us(lambda: _block(asm(*args)), cfg, 0.5)
    solve = jax.jit(_cholesky_solve)
    r["solve_flops"], _ = flops_of(solve.lower(A, b).compile())
    _block(solve(A, b))
    r["solve_us"] = _latency_us(lambda: _block(solve(A, b)), cfg, 0.5)
    say(
        f"  chain n={n:3d}: call {r['single_closure_us']:8.1f} us, in-loop {r['loop_us']:8.1f} us, "
        f"{r['flops']:10.4g} FLOPs | assembly {r['assembly_us']:8.1f} us {r['assembly_flops']:10.4g} FLOPs | "
        f"Cholesky solve {r['solve_us']:8.1f} us {r['solve_flops']:10.4g} FLOPs "
        f"(+ LAPACK ~{r['lapack_flops_est']:.4g})"
    )
    r["flops_with_lapack"] = r["flops"] + r["lapack_flops_est"]
    return r


def loglog_slope(n, y):
    n, y = np.asarray(n, float), np.asarray(y, float)
    ok = np.isfinite(y) & (y > 0)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(n[ok]), np.log(y[ok]), 1)[0])


# ----------------------------------------------------------------------------- peers: Pinocchio and MuJoCo
class PinocchioTree:
    """The scene as a Pinocchio model: a free flyer for body 0, unaligned revolute joints for the hinges."""

    def __init__(self, model):
        import pinocchio as pin

        self.pin = pin
        pm, jid, self.iq, self.iv, self.com = pinocchio_model(model)
        self.model, self.data, self.jid = pm, pm.createData(), jid

    def set_state(self, omega0, gamma, gamma_dot, tau):
        pm = self.model
        q = self.pin.neutral(pm)  # identity attitude: the dynamics do not depend on it without gravity
        q[self.iq] = gamma
        v = np.zeros(pm.nv)
        v[3:6] = omega0  # free-flyer velocity in the local frame: linear (zero), then angular
        v[self.iv] = gamma_dot
        t = np.zeros(pm.nv)
        t[self.iv] = tau
        self.q, self.v, self.tau = q, v, t

    def external(self, bodies, force, torque):
        """Forces at the mass centers and torques (body frames) as joint-frame wrenches for `aba`."""
        pin = self.pin
        fext = pin.StdVec_Force()
        for _ in range(self.model.njoints):
            fext.append(pin.Force.Zero())
        for b, F, T in zip(bodies, force, torque):
            fext[self.jid[b]] = pin.Force(np.asarray(F, float), np.asarray(T, float) + np.cross(self.com[b], F))
        return fext

    def accelerations(self, fext=None):
        args = (self.model, self.data, self.q, self.v, self.tau) + (() if fext is None else (fext,))
        ddq = np.array(self.pin.aba(*args))
        return ddq[3:6], ddq[self.iv]

    def timer(self):
        aba, m, d, q, v, tau = self.pin.aba, self.model, self.data, self.q, self.v, self.tau
        return lambda: aba(m, d, q, v, tau)


class MujocoTree:
    """The scene as MJCF: a free joint for body 0, hinge joints, and the bodies' inertials."""

    def __init__(self, model):
        import mujoco

        self.mj = mujoco
        self.xml, self.tiny = mjcf(model, timestep=0.001)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        jnt = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, f"h{k}") for k in range(1, model.n + 1)]
        self.iq = self.model.jnt_qposadr[jnt]
        self.iv = self.model.jnt_dofadr[jnt]
        self.bid = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, f"b{k}") for k in range(model.n + 1)]

    def set_state(self, omega0, gamma, gamma_dot, tau):
        d = self.data
        d.qpos[:] = 0.0
        d.qpos[3] = 1.0  # identity quaternion (w, x, y, z)
        d.qpos[self.iq] = gamma
        d.qvel[:] = 0.0
        d.qvel[3:6] = omega0  # free joint: linear velocity in the world frame, angular in the body frame
        d.qvel[self.iv] = gamma_dot
        d.qfrc_applied[:] = 0.0
        d.qfrc_applied[self.iv] = tau
        d.xfrc_applied[:] = 0.0

    def external(self, bodies, force, torque):
        """Forces at the mass centers and torques (body frames) as world-frame ``xfrc_applied``."""
        self.mj.mj_kinematics(self.model, self.data)
        for b, F, T in zip(bodies, force, torque):
            R = self.data.xmat[self.bid[b]].reshape(3, 3)  # body frame -> world
            self.data.xfrc_applied[self.bid[b]] = np.concatenate([R @ F, R @ T])

    def accelerations(self):
        self.mj.mj_forward(self.model, self.data)
        return np.array(self.data.qacc[3:6]), np.array(self.data.qacc[self.iv])

    def timer(self):
        fwd, m, d = self.mj.mj_forward, self.model, self.data
        return lambda: fwd(m, d)


def bench_peer(kind, name, cfg):
    """Build `name` in Pinocchio or MuJoCo, cross-check its accelerations, time one call at a time."""
    model = load_model(name)
    tree = PinocchioTree(model) if kind == "pinocchio" else MujocoTree(model)
    (dcm, omega0, gamma, gamma_dot), tau, w_ref, g_ref = reference_solution(model)
    tree.set_state(omega0, gamma, gamma_dot, tau)
    w, g = tree.accelerations()
    scale = max(1.0, float(np.abs(g_ref).max()), float(np.abs(w_ref).max()))
    r = {
        "scene": name,
        "n": model.n,
        "max_diff": float(max(np.abs(g - g_ref).max(), np.abs(w - w_ref).max())),
        "scale": scale,
    }
    # with the constant external loads
    loaded = with_loads(model)
    _, tau_l, w_ref_l, g_ref_l = reference_solution(loaded)
    F, T = (
        np.asarray(x)
        for x in _constant_loads(0.0, jaxtree.State(*(jnp.asarray(x) for x in (dcm, omega0, gamma, gamma_dot))))
    )
    bodies = (0, model.n)
    tree.set_state(omega0, gamma, gamma_dot, tau_l)
    if kind == "pinocchio":
        w, g = tree.accelerations(tree.external(bodies, F, T))
    else:
        tree.external(bodies, F, T)
        w, g = tree.accelerations()
    r["max_diff_loads"] = float(max(np.abs(g - g_ref_l).max(), np.abs(w - w_ref_l).max()))
    # how much the loads change the accelerations (so that agreement with loads means something)
    r["load_effect"] = float(max(np.abs(g_ref_l - g_ref).max(), np.abs(w_ref_l - w_ref).max()))
    if kind == "mujoco":
        r["tiny_mass_bodies"] = list(tree.tiny)
    # timing at the scene's initial state, no external loads
    tree.set_state(omega0, gamma, gamma_dot, tau)
    fn = tree.timer()
    fn()
    st = time_loop(fn, calls=cfg.peer_calls, budget_s=cfg.budget / 2, min_repeats=cfg.min_batches)
    r["us"], r["stats"] = st["median"] * 1e6, st
    return r


def run_peers(kind, names, cfg):
    try:
        __import__(kind)
    except ImportError:
        pkg = "pin" if kind == "pinocchio" else "mujoco"
        say(f"\n== {kind}: not installed (pip install {pkg}, or the 'peers' extra); skipped")
        return None
    say(
        f"\n== {kind} {_version(kind)}: one call at a time in a Python loop "
        + ("(pinocchio.aba)" if kind == "pinocchio" else "(mujoco.mj_forward)")
    )
    out = {}
    for name in names:
        try:
            r = bench_peer(kind, name, cfg)
        except Exception as e:  # report and go on: a peer must never stop the benchmark
            say(f"  {name}: failed: {type(e).__name__}: {e}")
            continue
        out[name] = r
        extra = (
            f"; massless bodies given mass {MUJOCO_TINY_MASS:g}: {r['tiny_mass_bodies']}"
            if r.get("tiny_mass_bodies")
            else ""
        )
        say(
            f"  {name:9s} n={r['n']:3d}: {r['us']:8.2f} us per call | accelerations vs jaxtree: max |diff| "
            f"{r['max_diff']:.2e} (no loads), {r['max_diff_loads']:.2e} (loads; they change the accelerations by "
            f"{r['load_effect']:.2e}), largest acceleration {r['scale']:.3g}{extra}"
        )
    return out


# ----------------------------------------------------------------------------- report
def _fmt(x, spec):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "-".rjust(int(spec.split(".")[0]))
    return format(x, spec)


def summary(results):
    scenes, pin, mj = results["scenes"], results.get("pinocchio") or {}, results.get("mujoco") or {}
    say("\n== summary (times are medians; compile = first call of a fresh jit, including trace/lower/compile)")
    head = (
        f"{'scene':9s} {'n':>4s} {'compile s':>9s} {'single us':>9s} {'closure us':>10s} {'in-loop us':>10s} "
        f"{'vmap us/state':>13s} {'FLOPs':>10s} {'FLOPs loads':>11s} {'+LAPACK est':>11s} {'pinocchio us':>12s} "
        f"{'mujoco us':>9s}"
    )
    say(head)
    say("-" * len(head))
    for name, r in scenes.items():
        p, m = pin.get(name, {}).get("us"), mj.get(name, {}).get("us")
        say(
            f"{name:9s} {r['n']:4d} {r['first_call_s']:9.2f} {r['single_us']:9.1f} {r['single_closure_us']:10.1f} "
            f"{r['loop_us']:10.1f} {r['vmap_us_per_state']:13.2f} {r['flops']:10.4g} {r['flops_loads']:11.4g} "
            f"{r['lapack_flops_est']:11.4g} {_fmt(p, '12.2f')} {_fmt(m, '9.2f')}"
        )
    say(
        "(single: model passed as an argument; closure: model closed over; in-loop: one evaluation inside a jitted "
        "lax.map; FLOPs: XLA's cost analysis, which leaves out the LAPACK calls estimated in '+LAPACK est')"
    )
    g = results["growth"]
    say(f"\ngrowth with n (chain {', '.join(str(x['n']) for x in g['points'])}): log-log slopes")
    for key, label in (
        ("single_closure_us", "per-call time"),
        ("loop_us", "in-loop time"),
        ("flops", "FLOPs (XLA count)"),
        ("flops_with_lapack", "FLOPs + LAPACK estimate"),
        ("assembly_us", "assembly time"),
        ("assembly_flops", "assembly FLOPs"),
        ("solve_us", "Cholesky solve time"),
        ("solve_flops", "Cholesky solve FLOPs"),
        ("pinocchio_us", "pinocchio time"),
        ("mujoco_us", "mujoco time"),
    ):
        if key in g["slopes"]:
            say(f"  {label:24s} {_fmt(g['slopes'][key], '5.2f')}")

    blas = results["machine"]["blas_threads"]["OPENBLAS_NUM_THREADS"]
    if blas == "unset":
        say(
            "\nnote: OPENBLAS_NUM_THREADS is unset, so the LAPACK Cholesky that jaxlib calls may run OpenBLAS "
            "threads beside XLA's; on a small busy machine that can inflate the n = 200 figures by orders of "
            "magnitude (compare --blas-threads 1)"
        )
    say("\ngoal checks")
    checks = results["goals"] = []

    def check(label, ok, detail):
        checks.append({"goal": label, "ok": ok, "detail": detail})
        say(f"  [{'PASS' if ok else ('FAIL' if ok is not None else 'n/a ')}] {label}: {detail}")

    for name, limit in GOALS["compile_s"].items():
        if name in scenes:
            c = scenes[name]["first_call_s"]
            check(
                f"compile {name} <= {limit:g} s",
                c <= limit,
                f"{c:.2f} s (vmapped: {scenes[name]['vmap_compile_s']:.2f} s)",
            )
    if "fig4" in scenes:
        ref = pin.get("fig4", {}).get("us")
        src = "measured"
        if ref is None:
            ref, src = ANCHORS["pinocchio"]["fig4"], "anchor"
        v = scenes["fig4"]["vmap_us_per_state"]
        f = GOALS["vmap_vs_pinocchio"]
        check(
            f"vmapped fig4 throughput >= {f:g} x Pinocchio one at a time",
            v <= ref / f,
            f"{v:.2f} us per state vs Pinocchio {ref:.2f} us ({src}): {ref / v:.2f} x (goal: <= {ref / f:.2f} us)",
        )
    for key, label in (
        ("single_closure_us", "per-call time"),
        ("loop_us", "in-loop time"),
        ("flops", "FLOPs (XLA count)"),
        ("flops_with_lapack", "FLOPs + LAPACK estimate"),
    ):
        s = g["slopes"].get(key)
        if s is not None and math.isfinite(s):
            check(f"{label} grows no faster than n^{GOALS['slope']:g}", s <= GOALS["slope"], f"slope {s:.2f}")
    for kind in ("pinocchio", "mujoco"):
        peer = results.get(kind) or {}
        if not peer:
            continue
        # accelerations relative to the largest one; 1e-8 (MuJoCo: 1e-6 where massless bodies got a tiny mass)
        rel = {name: max(r["max_diff"], r["max_diff_loads"]) / r["scale"] for name, r in peer.items()}
        tol = {name: 1e-6 if r.get("tiny_mass_bodies") else 1e-8 for name, r in peer.items()}
        worst = max(rel, key=lambda k: rel[k] / tol[k])
        check(
            f"{kind} accelerations agree with jaxtree ({len(peer)} trees, with and without loads)",
            all(rel[k] <= tol[k] for k in rel),
            f"worst {worst}: max |diff| / largest acceleration = {rel[worst]:.1e} (tolerance {tol[worst]:.0e})",
        )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions (noisier figures)")
    ap.add_argument("--json", metavar="PATH", help="also write the results as JSON (atomically)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), help=f"scenes to time (default: {' '.join(SCENES)})")
    ap.add_argument("--growth", nargs="+", type=int, default=list(GROWTH), help="chain lengths for the growth fit")
    ap.add_argument("--batch", type=int, default=BATCH, help="states per vmapped batch")
    ap.add_argument("--no-peers", action="store_true", help="skip Pinocchio and MuJoCo even if installed")
    ap.add_argument(
        "--no-breakdown",
        dest="breakdown",
        action="store_false",
        help="skip timing the vmapped assembly and solve apart",
    )
    ap.add_argument("--default-xla", action="store_true", help="keep XLA's default CPU emitters")
    ap.add_argument(
        "--blas-threads",
        metavar="N",
        help="set OPENBLAS_NUM_THREADS and OMP_NUM_THREADS to N "
        "(acts only when the script is run directly, before jax is imported)",
    )
    cfg = ap.parse_args(argv)
    cfg.budget = 0.3 if cfg.quick else 1.0  # seconds of single calls per figure
    cfg.budget_batch = 0.5 if cfg.quick else 2.0  # seconds of batches per figure
    cfg.min_calls = 20 if cfg.quick else 50
    cfg.min_batches = 2 if cfg.quick else 3
    cfg.loop_s = 0.1 if cfg.quick else 0.3  # target length of one lax.map call
    cfg.peer_calls = 200 if cfg.quick else 1000
    t_start = time.perf_counter()

    info = machine_info()
    # the dispatch floor: a jitted call that does (almost) nothing
    x = jnp.zeros(3)
    nop = jax.jit(lambda x: x + 1.0)
    _block(nop(x))
    info["dispatch_floor_us"] = time_calls(lambda: _block(nop(x)), budget_s=cfg.budget, min_calls=100)["median"] * 1e6
    say("== jaxtree forward_dynamics benchmark")
    for key in (
        "date",
        "cpu",
        "cores",
        "cores_usable",
        "platform",
        "python",
        "jax",
        "jaxlib",
        "equinox",
        "numpy",
        "scipy",
        "jaxtree",
        "jaxtree_commit",
        "devices",
        "x64",
        "xla_flags",
        "blas_threads",
        "pinocchio",
        "mujoco",
        "loadavg_start",
        "dispatch_floor_us",
    ):
        v = info[key]
        if key == "dispatch_floor_us":
            v = f"{v:.1f} us (median latency of a trivial jitted call)"
        elif v is None and key in ("pinocchio", "mujoco"):
            v = "not installed"
        say(f"  {key:17s} {v}")
    say(
        f"  mode              {'quick' if cfg.quick else 'full'}; batch {cfg.batch}; "
        "compile times are measured apart from run times, each on a fresh function"
    )

    results = {
        "machine": info,
        "config": {"quick": cfg.quick, "batch": cfg.batch, "scenes": cfg.scenes, "growth": cfg.growth},
        "scenes": {},
    }
    for name in cfg.scenes:
        results["scenes"][name] = bench_scene(name, cfg)

    say(
        "\n== growth with n: chains of n sprung segments (model closed over; assembly = Eq. (1) matrix and "
        "right side, solve = Cholesky)"
    )
    points = []
    for n in cfg.growth:
        cached = results["scenes"].get(f"chain{n}")
        points.append(bench_growth(n, cfg, cached))
    results["growth"] = {"points": points}

    peer_names = list(dict.fromkeys(list(cfg.scenes) + [f"chain{n}" for n in cfg.growth]))
    for kind in ("pinocchio", "mujoco"):
        results[kind] = None if cfg.no_peers else run_peers(kind, peer_names, cfg)

    ns = [p["n"] for p in points]
    slopes = {}
    for key in (
        "single_closure_us",
        "loop_us",
        "flops",
        "flops_with_lapack",
        "assembly_us",
        "assembly_flops",
        "solve_us",
        "solve_flops",
    ):
        slopes[key] = loglog_slope(ns, [p[key] for p in points])
    for kind in ("pinocchio", "mujoco"):
        peer = results.get(kind) or {}
        if all(f"chain{n}" in peer for n in ns):
            for p in points:
                p[f"{kind}_us"] = peer[f"chain{p['n']}"]["us"]
            slopes[f"{kind}_us"] = loglog_slope(ns, [p[f"{kind}_us"] for p in points])
    results["growth"]["slopes"] = slopes

    summary(results)
    info["loadavg_end"] = os.getloadavg() if hasattr(os, "getloadavg") else None
    info["total_s"] = time.perf_counter() - t_start
    say(f"\nload average at the end {info['loadavg_end']}; total {info['total_s']:.0f} s")
    if cfg.json:
        write_json(cfg.json, results)
        say(f"results written to {cfg.json}")
    return results


if __name__ == "__main__":
    main()
