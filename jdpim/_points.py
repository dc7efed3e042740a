r"""Representative points and their assigned probabilities (GF-discrepancy point selection).

Chen, Yang & Li (2016), Structural Safety 59:20-31; the authors' ``SelectPoint_GF.m``:

1. a Sobol base set (skipping the origin);
2. rank rearrangement: each coordinate moved to the mid-quantiles ``F_j^{-1}((rank - 1/2) / N)``;
3. assigned probabilities ``P_q`` = probability of the Voronoi cell of ``theta_q`` (in standardised
   coordinates), estimated by assigning scrambled-Sobol reference samples to their nearest point;
4. rearrangement with the weights ``theta_jq <- F_j^{-1}(sum_{k: theta_jk < theta_jq} P_k + P_q / 2)``.

The GF-discrepancy ``D_GF = max_j sup_x |sum_q P_q 1[theta_jq <= x] - F_j(x)|`` after step 4 equals
``max_q P_q / 2``.
"""

from __future__ import annotations

import functools
import math
import warnings
from typing import Any

import numpy as np
from scipy.spatial import cKDTree
from scipy.stats import qmc

from ._cpu import host_memory
from ._distributions import Distribution
from ._pytree import check_int, pytree_dataclass, static_field


@pytree_dataclass
class PointSet:
    """Representative points ``theta`` (shape ``(N, d)``) with probabilities ``weights`` (``(N,)``, sum 1).

    ``distributions`` (static) gives the marginal distribution of each of the ``d`` coordinates.
    """

    theta: Any
    weights: Any
    distributions: tuple = static_field()

    @property
    def n_points(self) -> int:
        return int(np.shape(self.theta)[0])

    def discrepancy(self) -> float:
        """The GF-discrepancy of the set (NumPy; not traceable)."""
        return gf_discrepancy(np.asarray(self.theta), np.asarray(self.weights), self.distributions)


def gf_discrepancy(theta: np.ndarray, weights: np.ndarray, distributions: tuple[Distribution, ...]) -> float:
    r"""``D_GF = max_j sup_x |F_hat_j(x) - F_j(x)|`` with ``F_hat_j(x) = sum_q P_q 1[theta_jq <= x]``.

    Args:
        theta: points, shape ``(N, d)``.
        weights: probabilities, shape ``(N,)``.
        distributions: the ``d`` marginal distributions.
    """
    theta = np.asarray(theta, dtype=float)
    weights = np.asarray(weights, dtype=float)
    worst = 0.0
    for j, dist in enumerate(distributions):
        order = np.argsort(theta[:, j], kind="stable")
        F = dist.cdf(theta[order, j])
        upper = np.cumsum(weights[order])
        lower = upper - weights[order]
        worst = max(worst, float(np.max(np.maximum(np.abs(upper - F), np.abs(lower - F)))))
    return worst


def select_points(
    distributions: tuple[Distribution, ...], n_points: int, *, n_reference: int | None = None, seed: int = 0
) -> PointSet:
    """Representative points by GF-discrepancy point selection (steps 1-4 of the module doc).

    Args:
        distributions: marginal distribution of each input coordinate (independent).
        n_points: number of points ``N`` (>= 2).
        n_reference: number of reference samples for the Voronoi probabilities, or ``None`` for
            ``1000 N`` rounded up to a power of two, between ``2^18`` and ``2^23`` (each ``P_q`` then
            carries about 3 % estimation noise at N = 1000).
        seed: seed of the scrambled Sobol reference samples.

    Returns:
        A :class:`PointSet` (NumPy float64 arrays). Results are cached.

    Examples:
        >>> import jdpim
        >>> ps = jdpim.select_points((jdpim.Uniform(), jdpim.Uniform()), 64)
        >>> ps.theta.shape, round(float(ps.weights.sum()), 12)
        ((64, 2), 1.0)
    """
    n_points = check_int("n_points", n_points, low=2)
    if n_reference is None:
        n_reference = max(n_points, 2 ** int(np.clip(math.ceil(math.log2(1000 * n_points)), 18, 23)))
    n_reference = check_int("n_reference", n_reference, low=n_points)
    need = 64 * (n_points + n_reference) * max(1, len(tuple(distributions)))  # points, samples, their work
    if need > host_memory() // 2:
        raise ValueError(
            f"n_points={n_points} needs about {need / 2**30:.3g} GiB for the point selection, more than half of "
            f"this host's {host_memory() / 2**30:.3g} GiB: use fewer n_points"
        )
    seed = check_int("seed", seed, low=0)
    distributions = tuple(distributions)
    if not distributions:
        raise ValueError("distributions must name at least one input coordinate")
    return _select_points(distributions, n_points, n_reference, seed)


@functools.lru_cache(maxsize=32)
def _select_points(distributions, n_points, n_reference, seed) -> PointSet:
    d = len(distributions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol balance warning for n not a power of 2
        base = qmc.Sobol(d, scramble=False)
        base.fast_forward(1)
        u = base.random(n_points)
    ranks = np.argsort(np.argsort(u, axis=0, kind="stable"), axis=0, kind="stable")
    return assign_probabilities(_map(distributions, (ranks + 0.5) / n_points), distributions, n_reference, seed)


def assign_probabilities(theta: np.ndarray, distributions, n_reference: int, seed: int) -> PointSet:
    """Steps 3-4: Voronoi-cell probabilities from scrambled-Sobol reference samples, then rearrangement."""
    d = len(distributions)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol balance warning for n not a power of 2
        ref = qmc.Sobol(d, scramble=True, seed=seed).random(n_reference)
    weights = voronoi_probabilities(
        _standardise(distributions, theta), _standardise(distributions, _map(distributions, ref))
    )
    return PointSet(theta=rearrange(theta, weights, distributions), weights=weights, distributions=distributions)


def voronoi_probabilities(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Share of ``reference`` samples (``(M, d)``) nearest to each point (``(N, d)``); shape ``(N,)``."""
    _, nearest = cKDTree(points).query(reference, workers=-1)
    return np.bincount(nearest, minlength=points.shape[0]) / reference.shape[0]


def rearrange(theta: np.ndarray, weights: np.ndarray, distributions) -> np.ndarray:
    """Step 4: move each coordinate to ``F^{-1}(P-weighted mid-rank)``; the GF-discrepancy becomes ``max P / 2``."""
    out = np.empty_like(theta)
    for j, dist in enumerate(distributions):
        order = np.argsort(theta[:, j], kind="stable")
        w = weights[order]
        out[order, j] = dist.ppf(np.cumsum(w) - w / 2)
    return out


def _map(distributions, u):
    return np.stack([dist.ppf(u[:, j]) for j, dist in enumerate(distributions)], axis=1)


def _standardise(distributions, theta):
    """Coordinates centred and scaled by each distribution's mean and std (NumPy or JAX arrays)."""
    centre = np.array([dist.mean for dist in distributions])
    scale = np.array([dist.std for dist in distributions])
    return (theta - centre[None, :]) / scale[None, :]
