"""A notebook's first cells: eager calls (outside any `jax.jit`) in a fresh process.

Builds a beam and a plate, their appendages (one with `n_modes="auto"`), and evaluates Eq. (1)
and the energy of `wings`, each step timed on its first call in a fresh process with JAX's
persistent cache off (`JAXTREE_CACHE_DIR=0`): what a new user waits for. The peer, in the same
run, is the same process under `jax.disable_jit()`: JAX runs every operation on its own, compiling
each the first time it meets its shapes (how jaxtree's eager calls ran before they became one
program each; `jax.disable_jit` also takes jaxtree's own build programs apart, so the peer is a
little slower than that code was). The processes alternate; the best of `--repeats` per step.

    python benchmarks/bench_first_calls.py [--repeats 2]

**The census** (``--census``): each public call a user makes first (simulate of two bundled
scenes, linearize and modes, a hybrid model and its run, an appendage, Radau5 on flex95, a
campaign's first 64 runs, the identification fit), each in a fresh process with the cache off,
divided by the first call of the yardstick compiled in the same process
(``../shared/tools/yardstick.py``: a diffrax Dopri8 solve of the Lorenz system, 101 save points);
the programs XLA compiled (their StableHLO operations as handed to XLA, and the compile seconds
of each), the seconds of tracing, lowering and compiling (JAX's monitoring events), and for the
largest of jaxtree's programs the source functions its operations come from (the innermost
frame of jaxtree, diffrax or lineax in each operation's traceback; a custom_vmap or custom_jvp
rule's body has no traceback and is counted as "(rule body)").

    python benchmarks/bench_first_calls.py --census [--calls "simulate fig4_free;simulate wings"]

**A notebook top to bottom** (``--notebook quickstart``): ``notebooks/<name>.ipynb`` executed in a
fresh Jupyter kernel (nbclient, as the notebooks' test runs it; the kernel's start included),
the cache off, divided by the yardstick's first call in a fresh process just before and just
after it (their mean), alternated `--repeats` times.

    python benchmarks/bench_first_calls.py --notebook quickstart [--repeats 3]
"""

import argparse
import json
import os
import subprocess
import sys

from _common import machine, write_json

STEPS = ("beam", "plate", "appendage auto", "appendage 4", "plate appendage", "solve_accelerations", "energy")

_CHILD = r"""
import contextlib, json, sys, time
import jax
import jaxtree

ctx = jax.disable_jit() if sys.argv[1] == "op by op" else contextlib.nullcontext()
out = {}


def step(name, fn):
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    out[name] = time.perf_counter() - t0


with ctx:
    jax.block_until_ready(jax.numpy.zeros(3) + 1.0)  # the backend started, outside the timings
    fe = {}
    step("beam", lambda: fe.setdefault("beam", jaxtree.beam(2.0, 10, E=7e10, rho=2700.0, area=1e-4, Iy=1e-8)).mass)
    step("plate", lambda: fe.setdefault("plate", jaxtree.plate(1.0, 0.5, 4, 2, E=7e10, rho=2700.0, thickness=1e-3)).mass)
    step("appendage auto", lambda: jaxtree.appendage(fe["beam"], 0, n_modes="auto").terms.A0)
    step("appendage 4", lambda: jaxtree.appendage(fe["beam"], 0, n_modes=4).terms.A0)
    edge = jaxtree.plate_edge(4, 2)
    step("plate appendage", lambda: jaxtree.appendage(fe["plate"], 0, interface=edge, n_modes=3).terms.A0)
    model = jaxtree.load_scene("wings")
    s = model.initial
    step("solve_accelerations", lambda: jaxtree.solve_accelerations(model, s).gamma_ddot)
    step("energy", lambda: (jaxtree.kinetic_energy(model, s), jaxtree.angular_momentum(model, s)))
print(json.dumps(out))
"""


