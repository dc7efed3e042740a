r"""The error of a DPIM density, from randomised point sets.

A DPIM point set is deterministic, so its error cannot be read off its own points. Randomising the
set keeps the method and makes the error measurable. Each replicate

1. draws an Owen-scrambled Sobol base set (seed ``k``) and passes it through the same selection as
   ``jdpim.select_points`` (rank rearrangement, Voronoi-cell probabilities, weighted rearrangement);
2. shifts every elementary angle by one uniform random amount modulo ``2 pi`` (a Cranley-Patterson
   rotation). The response is ``2 pi``-periodic in each angle and the angles are uniform, so each shifted
   point is uniformly distributed and the replicate's kernel density is an unbiased estimate of the
   kernel-smoothed density, whatever the point set (without the shift, replicates share the structure
   of the selection and their spread understates the error).

The replicates are independent and identically distributed point sets of the same size, so the spread
of their densities,

.. math::  s(y) = \Big(\frac{1}{R - 1}\sum_{k=1}^{R} \big(p_k(y) - \bar p(y)\big)^2\Big)^{1/2},

estimates the error of one DPIM run of that size (and ``s / sqrt(R)`` that of their mean). The
programme is compiled once: only the points change between replicates.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np
from scipy.stats import qmc

from ._distributions import ANGLE
from ._points import PointSet, _map, assign_probabilities
from ._pytree import check_int


def randomised_points(distributions: tuple, n_points: int, seed: int, *, n_reference: int | None = None) -> PointSet:
    """A GF-discrepancy point set from an Owen-scrambled Sobol base set (``seed``), selected as usual, with
    its angle coordinates rotated by a random shift modulo ``2 pi`` (module docstring).

    Results are cached.

    Examples:
        >>> import jdpim
        >>> ps = jdpim.randomised_points((jdpim.Uniform(), jdpim.Uniform()), 32, seed=1)
        >>> ps.theta.shape
        (32, 2)
    """
    n_points = check_int("n_points", n_points, low=2)
    seed = check_int("seed", seed, low=0)
    if n_reference is None:
        n_reference = 2 ** int(np.clip(np.ceil(np.log2(1000 * n_points)), 18, 23))
    return _randomised_points(tuple(distributions), n_points, seed, check_int("n_reference", n_reference, low=2))


@functools.lru_cache(maxsize=64)
def _randomised_points(distributions, n_points, seed, n_reference) -> PointSet:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol balance warning for n not a power of 2
        u = qmc.Sobol(len(distributions), scramble=True, seed=seed).random(n_points)
    ranks = np.argsort(np.argsort(u, axis=0, kind="stable"), axis=0, kind="stable")
    ps = assign_probabilities(_map(distributions, (ranks + 0.5) / n_points), distributions, n_reference, seed + 1)
    shift = np.random.default_rng(seed).uniform(0.0, 2 * np.pi, len(distributions))
    angle = np.array([d == ANGLE for d in distributions])
    theta = np.where(angle, np.mod(ps.theta + np.pi + shift, 2 * np.pi) - np.pi, ps.theta)
    return PointSet(theta=theta, weights=ps.weights, distributions=ps.distributions)
