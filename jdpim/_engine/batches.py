r"""The resolution of a step's crossings: the crossing paths gathered in small batches, resolved and scattered back.

The paths are split into ``cap`` lanes of ``G = ceil(n / cap)`` (``cap``: :func:`batch_rows`, ``ceil(n / 64)``), and
a batch takes the first crossing path of every lane that has one, gathered in one piece (every per-path input packed
in the columns of one array, :func:`pack`), resolves up to ``max_impacts`` impacts of each on these few rows
(:func:`resolve_batch`), and scatters their end states back (:func:`one_batch`). Every loop that runs on the batch
touches only its small arrays, and every loop level over batches has a few operations in a chain, so XLA's CPU runtime
runs them inline rather than handing them to its thread pool (which costs more than the work).

``G`` batches serve any step; ``2**depth >= G`` of them run as a binary tree of ``fori_loop`` of two iterations
(static trip counts, so reverse-mode AD works) whose subtrees are skipped once no path is pending (:func:`batches`):
the resolution is traced once, and a step whose crossings fit in one batch passes ``depth`` skipped subtrees.

A chunk of ``WIDE_CHUNK`` paths or more (an accelerator's; a CPU's where ``default_chunk_size`` makes it so) is served
by a wide batch first (:func:`wide_first`): up to ``cap`` (``ceil(n / 16)``) crossing paths, taken in order
(``jnp.nonzero``) and gathered column by column, every round on every row; lanes of ``G = 16`` paths serve the
crossings beyond it. On an accelerator that runs in every step without branches: every branch costs a read of its
predicate by the host and kernels of its own, which set the cost of a step (docs/speed.md). There the paths at rest on
the barrier (one degree of freedom) are served with the crossing paths, and their batch restarts them where the force
pulls them off. On a CPU a branch is cheap, and a wide batch costs as much whether 10 or 800 paths cross: only a step
where more than ``n / CROWDED_AT`` paths cross takes it (the impact damper's rattling), any other the lanes of 64 (the
reference scene's few crossings).
"""

from __future__ import annotations

import functools
import itertools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from .._cpu import on_cpu
from .elementwise import along_paths
from .one_path import Engine, each, from_rest, per_path, resolve, resolve_event, rests, to_locate

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


class Packing(NamedTuple):
    """How a chunk's per-path inputs sit in the columns of one array: the chunk's ``n`` paths, each input's
    ``widths``, and the step length ``h`` (``None``: a column per path)."""

    n: int
    widths: tuple[int, ...]
    h: Any


def pack(eng: Engine, y0, tau0, y1, e, rand, h, held, force):
    """The per-path inputs of a chunk's step as a tuple of ``(n, width)`` columns, and their :class:`Packing`."""
    per_path_h = jnp.ndim(h) != 0
    e = tuple(e) if isinstance(e, (tuple, list)) else tuple(e[:, i] for i in range(3))
    columns = (*y0, tau0[:, None], *y1, *e, rand) + ((h[:, None],) if per_path_h else ())
    if eng.holding:
        columns = columns + (force, held.astype(tau0.dtype)[:, None])
    return columns, Packing(y0[0].shape[0], tuple(c.shape[1] for c in columns), None if per_path_h else h)


def unpack(packing: Packing, rows):
    """``(y0, tau0, y1, e, rand, h, held_columns)`` of the rows of a batch (:func:`pack`)."""
    parts = jnp.split(rows, list(itertools.accumulate(packing.widths))[:-1], axis=1)
    q0, v0, t0, q1, v1, e0, e1, e2, r = parts[:9]
    t0 = t0[:, 0]
    h = parts[9][:, 0] if packing.h is None else packing.h
    return (q0, v0), t0, (q1, v1), (e0, e1, e2), r, h, parts[-2:]


def resolve_batch_held(eng: Engine, b0, t0, b1, be, br, bh, held_columns, wide):
    """Up to ``max_impacts + 1`` events (impacts, departures) of each of the batch's held or crossing paths."""
    last = jnp.full(t0.shape, -1, jnp.int32)
    bforce, bheld = held_columns[0], held_columns[1][:, 0].astype(jnp.int32)

    def one_event(_, carry):
        pending = carry[-1]

        def resolve_all(c):
            located = each(to_locate, eng)(c[0], c[2], br, c[5])
            new = per_path(resolve_event, eng, bh)(*c[:6], located, be, br)
            return jax.tree_util.tree_map(lambda a, b: jnp.where(along_paths(pending, a), a, b), new, c)

        return resolve_all(carry) if wide else jax.lax.cond(jnp.any(pending), resolve_all, lambda c: c, carry)

    init = (b0, t0, b1, bforce, last, bheld, jnp.ones(t0.shape, bool))
    return jax.lax.fori_loop(0, eng.rule.max_impacts + 1, one_event, init)[2]


