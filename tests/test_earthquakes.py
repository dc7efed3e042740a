"""Earthquake excitation and the statistics an engineer reads: envelopes, the Clough-Penzien filter on one- and
two-degree-of-freedom models, moments against the exact time-varying covariance, PSD and autocorrelation against
the exact stationary ones."""

import dataclasses

import jax
import numpy as np
import pytest
import scipy.stats

import jdpim

ENVELOPE = jdpim.ShinozukaSato(b1=0.1, b2=0.5)  # peak at t = 4.02 s
TIMES = tuple(float(t) for t in range(2, 22, 2))
N_SAMPLES = 4000


@pytest.fixture(scope="module")
def frame_scene():
    """A linear two-storey frame (first mode 1 rad/s, 5 % damping) under modulated Clough-Penzien ground motion,
    from rest, saved at 10 times over 20 s."""
    frame = jdpim.pounding_frame(n_storeys=2, frequency=1.0, damping_ratio=0.05).replace(constraints=())
    model = jdpim.clough_penzien(frame, omega_g=3.0, zeta_g=0.6, omega_f=0.3, zeta_f=0.6)
    noise = jdpim.WhiteNoise(D=0.05, envelope=ENVELOPE)
    return jdpim.Scene(model, noise=noise, t_end=TIMES[-1], dt=0.02, save_at=TIMES)


@pytest.fixture(scope="module")
def frame_exact(frame_scene):
    """Variances of the 8 state entries at ``TIMES``, ``(10, 8)``, from the Lyapunov equation."""
    P = jdpim.exact.lyapunov_covariance(frame_scene.model, frame_scene.noise, TIMES)
    return np.diagonal(P, axis1=1, axis2=2)


def test_monte_carlo_variances_of_every_coordinate_follow_the_lyapunov_equation(frame_scene, frame_exact):
    """Every coordinate of the frame and its filters, at all 10 times: within 3 standard errors
    (``sqrt((m4 - m2^2) / N)``, ``N = 4000``) of the exact variance; the means within 3 of 0."""
    res = jdpim.solve(frame_scene, jdpim.MonteCarlo(n_samples=N_SAMPLES, seed=0))
    names = frame_scene.model.coordinates
    zs = []
    for i, name in enumerate(names):
        stats = jdpim.response_moments(res, name)
        z = (np.asarray(stats.variance) - frame_exact[:, i]) / np.asarray(stats.variance_stderr)
        assert np.all(np.abs(z) < 3.0), (name, np.round(z, 2))
        assert np.all(np.abs(np.asarray(stats.mean) / np.asarray(stats.mean_stderr)) < 3.0), name
        zs.append(z)
    print(
        f"\nMonte Carlo variances: max |z| {np.abs(zs).max():.2f}, {np.sum(np.abs(zs) < 2)} of {np.size(zs)} within 2"
    )
    assert stats.times == TIMES
    x2 = frame_exact[:, names.index("x2")]
    assert x2.argmax() not in (0, len(TIMES) - 1)  # the response builds up and decays within the record


def test_dpim_variances_within_their_replicate_spread(frame_scene, frame_exact):
    """The mean variance of 4 randomised DPIM replicates (1000 points) lies within 3 standard deviations of one
    replicate (the error bar of one run) of the exact one, for the storeys' displacements and velocities."""
    method = jdpim.DPIM(n_points=1000)
    runs = [jdpim.solve(frame_scene, method.replicate(frame_scene, k)) for k in range(4)]
    names = frame_scene.model.coordinates
    for name in ("x1", "x2", "v1", "v2"):
        stats = jdpim.response_moments(runs, name)
        spread = np.asarray(stats.variance_stderr) * np.sqrt(len(runs))
        exact = frame_exact[:, names.index(name)]
        z = (np.asarray(stats.variance) - exact) / spread
        assert np.all(np.abs(z) < 3.0), (name, np.round(z, 2))
        relative = np.abs(np.asarray(stats.variance) / exact - 1).max()
        print(f"\nDPIM {name}: max deviation {np.abs(z).max():.2f} spreads, relative error {relative:.3f}")
    one = jdpim.response_moments(runs[0], "x1")
    assert one.variance_stderr is None and one.method == "dpim"


