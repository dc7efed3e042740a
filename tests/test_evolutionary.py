"""Fully non-stationary noise, an evolutionary spectrum ``S(omega, t) = (D / pi) |A(omega, t)|^2``: the spectral
representation under it, against the uniformly modulated forcing it generalises and against the exact evolutionary
covariance of a linear two-storey frame (Monte Carlo and DPIM); the exact covariance against the Lyapunov equation;
refusals."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim._excitation import (
    gaussian_coefficients,
    random_function_coefficients,
    synthesize,
    synthesize_evolutionary,
)

ENVELOPE = jdpim.ShinozukaSato(b1=0.1, b2=0.5)
TIMES = tuple(float(t) for t in range(2, 22, 2))
# the soil softens through the record: omega_g falls from 12 to 3 rad/s, past the frame's modes (2 and 5.2 rad/s)
GROUND = jdpim.EvolutionaryKanaiTajimi(omega_g=((0.0, 20.0), (12.0, 3.0)), zeta_g=0.4, envelope=ENVELOPE)
N_SAMPLES = 2000
N_POINTS = 1000


@pytest.fixture(scope="module")
def frame_scene():
    """A linear two-storey frame (first mode 2 rad/s, 5 % damping) from rest under the evolutionary Kanai-Tajimi
    ground motion, saved at 10 times over 20 s; the spectral grid up to 30 rad/s."""
    frame = jdpim.pounding_frame(n_storeys=2, frequency=2.0, damping_ratio=0.05).replace(constraints=())
    noise = jdpim.WhiteNoise(D=0.05, envelope=GROUND)
    excitation = jdpim.SpectralRepresentation(cutoff=30.0)
    return jdpim.Scene(frame, noise=noise, t_end=TIMES[-1], dt=0.04, save_at=TIMES, excitation=excitation)


@pytest.fixture(scope="module")
def frame_exact(frame_scene):
    """Variances of the 4 state entries at ``TIMES``, ``(10, 4)``: the exact covariance on the scene's grid."""
    grid = frame_scene.excitation.grid(frame_scene.t_end, frame_scene.dt)
    P = jdpim.exact.evolutionary_covariance(frame_scene.model, frame_scene.noise, TIMES, dw=grid.dw, cutoff=grid.cutoff)
    return np.diagonal(P, axis1=1, axis2=2)


def test_monte_carlo_variances_follow_the_evolutionary_covariance(frame_scene, frame_exact):
    """Every state entry at all 10 times within 3 standard errors (``sqrt((m4 - m2^2) / N)``, ``N = 2000``) of the
    exact variance; the variance peaks inside the record."""
    res = jdpim.solve(frame_scene, jdpim.MonteCarlo(n_samples=N_SAMPLES, seed=1))
    zs = []
    for i, name in enumerate(frame_scene.model.coordinates):
        stats = jdpim.response_moments(res, name)
        zs.append((np.asarray(stats.variance) - frame_exact[:, i]) / np.asarray(stats.variance_stderr))
    zs = np.asarray(zs)
    print(
        f"\nMonte Carlo: max |z| {np.abs(zs).max():.2f}, mean z {zs.mean():.2f}, "
        f"{np.sum(np.abs(zs) < 2)} of {zs.size} within 2"
    )
    assert np.all(np.abs(zs) < 3.0), np.round(zs, 2)
    assert frame_exact[:, 1].argmax() not in (0, len(TIMES) - 1)


def test_dpim_variances_within_their_replicate_spread(frame_scene, frame_exact):
    """The mean variance of 4 randomised DPIM replicates (1000 points, two elementary variables) lies within 3
    standard deviations of one replicate of the exact one, for every state entry."""
    method = jdpim.DPIM(n_points=N_POINTS)
    assert len(method.input_distributions(frame_scene)) == 2
    runs = [jdpim.solve(frame_scene, method.replicate(frame_scene, k)) for k in range(4)]
    for i, name in enumerate(frame_scene.model.coordinates):
        stats = jdpim.response_moments(runs, name)
        spread = np.asarray(stats.variance_stderr) * np.sqrt(len(runs))
        z = (np.asarray(stats.variance) - frame_exact[:, i]) / spread
        relative = np.abs(np.asarray(stats.variance) / frame_exact[:, i] - 1).max()
        print(f"\nDPIM {name}: max deviation {np.abs(z).max():.2f} spreads, relative error {relative:.3f}")
        assert np.all(np.abs(z) < 3.0), (name, np.round(z, 2))


