"""Monte Carlo and DPIM split over two local CPU processes with ``jax.distributed``: the states, densities and
first-passage probabilities (a tracked quantity) are those of one process, bit for bit."""

import os
import socket
import subprocess
import sys

import numpy as np

import jdpim
from jdpim.bench.processes import core_shares

WORKER = """
import sys
import jax
jax.distributed.initialize(coordinator_address=f"127.0.0.1:{sys.argv[2]}", num_processes=2, process_id=int(sys.argv[1]))
import numpy as np
sys.path.insert(0, sys.argv[4])
import test_processes as t
np.savez(sys.argv[3], process_count=jax.process_count(), **t.compute())
"""


def compute() -> dict:
    """What both processes and this one compute: an odd number of Monte Carlo paths (the last share padded). The
    chunks are those of a process's share (76 of its 151 paths, 100 of its 100 points), so that each process loads the
    programs this one compiled first (the session's compilation cache, conftest.py)."""
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=2.0, dt=0.01, save_at=(1.0, 2.0)
    )
    mc = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=301, seed=0, chunk_size=76, progress=False))
    dp = jdpim.solve(scene, jdpim.DPIM(n_points=200, chunk_size=100, progress=False))
    fp = jdpim.first_passage(
        scene, "x", [0.2, 0.4], jdpim.MonteCarlo(n_samples=301, seed=1, chunk_size=76, progress=False)
    )
    grid = np.linspace(0.0, 1.0, 31)
    return {
        "mc": np.asarray(mc.states),
        "dpim": np.asarray(dp.states),
        "pdf": np.asarray(mc.pdf("x", grid, 2.0)),
        "pdf_error": np.asarray(mc.pdf_error("x", grid, 2.0)),
        "first_passage": np.asarray(fp.probability),
        "stderr": np.asarray(fp.probability_stderr),
    }


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_give_the_results_of_one(tmp_path):
    one = compute()  # first: the processes then load its programs
    (tmp_path / "worker.py").write_text(WORKER)
    port, here = _free_port(), str(__import__("pathlib").Path(__file__).parent)
    procs = [
        subprocess.Popen(
            [sys.executable, str(tmp_path / "worker.py"), str(i), str(port), str(tmp_path / f"{i}.npz"), here],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for i in range(2)
    ]
    logs = [p.communicate(timeout=300)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs), logs
    for i in range(2):
        with np.load(tmp_path / f"{i}.npz") as got:
            assert int(got["process_count"]) == 2
            for name, value in one.items():
                np.testing.assert_array_equal(got[name], value, err_msg=f"process {i}: {name}")


def test_the_bench_binds_each_process_to_its_own_share_of_the_cores(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {7, 4, 6, 5}, raising=False)
    assert core_shares(2, 2) == ["4,5", "6,7"]
    assert core_shares(4, 1) == ["4", "5", "6", "7"]
    assert core_shares(1, 1) == ["4"]
    assert core_shares(1, 4) == [""]  # every core: left unbound
