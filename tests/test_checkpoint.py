"""Runs that survive interruption (``checkpoint=``): a run stopped after some blocks of paths (subset simulation:
levels) and resumed gives the uninterrupted run's result bit for bit; a checkpoint of another job is refused.

The interruption is a ``KeyboardInterrupt`` raised right after the ``k``-th part file is written (the moment a
kill would leave the most finished work behind), and for Monte Carlo a real ``SIGKILL`` of a child process.
"""

import os
import signal
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import jdpim
from jdpim import _checkpoint

SCENE = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.02, save_at=(0.5, 1.0))
# chunks of 2 paths: blocks of 16 chunks (32 paths) by default, so that a run without a checkpoint streams the
# same blocks and both compile one program
MC = jdpim.MonteCarlo(n_samples=96, seed=3, chunk_size=2)


def assert_same(a, b):
    """The same pytree structure and bit-identical leaves."""
    leaves_a, tree_a = jax.tree_util.tree_flatten(a)
    leaves_b, tree_b = jax.tree_util.tree_flatten(b)
    assert tree_a == tree_b
    for x, y in zip(leaves_a, leaves_b, strict=True):
        assert np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
        assert np.asarray(x).dtype == np.asarray(y).dtype


def parts(path):
    return sorted(os.listdir(path)) if os.path.isdir(path) else []


def interrupted(monkeypatch, after: int, run):
    """Run ``run()`` until the ``after``-th part file is written, then raise ``KeyboardInterrupt``."""
    store, written = _checkpoint.Session.store, []

    def stop(self, name, covers, part):
        store(self, name, covers, part)
        written.append(name)
        if len(written) == after:
            raise KeyboardInterrupt

    with monkeypatch.context() as m:
        m.setattr(_checkpoint.Session, "store", stop)
        with pytest.raises(KeyboardInterrupt):
            run()
    return written


def resumed(monkeypatch, after: int, run, path, expect_loaded: int):
    """``run()`` interrupted after ``after`` parts, then resumed: its result; checks that the resumed run loaded
    the ``expect_loaded`` finished parts (computing none of them again) and deleted the checkpoint."""
    interrupted(monkeypatch, after, run)
    assert len(parts(path)) == after
    load, loaded = _checkpoint.Session.load, []

    def count(self, name, covers):
        out = load(self, name, covers)
        loaded.extend([name] if out is not None else [])
        return out

    with monkeypatch.context() as m:
        m.setattr(_checkpoint.Session, "load", count)
        out = run()
    assert len(loaded) == expect_loaded
    assert not os.path.exists(path)  # deleted when the run finished
    return out


def test_monte_carlo_resumes_bit_for_bit(monkeypatch, tmp_path):
    path = tmp_path / "mc"
    whole = jdpim.solve(SCENE, MC)
    out = resumed(monkeypatch, 2, lambda: jdpim.solve(SCENE, MC, checkpoint=path), path, 2)  # 3 blocks
    assert_same(out, whole)


@pytest.mark.slow  # the default tier resumes blocks of chunks of paths in test_monte_carlo_resumes_bit_for_bit
def test_dpim_resumes_bit_for_bit(monkeypatch, tmp_path):
    path = tmp_path / "dpim"
    method = jdpim.DPIM(n_points=48, chunk_size=2)
    whole = jdpim.solve(SCENE, method)
    out = resumed(monkeypatch, 1, lambda: jdpim.solve(SCENE, method, checkpoint=path), path, 1)  # 2 blocks
    assert_same(out, whole)


def test_first_passage_resumes_bit_for_bit(monkeypatch, tmp_path):
    """With derivatives: the likelihood ratio's scores ride along the nominal paths, and the central difference in
    ``r`` reruns them twice; every run of paths is kept (3 runs of 3 blocks), the interruption in the second."""
    path = tmp_path / "fp"

    def run(checkpoint=None):
        return jdpim.first_passage(SCENE, "x", [0.05, 0.1], MC, wrt=("alpha", "r"), checkpoint=checkpoint)

    whole = run()
    out = resumed(monkeypatch, 4, lambda: run(jdpim.Checkpoint(path)), path, 4)
    assert_same(out, whole)


