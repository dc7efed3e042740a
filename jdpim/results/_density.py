r"""Weighted kernel density estimates (the smoothed probability density integral equation).

.. math::  p_Y(y, t) = \sum_q P_q \, \mathcal{N}(y; y_q(t), \sigma^2)

with the kernel reflected at the bounds of the quantity, so no probability leaks past them: at a lower bound
``a`` alone (the barrier of the displacement) ``N(y - y_q) + N(y + y_q - 2 a)`` on ``y >= a`` and zero below; in
an interval ``[a, b]`` (a relative displacement within a clearance) the images of ``y_q`` in both ends and
their images in turn, ``N(y - y_q) + N(y + y_q - 2 a) + N(y + y_q - 2 b) + N(y - y_q - 2 (b - a)) + ...``, on
``[a, b]`` (mass 1 inside for any bandwidth; see :func:`_interval_kernel`). Sums run over chunks of points
(bounded memory). Paths with non-finite states get weight zero: their mass is missing from the density, never
smeared into it (see ``Result.lost_mass``).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import check_grid, check_points, check_real, concrete, plain

RULES = ("chen", "silverman", "scott")
CHEN_C = 1.25  # constant c of Chen & Yang's rule; L1 errors vs exact solutions were lowest for c = 1-1.5 (README)
_POINT_CHUNK = 2048


def program_input(value):
    """``value`` ready to enter a compiled program: a JAX array (or tracer) as it is, anything else (a NumPy array,
    a list, a number) as a NumPy array, converted to JAX's dtype where it enters, with no program of its own."""
    return value if isinstance(value, jax.Array) else np.asarray(value)


def _clean(samples, weights):
    """Zero the weight (and value) of non-finite samples (their mass is left out, not redistributed)."""
    ok = jnp.isfinite(samples)
    return jnp.where(ok, samples, 0.0), jnp.where(ok, weights, 0.0)


def weighted_quantile(samples, weights, q):
    """Quantile ``q`` (a scalar or an array of them) of the weighted sample (linear interpolation of mid-weight
    positions)."""
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
    if rule == "chen":
        factor, exponent = (CHEN_C if c is None else c), -1.0 / (4 + dim)
    else:
        factor = {"silverman": 0.9, "scott": 1.06}[rule] if dim == 1 else 1.0
        exponent = -0.2 if dim == 1 else -1.0 / 6
    return _rule_bandwidth(*map(program_input, (samples, weights)), factor, exponent, rule == "scott")


@jax.jit
def _rule_bandwidth(samples, weights, factor, exponent, use_std):
    """``factor * spread * n^exponent`` (``std`` in place of ``spread`` where ``use_std``): :func:`bandwidth` as one
    compiled program for every rule and dimension, per shape and dtype."""
    samples, weights = _clean(samples, weights)
    wn = weights / jnp.sum(weights)
    mean = jnp.sum(wn * samples)
    std = jnp.sqrt(jnp.sum(wn * (samples - mean) ** 2))
    upper, lower = weighted_quantile(samples, weights, jnp.array([0.75, 0.25], samples.dtype))  # one sort
    iqr = upper - lower
    spread = jnp.where(iqr > 0, jnp.minimum(std, iqr / 1.34), std)  # IQR 0: over half the mass at one value
    n = effective_size(weights)
    return factor * jnp.where(use_std, std, spread) * n**exponent


def limits(barrier=None, bounds=None, name: str = "bounds") -> tuple:
    """``(lower, upper)`` of a kernel from ``barrier`` (a lower bound) or ``bounds = (a, b)``; ``None`` for a side
    without a bound (given as ``None`` or an infinite value). Concrete values are checked (``a < b``)."""
    if bounds is None:
        if barrier is not None:
            check_real("barrier", barrier)
        return barrier, None
    if barrier is not None:
        raise ValueError(f"give either barrier or {name}, not both (barrier={plain(barrier)!r}, {name}={bounds!r})")
    if not isinstance(bounds, (tuple, list)) or len(bounds) != 2:
        raise ValueError(f"{name} must be a pair (a, b), either side None for no bound, got {plain(bounds)!r}")
    out = []
    for side, value in zip(("lower", "upper"), bounds, strict=True):
        arr = concrete(value)
        if value is None or (arr is not None and arr.ndim == 0 and np.isinf(arr) and (arr < 0) == (side == "lower")):
            out.append(None)
            continue
        check_real(f"{name} ({side})", value, scalar=True)
        out.append(value)
    lo, hi = (concrete(v) for v in out)
    if lo is not None and hi is not None and not lo < hi:
        raise ValueError(f"{name} must be a pair (a, b) with a < b, got {plain(bounds)!r}")
    return tuple(out)


