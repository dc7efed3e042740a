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

* **Linear systems** (no barrier, no nonlinear force; filters included) under white noise, stationary or
  modulated by an envelope ``e(t)``: the state ``y = (q, q')`` obeys ``y' = A y + G xi`` with
  ``E[xi xi^T] = 2 D e(t)^2 delta``, and its covariance the Lyapunov equation
  ``P' = A P + P A^T + G Q(t) G^T``, ``Q(t) = 2 D e(t)^2`` (:func:`lyapunov_covariance`); stationary
  noise gives the power spectral density ``S(omega) = H Q H^* / (2 pi)``, ``H = (i omega - A)^{-1} G``
  (:func:`linear_psd`) and the autocorrelation ``R(tau) = e^{A tau} P`` (:func:`linear_autocorrelation`).
* **Linear systems under an evolutionary spectrum** ``S(omega, t) = (D / pi) |A(omega, t)|^2`` (Priestley): the
  response to each harmonic, ``h(t, omega) = int_0^t e^{A (t - s)} G L A(omega, s) e^{i omega s} ds``, obeys a
  linear ODE, and ``P(t) = (2 / pi) int_0^inf Re(h h^*) d omega`` (:func:`evolutionary_covariance`).

All functions are NumPy/SciPy in float64 (reference values, not traced).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from scipy import integrate, linalg, special

from ._models import AbstractOscillator
from ._pytree import check_number
from .filters import as_mdof


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


def _state_space(model, noise) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, G, Q)`` of a linear ``model`` (a one-degree-of-freedom oscillator is lifted by
    ``jdpim.filters.as_mdof``): ``y' = A y + G xi``, ``(2 n, 2 n)`` and ``(2 n, m)``; ``Q = 2 D``, ``(m, m)``."""
    mdof = as_mdof(model) if isinstance(model, AbstractOscillator) else model
    if mdof.has_barrier or getattr(mdof, "force", None) is not None:
        raise ValueError(
            f"the covariance is exact for a linear model (no barrier, no nonlinear force), got {type(model).__name__} "
            f"with {'a barrier' if mdof.has_barrier else 'a nonlinear force'}"
        )
    A = mdof.linearised()
    if A is None:
        raise ValueError("the model's parameters must be numbers (they are traced)")
    n = mdof.dimension
    G = np.vstack([np.zeros((n, mdof.n_sources)), mdof.inverse_mass() @ np.asarray(mdof.gains, float)])
    Q = 2.0 * np.atleast_2d(np.asarray(noise.D, float))
    if Q.shape[0] != G.shape[1]:
        raise ValueError(f"the noise has {Q.shape[0]} sources; the model has {G.shape[1]}")
    return np.asarray(A, float), G, Q


def lyapunov_covariance(model, noise, times, P0=None) -> np.ndarray:
    r"""The covariance of the state ``(q, q')`` of a linear model at ``times``: ``P' = A P + P A^T + G Q(t) G^T``.

    ``Q(t) = 2 D e(t)^2`` for a noise modulated by ``e(t)`` (``2 D`` for stationary noise); solved by
    ``scipy.integrate.solve_ivp`` (DOP853, ``rtol = 1e-10``) in float64, the envelope evaluated in float64.

    Args:
        model: a linear model (:class:`jdpim.MDOFOscillator` without constraints or ``force``, filters
            included; or a one-degree-of-freedom oscillator without barrier or nonlinear terms).
        noise: a :class:`jdpim.WhiteNoise`.
        times: the times in s, increasing, >= 0.
        P0: the covariance at ``t = 0``, ``(2 n, 2 n)`` (``None``: zero, a start from rest).

    Returns:
        ``(len(times), 2 n, 2 n)``, ordered as the model's ``coordinates``.

    Examples:
        >>> import jdpim
        >>> model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None)
        >>> P = jdpim.exact.lyapunov_covariance(model, jdpim.WhiteNoise(D=0.1), [100.0])
        >>> round(float(P[0, 0, 0]), 6)  # D / alpha
        0.5
    """
    A, G, Q = _state_space(model, noise)
    if noise.spectrum is not None:
        raise ValueError(
            f"the noise has an evolutionary spectrum {noise.envelope!r}: its covariance is evolutionary_covariance's"
        )
    times = _times(times)
    k = A.shape[0]
    P0 = np.zeros((k, k)) if P0 is None else np.asarray(P0, float)
    if P0.shape != (k, k):
        raise ValueError(f"P0 must have shape {(k, k)}, got {P0.shape}")
    GQG = G @ Q @ G.T
    envelope = None if noise.envelope is None else jax.jit(noise.envelope)

    def rhs(t, p):
        P = p.reshape(k, k)
        weight = 1.0 if envelope is None else float(envelope(t)) ** 2
        return (A @ P + P @ A.T + weight * GQG).ravel()

    scale = max(1e-300, float(np.abs(GQG).max()))
    with jax.enable_x64(True):  # the envelope in float64
        sol = integrate.solve_ivp(
            rhs, (0.0, float(times[-1])), P0.ravel(), t_eval=times, method="DOP853", rtol=1e-10, atol=1e-14 * scale
        )
    if not sol.success:
        raise RuntimeError(f"the Lyapunov equation could not be integrated: {sol.message}")
    P = sol.y.T.reshape(len(times), k, k)
    return 0.5 * (P + np.swapaxes(P, 1, 2))


