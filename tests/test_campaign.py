"""jaxtree.monte_carlo: the dataset, failed members, stores and resuming, several host devices
and a Dask cluster. Every campaign here has the same shape (fig4_free, 6 runs of 1 s in chunks
of 4, 11 save times) so that the in-process runs share one compiled chunk."""

import os
import pathlib
import subprocess
import sys

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src.campaigns.campaign import monte_carlo

N, CHUNK, T1, SAVES, TOL, MAX_STEPS = 6, 4, 1.0, 11, 1e-8, 3000
KEY = 7
EPS = float(np.finfo(np.float64).eps)
LOCK = 0.3  # share of members whose inner gimbal starts at 90 deg: gimbal lock
# a batched member against the lone run of its vehicle, two integrations at TOL: batched and single kernels
# round differently, which can flip an accept/reject decision and give another step sequence, so they
# agree to the integration error (a few TOL), not to round-off
SAME_RUN = 10 * TOL
ROUNDOFF = 1e-12  # C from the stored Euler parameters (Def. 9) against the run's C: float64 round-off
# relative drift of the conserved energy and angular momentum over a run at TOL: its global error,
# observed <= 2e-8 on these members run alone (about 70 steps each)
DRIFT = 1e-6


def sample(key, model):
    """Dispersed bus mass, platform inertia, panel stiffness and bus rate; some members start
    in gimbal lock (hinge 3 at 90 deg puts the rotor's axis on the outer gimbal's)."""
    k = jax.random.split(key, 5)
    s = model.initial
    lock = jax.random.uniform(k[0]) < LOCK
    gamma = s.gamma.at[2].set(jnp.where(lock, jnp.pi / 2, s.gamma[2]))
    omega0 = s.omega0 + 1e-2 * jax.random.normal(k[1], (3,))
    mass = model.mass.at[0].multiply(1 + 0.02 * jax.random.normal(k[2]))
    inertia = model.inertia.at[1].multiply(1 + 0.05 * jax.random.normal(k[3]))
    stiffness = model.stiffness * (1 + 0.1 * jax.random.normal(k[4], model.stiffness.shape))
    return eqx.tree_at(
        lambda m: (m.mass, m.inertia, m.stiffness, m.initial),
        model,
        (mass, inertia, stiffness, s._replace(omega0=omega0, gamma=gamma)),
    )


def run(**kw):
    model = jaxtree.load_scene("fig4_free")
    return monte_carlo(
        model,
        sample,
        N,
        T1,
        key=jax.random.key(KEY),
        saveat=SAVES,
        rtol=TOL,
        atol=TOL,
        chunk_size=CHUNK,
        max_steps=MAX_STEPS,
        **kw,
    )


def locked_members():
    keys = jax.random.split(jax.random.key(KEY), N)
    return np.asarray([bool(jax.random.uniform(jax.random.split(k, 5)[0]) < LOCK) for k in keys])


@pytest.fixture(scope="module")
def campaign():
    return run()


