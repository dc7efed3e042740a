r"""Batched RK4 over time with impacts located inside the step, on state vectors ``(q, v)`` with constraints.

Every step of every path is one classical RK4 step ``t_n -> t_n + h`` whose forcing is the quadratic
through the excitation at ``t_n``, ``t_n + h/2`` and ``t_n + h`` (exactly RK4's stage values). A path's
state is ``q``, ``v`` of shape ``(d,)``; its model's unilateral constraints ``c_j(q) = n_j . q - b_j >= 0``
(one for a single-degree-of-freedom oscillator with a barrier: ``x - b >= 0``) are stacked by
:mod:`._constraints`. Where the step ends with a constraint violated the impact is located and resolved:

1. ``s``: root of the cubic Hermite interpolant of each violated ``c_j`` (its values and rates at both ends),
   by a bracketed Newton iteration with a fixed number of steps and one final plain Newton step (so that
   derivatives follow the implicit function theorem and carry the event-time shift: the saltation
   matrix); the constraint crossed first is resolved;
2. redo the step as ``RK4(s h)`` -> impact (``q`` onto ``c_j = 0``, the generalised Newton law
   ``v+ = v- - (1 + r_j) (n_j . v-) M^-1 n_j / (n_j . M^-1 n_j)``; ``x = b``, ``v = -r v`` for one
   coordinate) -> ``RK4((1 - s) h)``;
3. repeat for up to ``max_impacts`` impacts in one step, then fall back to a mirror through every violated
   constraint (``c -> -c``, ``n . v -> -r n . v``), so that no stored state violates a constraint;
4. sticking (one degree of freedom): when the outgoing speed ``r |v_-|`` is below ``stick_velocity`` and
   the force at ``(b, 0)`` pushes into the barrier, the path rests at ``(b, 0)`` until the force (a
   quadratic in the step fraction) turns outward; that departure time is located inside the step, and a
   path that starts a step at rest with an inward force waits for it too. This holds for every ``r``
   (with ``r = 1`` a path pressed against the barrier at rest makes bounces of zero height: it rests too).
   Several degrees of freedom (on the constraints ``ImpactRule.hold`` allows): after such an impact the path
   is held on the constraint, ``n_j . q = b_j`` and ``n_j . v = 0``, and slides along it with the normal part
   of its acceleration taken out (:func:`held_rk4`) until the free normal acceleration turns outward; that
   departure is located inside the step on the quadratic through the held step's stage values. A held
   path that lets go or crosses another constraint inside a step is served with the crossing paths.
5. stiffness: a path whose local rate ``rho = |da/dv| + sqrt(|da/dq|)`` at the start of a step, or at
   the end of its full step, exceeds ``limit / h`` redoes that step as
   ``k = min(max_substeps, ceil(h rho / limit))`` equal sub-steps of its own (see :class:`Substeps`).

Only the crossing paths do the impact work, in batches of up to ``ceil(n / 64)`` paths gathered in one
piece, each path's impacts resolved on the batch's small arrays and scattered back (see
``resolve_crossings`` in :func:`make_batch_step`); the loops have static trip counts and skip their
iterations (``lax.cond``) once no path is pending, so the resolution is traced once whatever
``max_impacts``, and a step without any crossing skips all of it. Chunks of ``WIDE_CHUNK`` paths or more
resolve a first batch of up to ``n / 16`` crossing paths: an accelerator's (where every branch costs a read by
the host) in every step without branches, a CPU's in the steps where more than ``n / 128`` paths cross. The
``"mirror"`` method is the first-order "flip after the step" rule, kept for comparison.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import itertools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._constraints import dot, geometry, values
from ._cpu import on_cpu
from ._excitation import AbstractNodes, ArrayNodes
from ._pytree import check_int, check_real


@dataclasses.dataclass(frozen=True)
class ImpactRule:
    """How impacts are resolved (static settings).

    Args:
        method: ``"locate"`` (fourth order: impact time located inside the step) or ``"mirror"``
            (first order: reflect the end-of-step state).
        max_impacts: located impacts per path and step (>= 1) before the mirror fallback.
        stick_velocity: outgoing speed (units of x per s, >= 0) below which a path whose net force
            points into the barrier sticks to it; 0 disables sticking.
        newton_iterations: bracketed Newton steps used to locate the impact (>= 1).
        mirror_below: normal speed (units of x per s, >= 0) below which a crossing is mirrored instead of
            located (``"locate"`` only): the speed ``|n . v|`` at both ends of the step is below it. The slow
            impacts of chattering then cost a plain step; each one's position error is at most about
            ``mirror_below * dt``. Sticking needs located impacts, so a path pressed against a constraint
            bounces in place instead of resting where ``mirror_below`` exceeds ``stick_velocity / r``. 0 (the
            default) locates every impact.
        hold: sticking per constraint for several degrees of freedom (one degree of freedom always sticks
            below ``stick_velocity``): whether a path may be held on a constraint after an impact slower than
            ``stick_velocity`` and slide along it until the free normal acceleration turns outward, one bool
            for every constraint or one per constraint. ``None`` (the default) lets the scene decide:
            constraints whose normal acceleration the white noise reaches (``n_j . M^-1 B != 0``) are not
            held, because there the contact force changes sign within every step and holding only adds
            departures to the impacts; the others (a structure driven through a filter, by a harmonic
            force, or not at all) are.
    """

    method: str = "locate"
    max_impacts: int = 2
    stick_velocity: float = 1e-3
    newton_iterations: int = 4
    mirror_below: float = 0.0
    hold: bool | tuple[bool, ...] | None = None
    scene_hold: tuple[bool, ...] | None = dataclasses.field(default=None, repr=False)  # set by the scene

    def __post_init__(self):
        if self.method not in ("locate", "mirror"):
            raise ValueError(f"method must be 'locate' or 'mirror', got {self.method!r}")
        check_int("max_impacts", self.max_impacts, low=1)
        check_int("newton_iterations", self.newton_iterations, low=1)
        check_real("stick_velocity", self.stick_velocity, low=0.0)
        check_real("mirror_below", self.mirror_below, low=0.0)
        if isinstance(self.hold, list):
            object.__setattr__(self, "hold", tuple(self.hold))
        flags = self.hold if isinstance(self.hold, tuple) else (self.hold,)
        if self.hold is not None and not (flags and all(isinstance(f, (bool, np.bool_)) for f in flags)):
            raise TypeError(f"hold must be None, a bool or a tuple of bools (one per constraint), got {self.hold!r}")
        if isinstance(self.hold, tuple):
            object.__setattr__(self, "hold", tuple(bool(f) for f in self.hold))

    def held(self, n_constraints: int) -> np.ndarray:
        """``(J,)`` bool: the constraints a path may be held on: ``hold``, or where it is ``None`` the scene's
        decision (none without one)."""
        if isinstance(self.hold, tuple):
            if len(self.hold) != n_constraints:
                raise ValueError(f"hold has {len(self.hold)} entries; the model has {n_constraints} constraints")
            return np.asarray(self.hold, bool)
        if self.hold is None and self.scene_hold is not None and len(self.scene_hold) == n_constraints:
            return np.asarray(self.scene_hold, bool)
        return np.full(n_constraints, bool(self.hold))


@dataclasses.dataclass(frozen=True)
class Substeps:
    r"""Sub-stepping of stiff steps (static settings).

    RK4 is stable on the real axis for ``h |lambda| < 2.785``; cubic damping ``gamma v^3`` has the rate
    ``|da/dv| = alpha + 3 gamma v^2``, which large velocities push past that. A path takes a step as
    ``k = min(max_substeps, ceil(h rho / limit))`` equal sub-steps of its own (the forcing quadratic
    resampled on each sub-interval) when the local rate ``rho = |da/dv| + sqrt(|da/dx|)`` at the start
    of the step, or at the end of its full step (a trial every path takes first), calls for it; a
    trial that blew up asks for ``max_substeps``. Each path's ``k`` is its own, so its result does not
    depend on which paths share its batch (chunk size, devices). The sub-steps run inside a
    ``fori_loop`` of ``max_substeps + 1`` iterations (static trip count, so reverse-mode AD works)
    whose iterations past the largest ``k`` are skipped; paths with fewer sub-steps idle in them. A
    step without a stiff path costs the trial and two rate evaluations per path. Paths still unstable
    at ``max_substeps`` blow up and are counted (``Result.n_nonfinite``), never hidden.

    ``limit`` trades accuracy for time: ``h rho`` near RK4's stability bound (2.785) is stable but
    inaccurate (RK4 damps a mode with ``h lambda = -2`` by 0.33 instead of ``e^-2 = 0.14``). The default
    0.5 keeps the error of the fastest mode per step below 1e-3; measured figures are in the hard-cases
    documentation.

    Args:
        max_substeps: largest number of sub-steps per step (>= 1); 1 disables sub-stepping. It is
            traced only for models that can be stiff (``model.may_be_stiff``), and only when the scene
            asks for it (``Scene(..., substeps=Substeps())``; the default ``None`` costs nothing).
        limit: target ``h rho`` per sub-step, in (0, 2.785).
    """

    max_substeps: int = 16
    limit: float = 0.5

    def __post_init__(self):
        check_int("max_substeps", self.max_substeps, low=1)
        check_real("limit", self.limit, low=0.0, high=2.785, low_open=True, high_open=True)


def _forcing(e, tau):
    """Quadratic through ``e[0], e[1], e[2]`` at ``tau = 0, 1/2, 1`` (the three nodes, each ``(m,)`` or ``(n, m)``)."""
    if isinstance(tau, (int, float)) and tau in (0.0, 0.5, 1.0):
        return e[int(2 * tau)]  # the nodes themselves: no interpolation arithmetic in the plain step
    l0 = 2.0 * (tau - 0.5) * (tau - 1.0)
    lm = -4.0 * tau * (tau - 1.0)
    l1 = 2.0 * tau * (tau - 0.5)
    return l0 * e[0] + lm * e[1] + l1 * e[2]


def rk4(model, q, v, e, h, ta=0.0, tb=1.0):
    """One RK4 step of one path (``q``, ``v``: ``(d,)``) from step fraction ``ta`` to ``tb`` (step length ``h``, s)."""
    H = (tb - ta) * h
    tm = 0.5 * (ta + tb)

    def f(tau, q, v):
        return v, model.state_acceleration(q, v, _forcing(e, tau))

    k1x, k1v = f(ta, q, v)
    k2x, k2v = f(tm, q + 0.5 * H * k1x, v + 0.5 * H * k1v)
    k3x, k3v = f(tm, q + 0.5 * H * k2x, v + 0.5 * H * k2v)
    k4x, k4v = f(tb, q + H * k3x, v + H * k3v)
    return (q + H / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x), v + H / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))


def held_rk4(model, geo, q, v, e, h, ta, tb, k):
    """RK4 of one path held on constraint ``k`` (``k < 0``: free) from step fraction ``ta`` to ``tb``.

    Held, the path moves on the plane ``c_k = 0`` with ``n_k . v = 0``: every stage's acceleration loses its
    normal part, ``a - (n_k . a) push_k`` (the contact force that keeps ``n_k . a = 0``; for a mass-mass
    contact the pair moves as one body), and the end state is put back onto the plane against rounding.
    Returns ``(q, v, f)``, ``f`` ``(4,)`` the free normal acceleration ``n_k . a`` at the four stages
    (fractions ``ta``, the midpoint twice, ``tb``): the contact holds while it is not positive.
    """
    held = k >= 0
    kk = jnp.maximum(k, 0)
    normal, position, push, onto, unit, keep = (
        _pick(a, kk) for a in (geo.normal, geo.position, geo.push, geo.onto, geo.unit, geo.keep)
    )
    H = (tb - ta) * h
    tm = 0.5 * (ta + tb)

    def f(tau, q, v):
        a = model.state_acceleration(q, v, _forcing(e, tau))
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


@jax.custom_jvp
def _stored(x):
    """``x`` itself, computed once into memory on a CPU (tangents pass through unchanged).

    XLA's CPU loop fusion computes an elementwise value again inside the loop of every fusion that uses it (and
    for every column of a ``(k, d)`` consumer), so the chains of a resolution (Newton iterations, the crossing
    time, the RK4 redo) are recomputed many times over. A reduction is not fused into its consumers: the exact
    ``max(x, lowest)`` over a stacked pair stores ``x`` (``jax.lax.optimization_barrier`` does not: the CPU compiler
    removes it before fusing). Elsewhere
    (accelerators, unmeasured) ``x`` is returned.
    """
    if not on_cpu():
        return x
    low = -jnp.inf if jnp.issubdtype(x.dtype, jnp.floating) else jnp.iinfo(x.dtype).min
    return jnp.max(jnp.stack([x, jnp.full_like(x, low)]), axis=0)


@_stored.defjvp
def _stored_jvp(primals, tangents):
    return _stored(primals[0]), tangents[0]


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
    s = jax.lax.stop_gradient(jnp.where(on_barrier, _deflated_root(c0, c1, c2, a1), guess))
    for _ in range(n_iter):
        ps = f(s)
        pos = ps >= 0
        lo, hi = jnp.where(pos, s, lo), jnp.where(pos, hi, s)
        d = df(s)
        sn = s - ps / jnp.where(d == 0, 1.0, d)
        # a converged s (its step rounds to zero) stays, but not s = 0: a step from the barrier seeks the next root
        s = _stored(jnp.where(((sn > lo) & (sn < hi)) | ((sn == s) & (s > 0)), sn, 0.5 * (lo + hi)))
    d = dp(s)
    s = s - p(s) / jnp.where(d == 0, 1.0, d)  # plain Newton step: derivative by the implicit function theorem
    return jnp.clip(s, 0.0, 1.0)


def _deflated_root(c0, c1, c2, q1):
    """Root in ``(0, 1)`` of ``q(s) = c0 + c1 s + c2 s^2``, where ``q(0) = c0 >= 0 > q(1) = q1`` (stable formula)."""
    disc = c1 * c1 - 4.0 * c2 * c0
    t = -0.5 * (c1 + jnp.where(c1 < 0, -1.0, 1.0) * jnp.sqrt(jnp.maximum(disc, 0.0)))
    roots = jnp.stack([t / jnp.where(c2 == 0, 1.0, c2), c0 / jnp.where(t == 0, 1.0, t)])
    ok = jnp.stack([c2 != 0, t != 0]) & (roots > 0) & (roots < 1)
    fallback = c0 / jnp.where(c0 - q1 == 0, 1.0, c0 - q1)  # the secant of q over [0, 1]
    return jnp.where(jnp.any(ok, axis=0), jnp.min(jnp.where(ok, roots, 2.0), axis=0), fallback)


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


def _crossing_time(rule: ImpactRule, h, y0, tau0, y1, last, geo, held=None):
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
    j = jnp.zeros((), jnp.int32) if one else jnp.argmin(jnp.where(crossing, s_all, 2.0)).astype(jnp.int32)
    return hit, _stored(j), _stored(tau0 + _pick(s_all, j) * (1.0 - tau0))


def first_crossing(model, rule: ImpactRule, h, y0, tau0, y1, last, e):
    """The first constraint crossed in ``[tau0, 1]`` of a step of one path whose end ``y1`` violates one.

    Returns ``(geometry, hit, j, theta, (q, v))``: the constraints' geometry, whether any is violated at the end,
    the index of the one crossed first, the step fraction of its crossing (located on the cubic Hermite
    interpolant of ``c_j``) and the state there (RK4 from ``y0`` at ``tau0``), before the impact.
    """
    geo = geometry(model.stacked_constraints(), y0[0].dtype)
    hit, j, theta = _crossing_time(rule, h, y0, tau0, y1, last, geo)
    return geo, hit, j, theta, tuple(map(_stored, rk4(model, *y0, e, h, tau0, theta)))


def _resolve_one(model, rule: ImpactRule, h, y0, tau0, y1, last, e):
    """Resolve the first impact of one path inside ``[tau0, 1]`` of the step, where ``y1`` violates a constraint.

    ``y0 = (q, v)`` at ``tau0``, ``y1`` at the step's end, ``last`` the constraint resolved last in this step
    (-1 for none). Of the violated constraints the one crossed first is located and resolved (the others,
    if still violated, by the next calls). Returns the new ``(y0, tau0, y1, last)``.
    """
    (q0, v0), (q1, v1) = y0, y1
    geo, hit, j, theta, (qc, vc) = first_crossing(model, rule, h, y0, tau0, y1, last, e)
    normal, position, r, push, onto, unit, keep, _ = (_pick(a, j) for a in geo)
    q_plus = dot(onto, qc) + position * unit  # on the plane c_j = 0
    v_plus = dot(keep, vc) + r * jnp.abs(dot(normal, vc)) * push  # generalised Newton law
    q_plus, v_plus = _stored(q_plus), _stored(v_plus)
    qr, vr = rk4(model, q_plus, v_plus, e, h, theta, 1.0)
    if rule.stick_velocity > 0 and q0.shape[0] == 1:  # one degree of freedom: rest on the constraint
        rest = jnp.zeros_like(v0)
        pushes_in = dot(normal, model.state_acceleration(q_plus, rest, _forcing(e, theta))) <= 0
        stick = (r * jnp.abs(dot(normal, vc)) < rule.stick_velocity) & pushes_in
        tau_d = _stored(departure(model, e, theta, normal, q_plus))  # rest at (q_plus, 0) until the force pulls away
        qd, vd = rk4(model, q_plus, rest, e, h, tau_d, 1.0)
        qr, vr = jnp.where(stick, qd, qr), jnp.where(stick, vd, vr)
        v_plus, theta = jnp.where(stick, rest, v_plus), jnp.where(stick, tau_d, theta)
    new_y0 = (jnp.where(hit, q_plus, q0), jnp.where(hit, v_plus, v0))
    new_y1 = (jnp.where(hit, qr, q1), jnp.where(hit, vr, v1))
    return new_y0, jnp.where(hit, theta, tau0), new_y1, jnp.where(hit, j, last)


def _resolve_held(model, rule: ImpactRule, h, y0, tau0, y1, force, last, held, located, e, hold):
    """The next event of one path inside ``[tau0, 1]`` of the step, with sticking per constraint (several degrees
    of freedom): a departure from the constraint ``held`` (-1 for none) or the first crossing of another.

    ``y1`` is the end of the step from ``y0`` at ``tau0`` (held on ``held`` where it is one) and ``force`` ``(4,)``
    that step's free normal acceleration at its stages (:func:`held_rk4`). A held path departs where the free
    normal acceleration ``n . a`` turns positive: the first positive point of the quadratic through its stage
    values (start, midpoint, end); it then moves freely from there. A crossing (where ``located``, see
    ``mirror_below``) is resolved by the generalised Newton law, or, where the outgoing normal speed ``r |u|``
    is below ``stick_velocity`` and the free acceleration at the contact presses into it, by holding the path
    on the constraint (normal speed zero) from the impact on (where ``hold``, ``(J,)`` bool, allows it). The
    step is redone to the event (held as before) and from it (held or free as after). Returns the new
    ``(y0, tau0, y1, force, last, held, pending)``, ``pending`` whether the rest of the step may hold another
    event.
    """
    (q0, v0), (q1, v1) = y0, y1
    geo = geometry(model.stacked_constraints(), q0.dtype)
    hit, j, theta = _crossing_time(rule, h, y0, tau0, y1, last, geo, held)
    hit = hit & located
    s_off = _stored(turns_positive(jnp.stack([force[0], 0.5 * (force[1] + force[2]), force[3]]), 0.0))
    tau_off = tau0 + s_off * (1.0 - tau0)
    off_first = (held >= 0) & (s_off < 1) & (~hit | (tau_off <= theta))
    event = off_first | hit
    tau_e = _stored(jnp.where(off_first, tau_off, jnp.where(hit, theta, 1.0)))
    q_e, v_e = map(_stored, held_rk4(model, geo, q0, v0, e, h, tau0, tau_e, held)[:2])
    # the impact on j at theta: a bounce, or held from theta on
    normal, position, r, push, onto, unit, keep, _ = (_pick(a, j) for a in geo)
    q_plus = dot(onto, q_e) + position * unit
    u = dot(normal, v_e)
    v_slide = dot(keep, v_e)
    pressed = dot(normal, model.state_acceleration(q_plus, v_slide, _forcing(e, tau_e))) <= 0
    stick = (r * jnp.abs(u) < rule.stick_velocity) & pressed & (_pick(hold, j) > 0)
    impact = hit & ~off_first
    q_a = jnp.where(impact, q_plus, q_e)
    v_a = jnp.where(impact, jnp.where(stick, v_slide, v_slide + r * jnp.abs(u) * push), v_e)
    q_a, v_a = _stored(q_a), _stored(v_a)
    held_after = jnp.where(impact & stick, j, -1).astype(jnp.int32)
    q_end, v_end, f_end = held_rk4(model, geo, q_a, v_a, e, h, tau_e, 1.0, held_after)

    def choose(new, old):
        return jnp.where(event, new, old)

    pending = event & ((held_after < 0) | lets_go(held_after, f_end))
    return (
        (choose(q_a, q0), choose(v_a, v0)),
        choose(tau_e, tau0),
        (choose(q_end, q1), choose(v_end, v1)),
        choose(f_end, force),
        jnp.where(off_first, held, jnp.where(hit, j, last)),
        choose(held_after, held),
        pending,
    )


def _pick(a, j):
    """``a[j]`` for a traced ``j``: a masked sum (elementwise for XLA, where a gather per path is slow); ``a[0]``
    when there is one constraint."""
    if a.shape[0] == 1:
        return a[0]
    mask = jnp.reshape(jnp.arange(a.shape[0]) == j, (-1,) + (1,) * (a.ndim - 1))
    return jnp.sum(jnp.where(mask, a, 0), axis=0)


def _mirror(model, q, v):
    """Reflect ``(q, v)`` through every constraint it violates (in order): ``c -> -c``, ``u -> -r u``."""
    geo = geometry(model.stacked_constraints(), q.dtype)
    for j in range(geo.normal.shape[0]):
        beyond = dot(geo.normal[j], q) - geo.position[j] < 0
        q_new = dot(geo.flip[j], q) + 2.0 * geo.position[j] * geo.unit[j]
        v_new = dot(geo.keep[j], v) - geo.r[j] * dot(geo.normal[j], v) * geo.push[j]
        q, v = jnp.where(beyond, q_new, q), jnp.where(beyond, v_new, v)
    return q, v


# chunks of at least this many paths resolve their crossings in a wide batch first, of a WIDE_SHARE-th of the
# paths: an accelerator's chunks in every step, without branches; a CPU's (where default_chunk_size makes them so)
# in the steps where more than a CROWDED_AT-th of the paths cross, the others by the lanes (docs/mdof.md)
WIDE_CHUNK = 8192
WIDE_SHARE = 16
CROWDED_AT = 128
# a batch of more rows than this has a multiple of them: XLA's CPU code for a batch of an odd number of rows is
# markedly slower per step
BATCH_ROWS = 8


def branch_free(n: int) -> bool:
    """Whether a chunk of ``n`` paths resolves its crossings without branches: a wide chunk on an accelerator."""
    return n >= WIDE_CHUNK and not on_cpu()


def batch_rows(n: int, wide: bool) -> int:
    """Rows of one resolution batch in a chunk of ``n`` paths: ``ceil(n / 64)``, or ``ceil(n / WIDE_SHARE)`` in a
    wide chunk, rounded up to a multiple of ``BATCH_ROWS`` above it (XLA's CPU code is markedly slower per step
    for batches of an odd number of rows)."""
    cap = -(-n // WIDE_SHARE) if wide else max(1, -(-n // 64))
    return min(n, -(-cap // BATCH_ROWS) * BATCH_ROWS) if cap > BATCH_ROWS else cap


def first_in_lanes(mask, lanes: int):
    """Index of the first true entry of ``mask`` (``(n,)`` bool) in each of ``lanes`` runs of it, ``n`` if none.

    Lane ``l`` covers the entries ``l G .. (l + 1) G - 1``, ``G = ceil(n / lanes)``: one reduction, where
    ``jnp.nonzero(mask, size=lanes)`` takes two cumulative sums and a scatter (4.5 us against 0.5 us for
    500 entries on a CPU).
    """
    n = mask.shape[0]
    group = -(-n // lanes)
    runs = jnp.pad(mask, (0, lanes * group - n)).reshape(lanes, group)
    return jnp.where(jnp.any(runs, axis=1), jnp.arange(lanes) * group + jnp.argmax(runs, axis=1), n)


def stiffness_rate(model, q, v, xi):
    """``rho = |da/dv| + sqrt(|da/dq|)`` of one path (1/s; infinity norms): bounds the Jacobian's spectral radius."""
    a_q = jax.jacfwd(lambda q: model.state_acceleration(q, v, xi))(q)
    a_v = jax.jacfwd(lambda v: model.state_acceleration(q, v, xi))(v)
    return jnp.max(jnp.sum(jnp.abs(a_v), axis=1)) + jnp.sqrt(jnp.max(jnp.sum(jnp.abs(a_q), axis=1)))


