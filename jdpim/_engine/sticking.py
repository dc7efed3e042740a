"""Sticking: whether a path rests or is held on a constraint, and the fraction of the step at which the force
pulls it off."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._constraints import dot, values


def lets_go(held, f):
    """Whether a path held on a constraint (``held >= 0``) lets go inside its held step: the free normal acceleration
    ``f`` ``(4,)`` at the step's stages (:func:`held_rk4`) is positive at the midpoint or the end."""
    return (held >= 0) & ((0.5 * (f[1] + f[2]) > 0) | (f[3] > 0))


def resting_on(geo, q, v):
    """``(J,)`` bool: the constraints on whose plane one path lies with no normal speed, to rounding
    (``|c_j|`` and ``|n_j . v|`` within 16 ulp of their terms' sizes)."""
    tol = 16.0 * jnp.finfo(q.dtype).eps
    absn = np.abs(geo.normal)
    near = jnp.abs(values(geo, q)) <= tol * (jnp.abs(geo.position) + dot(absn, jnp.abs(q)))
    return near & (jnp.abs(dot(geo.normal, v)) <= tol * dot(absn, jnp.abs(v)))


def held_constraint(model, geo, q, v, e0, hold):
    """The constraint one path starts a step held on: the first of those it may be held on (``hold``, ``(J,)``
    bool) that it rests on (:func:`resting_on`) and whose free normal acceleration under the forcing ``e0``
    presses into it (``n_j . a <= 0``); -1 for none."""
    pressed = hold & resting_on(geo, q, v) & (dot(geo.normal, model.state_acceleration(q, v, e0)) <= 0)
    return jnp.where(jnp.any(pressed), jnp.argmax(pressed), -1).astype(jnp.int32)


def _bracketed_newton(q, dq, lo, hi, n_iter):
    """Root of ``q`` in ``[lo, hi]`` where ``q(lo) <= 0 < q(hi)`` and ``q`` is monotone: regula falsi, then Newton."""
    qlo, qhi = q(lo), q(hi)
    s = lo + (hi - lo) * jnp.clip(-qlo / jnp.where(qhi > qlo, qhi - qlo, 1.0), 0.0, 1.0)
    for _ in range(n_iter):
        d = dq(s)
        sn = s - q(s) / jnp.where(d == 0, 1.0, d)
        s = jnp.clip(sn, lo, hi)
    return s


def departure(model, e, tau0, normal, q_rest, n_iter=5):
    """First fraction in ``[tau0, 1]`` of the step where a path at rest at ``q_rest`` is pulled off; 1 if never.

    One degree of freedom: the force along the constraint's normal at rest, ``F(tau) = n a(q_rest, 0, xi(tau))``,
    is affine in ``xi`` and so exactly the quadratic through its values at ``tau = 0, 1/2, 1``; the path
    leaves at the first ``tau`` with ``F(tau) > 0``.
    """
    rest = jnp.zeros_like(q_rest)
    f = jnp.stack([dot(normal, model.state_acceleration(q_rest, rest, e[i])) for i in range(3)])
    return turns_positive(f, tau0, n_iter)


def turns_positive(f, tau0, n_iter=5):
    """First ``tau`` in ``[tau0, 1]`` where the quadratic through ``f[0], f[1], f[2]`` at ``tau = 0, 1/2, 1`` is
    positive; 1 if never (``tau0`` if it is positive there)."""
    c0, c1, c2 = f[0], -3.0 * f[0] + 4.0 * f[1] - f[2], 2.0 * f[0] - 4.0 * f[1] + 2.0 * f[2]

    def q(tau):
        return c0 + tau * (c1 + tau * c2)

    def dq(tau):
        return c1 + 2.0 * tau * c2

    # split [tau0, 1] at the extremum m of F into two monotone pieces
    m = jnp.where(c2 != 0, jnp.clip(-0.5 * c1 / jnp.where(c2 == 0, 1.0, c2), tau0, 1.0), tau0)
    in_first = q(m) > 0
    lo, hi = jnp.where(in_first, tau0, m), jnp.where(in_first, m, 1.0)
    root = _bracketed_newton(q, dq, lo, hi, n_iter)
    return jnp.where(q(tau0) > 0, tau0, jnp.where(in_first | (q(1.0) > 0), root, 1.0))
