"""Values of the impact resolution stored once on a CPU (``jdpim._engine.elementwise.stored``): exact, with
derivatives passed through, and without a bit of difference in the states."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import DT_SMALL, N_SMALL, T_SMALL

import jdpim
from jdpim._engine import batches, elementwise, locate, resolve, rk4


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64, jnp.int32])
def test_stored_is_the_value_itself(dtype):
    with jax.enable_x64(dtype == jnp.float64):
        if jnp.issubdtype(dtype, jnp.floating):
            info = jnp.finfo(dtype)
            x = jnp.array([-jnp.inf, jnp.inf, jnp.nan, -0.0, 0.0, info.min, info.max, info.tiny, -1.5], dtype)
        else:
            info = jnp.iinfo(dtype)
            x = jnp.array([info.min, info.max, -1, 0, 7], dtype)
        y = jax.jit(jax.vmap(elementwise.stored))(x)
        assert y.dtype == x.dtype
        np.testing.assert_array_equal(np.asarray(y).view(np.uint8), np.asarray(x).view(np.uint8))


def test_stored_passes_derivatives_through():
    x = jnp.array([-2.0, 0.0, 3.0])
    _, tangent = jax.jvp(elementwise.stored, (x,), (jnp.array([1.0, -2.0, 0.5]),))
    np.testing.assert_array_equal(tangent, [1.0, -2.0, 0.5])
    np.testing.assert_array_equal(jax.grad(lambda x: jnp.sum(elementwise.stored(x) ** 2))(x), 2 * x)


# Scenes and methods: every path crossing in its first step (one degree of freedom, sticking on as by default), the
# impact damper (both on the small sizes of conftest.py, the damper saved twice as test_scenefile_mdof.py runs it), and
# the damper held on its walls behind a Kanai-Tajimi filter as test_mdof_sticking.py runs it (same sizes), so that a
# session compiles those programs, the ones users run, once.
SCENES = {
    "one degree of freedom": (
        lambda: jdpim.Scene(
            jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.08), t_end=T_SMALL, dt=DT_SMALL, x0=1e-3, v0=-1.0
        ),
        jdpim.MonteCarlo(n_samples=N_SMALL, seed=5),
    ),
    "impact damper": (
        lambda: jdpim.Scene(
            jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.05), t_end=T_SMALL, dt=DT_SMALL, save_at=(1.0, T_SMALL)
        ),
        jdpim.MonteCarlo(n_samples=N_SMALL, seed=5),
    ),
    "held on the walls": (
        lambda: jdpim.Scene(
            jdpim.kanai_tajimi(jdpim.impact_damper(), omega_g=3.0, zeta_g=0.6),
            noise=jdpim.WhiteNoise(D=0.01),
            t_end=20.0,
            dt=0.01,
            save_at=(10.0, 20.0),
        ),
        jdpim.MonteCarlo(n_samples=400, seed=0),
    ),
}


# slow: [held on the walls] repeats on a third scene what [impact damper] checks (several degrees of freedom, every
# store of locate.py, resolve.py and rk4.py left out); that each store is its value bit for bit,
# test_stored_is_the_value_itself
@pytest.mark.parametrize(
    "name", [pytest.param(name, marks=pytest.mark.slow) if name == "held on the walls" else name for name in SCENES]
)
def test_storing_changes_no_state_beyond_its_last_bits(name, monkeypatch):
    """Monte Carlo states with the values stored and with every store left out: bit for bit for one degree of
    freedom; for several, XLA may contract a multiply-add inside a fusion that computes a value again where it does
    not in the one that stores it, and a state's last bit moves (the impact damper: 8 of 512 values, by at most two
    units in the last place)."""
    scene, method = SCENES[name][0](), SCENES[name][1]
    stored = np.asarray(jdpim.solve(scene, method).states)
    for module in (locate, resolve, rk4):  # every user of the stored values
        monkeypatch.setattr(module, "stored", lambda x: x)
    jax.clear_caches()
    plain = np.asarray(jdpim.solve(scene, method).states)
    assert np.all(np.isfinite(stored))
    if name == "one degree of freedom":
        np.testing.assert_array_equal(stored, plain)
    else:
        np.testing.assert_allclose(stored, plain, rtol=4 * np.finfo(stored.dtype).eps, atol=0)


@pytest.mark.parametrize("n", [2, 64, 512])
def test_a_compact_batch_keeps_its_stored_values(n):
    """A compact batch of a chunk of ``n`` paths has enough rows for XLA to keep each stored value as a reduction: a
    chain of four stored values, mapped over the batch, compiles to four reductions (one row would give none)."""

    def chain(x):
        for _ in range(4):
            x = elementwise.stored(x * x * 0.5 + jnp.sin(x))
        return x

    rows = batches.compact_rows(n)
    assert rows >= 2
    hlo = jax.jit(jax.vmap(chain)).lower(jnp.ones(rows)).compile().as_text()
    assert hlo.count(" reduce(") == 4


def test_tangents_are_stored_with_their_values():
    """Forward mode stores each stored value's tangent too (a sum with zero: linear, so reverse mode transposes it):
    a chain of four stored values has eight reductions in its derivative's program, and its derivative is exact."""

    def chain(x):
        for _ in range(4):
            x = elementwise.stored(x * x * 0.5 + jnp.sin(x))
        return x

    x = jnp.linspace(0.1, 1.0, 8)
    hlo = jax.jit(lambda x: jax.jvp(jax.vmap(chain), (x,), (jnp.ones_like(x),))).lower(x).compile().as_text()
    assert hlo.count(" reduce(") == 8

    def plain(x):
        for _ in range(4):
            x = x * x * 0.5 + jnp.sin(x)
        return x

    np.testing.assert_allclose(
        jax.grad(lambda x: jnp.sum(chain(x)))(x), jax.grad(lambda x: jnp.sum(plain(x)))(x), rtol=1e-6
    )
