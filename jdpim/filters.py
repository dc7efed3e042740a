r"""Excitations beyond white noise, as filter coordinates appended to a :class:`jdpim.MDOFOscillator`.

A one-degree-of-freedom oscillator (:class:`jdpim.VibroImpactOscillator`, :class:`jdpim.Oscillator`) is first
lifted to the same description by :func:`as_mdof` (coordinate ``x``, its barrier a constraint ``x >= b``).

Each function returns a new model whose last coordinates are a linear filter driven by the scene's white
noise (``E[w(t) w(t+s)] = 2 D delta(s)``); the structure feels the filter's output through the augmented
damping and stiffness matrices. DPIM and Monte Carlo carry the filter like any other coordinate, densities
of its coordinates are available by name, and its parameters are entries of the matrices
(``jdpim.parameter_names(scene)``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

from ._mdof import Barrier, MDOFOscillator
from ._models import AbstractOscillator, VibroImpactOscillator
from ._pytree import check_number, check_real, concrete

HARMONIC = "xh"  # the coordinate of a harmonic filter (its cosine)


@dataclasses.dataclass(frozen=True)
class _PaddedForce:
    """A model's force ``f(q, v, params)`` on its ``n`` coordinates, zero on ``k`` filter coordinates appended."""

    force: Callable
    n: int
    k: int

    def __call__(self, q, v, params):
        f = jnp.reshape(self.force(q[: self.n], v[: self.n], params), (self.n,))
        return jnp.concatenate([f, jnp.zeros((self.k,), f.dtype)])


def _block(model: MDOFOscillator, name: str, k: int) -> np.ndarray:
    """``model``'s damping or stiffness matrix padded to ``(n + k, n + k)`` (zeros where absent)."""
    n = model.dimension
    out = np.zeros((n + k, n + k))
    value = getattr(model, name)
    if value is not None:
        out[:n, :n] = np.asarray(value)
    return out


def _cubic_damping(q, v, gamma):
    """The force ``-gamma v^3`` of :class:`jdpim.VibroImpactOscillator`'s cubic damping, ``(1,)``."""
    return -gamma * v**3


def _oscillator_force(q, v, model):
    """The force ``-g(x) - f(x, v)`` of a one-degree-of-freedom ``model``, ``(1,)``."""
    return jnp.reshape(-model.restoring(q[0]) - model.damping(q[0], v[0]), (1,))


def as_mdof(model: AbstractOscillator) -> MDOFOscillator:
    r"""A one-degree-of-freedom oscillator as the :class:`jdpim.MDOFOscillator` with the same paths.

    ``x'' + g(x) + f(x, x') = h . xi`` becomes ``M = [[1]]``, ``B = h`` (a row: the gains must not depend on
    the state), the barrier the constraint ``x >= b`` with restitution ``r``; the coordinate keeps its name
    ``x``, and paths start at the barrier where a scene gives no ``x0``, as for the oscillator itself. For
    :class:`jdpim.VibroImpactOscillator` the linear terms are the matrices ``C = [[alpha]]``,
    ``K = [[omega^2]]`` and the cubic damping a force with ``params = gamma``; for other oscillators
    ``g`` and ``f`` are a force with ``params = model`` (the model's parameters stay traced leaves).

    Examples:
        >>> import jdpim
        >>> lifted = jdpim.filters.as_mdof(jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, omega=2.0))
        >>> lifted.coordinates, lifted.stiffness.tolist()
        (('x', 'v'), [[4.0]])
    """
    if not isinstance(model, AbstractOscillator):
        raise TypeError(f"model must be a one-degree-of-freedom oscillator, got {type(model).__name__}")
    zero = jnp.zeros(())
    gains = jnp.reshape(jnp.asarray(model.gains(zero, zero)), (1, -1))
    probe = jnp.asarray([0.7, -1.3])
    moved = concrete(jnp.reshape(jnp.asarray(model.gains(probe[0], probe[1])), (1, -1)))
    if moved is not None and concrete(gains) is not None and not np.array_equal(moved, concrete(gains)):
        raise ValueError(
            f"a filter needs additive noise, but {type(model).__name__}'s gains depend on the state "
            f"({_numbers(concrete(gains))} at rest, {_numbers(moved)} at (x, v) = (0.7, -1.3))"
        )
    constraints = () if model.barrier is None else (Barrier((1.0,), model.barrier, model.r),)
    barrier = None if model.barrier is None else concrete(model.barrier)
    start = None if barrier is None else (float(barrier),)  # a scene without x0 starts at the barrier
    gains = gains if concrete(gains) is None else np.asarray(concrete(gains), dtype=float)
    common = {"mass": np.ones((1, 1)), "gains": gains, "constraints": constraints, "names": ("x",), "start": start}
    if isinstance(model, VibroImpactOscillator):
        damping = None if model.alpha is None else _one_by_one(model.alpha)
        force = None if model.gamma is None else _cubic_damping
        stiffness = _one_by_one(model.omega, power=2)
        return MDOFOscillator(damping=damping, stiffness=stiffness, force=force, params=model.gamma, **common)
    return MDOFOscillator(force=_oscillator_force, params=model, **common)


