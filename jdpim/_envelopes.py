r"""Envelopes ``e(t)`` of uniformly modulated noise (``jdpim.WhiteNoise(D, envelope=...)``).

An envelope is any hashable function of the time in s that JAX can trace; the classes here are frozen
dataclasses of floats (static: a new value recompiles).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp

from ._pytree import check_real


@dataclasses.dataclass(frozen=True)
class ShinozukaSato:
    r"""The Shinozuka-Sato envelope ``e(t) = (exp(-b1 t) - exp(-b2 t)) / e_max``, normalised to a peak of 1.

    The peak lies at ``t* = ln(b2 / b1) / (b2 - b1)``; the envelope rises from 0 at ``t = 0`` and decays like
    ``exp(-b1 t)``.

    Args:
        b1: decay rate in 1/s (> 0).
        b2: rise rate in 1/s (> b1).

    Example:
        >>> import jdpim
        >>> env = jdpim.ShinozukaSato(b1=0.1, b2=0.5)
        >>> round(env.peak_time, 4), round(float(env(env.peak_time)), 6)
        (4.0236, 1.0)
    """

    b1: float = 0.1
    b2: float = 0.5

    def __post_init__(self):
        check_real("b1", self.b1, low=0.0, low_open=True, scalar=True)
        check_real("b2", self.b2, low=float(self.b1), low_open=True, scalar=True)
        object.__setattr__(self, "b1", float(self.b1))
        object.__setattr__(self, "b2", float(self.b2))

    @property
    def peak_time(self) -> float:
        """``t*``, s: where the envelope peaks."""
        return math.log(self.b2 / self.b1) / (self.b2 - self.b1)

    def __call__(self, t):
        t_peak = self.peak_time
        peak = math.exp(-self.b1 * t_peak) - math.exp(-self.b2 * t_peak)
        return (jnp.exp(-self.b1 * t) - jnp.exp(-self.b2 * t)) / peak
