r"""Evolutionary spectra: fully non-stationary noise ``WhiteNoise(D, envelope=spectrum)`` (Priestley's oscillatory
processes).

The forcing is the white noise's spectral process shaped harmonic by harmonic by a modulating function
``A(omega, t) >= 0`` that depends on the frequency as well as the time,

.. math::
    \xi(t) = \int_{-\infty}^{\infty} A(\omega, t)\, e^{i\omega t}\, dZ(\omega), \qquad
    E|dZ(\omega)|^2 = \frac{D}{\pi}\, d\omega,

so that its evolutionary (two-sided, per rad/s) spectrum is ``S(omega, t) = (D / pi) |A(omega, t)|^2``. A spectrum
object gives ``|A(omega, t)|^2`` (dimensionless: the evolutionary spectrum relative to the white noise's density
``D / pi``); an envelope ``e(t)`` is the case ``|A|^2 = e(t)^2``. The spectral representation
(:class:`jdpim.SpectralRepresentation`) draws it with the same coefficients as the white noise,
``sum_k sqrt(2 (D / pi) |A(w_k, t)|^2 dw) (X_k cos w_k t + Y_k sin w_k t)``: two elementary variables per source
for DPIM, as for stationary noise.

The classes are frozen dataclasses (hashable, static: a new value recompiles).
"""

from __future__ import annotations

import abc
import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._envelopes import check_envelope, traced_scalar
from ._pytree import check_real


class AbstractEvolutionarySpectrum(abc.ABC):
    """``|A(omega, t)|^2``: an evolutionary spectrum relative to the white noise's density ``D / pi``.

    Subclasses are hashable and implement ``__call__(omega, t)`` (rad/s, s; scalars, traced by JAX) and may add
    checks of their parameters over the record (:meth:`check_times`).
    """

    @abc.abstractmethod
    def __call__(self, omega, t):
        """``|A(omega, t)|^2 >= 0`` at the frequency ``omega`` (rad/s) and the time ``t`` (s)."""

    def check_times(self, times: np.ndarray) -> None:
        """Raise a ``ValueError`` naming a parameter that leaves its range at some of ``times`` (s); none here."""
        return

    def on_grid(self, omega, times):
        """``|A(omega_k, t_j)|^2``, ``(len(times), len(omega))``, traced (one evaluation per grid point)."""
        return jax.vmap(jax.vmap(self, (0, None)), (None, 0))(omega, times)

    def check(self, omega: np.ndarray, times: np.ndarray) -> None:
        """``ValueError`` unless the spectrum is finite and non-negative at every ``omega`` (rad/s) and ``times``
        (s), its parameters in range (computed once per grid)."""
        self.check_times(np.asarray(times, float))
        message = _grid_message(self, tuple(np.asarray(omega, float)), tuple(np.asarray(times, float)))
        if message:
            raise ValueError(message)


