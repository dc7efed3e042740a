"""One shape for every method: ``solve(scene, method)``, method objects, and the result interface they share."""

import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import DT_SMALL, FREE_MODEL, N_SMALL, T_SMALL
from test_first_solve import _Compiles

import jdpim

PI = jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1)


@pytest.fixture(scope="module")
def scene():
    return jdpim.Scene(FREE_MODEL, noise=jdpim.WhiteNoise(D=0.05), t_end=T_SMALL, dt=DT_SMALL)


@pytest.fixture(scope="module")
def results(scene):
    return {
        "dpim": jdpim.solve(scene, jdpim.DPIM(n_points=N_SMALL)),
        "monte_carlo": jdpim.solve(scene, jdpim.MonteCarlo(n_samples=N_SMALL, seed=3)),
        "path_integration": jdpim.solve(scene, PI),
    }


def test_solve_reproduces_the_shorthands_bit_for_bit(scene, results):
    np.testing.assert_array_equal(results["dpim"].states, jdpim.dpim(scene, N_SMALL).states)
    np.testing.assert_array_equal(results["monte_carlo"].states, jdpim.monte_carlo(scene, N_SMALL, seed=3).states)
    np.testing.assert_array_equal(results["path_integration"].density, jdpim.path_integration(scene, PI).density)


# slow: the default tier checks path_integration(...) as solve(...) in the test above (one code path), and a
# stationary run's times in path_integration's doctest (jdpim/methods/_path_integration.py)
@pytest.mark.slow
def test_solve_reproduces_the_stationary_shorthand_bit_for_bit(scene):
    stationary = jdpim.solve(scene, jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1, stationary=True))
    np.testing.assert_array_equal(stationary.density, jdpim.path_integration(scene, PI, stationary=True).density)
    assert stationary.times == (float("inf"),)


def test_every_result_answers_the_same_questions(scene, results):
    grid = np.linspace(-1.0, 1.0, 9)
    for name, res in results.items():
        assert res.method == name and res.times == (2.0,) and res.coordinates == ("x", "v")
        for var in ("x", "v"):
            p = res.pdf(var, grid)  # one saved time: t may be left out
            np.testing.assert_array_equal(p, res.pdf(var, grid, t=2.0))
            assert p.shape == (9,) and np.all(np.isfinite(p))
            assert res.pdf(var, 0.5).shape == ()  # a scalar grid gives a scalar
        joint = res.joint_pdf(("x", "v"), (grid, grid[:5]))
        assert joint.shape == (9, 5)
        np.testing.assert_allclose(res.joint_pdf(("v", "x"), (grid[:5], grid)), joint.T, rtol=1e-5, atol=1e-7)
        assert float(res.mass()) == pytest.approx(1.0, abs=1e-5)
        assert res.n_nonfinite().shape == (1,) and int(res.n_nonfinite()[0]) == 0
        assert float(res.moment("x", 2)) > 0


def test_densities_of_functions_of_the_state(results):
    """A function of the state is a quantity like a coordinate: same density, same moments."""
    grid = np.linspace(-1.0, 1.0, 9)
    energy = lambda s: 0.5 * s[0] ** 2 + 0.5 * s[1] ** 2  # noqa: E731
    for res in results.values():
        np.testing.assert_allclose(res.moment(lambda s: s[1], 2), res.moment("v", 2), rtol=1e-5)
        e = 0.5 * (res.moment("x", 2) + res.moment("v", 2))
        np.testing.assert_allclose(res.moment(energy, 1), e, rtol=1e-5)
        p = res.pdf(lambda s: s[0], grid, bandwidth=0.1)
        assert p.shape == (9,) and np.all(np.asarray(p) >= 0)
    samples = results["monte_carlo"]
    np.testing.assert_allclose(
        samples.pdf(lambda s: s[0], grid, bandwidth=0.1), samples.pdf("x", grid, bandwidth=0.1), rtol=1e-6
    )
    e_grid = np.linspace(-0.05, 1.0, 421)  # the energy's kernel is not reflected at 0: its tail reaches below
    p_e = np.asarray(results["path_integration"].pdf(energy, e_grid, bandwidth=0.01))
    assert np.sum(p_e) * (e_grid[1] - e_grid[0]) == pytest.approx(1.0, abs=1e-3)


