"""Bounded sensitivity estimators (likelihood ratio, noise scaling, central differences) and the warning.

Exact references: the free linear oscillator from rest is Gaussian with the variance of
``jdpim.exact.linear_covariance``; with the barrier at 0 and r = 1 it is the folded Gaussian. Smoothing
with a Gaussian (reflected) kernel of fixed width ``h`` adds ``h^2`` to the variance, so the derivatives of
the smoothed density are closed-form.
"""

import numpy as np
import pytest

import jdpim
from jdpim import exact
from jdpim._integrate import ImpactRule, Sums, integrate
from jdpim.sensitivities._estimators import (
    CentralDifference,
    LikelihoodRatio,
    NoiseScaling,
    Pathwise,
    SensitivityWarning,
)
from jdpim.sensitivities._sensitivity import _score_settings

ALPHA, D, T, H = 0.2, 0.05, 6.0, 0.15
XS = np.linspace(-1.2, 1.2, 25)


def _smoothed(alpha, d, xs=XS, t=T, folded=False):
    s2 = exact.linear_covariance(alpha, d, t)[0] + H**2
    p = np.exp(-0.5 * xs**2 / s2) / np.sqrt(2 * np.pi * s2)
    return 2 * p if folded else p


def _exact_derivative(name, **kw):
    e = 1e-6
    if name == "alpha":
        return (_smoothed(ALPHA + e, D, **kw) - _smoothed(ALPHA - e, D, **kw)) / (2 * e)
    return (_smoothed(ALPHA, D + e, **kw) - _smoothed(ALPHA, D - e, **kw)) / (2 * e)


@pytest.fixture(scope="module")
def free():
    """The free linear oscillator (no barrier: cheap to compile), Monte Carlo, every bounded estimator."""
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, barrier=None)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=T, dt=0.02)
    est = {"alpha": LikelihoodRatio(), "D": NoiseScaling()}
    lr = jdpim.sensitivity(
        scene, ("alpha", "D"), "x", XS, bandwidth=H, estimator=est, method=jdpim.MonteCarlo(n_samples=4000)
    )
    cd = jdpim.sensitivity(
        scene, ("alpha",), "x", XS, bandwidth=H, estimator=CentralDifference(), method=jdpim.MonteCarlo(n_samples=4000)
    )
    return scene, lr, cd


@pytest.mark.parametrize("name", ["alpha", "D"])
def test_bounded_estimators_match_the_exact_derivative(free, name):
    # Measured (4000 paths): relative L2 error 0.074 (alpha, likelihood ratio; standard error 0.067), 0.067
    # (D, noise scaling; standard error 0.068); every grid point within 3 standard errors.
    _, lr, _ = free
    ref = _exact_derivative(name)
    value, err = np.asarray(lr[name]), np.asarray(lr.value_stderr[name])
    rel = np.linalg.norm(value - ref) / np.linalg.norm(ref)
    rel_err = np.linalg.norm(err) / np.linalg.norm(ref)
    assert 0 < rel_err < 0.15
    assert rel < 3 * rel_err
    assert np.mean(np.abs(value - ref) < 3 * err + 1e-3 * np.abs(ref).max()) > 0.9  # pointwise consistency


def test_central_differences_with_common_random_numbers(free):
    # Measured (4000 paths, float32, step 0.01): relative L2 error 0.058, standard error 0.082 of the norm
    # (pathwise-like variance ~ 1/h^3: larger than the likelihood ratio's at this bandwidth).
    _, _, cd = free
    ref = _exact_derivative("alpha")
    rel = np.linalg.norm(cd["alpha"] - ref) / np.linalg.norm(ref)
    rel_err = np.linalg.norm(cd.value_stderr["alpha"]) / np.linalg.norm(ref)
    assert rel < 0.15 and rel < 3 * rel_err
    assert isinstance(cd.estimators["alpha"], CentralDifference) and cd.times == (T,)


def test_auto_and_the_result_object(free):
    scene, lr, _ = free
    assert set(lr) == {"alpha", "D"} and lr.value["D"].shape == XS.shape and lr.value_stderr["D"].shape == XS.shape
    dp = jdpim.sensitivity(scene, ("alpha",), "x", XS, bandwidth=H, method=jdpim.MonteCarlo(n_samples=4000))
    assert isinstance(dp.estimators["alpha"], Pathwise)  # no barrier: pathwise derivatives are exact and bounded
    # Its standard error comes from the per-path contributions, like the other estimators'. Measured (4000
    # paths): relative L2 error 0.10 against the exact derivative, standard error 0.081 of the norm, every grid
    # point within 3 standard errors.
    ref = _exact_derivative("alpha")
    value, err = np.asarray(dp["alpha"]), np.asarray(dp.value_stderr["alpha"])
    rel = np.linalg.norm(value - ref) / np.linalg.norm(ref)
    rel_err = np.linalg.norm(err) / np.linalg.norm(ref)
    assert 0 < rel_err < 0.15
    assert rel < 3 * rel_err
    assert np.mean(np.abs(value - ref) < 3 * err + 1e-3 * np.abs(ref).max()) > 0.9


