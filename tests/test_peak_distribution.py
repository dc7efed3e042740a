"""The distribution of the peak over the record: exactly one minus the first-passage probability, monotone, saved
and loaded; one-line errors for levels that are not an increasing grid."""

import numpy as np
import pytest

import jdpim

LEVELS = (0.05, 0.1, 0.2, 0.4)


@pytest.fixture(scope="module")
def linear():
    """A linear oscillator (no barrier) and 200 Monte Carlo paths of it."""
    model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(0.1), t_end=2.0, dt=0.02, save_at=(1.0, 2.0))
    return scene, jdpim.MonteCarlo(n_samples=200, seed=3)


def test_the_peak_distribution_is_one_minus_first_passage_and_monotone(linear, tmp_path):
    scene, method = linear
    peak = jdpim.peak_distribution(scene, "x", LEVELS, method)
    fp = jdpim.first_passage(scene, "x", LEVELS, method)
    assert peak.times == fp.times == (1.0, 2.0) and peak.method == "monte_carlo"
    np.testing.assert_array_equal(peak.levels, fp.levels)
    np.testing.assert_array_equal(peak.cdf, 1.0 - fp.probability)
    np.testing.assert_array_equal(peak.cdf_stderr, fp.probability_stderr)
    np.testing.assert_array_equal(peak.lost_mass, fp.lost_mass)
    cdf = np.asarray(peak.cdf)
    assert np.all(np.diff(cdf, axis=1) >= 0.0) and np.all(np.diff(cdf, axis=0) <= 0.0)  # levels up, time on
    assert 0.0 < cdf[-1, 0] < cdf[-1, -1] <= 1.0  # levels that tell something
    peak.save(tmp_path / "peak.npz")
    back = jdpim.load(tmp_path / "peak.npz")
    assert type(back) is jdpim.PeakDistribution and back.times == peak.times
    for name in ("levels", "cdf", "cdf_stderr", "lost_mass"):
        np.testing.assert_array_equal(getattr(back, name), np.asarray(getattr(peak, name)), err_msg=name)


@pytest.mark.parametrize(
    ("levels", "error", "message"),
    [
        ([0.2, 0.1], ValueError, r"^levels must be a 1-D sequence of at least two increasing levels, got \[0.2, 0.1\]"),
        ([0.2], ValueError, r"^levels must be a 1-D sequence of at least two increasing levels"),
        ("0.1", TypeError, r"^levels must be a 1-D sequence of increasing levels, got '0.1'"),
    ],
)
def test_levels_must_be_an_increasing_grid(linear, levels, error, message):
    scene, method = linear
    with pytest.raises(error, match=message):
        jdpim.peak_distribution(scene, "x", levels, method)
