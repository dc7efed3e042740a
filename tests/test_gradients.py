"""Derivatives of PDFs through the whole pipeline: finite differences, the saltation matrix, exact solutions.

Finite-difference checks run in float64 inside ``jax.enable_x64`` (a context manager, so the flag does
not leak into other test modules) and return NumPy arrays.
"""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import optimize

import jdpim
from jdpim import exact
from jdpim._integrate import ImpactRule, integrate, make_batch_step
from jdpim.sensitivities._estimators import Pathwise, SensitivityWarning
from jdpim.sensitivities._sensitivity import _density as density_of
from jdpim.sensitivities._sensitivity import pathwise_guard

PARAMS = ("alpha", "gamma", "r", "barrier", "D")
T_FD = 5.0
SIGMA_FD = 0.1


def _fd_scene():
    # Start off the barrier (a start at rest on it is a grazing impact, with singular sensitivity), a
    # 2 pi cutoff (pathwise sensitivities grow with the forcing level at impacts, S21 = (a+ + r a-) / v-)
    # and no sticking (a switch): a case where the computed PDF is smooth in the parameters.
    model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=0.05, r=0.9)
    return jdpim.Scene(
        model,
        noise=jdpim.WhiteNoise(D=0.05),
        t_end=T_FD,
        dt=0.02,
        x0=0.5,
        excitation=jdpim.SpectralRepresentation(cutoff=2 * math.pi),
        impacts=ImpactRule(stick_velocity=0.0),
        dtype="float64",
    )


X_FD = np.linspace(0.05, 1.5, 30)  # off the barrier: the reflected density jumps to zero there
V_FD = np.linspace(-1.5, 1.5, 31)
XJ, VJ = np.linspace(0.05, 1.2, 12), np.linspace(-1.2, 1.2, 13)


@pytest.fixture(scope="module")
def fd_case():
    """AD derivatives (forward mode, one jacfwd) and central differences with the same points, float64."""
    with jax.enable_x64(True):
        scene = _fd_scene()
        points = jdpim.dpim_points(scene, 128)
        nominal = {
            name: float(jnp.asarray(scene.noise.D if name == "D" else getattr(scene.model, name))) for name in PARAMS
        }

        def pdfs(values):
            res = jdpim.dpim(jdpim.with_parameters(scene, values), points=points)
            return jnp.concatenate(
                [
                    res.pdf("x", X_FD, T_FD, bandwidth=SIGMA_FD),
                    res.pdf("v", V_FD, T_FD, bandwidth=SIGMA_FD),
                    res.joint_pdf(("x", "v"), (XJ, VJ), T_FD, bandwidth=(SIGMA_FD, SIGMA_FD)).ravel(),
                ]
            )

        # 128 points carry these derivatives unevenly (a few paths' tangents grew across impacts), which the
        # SensitivityWarning reports; they are the exact derivatives of the computed densities all the same,
        # and that is what is checked here.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", jdpim.SensitivityWarning)
            ad = jax.jacfwd(pdfs)({k: jnp.asarray(v) for k, v in nominal.items()})
        fd = {}
        for name, value in nominal.items():
            h = 1e-4 * max(abs(value), 0.1)
            up, down = dict(nominal, **{name: value + h}), dict(nominal, **{name: value - h})
            fd[name] = (np.asarray(pdfs(up)) - np.asarray(pdfs(down))) / (2 * h)
        return {k: np.asarray(v) for k, v in ad.items()}, fd


def _split(a):
    nx, nv = X_FD.size, V_FD.size
    return {"x": a[:nx], "v": a[nx : nx + nv], "xv": a[nx + nv :]}


@pytest.mark.parametrize("name", PARAMS)
def test_pdf_derivatives_match_central_differences(fd_case, name):
    # Measured relative L2 errors (float64, h = 1e-4 relative): <= 1e-3 for every parameter and PDF.
    ad, fd = fd_case
    for var in ("x", "v", "xv"):
        a, f = _split(ad[name])[var], _split(fd[name])[var]
        assert np.all(np.isfinite(a))
        assert np.linalg.norm(f) > 0
        assert np.linalg.norm(a - f) / np.linalg.norm(f) < 5e-3, (name, var)


