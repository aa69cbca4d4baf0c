"""Programs kept across processes (jaxtree._src.programs): a second process reads a traced program
back instead of tracing it, with the same results; the key tells apart what changes the trace;
what cannot be keyed safely (a user's function) or exported (host callbacks) is traced as before."""

import os
import subprocess
import sys

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree._src import cache, programs

PROBE = """
import json, sys, numpy as np, jaxtree
from jaxtree._src import programs
model = jaxtree.load_scene("appendix_c")
with programs.PREPARED.timing():
    sol = jaxtree.simulate(model, 0.3, saveat=4, rtol=1e-8, atol=1e-8)
prepared = programs.PREPARED.mark()
mark = programs.PREPARED.mark()
jaxtree.simulate(model, 0.3, saveat=4, rtol=1e-7, atol=1e-7)  # the same programs, ready
again = programs.PREPARED.since(mark)
exports = sorted(name for name, c in programs.COUNTS.items() if c["exported"])
loads = sorted(name for name, c in programs.COUNTS.items() if c["loaded"])
print(json.dumps({"exports": exports, "loads": loads, "gamma": np.asarray(sol.gamma).tolist(),
                  "energy": np.asarray(sol.energy).tolist(), "steps": int(sol.stats["num_accepted_steps"]),
                  "prepared": prepared, "again": again}))
"""


