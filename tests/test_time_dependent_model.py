"""A model whose acceleration depends on the time: the integrator hands it the time of every RK4 stage."""

from typing import Any

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import jdpim
from jdpim._pytree import pytree_dataclass

ALPHA, OMEGA, AMPLITUDE, FREQUENCY = 0.1, 1.0, 0.5, 1.3


@pytree_dataclass
class HarmonicLoad(jdpim.VibroImpactOscillator):
    """``x'' + alpha x' + omega^2 x = A cos(W t) + xi(t)``: a deterministic load beside the noise."""

    amplitude: Any = AMPLITUDE
    frequency: Any = FREQUENCY

    @property
    def time_dependent(self) -> bool:
        return True

    def state_acceleration_at(self, t, q, v, xi):
        return self.state_acceleration(q, v, xi) + self.amplitude * jnp.cos(self.frequency * t)


def test_the_time_reaches_the_model():
    """Without noise every path is the forced response from rest, to RK4's and float32's accuracy."""
    times = (2.5, 5.0, 7.5, 10.0)
    model = HarmonicLoad(alpha=ALPHA, gamma=None, barrier=None, omega=OMEGA)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.0), t_end=10.0, dt=0.01, save_at=times)
    states = np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=2, seed=0)).states)

    def rhs(t, y):
        return [y[1], -ALPHA * y[1] - OMEGA**2 * y[0] + AMPLITUDE * np.cos(FREQUENCY * t)]

    exact = solve_ivp(rhs, (0.0, 10.0), [0.0, 0.0], t_eval=times, method="DOP853", rtol=1e-11, atol=1e-13).y.T
    assert np.abs(exact).max() > 0.5  # the load moves the oscillator
    np.testing.assert_allclose(states[0], exact, atol=2e-5)
    np.testing.assert_array_equal(states[0], states[1])
    with pytest.raises(ValueError, match="LikelihoodRatio needs a model whose forces do not depend on the time"):
        jdpim.LikelihoodRatio().check(scene.replace(model=model.replace(barrier=0.0)), "alpha")
