"""Throughput on the visible devices: path-steps per second of the reference scene against batch size.

``python -m jdpim.bench throughput --sizes 1000 100000 --chunk-sizes 4096 65536``: for each method, number
of paths ``n`` and chunk size, the paths go through :func:`jdpim.methods._paths.run_paths` (sharded over every
local device, streamed in blocks), exactly as ``jdpim.dpim`` / ``jdpim.monte_carlo`` run them, followed by the
kernel density of ``x`` at the end time on 481 points (``Result.pdf``; its time is a column of its own and part
of the path-steps per second). ``--forcing nodes`` gives Monte Carlo the noise drawn inside the steps
(:class:`jdpim.GaussianNodes`), ``--impacts mirror`` the first-order mirror rule. Protocol: the first call
(compilation included) is timed apart, then ``repeats`` warm calls, median. Input preparation (point
selection, keys) is outside the clock. Peak device memory is the allocator's high-water mark where the
backend reports one (GPUs), else the process's resident high-water mark.
"""

from __future__ import annotations

import json
import pathlib
import resource
import statistics
import time

import jax
import numpy as np

from .._excitation import GaussianNodes, SpectralRepresentation
from .._integrate import ImpactRule
from ..methods._paths import _finish, dpim_inputs, monte_carlo_inputs, run_paths
from .accuracy import grids, paper_scene
from .record import record, record_lines


def _peak_mib() -> float:
    stats = jax.local_devices()[0].memory_stats() or {}
    if "peak_bytes_in_use" in stats:
        return stats["peak_bytes_in_use"] / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(scene, method: str, n: int, chunk_size: int, repeats: int) -> dict:
    """One row: first-call and warm median wall times (s) of ``n`` paths in chunks of ``chunk_size``."""
    if method == "dpim":
        rows, _, chunk = dpim_inputs(scene, n, chunk_size=chunk_size)
    else:
        rows, _, chunk = monte_carlo_inputs(scene, n, chunk_size=chunk_size)

    weights = jax.numpy.full((n,), 1.0 / n, scene.float_dtype)
    x_grid = grids(1.0)[0]

    def call():
        t0 = time.perf_counter()
        states = jax.block_until_ready(run_paths(scene, rows, kind=method, chunk_size=chunk, progress=False))
        t1 = time.perf_counter()
        jax.block_until_ready(_finish(scene, states, weights, method).pdf("x", x_grid, scene.t_end))
        return states, t1 - t0, time.perf_counter() - t1

    t0 = time.perf_counter()
    states, _, _ = call()
    first_s = time.perf_counter() - t0
    totals, kde_s = [], []
    for _ in range(repeats):
        states, paths, kde = call()
        totals.append(paths + kde)
        kde_s.append(kde)
    median = statistics.median(totals)
    finite = np.isfinite(np.asarray(states)).all(axis=(1, 2))
    return {
        "method": method,
        "n_paths": n,
        "chunk_size": chunk,
        "first_call_s": round(first_s, 3),
        "median_s": float(f"{median:.4g}"),
        "kde_s": float(f"{statistics.median(kde_s):.4g}"),
        "repeats": repeats,
        "path_steps_per_s": float(f"{n * scene.n_steps / median:.3g}"),
        "n_nonfinite": int(n - finite.sum()),
        "peak_mib": round(_peak_mib()),
    }


def run_throughput(
    out: pathlib.Path,
    *,
    sizes=(1000, 10_000),
    chunk_sizes=(None,),
    methods=("dpim", "monte_carlo"),
    dtype: str = "float32",
    forcing: str = "spectral",
    impacts: str = "locate",
    t_end: float = 200.0,
    dt: float = 0.01,
    repeats: int = 3,
    log=print,
) -> list[str]:
    """Run the throughput table; writes ``throughput.json`` and ``throughput.md`` under ``out``."""
    if dtype == "float64":
        jax.config.update("jax_enable_x64", True)
    forcings = {"spectral": SpectralRepresentation, "nodes": GaussianNodes}
    if forcing not in forcings:
        raise ValueError(f"forcing must be one of {sorted(forcings)}, got {forcing!r}")
    scene = paper_scene(t_end, dt, forcings[forcing](), dtype=dtype, impacts=ImpactRule(method=impacts))
    if forcing == "nodes" and "dpim" in methods:
        methods = [m for m in methods if m != "dpim"]
        if not methods:
            raise ValueError("DPIM needs the spectral forcing: run it without forcing='nodes'")
        log("[throughput] DPIM left out: it needs the spectral forcing")
    rows = []
    for method in methods:
        for n in sizes:
            for chunk in chunk_sizes:
                if chunk is not None and chunk > n:
                    continue
                log(f"[throughput] {method} n={n} chunk={chunk or 'default'} ...")
                rows.append(
                    {
                        "dtype": dtype,
                        "forcing": forcing,
                        "impacts": impacts,
                        **measure(scene, method, n, chunk, repeats),
                    }
                )
                log(f"[throughput]   {rows[-1]}")
    rec = record(
        f"the first call (compilation included) timed apart, then {repeats} warm calls, the median wall time "
        "(paths and the x density); input preparation outside the clock"
    )
    info = {
        "record": rec,
        "scene": {"alpha": 0.03, "gamma": 0.03, "r": 0.98, "D": 0.03, "t_end": t_end, "dt": dt},
        "rows": rows,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "throughput.json").write_text(json.dumps(info, indent=1) + "\n")
    cols = list(rows[0]) if rows else []
    lines = record_lines(rec) + ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r[c]) for c in cols) + " |" for r in rows]
    (out / "throughput.md").write_text("\n".join(lines) + "\n")
    log("\n".join(lines))
    return ["throughput.json", "throughput.md"]
