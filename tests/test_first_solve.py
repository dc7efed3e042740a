"""What a first solve compiles: the run's program and a few small ones, never one per operation."""

import contextlib
import logging
import re

import jax
import numpy as np
import pytest

import jdpim
from jdpim.results._samples import model_constraints

# programs a first Monte Carlo solve, density and moment compile besides the run in a fresh process: keys and
# weights, forces at rest, finished states, the stacked constraints, the constraint bound, the entry, the held paths,
# the bandwidth rule, the kernel sum, the moment (docs/compilation.md)
FIRST_SOLVE_PROGRAMS = 10
# programs a density, the held mass and the mass of a function of the state compile in a fresh process: the
# library's 7 (the bound, the state at a time, the held paths, the weights without them, the kernel sum, the held mass,
# the mass) and the function's own operations, evaluated one by one (14 for a difference of two coordinates: its
# values, its derivative for the linearity probe, its rate along the motion)
FUNCTION_QUESTION_PROGRAMS = 21


class _Compiles(logging.Handler):
    """Names of the programs XLA compiles while attached to JAX's logger."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.names = []

    def emit(self, record):
        found = re.search(r"Finished XLA compilation of (\S+)", record.getMessage())
        if found:
            self.names.append(found.group(1))


@contextlib.contextmanager
def compiled_programs():
    """The names of the programs XLA compiles inside the ``with`` block (a list, filled as they compile)."""
    logger, handler = logging.getLogger("jax"), _Compiles()
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    try:
        yield handler.names
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def test_a_first_solve_compiles_a_few_programs():
    """A solve of a size not seen before, its density and its moment compile the run and at most
    ``FIRST_SOLVE_PROGRAMS`` others (fewer where earlier tests compiled the shared ones): operation-by-operation
    evaluation would compile dozens."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=0.2, dt=0.01)
    with compiled_programs() as names:
        res = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=13, seed=0))
        jax.block_until_ready((res.pdf("x", [0.1, 0.5]), res.moment("x", 2)))
    others = [name for name in names if name != "jit(simulate)"]
    assert len(others) <= FIRST_SOLVE_PROGRAMS, others


def test_a_new_number_of_chunks_compiles_no_new_run():
    """Chunks run one by one through one program per chunk size: 26 and 39 paths in chunks of 13 compile at most
    one run (none after the first solve above); tests/test_pipelines.py checks that the states do not depend on the
    chunking."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=0.2, dt=0.01)
    with compiled_programs() as names:
        two = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=26, seed=0, chunk_size=13))
        three = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=39, seed=0, chunk_size=13))
    assert names.count("jit(simulate)") <= 1, names
    assert two.states.shape == (26, 1, 2) and three.states.shape == (39, 1, 2)


def test_nearby_sample_counts_share_one_run():
    """290 and 300 paths take one chunk of the same shared size (304): the second solve compiles no new run."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03), t_end=0.2, dt=0.01)
    with compiled_programs() as names:
        a = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=290, seed=0))
        b = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=300, seed=0))
    assert names.count("jit(simulate)") <= 1, names
    np.testing.assert_array_equal(a.states, b.states[:290])  # the same paths, whatever the padding


def test_moment_order_is_an_integer():
    """``Result.moment`` checks its order as ``GridResult.moment`` does."""
    res = jdpim.Result((1.0,), np.zeros((3, 1, 2), np.float32), np.full(3, 1 / 3, np.float32), 0.0)
    with pytest.raises(TypeError, match="order must be an integer"):
        res.moment("x", 1.5)
    with pytest.raises(ValueError, match="order must be an integer >= 0"):
        res.moment("x", -1)


def test_questions_about_a_function_of_the_state_compile_a_few_programs():
    """Density, held mass and mass of the impact damper's gap (a function of the state) on a result built by hand:
    the library's steps are one compiled program each, only the function's own operations are evaluated one by one
    (a new function object compiles no new program)."""
    damper = jdpim.impact_damper()
    states = np.array([[0.3, 0.2, 0.5, 0.5], [-0.05, 0.05, 0.0, 0.2], [0.2, 0.21, 0.1, -0.4]], np.float32)
    res = jdpim.Result((1.0,), states[:, None, :], np.full(3, 1 / 3, np.float32), None, "monte_carlo",
                       damper.coordinates, model_constraints(damper))  # fmt: skip
    with compiled_programs() as names:
        jax.block_until_ready((res.pdf(_gap, [0.0, 0.05], bandwidth=0.02), res.atoms(_gap), res.mass()))
    assert len(names) <= FUNCTION_QUESTION_PROGRAMS, names
    with compiled_programs() as again:
        jax.block_until_ready((res.pdf(lambda s: s[1] - s[0], [0.0, 0.05], bandwidth=0.02), res.atoms(_gap)))
    assert again == [], again


def _gap(state):
    return state[1] - state[0]


def _cubic(q, v, p):
    return -p * q**3


def test_the_jacobian_at_rest_is_one_program():
    """The step-size check of a model with a ``force`` function evaluates its Jacobian at rest as one compiled
    program per model structure: other parameter values compile nothing."""

    def model(k):
        return jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], damping=[[0.1]], stiffness=[[k]],
                                    force=_cubic, params=0.5)  # fmt: skip

    with compiled_programs() as names:
        first = model(2.0).linearised()
    with compiled_programs() as again:
        second = model(3.0).linearised()
    assert names.count("jit(_rest_jacobian)") <= 1 and len(names) <= 1, names
    assert again == [], again
    np.testing.assert_array_equal(first[1], np.float32([-2.0, -0.1]))  # computed in float32
    np.testing.assert_array_equal(second[1], np.float32([-3.0, -0.1]))


@pytest.mark.slow
def test_the_first_solve_bench_times_a_new_process_and_its_cache(tmp_path):
    """``jdpim.bench.first_solve``: a new process without a cache compiles (no cache events); one with a new cache
    compiles and stores its programs; one more with that cache loads every program and compiles none. Each row's
    first call holds its own tracing, lowering and compilation."""
    from jdpim.bench.first_solve import first_solve

    def row(cache_dir):
        return first_solve("dpim", "mirror", n=64, t_end=0.5, cache_dir=cache_dir, repeats=1)

    none, new, filled = row(None), row(tmp_path), row(tmp_path)
    assert none["cache_hits"] == none["cache_misses"] == 0 and none["compile_s"] > 0
    assert new["cache_hits"] == 0 and new["cache_misses"] > 0 and any(tmp_path.iterdir())
    assert filled["cache_misses"] == 0 and filled["cache_hits"] == new["cache_misses"]
    for r in (none, new, filled):
        assert 0 < r["trace_s"] + r["lower_s"] + r["compile_s"] < r["first_s"]
        assert r["overhead_s"] == pytest.approx(r["first_s"] - r["warm_s"], abs=2e-3)