def _times(times) -> np.ndarray:
    """``times`` as a 1-D float array, checked finite, ``>= 0`` and increasing."""
    times = np.atleast_1d(np.asarray(times, float))
    if times.ndim != 1 or np.any(times < 0) or np.any(np.diff(times) < 0) or not np.all(np.isfinite(times)):
        raise ValueError(f"times must be finite, >= 0 and increasing, got {times.tolist()}")
    return times


def evolutionary_covariance(model, noise, times, *, dw: float, cutoff: float, step: float = 0.01) -> np.ndarray:
    r"""The covariance of the state ``(q, q')`` of a linear model from rest under an evolutionary spectrum.

    The noise ``xi(t) = L int A(omega, t) e^{i omega t} dZ(omega)`` (``L L^T = D``, ``E|dZ|^2 = d omega / pi`` per
    source; ``|A|^2`` the noise's evolutionary spectrum, ``e(t)^2`` for an envelope, 1 for white noise) drives
    ``y' = M y + G xi`` (``M`` the state matrix). The response to the harmonic ``omega`` is
    ``h(t, omega) e^{i omega t}`` with

    .. math::
        \dot h = (M - i\omega)\, h + G L A(\omega, t), \qquad h(0) = 0,
        \qquad P(t) = rac{2}{\pi} \int_0^\infty \mathrm{Re}ig(h h^*ig)\, d\omega,

    (``A`` real and even in ``omega``). The ODE is solved exactly for ``A`` linear in time between the nodes of a
    grid of spacing at most ``step`` (an exponential integrator: ``exp((M - i omega) step)`` and its two
    ``phi`` functions from one matrix exponential per frequency), so the only error in time is that of the linear
    interpolation of ``A``, ``O(step^2 d^2A/dt^2)``. The frequency integral is the spectral representation's sum:
    ``omega_k = k dw``, ``k = 0..round(cutoff / dw)``, weight ``dw`` (half at ``k = 0``). With the ``dw`` and
    ``cutoff`` of a scene's :meth:`jdpim.SpectralRepresentation.grid` this is the exact covariance of the forcing
    the scene simulates (over the representation's period, longer than the record, the sum is exact); as ``dw ->
    0`` and ``cutoff -> inf`` it tends to Priestley's integral. For an envelope or white noise it tends to
    :func:`lyapunov_covariance`, less the variance beyond the cutoff.

    Args:
        model: a linear model (as :func:`lyapunov_covariance`).
        noise: a :class:`jdpim.WhiteNoise`, with an evolutionary spectrum, an envelope or neither.
        times: the times in s, increasing, >= 0.
        dw: the frequency step, rad/s, > 0.
        cutoff: the largest frequency, rad/s, >= dw.
        step: the largest time step of the exponential integrator, s, > 0.

    Returns:
        ``(len(times), 2 n, 2 n)``, ordered as the model's ``coordinates``.

    Examples:
        >>> import jdpim
        >>> model = jdpim.VibroImpactOscillator(alpha=0.5, gamma=None, barrier=None)
        >>> P = jdpim.exact.evolutionary_covariance(model, jdpim.WhiteNoise(D=0.1), [40.0], dw=0.1, cutoff=20.0)
        >>> round(float(P[0, 0, 0]), 4)  # D / alpha
        0.2
    """
    A, G, Q = _state_space(model, noise)
    times = _times(times)
    dw = check_number("dw", dw, low=0.0, low_open=True)
    cutoff = check_number("cutoff", cutoff, low=dw)
    step = check_number("step", step, low=0.0, low_open=True)
    omega = dw * np.arange(int(round(cutoff / dw)) + 1)
    weight = np.full(omega.size, dw)
    weight[0] /= 2.0
    k = A.shape[0]
    GL = G @ np.linalg.cholesky(Q / 2.0)  # (2 n, m)
    spectrum = noise.spectrum
    with jax.enable_x64(True):  # |A|^2 in float64
        if spectrum is not None:
            square = jax.jit(lambda t: spectrum.on_grid(jnp.asarray(omega), t))
        elif noise.envelope is not None:
            square = jax.jit(
                lambda t: jnp.broadcast_to(jax.vmap(noise.envelope)(t)[:, None] ** 2, (t.size, omega.size))
            )
        else:
            square = None
        h = np.zeros((omega.size, k, GL.shape[1]), complex)
        out, t0 = [], 0.0
        for t1 in times:
            n_steps = int(np.ceil((t1 - t0) / step - 1e-9))
            if n_steps:
                nodes = np.linspace(t0, t1, n_steps + 1)
                if spectrum is not None:
                    spectrum.check_times(nodes)  # its parameters in range, with their names
                amplitude = np.ones((nodes.size, omega.size)) if square is None else np.asarray(square(nodes))
                if not np.all(np.isfinite(amplitude)) or np.any(amplitude < 0):
                    raise ValueError(f"the noise's |A(omega, t)|^2 must be finite and >= 0 on [{t0:g}, {t1:g}] s")
                h = _propagate(A, GL, omega, nodes, np.sqrt(amplitude), h)
            P = 2.0 / np.pi * np.einsum("w,wim,wjm->ij", weight, h, h.conj()).real
            out.append(0.5 * (P + P.T))
            t0 = t1
    return np.stack(out)


