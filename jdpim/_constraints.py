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


class Constraints(NamedTuple):
    """The constraints of one path's model, stacked (``J`` constraints, ``d`` coordinates).

    Attributes:
        normal: ``(J, d)``: the normals ``n_j``.
        position: ``(J,)``: the offsets ``b_j`` (units of ``q``).
        r: ``(J,)``: the restitutions in [0, 1].
        push: ``(J, d)``: ``M^-1 n_j / (n_j . M^-1 n_j)``, the velocity change per unit change of ``n_j . v``.
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
    """The integrator's view of ``constraints`` in ``dtype``."""
    n, b, r, push = (jnp.asarray(a, dtype) for a in constraints)
    eye = jnp.eye(n.shape[1], dtype=dtype)[None]
    unit = n / jnp.sum(n * n, axis=1, keepdims=True)
    outer = n[:, :, None] * unit[:, None, :]
    keep = eye - push[:, :, None] * n[:, None, :]
    return Geometry(n, b, r, push, eye - outer, unit, keep, eye - 2.0 * outer)


def values(geo: Geometry, q):
    """``c_j(q) = n_j . q - b_j`` for every constraint, ``(J,)``, of one path's coordinates ``q`` ``(d,)``."""
    return dot(geo.normal, q) - geo.position


def dot(a, b):
    """``sum(a * b)`` over the last axis, leading axes broadcast (fused by XLA; a tiny ``jnp.dot`` is a call)."""
    a, b = jnp.broadcast_arrays(a, b)
    return jnp.sum(a * b, axis=-1)