# name -> (setup, the call): the setup is not timed, its compilations not counted
CALLS = {
    "simulate fig4_free": ("m = jaxtree.load_scene('fig4_free')", "jaxtree.simulate(m, 10.0)"),
    "simulate wings": ("m = jaxtree.load_scene('wings')", "jaxtree.simulate(m, 10.0)"),
    "simulate fig4 (the quickstart's)": (
        "m = jaxtree.load_scene('fig4')",
        "jaxtree.simulate(m, 10.0, saveat=1001, rtol=1e-9, atol=1e-9)",
    ),
    "linearize + modes fig4_free": (
        "m = jaxtree.load_scene('fig4_free')",
        "jaxtree.modes(jaxtree.linearize(m, tuple(m.sprung))).frequencies",
    ),
    "hybrid_model + simulate_hybrid wings": (
        "m = jaxtree.load_scene('wings')",
        "jaxtree.simulate_hybrid(jaxtree.hybrid_model(m, tuple(m.sprung), 4), 10.0)",
    ),
    "appendage (beam, 4 modes)": (
        "fe = jaxtree.beam(2.0, 10, E=7e10, rho=2700.0, area=1e-4, Iy=1e-8)",
        "jaxtree.appendage(fe, 0, n_modes=4).terms.A0",
    ),
    "Radau5 flex95 (2 s, rtol 1e-6)": (
        "m = jaxtree.load_scene('flex95')",
        "jaxtree.simulate(m, 2.0, solver=jaxtree.Radau5(), rtol=1e-6, atol=1e-6)",
    ),
    "monte_carlo 64 fig4_free (10 s)": (
        "m = jaxtree.load_scene('fig4_free'); from _common import dispersed_fig4",
        "jaxtree.monte_carlo(m, dispersed_fig4, 64, 10.0, key=jax.random.PRNGKey(0), progress=False)",
    ),
    "identify (wings, 6 parameters)": (
        "import warnings; warnings.simplefilter('ignore'); import _identify_problem as P\n"
        "m = jaxtree.load_scene(P.SCENE); ts = P.times(); data = P.record(m, P.FREE6, P.TRUTH6)",
        "jaxtree.identify(m, P.FREE6, ts, data, P.SIGMA, rtol=P.TOL, atol=P.TOL).values",
    ),
}

_CENSUS_CHILD = r"""
import collections, json, sys, time
sys.path[:0] = [sys.argv[3], sys.argv[4]]  # benchmarks/, the shared tools
import jax
from jax._src import compiler
from jax._src.lib.mlir import ir
import jaxtree
from jaxtree._src import programs as kept
from yardstick import yardstick

compiled, seconds, captured = [], collections.Counter(), {}
_compile = compiler.backend_compile_and_load


def counting(backend, module, *args, **kwargs):
    count = [0]

    def visit(op):
        count[0] += 1
        return ir.WalkResult.ADVANCE

    module.operation.walk(visit)
    name = str(module.operation.attributes["sym_name"]).strip('"')
    t = time.perf_counter()
    out = _compile(backend, module, *args, **kwargs)
    compiled.append((name, count[0], time.perf_counter() - t))
    return out


compiler.backend_compile_and_load = counting
_call = kept.call


def capture(fn, args, kwargs, options, jitted):  # jaxtree's top-level programs and their arguments
    captured.setdefault(fn.__name__, (fn, args, kwargs))
    return _call(fn, args, kwargs, options, jitted)


kept.call = capture
jax.monitoring.register_event_duration_secs_listener(
    lambda e, d, **k: seconds.update({e.rsplit("/", 1)[-1]: d})
)
stick = yardstick()
setup, call = json.loads(sys.argv[2])
exec(setup)
jax.block_until_ready(jax.numpy.zeros(3) + 1.0)
compiled.clear(); seconds.clear(); captured.clear()
t = time.perf_counter()
jax.block_until_ready(eval(call))
wall = time.perf_counter() - t
timing = dict(seconds)  # (before the attribution below traces the program again)
t = time.perf_counter()
jax.block_until_ready(eval(call))
again = time.perf_counter() - t


def attribute(name):
    # the operations of jaxtree's program `name` by the innermost source function of jaxtree,
    # diffrax or lineax in their traceback
    import equinox as eqx

    fn, args, kwargs = captured[name]
    jaxpr = eqx.filter_make_jaxpr(fn)(*args, **kwargs)[0].jaxpr
    by = collections.Counter()

    def walk(j):
        for e in j.eqns:
            subs = []
            for v in e.params.values():
                for x in v if isinstance(v, (list, tuple)) else [v]:
                    if hasattr(x, "eqns"):
                        subs.append(x)
                    elif hasattr(getattr(x, "jaxpr", None), "eqns"):
                        subs.append(x.jaxpr)
            if subs:
                for x in subs:
                    walk(x)
                continue
            tb = e.source_info.traceback
            frames = [f for f in (tb.frames if tb else ()) if any(p in f.file_name for p in ("jaxtree", "diffrax", "lineax"))]
            f = frames[0] if frames else None
            by["(rule body)" if f is None else f.file_name.split("/")[-1] + ":" + f.function_name] += 1

    walk(jaxpr)
    return by.most_common(12), sum(by.values())


largest = max((c for c in compiled if c[0].removeprefix("jit_") in captured), key=lambda c: c[1], default=None)
sources = attribute(largest[0].removeprefix("jit_")) if largest else None
print(json.dumps(dict(
    yardstick=stick, wall=wall, again=again, programs=sorted(compiled, key=lambda c: -c[2]),
    trace=timing["jaxpr_trace_duration"], lower=timing["jaxpr_to_mlir_module_duration"],
    compile=timing["backend_compile_duration"], largest=largest and largest[0], sources=sources,
)))
"""


