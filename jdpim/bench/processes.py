"""Monte Carlo and DPIM over several processes (``jax.distributed``) against one process, on this host.

Scene: the reference oscillator (alpha = gamma = 0.03, r = 0.98, D = 0.03) from rest to ``t_end``; Monte Carlo
with the spectral forcing and with :class:`jdpim.GaussianNodes` (no FFT), and DPIM. Each
configuration starts its processes afresh (``python -m jdpim.bench.processes``, one coordinator on
``127.0.0.1``): one process on one CPU device, free to run on every core (the baseline) and bound to one
core, one process on one device per core, and one process per core on one device each, each bound to its own
core. A process is bound with ``os.sched_setaffinity`` before JAX starts its backend: XLA sizes a process's
thread pools by the cores it may run on, so processes free to run on every core start more threads than there
are cores, and contend when XLA splits the work of large chunks over them. Every process runs the job once to
compile, then ``repeats`` times after a barrier
(``multihost_utils.sync_global_devices``); the time is process 0's median, from the call to the ``x`` density
of the last saved time on a grid (the states gathered on every process included). The densities of every
configuration are compared with the first, bit for bit.
"""

from __future__ import annotations

import json
import os
import pathlib
import socket
import subprocess
import sys
import time

import numpy as np

from .._cpu import DEVICE_COUNT_FLAG, usable_cores
from .record import record, record_lines, table_lines


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _worker(argv) -> None:
    """One process: ``index count port t_end n_samples n_points repeats out [cores]`` (``count`` 1: no
    coordinator; ``cores``: comma-separated CPU ids to bind the process to)."""
    if len(argv) > 8:
        os.sched_setaffinity(0, {int(c) for c in argv[8].split(",")})
    import jax

    index, count, port = int(argv[0]), int(argv[1]), argv[2]
    t_end, n_samples, n_points, repeats, out = float(argv[3]), int(argv[4]), int(argv[5]), int(argv[6]), argv[7]
    if count > 1:
        jax.distributed.initialize(f"127.0.0.1:{port}", num_processes=count, process_id=index)
    from jax.experimental import multihost_utils

    import jdpim

    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=t_end, dt=0.01)
    grid = np.linspace(0.0, 2.0, 201)
    rows = {}
    monte_carlo = jdpim.MonteCarlo(n_samples=n_samples, seed=0, progress=False)
    for name, method, job_scene in (
        ("monte_carlo", monte_carlo, scene.replace(excitation=jdpim.SpectralRepresentation())),
        ("monte_carlo_nodes", monte_carlo, scene.replace(excitation=jdpim.GaussianNodes())),
        ("dpim", jdpim.DPIM(n_points=n_points, progress=False), scene),
    ):

        def job(method=method, job_scene=job_scene):
            return np.asarray(jdpim.solve(job_scene, method).pdf("x", grid, t_end))

        job()
        times = []
        for _ in range(repeats):
            if count > 1:
                multihost_utils.sync_global_devices("jdpim.bench.processes")
            t0 = time.perf_counter()
            pdf = job()
            times.append(time.perf_counter() - t0)
        rows[name] = {"median_s": float(np.median(times)), "pdf": pdf.tolist()}
    if index == 0:
        pathlib.Path(out).write_text(json.dumps({"devices": len(jax.local_devices()), "rows": rows}))


def core_shares(processes: int, cores_per_process: int) -> list[str]:
    """Contiguous shares of ``cores_per_process`` of this process's usable cores, one per process (``""``: all)."""
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if cores_per_process >= len(cores):
        return [""] * processes
    c = cores_per_process
    return [",".join(map(str, cores[i * c : (i + 1) * c])) for i in range(processes)]


def device_env(devices: int) -> dict:
    """This process's environment for a new process of ``devices`` JAX CPU devices: ``JAX_NUM_CPU_DEVICES`` set, a
    device count in ``XLA_FLAGS`` taken out (the other flags kept)."""
    env = dict(os.environ, JAX_NUM_CPU_DEVICES=str(devices))
    flags = DEVICE_COUNT_FLAG.sub("", env.pop("XLA_FLAGS", "")).strip()
    return env | ({"XLA_FLAGS": flags} if flags else {})


def _launch(processes: int, devices: int, cores_per_process: int, args: tuple, out: pathlib.Path) -> dict:
    port = _free_port()
    env = device_env(devices) | {"JAX_PLATFORMS": "cpu"}
    shares = core_shares(processes, cores_per_process)
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "jdpim.bench.processes", str(i), str(processes), str(port), *map(str, args), out]
            + ([shares[i]] if shares[i] else []),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for i in range(processes)
    ]
    logs = [p.communicate()[0] for p in procs]
    if any(p.returncode for p in procs):
        raise RuntimeError(f"a benchmark process failed:\n{logs}")
    return json.loads(out.read_text())


def run_processes(
    out: pathlib.Path,
    *,
    t_end: float = 100.0,
    n_samples: int = 40_000,
    n_points: int = 8000,
    repeats: int = 3,
    log=print,
) -> list[str]:
    """The table (``processes.json``, ``processes.md``) for 1 and ``usable_cores()`` processes and devices.

    Rows ``(processes, devices per process, cores per process)``: one process on one device that may run on
    every core (the baseline of the speed-ups), the same bound to one core, one process with one device per
    core, and one process per core on one device, each bound to its core.
    """
    cores = usable_cores()
    configs = [(1, 1, cores), (1, 1, 1), (1, cores, cores), (cores, 1, 1)] if cores > 1 else [(1, 1, 1)]
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for processes, devices, per in configs:
        got = _launch(processes, devices, per, (t_end, n_samples, n_points, repeats), out / "processes_worker.json")
        results.append((processes, devices, per, got["rows"]))
    (out / "processes_worker.json").unlink()
    base = results[0][3]
    rows = []
    for processes, devices, per, got in results:
        row = {"processes": processes, "devices_per_process": devices, "cores_per_process": per}
        for name, n in (("monte_carlo", n_samples), ("monte_carlo_nodes", n_samples), ("dpim", n_points)):
            t = got[name]["median_s"]
            row[f"{name}_s"] = round(t, 3)
            row[f"{name}_speedup"] = round(base[name]["median_s"] / t, 2)
            row[f"{name}_path_steps_per_s"] = f"{n * t_end / 0.01 / t:.2e}"
            row[f"{name}_same_pdf"] = got[name]["pdf"] == base[name]["pdf"]
        rows.append(row)
        log(str(row))
    rec = record(
        f"each configuration in fresh processes: one run to compile, then {repeats} runs after a barrier; "
        "process 0's median wall time, from the call to the x density (the gathered states included)"
    )
    summary = {
        "record": rec,
        "t_end": t_end,
        "n_samples": n_samples,
        "n_points": n_points,
        "repeats": repeats,
        "rows": rows,
    }
    (out / "processes.json").write_text(json.dumps(summary, indent=1))
    title = (
        f"Reference scene to t = {t_end:g} s (dt = 0.01, float32): Monte Carlo {n_samples} paths (spectral forcing; "
        f"`monte_carlo_nodes`: GaussianNodes, drawn inside the steps), DPIM {n_points} points; median of {repeats} "
        f"warm runs including the x density; speed-up against the first row (1 process on 1 device, free to run "
        f"on every core); a process with fewer cores than the host is bound to its own"
    )
    (out / "processes.md").write_text(
        "\n".join([*record_lines(rec), title, "", *table_lines(rows, list(rows[0]))]) + "\n"
    )
    return ["processes.json", "processes.md"]


if __name__ == "__main__":
    _worker(sys.argv[1:])
