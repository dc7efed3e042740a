"""Misuse that used to come back as a silently wrong answer: each now fails in one line, warns, or is counted.

Random parameters are checked against the same ranges as fixed values; ``dt`` against RK4's stability bound for
the fastest mode of the linearised model (filters included); clearances against what one step resolves; paths
that blow up are counted with the non-finite ones.
"""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim._distributions import elementary_ppf
from jdpim.methods._paths import _finish, divergence_scale

REFERENCE = jdpim.VibroImpactOscillator()
TWO_PI = jdpim.VibroImpactOscillator(omega=2.0 * math.pi, alpha=0.03, gamma=None, barrier=None)


def scene(model=REFERENCE, **kw):
    kw.setdefault("t_end", 2.0)
    return jdpim.Scene(model, **kw)


REFUSED = {
    # random laws whose support leaves the parameter's range (the range fixed values are checked against)
    "random-r-above-1": (
        lambda: scene(random={"r": jdpim.Uniform(1.1, 1.2)}),
        ValueError,
        r"random\['r'\] = Uniform.* r must lie in \[0, 1\]; use a truncated law, e.g. jdpim.TruncatedNormal",
    ),
    "random-negative-damping": (
        lambda: scene(random={"alpha": jdpim.Normal(0.03, 0.1)}),
        ValueError,
        r"random\['alpha'\] = Normal.* takes values in \(-inf, inf\) but alpha must lie in \[0, inf\); "
        r"use a truncated law, e.g. jdpim.TruncatedNormal\(0.03, 0.1, low=0\)",
    ),
    "random-start-below-barrier": (
        lambda: scene(random={"x0": jdpim.Normal(0.0, 1.0)}),
        ValueError,
        r"random\['x0'\] = Normal.* x0 must lie in \[0, inf\)",
    ),
    "random-barrier-above-start": (
        lambda: scene(x0=0.5, random={"barrier": jdpim.Uniform(0.0, 1.0)}),
        ValueError,
        r"barrier must lie in \(-inf, 0.5\]",
    ),
    "random-omega-at-zero": (
        lambda: scene(random={"omega": jdpim.Uniform(0.0, 2.0)}),
        ValueError,
        r"omega must lie in \(0, inf\)",
    ),
    "random-mdof-damping-diagonal": (
        lambda: scene(jdpim.impact_damper(), random={"damping[0,0]": jdpim.Normal(0.02, 0.05)}),
        ValueError,
        r"damping\[0,0\] must lie in \[0, inf\)",
    ),
    "random-mdof-restitution": (
        lambda: scene(jdpim.impact_damper(), random={"constraints[1].r": jdpim.Uniform(0.5, 1.5)}),
        ValueError,
        r"constraints\[1\].r must lie in \[0, 1\]; use jdpim.Uniform\(0.5, 1\)",
    ),
    # MDOF matrices: what alpha < 0 is for one degree of freedom
    "mdof-negative-damping": (
        lambda: jdpim.MDOFOscillator(mass=[[1.0]], gains=[[1.0]], damping=[[-0.5]], stiffness=[[1.0]]),
        ValueError,
        r"damping must be positive semi-definite \(it dissipates energy\); its smallest eigenvalue is -0.5",
    ),
    "mdof-indefinite-damping": (
        lambda: jdpim.MDOFOscillator(mass=np.eye(2), gains=[[1.0], [0.0]], damping=[[0.1, 0.5], [0.5, 0.1]]),
        ValueError,
        r"damping must be positive semi-definite \(it dissipates energy\); its smallest eigenvalue is -0.4",
    ),
    # dt beyond RK4's stability bound (|1 + z + z^2/2 + z^3/6 + z^4/24| <= 1, z = lambda dt)
    "dt-kanai-tajimi-filter": (
        lambda: scene(jdpim.kanai_tajimi(jdpim.impact_damper()), dt=0.2),
        ValueError,
        r"dt=0.2 is beyond RK4's stability bound for the mode with eigenvalue -9.36\+12.48j "
        r"\(\|lambda\| = 15.6 rad/s\): the largest stable dt is 0.1685",
    ),
    "dt-linear-two-pi": (
        lambda: scene(TWO_PI, t_end=5.0, dt=0.5),
        ValueError,
        r"dt=0.5 is beyond RK4's stability bound .*6.283 rad/s\): the largest stable dt is 0.451",
    ),
    # clearances the step cannot resolve
    "clearance-1e-5": (
        lambda: scene(jdpim.impact_damper(clearance=1e-5), dt=0.01),
        ValueError,
        r"the clearance between constraints\[0\] and \[1\] \(2e-05 wide\) is below what dt=0.01 resolves: .* "
        r"use dt <= 0.00108",
    ),
    "clearance-1e-6": (
        lambda: scene(jdpim.impact_damper(clearance=1e-6), dt=0.01),
        ValueError,
        r"\(2e-06 wide\) is below what dt=0.01 resolves",
    ),
    "backlash-1e-5": (
        lambda: scene(jdpim.gear_pair(backlash=1e-5), dt=0.01),
        ValueError,
        r"\(2e-05 wide\) is below what dt=0.01 resolves",
    ),
    # smaller ones
    "harmonic-switched-off-by-x0": (
        lambda: scene(jdpim.harmonic(jdpim.impact_damper(), 0.1, 0.9), x0=0.0),
        ValueError,
        r"x0 starts the harmonic filter coordinate xh at 0, which scales the harmonic force by 0: give x0\[2\] = 1.0",
    ),
    "filter-of-multiplicative-noise": (
        lambda: jdpim.kanai_tajimi(jdpim.Oscillator(h=lambda x, v, p: jnp.array([1.0 + x]))),
        ValueError,
        r"a filter needs additive noise, but Oscillator's gains depend on the state \(\[1\] at rest, \[1.7\] at "
        r"\(x, v\) = \(0.7, -1.3\)\)",
    ),
    "oscillator-g-wrong-shape": (
        lambda: jdpim.Oscillator(g=lambda x, p: jnp.stack([x, x])),
        ValueError,
        r"g must return one number for one path's scalars, got shape \[2\]",
    ),
    "oscillator-f-wrong-shape": (
        lambda: jdpim.Oscillator(f=lambda x, v, p: jnp.zeros(3)),
        ValueError,
        r"f must return one number for one path's scalars, got shape \[3\]",
    ),
}


