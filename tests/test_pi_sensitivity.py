"""Sensitivities by path integration (``jax.jacfwd`` through ``jdpim.path_integration``) and the method choice.

Exact reference: r = 1, no cubic damping: the folded Gaussian with the variance of
``jdpim.exact.linear_covariance`` (``D / alpha`` at stationarity); smoothing with the reflected kernel of
width ``h`` adds ``h^2`` to the variance, so the derivatives of the smoothed density are closed-form.
"""

import dataclasses

import numpy as np
import pytest
from test_first_solve import compiled_programs

import jdpim
from jdpim import exact

ALPHA, D, T, H = 0.1, 0.05, 10.0, 0.1
XS = np.linspace(0.0, 2.0, 41)
SETTINGS = jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1)


def _exact_derivative(name, t):
    def smoothed(a, d):
        s2 = (d / a if np.isinf(t) else exact.linear_covariance(a, d, t)[0]) + H**2
        return 2 * np.exp(-0.5 * XS**2 / s2) / np.sqrt(2 * np.pi * s2)

    e = 1e-6
    if name == "alpha":
        return (smoothed(ALPHA + e, D) - smoothed(ALPHA - e, D)) / (2 * e)
    return (smoothed(ALPHA, D + e) - smoothed(ALPHA, D - e)) / (2 * e)


@pytest.fixture(scope="module")
def elastic():
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, r=1.0)
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=T, dt=0.05)


@pytest.mark.parametrize("stationary", [False, True])
def test_path_integration_matches_the_exact_derivative(elastic, stationary):
    # Measured (float32, 61 x 121 nodes, tau = 0.1): relative L2 error 1.0e-3 (alpha) and 2.0e-3 (D) at t = 10,
    # 6.7e-4 and 9.9e-4 stationary: the grid's error, there is no sampling error.
    t = np.inf if stationary else T
    kw = {"method": dataclasses.replace(SETTINGS, stationary=True)} if stationary else {"t": T, "method": SETTINGS}
    out = jdpim.sensitivity(elastic, ("alpha", "D"), "x", XS, bandwidth=H, **kw)
    assert out.method == "path_integration" and out.times == (t,)
    for name in ("alpha", "D"):
        ref = _exact_derivative(name, t)
        rel = np.linalg.norm(out[name] - ref) / np.linalg.norm(ref)
        assert rel < 5e-3, (name, rel)
        assert np.all(np.asarray(out.value_stderr[name]) == 0.0)  # no sampling error
        assert out.estimators[name].x_max is not None and out.estimators[name].order == 4


def test_unsmoothed_derivative_is_that_of_the_grid_density(elastic):
    """``bandwidth=None``: the derivative of ``GridResult.pdf``, interpolated to the user's grid.

    Measured: relative L2 error 7.4e-4 (alpha) and 1.1e-3 (D) against the unsmoothed exact derivative.
    """
    out = jdpim.sensitivity(elastic, ("alpha", "D"), "x", XS, method=dataclasses.replace(SETTINGS, stationary=True))
    e = 1e-6
    for name, (lo, hi) in {
        "alpha": (D / (ALPHA - e), D / (ALPHA + e)),
        "D": ((D - e) / ALPHA, (D + e) / ALPHA),
    }.items():
        pdf = [2 * np.exp(-0.5 * XS**2 / s2) / np.sqrt(2 * np.pi * s2) for s2 in (lo, hi)]
        ref = (pdf[1] - pdf[0]) / (2 * e)
        rel = np.linalg.norm(out[name] - ref) / np.linalg.norm(ref)
        assert rel < 5e-3, (name, rel)


def test_the_method_choice(elastic):
    """method=None: path integration where it accepts the scene; Monte Carlo where a sampling estimator is asked for."""
    short = jdpim.Scene(elastic.model, noise=elastic.noise, t_end=0.5, dt=0.05)  # which method, not its accuracy
    out = jdpim.sensitivity(short, ("alpha",), "x", XS, bandwidth=H, estimator=jdpim.LikelihoodRatio())
    assert out.method == "monte_carlo" and out.estimators["alpha"] == jdpim.LikelihoodRatio()
    with pytest.raises(TypeError, match=r"method must be None or a jdpim method"):
        jdpim.sensitivity(elastic, ("alpha",), "x", XS, method="path_integration")


