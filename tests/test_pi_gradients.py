"""Derivatives of path-integration densities: reverse mode, forward mode and central differences agree.

The functional is ``f = p_x(0.3) + p_x(0.8)`` of the stationary density (alpha = 0.05, D = 0.05), in float64,
differentiated with respect to alpha, gamma, r and D. The grid is smaller than the default (61 x 121
nodes), so that the matrix stays cheap; ``docs/path_integration.md`` gives the full matrix on the default
grid. Two properties of the solver make the three agree: linear solves that converge (BiCGStab on the
operator of 16 steps, checked; restarted GMRES stagnates on the adjoint, and BiCGStab on the one-step adjoint
of a pointwise density can stall) and deposition weights that are continuously differentiable
in the images (Catmull-Rom; Lagrange weights have kinks where an image crosses a node, where a
central difference and a one-sided derivative differ).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim

GRID = jnp.array([0.3, 0.8])
NAMES = ("alpha", "gamma", "r", "D")


def _scene(alpha, gamma, r, D, dtype="float64"):
    model = jdpim.VibroImpactOscillator(alpha=alpha, gamma=gamma, r=r)
    return jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=1.0, dt=0.01, dtype=dtype)


def _functional(settings, stationary=True):
    def f(p):
        scene = _scene(*p)
        if stationary:
            return jnp.sum(jdpim.path_integration(scene, settings, stationary=True).pdf("x", GRID))
        return jnp.sum(jdpim.path_integration(scene, settings).pdf("x", GRID, t=1.0))

    return f


def _central(f, p0, h=1e-4):
    out = []
    for i in range(p0.size):
        e = np.zeros(p0.size)
        e[i] = h
        if p0[i] == 0.0:  # gamma >= 0: a one-sided difference of second order
            out.append((-3 * f(p0) + 4 * f(p0 + e) - f(p0 + 2 * e)) / (2 * h))
        else:
            out.append((f(p0 + e) - f(p0 - e)) / (2 * h))
    return np.array([float(v) for v in out])


def _three_ways(f, p0):
    """``jax.grad``, ``jax.jacfwd`` (both in one compiled program) and central differences of ``f`` at ``p0``."""
    rev, fwd = jax.jit(lambda p: (jax.grad(f)(p), jax.jacfwd(f)(p)))(jnp.asarray(p0))
    return np.asarray(rev), np.asarray(fwd), _central(jax.jit(f), p0)


# On the default grid the same comparison is within 4e-4 in every cell of gamma x r x extents but one
# (docs/path_integration.md, "Derivatives"); GMRES(60) with Lagrange weights leaves reverse mode 9-12 % off.
@pytest.mark.parametrize(
    ("gamma", "r", "extent"),
    [
        (0.03, 0.1, 5.0),
        pytest.param(0.03, 0.9, 5.0, marks=pytest.mark.slow),  # stationary, cubic weights: the adjoint test below
        pytest.param(0.0, 0.3, None, marks=pytest.mark.slow),
        pytest.param(0.03, 0.5, 5.0, marks=pytest.mark.slow),
        pytest.param(0.0, 0.98, 5.0, marks=pytest.mark.slow),
    ],
)
def test_grad_jacfwd_and_central_differences_agree(gamma, r, extent):
    with jax.enable_x64(True):
        nominal = _scene(0.05, gamma, r, 0.05)
        if extent is None:  # the default extents of the nominal scene, fixed (they may not follow traced values)
            from jdpim.methods._path_integration import default_extents

            x_max, v_max = default_extents(nominal, jdpim.PathIntegration())
        else:
            x_max = v_max = extent
        settings = jdpim.PathIntegration(n_x=61, n_v=121, x_max=x_max, v_max=v_max, order=2 if r < 0.25 else 4)
        rev, fwd, fd = _three_ways(_functional(settings), np.array([0.05, gamma, r, 0.05]))
    np.testing.assert_allclose(rev, fwd, rtol=1e-6)
    np.testing.assert_allclose(fwd, fd, rtol=1e-3)


# slow: two reported cells of the 16-step adjoint with cubic weights; the default tier runs that adjoint with linear
# weights (test_grad_jacfwd_and_central_differences_agree[0.03-0.1-5.0]) and cubic weights in the transient derivatives
# (test_transient_derivatives_agree_with_central_differences), each against forward mode and differences
@pytest.mark.slow
def test_adjoint_of_a_pointwise_density_converges_where_plain_bicgstab_stalled():
    """Cells where BiCGStab on the one-step adjoint stopped at relative residual 3.6e-4 and 9.8e-2 (NaN gradients);
    the derivative solves run on the 16-step operator (docs/path_integration.md, "Derivatives"). Reverse and
    forward mode agree, and forward mode agrees with central differences (cubic weights; measured: within 2e-4)."""
    with jax.enable_x64(True):
        f = _functional(jdpim.PathIntegration(n_x=41, n_v=81, x_max=4.5, v_max=4.5, order=4))

        @jax.jit
        def both(theta):  # jax.grad's linearise-and-transpose, and jax.jacfwd, in one program (one compilation)
            _, tangent = jax.linearize(f, theta)
            return jax.linear_transpose(tangent, theta)(jnp.ones(()))[0], jax.vmap(tangent)(jnp.eye(4))

        value = jax.jit(f)  # the differences run the value alone: a solve without its derivatives
        for theta in ([0.03, 0.04, 0.95, 0.04], [0.06, 0.04, 0.95, 0.03]):
            rev, fwd = both(jnp.asarray(theta))
            np.testing.assert_allclose(np.asarray(rev), np.asarray(fwd), rtol=1e-6)
            np.testing.assert_allclose(np.asarray(fwd), _central(value, np.array(theta)), rtol=1e-3)


@pytest.mark.slow
def test_reported_cell_reverse_mode_agrees_with_forward_mode():
    """alpha = 0.06, gamma = 0.04, r = 0.95, D = 0.04, extents 4.5, order 4 (81 x 161 nodes: NaN before)."""
    with jax.enable_x64(True):
        settings = jdpim.PathIntegration(n_x=81, n_v=161, x_max=4.5, v_max=4.5, order=4)
        f, theta = jax.jit(_functional(settings)), jnp.asarray([0.06, 0.04, 0.95, 0.04])
        np.testing.assert_allclose(np.asarray(jax.grad(f)(theta)), np.asarray(jax.jacfwd(f)(theta)), rtol=1e-6)


def test_transient_derivatives_agree_with_central_differences():
    with jax.enable_x64(True):
        settings = jdpim.PathIntegration(n_x=41, n_v=81, x_max=3.0, v_max=3.0, t0=0.5, tau=0.05, order=4)
        rev, fwd, fd = _three_ways(_functional(settings, stationary=False), np.array([0.05, 0.03, 0.9, 0.05]))
    np.testing.assert_allclose(rev, fwd, rtol=1e-8)
    np.testing.assert_allclose(fwd, fd, rtol=1e-3)


def test_traced_parameters_that_choose_the_grid_fail_in_one_line():
    scene = _scene(0.05, 0.03, 0.9, 0.05, dtype=None)

    def with_alpha(a):
        return jdpim.path_integration(scene.replace(model=scene.model.replace(alpha=a)), stationary=True).mass()

    with pytest.raises(ValueError, match=r"alpha is traced .* give x_max and v_max"):
        jax.grad(with_alpha)(0.05)

    fixed = jdpim.PathIntegration(n_x=41, n_v=81, x_max=3.0, v_max=3.0)

    def with_r(r):
        return jdpim.path_integration(scene.replace(model=scene.model.replace(r=r)), fixed, stationary=True).mass()

    with pytest.raises(ValueError, match=r"r is traced .* give order=2 \(r < 0.25\) or order=4"):
        jax.grad(with_r)(0.9)


def test_a_linear_solve_that_does_not_converge_gives_nan_and_warns():
    scene = _scene(0.05, 0.03, 0.9, 0.05, dtype=None)
    starved = jdpim.PathIntegration(
        n_x=41, n_v=81, x_max=3.0, v_max=3.0, warmup=0, max_iter=1, max_restarts=1, restart=2
    )
    with pytest.warns(jdpim.PathIntegrationWarning) as record:
        res = jdpim.path_integration(scene, starved, stationary=True)
    messages = [str(w.message) for w in record]
    assert any("linear solve stopped" in m for m in messages), messages
    assert any("non-finite nodal densities" in m for m in messages), messages
    assert int(res.n_nonfinite()[0]) > 0


def test_gradient_matrix_runs_every_cell_once_covering_every_value_and_pair_early():
    """``python -m jdpim.bench pi-gradients`` runs its 72 cells so that a run cut short covers the matrix."""
    import itertools

    from jdpim.bench.pi_gradients import AXES, EXTRA, FULL

    cells = FULL.cells[: -len(EXTRA)]
    assert sorted(cells, key=str) == sorted(itertools.product(*AXES), key=str)
    assert FULL.cells[-len(EXTRA) :] == EXTRA
    for i, values in enumerate(AXES):
        assert {c[i] for c in cells[:4]} == set(values)
    pairs = [set(itertools.combinations(enumerate(c), 2)) for c in cells]
    assert set().union(*pairs[:9]) == set().union(*pairs)