def resolve_batch(eng: Engine, packing: Packing, rows, wide):
    """Up to ``max_impacts`` impacts of each of the batch's paths: ``(k, 2 d)`` end states (``wide``: every
    round on every row, without branches)."""
    b0, t0, b1, be, br, bh, held_columns = unpack(packing, rows)
    if eng.sticking and branch_free(packing.n):  # its paths at rest start where the force pulls them off
        resting = each(rests, eng)(*b0, br)
        *moved, t0 = from_rest(eng, *b0, be, br, bh)
        b1 = tuple(jnp.where(along_paths(resting, a), a, b) for a, b in zip(moved, b1, strict=True))
    if eng.holding:
        return jnp.concatenate(resolve_batch_held(eng, b0, t0, b1, be, br, bh, held_columns, wide), axis=1)
    last = jnp.full(t0.shape, -1, jnp.int32)

    def one_impact(_, carry):
        located = each(to_locate, eng)(carry[0], carry[2], br)

        def resolve_all(c):
            new = per_path(resolve, eng, bh)(*c, be, br)
            if eng.rule.mirror_below == 0:
                return new
            return jax.tree_util.tree_map(lambda a, b: jnp.where(along_paths(located, a), a, b), new, c)

        return resolve_all(carry) if wide else jax.lax.cond(jnp.any(located), resolve_all, lambda c: c, carry)

    b1 = jax.lax.fori_loop(0, eng.rule.max_impacts, one_impact, (b0, t0, b1, last))[2]
    return jnp.concatenate(b1, axis=1)


def one_batch(eng: Engine, packing: Packing, carry, wide, in_order=False):
    """One batch: up to ``batch_rows`` pending paths of ``carry = (source, end, todo, any pending)`` resolved, their
    end states scattered into ``end`` and their ``todo`` cleared; taken in order or the first of every lane."""
    source, end, todo, _ = carry
    n = packing.n
    cap = batch_rows(n, wide)
    idx = jnp.nonzero(todo, size=cap, fill_value=n)[0] if in_order else first_in_lanes(todo, cap)
    if wide:  # the columns themselves: packing them would copy every path in every step
        rows = jnp.concatenate([c.at[idx].get(mode="clip") for c in source], axis=1)
    else:
        rows = source.at[idx].get(mode="clip")
    end = end.at[idx].set(resolve_batch(eng, packing, rows, wide), mode="drop")
    todo = todo.at[idx].set(False, mode="drop")
    return source, end, todo, jnp.any(todo)


def batches(eng: Engine, packing: Packing, carry, wide, depth=None):
    """``carry`` if no path is pending, else up to ``2**depth`` batches (``None``: enough for any step): two
    subtrees of ``depth - 1``."""
    if depth is None:
        depth = (-(-packing.n // batch_rows(packing.n, wide)) - 1).bit_length()

    def run(carry):
        if depth == 0:
            return one_batch(eng, packing, carry, wide)
        return jax.lax.fori_loop(0, 2, lambda _, c: batches(eng, packing, c, wide, depth - 1), carry)

    return jax.lax.cond(carry[3], run, lambda c: c, carry)


def by_lanes(eng: Engine, packing: Packing, columns, end, todo):
    """The end states with every pending path resolved by batches of the first pending path of every lane."""
    return batches(eng, packing, (jnp.concatenate(columns, axis=1), end, todo, jnp.any(todo)), wide=False)[1]


def wide_first(eng: Engine, packing: Packing, columns, end, todo):
    """The end states with a wide batch of the pending paths in order resolved first, then the rest by lanes."""
    first = one_batch(eng, packing, (columns, end, todo, True), wide=True, in_order=True)
    return batches(eng, packing, first, wide=True)[1]


def resolve_crossings(eng: Engine, y0, tau0, y1, e, rand, h, held=None, force=None, departs=None):
    """Every located impact of the step: ``y1`` with each crossing path's impacts resolved (with ``held``, the
    constraint each path is held on, ``force``, its stage forces, and ``departs``, whether it lets go inside the
    step: every event of :func:`resolve_held`), by batches of the crossing paths (see the module's text)."""
    n, d = y0[0].shape
    wide, unbranched = n >= WIDE_CHUNK, branch_free(n)
    columns, packing = pack(eng, y0, tau0, y1, e, rand, h, held, force)
    lanes, first = (functools.partial(f, eng, packing, columns) for f in (by_lanes, wide_first))
    todo = each(to_locate, eng)(y0, y1, rand) if held is None else each(to_locate, eng)(y0, y1, rand, held) | departs
    if eng.sticking and unbranched:
        todo = todo | each(rests, eng)(*y0, rand)
    end = jnp.concatenate(y1, axis=1)
    if not wide:
        end = jax.lax.cond(jnp.any(todo), lanes, lambda end, _: end, end, todo)
    elif unbranched:
        end = first(end, todo)
    else:  # a CPU: a branch is cheap, no host reads its predicate from an accelerator's memory
        end = jax.lax.cond(jnp.sum(todo) > n // CROWDED_AT, first, lanes, end, todo)
    return end[:, :d], end[:, d:]
