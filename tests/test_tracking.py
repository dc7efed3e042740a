"""Statistics tracked along paths (``jdpim.tracking``): a statistic defined here runs through Monte Carlo and
DPIM; the built-ins agree with the saved states; first passage holds a diverged path's maximum."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim.methods._paths import diverged
from jdpim.reliability._passage import FirstPassage
from jdpim.tracking import AbstractTracked, Function, Integral, RunningMaximum, track

# saved at every step, so that the states show what a statistic sees at the start and the end of every step
SCENE = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=0.5, dt=0.01, save_at=tuple(np.arange(51) * 0.01))


@dataclasses.dataclass(frozen=True)
class RunningMinimum(AbstractTracked):
    """The smallest velocity so far: a statistic written outside the library, in one class."""

    def init(self, model, q, v, e):
        return v

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        return jnp.minimum(acc, v_new)


@pytest.mark.parametrize("method", [jdpim.MonteCarlo(n_samples=64, seed=2), jdpim.DPIM(n_points=64)])
def test_a_statistic_of_ones_own_runs_through_monte_carlo_and_dpim(method):
    tracked = track(SCENE, method, RunningMinimum())
    states = np.asarray(jdpim.solve(SCENE, method).states)
    np.testing.assert_array_equal(np.asarray(tracked.values)[..., 0], np.minimum.accumulate(states[..., 1], axis=1))
    weights = np.asarray(tracked.weights)
    np.testing.assert_allclose(tracked.mean[:, 0], weights @ np.asarray(tracked.values)[..., 0], rtol=1e-5, atol=1e-7)
    assert tracked.times == SCENE.save_at
    assert (tracked.mean_stderr is not None) == isinstance(method, jdpim.MonteCarlo)


def energy(state):
    return 0.5 * state[1] ** 2 + 0.5 * state[0] ** 2


def test_built_in_function_and_integral_agree_with_the_saved_states():
    method = jdpim.MonteCarlo(n_samples=32, seed=5)
    states = np.asarray(jdpim.solve(SCENE, method).states)
    np.testing.assert_array_equal(np.asarray(track(SCENE, method, Function()).values), states)
    integral = np.asarray(track(SCENE, method, Integral(energy)).values)[..., 0]
    e = energy(np.moveaxis(states, -1, 0))
    trapezoid = np.concatenate([np.zeros((32, 1)), np.cumsum(0.5 * SCENE.dt * (e[:, 1:] + e[:, :-1]), axis=1)], 1)
    np.testing.assert_allclose(integral, trapezoid, rtol=1e-5, atol=1e-9)


def test_track_refuses_what_it_cannot_run():
    with pytest.raises(ValueError, match="MonteCarlo or jdpim.DPIM"):
        track(SCENE, jdpim.PathIntegration(), RunningMinimum())
    with pytest.raises(TypeError, match="statistic must be"):
        track(SCENE, jdpim.MonteCarlo(n_samples=8), energy)


def test_first_passage_counts_a_diverged_path_as_densities_do():
    """Divergence (beyond 1e6 times ``divergence_scale``, 21.9 in x for the reference scene to t = 20) is the rule
    densities use: a path that passed the level before it diverged has passed, one that did not is lost (not passed
    because its blow-up exceeds every level), and paths within the scale are unchanged."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=20.0, save_at=(5.0, 10.0, 20.0))
    states = np.zeros((4, 3, 2), np.float32)
    states[:, :, 0] = [[0.5, 0.7, 0.2], [0.1, 3e7, 2e20], [0.8, 0.1, 3e7], [0.2, 0.3, 0.4]]
    maxima = np.maximum.accumulate(np.abs(states[..., 0]), axis=1)
    values = jnp.asarray(np.stack([maxima, np.zeros_like(maxima)], -1))
    held = RunningMaximum(lambda s: s[0]).finalise(values, diverged(scene, jnp.asarray(states)))
    fp = FirstPassage.from_tracked(scene.save_at, [0.6], held, jnp.full(4, 0.25), "monte_carlo", stderr=False)
    # passed 0.6: path 0 from t = 10; path 2 from t = 5, before it diverged at t = 20; path 1 diverged at t = 10
    np.testing.assert_allclose(np.asarray(fp.probability)[:, 0], [0.25, 0.5, 0.5], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(fp.lost_mass)[:, 0], [0.0, 0.25, 0.25], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(held)[[0, 3]], np.asarray(values)[[0, 3]])
