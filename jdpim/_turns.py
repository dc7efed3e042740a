"""Angles in turns (one turn is ``2 pi``): multiples modulo one, and their cosine and sine.

The DPIM random functions evaluate ``m Theta`` for harmonics ``m`` in the thousands. In float32 the product
``m Theta`` keeps only about 11 bits below the point at ``m = 6000``, so its value modulo ``2 pi`` is coarse:
a uniform derived from it is resolved to about 1e-4 there and rounds to 0 for about one harmonic in eight
thousand (6446 harmonics at t = 200 s, dt = 0.01 s). :func:`fractional_multiples`
takes the multiple of a turn ``t`` modulo one exactly in integer arithmetic for the leading bits of ``t`` and
rounds only the small rest, so the result is accurate to the precision of ``t`` itself whatever ``m``.

XLA's CPU cosine and sine handle any argument and are not vectorised (an order of magnitude slower than ``exp``
there); :func:`cos_sin_turns` needs only ``[0, 1)`` turns, reduced exactly to an eighth of a turn and a quadrant,
and evaluates Taylor polynomials there, in the operations XLA fuses and vectorises.
"""

import math

import jax.numpy as jnp
import numpy as np

_SPLIT = 2**11  # t = n / _SPLIT + low with |n| <= _SPLIT for |t| <= 1: n m is an exact integer


def fractional_multiples(t, m, offset: float = 0.0):
    """``m (offset + t)`` modulo one, in ``[0, 1)``.

    Args:
        t: turns, a float array with ``|t| <= 1``.
        m: non-negative integers (NumPy, static), of ``t``'s rank, broadcast against it.
        offset: a static number of turns, a multiple of ``2**-11``, taken exactly (``t + offset`` would round).

    Returns:
        ``frac(m (offset + t))`` in ``t``'s dtype, with the error of two roundings of numbers below
        ``1 + m / 4096`` (the product ``m t`` itself is never formed).
    """
    m = np.asarray(m, dtype=np.int64)
    steps = offset * _SPLIT
    if steps != round(steps):
        raise ValueError(f"offset must be a multiple of 2**-11 turn, got {offset!r}")
    n = jnp.round(t * _SPLIT)
    low = t - n / _SPLIT  # exact: |low| <= 2**-12, on t's own grid
    m_mod = m % _SPLIT  # m (n + steps) modulo _SPLIT, in int32 without overflow
    whole = jnp.mod(jnp.asarray(m_mod, jnp.int32) * n.astype(jnp.int32) + (m_mod * int(steps)) % _SPLIT, _SPLIT)
    s = whole.astype(t.dtype) / _SPLIT + jnp.asarray(m, t.dtype) * low
    return s - jnp.floor(s)


def _taylor(odd: bool, dtype) -> tuple[float, ...]:
    """Coefficients of ``sin(2 pi r) / r`` (odd) or ``cos(2 pi r)`` in powers of ``r**2``, every term that reaches
    a 64th of ``dtype``'s epsilon on ``|r| <= 1/8``."""
    eps = float(jnp.finfo(dtype).eps)
    terms, k = [], 1 if odd else 0
    while (math.pi / 4) ** k / math.factorial(k) > eps / 64:
        terms.append((-1) ** (k // 2) * (2 * math.pi) ** k / math.factorial(k))
        k += 2
    return tuple(terms)


def _horner(r2, coefficients):
    acc = jnp.full_like(r2, coefficients[-1])
    for c in coefficients[-2::-1]:
        acc = acc * r2 + c
    return acc


def cos_sin_turns(s):
    """``(cos(2 pi s), sin(2 pi s))`` for a float array ``s`` in ``[0, 1)``, each to about one ulp.

    ``s = q / 4 + r`` with the nearest quarter ``q / 4`` (so ``|r| <= 1/8``, exact); Taylor polynomials in ``r``
    give the cosine and sine of ``2 pi r``, and the quadrant ``q`` turns them.
    """
    q = jnp.round(4 * s)
    r = s - q / 4
    r2 = r * r
    c = _horner(r2, _taylor(False, s.dtype))
    sn = r * _horner(r2, _taylor(True, s.dtype))
    quadrant = q.astype(jnp.int32) % 4
    cos = jnp.select([quadrant == 0, quadrant == 1, quadrant == 2], [c, -sn, -c], sn)
    sin = jnp.select([quadrant == 0, quadrant == 1, quadrant == 2], [sn, c, -sn], -c)
    return cos, sin
