"""Sensitivities of the densities of systems with several degrees of freedom: central differences and the
likelihood ratio.

Central differences rerun the paths at two values of the parameter with the same random inputs (the same
seed, or the same DPIM points), so the per-path differences of the kernel estimate have a small variance; the
kernel width is held at its value for the nominal run. The likelihood ratio runs the paths once, tracking the
Girsanov score of each drift parameter whose change of the acceleration lies along the noise's direction
(``jdpim.LikelihoodRatio``; :func:`._estimators.check_likelihood_ratio`). Pathwise derivatives are not
offered: through impacts between masses they are not validated (see ``jdpim.methods._ad_guard``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from .._pytree import check_real
from .._scene import Scene, get_parameter, with_parameters
from ..methods._base import AbstractMethod, solve
from ..methods._monte_carlo import MonteCarlo
from ..methods._path_integration import PathIntegration
from ..results._density import bandwidth as rule_bandwidth
from ..results._density import kde_difference, kernel_matrix
from ..results._samples import reflection
from ..tracking import Sums
from ._estimators import CentralDifference, LikelihoodRatio, Score, warn_if_noisy
from ._scores import centred_scores, finite_weights, moments, score_windows


def several_dof_sensitivity(
    scene: Scene, wrt: tuple[str, ...], var, grid, t: float, method: AbstractMethod | None, bandwidth, rule, estimator
):
    """``(value, stderr, estimators, method)`` for a scene whose model has several degrees of freedom."""
    if isinstance(method, PathIntegration):
        raise ValueError("path integration takes one degree of freedom; use jdpim.MonteCarlo() or jdpim.DPIM()")
    method = MonteCarlo(n_samples=100_000) if method is None else method
    estimators = {name: _estimator(name, estimator) for name in wrt}
    for name, est in estimators.items():
        est.check(scene, name)
    if not (callable(var) or var in scene.model.coordinates):
        raise ValueError(
            f"var must be one of the coordinates {scene.model.coordinates} or a function of the state, got {var!r}"
        )
    if isinstance(bandwidth, str):
        raise ValueError("bandwidth='adaptive' needs the Pathwise estimator: one degree of freedom only")
    grid = jnp.asarray(grid)
    if bandwidth is not None:
        check_real("bandwidth", bandwidth, low=0.0, low_open=True)
    reflect = reflection(scene.model.bounds(), var)
    scored = {n: e for n, e in estimators.items() if isinstance(e, LikelihoodRatio)}
    central = [n for n in wrt if n not in scored]
    # the nominal paths: one run tracking the scores, or an untracked one where central differences need it
    nominal = solve(scene, method) if central else None
    paths = _scored_paths(scene, scored, var, t, method) if scored else None
    if bandwidth is None:
        y, w = (nominal.samples(var, t), nominal.weights) if nominal is not None else paths.nominal
        bandwidth = float(rule_bandwidth(y, w, rule, dim=1))
    value, stderr = _likelihood_ratio(paths, grid, bandwidth, reflect) if scored else ({}, {})
    for name in central:
        est = estimators[name]
        nominal_value = scene.noise.D if name == "D" else get_parameter(scene.model, name)
        lo, hi = est.pair(name, float(nominal_value))
        runs = [solve(with_parameters(scene, {name: p}), method) for p in (lo, hi)]
        d, se = kde_difference(
            runs[0].samples(var, t), runs[1].samples(var, t), nominal.weights, grid, bandwidth, reflect
        )
        value[name], stderr[name] = d / (hi - lo), se / (hi - lo)
    for name in wrt:
        warn_if_noisy(name, value[name], stderr[name], stacklevel=3)
    return value, stderr, estimators, method


class _ScoredPaths(NamedTuple):
    """One run of the paths tracking the scores: ``nominal`` the samples of ``var`` at ``t`` and the path weights
    (as ``jdpim.solve`` gives them), ``y`` and ``w`` the same with non-finite paths at zero weight, ``scores``
    ``{name: (N,)}`` the centred scores."""

    nominal: tuple
    y: Any
    w: Any
    scores: dict


def _scored_paths(scene: Scene, settings: dict, var, t: float, method) -> _ScoredPaths:
    """The paths of ``method`` up to ``t``, tracking the score sums of ``settings`` (``{name: LikelihoodRatio}``)."""
    k_t, starts, times, run_scene = score_windows(scene, settings, t)
    rows, weights, chunk = method.inputs(scene)
    states, sums = method.paths(run_scene, rows, chunk, track=Sums(Score(tuple(settings), scene.dt)))
    at = states[:, times.index(k_t)]
    y = jax.vmap(var)(at) if callable(var) else at[:, scene.model.coordinates.index(var)]
    w, (_, finite_y) = finite_weights(weights, jnp.concatenate([at, sums[:, times.index(k_t)]], axis=1), y)
    return _ScoredPaths((y, weights), finite_y, w, centred_scores(scene, settings, sums, w, times, k_t, starts))


def _likelihood_ratio(paths: _ScoredPaths, grid, sigma: float, reflect):
    """``(value, stderr)`` dicts of ``sum_i w_i K(y - Y_i) (S_i - Sbar)`` for each parameter scored in ``paths``."""
    grid_flat = jnp.atleast_1d(grid).astype(paths.y.dtype)

    def contribution(y, s):
        return kernel_matrix(grid_flat, y, sigma, reflect).T * s[:, None]

    value, stderr = {}, {}
    for name, score in paths.scores.items():
        d, se = moments(contribution, (paths.y, score), paths.w)
        value[name], stderr[name] = d.reshape(grid.shape), se.reshape(grid.shape)
    return value, stderr


def _estimator(name: str, estimator):
    est = estimator.get(name, "auto") if isinstance(estimator, dict) else estimator
    if isinstance(est, str) and est == "auto":
        return CentralDifference()
    if not isinstance(est, (CentralDifference, LikelihoodRatio)):
        raise ValueError(
            f"estimator for {name!r}: several degrees of freedom take CentralDifference or LikelihoodRatio (pathwise "
            f"derivatives through impacts between masses are not validated), got {est!r}"
        )
    return est
