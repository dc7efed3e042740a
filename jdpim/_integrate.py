r"""Integration of a batch of paths over the time grid (:func:`integrate`), with the step of :mod:`jdpim._engine`, and
the per-path quantities carried along the steps (:class:`Tracker`)."""

from __future__ import annotations

import abc
import dataclasses
import functools
import itertools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._constraints import dot, geometry, values
from ._engine.elementwise import pick
from ._engine.locate import first_crossing
from ._engine.rk4 import rk4
from ._engine.settings import ImpactRule, Substeps
from ._engine.step import make_batch_step
from ._engine.sticking import resting_on
from ._excitation import AbstractNodes, ArrayNodes


class Tracker(abc.ABC):
    """A per-path quantity carried along every step and stored at the save slots like the states.

    A frozen dataclass, and a pytree (every subclass is registered, :func:`_flatten`): its fields that hold arrays
    (``jax.Array`` or NumPy) are traced leaves of the jitted integration, so that a new value reuses the compiled
    program; its other fields (functions, numbers, settings) are structure, hashed into the jit cache.
    ``init(model, q, v, e)`` gives its value at
    the start (``e``: zero forcing nodes), ``update(model, acc, q, v, q_new, v_new, e, h)`` its value after a
    step of length ``h`` from ``(q, v)`` to ``(q_new, v_new)`` (each ``(d,)``, one path) under the forcing
    ``e``, the nodes at the step's start, middle and end (each ``(m,)``); both return shape ``(k,)``.
    """

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        jax.tree_util.register_pytree_node(cls, _flatten, functools.partial(_unflatten, cls))

    @abc.abstractmethod
    def init(self, model, q, v, e): ...

    @abc.abstractmethod
    def update(self, model, acc, q, v, q_new, v_new, e, h): ...


def _holds_arrays(value) -> bool:
    return any(isinstance(leaf, (jax.Array, np.ndarray)) for leaf in jax.tree_util.tree_leaves(value))


def _flatten(tracker):
    """A tracker's fields that hold arrays (children, traced) and the others (structure, with the names of the
    traced ones). A tracker rebuilt under a transformation keeps the split it was flattened with."""
    fields = [f.name for f in dataclasses.fields(tracker)]
    traced = getattr(tracker, "_traced_fields", None)
    if traced is None:
        traced = tuple(name for name in fields if _holds_arrays(getattr(tracker, name)))
    static = tuple((name, getattr(tracker, name)) for name in fields if name not in traced)
    return tuple(getattr(tracker, name) for name in traced), (traced, static)


def _unflatten(cls, aux, children):
    traced, static = aux
    tracker = object.__new__(cls)  # no __init__: the children may be tracers or placeholders
    for name, value in (*zip(traced, children, strict=True), *static):
        object.__setattr__(tracker, name, value)
    object.__setattr__(tracker, "_traced_fields", traced)
    return tracker


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
    edges: Any  # bin edges of the impact speed, increasing: an array (traced), or () for none

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
        speed = jnp.abs(dot(pick(geo.normal, j), vc))
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