def _check_kernel(grid_name, grid, sigma):
    """Validate concrete kernel arguments (tracers pass through)."""
    check_points(grid_name, grid)
    check_real("bandwidth", sigma, low=0.0, low_open=True)


def _gauss(z):
    return jnp.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


_IMAGES = 2  # interval kernel, sigma <= (b - a) / 2: images 2 k (b - a) apart for |k| <= _IMAGES (error < e^-50)
_MODES = 5  # interval kernel, sigma > (b - a) / 2: cosine modes m <= _MODES (error < e^-44)


def _interval_kernel(u, w, sigma, length):
    r"""The Gaussian kernel of a point at ``w`` reflected at both ends of ``[0, length]``, at ``u`` (both in
    ``[0, length]``; broadcast), unnormalised by ``sigma`` as in :func:`kernel_matrix`.

    The sum over all images, ``sum_k N(u - w + 2 k L) + N(u + w + 2 k L)``, taken directly where
    ``sigma <= L / 2`` (the images nearer than ``10 sigma``) and as its Fourier series (Poisson's summation)
    ``sigma / L (1 + 2 sum_m exp(-(pi m sigma / L)^2 / 2) cos(pi m u / L) cos(pi m w / L))`` where the bandwidth
    is wider: both exact to rounding, so the kernel integrates to 1 over the interval for every bandwidth.
    """

    def image_pair(k, acc):  # the images 2 k L apart of the point and of its mirror in 0
        shift = 2 * k * length
        return acc + _gauss((u - w + shift) / sigma) + _gauss((u + w + shift) / sigma)

    shape = jnp.broadcast_shapes(jnp.shape(u), jnp.shape(w))
    direct = jax.lax.fori_loop(-_IMAGES, _IMAGES + 1, image_pair, jnp.zeros(shape, jnp.result_type(u, w, sigma)))
    direct = direct + _gauss((u + w - 2 * (_IMAGES + 1) * length) / sigma)

    def mode(m, acc):
        c = jnp.pi * m
        return acc + jnp.exp(-0.5 * (c * ratio) ** 2) * jnp.cos(c * u / length) * jnp.cos(c * w / length)

    ratio = sigma / length
    series = 1.0 + 2.0 * jax.lax.fori_loop(1, _MODES + 1, mode, jnp.zeros_like(direct))
    return jnp.where(ratio <= 0.5, direct, ratio * series)


def kernel_matrix(grid, samples, sigma, lower=None, upper=None):
    """``K[g, q]``: kernel of point ``q`` at grid node ``g``, reflected at ``lower`` and ``upper`` where given
    (zero beyond them)."""
    g, s = grid[:, None], samples[None, :]
    if lower is not None and upper is not None:
        k = _interval_kernel(g - lower, s - lower, sigma, upper - lower)
        return jnp.where((g >= lower) & (g <= upper), k, 0.0) / sigma
    k = _gauss((g - s) / sigma)
    if lower is not None:
        k = k + _gauss((g + s - 2 * lower) / sigma)
        k = jnp.where(g >= lower, k, 0.0)
    if upper is not None:
        k = k + _gauss((g + s - 2 * upper) / sigma)
        k = jnp.where(g <= upper, k, 0.0)
    return k / sigma


def _chunks(*arrays, size=_POINT_CHUNK):
    """Pad the leading (point) axis to a multiple of ``size`` with zeros and split it into chunks."""
    n = arrays[0].shape[0]
    size = min(size, n)
    pad = (-n) % size
    return tuple(jnp.pad(a, (0, pad)).reshape(-1, size) for a in arrays)


