"""Fragility curves: the intensity scaling, the lognormal fit against direct Monte Carlo and against synthetic
counts, Wilson intervals, separated counts, refusals."""

import jax
import numpy as np
import pytest
from scipy import special

import jdpim
from jdpim.reliability._fragility import fit_lognormal, wilson_interval

LEVEL = 0.5
FIT_AT = (0.8, 1.0, 1.25, 1.6, 2.0)  # P from about 0.1 to 0.9
CHECK_AT = (0.9, 1.4, 1.8)


@pytest.fixture(scope="module")
def scene():
    """A linear oscillator from rest under Shinozuka-Sato modulated white noise over a 10 s record."""
    model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None, omega=1.5)
    noise = jdpim.WhiteNoise(0.1, envelope=jdpim.ShinozukaSato(b1=0.2, b2=1.0))
    return jdpim.Scene(model, noise=noise, t_end=10.0, dt=0.02)


@pytest.fixture(scope="module")
def curve(scene):
    return jdpim.fragility(scene, "x", LEVEL, FIT_AT, jdpim.MonteCarlo(n_samples=400, seed=0))


def test_lognormal_fit_against_direct_monte_carlo(scene, curve):
    """At three intensities not fitted, the fit and a direct Monte Carlo run (400 other paths each) differ by
    less than 3 standard errors of the difference; the direct probability's Wilson interval brackets it. The
    lognormal is a model: for a Gaussian response its lower tail is too heavy (it overestimates small
    probabilities), which is why the intensities lie in the middle of the curve."""
    direct = jdpim.fragility(scene, "x", LEVEL, CHECK_AT, jdpim.MonteCarlo(n_samples=400, seed=100))
    p, se = curve.fitted(np.asarray(CHECK_AT))
    z = (p - direct.probability) / np.sqrt(se**2 + direct.probability_stderr**2)
    assert np.all(np.abs(z) < 3.0), np.round(z, 2)
    assert np.all((direct.lower <= direct.probability) & (direct.probability <= direct.upper))
    assert np.all(np.diff(direct.probability) > 0)
    assert 0.0 < curve.beta_stderr < 0.2 * curve.beta and 0.0 < curve.median_stderr < 0.1 * curve.median


def test_intensity_scales_the_ground_motion(scene, curve):
    """At intensity ``s`` the noise intensity is ``D s^2``: a linear response is ``s`` times the scene's on the same
    paths, so exceeding ``LEVEL`` at ``s`` is exceeding ``LEVEL / s`` at ``s = 1`` (intensity ``i`` on seed ``i``)."""
    for i in (0, 3):
        fp = jdpim.first_passage(scene, "x", LEVEL / FIT_AT[i], jdpim.MonteCarlo(n_samples=400, seed=i))
        assert float(curve.probability[i]) == pytest.approx(float(fp.probability[-1, 0]), abs=1.5 / 400)
    # a reference intensity measure only relabels the axis
    scaled = jdpim.fragility(scene, "x", LEVEL, np.asarray(FIT_AT) * 3.0, jdpim.MonteCarlo(400, 0), reference=3.0)
    np.testing.assert_allclose(scaled.probability, curve.probability)
    assert float(scaled.median) == pytest.approx(3.0 * float(curve.median), rel=1e-9)
    assert curve.times == (10.0,)


def test_fit_of_synthetic_counts_and_its_standard_errors():
    """Counts drawn from a known lognormal curve: over 300 synthetic data sets the estimates' mean lies within 3
    standard errors of the truth, and the mean observed-information standard error matches their spread to 15 %."""
    rng = np.random.default_rng(0)
    s, n, median, beta = np.array([0.5, 0.7, 1.0, 1.4, 2.0]), 200, 1.1, 0.5
    p = special.ndtr(np.log(s / median) / beta)
    fits = [fit_lognormal(s, rng.binomial(n, p), n) for _ in range(300)]
    estimates = np.array([[f[0], f[1]] for f in fits])
    stderr = np.array([[f[0] * np.sqrt(f[2][0, 0]), np.sqrt(f[2][1, 1])] for f in fits])
    spread = estimates.std(axis=0, ddof=1)
    assert np.all(np.abs(estimates.mean(axis=0) - [median, beta]) < 3.0 * spread / np.sqrt(300))
    np.testing.assert_allclose(stderr.mean(axis=0), spread, rtol=0.15)


def test_wilson_interval():
    lower, upper = wilson_interval([0, 7, 100], 100, 0.95)
    z2 = special.ndtri(0.975) ** 2
    assert lower[0] == 0.0 and upper[0] == pytest.approx(z2 / (100 + z2))  # no exceedance: still an upper bound
    assert lower[1] < 0.07 < upper[1]
    assert lower[2] == pytest.approx(1.0 - upper[0]) and upper[2] == 1.0


def test_separated_counts_have_no_fit(scene):
    with pytest.warns(jdpim.FragilityWarning, match=r"counts \[0, 400\] of 400 paths are separated"):
        fr = jdpim.fragility(scene, "x", LEVEL, [0.1, 100.0], jdpim.MonteCarlo(n_samples=400, seed=0))
    assert np.isnan(float(fr.median)) and np.isnan(float(fr.beta_stderr))
    assert fit_lognormal([1.0, 2.0, 3.0], [0, 3, 10], 10) is None  # one mixed count between: still separated
    assert fit_lognormal([1.0, 2.0, 3.0], [1, 0, 10], 10) is not None


def test_result_passes_through_jit(curve):
    out = jax.jit(lambda f: f)(curve)
    assert isinstance(out, jdpim.Fragility) and out.level == LEVEL and out.n_samples == 400
    np.testing.assert_allclose(out.probability, curve.probability)


def test_refusals(scene):
    mc = jdpim.MonteCarlo(n_samples=10, seed=0)
    with pytest.raises(TypeError, match=r"^method must be jdpim.MonteCarlo"):
        jdpim.fragility(scene, "x", LEVEL, FIT_AT, jdpim.DPIM(n_points=100))
    with pytest.raises(ValueError, match=r"^intensities must be at least 2 increasing positive finite numbers"):
        jdpim.fragility(scene, "x", LEVEL, [1.0, 0.5], mc)
    with pytest.raises(ValueError, match=r"^intensities must be at least 2"):
        jdpim.fragility(scene, "x", LEVEL, [1.0], mc)
    with pytest.raises(ValueError, match=r"^confidence must lie in \(0, 1\)"):
        jdpim.fragility(scene, "x", LEVEL, FIT_AT, mc, confidence=1.0)
    with pytest.raises(ValueError, match=r"^reference must lie in \(0, inf"):
        jdpim.fragility(scene, "x", LEVEL, FIT_AT, mc, reference=0.0)
    with pytest.raises(TypeError, match=r"^level must be a number"):
        jdpim.fragility(scene, "x", [0.5, 0.6], FIT_AT, mc)
    with pytest.raises(ValueError, match=r"^intensity must be positive"):
        jdpim.Fragility(times=(1.0,), median=1.0, beta=0.5, covariance=np.eye(2)).fitted(0.0)
