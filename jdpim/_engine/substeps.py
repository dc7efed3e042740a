"""Sub-stepping of stiff steps: each path that needs it redoes the step as ``k`` equal sub-steps of its own (see
:class:`jdpim.Substeps`)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from .elementwise import along_paths
from .loops import while_differentiated_as
from .one_path import Engine
from .rk4 import forcing, stiffness_rate
from .settings import Substeps


def needed(eng: Engine, substeps: Substeps, h, q, v, e, rand, node):
    """Sub-steps one path needs at ``(q, v)`` under its forcing node ``e[node]`` (``max_substeps`` if not finite)."""
    n_max = substeps.max_substeps
    k = jnp.ceil(h * stiffness_rate(eng.path_model(rand), q, v, e[node]) / substeps.limit)
    return jnp.clip(jnp.where(jnp.isfinite(k), k, n_max), 1, n_max).astype(jnp.int32)


def sub_forcing(e, ta, tb):
    """One path's forcing nodes at the start, middle and end of its sub-interval ``[ta, tb]``."""
    return tuple(forcing(e, tau) for tau in (ta, 0.5 * (ta + tb), tb))


def sub_step(plain_step, h, i, y, e, rand, k):
    """Sub-step ``i`` (of the step of length ``h``) of each path whose own number of sub-steps ``k`` (``(n,)``)
    exceeds ``i``, by ``plain_step(q, v, e, rand, h)``.

    The other paths take a step of length 0 inside the step (forcing read at its start): they stay
    where they are and cross nothing, so they add no impact work.
    """
    active = i < k
    kf = k.astype(y[0].dtype)
    ta, tb = jnp.where(active, i / kf, 0.0), jnp.where(active, (i + 1) / kf, 0.0)
    sub_e = jax.vmap(sub_forcing)(e, ta, tb)
    new = plain_step(*y, sub_e, rand, jnp.where(active, h / kf, 0.0))
    return tuple(jnp.where(along_paths(active, a), a, b) for a, b in zip(new, y, strict=True))


def substepped(eng: Engine, substeps: Substeps, plain_step, h, q, v, e, rand):
    """The step of every path, as the sub-steps of :func:`sub_step` where the path's start or the end of its full
    step (a trial every path takes first) is stiff or blew up."""
    start = (q, v)
    finite = jnp.all(jnp.isfinite(q), axis=1) & jnp.all(jnp.isfinite(v), axis=1)
    k_start = jax.vmap(functools.partial(needed, eng, substeps, h, node=0))(q, v, e, rand)

    def body(i, carry):
        # iteration 0: every path's full step (its trial); then the paths that need it redo the
        # step from the start in k sub-steps, i = 1 .. k
        trial, y, k = carry
        first = i == 0
        new = sub_step(plain_step, h, jnp.where(first, 0, i - 1), y, e, rand, jnp.where(first, 1, k))

        def after_trial():
            # a path needs sub-steps if its start or the end of its trial step is stiff (or blew up)
            k_end = jax.vmap(functools.partial(needed, eng, substeps, h, node=2))(*new, e, rand)
            return new, start, jnp.where(finite, jnp.maximum(k_start, k_end), 1)

        return jax.lax.cond(first, after_trial, lambda: (trial, new, k))

    def active(c):  # c = (i, trial, y, k): iteration i has work
        i, k_max = c[0], jnp.max(c[3])
        return (i == 0) | ((k_max > 1) & (i <= k_max))

    def iteration(c):
        return (c[0] + 1, *body(c[0], c[1:]))

    def bounded(active, iteration, c):  # max_substeps + 1 iterations, those past the last skipped
        return jax.lax.fori_loop(
            0, substeps.max_substeps + 1, lambda _, c: jax.lax.cond(active(c), iteration, lambda c: c, c), c
        )

    # as many iterations as the step's stiffest path needs (one where none is stiff)
    carry = (jnp.zeros((), jnp.int32), start, start, k_start)
    _, trial, y, k = while_differentiated_as(bounded, active, iteration, carry)
    return tuple(jnp.where(along_paths(k > 1, a), a, b) for a, b in zip(y, trial, strict=True))
