"""GF-discrepancy point selection."""

import math

import numpy as np
import pytest

import jdpim


@pytest.fixture(scope="module")
def points_2d():
    return jdpim.select_points((jdpim.Uniform(), jdpim.Uniform()), 1000)


def brute_force_gf(theta, weights, distributions, n_x=20001):
    """sup_x |F_hat(x) - F(x)| on a dense grid plus both one-sided limits at every point (oracle)."""
    worst = 0.0
    for j, dist in enumerate(distributions):
        xs = np.sort(theta[:, j])
        for x in (xs, np.nextafter(xs, -np.inf)):
            Fhat = np.array([weights[theta[:, j] <= xi].sum() for xi in x])
            worst = max(worst, np.abs(Fhat - dist.cdf(x)).max())
    return worst


def test_weights_are_probabilities(points_2d):
    assert np.all(points_2d.weights > 0)
    assert points_2d.weights.sum() == pytest.approx(1.0, abs=1e-12)


def test_gf_discrepancy_after_rearrangement_is_half_max_weight(points_2d):
    d = points_2d.discrepancy()
    assert d == pytest.approx(points_2d.weights.max() / 2, rel=1e-9)
    assert 1 / (2 * 1000) <= d < 1.5e-3  # 8.5-9e-4 is typical for N = 1000 in 2-D


def test_gf_discrepancy_matches_brute_force():
    dists = (jdpim.Uniform(), jdpim.Normal(0.03, 0.005))
    ps = jdpim.select_points(dists, 60)
    assert jdpim.gf_discrepancy(ps.theta, ps.weights, dists) == pytest.approx(
        brute_force_gf(ps.theta, ps.weights, dists), rel=1e-9
    )


def test_marginals_follow_distributions():
    """The P-weighted mean and variance of each coordinate match the distribution's."""
    dists = (jdpim.Uniform(), jdpim.Uniform(), jdpim.Normal(1.0, 0.2))
    ps = jdpim.select_points(dists, 500)
    w = ps.weights
    for j, dist in enumerate(dists):
        mean = w @ ps.theta[:, j]
        std = math.sqrt(w @ (ps.theta[:, j] - mean) ** 2)
        assert mean == pytest.approx(dist.mean, abs=0.01 * dist.std)
        assert std == pytest.approx(dist.std, rel=0.02)


def test_bad_arguments():
    with pytest.raises(ValueError, match="n_points"):
        jdpim.select_points((jdpim.Uniform(),), 1)
    with pytest.raises(ValueError, match="distributions"):
        jdpim.select_points((), 10)
