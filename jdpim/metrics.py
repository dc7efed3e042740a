r"""Distances between densities tabulated on a grid (trapezoidal quadrature).

* ``l1``: ``int |p - q|`` (twice the total-variation distance; 0 to 2);
* ``hellinger``: ``sqrt(1/2 int (sqrt p - sqrt q)^2)`` (0 to 1);
* ``peak_relative_error``: ``max |p - q| / max q`` over the region where ``q >= level * max q``.
"""

from __future__ import annotations

import numpy as np


def _trapz(y, x):
    return float(np.trapezoid(y, x))


def l1(p, q, grid) -> float:
    """``int |p - q| dy`` on a 1-D ``grid``; for 2-D ``p, q`` pass ``grid=(x_grid, v_grid)``."""
    return _integrate(np.abs(np.asarray(p, float) - np.asarray(q, float)), grid)


def hellinger(p, q, grid) -> float:
    """Hellinger distance ``sqrt(1/2 int (sqrt p - sqrt q)^2)``; negative values are clipped to 0 first."""
    d = (np.sqrt(np.clip(p, 0, None)) - np.sqrt(np.clip(q, 0, None))) ** 2
    return float(np.sqrt(0.5 * max(_integrate(d, grid), 0.0)))


def peak_relative_error(p, q, level: float = 0.5) -> float:
    """``max |p - q| / max q`` where ``q >= level * max q`` (error near the peak of the reference ``q``)."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    region = q >= level * q.max()
    return float(np.max(np.abs(p - q)[region]) / q.max())


def _integrate(f, grid):
    if isinstance(grid, tuple):
        x, v = grid
        return _trapz(np.trapezoid(f, v, axis=1), x)
    return _trapz(f, grid)


def batch_spread(values) -> float:
    """Standard error of the mean of independent batch estimates (e.g. of an error metric)."""
    values = np.asarray(values, float)
    return float(values.std(ddof=1) / np.sqrt(values.size))
