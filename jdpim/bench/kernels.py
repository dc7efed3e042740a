"""The XLA kernels a Monte Carlo run launches, grouped by how often each one runs: per step, per batch of crossing
paths, per impact round.

On a CPU a located impact's cost is set by the number of kernels its batch and its rounds launch more than by their
arithmetic: a batch has a few hundred rows, and each of its kernels takes about as long whatever its size.
:func:`kernel_profile` compiles the run of a scene's paths ahead of time, runs it once to warm up, and runs it once
more under JAX's profiler; every kernel of the compiled program (an HLO instruction; loops and conditionals, whose
time includes the kernels inside them, are left out) is counted by its number of calls. Kernels that run the same
number of times form a group: the step's kernels run once per step, the batch's machinery once per batch, a round's
kernels once per round taken. The profiler adds its own cost to every kernel, so times are for comparison within a
record, not run times.
"""

from __future__ import annotations

import collections
import gzip
import json
import pathlib
import re
import tempfile

import jax

from .._excitation import GaussianNodes
from .._integrate import ImpactRule
from .._pytree import check_int
from .accuracy import paper_scene
from .record import record, record_lines, table_lines, write_record

DT = 0.01
# a profiler's trace keeps this many spans (events of phase "X") and drops the rest (measured: a run of more)
MAX_SPANS = 1_000_000
CONTROL_FLOW = ("while", "conditional", "call")
SMALL_CALL = 'xla_cpu_small_call="true"'
_INSTRUCTION = re.compile(r"^\s*(?:ROOT )?%?([\w.\-]+) = (?:\([^)]*\)|\S+) ([\w\-]+)\(", re.M)


def kernels_of(hlo_text: str) -> set[str]:
    """The names of the kernels of a compiled program's HLO text: its instructions other than loops, conditionals
    and calls, and the calls that XLA emits as one kernel each (``xla_cpu_small_call``: a batch's resolution on a
    CPU, ``jdpim._engine.one_kernel``)."""
    kernels = set()
    for line in hlo_text.splitlines():
        match = _INSTRUCTION.match(line)
        if match and (match.group(2) not in CONTROL_FLOW or SMALL_CALL in line):
            kernels.add(match.group(1))
    return kernels


def call_groups(events, kernels: set[str], n_steps: int) -> list[dict]:
    """``events`` (a Perfetto trace's ``traceEvents``) grouped by calls: for each number of calls, the kernels of
    ``kernels`` that ran that often, their calls per step (``n_steps``: the steps of every chunk together), and
    their time in all and per call, most calls first."""
    calls, time_us = collections.Counter(), collections.Counter()
    for event in events:
        if event.get("ph") == "X" and event.get("name") in kernels:
            calls[event["name"]] += 1
            time_us[event["name"]] += event.get("dur", 0.0)
    groups = collections.defaultdict(list)
    for name, count in calls.items():
        groups[count].append(name)
    return [
        {
            "calls": count,
            "per_step": round(count / n_steps, 3),
            "kernels": len(names),
            "total_ms": round(sum(time_us[n] for n in names) / 1e3, 2),
            "us_per_call": round(sum(time_us[n] for n in names) / count, 1),
        }
        for count, names in sorted(groups.items(), reverse=True)
    ]


def kernel_profile(scene, n_paths: int) -> list[dict]:
    """:func:`call_groups` of one warm Monte Carlo run of ``n_paths`` paths of ``scene`` on one device (calls per
    step of a chunk: the run's chunks take their steps one after the other)."""
    from ..methods._paths import monte_carlo_inputs, simulate

    n_paths = check_int("n_paths", n_paths, low=2)
    rows, _, chunk = monte_carlo_inputs(scene, n_paths)
    compiled = simulate.lower(scene, rows, kind="monte_carlo", chunk_size=chunk).compile()
    jax.block_until_ready(compiled(scene, rows))
    with tempfile.TemporaryDirectory() as trace_dir:
        with jax.profiler.trace(trace_dir, create_perfetto_trace=True):
            jax.block_until_ready(compiled(scene, rows))
        (path,) = pathlib.Path(trace_dir).rglob("perfetto_trace.json.gz")
        events = json.loads(gzip.decompress(path.read_bytes()))["traceEvents"]
    if sum(event.get("ph") == "X" for event in events) >= MAX_SPANS:
        raise ValueError(f"the profile reached the {MAX_SPANS} spans a trace keeps: profile fewer paths or steps")
    n_chunks = -(-n_paths // chunk)
    return call_groups(events, kernels_of(compiled.as_text()), n_chunks * round(scene.t_end / scene.dt))


def scenes(t_end: float) -> list[tuple[str, str, object]]:
    """``(scene, impacts, Scene)`` of the record: the reference scene with the mirror rule and with located impacts,
    and the impact damper with located impacts, each with Monte Carlo's default forcing."""
    from .mdof import damper_scene

    reference = paper_scene(t_end, DT, GaussianNodes())
    damper = damper_scene(t_end, DT).replace(excitation=GaussianNodes())
    return [
        ("reference", "mirror", reference.replace(impacts=ImpactRule(method="mirror"))),
        ("reference", "locate", reference),
        ("impact damper", "locate", damper),
    ]


def run_kernels(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    """Profile every scene of :func:`scenes` (1e4 paths, t = 5 s; ``quick``: 2000 paths, t = 2 s) and write
    ``kernels[_quick].md/.json`` under ``out``; returns the names of the files written."""
    n_paths, t_end = (2000, 2.0) if quick else (10_000, 5.0)
    rows = []
    for name, impacts, scene in scenes(t_end):
        for group in kernel_profile(scene, n_paths):
            rows.append({"scene": name, "impacts": impacts, "n_paths": n_paths, **group})
        log(f"kernels: {name}, {impacts}: {len(rows)} groups so far")
    rec = record(
        "each scene's Monte Carlo run (one device, float32) compiled ahead of time, run once to warm up and once "
        "under JAX's profiler; every kernel of the compiled program (loops and conditionals left out) counted by "
        "its calls, and the kernels with the same number of calls grouped (calls per step of a chunk: 1 for the "
        "step's own kernels, the batches and impact rounds per step for theirs); times include the profiler's own "
        "cost per kernel"
    )
    columns = ["scene", "impacts", "n_paths", "calls", "per_step", "kernels", "total_ms", "us_per_call"]
    lines = record_lines(rec) + table_lines(rows, columns)
    return write_record(out, "kernels_quick" if quick else "kernels", {"record": rec, "rows": rows}, lines, log=log)
