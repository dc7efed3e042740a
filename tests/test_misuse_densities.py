"""Densities of bounded quantities: reflection at both ends of an interval, probability held at a constraint
(atoms), and the impact damper's relative displacement, which a kernel reflected at one end or none would get
silently wrong (mass leaking past the walls, the peaks at the walls flattened)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

import jdpim
from jdpim.results._density import _gauss, _interval_kernel
from jdpim.results._samples import model_constraints

C = 0.1  # the damper's clearance (jdpim.impact_damper's default)


def gap(s):
    """The damper's relative displacement ``x2 - x1``, in ``[-c, c]``."""
    return s[1] - s[0]


@pytest.mark.parametrize("ratio", [0.05, 0.3, 0.5, 0.8, 3.0])
def test_interval_kernel_is_the_sum_over_all_images(ratio):
    """Both forms of the two-sided kernel (images where sigma <= L / 2, cosine series above) against 30 images a
    side, float64: equal to 1e-14, on both sides of the switch."""
    with jax.enable_x64(True):
        u, w = jnp.linspace(0.0, 1.0, 41)[:, None], jnp.linspace(0.0, 1.0, 17)[None, :]
        images = sum(_gauss((u - w + 2 * k) / ratio) + _gauss((u + w + 2 * k) / ratio) for k in range(-30, 31))
        np.testing.assert_allclose(
            np.asarray(_interval_kernel(u, w, ratio, 1.0)), np.asarray(images), rtol=0, atol=1e-14
        )


@pytest.mark.parametrize("sigma", [0.01, 0.1, 0.4, 1.0, 5.0])
def test_two_sided_kde_holds_unit_mass_inside(sigma):
    """Any sample in [a, b], any bandwidth: the density integrates to 1 over [a, b] (to the quadrature's 1e-6)
    and is zero outside; reflected at a alone, the mass past b is lost (0.021 at sigma = 0.01, 0.70 at 5)."""
    with jax.enable_x64(True):
        y = jnp.asarray(np.random.default_rng(0).beta(0.5, 0.5, size=500) * 2.0 - 0.5)  # piled at both ends
        w = jnp.full(y.shape, 1 / y.size)
        g = np.linspace(-0.5, 1.5, 4001)
        p = np.asarray(jdpim.kde(y, w, g, sigma, bounds=(-0.5, 1.5)))
        assert np.trapezoid(p, g) == pytest.approx(1.0, abs=1e-6)
        assert float(jdpim.kde(y, w, 1.6, sigma, bounds=(-0.5, 1.5))) == 0.0
        one_sided = np.trapezoid(np.asarray(jdpim.kde(y, w, g, sigma, barrier=-0.5)), g)
        assert one_sided < 0.98


@pytest.mark.parametrize("sigma", [0.05, 0.2, 0.7])
def test_two_sided_kde_recovers_a_known_density(sigma):
    """Samples of ``p(y) = (1 + cos(pi y)) / 1`` on [0, 1] (zero slope at both ends): the reflected kernel keeps
    its cosine, so the estimate's mean is ``1 + exp(-(pi sigma)^2 / 2) cos(pi y)`` exactly, up to the walls and
    for any bandwidth. 4e4 samples: within 4 standard errors (kde_stderr) on 51 points, the walls included."""
    nodes = np.linspace(0.0, 1.0, 100_001)
    y = np.interp(np.random.default_rng(1).uniform(size=40_000), nodes + np.sin(np.pi * nodes) / np.pi, nodes)
    w = np.full(y.size, 1 / y.size)
    g = np.linspace(0.0, 1.0, 51)
    p = np.asarray(jdpim.kde(y, w, g, sigma, bounds=(0.0, 1.0)))
    se = np.asarray(jdpim.kde_stderr(y, w, g, sigma, bounds=(0.0, 1.0)))
    mean = 1.0 + np.exp(-0.5 * (np.pi * sigma) ** 2) * np.cos(np.pi * g)
    assert np.all(np.abs(p - mean) <= 4 * se), np.max(np.abs(p - mean) / se)


def test_bounds_are_checked():
    y, w = jnp.linspace(0.0, 1.0, 11), jnp.full(11, 1 / 11)
    with pytest.raises(ValueError, match=r"bounds must be a pair \(a, b\) with a < b, got \(1.0, 0.0\)"):
        jdpim.kde(y, w, 0.5, 0.1, bounds=(1.0, 0.0))
    with pytest.raises(ValueError, match="give either barrier or bounds, not both"):
        jdpim.kde(y, w, 0.5, 0.1, barrier=0.0, bounds=(0.0, 1.0))
    with pytest.raises(ValueError, match=r"bounds must be a pair \(a, b\), either side None"):
        jdpim.kde(y, w, 0.5, 0.1, bounds=0.0)


@pytest.fixture(scope="module")
def damper():
    """The impact damper (clearance +-0.1, r = 0.5), white noise on the primary, from rest: 2000 paths, t = 5 s."""
    scene = jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.01), t_end=5.0, dt=0.01, save_at=(5.0,))
    return jdpim.solve(scene, jdpim.MonteCarlo(n_samples=2000, seed=0))