def test_the_grid_density_smoothed_as_the_sampling_methods_smooth(results):
    """``GridResult.pdf(..., bandwidth=h)`` is the grid density convolved with the Gaussian of sd h."""
    ref = results["path_integration"]
    grid = np.linspace(-0.6, 0.6, 7)
    nodes = np.asarray(ref.x)
    fine = np.asarray(ref.pdf("x", nodes))
    kernel = np.exp(-0.5 * ((grid[:, None] - nodes[None, :]) / 0.1) ** 2) / (0.1 * np.sqrt(2 * np.pi))
    direct = kernel @ (np.asarray(ref.x_weights) * fine)
    np.testing.assert_allclose(ref.pdf("x", grid, bandwidth=0.1), direct, rtol=1e-4)


def _compiled(questions) -> list:
    """Names of the programs XLA compiles while ``questions()`` runs."""
    logger, handler = logging.getLogger("jax"), _Compiles()
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    try:
        jax.block_until_ready(questions())
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    return handler.names


def test_a_grid_question_is_one_compiled_program(results):
    """Each question to a grid result compiles one program (never one per operation), and the same questions at
    other values of the same shapes (grid, bandwidth, saved time) compile nothing."""
    res, grid = results["path_integration"], np.linspace(-0.7, 0.7, 6)

    def questions(shift, h):
        return (
            res.pdf("x", grid + shift),
            res.joint_pdf(("v", "x"), (grid[:3], grid + shift), bandwidth=(h, 2 * h)),
            res.moment("v", 3),
            res.nodal_marginal("x"),
        )

    first = _compiled(lambda: questions(0.0, 0.1))
    assert sorted(first) == ["jit(_joint_pdf_at)", "jit(_marginal)", "jit(_moment_at)", "jit(_pdf_at)"], first
    assert _compiled(lambda: questions(0.05, 0.2)) == []


def test_t_is_required_where_a_result_holds_several_times(scene):
    res = jdpim.solve(scene.replace(save_at=(1.0, 2.0)), jdpim.DPIM(n_points=N_SMALL))
    with pytest.raises(ValueError, match=r"t is required: this result holds 2 saved times"):
        res.pdf("x", np.linspace(-1, 1, 5))
    with pytest.raises(ValueError, match=r"coordinates \('x', 'v'\) or a function of the state"):
        res.pdf("y", np.linspace(-1, 1, 5), t=1.0)


@pytest.mark.parametrize(
    "call, error, match",
    [
        (lambda s: jdpim.solve(s, "dpim"), TypeError, r"a jdpim method object, e.g. jdpim.DPIM\(\).*got 'dpim'"),
        (lambda s: jdpim.solve(s, jdpim.DPIM), TypeError, r"got the class DPIM"),
        (lambda s: jdpim.solve(s, jdpim.DPIM(N_SMALL)).pdf("x", "abc"), TypeError, r"grid must be numbers"),
        (lambda s: jdpim.solve(None, jdpim.DPIM()), TypeError, "scene must be a jdpim.Scene"),
        (lambda s: jdpim.DPIM(n_points=1), ValueError, "n_points must be an integer >= 2"),
        (lambda s: jdpim.DPIM(points=np.ones((4, 2))), TypeError, "points must be a jdpim.PointSet"),
        (lambda s: jdpim.MonteCarlo(n_samples=10, seed=-1), ValueError, "seed must be an integer >= 0"),
        (lambda s: jdpim.MonteCarlo(progress="yes"), TypeError, "progress must be None, True or False"),
        (lambda s: jdpim.MonteCarlo(chunk_size=0), ValueError, "chunk_size must be an integer >= 1"),
        (lambda s: jdpim.PathIntegration(stationary=1), TypeError, "stationary must be True or False"),
        (lambda s: jdpim.PathIntegration(initial=3.0), TypeError, "initial must be a callable"),
    ],
)
def test_methods_check_their_settings(scene, call, error, match):
    with pytest.raises(error, match=match):
        call(scene)


def test_solve_and_its_results_pass_through_jit(scene):
    grid = jnp.linspace(-1.0, 1.0, 5)
    method = jdpim.MonteCarlo(n_samples=N_SMALL, seed=1)
    eager = jdpim.solve(scene, method)
    res = jax.jit(jdpim.solve)(scene, method)  # the method is pytree structure, the scene's leaves are traced
    np.testing.assert_allclose(res.states, eager.states, rtol=1e-6, atol=1e-7)
    pdf = jax.jit(lambda r: r.pdf("x", grid))(eager)
    np.testing.assert_allclose(pdf, eager.pdf("x", grid), rtol=1e-6)
