"""Whether a pathwise derivative of a sampled quantity can be trusted, read from its own per-path contributions.

A derivative taken by AD through weighted paths is a sum ``dF/dtheta = sum_i c_i`` of per-path contributions
(``c_i = w_i f'(Y_i) dY_i/dtheta`` for ``F = sum_i w_i f(Y_i)``). Its standard error comes from the second
moment ``sum_i c_i^2``; when a few paths carry that second moment (their tangents grew across impacts, near
grazing ones above all: each multiplies the tangent by a saltation matrix that divides by the impact speed),
the estimate is one or two paths' tangents and its error cannot be estimated. The effective number of paths
carrying it, ``n_eff = (sum_i a_i)^2 / sum_i a_i^2`` with ``a_i = |c_i|^2`` (summed over the outputs), is
``N / 3`` for Gaussian contributions and near 1 when one path dominates; the relative standard error of the
second moment is about ``n_eff^-1/2``. Below ``MIN_EFFECTIVE_PATHS`` (that error above a quarter), with a
standard error of the derivative itself at least ``STDERR_WARN`` of its size, a :class:`SensitivityWarning`
names ``jdpim.sensitivity`` (:func:`warn_if_unreliable`).

Measured (reference oscillator, ``x0 = 0.5``, D = 0.03, 2000 Monte Carlo paths, ``d/dalpha`` of
``pdf('x', 0.5, bandwidth=0.1)``): ``n_eff`` 138 at t = 2 (the derivative agrees with central differences),
3.5 at t = 12 and 1.0 at t = 50 (the derivative is -1.3e5 and 2.3e18; central differences of the same paths
give +1.2 to +2.6 and -2.6 to -5.4 depending on the step). The state tangents
alone cannot tell: at t = 2 two paths near the barrier already carry most of their second moment, and the
density at 0.5 does not see them.

Both modes of AD are covered. Forward mode (``jax.jvp``, ``jax.jacfwd``): :func:`watch_forward` reads the
contributions where a result's functional knows its own ``f'``. Reverse mode (``jax.grad``, ``jax.vjp``,
``jax.jacrev``): :func:`contract` carries the paths' tangents ``J`` (found by forward mode, one direction per
differentiated scalar) and its transpose sees the contributions ``c_i = <ct_i, J_i>`` of whatever functional
the cotangent ``ct`` comes from. The check runs on the host (``jax.debug.callback``), under ``jit`` too.
"""

from __future__ import annotations

import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir

from ._warnings import SensitivityWarning

MIN_EFFECTIVE_PATHS = 16.0  # below this the second moment of the contributions is uncertain by more than 1/4
STDERR_WARN = 0.25  # relative L2 standard error from which a sampled derivative is flagged
PROJECTIONS = 8  # outputs beyond which per-path contributions are projected before they leave the device


def effective_paths(norms) -> float:
    """``(sum_i a_i)^2 / sum_i a_i^2`` of the per-path squared contributions ``a_i`` (``(N,)``; scaled by their
    largest first, so nothing overflows); 0 when one is not finite, ``inf`` when all are zero."""
    a = np.asarray(norms, np.float64)
    top = np.max(a)
    if not np.isfinite(top):
        return 0.0
    if top == 0:
        return np.inf
    r = a / top
    return float(np.sum(r) ** 2 / np.sum(r * r))


def relative_error(contributions) -> float:
    """Standard error of ``sum_i c_i`` (as for equal weights; relative L2 over the outputs) against its size,
    from per-path contributions ``(N, M)``; scaled by the largest first."""
    c = np.asarray(contributions, np.float64)
    n = c.shape[0]
    top = np.max(np.abs(c))
    if not np.isfinite(top):
        return np.inf
    c = c / (top if top > 0 else 1.0)
    value = np.sum(c, axis=0)
    stderr = np.sqrt(np.sum((c - value / n) ** 2, axis=0) * n / max(n - 1, 1))
    size = np.linalg.norm(value)
    if size == 0:
        return np.inf if top > 0 else 0.0
    return float(np.linalg.norm(stderr) / size)


