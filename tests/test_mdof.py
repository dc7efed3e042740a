"""Several degrees of freedom: exact stationary densities, the impact law's invariants, hard cases, bad input."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.stats

import jdpim
from jdpim._integrate import ImpactRule, integrate
from jdpim.metrics import l1

THETA = 0.1  # temperature: B D B^T = THETA C
SYSTEMS = {
    # masses, stiffness, constraints (normal, position): a wall at q1 >= -0.3 and a gap between two masses
    2: ([1.0, 0.5], [[2.0, -1.0], [-1.0, 1.0]], [((1.0, 0.0), -0.3), ((-1.0, 1.0), -0.25)]),
    3: (
        [1.0, 0.8, 0.5],
        [[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]],
        [((1.0, 0.0, 0.0), -0.3), ((0.0, -1.0, 1.0), -0.2)],
    ),
}


def elastic_system(n):
    masses, stiffness, constraints = SYSTEMS[n]
    M = np.diag(masses)
    barriers = tuple(jdpim.Barrier(normal, position, 1.0) for normal, position in constraints)
    model = jdpim.MDOFOscillator(mass=M, gains=np.eye(n), damping=0.4 * M, stiffness=stiffness, constraints=barriers)
    return model, jdpim.WhiteNoise(D=THETA * 0.4 * M)


def exact_marginals(n, grids):
    """Marginals of ``exp(-q^T K q / (2 THETA))`` on the admissible set, by quadrature on the product grid."""
    _, K, constraints = SYSTEMS[n]
    Q = np.stack(np.meshgrid(*grids, indexing="ij"), axis=-1)
    ok = np.all([Q @ np.asarray(normal) >= position for normal, position in constraints], axis=0)
    p = np.where(ok, np.exp(-0.5 * np.einsum("...i,ij,...j->...", Q, np.asarray(K), Q) / THETA), 0.0)
    out = []
    for i in range(n):
        m = p
        for j in reversed(range(n)):
            if j != i:
                m = np.trapezoid(m, grids[j], axis=j)
        out.append(m / np.trapezoid(m, grids[i]))
    return out


# slow: n = 3 repeats the check of n = 2 (a wall and a constraint between two masses) on a third mass
@pytest.mark.parametrize("n", [2, pytest.param(3, marks=pytest.mark.slow)])
def test_stationary_marginals_match_the_gibbs_density(n):
    """Linear M, C, K with B D B^T = theta C and elastic constraints: p ~ exp(-(v^T M v + q^T K q) / (2 theta)) on the
    admissible set. Monte Carlo, 6000 paths pooled over 13 times in [30, 60] s (relaxation time 2.5 s): every
    coordinate's and velocity's marginal within L1 0.02 (measured at n = 2: 0.010-0.014)."""
    model, noise = elastic_system(n)
    save = tuple(np.arange(30.0, 60.1, 2.5))
    scene = jdpim.Scene(model, noise=noise, t_end=60.0, dt=0.02, save_at=save)
    res = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=6000, seed=0))
    states = np.asarray(res.states).reshape(-1, 1, 2 * n)
    pooled = jdpim.Result(
        (0.0,), states, np.full(len(states), 1.0 / len(states)), model.bounds(), "monte_carlo", model.coordinates
    )
    grids = [np.linspace(-0.3, 2.0, 240)] + [np.linspace(-2.2, 2.2, 240 if n == 2 else 120)] * (n - 1)
    for name, grid, exact in zip(model.coordinates, grids, exact_marginals(n, grids), strict=False):
        assert l1(np.asarray(pooled.pdf(name, grid)), exact, grid) < 0.02, name
    masses = SYSTEMS[n][0]
    for name, m in zip(model.coordinates[n:], masses, strict=True):
        sd = np.sqrt(THETA / m)  # velocities: independent Gaussians whatever the constraints
        grid = np.linspace(-5 * sd, 5 * sd, 401)
        exact = np.exp(-0.5 * (grid / sd) ** 2) / (np.sqrt(2 * np.pi) * sd)
        assert l1(np.asarray(pooled.pdf(name, grid)), exact, grid) < 0.02, name
    cons = model.stacked_constraints()
    assert np.all(states[:, 0, :n] @ cons.normal.T - np.asarray(cons.position) >= 0)  # no penetration


@functools.partial(jax.jit, static_argnames=("n_steps",))
def free_flight(model, q0, v0, h, n_steps):
    """Paths of a force-free model (RK4 is exact between impacts), saved after every step; float64."""
    n, d = q0.shape
    slots = jnp.arange(n_steps, dtype=jnp.int32)
    e = jnp.zeros((2 * n_steps + 1, n, 1), q0.dtype)
    rule = ImpactRule(stick_velocity=0.0)
    return integrate(lambda _: model, rule, h, q0, v0, e, jnp.zeros((n, 0), q0.dtype), slots, n_steps, n_steps)


@pytest.mark.parametrize("r", [1.0, 0.5])
def test_impacts_conserve_momentum_and_elastic_ones_energy(r):
    """Two masses (1 and 3) closing a gap, alone and between two elastic walls: every impact keeps the momentum of
    a mass-mass contact; with r = 1 every impact keeps the kinetic energy (to rounding), with r < 1 none adds any."""
    walls = (jdpim.Barrier((1.0, 0.0), -1.0, 1.0), jdpim.Barrier((0.0, -1.0), -1.0, 1.0))  # q1 >= -1, q2 <= 1
    gap = jdpim.Barrier((-1.0, 1.0), 0.1, r)  # q2 - q1 >= 0.1
    with jax.enable_x64(True):
        M = np.diag([1.0, 3.0])
        for constraints in ((gap,), walls + (gap,)):
            model = jdpim.MDOFOscillator(mass=M, gains=np.zeros((2, 1)), constraints=constraints)
            rng = np.random.default_rng(0)
            q0 = np.stack([rng.uniform(-0.9, -0.5, 64), rng.uniform(0.0, 0.9, 64)], axis=1)
            v0 = rng.normal(0.0, 1.0, (64, 2))
            v0[:, 0] = np.abs(v0[:, 0])  # the masses approach each other first
            v0[:, 1] = -np.abs(v0[:, 1])
            out = np.asarray(free_flight(model, jnp.asarray(q0), jnp.asarray(v0), 0.01, 400))
            q, v = out[..., :2], out[..., 2:]
            energy = 0.5 * np.einsum("psi,ij,psj->ps", v, M, v)
            momentum = v @ np.diag(M)
            assert np.all(q[..., 1] - q[..., 0] >= 0.1 - 1e-12)  # no penetration
            if len(constraints) == 1:  # a mass-mass contact only: momentum kept through every impact
                np.testing.assert_allclose(momentum, np.repeat((v0 @ np.diag(M))[:, None], 400, axis=1), atol=1e-12)
                assert np.any(v[:, -1, 0] != v0[:, 0])  # the masses did collide
            else:
                assert np.all(np.abs(q) <= 1.0 + 1e-12)
            e0 = 0.5 * np.einsum("pi,ij,pj->p", v0, M, v0)
            if r == 1.0:
                np.testing.assert_allclose(energy, np.repeat(e0[:, None], 400, axis=1), rtol=1e-12)
            else:  # never gains energy; most paths lost some
                assert np.all(np.diff(energy, axis=1) <= 1e-12 * e0[:, None])
                assert np.mean(energy[:, -1] < 0.999 * e0) > 0.5


A, G, R = 0.03, 0.03, 0.98
REFERENCE_AS_MDOF = jdpim.MDOFOscillator(
    mass=[[1.0]],
    gains=[[1.0]],
    damping=[[A]],
    stiffness=[[1.0]],
    force=lambda q, v, p: -G * v**3,
    constraints=(jdpim.Barrier((1.0,), 0.0, R),),
    names=("x",),
)


def reference_scene():
    """The reference oscillator from x0 = 0.5 to t = 10 s in float64 (built inside ``jax.enable_x64``)."""
    return jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=A, gamma=G, r=R),
        noise=jdpim.WhiteNoise(D=0.03),
        t_end=10.0,
        dt=0.01,
        save_at=(2.0, 10.0),
        x0=0.5,
        dtype="float64",
    )


def test_one_degree_of_freedom_as_mdof_reproduces_the_reference_scene():
    """The reference oscillator written as an MDOFOscillator (same seed): the same paths to rounding in float64
    (measured max 2e-10 at t = 10 s from x0 = 0.5; only the order of the force terms differs)."""
    mdof = REFERENCE_AS_MDOF
    assert mdof.coordinates == ("x", "v")
    with jax.enable_x64(True):
        ref = reference_scene()
        method = jdpim.MonteCarlo(n_samples=300, seed=0)
        one, many = jdpim.solve(ref, method), jdpim.solve(ref.replace(model=mdof), method)
        assert np.max(np.abs(np.asarray(one.states) - np.asarray(many.states))) < 1e-8
        grid = np.linspace(0, 2, 21)
        np.testing.assert_allclose(many.pdf("x", grid, 10.0), one.pdf("x", grid, 10.0), atol=1e-8)


@pytest.mark.slow  # the default tier checks the likelihood ratio of damping[0,0] of several degrees of freedom against
# the exact derivative (test_likelihood_ratio_of_several_degrees_of_freedom_matches_the_exact_derivative), and that of
# a first passage (test_first_passage.py::test_brownian_velocity_with_drift_passes_and_its_derivatives_as_exactly_known)
def test_one_degree_of_freedom_as_mdof_gives_the_likelihood_ratio_of_the_reference_scene():
    """The likelihood ratio (the default of first passage) of alpha, and of C[0,0] of the reference oscillator written
    as an MDOFOscillator (same seed): the same scores, hence the same derivatives and standard errors."""
    mdof = REFERENCE_AS_MDOF
    with jax.enable_x64(True):
        ref, method = reference_scene(), jdpim.MonteCarlo(n_samples=300, seed=0)
        fp_one = jdpim.first_passage(ref, "x", 1.0, method, wrt="alpha")
        fp_many = jdpim.first_passage(ref.replace(model=mdof), "x", 1.0, method, wrt="damping[0,0]")
        np.testing.assert_allclose(fp_many.derivative["damping[0,0]"], fp_one.derivative["alpha"], rtol=1e-6)
        np.testing.assert_allclose(
            fp_many.derivative_stderr["damping[0,0]"], fp_one.derivative_stderr["alpha"], rtol=1e-6
        )
        d, se = np.asarray(fp_one.derivative["alpha"])[-1], np.asarray(fp_one.derivative_stderr["alpha"])[-1]
        assert np.all(np.abs(d) > 4 * se)  # at t = 10 s (at t = 2 s no path has passed yet)


def damper_scene():
    """The impact damper (clearance +-0.1, r = 0.5) to t = 5 s, as tests here and in test_examples_mdof.py run it with
    :data:`DAMPER_MC` (one compiled program)."""
    return jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.01), t_end=5.0, dt=0.01, save_at=(2.5, 5.0))


DAMPER_MC = jdpim.MonteCarlo(n_samples=200, seed=3)


def test_slow_impacts_mirrored_trade_a_little_accuracy_for_time():
    """``ImpactRule(mirror_below=v)`` mirrors the crossings slower than ``v`` instead of locating them: above every
    speed it is the mirror rule, bit for bit; at 0.01 on the impact damper the paths stay within 1e-3 of the
    located ones (common random numbers; measured 3.0e-4 RMS of x1 at t = 2.5 and 5 s, 1.6e-4 with 2000 paths),
    a sixth of the mirror rule's distance (1.7e-3) or less, and every saved state is admissible."""
    scene, mc = damper_scene(), DAMPER_MC
    run = {
        name: np.asarray(jdpim.solve(scene.replace(impacts=rule), mc).states)
        for name, rule in (
            ("locate", jdpim.ImpactRule()),
            ("slow", jdpim.ImpactRule(mirror_below=0.01)),
            ("all", jdpim.ImpactRule(mirror_below=1e9)),
            ("mirror", jdpim.ImpactRule(method="mirror")),
        )
    }
    np.testing.assert_array_equal(run["all"], run["mirror"])

    def rms(a, b):
        return float(np.sqrt(np.mean((a[..., 0] - b[..., 0]) ** 2)))

    assert 0 < rms(run["slow"], run["locate"]) < 1e-3
    assert rms(run["slow"], run["locate"]) < rms(run["mirror"], run["locate"]) / 4
    gap = run["slow"][..., 1] - run["slow"][..., 0]
    assert np.all(np.abs(gap) <= 0.1 + 1e-6)