def kde(samples, weights, grid, sigma, barrier=None, *, bounds=None):
    """Weighted 1-D Gaussian KDE on ``grid``; shaped like ``grid`` (a scalar, or 1-D with one point or more).

    Args:
        samples: shape ``(N,)``.
        weights: shape ``(N,)``.
        grid: evaluation points: a scalar, or shape ``(G,)``, strictly increasing.
        sigma: kernel standard deviation (> 0).
        barrier: reflect the kernel at this position (density zero below it), or ``None``.
        bounds: ``(a, b)``: the samples' range (``a < b``; either side ``None`` for no bound), the kernel
            reflected at both ends and the density zero outside (instead of ``barrier``: ``(barrier, None)``).

    Example:
        >>> import jdpim, jax.numpy as jnp
        >>> y = jnp.linspace(0.0, 1.0, 101)
        >>> p = jdpim.kde(y, jnp.full(101, 1 / 101), jnp.linspace(0.0, 1.0, 1001), 0.3, bounds=(0.0, 1.0))
        >>> round(float(jnp.trapezoid(p, dx=0.001)), 6)
        1.0
    """
    _check_kernel("grid", grid, sigma)
    lim = limits(barrier, bounds)
    return _kde(*map(program_input, (samples, weights, grid)), sigma, lim)


@jax.jit
def _kde(samples, weights, grid, sigma, lim):
    samples, weights = _clean(samples, weights)
    g = grid.astype(samples.dtype)
    flat = jnp.atleast_1d(g)

    def body(acc, chunk):
        s, w = chunk
        return acc + kernel_matrix(flat, s, sigma, *lim) @ w, None

    out, _ = jax.lax.scan(body, jnp.zeros(flat.shape, samples.dtype), _chunks(samples, weights))
    return out.reshape(g.shape)


def kde_stderr(samples, weights, grid, sigma, barrier=None, *, bounds=None):
    r"""Sampling standard error of :func:`kde` for independent samples, from the per-path kernel contributions.

    With ``p(y) = sum_q w_q K_q(y)`` and independent paths,
    ``se(y)^2 = n / (n - 1) * sum_q w_q^2 (K_q(y) - p(y))^2`` (``n`` paths with finite states); for equal
    weights ``1/n`` this is the sample variance of ``K_q(y)`` over ``n``. The bandwidth is held fixed (the
    error of the smoothed density; the smoothing bias is not included). Shaped like ``grid``. ``barrier``,
    ``bounds``: as in :func:`kde`.

    Examples:
        >>> import jdpim, jax.numpy as jnp
        >>> y = jnp.linspace(-2.0, 2.0, 101)
        >>> se = jdpim.kde_stderr(y, jnp.full(101, 1 / 101), 0.0, 0.5)
        >>> se.shape
        ()
    """
    _check_kernel("grid", grid, sigma)
    lim = limits(barrier, bounds)
    return _kde_stderr(*map(program_input, (samples, weights, grid)), sigma, lim)


@jax.jit
def _kde_stderr(samples, weights, grid, sigma, lim):
    n = jnp.sum(jnp.isfinite(samples))
    samples, weights = _clean(samples, weights)
    g = grid.astype(samples.dtype)
    flat = jnp.atleast_1d(g)

    def body(acc, chunk):
        s, w = chunk
        k = kernel_matrix(flat, s, sigma, *lim)
        w2 = w * w
        return (acc[0] + k @ w, acc[1] + (k * k) @ w2, acc[2] + k @ w2, acc[3] + jnp.sum(w2)), None

    zero = jnp.zeros(flat.shape, samples.dtype)
    (p, s_kk, s_k, s_1), _ = jax.lax.scan(body, (zero, zero, zero, zero[0]), _chunks(samples, weights))
    var = (s_kk - 2 * p * s_k + p * p * s_1) * n / jnp.maximum(n - 1, 1)
    return jnp.sqrt(jnp.maximum(var, 0.0)).reshape(g.shape)


def kde_difference(lo, hi, weights, grid, sigma, barrier=None, *, bounds=None):
    """Mean and standard error of the per-path kernel differences ``c_q(y) = K_q(y; hi_q) - K_q(y; lo_q)``.

    ``lo``, ``hi``: the same paths' values at two parameter values (common random numbers), ``(N,)``; a path
    non-finite at either end is left out. ``se(y)^2 = n / (n - 1) sum_q w_q^2 (c_q(y) - d(y))^2`` with
    ``d = sum_q w_q c_q``. Returns ``(d, se)``, each shaped like ``grid``. ``barrier``, ``bounds``: as in
    :func:`kde`.
    """
    _check_kernel("grid", grid, sigma)
    lim = limits(barrier, bounds)
    return _kde_difference(*map(program_input, (lo, hi, weights, grid)), sigma, lim)


