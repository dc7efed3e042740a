r"""The resolution of a step's crossings: the crossing paths gathered in small batches, resolved and scattered back.

A compact batch (:func:`compact`) takes up to :func:`compact_rows` (``ceil(n / 64)``) pending paths, the first two of
each of ``ceil(n / 32)`` runs of paths (:func:`pending_in_runs`: elementwise, where ``jnp.nonzero`` over every path
costs more than the resolution), gathers their rows column by column, resolves up to ``max_impacts`` impacts of each on
these few rows (:func:`resolve_batch`, one kernel on a CPU: :func:`.one_kernel.one_kernel`) and scatters their end
states back into ``q`` and ``v``. Every loop that runs on the batch touches only its small arrays. Compact batches run
until none is pending, in a ``while_loop`` (:func:`until_done`): a step whose crossings fit in one batch runs one, and
the loop's control costs one test per batch. Derivatives take the same batches as a binary tree of ``fori_loop`` of
two iterations whose subtrees are skipped once no path is pending (:func:`tree`): its static trip counts (``2**depth``
batches serve any step, :func:`compact_depth`) are what reverse mode needs. The resolution is traced once either way.
Compact batches serve every step of a CPU's chunks, and of an accelerator's chunks of fewer than ``WIDE_CHUNK`` paths.

An accelerator's chunk of ``WIDE_CHUNK`` paths or more has a wide batch (:func:`wide_first`): up to ``cap``
(``ceil(n / 16)``, :func:`batch_rows`) crossing paths, taken in order and gathered column by column, every round on
every row; batches of the first pending path of each of ``cap`` lanes of ``G = 16`` paths (:func:`one_batch`,
:func:`batches`) serve the crossings beyond it. It runs in every step without branches: every branch costs a read of
its predicate by the host and kernels of its own, which set the cost of a step (docs/speed.md). On a CPU a branch is
cheap, and compact batches serve even the impact damper's crowded steps faster than a wide batch, in a program with
one copy of the resolution.

The paths at rest on the barrier (one degree of freedom) are pending too: every path's step starts with the plain
RK4 step from the step's start, and the batch restarts a resting path where the force pulls it off
(:func:`resolve_batch`). A branch over every path for the few at rest would cost more in every step than these rows.

A compact batch resolves each row by the same function whatever the batch's rows (rounds under ``lax.cond``), so a
path's end state does not depend on which batch serves it; the wide batch runs every round on every row without
branches, which XLA fuses differently, and agrees with it to rounding.
"""

from __future__ import annotations

import functools
import itertools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from .._cpu import on_cpu
from .elementwise import along_paths
from .loops import while_differentiated_as
from .one_kernel import one_kernel
from .one_path import Engine, each, from_rest, per_path, resolve, resolve_event, rests, to_locate

# an accelerator's chunks of at least this many paths resolve their crossings in a wide batch first, of a
# WIDE_SHARE-th of the paths, in every step, without branches (docs/mdof.md)
WIDE_CHUNK = 8192
WIDE_SHARE = 16
# a batch of more rows than this has a multiple of them: XLA's CPU code for a batch of an odd number of rows is
# markedly slower per step
BATCH_ROWS = 8
# a compact batch takes the first two pending paths of each run of this many paths
PICK_RUN = 32


def branch_free(n: int) -> bool:
    """Whether a chunk of ``n`` paths resolves its crossings without branches: a wide chunk on an accelerator."""
    return n >= WIDE_CHUNK and not on_cpu()