# slow: DPIM runs its paths through the steps of the Monte Carlo cell, from other inputs (DPIM on several degrees of
# freedom: test_scenefile_mdof.py::test_run_stores_every_coordinate_and_equals_solve_on_the_scene_built_by_hand)
@pytest.mark.parametrize(
    "method",
    [jdpim.MonteCarlo(n_samples=500, seed=0), pytest.param(jdpim.DPIM(n_points=300), marks=pytest.mark.slow)],
    ids=["monte_carlo", "dpim"],
)
def test_hard_cases_stay_finite_and_admissible(method):
    """An impact damper: a light mass (0.05) in a clearance of +-0.05 around a primary mass, r = 0.3 (chattering),
    stiff coupling (k = 400 on the light mass: h omega = 0.9 at dt = 0.01), a wall hit in the same steps: finite
    states, no constraint violated at any saved time, by Monte Carlo and DPIM."""
    M = np.diag([1.0, 0.05])
    K = np.array([[1.0, 0.0], [0.0, 0.0]]) + 20.0 * np.array([[1.0, -1.0], [-1.0, 1.0]])
    constraints = (
        jdpim.Barrier((-1.0, 1.0), -0.05, 0.3),  # q2 - q1 >= -0.05
        jdpim.Barrier((1.0, -1.0), -0.05, 0.3),  # q2 - q1 <= 0.05
        jdpim.Barrier((1.0, 0.0), -0.2, 0.7),  # the primary mass against a wall
    )
    model = jdpim.MDOFOscillator(mass=M, gains=[[1.0], [0.0]], damping=0.02 * M, stiffness=K, constraints=constraints)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.05), t_end=20.0, dt=0.01, save_at=tuple(range(1, 21)))
    cons = model.stacked_constraints()
    res = jdpim.solve(scene, method)
    states = np.asarray(res.states)
    assert np.all(np.isfinite(states))
    c = states[..., :2] @ cons.normal.T - np.asarray(cons.position)
    assert c.min() >= -1e-6
    assert res.coordinates == ("x1", "x2", "v1", "v2")


