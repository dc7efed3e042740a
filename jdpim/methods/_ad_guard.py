"""Guards on pathwise derivatives through the sampled pipeline: by mechanism, and in three static cases.

By mechanism (:func:`probed`, around the simulation whenever it is traced): differentiated, each path's tangent
is found by forward mode, so that reverse mode too can read the per-path contributions of whatever it
differentiates and warn where few paths carry the derivative (``jdpim._tangents``); ``Result.pdf``,
``Result.joint_pdf`` and ``Result.moment`` read theirs in forward mode. Statically, whatever the numbers: a
grazing start, the impacts of a system of several degrees of freedom (not validated), and probabilities counted
over sampled paths (zero).

Paths that start at rest on the barrier (the default start) graze it at once: the impact's saltation
factor divides by an impact speed near zero, so the pathwise derivative of each path is dominated by
that first contact and the derivative of the density is wrong (measured: ``jax.grad`` through
``jdpim.dpim`` at t = 2, 256 points, reference model: dp/dalpha -2.3 in float32 and +0.6 in float64
against -0.4 by central differences). Differentiation is detected by a ``jax.custom_jvp`` identity on the
scene's parameters, whose tangent rule runs only when something is differentiated (forward or reverse
mode, also under ``jit``): values and cost are unchanged otherwise.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._models import AbstractOscillator
from .._pytree import concrete
from .._scene import Scene
from .._tangents import check_only, contract, projections, tangent_basis, watch

MAX_DIRECTIONS = 32  # differentiated scalars beyond which tangents come from plain AD, checked along projections

GRAZING = (
    "pathwise derivatives through a start at rest on the barrier (a grazing impact) are biased: each path's "
    "tangent divides by its impact speed near zero (measured at t = 2: dp/dalpha -2.3 against -0.4 by central "
    "differences); use jdpim.sensitivity (path integration, or its likelihood-ratio and central-difference "
    "estimators), or start off the barrier (x0 > barrier)"
)


def starts_grazing(scene: Scene) -> bool:
    """Whether every path starts at rest on a constraint (``x0`` on the barrier or ``None``, ``v0 = 0``)."""
    model = scene.model
    if not model.has_barrier or any(name in ("x0", "v0") for name, _ in scene.random):
        return False
    x0, v0 = (concrete(z) for z in scene.initial_state())
    if isinstance(model, AbstractOscillator):
        normal, b = np.ones((1, 1)), concrete(model.barrier)
    else:  # read from the fields: inside a trace the stacked constraints are staged, not concrete
        normal, b = np.array([c.normal for c in model.constraints]), concrete([c.position for c in model.constraints])
    if x0 is None or v0 is None or b is None:
        return False
    c = normal @ np.broadcast_to(x0, (model.dimension,)) - b
    return bool(np.all(v0 == 0) and np.any(c == 0))


SEVERAL_DOF = (
    "pathwise derivatives through the impacts of a system of several degrees of freedom are not validated and "
    "can be far off (measured: d E[x1^2] / d c11 of an impact damper, r = 0.5, t = 5, 200 paths: 7.5 by jax.grad "
    "against -0.13 by central differences with common random numbers); difference jdpim.solve runs of the "
    "same seed instead (jdpim.with_parameters)"
)


INDICATOR = (
    "the pathwise derivative of a probability counted over sampled paths (first passage, impacts) is zero: each "
    "path's indicator is piecewise constant in the parameters; pass wrt= to jdpim.first_passage (likelihood "
    "ratio or central differences) or use path integration"
)


def guard(scene: Scene) -> Scene:
    """``scene`` itself; differentiating through it warns (``SensitivityWarning``) when its paths start grazing,
    or when it has several degrees of freedom and constraints."""
    if starts_grazing(scene):
        message = GRAZING
    elif not isinstance(scene.model, AbstractOscillator) and scene.model.has_barrier:
        message = SEVERAL_DOF
    else:
        return scene
    return watch(scene, message)


def probed(run, scene: Scene, rows):
    """``run(scene, rows)`` (per-path outputs, path axis first); differentiated, its per-path tangents are
    found by forward mode, one direction per differentiated scalar of ``scene``, so that reverse mode can
    check the per-path contributions of whatever it differentiates (``jdpim._tangents``).

    Values and cost are unchanged when nothing is differentiated. Differentiated, the cost is that of
    ``jax.jacfwd`` over those scalars (reverse mode then needs no backward pass through the steps). Beyond
    ``MAX_DIRECTIONS`` of them the tangent is plain AD (a backward pass in reverse mode) and the check reads
    the contributions along ``PROJECTIONS`` fixed random combinations of the scalars (``jdpim._tangents.projections``:
    their squared norms and sums are kept in expectation), at the cost of that many forward directions more.
    """
    leaves, treedef = jax.tree_util.tree_flatten(scene)
    return _probed(run, treedef, leaves, rows)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _probed(run, treedef, leaves, rows):
    return run(jax.tree_util.tree_unflatten(treedef, leaves), rows)


def _inexact(x) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.inexact)


def _probed_jvp(run, treedef, primals, tangents):
    leaves, rows = primals
    dots = tangents[0]
    live = [i for i, (x, d) in enumerate(zip(leaves, dots, strict=True)) if _inexact(x) and not _zero(d)]

    def f(live_leaves):
        full = list(leaves)
        for i, x in zip(live, live_leaves, strict=True):
            full[i] = x
        return run(jax.tree_util.tree_unflatten(treedef, full), rows)

    live_leaves = [leaves[i] for i in live]
    live_dots = [dots[i] for i in live]
    if not live:
        return jax.jvp(f, (live_leaves,), (live_dots,))
    basis, n_dir = tangent_basis(live_leaves)
    td = jnp.concatenate([jnp.reshape(d, (-1,)) for d in live_dots])
    if n_dir <= MAX_DIRECTIONS:
        out, J = jax.vmap(lambda d: jax.jvp(f, (live_leaves,), (d,)), out_axes=(None, 0))(basis)
        return out, jax.tree_util.tree_map(lambda j: contract(j, td.astype(j.dtype)), J)
    # many scalars: the tangent by plain AD, checked along PROJECTIONS fixed random directions of them
    u = projections(n_dir)  # (n_dir, K)
    directions = [jnp.tensordot(u.T, b, axes=1).astype(b.dtype) for b in basis]
    out, tangent = jax.jvp(f, (live_leaves,), (live_dots,))
    _, J = jax.vmap(lambda d: jax.jvp(f, (live_leaves,), (d,)), out_axes=(None, 0))(directions)
    tk = jnp.asarray(u.T, td.dtype) @ td
    return out, jax.tree_util.tree_map(lambda y, j: y + check_only(j, tk.astype(j.dtype)), tangent, J)


_probed.defjvp(_probed_jvp, symbolic_zeros=True)


def _zero(d) -> bool:
    return type(d) is jax.custom_derivatives.SymbolicZero or jnp.result_type(d) == jax.dtypes.float0