def _one_by_one(value, power: int = 1):
    """``[[value^power]]``: float64 NumPy where ``value`` is a number (as the matrices of a model built from
    numbers), else traced."""
    number = concrete(value)
    if number is None:
        return jnp.reshape(jnp.asarray(value) ** power, (1, 1))
    return np.reshape(float(number) ** power, (1, 1))


def _numbers(values) -> str:
    """``values`` as ``[a, b, ...]`` with 6 significant digits."""
    return "[" + ", ".join(f"{float(a):.6g}" for a in np.ravel(values)) + "]"


def _structure(model) -> MDOFOscillator:
    """``model`` as the :class:`jdpim.MDOFOscillator` a filter is appended to (:func:`as_mdof` for one degree of
    freedom), else a ``TypeError``."""
    if isinstance(model, AbstractOscillator):
        return as_mdof(model)
    if not isinstance(model, MDOFOscillator):
        raise TypeError(
            f"model must be a jdpim.MDOFOscillator or a one-degree-of-freedom oscillator, got {type(model).__name__}"
        )
    return model


def _augment(model, names, mass, damping, stiffness, gains, start=None) -> MDOFOscillator:
    """``model`` with the filter coordinates ``names`` appended: the filter rows of every matrix given."""
    n, k = model.dimension, len(names)
    base = model.coordinates[:n]
    clash = sorted(set(base) & set(names))
    if clash:
        raise ValueError(f"the model already has coordinates named {clash}: name its coordinates (names=...)")
    constraints = tuple(
        Barrier(c.normal + (0.0,) * k, c.position, c.r) for c in model.constraints
    )  # the filter is not constrained
    force = None if model.force is None else _PaddedForce(model.force, n, k)
    if start is None and model.start is not None:
        start = model.start + (0.0,) * k
    return MDOFOscillator(
        mass=np.block([[np.asarray(model.mass), np.zeros((n, k))], [np.zeros((k, n)), mass]]),
        gains=gains,
        damping=damping,
        stiffness=stiffness,
        constraints=constraints,
        force=force,
        params=model.params,
        names=base + tuple(names),
        start=start,
    )


def _influence(model: MDOFOscillator, influence) -> np.ndarray:
    n = model.dimension
    iota = np.ones(n) if influence is None else np.asarray(influence, dtype=float)
    if iota.shape != (n,):
        raise ValueError(f"influence must have {n} entries (one per coordinate), got shape {list(iota.shape)}")
    check_real("influence", iota)
    return iota


def kanai_tajimi(model: MDOFOscillator, omega_g: float = 15.6, zeta_g: float = 0.6, influence=None) -> MDOFOscillator:
    r"""``model`` shaken by a Kanai-Tajimi ground acceleration instead of its own forcing.

    The filter coordinate ``xf`` (velocity ``vf``) obeys ``xf'' + 2 zeta_g omega_g xf' + omega_g^2 xf = -w(t)``;
    the ground acceleration ``a_g = xf'' + w = -(2 zeta_g omega_g xf' + omega_g^2 xf)`` has the power spectral
    density

    .. math::
        S_{a_g}(\omega) = S_0\,\frac{\omega_g^4 + 4\zeta_g^2\omega_g^2\omega^2}
                                     {(\omega_g^2 - \omega^2)^2 + 4\zeta_g^2\omega_g^2\omega^2},
        \qquad S_0 = D / \pi \ \text{(two-sided)},

    and the structure feels ``-M iota a_g``: ``M q'' + C q' + K q = M iota (2 zeta_g omega_g xf' + omega_g^2 xf)``.
    The model's own gains are not used (the scene's single noise source drives the filter).

    Args:
        model: the structure, ``n`` coordinates.
        omega_g: the ground's frequency, rad/s, > 0 (15.6 with ``zeta_g = 0.6``: firm soil).
        zeta_g: the ground's damping ratio, > 0.
        influence: ``iota``, ``(n,)``: how each coordinate feels the ground (``None``: ones).

    Examples:
        >>> import jdpim
        >>> jdpim.kanai_tajimi(jdpim.pounding_frame(n_storeys=2)).coordinates
        ('x1', 'x2', 'xf', 'v1', 'v2', 'vf')
    """
    model = _structure(model)
    wg = check_number("omega_g", omega_g, low=0.0, low_open=True)
    zg = check_number("zeta_g", zeta_g, low=0.0, low_open=True)
    iota = _influence(model, influence)
    n = model.dimension
    m_iota = np.asarray(model.mass) @ iota
    damping, stiffness = _block(model, "damping", 1), _block(model, "stiffness", 1)
    damping[:n, n], stiffness[:n, n] = -2.0 * zg * wg * m_iota, -wg * wg * m_iota
    damping[n, n], stiffness[n, n] = 2.0 * zg * wg, wg * wg
    gains = np.zeros((n + 1, 1))
    gains[n, 0] = -1.0
    return _augment(model, ("xf",), np.ones((1, 1)), damping, stiffness, gains)


