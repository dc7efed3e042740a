"""Raw AD through sampled results: right, or warned by the estimate's own per-path contributions.

Each misuse case must fail if its derivative comes back silently wrong: a derivative carried by one path
(its tangent grew across impacts) must warn in every mode of AD, and a well-spread one must come back
exact and without a word. The cheap cases drive the mechanism with paths whose tangents are given
(``probed`` with a toy run, as the pipeline uses it); the slow case is the acceptance run itself.
"""

import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim._integrate import ImpactRule
from jdpim.methods._ad_guard import probed

N, Y, H = 512, 0.5, 0.1
MATCH = r"carried by .* of them.*jdpim\.sensitivity"


def _paths(heavy: bool):
    """``(x0, tau)``: positions at the nominal alpha and their tangents ``dx/dalpha``, ``(N,)`` each."""
    rng = np.random.default_rng(0)
    x0 = np.abs(rng.normal(0.5, 0.3, N))
    tau = rng.normal(0.0, 1.0, N)
    if heavy:  # one path near Y whose tangent grew across impacts: it alone carries the derivative
        tau[np.argmin(np.abs(x0 - Y - 0.05))] = 1e4
    return jnp.asarray(np.stack([x0, tau], axis=1), jnp.float32)


def _toy_run(scene, rows):
    """States ``(N, 1, 2)`` moving with alpha along the given tangents (a stand-in for ``simulate``)."""
    alpha = scene.model.alpha - 0.03
    x = rows[:, 0] + alpha * rows[:, 1]
    return jnp.stack([x, jnp.zeros_like(x)], axis=-1)[:, None, :]


def _result(alpha, rows):
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(alpha=alpha), t_end=1.0, dt=0.1)
    states = probed(_toy_run, scene, rows)
    return jdpim.Result(times=(1.0,), states=states, weights=jnp.full((N,), 1.0 / N), barrier=0.0)


FUNCTIONALS = {
    "pdf": lambda res: res.pdf("x", Y, bandwidth=H),
    "moment": lambda res: res.moment("x", 2),
}


def _exact(name, rows):
    """The pathwise derivative ``sum_i w_i f'(x_i) tau_i`` of each functional at the nominal alpha."""
    x, tau = np.asarray(rows, np.float64).T
    if name == "moment":
        return np.mean(2 * x * tau)
    dk = sum(s * (Y - s * x) / H**2 * np.exp(-0.5 * ((Y - s * x) / H) ** 2) for s in (1, -1)) / (H * np.sqrt(2 * np.pi))
    return np.mean(dk * tau)


TRANSFORMS = {
    "grad": jax.grad,
    "jacfwd": jax.jacfwd,
    "jacrev": jax.jacrev,
    "jit_grad": lambda f: jax.jit(jax.grad(f)),
    "jit_jacfwd": lambda f: jax.jit(jax.jacfwd(f)),
}


def _derivative(transform, functional, rows):
    f = functools.partial(lambda a, rows: FUNCTIONALS[functional](_result(a, rows)), rows=rows)
    return float(TRANSFORMS[transform](f)(jnp.float32(0.03)))


@pytest.mark.parametrize("functional", FUNCTIONALS)
@pytest.mark.parametrize("transform", TRANSFORMS)
def test_a_derivative_carried_by_one_path_warns(transform, functional):
    rows = _paths(heavy=True)
    with pytest.warns(jdpim.SensitivityWarning, match=MATCH):
        d = _derivative(transform, functional, rows)
    assert abs(d) > 100 * abs(_exact(functional, _paths(heavy=False)))  # what it would have returned silently


