"""Tests of the hybrid coordinates' truncation (Likins 1972, Sec. III E, Eqs. 105-123): the modes
chosen to an accuracy (``hybrid_model(..., n_modes="auto", tol=...)``) and the estimate of the
error of the modes left out (``simulate_hybrid``'s ``truncation_error``).

Expected numbers come from outside the estimate: the "true error" is the hybrid run's difference
from the full nonlinear Eq. (1) (``jaxtree.simulate``, Dopri8 at rtol = atol = 1e-10) at the
same save times, in the largest small angle over the run.

The slew (also ``benchmarks/bench_stiff.py``): the bundled ``flex95`` vehicle, its rotor
at 10 pi rad/s and its bus spin, a torque of (15, 9, 0) N m on the bus on at 1 s and off at 3 s
with 0.2 s tanh edges, 10 s; the 90 wing hinges small (six substructures on the bus). The boom:
``chain50`` with its hub made 1000 times heavier (a large root body: with the bundled 100 kg hub
the 100 kg, 25 m boom makes Eq. (30) itself fail, the hybrid's hub rate off by 90 % with every mode
kept), straight and at rest, a torque of (0, 40, 15) N m on the hub with the same pulse, 10 s; its
50 hinges small (one substructure). Every run is the full 10 s.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import jaxtree
from jaxtree import SceneError

TOL = 1e-10  # the runs' tolerances: their integration error is far below the truncation error
FACTOR = 3  # the hybrid goals' bound: the truncation estimate within a factor 3 of the true error
# the run corrected by adding the estimate keeps under this fraction of the true error (the estimate has the
# error's sign and shape, not only its size)
CORRECTED = 0.6
AUTO_TOL = 1e-2  # n_modes="auto"'s accuracy on flex95, and the slew's goal on the wings' relative error
HUB_GOAL = 1e-3  # the slew's goal on the hub rate's relative error
# with every mode kept the neglected modes' flexibility is zero (computed exactly 0.0 on wings): the bound
# allows round-off of its entries, up to 1e-2 with no mode kept
ZERO = 1e-14
ZERO_ERROR = 1e-12  # the same for the estimate's largest angle (rad)
ROUNDOFF = 1e-12  # the same flexibility by two routes (masks, the one-mode model's system K), relative: round-off
# the command line's estimate against the error from the full Eq. (1): to the run's own integration error
CLI_ESTIMATE = 1e-3
SPAN = 10.0
TS = jnp.linspace(0.0, SPAN, 101)


def pulse(t):
    return jaxtree.thruster_pulse(t, 1.0, 2.0, 0.2)


def _errors(sol, ref, small):
    """(largest small-angle error (rad), that over the peak small angle, hub rate error over its
    peak) of a hybrid run against the full one."""
    S = np.asarray(small) - 1
    g, G = np.asarray(sol.gamma)[:, S], np.asarray(ref.gamma)[:, S]
    w, W = np.asarray(sol.omega0), np.asarray(ref.omega0)
    err = np.abs(g - G).max()
    return err, err / np.abs(G).max(), np.abs(w - W).max() / np.abs(W).max()


class Case:
    """A scene, its small set, its start and its full Eq. (1) reference; hybrid runs cached by
    their modes per substructure."""

    def __init__(self, model, small, state):
        self.model, self.small, self.state = model, small, state
        self.ref = jaxtree.simulate(model, SPAN, y0=state, saveat=TS, rtol=TOL, atol=TOL)
        self.runs = {}

    def run(self, hm):
        key = (hm.modes_per_substructure, tuple(np.asarray(hm.keep).tolist()))
        if key not in self.runs:
            self.runs[key] = jaxtree.simulate_hybrid(hm, SPAN, y0=self.state, saveat=TS, rtol=TOL, atol=TOL)
        return self.runs[key]


@pytest.fixture(scope="module")
def flex95():
    model = jaxtree.load_scene("flex95")
    model = model.with_loads(jaxtree.BodyTorque(0, jnp.asarray([15.0, 9.0, 0.0]), pulse))
    wings = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    rotor = model.names.index("rotor") - 1
    assert float(model.initial.gamma_dot[rotor]) == pytest.approx(10 * np.pi)  # the scene's rotor rate
    return Case(model, wings, model.initial)


@pytest.fixture(scope="module")
def boom():
    base = jaxtree.load_scene("chain50")
    base = eqx.tree_at(
        lambda m: (m.mass, m.inertia), base, (base.mass.at[0].multiply(1000.0), base.inertia.at[0].multiply(1000.0))
    )
    model = base.with_loads(jaxtree.BodyTorque(0, jnp.asarray([0.0, 40.0, 15.0]), pulse))
    state = model.initial._replace(gamma=jnp.zeros(model.n), gamma_dot=jnp.zeros(model.n))
    return Case(model, tuple(range(1, model.n + 1)), state)


def _check_estimate(case, hm, k):
    sol = case.run(hm)
    true, rel, hub = _errors(sol, case.ref, case.small)
    est = float(sol.max_truncation_error())
    static = float(np.abs(np.asarray(sol.truncation_static)).max())
    S = np.asarray(case.small) - 1
    diff = np.asarray(case.ref.gamma)[:, S] - np.asarray(sol.gamma)[:, S]
    corrected = np.abs(diff - np.asarray(sol.truncation)).max()
    print(
        f"{k} modes per substructure: estimate {est:.3e} rad (quasi-static {static:.3e}), true {true:.3e} "
        f"(ratio {est / true:.3f}; {rel:.2e} of the peak, hub {hub:.2e}); corrected {corrected:.3e}"
    )
    assert true > 1e-6  # the truncation error stands well above the runs' own errors
    assert true / FACTOR <= est <= FACTOR * true
    assert sol.truncation_error.shape == (len(TS),)
    np.testing.assert_allclose(np.asarray(sol.truncation_error), np.abs(np.asarray(sol.truncation)).max(1))
    # the estimate has the error's sign and shape, not only its size: adding it corrects the run
    assert corrected < CORRECTED * true


@pytest.mark.parametrize("k", [1, 2, 3])
def test_flex95_estimate_within_a_factor_3_of_the_true_error(flex95, k):
    """flex95's slew with k modes per wing (models built with ``n_modes=k``): the estimate within a
    factor 3 of the largest wing-angle error against the full Eq. (1) (measured 1.09, 0.97, 0.98)."""
    hm = jaxtree.hybrid_model(flex95.model, flex95.small, k)
    assert hm.modes_per_substructure == (k,) * 6
    _check_estimate(flex95, hm, k)


@pytest.mark.parametrize("k", [1, 2, 3])
def test_boom_estimate_within_a_factor_3_of_the_true_error(boom, k):
    """chain50 as a boom, one model of 3 modes masked to k by ``retain`` (one substructure): the
    estimate within a factor 3 of the true error (measured 0.85, 0.99, 0.99). The boom's lowest
    modes (0.05 to 2 rad/s) are slow against the pulse, so the neglected ones respond dynamically:
    their quasi-static response alone is 12, 1.9 and 1.6 times the error."""
    hm = jaxtree.hybrid_model(boom.model, boom.small, 3).retain(k)
    assert hm.modes_per_substructure == (3,)  # masked modes still count there
    _check_estimate(boom, hm, k)


def test_auto_modes_meet_the_slew_goals(flex95):
    """``n_modes="auto"`` with ``tol=1e-2`` on flex95: the same number of modes on each of the six
    identical wings, fewer for a looser tolerance, and the 10 s slew within wings 1e-2 and hub
    1e-3 of the full Eq. (1) (measured 3 per wing: 3.6e-3 and 1.0e-4; 2 per wing gives 1.15e-2)."""
    hm = jaxtree.hybrid_model(flex95.model, flex95.small, "auto", tol=AUTO_TOL)
    per = hm.modes_per_substructure
    assert len(set(per)) == 1 and per[0] >= 1
    loose = jaxtree.hybrid_model(flex95.model, flex95.small, "auto", tol=1e-1).modes_per_substructure
    tight = jaxtree.hybrid_model(flex95.model, flex95.small, "auto", tol=1e-3).modes_per_substructure
    assert loose[0] < per[0] < tight[0]
    sol = flex95.run(hm)
    true, wings, hub = _errors(sol, flex95.ref, flex95.small)
    print(f"auto: {per[0]} modes per wing; wings {wings:.2e}, hub {hub:.2e}")
    assert wings <= AUTO_TOL
    assert hub <= HUB_GOAL
    assert float(sol.max_truncation_error()) <= FACTOR * true


def test_all_modes_estimate_nothing_and_masked_modes_count():
    """With every mode kept the estimate is zero; masking modes with ``retain`` makes them count as
    neglected (the quasi-static flexibility of the neglected modes grows to ``K^{-1}``)."""
    model = jaxtree.load_scene("wings")
    small = tuple(k for k in range(1, model.n + 1) if model.names[k].startswith("wing"))
    hm = jaxtree.hybrid_model(model, small)
    tr = hm.truncation
    assert tr is not None
    np.testing.assert_allclose(np.asarray(tr.static(hm.keep)), 0.0, atol=ZERO)
    sol = jaxtree.simulate_hybrid(hm, 0.5, saveat=6)
    assert float(sol.max_truncation_error()) < ZERO_ERROR
    assert np.abs(np.asarray(sol.gamma)).max() > 1e-6
    one = hm.retain(1)
    grows = np.asarray(one.truncation.static(one.keep))  # type: ignore[union-attr]
    assert np.abs(grows).max() > 1e-6
    none = np.asarray(tr.static(jnp.zeros_like(hm.keep)))
    systems_K = jaxtree.hybrid_model(model, small, 1).truncation.static(jnp.zeros(2))  # type: ignore[union-attr]
    np.testing.assert_allclose(np.asarray(systems_K), none, atol=ROUNDOFF * np.abs(none).max())
    off = jaxtree.simulate_hybrid(one, 0.5, saveat=6, truncation_error=False)
    assert off.truncation is None and off.truncation_error is None


@pytest.mark.parametrize("tol", [0.0, -1e-2, float("nan"), float("inf"), "1e-2"])
def test_bad_tolerance_is_refused_before_tracing(tol):
    model = jaxtree.load_scene("wings")
    with pytest.raises(SceneError) as e:
        jaxtree.hybrid_model(model, (1, 2, 3, 4), "auto", tol=tol)
    assert "tol" in str(e.value)


def test_unknown_n_modes_word_is_refused():
    model = jaxtree.load_scene("wings")
    with pytest.raises(SceneError, match="'auto'"):
        jaxtree.hybrid_model(model, (1, 2, 3, 4), "all")


def test_command_line_prints_the_truncation_beside_the_integration_error(tmp_path, capsys):
    """``jaxtree simulate wings --hybrid-small 1-8 --modes 1``: the summary says the modes count per
    substructure and prints the truncation estimate beside the integration error estimate; wings
    starts deflected outside the retained modes, so the estimate is the neglected modes' free
    motion, equal to the error against the full Eq. (1) (to 1e-3 here: the run's own error), also
    across the run's two parts (the neglected modes' state carried from one to the next)."""
    from jaxtree._src import cli

    out = tmp_path / "h.nc"
    args = ["simulate", "wings", "--t1", "2", "--points", "21", "--chunks", "2", "--hybrid-small", "1-8"]
    rc = cli.main(args + ["--modes", "1", "--out", str(out), "--no-plot", "--no-progress"])
    text = capsys.readouterr().out
    assert rc == 0
    assert "1 per substructure, 2 substructures" in text
    assert "integration error estimate" in text and "truncation error estimate" in text
    ds = jaxtree.load_result(out, as_dataset=True)
    ref = jaxtree.simulate(jaxtree.load_scene("wings"), 2.0, saveat=21, rtol=TOL, atol=TOL)
    true = np.abs(ds["gamma"].values[:, :8] - np.asarray(ref.gamma)[:, :8]).max()
    est = float(ds.attrs["truncation_error"])
    print(f"wings, 1 mode per wing: estimate {est:.4e}, true {true:.4e}")
    assert abs(est - true) <= CLI_ESTIMATE * true
    assert float(ds.attrs["error_estimate_gamma"]) < 1e-6 < est
    assert cli.main(args + ["--modes", "2", "--modes-tol", "0.1", "--out", str(tmp_path / "x.nc")]) != 0
    assert "--modes-tol needs --modes auto" in capsys.readouterr().err