def test_a_separable_spectrum_is_the_uniformly_modulated_forcing():
    """``|A(omega, t)|^2 = e(t)^2`` gives the forcing of the envelope ``e`` from the same coefficients (Monte Carlo's
    Gaussian ones from the same keys, DPIM's random functions of the same points) to float32 rounding (1e-6 of the
    largest value): the direct sum is the FFT's, phases and time origin included."""
    grid = jdpim.SpectralRepresentation().grid(t_end=4.0, dt=0.02)
    mixing = np.sqrt(np.full((1, 1), 0.1, np.float32))
    points = np.random.default_rng(1).uniform(-np.pi, np.pi, (8, 2)).astype(np.float32)

    @jax.jit
    def both(points):
        keys = jax.random.split(jax.random.key(0), 8)
        gaussian = jax.vmap(lambda k: gaussian_coefficients(k, 1, grid, mixing, jnp.float32))(keys)
        functions = jax.vmap(lambda p: random_function_coefficients(p, grid, mixing))(points)
        c = jnp.concatenate([gaussian, functions])
        spectrum = jdpim.EvolutionarySpectrum(_squared_envelope)
        return synthesize_evolutionary(c, grid, spectrum, 0.01, jnp.float32), synthesize(c, grid)

    shaped, fft = both(points)
    expected = np.asarray(fft) * np.asarray(ENVELOPE(0.01 * np.arange(grid.n_half)))[:, None, None]
    np.testing.assert_allclose(np.asarray(shaped), expected, rtol=0, atol=1e-6 * np.abs(expected).max())


def _squared_envelope(omega, t):
    return ENVELOPE(t) ** 2


def test_exact_covariance_is_the_lyapunov_equation_for_an_envelope():
    """For ``|A|^2 = e(t)^2`` on a fine grid the evolutionary covariance is the Lyapunov one: displacement within
    1e-4 (relative; the linear interpolation of ``A`` in time), velocity less the variance beyond the cutoff
    (``2 D / (pi w_u) e^2``-sized, under 1 %); a spectrum object and the envelope itself give the same."""
    model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None, omega=1.5)
    noise = jdpim.WhiteNoise(0.1, envelope=ENVELOPE)
    times = (2.0, 5.0, 10.0)
    exact = jdpim.exact.lyapunov_covariance(model, noise, times)
    P = jdpim.exact.evolutionary_covariance(model, noise, times, dw=0.25, cutoff=100.0)
    np.testing.assert_allclose(P[:, 0, 0], exact[:, 0, 0], rtol=1e-4)
    assert np.all(np.abs(P[:, 1, 1] / exact[:, 1, 1] - 1) < 0.01)
    shaped = jdpim.WhiteNoise(0.1, envelope=jdpim.EvolutionarySpectrum(_squared_envelope))
    Q = jdpim.exact.evolutionary_covariance(model, shaped, times, dw=0.25, cutoff=100.0)
    np.testing.assert_allclose(Q, P, rtol=1e-9, atol=1e-15)


def test_kanai_tajimi_with_constant_parameters_is_the_filter_density():
    """``EvolutionaryKanaiTajimi`` with constant parameters is ``e(t)^2`` times the Clough-Penzien density of
    ``jdpim.clough_penzien`` relative to ``S0``."""
    wg, zg, wf, zf = 15.6, 0.6, 1.5, 0.6
    omega = np.linspace(0.0, 40.0, 81)
    spectrum = jdpim.EvolutionaryKanaiTajimi(wg, zg, omega_f=wf, zeta_f=zf, envelope=ENVELOPE)
    kt = (wg**4 + 4 * zg**2 * wg**2 * omega**2) / ((wg**2 - omega**2) ** 2 + 4 * zg**2 * wg**2 * omega**2)
    hp = omega**4 / ((wf**2 - omega**2) ** 2 + 4 * zf**2 * wf**2 * omega**2)
    got = np.asarray(spectrum.on_grid(jnp.asarray(omega), jnp.asarray([3.0])))[0]
    np.testing.assert_allclose(got, kt * hp * float(ENVELOPE(3.0)) ** 2, rtol=1e-5)