BAD = {
    "mass-not-spd": (
        lambda: jdpim.MDOFOscillator(mass=[[1.0, 2.0], [2.0, 1.0]], gains=[[1.0], [0.0]]),
        ValueError,
        "mass must be symmetric positive definite",
    ),
    "mass-not-square": (lambda: jdpim.MDOFOscillator(mass=[[1.0, 0.0]], gains=[[1.0]]), ValueError, "mass must be"),
    "normal-length": (
        lambda: jdpim.MDOFOscillator(
            mass=np.eye(2), gains=[[1.0], [0.0]], constraints=(jdpim.Barrier((1.0,), 0.0, 1.0),)
        ),
        ValueError,
        r"constraints\[0\].normal has 1 entries; the system has 2",
    ),
    "normal-zero": (lambda: jdpim.Barrier((0.0, 0.0)), ValueError, "normal must not be zero"),
    "r-range": (lambda: jdpim.Barrier((1.0, 0.0), 0.0, 1.5), ValueError, r"r must lie in \[0, 1\]"),
    "gains-shape": (
        lambda: jdpim.MDOFOscillator(mass=np.eye(2), gains=[[1.0, 0.0, 0.0]]),
        ValueError,
        r"gains must be a matrix of shape \(2, m\)",
    ),
    "damping-shape": (
        lambda: jdpim.MDOFOscillator(mass=np.eye(2), gains=np.eye(2), damping=np.eye(3)),
        ValueError,
        r"damping must be a matrix of shape \(2, 2\)",
    ),
    "constraints-type": (
        lambda: jdpim.MDOFOscillator(mass=np.eye(2), gains=np.eye(2), constraints=((1.0, 0.0),)),
        TypeError,
        "constraints must be a tuple of jdpim.Barrier",
    ),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_fails_in_one_clear_line(case):
    build, kind, message = BAD[case]
    with pytest.raises(kind, match=message):
        build()


def test_scene_checks_the_start_and_path_integration_refuses():
    model, noise = elastic_system(2)
    with pytest.raises(ValueError, match=r"x0=\[-0.5, 0.0\] violates constraints\[0\]"):
        jdpim.Scene(model, noise=noise, x0=[-0.5, 0.0])
    with pytest.raises(ValueError, match=r"v0 must be a scalar or have shape \(2,\)"):
        jdpim.Scene(model, noise=noise, v0=[0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="noise source"):
        jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.1))
    scene = jdpim.Scene(model, noise=noise, t_end=1.0, dt=0.01)
    with pytest.raises(ValueError, match="path integration needs a grid of dimension 2n, here 4"):
        jdpim.solve(scene, jdpim.PathIntegration())


