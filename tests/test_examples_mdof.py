"""Built-in systems with several degrees of freedom (jdpim.systems) and filtered excitation (jdpim.filters)."""

import jax
import numpy as np
import pytest
import scipy.linalg

import jdpim

D = 0.01


def admissible_and_finite(model, res):
    s = np.asarray(res.states)
    n = model.dimension
    assert np.all(np.isfinite(s)) and int(np.sum(res.n_nonfinite())) == 0
    for c in model.constraints:
        gap = s[..., :n] @ np.asarray(c.normal) - c.position
        assert gap.min() >= -1e-5, f"a saved state violates {c}"


# slow: the frame and the gear pair repeat on further linear systems what the impact damper checks (two constraints on
# a relative displacement, as the gear pair's backlash); a wall on one coordinate, as the frame's, is checked in
# test_mdof.py::test_stationary_marginals_match_the_gibbs_density[2], and frames that impact in
# test_pounding.py::test_first_impact_is_the_first_passage_without_contact
@pytest.mark.parametrize(
    "model",
    [
        jdpim.impact_damper(r=0.3),
        pytest.param(jdpim.pounding_frame(n_storeys=3, gap=0.05), marks=pytest.mark.slow),
        pytest.param(jdpim.gear_pair(backlash=0.02), marks=pytest.mark.slow),
    ],
    ids=["impact_damper", "pounding_frame", "gear_pair"],
)
def test_examples_run_finite_and_admissible(model):
    """Sizes as test_mdof.py runs the impact damper (its program is compiled once in a session)."""
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.05), t_end=5.0, dt=0.01, save_at=(2.5, 5.0))
    method = jdpim.MonteCarlo(n_samples=200, seed=3)
    res = jdpim.solve(scene, method)
    admissible_and_finite(model, res)
    # the constraints act: the same paths without them would violate them
    free = jdpim.solve(scene.replace(model=model.replace(constraints=())), method)
    q = np.asarray(free.states)[..., : model.dimension]
    beyond = [np.mean(q @ np.asarray(c.normal) < c.position) for c in model.constraints]
    assert max(beyond) > 0.05, beyond


def test_pounding_frame_has_the_first_mode_asked_for():
    frame = jdpim.pounding_frame(n_storeys=4, frequency=2.0, damping_ratio=0.05)
    w2, modes = scipy.linalg.eigh(np.asarray(frame.stiffness), np.asarray(frame.mass))
    assert np.sqrt(w2[0]) == pytest.approx(2.0, rel=1e-12)
    zeta = np.diag(modes.T @ np.asarray(frame.damping) @ modes)[0] / (2 * np.sqrt(w2[0]))
    assert zeta == pytest.approx(0.05, rel=1e-12)


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: jdpim.impact_damper(clearance=0.0), r"clearance must lie in \(0, inf\)"),
        (lambda: jdpim.impact_damper(r=1.5), r"r must lie in \[0, 1\]"),
        (lambda: jdpim.impact_damper(mass_ratio="0.1"), "mass_ratio must be a number"),
        (lambda: jdpim.pounding_frame(n_storeys=0), "n_storeys"),
        (lambda: jdpim.pounding_frame(n_storeys=2, storey=3), r"storey must lie in \[1, 2\]"),
        (lambda: jdpim.gear_pair(drag=0.0), r"drag must lie in \(0, inf\)"),
        (lambda: jdpim.kanai_tajimi(jdpim.impact_damper(), zeta_g=-1.0), "zeta_g"),
        (lambda: jdpim.kanai_tajimi(jdpim.impact_damper(), influence=[1.0]), "influence must have 2 entries"),
        (lambda: jdpim.harmonic(jdpim.impact_damper(), 1.0, 0.0), "frequency"),
        (lambda: jdpim.first_order_filter(jdpim.WhiteNoise()), "must be a jdpim.MDOFOscillator or a one-degree"),
        (lambda: jdpim.kanai_tajimi(jdpim.kanai_tajimi(jdpim.impact_damper())), "already has coordinates"),
    ],
)
def test_bad_inputs_fail_in_one_line(build, message):
    with pytest.raises((ValueError, TypeError), match=message) as info:
        build()
    assert "\n" not in str(info.value)


