"""Impact location: the step fraction at which a path's step first crosses a constraint."""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._constraints import dot, geometry, values
from .elementwise import pick, stored
from .rk4 import rk4
from .settings import ImpactRule


def locate_crossing(x0, v0, x1, v1, H, n_iter, on_barrier=None):
    """Root ``s`` in [0, 1] of the cubic Hermite interpolant of ``c = x - b`` over a step of length ``H``.

    ``x0 >= 0 > x1`` are the constraint's values ``c`` at the ends, ``v0``, ``v1`` their rates ``dc/dt``;
    ``on_barrier`` marks steps that start on the constraint (default ``x0 == 0``).
    """
    a0, a1, b0, b1 = x0, x1, H * v0, H * v1

    def p(s):
        s2, s3 = s * s, s * s * s
        return (2 * s3 - 3 * s2 + 1) * a0 + (s3 - 2 * s2 + s) * b0 + (3 * s2 - 2 * s3) * a1 + (s3 - s2) * b1

    def dp(s):
        s2 = s * s
        return (6 * s2 - 6 * s) * (a0 - a1) + (3 * s2 - 4 * s + 1) * b0 + (3 * s2 - 2 * s) * b1

    # A step that starts on the barrier (after an impact or a departure) must step past the root p(0) = 0:
    # it seeks the root of the deflated quadratic q(s) = p(s) / s (q(0) = b0 >= 0 > q(1) = a1), from its
    # closed-form root; the iterations then only polish it.
    on_barrier = a0 == 0 if on_barrier is None else on_barrier
    c0, c1, c2 = b0, 3 * a1 - 2 * b0 - b1, b0 - 2 * a1 + b1

    def f(s):
        return jnp.where(on_barrier, c0 + s * (c1 + s * c2), p(s))

    def df(s):
        return jnp.where(on_barrier, c1 + 2 * s * c2, dp(s))

    lo, hi = jnp.zeros_like(x0), jnp.ones_like(x0)
    # Starting points carry no derivative (the iterations and the final Newton step give it): the secant's
    # derivative divides by (a0 - a1)^2, which underflows where a step ends a rounding error beyond the
    # constraint it starts on, and reverse mode would then multiply 0 by it (nan).
    guess = jnp.clip(a0 / (a0 - a1), 0.0, 1.0)
    s = jax.lax.stop_gradient(jnp.where(on_barrier, deflated_root(c0, c1, c2, a1), guess))
    for _ in range(n_iter):
        ps = f(s)
        pos = ps >= 0
        lo, hi = jnp.where(pos, s, lo), jnp.where(pos, hi, s)
        d = df(s)
        sn = s - ps / jnp.where(d == 0, 1.0, d)
        # a converged s (its step rounds to zero) stays, but not s = 0: a step from the barrier seeks the next root
        s = stored(jnp.where(((sn > lo) & (sn < hi)) | ((sn == s) & (s > 0)), sn, 0.5 * (lo + hi)))
    d = dp(s)
    s = s - p(s) / jnp.where(d == 0, 1.0, d)  # plain Newton step: derivative by the implicit function theorem
    return jnp.clip(s, 0.0, 1.0)


def deflated_root(c0, c1, c2, q1):
    """Root in ``(0, 1)`` of ``q(s) = c0 + c1 s + c2 s^2``, where ``q(0) = c0 >= 0 > q(1) = q1`` (stable formula)."""
    disc = c1 * c1 - 4.0 * c2 * c0
    t = -0.5 * (c1 + jnp.where(c1 < 0, -1.0, 1.0) * jnp.sqrt(jnp.maximum(disc, 0.0)))
    roots = jnp.stack([t / jnp.where(c2 == 0, 1.0, c2), c0 / jnp.where(t == 0, 1.0, t)])
    ok = jnp.stack([c2 != 0, t != 0]) & (roots > 0) & (roots < 1)
    fallback = c0 / jnp.where(c0 - q1 == 0, 1.0, c0 - q1)  # the secant of q over [0, 1]
    return jnp.where(jnp.any(ok, axis=0), jnp.min(jnp.where(ok, roots, 2.0), axis=0), fallback)


def crossing_time(rule: ImpactRule, h, y0, tau0, y1, last, geo, held=None):
    """``(hit, j, theta)`` of one path's step ``y0`` (at ``tau0``) -> ``y1``: whether a constraint is violated at
    the end (other than ``held``, the one the path is held on), the one crossed first and the step fraction of
    its crossing, located on the cubic Hermite interpolant of ``c_j``."""
    (q0, v0), (q1, v1) = y0, y1
    c0, c1 = values(geo, q0), values(geo, q1)
    crossing = c1 < 0
    if held is not None:
        crossing = crossing & (jnp.arange(c1.shape[0]) != held)
    one = c0.shape[0] == 1  # one constraint: no reductions over constraints (each one a kernel of its own in XLA)
    hit = crossing[0] if one else jnp.any(crossing)
    # Constraints without a crossing get harmless stand-in values, so that no NaN reaches a derivative.
    rc0 = jnp.where(crossing, c0, 1.0)
    rc1 = jnp.where(crossing, c1, -1.0)
    on = crossing & ((c0 == 0) | (jnp.arange(c0.shape[0]) == last))
    span = jnp.where(crossing, (1.0 - tau0) * h, h)
    s_all = locate_crossing(rc0, dot(geo.normal, v0), rc1, dot(geo.normal, v1), span, rule.newton_iterations, on)
    if one:  # a constant: nothing to store
        j = jnp.zeros((), jnp.int32)
    else:
        j = stored(jnp.argmin(jnp.where(crossing, s_all, 2.0)).astype(jnp.int32))
    return hit, j, stored(tau0 + pick(s_all, j) * (1.0 - tau0))


def first_crossing(model, rule: ImpactRule, h, y0, tau0, y1, last, e):
    """The first constraint crossed in ``[tau0, 1]`` of a step of one path whose end ``y1`` violates one.

    Returns ``(geometry, hit, j, theta, (q, v))``: the constraints' geometry, whether any is violated at the end,
    the index of the one crossed first, the step fraction of its crossing (located on the cubic Hermite
    interpolant of ``c_j``) and the state there (RK4 from ``y0`` at ``tau0``), before the impact.
    """
    geo = geometry(model.stacked_constraints(), y0[0].dtype)
    hit, j, theta = crossing_time(rule, h, y0, tau0, y1, last, geo)
    return geo, hit, j, theta, tuple(map(stored, rk4(model, *y0, e, h, tau0, theta, store=True)))
