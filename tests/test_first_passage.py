"""First-passage probabilities by Monte Carlo and DPIM: the running maximum of every step, exact checks, input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.stats import norm
from test_first_solve import compiled_programs

import jdpim

REF = jdpim.VibroImpactOscillator()  # alpha = gamma = 0.03, r = 0.98


# One scene, one set of paths and one set of levels for the tests below that need a first-passage run of the
# reference oscillator: its programs are compiled once.
PASSAGE_SCENE = jdpim.Scene(REF, noise=jdpim.WhiteNoise(D=0.03), t_end=3.0, dt=0.01, save_at=(0.0, 1.0, 2.0, 3.0))
PASSAGE_MC = jdpim.MonteCarlo(n_samples=1000, seed=0)
LEVELS = [0.1, 0.3, 0.6]


@pytest.fixture(scope="module")
def passage():
    return jdpim.first_passage(PASSAGE_SCENE, "x", LEVELS, PASSAGE_MC)


def test_the_running_maximum_sees_every_step_not_only_the_saved_times(passage):
    """Saved at a few times, the probabilities equal those of the maxima over every step's saved state."""
    dense = PASSAGE_SCENE.replace(save_at=np.arange(301) * 0.01)
    x = np.asarray(jdpim.solve(dense, PASSAGE_MC).states[..., 0])  # (N, 301): every step of the same paths
    for i, k in enumerate((0, 100, 200, 300)):
        brute = np.sum(np.max(x[:, : k + 1], axis=1)[:, None] > np.asarray(LEVELS), axis=0)  # paths passed
        np.testing.assert_array_equal(np.round(np.asarray(passage.probability[i]) * 1000), brute)
    only_saved = np.sum(np.max(x[:, [0, 100, 200, 300]], axis=1)[:, None] > np.asarray(LEVELS), axis=0)
    assert np.all(only_saved < brute)  # the saved times alone miss passages


def drifted_brownian_passage(mu, D, t, b):
    """``P(max_{s<=t} (sigma W_s - mu s) > b)``, ``sigma^2 = 2 D`` (reflection principle with drift)."""
    s = np.sqrt(2 * D * t)
    return norm.cdf((-b - mu * t) / s) + np.exp(-mu * b / D) * norm.cdf((-b + mu * t) / s)


def stepped_brownian_passage(mu, D, dt, steps, b):
    """``P(max_{k<=K} v_k > b)`` ``(len(mu), len(steps), len(b))`` for the step ends ``v_k`` of ``v' = -mu + xi``
    integrated by RK4 with Gaussian nodes, monitored at the steps ``K`` in ``steps``: the scheme's own law.

    A step adds ``dt/6 (e_k + 4 e_{k+1/2} + e_{k+1}) - mu dt`` with nodes ``e`` of variance ``18 D / (5 dt)``, so
    neighbouring increments share a node. ``T_k = v_k + dt/6 e_k`` is a random walk (independent increments
    ``N(-mu dt, 2 D dt)``, ``T_0 ~ N(0, D dt / 10)``), and given ``T_k`` and ``T_{k+1}`` the step end ``v_{k+1}`` is
    normal with mean ``0.1 T_k + 0.9 T_{k+1} - 0.1 mu dt`` and variance ``0.08 D dt``. The density of the walks
    whose ``v`` stayed below ``b`` is carried over the steps on a grid of the distance ``b - T`` (trapezoid rule,
    spacing ``sqrt(0.08 D dt)``: exact to about 1e-13 here, as halving it shows); the transition is a convolution
    except within a few spacings of the barrier."""
    mu, b = np.atleast_1d(np.asarray(mu, float)), np.asarray(b, float)
    sd, h = np.sqrt(2 * D * dt), np.sqrt(0.08 * D * dt)
    half = int(np.ceil(8 * sd / h))
    d = h * np.arange(-half, half + 1)  # T_{k+1} - T_k
    r = h * np.arange(-half, int(np.ceil((mu.max() + 8 * np.sqrt(2 * D / (steps[-1] * dt))) * steps[-1] * dt / h)))
    g = norm.pdf(d + mu[:, None] * dt, scale=sd) * h
    n_fft = 1 << int(np.ceil(np.log2(r.size + d.size)))
    g_hat = np.fft.rfft(g[:, ::-1], n_fft)[:, None, :]
    near = int(np.argmax(norm.cdf((r + 0.1 * d.min() + 0.1 * mu.min() * dt) / h) == 1.0))  # below b there
    below = g[:, None, :] * norm.cdf((r[:near, None] + 0.1 * d + 0.1 * mu[:, None, None] * dt) / h)
    f = np.broadcast_to(norm.pdf(b[:, None] - r, scale=np.sqrt(D * dt / 10)) * h, (mu.size, b.size, r.size))
    out = []
    for k in range(1, steps[-1] + 1):
        edge = np.lib.stride_tricks.sliding_window_view(
            np.pad(f[..., : near + half], ((0, 0), (0, 0), (half, 0))), d.size, axis=-1
        )
        head = np.einsum("cbrj,crj->cbr", edge, below)
        f = np.fft.irfft(np.fft.rfft(f, n_fft) * g_hat, n_fft)[..., half : half + r.size]
        f[..., :near] = head
        if k in steps:
            out.append(1 - f.sum(-1))
    return np.stack(out, axis=1)


