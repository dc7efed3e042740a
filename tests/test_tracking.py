"""Statistics tracked along paths (``jdpim.tracking``): a statistic defined here runs through Monte Carlo and
DPIM; the built-ins agree with the saved states; first passage holds a diverged path's maximum."""

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim.tracking import AbstractTracked, Function, ImpactCounts, Integral, RunningMaximum, track

# saved at every step, so that the states show what a statistic sees at the start and the end of every step
SCENE = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=0.5, dt=0.01, save_at=tuple(np.arange(51) * 0.01))


@dataclasses.dataclass(frozen=True)
class RunningMinimum(AbstractTracked):
    """The smallest velocity so far: a statistic written outside the library, in one class."""

    def init(self, model, q, v, e):
        return v

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        return jnp.minimum(acc, v_new)


MC = jdpim.MonteCarlo(n_samples=64, seed=2)  # one set of paths for every test: compiled once


# slow: the default tier checks a statistic of one's own along the paths in the MC cell, and a statistic tracked
# along DPIM's paths (the running maximum, weighted) in
# test_first_passage::test_probabilities_grow_with_time_fall_with_the_level_and_carry_binomial_errors
@pytest.mark.parametrize("method", [MC, pytest.param(jdpim.DPIM(n_points=64), marks=pytest.mark.slow)])
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
    method = MC
    states = np.asarray(jdpim.solve(SCENE, method).states)
    np.testing.assert_array_equal(np.asarray(track(SCENE, method, Function()).values), states)
    integral = np.asarray(track(SCENE, method, Integral(energy)).values)[..., 0]
    e = energy(np.moveaxis(states, -1, 0))
    trapezoid = np.concatenate(
        [np.zeros((len(states), 1)), np.cumsum(0.5 * SCENE.dt * (e[:, 1:] + e[:, :-1]), axis=1)], 1
    )
    np.testing.assert_allclose(integral, trapezoid, rtol=1e-5, atol=1e-9)


def test_track_refuses_what_it_cannot_run():
    with pytest.raises(ValueError, match="MonteCarlo or jdpim.DPIM"):
        track(SCENE, jdpim.PathIntegration(), RunningMinimum())
    with pytest.raises(TypeError, match="statistic must be"):
        track(SCENE, jdpim.MonteCarlo(n_samples=8), energy)


def test_the_running_maximum_leaves_out_states_beyond_the_divergence_bound():
    """A state beyond ``bound`` counts as diverged, like a non-finite one: left out of the maximum, and the path
    marked and its maximum held from then on."""
    running = RunningMaximum(lambda s: s[0], bound=(10.0, 10.0))
    zero = (jnp.zeros(1),) * 3
    acc = running.init(None, jnp.array([0.5]), jnp.array([0.0]), zero)
    for x, v, expected in [(2.0, 1.0, [2.0, 0.0]), (50.0, 1.0, [2.0, 1.0]), (3.0, 1.0, [2.0, 1.0])]:
        acc = running.update(None, acc, None, None, jnp.array([x]), jnp.array([v]), zero, 0.01)
        np.testing.assert_array_equal(np.asarray(acc), expected)
    free = RunningMaximum(lambda s: s[0])
    assert free.update(None, acc, None, None, jnp.array([50.0]), jnp.array([1.0]), zero, 0.01)[0] == 50.0


@dataclasses.dataclass(frozen=True)
class StepsAbove(AbstractTracked):
    """Steps that end with the velocity above ``level``: a field given as an array is traced data."""

    level: Any

    def init(self, model, q, v, e):
        return jnp.zeros(1, q.dtype)

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        return acc + (v_new > self.level).astype(acc.dtype)


def test_array_fields_of_a_statistic_are_traced_and_the_rest_is_structure():
    """A statistic is a pytree: its array fields are leaves (a new value reuses the compiled run), its functions
    and numbers structure (a new one compiles anew)."""
    low, high = StepsAbove(np.asarray(0.1)), StepsAbove(jnp.asarray(0.2))
    assert jax.tree_util.tree_structure(low) == jax.tree_util.tree_structure(high)
    assert jax.tree_util.tree_leaves(high) == [high.level]
    assert jax.tree_util.tree_leaves(StepsAbove(0.1)) == []
    bounded, free = RunningMaximum(energy, np.ones(2)), RunningMaximum(energy)
    assert jax.tree_util.tree_leaves(free) == [] and len(jax.tree_util.tree_leaves(bounded)) == 1
    doubled = jax.tree_util.tree_map(lambda a: 2 * a, bounded)
    assert isinstance(doubled, RunningMaximum) and doubled.quantity is energy
    np.testing.assert_array_equal(doubled.bound, [2.0, 2.0])
    counts = ImpactCounts(SCENE.impacts, np.linspace(0.0, 1.0, 5))  # impact statistics' speed bins: traced edges
    assert jax.tree_util.tree_structure(counts) == jax.tree_util.tree_structure(
        dataclasses.replace(counts, edges=np.linspace(0.0, 2.0, 5))
    )


@dataclasses.dataclass(frozen=True)
class Position(AbstractTracked):
    """The coordinates at the saved times, left out (NaN) once a path has diverged, as densities leave it out."""

    def init(self, model, q, v, e):
        return q

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        return q_new

    def finalise(self, values, diverged):
        return jnp.where(diverged[..., None], jnp.nan, values)


def test_finalise_sees_the_paths_that_diverged_as_the_densities_do():
    """``x'' - 4 x = xi`` diverges (beyond 6.6e7 in x by t = 10 on most paths): the statistic's ``finalise`` gets
    the same paths, at the same saved times, as the result leaves out of its densities."""
    model = jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], stiffness=[[-4.0]])
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.01), t_end=12.0, dt=0.01, save_at=(2.0, 12.0))
    method = jdpim.MonteCarlo(n_samples=16, seed=0)
    tracked = np.asarray(track(scene, method, Position()).values)[..., 0]
    with pytest.warns(jdpim.NonFiniteWarning, match="non-finite or diverged"):
        states = np.asarray(jdpim.solve(scene, method).states)[..., 0]
    assert np.isfinite(tracked[:, 0]).all() and np.isnan(tracked[:, 1]).sum() >= 8
    np.testing.assert_array_equal(tracked, states)