R_SALTATION, B_SALTATION, H_SALTATION = 0.8, -0.3, 0.05


def _one_step_across_an_impact():
    """``(end, y0)``: the state after one RK4 step of ``x'' = -x`` from ``y0``, across an impact at ``b = -0.3``."""
    model = jdpim.VibroImpactOscillator(alpha=None, gamma=None, r=R_SALTATION, barrier=B_SALTATION)
    step = make_batch_step(lambda _: model, ImpactRule(stick_velocity=0.0), H_SALTATION)
    e, rand = jnp.zeros((1, 3, 1)), jnp.zeros((1, 0))

    def end(y):
        return jnp.concatenate(step(y[None, :1], y[None, 1:], e, rand), axis=1)[0]

    return end, jnp.array([B_SALTATION + 0.02, -0.7])


def test_single_impact_gives_the_saltation_matrix():
    """One RK4 step across an impact of ``x'' = -x`` at ``b = -0.3``: ``Phi((1 - s) h) S Phi(s h)``."""
    r, b, h = R_SALTATION, B_SALTATION, H_SALTATION
    with jax.enable_x64(True):
        end, y0 = _one_step_across_an_impact()
        jac = np.asarray(jax.jit(jax.jacfwd(end))(y0))
    x0, v0 = (float(c) for c in y0)
    # exact flow: x(t) = x0 cos t + v0 sin t reaches b at the impact time t*
    t_star = optimize.brentq(lambda t: x0 * math.cos(t) + v0 * math.sin(t) - b, 0.0, h, xtol=1e-15)
    assert 0 < t_star < h
    v_minus = -x0 * math.sin(t_star) + v0 * math.cos(t_star)
    a_minus = a_plus = -b  # x'' = -x at the barrier, before and after
    S = np.array([[-r, 0.0], [(a_plus + r * a_minus) / v_minus, -r]])

    def rot(tau):
        return np.array([[math.cos(tau), math.sin(tau)], [-math.sin(tau), math.cos(tau)]])

    expected = rot(h - t_star) @ S @ rot(t_star)
    naive = rot(h - t_star) @ np.diag([1.0, -r]) @ rot(t_star)
    # measured difference 1e-9 (RK4 and Hermite-interpolation error at h = 0.05)
    np.testing.assert_allclose(jac, expected, atol=1e-6)
    assert np.abs(jac - naive).max() > 0.5


# slow: the default tier checks reverse mode against forward mode across an impact (the same step, in the pipeline) in
# test_mdof_sticking::test_reverse_mode_from_rest_on_a_wall_is_finite_and_equals_forward_mode
@pytest.mark.slow
def test_single_impact_reverse_mode_equals_forward_mode():
    with jax.enable_x64(True):
        end, y0 = _one_step_across_an_impact()
        jac = np.asarray(jax.jit(jax.jacfwd(end))(y0))
        np.testing.assert_allclose(np.asarray(jax.jit(jax.jacrev(end))(y0)), jac, rtol=1e-12, atol=1e-12)


def test_reverse_mode_stores_only_the_step_carry():
    """Memory of reverse mode: per step only ``q, v`` (``(n, 1)`` each) and the excitation nodes (three ``(n, m)``) are
    saved (``jax.checkpoint`` around the step); RK4 stages and impact resolution are recomputed."""
    from jax._src.ad_checkpoint import saved_residuals

    model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=0.05, r=0.9)
    T, n = 50, 8

    def f(alpha):
        m = model.replace(alpha=alpha)
        exc, slots = jnp.zeros((2 * T + 1, n, 1)), jnp.ones((T,), jnp.int32)
        q0, v0 = jnp.full((n, 1), 0.5), jnp.zeros((n, 1))
        out = integrate(lambda _: m, ImpactRule(), 0.02, q0, v0, exc, jnp.zeros((n, 0)), slots, 1, 1)
        return out.sum()

    shapes = [tuple(aval.shape) for aval, _ in saved_residuals(f, 0.1)]
    per_step = sorted(s for s in shapes if s[:1] == (T,))
    assert per_step == sorted([(T,), (T, n, 1), (T, n, 1), (T, n, 1), (T, n, 1), (T, n, 1)])
    assert all(math.prod(s) <= n for s in shapes if s[:1] != (T,))  # constants and the inputs: nothing per step


