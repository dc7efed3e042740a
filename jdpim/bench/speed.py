"""Speed of the reference scene: jdpim's pipelines against a plain vectorised NumPy RK4 Monte Carlo.

Reference scene: alpha = gamma = 0.03, r = 0.98, D = 0.03, t_end = 200 s, dt = 0.01 s (2e4 steps).
Protocol (``timing.timed``): AOT compile (timed apart), one warm-up run, ``repeats`` warm runs, median.
Each configuration runs on one device, and again on every local device when there are several (as
``python -m jdpim.bench`` sets up on a multi-core CPU: one device per core).
The split times the two stages of one chunk on their own (excitation synthesis; the rest of the
chunk, mostly integration), times the number of chunks, and the densities (``Result.pdf`` of x and v
on 481 / 961 points at t_end).
Peak memory is the process's resident high-water mark (``resource.getrusage(...).ru_maxrss``), read
after each row: it only grows, so a row's figure bounds that row's own peak from above.
"""

from __future__ import annotations

import functools
import json
import os
import pathlib
import platform
import resource
import statistics
import time

import jax
import numpy as np

from .._excitation import synthesize
from .._pipelines import _path_inputs, _simulate_chunk, dpim_inputs, monte_carlo_inputs
from .accuracy import grids, paper_scene
from .timing import timed

T_END, DT = 200.0, 0.01


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _median_time(fn, repeats: int) -> float:
    jax.block_until_ready(fn())
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs)


def split(scene, rows, kind: str, repeats: int, n_chunks: int) -> dict:
    """Warm median seconds of the excitation and of the integration of one chunk ``rows``, times ``n_chunks``."""
    grid = scene.spectral_grid()

    @jax.jit
    def excite(scene, rows):
        coeffs, _ = jax.vmap(functools.partial(_path_inputs, scene, kind))(rows)
        return synthesize(coeffs, grid).astype(scene.float_dtype)

    @jax.jit
    def whole(scene, rows):
        return _simulate_chunk(scene, kind, rows)

    t_exc = _median_time(lambda: excite(scene, rows), repeats)
    t_all = _median_time(lambda: whole(scene, rows), repeats)
    return {
        "excitation_s": round(n_chunks * t_exc, 4),
        "integration_s": round(n_chunks * max(t_all - t_exc, 0.0), 4),
    }


def density_time(result, repeats: int) -> float:
    gx, gv = grids(1.0)
    t = result.times[-1]
    return _median_time(lambda: (result.pdf("x", gx, t), result.pdf("v", gv, t)), repeats)


def numpy_mcs(n_paths: int, seed: int = 0, dtype=np.float64) -> tuple[np.ndarray, float]:
    """Vectorised NumPy RK4 + mirror Monte Carlo of the reference scene, as a user would write it.

    The white noise of intensity D (``E[xi(t) xi(t+s)] = 2 D delta(s)``) is synthesised by an inverse
    real FFT of Gaussian coefficients on the half-step grid (the same spectral method, cutoff pi / dt).
    Returns the final states ``(n, 2)`` and the wall time (excitation + integration) in s.
    """
    alpha, gamma, r, D = 0.03, 0.03, 0.98, 0.03
    n_steps = int(round(T_END / DT))
    h = DT
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    n_half = 2 * n_steps + 1
    n_fft = 2 * n_half
    dw = 2 * np.pi / (n_fft * h / 2)
    k = n_fft // 2 + 1
    amp = np.sqrt(2 * (2 * D / (2 * np.pi)) * dw)  # two-sided PSD S0 = D / pi -> one-sided 2 S0
    spec = amp * (rng.standard_normal((n_paths, k)) - 1j * rng.standard_normal((n_paths, k)))
    spec[:, 0] = 0.0
    xi = (np.fft.irfft(spec, n=n_fft, axis=1) * (n_fft / 2))[:, :n_half].T.astype(dtype)  # (n_half, n)
    x = np.zeros(n_paths, dtype)
    v = np.zeros(n_paths, dtype)

    def acc(x, v, f):
        return f - alpha * v - gamma * v**3 - x

    for i in range(n_steps):
        f0, fm, f1 = xi[2 * i], xi[2 * i + 1], xi[2 * i + 2]
        k1x, k1v = v, acc(x, v, f0)
        k2x, k2v = v + 0.5 * h * k1v, acc(x + 0.5 * h * k1x, v + 0.5 * h * k1v, fm)
        k3x, k3v = v + 0.5 * h * k2v, acc(x + 0.5 * h * k2x, v + 0.5 * h * k2v, fm)
        k4x, k4v = v + h * k3v, acc(x + h * k3x, v + h * k3v, f1)
        x = x + h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
        v = v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        hit = x < 0
        x = np.where(hit, -x, x)
        v = np.where(hit, -r * v, v)
    return np.stack([x, v], axis=-1), time.perf_counter() - t0