@pytest.mark.parametrize("case", list(REFUSED), ids=list(REFUSED))
def test_misuse_is_refused_in_one_line(case):
    build, kind, message = REFUSED[case]
    with pytest.raises(kind, match=message) as info:
        build()
    assert "\n" not in str(info.value)


@pytest.mark.parametrize(
    "build",
    [
        lambda: scene(jdpim.kanai_tajimi(jdpim.impact_damper()), dt=0.1),  # 59 % of the bound 0.1685
        lambda: scene(TWO_PI, t_end=5.0, dt=0.25),  # 55 % of 0.451
    ],
    ids=["kanai-tajimi", "linear-two-pi"],
)
def test_a_step_near_the_stability_bound_warns(build):
    with pytest.warns(jdpim.StepSizeWarning, match=r"of RK4's stability bound"):
        build()


def test_steps_within_the_bound_and_admissible_laws_pass_silently():
    """The edges of what is accepted: half the bound and less, laws inside each range (truncated or log-normal),
    the clearance resolved at a smaller dt, the harmonic filter started at 1 by the scene's x0."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scene(TWO_PI, t_end=5.0, dt=0.2)
        scene(jdpim.kanai_tajimi(jdpim.impact_damper()), dt=0.05)
        scene(random={"r": jdpim.Uniform(0.5, 1.0), "x0": jdpim.TruncatedNormal(0.0, 1.0, low=0.0)})
        scene(random={"alpha": jdpim.TruncatedNormal(0.03, 0.1, low=0.0), "omega": jdpim.LogNormal(0.0, 0.2)})
        scene(x0=1.0, random={"barrier": jdpim.Uniform(-1.0, 1.0)})
        scene(jdpim.impact_damper(clearance=1e-5), dt=0.001)
        scene(jdpim.harmonic(jdpim.impact_damper(), 0.1, 0.9), x0=[0.1, 0.0, 1.0])


@pytest.mark.parametrize(
    "law",
    [
        jdpim.TruncatedNormal(0.03, 0.1, low=0.0),
        jdpim.TruncatedNormal(0.0, 1.0, low=2.0, high=3.0),  # in the upper tail: sampled mirrored
        jdpim.TruncatedNormal(0.5, 0.2, low=0.0, high=1.0),
        jdpim.LogNormal(-1.0, 0.5),
    ],
    ids=["half-line", "upper-tail", "interval", "log-normal"],
)
def test_truncated_and_log_normal_laws_sample_inside_their_support_with_their_moments(law):
    """NumPy and JAX inverse CDFs agree, stay inside the support, and 2^16 midpoint quantiles reproduce ``mean``
    and ``std`` (to 2e-3 of std: the midpoint rule's error; measured <= 2e-4 relative)."""
    u = (np.arange(2**16) + 0.5) / 2**16
    x = law.ppf(u)
    lo, hi = law.support
    assert np.all((x >= lo) & (x <= hi))
    np.testing.assert_allclose(np.asarray(elementary_ppf(law, jnp.asarray(u[::64]))), x[::64], rtol=2e-4, atol=1e-6)
    assert abs(x.mean() - law.mean) < 2e-3 * law.std
    assert abs(x.std() - law.std) < 2e-3 * law.std
    np.testing.assert_allclose(law.cdf(x[::512]), u[::512], rtol=1e-6, atol=1e-9)


def test_save_at_left_at_its_default_follows_t_end():
    base = scene(t_end=5.0)
    assert base.replace(t_end=2.0).save_at == (2.0,)
    assert base.replace(t_end=8.0).save_at == (8.0,)
    assert scene(t_end=5.0, save_at=(1.0, 5.0)).replace(t_end=6.0).save_at == (1.0, 5.0)


def test_a_constrained_scene_built_inside_jit_checks_its_start():
    def build(d, x0):
        return jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=d), x0=x0, t_end=1.0, dt=0.01).t_end

    assert jax.jit(build, static_argnums=1)(0.01, (0.0, 0.0)) == 1.0
    with pytest.raises(ValueError, match=r"violates constraints\[1\]"):
        jax.jit(build, static_argnums=1)(0.01, (0.0, 5.0))