def stationary_covariance(model, D, drop=()):
    """Exact stationary covariance of ``(q, v)`` of a linear model without constraints (Lyapunov equation),
    without the states ``drop`` (a filter coordinate that only its velocity leaves: it has no stationary law)."""
    n = model.dimension
    Minv = np.linalg.inv(np.asarray(model.mass))
    K, C = np.asarray(model.stiffness), np.asarray(model.damping)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]])
    G = np.vstack([np.zeros((n, model.n_sources)), Minv @ np.asarray(model.gains)])
    keep = [i for i in range(2 * n) if i not in drop]
    A, G = A[np.ix_(keep, keep)], G[keep]
    P = scipy.linalg.solve_continuous_lyapunov(A, -2.0 * D * G @ G.T)
    return {i: P[a, a] for a, i in enumerate(keep)}


def pooled_variance(res, i):
    """Mean of coordinate ``i`` squared over paths and saved times, with a standard error from the per-path means."""
    per_path = np.mean(np.asarray(res.states)[..., i] ** 2, axis=1)
    return per_path.mean(), per_path.std(ddof=1) / np.sqrt(per_path.size)


LINEAR = jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], damping=[[0.4]], stiffness=[[1.0]])
TIMES = tuple(np.linspace(20.0, 40.0, 11))


@pytest.mark.parametrize(
    "model",
    [jdpim.kanai_tajimi(LINEAR, omega_g=3.0, zeta_g=0.6), jdpim.first_order_filter(LINEAR, a=0.5)],
    ids=["kanai_tajimi", "first_order"],
)
def test_filtered_linear_response_has_the_exact_stationary_variance(model, request):
    """Monte Carlo variance of the structure (and of the Kanai-Tajimi filter) against the Lyapunov solution."""
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=D), t_end=40.0, dt=0.01, save_at=TIMES)
    res = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=3000, seed=2))
    kt = "kanai" in request.node.name
    # the first-order filter's own coordinate (index 1) diffuses: only its velocity (index 3) is stationary
    var = stationary_covariance(model, D, drop=() if kt else (1,))
    for i in (0, 1, 2) if kt else (0, 2, 3):
        m, se = pooled_variance(res, i)
        assert abs(m - var[i]) < 4 * se, (model.coordinates[i], m, var[i], se)
    if not kt:
        assert var[3] == pytest.approx(D / 0.5, rel=1e-9)  # y' = -a y + w: var y = D / a
    # the filter shapes the response: white noise into the same structure gives the variance D / (c k)
    assert abs(var[0] - D / 0.4) > 8 * pooled_variance(res, 0)[1]


def test_harmonic_filter_is_the_cosine_and_drives_the_structure():
    """Without noise the filter coordinate is cos(Omega t) (RK4 accuracy) and a linear structure's response is
    the exact forced response from rest."""
    omega, A = 0.7, 0.3
    model = jdpim.harmonic(LINEAR, amplitude=A, frequency=omega)
    times = (5.0, 10.0, 20.0)
    with jax.enable_x64(True):
        scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.0), t_end=20.0, dt=0.01, save_at=times, dtype="float64")
        res = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=2, seed=0))
        s = np.asarray(res.states)[0]
    np.testing.assert_allclose(s[:, 1], np.cos(omega * np.asarray(times)), atol=1e-9)
    # x'' + 0.4 x' + x = A cos(omega t) from rest: exact solution by the matrix exponential of the 4-state system
    F = np.array([[0, 1, 0, 0], [-1, -0.4, A, 0], [0, 0, 0, 1], [0, 0, -(omega**2), 0]])
    for k, t in enumerate(times):
        x, v, z, _ = scipy.linalg.expm(F * t) @ np.array([0.0, 0.0, 1.0, 0.0])
        np.testing.assert_allclose([s[k, 0], s[k, 2]], [x, v], atol=1e-8)