def test_path_integration_refusals(elastic):
    kw = {"bandwidth": H, "method": SETTINGS}
    with pytest.raises(ValueError, match="estimator is for the sampling methods"):
        jdpim.sensitivity(elastic, ("alpha",), "x", XS, estimator=jdpim.LikelihoodRatio(), **kw)
    with pytest.raises(ValueError, match="leave t out"):
        jdpim.sensitivity(elastic, ("alpha",), "x", XS, T, bandwidth=H, method=jdpim.PathIntegration(stationary=True))
    with pytest.raises(ValueError, match="bandwidth=None"):
        jdpim.sensitivity(elastic, ("alpha",), "x", XS, bandwidth="adaptive", method=jdpim.PathIntegration())
    with pytest.raises(ValueError, match=r"bandwidth must lie in \(0, inf\)"):
        jdpim.sensitivity(elastic, ("alpha",), "x", XS, bandwidth=-0.1, method=SETTINGS)
    with pytest.raises(TypeError, match="jdpim.PathIntegration"):
        jdpim.sensitivity(elastic, ("alpha",), "x", XS, method={"n_x": 61})
    random = elastic.replace(random=(("alpha", jdpim.Uniform(0.05, 0.15)),))
    with pytest.raises(ValueError, match="random parameters"):  # path integration's own refusal
        jdpim.sensitivity(random, ("D",), "x", XS, bandwidth=H, method=jdpim.PathIntegration())


def test_auto_falls_back_to_monte_carlo_where_path_integration_refuses():
    """t = 0.2 lies before path integration's earliest default start ``t0 = 0.25``: ``method='auto'`` samples."""
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, barrier=None)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=0.2, dt=0.05)
    out = jdpim.sensitivity(scene, ("alpha",), "x", np.linspace(-0.3, 0.3, 5), bandwidth=0.1)
    assert out.method == "monte_carlo" and isinstance(out.estimators["alpha"], jdpim.Pathwise)


def test_an_unresolved_diffusion_step_is_flagged_for_d(elastic):
    """dp/dD needs one step's diffusion to span enough velocity nodes (measured: 4 % error at 0.67 spacings)."""
    from types import SimpleNamespace

    from jdpim.sensitivities._path_integration import check_noise_resolution

    nodes = SimpleNamespace(
        x=np.linspace(0.0, 2.0, 5, dtype=np.float32), v=np.linspace(-1.0, 1.0, 21, dtype=np.float32)
    )
    check_noise_resolution(elastic, jdpim.PathIntegration(tau=0.2), nodes)  # sqrt(0.05 * 0.2) = 0.1: 1 spacing
    with pytest.warns(jdpim.SensitivityWarning, match="raise n_v or tau"):
        check_noise_resolution(elastic, jdpim.PathIntegration(tau=0.1), nodes)  # 0.71 spacings


@pytest.mark.slow
def test_default_call_at_stationarity_and_energy_dependent_damping():
    """The issue's acceptance cases with the defaults (about a minute on 2 cores).

    Measured (float32, default grid, h = 0.1, x in [0, 3]): r = 1, alpha = D = 0.05, t = 200: relative L2 error
    1.5e-4 (alpha) and 2.2e-4 (D); ``(alpha + beta H) x'``, alpha = beta = D = 0.05: 2.1e-4 (beta).
    """
    a, d, b, t, h = 0.05, 0.05, 0.05, 200.0, 0.1
    xs = np.linspace(0.0, 3.0, 61)
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(alpha=a, gamma=None, r=1.0), noise=jdpim.WhiteNoise(D=d), t_end=t)
    out = jdpim.sensitivity(scene, ("alpha", "D"), "x", xs, bandwidth=h)
    assert out.method == "path_integration"
    e = 1e-6
    for name, (lo, hi) in {"alpha": ((a - e, d), (a + e, d)), "D": ((a, d - e), (a, d + e))}.items():
        pdf = []
        for aa, dd in (lo, hi):
            s2 = exact.linear_covariance(aa, dd, t)[0] + h**2
            pdf.append(2 * np.exp(-0.5 * xs**2 / s2) / np.sqrt(2 * np.pi * s2))
        ref = (pdf[1] - pdf[0]) / (2 * e)
        assert np.linalg.norm(out[name] - ref) / np.linalg.norm(ref) < 2e-3, name

    model = jdpim.Oscillator(
        params={"alpha": a, "beta": b},
        g=lambda x, p: x,
        f=lambda x, v, p: (p["alpha"] + p["beta"] * (0.5 * v**2 + 0.5 * x**2)) * v,
        r=1.0,
    )
    out = jdpim.sensitivity(scene.replace(model=model), ("beta",), "x", xs, bandwidth=h)
    u, vv = np.linspace(0, 8, 2001), np.linspace(-8, 8, 2001)

    def reference(beta):
        X, V = np.meshgrid(u, vv, indexing="ij")
        H_ = 0.5 * X**2 + 0.5 * V**2
        px = np.trapezoid(np.exp(-(a * H_ + beta * H_**2 / 2) / d), vv, axis=1)
        px /= np.trapezoid(px, u)
        z = lambda s: np.exp(-0.5 * (s / h) ** 2) / (h * np.sqrt(2 * np.pi))  # noqa: E731
        return np.trapezoid((z(xs[:, None] - u) + z(xs[:, None] + u)) * px, u, axis=1)

    ref = (reference(b + 1e-5) - reference(b - 1e-5)) / 2e-5
    assert np.linalg.norm(out["beta"] - ref) / np.linalg.norm(ref) < 2e-3