def test_a_scene_of_several_degrees_of_freedom_passes_through_jit_and_lower():
    """The scene is a pytree argument: jit and AOT lowering rebuild it with tracers or placeholders as leaves."""
    scene = damper_scene()
    back = jax.jit(lambda s: s)(scene)  # every leaf a tracer inside, an array (of JAX's dtype) out
    assert jax.tree_util.tree_structure(back) == jax.tree_util.tree_structure(scene)
    for a, b in zip(jax.tree_util.tree_leaves(back), jax.tree_util.tree_leaves(scene), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b, np.asarray(a).dtype))
    assert jax.jit(lambda s: s.t_end * 2.0).lower(scene).compile()(scene) == 2.0 * scene.t_end


@pytest.mark.slow  # the default tier solves a scene given to jit in
# test_api.py::test_solve_and_its_results_pass_through_jit and rebuilds one of several degrees of freedom (above)
def test_a_scene_of_several_degrees_of_freedom_solves_under_jit_as_it_does_eagerly():
    scene = damper_scene()
    direct = jdpim.solve(scene, DAMPER_MC).states
    jitted = jax.jit(lambda s: jdpim.solve(s, DAMPER_MC).states)
    np.testing.assert_array_equal(np.asarray(jitted(scene)), np.asarray(direct))


