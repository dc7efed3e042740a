r"""Fragility curves: ``P(max_{0 <= t <= T} q(t) > level)`` as a function of the excitation's intensity.

At every intensity ``s`` the scene's noise intensity is ``D (s / reference)^2``: the ground motion (white noise,
or a linear filter of it, modulated or not) is ``s / reference`` times the scene's, so any intensity measure
proportional to it (the root-mean-square ground acceleration at the envelope's peak, the median peak ground
acceleration) is ``s`` where the scene's is ``reference``. The probability of exceeding the level within the record
is a first passage on its own paths (independent seeds), so the estimates at the intensities are independent:

- Monte Carlo: the counts ``k_i`` of ``n`` paths are binomials, with Wilson intervals;
- subset simulation: ``p_i`` with the c.o.v. ``delta_i`` of Au & Beck (chain correlation included); above level 0
  the estimate is a product of level fractions, so ``ln p_i`` is close to normal and the interval is lognormal,
  ``p_i exp(-+ z sqrt(ln(1 + delta_i^2)))``; where it stops at level 0 it is a binomial count of ``N`` (Wilson).

The lognormal fragility ``P(s) = Phi(ln(s / median) / beta)`` is fitted by maximum likelihood of binomial counts
(a probit regression on ``ln s``), with standard errors from the observed information. For subset simulation each
estimate enters as ``p_i n_i`` exceedances of ``n_i = p_i (1 - p_i) / se_i^2`` paths, its effective sample size:
the binomial (quasi-)likelihood whose variance at the estimate is subset simulation's, so each intensity weighs
by its own precision, and Monte Carlo (``n_i = n``) is the special case.
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Any

import numpy as np
from scipy import special, stats

from .._io import Persistent
from .._pytree import check_int, check_number, concrete, pytree_dataclass, real_array, static_field
from .._scene import Scene, parameter_value, with_parameters
from ..methods._monte_carlo import MonteCarlo
from ._first_passage import first_passage
from ._subset import SubsetSimulation


class FragilityWarning(UserWarning):
    """The lognormal fit of a fragility curve does not exist (the counts are separated), or subset simulation found
    no sample above the level at an intensity: more paths, intensities or levels."""


@pytree_dataclass
class Fragility(Persistent):
    r"""A fragility curve and its lognormal fit.

    Attributes:
        times: ``(T,)``, the end of the record, s: the probabilities are of an exceedance in ``[0, T]``.
        intensities: ``(I,)``, the intensity measures ``s`` (units of ``reference``).
        probability: ``(I,)``, ``P(max q > level)`` at each intensity (Monte Carlo: ``k_i / n``).
        probability_stderr: ``(I,)``, Monte Carlo: ``sqrt(p (1 - p) / n)``; subset simulation: ``p delta``, its
            c.o.v. ``delta`` with the correlation along the chains (``nan`` where ``p = 0``).
        lower, upper: ``(I,)``, the interval of each probability at ``confidence``: Wilson's score interval for a
            binomial count (Monte Carlo, and subset simulation that stops at level 0), else the lognormal interval
            ``p exp(-+ z sqrt(ln(1 + delta^2)))`` (``[0, nan]`` where subset simulation gives ``p = 0``).
        median: the fitted median capacity ``theta`` (units of ``s``): ``P(theta) = 1/2``; ``nan`` where the
            fit does not exist.
        median_stderr: its standard error (observed information, delta method).
        beta: the fitted dispersion (the standard deviation of ``ln`` capacity).
        beta_stderr: its standard error.
        covariance: ``(2, 2)``, the covariance of the estimates of ``(ln median, beta)``.
        fit_p_value: the p-value of Pearson's chi-square of the fit, ``sum_i (k_i - n_i P(s_i))^2 / (n_i P (1 - P))``
            on ``I - 2`` degrees of freedom (``nan`` for ``I = 2`` or without a fit): a small value says the
            lognormal does not describe the curve at the precision of its estimates.
        level: the demand level.
        n_samples: ``n``, the paths at each intensity (subset simulation: ``N``, the samples per level).
        n_evaluations: ``(I,)``, the responses computed (paths integrated) at each intensity.
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
    fit_p_value: Any = None
    n_evaluations: Any = None
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


