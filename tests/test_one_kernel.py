"""A batch's resolution as one CPU kernel (``jdpim._engine.one_kernel``): tagged only where XLA's single-kernel
emitter takes every operation, the same values, derivatives of the function itself, and on in the engine's programs."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import DT_SMALL, N_SMALL, T_SMALL

import jdpim
from jdpim._engine import batches, one_kernel
from jdpim.bench.timing import monte_carlo_inputs
from jdpim.methods._paths import simulate


def _small_calls(compiled_text: str) -> int:
    """The calls of a compiled program's entry computation that XLA emits as one kernel each (a call inside one is
    part of its kernel)."""
    entry = compiled_text[compiled_text.index("\nENTRY ") :]
    entry = entry[: entry.index("\n}")]
    return sum(" call(" in line and 'xla_cpu_small_call="true"' in line for line in entry.splitlines())


def _newton(x, y):
    """Elementwise steps in a loop, then a branch: what a batch's resolution is made of."""

    def step(_, s):
        return s - (s * s * s - y) / jnp.where(s == 0, 1.0, 3.0 * s * s)

    s = jax.lax.fori_loop(0, 4, step, x)
    return jax.lax.cond(jnp.any(s > 1.0), jnp.sqrt, lambda s: s * s, s), jnp.clip(x / y, 0.0, 1.0)


X = jnp.linspace(0.1, 2.0, 160, dtype=jnp.float32)
Y = jnp.linspace(2.0, 0.3, 160, dtype=jnp.float32)


def test_a_function_of_supported_operations_is_one_kernel_with_the_same_values():
    tagged = jax.jit(lambda x, y: one_kernel.one_kernel(_newton, x, y))
    assert _small_calls(tagged.lower(X, Y).compile().as_text()) == 1
    for got, want in zip(tagged(X, Y), jax.jit(_newton)(X, Y), strict=True):
        np.testing.assert_array_equal(got, want)


UNSUPPORTED = {
    "matrix product": lambda x: jnp.reshape(jnp.reshape(x, (-1, 2)) @ jnp.array([[2.0, 0.1], [0.1, 1.0]]), (-1,)),
    "sort": jnp.sort,
    "scatter": lambda x: x.at[jnp.argmax(x)].set(0.0),
}


@pytest.mark.parametrize("name", list(UNSUPPORTED))
def test_a_function_the_single_kernel_emitter_does_not_take_runs_as_it_is(name):
    """XLA's single-kernel emitter fails to compile a matrix product or a sort: such a function is left untagged,
    compiles and gives its values."""
    fn = UNSUPPORTED[name]
    tagged = jax.jit(lambda x: one_kernel.one_kernel(fn, x))
    assert _small_calls(tagged.lower(X).compile().as_text()) == 0
    np.testing.assert_array_equal(tagged(X), jax.jit(fn)(X))


def test_a_product_of_one_element_vectors_is_taken():
    """``jnp.dot`` of the one-element vectors of a one-degree-of-freedom model's gains and forcing is a product of
    numbers, which the single-kernel emitter takes; a matrix product is not."""
    assert one_kernel.primitives(jax.make_jaxpr(jnp.dot)(jnp.ones(1), jnp.ones(1))) == {"dot_general"}
    assert one_kernel.primitives(jax.make_jaxpr(jnp.dot)(jnp.ones((2, 2)), jnp.ones(2))) == {"matrix product"}


def test_derivatives_are_those_of_the_function_including_closed_over_parameters():
    """Forward and reverse mode with respect to the argument and to a traced value the function closes over (as the
    resolution closes over the model's parameters) equal those of the function itself."""

    def loss(x, a, tag):
        def fn(x):
            return jnp.sum(_newton(x * a, Y)[0] ** 2)

        return one_kernel.one_kernel(fn, x) if tag else fn(x)

    def derivatives(tag):
        grads = jax.jit(jax.grad(loss, argnums=(0, 1)), static_argnums=2)(X, a, tag)
        tangent = jax.jit(lambda x, a: jax.jvp(lambda x, a: loss(x, a, tag), (x, a), (jnp.ones_like(x), 1.0)))(X, a)
        return (*grads, *tangent)

    a = jnp.float32(1.3)
    for got, want in zip(derivatives(True), derivatives(False), strict=True):
        np.testing.assert_array_equal(got, want)


def _lowered(scene, n):
    rows, _, chunk = monte_carlo_inputs(scene, n, seed=0)
    return simulate.lower(scene, rows, kind="monte_carlo", chunk_size=chunk).as_text()


def test_the_engine_resolves_compact_batches_in_one_kernel_on_a_cpu_only(monkeypatch):
    """The reference scene's Monte Carlo program tags its compact batches' resolution (lowered, not compiled); taken
    for an accelerator's, it does not."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=T_SMALL, dt=DT_SMALL)
    assert "xla_cpu_small_call" in _lowered(scene, N_SMALL)
    monkeypatch.setattr(one_kernel, "on_cpu", lambda: False)
    jax.clear_caches()
    assert "xla_cpu_small_call" not in _lowered(scene, N_SMALL)


def test_one_kernel_changes_no_state_beyond_its_last_bits(monkeypatch):
    """Monte Carlo states of paths that all cross in their first step, with the resolution as one kernel and as XLA
    fuses it otherwise: bit for bit here. (XLA rounds some operations differently in the two, so that a grazing
    path's state can move by a few units in the last place, which later impacts amplify: docs/speed.md.)"""
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.08), t_end=T_SMALL, dt=DT_SMALL, x0=1e-3, v0=-1.0
    )
    method = jdpim.MonteCarlo(n_samples=N_SMALL, seed=5)
    tagged = np.asarray(jdpim.solve(scene, method).states)
    monkeypatch.setattr(batches, "one_kernel", lambda fn, *args: fn(*args))
    jax.clear_caches()
    np.testing.assert_array_equal(tagged, np.asarray(jdpim.solve(scene, method).states))