def test_refusals():
    model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None)
    with pytest.raises(ValueError, match=r"^omega_g must lie in \(0, inf\), got -1"):
        jdpim.EvolutionaryKanaiTajimi(omega_g=-1.0)
    with pytest.raises(ValueError, match=r"^zeta_g's table needs two rows"):
        jdpim.EvolutionaryKanaiTajimi(zeta_g=((0.0, 1.0), (0.5,)))
    with pytest.raises(TypeError, match=r"^density must be a function density\(omega, t\)"):
        jdpim.EvolutionarySpectrum(3.0)
    with pytest.raises(TypeError, match="density must return a real scalar"):
        jdpim.EvolutionarySpectrum(lambda w, t: jnp.stack([w, t]))
    falling = jdpim.WhiteNoise(0.1, envelope=jdpim.EvolutionaryKanaiTajimi(omega_g=_falling))
    excitation = jdpim.SpectralRepresentation(cutoff=20.0)
    with pytest.raises(ValueError, match=r"^omega_g must be finite and > 0 over the record, got 0 at t=10 s"):
        jdpim.Scene(model, noise=falling, t_end=12.0, dt=0.02, excitation=excitation)
    negative = jdpim.WhiteNoise(0.1, envelope=jdpim.EvolutionarySpectrum(_negative))
    with pytest.raises(ValueError, match=r"must be finite and >= 0 on the spectral grid; at omega=0 rad/s, t=2.01 s"):
        jdpim.Scene(model, noise=negative, t_end=4.0, dt=0.02, excitation=excitation)
    shaped = jdpim.WhiteNoise(0.1, envelope=GROUND)
    with pytest.raises(ValueError, match="give the scene excitation=jdpim.SpectralRepresentation()"):
        jdpim.Scene(model, noise=shaped, t_end=4.0, dt=0.02, excitation=jdpim.GaussianNodes())
    scene = jdpim.Scene(model, noise=shaped, t_end=4.0, dt=0.02)
    with pytest.raises(ValueError, match="give the scene excitation=jdpim.SpectralRepresentation()"):
        jdpim.solve(scene, jdpim.MonteCarlo(n_samples=4))
    with pytest.raises(ValueError, match="its covariance is evolutionary_covariance's"):
        jdpim.exact.lyapunov_covariance(model, shaped, [1.0])
    with pytest.raises(ValueError, match="no intensity D e"):
        shaped.intensity(1.0)
    with pytest.raises(ValueError, match="path integration .* assumes a constant noise intensity"):
        jdpim.solve(scene, jdpim.PathIntegration(n_x=21, n_v=21))
    with pytest.raises(ValueError, match=r"^cutoff must lie in \[0.5, inf\)"):
        jdpim.exact.evolutionary_covariance(model, shaped, [1.0], dw=0.5, cutoff=0.1)


def _falling(t):
    return 10.0 - t


def _negative(omega, t):
    return 2.0 - t


SCENE_FILE = """
[model]
alpha = 0.2
gamma = "none"
barrier = "none"
r = 0.5
[noise]
D = 0.1
[noise.envelope]
kind = "evolutionary_kanai_tajimi"
omega_g = [[0.0, 20.0], [12.0, 3.0]]
zeta_g = 0.4
envelope = { kind = "shinozuka_sato" }
[time]
t_end = 1.0
dt = 0.02
[method]
name = "monte_carlo"
n_samples = 16
"""


def test_scene_file_key(tmp_path):
    """``[noise] envelope = { kind = "evolutionary_kanai_tajimi", ... }`` is the library's object; Monte Carlo under it
    needs ``forcing = "spectral"``; errors name the key."""
    from jdpim.cli._scenefile import SceneFileError, load

    path = tmp_path / "s.toml"
    path.write_text(SCENE_FILE + 'forcing = "spectral"\n')
    noise = load(path).scene.noise
    assert noise == jdpim.WhiteNoise(D=0.1, envelope=GROUND)
    path.write_text(SCENE_FILE)
    with pytest.raises(SceneFileError, match=r'^s.toml: \[method\] forcing: must be "spectral" under an evolutionary'):
        load(path)
    path.write_text(SCENE_FILE.replace("zeta_g = 0.4", "zeta_g = -0.4") + 'forcing = "spectral"\n')
    with pytest.raises(SceneFileError, match=r"^s.toml: \[noise\] envelope.zeta_g: must lie in \(0, inf\)"):
        load(path)
    path.write_text(SCENE_FILE.replace('kind = "shinozuka_sato"', 'kind = "evolutionary_kanai_tajimi"'))
    with pytest.raises(SceneFileError, match=r"^s.toml: \[noise\] envelope.envelope.kind: must be one of \['shinozuka"):
        load(path)
