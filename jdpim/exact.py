r"""Exact and reference solutions for the oscillator with a rigid barrier at ``x = b``.

Notation: ``H = (x^2 + v^2) / 2`` (unit natural frequency), ``a = alpha / 2``, ``wd = sqrt(1 - a^2)``.

* **Elastic impacts, linear damping** (``r = 1``, ``x'' + alpha x' + x = xi``, barrier at 0, from rest):
  the impact map is the folding ``x = |s|``, ``v = sign(s) s'`` of the free linear oscillator
  ``s'' + alpha s' + s = xi`` (Zhuravlev's transformation), whose state is Gaussian with the Lyapunov
  covariance ``C(t)``; so ``p(x, v, t) = 2 N2((x, v); 0, C(t))`` on ``x > 0`` exactly.
* **Elastic impacts, energy-dependent damping** ``x'' + h(H) x' + x = xi``: the stationary
  Fokker-Planck solution of the folded free system, ``p(x, v) = C exp(-(1/D) int_0^H h(u) du)`` on ``x > 0``.
* **r < 1, the paper's system** (approximate): energy-envelope stochastic averaging with one impact
  per half period ``pi`` losing ``(1 - r^2) H``: ``p_H(H) = exp(-(a_e H + b H^2) / D) / Z``,
  ``a_e = alpha + (1 - r^2) / pi``, ``b = 3 gamma / 4``; ``p(x, v) = p_H(H) / pi`` on ``x > 0``.

All functions are NumPy/SciPy (reference values, not traced).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import integrate, special


def linear_covariance(alpha: float, D: float, t: float) -> tuple[float, float, float]:
    r"""``(E[s^2], E[s'^2], E[s s'])`` of ``s'' + alpha s' + s = xi`` from rest, ``E[xi xi] = 2 D delta``.

    .. math::
        \sigma_x^2 = \frac{D}{\alpha}\Big[1 - e^{-2at}\big(1 + \tfrac{a}{w_d}\sin 2w_d t
                     + 2\tfrac{a^2}{w_d^2}\sin^2 w_d t\big)\Big],\quad
        c_{xv} = \frac{D}{w_d^2} e^{-2at}\sin^2 w_d t,

    and ``sigma_v^2`` with the sign of the ``sin 2 wd t`` term flipped. ``t = inf`` gives ``(D/alpha, D/alpha, 0)``.
    """
    if not 0 < alpha < 2:
        raise ValueError(f"alpha must lie in (0, 2) (underdamped), got {alpha!r}")
    if np.isinf(t):
        return D / alpha, D / alpha, 0.0
    a = alpha / 2
    wd = np.sqrt(1 - a * a)
    e = np.exp(-2 * a * t)
    s2 = 2 * (a / wd) ** 2 * np.sin(wd * t) ** 2
    sx2 = D / alpha * (1 - e * (1 + a / wd * np.sin(2 * wd * t) + s2))
    sv2 = D / alpha * (1 - e * (1 - a / wd * np.sin(2 * wd * t) + s2))
    cxv = D * e * np.sin(wd * t) ** 2 / wd**2
    return float(sx2), float(sv2), float(cxv)


def elastic_linear_pdf_x(x, alpha: float, D: float, t: float = np.inf):
    """Exact marginal PDF of the displacement (half-normal), ``r = 1``, barrier at 0, from rest."""
    sx2, _, _ = linear_covariance(alpha, D, t)
    x = np.asarray(x, float)
    return np.where(x >= 0, 2 * np.exp(-0.5 * x * x / sx2) / np.sqrt(2 * np.pi * sx2), 0.0)


def elastic_linear_pdf_v(v, alpha: float, D: float, t: float = np.inf):
    r"""Exact marginal PDF of the velocity (skew-normal), ``r = 1``, barrier at 0, from rest.

    ``p(v) = 2 N(v; 0, sv2) Phi(cxv v / (sv2 sc))`` with ``sc^2 = sx2 - cxv^2 / sv2``.
    """
    sx2, sv2, cxv = linear_covariance(alpha, D, t)
    v = np.asarray(v, float)
    sc = np.sqrt(max(sx2 - cxv**2 / sv2, 1e-300))
    return 2 * np.exp(-0.5 * v * v / sv2) / np.sqrt(2 * np.pi * sv2) * special.ndtr(cxv * v / (sv2 * sc))


def elastic_linear_joint_pdf(x, v, alpha: float, D: float, t: float = np.inf):
    """Exact joint PDF ``2 N2((x, v); 0, C(t))`` on ``x >= 0``, grid ``x`` by ``v``; shape ``(len(x), len(v))``."""
    sx2, sv2, cxv = linear_covariance(alpha, D, t)
    X, V = np.meshgrid(np.asarray(x, float), np.asarray(v, float), indexing="ij")
    det = sx2 * sv2 - cxv**2
    q = (sv2 * X * X - 2 * cxv * X * V + sx2 * V * V) / det
    return np.where(X >= 0, 2 * np.exp(-0.5 * q) / (2 * np.pi * np.sqrt(det)), 0.0)


def energy_damping_pdf(h: Callable[[np.ndarray], np.ndarray], D: float):
    r"""Exact stationary joint PDF for ``x'' + h(H) x' + x = xi``, ``r = 1``, barrier at 0.

    ``p(x, v) = C exp(-(1/D) int_0^H h(u) du)`` on ``x > 0``, ``1/C = pi int_0^inf exp(-(1/D) int_0^E h) dE``.

    Args:
        h: energy-dependent damping coefficient, vectorised over ``H >= 0``.
        D: noise intensity (> 0).

    Returns:
        a function ``(x, v) -> p`` (broadcasting arrays).
    """

    def potential(E):
        return integrate.quad(h, 0.0, E)[0] / D

    upper = 1.0
    while potential(upper) < 60.0:
        upper *= 2.0
    norm = np.pi * integrate.quad(lambda E: np.exp(-potential(E)), 0.0, upper, limit=200)[0]
    Es = np.linspace(0.0, upper, 40001)
    phi = integrate.cumulative_trapezoid(h(Es), Es, initial=0.0) / D

    def pdf(x, v):
        x, v = np.asarray(x, float), np.asarray(v, float)
        H = 0.5 * (x * x + v * v)
        return np.where(x >= 0, np.exp(-np.interp(H, Es, phi, right=np.inf)) / norm, 0.0)

    return pdf


def averaging_energy_pdf(H, alpha: float, gamma: float, r: float, D: float):
    r"""Stochastic-averaging stationary PDF of the energy ``H`` (approximate, r < 1 allowed).

    ``p_H = exp(-(a_e H + b H^2) / D) / Z``, ``a_e = alpha + (1 - r^2) / pi``, ``b = 3 gamma / 4``.
    """
    a_e = alpha + (1 - r * r) / np.pi
    b = 0.75 * gamma
    H = np.asarray(H, float)
    if b == 0:
        Z = D / a_e
    else:
        Z = 0.5 * np.sqrt(np.pi * D / b) * special.erfcx(a_e / (2 * np.sqrt(b * D)))
    return np.where(H >= 0, np.exp(-(a_e * H + b * H * H) / D) / Z, 0.0)


def averaging_joint_pdf(x, v, alpha: float, gamma: float, r: float, D: float):
    """Stochastic-averaging stationary joint PDF ``p_H(H) / pi`` on ``x >= 0``, grid ``x`` by ``v`` (approximate)."""
    X, V = np.meshgrid(np.asarray(x, float), np.asarray(v, float), indexing="ij")
    return np.where(X >= 0, averaging_energy_pdf(0.5 * (X * X + V * V), alpha, gamma, r, D) / np.pi, 0.0)


def averaging_pdf_x(x, alpha: float, gamma: float, r: float, D: float, n_v: int = 801):
    """Stochastic-averaging stationary marginal PDF of ``x`` (quadrature over ``v``; approximate)."""
    return _marginal(lambda xx, vv: averaging_joint_pdf(xx, vv, alpha, gamma, r, D), x, axis=1, n=n_v)


def averaging_pdf_v(v, alpha: float, gamma: float, r: float, D: float, n_x: int = 801):
    """Stochastic-averaging stationary marginal PDF of ``v`` (quadrature over ``x``; approximate)."""
    return _marginal(lambda xx, vv: averaging_joint_pdf(xx, vv, alpha, gamma, r, D), v, axis=0, n=n_x)


def averaging_second_moment(alpha: float, gamma: float, r: float, D: float) -> float:
    """``E[x^2] = E[H]`` of the averaged stationary PDF (energy equipartition on average)."""
    return integrate.quad(lambda H: H * averaging_energy_pdf(H, alpha, gamma, r, D), 0, np.inf)[0]


def _marginal(joint, y, axis: int, n: int):
    y = np.asarray(y, float)
    span = 12.0 * max(1.0, float(np.max(np.abs(y))))
    other = np.linspace(0.0 if axis == 0 else -span, span, n)
    grid = joint(other, y) if axis == 0 else joint(y, other)
    return integrate.simpson(grid, x=other, axis=axis)
