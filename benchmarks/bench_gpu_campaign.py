#!/usr/bin/env python3
"""The two campaigns on an accelerator against MJX's rollout on the same card (the campaigns
issue, point 6). A benchmark, not a test; it runs on a CPU too (``--quick``), where it checks
itself.

- **fig4_free**: 1000 runs of 10 s, 101 saves, the members of bench_campaign.py (body rate, panel
  hinge rates and panel stiffness dispersed; ``jax.random.key(0)``). jaxtree through
  :func:`jaxtree.monte_carlo` in one chunk: float64 at a fixed step of 0.02 s (Dopri8) and at
  rtol = atol = 1e-7, float32 at its default tolerance. MJX (``mujoco.mjx``, its jax
  implementation): RK4 at 0.00125 s, the cheapest step of MuJoCo's RK4 with error <= 1e-6 on
  the CPU (bench_campaign.py: 4.7e-7), each member with its own joint stiffness and initial
  velocities, ``mjx.step`` in a loop of loops (saves, steps) vmapped over the members; float64
  and float32.
- **flex95**: 256 slews of 10 s, 201 saves, the members of bench_campaign.py ``--scene flex95``
  (wing stiffness and slew torque each x U(0.9, 1.1)). jaxtree: the members' hybrid models
  rebuilt from their stiffness (vmapped; one after another on a CPU), integrated vmapped by jaxtree.Radau5 at 5e-5 and by
  Dopri8 at 1e-3 (the loosest tolerances meeting the goal on the CPU); the full Eq. (1) by
  Dopri8 at 1e-3 last. MJX: RK4 at 0.005 s (MuJoCo's RK4 on the CPU, members 0-1: hub 8.0e-4,
  wings 3.9e-3; at 0.00625 hub 1.0e-3; at 0.01 unstable), the slew torque set as the free
  joint's applied force (body axes) at the start of each step, float32 and float64.

Each row gives the compile time apart from the run (jaxtree: the first call, with compilation,
then the same call again; MJX: ``lower`` + ``compile``, then a probe of one save interval, then
the run), members per second and the error of the first members against a tight reference
(fig4_free: jaxtree at rtol = atol = 1e-12, the goal 1e-6 on (omega0, gamma); flex95: the full
Eq. (1), Dopri8 at 1e-10, bench_hybrid.py's measure, goal hub 1e-3, wings 1e-2). Where an MJX
run would outlast the budget it stops after the save intervals that fit and its rate is
extrapolated (said on the row). The references are read from ``--reference`` (an .npz) when it
exists, else computed here and written there.

The sections run in the order of their value and stop when ``--budget`` seconds have passed (a
lent device is held for minutes, compilation takes most of it); each row is written to
``--json`` as it comes, and a section that fails prints its error and the next one runs.

Run:  python benchmarks/bench_gpu_campaign.py [--quick] [--budget 480] [--reference PATH] [--json PATH]
(on a GPU machine without an install: ``PYTHONPATH=src``; MJX from the ``mujoco-mjx`` wheel whose
version matches ``mujoco``'s). On the lent H200 of 2026-11-29 (Python 3.12, jax 0.11.2, no network)
these wheels were carried and installed with ``pip install --no-deps --target``: mujoco 3.17.0
(cp312, manylinux_2_28), mujoco-mjx 3.17.0, glfw, pyopengl, websockets, trimesh,
importlib_resources; the references were computed on a CPU beforehand and carried as the .npz of
``--reference`` (a run without it computes them on the card, about 20-40 s).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback

import jax

jax.config.update("jax_enable_x64", True)

import diffrax as dfx
import jax.numpy as jnp
import numpy as np

import jaxtree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import dispersed_fig4, machine, write_json
from _flex95 import FLEX_SAVES, FLEX_T1, Flex, flex_errors, flex_factors, flex_meets

T1, SAVES, GOAL = 10.0, 101, 1e-6
MJX_DT = {"fig4_free": 0.00125, "flex95": 0.005}
SECTIONS = ("fig4", "mjx4", "flex", "mjxflex", "flexdopri", "fig4more", "mjx4f32", "mjxflex64", "flexfull")
MORE = ("flexhost", "flexdoprihost")
START = time.perf_counter()


def _args():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="few members, few saves of MJX (a CPU check)")
    p.add_argument("--budget", type=float, default=480.0, help="seconds after which no new row starts")
    p.add_argument("--runs", type=int, help="fig4_free members (default 1000; --quick 16)")
    p.add_argument("--flex-runs", type=int, help="flex95 members (default 256; --quick 8)")
    p.add_argument("--sections", nargs="+", choices=SECTIONS + MORE, default=list(SECTIONS), help="rows, in this order")
    p.add_argument("--reference", help="the references' .npz (read when it exists, else computed and written)")
    p.add_argument("--json", help="write the figures to this JSON file (atomically, after each row)")
    a = p.parse_args()
    a.runs = a.runs or (16 if a.quick else 1000)
    a.flex_runs = a.flex_runs or (8 if a.quick else 256)
    return a


ARGS = _args()
RESULTS: dict = {"machine": machine(), "backend": jax.default_backend(), "rows": []}
SUB4, SUB95 = min(8, ARGS.runs), min(4, ARGS.flex_runs)  # members whose error is measured


def say(*a):
    print(f"[{time.perf_counter() - START:6.1f} s]", *a, flush=True)


def row(**r):
    RESULTS["rows"].append(r)
    if ARGS.json:
        write_json(ARGS.json, RESULTS)


def left():
    return ARGS.budget - (time.perf_counter() - START)


# ------------------------------------------------------------------------------------ references
def fig4_campaign(model, n, **kw):
    kw.setdefault("chunk_size", n)
    return jaxtree.monte_carlo(model, dispersed_fig4, n, T1, key=jax.random.key(0), saveat=SAVES, progress=False, **kw)


def references():
    """{fig4: (omega0, gamma) of the first SUB4 fig4_free members at 1e-12; flex: (omega0, gamma)
    of the first SUB95 flex95 members, full Eq. (1), Dopri8 at 1e-10}."""
    path = ARGS.reference
    if path and os.path.exists(path):
        z = np.load(path)
        if z["fig4_omega0"].shape[0] >= SUB4 and z["flex_omega0"].shape[0] >= SUB95:
            say(f"references read from {path}")
            return {
                "fig4": (z["fig4_omega0"][:SUB4], z["fig4_gamma"][:SUB4]),
                "flex": (z["flex_omega0"][:SUB95], z["flex_gamma"][:SUB95]),
            }
    t = time.perf_counter()
    ds = fig4_campaign(jaxtree.load_scene("fig4_free"), SUB4, rtol=1e-12, atol=1e-12)
    fig4 = (ds.omega0.values, ds.gamma.values)
    flex = FLEX()
    sim = jax.jit(
        jax.vmap(
            lambda f: (lambda s: (s.omega0, s.gamma))(
                jaxtree.simulate(
                    flex.member(f[0], f[1]),
                    FLEX_T1,
                    y0=flex.state,
                    saveat=flex.ts,
                    rtol=1e-10,
                    atol=1e-10,
                    solver=dfx.Dopri8(),
                )
            )
        )
    )
    w, g = sim(jnp.asarray(flex_factors(SUB95)))
    out = {"fig4": fig4, "flex": (np.asarray(w), np.asarray(g))}
    say(f"references computed in {time.perf_counter() - t:.1f} s")
    if path:
        tmp = path + ".tmp.npz"
        np.savez(tmp, fig4_omega0=fig4[0], fig4_gamma=fig4[1], flex_omega0=out["flex"][0], flex_gamma=out["flex"][1])
        os.replace(tmp, path)
    return out


_FLEX: list = []


def FLEX():
    """The flex95 slew (built once)."""
    if not _FLEX:
        _FLEX.append(Flex())
    return _FLEX[0]


def fig4_error(w, g, ref):
    k = min(len(w), len(ref[0]))
    T = w.shape[1]
    return float(max(np.abs(w[:k] - ref[0][:k, :T]).max(), np.abs(g[:k] - ref[1][:k, :T]).max()))


def flex_error(w, g, ref):
    k = min(len(w), len(ref[0]))
    T = w.shape[1]
    return flex_errors(w[:k], g[:k], (ref[0][:k, :T], ref[1][:k, :T]), FLEX().wings)


# -------------------------------------------------------------------------------------- jaxtree
def jaxtree_fig4(label, dtype, refs, **kw):
    model = jaxtree.load_scene("fig4_free")
    model = model if dtype == "float64" else model.astype(jnp.float32)
    n = ARGS.runs
    t = time.perf_counter()
    fig4_campaign(model, n, **kw)
    first = time.perf_counter() - t
    t = time.perf_counter()
    ds = fig4_campaign(model, n, **kw)
    wall = time.perf_counter() - t
    e = fig4_error(ds.omega0.values, ds.gamma.values, refs["fig4"])
    ok = int((ds.status.values == "successful").sum())
    row(
        scene="fig4_free",
        engine="jaxtree",
        variant=label,
        dtype=dtype,
        members=n,
        first_s=first,
        wall_s=wall,
        members_per_s=n / wall,
        error=e,
        meets=e <= GOAL,
        successful=ok,
        steps_max=int(ds.steps.values.max()),
    )
    say(
        f"  jaxtree {label:22s} first call {first:6.1f} s; campaign {wall:7.2f} s = {n / wall:8.1f} runs/s; "
        f"error {e:.1e}{' (meets)' if e <= GOAL else ''}; steps max {int(ds.steps.values.max())}; {ok}/{n} successful"
    )
    return ds


def jaxtree_flex(form, solver_name, tol, refs, where="device"):
    """The flex95 campaign in one vmapped chunk: the members' models (hybrid: rebuilt, vmapped),
    then their integration. `where` the models are built: "device" (vmapped on the default
    device) or "host" (on the host's CPU devices, each its share one after another, ``lax.map``
    in ``shard_map``; then moved to the default device)."""
    flex = FLEX()
    n = ARGS.flex_runs
    solver = jaxtree.Radau5() if solver_name == "Radau5" else dfx.Dopri8()

    def sim(x):
        kw = dict(y0=flex.state, saveat=flex.ts, rtol=tol, atol=tol, solver=solver)
        if form == "hybrid":
            sol = jaxtree.simulate_hybrid(x, FLEX_T1, truncation_error=False, **kw)
        else:
            sol = jaxtree.simulate(x, FLEX_T1, **kw)
        return sol.omega0, sol.gamma, sol.stats["num_accepted_steps"]

    one = flex.hybrid if form == "hybrid" else flex.member
    members = lambda f: one(f[0], f[1])
    factors = jnp.asarray(flex_factors(n))
    place, cpus = (lambda xs: xs), []
    if where == "host":
        from jax.sharding import Mesh, NamedSharding
        from jax.sharding import PartitionSpec as P

        cpus = jax.devices("cpu")
        cpus = cpus[: max(k for k in range(1, len(cpus) + 1) if n % k == 0)]
        mesh = Mesh(np.array(cpus), ("m",))
        build = jax.jit(
            jax.shard_map(
                lambda fs: jax.lax.map(members, fs), mesh=mesh, in_specs=P("m"), out_specs=P("m"), check_vma=False
            )
        )
        factors = jax.device_put(factors, NamedSharding(mesh, P("m")))
        place = lambda xs: jax.device_put(xs, jax.devices()[0])
    elif jax.default_backend() == "cpu":
        # the batched complex LU of a vmapped build deadlocks in jaxlib's CPU LAPACK pool (FINDINGS)
        build = jax.jit(lambda fs: jax.lax.map(members, fs))
    else:
        build = jax.jit(jax.vmap(members))
    integrate = jax.jit(jax.vmap(sim))

    def campaign():
        t = time.perf_counter()
        xs = jax.block_until_ready(place(build(factors)))
        tb = time.perf_counter() - t
        t = time.perf_counter()
        out = jax.block_until_ready(integrate(xs))
        return out, tb, time.perf_counter() - t

    t = time.perf_counter()
    campaign()
    first = time.perf_counter() - t
    (w, g, steps), tb, ti = campaign()
    wall = tb + ti
    e = flex_error(np.asarray(w), np.asarray(g), refs["flex"])
    label = f"{form} {solver_name} {tol:g}" + (f", models on {len(cpus)} host cores" if where == "host" else "")
    row(
        scene="flex95",
        engine="jaxtree",
        variant=label,
        dtype="float64",
        members=n,
        first_s=first,
        wall_s=wall,
        build_s=tb,
        integrate_s=ti,
        members_per_s=n / wall,
        hub=e[0],
        wings=e[1],
        meets=flex_meets(e),
        steps_max=int(np.max(steps)),
    )
    say(
        f"  jaxtree {label:22s} first call {first:6.1f} s; campaign {wall:7.2f} s = {n / wall:8.1f} members/s "
        f"(models {tb:.2f} s, integration {ti:.2f} s); hub {e[0]:.1e} wings {e[1]:.1e}"
        f"{' (meets)' if flex_meets(e) else ''}; steps max {int(np.max(steps))}"
    )


# ------------------------------------------------------------------------------------------ MJX
def _mjx():
    try:
        import mujoco  # pyright: ignore[reportMissingImports]
        from mujoco import mjx  # pyright: ignore[reportMissingImports]
    except ImportError as e:
        say(f"  MJX not available ({e}): skipped")
        return None
    return mujoco, mjx


def mjx_campaign(scene, dtype, stiffness, qpos, qvel, kt, refs):
    """One MJX row: RK4 at MJX_DT[scene] for the members given by their joint stiffness (B, njnt),
    initial qpos (B, nq) and qvel (B, nv), and (flex95) slew torque factors kt (B,)."""
    mods = _mjx()
    if mods is None:
        return
    mujoco, mjx = mods
    from jaxtree.bench.peers import mjcf

    flex = scene == "flex95"
    model = FLEX().model.with_loads(None) if flex else jaxtree.load_scene(scene)
    n_hinges = model.n
    dt = MJX_DT[scene]
    t1, saves = (FLEX_T1, FLEX_SAVES) if flex else (T1, SAVES)
    per_save = round(t1 / (saves - 1) / dt)
    xml, _ = mjcf(model, timestep=dt, integrator="RK4", springs=True)
    M = mujoco.MjModel.from_xml_string(xml)
    iq = M.jnt_qposadr[[mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_JOINT, f"h{k}") for k in range(1, n_hinges + 1)]]
    torque = np.asarray(FLEX().torque, float) if flex else None
    B = stiffness.shape[0]
    with jax.enable_x64(dtype == "float64"):
        mx = mjx.put_model(M, impl="jax")
        dx = mjx.put_data(M, mujoco.MjData(M), impl="jax")
        ft = jnp.float64 if dtype == "float64" else jnp.float32

        def observe(d):
            return jnp.concatenate([d.qvel[3:6], d.qpos[iq]])

        def member(stiff, q0, v0, k, nsaves):
            m = mx.replace(jnt_stiffness=stiff)
            d = dx.replace(qpos=q0, qvel=v0)

            def step(_, d):
                if flex:
                    # the slew torque about the bus axes: the free joint's rotational generalized force
                    tq = (
                        k
                        * jnp.asarray(torque, ft)
                        * 0.5
                        * (jnp.tanh((d.time - 1.0) / 0.1) - jnp.tanh((d.time - 3.0) / 0.1))
                    )
                    d = d.replace(qfrc_applied=d.qfrc_applied.at[3:6].set(tq))
                return mjx.step(m, d)

            def save(i, c):
                d, h = c
                d = jax.lax.fori_loop(0, per_save, step, d)
                return d, h.at[i + 1].set(observe(d))

            h = jnp.zeros((saves, 3 + n_hinges), ft).at[0].set(observe(d))
            return jax.lax.fori_loop(0, nsaves, save, (d, h))[1]

        run = jax.jit(jax.vmap(member, in_axes=(0, 0, 0, 0, None)))
        args = tuple(jnp.asarray(a, ft) for a in (stiffness, qpos, qvel, kt))
        t = time.perf_counter()
        compiled = run.lower(*args, jnp.asarray(1, jnp.int32)).compile()
        compile_s = time.perf_counter() - t
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args, jnp.asarray(1, jnp.int32)))
        probe = time.perf_counter() - t
        intervals = saves - 1
        fit = max(1, int(0.8 * max(left(), 0.0) / max(probe, 1e-9)))
        if ARGS.quick:
            fit = min(fit, 4)
        k = min(intervals, fit)
        t = time.perf_counter()
        h = np.asarray(jax.block_until_ready(compiled(*args, jnp.asarray(k, jnp.int32))), np.float64)
        wall = (time.perf_counter() - t) * intervals / k
    w, g = h[:, : k + 1, :3], h[:, : k + 1, 3:]
    finite = bool(np.all(np.isfinite(h[:, : k + 1])))
    extrapolated = k < intervals
    if flex:
        e = flex_error(w, g, refs["flex"])
        meets, err = flex_meets(e), dict(hub=e[0], wings=e[1])
        etext = f"hub {e[0]:.1e} wings {e[1]:.1e}"
    else:
        e = fig4_error(w, g, refs["fig4"])
        meets, err = e <= GOAL, dict(error=e)
        etext = f"error {e:.1e}"
    row(
        scene=scene,
        engine="MJX",
        variant=f"RK4 dt {dt:g}",
        dtype=dtype,
        precision=str(h.dtype) if dtype == "float64" else "float32",
        members=B,
        compile_s=compile_s,
        probe_s=probe,
        wall_s=wall,
        members_per_s=B / wall,
        saves_run=k,
        extrapolated=extrapolated,
        meets=meets,
        finite=finite,
        steps=round(t1 / dt),
        **err,
    )
    say(
        f"  MJX RK4 dt {dt:g} {dtype:7s}    compile {compile_s:6.1f} s; one save interval {probe * 1e3:.0f} ms; "
        f"campaign {wall:7.2f} s = {B / wall:8.1f} members/s"
        + (f" (extrapolated from {k} of {intervals} save intervals)" if extrapolated else "")
        + f"; {etext}{' (meets)' if meets else ''} (first members, the saves run)"
        + ("" if finite else "; NON-FINITE")
    )


def mjx_fig4_members(ds):
    """(stiffness, qpos, qvel) of MJX for the members of the jaxtree campaign `ds`."""
    mods = _mjx()
    if mods is None:
        return None
    mujoco, _ = mods
    from jaxtree.bench.peers import base_velocities, mjcf

    model = jaxtree.load_scene("fig4_free")
    M = mujoco.MjModel.from_xml_string(mjcf(model, timestep=1e-3, integrator="RK4", springs=True)[0])
    jnt = np.array([mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_JOINT, f"h{k}") for k in range(1, model.n + 1)])
    iq, iv = M.jnt_qposadr[jnt], M.jnt_dofadr[jnt]
    n = ds.sizes["run"]
    sprung = np.asarray(model.sprung, int) - 1
    stiffness = np.tile(M.jnt_stiffness, (n, 1))
    stiffness[:, jnt[sprung]] = ds["param.stiffness"].values[:, sprung]
    omega0 = ds["param.initial.omega0"].values
    gamma = np.tile(np.asarray(model.initial.gamma), (n, 1))
    gamma_dot = ds["param.initial.gamma_dot"].values
    qpos = np.tile(M.qpos0, (n, 1))
    qpos[:, iq] = gamma
    qvel = np.zeros((n, M.nv))
    qvel[:, 0:3] = base_velocities(model, jnp.asarray(omega0), jnp.asarray(gamma), jnp.asarray(gamma_dot))
    qvel[:, 3:6] = omega0
    qvel[:, iv] = gamma_dot
    return stiffness, qpos, qvel, np.ones(n)


def mjx_flex_members():
    """(stiffness, qpos, qvel, torque factors) of MJX for the flex95 members."""
    mods = _mjx()
    if mods is None:
        return None
    mujoco, _ = mods
    from jaxtree.bench.peers import base_velocities, mjcf

    flex = FLEX()
    model, s = flex.model.with_loads(None), flex.state
    M = mujoco.MjModel.from_xml_string(mjcf(model, timestep=1e-3, integrator="RK4", springs=True)[0])
    jnt = np.array([mujoco.mj_name2id(M, mujoco.mjtObj.mjOBJ_JOINT, f"h{k}") for k in range(1, model.n + 1)])
    iq, iv = M.jnt_qposadr[jnt], M.jnt_dofadr[jnt]
    f = flex_factors(ARGS.flex_runs)
    n = len(f)
    stiffness = np.tile(M.jnt_stiffness, (n, 1))
    stiffness[:, jnt[flex.wings]] *= f[:, :1]
    qpos = np.tile(M.qpos0, (n, 1))
    qpos[:, iq] = np.asarray(s.gamma)
    v0 = base_velocities(model, *(jnp.asarray(np.asarray(a))[None] for a in (s.omega0, s.gamma, s.gamma_dot)))[0]
    qvel = np.zeros((n, M.nv))
    qvel[:, 0:3] = v0
    qvel[:, 3:6] = np.asarray(s.omega0)
    qvel[:, iv] = np.asarray(s.gamma_dot)
    return stiffness, qpos, qvel, f[:, 1]


# ------------------------------------------------------------------------------------------ main
def summary():
    """Each scene's fastest jaxtree row meeting the goal against MJX's fastest meeting it."""
    for scene in ("fig4_free", "flex95"):
        best = {}
        for eng in ("jaxtree", "MJX"):
            ok = [r for r in RESULTS["rows"] if r["scene"] == scene and r["engine"] == eng and r["meets"]]
            best[eng] = max(ok, key=lambda r: r["members_per_s"]) if ok else None
        a, b = best["jaxtree"], best["MJX"]
        if a and b:
            ratio = a["members_per_s"] / b["members_per_s"]
            RESULTS.setdefault("ratios", {})[scene] = ratio
            write_json(ARGS.json, RESULTS) if ARGS.json else None
            say(
                f"{scene}: jaxtree {a['variant']} {a['dtype']} {a['members_per_s']:.1f} members/s against MJX "
                f"{b['variant']} {b['dtype']} {b['members_per_s']:.1f}: {ratio:.2f}x (each its fastest meeting the goal)"
            )
        else:
            say(f"{scene}: no pair of rows meeting the goal")


def main():
    say(RESULTS["machine"])
    RESULTS["devices"] = [f"{d} ({d.device_kind})" for d in jax.devices()]
    say("devices: " + ", ".join(RESULTS["devices"]))
    refs = references()
    state: dict = {}

    def fig4_ds():
        if "ds" not in state:
            say(f"fig4_free: {ARGS.runs} runs of {T1:g} s, {SAVES} saves, in one chunk")
            state["ds"] = jaxtree_fig4("float64 dt 0.02", "float64", refs, dt=0.02)
        return state["ds"]

    def mjx_fig4(dtype):
        members = state.get("mjx4") or mjx_fig4_members(fig4_ds())
        if members is not None:
            state["mjx4"] = members
            mjx_campaign("fig4_free", dtype, *members, refs)

    def flex_mjx(dtype):
        members = state.get("mjx95") or mjx_flex_members()
        if members is not None:
            state["mjx95"] = members
            mjx_campaign("flex95", dtype, *members, refs)

    def fig4_more():
        fig4_ds()
        jaxtree_fig4("float64 rtol 1e-7", "float64", refs, rtol=1e-7, atol=1e-7)
        jaxtree_fig4("float32 default tol", "float32", refs)

    n95 = ARGS.flex_runs
    actions = {
        "fig4": fig4_ds,
        "mjx4": lambda: mjx_fig4("float64"),
        "flex": lambda: (
            say(f"flex95: {n95} slews of {FLEX_T1:g} s, {FLEX_SAVES} saves, one chunk"),
            jaxtree_flex("hybrid", "Radau5", 5e-5, refs),
        ),
        "mjxflex": lambda: flex_mjx("float32"),
        "flexdopri": lambda: jaxtree_flex("hybrid", "Dopri8", 1e-3, refs),
        "fig4more": fig4_more,
        "mjx4f32": lambda: mjx_fig4("float32"),
        "mjxflex64": lambda: flex_mjx("float64"),
        "flexfull": lambda: jaxtree_flex("full", "Dopri8", 1e-3, refs),
        "flexhost": lambda: jaxtree_flex("hybrid", "Radau5", 5e-5, refs, where="host"),
        "flexdoprihost": lambda: jaxtree_flex("hybrid", "Dopri8", 1e-3, refs, where="host"),
    }
    for name in ARGS.sections:
        if left() <= 0:
            say(f"budget of {ARGS.budget:g} s spent: {name} skipped")
            continue
        say(f"[{name}]")
        try:
            actions[name]()
        except Exception:  # one failing row must not cost the device time of the others
            say(f"  {name} failed:\n" + traceback.format_exc())
            RESULTS.setdefault("failed", []).append(name)
    summary()
    say("done")


if __name__ == "__main__":
    main()
