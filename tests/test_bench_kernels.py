"""The kernel profile of the speed bench (``speed --kernels``): kernels counted by their calls under JAX's profiler."""

import gzip
import json
import pathlib
import re

import jax
import jax.numpy as jnp
import pytest

from jdpim._engine.one_kernel import one_kernel
from jdpim.bench.kernels import call_groups, kernels_of, run_kernels


def test_kernels_are_grouped_by_their_calls_and_other_events_left_out():
    events = [
        {"ph": "X", "name": "fusion.1", "dur": 2.0},
        {"ph": "X", "name": "fusion.1", "dur": 4.0},
        {"ph": "X", "name": "copy.3", "dur": 1.0},
        {"ph": "X", "name": "copy.3", "dur": 1.0},
        {"ph": "X", "name": "fusion.2", "dur": 9.0},
        {"ph": "X", "name": "while.5", "dur": 50.0},  # a loop: its time holds its kernels'
        {"ph": "X", "name": "ThunkExecutor::Execute", "dur": 60.0},
        {"ph": "i", "name": "fusion.2"},  # not a span
    ]
    groups = call_groups(events, {"fusion.1", "copy.3", "fusion.2"}, n_steps=2)
    assert groups == [
        {"calls": 2, "per_step": 1.0, "kernels": 2, "total_ms": 0.01, "us_per_call": 4.0},
        {"calls": 1, "per_step": 0.5, "kernels": 1, "total_ms": 0.01, "us_per_call": 9.0},
    ]


def test_a_loop_s_kernels_run_once_per_iteration_under_the_profiler(tmp_path):
    @jax.jit
    def loop(x):
        return jax.lax.fori_loop(0, 7, lambda i, y: jnp.sin(y) * 1.5 + jnp.cumsum(y), x)

    x = jnp.linspace(0.0, 1.0, 1000)
    compiled = loop.lower(x).compile()
    kernels = kernels_of(compiled.as_text())
    loops = set(re.findall(r"%([\w.\-]+) = (?:\([^)]*\)|\S+) while\(", compiled.as_text()))
    assert kernels and loops and loops.isdisjoint(kernels)
    jax.block_until_ready(compiled(x))
    with jax.profiler.trace(str(tmp_path), create_perfetto_trace=True):
        jax.block_until_ready(compiled(x))
    (path,) = pathlib.Path(tmp_path).rglob("perfetto_trace.json.gz")
    groups = call_groups(json.loads(gzip.decompress(path.read_bytes()))["traceEvents"], kernels, n_steps=7)
    assert 7 in [g["calls"] for g in groups]  # the body's kernels, once per iteration
    assert max(g["calls"] for g in groups) == 7


def test_a_call_emitted_as_one_kernel_counts_once_per_iteration(tmp_path):
    """A batch's resolution on a CPU is one call emitted as one kernel (``jdpim._engine.one_kernel``): the profile
    counts it as one kernel, run once per iteration."""

    def chain(y):
        return jnp.sqrt(jnp.abs(jnp.sin(y) * 1.5 - y)) + 0.1 * y

    @jax.jit
    def loop(x):
        return jax.lax.fori_loop(0, 7, lambda i, y: one_kernel(chain, y) + jnp.cumsum(y), x)

    x = jnp.linspace(0.0, 1.0, 64)
    compiled = loop.lower(x).compile()
    text = compiled.as_text()
    calls = set(re.findall(r"%([\w.\-]+) = (?:\([^)]*\)|\S+) call\(.*xla_cpu_small_call", text))
    assert len(calls) == 1 and calls <= kernels_of(text)
    jax.block_until_ready(compiled(x))
    with jax.profiler.trace(str(tmp_path), create_perfetto_trace=True):
        jax.block_until_ready(compiled(x))
    (path,) = pathlib.Path(tmp_path).rglob("perfetto_trace.json.gz")
    events = json.loads(gzip.decompress(path.read_bytes()))["traceEvents"]
    assert [(g["calls"], g["kernels"]) for g in call_groups(events, calls, n_steps=7)] == [(7, 1)]


@pytest.mark.slow  # the profiler's path through a run: test_a_loop_s_kernels_run_once_per_iteration_under_the_profiler
def test_the_kernel_record_counts_the_located_batches_beyond_the_mirror_rule(tmp_path):
    run_kernels(tmp_path, quick=True, log=lambda s: None)
    rows = json.loads((tmp_path / "kernels_quick.json").read_text())["rows"]
    assert (tmp_path / "kernels_quick.md").read_text().count("| reference | locate |") > 0

    def launched(scene, impacts):  # kernels launched per step of a chunk
        return sum(r["per_step"] * r["kernels"] for r in rows if (r["scene"], r["impacts"]) == (scene, impacts))

    assert any(r["per_step"] == 1.0 for r in rows if r["impacts"] == "mirror")  # the step's own kernels
    assert launched("reference", "locate") > 2 * launched("reference", "mirror")