ALPHA, D = 0.6, 0.1  # damping ratio 0.3 at omega_n = 1 rad/s
DT_SAVE, SEGMENT, BURN = 0.2, 512, 30.0  # segments of 102.4 s, 4 of them half overlapping per path


@pytest.fixture(scope="module")
def stationary():
    """400 Monte Carlo paths of a linear oscillator, saved every 0.2 s over 256 s after a 30 s transient
    (``exp(-alpha * 30) < 1e-7``)."""
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, barrier=None, omega=1.0)
    noise = jdpim.WhiteNoise(D=D)
    length = SEGMENT // 2 * 5
    save = tuple(round(BURN + DT_SAVE * k, 10) for k in range(length))
    scene = jdpim.Scene(model, noise=noise, t_end=BURN + DT_SAVE * length, dt=0.05, save_at=save)
    return model, noise, jdpim.solve(scene, jdpim.MonteCarlo(n_samples=400, seed=0))


def test_psd_of_a_linear_oscillator(stationary):
    r"""Welch's estimate against ``|H(omega)|^2 D / pi`` on the 49 frequencies of ``[0, 3 omega_n]``, within its
    standard errors. The window's kernel bias, the exact expectation of the estimate (from the exact
    autocovariance) minus the density, is below one standard error everywhere (0.53 at most, at the resonance), and
    the errors ``z`` are measured from that expectation. Neighbouring bins correlate (0.44 for the Hann window,
    ``(2/3)^2``), bins two apart hardly (``(1/6)^2 = 0.03``), so the even and the odd bins each give a chi-square
    statistic of 25 and 24 nearly independent ``z^2``, each below its ``1 - 5e-4`` quantile, and every ``|z|`` is
    below the Bonferroni bound of 49 normal bins (4.26): a false alarm rate of at most ``2e-3`` in all. Over 10
    seeds of each of two noise generators the statistics average 24.9 and 25.3 (expected 25 and 24), at most 39.7,
    and ``|z|`` at most 3.44."""
    model, noise, mc = stationary
    spectrum = jdpim.response_psd(mc, "x", segment=SEGMENT)
    omega, psd, se = (np.asarray(a, float) for a in (spectrum.frequencies, spectrum.psd, spectrum.psd_stderr))
    band = omega <= 3.0
    exact = jdpim.exact.linear_psd(model, noise, omega)[:, 0]
    window = np.hanning(SEGMENT + 2)[1:-1]
    lags = np.arange(-(SEGMENT - 1), SEGMENT)
    R = jdpim.exact.linear_autocorrelation(model, noise, lags * DT_SAVE)[:, 0]
    overlap = np.correlate(window, window, mode="full")  # sum_j h_j h_(j + m), m = -(L - 1) .. L - 1
    expected = (
        DT_SAVE
        / (2 * np.pi * np.sum(window**2))
        * np.real(np.exp(-1j * np.outer(omega, lags) * DT_SAVE) @ (R * overlap))
    )
    assert np.all(np.abs(expected - exact)[band] < se[band])
    z = ((psd - expected) / se)[band]
    even, odd = np.sum(z[0::2] ** 2), np.sum(z[1::2] ** 2)
    assert band.sum() == 49 and np.all(np.abs(z) < scipy.stats.norm.isf(1e-3 / 98)), np.round(z, 2)
    assert even < scipy.stats.chi2.isf(5e-4, 25) and odd < scipy.stats.chi2.isf(5e-4, 24), (even, odd)
    bias = np.abs(expected - exact)[band] / se[band]
    print(
        f"\nPSD: kernel bias <= {bias.max():.2f} SE, chi-square {even:.1f} (25 even bins), {odd:.1f} (24 odd), "
        f"max |z| {np.abs(z).max():.2f}, relative SE <= {(se / psd)[band].max():.3f}"
    )
    assert spectrum.times[0] == BURN and len(spectrum.times) == SEGMENT // 2 * 5


