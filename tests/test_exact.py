"""Reference solutions against independent computations (ODE for moments, quadrature)."""

import numpy as np
import pytest
from scipy import integrate

from jdpim import exact


@pytest.mark.parametrize("t", [0.7, 10.0, 55.0])
def test_linear_covariance_solves_lyapunov_ode(t):
    """dC/dt = A C + C A^T + diag(0, 2D) from C(0) = 0, integrated numerically."""
    alpha, D = 0.03, 0.05
    A = np.array([[0.0, 1.0], [-1.0, -alpha]])

    def rhs(_, c):
        C = c.reshape(2, 2)
        return (A @ C + C @ A.T + np.diag([0.0, 2 * D])).ravel()

    C = integrate.solve_ivp(rhs, (0, t), np.zeros(4), rtol=1e-10, atol=1e-12).y[:, -1].reshape(2, 2)
    np.testing.assert_allclose(exact.linear_covariance(alpha, D, t), [C[0, 0], C[1, 1], C[0, 1]], rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("t", [3.0, 40.0, np.inf])
def test_elastic_marginals_are_marginals_of_the_joint(t):
    x, v = np.linspace(0, 12, 1201), np.linspace(-12, 12, 2401)
    J = exact.elastic_linear_joint_pdf(x, v, 0.03, 0.03, t)
    np.testing.assert_allclose(
        integrate.simpson(J, x=v, axis=1), exact.elastic_linear_pdf_x(x, 0.03, 0.03, t), atol=1e-6
    )
    np.testing.assert_allclose(
        integrate.simpson(J, x=x, axis=0), exact.elastic_linear_pdf_v(v, 0.03, 0.03, t), atol=1e-6
    )
    assert integrate.simpson(integrate.simpson(J, x=v, axis=1), x=x) == pytest.approx(1.0, abs=1e-6)


def test_energy_damping_reduces_to_linear_case_and_normalises():
    x, v = np.linspace(0, 10, 801), np.linspace(-10, 10, 1601)
    p_lin = exact.energy_damping_pdf(lambda H: 0.03 + 0 * H, 0.03)(x[:, None], v[None, :])
    np.testing.assert_allclose(p_lin, exact.elastic_linear_joint_pdf(x, v, 0.03, 0.03), rtol=1e-6, atol=1e-12)
    p_nl = exact.energy_damping_pdf(lambda H: 0.02 + 0.05 * H, 0.05)(x[:, None], v[None, :])
    assert integrate.simpson(integrate.simpson(p_nl, x=v, axis=1), x=x) == pytest.approx(1.0, abs=1e-4)


@pytest.mark.parametrize(("D", "ex2"), [(0.01, 0.1755), (0.03, 0.4040), (0.08, 0.7841)])
def test_averaging_second_moments(D, ex2):
    """Stochastic averaging gives E[x^2] = 0.1755, 0.4040, 0.7841 for the paper's system."""
    assert exact.averaging_second_moment(0.03, 0.03, 0.98, D) == pytest.approx(ex2, abs=6e-5)


def test_averaging_marginals_normalise_and_match_energy_moment():
    x = np.linspace(0, 6, 1201)
    px = exact.averaging_pdf_x(x, 0.03, 0.03, 0.98, 0.03)
    assert integrate.simpson(px, x=x) == pytest.approx(1.0, abs=1e-5)
    assert integrate.simpson(x * x * px, x=x) == pytest.approx(
        exact.averaging_second_moment(0.03, 0.03, 0.98, 0.03), rel=1e-4
    )


def test_averaging_with_r1_and_no_cubic_is_the_exact_linear_solution():
    x, v = np.linspace(0, 5, 51), np.linspace(-5, 5, 101)
    np.testing.assert_allclose(
        exact.averaging_joint_pdf(x, v, 0.03, 0.0, 1.0, 0.03),
        exact.elastic_linear_joint_pdf(x, v, 0.03, 0.03),
        rtol=1e-10,
    )
