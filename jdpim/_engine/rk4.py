"""One RK4 step of one path, free or held on a constraint, with the forcing a quadratic through the step's
three nodes; and the local rate that decides sub-stepping."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._constraints import dot
from .elementwise import pick, stored


def forcing(e, tau):
    """Quadratic through ``e[0], e[1], e[2]`` at ``tau = 0, 1/2, 1`` (the three nodes, each ``(m,)`` or ``(n, m)``)."""
    if isinstance(tau, (int, float)) and tau in (0.0, 0.5, 1.0):
        return e[int(2 * tau)]  # the nodes themselves: no interpolation arithmetic in the plain step
    l0 = 2.0 * (tau - 0.5) * (tau - 1.0)
    lm = -4.0 * tau * (tau - 1.0)
    l1 = 2.0 * tau * (tau - 0.5)
    return l0 * e[0] + lm * e[1] + l1 * e[2]


def rk4(model, q, v, e, h, ta=0.0, tb=1.0, store: bool = False):
    """One RK4 step of one path (``q``, ``v``: ``(d,)``) from step fraction ``ta`` to ``tb`` (step length ``h``, s).

    ``store``: with several coordinates, each stage's acceleration is computed once into memory (:func:`stored`). A
    fusion that writes the ``(k, d)`` end state computes the stages for every one of its ``d`` columns otherwise;
    on a batch of a few hundred rows (an impact's steps to and from its crossing) storing them costs less than that,
    on every path's plain step more (measured on the impact damper).
    """
    H = (tb - ta) * h
    tm = 0.5 * (ta + tb)
    once = stored if store and q.shape[0] > 1 else (lambda a: a)

    def f(tau, q, v):
        return v, once(model.state_acceleration(q, v, forcing(e, tau)))

    k1x, k1v = f(ta, q, v)
    k2x, k2v = f(tm, q + 0.5 * H * k1x, v + 0.5 * H * k1v)
    k3x, k3v = f(tm, q + 0.5 * H * k2x, v + 0.5 * H * k2v)
    k4x, k4v = f(tb, q + H * k3x, v + H * k3v)
    return (q + H / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x), v + H / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))


def held_rk4(model, geo, q, v, e, h, ta, tb, k, store: bool = False):
    """RK4 of one path held on constraint ``k`` (``k < 0``: free) from step fraction ``ta`` to ``tb``.

    Held, the path moves on the plane ``c_k = 0`` with ``n_k . v = 0``: every stage's acceleration loses its
    normal part, ``a - (n_k . a) push_k`` (the contact force that keeps ``n_k . a = 0``; for a mass-mass
    contact the pair moves as one body), and the end state is put back onto the plane against rounding.
    Returns ``(q, v, f)``, ``f`` ``(4,)`` the free normal acceleration ``n_k . a`` at the four stages
    (fractions ``ta``, the midpoint twice, ``tb``): the contact holds while it is not positive. ``store``: each
    stage's acceleration computed once into memory, as :func:`rk4` does.
    """
    held = k >= 0
    kk = jnp.maximum(k, 0)
    normal, position, push, onto, unit, keep = (
        pick(a, kk) for a in (geo.normal, geo.position, geo.push, geo.onto, geo.unit, geo.keep)
    )
    H = (tb - ta) * h
    tm = 0.5 * (ta + tb)
    once = stored if store and q.shape[0] > 1 else (lambda a: a)

    def f(tau, q, v):
        a = once(model.state_acceleration(q, v, forcing(e, tau)))
        fn = dot(normal, a)
        return v, jnp.where(held, a - fn * push, a), fn

    k1x, k1v, f1 = f(ta, q, v)
    k2x, k2v, f2 = f(tm, q + 0.5 * H * k1x, v + 0.5 * H * k1v)
    k3x, k3v, f3 = f(tm, q + 0.5 * H * k2x, v + 0.5 * H * k2v)
    k4x, k4v, f4 = f(tb, q + H * k3x, v + H * k3v)
    q_end = q + H / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
    v_end = v + H / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v)
    q_end = jnp.where(held, dot(onto, q_end) + position * unit, q_end)
    v_end = jnp.where(held, dot(keep, v_end), v_end)
    return q_end, v_end, jnp.stack([f1, f2, f3, f4])


def stiffness_rate(model, q, v, xi):
    """``rho = |da/dv| + sqrt(|da/dq|)`` of one path (1/s; infinity norms): bounds the Jacobian's spectral radius."""
    a_q = jax.jacfwd(lambda q: model.state_acceleration(q, v, xi))(q)
    a_v = jax.jacfwd(lambda v: model.state_acceleration(q, v, xi))(v)
    return jnp.max(jnp.sum(jnp.abs(a_v), axis=1)) + jnp.sqrt(jnp.max(jnp.sum(jnp.abs(a_q), axis=1)))