def test_brownian_velocity_with_drift_passes_and_its_derivatives_as_exactly_known():
    """``x'' = -mu + xi``: ``v`` is a Brownian motion with drift ``-mu`` and variance ``2 D t``, its first passage
    and ``dP/dmu`` known exactly for the steps' discrete monitoring (:func:`stepped_brownian_passage`).

    The probabilities, the likelihood ratio's ``dP/dmu`` (the default for a drift parameter) and the central
    difference with common random numbers (against the difference quotient of the exact probabilities, its own
    expectation) each lie within 4 standard errors of their exact values: 12 values, so a sound estimator fails
    with probability below 12 x 6.3e-5 < 1e-3. The continuous-time probability misses the passages between the
    steps and lies 4.0 to 6.8 standard errors above the exact one at these sizes: the check can tell (the sum of
    the four squared standardised errors against it, about 116 in expectation, must exceed 40)."""
    D, dt, mu, levels = 0.5, 0.0025, 0.3, np.array([0.5, 1.0])
    model = jdpim.Oscillator(
        params={"mu": mu},
        g=lambda x, p: 0.0 * x,
        f=lambda x, v, p: p["mu"] + 0.0 * v,
        h=lambda x, v, p: jnp.ones((1,), v.dtype),
        barrier=None,
    )
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=2.0, dt=dt, save_at=(1.0, 2.0))
    step, eps = 0.05, 1e-4
    exact = stepped_brownian_passage(mu + np.array([0.0, -eps, eps, -step, step]), D, dt, [400, 800], levels)
    d_exact, cd_exact = (exact[2] - exact[1]) / (2 * eps), (exact[4] - exact[3]) / (2 * step)
    mc = jdpim.MonteCarlo(n_samples=20_000, seed=0, progress=False)
    fp = jdpim.first_passage(scene, "v", levels, mc, wrt="mu")
    p, se = np.asarray(fp.probability), np.asarray(fp.probability_stderr)
    assert np.all(np.abs(p - exact[0]) < 4 * se), ((p - exact[0]) / se).tolist()
    continuous = (p - drifted_brownian_passage(mu, D, np.asarray(scene.save_at)[:, None], levels)) / se
    assert np.sum(continuous**2) > 40, continuous.tolist()
    lr, lr_se = np.asarray(fp.derivative["mu"]), np.asarray(fp.derivative_stderr["mu"])
    assert np.all(np.abs(lr - d_exact) < 4 * lr_se), ((lr - d_exact) / lr_se).tolist()
    cd = jdpim.first_passage(scene, "v", levels, mc, wrt="mu", estimator=jdpim.CentralDifference(step=step))
    cd_value, cd_se = np.asarray(cd.derivative["mu"]), np.asarray(cd.derivative_stderr["mu"])
    assert np.all(np.abs(cd_value - cd_exact) < 4 * cd_se), ((cd_value - cd_exact) / cd_se).tolist()
    np.testing.assert_array_equal(np.asarray(cd.probability), p)  # the nominal paths are the same


