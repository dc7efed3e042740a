"""The speed bench's NumPy and plain JAX baselines integrate the same oscillator as jdpim, in distribution; its rows of
one core run on one core.

Second moments at a fixed seed against the exact r = 1 solution (the mirror rule is exact there: it is the
folding of the free oscillator) and against jdpim's Monte Carlo of the reference scene. Tolerance: four
standard errors of the difference, estimated from the samples.
"""

import jax
import numpy as np
import pytest

import jdpim
from jdpim import exact
from jdpim._cpu import usable_cores
from jdpim.bench import timing
from jdpim.bench.accuracy import paper_scene
from jdpim.bench.processes import device_env
from jdpim.bench.speed import (
    JAX_KEY_IMPLS,
    UNREACHED_BARRIER,
    jax_mcs,
    layers,
    numpy_mcs,
    on_one_core,
    one_core,
    split,
)
from jdpim.bench.timing import interleaved
from jdpim.methods._paths import dpim_inputs

N_PATHS, T = 20_000, 10.0


def _mean_and_se(samples):
    return float(np.mean(samples)), float(np.std(samples) / np.sqrt(samples.size))


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_baseline_matches_exact_r1(dtype):
    """r = 1, gamma = 0: E[x^2] and E[v^2] at t = 10 s equal the free linear oscillator's variances."""
    x, v = numpy_mcs(N_PATHS, t_end=T, gamma=0.0, r=1.0, seed=1, dtype=dtype)
    assert x.dtype == np.dtype(dtype) and np.all(x >= 0)
    var_x, var_v, _ = exact.linear_covariance(0.03, 0.03, T)
    for samples, exact_value in ((x**2, var_x), (v**2, var_v)):
        mean, se = _mean_and_se(samples.astype(np.float64))
        assert abs(mean - exact_value) < 4 * se, (mean, exact_value, se)


def test_baseline_matches_jdpim_reference_scene():
    """Reference scene (r = 0.98, cubic damping): E[x^2], E[v^2] at t = 10 s agree with jdpim's Monte Carlo.

    The two differ in their forcing (independent half-step values against jdpim's band-limited spectral
    representation) and impact rule (mirror against located impacts), both of which converge to the same SDE.
    """
    x, v = numpy_mcs(N_PATHS, t_end=T, seed=2)
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98), noise=jdpim.WhiteNoise(D=0.03), t_end=T, dt=0.01
    )
    states = np.asarray(jdpim.monte_carlo(scene, n_samples=4000, seed=0).states, dtype=np.float64)[:, -1]
    for ours, theirs in ((x**2, states[:, 0] ** 2), (v**2, states[:, 1] ** 2)):
        (m1, se1), (m2, se2) = _mean_and_se(ours), _mean_and_se(theirs)
        assert abs(m1 - m2) < 4 * np.hypot(se1, se2), (m1, m2, se1, se2)


@pytest.fixture(scope="module")
def numpy_reference():
    """NumPy's paths of the reference scene at seed 3, computed once for every key implementation."""
    return numpy_mcs(N_PATHS, t_end=T, seed=3)


@pytest.mark.parametrize("impl", JAX_KEY_IMPLS)
def test_plain_jax_baseline_matches_the_numpy_baseline(impl, numpy_reference):
    """The plain JAX scan of the same scheme: E[x^2], E[v^2] of the reference scene at t = 10 s agree with NumPy's,
    with each of the key implementations the bench times."""
    x, v = (np.asarray(a, np.float64) for a in jax_mcs(N_PATHS, int(T / 0.01), jax.random.key(3, impl=impl)))
    xn, vn = numpy_reference
    assert np.all(x >= 0)
    for ours, theirs in ((x**2, xn**2), (v**2, vn**2)):
        (m1, se1), (m2, se2) = _mean_and_se(ours), _mean_and_se(theirs)
        assert abs(m1 - m2) < 4 * np.hypot(se1, se2), (m1, m2, se1, se2)


def test_layers_of_impact_handling_differ_by_one_layer_each():
    """The speed bench's rows of jdpim (``layers``): with located impacts and a barrier that no path reaches, every
    path's states are those of the oscillator without a barrier, bit for bit (the test of every step changes no
    path), and the paths stay far from that barrier; the mirror rule and located impacts run the reference scene."""
    scenes = dict(layers(T))
    assert list(scenes) == ["none", "mirror", "locate, unreached", "locate"]
    free, unreached = (
        np.asarray(jdpim.monte_carlo(scenes[k], n_samples=2000, seed=0).states) for k in ("none", "locate, unreached")
    )
    np.testing.assert_array_equal(unreached, free)
    assert free[..., 0].min() > UNREACHED_BARRIER / 5
    assert scenes["mirror"].impacts.method == "mirror" and scenes["locate"].impacts.method == "locate"
    assert scenes["mirror"].model == scenes["locate"].model and scenes["locate"].model.barrier == 0.0


def test_rows_of_one_core_run_on_one_core_with_one_device(monkeypatch):
    """``on_one_core`` runs its code in a process that may use one core (the first of this process's), on one JAX
    device whatever device count this process was given; other XLA flags pass on. Where this process has one core,
    there is nothing to restrict and nothing runs."""
    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=2 --xla_cpu_enable_fast_math=false")
    env = device_env(1)
    assert env["JAX_NUM_CPU_DEVICES"] == "1" and env["XLA_FLAGS"] == "--xla_cpu_enable_fast_math=false"
    code = (
        "import json, os, sys\n"
        "import jax\n"
        "json.dump([sorted(os.sched_getaffinity(0)), jax.local_device_count()], open(sys.argv[-1], 'w'))\n"
    )
    result = on_one_core(code)
    if usable_cores() < 2:
        assert one_core() is None and result is None
    else:
        assert result == [[one_core()], 1]


def test_interleaved_runs_warm_up_once_then_rounds_in_turn(monkeypatch):
    """``interleaved`` runs every configuration once to warm up, then ``repeats`` rounds of each once in turn, and
    takes each one's median over its rounds (the warm-up excluded), of wall and process CPU time alike."""
    calls, clock = [], iter(range(1000))
    monkeypatch.setattr(timing.time, "perf_counter", lambda: float(next(clock)))
    monkeypatch.setattr(timing.time, "process_time", lambda: 0.0)
    slow = {"a": 0, "b": 5}

    def run(name):
        def go():
            calls.append(name)
            for _ in range(slow[name]):  # b's rounds take five more ticks of the fake clock
                next(clock)

        return go

    times = interleaved([run("a"), run("b")], 3)
    assert calls == ["a", "b"] + ["a", "b"] * 3
    assert [t[0] for t in times] == [1.0, 6.0] and [t[1] for t in times] == [0.0, 0.0]


def test_split_times_the_excitation_and_the_integration_apart():
    """The split runs one chunk's excitation and its integration under that excitation, each on its own (its times
    are the bench's record, not asserted here)."""
    scene = paper_scene(2.0, 0.02, jdpim.SpectralRepresentation(), impacts=jdpim.ImpactRule(method="mirror"))
    rows = dpim_inputs(scene, 64)[0]
    times = split(scene, rows, "dpim", 1, 3)
    assert set(times) == {"excitation_s", "integration_s"}
    assert all(np.isfinite(t) and t >= 0 for t in times.values())
