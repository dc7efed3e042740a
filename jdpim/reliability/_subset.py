r"""Subset simulation (Au & Beck 2001) for small first-passage probabilities.

The input space is the Gaussian forcing of :class:`jdpim.GaussianNodes`: ``z``, independent standard
normals at the ``2 T + 1`` half-step nodes of every source (``(2 T + 1) m`` dimensions), mapped to the
forcing ``sqrt(18 / (5 dt)) L z`` (``GaussianNodes.from_normals``; times the noise's envelope, if any). The
response is ``Y(z) = max_{0 <= s <= t} q(s)`` at the last saved time.
``P(Y > b)`` is written as a product of conditional probabilities of nested events ``Y > b_1 > ... ``:

1. level 0: ``N`` independent samples; ``b_1`` is the ``1 - p0`` quantile of ``Y``;
2. level ``i``: the ``p0 N`` samples above ``b_i`` seed Markov chains of ``1 / p0`` states each, by the
   modified Metropolis algorithm (every component proposed ``z_j + U(-w, w)`` and kept with probability
   ``min(1, phi(xi_j) / phi(z_j))``; the candidate replaces the state if ``Y > b_i``, else the state repeats);
   ``b_{i+1}`` is again the ``1 - p0`` quantile, until it passes the highest level asked for.

Then ``P(Y > b) = p0^i P(Y > b | level i)`` for ``b_i <= b < b_{i+1}``, with the coefficient of variation
``delta^2 = sum_i (1 - p_i) / (N p_i) (1 + gamma_i)``, ``gamma_i`` from the correlation of the indicators along
the chains (``gamma_0 = 0``); the standard error is ``P delta``.

Derivatives ``dP/dtheta`` (``first_passage(..., wrt=...)``) come from the samples of the levels, which follow
the law of ``z`` given ``Y > b_j``; for ``b`` in level ``i``, ``dP/dtheta = p0^i E[c | Y > b_i]`` with per-sample
contributions

- drift parameters (where :class:`jdpim.LikelihoodRatio` applies, the default): ``c = 1(Y > b) (S - Sbar)`` with
  ``S`` the Girsanov score of the whole history that Monte Carlo uses, centred by its mean ``Sbar`` over level 0;
- the noise intensity ``D`` (the default for it): ``c = 1(Y > b) (|z|^2 - n) / (2 D)``, the exact score of the
  forcing ``sqrt(D) z`` (``n = (2 T + 1) m``), of mean zero;
- any other parameter (restitution, constraints, gains) or ``estimator=jdpim.CentralDifference()``: common random
  numbers on the samples themselves, ``c = (1(Y(theta + d) > b) - 1(Y(theta - d) > b)) / 2 d``, summed over the
  shells ``b_j < Y <= b_{j + 1}`` of the levels below ``i`` (a path may cross ``b`` at ``theta +- d`` from any shell)
  and ``Y > b_i`` of level ``i``: ``dP/dtheta = sum_j p0^j E[c 1(shell j) | Y > b_j]``; two more responses per
  sample of levels ``0 .. i``.

Each term ``p0^j E[c_j]`` has the variance ``p0^2j Var(c_j) (1 + gamma_c) / N + (p0^j E[c_j])^2 sum_{k < j}
delta_k^2``, ``gamma_c`` from the correlation of ``c`` along the chains; the terms add (correlation between levels
left out, as for ``P``), and the centred score adds ``P^2 Var(S) / N``.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._excitation import GaussianNodes
from .._integrate import RunningMax, Stacked, Sums
from .._pytree import check_int, check_real, pytree_dataclass, static_field
from .._scene import Scene, with_parameters
from ..methods._paths import NonFiniteWarning, integrate_forcing, is_traced, without_diverged
from ..sensitivities._estimators import CentralDifference, LikelihoodRatio, Score
from ._failure import AbstractFailureMethod
from ._passage import FirstPassage


@pytree_dataclass
class SubsetSimulation(AbstractFailureMethod):
    """Subset simulation for first-passage probabilities and their derivatives (use it with
    ``jdpim.first_passage``; it gives no densities, so ``jdpim.solve`` refuses it).

    Args:
        n_per_level: samples per level ``N`` (>= 10; ``p0 N`` and ``1 / p0`` must be whole numbers).
        p0: conditional probability of each level, in (0, 0.5].
        seed: PRNG seed (>= 0).
        width: half-width ``w`` of the uniform component proposal (> 0).
        max_levels: most levels (>= 1) before giving up on the highest level asked for.

    The scene's forcing must be that of ``jdpim.GaussianNodes()`` (the input space is its node values; a
    scene's default, ``excitation=None``, gives it) and it may have no random parameters. Probabilities are
    given at the scene's last saved time; derivatives ``wrt=...`` with standard errors (module docstring,
    ``docs/reliability.md``). Paths whose state turns non-finite or diverges (as ``jdpim.solve`` counts them)
    count as below every level, with a ``NonFiniteWarning``. With ``first_passage(..., checkpoint=...)`` every
    finished level is kept on disk, and an interrupted run resumes from it bit for bit.
    """

    n_per_level: int = static_field(default=1000)
    p0: float = static_field(default=0.1)
    seed: int = static_field(default=0)
    width: float = static_field(default=1.0)
    max_levels: int = static_field(default=10)
    name = "subset_simulation"
    resumable = True  # first_passage(..., checkpoint=...) keeps every finished level
    default_excitation = GaussianNodes()  # its input space: the normals at the nodes

    def __post_init__(self):
        check_int("n_per_level", self.n_per_level, low=10)
        check_real("p0", self.p0, low=0.0, high=0.5, low_open=True)
        check_int("seed", self.seed, low=0)
        check_real("width", self.width, low=0.0, low_open=True)
        check_int("max_levels", self.max_levels, low=1)
        seeds, length = self.p0 * self.n_per_level, 1.0 / self.p0
        if abs(seeds - round(seeds)) > 1e-9 or abs(length - round(length)) > 1e-9:
            raise ValueError(
                f"p0={self.p0!r} and n_per_level={self.n_per_level!r} must make p0 * n_per_level and 1 / p0 "
                "whole numbers (chains of equal length)"
            )

    def first_passage(self, scene: Scene, query) -> FirstPassage:
        if isinstance(jnp.zeros(()), jax.core.Tracer) or is_traced(scene):
            raise TypeError(
                "SubsetSimulation cannot run under a JAX transformation (jit, vmap, grad): it picks each level's "
                "threshold and seeds from concrete responses; call first_passage outside, with wrt=... for derivatives"
            )
        if scene.random:
            raise ValueError("SubsetSimulation needs a scene without random parameters")
        return _subset_simulation(self, scene, query, _estimators(query))


def _estimators(query) -> dict:
    """``{name: LikelihoodRatio | CentralDifference | "noise"}``: how each derivative of ``query`` is estimated
    (``"noise"``: the exact score of the forcing with respect to ``D``)."""
    out = {}
    for name in query.wrt:
        est = query.estimators[name]
        if name == "D" and query.estimator is None:
            if query.values["D"] <= 0.0:
                raise ValueError(f"D must be > 0 to differentiate with respect to it, got {query.values['D']!r}")
            est = "noise"
        elif not isinstance(est, (LikelihoodRatio, CentralDifference)):
            raise ValueError(
                f"SubsetSimulation estimates derivatives by jdpim.LikelihoodRatio() or jdpim.CentralDifference(), "
                f"not {type(est).__name__}"
            )
        out[name] = est
    return out


@functools.lru_cache(maxsize=16)
def _response(quantity, excitation, names: tuple, dt: float):
    """``(scene, z (n, 2 T + 1, m)) -> (states (n, S, 2 d), tracked (n, 2 + 2 K + 1), |z|^2 (n,))``, jitted:
    the running maximum of ``quantity`` at the last saved time and, for the ``K`` parameters ``names``, the score
    sums of :class:`Score`."""
    track = Stacked((RunningMax(quantity), Sums(Score(names, dt)))) if names else RunningMax(quantity)

    @jax.jit
    def response(scene, z):
        forcing = excitation.from_normals(scene, z)
        states, tracked = integrate_forcing(scene, forcing, jnp.zeros((z.shape[0], 0), scene.float_dtype), track)
        return states, tracked[:, -1], jnp.sum(jnp.square(z.astype(jnp.float32)), axis=(1, 2))

    return response


def _evaluate(response, scene: Scene, z) -> tuple:
    """``(y (n,), extras (n, 2 K + 2), bad (n,))``: ``Y``, set to ``-inf`` on paths that turned non-finite or
    diverged (``without_diverged``); the score sums and ``|z|^2``; which paths those are."""
    states, tracked, squares = response(scene, z)
    states = without_diverged(scene, states)
    bad = np.asarray((tracked[:, 1] > 0) | jnp.any(jnp.isnan(states[:, -1]), axis=-1))
    y = np.where(bad, -np.inf, np.asarray(tracked[:, 0], float))
    return y, np.concatenate([np.asarray(tracked[:, 2:], float), np.asarray(squares, float)[:, None]], 1), bad


@dataclasses.dataclass(frozen=True)
class _Level:
    """The ``N`` samples of one level: ``z``, ``y``, ``extras`` (as :func:`_evaluate`), the threshold ``b_i``
    they exceed (``-inf`` at level 0), and whether they are ordered (chain step, chain) (levels above 0)."""

    z: jax.Array
    y: np.ndarray
    extras: np.ndarray
    threshold: float
    chained: bool


def _gamma(values: np.ndarray, mean: float, var: float) -> float:
    """Au & Beck's correlation factor ``gamma`` of a quantity ``(n_chains, length)`` along the chains: the
    variance of its sample mean is ``var (1 + gamma) / N``."""
    n_c, n_s = values.shape
    if n_s < 2 or var <= 0.0:
        return 0.0
    gamma = 0.0
    for k in range(1, n_s):
        r_k = np.sum(values[:, : n_s - k] * values[:, k:]) / (n_c * (n_s - k)) - mean * mean
        gamma += 2.0 * (1.0 - k / n_s) * r_k / var
    return gamma


def _variance_of_mean(level: _Level, c: np.ndarray, n_chains: int) -> float:
    """The variance of the mean of the per-sample quantity ``c`` ``(N,)`` over ``level``'s samples."""
    mean, var = float(np.mean(c)), float(np.var(c))
    gamma = _gamma(c.reshape(-1, n_chains).T, mean, var) if level.chained else 0.0
    return var * (1.0 + gamma) / c.size