@pytest.mark.slow  # dP/dalpha by the likelihood ratio is checked against path integration (test_first_passage_pi)
def test_derivatives_take_the_likelihood_ratio_for_drift_and_differences_for_restitution():
    scene = jdpim.Scene(REF, noise=jdpim.WhiteNoise(D=0.03), t_end=10.0, dt=0.01)
    fp = jdpim.first_passage(scene, "x", [0.4, 0.8], jdpim.MonteCarlo(n_samples=4000, seed=0), wrt=("alpha", "r"))
    a, a_se = np.asarray(fp.derivative["alpha"]), np.asarray(fp.derivative_stderr["alpha"])
    r, r_se = np.asarray(fp.derivative["r"]), np.asarray(fp.derivative_stderr["r"])
    assert np.all(a < -2 * a_se) and np.all(r > 2 * r_se)  # more damping: fewer passages; bouncier: more
    dp = jdpim.first_passage(scene, "x", 0.4, jdpim.DPIM(n_points=200), wrt="r")
    assert dp.derivative_stderr is None and dp.derivative["r"].shape == (1, 1)


def test_estimators_that_do_not_apply_are_refused_in_one_line(passage):
    with pytest.raises(ValueError, match="LikelihoodRatio applies to drift parameters only, not 'r'"):
        jdpim.first_passage(PASSAGE_SCENE, "x", 0.4, PASSAGE_MC, wrt="r", estimator=jdpim.LikelihoodRatio())
    # refused when the question is asked, before any path runs
    with pytest.raises(ValueError, match="Pathwise does not estimate first-passage derivatives"):
        jdpim.first_passage(PASSAGE_SCENE, "x", LEVELS, PASSAGE_MC, wrt="alpha", estimator=jdpim.Pathwise())
    with pytest.raises(ValueError, match="whole history"):
        jdpim.first_passage(
            PASSAGE_SCENE, "x", 0.4, PASSAGE_MC, wrt="alpha", estimator=jdpim.LikelihoodRatio(window=5.0)
        )
    with pytest.raises(ValueError, match="whole history"):
        jdpim.first_passage(
            PASSAGE_SCENE, "x", 0.4, jdpim.SubsetSimulation(), wrt="alpha", estimator=jdpim.LikelihoodRatio(window=5.0)
        )


def test_probabilities_grow_with_time_fall_with_the_level_and_carry_binomial_errors(passage):
    fp, p = passage, np.asarray(passage.probability)
    assert p.shape == (4, 3) and np.all(p[0] == 0.0)  # from rest at the barrier: nothing has passed at t = 0
    assert np.all(np.diff(p, axis=0) >= 0) and np.all(np.diff(p, axis=1) <= 0)
    assert p[-1, 0] > 0.5 and 0.0 < p[-1, -1] < p[-1, 0]
    # float32: p near 1 is rounded to about 1e-6, which (1 - p)^2 turns into 0.5 % at p = 0.998
    np.testing.assert_allclose(np.asarray(fp.probability_stderr), np.sqrt(p * (1 - p) / 1000), rtol=1e-2, atol=1e-7)
    value, stderr = fp.at(2.0)
    np.testing.assert_array_equal(np.asarray(value), p[2])
    assert np.all(np.asarray(fp.lost_mass) == 0.0)
    dp = jdpim.first_passage(PASSAGE_SCENE, "x", LEVELS, jdpim.DPIM(n_points=300))
    assert dp.probability_stderr is None and dp.method == "dpim" and dp.at()[1] is None
    assert np.all(np.abs(np.asarray(dp.probability) - p) < 5 * np.asarray(fp.probability_stderr) + 0.02)


