r"""Batched RK4 over time with impacts located inside the step.

Every step of every path is one classical RK4 step ``t_n -> t_n + h`` whose forcing is the quadratic
through the excitation at ``t_n``, ``t_n + h/2`` and ``t_n + h`` (exactly RK4's stage values). Where the
step ends beyond the barrier (``x_{n+1} < b``) the impact is located and resolved:

1. ``s``: root of the cubic Hermite interpolant of ``(x_n, v_n, x_{n+1}, v_{n+1})``, by a bracketed
   Newton iteration with a fixed number of steps and one final plain Newton step (so that derivatives
   follow the implicit function theorem and carry the event-time shift: the saltation matrix);
2. redo the step as ``RK4(s h)`` -> reset ``v <- -r v``, ``x <- b`` -> ``RK4((1 - s) h)``;
3. repeat for up to ``max_impacts`` impacts in one step, then fall back to a mirror
   ``(x, v) <- (2b - x, -r v)``, so that no stored state lies beyond the barrier;
4. sticking (``r < 1`` only): when the outgoing speed ``r |v_-|`` is below ``stick_velocity`` and the
   force at ``(b, 0)`` pushes into the barrier, the path rests at ``(b, 0)`` for the rest of the step.
   With ``r = 1`` impacts never accumulate (the motion is the fold ``x = |s|`` of a free path), so a
   path at rest on the barrier with an inward force moves off it, as the exact solution does.

Steps without any crossing in the batch skip the impact work (``lax.cond`` at batch level). The
``"mirror"`` method is the first-order "flip after the step" rule, kept for comparison.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp

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
    """

    method: str = "locate"
    max_impacts: int = 2
    stick_velocity: float = 1e-3
    newton_iterations: int = 4

    def __post_init__(self):
        if self.method not in ("locate", "mirror"):
            raise ValueError(f"method must be 'locate' or 'mirror', got {self.method!r}")
        check_int("max_impacts", self.max_impacts, low=1)
        check_int("newton_iterations", self.newton_iterations, low=1)
        check_real("stick_velocity", self.stick_velocity, low=0.0)


def _forcing(e, tau):
    """Quadratic through ``e[0], e[1], e[2]`` at ``tau = 0, 1/2, 1``; ``e`` has shape ``(3, m)``."""
    l0 = 2.0 * (tau - 0.5) * (tau - 1.0)
    lm = -4.0 * tau * (tau - 1.0)
    l1 = 2.0 * tau * (tau - 0.5)
    return l0 * e[0] + lm * e[1] + l1 * e[2]


def rk4(model, x, v, e, h, ta=0.0, tb=1.0):
    """One RK4 step of one path from step fraction ``ta`` to ``tb`` (step length ``h``, seconds)."""
    H = (tb - ta) * h
    tm = 0.5 * (ta + tb)

    def f(tau, x, v):
        return v, model.acceleration(x, v, _forcing(e, tau))

    k1x, k1v = f(ta, x, v)
    k2x, k2v = f(tm, x + 0.5 * H * k1x, v + 0.5 * H * k1v)
    k3x, k3v = f(tm, x + 0.5 * H * k2x, v + 0.5 * H * k2v)
    k4x, k4v = f(tb, x + H * k3x, v + H * k3v)
    return (x + H / 6.0 * (k1x + 2.0 * k2x + 2.0 * k3x + k4x), v + H / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v))


def locate_crossing(x0, v0, x1, v1, H, n_iter):
    """Root ``s`` in [0, 1] of the cubic Hermite interpolant of ``x - b`` over a step of length ``H``.

    ``x0 >= 0 > x1`` are positions relative to the barrier; velocities are ``dx/dt``.
    """
    a0, a1, b0, b1 = x0, x1, H * v0, H * v1

    def p(s):
        s2, s3 = s * s, s * s * s
        return (2 * s3 - 3 * s2 + 1) * a0 + (s3 - 2 * s2 + s) * b0 + (3 * s2 - 2 * s3) * a1 + (s3 - s2) * b1

    def dp(s):
        s2 = s * s
        return (6 * s2 - 6 * s) * (a0 - a1) + (3 * s2 - 4 * s + 1) * b0 + (3 * s2 - 2 * s) * b1

    lo, hi = jnp.zeros_like(x0), jnp.ones_like(x0)
    s = jnp.clip(a0 / (a0 - a1), 0.0, 1.0)
    for _ in range(n_iter):
        ps = p(s)
        pos = ps > 0
        lo, hi = jnp.where(pos, s, lo), jnp.where(pos, hi, s)
        d = dp(s)
        sn = s - ps / jnp.where(d == 0, 1.0, d)
        s = jnp.where((sn > lo) & (sn < hi), sn, 0.5 * (lo + hi))
    d = dp(s)
    s = s - p(s) / jnp.where(d == 0, 1.0, d)  # plain Newton step: derivative by the implicit function theorem
    return jnp.clip(s, 0.0, 1.0)


