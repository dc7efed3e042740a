"""What a first solve compiles: the run's program and a few small ones, never one per operation."""

import contextlib
import logging
import re

import jax
import numpy as np
import pytest

import jdpim

# programs a first Monte Carlo solve, density and moment compile besides the run in a fresh process: the dtype probe,
# keys and weights, forces at rest, finished states, the barrier's two, the constraint bound, the entry, the held
# paths, the bandwidth rule, the kernel sum, the moment (docs/compilation.md)
FIRST_SOLVE_PROGRAMS = 12


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


def test_moment_order_is_an_integer():
    """``Result.moment`` checks its order as ``GridResult.moment`` does."""
    res = jdpim.Result((1.0,), np.zeros((3, 1, 2), np.float32), np.full(3, 1 / 3, np.float32), 0.0)
    with pytest.raises(TypeError, match="order must be an integer"):
        res.moment("x", 1.5)
    with pytest.raises(ValueError, match="order must be an integer >= 0"):
        res.moment("x", -1)
