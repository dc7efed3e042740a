"""Results are pytrees: they pass through ``jax.jit`` and ``jax.vmap`` as arguments and outputs, and their
methods give the same numbers inside a transformation as outside. Grid densities hold their mass, and the
grid's error estimate covers the exact error.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import DT_SMALL, N_SMALL, T_SMALL

import jdpim
from jdpim import exact, metrics

GRID = jnp.array([0.2, 0.5, 0.9])


@pytest.fixture(scope="module")
def scene():
    model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=0.03, r=0.9)
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.03), t_end=T_SMALL, dt=DT_SMALL, save_at=(1.0, T_SMALL))


@pytest.fixture(scope="module")
def results(scene):
    small = jdpim.PathIntegration(n_x=41, n_v=81, x_max=1.5, v_max=1.5, tau=0.1, t0=1.0)
    return {
        "dpim": jdpim.dpim(scene, n_points=N_SMALL),
        "mcs": jdpim.monte_carlo(scene, n_samples=N_SMALL, seed=0),
        "grid": jdpim.path_integration(scene, small),
    }


@pytest.mark.parametrize("name", ["dpim", "mcs", "grid"])
def test_results_pass_through_jit_as_arguments_and_outputs(results, name):
    res = results[name]
    inside = jax.jit(lambda r: (r.pdf("x", GRID, 2.0), r.pdf("v", 0.1, 2.0), r.moment("x", 2, 2.0), r.mass(2.0)))
    outside = (res.pdf("x", GRID, 2.0), res.pdf("v", 0.1, 2.0), res.moment("x", 2, 2.0), res.mass(2.0))
    for a, b in zip(inside(res), outside, strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6)
    again = jax.jit(lambda r: r)(res)
    assert type(again) is type(res) and again.times == res.times
    np.testing.assert_allclose(np.asarray(again.pdf("x", GRID, 1.0)), np.asarray(res.pdf("x", GRID, 1.0)), rtol=1e-6)
    assert np.asarray(res.joint_pdf(("x", "v"), (0.5, jnp.array([-0.1, 0.1])), 2.0)).shape == (2,)


def test_a_batch_of_results_passes_through_vmap(scene):
    points = jdpim.dpim_points(scene, N_SMALL)  # the size of results["dpim"]: run(D) below reuses its program

    def run(D):
        return jdpim.dpim(scene.replace(noise=jdpim.WhiteNoise(D=D)), points=points)

    batch = jax.vmap(run)(jnp.array([0.02, 0.04]))
    assert batch.states.shape == (2, N_SMALL, 2, 2) and batch.times == (1.0, 2.0)
    pdfs = jax.vmap(lambda r: r.pdf("x", GRID, 2.0))(batch)
    for i, D in enumerate((0.02, 0.04)):
        np.testing.assert_allclose(np.asarray(pdfs[i]), np.asarray(run(D).pdf("x", GRID, 2.0)), rtol=2e-5, atol=1e-7)


def test_sensitivity_passes_through_jit():
    """A :class:`jdpim.Sensitivity` of the kind ``jdpim.sensitivity`` returns, built from its fields (estimators,
    times and method: structure; the arrays: leaves); a computed one's pytree is flattened and compared in
    test_persistence.py::test_sensitivity_round_trip."""
    value, stderr = {"alpha": jnp.array([0.3, -1.2, 0.4])}, {"alpha": jnp.array([0.1, 0.2, 0.1])}
    out = jdpim.Sensitivity(value, stderr, {"alpha": jdpim.LikelihoodRatio()}, (2.0,), "dpim")
    again = jax.jit(lambda s: s)(out)
    assert isinstance(again, jdpim.Sensitivity) and again.times == out.times and again.method == out.method
    np.testing.assert_allclose(np.asarray(again["alpha"]), np.asarray(out["alpha"]))
    doubled = jax.jit(lambda s: jax.tree.map(lambda a: 2 * a, s))(out)
    np.testing.assert_allclose(np.asarray(doubled["alpha"]), 2 * np.asarray(out["alpha"]), rtol=1e-6)


def test_times_are_checked(results):
    res = results["dpim"]
    with pytest.raises(ValueError, match="one saved time"):
        res.pdf("x", GRID, np.array([1.0, 2.0]))
    assert np.allclose(res.moment("x", 2, np.float32(2.0)), res.moment("x", 2, 2.0))
    with pytest.raises(TypeError, match="concrete saved time"):
        jax.jit(lambda t: res.moment("x", 2, t))(2.0)


@pytest.mark.filterwarnings("ignore:path integration. the stationary balance")  # r = 0.3 on this small grid
@pytest.mark.parametrize("r", [0.05, 0.3, 0.98])
def test_interpolated_marginals_integrate_to_one(r):
    # Measured (61 x 121): 1 - 5e-7, 1 - 5e-8, 1 + 6e-8 for x; before, the interpolant lost 0.9 % at r = 0.3
    model = jdpim.VibroImpactOscillator(alpha=0.05, gamma=None, r=r)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.1), t_end=1.0, dt=0.01)
    res = jdpim.path_integration(scene, jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1), stationary=True)
    xs = np.linspace(float(res.x[0]), float(res.x[-1]), 20001)
    vs = np.linspace(float(res.v[0]), float(res.v[-1]), 20001)
    assert abs(np.trapezoid(np.asarray(res.pdf("x", xs)), xs) - 1) < 1e-3
    assert abs(np.trapezoid(np.asarray(res.pdf("v", vs)), vs) - 1) < 1e-3
    assert abs(float(res.mass()) - 1) < 1e-5


@pytest.mark.slow  # grid errors are also checked in tests/test_first_passage_pi.py
def test_grid_error_estimate_covers_the_exact_error():
    # Measured (float64): estimate / error = 5.5-11 (x) and 4.4-8.8 (v) over stationary, t = 5 and t = 20
    # on 61 x 121 and 121 x 241 nodes
    alpha, D = 0.1, 0.01
    xs, vs = np.linspace(0.0, 2.0, 2001), np.linspace(-2.0, 2.0, 4001)
    model = jdpim.VibroImpactOscillator(alpha=alpha, gamma=None, r=1.0)
    with jax.enable_x64(True):
        scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=5.0, dt=0.1, dtype="float64")
        settings = jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1, estimate_error=True)
        res = jdpim.path_integration(scene, settings)
        err_x = metrics.l1(np.asarray(res.pdf("x", xs, 5.0)), exact.elastic_linear_pdf_x(xs, alpha, D, 5.0), xs)
        err_v = metrics.l1(np.asarray(res.pdf("v", vs, 5.0)), exact.elastic_linear_pdf_v(vs, alpha, D, 5.0), vs)
        est_x, est_v = float(res.l1_error("x", 5.0)), float(res.l1_error("v", 5.0))
        pointwise = np.asarray(res.pdf_error("x", xs, 5.0))
    assert err_x < est_x < 20 * err_x and err_v < est_v < 20 * err_v, (err_x, est_x, err_v, est_v)
    assert pointwise.shape == xs.shape and np.all(pointwise >= 0)
    with pytest.raises(ValueError, match="estimate_error=True"):
        jdpim.path_integration(scene.replace(dtype=None), jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1)).l1_error(
            "x", 5.0
        )
