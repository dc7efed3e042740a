"""The step of a batch of paths: the free RK4 step of every path, the crossing paths' impacts located and resolved,
the mirror fallback, and sub-steps where a path's step is stiff."""

from __future__ import annotations

import functools

from .batches import resolve_crossings
from .one_path import Engine, each, free_from_start, mirrored, per_path, start_held
from .settings import ImpactRule, Substeps
from .substeps import substepped


def plain_step(eng: Engine, q, v, e, rand, h):
    """One step of every path; ``h`` is the step length, shared (scalar) or per path ``(n,)``."""
    # every path takes the plain form from the step's start (the forcing nodes themselves, the step's constants
    # folded); a path at rest on the barrier is one of the resolution's pending paths, which its batch restarts
    # where the force pulls it off (resolve_crossings), so no branch over every path runs in every step
    if eng.holding:
        q1, v1, force, held, departs = per_path(start_held, eng, h)(q, v, e, rand)
    else:
        q1, v1 = per_path(free_from_start, eng, h)(q, v, e, rand)
    if not eng.constrained:
        return q1, v1
    if eng.holding:
        q1, v1 = resolve_crossings(eng, (q, v), (q1, v1), e, rand, h, held, force, departs)
    elif eng.rule.method == "locate":
        q1, v1 = resolve_crossings(eng, (q, v), (q1, v1), e, rand, h)
    return each(mirrored, eng)(q1, v1, rand)


def make_batch_step(path_model, rule: ImpactRule, h, substeps: Substeps | None = None):
    """The step for a batch of paths: ``(q, v, e, rand) -> (q, v)``, ``q`` and ``v`` each ``(n, d)``.

    ``e`` is the forcing at the start, middle and end of the step: a tuple of three ``(n, m)`` arrays
    (or one ``(n, 3, m)`` array).

    ``path_model(rand)`` builds one path's model from its random-parameter vector. Impacts are resolved
    on the crossing paths only, gathered in small batches, resolved and scattered back: compact batches of up to
    ``ceil(n / 64)`` of them, or in chunks of ``WIDE_CHUNK`` paths or more a first batch of up to
    ``ceil(n / 16)`` (see :mod:`.batches`). With ``substeps``
    (and a model that may be stiff) each path that needs it takes the step as sub-steps of its own (see
    :class:`Substeps`).
    """
    eng = Engine.of(path_model, rule)
    plain = functools.partial(plain_step, eng)
    if substeps is None or substeps.max_substeps == 1 or not path_model(None).may_be_stiff:
        return functools.partial(plain, h=h)
    return functools.partial(substepped, eng, substeps, plain, h)