def test_dataset_holds_each_member_as_run_alone_and_failed_members_apart(campaign):
    ds = campaign
    model = jaxtree.load_scene("fig4_free")
    assert dict(ds.sizes) == {
        "run": N,
        "time": SAVES,
        "hinge": 10,
        "axis": 3,
        "quaternion": 4,
        "body": 11,
        "axis_j": 3,
    }  # param.inertia (run, body, axis, axis_j)
    locked = locked_members()
    assert 0 < locked.sum() < N  # the seed gives both kinds
    # members in gimbal lock fail with a named status and NaN outputs; nothing raised
    assert set(ds.failure.values[locked]) == {"singular_matrix"}
    assert all(s != "successful" for s in ds.status.values[locked])
    assert np.all(np.isnan(ds.omega0.values[locked])) and np.all(np.isnan(ds.energy.values[locked]))
    ok = ~locked
    assert set(ds.status.values[ok]) == {"successful"} and set(ds.failure.values[ok]) == {""}
    assert np.all(ds.steps.values > 0) and np.all(ds.t_final.values[ok] == T1)
    # the dispersed parameters are recorded: they are sample(key_i, model), here run op by op,
    # there compiled as one program (XLA's fused arithmetic: equal to a few units of round-off)
    keys = jax.random.split(jax.random.key(KEY), N)
    for i in range(N):
        m = sample(keys[i], model)
        np.testing.assert_allclose(ds["param.mass"].values[i], np.asarray(m.mass), rtol=4 * EPS, atol=0)
        np.testing.assert_allclose(
            ds["param.initial.omega0"].values[i], np.asarray(m.initial.omega0), rtol=4 * EPS, atol=4 * EPS * 1e-2
        )
    # a successful member equals the run of its vehicle alone (one lone simulate, independent of the batch)
    i = int(np.flatnonzero(ok)[-1])
    # two integrations at TOL: they agree to its integration error, not to round-off (SAME_RUN)
    alone = jaxtree.simulate(sample(keys[i], model), T1, saveat=SAVES, rtol=TOL, atol=TOL)
    np.testing.assert_allclose(ds.omega0.values[i], np.asarray(alone.omega0), rtol=0, atol=SAME_RUN)
    np.testing.assert_allclose(ds.gamma.values[i], np.asarray(alone.gamma), rtol=0, atol=SAME_RUN)
    C = np.asarray(alone.dcm)  # the stored Euler parameters give back C (Def. 9)
    q = ds.attitude.values[i]
    q0, v = q[:, :1, None], q[:, 1:]
    vx = np.cross(np.eye(3)[None], v[:, None, :])
    Cq = (q0**2 - np.sum(v * v, -1)[:, None, None]) * np.eye(3) + 2 * v[:, :, None] * v[:, None, :] - 2 * q0 * vx
    np.testing.assert_allclose(Cq, C, atol=ROUNDOFF)
    # no loads, no damping: every successful run conserves energy and angular momentum
    E, H = ds.energy.values[ok], ds.angular_momentum.values[ok]
    assert np.abs(E - E[:, :1]).max() / np.abs(E).max() < DRIFT
    assert np.abs(H - H[:, :1]).max() / np.abs(H).max() < DRIFT
    eff = ds.attrs["chunk_efficiency"]
    assert len(eff) == 2 and all(0 < e <= 1 for e in eff)


