"""Derivatives of first-passage probabilities by subset simulation (``first_passage(..., SubsetSimulation(),
wrt=...)``): against Monte Carlo, for drift parameters, the noise intensity, restitution and a system of several
degrees of freedom; the method's place among the methods; diverged paths."""

import jax
import numpy as np
import pytest

import jdpim

W, ZETA = 7.85, 0.02  # Au & Beck's oscillator, over a short horizon (cheap)
D = np.pi
SIGMA = np.sqrt(D / (2 * ZETA * W**3))  # the stationary standard deviation of x
MODEL = jdpim.VibroImpactOscillator(alpha=2 * ZETA * W, gamma=None, barrier=None, omega=W)
SCENE = jdpim.Scene(MODEL, noise=jdpim.WhiteNoise(D=D), t_end=4.0, dt=0.02)
LEVEL = 3.0 * SIGMA  # P about 5e-4 by t = 4 s: two levels above level 0 at N = 500


def absolute(state):
    return abs(state[0])


@pytest.fixture(scope="module")
def monte_carlo():
    return jdpim.first_passage(SCENE, absolute, LEVEL, jdpim.MonteCarlo(n_samples=20_000, seed=1), wrt=("alpha", "D"))


def _value(fp, name):
    return float(fp.derivative[name][0, 0]), float(fp.derivative_stderr[name][0, 0])


def test_likelihood_ratio_and_noise_score_agree_with_monte_carlo(monte_carlo):
    """``dP/dalpha`` by the likelihood ratio carried through the levels, resolved (standard error below a third
    of the value), and ``dP/dD`` by the exact score of the forcing, both within three combined standard errors
    of Monte Carlo (likelihood ratio; central differences for D)."""
    ss = jdpim.first_passage(
        SCENE, absolute, LEVEL, jdpim.SubsetSimulation(n_per_level=500, seed=0), wrt=("alpha", "D")
    )
    assert ss.n_evaluations == 1500  # levels 0, 1 and 2: the chains carry the derivative
    for name in ("alpha", "D"):
        (d, se), (d_mc, se_mc) = _value(ss, name), _value(monte_carlo, name)
        assert abs(d - d_mc) < 3 * np.hypot(se, se_mc), (name, d, se, d_mc, se_mc)
    d, se = _value(ss, "alpha")
    assert se < abs(d) / 3, (d, se)


def test_central_differences_on_the_level_samples_agree_with_monte_carlo(monte_carlo):
    """``estimator=jdpim.CentralDifference()``: common random numbers on the samples of one run, resolved and
    within three combined standard errors of Monte Carlo; their reruns count as evaluations."""
    ss = jdpim.first_passage(
        SCENE, absolute, LEVEL, jdpim.SubsetSimulation(n_per_level=500, seed=0), wrt="D",
        estimator=jdpim.CentralDifference(),
    )  # fmt: skip
    (d, se), (d_mc, se_mc) = _value(ss, "D"), _value(monte_carlo, "D")
    assert abs(d - d_mc) < 3 * np.hypot(se, se_mc) and se < abs(d) / 3, (d, se, d_mc, se_mc)
    assert ss.n_evaluations > 1500


# slow: further scenes of the estimators that the default tier checks against Monte Carlo on the level samples:
# the likelihood ratio in test_likelihood_ratio_and_noise_score_agree_with_monte_carlo and central differences in
# test_central_differences_on_the_level_samples_agree_with_monte_carlo
@pytest.mark.slow
def test_restitution_and_several_degrees_of_freedom():
    """Restitution (central differences on the level samples, ``step=0.1``): on the impact oscillator the
    rebound speed is ``r`` times the impact speed, so ``dP/dr > 0`` for the velocity's passage, by more than two
    standard errors at P about 5e-4; exactly 0 without
    a barrier, where ``r`` changes no path. Two masses, the noise on the first: the passage of the second falls
    with the first's damping (likelihood ratio) and with the coupling spring's stiffness ``stiffness[0,0]``
    (central differences), each by more than two standard errors."""
    method = jdpim.SubsetSimulation(n_per_level=500, seed=0)
    impact = jdpim.Scene(jdpim.VibroImpactOscillator(r=0.8), noise=jdpim.WhiteNoise(D=0.3), t_end=4.0, dt=0.02)
    fp = jdpim.first_passage(impact, "v", 3.0, method, wrt="r", estimator=jdpim.CentralDifference(step=0.1))
    d, se = _value(fp, "r")
    assert d > 2 * se > 0 and float(fp.probability[0, 0]) < 3e-3, (d, se, fp.probability)
    fp = jdpim.first_passage(SCENE, absolute, LEVEL, jdpim.SubsetSimulation(n_per_level=100), wrt="r")
    assert _value(fp, "r") == (0.0, 0.0)
    two = jdpim.MDOFOscillator(
        mass=np.eye(2), gains=[[1.0], [0.0]], damping=[[0.4, -0.2], [-0.2, 0.4]], stiffness=[[2.0, -1.0], [-1.0, 2.0]]
    )
    scene = jdpim.Scene(two, noise=jdpim.WhiteNoise(D=0.5), t_end=4.0, dt=0.02)
    fp = jdpim.first_passage(scene, "x2", 0.6, method, wrt=("damping[0,0]", "stiffness[0,0]"))
    for name in ("damping[0,0]", "stiffness[0,0]"):
        d, se = _value(fp, name)
        assert d < -2 * se < 0, (name, d, se)


def test_a_method_for_failure_probabilities_only():
    """``SubsetSimulation`` is a failure-probability method, not a density method: ``solve`` and ``sensitivity``
    refuse it with a TypeError; estimators it cannot carry fail in one line."""
    ss = jdpim.SubsetSimulation(n_per_level=100)
    assert isinstance(ss, jdpim.AbstractFailureMethod) and not isinstance(ss, jdpim.AbstractMethod)
    with pytest.raises(TypeError, match="method must be a jdpim method object"):
        jdpim.solve(SCENE, ss)
    with pytest.raises(TypeError, match="method must be"):
        jdpim.sensitivity(SCENE, "alpha", "x", np.linspace(-1, 1, 5), 4.0, method=ss)
    with pytest.raises(ValueError, match="Pathwise does not estimate first-passage derivatives"):
        jdpim.first_passage(SCENE, "x", 1.0, ss, wrt="alpha", estimator=jdpim.Pathwise())
    with pytest.raises(ValueError, match="window=1.0"):
        jdpim.first_passage(SCENE, "x", 1.0, ss, wrt="alpha", estimator=jdpim.LikelihoodRatio(window=1.0))
    with pytest.raises(ValueError, match="states its own error"):
        jdpim.first_passage(SCENE, "x", 1.0, ss, replicates=2)

    def under_jit(D):
        return jdpim.first_passage(SCENE.replace(noise=jdpim.WhiteNoise(D)), "x", 1.0, ss).probability

    with pytest.raises(TypeError, match="SubsetSimulation cannot run under a JAX transformation"):
        jax.jit(under_jit)(0.03)


def test_diverged_paths_count_below_every_level():
    """``x'' - 4 x = xi`` grows past a million times the reach of its start and noise by t = 10 s while its state
    stays finite: those paths diverged (as ``jdpim.solve`` counts them), so none passes, with a warning."""
    model = jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], stiffness=[[-4.0]])
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.01), t_end=10.0, dt=0.01)
    with pytest.warns(jdpim.NonFiniteWarning, match="not finite or diverged"):
        fp = jdpim.first_passage(scene, "x1", 1.0, jdpim.SubsetSimulation(n_per_level=10, max_levels=1))
    assert float(fp.probability[0, 0]) == 0.0