def test_random_matrix_entry_gives_the_mixture_variance():
    """``x'' + c x' + k x = xi`` with ``k ~ U(0.5, 2)`` random per path: stationary ``E[x^2] = (D / c) E[1/k]``,
    ``E[1/k] = ln 4 / 1.5``; the fixed mean ``k = 1.25`` gives ``D / (1.25 c)``, 13 % less (six standard errors)."""
    D, c = 0.04, 0.4
    model = jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], damping=[[c]], stiffness=[[1.25]])
    scene = jdpim.Scene(
        model, noise=jdpim.WhiteNoise(D=D), t_end=60.0, dt=0.02, random={"stiffness[0,0]": jdpim.Uniform(0.5, 2.0)}
    )
    x = np.asarray(jdpim.solve(scene, jdpim.MonteCarlo(n_samples=4000, seed=0)).states[:, -1, 0], float)
    mean, se = np.mean(x**2), np.std(x**2) / np.sqrt(x.size)
    exact = D / c * np.log(4.0) / 1.5
    assert abs(mean - exact) < 4 * se, (mean, exact, se)
    assert mean - D / (1.25 * c) > 3 * se


def test_parameters_of_several_degrees_of_freedom_by_name():
    damper = jdpim.impact_damper(damping_ratio=0.0)  # undamped primary, clearance +-0.1, r = 0.5
    scene = jdpim.Scene(damper, noise=jdpim.WhiteNoise(D=0.01), t_end=1.0, dt=0.01)
    names = jdpim.parameter_names(scene)
    assert {"stiffness[0,0]", "gains[1,0]", "constraints[1].r", "constraints[0].position", "D"} <= set(names)
    changed = jdpim.with_parameters(scene, {"constraints[1].r": 0.9, "stiffness[0,0]": 4.0})
    assert changed.model.constraints[1].r == 0.9 and changed.model.constraints[0].r == 0.5
    np.testing.assert_array_equal(np.asarray(changed.model.stiffness), np.diag([4.0, 0.0]))
    with pytest.raises(ValueError, match="random parameter 'x0' is not a model parameter"):
        scene.replace(random={"x0": jdpim.Uniform(0.0, 0.1)})
    with pytest.raises(ValueError, match="unknown parameter"):
        jdpim.with_parameters(scene, {"stiffness[2,0]": 1.0})


def _damper_scene():
    damper = jdpim.MDOFOscillator(
        mass=np.diag([1.0, 0.05]),
        gains=[[1.0], [0.0]],
        stiffness=np.diag([1.0, 0.0]),
        constraints=(jdpim.Barrier((-1.0, 1.0), -0.1, 1.0), jdpim.Barrier((1.0, -1.0), -0.1, 0.5)),
    )
    return jdpim.Scene(damper, noise=jdpim.WhiteNoise(D=0.01), t_end=0.5, dt=0.01, x0=[0.3, 0.3])


DAMPER = _damper_scene()  # built once, outside the traces below