@pytest.mark.parametrize("functional", FUNCTIONALS)
@pytest.mark.parametrize("transform", TRANSFORMS)
def test_a_well_spread_derivative_is_exact_and_quiet(transform, functional):
    rows = _paths(heavy=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", jdpim.SensitivityWarning)
        d = _derivative(transform, functional, rows)
    np.testing.assert_allclose(d, _exact(functional, rows), rtol=1e-4)


@pytest.mark.parametrize("transform", ["grad", "jacfwd"])
def test_histogram_derivatives_warn(transform):
    """A histogram is piecewise constant in the paths: its derivative is zero, never a sensitivity."""
    rows = _paths(heavy=False)
    edges = np.linspace(0.0, 1.0, 6)
    with pytest.warns(jdpim.SensitivityWarning, match=r"derivative of a histogram is zero.*jdpim\.sensitivity"):
        d = TRANSFORMS[transform](lambda a: _result(a, rows).histogram("x", edges)[2])(jnp.float32(0.03))
    assert float(d) == 0.0


def test_the_pipeline_carries_the_check():
    """Differentiated, ``jdpim.solve`` contracts forward-mode tangents (the primitive whose transpose checks on
    the host): traced only, nothing compiled."""
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(), x0=0.5, t_end=0.2, dt=0.1)

    def pdf(alpha):
        res = jdpim.solve(jdpim.with_parameters(scene, {"alpha": alpha}), jdpim.MonteCarlo(n_samples=8))
        return res.pdf("x", Y, bandwidth=H)

    assert "jdpim_contract" in str(jax.make_jaxpr(jax.jacfwd(pdf))(0.03))
    assert "debug_callback" in str(jax.make_jaxpr(jax.grad(pdf))(0.03))  # the transpose's check


def test_values_are_unchanged_without_derivatives():
    rows = _paths(heavy=True)
    states = _result(jnp.float32(0.03), rows).states
    np.testing.assert_array_equal(np.asarray(states[:, 0, 0]), np.asarray(rows[:, 0]))


def test_jit_over_sensitivity_is_refused_in_one_line():
    scene = jdpim.Scene(jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, barrier=None), t_end=1.0, dt=0.1)
    grid = np.linspace(-1.0, 1.0, 5)
    method = jdpim.MonteCarlo(n_samples=64)
    with pytest.raises(TypeError, match=r"jdpim\.sensitivity cannot run under a JAX transformation"):
        jax.jit(lambda: jdpim.sensitivity(scene, "alpha", "x", grid, method=method)["alpha"])()
    with pytest.raises(TypeError, match=r"jdpim\.sensitivity cannot run under a JAX transformation"):
        jax.jit(lambda a: jdpim.sensitivity(jdpim.with_parameters(scene, {"alpha": a}), "alpha", "x", grid)["alpha"])(
            0.1
        )


@pytest.mark.slow
def test_the_pipeline_warns_at_long_horizons_only():
    """``jax.grad`` of ``Result.pdf`` through Monte Carlo from ``x0 = 0.5``: right at t = 2, warned at t = 50.

    Measured (512 paths, dt = 0.05, linear damping, no sticking): t = 2: -1.744 against -1.745 by central
    differences (same paths); t = 50: 2.8e10 against 8.7, carried by one path. About a minute of compilation.
    """
    model = jdpim.VibroImpactOscillator(alpha=0.03, gamma=None, r=0.98)
    scene = jdpim.Scene(
        model,
        noise=jdpim.WhiteNoise(D=0.03),
        x0=0.5,
        t_end=50.0,
        dt=0.05,
        save_at=(2.0, 50.0),
        impacts=ImpactRule(stick_velocity=0.0),
    )
    method = jdpim.MonteCarlo(n_samples=N, seed=0)

    def pdf(alpha, t):
        return jdpim.solve(jdpim.with_parameters(scene, {"alpha": alpha}), method).pdf("x", Y, t, bandwidth=H)

    d2 = float(jax.grad(pdf)(jnp.float32(0.03), 2.0))  # warnings are errors here
    step = 3e-3
    cd = (float(pdf(0.03 + step, 2.0)) - float(pdf(0.03 - step, 2.0))) / (2 * step)
    assert abs(d2 - cd) < 0.05 * abs(cd)
    with pytest.warns(jdpim.SensitivityWarning, match=MATCH):
        jax.grad(pdf)(jnp.float32(0.03), 50.0)


JOINT_X, JOINT_V = jnp.array([Y - 0.05, Y, Y + 0.05]), jnp.array([-0.1, 0.0, 0.1])


def _joint(res):
    """The joint density at ``(Y, 0)`` from a 3 x 3 grid: forward mode checks all nine nodes (projected)."""
    return res.joint_pdf(("x", "v"), (JOINT_X, JOINT_V), bandwidth=(H, H))[1, 1]


