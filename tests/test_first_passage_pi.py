"""First passage by path integration (absorbing boundary): against Monte Carlo on the reference scene, exact
bounds on the elastic linear oscillator, and one-line errors for bad input.

Grids are small (compile time dominates); ``x_max``/``v_max`` are set a little past the largest level, where
the absorbed density lives, rather than the scene's default extents.
"""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.linalg import expm
from scipy.stats import multivariate_normal
from test_first_solve import compiled_programs

import jdpim
from jdpim import exact

SAVE_AT = (5.0, 10.0)
LEVELS = np.array([0.3, 0.5, 0.7])


def reference_scene():
    return jdpim.Scene(
        jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=10.0, dt=0.01, save_at=SAVE_AT
    )


@pytest.fixture(scope="module")
def reference():
    scene = reference_scene()
    settings = jdpim.PathIntegration(n_x=121, n_v=241, x_max=1.6, v_max=1.6, t0=0.25, estimate_error=True)
    pi = jdpim.first_passage(scene, "x", LEVELS, settings, wrt="alpha")
    mc = jdpim.first_passage(scene, "x", LEVELS, jdpim.MonteCarlo(n_samples=20_000, seed=0), wrt="alpha")
    return pi, mc


def test_reference_scene_defaults():
    model = jdpim.VibroImpactOscillator()
    assert (model.alpha, model.gamma, model.r, model.barrier) == (0.03, 0.03, 0.98, 0.0)


# slow: the default tier checks the absorbing solver's probabilities against exact bounds (and its grid error) in
# test_elastic_linear_exact_bounds, its forward-mode derivatives against central differences of the same solver
# (alpha, r, D) in test_derivatives_equal_differences_of_the_same_solver, and the likelihood ratio against the exact
# dP/dmu in test_first_passage::test_brownian_velocity_with_drift_passes_and_its_derivatives_as_exactly_known.
@pytest.mark.slow
def test_agrees_with_monte_carlo(reference):
    pi, mc = reference
    assert pi.method == "path_integration" and pi.probability_stderr is None and pi.times == SAVE_AT
    assert pi.probability.shape == pi.grid_error.shape == (2, 3) and np.all(np.asarray(pi.lost_mass) == 0)
    p, err = np.asarray(pi.probability), np.asarray(pi.grid_error)
    p_mc, se = np.asarray(mc.probability), np.asarray(mc.probability_stderr)
    used = (p_mc > 0.01) & (p_mc < 0.9)
    assert used.sum() >= 4
    assert np.all(err[used] < 0.05)  # the grid error stated is small enough to make the comparison a test
    assert np.all(np.abs(p - p_mc)[used] <= 4 * se[used] + err[used])


@pytest.mark.slow  # as test_agrees_with_monte_carlo: the same Monte Carlo reference run
def test_derivative_agrees_with_the_likelihood_ratio(reference):
    """dP/dalpha by forward-mode AD through the absorbed steps against Monte Carlo's likelihood ratio (measured:
    within 1.5 standard errors at every level and time)."""
    pi, mc = reference
    d, d_mc, se = (np.asarray(a["alpha"]) for a in (pi.derivative, mc.derivative, mc.derivative_stderr))
    assert d.shape == (2, 3) and pi.derivative_stderr is None
    assert np.all(d < 0) and np.all(se < 0.2 * np.abs(d_mc))  # more damping, fewer passages; a resolving test
    assert np.all(np.abs(d - d_mc) <= 3 * se)


NAMES, NOMINAL = ("alpha", "r", "D"), {"alpha": 0.03, "r": 0.98, "D": 0.03}  # the reference scene's values


@pytest.fixture(scope="module")
def float64_case():
    """``(scene, settings, levels, fp)``: a small float64 case with ``dP/dalpha``, ``dP/dr``, ``dP/dD`` (one solver
    against itself: its programs serve both tests below)."""
    with jax.enable_x64(True):
        scene = reference_scene().replace(save_at=(10.0,), dtype="float64")
        settings = jdpim.PathIntegration(n_x=41, n_v=81, x_max=1.6, v_max=1.6, order=4)  # r traced: order given
        levels = [0.3, 0.6]
        return scene, settings, levels, jdpim.first_passage(scene, "x", levels, settings, wrt=NAMES)