def _probe(tmp_path, **extra):
    import json

    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAXTREE_CACHE", "JAX_COMPILATION_CACHE"))}
    env.update(JAXTREE_CACHE_DIR=str(tmp_path / "cache"), **extra)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_second_process_reads_the_program_back_with_the_same_results(tmp_path):
    """Fresh interpreters on one cache directory: the first traces and exports the solve and its
    diagnostics, the second exports nothing and computes the same numbers bit for bit; without
    the kept programs (JAXTREE_PROGRAM_CACHE=0, the programs traced as before) the numbers agree
    to round-off."""
    first = _probe(tmp_path)
    assert {"_solve", "run_diagnostics"} <= set(first["exports"]), first["exports"]
    # the stopwatch of the programs' preparation (the main job's compile / run split): every
    # program of the first call timed, nothing to prepare for the second
    assert first["prepared"][0] > 0 and first["prepared"][1] == 0
    assert first["again"] == [0.0, True]
    kept = sorted(os.listdir(tmp_path / "cache" / programs.SUBDIR))
    assert len(kept) >= 2
    assert first["loads"] == []
    second = _probe(tmp_path)
    assert second["exports"] == [] and set(second["loads"]) == set(first["exports"])
    assert second["gamma"] == first["gamma"] and second["energy"] == first["energy"]
    assert second["steps"] == first["steps"]
    assert second["prepared"][0] > 0 and second["prepared"][1] == 0  # loaded and compiled (a cache hit)
    plain = _probe(tmp_path, JAXTREE_PROGRAM_CACHE="0")
    assert plain["exports"] == plain["loads"] == [] and plain["steps"] == first["steps"]
    # traced as before: compiled inside the calls, so nothing timed and every call counted untimed
    assert plain["prepared"][0] == 0 and plain["prepared"][1] >= 2 and plain["again"][1] is False
    np.testing.assert_allclose(plain["gamma"], first["gamma"], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(plain["energy"], first["energy"], rtol=1e-12)
    assert sorted(os.listdir(tmp_path / "cache" / programs.SUBDIR)) == kept  # nothing added


def _solve():
    from jaxtree._src.integration import simulate

    return simulate._solve.__wrapped__


def _key(*args, fn=None, options=None):
    dyn, static = eqx.partition((args, {}), eqx.is_array)
    return programs.key(fn or _solve(), dyn, static, options)


def test_the_key_tells_apart_what_changes_the_trace(monkeypatch):
    """Equal for the same scene loaded twice (and for equal strings, one object or two);
    different for another scene, another dtype,
    another shape of the same leaf, other compile options, inside equinox's callback-free checks
    and with another JAXTREE_EQX_CHECKS; a function of numpy's is keyed (by numpy's version), one
    or a class of the user's is refused, and so is a program that is not jaxtree's."""
    a, b = jaxtree.load_scene("appendix_c"), jaxtree.load_scene("appendix_c")
    base = _key(a)
    assert _key(b) == base
    assert _key(jaxtree.load_scene("appendix_b")) != base
    assert _key(a.astype(jnp.float32)) != base
    assert _key(a, jnp.zeros(3)) != _key(a, jnp.zeros(4)) != _key(a, jnp.zeros(4, jnp.float32))
    assert _key(a, options={"xla_cpu_use_fusion_emitters": False}) != base
    with cache.checks_without_callbacks():
        assert _key(a) != base
    with monkeypatch.context() as m:
        m.setenv("JAXTREE_EQX_CHECKS", "raise")
        assert _key(a) != base
    assert _key(a, np.sin) == _key(b, np.sin) != base
    # equal strings keyed alike whether one object or two (how a scene's strings were made
    # differs from process to process: with pickle's memo the keys differed)
    one, two = "".join(["inte", "gral"]), "".join(["inte", "gral"])
    assert one is not two and _key(a, (one, one)) == _key(a, (one, two)) != _key(a, (one, "rate"))

    def law(t, state, params):
        return state.gamma

    class Mine:
        pass

    for user in (law, lambda t: t, Mine, Mine()):
        with pytest.raises(programs.Unkeyable):
            _key(a, user)
    with pytest.raises(programs.Unkeyable):
        _key(a, fn=lambda m: m)


def test_unreadable_entries_and_eviction(tmp_path, monkeypatch):
    """A damaged entry reads as absent (traced and written again); a write is atomic (no
    temporary file left); beyond MAX_BYTES the least recently used entries go."""
    bad = tmp_path / "damaged"
    bad.write_bytes(b"not a program")
    assert programs._load(str(bad), "x", None) == (False, None)
    assert programs._load(str(tmp_path / "absent"), "x", None) == (False, None)
    monkeypatch.setattr(programs, "MAX_BYTES", 2500)
    for i in range(4):
        programs._write(str(tmp_path / "kept" / f"e{i}"), bytes(1000))
        os.utime(tmp_path / "kept" / f"e{i}", (1000 + i, 1000 + i))
    assert sorted(os.listdir(tmp_path / "kept")) == ["e2", "e3"]


METER = """
import json, numpy as np, jaxtree
from jaxtree._src import programs
model = jaxtree.load_scene("appendix_c")
with_meter = jaxtree.simulate(model, 0.2, saveat=3, progress=True)
counts = {k: dict(v) for k, v in programs.COUNTS.items()}
plain = jaxtree.simulate(model, 0.2, saveat=3)
print(json.dumps({"counts": counts, "difference": float(np.max(np.abs(with_meter.gamma - plain.gamma)))}))
"""


def test_a_program_with_host_callbacks_is_traced_as_before(tmp_path):
    """A solve with a progress meter (host callbacks) cannot be exported: it is refused, the
    refusal is remembered on disk (a second process does not try again), and it runs as before,
    with the numbers of the run without the meter. Fresh interpreters."""
    import json

    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAXTREE_CACHE", "JAX_COMPILATION_CACHE"))}
    env.update(JAXTREE_CACHE_DIR=str(tmp_path / "cache"))
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", METER], env=env, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        got = json.loads(out.stdout.strip().splitlines()[-1])
        assert got["counts"]["_solve"] == {"refused": 1}, got["counts"]
        assert got["difference"] < 1e-12
    refused = [p for p in (tmp_path / "cache" / programs.SUBDIR).iterdir() if _kind(p) == "refused"]
    assert len(refused) == 1


def _kind(path):
    import pickle

    return pickle.loads(path.read_bytes())[0]


def test_a_rebound_name_keeps_the_kept_programs_off(monkeypatch):
    """A name of jaxtree's rebound at run time (a module constant, a class's method) is reported
    by `rebound` while it lasts, and a program called meanwhile is traced as before: not read from
    disk, not written there."""
    from jaxtree._src.integration import autosolver_linearize

    assert programs.rebound() is None
    with monkeypatch.context() as m:
        m.setattr(autosolver_linearize, "SAMPLES", autosolver_linearize.SAMPLES + 1)
        assert programs.rebound() == "jaxtree._src.integration.autosolver_linearize.SAMPLES"
        calls = []
        assert programs.call(_solve(), (), {}, None, lambda: calls.append(1) or "traced") == "traced"
        assert calls == [1]
    assert programs.rebound() is None
    with monkeypatch.context() as m:
        m.setattr(jaxtree.HybridModel, "pack", lambda *a: None)
        assert programs.rebound() == "jaxtree._src.hybrid.model.HybridModel.pack"
    assert programs.rebound() is None


def test_recording_survives_an_import_during_a_garbage_collection():
    """`record` snapshots ``sys.modules`` while another thread may import (the command line warms
    its writers on a thread while the run traces). Here a garbage collection adds a module, as a
    thread that runs during a collection's finalizers would; it is made to happen while the
    modules are listed (the free list of pairs used up, a collection on every allocation). Before
    the snapshot was one ``dict.copy``, this raised "dictionary changed size during iteration"
    (five errors of one test run)."""
    import gc
    import types

    added = []

    def import_now(phase, info):
        if phase == "start":
            name = f"_jaxtree_probe_{len(added)}"
            sys.modules[name] = types.ModuleType(name)
            added.append(name)

    # (a test before this one in the same worker may have rebound a name while programs ran: the
    # probe modules must change nothing about that)
    before = programs.rebound()
    pairs = [(None, i) for i in range(5000)]  # no free 2-tuples left: each new pair is allocated
    threshold = gc.get_threshold()
    gc.callbacks.append(import_now)
    gc.set_threshold(1)
    try:
        programs.record()
    finally:
        gc.set_threshold(*threshold)
        gc.callbacks.remove(import_now)
        for name in added:
            sys.modules.pop(name, None)
    assert len(pairs) == 5000 and added  # collections did run while record listed the modules
    assert programs.rebound() == before
