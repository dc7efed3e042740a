"""Path integration under uniformly modulated white noise ``e(t) xi(t)``: the folded linear response at r = 1 against
the Lyapunov equation, Monte Carlo at r = 0.98, first passage, kernels matched at low intensity, refusals.

Grids are small (compile time dominates); float64 runs inside ``jax.enable_x64`` so nothing leaks.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim import exact
from jdpim.methods._pi_operator import node_exponent

ALPHA, D = 0.2, 0.02
ENVELOPE = jdpim.ShinozukaSato(b1=0.1, b2=0.5)
NOISE = jdpim.WhiteNoise(D=D, envelope=ENVELOPE)
TIMES = tuple(2.0 * k for k in range(1, 11))  # 2, 4, ..., 20 s: rise, peak (4 s) and decay
SETTINGS = jdpim.PathIntegration(n_x=41, n_v=81, tau=0.1, t0=2.0)


def elastic(noise=NOISE, save_at=TIMES, dtype="float64"):
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, r=1.0)
    return jdpim.Scene(model, noise=noise, t_end=max(save_at), dt=0.1, save_at=save_at, dtype=dtype)


def test_elastic_impacts_fold_the_modulated_linear_response():
    """r = 1 from rest is the folded free oscillator: E[x^2](t), E[v^2](t) are its Lyapunov variances under the
    same modulated noise. Each error lies within the grid's own estimate (the coarse grid's change) and within
    0.3 % (measured on this grid: at most 0.11 %; 1e-4 on 61 x 121, see docs/path_integration.md)."""
    with jax.enable_x64(True):
        res = jdpim.path_integration(elastic(), dataclasses.replace(SETTINGS, estimate_error=True))
        free = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, barrier=None)
        P = exact.lyapunov_covariance(free, NOISE, TIMES)
        for k, var in enumerate(("x", "v")):
            fine = np.array([float(res.moment(var, 2, t)) for t in TIMES])
            coarse = np.array([float(res.coarse.moment(var, 2, t)) for t in TIMES])
            err, estimate = np.abs(fine - P[:, k, k]), np.abs(fine - coarse)
            assert np.all(err <= estimate), (var, err, estimate)
            assert np.all(err <= 3e-3 * P[:, k, k]), (var, err / P[:, k, k])
        assert np.all(np.asarray(res.mass_defect) < 1e-6)


def test_a_unit_envelope_reproduces_the_stationary_noise():
    """e(t) = 1 takes the per-step kernels; where they span two spacings or more they are the operator's own."""
    settings = jdpim.PathIntegration(n_x=31, n_v=61, tau=0.1, x_max=1.5, v_max=1.5, t0=1.0)
    unit = jdpim.WhiteNoise(D=D, envelope=_unit)
    a = jdpim.path_integration(elastic(unit, save_at=(3.0,), dtype="float32"), settings)
    b = jdpim.path_integration(elastic(jdpim.WhiteNoise(D=D), save_at=(3.0,), dtype="float32"), settings)
    np.testing.assert_allclose(np.asarray(a.density), np.asarray(b.density), rtol=1e-4, atol=1e-5)


def _unit(t):
    return jnp.ones_like(t)


def test_node_exponent_matches_the_variance_on_the_nodes():
    """The kernel exp(-z k^2) carries the asked variance from 1e-9 to 10 spacings^2; a sampled Gaussian (z = 1 / (2
    var)) falls short below one spacing, by 87 % at var = 0.1."""
    var = np.array([1e-9, 1e-6, 1e-3, 0.1, 0.36, 1.0, 3.0, 4.0, 10.0])
    k2 = np.arange(-60, 61.0) ** 2
    with jax.enable_x64(True):
        z = np.asarray(jax.jit(node_exponent)(jnp.asarray(var)))
        grad = jax.jit(jax.grad(node_exponent))(jnp.asarray(0.0))
    g = np.exp(-z[:, None] * k2)
    np.testing.assert_allclose((g * k2).sum(1) / g.sum(1), var, rtol=1e-9)
    sampled = np.exp(-k2 / (2 * 0.1))
    assert (sampled * k2).sum() / sampled.sum() < 0.14 * 0.1
    assert float(grad) == 0.0  # an intensity of zero: the identity, with a finite derivative


def test_modulated_noise_refusals():
    with pytest.raises(ValueError, match=r"^PathIntegration\(stationary=True\) .* assumes a constant noise intensity"):
        jdpim.path_integration(elastic(dtype="float32"), SETTINGS, stationary=True)
    model = jdpim.Oscillator(g=lambda x, p: x, f=lambda x, v, p: ALPHA * v, h=lambda x, v, p: jnp.sqrt(1 + v * v)[None])
    scene = jdpim.Scene(model, noise=NOISE, t_end=4.0, dt=0.1, save_at=(4.0,))
    with pytest.raises(ValueError, match="modulated noise needs state-independent gains"):
        jdpim.path_integration(scene, SETTINGS)
    spectrum = jdpim.EvolutionaryKanaiTajimi(omega_g=((0.0, 4.0), (12.0, 3.0)), zeta_g=0.4)
    evolving = elastic(dtype="float32").replace(noise=jdpim.WhiteNoise(D=0.02, envelope=spectrum))
    for question in (
        lambda s: jdpim.path_integration(s, SETTINGS),
        lambda s: jdpim.first_passage(s, "x", 0.5, SETTINGS),
    ):
        with pytest.raises(ValueError, match="^path integration takes white noise, modulated or not, not an evolution"):
            question(evolving)


@pytest.mark.slow
def test_reference_oscillator_and_its_first_passage_against_monte_carlo():
    """r = 0.98, alpha = gamma = 0.03 under Shinozuka-Sato modulated noise: second moments and the first passage of
    x over 0.6 within 3 Monte Carlo standard errors (fixed seeds). docs/path_integration.md has the larger run."""
    noise = jdpim.WhiteNoise(D=0.03, envelope=ENVELOPE)
    model = jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98)
    scene = jdpim.Scene(model, noise=noise, t_end=10.0, dt=0.05, save_at=(6.0, 10.0), dtype="float32")
    settings = jdpim.PathIntegration(n_x=41, n_v=81, tau=0.1, t0=2.0, x_max=2.0, v_max=2.0)
    pi = jdpim.path_integration(scene, settings)
    mc = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=2000, seed=5))
    for t in scene.save_at:
        for var in ("x", "v"):
            s = np.asarray(mc.samples(var, t), float) ** 2
            z = (float(pi.moment(var, 2, t)) - s.mean()) / (s.std(ddof=1) / np.sqrt(s.size))
            assert abs(z) < 3, (t, var, z)
    passage = [jdpim.first_passage(scene, "x", 0.6, m) for m in (settings, jdpim.MonteCarlo(n_samples=2000, seed=6))]
    z = (np.asarray(passage[0].probability) - np.asarray(passage[1].probability)) / np.asarray(
        passage[1].probability_stderr
    )
    assert np.all(np.abs(z) < 3), z
