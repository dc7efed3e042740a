"""jdpim.design.minimise: converges on noisy problems with known optima, keeps to its bounds, grows its sample
only when the gradient is lost in the noise, and refuses bad inputs in one line."""

import numpy as np
import optax
import pytest

import jdpim

SE = 0.02  # standard error of one batch's value and gradient


def noisy_quadratic(centre, calls=None):
    """``(x - centre)^2`` summed, estimated with independent noise of standard error ``SE`` per batch; the noise
    depends on the seed only (common random numbers: the same seed gives the same errors at every x)."""

    def objective(x, seed):
        if calls is not None:
            calls.append((x.copy(), seed))
        e = np.random.default_rng(seed).normal(size=1 + x.size) * SE
        return float(np.sum((x - centre) ** 2) + e[0]), SE, 2 * (x - centre) + e[1:], np.full(x.size, SE)

    return objective


def test_converges_to_an_interior_optimum_with_growing_samples():
    calls = []
    d = jdpim.design.minimise(
        noisy_quadratic(0.3, calls), [0.9], [(0.0, 1.0)], optax.sgd(0.3), max_steps=60, max_batches=16
    )
    assert d.converged
    # stopped where the gradient 2 (x - 0.3) is within 2 standard errors (SE / 4 at 16 batches) of zero,
    # up to the noise of the averaged gradient itself: |x - 0.3| <= (2 + 3) * SE / 4 / 2
    assert abs(d.x[0] - 0.3) <= 5 * SE / 8
    assert d.batches[0] == 1 and d.batches[-1] == 16 and np.all(np.diff(d.batches) >= 0)
    assert d.value_stderr == pytest.approx(SE / 4)
    assert d.n_evaluations == len(calls)
    # common random numbers: batch k is drawn with seed k at every design
    assert {s for _, s in calls} == set(range(16))
    assert d.history_x.shape == (d.batches.size, 1) and d.history_x[-1, 0] == d.x[0]


def test_stays_in_its_bounds_and_stops_at_an_active_bound():
    # the optimum (1.5, -0.2) lies outside the box: the answer is the corner (1, 0), and no step leaves the box
    d = jdpim.design.minimise(
        noisy_quadratic(np.array([1.5, -0.2])), [0.5, 0.5], [(0.0, 1.0), (0.0, 1.0)], optax.adam(0.2), max_steps=40
    )
    assert d.converged
    np.testing.assert_array_equal(d.x, [1.0, 0.0])
    assert np.all(d.history_x >= 0.0) and np.all(d.history_x <= 1.0)
    # at the corner the gradient points out of the box: it is projected away, no extra batches are drawn
    assert d.batches[-1] < 8


def test_stops_after_max_steps_without_convergence():
    d = jdpim.design.minimise(noisy_quadratic(0.3), [0.9], [(0.0, 1.0)], optax.sgd(1e-3), max_steps=3)
    assert not d.converged and d.history_x.shape == (4, 1) and d.n_evaluations == 4


def test_a_gradient_lost_in_the_noise_is_not_taken_for_a_flat_one_with_gradient_tol():
    # a slope of 0.2 (the quadratic at x = 0.4, centre 0.3) with batches of standard error 0.5: 2 batches cannot
    # tell it from zero; without a tolerance that stop reads as converged, with gradient_tol = 0.1 it does not
    def objective(x, seed):  # estimates whose errors happen to be zero: the stop is deterministic
        return float((x[0] - 0.3) ** 2), 0.5, [2 * (x[0] - 0.3)], [0.5]

    args = (objective, [0.4], [(0.0, 1.0)], optax.sgd(0.1))
    plain = jdpim.design.minimise(*args, max_batches=2)
    assert plain.converged and plain.history_x.shape == (1, 1)
    with pytest.warns(jdpim.design.DesignWarning, match="a slope up to 0.707 could hide"):
        strict = jdpim.design.minimise(*args, max_batches=2, gradient_tol=0.1)
    assert not strict.converged and strict.history_x.shape == (1, 1)
    # resolved to within the tolerance: converged, without a warning
    d = jdpim.design.minimise(
        noisy_quadratic(0.3), [0.9], [(0.0, 1.0)], optax.sgd(0.3), max_steps=60, max_batches=16, gradient_tol=0.05
    )
    assert d.converged and 2 * d.gradient_stderr[0] <= 0.05


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        ({"x0": [1.5]}, ValueError, "inside bounds"),
        ({"x0": [np.nan]}, ValueError, "x0 must be a finite"),
        ({"x0": ["a"]}, TypeError, "x0 must be"),
        ({"bounds": [(0.0, 1.0), (0.0, 1.0)]}, ValueError, "bounds must be 1"),
        ({"bounds": [(1.0, 0.0)]}, ValueError, "low < high"),
        ({"optimiser": "adam"}, TypeError, "optimiser must be an optax"),
        ({"objective": 3}, TypeError, "objective must be a function"),
        ({"max_steps": 0}, ValueError, "max_steps must be an integer >= 1"),
        ({"batches": 4, "max_batches": 2}, ValueError, "max_batches must be an integer >= 4"),
        ({"objective": lambda x, s: (0.0, 0.1, [0.0, 0.0], [0.1, 0.1])}, ValueError, "gradient and its stderrs of 1"),
        ({"objective": lambda x, s: (np.nan, 0.1, [0.0], [0.1])}, ValueError, "non-finite"),
        ({"objective": lambda x, s: 0.0}, ValueError, "must return"),
        ({"gradient_tol": 0.0}, ValueError, "gradient_tol must be a positive number or 1"),
        ({"gradient_tol": [0.1, 0.1]}, ValueError, "gradient_tol must be a positive number or 1"),
    ],
)
def test_refuses_bad_inputs(kwargs, error, match):
    args = {"objective": noisy_quadratic(0.3), "x0": [0.5], "bounds": [(0.0, 1.0)], "optimiser": optax.sgd(0.1)}
    args.update(kwargs)
    with pytest.raises(error, match=match):
        jdpim.design.minimise(args.pop("objective"), args.pop("x0"), args.pop("bounds"), args.pop("optimiser"), **args)