def test_joint_derivative_integrates_to_the_marginal(free):
    """Same paths, same kernels: integrating ``dp(x, v)`` over ``v`` gives ``dp(x)`` up to quadrature."""
    scene, lr, _ = free
    vg = np.linspace(-2.5, 2.5, 101)
    est = {"alpha": LikelihoodRatio(), "D": NoiseScaling()}
    joint = jdpim.sensitivity(
        scene, ("alpha", "D"), "xv", (XS, vg), bandwidth=(H, H), estimator=est, method=jdpim.MonteCarlo(n_samples=4000)
    )
    for name in ("alpha", "D"):
        assert joint[name].shape == (XS.size, vg.size) and np.all(np.isfinite(joint.value_stderr[name]))
        marginal = np.trapezoid(np.asarray(joint[name]), vg, axis=1)
        np.testing.assert_allclose(marginal, lr[name], atol=2e-3 * np.abs(lr[name]).max())


def test_large_standard_errors_are_flagged(free):
    """The fixture's paths (its simulation program) with a narrow kernel: dp/dD's standard error is 0.76 of
    its value at bandwidth 0.01."""
    scene, _, _ = free
    est = {"alpha": LikelihoodRatio(), "D": NoiseScaling()}
    with pytest.warns(SensitivityWarning, match="dp/dD: standard error"):
        jdpim.sensitivity(
            scene, ("alpha", "D"), "x", XS, bandwidth=0.01, estimator=est, method=jdpim.MonteCarlo(n_samples=4000)
        )


def test_estimators_refuse_what_they_cannot_do():
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, r=0.9, barrier=0.0)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=T, dt=0.02, x0=0.5)
    with pytest.raises(ValueError, match="drift parameters only"):
        jdpim.sensitivity(scene, ("r",), "x", XS + 1.5, estimator=LikelihoodRatio())
    with pytest.raises(ValueError, match="start is not at rest"):
        jdpim.sensitivity(scene, ("D",), "x", XS + 1.5, estimator=NoiseScaling())
    with pytest.raises(TypeError, match="estimator for 'alpha'"):
        jdpim.sensitivity(scene, ("alpha",), "x", XS + 1.5, estimator="pathwise")


def test_estimators_carry_their_behaviour():
    """Which scores each estimator asks for (a parameter's own settings win), which is joint, what each refuses."""
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=0.03, r=0.9, barrier=0.0)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=T, dt=0.02)
    lr = LikelihoodRatio(window=3.0)
    assert lr.scores_needed("alpha", scene) == {"alpha": lr}
    assert NoiseScaling().scores_needed("D", scene) == {"gamma": LikelihoodRatio()}
    assert CentralDifference().scores_needed("r", scene) == {}
    assert _score_settings(scene, ("D", "gamma"), {"D": NoiseScaling(), "gamma": lr}) == {"gamma": lr}
    assert Pathwise().joint and not any(e.joint for e in (lr, NoiseScaling(), CentralDifference()))
    with pytest.raises(ValueError, match="barrier moves the kernel"):  # refused before any path is run
        jdpim.sensitivity(scene, ("barrier",), "x", XS + 1.5, estimator=CentralDifference(), method=jdpim.MonteCarlo())


def test_accumulator_sums_the_noise_increments():
    """Running sums at the save slots; without an accumulator the output is the plain states."""
    import jax.numpy as jnp

    model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, barrier=None)
    T_, n, h = 10, 3, 0.1
    exc = jnp.asarray(np.random.default_rng(0).normal(size=(2 * T_ + 1, n, 1)), jnp.float32)
    slots = jnp.asarray([2] * 4 + [0] + [2] * 4 + [1], jnp.int32)  # save after steps 5 and 10
    args = (lambda _: model, ImpactRule(), h, jnp.zeros((n, 1)), jnp.zeros((n, 1)), exc, jnp.zeros((n, 0)), slots, 2, 2)
    states, sums = integrate(*args, track=Sums(lambda m, q, v, dw: jnp.stack([dw[0], jnp.ones_like(q[0])])))
    np.testing.assert_array_equal(np.asarray(states), np.asarray(integrate(*args)))
    e = np.asarray(exc)[:, :, 0]
    incr = h / 6 * (e[0:-1:2] + 4 * e[1::2] + e[2::2])  # Simpson's rule per step
    np.testing.assert_allclose(np.asarray(sums[:, :, 0]).T, np.cumsum(incr, axis=0)[[4, 9]], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(sums[:, :, 1]), [[5, 10]] * n)


