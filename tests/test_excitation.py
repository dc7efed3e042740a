"""Spectral white noise: FFT synthesis, variance normalisation, orthonormal random functions."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import jdpim
from jdpim import _excitation as ex


@pytest.fixture(scope="module")
def grid():
    return jdpim.SpectralRepresentation(cutoff=4 * math.pi).grid(t_end=20.0, dt=0.02)


def direct_sum(coeffs, grid, times):
    """xi(t) = Re sum_k c_k exp(i w_k t), k = 0..K, evaluated term by term (the oracle)."""
    w = np.arange(grid.n_terms + 1) * grid.dw
    return np.real(np.exp(1j * np.outer(times, w)) @ coeffs)


def test_fft_synthesis_equals_direct_sum(grid):
    key = jax.random.key(3)
    c = np.asarray(ex.gaussian_coefficients(key, 1, grid, jnp.eye(1), jnp.float32))[0]
    xi = np.asarray(ex.synthesize(jnp.asarray(c)[None, None], grid))[:, 0, 0]
    half = 0.01
    times = (grid.start + np.arange(grid.n_half)) * half
    np.testing.assert_allclose(xi, direct_sum(c, grid, times), atol=2e-4 * np.abs(xi).max())


def _random_coefficients(n, grid, seed=0):
    rng = np.random.default_rng(seed)
    shape = (n, 1, grid.n_terms + 1)
    return jnp.asarray(rng.standard_normal(shape) + 1j * rng.standard_normal(shape), jnp.complex64)


def test_synthesis_in_blocks_equals_one_fft(grid, monkeypatch):
    """On a CPU the paths go through the FFT in blocks (here 3 of 16 rows for 40 paths, the last one redoing 8 of
    the second's): the same values, bit for bit, as one FFT over every path."""
    c = _random_coefficients(40, grid)
    monkeypatch.setattr(ex, "SYNTHESIS_BLOCK_BYTES", 16 * 3 * grid.n_fft * 4 * jax.local_device_count())
    assert ex.synthesis_rows(40, 1, grid.n_fft, 4) == 16
    blocked = np.asarray(jax.jit(ex.synthesize, static_argnums=1)(c, grid))
    whole = np.asarray(jax.jit(ex._synthesize_block, static_argnums=1)(c, grid))
    assert blocked.shape == (grid.n_half, 40, 1)
    np.testing.assert_array_equal(blocked, whole)


def test_synthesis_computes_each_blocks_coefficients_as_the_whole_batchs(grid, monkeypatch):
    """With a function of the paths' inputs, each block computes its own coefficients: the same values, bit for bit,
    as the coefficients of every path computed first (DPIM's random functions, 3 blocks of 16 rows for 40 paths)."""
    theta = jnp.asarray(np.random.default_rng(2).uniform(-np.pi, np.pi, (40, 2)), jnp.float32)
    of = jax.vmap(lambda t: ex.random_function_coefficients(t, grid, jnp.eye(1)))
    monkeypatch.setattr(ex, "SYNTHESIS_BLOCK_BYTES", 16 * 3 * grid.n_fft * 4 * jax.local_device_count())
    assert ex.synthesis_rows(40, 1, grid.n_fft, 4) == 16
    by_blocks = np.asarray(jax.jit(lambda t: ex.synthesize(t, grid, of))(theta))
    whole = np.asarray(jax.jit(lambda t: ex.synthesize(of(t), grid))(theta))
    np.testing.assert_array_equal(by_blocks, whole)


def test_synthesis_in_blocks_is_differentiated_as_one_fft(grid, monkeypatch):
    c = _random_coefficients(40, grid, seed=1)
    monkeypatch.setattr(ex, "SYNTHESIS_BLOCK_BYTES", 16 * 3 * grid.n_fft * 4 * jax.local_device_count())
    assert ex.synthesis_rows(40, 1, grid.n_fft, 4) == 16

    def energy(scale, synthesize):
        x = synthesize(scale * c, grid)
        return jnp.sum(x * x * jnp.arange(x.shape[1])[None, :, None])  # weights every path apart

    blocked = jax.grad(energy)(1.0, ex.synthesize)
    whole = jax.grad(energy)(1.0, ex._synthesize_block)
    np.testing.assert_allclose(blocked, whole, rtol=1e-6)


@pytest.mark.parametrize("n_paths", [1, 15, 16, 17, 100, 130, 512, 10_000])
@pytest.mark.parametrize("n_fft", [64, 4320, 40500])
def test_synthesis_rows(n_paths, n_fft):
    rows = ex.synthesis_rows(n_paths, 1, n_fft, 4)
    per_path = 3 * n_fft * 4
    budget = ex.SYNTHESIS_BLOCK_BYTES // jax.local_device_count()  # the devices share the cache
    assert 1 <= rows <= n_paths
    assert rows == n_paths or rows % ex.SYNTHESIS_ROWS == 0
    assert rows * per_path <= budget + ex.SYNTHESIS_ROWS * per_path  # a block within the device's budget
    redone = -(-n_paths // rows) * rows - n_paths  # paths that overlapping blocks compute twice
    if rows > ex.SYNTHESIS_MAX_ROWS:  # the cap is left out only where it would redo more than a sixteenth
        per_block = -(-n_paths // -(-n_paths // ex.SYNTHESIS_MAX_ROWS))  # equal blocks of at most the cap
        capped_rows = -(-per_block // ex.SYNTHESIS_ROWS) * ex.SYNTHESIS_ROWS
        assert -(-n_paths // capped_rows) * capped_rows - n_paths > n_paths // 16
    else:
        assert rows == n_paths or redone <= n_paths // 16 or rows * 2 * per_path > budget  # few redone paths
    assert rows < n_paths or n_paths * per_path <= budget + ex.SYNTHESIS_ROWS * per_path


def test_the_cpu_devices_share_the_synthesis_budget(monkeypatch):
    one = ex.synthesis_rows(512, 1, 40500, 4)
    monkeypatch.setattr(jax, "local_device_count", lambda: 2)
    assert ex.synthesis_rows(512, 1, 40500, 4) < one


def test_synthesis_takes_every_path_at_once_off_a_cpu(monkeypatch):
    monkeypatch.setattr(ex, "on_cpu", lambda: False)
    assert ex.synthesis_rows(10_000, 1, 40500, 4) == 10_000


def test_gaussian_variance_normalisation(grid):
    """E[xi^2] = 2 S0 (w_u + dw / 2) with S0 = D / pi; 4000 paths give a 2.2 % standard error."""
    D, n = 0.3, 4000
    keys = jax.random.split(jax.random.key(0), n)
    L = jdpim.WhiteNoise(D=D).mixing()
    c = jax.vmap(lambda k: ex.gaussian_coefficients(k, 1, grid, L, jnp.float32))(keys)
    xi = np.asarray(ex.synthesize(c, grid))[:, :, 0]
    expected = 2 * D / math.pi * (grid.cutoff + grid.dw / 2)
    var_per_time = (xi**2).mean(axis=1)
    assert abs(var_per_time.mean() / expected - 1) < 0.03  # pooled over times: stationarity
    assert abs(var_per_time[len(var_per_time) // 2] / expected - 1) < 4 * math.sqrt(2 / n)


def _coefficients(theta, grid, kind):
    g = dataclasses.replace(grid, random_functions=kind)
    c = jax.vmap(lambda t: ex.random_function_coefficients(t, g, jnp.eye(1)))(jnp.asarray(theta))[:, 0]
    a = jnp.asarray(g.amplitude())
    return np.asarray(jnp.real(c) / a[None, :]), np.asarray(-jnp.imag(c)[:, 1:] / a[None, 1:])


def test_cosine_random_functions_are_orthonormal(grid):
    """Theta1, Theta2 each on a fine uniform grid (paired by a random permutation): E[X_k X_l] = E[Y_k Y_l]
    = delta_kl exactly (the grid integrates harmonics below its size exactly); E[X_k Y_l] = 0 up to the
    pairing noise 1/sqrt(n)."""
    n = 64 * (grid.n_terms + 2)
    th = np.linspace(-math.pi, math.pi, n, endpoint=False)
    X, Y = _coefficients(np.stack([th, np.random.default_rng(0).permutation(th)], 1), grid, "cosine")
    np.testing.assert_allclose(X.T @ X / n, np.eye(X.shape[1]), atol=1e-4)
    np.testing.assert_allclose(Y.T @ Y / n, np.eye(Y.shape[1]), atol=1e-4)
    assert np.abs(X.T @ Y / n).max() < 5 / math.sqrt(n)


def test_rayleigh_random_functions_are_orthonormal_and_gaussian(grid):
    """Independent uniform (Theta1, Theta2), n = 1e5: E[X_k X_l], E[Y_k Y_l] = delta_kl and E[X_k Y_l] = 0
    within 5 standard errors (1/sqrt(n) for unit-variance products), and X_k, Y_k standard normal (KS)."""
    n = 100_000
    theta = np.random.default_rng(1).uniform(-math.pi, math.pi, size=(n, 2))
    X, Y = _coefficients(theta, grid, "rayleigh")
    tol = 5 / math.sqrt(n) * math.sqrt(2)  # diagonal entries have variance 2
    np.testing.assert_allclose(X.T @ X / n, np.eye(X.shape[1]), atol=tol)
    np.testing.assert_allclose(Y.T @ Y / n, np.eye(Y.shape[1]), atol=tol)
    assert np.abs(X.T @ Y / n).max() < tol
    for k in (0, 1, grid.n_terms // 2):
        assert stats.kstest(X[:, k], "norm").pvalue > 1e-3
        assert stats.kstest(Y[:, k], "norm").pvalue > 1e-3


def test_dpim_excitation_variance_over_points():
    """The P-weighted variance of the DPIM excitation over 1000 points matches 2 S0 (w_u + dw/2)."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=20.0, dt=0.02)
    g = jdpim.SpectralRepresentation().grid(scene.t_end, scene.dt)
    pts = jdpim.dpim_points(scene, 1000)
    c = jax.vmap(lambda t: ex.random_function_coefficients(t, g, scene.noise.mixing()))(jnp.asarray(pts.theta))
    xi = np.asarray(ex.synthesize(c, g))[:, :, 0]
    var = (np.asarray(pts.weights)[None, :] * xi**2).sum(axis=1)
    expected = 2 * 0.03 / math.pi * (g.cutoff + g.dw / 2)
    assert abs(var.mean() / expected - 1) < 0.02


def test_spectral_grid_covers_window_and_rejects_aliasing():
    g = jdpim.SpectralRepresentation().grid(t_end=200.0, dt=0.01)
    period = 2 * math.pi / g.dw
    assert period >= 200.0 + 2 * g.start * 0.005 - 1e-9
    assert g.cutoff == pytest.approx(2.0 / 0.01, rel=0.01)  # default: cutoff * dt = 2
    with pytest.raises(ValueError, match="Nyquist"):
        jdpim.SpectralRepresentation(cutoff=700.0).grid(t_end=10.0, dt=0.01)  # Nyquist: pi / 0.005 = 628


def test_correlated_sources_mixing():
    D = np.array([[0.05, 0.02], [0.02, 0.04]])
    L = np.asarray(jdpim.WhiteNoise(D=D).mixing())
    np.testing.assert_allclose(L @ L.T, D, rtol=1e-6)