def _propagate(A, GL, omega, nodes, amplitude, h):
    r"""``h`` ``(W, 2 n, m)`` advanced over ``nodes`` (equal steps ``tau``) by ``h' = (A - i omega) h + GL a(omega,
    t)``, ``a`` ``(len(nodes), W)`` linear between the nodes, exactly: one step is ``h <- E h + F1 b0 + F2 (b1 - b0)``
    with ``E = e^Z``, ``F1 = tau phi1(Z)``, ``F2 = tau phi2(Z)``, ``Z = (A - i omega) tau``, ``phi1(z) = (e^z - 1) /
    z``, ``phi2(z) = (e^z - 1 - z) / z^2``. Where ``A`` is diagonalisable they act on its modes, and many steps are
    summed at once (``E^p = e^{p Z}``); else step by step with one matrix exponential per frequency (Van Loan's
    block ``[[Z, tau I, 0], [0, 0, I], [0, 0, 0]]``)."""
    k, tau = A.shape[0], nodes[1] - nodes[0]
    lam, V = np.linalg.eig(A)
    if np.linalg.cond(V) < 1e8:
        z = (lam[None, :] - 1j * omega[:, None]) * tau  # (W, k)
        small = np.abs(z) < 0.1  # Taylor series: no cancellation
        safe = np.where(small, 1.0, z)
        phi1 = np.where(small, sum(z**j / math.factorial(j + 1) for j in range(10)), np.expm1(safe) / safe)
        phi2 = np.where(small, sum(z**j / math.factorial(j + 2) for j in range(10)), (np.expm1(safe) - safe) / safe**2)
        inverse = np.linalg.inv(V)
        g = inverse @ GL  # (k, m): the forcing on the modes
        w = np.einsum("ij,wjm->wim", inverse, h)
        chunk = max(1, 2**22 // z.size)
        for j0 in range(0, nodes.size - 1, chunk):
            a = amplitude[j0 : j0 + chunk + 1]  # (p + 1, W)
            p = a.shape[0] - 1
            c = tau * (phi1[None] * a[:-1, :, None] + phi2[None] * (a[1:] - a[:-1])[:, :, None])  # (p, W, k)
            decay = np.exp(z[None] * np.arange(p - 1, -1, -1)[:, None, None])  # E^(p - 1 - j)
            w = np.exp(p * z)[:, :, None] * w + np.sum(decay * c, axis=0)[:, :, None] * g[None]
        return np.einsum("ij,wjm->wim", V, w)
    block = np.zeros((omega.size, 3 * k, 3 * k), complex)
    block[:, :k, :k] = (A[None] - 1j * omega[:, None, None] * np.eye(k)) * tau
    block[:, :k, k : 2 * k] = tau * np.eye(k)
    block[:, k : 2 * k, 2 * k :] = np.eye(k)
    expm = linalg.expm(block)
    E, F1, F2 = expm[:, :k, :k], expm[:, :k, k : 2 * k], expm[:, :k, 2 * k :]
    for j in range(nodes.size - 1):
        b0, b1 = amplitude[j][:, None, None] * GL, amplitude[j + 1][:, None, None] * GL
        h = E @ h + F1 @ b0 + F2 @ (b1 - b0)
    return h


def linear_psd(model, noise, omega) -> np.ndarray:
    r"""Two-sided power spectral densities ``S_ii(omega)`` (per rad/s) of every state entry of a linear model in
    its stationary state: the diagonal of ``H Q H^* / (2 pi)``, ``H = (i omega I - A)^{-1} G``, ``Q = 2 D``;
    ``int S_ii = P_ii``, the stationary variance. For one source this is ``|H_i(omega)|^2 S0``, ``S0 = D / pi``.

    Returns:
        ``(len(omega), 2 n)``, ordered as the model's ``coordinates``.
    """
    A, G, Q = _state_space(model, noise)
    noise.require_stationary("linear_psd", "give a WhiteNoise without an envelope")
    omega = np.atleast_1d(np.asarray(omega, float))
    eye = np.eye(A.shape[0])
    H = np.linalg.solve(1j * omega[:, None, None] * eye - A, np.broadcast_to(G, (len(omega), *G.shape)))
    return np.real(np.einsum("wik,kl,wil->wi", H, Q, H.conj())) / (2.0 * np.pi)


def linear_autocorrelation(model, noise, lags) -> np.ndarray:
    r"""Stationary autocovariances ``R_ii(tau) = E[y_i(t) y_i(t + tau)]`` of every state entry of a linear model:
    the diagonal of ``P e^{A^T tau}``, ``P`` the stationary covariance (``A P + P A^T + G Q G^T = 0``).

    Returns:
        ``(len(lags), 2 n)``, ordered as the model's ``coordinates``.
    """
    A, G, Q = _state_space(model, noise)
    noise.require_stationary("linear_autocorrelation", "give a WhiteNoise without an envelope")
    P = linalg.solve_continuous_lyapunov(A, -G @ Q @ G.T)
    lags = np.abs(np.atleast_1d(np.asarray(lags, float)))
    lam, V = np.linalg.eig(A.T)
    if np.linalg.cond(V) < 1e8:  # e^{A^T tau} = V e^{Lambda tau} V^-1, all lags at once
        E = np.einsum("ik,tk,kj->tij", V, np.exp(np.outer(lags, lam)), np.linalg.inv(V)).real
    else:  # a defective (critically damped) mode
        E = np.stack([linalg.expm(A.T * tau) for tau in lags])
    return np.einsum("ij,tji->ti", P, E)  # the diagonal of P e^{A^T tau}