def test_a_function_of_the_state_and_several_degrees_of_freedom():
    """The damper mass's displacement relative to the primary never leaves its clearance of +-0.1."""
    scene = jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.01), t_end=10.0, dt=0.01)
    fp = jdpim.first_passage(scene, lambda s: s[1] - s[0], [0.05, 0.1 + 1e-5], jdpim.MonteCarlo(n_samples=200, seed=0))
    assert float(fp.probability[0, 0]) > 0.2 and float(fp.probability[0, 1]) == 0.0


def test_a_path_that_passes_before_it_diverges_counts_as_passed():
    """``x'' - 4 x = xi`` diverges on every path: those that went up passed the level before they diverged, the
    others are lost. Divergence is the densities' rule (beyond 1e6 times ``divergence_scale``, 6.6e7 in x here):
    a level beyond it is passed by no path, every path is lost, not passed by its blow-up."""
    model = jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], stiffness=[[-4.0]])
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.01), t_end=60.0, dt=0.01, save_at=(10.0, 60.0))
    with pytest.warns(jdpim.NonFiniteWarning, match="left out of FirstPassage.probability"):
        fp = jdpim.first_passage(scene, "x1", [1.0, 1e9], jdpim.MonteCarlo(n_samples=200, seed=0))
    p, lost = np.asarray(fp.probability), np.asarray(fp.lost_mass)
    assert 0.3 < p[0, 0] < 0.7
    np.testing.assert_allclose(p[1, 0], p[0, 0], atol=1e-6)  # the passed paths stay passed after they diverge
    np.testing.assert_allclose(p[1] + lost[1], [1.0, 1.0], atol=1e-5)  # by t = 60 every path has diverged
    np.testing.assert_array_equal(p[:, 1], [0.0, 0.0])


def test_another_noise_intensity_compiles_nothing(passage):
    """The divergence bound, which the noise intensity sets, is traced data of the running maximum, and the
    probabilities are one program per shape: a run at another ``D`` (a fragility curve's next point) compiles
    nothing."""
    with compiled_programs() as names:
        other = jdpim.first_passage(PASSAGE_SCENE.replace(noise=jdpim.WhiteNoise(D=0.05)), "x", LEVELS, PASSAGE_MC)
    assert names == []
    assert np.sum(other.probability) > np.sum(passage.probability)  # more noise, more passes: a real run


def test_the_result_passes_through_jit(passage):
    twice = jax.jit(lambda f: f.probability * 2.0)(passage)
    np.testing.assert_array_equal(np.asarray(twice), 2.0 * np.asarray(passage.probability))


