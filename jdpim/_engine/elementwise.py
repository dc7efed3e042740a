"""Elementwise helpers of the engine: a value stored once (:func:`stored`), an entry picked by a traced index
(:func:`pick`) and a per-path mask broadcast (:func:`along_paths`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._cpu import on_cpu


@jax.custom_jvp
def stored(x):
    """``x`` itself, computed once into memory on a CPU, and so is its tangent (values unchanged).

    XLA's CPU loop fusion computes an elementwise value again inside the loop of every fusion that uses it (and
    for every column of a ``(k, d)`` consumer), so the chains of a resolution (Newton iterations, the crossing
    time, the RK4 redo) are recomputed many times over. A reduction is not fused into its consumers: the exact
    ``max(x, lowest)`` over a stacked pair stores ``x`` (``jax.lax.optimization_barrier`` does not: the CPU compiler
    removes it before fusing). XLA folds that reduction away where its output has one element (a batch of one path),
    so batches that store values have at least two rows. A tangent is stored too, by a sum with zero (linear, so that
    reverse mode transposes it), or derivative programs compute every tangent chain again. Elsewhere (accelerators,
    unmeasured) ``x`` is returned.
    """
    if not on_cpu():
        return x
    low = -jnp.inf if jnp.issubdtype(x.dtype, jnp.floating) else jnp.iinfo(x.dtype).min
    return jnp.max(jnp.stack([x, jnp.full_like(x, low)]), axis=0)


@stored.defjvp
def _stored_jvp(primals, tangents):
    return stored(primals[0]), _stored_linear(tangents[0])


def _stored_linear(t):
    """A tangent stored as ``stored`` stores a value, by a linear reduction (so that reverse mode transposes it)."""
    if not on_cpu() or not jnp.issubdtype(t.dtype, jnp.floating):
        return t
    return jnp.sum(jnp.stack([t, jnp.zeros_like(t)]), axis=0)


def pick(a, j):
    """``a[j]`` for a traced ``j``: a masked sum (elementwise for XLA, where a gather per path is slow); ``a[0]``
    when there is one constraint."""
    if a.shape[0] == 1:
        return a[0]
    mask = jnp.reshape(jnp.arange(a.shape[0]) == j, (-1,) + (1,) * (a.ndim - 1))
    return jnp.sum(jnp.where(mask, a, 0), axis=0)


def along_paths(mask, a):
    """``mask`` ``(n,)`` broadcast against the per-path array ``a`` ``(n, ...)``."""
    return jnp.reshape(mask, mask.shape + (1,) * (a.ndim - 1))