@pytest.mark.parametrize("suffix", [".zarr", ".nc"])
def test_store_is_written_chunk_by_chunk_and_a_rerun_resumes(campaign, tmp_path, monkeypatch, suffix):
    """A campaign killed after its first chunk leaves that chunk in the store; the rerun computes
    only the second and returns the numbers of an uninterrupted in-memory run."""
    import jaxtree._src.campaigns.campaign as C  # (zarr, and scipy for NetCDF, come with the test extra)

    out = tmp_path / f"mc{suffix}"
    real, calls = C.run_chunk, []

    def dies_on_the_second(*args, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt("killed")
        return real(*args, **kw)

    monkeypatch.setattr(C, "run_chunk", dies_on_the_second)
    with pytest.raises(KeyboardInterrupt):
        run(out=out)
    monkeypatch.setattr(C, "run_chunk", real)
    ds = run(out=out)
    assert ds.attrs["chunks_run"] == 1
    # a Zarr store's dataset comes back unread (a campaign larger than memory); a NetCDF file's read
    assert ds.omega0.variable._in_memory == (suffix == ".nc")
    for v in campaign.data_vars:
        np.testing.assert_array_equal(ds[v].values, campaign[v].values, err_msg=v)
    again = run(out=out)  # all done: nothing runs
    assert again.attrs["chunks_run"] == 0 and again.omega0.equals(campaign.omega0)
    # the file itself holds the campaign's settings and the versions that ran it
    import xarray as xr

    opened = xr.open_zarr(out, consolidated=False) if suffix == ".zarr" else xr.open_dataset(out)
    with opened as f:
        assert (f.attrs["n"], f.attrs["chunk_size"], f.attrs["rtol"], f.attrs["t1"]) == (N, CHUNK, TOL, T1)
        assert f.attrs["model"] == "fig4_free" and f.attrs["jax_version"] == jax.__version__
        assert f.attrs["jaxtree_version"] == jaxtree.__version__ and f.attrs["max_steps"] == MAX_STEPS
    model = jaxtree.load_scene("fig4_free")
    with pytest.raises(ValueError, match="different campaign"):
        monte_carlo(
            model,
            sample,
            N,
            2 * T1,
            key=jax.random.key(KEY),
            saveat=SAVES,
            rtol=TOL,
            atol=TOL,
            chunk_size=CHUNK,
            max_steps=MAX_STEPS,
            out=out,
        )


def test_a_full_disk_stops_the_campaign_with_a_message_and_the_rerun_resumes(campaign, tmp_path, monkeypatch):
    """The store's disk fills while the second chunk is written: an OSError (ENOSPC) that names
    the store and says how to resume, the first chunk kept; the rerun runs the second alone and
    returns the numbers of the in-memory run. With progress, a line per chunk with its time and
    an estimate of the time left."""
    import errno

    import jaxtree._src.campaigns.campaign as C

    out = tmp_path / "full.nc"
    real, calls = C.Store.write, []

    def fills_on_the_second(self, *args):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, *args)

    monkeypatch.setattr(C.Store, "write", fills_on_the_second)
    with pytest.raises(OSError, match=r"no space left for the store .*full\.nc.*chunk 2 of 2.*run the same call again"):
        run(out=out)
    monkeypatch.setattr(C.Store, "write", real)
    ds = run(out=out, progress=True)
    assert ds.attrs["chunks_run"] == 1
    np.testing.assert_array_equal(ds.omega0.values, campaign.omega0.values)


def test_progress_says_what_is_left(capsys):
    """progress=True: one line per chunk, the first with an upper bound of the time left, the last
    with none."""
    run(progress=True)
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("monte_carlo:")]
    assert len(lines) == 2, lines
    assert "chunk 1/2 done in" in lines[0] and "1/2 run in" in lines[0] and "s left" in lines[0]
    assert "chunk 2/2 done in" in lines[1] and "2/2 run in" in lines[1] and "left" not in lines[1]


def test_a_campaign_on_one_device_and_on_two_gives_the_same_states(campaign, tmp_path):
    """A campaign whose chunks are sharded over two host devices (the default where the machine
    has two cores: `import jaxtree` gives the CPU a device per core) and the same campaign on one
    device: the same states and step counts, bit for bit (at the suite's XLA optimization level
    0 here; at XLA's default level in a fresh process below). In this process where it has
    two devices, else in a fresh one asked for two (JAXTREE_HOST_DEVICES, read when JAX starts)."""
    if len(jax.local_devices()) >= 2:
        one, two = run(devices=1), run(devices=2)
        two = {k: two[k].values for k in ("omega0", "gamma", "steps", "failure")}
    else:
        one = campaign
        script = f"""
import jax, numpy as np
from test_campaign import run
assert len(jax.local_devices()) == 2
ds = run()
np.savez({str(tmp_path / "two.npz")!r}, omega0=ds.omega0.values, gamma=ds.gamma.values, steps=ds.steps.values,
         failure=ds.failure.values)
"""
        # the child imports this module from this folder (PYTHONPATH, as pytest's rootdir does here)
        path = os.pathsep.join(filter(None, [str(pathlib.Path(__file__).parent), os.environ.get("PYTHONPATH")]))
        env = dict(os.environ, PYTHONPATH=path, JAXTREE_HOST_DEVICES="2")
        proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, env=env)
        assert proc.returncode == 0, proc.stderr[-3000:]
        two = np.load(tmp_path / "two.npz")
    np.testing.assert_array_equal(two["omega0"], one.omega0.values)
    np.testing.assert_array_equal(two["gamma"], one.gamma.values)
    np.testing.assert_array_equal(two["steps"], one.steps.values)
    assert list(two["failure"]) == list(one.failure.values)


