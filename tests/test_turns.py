"""Angles in turns: multiples modulo one exact to two roundings, the cosine and sine of turns to about an ulp,
and the DPIM random functions they give at a long horizon in float32."""

import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim import _excitation as ex
from jdpim._turns import cos_sin_turns, fractional_multiples


@pytest.mark.parametrize("offset", [0.0, 0.5])
@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_fractional_multiples_to_two_roundings(dtype, offset):
    """``frac(m (offset + t))`` against exact rational arithmetic on ``t``'s own value, ``m`` up to 4e4: within
    two ulp of 8 (two roundings of numbers below ``1 + m / 4096``), where ``m t`` itself in ``dtype`` is off by up
    to 0.5 ulp of ``4e4`` (more than 0.001 turn in float32)."""
    rng = np.random.default_rng(0)
    with jax.enable_x64(dtype == jnp.float64):
        t = jnp.asarray(rng.uniform(-1.0, 1.0, (40, 1)), dtype)
        m = np.concatenate([[0, 1, 2, 2047, 2048, 2049], rng.integers(0, 40_000, 34)])[None, :]
        got = np.asarray(jax.jit(lambda t: fractional_multiples(t, m, offset))(t), np.float64)
    turns = [Fraction(float(a)) + Fraction(offset) for a in np.asarray(t, np.float64)[:, 0]]
    exact = np.array([[float(a * int(k) % 1) for k in m[0]] for a in turns])
    err = np.abs(got - exact)
    err = np.minimum(err, 1.0 - err)  # 0 and 1 are the same turn
    assert np.all((got >= 0.0) & (got < 1.0))
    assert err.max() <= 2 * 8 * np.finfo(dtype).eps


def test_fractional_multiples_reject_an_inexact_offset():
    with pytest.raises(ValueError, match="offset must be a multiple of 2"):
        fractional_multiples(jnp.zeros((1, 1)), np.ones((1, 3), int), offset=0.1)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_cos_sin_turns_within_two_ulp(dtype):
    s = np.concatenate([np.random.default_rng(1).uniform(0.0, 1.0, 100_000), np.arange(16) / 16, [1 - 2**-24]])
    with jax.enable_x64(dtype == jnp.float64):
        s = jnp.asarray(s, dtype)
        cos, sin = jax.jit(cos_sin_turns)(s)
    angle = 2 * np.pi * np.asarray(s, np.longdouble)
    eps = np.finfo(dtype).eps
    assert np.abs(np.asarray(cos, np.longdouble) - np.cos(angle)).max() <= 2 * eps
    assert np.abs(np.asarray(sin, np.longdouble) - np.sin(angle)).max() <= 2 * eps


def test_rayleigh_random_functions_at_a_long_horizon_in_float32():
    """t = 200 s, dt = 0.01 s: 6446 harmonics, so ``m_k Theta`` reaches 2e4. The float32 coefficients of 500 points
    have radii ``r = |X_k + i Y_k|`` with E[r^2] = 2 within 4 standard errors (of the points' means) and none beyond
    the float32 tail (``sqrt(-2 ln(eps / 4))`` = 5.9), and equal the float64 coefficients of the same turns
    ``Theta / 2 pi`` in phase to 1e-5 rad and in their uniform ``u = exp(-r^2 / 2)`` to 1e-6. (Forming ``m Theta``
    in float32 gave phases off by 1e-3 rad, uniforms off by 2e-4, and r = 13.2 wherever ``m (Theta1 + pi) / 2 pi``
    rounded to an integer: 0.8 harmonics per point, E[r^2] = 2.02.)"""
    grid = jdpim.SpectralRepresentation().grid(t_end=200.0, dt=0.01)
    theta = np.random.default_rng(2).uniform(-math.pi, math.pi, (500, 2)).astype(np.float32)
    turns = theta * np.float32(1 / (2 * math.pi))  # as the float32 code rounds them

    def coefficients(theta):
        c = jax.jit(jax.vmap(lambda t: ex.random_function_coefficients(t, grid, jnp.eye(1, dtype=t.dtype))))(theta)
        return np.asarray(c[:, 0, 1:], np.complex128) / grid.amplitude()[1:]

    c32 = coefficients(jnp.asarray(theta))
    with jax.enable_x64(True):
        c64 = coefficients(jnp.asarray(2 * math.pi * turns.astype(np.float64)))
    r2 = np.abs(c32) ** 2
    per_point = r2.mean(axis=1)  # a point's harmonics are not independent: its mean is one sample
    assert abs(per_point.mean() - 2.0) < 4 * per_point.std() / math.sqrt(len(per_point))
    assert r2.max() < -2 * math.log(np.finfo(np.float32).eps / 4)
    assert np.abs(np.angle(c32 / c64)).max() < 1e-5
    assert np.abs(np.exp(-r2 / 2) - np.exp(-(np.abs(c64) ** 2) / 2)).max() < 1e-6
