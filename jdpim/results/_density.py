r"""Weighted kernel density estimates (the smoothed probability density integral equation).

.. math::  p_Y(y, t) = \sum_q P_q \, \mathcal{N}(y; y_q(t), \sigma^2)

with the kernel reflected at the barrier ``b`` for the displacement,
``N(x - x_q) + N(x + x_q - 2 b)`` on ``x >= b`` and zero below, so no probability leaks past it.
Sums run over chunks of points (bounded memory). Paths with non-finite states get weight zero:
their mass is missing from the density, never smeared into it (see ``Result.lost_mass``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from .._pytree import check_grid, check_points, check_real

RULES = ("chen", "silverman", "scott")
CHEN_C = 1.25  # constant c of Chen & Yang's rule; L1 errors vs exact solutions were lowest for c = 1-1.5 (README)
_POINT_CHUNK = 2048


def _clean(samples, weights):
    """Zero the weight (and value) of non-finite samples (their mass is left out, not redistributed)."""
    ok = jnp.isfinite(samples)
    return jnp.where(ok, samples, 0.0), jnp.where(ok, weights, 0.0)


def weighted_quantile(samples, weights, q):
    """Quantile ``q`` of the weighted sample (linear interpolation of mid-weight positions)."""
    order = jnp.argsort(samples)
    s, w = samples[order], weights[order]
    cw = (jnp.cumsum(w) - 0.5 * w) / jnp.sum(w)
    return jnp.interp(q, cw, s)


def effective_size(weights):
    """Kish's effective sample size ``(sum w)^2 / sum w^2``."""
    return jnp.sum(weights) ** 2 / jnp.sum(weights**2)