@functools.lru_cache(maxsize=64)
def _grid_message(spectrum, omega: tuple, times: tuple) -> str:
    """``""`` where ``spectrum`` is finite and ``>= 0`` on the grid, else where it is not (evaluated in blocks of
    times, eagerly also inside a trace)."""
    w = np.asarray(omega)
    block = max(1, 2**20 // len(w))
    evaluate = jax.jit(spectrum.on_grid)  # one compilation, not one per operation
    with jax.ensure_compile_time_eval():
        values = np.concatenate(
            [np.asarray(evaluate(w, np.asarray(times[i : i + block]))) for i in range(0, len(times), block)]
        )
    bad = ~np.isfinite(values) | (values < 0)
    if not bad.any():
        return ""
    j, k = np.argwhere(bad)[0]
    return (
        f"the evolutionary spectrum {spectrum!r} must be finite and >= 0 on the spectral grid; at omega={w[k]:g} "
        f"rad/s, t={times[j]:g} s it is {values[j, k]:g}"
    )


@dataclasses.dataclass(frozen=True)
class EvolutionarySpectrum(AbstractEvolutionarySpectrum):
    r"""A user's evolutionary spectrum ``|A(omega, t)|^2 = density(omega, t)``: the forcing's evolutionary
    spectrum is ``S(omega, t) = (D / pi) density(omega, t)`` (two-sided, per rad/s).

    Args:
        density: a function of the frequency (rad/s) and the time (s), scalars, returning a real scalar ``>= 0``;
            traceable by JAX and hashable (a function, or a frozen dataclass). Checked finite and non-negative on
            the spectral grid of each scene.

    Examples:
        >>> import jax.numpy as jnp
        >>> import jdpim
        >>> spectrum = jdpim.EvolutionarySpectrum(lambda w, t: jnp.exp(-0.1 * t) / (1.0 + (w / (10.0 - 0.2 * t)) ** 2))
        >>> noise = jdpim.WhiteNoise(D=0.05, envelope=spectrum)
        >>> round(float(spectrum(0.0, 1.0)), 4)
        0.9048
    """

    density: Callable

    def __post_init__(self):
        if not callable(self.density):
            raise TypeError(f"density must be a function density(omega, t) -> scalar, got {self.density!r}")
        try:
            hash(self.density)
        except TypeError:
            raise TypeError(
                f"density must be hashable (a function, or a frozen dataclass), got {self.density!r}"
            ) from None
        message = traced_scalar(self.density, "density", "density(omega, t)", "scalar omega and t", 2)
        if message:
            raise TypeError(message)

    def __call__(self, omega, t):
        return self.density(omega, t)


def _law(name: str, value):
    """A parameter that may vary in time: a number (> 0), a piecewise-linear table ``((t_0, t_1, ...), (p_0, p_1,
    ...))`` (times increasing, values > 0; constant beyond its ends), or a function ``p(t)`` (hashable, traceable,
    a real scalar); returned as a float, a pair of float tuples, or the function."""
    if callable(value):
        try:
            check_envelope(value)
        except TypeError as err:
            raise TypeError(str(err).replace("envelope", name).replace("e(t)", f"{name}(t)")) from None
        return value
    if isinstance(value, (list, tuple)):
        try:
            times, values = (np.asarray(v, dtype=float) for v in value)
        except (TypeError, ValueError):
            raise ValueError(
                f"{name} must be a number, a function of t or a table ((t0, t1, ...), (p0, p1, ...)), got {value!r}"
            ) from None
        if times.ndim != 1 or times.shape != values.shape or times.size < 2 or np.any(np.diff(times) <= 0):
            raise ValueError(f"{name}'s table needs two rows of equal length >= 2, times increasing; got {value!r}")
        check_real(f"{name}'s times", times)
        check_real(name, values, low=0.0, low_open=True)
        return tuple(times.tolist()), tuple(values.tolist())
    check_real(name, value, low=0.0, low_open=True, scalar=True)
    return float(value)


@functools.partial(jax.jit, static_argnums=0)
def _on_times(law, times):
    """A :func:`_law`'s values at ``times`` ``(T,)`` (one compilation per law)."""
    return jax.vmap(lambda t: jnp.asarray(_at(law, t), float))(times)


def _at(law, t):
    """The value of a :func:`_law` at the time ``t`` (traced)."""
    if isinstance(law, float):
        return law
    if isinstance(law, tuple):
        return jnp.interp(t, jnp.asarray(law[0]), jnp.asarray(law[1]))
    return law(t)


@dataclasses.dataclass(frozen=True)
class EvolutionaryKanaiTajimi(AbstractEvolutionarySpectrum):
    r"""The non-stationary Kanai-Tajimi (or Clough-Penzien) ground acceleration: the soil's frequency and damping vary
    in time, and an envelope sets the intensity.

    .. math::
        |A(\omega, t)|^2 = e(t)^2\,
            \frac{\omega_g^4 + 4\zeta_g^2\omega_g^2\omega^2}{(\omega_g^2 - \omega^2)^2 + 4\zeta_g^2\omega_g^2\omega^2}
            \Big[\frac{\omega^4}{(\omega_f^2 - \omega^2)^2 + 4\zeta_f^2\omega_f^2\omega^2}\Big],
        \quad \omega_g = \omega_g(t),\ \zeta_g = \zeta_g(t),

    the bracket (Clough-Penzien's high-pass) where ``omega_f`` is given. With constant parameters and the white
    noise's density ``S0 = D / pi`` this is the stationary density of :func:`jdpim.kanai_tajimi` (or
    :func:`jdpim.clough_penzien`) times ``e(t)^2``: the evolutionary model lets the frequency content drift as well,
    typically ``omega_g`` falling through the record as the surface waves arrive.

    Args:
        omega_g: the ground's frequency in rad/s: a number > 0, a table ``((t0, t1, ...), (w0, w1, ...))``
            interpolated linearly (constant beyond its ends), or a function of ``t`` (hashable, traceable); > 0
            over the record.
        zeta_g: the ground's damping ratio, in the same forms, > 0.
        omega_f: the high-pass frequency in rad/s (same forms), or ``None`` for Kanai-Tajimi alone.
        zeta_f: the high-pass damping ratio (same forms), > 0.
        envelope: ``e(t)`` (:class:`jdpim.ShinozukaSato`, :class:`jdpim.Jennings`, any function), or ``None``
            (``e = 1``).

    Examples:
        >>> import jdpim
        >>> ground = jdpim.EvolutionaryKanaiTajimi(omega_g=((0.0, 20.0), (15.0, 6.0)), zeta_g=0.4,
        ...                                        envelope=jdpim.ShinozukaSato(0.1, 0.5))
        >>> noise = jdpim.WhiteNoise(D=0.02, envelope=ground)
        >>> round(float(ground(0.0, 10.0)), 4), round(float(jdpim.ShinozukaSato(0.1, 0.5)(10.0)) ** 2, 4)  # e(t)^2 at 0
        (0.4557, 0.4557)
    """

    omega_g: object = 15.6
    zeta_g: object = 0.6
    omega_f: object = None
    zeta_f: object = 0.6
    envelope: Callable | None = None

    def __post_init__(self):
        for name in ("omega_g", "zeta_g", "zeta_f") + (() if self.omega_f is None else ("omega_f",)):
            object.__setattr__(self, name, _law(name, getattr(self, name)))
        check_envelope(self.envelope)

    def _laws(self) -> tuple:
        names = ("omega_g", "zeta_g") + (() if self.omega_f is None else ("omega_f", "zeta_f"))
        return tuple((name, getattr(self, name)) for name in names)

    def check_times(self, times: np.ndarray) -> None:
        """``omega_g``, ``zeta_g`` (and ``omega_f``, ``zeta_f``) finite and > 0 at every one of ``times``."""
        for name, law in self._laws():
            if isinstance(law, float):
                continue
            with jax.ensure_compile_time_eval():
                values = np.asarray(_on_times(law, times))
            bad = ~np.isfinite(values) | (values <= 0)
            if bad.any():
                j = int(np.argmax(bad))
                raise ValueError(
                    f"{name} must be finite and > 0 over the record, got {values[j]:g} at t={times[j]:g} s"
                )

    def __call__(self, omega, t):
        w2 = omega * omega
        wg, zg = _at(self.omega_g, t), _at(self.zeta_g, t)
        cross = 4.0 * zg * zg * wg * wg * w2
        out = (wg**4 + cross) / ((wg * wg - w2) ** 2 + cross)
        if self.omega_f is not None:
            wf, zf = _at(self.omega_f, t), _at(self.zeta_f, t)
            out = out * w2 * w2 / ((wf * wf - w2) ** 2 + 4.0 * zf * zf * wf * wf * w2)
        if self.envelope is not None:
            out = out * jnp.asarray(self.envelope(t)) ** 2
        return out