def census(names) -> dict:
    here = os.path.dirname(os.path.abspath(__file__))
    tools = os.path.join(here, "..", "..", "shared", "tools")
    out = {}
    for name in names:
        env = dict(os.environ, JAXTREE_CACHE_DIR="0")
        arg = json.dumps(CALLS[name])
        done = subprocess.run(
            [sys.executable, "-c", _CENSUS_CHILD, name, arg, here, tools],
            env=env, capture_output=True, text=True, timeout=1800, cwd=here,
        )  # fmt: skip
        if done.returncode != 0:
            raise RuntimeError(f"{name}: {done.stderr[-3000:]}")
        out[name] = r = json.loads(done.stdout.strip().splitlines()[-1])
        n_ops = sum(p[1] for p in r["programs"])
        print(
            f"\n{name}: first call {r['wall']:.2f} s = {r['wall'] / r['yardstick']:.2f}x the yardstick "
            f"({r['yardstick']:.2f} s); again {r['again']:.3f} s\n"
            f"  trace {r['trace']:.2f} s, lowering {r['lower']:.2f} s, XLA {r['compile']:.2f} s in "
            f"{len(r['programs'])} programs ({n_ops} StableHLO operations)",
            flush=True,
        )
        for prog, ops, secs in r["programs"][:6]:
            print(f"    {prog[:48]:48s} {ops:7d} ops {secs:6.2f} s")
        if r["sources"]:
            top, total = r["sources"]
            print(f"  {r['largest']}: {total} operations in its jaxpr, by source function:")
            print("    " + ", ".join(f"{k} {v}" for k, v in top))
    return out


def yardstick_process(tools: str, env: dict) -> float:
    """The yardstick's first call (s) in a fresh process."""
    done = subprocess.run(
        [sys.executable, os.path.join(tools, "yardstick.py")], env=env, capture_output=True, text=True, check=True
    )
    return float(done.stdout.split()[1])


def notebook(name: str, repeats: int) -> dict:
    import time

    import nbformat
    from nbclient import NotebookClient

    here = os.path.dirname(os.path.abspath(__file__))
    tools = os.path.join(here, "..", "..", "shared", "tools")
    folder = os.path.join(here, "..", "notebooks")
    env = dict(os.environ, JAXTREE_CACHE_DIR="0")
    saved = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # the kernel inherits this process's environment
    runs = []
    try:
        for _ in range(repeats):
            before = yardstick_process(tools, env)
            nb = nbformat.read(os.path.join(folder, f"{name}.ipynb"), as_version=4)
            t0 = time.perf_counter()
            NotebookClient(nb, timeout=1800, kernel_name="python3", resources={"metadata": {"path": folder}}).execute()
            wall = time.perf_counter() - t0
            after = yardstick_process(tools, env)
            runs.append(dict(wall=wall, yardstick=(before + after) / 2))
            print(
                f"{name}.ipynb top to bottom in a fresh kernel: {wall:.1f} s = "
                f"{wall / runs[-1]['yardstick']:.1f}x the yardstick ({before:.2f} s before, {after:.2f} s after)",
                flush=True,
            )
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return dict(runs=runs)


def run(mode: str) -> dict:
    env = dict(os.environ, JAXTREE_CACHE_DIR="0")
    done = subprocess.run(
        [sys.executable, "-c", _CHILD, mode], env=env, capture_output=True, text=True, check=True, timeout=900
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--census", action="store_true", help="the census of the public first calls")
    parser.add_argument("--calls", default=";".join(CALLS), help="with --census: which calls, ';'-separated")
    parser.add_argument(
        "--notebook", help="a notebook of notebooks/ (its name) run top to bottom, against the yardstick"
    )
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "bench_first_calls.json"))
    args = parser.parse_args()
    if args.notebook:
        print(machine())
        result = notebook(args.notebook, args.repeats)
        write_json(os.path.join(os.path.dirname(args.out), f"bench_first_calls_{args.notebook}.json"), result)
        return
    if args.census:
        print(machine())
        results = census([c.strip() for c in args.calls.split(";") if c.strip()])
        out = os.path.join(os.path.dirname(args.out), "bench_first_calls_census.json")
        if set(results) != set(CALLS) and os.path.exists(out):  # some calls: the others' figures kept
            with open(out) as f:
                kept = json.load(f)
            results = {**kept.get("calls", {}), **results}
        write_json(out, {"machine": machine(), "calls": results})
        return
    modes = ("one program", "op by op")
    best = {m: {} for m in modes}
    for _ in range(args.repeats):
        for mode in modes:
            for k, v in run(mode).items():
                best[mode][k] = min(v, best[mode].get(k, float("inf")))
    print(machine())
    print("first calls in a fresh process, s (best of", args.repeats, "processes each; persistent cache off)")
    print(f"{'step':22s} {'one program':>12s} {'op by op':>10s}")
    for k in STEPS:
        print(f"{k:22s} {best['one program'][k]:12.2f} {best['op by op'][k]:10.2f}")
    totals = {m: sum(best[m].values()) for m in modes}
    print(f"{'total':22s} {totals['one program']:12.2f} {totals['op by op']:10.2f}")
    write_json(args.out, {"machine": machine(), "best": best, "totals": totals})


if __name__ == "__main__":
    main()
