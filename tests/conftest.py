"""Shared test configuration: strict JAX checks, and scenes/results computed once per session.

Compilation dominates the cost of the suite on a 2-core CPU, so expensive results are session-scoped
fixtures reused by many tests, and sizes are small. Heavier settings carry the ``slow`` marker.

Python's cyclic garbage collector runs less often in the test processes: tracing creates many short-lived
objects. XLA compiles with its defaults, as users run the library.
"""

import concurrent.futures
import gc
import multiprocessing

import jax
import numpy as np
import pytest

import jdpim

gc.set_threshold(50_000, 20, 100)
jax.config.update("jax_numpy_rank_promotion", "raise")

ALPHA, D_REF = 0.03, 0.03
T_TRANSIENT, T_LATE = 10.0, 100.0


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


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop JAX's compiled executables after each module: the suite's peak memory stays that of one module."""
    yield
    jax.clear_caches()


@pytest.fixture(autouse=True, scope="session")
def notebook_runs(request, tmp_path_factory):
    """The notebooks selected for this session, run one after another in a background process from its start.

    Their kernels compile on the core the test process leaves idle (it compiles on one);
    ``test_notebook_runs`` waits for each result. Maps a notebook's stem to a future.
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