@pytest.mark.parametrize("heavy", [True, False])
@pytest.mark.parametrize("transform", ["jacfwd", "grad"])
def test_joint_pdf_is_checked_in_both_modes(transform, heavy):
    """The velocities are all 0 with zero tangents: the derivative is that of ``pdf`` times ``K_v(0) = 1 / (H
    sqrt(2 pi))``."""
    rows = _paths(heavy=heavy)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", jdpim.SensitivityWarning)
        d = float(TRANSFORMS[transform](lambda a: _joint(_result(a, rows)))(jnp.float32(0.03)))
    flagged = [w for w in caught if issubclass(w.category, jdpim.SensitivityWarning)]
    exact = _exact("pdf", rows) / (H * np.sqrt(2 * np.pi))
    if heavy:
        assert flagged and all("carried by" in str(w.message) for w in flagged)
        assert abs(d) > 100 * abs(_exact("pdf", _paths(heavy=False)) / (H * np.sqrt(2 * np.pi)))
    else:
        assert not flagged
        np.testing.assert_allclose(d, exact, rtol=1e-4)


def test_vmap_of_grad_checks_each_parameter_value():
    """``jax.vmap(jax.grad(f))`` over alpha: the value whose derivative one path carries warns; a value where the
    toy paths have moved that path off the kernel (``alpha = 0.05``: ``x`` shifted by 200) is exact."""
    rows = _paths(heavy=True)
    f = functools.partial(lambda a, rows: FUNCTIONALS["pdf"](_result(a, rows)), rows=rows)
    with pytest.warns(jdpim.SensitivityWarning, match=MATCH) as caught:
        d = np.asarray(jax.vmap(jax.grad(f))(jnp.array([0.03, 0.05], jnp.float32)))
    assert len([w for w in caught if issubclass(w.category, jdpim.SensitivityWarning)]) == 1
    moved = np.asarray(rows).copy()
    moved[:, 0] += 0.02 * moved[:, 1]
    np.testing.assert_allclose(d[1], _exact("pdf", jnp.asarray(moved)), rtol=1e-3, atol=1e-6)
    assert abs(d[0]) > 100 * abs(_exact("pdf", _paths(heavy=False)))


P_MANY = 40  # differentiated scalars, beyond MAX_DIRECTIONS: tangents by plain AD, checked along projections


def _many_result(theta, rows):
    """A result whose paths move with ``mean(theta)`` (``P_MANY`` scalars) as ``_result``'s move with alpha."""
    states = probed(
        lambda th, r: _toy_run(jdpim.Scene(jdpim.VibroImpactOscillator(alpha=jnp.mean(th))), r), theta, rows
    )
    return jdpim.Result(times=(1.0,), states=states, weights=jnp.full((N,), 1.0 / N), barrier=0.0)


@pytest.mark.parametrize("heavy", [True, False])
@pytest.mark.parametrize(
    "transform",
    # slow: jacrev is reverse mode along the same projections, checked with jax.grad in the default tier
    ["grad", pytest.param("jacrev", marks=pytest.mark.slow)],
)
def test_many_parameters_are_checked_along_projections(transform, heavy):
    """Reverse mode over more than ``MAX_DIRECTIONS`` scalars (forward mode is checked by ``Result.pdf`` itself)."""
    from jdpim.methods._ad_guard import MAX_DIRECTIONS

    assert P_MANY > MAX_DIRECTIONS
    rows = _paths(heavy=heavy)
    theta = jnp.full((P_MANY,), 0.03, jnp.float32)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", jdpim.SensitivityWarning)
        d = np.asarray(TRANSFORMS[transform](lambda th: FUNCTIONALS["pdf"](_many_result(th, rows)))(theta))
    flagged = [w for w in caught if issubclass(w.category, jdpim.SensitivityWarning)]
    if heavy:
        assert flagged and all("carried by" in str(w.message) for w in flagged)
    else:
        assert not flagged
        np.testing.assert_allclose(d, np.full(P_MANY, _exact("pdf", rows) / P_MANY), rtol=1e-4)