def test_derivatives_equal_differences_of_the_same_solver(float64_case):
    """AD differentiates the discrete absorbed solver exactly: central differences of it agree (float64), for a
    drift parameter, the restitution and the noise intensity."""
    scene, settings, levels, fp = float64_case
    with jax.enable_x64(True):
        for name, h in (("alpha", 1e-4), ("r", 1e-4), ("D", 1e-5)):
            value = NOMINAL[name]
            up, down = (
                jdpim.first_passage(jdpim.with_parameters(scene, {name: value + dh}), "x", levels, settings).probability
                for dh in (h, -h)
            )
            np.testing.assert_allclose(fp.derivative[name], (up - down) / (2 * h), rtol=1e-5, err_msg=name)


def test_raw_jacfwd_equals_the_derivative_of_wrt(float64_case):
    """``jax.jacfwd`` of ``first_passage(...).probability`` by path integration, as a user writes it (parameters as
    Python numbers, weakly typed under ``jacfwd``), gives ``FirstPassage.derivative``, by the program that computed
    it: no solve is compiled again."""
    scene, settings, levels, fp = float64_case

    def p(values):
        return jdpim.first_passage(jdpim.with_parameters(scene, values), "x", levels, settings).probability

    with jax.enable_x64(True), compiled_programs() as names:
        raw = jax.jacfwd(p)(dict(NOMINAL))
    assert "jit(_survival)" not in names, names
    for name in NAMES:
        np.testing.assert_allclose(raw[name], fp.derivative[name], rtol=1e-5, err_msg=name)


JIT_SETTINGS = jdpim.PathIntegration(n_x=41, n_v=81, x_max=1.6, v_max=1.6, order=4)  # r traced: order given
JIT_LEVELS = [0.5, 1.0]


def _traced_scene(name, value):
    """The reference model from rest over 2 s with ``name`` set to ``value`` (``"gains"``: a general oscillator
    whose noise gain is ``value``)."""
    if name == "gains":
        model = jdpim.Oscillator(
            g=lambda x, p: x, f=lambda x, v, p: 0.1 * v, h=lambda x, v, p: p["c"] * jnp.ones(()), params={"c": value}
        )
    elif name == "D":
        model = jdpim.VibroImpactOscillator()
    else:
        model = jdpim.VibroImpactOscillator(**{name: value})
    noise = jdpim.WhiteNoise(D=value if name == "D" else 0.03)
    return jdpim.Scene(model, noise=noise, t_end=2.0, dt=0.02)


SLOW_CELL = pytest.mark.slow  # alpha and gains, in the default tier, check the host grid and the skipped gain check


@pytest.mark.parametrize(
    "name, value",
    [("alpha", 0.03), pytest.param("r", 0.98, marks=SLOW_CELL), pytest.param("D", 0.03, marks=SLOW_CELL)]
    + [("gains", 1.0)],
)
def test_jit_over_a_traced_parameter_is_the_direct_call(name, value):
    """``jax.jit`` of ``first_passage(...).probability`` with a traced model parameter and given extents: the grid,
    the absorbed fractions and the level checks depend on the extents and sizes only and are computed on the host,
    so the probabilities are the direct call's to float32 rounding of ``1 - survival``, the two programs fusing
    differently (measured: up to 4e-7 on grids of 41 x 81 to 121 x 241; before, reading the grid raised
    ``ConcretizationTypeError``, and for traced gains the resolution check did)."""

    def p(value):
        return jdpim.first_passage(_traced_scene(name, value), "x", JIT_LEVELS, JIT_SETTINGS).probability

    direct, inside = np.asarray(p(value)), np.asarray(jax.jit(p)(value))
    assert direct[0, 0] > 0.01  # level 0.5 is passed: a comparison of more than rounding
    np.testing.assert_allclose(inside, direct, rtol=0, atol=1e-6)


