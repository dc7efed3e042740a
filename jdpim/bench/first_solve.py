"""The cost of a first solve: the reference scene solved through the public API in a new Python process.

A new process compiles its programs on the first call of a method; later calls with the same scene structure (any
parameter values) reuse them. :func:`first_solve` starts a process that times its first call and then ``repeats``
warm calls (median), and splits the compilation JAX reports for the first call into tracing, lowering to MLIR and
XLA's compilation (``jax.monitoring``'s durations, summed over every program of the call). ``overhead_s`` is the
first call's time above a warm call's.

With ``cache_dir`` the process uses JAX's persistent compilation cache there (docs/compilation.md), storing every
program: a process that finds the programs in it loads them (``cache_hits``) instead of compiling them
(``cache_misses``). Without it the process uses none, whatever the environment says.
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import tempfile

from .._integrate import ImpactRule
from .._pytree import check_int, check_number
from .accuracy import ALPHA, GAMMA, D, R
from .record import record, record_lines, table_lines, write_record

DT = 0.01
# the reference scene's sizes: Monte Carlo 1e4 paths to t = 50 s, DPIM 1000 points to t = 200 s
SIZES = {"monte_carlo": (10_000, 50.0), "dpim": (1000, 200.0)}

_CHILD = r"""
import json, statistics, sys, time
args = json.loads(sys.argv[1])
t0 = time.perf_counter()
import jax
import jdpim
from jdpim.bench.accuracy import paper_scene
import_s = time.perf_counter() - t0
if args["cache_dir"]:
    jax.config.update("jax_compilation_cache_dir", args["cache_dir"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
counts = {"cache_hits": 0, "cache_misses": 0}
phases = {"trace_s": 0.0, "lower_s": 0.0, "compile_s": 0.0}
names = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
}
def on_event(event, **kwargs):
    key = event.rsplit("/", 1)[-1]
    if key in counts:
        counts[key] += 1
def on_duration(event, duration, **kwargs):
    if event in names:
        phases[names[event]] += duration
jax.monitoring.register_event_listener(on_event)
jax.monitoring.register_event_duration_secs_listener(on_duration)
scene = paper_scene(args["t_end"], args["dt"], None, impacts=jdpim.ImpactRule(method=args["impacts"]))
if args["method"] == "dpim":
    solve = lambda: jdpim.dpim(scene, n_points=args["n"], progress=False)
else:
    solve = lambda: jdpim.monte_carlo(scene, n_samples=args["n"], seed=0, progress=False)
def timed():
    t = time.perf_counter()
    jax.block_until_ready(jax.tree_util.tree_leaves(solve()))
    return time.perf_counter() - t
first_s = timed()
first_phases, first_counts = dict(phases), dict(counts)
warm_s = statistics.median([timed() for _ in range(args["repeats"])])
print(json.dumps({"devices": len(jax.local_devices()), "import_s": import_s, "first_s": first_s, "warm_s": warm_s,
                  **first_phases, **first_counts}))
"""


def first_solve(method: str, impacts: str, *, n: int, t_end: float, cache_dir=None, repeats: int = 3) -> dict:
    """One new process's first call of ``jdpim.<method>`` on the reference scene (``n`` paths or points to ``t_end``
    s, ``ImpactRule(method=impacts)``) against its warm calls: a row of seconds (``first_s``, ``warm_s``,
    ``overhead_s``, the first call's ``trace_s``, ``lower_s``, ``compile_s``; ``import_s`` of jax and jdpim), the
    process's number of ``devices`` and the first call's persistent-cache ``cache_hits`` and ``cache_misses`` (both
    0 without ``cache_dir``)."""
    if method not in SIZES:
        raise ValueError(f"method must be one of {sorted(SIZES)}, got {method!r}")
    ImpactRule(method=impacts)  # its errors here, not from the new process
    n, repeats = check_int("n", n, low=2), check_int("repeats", repeats, low=1)
    t_end = check_number("t_end", t_end, low=0.0, low_open=True)
    args = {"method": method, "impacts": impacts, "n": n, "t_end": t_end, "dt": DT, "repeats": repeats}
    args["cache_dir"] = None if cache_dir is None else str(cache_dir)
    # the process uses the cache it is given and no other: not one that the environment names (a test session's)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE"))}
    proc = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(args)], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"the first-solve process failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    times = json.loads(proc.stdout.strip().splitlines()[-1])
    row = {"method": method, "impacts": impacts, "n": n, "t_end": t_end}
    row.update({k: round(v, 3) if isinstance(v, float) else v for k, v in times.items()})
    row["overhead_s"] = round(times["first_s"] - times["warm_s"], 3)
    return row


def run_first_solve(out: pathlib.Path, *, quick: bool = False, processes: int = 3, log=print) -> list[str]:
    """:func:`first_solve` of DPIM and Monte Carlo on the reference scene (located impacts; and the mirror rule
    unless ``quick``): a process without a persistent compilation cache, one that fills a new cache, and one that
    finds its programs there, each ``processes`` times (the row of the median ``overhead_s``, with the range).
    Writes ``first_solve.json`` and ``first_solve.md`` (``first_solve_quick.*``)."""
    rows = []
    for method, (n, t_end) in SIZES.items():
        for impacts in ("locate",) if quick else ("locate", "mirror"):
            runs = {"none": [], "new": [], "filled": []}
            for _ in range(processes):
                with tempfile.TemporaryDirectory(prefix="jdpim-first-solve-") as cache:
                    for label, cache_dir in (("none", None), ("new", cache), ("filled", cache)):
                        log(f"[speed] first solve: {method} {impacts}, persistent cache {label} ...")
                        runs[label].append(first_solve(method, impacts, n=n, t_end=t_end, cache_dir=cache_dir))
                        log(f"[speed]   {runs[label][-1]}")
            for label, found in runs.items():
                found.sort(key=lambda r: r["overhead_s"])
                spread = f"{found[0]['overhead_s']} to {found[-1]['overhead_s']}"
                rows.append({"cache": label, **found[len(found) // 2], "overhead_range_s": spread})
    rec = record(
        f"each row the median of {processes} new Python processes by overhead_s (overhead_range_s: all of them), "
        "each timing its first call of jdpim.dpim / jdpim.monte_carlo on the reference scene and then 3 warm calls "
        "(median); overhead_s = first_s - warm_s; trace_s, lower_s and compile_s sum JAX's "
        "reported durations over the first call's programs; cache: none (no persistent compilation cache), new "
        "(an empty one, filled by this process), filled (the one the process before filled)"
    )
    info = {"record": rec, "scene": {"alpha": ALPHA, "gamma": GAMMA, "r": R, "D": D, "dt": DT}, "rows": rows}
    cols = "method impacts n t_end devices cache first_s warm_s overhead_s overhead_range_s".split()
    cols += "trace_s lower_s compile_s cache_hits cache_misses import_s".split()
    lines = record_lines(rec) + [
        f"The reference scene (alpha = gamma = 0.03, r = 0.98, D = 0.03, dt = {DT:g} s) from rest, float32, each "
        "method's default forcing; a new process's default devices (`devices`: it calls no `jdpim.use_cpu_cores`).",
        "",
        *table_lines(rows, cols),
    ]
    return write_record(out, "first_solve_quick" if quick else "first_solve", info, lines, log=log)
