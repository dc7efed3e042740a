r"""Response statistics a structural engineer reads: moments in time, power spectral density, autocorrelation.

All three take a method's result (``jdpim.solve``) and a quantity ``var`` (a coordinate name, or a function of
the state ``f(state) -> scalar``):

* :func:`response_moments`: the mean and variance of ``var`` at every saved time (a non-stationary response,
  an earthquake's), with standard errors;
* :func:`response_psd`: the two-sided power spectral density ``S(omega)`` (per rad/s, ``int_-inf^inf S = var``)
  of a stationary response by Welch's method over every path (Hann-windowed segments, half overlapping);
* :func:`response_autocorrelation`: its autocovariance ``R(tau) = E[y(t) y(t + tau)]``.

Monte Carlo paths are independent, so each estimate's standard error is the spread of the per-path values
over ``sqrt(N)`` (the sample moments' for the variance). A DPIM point set is deterministic and has none
(``*_stderr`` is ``None``); give a sequence of randomised replicates (``jdpim.DPIM(...).replicate(scene, k)``)
instead, and the estimate is their mean with the standard error of their spread.

The spectral estimates subtract the ensemble mean at every saved time (times ``N / (N - 1)`` for Monte Carlo,
which keeps them unbiased), not each segment's mean, so ``S(0)`` is kept.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._io import Persistent
from ._pytree import check_int, check_real, pytree_dataclass, static_field
from .results._samples import Result


@pytree_dataclass
class ResponseMoments(Persistent):
    """The mean and variance of a response quantity at the saved times.

    Attributes:
        times: the saved times, s (a tuple of ``S`` floats).
        mean, variance: ``(S,)``.
        mean_stderr, variance_stderr: their standard errors, ``(S,)``, or ``None`` (one DPIM run, path
            integration: no sampling error to read).
        method: the method of the result(s).
    """

    times: tuple = static_field()
    mean: Any = None
    mean_stderr: Any = None
    variance: Any = None
    variance_stderr: Any = None
    method: str = static_field(default="monte_carlo")


@pytree_dataclass
class ResponseSpectrum(Persistent):
    """The two-sided power spectral density of a stationary response quantity (per rad/s).

    Attributes:
        times: the saved times the estimate reads, s (a tuple).
        frequencies: ``omega``, rad/s, ``(F,)``: ``0, 2 pi / T_seg, ..., pi / dt`` (``T_seg`` a segment's length).
        psd: ``S(omega)``, ``(F,)``; the one-sided density is ``2 S``.
        psd_stderr: its standard error, ``(F,)``, or ``None``.
        method: the method of the result(s).
    """

    times: tuple = static_field()
    frequencies: Any = None
    psd: Any = None
    psd_stderr: Any = None
    method: str = static_field(default="monte_carlo")


@pytree_dataclass
class ResponseAutocorrelation(Persistent):
    """The autocovariance ``R(tau) = E[y(t) y(t + tau)]`` of a stationary, mean-removed response quantity.

    Attributes:
        times: the saved times the estimate reads, s (a tuple).
        lags: ``tau``, s, ``(K,)``: ``0, dt, ..., (K - 1) dt``.
        autocorrelation: ``R(tau)``, ``(K,)``.
        autocorrelation_stderr: its standard error, ``(K,)``, or ``None``.
        method: the method of the result(s).
    """

    times: tuple = static_field()
    lags: Any = None
    autocorrelation: Any = None
    autocorrelation_stderr: Any = None
    method: str = static_field(default="monte_carlo")


def response_moments(result, var) -> ResponseMoments:
    r"""The mean and variance of ``var`` at every saved time, with standard errors.

    Monte Carlo (``N`` finite paths at a time): the sample mean with ``sqrt(s^2 / N)``, the unbiased sample
    variance ``s^2`` with ``sqrt((m_4 - m_2^2) / N)``. DPIM: the weighted moments, no standard error; a
    sequence of replicates: their mean and the standard error of their spread. A
    ``jdpim.GridResult`` (path integration): ``E[var]`` and ``E[var^2] - E[var]^2`` from its density.

    Args:
        result: a result of ``jdpim.solve``, or a sequence of randomised DPIM replicates of one scene.
        var: a coordinate name or a function of the state.

    Examples:
        >>> import jdpim, numpy as np
        >>> states = np.random.default_rng(0).normal(size=(500, 3, 2))  # 500 paths, 3 saved times, (x, v)
        >>> mc = jdpim.Result(times=(1.0, 2.0, 3.0), states=states, weights=np.full(500, 1 / 500),
        ...                   method="monte_carlo", independent=True)
        >>> stats = jdpim.response_moments(mc, "x")
        >>> stats.variance.shape, stats.variance_stderr.shape
        ((3,), (3,))
    """
    results = _results(result)
    if len(results) > 1:
        each = [response_moments(r, var) for r in results]
        mean, mean_stderr = _spread([m.mean for m in each])
        variance, variance_stderr = _spread([m.variance for m in each])
        return ResponseMoments(each[0].times, mean, mean_stderr, variance, variance_stderr, each[0].method)
    result = results[0]
    if not isinstance(result, Result):
        first = jnp.stack([result.moment(var, 1, t) for t in result.times])
        second = jnp.stack([result.moment(var, 2, t) for t in result.times])
        return ResponseMoments(times=result.times, mean=first, variance=second - first**2, method=result.method)
    y = _values(result, var)  # (N, S)
    ok = jnp.isfinite(y)
    w = jnp.where(ok, result.weights[:, None], 0.0)
    w = w / jnp.sum(w, axis=0)[None, :]
    y = jnp.where(ok, y, 0.0)
    mean = jnp.sum(w * y, axis=0)
    centred = y - mean[None, :]
    m2, m4 = jnp.sum(w * centred**2, axis=0), jnp.sum(w * centred**4, axis=0)
    if not result.independent:
        return ResponseMoments(times=result.times, mean=mean, variance=m2, method=result.method)
    n = jnp.sum(ok, axis=0)
    variance = m2 * n / (n - 1)
    return ResponseMoments(
        times=result.times,
        mean=mean,
        mean_stderr=jnp.sqrt(variance / n),
        variance=variance,
        variance_stderr=jnp.sqrt(jnp.maximum(m4 - m2**2, 0.0) / n),
        method=result.method,
    )


def response_psd(result, var, *, segment: int, start: float | None = None) -> ResponseSpectrum:
    r"""Welch's estimate of the two-sided power spectral density of a stationary ``var`` over every path.

    The saved times from ``start`` on (equally spaced by ``dt``) are cut into segments of ``segment`` values
    that overlap by half; each is multiplied by a Hann window ``h_j`` and

    .. math::  \hat S(\omega_k) = \frac{dt}{2\pi \sum_j h_j^2}\Big|\sum_j h_j\, y_j\, e^{-i\omega_k j\,dt}\Big|^2,
        \qquad \omega_k = \frac{2\pi k}{\text{segment}\cdot dt},

    averaged over the segments of a path, then over the paths. Its expectation is the true density smoothed by
    the window's kernel, whose main lobe has the half-width ``4 pi / (segment dt)`` (longer segments: less bias,
    fewer segments); the variance falls as one over the number of paths times segments.

    Args:
        result: a result of ``jdpim.solve`` (or DPIM replicates) with equally spaced saved times.
        var: a coordinate name or a function of the state.
        segment: values per segment, >= 4, at most the number of saved times read.
        start: the first saved time read, s (``None``: the first saved time); the response must be
            stationary from there on (after the transient from the initial state).

    Examples:
        >>> import jdpim, numpy as np
        >>> states = np.random.default_rng(0).normal(size=(50, 100, 2))  # white: S = 0.1 / (2 pi) per rad/s
        >>> mc = jdpim.Result(times=tuple(0.1 * k for k in range(100)), states=states, weights=np.full(50, 0.02),
        ...                   method="monte_carlo", independent=True)
        >>> spectrum = jdpim.response_psd(mc, "x", segment=20)
        >>> spectrum.frequencies.shape
        (11,)
    """
    results = _results(result)
    if len(results) > 1:
        each = [response_psd(r, var, segment=segment, start=start) for r in results]
        psd, stderr = _spread([s.psd for s in each])
        return ResponseSpectrum(each[0].times, each[0].frequencies, psd, stderr, each[0].method)
    result = results[0]
    times, dt, y, w = _stationary(result, var, start)
    segment = check_int("segment", segment, low=4)
    if segment > y.shape[1]:
        raise ValueError(f"segment must be at most the {y.shape[1]} saved times from start={times[0]:g}, got {segment}")
    psd, stderr = _path_average(result, _welch(y, segment) * dt, w)
    frequencies = 2.0 * np.pi * np.fft.rfftfreq(segment, dt)
    return ResponseSpectrum(times, jnp.asarray(frequencies, y.dtype), psd, stderr, result.method)


def response_autocorrelation(result, var, *, max_lag: int, start: float | None = None) -> ResponseAutocorrelation:
    r"""The autocovariance of a stationary ``var``: ``R(k dt)``, the mean of ``y_j y_{j+k}`` over the time pairs of
    each path (``L - k`` of them), then over the paths.

    Args:
        result: a result of ``jdpim.solve`` (or DPIM replicates) with equally spaced saved times.
        var: a coordinate name or a function of the state.
        max_lag: the largest lag, in saved-time steps, >= 0 and below the number of saved times read.
        start: the first saved time read, s (``None``: the first saved time); the response must be stationary
            from there on.
    """
    results = _results(result)
    if len(results) > 1:
        each = [response_autocorrelation(r, var, max_lag=max_lag, start=start) for r in results]
        r, stderr = _spread([a.autocorrelation for a in each])
        return ResponseAutocorrelation(each[0].times, each[0].lags, r, stderr, each[0].method)
    result = results[0]
    times, dt, y, w = _stationary(result, var, start)
    max_lag = check_int("max_lag", max_lag, low=0)
    if max_lag >= y.shape[1]:
        raise ValueError(f"max_lag must be below the {y.shape[1]} saved times from start={times[0]:g}, got {max_lag}")
    r, stderr = _path_average(result, _lagged_products(y, max_lag), w)
    lags = jnp.asarray(dt * np.arange(max_lag + 1), y.dtype)
    return ResponseAutocorrelation(times, lags, r, stderr, result.method)


@functools.partial(jax.jit, static_argnums=1)
def _welch(y, segment: int):
    """Each path's Hann-windowed periodogram ``|sum_j h_j y_j e^{-i omega j dt}|^2 / (2 pi sum h^2)``, averaged
    over its half-overlapping segments, ``(N, segment // 2 + 1)`` (times ``dt`` gives the density)."""
    begins = np.arange(0, y.shape[1] - segment + 1, segment // 2)
    window = jnp.asarray(np.hanning(segment + 2)[1:-1], y.dtype)  # no zero end points
    pieces = y[:, begins[:, None] + np.arange(segment)[None, :]] * window[None, None, :]  # (N, n_segments, segment)
    periodograms = jnp.abs(jnp.fft.rfft(pieces, axis=-1)) ** 2 / (2.0 * np.pi * jnp.sum(window**2))
    return jnp.mean(periodograms, axis=1)


@functools.partial(jax.jit, static_argnums=1)
def _lagged_products(y, max_lag: int):
    """Each path's mean of ``y_j y_(j + k)`` over its ``L - k`` pairs, ``k = 0 .. max_lag``: ``(N, max_lag + 1)``."""
    length = y.shape[1]
    spectrum = jnp.fft.rfft(y, n=2 * length, axis=-1)
    sums = jnp.fft.irfft(jnp.abs(spectrum) ** 2, n=2 * length, axis=-1)[:, : max_lag + 1]
    return sums / jnp.asarray(length - np.arange(max_lag + 1), y.dtype)[None, :]


def _results(result) -> list:
    """``result`` as a list of results (one, or the replicates of a sequence), else a ``TypeError``."""
    items = list(result) if isinstance(result, Sequence) else [result]
    if not items or not all(hasattr(r, "times") and hasattr(r, "coordinates") for r in items):
        raise TypeError(f"result must be a result of jdpim.solve or a sequence of them, got {type(result).__name__}")
    if len({r.times for r in items}) > 1 or len({r.coordinates for r in items}) > 1:
        raise ValueError("the replicates must share their saved times and coordinates (one scene)")
    return items


def _values(result: Result, var):
    """``var`` on every path at every saved time, ``(N, S)``."""
    which = result._coordinate(var)
    if callable(which):
        return jax.vmap(jax.vmap(which))(result.states)
    return result.states[:, :, which]


def _stationary(result, var, start):
    """``(times, dt, y, w)``: the saved times from ``start`` (equally spaced, checked), ``var`` on them minus its
    ensemble mean, ``(N, L)``, and the paths' weights, ``(N,)`` (0 for a path with a non-finite value there)."""
    if not isinstance(result, Result):
        raise TypeError(f"result must hold paths (a jdpim.Result), got {type(result).__name__}")
    times = np.asarray(result.times, float)
    first = 0 if start is None else int(np.searchsorted(times, float(check_real("start", start, scalar=True)) - 1e-9))
    times = times[first:]
    if len(times) < 4:
        raise ValueError(f"the spectral estimates need at least 4 saved times from start={start!r}, got {len(times)}")
    steps = np.diff(times)
    dt = float(steps.mean())
    if np.max(np.abs(steps - dt)) > 1e-6 * dt:
        raise ValueError(
            f"the saved times from start must be equally spaced; their spacing ranges over [{steps.min():g}, "
            f"{steps.max():g}] s"
        )
    y = _values(result, var)[:, first:]
    ok = jnp.all(jnp.isfinite(y), axis=1)
    w = jnp.where(ok, result.weights, 0.0)
    w = w / jnp.sum(w)
    y = jnp.where(ok[:, None], y, 0.0)
    y = y - jnp.sum(w[:, None] * y, axis=0)[None, :]
    return tuple(float(t) for t in times), dt, y, w


def _path_average(result: Result, per_path, w):
    """The weighted mean over paths of ``per_path``, ``(N, K)``, and its standard error (Monte Carlo: the spread
    over the paths, the mean's ``N / (N - 1)`` correction applied; otherwise ``None``)."""
    mean = jnp.sum(w[:, None] * per_path, axis=0)
    if not result.independent:
        return mean, None
    n = jnp.sum(w > 0)
    variance = jnp.sum(w[:, None] * (per_path - mean[None, :]) ** 2, axis=0) * n / (n - 1)  # over the paths
    return mean * n / (n - 1), jnp.sqrt(variance / n) * n / (n - 1)


def _spread(values) -> tuple:
    """The mean of replicate estimates and its standard error (their sample spread over ``sqrt(R)``)."""
    stacked = jnp.stack(values)
    return jnp.mean(stacked, axis=0), jnp.std(stacked, axis=0, ddof=1) / np.sqrt(len(values))