@jax.jit
def _kde_difference(lo, hi, weights, grid, sigma, lim):
    ok = jnp.isfinite(lo) & jnp.isfinite(hi)
    n = jnp.sum(ok)
    lo, hi, weights = (jnp.where(ok, a, 0.0) for a in (lo, hi, weights))
    g = grid.astype(lo.dtype)
    flat = jnp.atleast_1d(g)

    def body(acc, chunk):
        a, b, w = chunk
        c = kernel_matrix(flat, b, sigma, *lim) - kernel_matrix(flat, a, sigma, *lim)
        w2 = w * w
        return (acc[0] + c @ w, acc[1] + (c * c) @ w2, acc[2] + c @ w2, acc[3] + jnp.sum(w2)), None

    zero = jnp.zeros(flat.shape, lo.dtype)
    (d, s_cc, s_c, s_1), _ = jax.lax.scan(body, (zero, zero, zero, zero[0]), _chunks(lo, hi, weights))
    var = (s_cc - 2 * d * s_c + d * d * s_1) * n / jnp.maximum(n - 1, 1)
    return d.reshape(g.shape), jnp.sqrt(jnp.maximum(var, 0.0)).reshape(g.shape)


def kde_2d(x, v, weights, x_grid, v_grid, sigma_x, sigma_v, barrier=None, *, x_bounds=None, v_bounds=None):
    """Weighted product-Gaussian KDE of ``(x, v)``; shape ``(len(x_grid), len(v_grid))``.

    A scalar grid drops its axis (both scalars: a scalar). Each factor is reflected at the bounds of its
    quantity: ``barrier`` (a lower bound of ``x``) or ``x_bounds``, and ``v_bounds`` (pairs as ``bounds`` of
    :func:`kde`).
    """
    _check_kernel("x_grid", x_grid, sigma_x)
    _check_kernel("v_grid", v_grid, sigma_v)
    lim_x, lim_v = limits(barrier, x_bounds, "x_bounds"), limits(None, v_bounds, "v_bounds")
    return _kde_2d(*map(program_input, (x, v, weights, x_grid, v_grid)), sigma_x, sigma_v, lim_x, lim_v)


@jax.jit
def _kde_2d(x, v, weights, x_grid, v_grid, sigma_x, sigma_v, lim_x, lim_v):
    ok = jnp.isfinite(x) & jnp.isfinite(v)
    x, v, weights = jnp.where(ok, x, 0.0), jnp.where(ok, v, 0.0), jnp.where(ok, weights, 0.0)
    shape = jnp.shape(x_grid) + jnp.shape(v_grid)
    x_grid = jnp.atleast_1d(jnp.asarray(x_grid, x.dtype))
    v_grid = jnp.atleast_1d(jnp.asarray(v_grid, x.dtype))

    def body(acc, chunk):
        xs, vs, w = chunk
        kx = kernel_matrix(x_grid, xs, sigma_x, *lim_x) * w[None, :]
        kv = kernel_matrix(v_grid, vs, sigma_v, *lim_v)
        return acc + kx @ kv.T, None

    init = jnp.zeros((x_grid.shape[0], v_grid.shape[0]), x.dtype)
    out, _ = jax.lax.scan(body, init, _chunks(x, v, weights))
    return out.reshape(shape)


def histogram(samples, weights, edges):
    """Weighted histogram density on ``edges`` (``(B + 1,)``), normalised by the total weight of all paths.

    Mass outside the edges (or on non-finite paths) is not renormalised into the bins.
    """
    check_grid("edges", edges)
    return _histogram(*map(program_input, (samples, weights, edges)))


@jax.jit
def _histogram(samples, weights, edges):
    total = jnp.sum(weights)
    samples, weights = _clean(samples, weights)
    counts, _ = jnp.histogram(samples, bins=edges, weights=weights)
    return counts / (total * jnp.diff(edges))