@pytest.fixture(scope="module")
def tiny():
    """A short scene with a few points: for transformation compositions (float32, the default dtype)."""
    model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=0.05, r=0.9)
    scene = jdpim.Scene(
        model, noise=jdpim.WhiteNoise(D=0.05), t_end=2.0, dt=0.02, x0=0.3, impacts=ImpactRule(stick_velocity=0.0)
    )
    return scene, jdpim.dpim_points(scene, 16)


V_TINY = np.linspace(-1.0, 1.0, 9)


def _loss(scene, points, alpha):
    """A scalar functional of the PDF: its value at the grid nodes, weighted."""
    res = jdpim.dpim(scene.replace(model=scene.model.replace(alpha=alpha)), points=points)
    return jnp.sum(res.pdf("v", V_TINY, 2.0, bandwidth=0.2) * jnp.linspace(0.0, 1.0, V_TINY.size))


def _forward(scene, points, alpha):
    """Forward mode on the same points, through ``jdpim.sensitivity``: 16 points carry a sampling error of the size of
    the derivative, which it reports (the tests compare modes of AD on the same points, not the estimate)."""
    s = scene.replace(model=scene.model.replace(alpha=alpha))
    with pytest.warns(SensitivityWarning, match="standard error"):
        dp = jdpim.sensitivity(
            s, ("alpha",), "v", V_TINY, bandwidth=0.2, estimator=Pathwise(), method=jdpim.DPIM(points=points)
        )["alpha"]
    return float(jnp.sum(dp * jnp.linspace(0.0, 1.0, V_TINY.size)))


def test_changing_parameters_does_not_retrace(tiny):
    """New alpha values reuse the compiled code: a user's jitted PDF function traces once."""
    scene, points = tiny
    traces = []

    @jax.jit
    def pdf_of(alpha):
        traces.append(None)
        res = jdpim.dpim(scene.replace(model=scene.model.replace(alpha=alpha)), points=points)
        return res.pdf("v", V_TINY, 2.0, bandwidth=0.2)

    before = jdpim.simulate._cache_size()
    for a in (0.05, 0.07, 0.11):
        assert np.all(np.isfinite(pdf_of(jnp.float32(a))))
        jdpim.dpim(scene.replace(model=scene.model.replace(alpha=a)), points=points)
    assert len(traces) == 1
    assert jdpim.simulate._cache_size() - before <= 1  # one entry for this scene structure, whatever alpha


@pytest.mark.slow
def test_jit_grad_agrees_with_forward_mode(tiny):
    """Reverse mode of the whole pipeline under jit (slow: its compilation dominates)."""
    scene, points = tiny
    g = float(jax.jit(jax.grad(lambda a: _loss(scene, points, a)))(jnp.float32(0.11)))
    # float32: forward and reverse accumulate in different orders
    np.testing.assert_allclose(g, _forward(scene, points, 0.11), rtol=2e-3, atol=1e-6)


@pytest.mark.slow
def test_jit_vmap_grad_compose(tiny):
    """``jit(vmap(grad))`` over alpha values (slow: about 3 minutes of compilation on 2 cores)."""
    scene, points = tiny
    alphas = jnp.array([0.05, 0.1, 0.2])
    batched = jax.jit(jax.vmap(jax.grad(lambda a: _loss(scene, points, a))))
    rev = np.asarray(batched(alphas))
    fwd = [_forward(scene, points, float(a)) for a in alphas]
    assert np.all(np.isfinite(rev))
    np.testing.assert_allclose(rev, fwd, rtol=2e-3, atol=1e-6)  # float32: forward vs reverse accumulation order


