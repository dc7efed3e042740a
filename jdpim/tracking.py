r"""What is tracked along paths: a statistic carried through every step of every path (Monte Carlo, DPIM).

A statistic is a small frozen (hashable) object with three functions over one path's state; the integrator
``jax.vmap``s them over the paths of a chunk and stores the values at the saved times, like the states:

- ``init(model, q, v, e) -> (k,)``: its value at the start (``q``, ``v``: coordinates and velocities ``(d,)``;
  ``e``: the forcing nodes, zero);
- ``update(model, acc, q, v, q_new, v_new, e, h) -> (k,)``: its value ``acc`` carried over a step of length ``h``
  (s) from ``(q, v)`` to ``(q_new, v_new)`` under the forcing ``e`` (the nodes at the step's start, middle and end,
  each ``(m,)``); ``model`` is the path's model (its random parameters set);
- ``finalise(values, diverged) -> values``: the stored values ``(N, S, k)`` of ``N`` paths at ``S`` saved times,
  given which paths have diverged by each saved time (``(N, S)`` bool, the rule that leaves such states out of
  densities); by default unchanged.

:func:`track` runs a statistic through a sampling method and gives its weighted mean at the saved times. The
built-ins are what the questions use: :class:`RunningMaximum` (first passage), :class:`ImpactCounts` (impact
statistics), :class:`Sums` (the likelihood-ratio scores of the sensitivities), and :class:`Integral` and
:class:`Function` of the state. A new statistic is a subclass of :class:`AbstractTracked` (``docs/extending.md``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp

from . import _integrate
from ._io import Labelled
from ._pytree import pytree_dataclass, static_field
from ._scene import Scene, static_times
from .methods._paths import SamplingMethod, beyond, diverged


class AbstractTracked(_integrate.Tracker):
    """A statistic carried along every step of every path (module docstring): subclasses are frozen dataclasses
    that give ``init`` and ``update``, and ``finalise`` where diverged paths call for it."""

    def finalise(self, values, diverged):
        """The values ``(N, S, k)`` at the saved times, given which paths have diverged (``(N, S)`` bool)."""
        return values


@dataclasses.dataclass(frozen=True)
class RunningMaximum(_integrate.RunningMax, AbstractTracked):
    """The largest value of ``quantity(state) -> scalar`` (``state``: ``(2 d,)``) over the start and the end of
    every step so far, and whether the state has been non-finite or diverged: ``(2,)`` (first passage).

    With ``bound`` (``(2 d,)``, :func:`jdpim.methods._paths.divergence_bound`), a state beyond it counts as
    diverged, as densities count it: like a non-finite state it is left out of the maximum, and the path is marked
    from then on, so that it has passed a level only if it did so before it diverged. Given as an array, the bound
    is traced: runs with other bounds (other noise intensities) reuse the compiled program."""

    bound: Any = None

    def _value(self, q, v):
        value, bad = super()._value(q, v)
        if self.bound is None:
            return value, bad
        out = beyond(jnp.concatenate([q, v]), self.bound)
        return jnp.where(out, jnp.nan, value), jnp.maximum(bad, out.astype(bad.dtype))

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        new = super().update(model, acc, q, v, q_new, v_new, e, h)
        return new if self.bound is None else jnp.where(acc[1] > 0, acc, new)  # a marked path keeps its maximum


class ImpactCounts(_integrate.Impacts, AbstractTracked):
    """Impacts along a path under the impact settings ``rule`` (``scene.impacts``): ``(impacted so far, steps with
    an impact so far, impact speeds per bin of ``edges`` so far)``, ``(2 + K,)`` for ``K + 1`` edges (impact
    statistics; the counting is :class:`jdpim._integrate.Impacts`)."""


class Sums(_integrate.Sums, AbstractTracked):
    """Running sums of ``increment(model, q, v, dw) -> (k,)`` at the start of every step with its noise increment
    ``dw = h/6 (e_0 + 4 e_1/2 + e_1)`` (the sensitivities' likelihood-ratio scores)."""


@dataclasses.dataclass(frozen=True)
class Integral(AbstractTracked):
    """``int_0^t f(state) ds`` by the trapezoid rule over the steps: ``(k,)`` for ``f(state) -> (k,)`` or a scalar
    (``state``: ``(2 d,)``), in the units of ``f`` times seconds. ``f`` must be hashable (a function, not a
    lambda made anew per call)."""

    f: Callable

    def _value(self, q, v):
        return jnp.atleast_1d(self.f(jnp.concatenate([q, v]))).astype(q.dtype)

    def init(self, model, q, v, e):
        return jnp.zeros_like(self._value(q, v))

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        return acc + 0.5 * h * (self._value(q, v) + self._value(q_new, v_new))


@dataclasses.dataclass(frozen=True)
class Function(AbstractTracked):
    """``f(state)`` at the saved times: ``(k,)`` for ``f(state) -> (k,)`` or a scalar; ``f=None`` keeps the state
    itself, ``(2 d,)``."""

    f: Callable | None = None

    def _value(self, q, v):
        state = jnp.concatenate([q, v])
        return state if self.f is None else jnp.atleast_1d(self.f(state)).astype(q.dtype)

    def init(self, model, q, v, e):
        return self._value(q, v)

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        return self._value(q_new, v_new)


def weighted_mean(weights, values, stderr: bool):
    """``(mean, stderr or None)`` over the paths of ``values`` ``(N, ...)`` with probabilities ``weights`` ``(N,)``:
    ``sum_i w_i y_i / sum_i w_i`` and, for independent samples, ``sqrt(sum_i w_i^2 (y_i - mean)^2)``."""
    mean = jnp.einsum("n,n...->...", weights, values) / jnp.einsum("n,n...->...", weights, jnp.ones_like(values))
    se = jnp.sqrt(jnp.einsum("n,n...->...", weights * weights, (values - mean[None]) ** 2)) if stderr else None
    return mean, se


@pytree_dataclass
class Tracked(Labelled):
    """A statistic tracked along the paths of a sampling method (:func:`track`).

    Attributes:
        times: saved times, s (pytree structure).
        values: ``(N, S, k)``, the statistic of every path at every saved time (after its ``finalise``).
        weights: ``(N,)``, the paths' probabilities.
        mean: ``(S, k)``, the weighted mean over the paths.
        mean_stderr: ``(S, k)``, its sampling standard error (Monte Carlo), or ``None`` (DPIM).
        method: the method's name.
    """

    times: tuple = static_field()
    values: Any = None
    weights: Any = None
    mean: Any = None
    mean_stderr: Any = None
    method: str = static_field(default="monte_carlo")

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))