# slow: an end-to-end repeat of what the default tier checks in test_held_paths_are_atoms_not_density (the gap's
# bounds from the damper's constraints, atoms, the mass inside), test_two_sided_kde_recovers_a_known_density (the
# reflected kernel at both walls) and, for a solved damper's gap bounded by its constraints, in
# test_scenefile_mdof.py::test_run_stores_every_coordinate_and_equals_solve_on_the_scene_built_by_hand
@pytest.mark.slow
def test_damper_relative_displacement_is_bounded_and_matches_a_histogram(damper):
    """The reproducer of issue 44: the density of x2 - x1 holds its mass inside [-c, c] (a kernel without the
    second wall held 0.81-0.85), and away from the walls (3 bandwidths) matches a histogram of 40 bins within 4
    standard errors of their difference; at the walls it is the histogram smoothed by the same reflected kernel (a
    kernel without reflection shows about half of it)."""
    assert damper.bounds(gap) == pytest.approx((-C, C))
    g = np.linspace(-C, C, 801)  # the walls, and the centres of 40 bins at every 20th node from the 10th
    p, se = np.asarray(damper.pdf(gap, g)), np.asarray(damper.pdf_error(gap, g))
    assert np.trapezoid(p, g) == pytest.approx(1.0, abs=1e-4)
    np.testing.assert_array_equal(np.asarray(damper.atoms(gap)), [0.0, 0.0])  # white noise reaches the gap: no sticking

    edges, sigma = np.linspace(-C, C, 41), float(damper.bandwidth(gap))
    h, width = np.asarray(damper.histogram(gap, edges)), np.diff(edges)
    se_h = np.sqrt(h * width * (1 - h * width) / damper.n_paths) / width
    mean = np.array([np.trapezoid(p[20 * i : 20 * i + 21], g[20 * i : 20 * i + 21]) for i in range(40)]) / width
    away = np.abs(g[10::20]) <= C - 3 * sigma
    assert away.sum() >= 10
    z = (mean - h) / np.sqrt(se_h**2 + se[10::20] ** 2)
    assert np.all(np.abs(z[away]) <= 4), z[away]

    # at the walls: the fine histogram (200 bins) smoothed by the kernel reflected at both walls, its images
    # summed (scipy), within half a standard error (the bins' discretisation); without reflection about half
    edges = np.linspace(-C, C, 201)
    h = np.asarray(damper.histogram(gap, edges))
    plain = np.asarray(jdpim.kde(damper.samples(gap), damper.weights, g, sigma))
    for i, wall in ((0, -C), (-1, C)):
        images = [(edges + 4 * C * k, 1) for k in range(-2, 3)] + [
            (-2 * C - edges + 4 * C * k, -1) for k in range(-2, 3)
        ]
        smoothed = sum(sgn * np.sum(h * np.diff(scipy.stats.norm.cdf((e - wall) / sigma))) for e, sgn in images)
        assert p[i] == pytest.approx(smoothed, abs=float(0.5 * se[i]))
        assert plain[i] < 0.6 * smoothed


def test_held_paths_are_atoms_not_density():
    """Damper states built by hand (float32): two paths held at the walls (on them, both masses at one velocity),
    one touching a wall on its way out, two inside. The held probability is reported per wall by ``atoms`` (also
    under ``jax.jit``) and left out of the density, which integrates to the rest; ``bounds=`` given by hand gives
    the same, and bounds the samples leave fail."""
    damper = jdpim.impact_damper()
    states = jnp.array(
        [
            [0.3, 0.2, 0.5, 0.5],  # held at x2 - x1 = -c
            [1.0, 1.1, -0.3, -0.3],  # held at +c
            [-0.05, 0.05, 0.0, 0.2],  # at +c, leaving it
            [0.2, 0.21, 0.1, -0.4],
            [-0.4, -0.45, 0.0, 0.3],
        ]
    )[:, None, :]
    weights = jnp.array([0.1, 0.15, 0.2, 0.25, 0.3])
    res = jdpim.Result((1.0,), states, weights, None, "monte_carlo", damper.coordinates, model_constraints(damper))
    assert res.bounds(gap) == pytest.approx((-C, C)) and res.bounds("x1") == (None, None)
    np.testing.assert_allclose(np.asarray(res.atoms(gap)), [0.1, 0.15], rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(jax.jit(lambda r: r.atoms(gap))(res)), np.asarray(res.atoms(gap)))
    g = np.linspace(-C, C, 2001)
    p = np.asarray(res.pdf(gap, g, bandwidth=0.02))
    assert np.trapezoid(p, g) == pytest.approx(0.75, abs=1e-4)
    np.testing.assert_array_equal(p, np.asarray(res.pdf(gap, g, bandwidth=0.02, bounds=(-C, C))))
    with pytest.raises(ValueError, match=r"bounds=\(-0.05, 0.05\) do not hold: 3 of 5 samples of the function"):
        res.pdf(gap, g, bounds=(-0.05, 0.05))


def test_one_degree_of_freedom_sticking_is_an_atom_at_the_barrier():
    """A path resting on the barrier (x = b, v = 0 exactly, as the integrator leaves it) is an atom of x; one
    passing the barrier (v != 0) is not. Built by hand: three paths, one resting, one on the barrier moving out."""
    states = jnp.array([[[0.5, 0.0]], [[0.5, 0.3]], [[1.2, -0.4]]])
    weights = jnp.array([0.2, 0.3, 0.5])
    model = jdpim.VibroImpactOscillator(barrier=0.5, r=0.5)
    res = jdpim.Result((1.0,), states, weights, 0.5, "monte_carlo", constraints=model_constraints(model))
    assert res.bounds("x") == (0.5, None) and res.bounds("v") == (None, None)
    np.testing.assert_allclose(np.asarray(res.atoms("x")), [0.2, 0.0])
    g = np.linspace(0.5, 4.0, 3501)
    assert np.trapezoid(np.asarray(res.pdf("x", g, bandwidth=0.1)), g) == pytest.approx(0.8, abs=1e-3)