def clough_penzien(
    model, omega_g: float = 15.6, zeta_g: float = 0.6, omega_f: float = 1.5, zeta_f: float = 0.6, influence=None
) -> MDOFOscillator:
    r"""``model`` shaken by a Clough-Penzien ground acceleration: Kanai-Tajimi with its low frequencies removed.

    The Kanai-Tajimi filter ``xf`` of :func:`kanai_tajimi` (driven by ``-w``) gives ``a1 = -(2 zeta_g omega_g xf'
    + omega_g^2 xf)``; a second filter ``xc'' + 2 zeta_f omega_f xc' + omega_f^2 xc = a1`` passes it through the
    high-pass ``-omega^2 / (omega_f^2 - omega^2 + 2 i zeta_f omega_f omega)``, and the ground acceleration is
    ``a_g = xc'' = a1 - 2 zeta_f omega_f xc' - omega_f^2 xc``, with the power spectral density

    .. math::
        S_{a_g}(\omega) = S_0\,\frac{\omega_g^4 + 4\zeta_g^2\omega_g^2\omega^2}
                                     {(\omega_g^2 - \omega^2)^2 + 4\zeta_g^2\omega_g^2\omega^2}\,
                          \frac{\omega^4}{(\omega_f^2 - \omega^2)^2 + 4\zeta_f^2\omega_f^2\omega^2},
        \qquad S_0 = D / \pi \ \text{(two-sided)}.

    It vanishes at ``omega = 0``, so the ground velocity and displacement stay bounded, unlike Kanai-Tajimi's.
    The structure feels ``-M iota a_g``; coordinates ``xf`` and ``xc`` (velocities ``vf``, ``vc``) are appended. A
    modulated noise (``jdpim.WhiteNoise(D, envelope=...)``) drives the filters: the ground motion is then the
    response of the filters to ``e(t) w(t)``. The model's own gains are not used.

    Args:
        model: the structure, ``n`` coordinates (a one-degree-of-freedom oscillator is lifted by :func:`as_mdof`).
        omega_g: the ground's frequency, rad/s, > 0.
        zeta_g: the ground's damping ratio, > 0.
        omega_f: the high-pass filter's frequency, rad/s, > 0 (about a tenth of ``omega_g``).
        zeta_f: the high-pass filter's damping ratio, > 0.
        influence: ``iota``, ``(n,)``: how each coordinate feels the ground (``None``: ones).

    Examples:
        >>> import jdpim
        >>> jdpim.clough_penzien(jdpim.VibroImpactOscillator(), omega_f=1.0).coordinates
        ('x', 'xf', 'xc', 'v', 'vf', 'vc')
    """
    model = _structure(model)
    wg = check_number("omega_g", omega_g, low=0.0, low_open=True)
    zg = check_number("zeta_g", zeta_g, low=0.0, low_open=True)
    wf = check_number("omega_f", omega_f, low=0.0, low_open=True)
    zf = check_number("zeta_f", zeta_f, low=0.0, low_open=True)
    iota = _influence(model, influence)
    n = model.dimension
    m_iota = np.asarray(model.mass) @ iota
    damping, stiffness = _block(model, "damping", 2), _block(model, "stiffness", 2)
    for matrix, ground, high in ((damping, 2.0 * zg * wg, 2.0 * zf * wf), (stiffness, wg * wg, wf * wf)):
        matrix[:n, n] = -ground * m_iota  # M q'' + C q' + K q = -M iota a_g
        matrix[:n, n + 1] = -high * m_iota
        matrix[n, n] = ground  # xf'' + ground xf = -w
        matrix[n + 1, n] = ground  # xc'' + high xc = a1 = -ground xf
        matrix[n + 1, n + 1] = high
    gains = np.zeros((n + 2, 1))
    gains[n, 0] = -1.0
    return _augment(model, ("xf", "xc"), np.eye(2), damping, stiffness, gains)


