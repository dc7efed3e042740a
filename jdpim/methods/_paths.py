"""The two pipelines, DPIM and Monte Carlo, sharing one chunked, jitted simulation core.

Data flow: scene -> input rows (DPIM points or MC keys) -> forcing at the integrator's nodes (the excitation's
``from_inputs`` or ``from_keys``: spectral coefficients and an FFT, or Gaussian node values drawn inside the steps;
the scene's excitation, else the method's ``default_excitation``) -> RK4 trajectories (only the saved times kept) ->
:class:`Result`. Paths are processed in chunks
(``lax.map``) so memory stays bounded; every chunk is a pure function of its rows. Large runs are
streamed in blocks of chunks from a host loop, and the path axis is sharded over the local devices.
"""

from __future__ import annotations

import abc
import copy
import functools
import sys
import time
import warnings
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from .._checkpoint import digest
from .._cpu import host_memory, on_cpu
from .._distributions import elementary_ppf
from .._engine.batches import WIDE_CHUNK
from .._excitation import AbstractExcitation, Clock, Clocked, modulate
from .._integrate import integrate
from .._points import PointSet, select_points
from .._pytree import check_int, concrete
from .._scene import Scene, with_model_parameters
from ..results._samples import Result, model_constraints, nonfinite_counts
from ._ad_guard import guard, probed
from ._base import AbstractMethod

MEMORY_BUDGET = 512 * 2**20  # bytes of excitation work per chunk where the device does not report its memory
DEVICE_MEMORY_SHARE = 0.5  # share of an accelerator's memory one chunk's excitation work may take
# most bytes of one per-path number per chunk on a CPU (512 float32 or 256 float64 paths): above about
# 2.1 KiB the cost per path-step rises 1.2-2.5x (docs/speed.md)
CPU_CHUNK_BYTES = 2048
# most paths per chunk on a CPU with the noise drawn inside the steps (no excitation array): larger chunks pay
# there (docs/speed.md, "Chunk and block sizes on a CPU"), and chunks of WIDE_CHUNK paths or more resolve a step
# where many of them cross in one wide batch (docs/mdof.md)
NODES_CHUNK = 2 * WIDE_CHUNK


class NonFiniteWarning(RuntimeWarning):
    """Some paths produced non-finite or diverged states (blow-up); their mass is left out of every density."""


# a path whose coordinate or velocity exceeds this many times the scale its start and the noise give it (see
# divergence_scale) has diverged: its states are stored as NaN, counted and warned about like non-finite ones
DIVERGED = 1e6


def divergence_scale(scene: Scene) -> np.ndarray | None:
    """``(2 n,)``: how far a path's coordinates and velocities can plausibly reach by ``t_end``; ``None`` where the
    scene's parameters are traced.

    The velocity scale ``V = |v0| + |J| |x0| + |B| sqrt(2 |D| t_end) + |a0| t_end`` adds the start (``J`` the
    Jacobian of the model linearised at rest, infinity norms), the free growth of the noise's impulses (``B`` the
    accelerations per unit noise at rest) and of a constant force (``a0`` the acceleration at rest without noise, its
    largest over the run for a time-dependent model);
    coordinates reach ``|x0| + V t_end``. Random starts count with their mean plus ten
    standard deviations."""
    model, jac, d = scene.model, scene.model.linearised(), concrete(scene.noise.D)
    x0, v0 = (concrete(a) for a in scene.initial_state())
    if jac is None or d is None or x0 is None or v0 is None:
        return None
    start = {"x0": float(np.max(np.abs(x0))), "v0": float(np.max(np.abs(v0)))}
    for name, dist in scene.random:
        if name in start:
            start[name] += abs(dist.mean) + 10.0 * dist.std
    q = np.asarray(model.rest(), scene.float_dtype)
    n_times = 257 if model.time_dependent else 1  # a time-dependent load's forces at 257 times over the run
    args = (model, q, scene.n_sources, scene.t_end, n_times)
    gains = drift = None
    if all(concrete(leaf) is not None for leaf in jax.tree_util.tree_leaves(model)):
        gains, drift = (concrete(a) for a in _rest_forces(*args))  # one compiled program per model structure
    if gains is None or drift is None:  # traced parameters, or inside a jit trace: concrete where they are
        with jax.ensure_compile_time_eval():
            gains, drift = (concrete(a) for a in _rest_forces.__wrapped__(*args))
    if gains is None or drift is None:
        return None
    norm = np.max(np.sum(np.abs(jac), axis=1))
    kick = np.max(np.sum(np.abs(gains), axis=-1)) * np.sqrt(2.0 * np.max(np.abs(d)) * scene.t_end)
    v = start["v0"] + norm * start["x0"] + kick + np.max(np.abs(drift)) * scene.t_end
    n = model.dimension
    return np.concatenate([np.full(n, start["x0"] + v * scene.t_end), np.full(n, v)])


