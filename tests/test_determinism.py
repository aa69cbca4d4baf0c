"""Determinism: the same scene, tolerances and solver give bit-identical trajectories twice in one
process and in two fresh processes on this CPU.

The run: fig4_free (gimbals, a rotor at 10 pi rad/s, a sprung panel chain) for 1 s at
rtol = atol = 1e-10, about a hundred adaptive Dopri8 steps, so that any difference of a rounding
anywhere (the step-size controller reacts to the last bit of the error estimate) shows up in
the saved states. The subprocesses inherit this process's environment (XLA_FLAGS included) and
compile everything afresh; in this process the second run reuses the first one's compilation
(clearing JAX's caches would make every later test compile again).
"""

import hashlib
import os
import subprocess
import sys

import numpy as np

import jaxtree

# rtol = atol of the runs (module docstring: tight enough for about a hundred steps); the check itself has
# no tolerance, the runs must agree bit for bit
RUN_TOL = 1e-10

RUN = f"""
import hashlib, sys
import numpy as np
import jaxtree
model = jaxtree.load_scene("fig4_free")
sol = jaxtree.simulate(model, 1.0, rtol={RUN_TOL!r}, atol={RUN_TOL!r})
fields = (sol.ts, sol.gamma, sol.gamma_dot, sol.omega0, sol.dcm, sol.energy, sol.stats["num_steps"])
sys.stdout.write(hashlib.sha256(b"".join(np.asarray(x).tobytes() for x in fields)).hexdigest())
"""


def _digest(sol):
    fields = (sol.ts, sol.gamma, sol.gamma_dot, sol.omega0, sol.dcm, sol.energy, sol.stats["num_steps"])
    return hashlib.sha256(b"".join(np.asarray(x).tobytes() for x in fields)).hexdigest()


def test_trajectories_are_bit_identical_in_one_process_and_across_processes():
    env = dict(os.environ, PYTHONHASHSEED="0")
    # two fresh processes, started first so that they run while this one computes
    procs = [
        subprocess.Popen([sys.executable, "-c", RUN], stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        for _ in range(2)
    ]
    model = jaxtree.load_scene("fig4_free")
    first = jaxtree.simulate(model, 1.0, rtol=RUN_TOL, atol=RUN_TOL)
    again = jaxtree.simulate(model, 1.0, rtol=RUN_TOL, atol=RUN_TOL)
    assert int(first.stats["num_steps"]) > 50  # enough steps for the controller to amplify a difference
    assert _digest(first) == _digest(again)
    outputs = []
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0, err.decode()[-2000:]
        outputs.append(out.decode().strip())
    assert outputs == [_digest(first)] * 2