def first_order_filter(model: MDOFOscillator, a: float = 1.0) -> MDOFOscillator:
    r"""``model`` driven by coloured noise: each of its white noises ``w_k`` replaced by ``y_k' = -a y_k + w_k``.

    ``y_k`` has the exponential correlation ``E[y_k(t) y_k(t+s)] = (D / a) e^{-a |s|}`` (stationary variance
    ``D / a``; the spectral density ``(D / pi) / (a^2 + omega^2)``). It is carried as the velocity of a filter
    coordinate ``z_k`` with ``z_k'' + a z_k' = w_k`` (named ``xf`` / ``vf``, or ``xf1``, ``xf2``, ... for
    several sources); the structure feels ``B y`` where it felt ``B w``. ``z_k`` itself diffuses without bound:
    only its velocity is the filter's output.

    Args:
        model: the structure, ``n`` coordinates and ``m`` noise sources (gains ``B``, ``(n, m)``).
        a: the filter's rate, 1/s, > 0 (its correlation time is ``1 / a``).

    Examples:
        >>> import jdpim
        >>> jdpim.first_order_filter(jdpim.impact_damper(), a=2.0).coordinates
        ('x1', 'x2', 'xf', 'v1', 'v2', 'vf')
    """
    model = _structure(model)
    rate = check_number("a", a, low=0.0, low_open=True)
    n, m = model.dimension, model.n_sources
    B = np.asarray(model.gains, dtype=float)
    damping = _block(model, "damping", m)
    damping[:n, n:] = -B
    damping[n:, n:] = rate * np.eye(m)
    gains = np.vstack([np.zeros((n, m)), np.eye(m)])
    names = ("xf",) if m == 1 else tuple(f"xf{k + 1}" for k in range(m))
    return _augment(model, names, np.eye(m), damping, _block(model, "stiffness", m), gains)


def harmonic(model: MDOFOscillator, amplitude: float, frequency: float, direction=None) -> MDOFOscillator:
    r"""``model`` with a harmonic force ``A cos(Omega t) b`` added to its white-noise forcing.

    The cosine is the filter coordinate ``xh`` (velocity ``vh``) of ``xh'' + Omega^2 xh = 0`` that starts at
    ``xh = 1``, ``vh = 0`` (the model's ``start``, used where the scene gives no ``x0``; a scene's ``x0`` must
    put 1 there itself, else the scene is refused); the structure feels ``A b xh``.

    Args:
        model: the structure, ``n`` coordinates.
        amplitude: ``A`` (units of force per unit mass of the model's matrices).
        frequency: ``Omega``, rad/s, > 0.
        direction: ``b``, ``(n,)`` (``None``: the model's first noise source's gains, ``B[:, 0]``).

    Examples:
        >>> import jdpim
        >>> jdpim.harmonic(jdpim.impact_damper(), amplitude=0.1, frequency=0.9).start
        (0.0, 0.0, 1.0)
    """
    model = _structure(model)
    amp = check_number("amplitude", amplitude)
    w = check_number("frequency", frequency, low=0.0, low_open=True)
    n = model.dimension
    b = np.asarray(model.gains, dtype=float)[:, 0] if direction is None else np.asarray(direction, dtype=float)
    if b.shape != (n,):
        raise ValueError(f"direction must have {n} entries (one per coordinate), got shape {list(b.shape)}")
    check_real("direction", b)
    stiffness = _block(model, "stiffness", 1)
    stiffness[:n, n] = -amp * b
    stiffness[n, n] = w * w
    gains = np.vstack([np.asarray(model.gains, dtype=float), np.zeros((1, model.n_sources))])
    start = (model.start or (0.0,) * n) + (1.0,)
    return _augment(model, (HARMONIC,), np.ones((1, 1)), _block(model, "damping", 1), stiffness, gains, start)


def check_harmonic_start(model, x0) -> None:
    """``ValueError`` where a scene's ``x0`` (concrete, scalar or ``(n,)``) gives the harmonic filter coordinate
    ``xh`` of :func:`harmonic` a start other than 1: it scales the harmonic force (0 switches it off)."""
    names = model.coordinates[: model.dimension]
    if HARMONIC not in names:
        return
    i = names.index(HARMONIC)
    value = float(np.broadcast_to(x0, (model.dimension,))[i])
    if value != 1.0:
        raise ValueError(
            f"x0 starts the harmonic filter coordinate {HARMONIC} at {value:g}, which scales the harmonic force by "
            f"{value:g}: give x0[{i}] = 1.0, or leave x0=None (the model's start)"
        )