def _run_levels(method: SubsetSimulation, scene: Scene, response, top: float, checkpoint=None) -> tuple:
    """``(levels, evaluations, n_bad)``: the levels up to the first whose threshold reaches ``top`` (or
    ``max_levels``), the responses computed and how many of them were not finite. With ``checkpoint`` (a
    :class:`jdpim._checkpoint.Session`) every level is written when finished, and those written are loaded."""
    n, p0 = method.n_per_level, method.p0
    n_c, n_s = int(round(p0 * n)), int(round(1.0 / p0))
    covers = {"n_per_level": n, "p0": p0}

    def finished(i, key, n_bad, make):
        """Level ``i`` and the key and count after it: loaded from ``checkpoint``, else ``make()`` and written."""
        part = None if checkpoint is None else checkpoint.load(f"level{i}.npz", covers)
        if part is not None:
            z, y, extras, threshold, chained, key_data, n_bad = part
            level = _Level(jnp.asarray(z), y, extras, float(threshold), bool(chained))
            return level, jax.random.wrap_key_data(jnp.asarray(key_data)), int(n_bad)
        level, key, n_bad = make(key, n_bad)
        if checkpoint is not None:
            part = (np.asarray(level.z), level.y, level.extras, level.threshold, level.chained)
            checkpoint.store(f"level{i}.npz", covers, (*part, np.asarray(jax.random.key_data(key)), n_bad))
        return level, key, n_bad

    def first(key, n_bad):
        key, k0 = jax.random.split(key)
        z = jax.random.normal(k0, (n, 2 * scene.n_steps + 1, scene.n_sources), jnp.float32)
        y, extras, bad = _evaluate(response, scene, z)
        return _Level(z, y, extras, -np.inf, False), key, n_bad + int(np.sum(bad))

    def chains(level, threshold, key, n_bad):
        # seeds of the next level: the p0 N samples above the threshold, each the start of a chain
        order = np.argsort(level.y)[n - n_c :]
        state, y_state, x_state = level.z[order], level.y[order], level.extras[order]
        zs, ys, xs = [], [], []
        for _ in range(n_s):
            key, k_prop, k_acc = jax.random.split(key, 3)
            xi = state + method.width * jax.random.uniform(k_prop, state.shape, jnp.float32, -1.0, 1.0)
            ratio = jnp.exp(0.5 * (state**2 - xi**2))
            candidate = jnp.where(jax.random.uniform(k_acc, state.shape, jnp.float32) < ratio, xi, state)
            y_new, x_new, bad = _evaluate(response, scene, candidate)
            n_bad += int(np.sum(bad))
            accept = y_new > threshold
            state = jnp.where(accept[:, None, None], candidate, state)
            y_state, x_state = np.where(accept, y_new, y_state), np.where(accept[:, None], x_new, x_state)
            zs.append(state)
            ys.append(y_state)
            xs.append(x_state)
        return _Level(jnp.concatenate(zs), np.concatenate(ys), np.concatenate(xs), threshold, True), key, n_bad

    level, key, n_bad = finished(0, jax.random.key(method.seed), 0, first)
    levels = [level]
    for i in range(1, method.max_levels):
        level = levels[-1]
        threshold = np.sort(level.y)[n - n_c - 1 : n - n_c + 1].mean()  # the 1 - p0 quantile
        if threshold >= top:
            break
        level, key, n_bad = finished(i, key, n_bad, functools.partial(chains, level, threshold))
        levels.append(level)
    return levels, n * len(levels), n_bad


