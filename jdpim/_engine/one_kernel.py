"""A small function of a batch compiled as one CPU kernel (:func:`one_kernel`).

XLA's CPU runtime runs a program kernel by kernel, and on a batch of a few hundred rows a kernel's launch costs more
than its work: the resolution of a compact batch of crossing paths is some 45 kernels. XLA emits a call that is tagged
small (``xla_cpu_small_call``) and kept as a call (``inlineable="false"``) as one kernel, loops and branches included:
it does so itself for the loops of fewer bytes than a process-wide threshold (docs/speed.md), and the tag does it for
one function of one program. Its single-kernel emitter does not take every operation (matrix products, sorts,
scatters and calls into XLA's runtime fail to compile in it), so a function is tagged only where every primitive of
its jaxpr is one that it takes (:data:`ONE_KERNEL_PRIMITIVES`); and derivatives are computed by the function as it is.
"""

from __future__ import annotations

import functools

import jax
from jax.experimental.xla_metadata import set_xla_metadata
from jax.extend.core import jaxprs_in_params

from .._cpu import on_cpu

# The primitives XLA's CPU single-kernel emitter takes: elementwise arithmetic, comparisons and conversions, the
# array's structure, reductions, loops and branches (``reshard``: a no-op on the values inside ``shard_map``), and
# ``dot_general`` where it contracts axes of length 1 only (:func:`unit_product`). Any other primitive keeps a function
# as XLA compiles it otherwise.
ONE_KERNEL_PRIMITIVES = frozenset(
    """abs acos acosh add and argmax argmin asin asinh atan atan2 atanh bitcast_convert_type broadcast_in_dim cbrt
    ceil clamp clz concatenate cond convert_element_type copy cos cosh custom_jvp_call div dot_general
    dynamic_slice dynamic_update_slice eq erf erf_inv erfc exp exp2 expm1 floor ge gt integer_pow iota is_finite jit
    le lgamma log log1p logistic lt max min mul ne neg nextafter not or pad population_count pow reduce_and
    reduce_max reduce_min reduce_or reduce_prod reduce_sum reduce_xor rem reshape reshard rev round rsqrt scan
    select_n shift_left shift_right_arithmetic shift_right_logical sign sin sinh slice split sqrt square squeeze
    stack stop_gradient sub tan tanh tile transpose unstack while xor""".split()
)
# the frontend attributes of a call that XLA's CPU compiler emits as one kernel
SMALL_CALL = {"inlineable": "false", "xla_cpu_small_call": "true"}


def unit_product(eqn) -> bool:
    """Whether a ``dot_general`` contracts only axes of length 1 (``jnp.dot`` of two one-element vectors): a product
    of numbers, which XLA writes as a multiplication."""
    (contracted, _), _ = eqn.params["dimension_numbers"]
    return all(eqn.invars[0].aval.shape[axis] == 1 for axis in contracted)


def primitives(jaxpr) -> set[str]:
    """Names of the primitives of ``jaxpr`` (``Jaxpr`` or ``ClosedJaxpr``) and of every jaxpr it calls; a
    ``dot_general`` that contracts an axis longer than 1 is named ``"matrix product"``."""
    jaxpr = getattr(jaxpr, "jaxpr", jaxpr)
    names = set()
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        names.add("matrix product" if name == "dot_general" and not unit_product(eqn) else name)
        for sub in jaxprs_in_params(eqn.params):
            names |= primitives(sub)
    return names


def one_kernel(fn, *args):
    """``fn(*args)`` (arrays or pytrees of them), compiled as one kernel on a CPU where every primitive of ``fn`` is
    one that XLA's single-kernel emitter takes; elsewhere ``fn(*args)`` as it is. Derivatives are those of ``fn``
    itself. ``fn`` may close over traced values (the model's parameters): they reach the call as arguments, so that
    derivatives with respect to them are exact."""
    if not on_cpu():
        return fn(*args)
    flat, tree = jax.tree_util.tree_flatten(args)
    closed, shapes = jax.make_jaxpr(lambda *a: fn(*jax.tree_util.tree_unflatten(tree, a)), return_shape=True)(*flat)
    if not primitives(closed) <= ONE_KERNEL_PRIMITIVES:
        return fn(*args)
    outs = _small_call(closed.jaxpr, len(closed.consts), *closed.consts, *flat)
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(shapes), outs)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _small_call(jaxpr, n_consts, *values):
    """``jaxpr`` of its ``n_consts`` constants and its arguments (``values``, in this order), in a call tagged
    :data:`SMALL_CALL` (and so is every call inside it, ``jnp.clip``'s for one, which the kernel calls in turn)."""
    with set_xla_metadata(**SMALL_CALL):
        return jax.jit(functools.partial(_evaluate, jaxpr, n_consts))(*values)


def _evaluate(jaxpr, n_consts, *values):
    return jax.core.eval_jaxpr(jaxpr, values[:n_consts], *values[n_consts:])


@_small_call.defjvp
def _small_call_jvp(jaxpr, n_consts, primals, tangents):
    return jax.jvp(functools.partial(_evaluate, jaxpr, n_consts), primals, tangents)