def track(scene: Scene, method: SamplingMethod, statistic: AbstractTracked) -> Tracked:
    """``statistic`` carried along every path of ``method`` on ``scene``, at the scene's saved times.

    Args:
        scene: the physics (:class:`jdpim.Scene`).
        method: ``jdpim.MonteCarlo(...)`` (with standard errors) or ``jdpim.DPIM(...)``.
        statistic: an :class:`AbstractTracked`, e.g. ``jdpim.tracking.Integral(f)``.

    Returns:
        :class:`Tracked`: every path's values, their weighted mean and its standard error.

    Examples:
        >>> import jdpim
        >>> from jdpim.tracking import Function, track
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.01, save_at=(0.5, 1.0))
        >>> track(scene, jdpim.MonteCarlo(n_samples=32, seed=1), Function()).values.shape
        (32, 2, 2)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if not isinstance(method, SamplingMethod):
        raise ValueError(f"statistics are tracked along paths: use jdpim.MonteCarlo or jdpim.DPIM, not {method!r}")
    if not isinstance(statistic, AbstractTracked):
        raise TypeError(f"statistic must be a jdpim.tracking.AbstractTracked, got {statistic!r}")
    rows, weights, chunk = method.inputs(scene)
    states, values = method.paths(scene, rows, chunk, track=statistic)
    values = statistic.finalise(values, diverged(scene, states))
    mean, se = weighted_mean(weights, values, method.independent)
    return Tracked(scene.save_at, values, weights, mean, se, method.name)
