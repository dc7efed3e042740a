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


Distribution = Uniform | Normal
ANGLE = Uniform(-math.pi, math.pi)


def elementary_ppf(dist: Distribution, u: jnp.ndarray) -> jnp.ndarray:
    """JAX inverse CDF (for sampling random parameters in Monte Carlo)."""
    if isinstance(dist, Uniform):
        return dist.low + (dist.high - dist.low) * u
    return dist.mean + dist.std * jsp.ndtri(u)