def warn_if_unreliable(n: int, n_eff: float, relative_error: float, stacklevel: int = 2) -> None:
    """Warn (:class:`SensitivityWarning`) when a pathwise derivative through ``n`` paths is both uncertain
    (standard error ``relative_error`` of its size, relative L2, at least ``STDERR_WARN``) and carried by few of
    its paths (``n_eff``, :func:`effective_paths`, below ``MIN_EFFECTIVE_PATHS``, or below ``n / 16`` for fewer
    than 256 paths), so that the standard error itself cannot be trusted.

    Few paths of one sign give ``relative_error`` about ``n_eff^-1/2`` (above 1/4 below 16 paths); many paths that
    a kernel localises in a tail give a small ``n_eff`` with a small error, which is not flagged.
    """
    if n_eff < min(MIN_EFFECTIVE_PATHS, n / 16) and not relative_error < STDERR_WARN:
        warnings.warn(
            f"this pathwise derivative through {n} sampled paths is carried by {n_eff:.3g} of them, with a standard "
            f"error of {relative_error:.2g} of its size: their tangents grew across (near-grazing) impacts and the "
            "estimate is not reliable; use jdpim.sensitivity (path integration, or its likelihood-ratio and "
            "central-difference estimators)",
            SensitivityWarning,
            stacklevel=stacklevel + 1,
        )


