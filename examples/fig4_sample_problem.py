"""The sample problem of Sec. II E (Fig. 4 of Likins 1972), simulated for 100 s.

Eleven bodies: the bus, a pointed platform whose hinge follows gamma_1 = sin(0.5 t) (prescribed,
Sec. II B: it leaves the unknowns and its torque is an output), two massless gimbal frames, a
rotor spinning at 10 pi rad/s, and a sprung chain of solar panels. The attitude of the bus is
integrated twice, with the Euler angles of Eqs. (23)-(24) as in the report and with quaternions;
the two runs must agree to integration tolerance.

Run:  python examples/fig4_sample_problem.py [output folder]
(`python -m jaxtree` does the same with options, a progress meter and timings.)
"""

import pathlib
import sys
import time

import jax
import numpy as np

import jaxtree

out = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else "results")
model = jaxtree.load_scene("fig4")
print(
    f"{model.name}: {model.n + 1} bodies, hinges {list(model.prescribed)} prescribed, "
    f"initial rotor rate {float(model.initial.gamma_dot[3]):.4f} rad/s"
)

runs = {}
for attitude in ("euler123", "quaternion"):
    t0 = time.perf_counter()
    sol = jaxtree.simulate(model, 100.0, attitude=attitude, saveat=1001, rtol=1e-9, atol=1e-9)
    jax.block_until_ready(sol.gamma)
    runs[attitude] = sol
    print(jaxtree.summary(attitude, sol, first=time.perf_counter() - t0))

e, q = runs["euler123"], runs["quaternion"]
print(
    "max |difference| Euler vs quaternion run:",
    f"gamma {np.abs(np.asarray(e.gamma - q.gamma)).max():.2e},",
    f"omega0 {np.abs(np.asarray(e.omega0 - q.omega0)).max():.2e},",
    f"C {np.abs(np.asarray(e.dcm - q.dcm)).max():.2e}",
)
print("hinge-1 hold torque: max |tau_1| =", f"{np.abs(np.asarray(q.hold_torque)).max():.4f} N m")

jaxtree.save_npz(out / "fig4_sample_problem.npz", runs)
for name, sol in runs.items():
    jaxtree.save_csv(out / f"fig4_sample_problem_{name}.csv", sol)
if not jaxtree.save_plot(out / "fig4_sample_problem.png", runs, title="Fig. 4 sample problem, 100 s"):
    print("matplotlib is not installed: no plot")
print(f"results in {out.resolve()}")
