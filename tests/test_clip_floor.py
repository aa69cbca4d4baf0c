"""diffrax's end-time floor computed in one loop (jaxtree/_src/integration/clip_floor.py): the same
number as diffrax's hundred ``prevbefore`` calls, the same derivative, per thread, and the same
integration to the bit."""

import threading

import diffrax
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxtree._src.integration import clip_floor


def values(dtype):
    """Ordinary end times, both zeros, a negative one, the smallest subnormal and normal numbers,
    the largest finite one and both infinities of `dtype`."""
    info = np.finfo(dtype)
    special = [info.smallest_subnormal, info.tiny, info.max, np.inf, -np.inf]
    return jnp.asarray(np.array([10.0, 1.0, 0.3, 0.0, -0.0, -3.0] + special, dtype))


def hundred(x):
    for _ in range(100):
        x = eqxi.prevbefore(x)
    return x


def counted(x):
    """The view's hundred calls, as diffrax's loop makes them while the context is entered."""
    view = clip_floor._integrate.eqxi
    for _ in range(100):
        x = view.prevbefore(x)
    return x


def test_the_installed_diffrax_computes_the_floor_as_clip_floor_expects():
    """Where diffrax's source differs (another version), nothing is replaced: this test then says
    that the floor costs its hundred operations again."""
    assert clip_floor._integrate is not None, "diffrax._integrate no longer matches clip_floor._LOOP_SOURCE"


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_the_floor_equals_a_hundred_prevbefore_calls_eagerly_and_traced(dtype):
    x = values(dtype)
    expected = np.asarray(jax.jit(jax.vmap(hundred))(x))
    with clip_floor.one_loop_floor():
        eager = np.stack([np.asarray(counted(v)) for v in x])
        traced = np.asarray(jax.jit(jax.vmap(counted))(x))
    np.testing.assert_array_equal(eager.view(np.uint8), expected.view(np.uint8))
    np.testing.assert_array_equal(traced.view(np.uint8), expected.view(np.uint8))
    assert clip_floor._integrate.eqxi is eqxi  # the module's own equinox.internal again


def test_the_floors_derivative_is_prevbefores():
    with clip_floor.one_loop_floor():
        assert float(jax.grad(counted)(2.0)) == float(jax.grad(hundred)(2.0)) == 1.0


def test_runs_in_two_threads_count_apart():
    """Two threads whose hundred calls interleave each get their own floor."""
    out, half = {}, threading.Barrier(2)

    def run(name, x):
        view = clip_floor._integrate.eqxi
        v = jnp.asarray(x)
        for i in range(100):
            if i == 50:
                half.wait()
            v = view.prevbefore(v)
        out[name] = float(v)

    with clip_floor.one_loop_floor():
        threads = [threading.Thread(target=run, args=(k, x)) for k, x in (("a", 1.0), ("b", 7.0))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert out == {"a": float(hundred(1.0)), "b": float(hundred(7.0))}


def test_a_solve_is_the_same_to_the_bit_with_the_floor_in_one_loop():
    """A traced end time that is not a multiple of the steps: the same steps and states."""

    def solve(t1):
        term = diffrax.ODETerm(lambda t, y, a: jnp.stack([y[1], -y[0] - 0.1 * y[1]]))
        return diffrax.diffeqsolve(
            term,
            diffrax.Tsit5(),
            0.0,
            t1,
            None,
            jnp.array([1.0, 0.0]),
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-8),
        )

    plain = jax.jit(solve)(3.7)
    with clip_floor.one_loop_floor():
        fast = jax.jit(lambda t1: solve(t1))(3.7)
    assert int(fast.stats["num_steps"]) == int(plain.stats["num_steps"])
    np.testing.assert_array_equal(np.asarray(fast.ts), np.asarray(plain.ts))
    np.testing.assert_array_equal(np.asarray(fast.ys), np.asarray(plain.ys))
