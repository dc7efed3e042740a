r"""Fragility curves: ``P(max_{0 <= t <= T} q(t) > level)`` as a function of the excitation's intensity.

At every intensity ``s`` the scene's noise intensity is ``D (s / reference)^2``: the ground motion (white noise,
or a linear filter of it, modulated or not) is ``s / reference`` times the scene's, so any intensity measure
proportional to it (the root-mean-square ground acceleration at the envelope's peak, the median peak ground
acceleration) is ``s`` where the scene's is ``reference``. The probability of exceeding the level within the record
is a Monte Carlo first passage on its own paths (independent seeds), so the counts ``k_i`` of ``n`` paths are
independent binomials; the lognormal fragility ``P(s) = Phi(ln(s / median) / beta)`` is fitted to them by
maximum likelihood (a probit regression on ``ln s``), with standard errors from the observed information.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np
from scipy import special

from .._io import Persistent
from .._pytree import check_int, check_number, concrete, pytree_dataclass, real_array, static_field
from .._scene import Scene, parameter_value, with_parameters
from ..methods._monte_carlo import MonteCarlo
from ._first_passage import first_passage


class FragilityWarning(UserWarning):
    """The lognormal fit of a fragility curve does not exist (the counts are separated): more paths or intensities."""


@pytree_dataclass
class Fragility(Persistent):
    r"""A fragility curve and its lognormal fit.

    Attributes:
        times: ``(T,)``, the end of the record, s: the probabilities are of an exceedance in ``[0, T]``.
        intensities: ``(I,)``, the intensity measures ``s`` (units of ``reference``).
        probability: ``(I,)``, ``P(max q > level)`` at each intensity (Monte Carlo: ``k_i / n``).
        probability_stderr: ``(I,)``, ``sqrt(p (1 - p) / n)``.
        lower, upper: ``(I,)``, the Wilson score interval of each probability at ``confidence``.
        median: the fitted median capacity ``theta`` (units of ``s``): ``P(theta) = 1/2``; ``nan`` where the
            fit does not exist.
        median_stderr: its standard error (observed information, delta method).
        beta: the fitted dispersion (the standard deviation of ``ln`` capacity).
        beta_stderr: its standard error.
        covariance: ``(2, 2)``, the covariance of the estimates of ``(ln median, beta)``.
        level: the demand level.
        n_samples: ``n``, the paths at each intensity.
        confidence: the level of ``lower``, ``upper``.
        method: the method's name.

    ``fitted(s)`` evaluates the lognormal curve with its standard error. A pytree: it passes through ``jax.jit``.
    """

    times: tuple = static_field()
    intensities: Any = None
    probability: Any = None
    probability_stderr: Any = None
    lower: Any = None
    upper: Any = None
    median: Any = None
    median_stderr: Any = None
    beta: Any = None
    beta_stderr: Any = None
    covariance: Any = None
    level: float = static_field(default=0.0)
    n_samples: int = static_field(default=0)
    confidence: float = static_field(default=0.95)
    method: str = static_field(default="monte_carlo")

    def fitted(self, intensity) -> tuple:
        """``(P, stderr)``: the fitted ``Phi(ln(s / median) / beta)`` at ``intensity`` (> 0; any shape) and its
        standard error from ``covariance`` (delta method)."""
        s = real_array("intensity", intensity, "a positive number or an array of them")
        if np.any(~np.isfinite(s)) or np.any(s <= 0):
            raise ValueError(f"intensity must be positive and finite, got {s.tolist()}")
        log_median, beta = np.log(float(self.median)), float(self.beta)
        eta = (np.log(s) - log_median) / beta
        density = np.exp(-0.5 * eta * eta) / np.sqrt(2.0 * np.pi)
        gradient = np.stack([-density / beta, -density * eta / beta], axis=-1)  # d/d(ln median), d/d beta
        variance = np.einsum("...i,ij,...j->...", gradient, np.asarray(self.covariance, float), gradient)
        return special.ndtr(eta), np.sqrt(variance)


def wilson_interval(k, n: int, confidence: float = 0.95) -> tuple:
    """``(lower, upper)``: the Wilson score interval of a binomial proportion ``k / n`` at ``confidence``.

    Unlike ``p +- z stderr`` it stays inside [0, 1] and gives ``k = 0`` a positive upper bound.

    Args:
        k: counts, any shape (``p n`` for a Monte Carlo probability ``p`` of ``n`` paths).
        n: the trials, >= 1.
        confidence: in (0, 1).

    Examples:
        >>> import jdpim
        >>> [round(float(b), 4) for b in jdpim.reliability.wilson_interval(0, 100)]
        [0.0, 0.037]
    """
    n = check_int("n", n, low=1)
    z = special.ndtri(
        0.5 + 0.5 * check_number("confidence", confidence, low=0.0, high=1.0, low_open=True, high_open=True)
    )
    k = real_array("k", k, "counts")
    if np.any(k < 0) or np.any(k > n):
        raise ValueError(f"k must lie in [0, n = {n}], got {k.tolist()}")
    centre = (k + 0.5 * z * z) / (n + z * z)
    half = z / (n + z * z) * np.sqrt(k * (n - k) / n + 0.25 * z * z)
    return np.where(k == 0, 0.0, centre - half), np.where(k == n, 1.0, centre + half)  # exact at the ends


def _probit_terms(eta, k, n):
    """The log-likelihood, its first and second derivatives in ``eta`` per intensity, for ``k`` of ``n``."""
    log_p, log_q = special.log_ndtr(eta), special.log_ndtr(-eta)
    log_density = -0.5 * eta * eta - 0.5 * np.log(2.0 * np.pi)
    up, down = np.exp(log_density - log_p), np.exp(log_density - log_q)  # phi / Phi, phi / (1 - Phi)
    loglik = k * log_p + (n - k) * log_q
    first = k * up - (n - k) * down
    second = -k * up * (eta + up) - (n - k) * down * (down - eta)
    return loglik, first, second


def fit_lognormal(intensities, counts, n: int) -> tuple:
    """``(median, beta, covariance of (ln median, beta))`` by maximum likelihood over the binomial counts, or
    ``None`` where the counts are separated (no exceedance above the lowest intensity with a non-exceedance,
    or the reverse) and the likelihood has no maximum."""
    x, k = np.log(np.asarray(intensities, float)), np.asarray(counts, float)
    if not (k > 0).any() or not (k < n).any() or x[k > 0].min() >= x[k < n].max():
        return None
    design = np.stack([np.ones_like(x), x], axis=1)
    target = special.ndtri((k + 0.5) / (n + 1.0))
    theta = np.linalg.lstsq(design, target, rcond=None)[0]  # a probit line through the smoothed proportions
    loglik = _probit_terms(design @ theta, k, n)[0].sum()
    for _ in range(100):  # Fisher scoring with step halving
        eta = design @ theta
        _, first, _ = _probit_terms(eta, k, n)
        weight = n * np.exp(-eta * eta) / (2.0 * np.pi) / (special.ndtr(eta) * special.ndtr(-eta))
        step = np.linalg.solve(design.T @ (weight[:, None] * design), design.T @ first)
        for _ in range(40):
            trial = _probit_terms(design @ (theta + step), k, n)[0].sum()
            if trial >= loglik - 1e-12 * abs(loglik):
                break
            step = 0.5 * step
        theta, loglik = theta + step, trial
        if np.max(np.abs(step)) < 1e-10:
            break
    a, b = theta
    second = _probit_terms(design @ theta, k, n)[2]
    information = -(design.T @ (second[:, None] * design))
    jacobian = np.array([[-1.0 / b, a / (b * b)], [0.0, -1.0 / (b * b)]])  # (a, b) -> (ln median, beta)
    covariance = jacobian @ np.linalg.inv(information) @ jacobian.T
    return float(np.exp(-a / b)), float(1.0 / b), covariance


def fragility(
    scene: Scene,
    var,
    level: float,
    intensities,
    method: MonteCarlo,
    *,
    reference: float = 1.0,
    confidence: float = 0.95,
) -> Fragility:
    r"""The fragility curve ``P(max_{0 <= t <= T} q(t) > level)`` against the intensity measure, with its
    lognormal fit.

    At the intensity ``s`` the scene's noise intensity ``D`` becomes ``D (s / reference)^2`` (the ground motion
    ``s / reference`` times the scene's; a harmonic force of :func:`jdpim.harmonic` is not scaled). The
    probability at each intensity is :func:`jdpim.first_passage` by Monte Carlo at the last saved time ``T``,
    intensity ``i`` on the seed ``method.seed + i`` (independent counts); the Wilson interval brackets it, and
    ``P(s) = Phi(ln(s / median) / beta)`` is fitted to all counts by maximum likelihood.

    Args:
        scene: the physics; its noise intensity ``D`` must be a concrete number.
        var: a coordinate name or a function of the state (as for :func:`jdpim.first_passage`).
        level: the demand level (one number).
        intensities: ``(I,)``, ``I >= 2`` increasing positive intensity measures.
        method: ``jdpim.MonteCarlo(...)``: ``n_samples`` paths at every intensity.
        reference: the intensity measure of the scene as given (> 0): for instance its peak ground acceleration
            in m/s^2, to give ``intensities`` in m/s^2; 1 (the default) makes ``s`` the scale factor itself.
        confidence: the level of the intervals, in (0, 1).

    Returns:
        :class:`Fragility`; its ``median``, ``beta`` and their standard errors are ``nan`` (with a
        :class:`FragilityWarning`) where the counts are separated and the fit does not exist.

    Examples:
        >>> import jdpim
        >>> model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None)
        >>> scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(0.1), t_end=5.0, dt=0.02)
        >>> fr = jdpim.fragility(scene, "x", 0.5, [0.5, 1.0, 2.0], jdpim.MonteCarlo(n_samples=500, seed=0))
        >>> fr.probability.shape, bool(fr.probability[2] > fr.probability[0])
        ((3,), True)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if not isinstance(method, MonteCarlo):
        raise TypeError(f"method must be jdpim.MonteCarlo(...) (binomial counts at every intensity), got {method!r}")
    noise = concrete(parameter_value(scene, "D"))
    if noise is None or noise.ndim != 0:
        raise ValueError(f"scene's noise intensity D must be one concrete number (not traced), got {scene.noise!r}")
    level = check_number("level", level)
    s = real_array("intensities", intensities, "a 1-D sequence of positive numbers")
    if s.ndim != 1 or s.size < 2 or not np.all(np.isfinite(s)) or np.any(s <= 0) or np.any(np.diff(s) <= 0):
        raise ValueError(f"intensities must be at least 2 increasing positive finite numbers, got {s.tolist()}")
    reference = check_number("reference", reference, low=0.0, low_open=True)
    confidence = check_number("confidence", confidence, low=0.0, high=1.0, low_open=True, high_open=True)
    d = float(noise)
    runs = [
        first_passage(
            with_parameters(scene, {"D": d * (si / reference) ** 2}),
            var,
            level,
            dataclasses.replace(method, seed=method.seed + i),
        )
        for i, si in enumerate(s.tolist())
    ]
    n = method.n_samples
    counts = np.rint(np.array([float(run.probability[-1, 0]) for run in runs]) * n)  # equal weights 1 / n
    p = counts / n
    lower, upper = wilson_interval(counts, n, confidence)
    fit = fit_lognormal(s, counts, n)
    if fit is None:
        warnings.warn(
            f"the counts {counts.astype(int).tolist()} of {n} paths are separated (no intensity with an exceedance "
            "lies below one without): the lognormal fit does not exist; add intensities between, or paths",
            FragilityWarning,
            stacklevel=2,
        )
        median, beta, covariance = np.nan, np.nan, np.full((2, 2), np.nan)
    else:
        median, beta, covariance = fit
    return Fragility(
        times=(scene.save_at[-1],),
        intensities=s,
        probability=p,
        probability_stderr=np.sqrt(p * (1.0 - p) / n),
        lower=lower,
        upper=upper,
        median=np.float64(median),
        median_stderr=np.float64(median * np.sqrt(covariance[0, 0])),
        beta=np.float64(beta),
        beta_stderr=np.float64(np.sqrt(covariance[1, 1])),
        covariance=covariance,
        level=level,
        n_samples=n,
        confidence=confidence,
        method=method.name,
    )