def _warned(f, value):
    """``(f(value), the first words of the warnings it gave)``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = np.asarray(f(value))
    return out, sorted(str(w.message).split(":")[0] for w in caught)


# gains: slow (test_jit_over_a_traced_parameter_is_the_direct_call[gains] checks the skipped gain check by default)
@pytest.mark.parametrize("name, value", [("alpha", 0.03), pytest.param("gains", 1.0, marks=pytest.mark.slow)])
def test_jit_over_a_derivative_of_d_is_the_direct_call(name, value):
    """``wrt="D"`` under ``jax.jit`` with a traced parameter: the check of the grid's velocity resolution for
    ``dP/dD`` reads the grid on the host and warns as the direct call does (61 velocity nodes: too few), or is
    skipped where the noise gain it needs is traced; the derivatives are the direct call's to float32 rounding
    (measured: 1e-6 relative; before, each raised ``ConcretizationTypeError``)."""
    settings = jdpim.PathIntegration(n_x=41, n_v=61, x_max=1.6, v_max=1.6, order=4)

    def dp(value):
        return jdpim.first_passage(_traced_scene(name, value), "x", JIT_LEVELS, settings, wrt="D").derivative["D"]

    (direct, said), (inside, said_inside) = _warned(dp, value), _warned(jax.jit(dp), value)
    resolution = "dp/dD by path integration"
    assert resolution in said and any("within 10 x t0" in s for s in said)  # t = 2 s is near the point start too
    assert said_inside == (said if name == "alpha" else [s for s in said if s != resolution])
    np.testing.assert_allclose(inside, direct, rtol=0, atol=1e-5 * np.max(np.abs(direct)))


@pytest.mark.parametrize(
    "name, var, settings, match",
    [
        ("barrier", "x", JIT_SETTINGS, "starts its grid at the barrier, so the barrier cannot be traced"),
        ("D", "v", JIT_SETTINGS, "checked against the grid's velocity end .* but D is traced"),
        ("alpha", "x", jdpim.PathIntegration(n_x=41, n_v=81), "but alpha is traced .* give x_max and v_max"),
        ("shift", None, JIT_SETTINGS, "var depends on a traced value"),
    ],
)
def test_what_jit_cannot_trace_fails_in_one_line(name, var, settings, match):
    """What sets the grid or its checks cannot be traced: the barrier (the grid starts there), D for a level of v
    (the level's distance from the grid's end is checked against a step's diffusion), the extents estimated from
    the parameters, a quantity closing over a traced value; each is refused in one line before the solve."""

    def p(value):
        if name == "shift":
            return jdpim.first_passage(_traced_scene("alpha", 0.03), lambda s: s[0] + value, 0.5, settings).probability
        return jdpim.first_passage(_traced_scene(name, value), var, 0.5, settings).probability

    with pytest.raises(ValueError, match=match) as info:
        jax.jit(p)(0.0 if name in ("barrier", "shift") else 0.03)
    assert "\n" not in str(info.value)


@pytest.mark.slow  # test_elastic_linear_exact_bounds checks the same monotonicity in the default tier
def test_monotone_in_time_and_level(reference):
    p = np.asarray(reference[0].probability)
    assert np.all(p >= -1e-6) and np.all(p <= 1 + 1e-6)
    assert np.all(np.diff(p, axis=0) >= -1e-6)  # later: more has passed
    assert np.all(np.diff(p, axis=1) <= 1e-6)  # higher level: less has passed


def _discrete_maximum(alpha, D, level, times):
    """``P(max_k |y(t_k)| > level)`` for the linear oscillator ``y'' + alpha y' + y = xi`` from rest (exact Gaussian
    law of ``y`` at the times; a multivariate normal rectangle)."""
    A = np.array([[0.0, 1.0], [-1.0, -alpha]])
    n = len(times)
    cov = np.empty((n, n))
    for i, a in enumerate(times):
        sx2, sv2, cxv = exact.linear_covariance(alpha, D, a)
        for j in range(i, n):  # Cov(Y(b), Y(a)) = exp(A (b - a)) C(a)
            cov[i, j] = cov[j, i] = (expm(A * (times[j] - a)) @ np.array([[sx2, cxv], [cxv, sv2]]))[0, 0]
    law = multivariate_normal(cov=cov, abseps=1e-5, releps=1e-4, maxpts=20_000 * n, seed=0)
    return 1.0 - law.cdf(np.full(n, level), lower_limit=np.full(n, -level))


def test_elastic_linear_exact_bounds():
    """r = 1 and linear damping: ``x = |y|`` with ``y`` the linear oscillator's Gaussian response, so that
    ``P(max_k x(t_k) > l) <= P_f(t) <= int_0^t nu+(s) ds``: the maximum over times ``t_k <= t`` (exact, a
    multivariate normal) below, Rice's expected number of upcrossings (exact transient joint density) above.

    In float64: at x = 0.7, t = 5 the probability lies within 2e-6 of the upper bound plus its grid error, and
    float32's ``1 - survival`` after 80 steps moves by 2e-6 when the nodes' last bits move."""
    alpha, D = 0.1, 0.01
    levels = np.array([0.3, 0.5, 0.7, 0.85])
    settings = jdpim.PathIntegration(n_x=121, n_v=241, x_max=1.0, v_max=1.0, estimate_error=True)
    with jax.enable_x64(True):
        model = jdpim.VibroImpactOscillator(alpha=alpha, gamma=0.0, r=1.0)
        scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=10.0, dt=0.01, save_at=SAVE_AT, dtype="float64")
        fp = jdpim.first_passage(scene, "x", levels, settings)
        p, err = np.asarray(fp.probability), np.asarray(fp.grid_error)
    assert np.all(p >= -1e-6) and np.all(p <= 1 + 1e-6)
    assert np.all(np.diff(p, axis=0) >= -1e-6)  # later: more has passed
    assert np.all(np.diff(p, axis=1) <= 1e-6)  # higher level: less has passed
    s, v = np.linspace(0.0, 10.0, 401)[1:], np.linspace(0.0, 3.0, 1501)
    joint = [[exact.elastic_linear_joint_pdf([lv], v, alpha, D, t)[0] for t in s] for lv in levels]
    nu = np.trapezoid(v * np.array(joint), v, axis=-1)  # (levels, times): upcrossing rate of each level
    for i, t in enumerate(SAVE_AT):
        k = s <= t
        upper = np.trapezoid(nu[:, k], s[k], axis=1)
        if t == 5.0:  # every eighth of a period of |y|: 13 times, tight (measured: within 2 % of P_f)
            lower = np.array([_discrete_maximum(alpha, D, lv, np.arange(t, 0.0, -math.pi / 8)[::-1]) for lv in levels])
        else:  # the tail at the latest time: weak, but absorption must exceed it clearly
            lower = np.array([math.erfc(lv / math.sqrt(2 * exact.linear_covariance(alpha, D, t)[0])) for lv in levels])
            assert np.all(p[i, :3] > 2 * lower[:3])
        assert np.all(p[i] <= upper + err[i] + 1e-6)
        assert np.all(p[i] >= lower - err[i] - 1e-4)
    assert abs(p[0, -1]) < 1e-4  # x = 0.85 (4.2 sd at t = 5) is not reached by t = 5


@pytest.mark.parametrize(
    "settings, var, level, match",
    [
        (jdpim.PathIntegration(stationary=True), "x", 0.5, r"stationary=True\) cannot compute first-passage"),
        (jdpim.PathIntegration(n_x=61, n_v=121, x_max=1.0, v_max=1.0), "x", 1.2, r"level \[1.2\] is not exceeded"),
        (jdpim.PathIntegration(n_x=61, n_v=121, x_max=1.0, v_max=1.0), "x", 0.95, r"level \[0.95\] of 'x' lies within"),
        (jdpim.PathIntegration(n_x=61, n_v=121, x_max=1.0, v_max=1.0), "v", 0.9, r"level \[0.9\] of 'v' lies within"),
        (jdpim.PathIntegration(n_x=61, n_v=121, x_max=1.0, v_max=1.0), lambda s: s[0] * s[1], 2.0, "not exceeded"),
    ],
)
def test_bad_input_fails_in_one_line(settings, var, level, match):
    with pytest.raises(ValueError, match=match) as info:
        jdpim.first_passage(reference_scene(), var, level, settings)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "wrt, estimator, match",
    [
        ("barrier", None, "respect to the barrier"),
        ("alpha", jdpim.CentralDifference(), "estimator is for the sampling"),
    ],
)
def test_derivatives_refused(wrt, estimator, match):
    with pytest.raises(ValueError, match=match) as info:
        jdpim.first_passage(reference_scene(), "x", 0.5, jdpim.PathIntegration(), wrt=wrt, estimator=estimator)
    assert "\n" not in str(info.value)


def test_several_degrees_of_freedom_refused():
    scene = jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.03), t_end=1.0, dt=0.01)
    with pytest.raises(ValueError, match="needs a one-degree-of-freedom scene.*MonteCarlo") as info:
        jdpim.first_passage(scene, "x1", 0.5, jdpim.PathIntegration())
    assert "\n" not in str(info.value)