def test_bandwidth_policy():
    """``None``: the rule's sigma at the nominal parameters, held fixed; ``"adaptive"`` adds d sigma / d lambda.

    Checked on samples that scale with a parameter (``y_q(a) = a y_q``), without the pipeline.
    """
    y0, w = jnp.linspace(0.1, 2.0, 32), jnp.full((32,), 1 / 32)
    grid = np.linspace(0.05, 3.0, 20)

    def result(a):
        states = jnp.stack([a * y0, -a * y0], axis=-1)[:, None, :]
        return jdpim.Result(times=np.array([1.0]), states=states, weights=w, barrier=0.0, method="dpim")

    def derivative(bandwidth):
        return np.asarray(jax.jacfwd(lambda a: density_of(result(a), "x", grid, 1.0, bandwidth, "chen"))(1.0))

    sigma = float(result(1.0).bandwidth("x", 1.0))
    fixed, adaptive = derivative(None), derivative("adaptive")
    np.testing.assert_allclose(fixed, derivative(sigma), rtol=1e-5, atol=1e-6)
    assert np.abs(adaptive - fixed).max() > 0.05 * np.abs(fixed).max()


def test_sensitivity_rejects_bad_arguments(tiny):
    scene, points = tiny
    with pytest.raises(ValueError, match="unknown parameter"):
        jdpim.sensitivity(scene, ("mass",), "x", V_TINY + 1.0, method=jdpim.DPIM(points=points))
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['mass'\];"):  # one name, not its letters
        jdpim.sensitivity(scene, "mass", "x", V_TINY + 1.0, method=jdpim.DPIM(points=points))
    with pytest.raises(TypeError, match="grid must be numbers: a 1-D array"):
        jdpim.sensitivity(scene, ("alpha",), "x", ["a", "b"], method=jdpim.DPIM(points=points))
    with pytest.raises(ValueError, match="var must be"):
        jdpim.sensitivity(scene, ("alpha",), "y", V_TINY, method=jdpim.DPIM(points=points))
    with pytest.raises(ValueError, match="is None"):
        jdpim.sensitivity(
            scene.replace(model=scene.model.replace(gamma=None)),
            ("gamma",),
            "v",
            V_TINY,
            method=jdpim.DPIM(points=points),
        )


def test_pathwise_guard():
    """Exploding pathwise values (the README call at t = 5 from rest gave max |dp/dalpha| ~ 1e10) are flagged."""
    p = np.array([0.1, 1.0, 0.5])
    ok = {"alpha": np.array([1.0, -3.0, 2.0])}
    pathwise_guard(True, 2.0, 4.0, {"alpha": 0.03}, ok, p)  # no warning (warnings are errors here)
    with pytest.warns(SensitivityWarning, match="beyond the Pathwise horizon"):
        pathwise_guard(True, 5.0, 4.0, {"alpha": 0.03}, ok, p)
    pathwise_guard(False, 50.0, 4.0, {"alpha": 0.03}, ok, p)  # no barrier: no impacts, no horizon
    with pytest.warns(SensitivityWarning, match="explodes"):
        pathwise_guard(False, 2.0, 4.0, {"alpha": 0.03}, {"alpha": np.array([1.0, 1.8e10, 2.0])}, p)


@pytest.mark.slow
def test_pathwise_beyond_its_horizon_warns(tiny):
    """Pathwise tangents through impacts grow without bound: never returned silently past the horizon."""
    scene, points = tiny
    # and a sampling error of the size of the derivative (16 points), reported too
    with (
        pytest.warns(SensitivityWarning, match="standard error"),
        pytest.warns(SensitivityWarning, match="beyond the Pathwise horizon"),
    ):
        dp = jdpim.sensitivity(
            scene,
            ("alpha",),
            "v",
            V_TINY,
            bandwidth=0.2,
            estimator=Pathwise(horizon=1.0),
            method=jdpim.DPIM(points=points),
        )
    assert np.all(np.isfinite(dp["alpha"]))