def fit_lognormal(intensities, counts, n) -> tuple:
    """``(median, beta, covariance of (ln median, beta))`` by maximum likelihood over the binomial counts ``k_i``
    of ``n`` trials (one number, or one per intensity, not necessarily whole: effective sample sizes), or ``None``
    where the counts are separated (no exceedance above the lowest intensity with a non-exceedance, or the
    reverse) and the likelihood has no maximum."""
    x, k = np.log(np.asarray(intensities, float)), np.asarray(counts, float)
    n = np.broadcast_to(np.asarray(n, float), k.shape)
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


def fit_p_value_of(intensities, counts, n, median: float, beta: float) -> float:
    """The p-value of Pearson's chi-square ``sum_i (k_i - n_i P_i)^2 / (n_i P_i (1 - P_i))`` of the lognormal
    ``P_i = Phi(ln(s_i / median) / beta)`` against the counts ``k_i`` of ``n_i``, on ``I - 2`` degrees of freedom
    (two fitted parameters); ``nan`` for ``I <= 2``."""
    eta = np.log(np.asarray(intensities, float) / median) / beta
    if eta.size <= 2:
        return np.nan
    k, n = np.asarray(counts, float), np.broadcast_to(np.asarray(n, float), eta.shape)
    p = special.ndtr(eta)
    chi_square = np.sum(np.square(k - n * p) / (n * p * special.ndtr(-eta)))  # 1 - P without cancellation
    return float(stats.chi2.sf(chi_square, eta.size - 2))


def _binomial(p, n: int, confidence: float) -> tuple:
    """``(p, stderr, lower, upper, counts, sizes)`` of Monte Carlo proportions ``p`` of ``n`` equally weighted
    paths: ``k / n`` of the counts ``k = p n`` (rounded), ``sqrt(p (1 - p) / n)``, the Wilson interval, ``k``,
    ``n`` per intensity."""
    counts = np.rint(p * n)  # equal weights 1 / n
    p = counts / n
    return p, np.sqrt(p * (1.0 - p) / n), *wilson_interval(counts, n, confidence), counts, np.full(p.shape, float(n))