def run_speed(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    """Run the speed table; writes ``speed.json`` and ``speed.md`` under ``out``."""
    repeats = 3
    dtypes = ("float32",) if quick else ("float32", "float64")
    mcs_sizes = (10_000,) if quick else (10_000, 100_000)
    rows = []
    # one device (the protocol's rows, with the split), then every local device (what dpim and monte_carlo use)
    device_sets = [None] + ([jax.local_devices()] if jax.local_device_count() > 1 else [])
    for dtype in dtypes:
        if dtype == "float64":
            jax.config.update("jax_enable_x64", True)
        scene = paper_scene(T_END, DT, dtype=dtype)
        for method, n in [("dpim", 1000)] + [("monte_carlo", m) for m in mcs_sizes]:
            for devices in device_sets:
                log(f"[speed] {dtype} {method} n={n} on {1 if devices is None else len(devices)} device(s) ...")
                res, tm = timed(method, scene, n, repeats=repeats if n <= 10_000 else 1, devices=devices)
                row = {"dtype": dtype, **tm.row()}
                if n <= 10_000 and devices is None:  # the split of one chunk of the same size
                    inputs = dpim_inputs(scene, n) if method == "dpim" else monte_carlo_inputs(scene, n)
                    chunk = inputs[0][: inputs[2]]
                    row.update(split(scene, chunk, method, repeats, -(-n // inputs[2])))
                    row["densities_s"] = round(density_time(res, repeats), 4)
                row["peak_rss_mib"] = round(_peak_mib())
                row["n_nonfinite"] = int(np.max(np.asarray(res.n_nonfinite())))
                rows.append(row)
                log(f"[speed]   {row}")
    n_np = 1000
    log(f"[speed] numpy baseline n={n_np} ...")
    np_runs = [numpy_mcs(n_np, seed=s)[1] for s in range(1 if quick else 2)]
    np_rate = n_np * int(round(T_END / DT)) / statistics.median(np_runs)
    for r in rows:
        r["x_numpy"] = round(r["path_steps_per_s"] / np_rate, 2)
    info = {
        "scene": {"alpha": 0.03, "gamma": 0.03, "r": 0.98, "D": 0.03, "t_end": T_END, "dt": DT},
        "numpy_rk4_mcs": {
            "n_paths": n_np,
            "median_s": round(statistics.median(np_runs), 3),
            "path_steps_per_s": float(f"{np_rate:.3g}"),
        },
        "rows": rows,
        "machine": {
            "platform": platform.platform(),
            "cpu_cores": os.cpu_count(),
            "devices": jax.local_device_count(),
            "backend": jax.default_backend(),
            "jax": jax.__version__,
        },
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "quick": quick,
    }
    out.mkdir(parents=True, exist_ok=True)
    name = "speed_quick" if quick else "speed"
    (out / f"{name}.json").write_text(json.dumps(info, indent=1) + "\n")
    cols = [
        "dtype",
        "method",
        "n_paths",
        "devices",
        "compile_s",
        "median_s",
        "excitation_s",
        "integration_s",
        "densities_s",
        "path_steps_per_s",
        "x_numpy",
        "peak_rss_mib",
    ]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in cols) + " |" for r in rows]
    np_s = info["numpy_rk4_mcs"]["median_s"]
    lines.append(f"\nNumPy RK4 + mirror MCS, {n_np} paths, float64: {np_s} s, {np_rate:.3g} path-steps/s.")
    lines.append(f"Load average (1, 5, 15 min) at the end: {info['load_average']}.")
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    log("\n".join(lines))
    return [f"{name}.json", f"{name}.md"]
