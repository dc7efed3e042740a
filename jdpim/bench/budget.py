"""Error budget on the exact-solution case: vary one knob at a time with the others fixed.

Knobs: time step ``dt``; excitation cutoff ``w_u``; frequency step ``dw`` (the period as a multiple of
the simulated window, so ``K`` relative to ``N``); DPIM random functions (``cosine`` or ``rayleigh``);
bandwidth rule; float32 vs float64 (in a subprocess with ``JAX_ENABLE_X64=1``). Each row reports the mean
L1 error of the x and x' marginals at t = 10 s and t_end against the exact solution, and ``E[x^2]`` at
t_end relative to the exact white-noise value. MCS rows with the same seed share their sampling noise,
so differences between them isolate the knob.
"""

from __future__ import annotations

import json
import math
import os
import pathlib
import subprocess
import sys

import numpy as np

from .. import exact
from .._excitation import SpectralRepresentation
from ..methods._dpim import dpim
from ..methods._monte_carlo import monte_carlo
from .accuracy import ALPHA, D, elastic_scene, exact_references, pdf_error
from .record import record


def _row(knob, value, method, n, res, scene) -> dict:
    t = scene.save_at[-1]
    ratio = float(res.moment("x", 2, t)) / exact.linear_covariance(ALPHA, D, t)[0]
    return {
        "knob": knob,
        "value": value,
        "method": method,
        "n": n,
        "l1": pdf_error(res, exact_references(scene)),
        "ex2_ratio": ratio,
    }


def _run(method, scene, n):
    return dpim(scene, n_points=n) if method == "dpim" else monte_carlo(scene, n_samples=n, seed=0)


def run_budget(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    t_end = 20.0 if quick else 50.0
    n_dpim, n_mc = (1000, 4000) if quick else (2000, 20_000)
    rows = []

    def add(row):
        rows.append(row)
        log(
            f"{row['knob']:>16s} = {row['value']!s:>9s}  {row['method']:11s} n={row['n']:>6d}  "
            f"L1={row['l1']:.4f}  E[x^2]/exact={row['ex2_ratio']:.3f}"
        )

    for dt in (0.04, 0.02, 0.01, 0.005):
        for method, n in (("monte_carlo", n_mc), ("dpim", n_dpim)):
            scene = elastic_scene(t_end, dt)
            add(_row("dt", dt, method, n, _run(method, scene, n), scene))
    for cutoff_pi in (4, 8, 16):
        scene = elastic_scene(
            t_end, 0.005 if cutoff_pi > 8 else 0.01, SpectralRepresentation(cutoff=cutoff_pi * math.pi)
        )
        for method, n in (("monte_carlo", n_mc), ("dpim", n_dpim)):
            add(_row("cutoff/pi", cutoff_pi, method, n, _run(method, scene, n), scene))
    for factor in (1, 2, 4):
        span = t_end + 2 * 10 * 2 * math.pi / (8 * math.pi)
        exc = SpectralRepresentation(dw=2 * math.pi / (factor * span))
        scene = elastic_scene(t_end, 0.01, exc)
        for n in (n_dpim // 2, n_dpim, 2 * n_dpim):
            res = dpim(scene, n_points=n)
            add(_row(f"period x (K={exc.grid(t_end, 0.01).n_terms})", factor, "dpim", n, res, scene))
    for rf in ("cosine", "rayleigh"):
        for n in (n_dpim // 4, n_dpim, 4 * n_dpim):
            scene = elastic_scene(t_end, 0.01, SpectralRepresentation(random_functions=rf))
            add(_row("random_functions", rf, "dpim", n, dpim(scene, n_points=n), scene))
    scene = elastic_scene(t_end, 0.01)
    refs = exact_references(scene)
    for method, n in (("monte_carlo", n_mc // 4), ("dpim", n_dpim // 2)):
        res = _run(method, scene, n)
        for rule in ("chen", "silverman", "scott"):
            errs = [
                float(np.trapezoid(np.abs(np.asarray(res.pdf(var, g, t, rule=rule)) - ref), g))
                for (var, t), (g, ref) in refs.items()
            ]
            rows.append(
                {
                    "knob": "bandwidth rule",
                    "value": rule,
                    "method": method,
                    "n": n,
                    "l1": float(np.mean(errs)),
                    "ex2_ratio": float("nan"),
                }
            )
            log(f"  bandwidth rule = {rule:>9s}  {method:11s} n={n:>6d}  L1={np.mean(errs):.4f}")
    rows += _float64_rows(t_end, n_dpim // 2, n_mc // 4, log)
    out.mkdir(parents=True, exist_ok=True)
    rec = record("no timings: L1 errors and second moments against the exact solution, one run per row")
    (out / "budget.json").write_text(json.dumps({"record": rec, "rows": rows}, indent=2))
    return ["budget.json"]


_X64_SCRIPT = """
import json, sys
import jdpim
from jdpim.bench.budget import _row, _run
from jdpim.bench.accuracy import elastic_scene
t_end, n_dpim, n_mc = float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
rows = []
for dtype in ("float32", "float64"):
    scene = elastic_scene(t_end, 0.01, dtype=dtype)
    for method, n in (("monte_carlo", n_mc), ("dpim", n_dpim)):
        rows.append(_row("dtype", dtype, method, n, _run(method, scene, n), scene))
print(json.dumps(rows))
"""


def _float64_rows(t_end, n_dpim, n_mc, log) -> list[dict]:
    env = dict(os.environ, JAX_ENABLE_X64="1")
    proc = subprocess.run(
        [sys.executable, "-c", _X64_SCRIPT, str(t_end), str(n_dpim), str(n_mc)],
        env=env,
        capture_output=True,
        text=True,
        check=True,
    )
    rows = json.loads(proc.stdout.strip().splitlines()[-1])
    for r in rows:
        log(
            f"{'dtype':>16s} = {r['value']:>9s}  {r['method']:11s} n={r['n']:>6d}  L1={r['l1']:.4f}  "
            f"E[x^2]/exact={r['ex2_ratio']:.3f}"
        )
    return rows
