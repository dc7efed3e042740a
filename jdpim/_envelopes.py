r"""Envelopes ``e(t)`` of uniformly modulated noise (``jdpim.WhiteNoise(D, envelope=...)``).

An envelope is any hashable function of the time in s that JAX can trace; the classes here are frozen
dataclasses of floats (static: a new value recompiles).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
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


@dataclasses.dataclass(frozen=True)
class Jennings:
    r"""The piecewise envelope of Jennings, Housner and Tsai (1968): a quadratic rise, a plateau, an exponential decay.

    .. math::
        e(t) = (t / t_1)^2 \ (0 \le t < t_1), \qquad 1 \ (t_1 \le t \le t_2), \qquad e^{-c (t - t_2)} \ (t > t_2).

    Amin and Ang (1968) modulate with the same three stages (the same class serves their model). The envelope
    is continuous, with a peak of 1 over the strong-motion phase ``[t1, t2]``.

    Args:
        t1: the end of the rise, s (> 0).
        t2: the end of the strong motion, s (>= t1).
        c: the decay rate after ``t2``, 1/s (> 0).

    Example:
        >>> import jdpim
        >>> env = jdpim.Jennings(t1=2.0, t2=6.0, c=0.5)
        >>> tuple(round(float(env(t)), 4) for t in (1.0, 4.0, 8.0))
        (0.25, 1.0, 0.3679)
    """

    t1: float = 2.0
    t2: float = 6.0
    c: float = 0.5

    def __post_init__(self):
        check_real("t1", self.t1, low=0.0, low_open=True, scalar=True)
        check_real("t2", self.t2, low=float(self.t1), scalar=True)
        check_real("c", self.c, low=0.0, low_open=True, scalar=True)
        for name in ("t1", "t2", "c"):
            object.__setattr__(self, name, float(getattr(self, name)))

    def __call__(self, t):
        t = jnp.asarray(t)
        rise = (jnp.clip(t, 0.0, self.t1) / self.t1) ** 2
        return rise * jnp.exp(-self.c * jnp.maximum(t - self.t2, 0.0))


def check_envelope(envelope) -> None:
    """``TypeError`` unless ``envelope`` is ``None`` or a hashable function of the time that JAX traces to a real
    scalar (checked on abstract values: nothing is computed)."""
    if envelope is None:
        return
    if not callable(envelope):
        raise TypeError(f"envelope must be None or a function e(t) -> scalar, got {envelope!r}")
    try:
        hash(envelope)
    except TypeError:
        raise TypeError(
            f"envelope must be hashable (it is static structure: a function, or a frozen dataclass), got {envelope!r}"
        ) from None
    message = traced_scalar(envelope, "envelope", "e(t)", "a scalar time")
    if message:
        raise TypeError(message)


@functools.lru_cache(maxsize=256)
def traced_scalar(fn, name: str, call: str, on: str, n_args: int = 1) -> str:
    """``""`` where ``fn`` traces to a real scalar on ``n_args`` scalars, else why not, naming the function ``name``
    and its form ``call`` (``"e(t)"``) traced ``on`` (``"a scalar time"``). Cached: noises are rebuilt at every
    pytree unflattening."""
    scalar = jax.ShapeDtypeStruct((), jnp.zeros(()).dtype)
    try:
        out = jax.eval_shape(fn, *(scalar,) * n_args)
    except Exception as err:  # noqa: BLE001 - any failure to trace is the user's function's
        return f"{name} must be a function {call} that JAX can trace on {on}; {fn!r} failed: {err}"
    shape, dtype = getattr(out, "shape", None), getattr(out, "dtype", None)
    real = dtype is not None and jnp.issubdtype(dtype, jnp.number) and not jnp.issubdtype(dtype, jnp.complexfloating)
    if shape != () or not real:
        return f"{name} must return a real scalar for {on}, got shape {shape} and dtype {dtype}"
    return ""
