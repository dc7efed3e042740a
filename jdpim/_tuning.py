r"""Tuning with optax: point sets with lower GF-discrepancy, and kernel bandwidths.

**Point sets.** After the rearrangement of step 4 (``jdpim.select_points``) the GF-discrepancy equals
``max_q P_q / 2`` exactly, so lowering it means evening out the Voronoi cell
probabilities. Neither the max nor the nearest-point assignment is differentiable; the surrogate uses

.. math::  \tilde P_q = \frac1M \sum_m \operatorname{softmax}_q\big(-\|r_m - s_q\|^2 / (2\tau^2)\big),
           \qquad L = \tfrac12 \big(\textstyle\sum_q \tilde P_q^{\,p}\big)^{1/p}

(soft Voronoi probabilities from ``M`` reference samples ``r_m`` in standardised coordinates, a p-norm
as smooth max), minimised over the point locations (as logits of their marginal CDF values) with
``optax.adam``. The result is finished like ``select_points``: hard Voronoi probabilities from many
reference samples, then the rearrangement, so its true ``gf_discrepancy`` is ``max P / 2`` again.

**Bandwidth.** ``sigma`` minimises either the weighted leave-one-out negative log-likelihood

.. math::  -\sum_i P_i \log \frac{\sum_{j \ne i} P_j K_\sigma(y_i, y_j)}{1 - P_i}

(likelihood cross-validation on the points; ``K`` reflected at the barrier) or, when a reference PDF
exists, the integrated squared error against it; the optimiser works on ``log sigma``.
"""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import optax
from scipy.stats import qmc

from ._distributions import elementary_ppf
from ._points import PointSet, _standardise, assign_probabilities
from ._pytree import check_int, check_real
from .results._density import bandwidth, kde, kernel_matrix


def _theta(distributions, u):
    return jnp.stack([elementary_ppf(d, u[:, j]) for j, d in enumerate(distributions)], axis=1)


def soft_voronoi_probabilities(points, reference, tau):
    """Soft cell probabilities ``mean_m softmax_q(-|r_m - s_q|^2 / (2 tau^2))``; shape ``(N,)``.

    ``points``: ``(N, d)``; ``reference``: ``(M, d)`` samples of the input distribution (same coordinates).
    """
    d2 = jnp.sum((reference[:, None, :] - points[None, :, :]) ** 2, axis=-1)
    return jnp.mean(jax.nn.softmax(-d2 / (2.0 * tau * tau), axis=1), axis=0)


def refine_points(
    points: PointSet,
    *,
    steps: int = 200,
    learning_rate: float = 2e-3,
    softness: float = 0.3,
    p: float = 8.0,
    n_reference: int | None = None,
    seed: int = 1,
) -> PointSet:
    r"""A point set with more even cell probabilities (lower GF-discrepancy), refined with optax.

    Args:
        points: the starting set, e.g. ``jdpim.select_points(...)`` (Sobol + rearrangement).
        steps: ``optax.adam`` steps.
        learning_rate: step size on the logits of the points' marginal CDF values.
        softness: temperature ``tau`` of the soft assignment, as a fraction of the mean
            nearest-neighbour distance of the starting points (standardised coordinates).
        p: exponent of the p-norm smooth max (larger: closer to the max, rougher).
        n_reference: reference samples of the surrogate (default ``16 N``, at most ``2^14``).
        seed: seed of the scrambled Sobol reference samples.

    Returns:
        A :class:`PointSet` after the final Voronoi probabilities and rearrangement (NumPy arrays).

    Examples:
        >>> import jdpim
        >>> base = jdpim.select_points((jdpim.Uniform(), jdpim.Uniform()), 32, n_reference=2**15)
        >>> better = jdpim.refine_points(base, steps=50)
        >>> better.theta.shape
        (32, 2)
    """
    steps = check_int("steps", steps, low=1)
    check_real("learning_rate", learning_rate, low=0.0, low_open=True)
    check_real("softness", softness, low=0.0, low_open=True)
    check_real("p", p, low=1.0)
    dists = tuple(points.distributions)
    n, d = np.shape(points.theta)
    m = min(16 * n, 2**14) if n_reference is None else check_int("n_reference", n_reference, low=n)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol balance warning for m not a power of 2
        ref_u = qmc.Sobol(d, scramble=True, seed=seed).random(m)
    u0 = np.stack([dist.cdf(np.asarray(points.theta)[:, j]) for j, dist in enumerate(dists)], axis=1)
    u0 = np.clip(u0, 1e-6, 1 - 1e-6)
    s0 = np.asarray(_standardise(dists, jnp.asarray(points.theta)))
    nn = np.sort(np.sqrt(((s0[:, None] - s0[None]) ** 2).sum(-1)), axis=1)[:, 1]
    tau = softness * float(nn.mean())
    reference = _standardise(dists, _theta(dists, jnp.asarray(ref_u)))

    def loss(z):
        s = _standardise(dists, _theta(dists, jax.nn.sigmoid(z)))
        P = soft_voronoi_probabilities(s, reference, tau)
        return 0.5 * jnp.sum(P**p) ** (1.0 / p)

    opt = optax.adam(learning_rate)

    @jax.jit
    def run(z):
        def body(carry, _):
            z, state = carry
            g = jax.grad(loss)(z)
            updates, state = opt.update(g, state, z)
            return (optax.apply_updates(z, updates), state), None

        (z, _), _ = jax.lax.scan(body, (z, opt.init(z)), None, length=steps)
        return z

    z = run(jnp.asarray(np.log(u0) - np.log1p(-u0)))
    theta = np.asarray(_theta(dists, jax.nn.sigmoid(z)), dtype=float)
    n_exact = 2 ** int(np.clip(math.ceil(math.log2(1000 * n)), 18, 23))
    return assign_probabilities(theta, dists, n_exact, seed + 1)


