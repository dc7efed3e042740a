"""One path's pieces of a step, each a function of the engine's static settings (:class:`Engine`) and of one
path's arrays, and their maps over the paths of a batch (:func:`per_path`, :func:`each`)."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .._constraints import dot, geometry, values
from .elementwise import pick
from .resolve import mirror, resolve_held, resolve_one
from .rk4 import held_rk4, rk4
from .settings import ImpactRule
from .sticking import departure, held_constraint, lets_go


@dataclasses.dataclass(frozen=True, eq=False)
class Engine:
    """The static settings of the step of a batch of paths, fixed when it is traced.

    Attributes:
        path_model: ``rand -> model`` of one path from its random-parameter vector (``None``: the shared model).
        rule: the impact settings.
        hold: ``(J,)`` bool: the constraints a path may be held on (:meth:`ImpactRule.held`; empty without any).
        constrained: whether the model has constraints.
        sticking: whether a path rests on the constraint after a slow impact (one degree of freedom).
        holding: whether a path is held on a constraint after a slow impact (several degrees of freedom).
    """

    path_model: Callable
    rule: ImpactRule
    hold: np.ndarray
    constrained: bool
    sticking: bool
    holding: bool

    @classmethod
    def of(cls, path_model, rule: ImpactRule) -> Engine:
        """The settings of the step of paths of the model ``path_model`` under the impact rule ``rule``."""
        shared = path_model(None)
        constrained = shared.stacked_constraints() is not None
        sticks = rule.method == "locate" and rule.stick_velocity > 0
        hold = rule.held(len(shared.stacked_constraints().normal)) if constrained else np.zeros(0, bool)
        holding = sticks and shared.dimension > 1 and bool(hold.any())
        return cls(path_model, rule, hold, constrained, constrained and sticks and shared.dimension == 1, holding)


def each(fn, eng: Engine):
    """``fn(eng, ...)`` mapped over the paths."""
    return jax.vmap(functools.partial(fn, eng))


def per_path(fn, eng: Engine, h):
    """``fn(eng, ..., h=)`` mapped over the paths, with a step length ``h`` shared (scalar) or per path ``(n,)``."""
    if jnp.ndim(h) == 0:
        return jax.vmap(functools.partial(fn, eng, h=h))
    return lambda *args: jax.vmap(lambda *a: fn(eng, *a[:-1], h=a[-1]))(*args, h)


def free(eng: Engine, q, v, e, rand, tau0, h):
    """One path's free RK4 step from the fraction ``tau0`` of the step to its end."""
    return rk4(eng.path_model(rand), q, v, e, h, tau0, 1.0)


def free_from_start(eng: Engine, q, v, e, rand, h):
    """One path's free RK4 step over the whole step."""
    return rk4(eng.path_model(rand), q, v, e, h)  # fractions 0 and 1: no interpolation of the forcing


def resolve(eng: Engine, y0, tau0, y1, last, e, rand, h):
    """One path's first impact in the rest of the step (:func:`resolve_one`)."""
    return resolve_one(eng.path_model(rand), eng.rule, h, y0, tau0, y1, last, e)


def resolve_event(eng: Engine, y0, tau0, y1, force, last, held, located, e, rand, h):
    """One path's next event in the rest of the step, held on constraints (:func:`resolve_held`)."""
    return resolve_held(eng.path_model(rand), eng.rule, h, y0, tau0, y1, force, last, held, located, e, eng.hold)


def start_held(eng: Engine, q, v, e, rand, h):
    """One path's step from its start, held on the constraint it rests on and is pressed into (if any):
    ``(q, v)`` at the end, its free normal accelerations at the stages ``(4,)``, that constraint (-1 for
    none), and whether it lets go inside the step."""
    model = eng.path_model(rand)
    geo = geometry(model.stacked_constraints(), q.dtype)
    held = held_constraint(model, geo, q, v, e[0], eng.hold)
    q1, v1, f = held_rk4(model, geo, q, v, e, h, 0.0, 1.0, held)
    return q1, v1, f, held, lets_go(held, f)


def mirrored(eng: Engine, q, v, rand):
    """One path's state reflected through every constraint it violates (:func:`mirror`)."""
    return mirror(eng.path_model(rand), q, v)


def constraint_values(eng: Engine, q, rand):
    """``c_j(q)`` of one path's constraints, ``(J,)``."""
    return values(geometry(eng.path_model(rand).stacked_constraints(), q.dtype), q)


def violates(eng: Engine, q, rand):
    """Whether one path's ``q`` violates a constraint."""
    c = constraint_values(eng, q, rand)
    return c[0] < 0 if c.shape[0] == 1 else jnp.any(c < 0)


def to_locate(eng: Engine, y0, y1, rand, held=None):
    """Whether the step ``y0 -> y1`` of one path ends beyond a constraint that it crossed at a normal speed
    of at least ``rule.mirror_below`` at either end (every crossing where it is 0), other than the one it
    is ``held`` on."""
    if eng.rule.mirror_below == 0 and held is None:
        return violates(eng, y1[0], rand)
    geo = geometry(eng.path_model(rand).stacked_constraints(), y1[0].dtype)
    beyond = values(geo, y1[0]) < 0
    if held is not None:
        beyond = beyond & (jnp.arange(beyond.shape[0]) != held)
    if eng.rule.mirror_below > 0:
        speed = jnp.maximum(jnp.abs(dot(geo.normal, y0[1])), jnp.abs(dot(geo.normal, y1[1])))
        beyond = beyond & (speed >= eng.rule.mirror_below)
    return jnp.any(beyond)


def rests(eng: Engine, q, v, rand):
    """Whether one path rests on a constraint: on its plane with every velocity zero."""
    c = constraint_values(eng, q, rand)
    on = c[0] == 0 if c.shape[0] == 1 else jnp.any(c == 0)
    return on & (v[0] == 0 if v.shape[0] == 1 else jnp.all(v == 0))


def start_fraction(eng: Engine, q, v, e, rand):
    """0, or for a path at rest on a constraint the fraction at which the force pulls it off."""
    model = eng.path_model(rand)
    geo = geometry(model.stacked_constraints(), q.dtype)
    normal = pick(geo.normal, jnp.argmax(values(geo, q) == 0))
    return jnp.where(rests(eng, q, v, rand), departure(model, e, 0.0, normal, q), 0.0)


def from_rest(eng: Engine, q, v, e, rand, h):
    """The step of every path from its :func:`start_fraction` (0 for a path not at rest): ``(q, v, tau)``."""
    tau = each(start_fraction, eng)(q, v, e, rand)
    return (*per_path(free, eng, h)(q, v, e, rand, tau), tau)
