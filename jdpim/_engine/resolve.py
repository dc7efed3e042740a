"""Impact resolution of one path: the first impact inside the rest of a step (the generalised Newton law, or
rest on the constraint), the next event of a path held on one, and the mirror fallback."""

from __future__ import annotations

import jax.numpy as jnp

from .._constraints import dot, geometry
from .elementwise import pick, stored
from .locate import crossing_time, first_crossing
from .rk4 import forcing, held_rk4, rk4
from .settings import ImpactRule
from .sticking import departure, lets_go, turns_positive


def resolve_one(model, rule: ImpactRule, h, y0, tau0, y1, last, e):
    """Resolve the first impact of one path inside ``[tau0, 1]`` of the step, where ``y1`` violates a constraint.

    ``y0 = (q, v)`` at ``tau0``, ``y1`` at the step's end, ``last`` the constraint resolved last in this step
    (-1 for none). Of the violated constraints the one crossed first is located and resolved (the others,
    if still violated, by the next calls). Returns the new ``(y0, tau0, y1, last)``.
    """
    (q0, v0), (q1, v1) = y0, y1
    geo, hit, j, theta, (qc, vc) = first_crossing(model, rule, h, y0, tau0, y1, last, e)
    normal, position, r, push, onto, unit, keep, _ = (pick(a, j) for a in geo)
    q_plus = dot(onto, qc) + position * unit  # on the plane c_j = 0
    v_plus = dot(keep, vc) + r * jnp.abs(dot(normal, vc)) * push  # generalised Newton law
    q_plus, v_plus = stored(q_plus), stored(v_plus)
    if rule.stick_velocity > 0 and q0.shape[0] == 1:  # one degree of freedom: rest on the constraint
        rest = jnp.zeros_like(v0)
        pushes_in = dot(normal, model.state_acceleration(q_plus, rest, forcing(e, theta))) <= 0
        stick = (r * jnp.abs(dot(normal, vc)) < rule.stick_velocity) & pushes_in
        tau_d = stored(departure(model, e, theta, normal, q_plus))  # rest at (q_plus, 0) until the force pulls away
        v_plus, theta = jnp.where(stick, rest, v_plus), jnp.where(stick, tau_d, theta)
    qr, vr = rk4(model, q_plus, v_plus, e, h, theta, 1.0, store=True)  # on from the bounce, or the departure
    new_y0 = (jnp.where(hit, q_plus, q0), jnp.where(hit, v_plus, v0))
    new_y1 = (jnp.where(hit, qr, q1), jnp.where(hit, vr, v1))
    return new_y0, jnp.where(hit, theta, tau0), new_y1, jnp.where(hit, j, last)


def resolve_held(model, rule: ImpactRule, h, y0, tau0, y1, force, last, held, located, e, hold):
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
    hit, j, theta = crossing_time(rule, h, y0, tau0, y1, last, geo, held)
    hit = hit & located
    s_off = stored(turns_positive(jnp.stack([force[0], 0.5 * (force[1] + force[2]), force[3]]), 0.0))
    tau_off = tau0 + s_off * (1.0 - tau0)
    off_first = (held >= 0) & (s_off < 1) & (~hit | (tau_off <= theta))
    event = off_first | hit
    tau_e = stored(jnp.where(off_first, tau_off, jnp.where(hit, theta, 1.0)))
    q_e, v_e = map(stored, held_rk4(model, geo, q0, v0, e, h, tau0, tau_e, held, store=True)[:2])
    # the impact on j at theta: a bounce, or held from theta on
    normal, position, r, push, onto, unit, keep, _ = (pick(a, j) for a in geo)
    q_plus = dot(onto, q_e) + position * unit
    u = dot(normal, v_e)
    v_slide = dot(keep, v_e)
    pressed = dot(normal, model.state_acceleration(q_plus, v_slide, forcing(e, tau_e))) <= 0
    stick = (r * jnp.abs(u) < rule.stick_velocity) & pressed & (pick(hold, j) > 0)
    impact = hit & ~off_first
    q_a = jnp.where(impact, q_plus, q_e)
    v_a = jnp.where(impact, jnp.where(stick, v_slide, v_slide + r * jnp.abs(u) * push), v_e)
    q_a, v_a = stored(q_a), stored(v_a)
    held_after = jnp.where(impact & stick, j, -1).astype(jnp.int32)
    q_end, v_end, f_end = held_rk4(model, geo, q_a, v_a, e, h, tau_e, 1.0, held_after, store=True)

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


def mirror(model, q, v):
    """Reflect ``(q, v)`` through every constraint it violates (in order): ``c -> -c``, ``u -> -r u``."""
    geo = geometry(model.stacked_constraints(), q.dtype)
    for j in range(geo.normal.shape[0]):
        beyond = dot(geo.normal[j], q) - geo.position[j] < 0
        q_new = dot(geo.flip[j], q) + 2.0 * geo.position[j] * geo.unit[j]
        v_new = dot(geo.keep[j], v) - geo.r[j] * dot(geo.normal[j], v) * geo.push[j]
        q, v = jnp.where(beyond, q_new, q), jnp.where(beyond, v_new, v)
    return q, v