def _scores(scene: Scene, settings: dict, extras: np.ndarray, level0: _Level) -> np.ndarray:
    """``(n, K)``: the whole-history scores of the parameters of ``settings`` (``{name: LikelihoodRatio}``) from
    their sums ``extras``, with the Wong-Zakai fraction measured on level 0's finite samples (as Monte Carlo's
    ``jdpim.sensitivities._scores.centred_scores``, uncentred)."""
    D = float(np.reshape(np.asarray(scene.noise.D), ()))
    q = np.mean(level0.extras[np.isfinite(level0.y), 2 * len(settings)]) / scene.n_steps
    frac = 1.0 - q / (2.0 * D * scene.dt)
    out = []
    for j, est in enumerate(settings.values()):
        c = frac if est.ito_correction else 0.0
        out.append((extras[:, 2 * j] - c * D * extras[:, 2 * j + 1]) / (2.0 * D))
    return np.stack(out, axis=1)


def _terms(est, name: str, b: float, m: int, hit, levels: list, scores: dict, values: dict, rerun) -> tuple:
    """``([(level j, c (N,)), ...], extra)``: the per-sample contributions to ``dP/d name`` at level ``b``
    (in level ``m``; ``hit``: its samples above ``b``) whose level means times ``p0^j`` add up to it, and for the
    likelihood ratio the variance of the score over level 0 (its centring's error), else 0."""
    if isinstance(est, LikelihoodRatio):
        per_level, mean0, var0 = scores[name]
        return [(m, np.where(hit, per_level[m] - mean0, 0.0))], var0
    if est == "noise":
        dims = levels[m].z[0].size
        return [(m, np.where(hit, (levels[m].extras[:, -1] - dims) / (2.0 * values["D"]), 0.0))], 0.0
    # central differences over every shell b_j < Y <= b_{j + 1} below level m, then Y > b_m: a path may cross b
    # at theta +- d from any of them
    lo, hi = est.pair(name, values[name])
    terms = []
    for j in range(m + 1):
        c = ((rerun(name, j, hi) > b).astype(float) - (rerun(name, j, lo) > b)) / (hi - lo)
        terms.append((j, c if j == m else np.where(levels[j].y <= levels[j + 1].threshold, c, 0.0)))
    return terms, 0.0