def test_joint_derivative_integrates_to_the_marginal(elastic):
    """The same nodal density and kernels: integrating ``dp(x, v)`` over ``v`` gives ``dp(x)``."""
    vg = np.linspace(-4.0, 4.0, 161)
    kw = {"method": dataclasses.replace(SETTINGS, stationary=True)}
    joint = jdpim.sensitivity(elastic, ("alpha", "D"), "xv", (XS, vg), bandwidth=(H, 0.15), **kw)
    marginal = jdpim.sensitivity(elastic, ("alpha", "D"), "x", XS, bandwidth=H, **kw)
    for name in ("alpha", "D"):
        assert joint[name].shape == (XS.size, vg.size)
        integral = np.trapezoid(np.asarray(joint[name]), vg, axis=1)
        np.testing.assert_allclose(integral, marginal[name], atol=2e-3 * np.abs(marginal[name]).max())


# slow: the default tier checks the transient derivative against the exact one in
# test_path_integration_matches_the_exact_derivative[False], the settings picked below t = 10 in
# test_short_horizons_pick_an_earlier_finer_start and the start's warning in
# test_short_horizons_after_the_point_start_are_flagged
@pytest.mark.slow
def test_short_horizons_default_to_an_earlier_finer_start():
    """Below t = 10 the default start is t0 = 0.25 on 241 x 481 nodes (tau = 0.025); still exact for r = 1.

    Measured (float32, t = 2, h = 0.1): relative L2 error 7e-5 (alpha) and 8e-5 (D) against the exact derivative.
    """
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, r=1.0)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=2.5, dt=0.05)
    out = jdpim.sensitivity(scene, ("alpha", "D"), "x", XS, bandwidth=H)  # no warning: the start is resolved
    used = out.estimators["alpha"]
    assert out.method == "path_integration" and (used.t0, used.n_x, used.n_v, used.tau) == (0.25, 241, 481, 0.025)
    for name in ("alpha", "D"):
        ref = _exact_derivative(name, 2.5)
        assert np.linalg.norm(out[name] - ref) / np.linalg.norm(ref) < 1e-3, name


def test_short_horizons_pick_an_earlier_finer_start():
    """The settings a default call takes: t0 = 0.25 on 241 x 481 nodes below t = 10 (transient only)."""
    from jdpim.sensitivities._path_integration import default_settings

    assert default_settings(2.5) == jdpim.PathIntegration(t0=0.25, n_x=241, n_v=481, tau=0.025)
    assert default_settings(10.0) == default_settings(2.5, stationary=True) == jdpim.PathIntegration()


def test_one_solve_program_and_the_nominal_warnings(elastic):
    """A derivative by path integration compiles one solve (its primal is the nominal density, no separate nominal
    solve), and reports that density's ``PathIntegrationWarning``: here mass reaches the edges of a too small grid."""
    settings = jdpim.PathIntegration(n_x=17, n_v=33, x_max=0.5, v_max=0.5, tau=0.1, order=2)  # no other test uses it
    with compiled_programs() as programs, pytest.warns(jdpim.PathIntegrationWarning, match="reached the grid's edges"):
        with pytest.warns(jdpim.SensitivityWarning, match="within 10 x t0"):  # t = 1.2 right after the start
            out = jdpim.sensitivity(elastic.replace(save_at=(1.2,)), ("alpha",), "x", XS, bandwidth=H, method=settings)
    assert np.all(np.isfinite(out["alpha"]))
    assert [n for n in programs if "_transient" in n] == ["jit(_transient)"]


def test_short_horizons_after_the_point_start_are_flagged():
    """The linearised start at t0 moved dp/dgamma and dp/dr by 5-8 % at t = 5 (reference scene, t0 = 1)."""
    from jdpim.sensitivities._path_integration import check_start

    check_start(10.0, jdpim.PathIntegration())
    check_start(2.5, jdpim.PathIntegration(t0=0.25, tau=0.025))
    with pytest.warns(jdpim.SensitivityWarning, match="t0=0.25"):
        check_start(5.0, jdpim.PathIntegration())
