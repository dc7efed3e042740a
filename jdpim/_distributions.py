"""Distributions of the elementary random variables (the DPIM input space ``Theta``)."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import jax.scipy.special as jsp
import numpy as np
from scipy import special

from ._pytree import check_real


@dataclasses.dataclass(frozen=True)
class Uniform:
    """Uniform distribution on ``[low, high)``.

    Examples:
        >>> import jdpim
        >>> jdpim.Uniform(-1.0, 1.0).ppf(0.75)
        0.5
    """

    low: float = -math.pi
    high: float = math.pi

    def __post_init__(self):
        check_real("low", self.low)
        check_real("high", self.high)
        if not self.high > self.low:
            raise ValueError(f"Uniform needs high > low, got low={self.low!r}, high={self.high!r}")

    def ppf(self, u):
        return self.low + (self.high - self.low) * u

    def cdf(self, x, xp=np):
        return xp.clip((x - self.low) / (self.high - self.low), 0.0, 1.0)

    @property
    def support(self) -> tuple[float, float]:
        return float(self.low), float(self.high)

    @property
    def mean(self) -> float:
        return 0.5 * (self.low + self.high)

    @property
    def std(self) -> float:
        return (self.high - self.low) / math.sqrt(12.0)


@dataclasses.dataclass(frozen=True)
class Normal:
    """Normal distribution with ``mean`` and standard deviation ``std`` (> 0).

    Examples:
        >>> import jdpim
        >>> float(jdpim.Normal(1.0, 2.0).ppf(0.5))
        1.0
    """

    mean: float = 0.0
    std: float = 1.0

    def __post_init__(self):
        check_real("mean", self.mean)
        check_real("std", self.std, low=0.0, low_open=True)

    def ppf(self, u):
        return self.mean + self.std * special.ndtri(u)

    def cdf(self, x, xp=np):
        z = (x - self.mean) / self.std
        return special.ndtr(z) if xp is np else jsp.ndtr(z)

    @property
    def support(self) -> tuple[float, float]:
        return -math.inf, math.inf


@dataclasses.dataclass(frozen=True)
class TruncatedNormal:
    """A normal law ``N(loc, scale^2)`` restricted to ``[low, high]`` (either end may be infinite).

    The law for a parameter with a bounded range: ``TruncatedNormal(0.03, 0.01, low=0.0)`` is a damping that
    is never negative. ``mean`` and ``std`` are the truncated law's own moments.

    Examples:
        >>> import jdpim
        >>> float(jdpim.TruncatedNormal(0.0, 1.0, low=0.0).ppf(0.5)) > 0
        True
    """

    loc: float = 0.0
    scale: float = 1.0
    low: float = -math.inf
    high: float = math.inf

    def __post_init__(self):
        check_real("loc", self.loc)
        check_real("scale", self.scale, low=0.0, low_open=True)
        for name in ("low", "high"):
            value = getattr(self, name)
            if isinstance(value, (str, bytes)) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise TypeError(f"{name} must be a number (or +-inf), got {value!r}")
        if not self.high > self.low:
            raise ValueError(f"TruncatedNormal needs high > low, got low={self.low!r}, high={self.high!r}")
        if self._mass() <= 0.0:
            raise ValueError(f"TruncatedNormal: [{self.low}, {self.high}] holds no probability of N({self.loc}, ...)")

    def _bounds(self):
        """The standardised ends ``(a, b)`` and whether the law is sampled mirrored (its mass in the upper tail)."""
        a, b = (self.low - self.loc) / self.scale, (self.high - self.loc) / self.scale
        return (-b, -a, True) if a > 0 else (a, b, False)  # the lower tail keeps ndtr accurate

    def _mass(self) -> float:
        a, b, _ = self._bounds()
        return float(special.ndtr(b) - special.ndtr(a))

    def ppf(self, u, ndtr=special.ndtr, ndtri=special.ndtri):
        a, b, flip = self._bounds()
        z = ndtri(ndtr(a) + (ndtr(b) - ndtr(a)) * (1.0 - u if flip else u))
        return self.loc + self.scale * (-z if flip else z)

    def cdf(self, x, xp=np):
        ndtr = special.ndtr if xp is np else jsp.ndtr
        lo, hi = special.ndtr((self.low - self.loc) / self.scale), special.ndtr((self.high - self.loc) / self.scale)
        return xp.clip((ndtr((x - self.loc) / self.scale) - lo) / (hi - lo), 0.0, 1.0)

    @property
    def support(self) -> tuple[float, float]:
        return float(self.low), float(self.high)

    @property
    def mean(self) -> float:
        a, b = (self.low - self.loc) / self.scale, (self.high - self.loc) / self.scale
        return self.loc + self.scale * (_phi(a) - _phi(b)) / self._mass()

    @property
    def std(self) -> float:
        a, b = (self.low - self.loc) / self.scale, (self.high - self.loc) / self.scale
        z, d = self._mass(), (_phi(a) - _phi(b)) / self._mass()
        return self.scale * math.sqrt(max(1.0 + (_xphi(a) - _xphi(b)) / z - d * d, 0.0))


@dataclasses.dataclass(frozen=True)
class LogNormal:
    """The law of ``exp(N(mu, sigma^2))``: positive, for a parameter that must exceed zero (a frequency, a mass).

    Examples:
        >>> import jdpim
        >>> round(float(jdpim.LogNormal(0.0, 0.5).ppf(0.5)), 6)
        1.0
    """

    mu: float = 0.0
    sigma: float = 1.0

    def __post_init__(self):
        check_real("mu", self.mu)
        check_real("sigma", self.sigma, low=0.0, low_open=True)

    def ppf(self, u, ndtri=special.ndtri, exp=np.exp):
        return exp(self.mu + self.sigma * ndtri(u))

    def cdf(self, x, xp=np):
        ndtr = special.ndtr if xp is np else jsp.ndtr
        z = (xp.log(xp.maximum(x, np.finfo(float).tiny)) - self.mu) / self.sigma
        return xp.where(x > 0, ndtr(z), 0.0)

    @property
    def support(self) -> tuple[float, float]:
        return 0.0, math.inf

    @property
    def mean(self) -> float:
        return math.exp(self.mu + 0.5 * self.sigma**2)

    @property
    def std(self) -> float:
        return self.mean * math.sqrt(math.expm1(self.sigma**2))


def _phi(z: float) -> float:
    """The standard normal density (0 at +-inf)."""
    return 0.0 if math.isinf(z) else math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)


def _xphi(z: float) -> float:
    """``z phi(z)`` (0 at +-inf)."""
    return 0.0 if math.isinf(z) else z * _phi(z)


Distribution = Uniform | Normal | TruncatedNormal | LogNormal
ANGLE = Uniform(-math.pi, math.pi)


def elementary_ppf(dist: Distribution, u: jnp.ndarray) -> jnp.ndarray:
    """JAX inverse CDF (for sampling random parameters in Monte Carlo)."""
    if isinstance(dist, Uniform):
        return dist.low + (dist.high - dist.low) * u
    if isinstance(dist, TruncatedNormal):
        return dist.ppf(u, jsp.ndtr, jsp.ndtri)
    if isinstance(dist, LogNormal):
        return dist.ppf(u, jsp.ndtri, jnp.exp)
    return dist.mean + dist.std * jsp.ndtri(u)


@dataclasses.dataclass(frozen=True)
class Range:
    """The values a parameter may take: ``[low, high]``, either end open or absent (``None``: unbounded).

    One table of ranges serves fixed values (:meth:`check`) and the support of random laws (:meth:`check_law`).
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False

    def check(self, name: str, value, *, scalar: bool = True) -> None:
        """``ValueError`` (one line, naming ``name``) unless ``value`` is finite and inside the range."""
        check_real(
            name, value, low=self.low, high=self.high, low_open=self.low_open, high_open=self.high_open, scalar=scalar
        )

    def __str__(self) -> str:
        lo = "-inf" if self.low is None else f"{self.low:g}"
        hi = "inf" if self.high is None else f"{self.high:g}"
        left = "(" if self.low_open or self.low is None else "["
        return f"{left}{lo}, {hi}{')' if self.high_open or self.high is None else ']'}"

    def check_law(self, name: str, dist: Distribution) -> None:
        """``ValueError`` (one line) unless the support of ``dist`` lies inside the range, with a law that would."""
        lo, hi = dist.support
        lo_in = self.low is None or lo > self.low or (lo == self.low and not (self.low_open and _closed_low(dist)))
        hi_in = self.high is None or hi < self.high or (hi == self.high and not (self.high_open and _closed_high(dist)))
        if lo_in and hi_in:
            return
        a = lo if self.low is None else max(lo, self.low)
        b = hi if self.high is None else min(hi, self.high)
        if isinstance(dist, Uniform) and b > a and (a, b) != (lo, hi):
            hint = f"jdpim.Uniform({a:g}, {b:g})"
        elif self.low_open and self.low == 0.0 and self.high is None:
            hint = f"a positive law, e.g. jdpim.LogNormal({math.log(abs(dist.mean) or 1.0):.3g}, 0.2) (median e^mu)"
        else:
            loc, scale = (dist.loc, dist.scale) if isinstance(dist, TruncatedNormal) else (dist.mean, dist.std)
            loc = min(
                max(loc, -math.inf if self.low is None else self.low), math.inf if self.high is None else self.high
            )
            ends = [f"{key}={end:g}" for key, end in (("low", self.low), ("high", self.high)) if end is not None]
            hint = f"a truncated law, e.g. jdpim.TruncatedNormal({loc:g}, {scale:g}, {', '.join(ends)})"
            if self.low == 0.0 and self.high is None:
                hint += " or jdpim.LogNormal(...)"
        shown = f"{'(' if math.isinf(lo) else '['}{lo:g}, {hi:g}{')' if math.isinf(hi) else ']'}"
        raise ValueError(
            f"random[{name!r}] = {dist!r} takes values in {shown} but {name} must lie in {self}; use {hint}"
        )


def _closed_low(dist) -> bool:
    """Whether ``dist`` can take the lowest value of its support (a uniform law can; continuous tails cannot)."""
    return isinstance(dist, (Uniform, TruncatedNormal))


def _closed_high(dist) -> bool:
    return isinstance(dist, TruncatedNormal)