def test_autocorrelation_of_a_linear_oscillator(stationary):
    """The autocovariance of ``x`` at lags 0 .. 20 s within 3 standard errors of ``P e^{A^T tau}``."""
    model, noise, mc = stationary
    acf = jdpim.response_autocorrelation(mc, "x", max_lag=100)
    exact = jdpim.exact.linear_autocorrelation(model, noise, np.asarray(acf.lags, float))[:, 0]
    z = (np.asarray(acf.autocorrelation) - exact) / np.asarray(acf.autocorrelation_stderr)
    assert np.all(np.abs(z) < 3.0), np.round(z, 2)
    assert float(acf.lags[-1]) == pytest.approx(20.0)


def test_statistics_refuse_what_they_cannot_read(stationary):
    _, _, mc = stationary
    with pytest.raises(ValueError, match=r"^segment must be at most the 1280 saved times from start=30"):
        jdpim.response_psd(mc, "x", segment=2000)
    with pytest.raises(ValueError, match=r"^max_lag must be below the 1280 saved times"):
        jdpim.response_autocorrelation(mc, "x", max_lag=1280)
    uneven = dataclasses.replace(mc, times=mc.times[:-1] + (mc.times[-1] + 0.1,))
    with pytest.raises(ValueError, match="equally spaced"):
        jdpim.response_psd(uneven, "x", segment=8)
    with pytest.raises(ValueError, match="var must be one of the coordinates"):
        jdpim.response_moments(mc, "y")
    with pytest.raises(TypeError, match="result must be a result of jdpim.solve"):
        jdpim.response_moments([1, 2], "x")


def test_clough_penzien_ground_acceleration_spectrum():
    """The ground acceleration ``xc''`` of the filter model has the Clough-Penzien density (relative 1e-10)."""
    wg, zg, wf, zf, D0 = 15.6, 0.6, 1.5, 0.6, 0.03
    model = jdpim.clough_penzien(jdpim.VibroImpactOscillator(gamma=None, barrier=None), wg, zg, wf, zf)
    A, G = model.linearised(), np.vstack([np.zeros((3, 1)), model.inverse_mass() @ np.asarray(model.gains)])
    row = model.coordinates.index("vc")
    omega = np.linspace(0.0, 40.0, 81)
    H = np.linalg.solve(1j * omega[:, None, None] * np.eye(6) - A, np.broadcast_to(G, (81, 6, 1)))
    accel = (A[row] @ H)[:, 0]  # xc'' = A[vc] y (no noise enters xc)
    kt = (wg**4 + 4 * zg**2 * wg**2 * omega**2) / ((wg**2 - omega**2) ** 2 + 4 * zg**2 * wg**2 * omega**2)
    hp = omega**4 / ((wf**2 - omega**2) ** 2 + 4 * zf**2 * wf**2 * omega**2)
    np.testing.assert_allclose(np.abs(accel) ** 2 * D0 / np.pi, D0 / np.pi * kt * hp, rtol=1e-10, atol=1e-14)
    assert G[row, 0] == 0.0
    with pytest.raises(ValueError, match=r"^omega_f must lie in \(0, inf\)"):
        jdpim.clough_penzien(model, omega_f=0.0)


