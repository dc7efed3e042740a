"""What the per-path estimators of the sensitivities and of first passage share: weighted moments of per-path
contributions, finite weights, and the centred likelihood-ratio scores of the score sums tracked along paths."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._estimators import window_of

CHUNK = 512  # paths per chunk of the sums over per-path contributions


def moments(contribution, inputs, weights):
    """``sum_i w_i c_i`` and its standard error ``sqrt(sum_i w_i^2 (c_i - mean)^2)``, over chunks of paths."""
    n = weights.shape[0]
    size = min(CHUNK, n)
    pad = (-n) % size
    chunks = jax.tree_util.tree_map(
        lambda a: jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)).reshape(-1, size, *a.shape[1:]), (inputs, weights)
    )

    def body(acc, chunk):
        inp, w = chunk
        c = contribution(*inp)
        ww = w * w
        terms = ((w, c), (ww, c * c), (ww, c))
        return tuple(a + jnp.tensordot(u, b, axes=1) for a, (u, b) in zip(acc, terms, strict=True)), None

    shape = jax.eval_shape(contribution, *jax.tree_util.tree_map(lambda a: a[0], chunks[0])).shape[1:]
    zeros = jnp.zeros(shape, weights.dtype)
    (s1, s2, s3), _ = jax.lax.scan(body, (zeros, zeros, zeros), chunks)
    var = s2 - 2.0 * s1 * s3 + s1 * s1 * jnp.sum(weights * weights)
    return s1, jnp.sqrt(jnp.maximum(var, 0.0))


def finite_weights(weights, *arrays):
    """``(weights, arrays)`` with the paths (first axis) not finite in every one of ``arrays`` at zero weight and
    their entries zero."""
    ok = jnp.ones(weights.shape, bool)
    for a in arrays:
        ok = ok & jnp.all(jnp.isfinite(a.reshape(a.shape[0], -1)), axis=1)
    return jnp.where(ok, weights, 0.0), [jnp.where(ok.reshape((-1,) + (1,) * (a.ndim - 1)), a, 0.0) for a in arrays]


def score_windows(scene, settings: dict, t: float):
    """``(k_t, starts, times, run_scene)`` of a run that tracks the scores of ``settings`` up to ``t``: the step of
    ``t``, ``{name: step}`` where each window starts (0: the whole history), the steps to save (``t`` and the
    windows' starts) and ``scene`` saving at them."""
    dt = scene.dt
    k_t = int(round(t / dt))
    starts = {n: max(0, k_t - int(round(min(window_of(e, scene.model), t) / dt))) for n, e in settings.items()}
    times = sorted({k_t} | {k for k in starts.values() if k > 0})
    return k_t, starts, times, scene.replace(save_at=tuple(k * dt for k in times))


def centred_scores(scene, settings: dict, sums, w, times: list, k_t: int, starts: dict) -> dict:
    """``{name: (N,)}`` scores ``S_i - Sbar`` over each window (zero for zero-weighted paths), per parameter unit.

    ``sums``: ``(N, len(times), 2 len(settings) + 1)`` running sums of :class:`Score` after the steps ``times``;
    ``k_t``: the step of ``t``; ``starts``: ``{name: step}`` where each window starts (0: the whole history).
    """
    D = jnp.reshape(jnp.asarray(scene.noise.D, scene.float_dtype), ())  # one source: a number, or a (1, 1) matrix
    total = sums[:, times.index(k_t)]
    q = jnp.sum(w * total[:, -1]) / jnp.sum(w) / max(k_t, 1)
    frac = 1.0 - q / (2.0 * D * scene.dt)
    scores = {}
    for j, (n, est) in enumerate(settings.items()):
        a = total - (sums[:, times.index(starts[n])] if starts[n] > 0 else 0.0)
        c = frac if est.ito_correction else 0.0
        s_i = (a[:, 2 * j] - c * D * a[:, 2 * j + 1]) / (2.0 * D)
        s_i = jnp.where(w > 0, s_i, 0.0)
        scores[n] = s_i - jnp.sum(w * s_i) / jnp.sum(w)
    return scores
