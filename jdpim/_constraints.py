r"""Unilateral constraints ``c_j(q) = n_j . q - b_j >= 0`` and the generalised Newton impact law.

At an impact on constraint ``j`` the normal velocity ``u = n_j . v`` is reversed and scaled by ``r_j``
while the motion the constraint does not see is kept:

    v+ = v- - (1 + r_j) u M^-1 n_j / (n_j . M^-1 n_j)

(``r_j = 1`` conserves ``v^T M v / 2``; a contact between two masses conserves momentum). A system with
one degree of freedom and a barrier at ``x = b`` is the case ``n = (1,)``, ``M = (1,)``: ``v+ = -r v-``.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np


class Constraints(NamedTuple):
    """The constraints of one path's model, stacked (``J`` constraints, ``d`` coordinates).

    Attributes:
        normal: ``(J, d)`` NumPy array (static): the normals ``n_j``.
        position: ``(J,)``: the offsets ``b_j`` (units of ``q``; may be traced).
        r: ``(J,)``: the restitutions in [0, 1] (may be traced).
        push: ``(J, d)`` NumPy array (static): ``M^-1 n_j / (n_j . M^-1 n_j)``, the velocity change per unit
            change of ``n_j . v``.
    """

    normal: Any
    position: Any
    r: Any
    push: Any


class Geometry(NamedTuple):
    """:class:`Constraints` in the state's dtype with the maps the integrator applies (built once per path).

    ``onto_j = I - n_j n_j^T / |n_j|^2`` and ``unit_j = n_j / |n_j|^2`` put a point on the plane
    ``c_j = 0`` (``onto_j q + b_j unit_j``); ``keep_j = I - push_j n_j^T`` keeps the velocity the constraint
    does not see; ``flip_j = I - 2 n_j n_j^T / |n_j|^2`` mirrors a point through the plane. For one
    coordinate (``n = 1``) these are ``0, 1, 0, -1``: the maps reduce exactly to ``x = b``, ``v = -r v``.
    The maps are NumPy constants (normals and masses are static), so that :func:`dot` drops their zero
    and unit coefficients when it traces.
    """

    normal: Any
    position: Any
    r: Any
    push: Any
    onto: Any
    unit: Any
    keep: Any
    flip: Any


def geometry(constraints: Constraints, dtype) -> Geometry:
    """The integrator's view of ``constraints`` in ``dtype`` (the maps computed in float64, then rounded)."""
    n, push = np.asarray(constraints.normal, np.float64), np.asarray(constraints.push, np.float64)
    eye = np.eye(n.shape[1])[None]
    unit = n / np.sum(n * n, axis=1, keepdims=True)
    outer = n[:, :, None] * unit[:, None, :]
    keep = eye - push[:, :, None] * n[:, None, :]
    b, r = jnp.asarray(constraints.position, dtype), jnp.asarray(constraints.r, dtype)
    maps = (np.asarray(a, dtype) for a in (n, push, eye - outer, unit, keep, eye - 2.0 * outer))
    n, push, onto, unit, keep, flip = maps
    return Geometry(n, b, r, push, onto, unit, keep, flip)


def clearances(normal, position) -> list[tuple[int, int, float]]:
    """``(i, j, width)`` for every pair of opposed constraints (``n_j = -n_i / lambda``, ``lambda > 0``): between
    them ``b_i <= n_i . q <= -lambda b_j``, a slab ``width = -(b_i + lambda b_j)`` wide in ``n_i . q`` (a
    clearance, a backlash: ``2 c`` for ``|x2 - x1| <= c``).

    ``normal`` ``(J, d)`` and ``position`` ``(J,)`` are NumPy arrays (concrete)."""
    size = np.linalg.norm(normal, axis=1)
    unit = normal / size[:, None]
    out = []
    for i, j in zip(*np.triu_indices(len(unit), k=1), strict=True):
        if np.allclose(unit[i], -unit[j], rtol=0.0, atol=1e-12):
            out.append((int(i), int(j), float(-(position[i] + size[i] / size[j] * position[j]))))
    return out


def values(geo: Geometry, q):
    """``c_j(q) = n_j . q - b_j`` for every constraint, ``(J,)``, of one path's coordinates ``q`` ``(d,)``."""
    return dot(geo.normal, q) - geo.position


def dot(a, b):
    """``sum(a * b)`` over the last axis, leading axes broadcast; ``a`` a NumPy constant or an array.

    Written out as multiply-adds for up to 8 terms (elementwise code that XLA fuses with its neighbours; a
    reduction or a tiny ``jnp.dot`` is a kernel of its own). A constant ``a`` whose column is all zeros drops
    that term and one of all ones drops the multiplication, so that one coordinate with the normal ``(1,)``
    traces the scalar arithmetic ``x - b``, ``-r v`` and nothing more.
    """
    if not isinstance(a, np.ndarray):
        a, b = jnp.broadcast_arrays(a, b)
    if a.shape[-1] > 8:
        return jnp.sum(a * b, axis=-1)
    shape = np.broadcast_shapes(np.shape(a), np.shape(b))[:-1]
    out = None
    for i in range(a.shape[-1]):
        if isinstance(a, np.ndarray) and not np.any(a[..., i]):
            continue
        term = b[..., i] if isinstance(a, np.ndarray) and np.all(a[..., i] == 1) else a[..., i] * b[..., i]
        out = term if out is None else out + term
    return jnp.zeros(shape, b.dtype) if out is None else jnp.broadcast_to(out, shape)