def test_paths_that_blow_up_are_counted_with_the_non_finite_ones():
    """A path beyond 1e6 times the reach of its start and the noise (``divergence_scale``: 21.9 in x, 1.10 in v for
    the reference scene to t = 20) is stored as NaN from there on, counted by ``n_nonfinite``, left out of the mass
    and warned about, like a non-finite one; paths within it are kept bit for bit."""
    grows = scene(t_end=20.0, save_at=(10.0, 20.0))
    np.testing.assert_allclose(divergence_scale(grows), [21.9089, 1.09545], rtol=1e-5)
    states = np.zeros((4, 2, 2), np.float32)
    states[:, :, 0] = [[0.5, 0.7], [3e7, 2e20], [0.1, 3e7], [0.2, np.inf]]
    with pytest.warns(jdpim.NonFiniteWarning, match=r"3 of 4 paths have non-finite or diverged states"):
        res = _finish(grows, jnp.asarray(states), jnp.full(4, 0.25), "monte_carlo")
    assert res.n_nonfinite().tolist() == [1, 3]
    np.testing.assert_allclose(np.asarray(res.lost_mass()), [0.25, 0.75])
    np.testing.assert_array_equal(np.asarray(res.states)[0], states[0])
    np.testing.assert_array_equal(np.asarray(res.states)[2, 0], states[2, 0])
