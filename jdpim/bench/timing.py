"""Timed DPIM and Monte Carlo runs with a fixed protocol: AOT compile, warm-up, repeats, median."""

from __future__ import annotations

import dataclasses
import statistics
import time

import jax

from .._scene import Scene
from ..methods._paths import (
    _finish,
    _sharded_simulate,
    balanced_chunk,
    dpim_inputs,
    home_device,
    monte_carlo_inputs,
    pad_rows,
    simulate,
)
from ..results._samples import Result


def protocol(repeats: int | str) -> str:
    """The timing protocol of :func:`timed` in words, for the benchmark's record."""
    return (
        f"each configuration compiled ahead of time (compile_s, apart), run once to warm up, then timed {repeats} "
        "times; the median wall time; the clock covers the excitation, the integration and the transfer of the "
        "saved states"
    )


@dataclasses.dataclass(frozen=True)
class Timing:
    """Wall times in s of one configuration: ``compile_s`` (AOT), every warm run, and their median."""

    method: str
    n_paths: int
    n_steps: int
    compile_s: float
    runs_s: tuple[float, ...]
    devices: int = 1

    @property
    def median_s(self) -> float:
        return statistics.median(self.runs_s)

    @property
    def path_steps_per_s(self) -> float:
        return self.n_paths * self.n_steps / self.median_s

    def row(self) -> dict:
        return {
            "method": self.method,
            "n_paths": self.n_paths,
            "devices": self.devices,
            "compile_s": round(self.compile_s, 3),
            "median_s": round(self.median_s, 4),
            "repeats": len(self.runs_s),
            "path_steps_per_s": float(f"{self.path_steps_per_s:.3g}"),
        }


def prepared(method: str, scene: Scene, n: int, *, seed: int = 0, points=None, chunk_size=None, devices=None):
    """``(compile_s, run, finish)`` of ``method`` (``"dpim"`` or ``"monte_carlo"``) with ``n`` paths: the seconds of
    its ahead-of-time compilation, ``run()`` (one call: the saved states, blocked until ready) and
    ``finish(states)`` (the :class:`jdpim.Result`). See :func:`timed` for ``devices``."""
    if method == "dpim":
        rows, weights, chunk = dpim_inputs(scene, n, points=points, chunk_size=chunk_size)
    elif method == "monte_carlo":
        rows, weights, chunk = monte_carlo_inputs(scene, n, seed=seed, chunk_size=chunk_size)
    else:
        raise ValueError(f"method must be 'dpim' or 'monte_carlo', got {method!r}")
    n, n_devices = int(rows.shape[0]), 1 if devices is None else len(devices)
    t0 = time.perf_counter()
    if n_devices == 1:
        compiled = simulate.lower(scene, rows, kind=method, chunk_size=chunk).compile()
    else:
        chunk = balanced_chunk(n, chunk, n_devices)
        fn, sharding = _sharded_simulate(method, chunk, tuple(devices))
        pad = (-n) % (chunk * n_devices)
        rows = jax.device_put(pad_rows(rows, pad), sharding)
        compiled = fn.lower(scene, rows).compile()
    compile_s = time.perf_counter() - t0
    home = None if devices is None else home_device(tuple(devices))

    def finish(states):
        return _finish(scene, (states if home is None else jax.device_put(states, home))[:n], weights, method)

    return compile_s, lambda: jax.block_until_ready(compiled(scene, rows)), finish


def interleaved(runs, repeats: int) -> list[tuple[float, float]]:
    """The median wall time and the median process CPU time (s, every thread) of each of ``runs`` (callables):
    each run once to warm up, then ``repeats`` rounds that run every one once in turn, so that a load that comes
    and goes weighs on all alike."""
    for run in runs:
        run()
    wall, cpu = [[] for _ in runs], [[] for _ in runs]
    for _ in range(max(1, repeats)):
        for i, run in enumerate(runs):
            t0, c0 = time.perf_counter(), time.process_time()
            run()
            wall[i].append(time.perf_counter() - t0)
            cpu[i].append(time.process_time() - c0)
    return [(statistics.median(w), statistics.median(c)) for w, c in zip(wall, cpu, strict=True)]


def timed(
    method: str,
    scene: Scene,
    n: int,
    *,
    seed: int = 0,
    repeats: int = 3,
    warmup: bool = True,
    points=None,
    chunk_size=None,
    devices=None,
) -> tuple[Result, Timing]:
    """Run ``method`` (``"dpim"`` or ``"monte_carlo"``) with ``n`` paths under the timing protocol.

    ``devices=None``: one device, the run is :func:`jdpim.methods._paths.simulate` (unsharded, unstreamed) on
    the default device. Several ``devices``: the path axis is split over them as ``dpim`` and
    ``monte_carlo`` split it (one call, unstreamed); ``Timing.devices`` records how many.

    Point selection (DPIM, cached) and key generation happen before the clock starts; the clock covers
    excitation, integration and the transfer of the saved states.

    Returns:
        the :class:`jdpim.Result` of the last run and its :class:`Timing`.
    """
    compile_s, run, finish = prepared(
        method, scene, n, seed=seed, points=points, chunk_size=chunk_size, devices=devices
    )
    if warmup:
        run()
    runs = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        states = run()
        runs.append(time.perf_counter() - t0)
    n_devices = 1 if devices is None else len(devices)
    return finish(states), Timing(method, n, scene.n_steps, compile_s, tuple(runs), n_devices)
