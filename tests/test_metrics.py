"""Density distances against closed forms for two normal densities."""

import numpy as np
import pytest
from scipy import special

from jdpim import metrics

GRID = np.linspace(-12, 12, 24001)


def normal(mu):
    return np.exp(-0.5 * (GRID - mu) ** 2) / np.sqrt(2 * np.pi)


@pytest.mark.parametrize("mu", [0.1, 1.0, 3.0])
def test_l1_and_hellinger_of_shifted_normals(mu):
    p, q = normal(0.0), normal(mu)
    assert metrics.l1(p, q, GRID) == pytest.approx(2 * (2 * special.ndtr(mu / 2) - 1), rel=1e-6)
    assert metrics.hellinger(p, q, GRID) == pytest.approx(np.sqrt(1 - np.exp(-mu * mu / 8)), rel=1e-5)


def test_identical_densities_have_zero_distance():
    p = normal(0.3)
    assert metrics.l1(p, p, GRID) == 0.0
    assert metrics.hellinger(p, p, GRID) == 0.0
    assert metrics.peak_relative_error(p, p) == 0.0


def test_peak_relative_error_looks_near_the_peak_only():
    q = normal(0.0)
    p = q.copy()
    p[np.abs(GRID) > 3] += 0.05  # far-tail error is ignored at level 0.5
    p[np.argmax(q)] *= 1.1
    assert metrics.peak_relative_error(p, q) == pytest.approx(0.1, rel=1e-9)


def test_two_dimensional_l1():
    x, v = np.linspace(-8, 8, 801), np.linspace(-8, 8, 801)
    p = np.outer(np.exp(-0.5 * x**2), np.exp(-0.5 * v**2)) / (2 * np.pi)
    assert metrics.l1(p, 0 * p, (x, v)) == pytest.approx(1.0, abs=1e-8)


def test_batch_spread():
    assert metrics.batch_spread([1.0, 1.0, 1.0]) == 0.0
    assert metrics.batch_spread([0.0, 2.0]) == pytest.approx(1.0)