def _paths(mask, a):
    """``mask`` ``(n,)`` broadcast against the per-path array ``a`` ``(n, ...)``."""
    return jnp.reshape(mask, mask.shape + (1,) * (a.ndim - 1))


def make_batch_step(path_model, rule: ImpactRule, h, substeps: Substeps | None = None):
    """The step for a batch of paths: ``(q, v, e, rand) -> (q, v)``, ``q`` and ``v`` each ``(n, d)``.

    ``e`` is the forcing at the start, middle and end of the step: a tuple of three ``(n, m)`` arrays
    (or one ``(n, 3, m)`` array).

    ``path_model(rand)`` builds one path's model from its random-parameter vector. Impacts are resolved
    on the crossing paths only, in batches of up to ``ceil(n / 64)`` of them (``ceil(n / 16)`` in chunks of
    ``WIDE_CHUNK`` paths or more) gathered, resolved and scattered back. With ``substeps`` (and a model that
    may be stiff) each path that needs it takes the step as sub-steps of its own (see :class:`Substeps`).
    """
    shared = path_model(None)
    constrained = shared.stacked_constraints() is not None
    sticking = constrained and rule.method == "locate" and rule.stick_velocity > 0 and shared.dimension == 1
    hold = rule.held(len(shared.stacked_constraints().normal)) if constrained else np.zeros(0, bool)
    holding = rule.method == "locate" and rule.stick_velocity > 0 and shared.dimension > 1 and bool(hold.any())

    def free(q, v, e, rand, tau0, h):
        return rk4(path_model(rand), q, v, e, h, tau0, 1.0)

    def free_from_start(q, v, e, rand, h):
        return rk4(path_model(rand), q, v, e, h)  # fractions 0 and 1: no interpolation of the forcing

    def resolve(y0, tau0, y1, last, e, rand, h):
        return _resolve_one(path_model(rand), rule, h, y0, tau0, y1, last, e)

    def resolve_held(y0, tau0, y1, force, last, held, located, e, rand, h):
        return _resolve_held(path_model(rand), rule, h, y0, tau0, y1, force, last, held, located, e, hold)

    def start_held(q, v, e, rand, h):
        """One path's step from its start, held on the constraint it rests on and is pressed into (if any):
        ``(q, v)`` at the end, its free normal accelerations at the stages ``(4,)``, that constraint (-1 for
        none), and whether it lets go inside the step."""
        model = path_model(rand)
        geo = geometry(model.stacked_constraints(), q.dtype)
        held = held_constraint(model, geo, q, v, e[0], hold)
        q1, v1, f = held_rk4(model, geo, q, v, e, h, 0.0, 1.0, held)
        return q1, v1, f, held, lets_go(held, f)

    def mirror(q, v, rand):
        return _mirror(path_model(rand), q, v)

    def constraint_values(q, rand):
        """``c_j(q)`` of one path's constraints, ``(J,)``."""
        return values(geometry(path_model(rand).stacked_constraints(), q.dtype), q)

    def violates(q, rand):
        c = constraint_values(q, rand)
        return c[0] < 0 if c.shape[0] == 1 else jnp.any(c < 0)

    def to_locate(y0, y1, rand, held=None):
        """Whether the step ``y0 -> y1`` of one path ends beyond a constraint that it crossed at a normal speed
        of at least ``rule.mirror_below`` at either end (every crossing where it is 0), other than the one it
        is ``held`` on."""
        if rule.mirror_below == 0 and held is None:
            return violates(y1[0], rand)
        geo = geometry(path_model(rand).stacked_constraints(), y1[0].dtype)
        beyond = values(geo, y1[0]) < 0
        if held is not None:
            beyond = beyond & (jnp.arange(beyond.shape[0]) != held)
        if rule.mirror_below > 0:
            speed = jnp.maximum(jnp.abs(dot(geo.normal, y0[1])), jnp.abs(dot(geo.normal, y1[1])))
            beyond = beyond & (speed >= rule.mirror_below)
        return jnp.any(beyond)

    def rests(q, v, rand):
        c = constraint_values(q, rand)
        on = c[0] == 0 if c.shape[0] == 1 else jnp.any(c == 0)
        return on & (v[0] == 0 if v.shape[0] == 1 else jnp.all(v == 0))

    def start_fraction(q, v, e, rand):
        """0, or for a path at rest on a constraint the fraction at which the force pulls it off."""
        model = path_model(rand)
        geo = geometry(model.stacked_constraints(), q.dtype)
        normal = _pick(geo.normal, jnp.argmax(values(geo, q) == 0))
        return jnp.where(rests(q, v, rand), departure(model, e, 0.0, normal, q), 0.0)

    def per_path(fn, h):
        """``fn(..., h=)`` vmapped over the paths, with a step length ``h`` shared (scalar) or per path ``(n,)``."""
        if jnp.ndim(h) == 0:
            return jax.vmap(functools.partial(fn, h=h))
        return lambda *args: jax.vmap(lambda *a: fn(*a[:-1], h=a[-1]))(*args, h)

    def from_rest(q, v, e, rand, h):
        """The step of every path from its :func:`start_fraction` (0 for a path not at rest): ``(q, v, tau)``."""
        tau = jax.vmap(start_fraction)(q, v, e, rand)
        return (*per_path(free, h)(q, v, e, rand, tau), tau)

    def resolve_crossings(y0, tau0, y1, e, rand, h, held=None, force=None, departs=None):
        """Every located impact of the step: ``y1`` with each crossing path's impacts resolved (with ``held``,
        the constraint each path is held on, ``force``, its stage forces, and ``departs``, whether it lets go
        inside the step: every event of :func:`_resolve_held`).

        The crossing paths are served in batches of up to ``cap`` (:func:`batch_rows`: ``ceil(n / 64)``): the
        paths are split into ``cap`` lanes of ``G = ceil(n / cap)``, and a batch takes the first crossing path of
        every lane that has one, gathered in one piece (every per-path input packed in the columns of one array),
        resolves up to ``max_impacts`` impacts of each on these few rows, and scatters their end states back.
        Every loop that runs on the batch touches only its small arrays, and every loop level over batches has a
        few operations in a chain, so XLA's CPU runtime runs them inline rather than handing them to its
        thread pool (which costs more than the work).

        ``G`` batches serve any step; ``2**depth >= G`` of them run as a binary tree of ``fori_loop`` of two
        iterations (static trip counts, so reverse-mode AD works) whose subtrees are skipped once no path is
        pending: the resolution is traced once, and a step whose crossings fit in one batch passes ``depth``
        skipped subtrees.

        A chunk of ``WIDE_CHUNK`` paths or more (an accelerator's; a CPU's where ``default_chunk_size`` makes
        it so) is served by a wide batch first: up to ``cap`` (``ceil(n / 16)``) crossing paths, taken in order
        (``jnp.nonzero``) and gathered column by column, every round on every row; lanes of ``G = 16`` paths
        serve the crossings beyond it. On an accelerator that runs in every step without branches: every branch
        costs a read of its predicate by the host and kernels of its own, which set the cost of a step
        (docs/speed.md). There the paths at rest on the barrier (one degree of freedom) are served with the
        crossing paths, and their batch restarts them where the force pulls them off. On a CPU a branch is
        cheap, and a wide batch costs as much whether 10 or 800 paths cross: only a step where more than
        ``n / CROWDED_AT`` paths cross takes it (the impact damper's rattling), any other the lanes of 64 (the
        reference scene's few crossings).
        """
        n, d = y0[0].shape
        wide, unbranched = n >= WIDE_CHUNK, branch_free(n)
        per_path_h = jnp.ndim(h) != 0
        e = tuple(e) if isinstance(e, (tuple, list)) else tuple(e[:, i] for i in range(3))
        columns = (*y0, tau0[:, None], *y1, *e, rand) + ((h[:, None],) if per_path_h else ())
        if holding:
            columns = columns + (force, held.astype(tau0.dtype)[:, None])
        widths = [c.shape[1] for c in columns]

        def unpack(rows):
            parts = jnp.split(rows, list(itertools.accumulate(widths))[:-1], axis=1)
            q0, v0, t0, q1, v1, e0, e1, e2, r = parts[:9]
            return (q0, v0), t0[:, 0], (q1, v1), (e0, e1, e2), r, (parts[9][:, 0] if per_path_h else h), parts[-2:]

        def resolve_batch_held(b0, t0, b1, be, br, bh, held_columns, wide):
            """Up to ``max_impacts + 1`` events (impacts, departures) of each of the batch's held or crossing paths."""
            last = jnp.full(t0.shape, -1, jnp.int32)
            bforce, bheld = held_columns[0], held_columns[1][:, 0].astype(jnp.int32)

            def one_event(_, carry):
                pending = carry[-1]

                def resolve_all(c):
                    located = jax.vmap(to_locate)(c[0], c[2], br, c[5])
                    new = per_path(resolve_held, bh)(*c[:6], located, be, br)
                    return jax.tree_util.tree_map(lambda a, b: jnp.where(_paths(pending, a), a, b), new, c)

                return resolve_all(carry) if wide else jax.lax.cond(jnp.any(pending), resolve_all, lambda c: c, carry)

            init = (b0, t0, b1, bforce, last, bheld, jnp.ones(t0.shape, bool))
            return jax.lax.fori_loop(0, rule.max_impacts + 1, one_event, init)[2]

        def resolve_batch(rows, wide):
            """Up to ``max_impacts`` impacts of each of the batch's paths: ``(k, 2 d)`` end states (``wide``: every
            round on every row, without branches)."""
            b0, t0, b1, be, br, bh, held_columns = unpack(rows)
            if sticking and unbranched:  # its paths at rest start where the force pulls them off (see plain_step)
                resting = jax.vmap(rests)(*b0, br)
                *moved, t0 = from_rest(*b0, be, br, bh)
                b1 = tuple(jnp.where(_paths(resting, a), a, b) for a, b in zip(moved, b1, strict=True))
            if holding:
                return jnp.concatenate(resolve_batch_held(b0, t0, b1, be, br, bh, held_columns, wide), axis=1)
            last = jnp.full(t0.shape, -1, jnp.int32)

            def one_impact(_, carry):
                located = jax.vmap(to_locate)(carry[0], carry[2], br)

                def resolve_all(c):
                    new = per_path(resolve, bh)(*c, be, br)
                    if rule.mirror_below == 0:
                        return new
                    return jax.tree_util.tree_map(lambda a, b: jnp.where(_paths(located, a), a, b), new, c)

                return resolve_all(carry) if wide else jax.lax.cond(jnp.any(located), resolve_all, lambda c: c, carry)

            b1 = jax.lax.fori_loop(0, rule.max_impacts, one_impact, (b0, t0, b1, last))[2]
            return jnp.concatenate(b1, axis=1)

        def one_batch(carry, wide, in_order=False):
            source, end, todo, _ = carry
            cap = batch_rows(n, wide)
            idx = jnp.nonzero(todo, size=cap, fill_value=n)[0] if in_order else first_in_lanes(todo, cap)
            if wide:  # the columns themselves: packing them would copy every path in every step
                rows = jnp.concatenate([c.at[idx].get(mode="clip") for c in source], axis=1)
            else:
                rows = source.at[idx].get(mode="clip")
            end = end.at[idx].set(resolve_batch(rows, wide), mode="drop")
            todo = todo.at[idx].set(False, mode="drop")
            return source, end, todo, jnp.any(todo)

        def batches(carry, wide, depth=None):
            """``carry`` if no path is pending, else up to ``2**depth`` batches (``None``: enough for any step): two
            subtrees of ``depth - 1``."""
            if depth is None:
                depth = (-(-n // batch_rows(n, wide)) - 1).bit_length()

            def run(carry):
                if depth == 0:
                    return one_batch(carry, wide)
                return jax.lax.fori_loop(0, 2, lambda _, c: batches(c, wide, depth - 1), carry)

            return jax.lax.cond(carry[3], run, lambda c: c, carry)

        def by_lanes(end, todo):
            return batches((jnp.concatenate(columns, axis=1), end, todo, jnp.any(todo)), wide=False)[1]

        def wide_first(end, todo):
            return batches(one_batch((columns, end, todo, True), wide=True, in_order=True), wide=True)[1]

        todo = jax.vmap(to_locate)(y0, y1, rand) if held is None else jax.vmap(to_locate)(y0, y1, rand, held) | departs
        if sticking and unbranched:
            todo = todo | jax.vmap(rests)(*y0, rand)
        end = jnp.concatenate(y1, axis=1)
        if not wide:
            end = jax.lax.cond(jnp.any(todo), by_lanes, lambda end, _: end, end, todo)
        elif unbranched:
            end = wide_first(end, todo)
        else:  # a CPU: a branch is cheap, no host reads its predicate from an accelerator's memory
            end = jax.lax.cond(jnp.sum(todo) > n // CROWDED_AT, wide_first, by_lanes, end, todo)
        return end[:, :d], end[:, d:]

    def plain_step(q, v, e, rand, h):
        """One step of every path; ``h`` is the step length, shared (scalar) or per path ``(n,)``."""
        tau0 = jnp.zeros(q.shape[:1], q.dtype)
        # A path at rest starts at its own fraction of the step. A step without one takes the plain form (the
        # forcing nodes themselves, the step's constants folded), which XLA keeps in fewer kernels. An
        # accelerator's compiler folds this branch into a select and takes the restart of every path in every
        # step: there the resolution's batch restarts the paths at rest instead (resolve_crossings).
        start = per_path(free_from_start, h)
        if sticking and not branch_free(q.shape[0]):

            def from_start():
                return (*start(q, v, e, rand), tau0)

            q1, v1, tau0 = jax.lax.cond(
                jnp.any(jax.vmap(rests)(q, v, rand)), lambda: from_rest(q, v, e, rand, h), from_start
            )
        elif holding:
            q1, v1, force, held, departs = per_path(start_held, h)(q, v, e, rand)
        else:
            q1, v1 = start(q, v, e, rand)
        if not constrained:
            return q1, v1
        if holding:
            q1, v1 = resolve_crossings((q, v), tau0, (q1, v1), e, rand, h, held, force, departs)
        elif rule.method == "locate":
            q1, v1 = resolve_crossings((q, v), tau0, (q1, v1), e, rand, h)
        return jax.vmap(mirror)(q1, v1, rand)

    if substeps is None or substeps.max_substeps == 1 or not shared.may_be_stiff:
        return functools.partial(plain_step, h=h)

    n_max = substeps.max_substeps

    def needed(q, v, e, rand, node):
        """Sub-steps one path needs at ``(q, v)`` under its forcing node ``e[node]`` (``n_max`` if not finite)."""
        k = jnp.ceil(h * stiffness_rate(path_model(rand), q, v, e[node]) / substeps.limit)
        return jnp.clip(jnp.where(jnp.isfinite(k), k, n_max), 1, n_max).astype(jnp.int32)

    def sub_forcing(e, ta, tb):
        """One path's forcing nodes at the start, middle and end of its sub-interval ``[ta, tb]``."""
        return tuple(_forcing(e, tau) for tau in (ta, 0.5 * (ta + tb), tb))

    def sub_step(i, y, e, rand, k):
        """Sub-step ``i`` of each path whose own number of sub-steps ``k`` (``(n,)``) exceeds ``i``.

        The other paths take a step of length 0 inside the step (forcing read at its start): they stay
        where they are and cross nothing, so they add no impact work.
        """
        active = i < k
        kf = k.astype(y[0].dtype)
        ta, tb = jnp.where(active, i / kf, 0.0), jnp.where(active, (i + 1) / kf, 0.0)
        sub_e = jax.vmap(sub_forcing)(e, ta, tb)
        new = plain_step(*y, sub_e, rand, jnp.where(active, h / kf, 0.0))
        return tuple(jnp.where(_paths(active, a), a, b) for a, b in zip(new, y, strict=True))

    def step(q, v, e, rand):
        start = (q, v)
        finite = jnp.all(jnp.isfinite(q), axis=1) & jnp.all(jnp.isfinite(v), axis=1)
        k_start = jax.vmap(functools.partial(needed, node=0))(q, v, e, rand)

        def body(i, carry):
            # iteration 0: every path's full step (its trial); then the paths that need it redo the
            # step from the start in k sub-steps, i = 1 .. k
            trial, y, k = carry
            first = i == 0
            new = sub_step(jnp.where(first, 0, i - 1), y, e, rand, jnp.where(first, 1, k))

            def after_trial():
                # a path needs sub-steps if its start or the end of its trial step is stiff (or blew up)
                k_end = jax.vmap(functools.partial(needed, node=2))(*new, e, rand)
                return new, start, jnp.where(finite, jnp.maximum(k_start, k_end), 1)

            return jax.lax.cond(first, after_trial, lambda: (trial, new, k))

        def active(i, carry):
            k_max = jnp.max(carry[2])
            return (i == 0) | ((k_max > 1) & (i <= k_max))

        trial, y, k = jax.lax.fori_loop(
            0, n_max + 1, lambda i, c: jax.lax.cond(active(i, c), body, lambda i, c: c, i, c), (start, start, k_start)
        )
        return tuple(jnp.where(_paths(k > 1, a), a, b) for a, b in zip(y, trial, strict=True))

    return step


class Tracker(abc.ABC):
    """A per-path quantity carried along every step and stored at the save slots like the states.

    Hashable (it is a static argument of the jitted integration). ``init(model, q, v, e)`` gives its value at
    the start (``e``: zero forcing nodes), ``update(model, acc, q, v, q_new, v_new, e, h)`` its value after a
    step of length ``h`` from ``(q, v)`` to ``(q_new, v_new)`` (each ``(d,)``, one path) under the forcing
    ``e``, the nodes at the step's start, middle and end (each ``(m,)``); both return shape ``(k,)``.
    """

    @abc.abstractmethod
    def init(self, model, q, v, e): ...

    @abc.abstractmethod
    def update(self, model, acc, q, v, q_new, v_new, e, h): ...


def increment(e, h):
    """The noise increment of a step, ``dw = h/6 (e_0 + 4 e_1/2 + e_1)`` (Simpson's rule of the forcing)."""
    return h / 6.0 * (e[0] + 4.0 * e[1] + e[2])


@dataclasses.dataclass(frozen=True)
class Sums(Tracker):
    """Running sums from 0 of ``increment(model, q, v, dw) -> (k,)``, taken at the start of every step with its
    noise increment ``dw`` (:func:`increment`)."""

    increment: Callable

    def init(self, model, q, v, e):
        return jnp.zeros_like(self.increment(model, q, v, e[0]))

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        return acc + self.increment(model, q, v, increment(e, h))


@dataclasses.dataclass(frozen=True)
class RunningMax(Tracker):
    """The largest value of ``quantity(state) -> scalar`` (``state = (q, v)``, shape ``(2 d,)``) over the start
    and the end of every step so far, and whether the state has been non-finite: shape ``(2,)``.

    A ``nan`` value of the quantity is left out of the maximum (a path that exceeded a level before its state
    turned non-finite keeps its maximum); the second entry is 1 from the first non-finite state on.
    """

    quantity: Callable

    def _value(self, q, v):
        state = jnp.concatenate([q, v])
        value = jnp.reshape(self.quantity(state), ()).astype(q.dtype)
        return value, (~jnp.all(jnp.isfinite(state))).astype(q.dtype)

    def init(self, model, q, v, e):
        value, bad = self._value(q, v)
        return jnp.stack([jnp.where(jnp.isnan(value), -jnp.inf, value), bad])

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        value, bad = self._value(q_new, v_new)
        return jnp.stack([jnp.where(value > acc[0], value, acc[0]), jnp.maximum(acc[1], bad)])


@dataclasses.dataclass(frozen=True)
class Impacts(Tracker):
    """Impacts along a path: ``(impacted so far, steps with an impact so far, impact speeds per bin so far)``,
    shape ``(2 + K,)`` for ``K + 1`` edges (``K = 0`` without edges).

    A step has an impact where its free RK4 step (the integrator's trial step) ends beyond a constraint and
    the path did not start the step at rest or held on one. The impact speed is ``|n . v|`` (normal to the
    constraint, relative for a mass-mass contact; the speed the impact law reverses) at the first crossing, located
    as the integrator locates it: at a grazing crossing the located state's normal velocity can have the wrong sign
    by the step's local error (under Gaussian node forcing 0.12 % of the impacts of a linear oscillator, all slower
    than 0.003). Speeds outside ``edges`` are counted as impacts but in no bin. Several impacts in one step count
    once.
    """

    rule: ImpactRule
    edges: tuple  # bin edges of the impact speed, increasing

    def init(self, model, q, v, e):
        return jnp.zeros((2 + max(len(self.edges) - 1, 0),), q.dtype)

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        geo = geometry(model.stacked_constraints(), q.dtype)
        hold = self.rule.held(geo.normal.shape[0])
        if q.shape[0] > 1 and self.rule.method == "locate" and self.rule.stick_velocity > 0 and hold.any():
            resting = jnp.any(hold & resting_on(geo, q, v))  # held on a constraint (sticking per constraint)
        else:
            resting = jnp.any(values(geo, q) == 0) & jnp.all(v == 0)
        trial = rk4(model, q, v, e, h)
        _, hit, j, _, (_, vc) = first_crossing(model, self.rule, h, (q, v), jnp.zeros((), q.dtype), trial, -1, e)
        impact = hit & ~resting
        speed = jnp.abs(dot(_pick(geo.normal, j), vc))
        edges = jnp.asarray(self.edges, q.dtype).reshape(-1)
        bins = impact & (speed >= edges[:-1]) & (speed < edges[1:]) if edges.size else jnp.zeros((0,), bool)
        new = jnp.concatenate([jnp.stack([impact, impact]), bins]).astype(q.dtype)
        return jnp.concatenate([jnp.maximum(acc[:1], new[:1]), acc[1:] + new[1:]])


@dataclasses.dataclass(frozen=True)
class Stacked(Tracker):
    """Several trackers carried together: their values concatenated, in order."""

    trackers: tuple

    def init(self, model, q, v, e):
        return jnp.concatenate([t.init(model, q, v, e) for t in self.trackers])

    def update(self, model, acc, q, v, q_new, v_new, e, h):
        sizes = [jax.eval_shape(t.init, model, q, v, e).shape[0] for t in self.trackers]
        parts = jnp.split(acc, list(itertools.accumulate(sizes))[:-1])
        return jnp.concatenate(
            [t.update(model, a, q, v, q_new, v_new, e, h) for t, a in zip(self.trackers, parts, strict=True)]
        )


def integrate(
    path_model,
    rule: ImpactRule,
    h: float,
    q0,
    v0,
    excitation,
    rand,
    slots,
    n_save: int,
    initial_slot: int,
    substeps: Substeps | None = None,
    track: Tracker | None = None,
):
    """Integrate a batch of paths over the whole time grid and keep only the saved states.

    Args:
        path_model: ``rand -> model`` for one path (``rand=None`` gives the shared model).
        rule: impact settings.
        h: time step, s.
        q0, v0: initial coordinates and velocities, shape ``(n, d)``.
        excitation: the forcing of the paths at the nodes (:class:`jdpim._excitation.AbstractNodes`), or ``xi`` on
            the half-step grid, time-major, shape ``(2 T + 1, n, m)``.
        rand: random parameters per path, shape ``(n, n_random)``.
        slots: shape ``(T,)`` int: the save slot written after each step (``n_save`` = none).
        n_save: number of saved times. Slot ``n_save`` is a scratch row.
        initial_slot: the save slot of ``t = 0`` (``n_save`` if not saved).
        substeps: sub-stepping of stiff steps, or ``None`` for none.
        track: ``None``, or a :class:`Tracker` carried along every step and stored at the save slots.

    Returns:
        shape ``(n, n_save, 2 d)``: ``(q, v)`` at the saved times; with ``track`` the pair ``(states, tracked)``,
        ``tracked`` of shape ``(n, n_save, k)``.
    """
    step = jax.checkpoint(make_batch_step(path_model, rule, h, substeps))
    T = slots.shape[0]
    nodes = excitation if isinstance(excitation, AbstractNodes) else ArrayNodes(excitation)
    e_first = nodes.start()
    n, m = nodes.shape

    def body(carry, inputs):
        q, v, buf, e_start = carry
        k, slot = inputs
        e, e_next = nodes.step(k, e_start)
        q, v = step(q, v, e, rand)
        buf = jax.lax.dynamic_update_index_in_dim(buf, jnp.concatenate([q, v], axis=-1), slot, axis=0)
        return (q, v, buf, e_next), e

    d = q0.shape[1]
    buf = jnp.zeros((n_save + 1, n, 2 * d), dtype=q0.dtype).at[initial_slot].set(jnp.concatenate([q0, v0], axis=-1))
    if track is None:
        (q, v, buf, _), _ = jax.lax.scan(
            lambda c, i: (body(c, i)[0], None), (q0, v0, buf, e_first), (jnp.arange(T), slots)
        )
        return jnp.moveaxis(buf[:n_save], 0, 1)

    def update(acc, q, v, q_new, v_new, e, r):
        return track.update(path_model(r), acc, q, v, q_new, v_new, e, h)

    def body_tracked(carry, inputs):
        (q, v, buf, e_start), acc, acc_buf = carry
        (q_new, v_new, buf, e_next), e = body((q, v, buf, e_start), inputs)
        acc = jax.vmap(update)(acc, q, v, q_new, v_new, e, rand)
        acc_buf = jax.lax.dynamic_update_index_in_dim(acc_buf, acc, inputs[1], axis=0)
        return ((q_new, v_new, buf, e_next), acc, acc_buf), None

    zero = (jnp.zeros((m,), q0.dtype),) * 3
    acc = jax.vmap(lambda q, v, r: track.init(path_model(r), q, v, zero))(q0, v0, rand)
    acc_buf = jnp.zeros((n_save + 1, *acc.shape), q0.dtype).at[initial_slot].set(acc)
    init = ((q0, v0, buf, e_first), acc, acc_buf)
    ((_, _, buf, _), _, acc_buf), _ = jax.lax.scan(body_tracked, init, (jnp.arange(T), slots))
    return jnp.moveaxis(buf[:n_save], 0, 1), jnp.moveaxis(acc_buf[:n_save], 0, 1)
