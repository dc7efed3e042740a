"""The first-passage result, :class:`FirstPassage`, and the checked question a method answers."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._io import Labelled
from .._pytree import pytree_dataclass, static_field
from .._scene import saved_index, static_times


@dataclasses.dataclass(frozen=True)
class Coordinate:
    """The state's entry ``index`` (named ``name``) as a function of the state (hashable)."""

    name: str
    index: int

    def __call__(self, state):
        return state[self.index]


@dataclasses.dataclass(frozen=True)
class FirstPassageQuery:
    """The checked arguments of :func:`first_passage` that a method's ``first_passage`` answers."""

    quantity: Callable  # state (n_state,) -> scalar; hashable
    levels: np.ndarray  # (L,)
    wrt: tuple = ()  # parameter names to differentiate with respect to
    values: dict = dataclasses.field(default_factory=dict)  # their nominal values (floats)
    estimators: dict = dataclasses.field(default_factory=dict)  # name -> estimator
    estimator: Any = None  # the one the user gave (None: each method's default)
    checkpoint: Any = None  # the job's jdpim._checkpoint.Session, or None


@pytree_dataclass
class FirstPassage(Labelled):
    r"""First-passage probabilities ``P(max_{s <= t} q(s) > level)``.

    Attributes:
        times: saved times, s: a tuple of ``S`` floats (pytree structure).
        levels: the levels, shape ``(L,)``.
        probability: shape ``(S, L)``: the probability that ``q`` has exceeded each level by each saved time,
            counted over the paths (or grid mass) that stayed finite.
        probability_stderr: shape ``(S, L)``, the sampling standard error of ``probability`` (Monte Carlo:
            ``sqrt(sum_i w_i^2 (1_i - p)^2)``, i.e. ``sqrt(p (1 - p) / N)`` for ``N`` equal weights), or
            ``None`` where the method has none (DPIM points are not independent samples).
        lost_mass: shape ``(S, L)``: the probability carried by paths whose state turned non-finite or
            diverged (the densities' rule, :func:`jdpim.methods._paths.beyond`) by each saved time before they
            exceeded the level; they are left out of ``probability``, so the true
            value lies in ``[probability, probability + lost_mass]`` (a path that exceeded the level first counts
            as passed).
        method: the method's name.
        derivative: ``{name: (S, L) array}``, ``dP/dtheta`` for each parameter of ``wrt`` (``None`` without).
        derivative_stderr: ``{name: (S, L) array}``, their sampling standard errors (``None`` for DPIM and
            path integration).
        grid_error: shape ``(S, L)``, path integration with ``estimate_error=True``: ``|probability - the same on
            a grid twice as coarse|``, the estimated discretisation error; else ``None``.
        n_evaluations: responses computed (paths integrated) by subset simulation; ``None`` otherwise.
        n_replicates: the number ``R`` of DPIM replicates averaged (``first_passage(..., replicates=R)``): then
            ``probability`` and ``derivative`` are their means and ``probability_stderr``, ``derivative_stderr``
            the standard errors of the means (``std / sqrt(R)``); ``None`` otherwise.

    A pytree (leaves: ``levels``, ``probability``, ``probability_stderr``, ``lost_mass``, the derivatives and
    ``grid_error``): it passes through ``jax.jit``.
    """

    times: tuple = static_field()
    levels: Any = None
    probability: Any = None
    probability_stderr: Any = None
    lost_mass: Any = None
    method: str = static_field(default="monte_carlo")
    derivative: Any = None
    derivative_stderr: Any = None
    grid_error: Any = None
    n_evaluations: int | None = static_field(default=None)
    n_replicates: int | None = static_field(default=None)

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))

    def at(self, t: float | None = None):
        """``(probability, stderr)`` at the saved time ``t`` (``None``: the last), each ``(L,)``;
        ``stderr`` is ``None`` where the method has none."""
        i = len(self.times) - 1 if t is None else saved_index(self.times, t)
        se = self.probability_stderr
        return self.probability[i], None if se is None else se[i]

    @classmethod
    def mean_of(cls, runs: list[FirstPassage]) -> FirstPassage:
        """The mean of ``R >= 2`` independent replicates, with the standard errors of the means."""
        first, r = runs[0], len(runs)

        def mean_and_stderr(values):
            stack = jnp.stack(values)
            return jnp.mean(stack, axis=0), jnp.std(stack, axis=0, ddof=1) / np.sqrt(r)

        p, se = mean_and_stderr([run.probability for run in runs])
        lost, _ = mean_and_stderr([run.lost_mass for run in runs])
        derivative = derivative_stderr = None
        if first.derivative is not None:
            pairs = {n: mean_and_stderr([run.derivative[n] for run in runs]) for n in first.derivative}
            derivative, derivative_stderr = ({n: pair[i] for n, pair in pairs.items()} for i in (0, 1))
        return cls(first.times, first.levels, p, se, lost, first.method, derivative, derivative_stderr, n_replicates=r)

    @staticmethod
    def passed(tracked, levels):
        """``(N, S, L)``: 1 where a path's running maximum (:class:`jdpim.tracking.RunningMaximum` values
        ``(N, S, 2)``) exceeds a level, else 0."""
        maxima = tracked[..., 0]
        return (maxima[..., None] > jnp.asarray(levels, maxima.dtype)[None, None]).astype(maxima.dtype)

    @classmethod
    def from_tracked(cls, times, levels, tracked, weights, method: str, *, stderr: bool) -> FirstPassage:
        """From :class:`jdpim.tracking.RunningMaximum` values ``(N, S, 2)`` (or more columns, the first two read) of
        ``N`` paths with probabilities ``weights`` ``(N,)``: a path has passed a level once its running maximum
        exceeds it (also if its state turned non-finite or diverged afterwards); a non-finite or diverged path that
        has not is lost. One compiled program per shape (:func:`_passage_statistics`)."""
        levels, p, se, lost = _passage_statistics(levels, tracked, weights, stderr)
        return cls(times, levels, p, se, lost, method)


@functools.partial(jax.jit, static_argnums=(3,))
def _passage_statistics(levels, tracked, weights, stderr: bool):
    """``(levels, probability, stderr or None, lost mass)`` of :meth:`FirstPassage.from_tracked`."""
    maxima, bad = tracked[..., 0], tracked[..., 1] > 0
    hit = FirstPassage.passed(tracked, levels)
    # over the total weight summed the same way: float32 rounding of a sum of many weights (1e-4 at 2e4
    # paths) then cancels, and a level every path passes gives exactly 1
    p = jnp.einsum("n,nsl->sl", weights, hit) / jnp.einsum("n,nsl->sl", weights, jnp.ones_like(hit))
    se = jnp.sqrt(jnp.einsum("n,nsl->sl", weights * weights, (hit - p[None]) ** 2)) if stderr else None
    lost = jnp.einsum("n,nsl->sl", weights, (1.0 - hit) * bad[..., None])
    return jnp.asarray(levels, maxima.dtype), p, se, lost