SCENE = jdpim.Scene(REF, t_end=1.0, dt=0.01)
MC = jdpim.MonteCarlo(n_samples=10)
BAD = {
    "level-below-barrier": ((SCENE, "x", [-0.1, 0.2], MC), ValueError, r"level \[-0.1\] is at or below the lower"),
    "level-not-finite": ((SCENE, "x", [np.inf], MC), ValueError, "level must be finite"),
    "level-empty": ((SCENE, "x", [], MC), ValueError, "non-empty 1-D sequence"),
    "level-text": ((SCENE, "x", "high", MC), TypeError, "level must be a number"),
    "level-numeric-text": ((SCENE, "x", ["0.2"], MC), TypeError, "level must be a number"),
    "level-bool": ((SCENE, "x", True, MC), TypeError, "level must be a number"),
    "var-name": ((SCENE, "x1", 0.2, MC), ValueError, r"var must be one of the coordinates \('x', 'v'\)"),
    "var-shape": ((SCENE, lambda s: s, 0.2, MC), ValueError, r"var must return a scalar .* got shape \(2,\)"),
    "method-class": ((SCENE, "x", 0.2, jdpim.MonteCarlo), TypeError, "method must be a jdpim method object"),
    "scene": (("scene", "x", 0.2, MC), TypeError, "scene must be a jdpim.Scene"),
    "wrt-unknown": ((SCENE, "x", 0.2, MC, "beta"), ValueError, "unknown parameter 'beta'"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_fails_in_one_clear_line(case):
    args, kind, message = BAD[case]
    with pytest.raises(kind, match=message):
        jdpim.first_passage(*args[:4], wrt=args[4] if len(args) > 4 else ())


def test_an_empty_saved_grid_fails_in_one_line():
    with pytest.raises(ValueError, match="save_at must be a non-empty 1-D sequence of times"):
        jdpim.Scene(REF, t_end=1.0, dt=0.01, save_at=())


def test_dpim_replicates_give_their_mean_and_its_standard_error(passage):
    """``replicates=R``: R DPIM runs on randomised point sets, averaged, with the standard error of the mean; against
    the Monte Carlo run of the same scene and levels (``passage``)."""
    scene, levels, method, R = PASSAGE_SCENE, LEVELS, jdpim.DPIM(n_points=100), 8
    fp = jdpim.first_passage(scene, "x", levels, method, wrt="alpha", replicates=R)
    runs = [jdpim.first_passage(scene, "x", levels, method.replicate(scene, k), wrt="alpha") for k in range(R)]
    for value, stderr, each in (
        (fp.probability, fp.probability_stderr, [r.probability for r in runs]),
        (fp.derivative["alpha"], fp.derivative_stderr["alpha"], [r.derivative["alpha"] for r in runs]),
    ):
        each = np.stack([np.asarray(e) for e in each])
        np.testing.assert_allclose(value, each.mean(0), rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(stderr, each.std(0, ddof=1) / np.sqrt(R), rtol=1e-4, atol=1e-7)
    p, se = np.asarray(fp.probability), np.asarray(fp.probability_stderr)
    assert fp.n_replicates == R and fp.method == "dpim" and np.all(se[(p > 0) & (p < 1)] > 0)
    assert np.all(p[0] == 0.0) and np.sum((p > 0) & (p < 1)) >= 6  # from rest at the barrier: none passed at t = 0
    mc = passage
    # the standard error of 8 replicates has 7 degrees of freedom: 5.4 is t_7's two-sided 0.1 % point; the
    # replicates measure DPIM's sampling error, and its two-variable random functions add a difference of their
    # own (measured 0.005 to 0.013 below Monte Carlo at t = 1 to 10 s, 16 x 1000 points)
    mc_se = np.asarray(mc.probability_stderr)
    assert np.all(np.abs(p - np.asarray(mc.probability)) <= 5.4 * np.hypot(se, mc_se) + 0.015)


@pytest.mark.parametrize(
    "method, replicates, kind, match",
    [
        (jdpim.MonteCarlo(n_samples=100), 2, ValueError, "replicates apply to jdpim.DPIM"),
        (jdpim.DPIM(n_points=100), 1, ValueError, "replicates"),
        (jdpim.DPIM(n_points=100), 2.5, TypeError, "replicates"),
    ],
)
def test_replicates_refused_in_one_line(method, replicates, kind, match):
    with pytest.raises(kind, match=match) as info:
        jdpim.first_passage(SCENE, "x", 0.2, method, replicates=replicates)
    assert "\n" not in str(info.value)


def test_raw_grad_through_sampled_probabilities_warns_that_it_is_zero():
    """``jax.grad`` through a Monte Carlo first-passage probability differentiates indicators: zero, and warned."""
    scene = jdpim.Scene(REF, noise=jdpim.WhiteNoise(D=0.03), t_end=1.0, dt=0.01, x0=0.3)

    def p(alpha):
        s = jdpim.with_parameters(scene, {"alpha": alpha})
        return jdpim.first_passage(s, "x", 0.35, jdpim.MonteCarlo(n_samples=64, seed=0)).probability[-1, 0]

    with pytest.warns(jdpim.SensitivityWarning, match="counted over sampled paths"):
        assert float(jax.grad(p)(0.03)) == 0.0
