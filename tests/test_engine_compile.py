"""What the integration shares between runs: one compiled program for every layout of as many saved times."""

import numpy as np

import jdpim
from jdpim.methods._paths import simulate


def test_saved_times_of_the_same_count_share_one_program():
    """The saved times reach the program as data: scenes that differ only in where their one saved time lies run
    the program of the methods' example scene (compiled once a session), and each keeps its own times; ``t = 0``
    saved gives the start itself."""
    base = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.01)
    first = jdpim.monte_carlo(base, n_samples=64)
    before = simulate._cache_size()
    runs = {t: jdpim.monte_carlo(base.replace(save_at=(t,)), n_samples=64) for t in (0.0, 0.5)}
    assert simulate._cache_size() == before
    assert runs[0.5].times == (0.5,)
    np.testing.assert_array_equal(np.asarray(runs[0.0].states)[:, 0], np.tile(np.ravel(base.initial_state()), (64, 1)))
    assert not np.array_equal(np.asarray(runs[0.5].states), np.asarray(first.states))