def _subset_simulation(method: SubsetSimulation, scene: Scene, query, estimators: dict) -> FirstPassage:
    levels_asked = np.asarray(query.levels, float)
    n, p0 = method.n_per_level, method.p0
    n_c = int(round(p0 * n))
    excitation = scene.excitation if scene.excitation is not None else method.default_excitation
    settings = {name: est for name, est in estimators.items() if isinstance(est, LikelihoodRatio)}
    response = _response(query.quantity, excitation, tuple(settings), scene.dt)
    levels, evaluations, n_bad = _run_levels(method, scene, response, levels_asked.max(), query.checkpoint)
    # the factor p0^i and the squared c.o.v. of the levels below level i, Au & Beck's sum
    factors, before = [1.0], [0.0]
    for level, upper in zip(levels[:-1], levels[1:], strict=False):
        hit = (level.y > upper.threshold).astype(float)
        gamma = _gamma(hit.reshape(-1, n_c).T, p0, p0 * (1.0 - p0)) if level.chained else 0.0
        factors.append(factors[-1] * p0)
        before.append(before[-1] + (1.0 - p0) / (n * p0) * (1.0 + gamma))
    thresholds = np.asarray([level.threshold for level in levels])
    prob, prob_se = np.full(levels_asked.shape, np.nan), np.full(levels_asked.shape, np.nan)
    value = {name: np.zeros(levels_asked.shape) for name in estimators}
    stderr = {name: np.zeros(levels_asked.shape) for name in estimators}
    scores = {}  # name -> (per level: its scores (N,), their mean and variance over level 0)
    if settings:
        per_level = [_scores(scene, settings, level.extras, levels[0]) for level in levels]
        finite = np.isfinite(levels[0].y)
        mean0, var0 = np.mean(per_level[0][finite], axis=0), np.var(per_level[0][finite], axis=0)
        scores = {name: ([s[:, k] for s in per_level], mean0[k], var0[k]) for k, name in enumerate(settings)}
    reruns = {}  # (name, level, value) -> y

    def rerun(name, i, v):
        if (name, i, v) not in reruns:
            plain = _response(query.quantity, excitation, (), scene.dt)
            reruns[name, i, v] = _evaluate(plain, with_parameters(scene, {name: v}), levels[i].z)[0]
        return reruns[name, i, v]

    for j, b in enumerate(levels_asked):
        m = int(np.sum(thresholds <= b)) - 1  # b_m <= b < b_{m + 1}
        hit = levels[m].y > b
        p_b = float(np.mean(hit))
        gamma = _gamma(hit.reshape(-1, n_c).T, p_b, p_b * (1.0 - p_b)) if levels[m].chained else 0.0
        prob[j] = factors[m] * p_b
        if p_b > 0:  # no error estimate from no sample above b
            prob_se[j] = prob[j] * np.sqrt(before[m] + (1.0 - p_b) / (n * p_b) * (1.0 + gamma))
        for name, est in estimators.items():
            terms, extra = _terms(est, name, b, m, hit, levels, scores, query.values, rerun)
            if isinstance(est, LikelihoodRatio):
                extra = prob[j] ** 2 * extra / n  # the error of the centring by Sbar
            parts = [(factors[i] * float(np.mean(c)), i, c) for i, c in terms]
            value[name][j] = sum(v for v, _, _ in parts)
            var = extra + sum(
                factors[i] ** 2 * _variance_of_mean(levels[i], c, n_c) + v**2 * before[i] for v, i, c in parts
            )
            stderr[name][j] = np.sqrt(var) if p_b > 0 else np.nan
    evaluations += sum(y.size for y in reruns.values())
    if n_bad:
        warnings.warn(
            f"{n_bad} of {evaluations} subset-simulation responses were not finite or diverged; they count as below "
            "every level",
            NonFiniteWarning,
            stacklevel=4,
        )
    dtype = scene.float_dtype
    t = (scene.save_at[-1],)
    p = jnp.asarray(prob[None], dtype)
    se = jnp.asarray(prob_se[None], dtype)
    derivative = derivative_stderr = None
    if estimators:
        derivative = {name: jnp.asarray(v[None], dtype) for name, v in value.items()}
        derivative_stderr = {name: jnp.asarray(v[None], dtype) for name, v in stderr.items()}
    return FirstPassage(
        t, jnp.asarray(levels_asked, dtype), p, se, jnp.zeros_like(p), method.name, derivative, derivative_stderr,
        n_evaluations=evaluations,
    )  # fmt: skip
