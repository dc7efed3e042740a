"""Loops that stop as soon as their work is done, differentiated as loops of a static trip count.

``lax.while_loop`` runs only the iterations a step needs, but reverse mode cannot differentiate it; a loop of a
static trip count whose iterations past the end are skipped under ``lax.cond`` can be differentiated, but tests
its condition and skips in every one of its iterations. :func:`while_differentiated_as` runs the first and
differentiates through the second, which computes the same values."""

from __future__ import annotations

import functools

import jax


def while_differentiated_as(bounded, cond_fun, body_fun, carry):
    """``lax.while_loop(cond_fun, body_fun, carry)``, differentiated as ``bounded(cond_fun, body_fun, carry)``.

    ``bounded`` runs the same calls of ``body_fun`` in loops of static trip counts (as reverse mode needs) and must
    give the same values. The derivative rule sees every value the two functions read (the step's arrays, the
    model's parameters) as an argument: each function is traced once to a jaxpr whose constants are passed
    explicitly (a ``custom_jvp`` cannot differentiate with respect to values it closes over)."""
    treedef = jax.tree_util.tree_structure(carry)
    cond_jaxpr, body_jaxpr = jax.make_jaxpr(cond_fun)(carry), jax.make_jaxpr(body_fun)(carry)

    def cond_call(consts, c):
        return jax.core.eval_jaxpr(cond_jaxpr.jaxpr, consts, *jax.tree_util.tree_leaves(c))[0]

    def body_call(consts, c):
        out = jax.core.eval_jaxpr(body_jaxpr.jaxpr, consts, *jax.tree_util.tree_leaves(c))
        return jax.tree_util.tree_unflatten(treedef, out)

    return _loop(bounded, cond_call, body_call, carry, list(cond_jaxpr.consts), list(body_jaxpr.consts))


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2))
def _loop(bounded, cond_call, body_call, carry, cond_consts, body_consts):
    return jax.lax.while_loop(
        functools.partial(cond_call, cond_consts), functools.partial(body_call, body_consts), carry
    )


@_loop.defjvp
def _loop_jvp(bounded, cond_call, body_call, primals, tangents):
    def static(carry, cond_consts, body_consts):
        return bounded(functools.partial(cond_call, cond_consts), functools.partial(body_call, body_consts), carry)

    return jax.jvp(static, primals, tangents)
