"""Subset simulation: small first-passage probabilities of Au & Beck's linear oscillator."""

import numpy as np
import pytest

import jdpim

W, ZETA, S = 7.85, 0.02, 1.0  # rad/s, damping ratio, two-sided spectral density of the white noise
D = np.pi * S  # E[xi(t) xi(t + s)] = 2 pi S delta(s) = 2 D delta(s)
SIGMA = np.sqrt(D / (2 * ZETA * W**3))  # the stationary standard deviation of x
MODEL = jdpim.VibroImpactOscillator(alpha=2 * ZETA * W, gamma=None, barrier=None, omega=W)
SCENE = jdpim.Scene(MODEL, noise=jdpim.WhiteNoise(D=D), t_end=30.0, dt=0.02)  # Monte Carlo's forcing, GaussianNodes


def test_subset_simulation_agrees_with_monte_carlo_and_reaches_small_probabilities():
    """``P(max_{t <= 30 s} |x| > b)`` at b = 3, 4 and 6 standard deviations: subset simulation (1000 samples per
    level) within three combined standard errors of Monte Carlo (20000 paths) where Monte Carlo reaches, and
    a probability near 1e-7 at 6 standard deviations with a stated coefficient of variation below 0.6."""
    levels = SIGMA * np.array([3.0, 4.0, 6.0])
    ss = jdpim.first_passage(SCENE, lambda s: abs(s[0]), levels, jdpim.SubsetSimulation(n_per_level=1000, seed=0))
    mc = jdpim.first_passage(SCENE, lambda s: abs(s[0]), levels[:2], jdpim.MonteCarlo(n_samples=20_000, seed=0))
    p, se = np.asarray(ss.probability)[0], np.asarray(ss.probability_stderr)[0]
    q, q_se = np.asarray(mc.probability)[0], np.asarray(mc.probability_stderr)[0]
    assert ss.times == (30.0,) and ss.method == "subset_simulation"
    assert np.all(np.abs(p[:2] - q) < 3 * np.hypot(se[:2], q_se)), (p, q, se, q_se)
    assert 1e-9 < p[2] < 1e-5 and p[2] < p[1] < p[0]
    assert np.all(se / p < 0.6)
    # N per level, and a level per factor p0 = 0.1 of the smallest probability (plus level 0)
    assert ss.n_evaluations % 1000 == 0 and ss.n_evaluations <= 1000 * (np.ceil(-np.log10(p[2])) + 1)


def test_subset_simulation_settings_and_scenes_it_refuses_fail_in_one_line():
    ss = jdpim.SubsetSimulation(n_per_level=100)
    with pytest.raises(ValueError, match=r"excitation=jdpim.GaussianNodes\(\)"):
        jdpim.first_passage(SCENE.replace(excitation=jdpim.SpectralRepresentation()), "x", 1.0, ss)
    with pytest.raises(ValueError, match="without random parameters"):
        jdpim.first_passage(SCENE.replace(random={"alpha": jdpim.Uniform(0.2, 0.4)}), "x", 1.0, ss)
    with pytest.raises(TypeError, match="method must be a jdpim method object"):
        jdpim.solve(SCENE, ss)
    with pytest.raises(ValueError, match="whole numbers"):
        jdpim.SubsetSimulation(n_per_level=1005, p0=0.1)
    with pytest.raises(ValueError, match=r"p0 must lie in \(0, 0.5\]"):
        jdpim.SubsetSimulation(p0=0.7)