def test_bit_for_bit_across_core_counts_and_chunk_sizes_at_xla_default_level(tmp_path):
    """In a process as a user has it (XLA's default optimization level, jaxtree's own compile
    options; the suite compiles at level 0), the campaign on one device in chunks of 4, on two
    devices in chunks of 4 (2 members a device) and on two in chunks of 2: the same histories,
    step counts and diagnoses, bit for bit. Before the chunk's program was compiled as one LLVM
    part (numerics.REPRODUCIBLE_OPTIONS) the states on one device and on two differed by ~2e-9 rad."""
    script = """
import jax, numpy as np, test_campaign as T
from jaxtree._src.campaigns.campaign import monte_carlo
assert len(jax.local_devices()) == 2
def go(devices, chunk):
    return monte_carlo(T.jaxtree.load_scene("fig4_free"), T.sample, T.N, T.T1,
                       key=jax.random.key(T.KEY), saveat=T.SAVES, rtol=T.TOL, atol=T.TOL, chunk_size=chunk,
                       max_steps=T.MAX_STEPS, devices=devices)
runs = [go(1, 4), go(2, 4), go(2, 2)]
for ds in runs[1:]:
    for k in ("omega0", "gamma", "gamma_dot", "attitude", "energy", "angular_momentum", "steps", "failure"):
        assert np.array_equal(ds[k].values, runs[0][k].values, equal_nan=ds[k].dtype.kind == "f"), k
print("same")
"""
    path = os.pathsep.join(filter(None, [str(pathlib.Path(__file__).parent), os.environ.get("PYTHONPATH")]))
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAXTREE_HOST_DEVICES")}
    env.update(PYTHONPATH=path, JAXTREE_HOST_DEVICES="2", JAXTREE_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=900, env=env)
    assert proc.returncode == 0 and "same" in proc.stdout, proc.stderr[-3000:]


def test_a_dask_local_cluster_of_two_processes_gives_the_same_numbers_with_a_worker_killed(campaign):
    """The campaign on a Dask cluster of two worker processes, one of them killed with SIGKILL
    while it holds a chunk: the scheduler gives the chunk to the other (and the nanny starts a
    new worker), and the campaign returns, bit for bit, the numbers of the in-process run."""
    import signal
    import threading
    import time

    import distributed  # the test extra's dask[distributed]

    killed = []

    def kill_a_busy_worker(client, pids, stop):
        while not stop.is_set() and not killed:
            busy = [w for w, tasks in client.processing().items() if tasks and w in pids]
            if busy:
                time.sleep(0.3)  # inside the chunk: compiling or integrating
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(busy[0])
            time.sleep(0.02)

    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl,
        distributed.Client(cl) as client,
    ):
        pids = client.run(os.getpid)  # worker address -> its process
        stop = threading.Event()
        killer = threading.Thread(target=kill_a_busy_worker, args=(client, pids, stop), daemon=True)
        killer.start()
        try:
            ds = run(client=client)
        finally:
            stop.set()
            killer.join(timeout=10)
    assert killed, "no worker was killed: the check below would prove nothing"
    assert ds.attrs["where"] == "dask"
    for v in campaign.data_vars:
        np.testing.assert_array_equal(ds[v].values, campaign[v].values, err_msg=v)


