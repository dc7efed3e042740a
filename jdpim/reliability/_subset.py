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
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._excitation import GaussianNodes
from .._integrate import RunningMax
from .._pytree import check_int, check_real, pytree_dataclass, static_field
from .._scene import Scene
from ..methods._base import AbstractMethod
from ..methods._paths import NonFiniteWarning, integrate_forcing
from ._first_passage import FirstPassage


@pytree_dataclass
class SubsetSimulation(AbstractMethod):
    """Subset simulation for first-passage probabilities (use it with ``jdpim.first_passage``).

    Args:
        n_per_level: samples per level ``N`` (>= 10; ``p0 N`` and ``1 / p0`` must be whole numbers).
        p0: conditional probability of each level, in (0, 0.5].
        seed: PRNG seed (>= 0).
        width: half-width ``w`` of the uniform component proposal (> 0).
        max_levels: most levels (>= 1) before giving up on the highest level asked for.

    The scene's forcing must be that of ``jdpim.GaussianNodes()`` (the input space is its node values; a
    scene's default, ``excitation=None``, gives it) and it may have no random parameters. Probabilities are
    given at the scene's last saved time.
    """

    n_per_level: int = static_field(default=1000)
    p0: float = static_field(default=0.1)
    seed: int = static_field(default=0)
    width: float = static_field(default=1.0)
    max_levels: int = static_field(default=10)
    name = "subset_simulation"
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

    def run(self, scene: Scene):
        raise ValueError("SubsetSimulation estimates failure probabilities: use jdpim.first_passage(scene, ...)")

    def sensitivity(self, scene: Scene, query):
        raise ValueError("SubsetSimulation has no density derivatives; use jdpim.MonteCarlo or jdpim.DPIM")

    def first_passage(self, scene: Scene, query) -> FirstPassage:
        if scene.random:
            raise ValueError("SubsetSimulation needs a scene without random parameters")
        if query.wrt:
            raise ValueError("SubsetSimulation gives no derivatives; use jdpim.MonteCarlo for wrt=...")
        return _subset_simulation(self, scene, query)


def _response(scene: Scene, quantity, excitation):
    """``z (n, 2 T + 1, m) -> Y (n,)``: the running maximum at the last saved time (jitted)."""
    dtype = scene.float_dtype

    @jax.jit
    def response(z):
        forcing = excitation.from_normals(scene, z)
        rand = jnp.zeros((z.shape[0], 0), dtype)
        _, tracked = integrate_forcing(scene, forcing, rand, RunningMax(quantity))
        y = tracked[:, -1, 0]
        return jnp.where(jnp.isnan(y), -jnp.inf, y), jnp.isnan(y)

    return response


def _gamma(indicators: np.ndarray, p: float) -> float:
    """Au & Beck's correlation factor of indicators ``(n_chains, length)`` along the chains."""
    n_c, n_s = indicators.shape
    if n_s < 2 or p <= 0.0 or p >= 1.0:
        return 0.0
    r0 = p * (1.0 - p)
    gamma = 0.0
    for k in range(1, n_s):
        r_k = np.sum(indicators[:, : n_s - k] * indicators[:, k:]) / (n_c * (n_s - k)) - p * p
        gamma += 2.0 * (1.0 - k / n_s) * r_k / r0
    return gamma


def _subset_simulation(method: SubsetSimulation, scene: Scene, query) -> FirstPassage:
    levels = np.asarray(query.levels, float)
    n, p0 = method.n_per_level, method.p0
    n_c, n_s = int(round(p0 * n)), int(round(1.0 / p0))
    dims = (2 * scene.n_steps + 1, scene.n_sources)
    excitation = scene.excitation if scene.excitation is not None else method.default_excitation
    response = _response(scene, query.quantity, excitation)
    key = jax.random.key(method.seed)
    key, k0 = jax.random.split(key)
    z = jax.random.normal(k0, (n, *dims), jnp.float32)
    y, bad = response(z)
    y, n_bad = np.asarray(y, float), int(np.sum(np.asarray(bad)))
    chains = None  # level 0: independent samples
    prob = np.full(levels.shape, np.nan)
    delta2 = np.full(levels.shape, np.nan)
    factor, d2_before, evaluations = 1.0, 0.0, n
    for level in range(method.max_levels):
        threshold = np.sort(y)[n - n_c - 1 : n - n_c + 1].mean()  # the 1 - p0 quantile
        last = threshold >= levels.max() or level == method.max_levels - 1
        for j, b in enumerate(levels):  # levels below this level's threshold (or all, at the last level)
            if np.isnan(prob[j]) and (b < threshold or last):
                p_b = float(np.mean(y > b))
                gamma = 0.0 if chains is None else _gamma(chains > b, p_b)
                d2 = (1.0 - p_b) / (n * p_b) * (1.0 + gamma) if p_b > 0 else np.inf
                prob[j], delta2[j] = factor * p_b, d2_before + d2
        if last:
            break
        # seeds of the next level: the p0 N samples above the threshold, each the start of a chain
        order = np.argsort(y)[n - n_c :]
        gamma = 0.0 if chains is None else _gamma(chains > threshold, p0)
        d2_before += (1.0 - p0) / (n * p0) * (1.0 + gamma)
        factor *= p0
        state, y_state = z[order], y[order]
        zs, ys = [], []
        for _ in range(n_s):
            key, k_prop, k_acc = jax.random.split(key, 3)
            xi = state + method.width * jax.random.uniform(k_prop, state.shape, jnp.float32, -1.0, 1.0)
            ratio = jnp.exp(0.5 * (state**2 - xi**2))
            candidate = jnp.where(jax.random.uniform(k_acc, state.shape, jnp.float32) < ratio, xi, state)
            y_new, bad = response(candidate)
            y_new, n_bad = np.asarray(y_new, float), n_bad + int(np.sum(np.asarray(bad)))
            accept = y_new > threshold
            state = jnp.where(accept[:, None, None], candidate, state)
            y_state = np.where(accept, y_new, y_state)
            zs.append(state)
            ys.append(y_state)
            evaluations += n_c
        chains = np.stack(ys, axis=1)  # (n_c, n_s)
        z, y = jnp.concatenate(zs), np.concatenate(ys)
    if n_bad:
        warnings.warn(
            f"{n_bad} of {evaluations} subset-simulation responses were not finite; they count as below every level",
            NonFiniteWarning,
            stacklevel=4,
        )
    dtype = scene.float_dtype
    t = (scene.save_at[-1],)
    p = jnp.asarray(prob[None], dtype)
    se = jnp.asarray((prob * np.sqrt(delta2))[None], dtype)
    return FirstPassage(t, jnp.asarray(levels, dtype), p, se, jnp.zeros_like(p), method.name, n_evaluations=evaluations)