def batch_rows(n: int) -> int:
    """Rows of a wide batch in a chunk of ``n`` paths: ``ceil(n / WIDE_SHARE)``, rounded up to a multiple of
    ``BATCH_ROWS`` above it (XLA's CPU code is markedly slower per step for batches of an odd number of rows)."""
    cap = -(-n // WIDE_SHARE)
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


STEP_ENDS = slice(2, 4)  # the columns of the step's ends (q, v) in pack's order: y0 (2), y1 (2), ...


def pack(eng: Engine, y0, y1, e, rand, h, held, force):
    """The per-path inputs of a chunk's step as a tuple of ``(n, width)`` columns, and their :class:`Packing`."""
    per_path_h = jnp.ndim(h) != 0
    e = tuple(e) if isinstance(e, (tuple, list)) else tuple(e[:, i] for i in range(3))
    columns = (*y0, *y1, *e, rand) + ((h[:, None],) if per_path_h else ())
    if eng.holding:
        columns = columns + (force, held.astype(force.dtype)[:, None])
    return columns, Packing(y0[0].shape[0], tuple(c.shape[1] for c in columns), None if per_path_h else h)


def unpack(packing: Packing, rows):
    """``(y0, tau0, y1, e, rand, h, held_columns)`` of the rows of a batch (:func:`pack`); ``tau0``, the fraction of
    the step ``y0`` is at, is 0 (every step starts at the step's start)."""
    parts = jnp.split(rows, list(itertools.accumulate(packing.widths))[:-1], axis=1)
    q0, v0, q1, v1, e0, e1, e2, r = parts[:8]
    t0 = jnp.zeros(q0.shape[:1], q0.dtype)
    h = parts[8][:, 0] if packing.h is None else packing.h
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
    if eng.sticking:  # its paths at rest start where the force pulls them off (a compact batch: if it holds one)
        resting = each(rests, eng)(*b0, br)

        def restart(b1):
            *moved, tau = from_rest(eng, *b0, be, br, bh)
            return tuple(jnp.where(along_paths(resting, a), a, b) for a, b in zip(moved, b1, strict=True)), tau

        b1, t0 = restart(b1) if wide else jax.lax.cond(jnp.any(resting), restart, lambda b1: (b1, t0), b1)
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


def one_batch(eng: Engine, packing: Packing, carry, in_order: bool = False):
    """One wide batch: up to ``batch_rows`` pending paths of ``carry = (columns, end, todo, any pending)`` resolved,
    their end states scattered into ``end`` and their ``todo`` cleared; taken in order or the first of every lane
    (``in_order``)."""
    source, end, todo, _ = carry
    n = packing.n
    cap = batch_rows(n)

    def ordered(todo):
        return jnp.nonzero(todo, size=cap, fill_value=n)[0].astype(jnp.int32)

    def by_lanes(todo):
        return first_in_lanes(todo, cap).astype(jnp.int32)

    idx = ordered(todo) if in_order else by_lanes(todo)
    # the columns themselves: packing them would copy every path in every step
    rows = jnp.concatenate([c.at[idx].get(mode="clip") for c in source], axis=1)
    end = end.at[idx].set(resolve_batch(eng, packing, rows, True), mode="drop")
    todo = todo.at[idx].set(False, mode="drop")
    return source, end, todo, jnp.any(todo)


def tree(leaf, carry, depth: int):
    """``carry`` if no path is pending (``carry[-1]``), else up to ``2**depth`` calls of ``leaf`` (one batch each):
    two subtrees of ``depth - 1``, in a ``fori_loop`` of two iterations."""

    def run(carry):
        if depth == 0:
            return leaf(carry)
        return jax.lax.fori_loop(0, 2, lambda _, c: tree(leaf, c, depth - 1), carry)

    return jax.lax.cond(carry[-1], run, lambda c: c, carry)


def until_done(leaf, carry, depth: int):
    """``leaf`` (one batch) called until no path is pending (``carry[-1]``): a ``while_loop`` of as many calls as the
    step needs, differentiated as the :func:`tree` of up to ``2**depth`` calls, which gives the same values
    (:func:`.loops.while_differentiated_as`)."""
    return while_differentiated_as(lambda cond, body, c: tree(body, c, depth), lambda c: c[-1], leaf, carry)


def depth_for(n: int, rows: int) -> int:
    """Depth of a :func:`tree` of batches of ``rows`` rows that serves any step of ``n`` paths."""
    return (-(-n // rows) - 1).bit_length()


def batches(eng: Engine, packing: Packing, carry):
    """``carry`` with every pending path resolved by wide batches of the first pending path of every lane."""
    return tree(functools.partial(one_batch, eng, packing), carry, depth_for(packing.n, batch_rows(packing.n)))


def wide_first(eng: Engine, packing: Packing, columns, end, todo):
    """The end states with a wide batch of the pending paths in order resolved first, in every step, then the rest by
    lanes."""
    first = one_batch(eng, packing, (columns, end, todo, True), in_order=True)
    return batches(eng, packing, first)[1]


def compact_rows(n: int) -> int:
    """Rows of a compact batch (:func:`compact`) in a chunk of ``n`` paths: ``ceil(n / 64)``, at least 2, rounded up to
    a multiple of ``BATCH_ROWS`` above it (XLA's CPU code is markedly slower per step for batches of an odd number of
    rows, and a batch of fewer rows takes code of its own, whose last bits differ). A batch of one row would leave
    every stored value of its resolution (:func:`.elementwise.stored`) to be computed again by each of its users: XLA
    folds a reduction with one element of output into elementwise code, and the program grows to about twice its
    size (the reference scene's, at 64 paths: 9063 instructions against 4820), for the same states."""
    cap = max(2, -(-n // 64))
    return min(n, -(-cap // BATCH_ROWS) * BATCH_ROWS) if cap > BATCH_ROWS else min(n, cap)


def first_two(runs):
    """Indices of the first two true entries of every column of ``runs`` ``(G, L)`` bool, ``G`` where there are fewer:
    ``(first, second)``, each ``(L,)`` int32.

    A chain of elementwise selects over the ``G`` rows, which XLA fuses into one pass over contiguous columns: on a
    CPU, reductions over the rows (``jnp.argmax``, or a minimum of the true entries' indices) take several times as
    long."""
    first = second = jnp.full(runs.shape[1:], runs.shape[0], jnp.int32)
    for j in reversed(range(runs.shape[0])):
        second = jnp.where(runs[j], first, second)
        first = jnp.where(runs[j], j, first)
    return first, second


# the most entries first_true ranks by population counts (its count of the words before each word takes
# (m / PREFIX_WORD)**2 terms); longer masks take jnp.nonzero
PREFIX_MAX = 4096
PREFIX_WORD = 32


def first_true(mask, size: int):
    """Indices of the first ``size`` true entries of ``mask`` (``(m,)`` bool) in order, ``m`` past the last: the
    indices of ``jnp.nonzero(mask, size=size, fill_value=m)``.

    Each true entry's rank is its prefix count, from the mask packed into 32-bit words: the population count of
    its own word below it plus those of the words before it (exact integers); a scatter puts its index at its rank.
    ``jnp.nonzero`` takes its prefix counts as XLA's cumulative sum, a tree of some ten kernels on a CPU, and
    products with triangular matrices of ones cost several times these few elementwise kernels on a batch's few
    hundred candidates. Masks of more than ``PREFIX_MAX`` entries take ``jnp.nonzero``: the same indices.
    """
    m = mask.shape[0]
    if m > PREFIX_MAX:
        return jnp.nonzero(mask, size=size, fill_value=m)[0].astype(jnp.int32)
    words = -(-m // PREFIX_WORD)
    bit = jnp.arange(PREFIX_WORD, dtype=jnp.uint32)
    bits = jnp.pad(mask, (0, words * PREFIX_WORD - m)).reshape(words, PREFIX_WORD).astype(jnp.uint32)
    packed = jnp.sum(bits << bit[None, :], axis=1, dtype=jnp.uint32)  # (words,): entry i of a word is its bit i
    counts = jax.lax.population_count(packed).astype(jnp.int32)
    word = jnp.arange(words)
    before = jnp.sum(jnp.where(word[None, :] < word[:, None], counts[None, :], 0), axis=1)
    below = jnp.where(bit == 0, jnp.uint32(0), jnp.uint32(0xFFFFFFFF) >> (PREFIX_WORD - bit))  # bits 0 .. i - 1
    within = jax.lax.population_count(packed[:, None] & below[None, :]).astype(jnp.int32)
    rank = (within + before[:, None]).reshape(-1)[:m]
    target = jnp.where(mask, rank, size)  # size: beyond the output, dropped
    return jnp.full((size,), m, jnp.int32).at[target].set(jnp.arange(m, dtype=jnp.int32), mode="drop")


def pending_in_runs(todo, rows: int):
    """Indices of up to ``rows`` pending paths (``todo``, ``(n,)`` bool), ``n`` past the last: the first two of each
    run of ``PICK_RUN`` paths, run ``l`` of ``L = ceil(n / PICK_RUN)`` holding the paths ``l, l + L, l + 2 L, ...``
    (:func:`first_two`: elementwise over contiguous paths), compacted by :func:`first_true` over these few
    candidates (over all ``n`` paths it costs some 150 us for 1e4 on a CPU, more than a batch's resolution). A third
    pending path of a run waits for the next batch. A batch resolves each row by the same function whatever its
    rows and their order (:func:`compact`), so which batch takes a path does not change its end state."""
    n = todo.shape[0]
    lanes = -(-n // PICK_RUN)
    runs = jnp.pad(todo, (0, lanes * PICK_RUN - n)).reshape(PICK_RUN, lanes)
    first, second = first_two(runs)
    picked = jnp.stack([first < PICK_RUN, second < PICK_RUN], axis=1).reshape(-1)
    candidates = jnp.stack([first, second], axis=1) * lanes + jnp.arange(lanes, dtype=jnp.int32)[:, None]
    candidates = jnp.append(candidates.reshape(-1), n)
    return candidates[first_true(picked, rows)]


def compact(eng: Engine, packing: Packing, columns, carry):
    """One compact batch: up to :func:`compact_rows` pending paths of ``carry = ((q, v), todo, any pending)``
    (:func:`pending_in_runs`), their rows gathered column by column, resolved, scattered back into ``q`` and
    ``v`` and cleared from ``todo``."""
    y1, todo, _ = carry
    n, d = y1[0].shape
    idx = pending_in_runs(todo, compact_rows(n))
    # the step's ends from the carry: a pending path's are still those of its free step, and the step's own copy
    # would have to outlive the carry's updates (a copy of every path's state in every step)
    columns = columns[: STEP_ENDS.start] + y1 + columns[STEP_ENDS.stop :]
    rows = jnp.concatenate([c.at[idx].get(mode="clip") for c in columns], axis=1)
    end = one_kernel(functools.partial(resolve_batch, eng, packing, wide=False), rows)
    y1 = tuple(y.at[idx].set(part, mode="drop") for y, part in zip(y1, (end[:, :d], end[:, d:]), strict=True))
    todo = todo.at[idx].set(False, mode="drop")
    return y1, todo, jnp.any(todo)


def compact_depth(n: int) -> int:
    """Depth of the :func:`tree` of compact batches that serves any step of ``n`` paths. A batch takes
    :func:`compact_rows` paths (at most ``n // rows`` such batches), or else every run's first two
    (:func:`pending_in_runs`), which empties every run, of at most ``min(n, PICK_RUN)`` paths, within
    ``ceil(min(n, PICK_RUN) / 2)`` such batches; one batch takes a chunk of at most two paths."""
    if n <= 2:
        return 0
    return (n // compact_rows(n) + -(-min(n, PICK_RUN) // 2) - 1).bit_length()


def resolve_crossings(eng: Engine, y0, y1, e, rand, h, held=None, force=None, departs=None):
    """Every located impact of the step from ``y0`` to ``y1`` (every path's plain step, from the step's start):
    ``y1`` with each crossing path's impacts resolved and each path at rest restarted (with ``held``, the
    constraint each path is held on, ``force``, its stage forces, and ``departs``, whether it lets go inside the
    step: every event of :func:`resolve_held`), by batches of the crossing paths (see the module's text)."""
    n, d = y0[0].shape
    unbranched = branch_free(n)
    columns, packing = pack(eng, y0, y1, e, rand, h, held, force)
    todo = each(to_locate, eng)(y0, y1, rand) if held is None else each(to_locate, eng)(y0, y1, rand, held) | departs
    if eng.sticking:
        todo = todo | each(rests, eng)(*y0, rand)

    def by_compact(y1, todo):  # compact batches until none is pending (one where few paths cross)
        leaf = functools.partial(compact, eng, packing, columns)
        return until_done(leaf, (y1, todo, jnp.any(todo)), compact_depth(n))[0]

    if not unbranched:
        return by_compact(y1, todo)
    end = wide_first(eng, packing, columns, jnp.concatenate(y1, axis=1), todo)
    return end[:, :d], end[:, d:]
