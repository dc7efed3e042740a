r"""Gaussian white noise ``E[xi_k(t) xi_l(t + s)] = 2 D_kl delta(s)``, optionally modulated in time by an envelope, or
shaped in time and frequency by an evolutionary spectrum."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._envelopes import check_envelope
from ._evolutionary import AbstractEvolutionarySpectrum
from ._pytree import check_real, concrete, pytree_dataclass, static_field


@pytree_dataclass
class WhiteNoise:
    r"""Zero-mean Gaussian white noise with intensity matrix ``D``: ``E[xi(t) xi(t+s)^T] = 2 D delta(s)``.

    With an envelope ``e(t)`` the noise is uniformly modulated, ``e(t) xi(t)``: its intensity at ``t`` is
    ``D e(t)^2`` (:meth:`intensity`), as for an earthquake's ground motion.

    Args:
        D: intensity, a scalar >= 0 (one source) or a symmetric positive-definite ``(m, m)`` matrix
            (``m`` correlated sources). The two-sided power spectral density is ``S0 = D / pi``.
        envelope: ``None`` (stationary), or a function ``e(t) -> scalar`` of the time in s, traceable by JAX and
            hashable (static: changing it recompiles), e.g. :class:`jdpim.ShinozukaSato`. It multiplies the
            forcing at the integrator's nodes, so every method that integrates paths (DPIM, Monte Carlo, subset
            simulation) takes it; estimators that assume a constant ``D`` refuse it. Or an evolutionary spectrum
            ``|A(omega, t)|^2`` (:class:`jdpim.EvolutionaryKanaiTajimi`, :class:`jdpim.EvolutionarySpectrum`): the
            noise is then fully non-stationary, with the evolutionary spectrum ``S(omega, t) = (D / pi)
            |A(omega, t)|^2``; it shapes the harmonics of the spectral representation, so the scene needs
            ``excitation=jdpim.SpectralRepresentation()`` for Monte Carlo (DPIM's default).

    Examples:
        >>> import jdpim
        >>> jdpim.WhiteNoise(D=0.03).n_sources
        1
        >>> round(float(jdpim.WhiteNoise(D=0.03, envelope=jdpim.ShinozukaSato(0.1, 0.5)).intensity(1.0)), 4)
        0.0093
    """

    D: Any = 0.03
    envelope: Callable | None = static_field(default=None)

    def __post_init__(self):
        if not isinstance(self.envelope, AbstractEvolutionarySpectrum):
            check_envelope(self.envelope)
        if isinstance(self.D, (str, bytes)):
            raise TypeError(f"D must be a real number or a matrix of them, got {self.D!r}")
        if isinstance(self.D, (list, tuple)):  # one array leaf, not a leaf per entry
            leaves = jax.tree_util.tree_leaves(self.D)
            traced = any(isinstance(x, jax.core.Tracer) for x in leaves)
            try:
                arr = jnp.asarray(self.D) if traced else np.asarray(self.D, dtype=float)
            except (TypeError, ValueError):
                if any(isinstance(x, (str, bytes)) for x in leaves):
                    raise TypeError(f"D must be a real number or a matrix of them, got {self.D!r}") from None
                raise ValueError(f"D must be a scalar or a square (m, m) matrix, got {self.D!r}") from None
            object.__setattr__(self, "D", arr)
        arr = concrete(self.D)
        if arr is None:
            return
        if arr.ndim == 0:
            check_real("D", self.D, low=0.0)
        elif arr.ndim == 2 and arr.shape[0] == arr.shape[1] and arr.shape[0] >= 1:
            check_real("D", arr)
            if not np.allclose(arr, arr.T, rtol=1e-10, atol=1e-12):
                raise ValueError(f"D must be symmetric, got {arr.tolist()}")
            eig = np.linalg.eigvalsh(arr)
            if eig.min() <= 0:
                raise ValueError(f"D must be positive definite; its smallest eigenvalue is {eig.min():g}")
        else:
            raise ValueError(f"D must be a scalar or a square (m, m) matrix, got shape {arr.shape}")

    @property
    def n_sources(self) -> int:
        shape = np.shape(self.D)
        return 1 if len(shape) == 0 else int(shape[0])

    def mixing(self) -> jnp.ndarray:
        """``L`` with ``L L^T = D``, shape ``(m, m)``: ``xi = L z`` for unit-intensity sources ``z``."""
        D = jnp.asarray(self.D)
        if D.ndim == 0:
            return jnp.sqrt(D).reshape(1, 1)
        return jnp.linalg.cholesky(D)

    @property
    def spectrum(self) -> AbstractEvolutionarySpectrum | None:
        """The evolutionary spectrum ``|A(omega, t)|^2`` that shapes the noise, or ``None`` (white, or modulated by an
        envelope ``e(t)``)."""
        return self.envelope if isinstance(self.envelope, AbstractEvolutionarySpectrum) else None

    def intensity(self, t):
        """``D e(t)^2``: the intensity at time ``t`` (s; ``D`` itself for a stationary noise)."""
        if self.spectrum is not None:
            raise ValueError(
                f"the noise has no intensity D e(t)^2: its evolutionary spectrum {self.envelope!r} depends on the "
                "frequency, S(omega, t) = D / pi |A(omega, t)|^2"
            )
        D = jnp.asarray(self.D)
        return D if self.envelope is None else D * jnp.asarray(self.envelope(t)) ** 2

    def require_stationary(self, what: str, instead: str) -> None:
        """Raise a ``ValueError`` naming ``what`` (which assumes a constant ``D``) and ``instead`` where the noise is
        modulated."""
        if self.envelope is not None:
            raise ValueError(
                f"{what} assumes a constant noise intensity D, but the noise is modulated by "
                f"{self.envelope!r}: {instead}"
            )