@functools.partial(jax.jit, static_argnums=(2, 4))
def _rest_forces(model, q, n_sources: int, t_end, n_times: int):
    """``(gains, drift)``: the accelerations per unit noise ``(T, n, n_sources)`` and without noise ``(T, n)`` of
    ``model`` at rest (coordinates ``q``, zero velocities) at ``n_times`` times over ``[0, t_end]``."""
    xi = jnp.zeros((n_sources,), q.dtype)
    times = jnp.linspace(0.0, t_end, n_times, dtype=q.dtype)

    def acceleration(xi, t):
        return model.state_acceleration_at(t, q, jnp.zeros_like(q), xi)

    return jax.vmap(jax.jacfwd(acceleration), (None, 0))(xi, times), jax.vmap(acceleration, (None, 0))(xi, times)


def divergence_bound(scene: Scene) -> np.ndarray | None:
    """``(2 n,)``: ``DIVERGED`` times :func:`divergence_scale`, the bound beyond which a state has diverged;
    ``None`` where the scene's parameters are traced."""
    scale = divergence_scale(scene)
    return None if scale is None else DIVERGED * scale


def beyond(states, bound):
    """Whether each state (the last axis, ``2 n``) of ``states`` lies beyond ``bound`` ``(2 n,)`` in some coordinate
    or velocity: a diverged state. Densities leave such states out (:func:`without_diverged`); first passage counts
    a path as lost from its first such state on, unless it has passed the level before
    (:class:`jdpim.tracking.RunningMaximum`)."""
    limit = jnp.asarray(bound, states.dtype).reshape((1,) * (states.ndim - 1) + (-1,))
    return jnp.any(jnp.abs(states) > limit, axis=-1)


def diverged(scene: Scene, states):
    """``(N, S)``: whether each path of ``states`` ``(N, S, 2 n)`` has been :func:`beyond`
    :func:`divergence_bound` at this or an earlier saved time (all ``False`` where the bound is traced)."""
    bound = divergence_bound(scene)
    if bound is None:
        return jnp.zeros(states.shape[:2], bool)
    return _diverged(states, bound)


@jax.jit
def _diverged(states, bound):
    return jnp.cumsum(beyond(states, bound), axis=1) > 0


def without_diverged(scene: Scene, states):
    """``states`` ``(N, S, 2 n)`` with those of paths that have :func:`diverged` set to NaN, so that they count as
    non-finite (``Result.n_nonfinite``)."""
    bound = divergence_bound(scene)
    return states if bound is None else _nan_diverged(states, bound)


@jax.jit
def _nan_diverged(states, bound):
    return jnp.where(_diverged(states, bound)[..., None], jnp.nan, states)


def _largest_chunk(scene: Scene, kind: str) -> int:
    """The most paths one chunk of method ``kind`` may hold: XLA indexes arrays with 32-bit integers."""
    return (2**31 - 1) // _values_per_path(scene, kind)


def _values_per_path(scene: Scene, kind: str) -> int:
    """Values one path of method ``kind`` holds in a chunk: its excitation's (a spectral excitation over the FFT
    grid), or where the noise is drawn inside the steps its saved states."""
    return excitation_of(scene, kind).values_per_path(scene) or 2 * scene.model.dimension * (len(scene.save_at) + 1)


def excitation_of(scene: Scene, kind: str) -> AbstractExcitation:
    """The excitation the sampling method named ``kind`` integrates ``scene`` with: the scene's, or where that is
    ``None`` the method's own (its ``default_excitation``)."""
    if scene.excitation is not None:
        return scene.excitation
    return SamplingMethod.named(kind).default_excitation


