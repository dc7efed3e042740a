"""Sharding over devices and streaming in blocks: the states do not depend on either."""

import os
import subprocess
import sys
import textwrap

import jax
import numpy as np

import jdpim
from jdpim._pipelines import monte_carlo_inputs, run_paths, simulate

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


_SHARDED = textwrap.dedent(
    """
    import jax, numpy as np, jdpim
    assert jax.local_device_count() == 2, jax.devices()
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.01, impacts=jdpim.ImpactRule(method="mirror"))
    two = jdpim.monte_carlo(scene, 30, seed=5, chunk_size=8)
    one = jdpim.monte_carlo(scene, 30, seed=5, chunk_size=8, devices=jax.devices()[:1])
    assert len(two.states.sharding.device_set) == 2, two.states.sharding
    np.testing.assert_array_equal(np.asarray(two.states), np.asarray(one.states))
    d2 = jdpim.dpim(scene, 32, chunk_size=8)
    d1 = jdpim.dpim(scene, 32, chunk_size=8, devices=jax.devices()[:1])
    assert len(d2.states.sharding.device_set) == 2, d2.states.sharding
    np.testing.assert_array_equal(np.asarray(d2.states), np.asarray(d1.states))
    print("ok")
    """
)


def test_two_host_devices_shard_the_paths_with_identical_results():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", _SHARDED], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip().endswith("ok")
