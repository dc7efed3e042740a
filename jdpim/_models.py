r"""Oscillator models: ``x'' + g(x) + f(x, x') = sum_k h_k(x, x') xi_k(t)`` on ``x > barrier``.

The impact law at the barrier is ``x'_+ = -r x'_-``. Physical parameters are traced pytree leaves; a
term set to ``None`` is left out of the traced program entirely (no ``gamma * v**3`` when there is no
cubic damping, no impact logic when ``barrier is None``).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._constraints import Constraints
from ._distributions import Range
from ._pytree import check_real, concrete, pytree_dataclass, static_field

# the values each parameter may take: fixed values are checked against these where a model is built, the laws of
# random parameters (``Scene(random=...)``) where a scene is
RESTITUTION = Range(0.0, 1.0)
RK4_RADIUS = 2.6  # RK4's stability region holds the half disc |z| <= 2.615 of the left half plane (rk4_step_limit)
GROWING = 1e-6  # a mode grows where Re(lambda) > GROWING |lambda| (below: the rounding of a neutral one's eigenvalue)
RANGES = {"alpha": Range(0.0), "gamma": Range(0.0), "omega": Range(0.0, low_open=True), "r": RESTITUTION}


class AbstractSystem:
    """What the integrator and the sampling methods need of a model (one path's functions; batches use ``vmap``).

    ``dimension`` (``n``), ``coordinates`` (``2 n`` names: coordinates then velocities), ``n_sources``,
    ``state_acceleration(q, v, xi) -> (n,)``, ``stacked_constraints() -> Constraints | None``, ``has_barrier``
    and ``may_be_stiff`` (whether sub-stepping is traced when the scene asks for it). A model whose forces depend
    on the time overrides ``time_dependent`` and ``state_acceleration_at(t, q, v, xi)``.
    """

    @property
    def may_be_stiff(self) -> bool:
        """Whether the model has terms that can make explicit RK4 unstable (then sub-stepping is traced)."""
        return True

    @property
    def time_dependent(self) -> bool:
        """Whether the acceleration depends on the time: the integrator then calls :meth:`state_acceleration_at`."""
        return False

    def state_acceleration_at(self, t, q, v, xi):
        """The acceleration ``(n,)`` at time ``t`` (s) of one path; ``state_acceleration(q, v, xi)`` unless the model
        overrides it (with ``time_dependent``), e.g. for a deterministic load ``f(t)``."""
        return self.state_acceleration(q, v, xi)

    def replace(self, **changes):
        """A copy with fields replaced, e.g. ``model.replace(alpha=0.05)``."""
        return dataclasses.replace(self, **changes)

    def parameter_range(self, name: str) -> Range:
        """The values the parameter ``name`` may take (what fixed values and random laws are checked against)."""
        return RANGES.get(name, Range())

    def rest(self) -> np.ndarray:
        """The coordinates the model is linearised at (:meth:`linearised`): zeros, ``(n,)``."""
        return np.zeros(self.dimension)

    def linearised(self) -> np.ndarray | None:
        """``(2 n, 2 n)``: the Jacobian of ``(q, v) -> (v, q'')`` without noise at ``(rest, 0)``; ``None`` where
        the model's parameters are traced (then the step is checked where the scene is built with numbers)."""
        if any(concrete(leaf) is None for leaf in jax.tree_util.tree_leaves(self)):
            return None
        n = self.dimension
        dq, dv = _rest_jacobian(self, np.asarray(self.rest(), jnp.result_type(float)), n_sources_of(self))
        return np.block([[np.zeros((n, n)), np.eye(n)], [np.asarray(dq), np.asarray(dv)]])


@functools.partial(jax.jit, static_argnums=2)
def _rest_jacobian(model: AbstractSystem, q, n_sources: int):
    """``(d q''/d q, d q''/d v)`` ``(n, n)`` each at ``(q, 0)`` without noise: one compiled program per model
    structure (the parameters traced)."""
    xi = jnp.zeros((n_sources,), q.dtype)
    return jax.jacfwd(lambda q, v: model.state_acceleration(q, v, xi), argnums=(0, 1))(q, jnp.zeros_like(q))


@jax.jit
def stack_scalars(*groups):
    """Each tuple of scalars in ``groups`` as one ``(J,)`` array (``jnp.stack``): one compiled program for all of
    them where the values are concrete numbers (a constraint's positions and restitutions), inline where traced."""
    return tuple(jnp.stack([jnp.asarray(v) for v in group]) for group in groups)


class AbstractOscillator(AbstractSystem):
    """Interface of a single-degree-of-freedom oscillator with an optional rigid barrier.

    Subclasses provide ``restoring(x)`` (g), ``damping(x, v)`` (f) and ``gains(x, v)`` (h, shape
    ``(n_sources,)``), and the fields ``r`` (restitution, in [0, 1]) and ``barrier`` (position, or
    ``None`` for a free oscillator). All functions act on one path (scalars); batches use ``vmap``.
    """

    r: Any
    barrier: Any

    def restoring(self, x):
        raise NotImplementedError

    def damping(self, x, v):
        raise NotImplementedError

    def gains(self, x, v):
        raise NotImplementedError

    @property
    def has_barrier(self) -> bool:
        return self.barrier is not None

    @property
    def coordinates(self) -> tuple[str, ...]:
        """Names of the state's entries, in order: displacement ``"x"`` and velocity ``"v"``."""
        return ("x", "v")

    def rest(self) -> np.ndarray:
        """``x = 0``, or the barrier where it lies above 0."""
        barrier = concrete(self.barrier) if self.has_barrier else None
        return np.array([0.0 if barrier is None else max(0.0, float(barrier))])

    def bounds(self):
        """The barrier (where density kernels of ``"x"`` are reflected), or ``None``."""
        return self.barrier if self.has_barrier else None

    @property
    def dimension(self) -> int:
        """Degrees of freedom: 1."""
        return 1

    def acceleration(self, x, v, xi):
        r"""``x'' = -g(x) - f(x, v) + h(x, v) . xi`` for one path; ``xi`` has shape ``(n_sources,)``."""
        return -self.restoring(x) - self.damping(x, v) + jnp.dot(self.gains(x, v), xi)

    def state_acceleration(self, q, v, xi):
        """:meth:`acceleration` on the state's vectors ``q``, ``v`` of shape ``(1,)`` (the integrator's form)."""
        return jnp.reshape(self.acceleration(q[0], v[0], xi), (1,))

    def stacked_constraints(self) -> Constraints | None:
        """The barrier as the one constraint ``x - barrier >= 0`` (``None`` without a barrier)."""
        if self.barrier is None:
            return None
        one = np.ones((1, 1))
        return Constraints(one, *stack_scalars((self.barrier,), (self.r,)), one)


def _check_impact(r, barrier) -> None:
    RESTITUTION.check("r", r)
    if barrier is not None:
        check_real("barrier", barrier, scalar=True)


@pytree_dataclass
class VibroImpactOscillator(AbstractOscillator):
    r"""The reference model ``x'' + alpha x' + gamma x'^3 + omega^2 x = xi(t)``, barrier at ``x = barrier``.

    Args:
        alpha: linear damping coefficient (>= 0), or ``None`` to leave the term out.
        gamma: cubic damping coefficient (>= 0), or ``None`` to leave the term out. ``0.0`` keeps the
            term (so that derivatives with respect to gamma exist); ``None`` removes it.
        r: coefficient of restitution in [0, 1].
        barrier: barrier position; the system lives on ``x >= barrier``. ``None`` means no barrier.
        omega: natural frequency (> 0), rad/s.

    Examples:
        >>> import jdpim, jax.numpy as jnp
        >>> model = jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98)
        >>> float(model.acceleration(1.0, 0.0, jnp.zeros(1)))
        -1.0

    The defaults are the seed paper's example (its eq. 7): alpha = gamma = 0.03, r = 0.98.
    """

    alpha: Any = 0.03
    gamma: Any = 0.03
    r: Any = 0.98
    barrier: Any = 0.0
    omega: Any = 1.0

    def __post_init__(self):
        for name in ("alpha", "gamma", "omega"):
            RANGES[name].check(name, getattr(self, name))
        _check_impact(self.r, self.barrier)

    @property
    def may_be_stiff(self) -> bool:
        return self.gamma is not None  # only cubic damping grows with the state

    def linearised(self) -> np.ndarray | None:
        """``[[0, 1], [-omega^2, -alpha]]`` (the cubic damping has no linear part)."""
        omega, alpha = concrete(self.omega), 0.0 if self.alpha is None else concrete(self.alpha)
        if omega is None or alpha is None:
            return None
        return np.array([[0.0, 1.0], [-(float(omega) ** 2), -float(alpha)]])

    def restoring(self, x):
        return self.omega**2 * x

    def damping(self, x, v):
        out = jnp.zeros_like(v)
        if self.alpha is not None:
            out = out + self.alpha * v
        if self.gamma is not None:
            out = out + self.gamma * v**3
        return out

    def gains(self, x, v):
        return jnp.ones((1,), dtype=jnp.result_type(v))


@pytree_dataclass
class Oscillator(AbstractOscillator):
    r"""A general oscillator ``x'' + g(x) + f(x, x') = sum_k h_k(x, x') xi_k(t)`` from user functions.

    Args:
        params: a pytree of parameters (traced: vmappable and differentiable).
        g: restoring force ``g(x, params) -> scalar``, or ``None`` for none.
        f: damping force ``f(x, v, params) -> scalar``, or ``None`` for none.
        h: noise gains ``h(x, v, params) -> (n_sources,)``, or ``None`` for unit additive gains.
        n_sources: number of white-noise sources (must match the scene's noise).
        r: coefficient of restitution in [0, 1].
        barrier: barrier position, or ``None`` for no barrier.

    The functions act on one path (scalars), must be JAX-traceable, and are part of the pytree
    structure (changing them recompiles). With state-dependent gains the smooth spectral excitation
    gives the Stratonovich interpretation (Wong-Zakai).

    Examples:
        >>> import jdpim, jax.numpy as jnp
        >>> duffing = jdpim.Oscillator(params={"k3": 0.1}, g=lambda x, p: x + p["k3"] * x**3,
        ...                            f=lambda x, v, p: 0.05 * v, r=0.9)
        >>> round(float(duffing.acceleration(1.0, 0.0, jnp.zeros(1))), 6)
        -1.1
    """

    params: Any = None
    g: Callable | None = static_field(default=None)
    f: Callable | None = static_field(default=None)
    h: Callable | None = static_field(default=None)
    n_sources: int = static_field(default=1)
    r: Any = 1.0
    barrier: Any = 0.0

    def __post_init__(self):
        for name in ("g", "f", "h"):
            fn = getattr(self, name)
            if fn is not None and not callable(fn):
                raise TypeError(f"{name} must be callable or None, got {fn!r}")
        if isinstance(self.n_sources, bool) or not isinstance(self.n_sources, int) or self.n_sources < 1:
            raise ValueError(f"n_sources must be an integer >= 1, got {self.n_sources!r}")
        _check_impact(self.r, self.barrier)
        if all(concrete(leaf) is not None for leaf in jax.tree_util.tree_leaves(self.params)):
            x = jnp.zeros(())  # one path's scalars (placeholders and tracers are checked where built with numbers)
            for name, fn in (("g", lambda: self.restoring(x)), ("f", lambda: self.damping(x, x))):
                shape = jax.eval_shape(fn).shape
                if shape != ():
                    raise ValueError(f"{name} must return one number for one path's scalars, got shape {list(shape)}")

    @property
    def may_be_stiff(self) -> bool:
        return self.f is not None or self.g is not None

    def parameter_range(self, name: str) -> Range:
        """``r`` in [0, 1]; the keys of ``params`` are the user's (any real value)."""
        return RESTITUTION if name == "r" else Range()

    def restoring(self, x):
        return jnp.zeros_like(x) if self.g is None else self.g(x, self.params)

    def damping(self, x, v):
        return jnp.zeros_like(v) if self.f is None else self.f(x, v, self.params)

    def gains(self, x, v):
        if self.h is None:
            return jnp.ones((self.n_sources,), dtype=jnp.result_type(v))
        return jnp.reshape(self.h(x, v, self.params), (self.n_sources,))


def rk4_step_limit(eigenvalues) -> tuple[float, complex]:
    """The largest step ``h`` with ``|R(lambda h')| <= 1`` for ``h' <= h`` and every decaying or neutral mode
    ``lambda`` (RK4's ``R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24``; 2.785 / |lambda| on the negative real axis,
    2 sqrt(2) / |lambda| on the imaginary one), and the mode that sets it; ``(inf, 0)`` where no mode limits the
    step. Growing modes (``Re lambda > 0``: an unstable rest state, e.g. between stops) set no bound."""

    def grows(z):
        return np.abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24) > 1.0 + 1e-12

    lam = np.asarray(eigenvalues, complex).ravel()
    size = np.abs(lam)
    lam = lam[(size > 0) & (lam.real <= GROWING * size)]
    if lam.size == 0:
        return np.inf, 0j
    lam = np.minimum(lam.real, 0.0) + 1j * lam.imag  # a neutral mode's rounding (double zeros) is no growth
    size = np.abs(lam)
    ray = lam / size
    s = np.linspace(0.0, 4.0, 401)  # |lambda| h along each mode's ray: the region lies within 2.96 of 0
    bad = grows(s[1:, None] * ray)
    first = np.argmax(bad, axis=0)  # the first grid point beyond the region, then bisection
    lo, hi = s[first], s[first + 1]
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        out = grows(mid * ray)
        lo, hi = np.where(out, lo, mid), np.where(out, mid, hi)
    limit = np.where(bad.any(axis=0), lo / size, np.inf)
    k = int(np.argmin(limit))
    return (float(limit[k]), complex(lam[k])) if np.isfinite(limit[k]) else (np.inf, 0j)


def n_sources_of(model: AbstractSystem) -> int:
    """Number of noise sources the model's gains expect (from an abstract evaluation for one degree of freedom)."""
    if not isinstance(model, AbstractOscillator):
        return model.n_sources
    shape = jax.eval_shape(lambda: model.gains(jnp.zeros(()), jnp.zeros(()))).shape
    return int(shape[0])