def loo_log_likelihood(samples, weights, sigma, barrier=None):
    r"""Weighted leave-one-out log-likelihood ``sum_i P_i log(sum_{j != i} P_j K(y_i, y_j) / (1 - P_i))``.

    Args:
        samples: shape ``(N,)`` (non-finite samples must be removed first).
        weights: shape ``(N,)``.
        sigma: kernel standard deviation (> 0).
        barrier: reflect the kernel at this position, or ``None``.
    """
    K = kernel_matrix(samples, samples, sigma, barrier)
    K = K * (1.0 - jnp.eye(samples.shape[0], dtype=K.dtype))
    loo = (K @ weights) / (1.0 - weights)
    return jnp.sum(weights * jnp.log(loo + jnp.finfo(K.dtype).tiny))


def tune_bandwidth(
    samples,
    weights,
    *,
    barrier=None,
    grid=None,
    reference=None,
    init=None,
    steps: int = 200,
    learning_rate: float = 0.05,
):
    r"""Kernel standard deviation tuned with ``optax.adam`` on ``log sigma``.

    Without ``reference``: maximise the weighted leave-one-out log-likelihood (``loo_log_likelihood``).
    With ``reference`` (a PDF on ``grid``): minimise ``int (p_sigma - reference)^2`` (trapezoidal).

    Args:
        samples: shape ``(N,)``, e.g. ``res.samples("x", t)``.
        weights: shape ``(N,)``, e.g. ``res.weights``.
        barrier: reflect the kernel at this position (displacements), or ``None``.
        grid: the nodes of ``reference`` (``(G,)``), or ``None``.
        reference: a reference PDF tabulated on ``grid`` (``(G,)``), or ``None``.
        init: starting sigma (default: the ``"chen"`` rule).
        steps: optimiser steps.
        learning_rate: the optimiser's learning rate.

    Returns:
        scalar sigma.

    Examples:
        >>> import jdpim, jax.numpy as jnp
        >>> y = jnp.linspace(-2.0, 2.0, 64)
        >>> w = jnp.full((64,), 1 / 64)
        >>> bool(0.05 < jdpim.tune_bandwidth(y, w) < 2.0)
        True
    """
    steps = check_int("steps", steps, low=1)
    check_real("learning_rate", learning_rate, low=0.0, low_open=True)
    if (grid is None) != (reference is None):
        raise ValueError("grid and reference must be given together")
    samples, weights = jnp.asarray(samples), jnp.asarray(weights)
    ok = jnp.isfinite(samples)
    samples, weights = jnp.where(ok, samples, 0.0), jnp.where(ok, weights, 0.0)
    sigma0 = bandwidth(samples, weights, "chen") if init is None else jnp.asarray(init, samples.dtype)

    if reference is None:

        def loss(log_s):
            return -loo_log_likelihood(samples, weights, jnp.exp(log_s), barrier)

    else:
        grid = jnp.asarray(grid, samples.dtype)
        reference = jnp.asarray(reference, samples.dtype)

        def loss(log_s):
            err = (kde(samples, weights, grid, jnp.exp(log_s), barrier) - reference) ** 2
            return jnp.trapezoid(err, grid)

    opt = optax.adam(learning_rate)

    def body(carry, _):
        z, state = carry
        updates, state = opt.update(jax.grad(loss)(z), state, z)
        return (optax.apply_updates(z, updates), state), None

    z0 = jnp.log(sigma0)
    (z, _), _ = jax.lax.scan(body, (z0, opt.init(z0)), None, length=steps)
    return jnp.exp(z)