def bandwidth(samples, weights, rule: str = "chen", *, dim: int = 1, c: float | None = None):
    r"""Kernel standard deviation from a rule of thumb on a weighted sample.

    ``spread = min(std, IQR / 1.34)`` (weighted; ``std`` where the IQR is 0: over half the probability at one
    value, e.g. a mass of an impact damper that has not moved yet), ``n = `` Kish's effective sample size:

    - ``"chen"`` (Chen & Yang's adaptive rule): ``c * spread * n^(-1/(4 + dim))`` with ``c = CHEN_C``;
    - ``"silverman"``: ``0.9 * spread * n^(-1/5)`` in 1-D, ``spread * n^(-1/6)`` in 2-D;
    - ``"scott"``: ``1.06 * std * n^(-1/5)`` in 1-D, ``std * n^(-1/6)`` in 2-D.

    Evaluated at each saved time, the bandwidth adapts to the spread of the response.

    Args:
        samples: shape ``(N,)``; non-finite entries are ignored.
        weights: shape ``(N,)``, non-negative.
        rule: one of ``RULES``.
        dim: dimension of the density the kernel is used for (1 or 2).
        c: constant of the ``"chen"`` rule (default ``CHEN_C``).
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    samples, weights = _clean(samples, weights)
    wn = weights / jnp.sum(weights)
    mean = jnp.sum(wn * samples)
    std = jnp.sqrt(jnp.sum(wn * (samples - mean) ** 2))
    iqr = weighted_quantile(samples, weights, 0.75) - weighted_quantile(samples, weights, 0.25)
    spread = jnp.where(iqr > 0, jnp.minimum(std, iqr / 1.34), std)  # IQR 0: over half the mass at one value
    n = effective_size(weights)
    if rule == "chen":
        return (CHEN_C if c is None else c) * spread * n ** (-1.0 / (4 + dim))
    if rule == "silverman":
        return (0.9 * spread * n ** (-0.2)) if dim == 1 else spread * n ** (-1.0 / 6)
    return (1.06 * std * n ** (-0.2)) if dim == 1 else std * n ** (-1.0 / 6)


def _check_kernel(grid_name, grid, sigma, barrier):
    """Validate concrete kernel arguments (tracers pass through)."""
    check_points(grid_name, grid)
    check_real("bandwidth", sigma, low=0.0, low_open=True)
    if barrier is not None:
        check_real("barrier", barrier)


def _gauss(z):
    return jnp.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


def _kernel_matrix(grid, samples, sigma, barrier):
    """``K[g, q]``: kernel of point ``q`` at grid node ``g`` (reflected at ``barrier`` if given)."""
    z = (grid[:, None] - samples[None, :]) / sigma
    k = _gauss(z)
    if barrier is not None:
        k = k + _gauss((grid[:, None] + samples[None, :] - 2 * barrier) / sigma)
        k = jnp.where(grid[:, None] >= barrier, k, 0.0)
    return k / sigma


def _chunks(*arrays, size=_POINT_CHUNK):
    """Pad the leading (point) axis to a multiple of ``size`` with zeros and split it into chunks."""
    n = arrays[0].shape[0]
    size = min(size, n)
    pad = (-n) % size
    return tuple(jnp.pad(a, (0, pad)).reshape(-1, size) for a in arrays)


def kde(samples, weights, grid, sigma, barrier=None):
    """Weighted 1-D Gaussian KDE on ``grid``; shaped like ``grid`` (a scalar, or 1-D with one point or more).

    Args:
        samples: shape ``(N,)``.
        weights: shape ``(N,)``.
        grid: evaluation points: a scalar, or shape ``(G,)``, strictly increasing.
        sigma: kernel standard deviation (> 0).
        barrier: reflect the kernel at this position (density zero below it), or ``None``.
    """
    _check_kernel("grid", grid, sigma, barrier)
    return _kde(jnp.asarray(samples), jnp.asarray(weights), jnp.asarray(grid), sigma, barrier)


@jax.jit
def _kde(samples, weights, grid, sigma, barrier):
    samples, weights = _clean(samples, weights)
    g = grid.astype(samples.dtype)
    flat = jnp.atleast_1d(g)

    def body(acc, chunk):
        s, w = chunk
        return acc + _kernel_matrix(flat, s, sigma, barrier) @ w, None

    out, _ = jax.lax.scan(body, jnp.zeros(flat.shape, samples.dtype), _chunks(samples, weights))
    return out.reshape(g.shape)


def kde_stderr(samples, weights, grid, sigma, barrier=None):
    r"""Sampling standard error of :func:`kde` for independent samples, from the per-path kernel contributions.

    With ``p(y) = sum_q w_q K_q(y)`` and independent paths,
    ``se(y)^2 = n / (n - 1) * sum_q w_q^2 (K_q(y) - p(y))^2`` (``n`` paths with finite states); for equal
    weights ``1/n`` this is the sample variance of ``K_q(y)`` over ``n``. The bandwidth is held fixed (the
    error of the smoothed density; the smoothing bias is not included). Shaped like ``grid``.

    Examples:
        >>> import jdpim, jax.numpy as jnp
        >>> y = jnp.linspace(-2.0, 2.0, 101)
        >>> se = jdpim.kde_stderr(y, jnp.full(101, 1 / 101), 0.0, 0.5)
        >>> se.shape
        ()
    """
    _check_kernel("grid", grid, sigma, barrier)
    return _kde_stderr(jnp.asarray(samples), jnp.asarray(weights), jnp.asarray(grid), sigma, barrier)


@jax.jit
def _kde_stderr(samples, weights, grid, sigma, barrier):
    n = jnp.sum(jnp.isfinite(samples))
    samples, weights = _clean(samples, weights)
    g = grid.astype(samples.dtype)
    flat = jnp.atleast_1d(g)

    def body(acc, chunk):
        s, w = chunk
        k = _kernel_matrix(flat, s, sigma, barrier)
        w2 = w * w
        return (acc[0] + k @ w, acc[1] + (k * k) @ w2, acc[2] + k @ w2, acc[3] + jnp.sum(w2)), None

    zero = jnp.zeros(flat.shape, samples.dtype)
    (p, s_kk, s_k, s_1), _ = jax.lax.scan(body, (zero, zero, zero, zero[0]), _chunks(samples, weights))
    var = (s_kk - 2 * p * s_k + p * p * s_1) * n / jnp.maximum(n - 1, 1)
    return jnp.sqrt(jnp.maximum(var, 0.0)).reshape(g.shape)


def kde_difference(lo, hi, weights, grid, sigma, barrier=None):
    """Mean and standard error of the per-path kernel differences ``c_q(y) = K_q(y; hi_q) - K_q(y; lo_q)``.

    ``lo``, ``hi``: the same paths' values at two parameter values (common random numbers), ``(N,)``; a path
    non-finite at either end is left out. ``se(y)^2 = n / (n - 1) sum_q w_q^2 (c_q(y) - d(y))^2`` with
    ``d = sum_q w_q c_q``. Returns ``(d, se)``, each shaped like ``grid``.
    """
    _check_kernel("grid", grid, sigma, barrier)
    lo, hi, weights = jnp.asarray(lo), jnp.asarray(hi), jnp.asarray(weights)
    return _kde_difference(lo, hi, weights, jnp.asarray(grid), sigma, barrier)


@jax.jit
def _kde_difference(lo, hi, weights, grid, sigma, barrier):
    ok = jnp.isfinite(lo) & jnp.isfinite(hi)
    n = jnp.sum(ok)
    lo, hi, weights = (jnp.where(ok, a, 0.0) for a in (lo, hi, weights))
    g = grid.astype(lo.dtype)
    flat = jnp.atleast_1d(g)

    def body(acc, chunk):
        a, b, w = chunk
        c = _kernel_matrix(flat, b, sigma, barrier) - _kernel_matrix(flat, a, sigma, barrier)
        w2 = w * w
        return (acc[0] + c @ w, acc[1] + (c * c) @ w2, acc[2] + c @ w2, acc[3] + jnp.sum(w2)), None

    zero = jnp.zeros(flat.shape, lo.dtype)
    (d, s_cc, s_c, s_1), _ = jax.lax.scan(body, (zero, zero, zero, zero[0]), _chunks(lo, hi, weights))
    var = (s_cc - 2 * d * s_c + d * d * s_1) * n / jnp.maximum(n - 1, 1)
    return d.reshape(g.shape), jnp.sqrt(jnp.maximum(var, 0.0)).reshape(g.shape)


def kde_2d(x, v, weights, x_grid, v_grid, sigma_x, sigma_v, barrier=None):
    """Weighted product-Gaussian KDE of ``(x, v)``, reflected in ``x``; shape ``(len(x_grid), len(v_grid))``.

    A scalar grid drops its axis (both scalars: a scalar).
    """
    _check_kernel("x_grid", x_grid, sigma_x, barrier)
    _check_kernel("v_grid", v_grid, sigma_v, None)
    args = (jnp.asarray(x), jnp.asarray(v), jnp.asarray(weights), jnp.asarray(x_grid), jnp.asarray(v_grid))
    return _kde_2d(*args, sigma_x, sigma_v, barrier)


@jax.jit
def _kde_2d(x, v, weights, x_grid, v_grid, sigma_x, sigma_v, barrier):
    ok = jnp.isfinite(x) & jnp.isfinite(v)
    x, v, weights = jnp.where(ok, x, 0.0), jnp.where(ok, v, 0.0), jnp.where(ok, weights, 0.0)
    shape = jnp.shape(x_grid) + jnp.shape(v_grid)
    x_grid = jnp.atleast_1d(jnp.asarray(x_grid, x.dtype))
    v_grid = jnp.atleast_1d(jnp.asarray(v_grid, x.dtype))

    def body(acc, chunk):
        xs, vs, w = chunk
        kx = _kernel_matrix(x_grid, xs, sigma_x, barrier) * w[None, :]
        kv = _kernel_matrix(v_grid, vs, sigma_v, None)
        return acc + kx @ kv.T, None

    init = jnp.zeros((x_grid.shape[0], v_grid.shape[0]), x.dtype)
    out, _ = jax.lax.scan(body, init, _chunks(x, v, weights))
    return out.reshape(shape)


def histogram(samples, weights, edges):
    """Weighted histogram density on ``edges`` (``(B + 1,)``), normalised by the total weight of all paths.

    Mass outside the edges (or on non-finite paths) is not renormalised into the bins.
    """
    check_grid("edges", edges)
    total = jnp.sum(weights)
    samples, weights = _clean(samples, weights)
    counts, _ = jnp.histogram(samples, bins=edges, weights=weights)
    return counts / (total * jnp.diff(edges))
