"""The wide resolution of an accelerator's large chunks (``WIDE_CHUNK`` paths or more, run without branches) gives
the states of the compact batches that smaller chunks, and every chunk on a CPU, use: the threshold is lowered, and
the CPU taken for an accelerator, so that small chunks take it here."""

import logging
import re

import jax
import numpy as np
import pytest

import jdpim
from jdpim._engine import batches, elementwise, one_kernel


def _states(scene, n, wide, monkeypatch, **method):
    monkeypatch.setattr(batches, "WIDE_CHUNK", 64 if wide else 2**62)
    for module in (batches, elementwise, one_kernel):
        monkeypatch.setattr(module, "on_cpu", lambda: False)
    jax.clear_caches()  # the threshold is read when the step is traced
    res = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=n, seed=3, chunk_size=n, **method))
    return np.asarray(res.states)


def _one_dof(excitation, t_end=2.0, gamma=0.03, **start):
    model = jdpim.VibroImpactOscillator(alpha=0.03, gamma=gamma, r=0.98)
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.08), t_end=t_end, dt=0.01, excitation=excitation, **start)


SCENES = {
    # every path crosses in its first step: 256 crossings against a batch of 8, so the lanes serve the rest
    "all cross at once": lambda: _one_dof(jdpim.GaussianNodes(), x0=1e-3, v0=-1.0),
    # every path starts at rest on the barrier: the batch restarts each where the force pulls it off
    "at rest on the barrier": lambda: _one_dof(jdpim.GaussianNodes(), x0=0.0, v0=0.0),
    # stiff steps split per path, from rest: each restarted path keeps its own sub-step length
    "sub-steps from rest": lambda: jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=0.03, gamma=10.0, r=0.8),
        noise=jdpim.WhiteNoise(D=1.0),
        t_end=1.0,
        dt=0.05,
        excitation=jdpim.GaussianNodes(),
        substeps=jdpim.Substeps(),
    ),
    "spectral forcing": lambda: _one_dof(jdpim.SpectralRepresentation(), x0=0.5),
    "impact damper": lambda: jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.05), t_end=2.0, dt=0.01),
    "held on the walls": lambda: jdpim.Scene(
        jdpim.kanai_tajimi(jdpim.impact_damper(), omega_g=3.0, zeta_g=0.6),
        noise=jdpim.WhiteNoise(D=0.05),
        t_end=3.0,
        dt=0.01,
    ),
}


@pytest.fixture(scope="module")
def lane_states():
    """The lane resolution's states of a scene (256 paths in one chunk), computed once for the module: a scene checked
    both ways of running the wide resolution, or with compact batches of other widths, is compared with the same
    lanes."""
    states = {}

    def lanes(name, monkeypatch):
        if name not in states:
            states[name] = _states(SCENES[name](), 256, False, monkeypatch)
        return states[name]

    return lanes


# The wide resolution serves only an accelerator's wide chunks; these tests force it on a CPU. The default tier runs
# the two one-degree-of-freedom scenes (one program: crossings served by the wide batch and the lanes, rounds run on
# every row without branches, and the restart of paths at rest). Slow: further scenes, each a program of its own.
# Sub-steps from rest: the per-path step column goes through the batch's rows as in
# test_hard_cases.py::test_substeps_are_per_path, the restart as in [at rest on the barrier]. Spectral forcing: other
# excitation columns, packed and gathered as in [all cross at once]. Impact damper and held on the walls: the events
# of several degrees of freedom, which the suite resolves in compact batches
# (test_mdof_sticking.py::test_held_paths_under_filtered_noise_stay_finite_admissible_and_held), resolved wide on
# every row without branches as [all cross at once] resolves one degree of freedom's.
FURTHER = ("sub-steps from rest", "spectral forcing", "impact damper", "held on the walls")


@pytest.mark.parametrize(
    "name", [pytest.param(name, marks=pytest.mark.slow) if name in FURTHER else name for name in SCENES]
)
def test_wide_resolution_gives_the_lane_states(name, monkeypatch, lane_states):
    scene = SCENES[name]()
    wide = _states(scene, 256, True, monkeypatch)
    lanes = lane_states(name, monkeypatch)
    assert np.all(np.isfinite(wide))
    np.testing.assert_allclose(wide, lanes, rtol=0, atol=1e-5)