@pytest.mark.slow
def test_elastic_impacts_at_stationarity():
    """r = 1, gamma = 0, barrier at 0, from rest, t = 200 (about 3 minutes on a loaded 2-core machine).

    Measured (2e4 paths, alpha = D = 0.05, h = 0.1): relative L2 error 0.073 for alpha (standard error 0.052),
    0.117 for D (standard error 0.126).
    """
    alpha, d, t, h = 0.05, 0.05, 200.0, 0.1
    xs = np.linspace(0.0, 3.0, 61)
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=alpha, gamma=None, r=1.0), noise=jdpim.WhiteNoise(D=d), t_end=t, dt=0.02
    )
    out = jdpim.sensitivity(scene, ("alpha", "D"), "x", xs, bandwidth=h, method=jdpim.MonteCarlo(n_samples=20_000))
    assert isinstance(out.estimators["alpha"], LikelihoodRatio) and isinstance(out.estimators["D"], NoiseScaling)
    for name, (a, dd) in {
        "alpha": ((alpha + 1e-6, d), (alpha - 1e-6, d)),
        "D": ((alpha, d + 1e-6), (alpha, d - 1e-6)),
    }.items():
        ref = []
        for aa, ddd in (a, dd):
            s2 = exact.linear_covariance(aa, ddd, t)[0] + h**2
            ref.append(2 * np.exp(-0.5 * xs**2 / s2) / np.sqrt(2 * np.pi * s2))
        ref = (ref[0] - ref[1]) / 2e-6
        rel = np.linalg.norm(out[name] - ref) / np.linalg.norm(ref)
        rel_err = np.linalg.norm(out.value_stderr[name]) / np.linalg.norm(ref)
        assert rel < max(3 * rel_err, 0.05), name


@pytest.mark.slow
def test_energy_dependent_damping_beta():
    """``(alpha + beta H) x'``, r = 1: exact stationary density ``exp(-(alpha H + beta H^2 / 2) / D)``.

    Checks the Ito correction of the score: measured at t = 100, 2e4 paths, window 40 s: relative L2
    error 0.073 (standard error 0.081); 0.28 without the correction, 0.39 with the full Wong-Zakai term.
    """
    alpha, beta, d, t, h = 0.05, 0.05, 0.05, 100.0, 0.1
    xs = np.linspace(0.0, 3.0, 61)
    model = jdpim.Oscillator(
        params={"alpha": alpha, "beta": beta},
        g=lambda x, p: x,
        f=lambda x, v, p: (p["alpha"] + p["beta"] * (0.5 * v**2 + 0.5 * x**2)) * v,
        r=1.0,
    )
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=d), t_end=t, dt=0.02)
    u, vv = np.linspace(0, 8, 2001), np.linspace(-8, 8, 2001)

    def reference(b):
        X, V = np.meshgrid(u, vv, indexing="ij")
        H_ = 0.5 * X**2 + 0.5 * V**2
        px = np.trapezoid(np.exp(-(alpha * H_ + b * H_**2 / 2) / d), vv, axis=1)
        px /= np.trapezoid(px, u)
        z = lambda s: np.exp(-0.5 * (s / h) ** 2) / (h * np.sqrt(2 * np.pi))  # noqa: E731
        return np.trapezoid((z(xs[:, None] - u) + z(xs[:, None] + u)) * px, u, axis=1)

    ref = (reference(beta + 1e-5) - reference(beta - 1e-5)) / 2e-5
    est = LikelihoodRatio(window=40.0)
    out = jdpim.sensitivity(
        scene, ("beta",), "x", xs, bandwidth=h, estimator=est, method=jdpim.MonteCarlo(n_samples=20_000)
    )
    rel = np.linalg.norm(out["beta"] - ref) / np.linalg.norm(ref)
    assert rel < max(3 * np.linalg.norm(out.value_stderr["beta"]) / np.linalg.norm(ref), 0.05)