def _second_moment(k):
    s = jdpim.with_parameters(DAMPER, {"stiffness[0,0]": k})
    return jdpim.solve(s, jdpim.MonteCarlo(n_samples=16, seed=0)).moment("x1", 2, 0.5)


def test_forward_mode_through_impacts_between_masses_warns():
    """Pathwise derivatives through impacts between masses are not validated: jax.jvp warns. The warning is raised
    while the derivative is traced, so tracing it (``jax.eval_shape``, nothing compiled) is the whole check."""
    with pytest.warns(jdpim.SensitivityWarning, match="several degrees of freedom"):
        jax.eval_shape(lambda k: jax.jvp(_second_moment, (k,), (1.0,)), 1.0)


def test_reverse_mode_through_impacts_between_masses_warns():
    """Pathwise derivatives through impacts between masses are not validated: jax.grad warns (traced, as above)."""
    with pytest.warns(jdpim.SensitivityWarning, match="several degrees of freedom"):
        jax.eval_shape(jax.grad(_second_moment), 1.0)


def test_sensitivity_of_several_degrees_of_freedom_takes_central_differences_or_the_likelihood_ratio():
    """``sensitivity`` refuses pathwise derivatives for several degrees of freedom, and the likelihood ratio where
    no score exists: a restitution, a parameter that changes the acceleration of a coordinate the noise does not
    drive, or the gains; the message names the estimator that applies."""
    scene = _damper_scene()
    grid = np.linspace(-1.0, 1.0, 5)
    with pytest.raises(ValueError, match="CentralDifference or LikelihoodRatio"):
        jdpim.sensitivity(scene, ("stiffness[0,0]",), "x1", grid, estimator=jdpim.Pathwise())
    with pytest.raises(ValueError, match="var must be one of the coordinates"):
        jdpim.sensitivity(scene, ("stiffness[0,0]",), "x", grid)
    lr = jdpim.LikelihoodRatio()
    for name, message in (
        ("constraints[0].r", "drift parameters only, not 'constraints\\[0\\].r'; use CentralDifference"),
        (
            "stiffness[1,0]",
            "changes the acceleration of coordinates the noise does not drive \\(it drives \\['x1'\\]\\)",
        ),
        ("gains[0,0]", "changes the noise gains: no likelihood ratio; use CentralDifference"),
    ):
        with pytest.raises(ValueError, match=message):
            jdpim.sensitivity(scene, (name,), "x1", grid, estimator=lr)
    two = scene.replace(
        model=scene.model.replace(gains=((1.0, 0.0), (0.0, 1.0))), noise=jdpim.WhiteNoise(D=np.diag([0.01, 0.01]))
    )
    with pytest.raises(ValueError, match="needs one noise source, the scene has 2"):
        jdpim.sensitivity(two, ("stiffness[0,0]",), "x1", grid, estimator=lr)
    with pytest.raises(ValueError, match="the noise intensity D is 0: no likelihood ratio"):
        jdpim.sensitivity(scene.replace(noise=jdpim.WhiteNoise(D=0.0)), ("stiffness[0,0]",), "x1", grid, estimator=lr)
    silent = scene.replace(model=scene.model.replace(gains=((0.0,), (0.0,))))
    with pytest.raises(ValueError, match="the noise gains are zero: no likelihood ratio"):
        jdpim.sensitivity(silent, ("stiffness[0,0]",), "x1", grid, estimator=lr)
    mc = jdpim.MonteCarlo(n_samples=64, seed=0)
    dp = jdpim.sensitivity(scene, ("constraints[0].r",), "x1", grid, method=mc, bandwidth=0.05)
    assert np.all(np.isfinite(np.asarray(dp.value["constraints[0].r"])))  # the pair (0.98, 1) stays in [0, 1]