def test_a_campaign_whose_process_is_killed_resumes_from_its_store(campaign, tmp_path):
    """A campaign process killed with SIGKILL after its first chunk reached the store (a real kill:
    no exception, no cleanup): the rerun in this process runs the second chunk alone and returns,
    bit for bit, the numbers of the uninterrupted run."""
    out = tmp_path / "killed.zarr"
    script = f"""
import os, signal
import jaxtree._src.campaigns.campaign as C
from test_campaign import run
real, calls = C.run_chunk, []
def dies_on_the_second(*args, **kw):
    calls.append(1)
    if len(calls) == 2:
        os.kill(os.getpid(), signal.SIGKILL)
    return real(*args, **kw)
C.run_chunk = dies_on_the_second
run(out={str(out)!r})
"""
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(filter(None, [str(pathlib.Path(__file__).parent), os.environ.get("PYTHONPATH")])),
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, env=env)
    assert proc.returncode == -9, (proc.returncode, proc.stderr[-3000:])  # killed, not finished
    ds = run(out=out)
    assert ds.attrs["chunks_run"] == 1  # the first chunk was not run again
    for v in campaign.data_vars:
        np.testing.assert_array_equal(ds[v].values, campaign[v].values, err_msg=v)


def test_the_default_chunk_fills_each_device_to_the_batch_first_size_within_the_memory(monkeypatch):
    """The default chunk: per device the members from which the batch-first recursion is used
    (fewer when the campaign is smaller, the chunk then a multiple of the devices), and fewer
    members when their histories would pass the memory share."""
    import jaxtree._src.campaigns.campaign as C
    from jaxtree._src.equations.solve import batch_first_min

    model = jaxtree.load_scene("fig4_free")
    per = batch_first_min()
    assert C.default_chunk(model, 10_000, 101, devices=1) == per
    assert C.default_chunk(model, 10_000, 101, devices=4) == 4 * per
    assert C.default_chunk(model, 7, 11, devices=2) == 8  # 4 a device: the last member padded
    memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    member = 3 * 1001 * (2 * model.n + 11) * 8  # bytes of a member's histories at 1001 saves
    monkeypatch.setattr(C, "CHUNK_MEMORY", 5.5 * member / memory)  # room for 5 members
    assert C.default_chunk(model, 10_000, 1001, devices=1) == 5
    assert C.default_chunk(model, 10_000, 1001, devices=2) == 4  # 2 a device


def test_an_implicit_solver_runs_each_member_as_its_single_run():
    """A stiff campaign under Radau5 (the tip hinge 1e6 times stiffer than the others, its
    stiffness dispersed by 10 %): each device runs its members one after another, so every member
    takes its single ``simulate`` run's steps and agrees with it to round-off (observed 4e-14 rad);
    a Dopri8 run of the same vehicle at 1e-10, the independent check, agrees to the campaign's
    tolerance (observed 1e-7 rad of 0.03)."""
    model = jaxtree.stiff_chain(1e6)
    t1, tol, saves = 0.2, 1e-6, 5

    def stiff(key, m):
        k = 1 + 0.1 * jax.random.normal(key)
        return eqx.tree_at(lambda m: m.stiffness, m, m.stiffness.at[-1].multiply(k))

    ds = monte_carlo(
        model, stiff, 4, t1, key=jax.random.key(3), saveat=saves, rtol=tol, atol=tol, solver=jaxtree.Radau5()
    )
    assert ds.attrs["solver"] == "Radau5" and list(ds.failure.values) == [""] * 4
    keys = jax.random.split(jax.random.key(3), 4)
    for i in (0, 3):
        member = stiff(keys[i], model)
        alone = jaxtree.simulate(member, t1, saveat=saves, rtol=tol, atol=tol, solver=jaxtree.Radau5())
        assert int(ds.steps.values[i]) == int(alone.stats["num_steps"])
        np.testing.assert_allclose(ds.gamma.values[i], np.asarray(alone.gamma), rtol=0, atol=ROUNDOFF)
        explicit = jaxtree.simulate(member, t1, saveat=saves, rtol=1e-10, atol=1e-10, solver=diffrax.Dopri8())
        np.testing.assert_allclose(ds.gamma.values[i], np.asarray(explicit.gamma), rtol=0, atol=tol)
