"""Shared test configuration: strict JAX checks, and scenes/results computed once per session.

Compilation dominates the cost of the suite on a 2-core CPU, so expensive results are session-scoped
fixtures reused by many tests, and sizes are small. Heavier settings carry the ``slow`` marker.

The tests compile with XLA's defaults, as users run the library. Two settings apply to the test session:

- JAX's persistent compilation cache (docs/compilation.md) in a directory made for the session and
  removed at its end, storing every program: a program compiled again (another test's closure with the
  same computation, a module's programs after ``jax.clear_caches``, a process the suite starts) is loaded,
  not compiled. A ``JAX_COMPILATION_CACHE_DIR`` already set is used as it is, and kept.
- Python's cyclic garbage collector runs less often: tracing creates many short-lived objects.
"""

import concurrent.futures
import ctypes
import ctypes.util
import gc
import multiprocessing
import os
import shutil
import sys
import tempfile

import jax
import numpy as np
import pytest

import jdpim

_CACHE_ENV = {
    "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
    "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES": "-1",
}


def pytest_configure(config):
    """Share one compilation cache between this process and those it starts (workers, notebooks, commands)."""
    if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
        os.environ["JAX_COMPILATION_CACHE_DIR"] = config._jdpim_cache_dir = tempfile.mkdtemp(prefix="jdpim-jax-cache-")
    os.environ.update(_CACHE_ENV)
    jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)


def pytest_unconfigure(config):
    if getattr(config, "_jdpim_cache_dir", None):
        shutil.rmtree(config._jdpim_cache_dir, ignore_errors=True)


gc.set_threshold(50_000, 20, 100)
jax.config.update("jax_numpy_rank_promotion", "raise")


_LIBC = ctypes.CDLL(ctypes.util.find_library("c")) if sys.platform.startswith("linux") else None


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
    """Drop a test file's compiled programs when it ends, and hand the freed memory back to the system (glibc keeps
    it otherwise: measured 773 -> 299 MB after a dozen small solves): each worker's memory stays that of one file's
    programs (a later file that needs one loads it from the session's compilation cache)."""
    yield
    jax.clear_caches()
    gc.collect()
    if _LIBC is not None and hasattr(_LIBC, "malloc_trim"):
        _LIBC.malloc_trim(0)


ALPHA, D_REF = 0.03, 0.03
T_TRANSIENT, T_LATE = 10.0, 100.0

# Sizes of a small run, for the tests (and the examples in docs/api.md and the docstrings, which write them out) that
# need some run of a scene, not a particular horizon or sample: a compiled program depends on the model's structure,
# t_end, dt, the number of saved times and the number of paths, not on parameter values or which times are saved, so
# every such test on these sizes and a scene of the same structure loads the program another compiled (the session's
# compilation cache). FREE_MODEL (no barrier, no cubic damping) is the cheapest to compile.
T_SMALL, DT_SMALL, N_SMALL = 2.0, 0.02, 64
FREE_MODEL = jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, barrier=None)


@pytest.fixture(scope="session")
def elastic_scene():
    """r = 1, linear damping (exact folded-Gaussian solution), saved at a transient and a late time."""
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, r=1.0)
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D_REF), t_end=T_LATE, dt=0.01, save_at=(T_TRANSIENT, T_LATE))


@pytest.fixture(scope="session")
def elastic_dpim(elastic_scene):
    return jdpim.dpim(elastic_scene, n_points=1000)


@pytest.fixture(scope="session")
def elastic_mc(elastic_scene):
    return jdpim.monte_carlo(elastic_scene, n_samples=4000, seed=0)


@pytest.fixture(scope="session")
def x_grid():
    return np.linspace(0.0, 5.0, 401)


@pytest.fixture(scope="session")
def v_grid():
    return np.linspace(-5.0, 5.0, 801)


@pytest.fixture(scope="session")
def notebook_runs(request, tmp_path_factory):
    """The notebooks selected for this session, run one after another in a background process.

    They start when the first notebook test asks for them (in the process that runs those tests, when
    pytest-xdist spreads the files over workers); ``test_notebook_runs`` waits for each result. Maps a
    notebook's stem to a future.
    """
    from test_notebooks import NOTEBOOKS, execute

    wanted = {
        item.callspec.id
        for item in request.session.items
        if getattr(item, "originalname", None) == "test_notebook_runs"
    }
    spawn = multiprocessing.get_context("spawn")  # no fork of a process that runs JAX's threads
    with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=spawn) as pool:
        yield {
            path.stem: pool.submit(execute, path, tmp_path_factory.mktemp(path.stem))
            for path in NOTEBOOKS
            if path.stem in wanted
        }