def _resolve_one(model, rule: ImpactRule, h, y0, tau0, y1, e):
    """Resolve the first impact of one path inside ``[tau0, 1]`` of the step, where ``y1`` is beyond it."""
    b = model.barrier
    (x0, v0), (x1, v1) = y0, y1
    hit = x1 < b
    # Paths without a crossing get harmless stand-in values, so that no NaN reaches a derivative.
    rx0 = jnp.where(hit, x0 - b, 1.0)
    rx1 = jnp.where(hit, x1 - b, -1.0)
    span = (1.0 - tau0) * h
    s = locate_crossing(rx0, v0, rx1, v1, jnp.where(hit, span, h), rule.newton_iterations)
    theta = tau0 + s * (1.0 - tau0)
    _, vc = rk4(model, x0, v0, e, h, tau0, theta)
    v_plus = model.r * jnp.abs(vc)
    xr, vr = rk4(model, jnp.asarray(b, x0.dtype), v_plus, e, h, theta, 1.0)
    if rule.stick_velocity > 0:
        pushes_in = model.acceleration(b, jnp.zeros_like(v0), _forcing(e, theta)) <= 0
        stick = (v_plus < rule.stick_velocity) & pushes_in & (model.r < 1)  # r = 1 never chatters to rest
        xr, vr = jnp.where(stick, b, xr), jnp.where(stick, 0.0, vr)
        v_plus = jnp.where(stick, 0.0, v_plus)
    new_y0 = (jnp.where(hit, b, x0), jnp.where(hit, v_plus, v0))
    new_y1 = (jnp.where(hit, xr, x1), jnp.where(hit, vr, v1))
    return new_y0, jnp.where(hit, theta, tau0), new_y1


def _mirror(model, x, v):
    b = model.barrier
    beyond = x < b
    return jnp.where(beyond, 2 * b - x, x), jnp.where(beyond, -model.r * v, v)


def make_batch_step(path_model, rule: ImpactRule, h):
    """The step for a batch of paths: ``(x, v, e, rand) -> (x, v)``, each ``(n,)``; ``e`` is ``(n, 3, m)``.

    ``path_model(rand)`` builds one path's model from its random-parameter vector. Impacts are resolved
    on the crossing paths only: up to ``n / 16`` of them are gathered, resolved and scattered back;
    a step with more crossings resolves the whole batch.
    """

    def free(x, v, e, rand):
        return rk4(path_model(rand), x, v, e, h)

    def resolve(y0, tau0, y1, e, rand):
        return _resolve_one(path_model(rand), rule, h, y0, tau0, y1, e)

    def mirror(x, v, rand):
        return _mirror(path_model(rand), x, v)

    def resolve_crossing(state, e, rand, barrier):
        n = barrier.shape[0]
        cap = max(1, -(-n // 16))
        hit = state[2][0] < barrier

        def all_paths(state):
            return jax.vmap(resolve)(*state, e, rand)

        def compacted(state):
            idx = jnp.nonzero(hit, size=cap, fill_value=n)[0]
            take = functools.partial(jax.tree_util.tree_map, lambda a: a.at[idx].get(mode="clip"))
            sub_state, sub_e, sub_rand = take((state, e, rand))
            out = jax.vmap(resolve)(*sub_state, sub_e, sub_rand)
            return jax.tree_util.tree_map(lambda a, b: a.at[idx].set(b, mode="drop"), state, out)

        if cap >= n:
            return all_paths(state)
        count = jnp.sum(hit)
        return jax.lax.cond(
            count == 0, lambda s: s, lambda s: jax.lax.cond(count <= cap, compacted, all_paths, s), state
        )

    def step(x, v, e, rand):
        x1, v1 = jax.vmap(free)(x, v, e, rand)
        if not path_model(None).has_barrier:
            return x1, v1
        barrier = jax.vmap(lambda r: jnp.asarray(path_model(r).barrier, x.dtype))(rand)
        if rule.method == "locate":
            state = ((x, v), jnp.zeros_like(x), (x1, v1))
            for _ in range(rule.max_impacts):
                state = resolve_crossing(state, e, rand, barrier)
            x1, v1 = state[2]
        return jax.vmap(mirror)(x1, v1, rand)

    return step


def integrate(path_model, rule: ImpactRule, h: float, x0, v0, excitation, rand, slots, n_save: int, initial_slot: int):
    """Integrate a batch of paths over the whole time grid and keep only the saved states.

    Args:
        path_model: ``rand -> model`` for one path (``rand=None`` gives the shared model).
        rule: impact settings.
        h: time step, s.
        x0, v0: initial states, shape ``(n,)``.
        excitation: ``xi`` on the half-step grid, time-major, shape ``(2 T + 1, n, m)``.
        rand: random parameters per path, shape ``(n, n_random)``.
        slots: shape ``(T,)`` int: the save slot written after each step (``n_save`` = none).
        n_save: number of saved times. Slot ``n_save`` is a scratch row.
        initial_slot: the save slot of ``t = 0`` (``n_save`` if not saved).

    Returns:
        shape ``(n, n_save, 2)``: ``(x, v)`` at the saved times.
    """
    step = jax.checkpoint(make_batch_step(path_model, rule, h))
    n_half, n, m = excitation.shape
    T = (n_half - 1) // 2
    pairs = excitation[1:].reshape(T, 2, n, m)

    def body(carry, inputs):
        x, v, e_prev, buf = carry
        pair, slot = inputs
        e = jnp.stack([e_prev, pair[0], pair[1]], axis=1)  # (n, 3, m)
        x, v = step(x, v, e, rand)
        buf = jax.lax.dynamic_update_index_in_dim(buf, jnp.stack([x, v], axis=-1), slot, axis=0)
        return (x, v, pair[1], buf), None

    buf = jnp.zeros((n_save + 1, n, 2), dtype=x0.dtype).at[initial_slot].set(jnp.stack([x0, v0], axis=-1))
    (x, v, _, buf), _ = jax.lax.scan(body, (x0, v0, excitation[0], buf), (pairs, slots))
    return jnp.moveaxis(buf[:n_save], 0, 1)


def with_parameters(model: Any, names: tuple[str, ...], values) -> Any:
    """``model`` with the fields ``names`` replaced by ``values[i]`` (one path's random parameters)."""
    if values is None or not names:
        return model
    return dataclasses.replace(model, **{name: values[i] for i, name in enumerate(names)})