def test_likelihood_ratio_of_several_degrees_of_freedom_matches_the_exact_derivative():
    """A chain of two unit masses (``K = [[2, -1], [-1, 1]]``, ``C = 0.5 I``) with white noise on the first only:
    the stationary covariance solves a Lyapunov equation. The density of ``x2``, which the noise does not drive,
    differentiated with respect to ``K[0,0]`` and ``C[0,0]`` (their changes act along the noise) by the
    likelihood ratio (10000 paths, one run, score window 20 s: truncation bias about ``e^-5``), against the exact
    derivative of the same smoothed density: within four standard errors at the grid points of the bulk, where at
    least 1000 of the paths fall within two bandwidths (``|x2| <= 0.25``, 1.7 standard deviations; 12 normal errors:
    a false alarm rate of at most ``7.6e-4``). Further out the few paths that carry the estimate make its error
    heavy-tailed: over 16 seeds of each of two noise generators it reaches 4.3 standard errors at 0.35 (432 paths
    near) and its mean square there is 1.4, while in the bulk it stays within 2.34 with mean square 0.73."""
    D, c, sigma = 0.02, 0.5, 0.05
    K = np.array([[2.0, -1.0], [-1.0, 1.0]])
    model = jdpim.MDOFOscillator(mass=np.eye(2), gains=[[1.0], [0.0]], damping=c * np.eye(2), stiffness=K)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=30.0, dt=0.02)
    grid = np.linspace(-0.45, 0.45, 10)
    names = ("stiffness[0,0]", "damping[0,0]")
    est = jdpim.LikelihoodRatio(window=20.0)
    dp = jdpim.sensitivity(
        scene, names, "x2", grid, method=jdpim.MonteCarlo(n_samples=10_000, seed=0), bandwidth=sigma, estimator=est
    )

    def variance(K, C):
        A = np.block([[np.zeros((2, 2)), np.eye(2)], [-K, -C]])
        b = np.array([0.0, 0.0, 1.0, 0.0])
        return scipy.linalg.solve_continuous_lyapunov(A, -2.0 * D * np.outer(b, b))[1, 1]

    def smoothed(K, C):
        s2 = variance(K, C) + sigma**2
        return np.exp(-0.5 * grid**2 / s2) / np.sqrt(2 * np.pi * s2)

    sd = np.sqrt(variance(K, c * np.eye(2)))
    near = 10_000 * (scipy.stats.norm.cdf((grid + 2 * sigma) / sd) - scipy.stats.norm.cdf((grid - 2 * sigma) / sd))
    bulk = near >= 1000
    assert bulk.sum() == 6

    h, E = 1e-5, np.diag([1.0, 0.0])
    for name, (dK, dC) in zip(names, ((E, 0 * E), (0 * E, E)), strict=True):
        exact = (smoothed(K + h * dK, c * np.eye(2) + h * dC) - smoothed(K - h * dK, c * np.eye(2) - h * dC)) / (2 * h)
        value, se = np.asarray(dp.value[name])[bulk], np.asarray(dp.value_stderr[name])[bulk]
        assert np.all(np.abs(value - exact[bulk]) < 4 * se), (name, np.max(np.abs(value - exact[bulk]) / se))
        assert np.max(np.abs(exact[bulk])) > 5 * np.max(se)  # the check has power


def test_central_difference_of_several_degrees_of_freedom_matches_the_exact_derivative():
    """``x'' + c x' + k x = xi`` written as an MDOF model: stationary ``p = N(0, D / (c k))``. Monte Carlo central
    differences (common random numbers, 20000 paths, ``k`` +- 0.2) with the kernel width held fixed, against the
    exact central difference of the same smoothed density (variance ``D / (c k) + sigma^2``): within four
    standard errors at every grid point."""
    D, c, k, h, sigma = 0.04, 0.4, 1.0, 0.2, 0.05
    model = jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], damping=[[c]], stiffness=[[k]])
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=40.0, dt=0.02)
    grid = np.linspace(-0.8, 0.8, 17)
    method, est = jdpim.MonteCarlo(n_samples=20_000, seed=0), jdpim.CentralDifference(step=h)
    dp = jdpim.sensitivity(scene, ("stiffness[0,0]",), "x1", grid, method=method, bandwidth=sigma, estimator=est)
    value, se = np.asarray(dp.value["stiffness[0,0]"]), np.asarray(dp.value_stderr["stiffness[0,0]"])

    def smoothed(k):
        s2 = D / (c * k) + sigma**2
        return np.exp(-0.5 * grid**2 / s2) / np.sqrt(2 * np.pi * s2)

    exact = (smoothed(k + h) - smoothed(k - h)) / (2 * h)
    assert np.all(np.abs(value - exact) < 4 * se), np.max(np.abs(value - exact) / se)
    assert np.max(np.abs(exact)) > 10 * np.max(se)  # the check has power: the derivative stands out of the noise