def memory_budget() -> int:
    """Bytes of excitation work per chunk: a share of the first local device's memory if it reports it.

    Otherwise (a CPU) ``MEMORY_BUDGET``, or less where the host's memory shared by the local devices, which
    run their chunks at once, calls for it: at most a quarter of it in all.
    """
    stats = jax.local_devices()[0].memory_stats() or {}
    if "bytes_limit" in stats:
        return int(DEVICE_MEMORY_SHARE * stats["bytes_limit"])
    return min(MEMORY_BUDGET, host_memory() // (4 * jax.local_device_count()))


def check_memory(scene: Scene, n_paths: int, name: str, input_bytes: int) -> None:
    """Fail at once, naming ``name``, when a run's saved states and inputs would not fit in half the host's memory.

    Counted per path: the saved states twice (device result and host copy, ``2 S`` values per path each)
    and ``input_bytes`` of inputs (DPIM: the point selection's work; Monte Carlo: the key).
    """
    need = n_paths * (2 * 2 * len(scene.save_at) * scene.float_dtype.itemsize + input_bytes)
    have = host_memory()
    if need > have // 2:
        raise ValueError(
            f"{name}={n_paths} needs about {need / 2**30:.3g} GiB for its saved states and inputs, more than half "
            f"of this host's {have / 2**30:.3g} GiB: use fewer {name}, or fewer saved times, and pool several runs"
        )


def default_chunk_size(scene: Scene, n_paths: int, kind: str) -> int:
    """Paths per chunk of method ``kind`` so that one chunk's excitation work stays within :func:`memory_budget`.

    On a CPU that is 512 MiB (about 800 paths of the reference scene), and at most 512 paths in float32
    or 256 in float64 (``CPU_CHUNK_BYTES``), above which XLA's CPU code takes longer per path. With
    :class:`jdpim.GaussianNodes` (no excitation array) a CPU's chunks hold up to ``NODES_CHUNK`` paths instead;
    those of ``WIDE_CHUNK`` paths or more resolve a step where many paths cross in one batch. On a GPU half its
    memory, as far as 32-bit indexing allows: a GPU's time per step barely grows with the paths in a chunk, so
    large chunks are what make it fast (``docs/speed.md``). The chunks are equal, of a size rounded up to one of
    ``SIZE_STEPS`` per octave within those limits (:func:`shared_size`), so that runs of nearby sizes share one
    compiled program.
    """
    bytes_per_path = 4 * scene.float_dtype.itemsize * _values_per_path(scene, kind)
    cpu = on_cpu()
    cap = CPU_CHUNK_BYTES // scene.float_dtype.itemsize if cpu else shared_size(n_paths)
    if cpu and excitation_of(scene, kind).values_per_path(scene) == 0:
        cap = NODES_CHUNK
    limit = max(1, min(cap, memory_budget() // bytes_per_path, _largest_chunk(scene, kind)))
    n_chunks = -(-n_paths // min(n_paths, limit))
    return min(limit, shared_size(-(-n_paths // n_chunks)))  # equal chunks, of a size that nearby runs share


def _monte_carlo_keys(scene: Scene, row):
    """The noise key ``(2,)`` (key data) and random-parameter values ``(n_random,)`` of one Monte Carlo path."""
    k_noise, k_par = jax.random.split(jax.random.wrap_key_data(row))
    n_rand = len(scene.random)
    u = jax.random.uniform(k_par, (n_rand,), jnp.float32, minval=1e-7, maxval=1.0 - 1e-7).astype(scene.float_dtype)
    rand = jnp.stack([elementary_ppf(d, u[j]) for j, (_, d) in enumerate(scene.random)]) if n_rand else u
    return jax.random.key_data(k_noise), rand


def path_forcing(scene: Scene, kind: str, rows):
    """``(forcing, rand)`` of a chunk of paths of method ``kind``: their forcing at the nodes (unit envelope) and
    their random-parameter values ``(n, n_random)``.

    DPIM rows are the excitation's elementary variables, then the random parameters; Monte Carlo rows are keys.
    """
    excitation = excitation_of(scene, kind)
    if kind == "dpim":
        k = len(excitation.input_distributions(scene.n_sources))
        return excitation.from_inputs(scene, rows[:, :k]), rows[:, k:]
    k_noise, rand = jax.vmap(functools.partial(_monte_carlo_keys, scene))(rows)
    return excitation.from_keys(scene, k_noise), rand


def _simulate_chunk(scene: Scene, kind: str, rows, track=None, layout=None):
    """States ``(n, S, 2 d)`` of one chunk of paths (and the values of ``track`` at the saved times: ``integrate``)."""
    return integrate_forcing(scene, *path_forcing(scene, kind, rows), track, layout)


def save_layout(scene: Scene):
    """``(slots, initial)``: the save slot written after each step, ``(T,)`` int32 (``S`` for none, ``S`` saved
    times), and the slot of ``t = 0`` (``S`` if it is not saved), as NumPy arrays."""
    n_save = len(scene.save_steps)
    slots = np.full(scene.n_steps, n_save, dtype=np.int32)  # slot written after step k (time k + 1)
    after = [(s - 1, i) for i, s in enumerate(scene.save_steps) if s > 0]
    if after:
        steps, idx = zip(*after, strict=True)
        slots[list(steps)] = idx
    initial = scene.save_steps.index(0) if 0 in scene.save_steps else n_save
    return slots, np.int32(initial)


def shared_scene(scene: Scene) -> Scene:
    """``scene`` with its saved times replaced by the last ``S`` steps of its grid: the one compiled program of every
    layout of ``S`` saved times, which then comes as data (:func:`save_layout`)."""
    k = len(scene.save_at)
    canonical = tuple(float(s) * scene.dt for s in range(scene.n_steps - k + 1, scene.n_steps + 1))
    if scene.save_at == canonical:
        return scene
    shared = copy.copy(scene)  # times on the grid, as the scene's checks would store them: no checks again (ms)
    object.__setattr__(shared, "save_at", canonical)
    return shared


def integrate_forcing(scene: Scene, excitation, rand, track=None, layout=None):
    """States ``(n, S, 2 d)`` of ``n`` paths under a given forcing (and ``track``'s values, see ``integrate``).

    ``excitation``: the unit-envelope forcing at the nodes (:class:`jdpim._excitation.AbstractNodes`), which the
    noise's envelope (if any) multiplies here; ``rand``: the random parameters ``(n, n_random)`` in the order of
    ``scene.random``; ``layout``: the saved times' :func:`save_layout` as arrays (``None``: the scene's, as constants).
    """
    dtype = scene.float_dtype
    excitation = modulate(excitation, scene.noise.envelope, scene.dt)
    clocked = scene.model.time_dependent  # the time reaches the model as the forcing's last column
    if clocked:
        excitation = Clock(excitation, scene.dt)
    names = tuple(name for name, _ in scene.random)
    model_names = tuple(n for n in names if n not in ("x0", "v0"))
    model_cols = jnp.asarray([names.index(n) for n in model_names], dtype=jnp.int32)

    def path_model(r):
        model = scene.model if r is None else with_model_parameters(scene.model, model_names, r[model_cols])
        return Clocked(model) if clocked else model

    shape = (rand.shape[0], scene.model.dimension)
    x_start, v_start = scene.initial_state()
    x0 = rand[:, names.index("x0"), None] if "x0" in names else jnp.broadcast_to(jnp.asarray(x_start, dtype), shape)
    v0 = rand[:, names.index("v0"), None] if "v0" in names else jnp.broadcast_to(jnp.asarray(v_start, dtype), shape)
    slots, initial = save_layout(scene) if layout is None else layout
    return integrate(
        path_model,
        scene.impacts,
        scene.dt,
        x0.astype(dtype),
        v0.astype(dtype),
        excitation,
        rand.astype(dtype),
        jnp.asarray(slots),
        len(scene.save_at),
        initial if layout is not None else int(initial),
        scene.substeps,
        track,
    )


def pad_rows(rows, pad: int):
    """``rows`` with ``pad`` copies of its first row appended (padding paths, dropped from the results); a NumPy
    array stays on the host (no program per size)."""
    xp = np if isinstance(rows, np.ndarray) else jnp
    return xp.concatenate([rows, xp.repeat(rows[:1], pad, axis=0)]) if pad else rows


def _simulate(scene: Scene, rows, layout=None, *, kind: str, chunk_size: int, track=None):
    SamplingMethod.named(kind)  # an unknown kind fails here, in one line
    # a chunk of one path compiles to code of its own, whose last bits differ: it runs with a padding path instead,
    # so that a path's states do not depend on the chunks (chunk_size=1, or one path per device)
    chunk_size = max(chunk_size, 2)
    n = rows.shape[0]
    pad = (-n) % chunk_size
    padded = pad_rows(rows, pad)
    chunks = padded.reshape(-1, chunk_size, *rows.shape[1:])
    out = jax.lax.map(functools.partial(_simulate_chunk, scene, kind, track=track, layout=layout), chunks)
    return jax.tree_util.tree_map(lambda a: a.reshape(-1, *a.shape[2:])[:n], out)


@functools.partial(jax.jit, static_argnames=("kind", "chunk_size"))
def simulate(scene: Scene, rows, layout=None, *, kind: str, chunk_size: int, track=None):
    """Saved states ``(N, S, 2)`` for input ``rows`` (``(N, d)`` DPIM points or ``(N, 2)`` MC key data).

    With ``track`` (a :class:`jdpim._integrate.Tracker`, a pytree: its array fields traced, the rest structure)
    the pair ``(states, tracked)``. ``layout``: the saved times as data (:func:`save_layout`), for a scene whose own
    saved times are then only their count (:func:`shared_scene`); ``None``: the scene's saved times.

    Jitted; differentiable with respect to every traced leaf of ``scene``. One device, one call; see
    :func:`run_paths` for sharding over devices and streaming in blocks.
    """
    return _simulate(scene, rows, layout, kind=kind, chunk_size=chunk_size, track=track)


def is_traced(tree) -> bool:
    return any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(tree))


def _devices(devices):
    """The devices to shard the path axis over: ``None`` means every local device."""
    if devices is None:
        return tuple(jax.local_devices())
    devices = tuple(devices)
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise ValueError(f"devices must be a non-empty sequence of jax.Device, got {devices!r}")
    return devices


SIZE_STEPS = 16  # chunk sizes per octave (sizes m 2**k, m = 16 .. 31): at most 1/16 of a chunk is padding


def shared_size(n: int) -> int:
    """``n`` paths rounded up to one of ``SIZE_STEPS`` chunk sizes per octave: runs whose chunks differ by less than
    a sixteenth share one compiled program, for at most ``1/16`` more paths (padding, dropped from the results; a
    path's states do not depend on its chunk)."""
    step = 1 << max(0, n.bit_length() - 5)
    return -(-n // step) * step


def balanced_chunk(n_paths: int, chunk_size: int, n_devices: int) -> int:
    """The chunk size for ``n_paths`` over ``n_devices``: equal chunks per device, none above ``chunk_size``, rounded
    up to a shared size (:func:`shared_size`) where that stays within ``chunk_size``.

    Each device then holds as few chunks as ``chunk_size`` allows, and as padding less than one path per chunk and
    a sixteenth of its paths.
    """
    share = -(-n_paths // n_devices)
    equal = -(-share // -(-share // chunk_size))
    return min(chunk_size, shared_size(equal))


def home_device(devices):
    """The device that gathers the states of a run over several CPU devices; ``None`` to keep them sharded.

    CPU devices share the host's memory, and computations on states sharded over them run XLA:CPU
    collectives, which we saw deadlock (``docs/speed.md``); states sharded over accelerators stay sharded.
    """
    return devices[0] if len(devices) > 1 and all(d.platform == "cpu" for d in devices) else None


@functools.lru_cache(maxsize=32)
def _sharded_simulate(kind: str, chunk_size: int, devices: tuple, tracked: bool = False):
    """``simulate`` with the path axis split over ``devices`` (one shard of whole chunks per device): a jitted
    ``(scene, rows) -> states``, or with ``tracked`` ``(scene, rows, track) -> (states, tracked)``."""
    mesh = jax.sharding.Mesh(np.asarray(devices), ("paths",))
    spec, whole = jax.sharding.PartitionSpec("paths"), jax.sharding.PartitionSpec()

    def local(scene, rows, *track):
        return _simulate(scene, rows, kind=kind, chunk_size=chunk_size, track=track[0] if tracked else None)

    specs = (whole, spec, whole) if tracked else (whole, spec)
    body = jax.shard_map(local, mesh=mesh, in_specs=specs, out_specs=spec, check_vma=False)
    return jax.jit(body), jax.sharding.NamedSharding(mesh, spec)


class _Progress:
    """A one-line text progress report on stderr (``paths done / total``, elapsed and remaining time)."""

    def __init__(self, total: int, label: str, enabled: bool):
        self.total, self.label, self.enabled, self.t0 = total, label, enabled, time.perf_counter()

    def update(self, done: int, out=None):
        """Report ``done`` paths, once ``out`` (the block just dispatched, if given) has been computed."""
        if not self.enabled:
            return
        jax.block_until_ready(out)
        elapsed = time.perf_counter() - self.t0
        eta = elapsed * (self.total - done) / max(done, 1)
        end = "\n" if done >= self.total else ""
        print(
            f"\r{self.label}: {done}/{self.total} paths, {elapsed:.1f} s, ~{eta:.0f} s left", end=end, file=sys.stderr
        )
        sys.stderr.flush()


def run_paths(
    scene: Scene,
    rows,
    *,
    kind: str,
    chunk_size: int,
    block_size=None,
    devices=None,
    progress=None,
    label="",
    track=None,
    checkpoint=None,
):
    """Saved states ``(N, S, 2)`` of ``rows``, sharded over ``devices`` and streamed in blocks of paths.

    The states come back sharded over accelerators, and on the first device from several CPU devices
    (:func:`home_device`).

    Args:
        scene, rows, kind, chunk_size: as for :func:`simulate`.
        block_size: most paths per call over all devices (``None``: 16 chunks per device); the blocks are made
            equal, of whole chunks on every device, so that little padding is computed. Larger runs are
            processed block by block in a host loop, each block's saved states moved to host memory, so that
            memory is bounded by one block whatever ``N``; the result is then one array.
        devices: devices to shard the path axis over (``None``: every local device). Each path is a
            pure function of its row, so the states do not depend on the devices or the blocks.
        progress: report progress on stderr (``None``: only when there is more than one block).
        label: the progress line's prefix.
        track: a quantity carried along every step (a :class:`jdpim._integrate.Tracker`); then the pair
            ``(states, tracked)`` is returned.
        checkpoint: a :class:`jdpim._checkpoint.Session` (``jdpim.solve(..., checkpoint=...)``) or ``None``:
            the blocks are then of its ``every`` paths, those it holds are loaded and the others written to it
            as they finish.

    Under ``jax.distributed`` (more than one process) the rows are split over the processes and the states
    gathered on every one (:func:`_across_processes`).

    Under a JAX transformation (traced scene or rows) this is :func:`simulate`, unsharded and unstreamed;
    differentiating paths that start at rest on the barrier then warns (``SensitivityWarning``: pathwise
    derivatives through that grazing impact are biased).
    """
    if is_traced((scene, rows)):
        if checkpoint is not None:
            raise ValueError("checkpoint applies to concrete runs, not under a JAX transformation (jit, grad, vmap)")
        run = functools.partial(simulate, kind=kind, chunk_size=chunk_size, track=track)
        return run(guard(scene), rows) if track is not None else probed(run, guard(scene), rows)
    local = functools.partial(
        _run_local,
        kind=kind,
        chunk_size=chunk_size,
        block_size=block_size,
        devices=devices,
        progress=progress,
        label=label,
        track=track,
        checkpoint=checkpoint,
    )
    return _across_processes(scene, rows, local, devices) if jax.process_count() > 1 else local(scene, rows)


def _across_processes(scene: Scene, rows, local, devices):
    """``local(scene, rows)`` with the rows split over the processes of ``jax.distributed``.

    Each process integrates an equal, contiguous share of the rows on its own devices (the last share padded
    with copies of the first row), and the shares are gathered on every process, so that densities, moments,
    error bars and estimators are then computed from the same states everywhere. A path is a pure function of
    its row: the states are those of one process.
    """
    from jax.experimental import multihost_utils

    n, count, index = rows.shape[0], jax.process_count(), jax.process_index()
    share = -(-n // count)
    mine = pad_rows(rows, share * count - n)[index * share : (index + 1) * share]
    out = jax.tree_util.tree_map(np.asarray, local(scene, mine))
    gathered = multihost_utils.process_allgather(out, tiled=True)
    return jax.tree_util.tree_map(lambda a: jax.device_put(np.asarray(a)[:n], _devices(devices)[0]), gathered)


def _chunk_by_chunk(scene: Scene, rows, *, layout, kind, chunk_size, track, device):
    """:func:`simulate` of ``rows`` (whole chunks) on one device, called once per chunk: one compiled program per
    chunk size, whatever the number of chunks (each chunk is a pure function of its rows: the states are those of
    one call over every chunk)."""
    one = functools.partial(simulate, layout=layout, kind=kind, chunk_size=chunk_size, track=track)
    if rows.shape[0] == chunk_size:
        return one(scene, rows)
    host = np.asarray(rows)
    parts = [one(scene, jax.device_put(host[i : i + chunk_size], device)) for i in range(0, len(host), chunk_size)]
    return jax.tree_util.tree_map(lambda *a: jax.device_put(np.concatenate(a), device), *parts)


def _run_local(scene: Scene, rows, *, kind, chunk_size, block_size, devices, progress, label, track, checkpoint):
    """:func:`run_paths` on this process's devices."""
    devices = _devices(devices)
    if checkpoint is not None and checkpoint.every is not None:
        block_size = checkpoint.every
    n = rows.shape[0]
    chunk_size = balanced_chunk(n, chunk_size, len(devices))
    unit = chunk_size * len(devices)
    block = 16 * unit if block_size is None else check_int("block_size", block_size, low=1)
    per_block = -(-n // -(-n // block))  # the paths split equally over the fewest blocks of at most `block`
    block = -(-per_block // unit) * unit  # whole chunks on every device
    n_blocks = -(-n // block)
    if len(devices) == 1:  # one program for every layout of as many saved times: the times come as data
        layout = save_layout(scene)
        run = functools.partial(
            _chunk_by_chunk, layout=layout, kind=kind, chunk_size=chunk_size, track=track, device=devices[0]
        )
        scene = shared_scene(scene)
        sharding = jax.sharding.SingleDeviceSharding(devices[0])
    else:
        fn, sharding = _sharded_simulate(kind, chunk_size, devices, track is not None)
        run = fn if track is None else lambda scene, rows: fn(scene, rows, track)
    bar = _Progress(n, label or kind, n_blocks > 1 if progress is None else bool(progress))
    pad = n_blocks * block - n
    rows = pad_rows(np.asarray(rows), pad)  # on the host: the rows of a block go to the devices as they run
    home = home_device(devices)
    if n_blocks == 1 and checkpoint is None:
        out = run(scene, jax.device_put(rows, sharding))
        bar.update(n, out)
        if home is not None:
            out = jax.device_put(out, home)
        return jax.tree_util.tree_map(lambda a: a[:n], out) if pad else out
    parts = []
    if checkpoint is not None:  # what its parts cover: these rows, in these blocks
        index = checkpoint.next_run()
        covers = {"kind": kind, "paths": n, "chunk": chunk_size, "block": block, "rows": digest(rows)}
    for b in range(n_blocks):
        name = f"paths{index}-block{b}.npz" if checkpoint is not None else None
        out = None if checkpoint is None else checkpoint.load(name, covers)
        if out is None:
            out = run(scene, jax.device_put(rows[b * block : (b + 1) * block], sharding))
            out = jax.tree_util.tree_map(np.asarray, out)
            if checkpoint is not None:
                checkpoint.store(name, covers, out)
        parts.append(out)
        bar.update(min(n, (b + 1) * block))
    target = home or (sharding if n % len(devices) == 0 else devices[0])
    return jax.tree_util.tree_map(lambda *a: jax.device_put(np.concatenate(a)[:n], target), *parts)


@jax.jit
def _finished_states(states, bound):
    """``states`` with those of diverged paths set to NaN where ``bound`` is given (:func:`without_diverged`), and
    the number of paths with non-finite states per saved time (``Result.n_nonfinite``): one compiled program."""
    states = states if bound is None else _nan_diverged(states, bound)
    return states, nonfinite_counts(states)


def _finish(scene: Scene, states, weights, method: str) -> Result:
    states, counts = _finished_states(states, divergence_bound(scene))
    model = scene.model
    constraints, independent = model_constraints(model), SamplingMethod.named(method).independent
    res = Result(scene.save_at, states, weights, model.bounds(), method, model.coordinates, constraints, independent)
    counts = concrete(counts)
    if counts is not None and counts.any():
        warnings.warn(
            f"{int(counts.max())} of {res.n_paths} paths have non-finite or diverged states (beyond {DIVERGED:g} "
            f"times the reach of their start and the noise; per saved time: "
            f"{counts.tolist()}); their probability is left out of the densities "
            "(Result.lost_mass). Reduce dt or the excitation level, or sub-step stiff steps "
            "(Scene(..., substeps=jdpim.Substeps())).",
            NonFiniteWarning,
            stacklevel=3,
        )
    return res


def dpim_input_distributions(scene: Scene) -> tuple:
    """Distributions of a scene's DPIM input space: the elementary variables of its excitation (``(Theta1,
    Theta2)`` per source for the spectral representation), then its random parameters."""
    excitation = excitation_of(scene, "dpim")
    return excitation.input_distributions(scene.n_sources) + tuple(d for _, d in scene.random)


def dpim_points(scene: Scene, n_points: int = 1000) -> PointSet:
    """The representative point set of a scene's input space (cached; see ``jdpim.select_points``)."""
    return select_points(dpim_input_distributions(scene), n_points)


def _chunk(scene: Scene, n: int, chunk_size: int | None, kind: str) -> int:
    if chunk_size is None:
        return default_chunk_size(scene, n, kind)
    chunk = min(check_int("chunk_size", chunk_size, low=1), n)
    largest = _largest_chunk(scene, kind)
    if chunk > largest:  # larger chunks came back all NaN on a GPU
        raise ValueError(
            f"chunk_size={chunk_size} exceeds {largest} for this scene: one chunk's excitation would hold more "
            "than 2**31 - 1 elements, beyond XLA's 32-bit indexing"
        )
    return chunk


def dpim_inputs(scene: Scene, n_points: int = 1000, *, points: PointSet | None = None, chunk_size=None):
    """``(rows, weights, chunk_size)`` of a DPIM run: the points ``(N, d)``, their probabilities ``(N,)``."""
    distributions = dpim_input_distributions(scene)
    if points is None:
        check_int("n_points", n_points, low=2)
        check_memory(scene, n_points, "n_points", 64 * len(distributions))
        points = dpim_points(scene, n_points)
    elif not isinstance(points, PointSet):
        raise TypeError(f"points must be a jdpim.PointSet, got {type(points).__name__}")
    elif tuple(points.distributions) != distributions:
        raise ValueError(f"points.distributions do not match the scene's input space {distributions}")
    dtype = scene.float_dtype
    rows, weights = (_on_device(a, dtype) for a in (points.theta, points.weights))
    return rows, weights, _chunk(scene, points.n_points, chunk_size, "dpim")


def _on_device(value, dtype):
    """``value`` as a JAX array of ``dtype``: a NumPy array converted on the host (no compiled program for it)."""
    return jnp.asarray(value, dtype) if isinstance(value, jax.Array) else jax.device_put(np.asarray(value, dtype))


def monte_carlo_inputs(scene: Scene, n_samples: int = 10_000, *, seed: int = 0, chunk_size=None):
    """``(rows, weights, chunk_size)`` of a Monte Carlo run: per-path key data ``(n, 2)``, weights ``1/n``."""
    n = check_int("n_samples", n_samples, low=2)
    seed = check_int("seed", seed, low=0)
    check_memory(scene, n, "n_samples", 8)
    keys, weights = _monte_carlo_rows(np.int64(seed), n, scene.float_dtype)
    return keys, weights, _chunk(scene, n, chunk_size, "monte_carlo")


@functools.partial(jax.jit, static_argnums=(1, 2))
def _monte_carlo_rows(seed, n: int, dtype):
    """Key data ``(n, 2)`` of ``n`` paths (the key of the integer ``seed``, as ``jax.random.key`` reads a Python
    integer, split ``n`` ways) and their weights ``1 / n``: one compiled program per ``n`` and dtype."""
    return jax.random.key_data(jax.random.split(jax.random.key(seed), n)), jnp.full((n,), 1.0 / n, dtype)


class SamplingMethod(AbstractMethod):
    """A method that integrates weighted paths (DPIM points or Monte Carlo samples) in the shared core.

    Subclasses give ``inputs(scene) -> (rows, weights, chunk_size)``, the fields ``chunk_size``, ``devices`` and
    ``progress``, and the class attributes ``name``, ``default_excitation`` (the forcing it integrates a scene
    with where the scene names none, ``Scene(excitation=None)``) and ``independent`` (whether its paths are
    independent samples, so that its estimates have sampling standard errors).

    Questions on paths (first passage, impact statistics, sensitivities, :func:`jdpim.tracking.track`) ask a
    sampling method for its ``inputs`` and run them with :meth:`paths`, tracking what they need along the steps.
    """

    chunk_size: int | None
    devices: tuple | None
    progress: bool | None
    default_excitation: ClassVar[AbstractExcitation]
    independent: ClassVar[bool]  # its paths are independent samples: its estimates have sampling standard errors
    _registry: ClassVar[dict] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            SamplingMethod._registry[cls.name] = cls

    @staticmethod
    def named(name: str) -> type[SamplingMethod]:
        """The sampling method class whose results carry ``name`` (``"dpim"``, ``"monte_carlo"``)."""
        if name not in SamplingMethod._registry:
            raise ValueError(f"kind must be one of {tuple(SamplingMethod._registry)}, got {name!r}")
        return SamplingMethod._registry[name]

    def excitation(self, scene: Scene) -> AbstractExcitation:
        """The excitation this method integrates ``scene`` with: the scene's, else its ``default_excitation``."""
        return excitation_of(scene, self.name)

    @abc.abstractmethod
    def inputs(self, scene: Scene) -> tuple:
        """``(rows, weights, chunk_size)``: per-path inputs ``(N, d)``, path probabilities ``(N,)``, paths per chunk."""

    resumable = True  # solve(..., checkpoint=...) applies

    def run(self, scene: Scene, checkpoint=None) -> Result:
        rows, weights, chunk = self.inputs(scene)
        states = self.paths(scene, rows, chunk, checkpoint=checkpoint)
        return _finish(scene, states, weights, self.name)

    def paths(self, scene: Scene, rows, chunk_size: int, track=None, checkpoint=None):
        """The saved states ``(N, S, 2 d)`` of the input ``rows`` (from :meth:`inputs`), integrated in chunks of
        ``chunk_size`` paths on this method's devices (:func:`run_paths`); with ``track`` (a
        :class:`jdpim.tracking.AbstractTracked`) the pair ``(states, values)``, the values ``(N, S, k)`` tracked
        along every step at the saved times. The primitive every question on paths asks for; with ``checkpoint``
        (the job's :class:`jdpim._checkpoint.Session`) its finished blocks are kept and reused."""
        return run_paths(
            scene,
            rows,
            kind=self.name,
            chunk_size=chunk_size,
            devices=self.devices,
            progress=self.progress,
            track=track,
            checkpoint=checkpoint,
        )


def check_run_settings(method) -> None:
    """Check the settings every sampling method shares: ``chunk_size``, ``devices``, ``progress``."""
    if method.chunk_size is not None:
        check_int("chunk_size", method.chunk_size, low=1)
    if method.devices is not None:
        object.__setattr__(method, "devices", _devices(method.devices))
    if method.progress is not None and not isinstance(method.progress, bool):
        raise TypeError(f"progress must be None, True or False, got {method.progress!r}")
