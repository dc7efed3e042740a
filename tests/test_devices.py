"""Sharding over devices and streaming in blocks: the states do not depend on either."""

import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

import jdpim
from jdpim.methods._paths import SIZE_STEPS, balanced_chunk, monte_carlo_inputs, run_paths, shared_size, simulate

SCENE = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.01, save_at=(1.0, 2.0))


def test_blocks_give_the_same_states_as_one_call(capsys):
    rows, _, chunk = monte_carlo_inputs(SCENE, 48, seed=3, chunk_size=8)
    whole = np.asarray(simulate(SCENE, rows, kind="monte_carlo", chunk_size=chunk))
    streamed = run_paths(SCENE, rows, kind="monte_carlo", chunk_size=chunk, block_size=20, progress=True)
    assert isinstance(streamed, jax.Array)
    np.testing.assert_array_equal(np.asarray(streamed), whole)
    assert "48/48 paths" in capsys.readouterr().err  # the progress line reached the end
    run_paths(SCENE, rows, kind="monte_carlo", chunk_size=chunk, block_size=20, progress=False)
    assert capsys.readouterr().err == ""


# One process for both checks below (each process imports JAX and jdpim): it splits its CPU into two devices
# with jdpim.use_cpu_cores, as a user does, and then runs on them.
_CPU_CORES = textwrap.dedent(
    """
    import jax, pytest, jdpim
    from jdpim._cpu import start_devices
    with pytest.raises(ValueError, match="n must be"):
        jdpim.use_cpu_cores(0)
    assert jdpim.use_cpu_cores(2) == 2
    assert jax.device_count() == 2  # the first computation starts JAX with two CPU devices
    assert jdpim.use_cpu_cores(2) == 2  # asking again for what runs is fine
    with pytest.raises(RuntimeError, match="already runs on 2 CPU device"):
        jdpim.use_cpu_cores(3)
    assert start_devices(None) == "2 CPU device(s)"  # the command line leaves a started JAX alone
    with pytest.raises(ValueError, match="already runs on 2"):
        start_devices(3)
    print("cores ok")
    """
)
_SHARDED = textwrap.dedent(
    """
    import jax, numpy as np, jdpim
    assert jax.local_device_count() == 2, jax.devices()
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.01, impacts=jdpim.ImpactRule(method="mirror"))
    from jdpim.methods._paths import _sharded_simulate
    _sharded_simulate.cache_clear()
    two = jdpim.monte_carlo(scene, 30, seed=5, chunk_size=8)
    one = jdpim.monte_carlo(scene, 30, seed=5, chunk_size=8, devices=jax.devices()[:1])
    assert _sharded_simulate.cache_info().currsize == 1  # the two-device run was sharded
    # CPU devices: the states are gathered on the first device (no XLA:CPU collectives in the densities)
    assert two.states.sharding.device_set == {jax.devices()[0]}, two.states.sharding
    np.testing.assert_array_equal(np.asarray(two.states), np.asarray(one.states))
    d2 = jdpim.dpim(scene, 32, chunk_size=8)
    d1 = jdpim.dpim(scene, 32, chunk_size=8, devices=jax.devices()[:1])
    assert d2.states.sharding.device_set == {jax.devices()[0]}, d2.states.sharding
    np.testing.assert_array_equal(np.asarray(d2.states), np.asarray(d1.states))
    v = np.linspace(-1.0, 1.0, 5)
    np.testing.assert_allclose(np.asarray(d2.pdf("v", v, 1.0)), np.asarray(d1.pdf("v", v, 1.0)))
    print("sharded ok")
    """
)


@pytest.fixture(scope="module")
def two_cpu_devices():
    """The output of ``_CPU_CORES`` then ``_SHARDED`` in a fresh process (JAX not started, no device count set)."""
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES")}
    return subprocess.run(
        [sys.executable, "-c", _CPU_CORES + _SHARDED],
        env=dict(env, JAX_PLATFORMS="cpu"),
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_use_cpu_cores_splits_the_cpu_before_jax_starts_and_says_when_too_late(two_cpu_devices):
    assert "cores ok" in two_cpu_devices.stdout.splitlines(), two_cpu_devices.stderr[-3000:]


def test_two_host_devices_split_the_paths_with_identical_results(two_cpu_devices):
    assert two_cpu_devices.returncode == 0, two_cpu_devices.stderr[-3000:]
    assert two_cpu_devices.stdout.splitlines()[-1] == "sharded ok"


@pytest.mark.parametrize(
    ("n", "chunk", "devices"), [(10_000, 770, 2), (10_000, 770, 1), (48, 20, 1), (7, 3, 4), (5, 8, 2)]
)
def test_balanced_chunks_are_no_larger_and_pad_less_than_a_path_per_chunk_and_a_sixteenth(n, chunk, devices):
    c = balanced_chunk(n, chunk, devices)
    share = -(-n // devices)
    n_chunks = -(-share // c)
    assert 1 <= c <= chunk
    assert c == chunk or c == shared_size(c)  # a size that nearby runs share, where the limit allows
    assert n_chunks == -(-share // chunk)  # as few chunks as the limit allows
    assert 0 <= n_chunks * c - share < n_chunks * (1 + c / SIZE_STEPS)


def test_shared_sizes_are_sixteen_per_octave():
    sizes = sorted({shared_size(n) for n in range(1, 4097)})
    assert sizes[:32] == list(range(1, 33))  # every size up to 32
    assert all(16 <= s >> max(0, s.bit_length() - 5) < 32 for s in sizes if s > 32)
    assert sum(1024 <= s < 2048 for s in sizes) == SIZE_STEPS
    assert all(n <= shared_size(n) < n * (1 + 1 / SIZE_STEPS) + 1 for n in range(1, 4097))


@pytest.mark.slow  # blocks: test_blocks_give_the_same_states_as_one_call
def test_blocks_are_equal_so_that_a_run_just_over_one_block_pads_little(capsys):
    """16 chunks of 8 make a default block of 128 paths; 136 paths run as two blocks of 72 (not 128 + 128)."""
    rows, _, chunk = monte_carlo_inputs(SCENE, 136, seed=4, chunk_size=8)
    whole = np.asarray(simulate(SCENE, rows, kind="monte_carlo", chunk_size=chunk))
    streamed = run_paths(SCENE, rows, kind="monte_carlo", chunk_size=chunk, progress=True)
    np.testing.assert_array_equal(np.asarray(streamed), whole)
    assert "72/136 paths" in capsys.readouterr().err
