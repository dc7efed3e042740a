"""Monte Carlo with Gaussian forcing drawn inside the steps (``jdpim.GaussianNodes``)."""

import jax
import numpy as np
import pytest
from conftest import DT_SMALL, N_SMALL, T_SMALL

import jdpim

NODES = jdpim.GaussianNodes()


def test_a_linear_oscillator_reaches_the_exact_stationary_variance():
    """``x'' + c x' + x = xi``: ``E[x^2] = E[v^2] = D / c`` at stationarity (4000 paths, 11 times in [20, 40] s)."""
    D, c = 0.05, 0.4
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=c, gamma=None, barrier=None),
        noise=jdpim.WhiteNoise(D=D),
        t_end=40.0,
        dt=0.01,
        save_at=tuple(np.linspace(20.0, 40.0, 11)),
        excitation=NODES,
    )
    s = np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=4000, seed=0)).states, float)
    for k in (0, 1):
        y = s[..., k] ** 2
        per_path = y.mean(axis=1)  # times 2 s apart are correlated: the error from per-path means
        se = per_path.std() / np.sqrt(per_path.size)
        assert abs(y.mean() - D / c) < 4 * se, (k, y.mean(), D / c, se)


def test_runs_are_deterministic_independent_of_chunks_and_share_the_random_parameters():
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=0.4, barrier=None),  # no impacts to amplify rounding
        t_end=5.0,
        dt=0.01,
        save_at=(0.0, 5.0),
        excitation=NODES,
        random={"x0": jdpim.Uniform(0.0, 0.5)},
    )
    a = np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=300, seed=1)).states)
    b = np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=300, seed=1, chunk_size=64)).states)
    c = np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=300, seed=2)).states)
    np.testing.assert_array_equal(a, np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=300, seed=1)).states))
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)  # chunks change only the rounding
    assert not np.allclose(a[:, -1], c[:, -1])
    spectral = jdpim.solve(scene.replace(excitation=jdpim.SpectralRepresentation()), jdpim.MonteCarlo(300, seed=1))
    np.testing.assert_array_equal(a[:, 0], np.asarray(spectral.states[:, 0]))  # the same random start per path
    assert not np.allclose(a[:, -1], np.asarray(spectral.states[:, -1]))  # and other forcing


def test_dpim_refuses_and_bad_settings_fail_in_one_line():
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.01, excitation=NODES)
    with pytest.raises(ValueError, match="DPIM needs the spectral representation"):
        jdpim.solve(scene, jdpim.DPIM(n_points=10))
    with pytest.raises(TypeError, match="excitation must be a jdpim.AbstractExcitation or None"):
        jdpim.Scene(jdpim.VibroImpactOscillator(), excitation="nodes")


# slow: the default tier runs a method on its own forcing in the "mc" cell (one code path for both methods,
# jdpim.methods._paths.excitation_of) and checks DPIM's own forcing in the assertions before the runs
@pytest.mark.parametrize("name", ["mc", pytest.param("dpim", marks=pytest.mark.slow)])
def test_each_method_takes_its_own_forcing_where_the_scene_leaves_it(name):
    """``Scene(excitation=None)``, the default: Monte Carlo runs on Gaussian nodes and DPIM on the default spectral
    representation, giving the states of those forcings named explicitly, bit for bit."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=T_SMALL, dt=DT_SMALL)
    assert scene.excitation is None
    assert jdpim.MonteCarlo().excitation(scene) == jdpim.MonteCarlo.default_excitation == NODES
    assert jdpim.DPIM().excitation(scene) == jdpim.DPIM.default_excitation == jdpim.SpectralRepresentation()
    spectral = scene.replace(excitation=jdpim.SpectralRepresentation())
    assert jdpim.MonteCarlo().excitation(spectral) == jdpim.SpectralRepresentation()
    method, explicit = {
        "mc": (jdpim.MonteCarlo(n_samples=N_SMALL, seed=3), scene.replace(excitation=NODES)),
        "dpim": (jdpim.DPIM(n_points=N_SMALL), spectral),
    }[name]
    a, b = jdpim.solve(scene, method), jdpim.solve(explicit, method)
    np.testing.assert_array_equal(np.asarray(a.states), np.asarray(b.states))


def test_cpu_chunks_with_the_noise_drawn_inside_the_steps_are_large():
    """On a CPU, Monte Carlo with the noise drawn inside the steps takes chunks of up to ``NODES_CHUNK`` paths,
    with or without constraints; those where every device gets at least ``WIDE_CHUNK`` paths are wide (one batch
    of crossings per step). With the spectral forcing it keeps the small chunks."""
    from jdpim._engine.batches import WIDE_CHUNK
    from jdpim.methods._paths import CPU_CHUNK_BYTES, NODES_CHUNK, balanced_chunk, default_chunk_size, shared_size

    small = CPU_CHUNK_BYTES // 4
    devices = jax.device_count()
    damper = jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.01), t_end=1.0, dt=0.01, excitation=NODES)
    for n in (devices * WIDE_CHUNK, 10**5, 10**6 + 1):
        chunk = default_chunk_size(damper, n, "monte_carlo")
        assert WIDE_CHUNK <= chunk <= NODES_CHUNK, (n, chunk)
        assert balanced_chunk(n, chunk, devices) >= WIDE_CHUNK, (n, chunk)  # each device's equal chunks stay wide
    for n in (1, 700, devices * WIDE_CHUNK - 1):  # one chunk, of the shared size that holds them
        assert default_chunk_size(damper, n, "monte_carlo") == shared_size(n)
    free = damper.replace(model=jdpim.VibroImpactOscillator(barrier=None))
    assert default_chunk_size(free, 10**5, "monte_carlo") > small
    mirrored = damper.replace(impacts=jdpim.ImpactRule(method="mirror"))
    assert default_chunk_size(mirrored, 10**5, "monte_carlo") > small
    assert default_chunk_size(damper.replace(excitation=jdpim.SpectralRepresentation()), 10**5, "monte_carlo") <= small
    default = damper.replace(excitation=None)  # each method's own forcing: Gaussian nodes for Monte Carlo only
    assert default_chunk_size(default, 10**5, "monte_carlo") == default_chunk_size(damper, 10**5, "monte_carlo")
    assert default_chunk_size(default, 10**5, "dpim") <= small