def test_subset_simulation_resumes_bit_for_bit(monkeypatch, tmp_path):
    path = tmp_path / "subset"
    model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None, omega=2.0)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.5), t_end=2.0, dt=0.05)
    method = jdpim.SubsetSimulation(n_per_level=40, p0=0.25, seed=1)

    def run(checkpoint=None):
        return jdpim.first_passage(scene, "x", 1.2, method, wrt="D", checkpoint=checkpoint)

    whole = run()
    assert whole.n_evaluations >= 3 * 40  # three levels or more: two written before the interruption
    out = resumed(monkeypatch, 2, lambda: run(path), path, 2)
    assert_same(out, whole)


def test_killed_process_resumes(tmp_path):
    """A child process running Monte Carlo with a checkpoint is killed by SIGKILL once two blocks are on disk
    (a half-written part beside them); the run resumed here gives the uninterrupted result bit for bit and
    deletes every part (the child compiles the run itself: about 11 s)."""
    path = tmp_path / "killed"
    child = textwrap.dedent(f"""
        import os, sys, time
        sys.path.insert(0, {os.getcwd()!r})
        import jdpim
        from jdpim import _checkpoint
        store = _checkpoint.Session.store
        def slow(self, name, covers, part):
            store(self, name, covers, part)
            if len(os.listdir({str(path)!r})) == 2:
                print("two", flush=True)
                time.sleep(600)
        _checkpoint.Session.store = slow
        scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.02, save_at=(0.5, 1.0))
        method = jdpim.MonteCarlo(n_samples=96, seed=3, chunk_size=2)
        jdpim.solve(scene, method, checkpoint={str(path)!r})
    """)
    with subprocess.Popen([sys.executable, "-c", child], stdout=subprocess.PIPE, text=True) as proc:
        try:
            assert proc.stdout.readline().strip() == "two"
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
    assert len(parts(path)) == 2
    (path / f"paths0-block2.npz.{proc.pid}.tmp").write_bytes(b"PK\x03\x04 cut short")  # a kill during a write
    out = jdpim.solve(SCENE, MC, checkpoint=path)
    assert_same(out, jdpim.solve(SCENE, MC))
    assert not os.path.exists(path)


def test_checkpoint_of_another_job_refused(monkeypatch, tmp_path):
    path = tmp_path / "other"
    ck = jdpim.Checkpoint(path)
    interrupted(monkeypatch, 1, lambda: jdpim.solve(SCENE, MC, checkpoint=ck))
    other_seed = jdpim.MonteCarlo(n_samples=96, seed=4, chunk_size=2)
    with pytest.raises(ValueError, match=r"is of another method .*seed=3.*seed=4"):
        jdpim.solve(SCENE, other_seed, checkpoint=ck)
    other_chunk = jdpim.MonteCarlo(n_samples=96, seed=3, chunk_size=4)
    with pytest.raises(ValueError, match="is of another method"):
        jdpim.solve(SCENE, other_chunk, checkpoint=ck)
    with pytest.raises(ValueError, match="is of another scene"):
        jdpim.solve(_finer(SCENE), MC, checkpoint=ck)
    with pytest.raises(ValueError, match="is of another question"):
        jdpim.first_passage(SCENE, "x", 0.1, MC, checkpoint=ck)
    with pytest.raises(ValueError, match="covers"):  # the same job in other blocks
        jdpim.solve(SCENE, MC, checkpoint=jdpim.Checkpoint(path, every=64))
    assert len(parts(path)) == 1  # a refused resume leaves the checkpoint as it was


def _finer(scene):
    return jdpim.Scene(scene.model, noise=scene.noise, t_end=scene.t_end, dt=0.01, save_at=scene.save_at)


def test_checkpoint_arguments_checked(tmp_path):
    with pytest.raises(ValueError, match="every must be an integer >= 1"):
        jdpim.Checkpoint(tmp_path, every=0)
    with pytest.raises(TypeError, match="checkpoint must be None, a path or a jdpim.Checkpoint"):
        jdpim.solve(SCENE, MC, checkpoint=3)
    with pytest.raises(ValueError, match="checkpoint applies to jdpim.DPIM and jdpim.MonteCarlo, not PathIntegration"):
        jdpim.solve(SCENE, jdpim.PathIntegration(), checkpoint=tmp_path)
