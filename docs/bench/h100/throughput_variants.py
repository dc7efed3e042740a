"""Throughput of Monte Carlo with the noise drawn inside the steps (`GaussianNodes`), one impact rule per process.

Times `run_paths` and the density of x at the end time on 481 points, as `python -m jdpim.bench throughput`
does (first call apart, then `--repeats` warm calls, median), for the reference scene under one impact rule,
and appends one JSON row per size to `OUT/rows.jsonl`, with E[x] and E[x^2] at the end time to compare
variants. XLA flags come from the caller's `XLA_FLAGS`; `--unroll k` runs every `lax.scan` with `unroll=k`.

    python3 docs/bench/h100/throughput_variants.py --tag loc --t-end 50 --sizes 1000000 4000000
"""

import argparse
import json
import os
import statistics
import time

import jax
import numpy as np


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--tag", required=True)
    p.add_argument("--unroll", type=int, default=1)
    p.add_argument("--impacts", default="locate")
    p.add_argument("--stick", type=float, default=1e-3)
    p.add_argument("--max-impacts", type=int, default=2)
    p.add_argument("--sizes", type=int, nargs="+", default=[10**6])
    p.add_argument("--t-end", type=float, default=50.0)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--out", default=os.environ.get("OUT", "/tmp"))
    a = p.parse_args()
    if a.unroll > 1:
        scan = jax.lax.scan
        jax.lax.scan = lambda *args, **kw: scan(*args, **{**kw, "unroll": a.unroll})

    from jdpim._excitation import GaussianNodes
    from jdpim._integrate import ImpactRule
    from jdpim.bench.accuracy import grids, paper_scene
    from jdpim.bench.throughput import _peak_mib
    from jdpim.methods._paths import _finish, monte_carlo_inputs, run_paths

    rule = ImpactRule(method=a.impacts, stick_velocity=a.stick, max_impacts=a.max_impacts)
    scene = paper_scene(a.t_end, 0.01, GaussianNodes(), dtype="float32", impacts=rule)
    x_grid = grids(1.0)[0]

    def call(rows, chunk, weights):
        t0 = time.perf_counter()
        states = jax.block_until_ready(run_paths(scene, rows, kind="monte_carlo", chunk_size=chunk, progress=False))
        jax.block_until_ready(_finish(scene, states, weights, "monte_carlo").pdf("x", x_grid, scene.t_end))
        return states, time.perf_counter() - t0

    for n in a.sizes:
        rows, _, chunk = monte_carlo_inputs(scene, n)
        weights = jax.numpy.full((n,), 1.0 / n, scene.float_dtype)
        t0 = time.perf_counter()
        states, _ = call(rows, chunk, weights)
        first = time.perf_counter() - t0
        times = []
        for _ in range(a.repeats):
            states, elapsed = call(rows, chunk, weights)
            times.append(elapsed)
        median = statistics.median(times)
        x = np.asarray(states[:, -1, 0], np.float64)
        row = {
            "tag": a.tag,
            "impacts": a.impacts,
            "stick": a.stick,
            "max_impacts": a.max_impacts,
            "unroll": a.unroll,
            "xla": os.environ.get("XLA_FLAGS", ""),
            "n": n,
            "chunk": chunk,
            "t_end": a.t_end,
            "first_s": round(first, 2),
            "times": [round(t, 3) for t in times],
            "median_s": round(median, 4),
            "pss": float(f"{n * scene.n_steps / median:.3g}"),
            "us_per_step": round(1e6 * median / scene.n_steps, 1),
            "ex": float(x.mean()),
            "ex2": float((x * x).mean()),
            "nonfinite": int((~np.isfinite(x)).sum()),
            "peak_mib": round(_peak_mib()),
            "device": jax.devices()[0].device_kind,
            "jax": jax.__version__,
        }
        print("ROW", json.dumps(row), flush=True)
        with open(os.path.join(a.out, "rows.jsonl"), "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