class _CacheKeys(logging.Handler):
    """The persistent compilation cache's keys of the runs (``jit_simulate``) compiled or loaded while attached."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.keys = []

    def emit(self, record):
        found = re.search(r"cache (?:hit|miss) for 'jit_simulate' with key '(\S+)'", record.getMessage(), re.I)
        if found:
            self.keys.append(found.group(1))


def test_a_cpu_serves_every_chunk_by_compact_batches(monkeypatch):
    """On a CPU a chunk of ``WIDE_CHUNK`` paths or more is served by compact batches too (faster there than a wide
    batch, also in the impact damper's crowded steps): with the threshold lowered below the chunk, where every path
    crosses in the first step, the run is the same program (the same key in the session's compilation cache,
    conftest.py) and gives the same states bit for bit."""
    scene = SCENES["all cross at once"]()
    logger, handler = logging.getLogger("jax"), _CacheKeys()
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)

    def states():
        jax.clear_caches()  # the threshold is read when the step is traced
        return np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=256, seed=3, chunk_size=256)).states)

    try:
        default = states()
        monkeypatch.setattr(batches, "WIDE_CHUNK", 64)
        lowered = states()
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    np.testing.assert_array_equal(lowered, default)
    assert len(handler.keys) == 2 and handler.keys[0] == handler.keys[1], handler.keys


# slow: [impact damper] repeats on several degrees of freedom what [all cross at once] checks (the batches' widths)
@pytest.mark.parametrize("name", ["all cross at once", pytest.param("impact damper", marks=pytest.mark.slow)])
def test_compact_batches_give_the_same_states_whatever_their_rows(name, monkeypatch, lane_states):
    """A chunk's crossing paths go through compact batches of ``compact_rows`` rows (4 of 256 paths), as many as a
    step needs (64 in the first step of the first scene, where every path crosses): batches of 16 rows, fewer of
    them, give the same states to rounding, since every row is resolved by the same code whichever batch serves it;
    XLA vectorises the two widths differently (other fused multiply-adds), so the last bits may differ (a few units
    in the last place of the states' scale). The default widths' states are the lanes of the test above."""
    default = lane_states(name, monkeypatch)
    assert batches.compact_rows(256) == 4
    monkeypatch.setattr(batches, "compact_rows", lambda n: 16)
    rounding = 8 * np.finfo(default.dtype).eps * np.max(np.abs(default))  # a few units of the states' last place
    np.testing.assert_allclose(_states(SCENES[name](), 256, False, monkeypatch), default, rtol=0, atol=rounding)


# slow: reverse mode through the wide batch's rounds without branches; the suite differentiates the compact batches in
# reverse mode (test_mdof_sticking.py::test_reverse_mode_from_rest_on_a_wall_is_finite_and_equals_forward_mode) and
# runs the wide batch forward ([all cross at once])
@pytest.mark.slow
def test_reverse_mode_through_the_wide_resolution(monkeypatch):
    """Reverse mode (``jax.value_and_grad``) of E[x^2] at t = 0.5 s with respect to the restitution, through the
    wide resolution (64 paths from the barrier's side, every one crossing at once, so the lanes serve most of them
    too), against central differences of the same paths; one program gives the values and the derivative. Linear
    damping: the cubic term's derivatives would only add to the program (a quarter of its compile time)."""
    monkeypatch.setattr(batches, "WIDE_CHUNK", 16)
    for module in (batches, elementwise, one_kernel):
        monkeypatch.setattr(module, "on_cpu", lambda: False)
    jax.clear_caches()
    scene = _one_dof(jdpim.GaussianNodes(), t_end=0.5, gamma=None, x0=1e-3, v0=-1.0)

    @jax.jit
    @jax.value_and_grad
    def second_moment(r):
        s = scene.replace(model=scene.model.replace(r=r))
        return jdpim.solve(s, jdpim.MonteCarlo(n_samples=64, seed=1, chunk_size=64)).moment("x", 2, 0.5)

    step = 1e-3
    central = (second_moment(0.98 + step)[0] - second_moment(0.98 - step)[0]) / (2 * step)
    np.testing.assert_allclose(float(second_moment(0.98)[1]), float(central), rtol=2e-3)


@pytest.mark.parametrize("n, rows", [(14286, 896), (16384, 1024), (8192, 512), (100, 7), (8, 1)])
def test_batch_rows_are_a_multiple_of_eight_above_it(n, rows):
    """Wide batches above ``BATCH_ROWS`` rows are rounded up to a multiple of it (odd ones ran 2x slower on a CPU)."""
    assert batches.batch_rows(n) == rows


@pytest.mark.parametrize(
    "n, rows", [(10_000, 160), (14_286, 224), (5000, 80), (512, 8), (100, 2), (64, 2), (5, 2), (1, 1)]
)
def test_compact_rows_are_a_64th_of_the_chunk(n, rows):
    assert batches.compact_rows(n) == rows
