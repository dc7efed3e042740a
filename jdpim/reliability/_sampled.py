"""First passage by the sampling methods (DPIM, Monte Carlo): running maxima, and derivatives by the estimators."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp

from .._integrate import Stacked
from .._scene import Scene, with_parameters
from ..methods._ad_guard import INDICATOR, watch
from ..methods._paths import divergence_bound
from ..sensitivities._estimators import Score
from ..sensitivities._scores import centred_scores
from ..tracking import RunningMaximum, Sums
from ._passage import FirstPassage


@dataclasses.dataclass(frozen=True)
class PassageContext:
    """What a first-passage derivative estimator needs, from one common set of paths.

    ``passed``: ``(N, S, L)`` passage indicators of the nominal paths; ``probability``: ``(S, L)`` their weighted
    mean over the finite paths; ``scores``: ``{name: (N, S)}`` centred whole-history scores at the saved times
    (likelihood ratio); ``rerun(name, value)``: the indicators of the same paths (same rows) with parameter
    ``name`` set to ``value``; ``values``: nominal parameter values.
    """

    passed: Any
    probability: Any
    scores: dict
    values: dict
    rerun: Callable


def sampled_first_passage(method, scene: Scene, query) -> FirstPassage:
    """:class:`FirstPassage` of ``query`` by a sampling ``method``, with the derivatives ``query.wrt`` asks for."""
    rows, weights, chunk = method.inputs(scene)
    settings = {}
    for name in query.wrt:
        settings.update(query.estimators[name].scores_needed(name, scene))
    bound = divergence_bound(scene)  # the nominal scene's, for every run: the same rule for common paths
    running = RunningMaximum(query.quantity, bound)  # the bound an array: one compiled program for every value
    track = Stacked((running, Sums(Score(tuple(settings), scene.dt)))) if settings else running

    def tracked(scene):
        return method.paths(scene, rows, chunk, track=track, checkpoint=query.checkpoint)[1]

    nominal = watch(tracked(scene), INDICATOR)
    sampled = method.independent  # independent samples: a sampling standard error
    out = FirstPassage.from_tracked(scene.save_at, query.levels, nominal, weights, method.name, stderr=sampled)
    if not query.wrt:
        return out
    passed = FirstPassage.passed(nominal, query.levels)
    steps = list(scene.save_steps)
    w = jnp.where(jnp.all(jnp.isfinite(nominal), axis=(1, 2)), weights, 0.0)
    scores = {}
    if settings:
        per_time = [
            centred_scores(scene, settings, nominal[..., 2:], w, steps, k, dict.fromkeys(settings, 0)) for k in steps
        ]
        scores = {n: jnp.stack([s[n] for s in per_time], axis=1) for n in settings}

    def rerun(name, value):
        return FirstPassage.passed(tracked(with_parameters(scene, {name: value}))[..., :2], query.levels)

    probability = jnp.sum(w[:, None, None] * passed, axis=0) / jnp.sum(w)
    ctx = PassageContext(passed, probability, scores, query.values, rerun)
    value, stderr = {}, {}
    for name in query.wrt:
        c = query.estimators[name].first_passage(ctx, name)  # (N, S, L) per-path contributions
        value[name] = jnp.einsum("n,nsl->sl", w, c)
        if sampled:
            stderr[name] = jnp.sqrt(jnp.einsum("n,nsl->sl", w * w, (c - value[name][None]) ** 2))
    return dataclasses.replace(out, derivative=value, derivative_stderr=stderr if sampled else None)