def _subset_estimates(runs, n: int, confidence: float) -> tuple:
    """``(p, stderr, lower, upper, counts, sizes, evaluations)`` of subset-simulation runs of ``n`` samples per
    level. A run that stopped at level 0 (``n`` evaluations: ``p >= p0``) is a count of ``n`` independent samples:
    the binomial case. Above it, the lognormal interval from the c.o.v. ``delta = stderr / p``, cut at 1, and the
    effective sample size ``n_e = p (1 - p) / stderr^2`` with the count ``p n_e``; where ``p = 0`` (no c.o.v.)
    the interval is ``[0, nan]`` and the size 0 (no weight in the fit)."""
    p = np.array([float(run.probability[-1, 0]) for run in runs])
    stderr = np.array([float(run.probability_stderr[-1, 0]) for run in runs])
    evaluations = np.array([int(run.n_evaluations) for run in runs])
    level0 = evaluations == n
    p0, stderr0, lower0, upper0, counts0, _ = _binomial(p, n, confidence)
    z = special.ndtri(0.5 + 0.5 * confidence)
    with np.errstate(divide="ignore", invalid="ignore"):
        spread = np.exp(z * np.sqrt(np.log1p(np.square(stderr / p))))
        sizes = np.where(p > 0, p * (1.0 - p) / np.square(stderr), 0.0)
    lower = np.where(level0, lower0, np.where(p > 0, p / spread, 0.0))
    upper = np.where(level0, upper0, np.minimum(p * spread, 1.0))
    sizes = np.where(level0, float(n), sizes)
    return (
        np.where(level0, p0, p),
        np.where(level0, stderr0, stderr),
        lower,
        upper,
        np.where(level0, counts0, p * sizes),
        sizes,
        evaluations,
    )


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
    probability at each intensity is :func:`jdpim.first_passage` by ``method`` at the last saved time ``T``,
    intensity ``i`` on the seed ``method.seed + i`` (independent estimates); a Wilson interval (binomial counts) or
    a lognormal one (subset simulation above level 0) brackets it, and ``P(s) = Phi(ln(s / median) / beta)`` is
    fitted to all of them by maximum likelihood (subset simulation's estimates as counts of their effective sample
    sizes ``p (1 - p) / stderr^2``; module docstring).

    Args:
        scene: the physics; its noise intensity ``D`` must be a concrete number.
        var: a coordinate name or a function of the state (as for :func:`jdpim.first_passage`).
        level: the demand level (one number).
        intensities: ``(I,)``, ``I >= 2`` increasing positive intensity measures.
        method: ``jdpim.MonteCarlo(...)``: ``n_samples`` paths at every intensity; or
            ``jdpim.SubsetSimulation(...)`` for small probabilities (down to ``p0^max_levels``), whose cost grows
            with ``ln(1 / P)`` instead of ``1 / P``.
        reference: the intensity measure of the scene as given (> 0): for instance its peak ground acceleration
            in m/s^2, to give ``intensities`` in m/s^2; 1 (the default) makes ``s`` the scale factor itself.
        confidence: the level of the intervals, in (0, 1).

    Returns:
        :class:`Fragility`; its ``median``, ``beta`` and their standard errors are ``nan`` (with a
        :class:`FragilityWarning`) where the counts are separated and the fit does not exist. Subset simulation
        that finds no sample above ``level`` within ``max_levels`` gives ``p = 0`` there, left out of the fit, with
        a :class:`FragilityWarning`.

    Examples:
        >>> import jdpim
        >>> model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None)
        >>> scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(0.1), t_end=2.0, dt=0.02)
        >>> fr = jdpim.fragility(scene, "x", 0.5, [0.5, 1.0, 2.0], jdpim.MonteCarlo(n_samples=200, seed=0))
        >>> fr.probability.shape, bool(fr.probability[2] > fr.probability[0])
        ((3,), True)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if not isinstance(method, (MonteCarlo, SubsetSimulation)):
        raise TypeError(
            f"method must be jdpim.MonteCarlo(...) or jdpim.SubsetSimulation(...) (independent estimates at every "
            f"intensity), got {method!r}"
        )
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
    if isinstance(method, MonteCarlo):
        n = method.n_samples
        probability = np.array([float(run.probability[-1, 0]) for run in runs])
        p, stderr, lower, upper, counts, sizes = _binomial(probability, n, confidence)
        evaluations = np.full(s.shape, n)
        data = f"the counts {counts.astype(int).tolist()} of {n} paths"
    else:
        n = method.n_per_level
        p, stderr, lower, upper, counts, sizes, evaluations = _subset_estimates(runs, n, confidence)
        data = f"the subset-simulation probabilities {p.tolist()}"
        if np.any(p == 0):
            warnings.warn(
                f"subset simulation found no sample above level={level!r} at the intensities "
                f"{s[p == 0].tolist()} within max_levels={method.max_levels}: their probabilities are 0 with no error "
                "estimate and they are left out of the fit; raise max_levels",
                FragilityWarning,
                stacklevel=2,
            )
    kept = sizes > 0
    fit = fit_lognormal(s[kept], counts[kept], sizes[kept])
    if fit is None:
        warnings.warn(
            f"{data} are separated (no intensity with an exceedance lies below one without): the lognormal fit does "
            "not exist; add intensities between, or paths",
            FragilityWarning,
            stacklevel=2,
        )
        median, beta, covariance, fit_p_value = np.nan, np.nan, np.full((2, 2), np.nan), np.nan
    else:
        median, beta, covariance = fit
        fit_p_value = fit_p_value_of(s[kept], counts[kept], sizes[kept], median, beta)
    return Fragility(
        times=(scene.save_at[-1],),
        intensities=s,
        probability=p,
        probability_stderr=stderr,
        lower=lower,
        upper=upper,
        median=np.float64(median),
        median_stderr=np.float64(median * np.sqrt(covariance[0, 0])),
        beta=np.float64(beta),
        beta_stderr=np.float64(np.sqrt(covariance[1, 1])),
        covariance=covariance,
        fit_p_value=np.float64(fit_p_value),
        n_evaluations=evaluations,
        level=level,
        n_samples=n,
        confidence=confidence,
        method=method.name,
    )
