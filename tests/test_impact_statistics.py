"""Impact statistics: the first impact does not depend on r; rates and impact speeds against Rice's formulas."""

import numpy as np
import pytest

import jdpim

# Both Monte Carlo runs of impact statistics below share one compiled program: the same structure (the cubic damping
# term kept, a speed histogram), the same sizes and saved times; the parameters are data.
SAVE, EDGES = (1.0, 2.0, 5.0, 20.0), np.linspace(0.0, 2.0, 401)
MC = jdpim.MonteCarlo(n_samples=1000, seed=0)


def test_the_first_impact_does_not_depend_on_r_and_is_the_free_first_passage():
    """From x0 = 0.5 a path is the same for every r until it first hits the barrier, so the probability of an
    impact by t is the same for r = 0.98 and 0.5 (bit for bit), and equals the probability that the oscillator
    without a barrier has gone below 0 by t (the same steps); the number of impacts after it does depend on r."""
    stats = {}
    for r in (0.98, 0.5):
        scene = jdpim.Scene(jdpim.VibroImpactOscillator(r=r), t_end=20.0, dt=0.01, x0=0.5, save_at=SAVE)
        stats[r] = jdpim.impact_statistics(scene, MC, speed_edges=EDGES)
    np.testing.assert_array_equal(np.asarray(stats[0.98].probability), np.asarray(stats[0.5].probability))
    p = np.asarray(stats[0.98].probability)
    assert np.all(np.diff(p) > 0) and 0.5 < p[1] < 0.99
    count, count_se = np.asarray(stats[0.98].mean_count), np.asarray(stats[0.98].mean_count_stderr)
    assert np.asarray(stats[0.5].mean_count)[-1] > count[-1] + 4 * count_se[-1]  # lower r: more, smaller bounces
    free = jdpim.Scene(jdpim.VibroImpactOscillator(barrier=None), t_end=20.0, dt=0.01, x0=0.5, save_at=SAVE)
    below = jdpim.first_passage(free, lambda s: -s[0], 0.0, MC)
    np.testing.assert_array_equal(np.round(p * 1000), np.round(np.asarray(below.probability)[:, 0] * 1000))


def test_elastic_impacts_follow_rice_rate_and_rayleigh_speeds():
    """r = 1 and linear damping (the cubic term kept at 0): impacts are the zero crossings of the linear
    oscillator's response, at the rate ``2 nu_0 = sigma_v / (pi sigma_x) = 1 / pi`` per second at stationarity,
    with speeds of the Rayleigh density ``(u / s^2) exp(-u^2 / (2 s^2))``, ``s^2 = E[v^2] = D / alpha`` (mean
    ``s sqrt(pi / 2)``). Damping ratio 0.5: the response forgets its start x0 = 0.5 within a few seconds (the mean
    decays as exp(-t / 2), the variances approach their stationary values as exp(-t)); the window [5, 20] s holds
    about 4.7 impacts per path."""
    alpha, D = 1.0, 0.05
    model = jdpim.VibroImpactOscillator(alpha=alpha, gamma=0.0, r=1.0)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=20.0, dt=0.01, x0=0.5, save_at=SAVE)
    st = jdpim.impact_statistics(scene, MC, speed_edges=EDGES)
    count, count_se = np.asarray(st.mean_count), np.asarray(st.mean_count_stderr)
    rate = (count[3] - count[2]) / 15.0  # the window [5, 20] s, near stationarity
    assert abs(rate - 1 / np.pi) < 3 * (count_se[2] + count_se[3]) / 15.0, rate
    binned = np.asarray(st.speed_density) * np.diff(EDGES)[None] * count[:, None]  # impacts per path and bin
    window, mid = binned[3] - binned[2], 0.5 * (EDGES[1:] + EDGES[:-1])
    mean = np.sum(window * mid) / np.sum(window)
    spread = np.sqrt(np.sum(window * (mid - mean) ** 2) / np.sum(window))
    se = spread / np.sqrt(np.sum(window) * MC.n_samples)  # impacts as if independent
    s = np.sqrt(D / alpha)
    assert abs(mean - s * np.sqrt(np.pi / 2)) < 4 * se, (mean, s * np.sqrt(np.pi / 2), se)
    np.testing.assert_allclose(np.sum(np.asarray(st.speed_density)[3] * np.diff(EDGES)), 1.0, atol=1e-3)


def test_impact_statistics_refuse_what_they_cannot_count():
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.01)
    with pytest.raises(ValueError, match="no constraint"):
        jdpim.impact_statistics(scene.replace(model=jdpim.VibroImpactOscillator(barrier=None)), jdpim.MonteCarlo(10))
    with pytest.raises(ValueError, match="use jdpim.MonteCarlo or jdpim.DPIM"):
        jdpim.impact_statistics(scene, jdpim.PathIntegration())
    with pytest.raises(ValueError, match="speed_edges must be strictly increasing"):
        jdpim.impact_statistics(scene, jdpim.MonteCarlo(10), speed_edges=[1.0, 0.5])
    dp = jdpim.impact_statistics(scene, jdpim.DPIM(n_points=50))
    assert dp.probability_stderr is None and dp.speed_density is None and dp.method == "dpim"