@pytest.mark.slow
def test_noise_derivative_against_the_exact_elastic_solution():
    """``dp/dD`` at t = 10 (r = 1, linear damping, from rest) against the exact derivative of the smoothed PDF.

    The exact half-normal smoothed with the reflected kernel is the half-normal with variance ``sx2 + sigma^2``.
    Measured relative L2 error with 256 points: 0.33 (the PDF itself: 5.7 %); ``dp/dalpha`` is far worse
    (6.5): pathwise derivatives are heavy-tailed across impacts (docs/gradients.md).
    """
    T, D, alpha = 10.0, 0.03, 0.1
    scene = jdpim.Scene(
        jdpim.VibroImpactOscillator(alpha=alpha, gamma=None, r=1.0), noise=jdpim.WhiteNoise(D=D), t_end=T, dt=0.02
    )
    points = jdpim.dpim_points(scene, 256)
    grid = np.linspace(0.02, 2.0, 100)
    sigma = float(jdpim.dpim(scene, points=points).bandwidth("x", T))
    # all reported: the start at rest on the barrier (a grazing impact), t beyond the Pathwise horizon, and a standard
    # error of about 0.3 of the derivative; with r = 1 and linear damping the tangents stay moderate, and the error
    # against the exact derivative is that standard error's size
    with (
        pytest.warns(SensitivityWarning, match="grazing"),
        pytest.warns(SensitivityWarning, match="horizon"),
        pytest.warns(SensitivityWarning, match="standard error"),
    ):
        dp = jdpim.sensitivity(
            scene, ("D",), "x", grid, T, bandwidth=sigma, estimator=Pathwise(), method=jdpim.DPIM(points=points)
        )["D"]
    dp = np.asarray(dp)

    def smoothed(d):
        s2 = exact.linear_covariance(alpha, d, T)[0] + sigma**2
        return 2 * np.exp(-0.5 * grid**2 / s2) / np.sqrt(2 * np.pi * s2)

    reference = (smoothed(D + 1e-6) - smoothed(D - 1e-6)) / 2e-6
    assert np.linalg.norm(dp - reference) / np.linalg.norm(reference) < 0.45


@pytest.fixture(scope="module")
def grazing():
    """The default start, at rest on the barrier: a grazing impact at t = 0."""
    model = jdpim.VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.03), t_end=1.0, dt=0.05)
    return scene, jdpim.dpim_points(scene, 32)


def _p_of(scene, points):
    def p(alpha):
        return jdpim.dpim(scene.replace(model=scene.model.replace(alpha=alpha)), points=points).pdf("x", 0.2, 1.0)

    return p


def test_pathwise_derivatives_through_a_grazing_start_warn(grazing):
    # measured (t = 2, 256 points, p_x(0.2)): jax.grad gives dp/dalpha -2.29 (float32) and +0.59 (float64) against
    # about -0.4 by central differences; from x0 = 0.5 AD and central differences agree within 2e-4. Forward
    # mode here: reverse mode goes through the same tangent rule, and its compilation takes minutes. The warning is
    # issued when the derivative is traced: the user's jitted function is traced (eval_shape), not compiled.
    p = _p_of(*grazing)
    with pytest.warns(jdpim.SensitivityWarning, match=r"grazing impact\) are biased.*jdpim\.sensitivity"):
        jax.eval_shape(jax.jit(jax.jacfwd(p)), jnp.float32(0.03))


@pytest.mark.slow  # the warning itself: test_pathwise_derivatives_through_a_grazing_start_warn
def test_no_grazing_warning_without_derivatives_or_off_the_barrier(grazing):
    scene, points = grazing
    with warnings.catch_warnings():
        warnings.simplefilter("error", jdpim.SensitivityWarning)
        _p_of(scene, points)(0.03)
        off = scene.replace(x0=0.3)
        jax.jacfwd(_p_of(off, jdpim.dpim_points(off, 32)))(jnp.float32(0.03))