def check_contributions(contributions) -> None:
    """:func:`warn_if_unreliable` of per-path contributions ``(N, M)`` (path axis first, weights included)."""
    c = np.asarray(contributions, np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        norms = np.sum(np.where(np.isfinite(c), c, np.inf) ** 2, axis=1)
    warn_if_unreliable(c.shape[0], effective_paths(norms), relative_error(c), stacklevel=2)


def _report(contributions) -> None:
    """Check per-path contributions ``(N, ...)`` on the host (:func:`check_contributions`), under ``jit`` too.

    Only linear maps of the contributions are computed on the device: in reverse mode the forward-mode check
    is part of the linear (transposed) computation, whose callback drops out. Beyond ``PROJECTIONS`` outputs
    (a density on a grid) they are projected on ``PROJECTIONS`` fixed random directions, which keep their
    norms and sums in expectation, so that ``(N, PROJECTIONS)`` numbers leave the device.
    """
    c = contributions.reshape(contributions.shape[0], -1)
    if c.shape[1] > PROJECTIONS:
        c = c @ jnp.asarray(projections(c.shape[1]), c.dtype)
    jax.debug.callback(check_contributions, c)


def projections(m: int) -> np.ndarray:
    """``PROJECTIONS`` fixed random directions in ``R^m``, ``(m, PROJECTIONS)``: projected on them, per-path
    contributions keep their squared norms and their sums in expectation."""
    return np.random.default_rng(0).normal(size=(m, PROJECTIONS)) / np.sqrt(PROJECTIONS)


@jax.custom_jvp
def watch_forward(y, contributions_of):
    """``y`` itself; in forward mode, ``contributions_of(y, y_dot)`` (per path, path axis first; linear in
    ``y_dot``) is checked (:func:`_report`).

    ``contributions_of`` is a ``jax.tree_util.Partial``. In reverse mode the check drops out (``jax.debug.callback``
    is dropped when transposed) and the pipeline's :func:`contract` checks instead.
    """
    return y


@watch_forward.defjvp
def _watch_forward_jvp(primals, tangents):
    y, fn = primals
    y_dot = tangents[0]
    _report(fn(y, y_dot))
    return y, y_dot


def watch(tree, message: str):
    """``tree`` itself; differentiating through it warns ``message`` (``SensitivityWarning``), in any mode."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return jax.tree_util.tree_unflatten(treedef, _watched(message, leaves))


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _watched(message, leaves):
    return leaves


@_watched.defjvp
def _watched_jvp(message, primals, tangents):
    warnings.warn(message, SensitivityWarning, stacklevel=2)
    return primals[0], tangents[0]


def tangent_basis(leaves) -> tuple[list, int]:
    """Unit tangents ``(P, *leaf.shape)`` per leaf, one per scalar of the given inexact leaves; and ``P``."""
    sizes = [int(np.size(leaf)) for leaf in leaves]
    total = sum(sizes)
    basis, start = [], 0
    for leaf, size in zip(leaves, sizes, strict=True):
        eye = np.zeros((total, size))
        eye[start : start + size] = np.eye(size)
        basis.append(jnp.asarray(eye.reshape(total, *np.shape(leaf)), jnp.result_type(leaf)))
        start += size
    return basis, total


# ``contract(J, td) = tensordot(J, td)``: J ``(P, N, ...)`` per-path tangents (one row per direction), td
# ``(P, *tail)`` the directions' tangents; out ``(N, ..., *tail)``. Linear in ``td``; its transpose checks the
# per-path contributions.
contract_p = Primitive("jdpim_contract")


def contract(J, td):
    """``sum_p J[p] td[p]`` (see ``contract_p``): per-path tangents from directions' tangents."""
    return contract_p.bind(J, td)


def check_only(J, td):
    """Zeros shaped like ``contract(J, td)``, linear in ``td``: in reverse mode its transpose checks the per-path
    contributions ``<ct_i, J_i>`` of the cotangent ``ct`` against the per-path tangents ``J`` (``(P, N, ...)``),
    and adds nothing to any value or derivative."""
    return contract(J, 0 * td)


def _contract_impl(J, td):
    return jnp.tensordot(J, td, axes=([0], [0]))


contract_p.def_impl(_contract_impl)
contract_p.def_abstract_eval(
    lambda J, td: jax.core.ShapedArray(J.shape[1:] + td.shape[1:], jnp.result_type(J.dtype, td.dtype))
)
mlir.register_lowering(contract_p, mlir.lower_fun(_contract_impl, multiple_results=False))


def _contract_jvp(primals, tangents):
    J, td = primals
    J_dot, td_dot = tangents
    out = contract(J, td)
    parts = []
    if type(J_dot) is not ad.Zero:
        parts.append(contract(J_dot, td))
    if type(td_dot) is not ad.Zero:
        parts.append(contract(J, td_dot))
    if not parts:
        return out, ad.Zero.from_primal_value(out)
    return out, sum(parts[1:], parts[0])


def _contract_transpose(ct, J, td):
    if ad.is_undefined_primal(J):
        raise ValueError("contract is linear in its second argument only")
    shape = td.aval.shape
    if type(ct) is ad.Zero:
        return None, ad.Zero(td.aval)
    p, n = J.shape[0], J.shape[1]
    tail = int(np.prod(shape[1:], dtype=int))
    c = jnp.einsum("pnm,nmt->npt", J.reshape(p, n, -1), ct.reshape(n, -1, tail))
    _report(c)
    return None, jnp.sum(c, axis=0).reshape(shape).astype(td.aval.dtype)


def _contract_batch(args, dims):
    J, td = args
    dJ, dtd = dims
    if dJ is not None:  # batched tangents themselves (vmap over primal values): a plain contraction
        J = jnp.moveaxis(J, dJ, 0)
        td = jnp.moveaxis(td, dtd, 0) if dtd is not None else jnp.broadcast_to(td, (J.shape[0], *td.shape))
        return jax.vmap(_contract_impl)(J, td), 0
    td = jnp.moveaxis(td, dtd, 1)
    return contract(J, td), J.ndim - 1


ad.primitive_jvps[contract_p] = _contract_jvp
ad.primitive_transposes[contract_p] = _contract_transpose
batching.primitive_batchers[contract_p] = _contract_batch