def test_filters_on_one_degree_of_freedom():
    """A lifted oscillator (barrier, cubic damping) has the original's accelerations, impact law and start; filters
    append to it; gains that depend on the state are refused."""
    model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=0.05, r=0.8, barrier=-0.5, omega=1.2)
    lifted = jdpim.filters.as_mdof(model)
    q, v, xi = np.random.default_rng(0).normal(size=(3, 50, 1)).astype(np.float32)
    accelerations = [jax.vmap(m.state_acceleration)(q, v, xi) for m in (model, lifted)]
    np.testing.assert_allclose(*accelerations, rtol=1e-5, atol=1e-6)
    a, b = model.stacked_constraints(), lifted.stacked_constraints()
    for field in ("normal", "position", "r", "push"):
        np.testing.assert_allclose(np.asarray(getattr(b, field)), np.asarray(getattr(a, field)), rtol=1e-6)
    assert lifted.start == (-0.5,) and lifted.coordinates == model.coordinates
    assert jdpim.kanai_tajimi(model).coordinates == ("x", "xf", "v", "vf")
    assert jdpim.first_order_filter(model, a=2.0).coordinates == ("x", "xf", "v", "vf")
    assert jdpim.harmonic(model, amplitude=0.1, frequency=0.9).start == (-0.5, 1.0)  # at the barrier
    state_dependent = jdpim.Oscillator(h=lambda x, v, p: jax.numpy.array([1.0 + x]))
    with pytest.raises(ValueError, match="a filter needs additive noise"):
        jdpim.kanai_tajimi(state_dependent)
    with pytest.raises(TypeError, match="model must be a jdpim.MDOFOscillator or a one-degree-of-freedom"):
        jdpim.kanai_tajimi("frame")
    with pytest.raises(ValueError, match="exact for a linear model"):
        jdpim.exact.lyapunov_covariance(model, jdpim.WhiteNoise(D=0.1), [1.0])


def test_envelopes():
    env = jdpim.Jennings(t1=2.0, t2=6.0, c=0.5)
    t = np.array([-1.0, 1.0, 2.0, 4.0, 6.0, 8.0])
    np.testing.assert_allclose(np.asarray(env(t)), [0.0, 0.25, 1.0, 1.0, 1.0, np.exp(-1.0)], rtol=1e-6)
    with pytest.raises(ValueError, match=r"^t2 must lie in \[2, inf\), got 1"):
        jdpim.Jennings(t1=2.0, t2=1.0)
    with pytest.raises(ValueError, match=r"^c must lie in \(0, inf\)"):
        jdpim.Jennings(c=0.0)
    noise = jdpim.WhiteNoise(D=0.1, envelope=lambda t: 1.0 - 0.5 * jax.numpy.cos(t))  # any traceable function
    assert float(noise.intensity(0.0)) == pytest.approx(0.025)

    class Unhashable:
        __hash__ = None

        def __call__(self, t):
            return t

    with pytest.raises(TypeError, match="envelope must be hashable"):
        jdpim.WhiteNoise(D=0.1, envelope=Unhashable())
    with pytest.raises(TypeError, match=r"envelope must return a real scalar .* shape \(2,\)"):
        jdpim.WhiteNoise(D=0.1, envelope=lambda t: jax.numpy.stack([t, t]))
    with pytest.raises(TypeError, match="envelope must be a function e\\(t\\) that JAX can trace"):
        jdpim.WhiteNoise(D=0.1, envelope=lambda t: float(t) * 2.0)


def test_statistics_pass_through_jit_and_read_path_integration(stationary):
    """The result classes are pytrees (jit gives the eager values); a path-integration density gives its moments,
    against the exact variance of the free oscillator (grid error below 1 %), without a standard error."""
    _, _, mc = stationary
    eager = jdpim.response_psd(mc, "x", segment=SEGMENT)
    jitted = jax.jit(lambda r: jdpim.response_psd(r, "x", segment=SEGMENT))(mc)
    np.testing.assert_allclose(jitted.psd, eager.psd, rtol=1e-5)
    assert jitted.times == eager.times and isinstance(jitted, jdpim.ResponseSpectrum)
    model = jdpim.VibroImpactOscillator(alpha=0.5, gamma=None, barrier=None)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.1), t_end=4.0, dt=0.1, save_at=(2.0, 4.0))
    grid = jdpim.solve(scene, jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1))
    stats = jdpim.response_moments(grid, "x")
    exact = jdpim.exact.lyapunov_covariance(model, scene.noise, (2.0, 4.0))[:, 0, 0]
    np.testing.assert_allclose(stats.variance, exact, rtol=0.01)
    assert stats.variance_stderr is None and stats.method == "path_integration"
