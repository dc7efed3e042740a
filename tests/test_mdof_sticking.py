"""Sticking per constraint with several degrees of freedom: held paths, departures, the default per constraint."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate

import jdpim
from jdpim._integrate import ImpactRule, integrate


@functools.partial(jax.jit, static_argnames=("n_steps", "rule"))
def deterministic(model, q0, v0, h, n_steps, rule):
    """Paths without noise, saved after every step: ``(n, n_steps, 2 d)``."""
    n, _ = q0.shape
    slots = jnp.arange(n_steps, dtype=jnp.int32)
    e = jnp.zeros((2 * n_steps + 1, n, 1), q0.dtype)
    return integrate(lambda _: model, rule, h, q0, v0, e, jnp.zeros((n, 0), q0.dtype), slots, n_steps, n_steps)


def _constant(*forces):
    def force(q, v, params):
        return jnp.stack([f * jnp.ones_like(q[0]) for f in forces])

    return force


# A model's force is static structure: one function per case, so that the restitutions (traced) share a program.
FALLING, PUSHED_TOGETHER = _constant(0.0, -1.0), _constant(1.0, -2.0)


@pytest.mark.parametrize("r", [0.0, 0.3, 0.5])
def test_a_ball_against_a_wall_rests_from_the_zeno_time_on(r):
    """A ball ``y'' = -1`` from rest at ``y = 0.5`` with a spring ``x'' = -x`` beside it (float64, h = 0.01): its
    bounces end at ``t = 1 + 2 r / (1 - r)`` (first impact at t = 1, flight times falling by r), and from one step
    after that on it rests exactly on the wall (``y = 0``, ``y' = 0``) while ``x`` follows ``cos t`` to 1e-8."""
    with jax.enable_x64(True):
        model = jdpim.MDOFOscillator(
            mass=np.eye(2),
            gains=np.zeros((2, 1)),
            stiffness=[[1.0, 0.0], [0.0, 0.0]],
            constraints=(jdpim.Barrier((0.0, 1.0), 0.0, r),),
            force=FALLING,
        )
        h, n = 0.01, 800
        out = np.asarray(deterministic(model, jnp.array([[1.0, 0.5]]), jnp.zeros((1, 2)), h, n, ImpactRule(hold=True)))
    t = h * np.arange(1, n + 1)
    rest = t > 1 + 2 * r / (1 - r) + h
    assert np.all(out[0, rest, 1] == 0) and np.all(out[0, rest, 3] == 0)
    assert np.all(out[0, :, 1] >= 0)
    np.testing.assert_allclose(out[0, :, 0], np.cos(t), atol=1e-8)


@pytest.mark.parametrize("r", [0.0, 0.5])
def test_two_masses_pushed_together_come_to_rest_on_each_other(r):
    """Masses 1 and 2 pushed together by forces +1 and -2 from a gap of 1 (``q2 - q1 >= 0``, float64): the gap closes
    at t = 1 and its bounces end at ``1 + 2 r / (1 - r)``; from then on the pair moves as one body (gap 0 and
    relative speed 0 to rounding) and the momentum is ``-t`` throughout (to 1e-12: the contact is internal)."""
    with jax.enable_x64(True):
        model = jdpim.MDOFOscillator(
            mass=np.diag([1.0, 2.0]),
            gains=np.zeros((2, 1)),
            constraints=(jdpim.Barrier((-1.0, 1.0), 0.0, r),),
            force=PUSHED_TOGETHER,
        )
        h, n = 0.01, 800
        out = np.asarray(deterministic(model, jnp.array([[0.0, 1.0]]), jnp.zeros((1, 2)), h, n, ImpactRule(hold=True)))
    t = h * np.arange(1, n + 1)
    gap, speed = out[0, :, 1] - out[0, :, 0], out[0, :, 3] - out[0, :, 2]
    rest = t > 1 + 2 * r / (1 - r) + h
    assert np.all(np.abs(gap[rest]) <= 1e-12) and np.all(np.abs(speed[rest]) <= 1e-12)
    assert np.all(gap >= -1e-12)
    np.testing.assert_allclose(out[0, :, 2] + 2.0 * out[0, :, 3], -t, atol=1e-12)


def test_departure_from_a_held_contact_converges_at_fourth_order():
    """A mass pressed against a wall (force -1) and pulled off by a spring (k = 4) to a second mass (0.5) that
    starts at 0 with speed 1.5: held until ``k q2 = 1`` (closed form), then free. The state 0.6 s after the
    departure against a tight-tolerance solution (float64): the error falls 16-fold per halving of the step
    (measured: 2.5e-7, 1.5e-8, 9.4e-10, 5.9e-11 at T/40 .. T/320), so the departure is located, not rounded
    to a step."""
    force, k, m2, speed = 1.0, 4.0, 0.5, 1.5
    w = np.sqrt(k / m2)
    t_off = np.arcsin(force / k * w / speed) / w
    t_end = t_off + 0.6

    def rhs(t, y):
        q1, q2, v1, v2 = y
        return [v1, v2, -force + k * (q2 - q1), -k * (q2 - q1) / m2]

    y_off = [0.0, speed / w * np.sin(w * t_off), 0.0, speed * np.cos(w * t_off)]
    exact = scipy.integrate.solve_ivp(rhs, (t_off, t_end), y_off, rtol=1e-13, atol=1e-14).y[:, -1]
    errors = []
    with jax.enable_x64(True):
        model = jdpim.MDOFOscillator(
            mass=np.diag([1.0, m2]),
            gains=np.zeros((2, 1)),
            stiffness=[[k, -k], [-k, k]],
            constraints=(jdpim.Barrier((1.0, 0.0), 0.0, 0.5),),
            force=_constant(-force, 0.0),
        )
        q0, v0 = jnp.zeros((1, 2)), jnp.array([[0.0, speed]])
        for steps in (40, 80, 160):  # one program of 160 steps (the step is traced), read at step `steps`
            out = np.asarray(deterministic(model, q0, v0, t_end / steps, 160, ImpactRule(hold=True)))[:, :steps]
            assert np.all(out[0, :, 0] >= 0)
            errors.append(np.abs(out[0, -1] - exact).max())
    assert errors[0] < 1e-6
    assert all(a / b > 12 for a, b in zip(errors, errors[1:], strict=False)), errors


def test_hold_is_decided_per_constraint_by_the_reach_of_the_noise():
    """``hold=None`` is decided by the scene: the damper driven by white noise holds on neither end of its
    clearance (the noise reaches the relative acceleration), the damper behind a Kanai-Tajimi filter holds on
    both; a one-degree-of-freedom scene holds on none (it sticks by ``stick_velocity``); given values are kept,
    and a new model is decided anew."""
    white = jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.01), t_end=1.0, dt=0.01)
    assert white.held_constraints == (False, False) and white.impacts.hold is None
    filtered = jdpim.Scene(
        jdpim.kanai_tajimi(jdpim.impact_damper(), omega_g=3.0, zeta_g=0.6),
        noise=jdpim.WhiteNoise(D=0.01),
        t_end=1.0,
        dt=0.01,
    )
    assert filtered.held_constraints == (True, True)
    assert jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.01).held_constraints == (False,)
    assert white.replace(impacts=ImpactRule(hold=(True, False))).held_constraints == (True, False)
    assert filtered.replace(model=filtered.model.replace(constraints=())).held_constraints == ()


@pytest.mark.parametrize(
    ("hold", "message"),
    [("yes", r"hold must be None, a bool or a tuple of bools"), ((), r"hold must be None, a bool or a tuple")],
)
def test_bad_hold_fails_in_one_line(hold, message):
    with pytest.raises(TypeError, match=message):
        ImpactRule(hold=hold)


def test_a_hold_of_the_wrong_length_fails_naming_the_constraints():
    with pytest.raises(ValueError, match="hold has 1 entries; the model has 2 constraints"):
        jdpim.Scene(jdpim.impact_damper(), noise=jdpim.WhiteNoise(D=0.01), impacts=ImpactRule(hold=(True,)))


def test_held_paths_under_filtered_noise_stay_finite_admissible_and_held():
    """The impact damper behind a Kanai-Tajimi filter (float32, 400 paths, t = 20 s): no non-finite path, no saved
    state beyond a wall by more than rounding, and some paths held against a wall (gap at +-c with the two
    masses at one speed) at the end."""
    model = jdpim.kanai_tajimi(jdpim.impact_damper(), omega_g=3.0, zeta_g=0.6)
    scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.01), t_end=20.0, dt=0.01, save_at=(10.0, 20.0))
    res = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=400, seed=0))
    states = np.asarray(res.states, np.float64)
    assert int(np.sum(res.n_nonfinite())) == 0
    gap = states[..., 1] - states[..., 0]
    assert np.all(np.abs(gap) <= 0.1 + 1e-6)
    held = (np.abs(np.abs(gap[:, -1]) - 0.1) < 1e-6) & (np.abs(states[:, -1, 4] - states[:, -1, 3]) < 1e-5)
    assert held.mean() > 0.05


def test_reverse_mode_from_rest_on_a_wall_is_finite_and_equals_forward_mode():
    """Paths of the filtered damper held at rest against a wall from the start (float32, 7 paths, 2 steps; one of
    them ends its held step a rounding error beyond the wall): reverse mode (as ``jax.grad`` runs it) of E[x1^2]
    with respect to ``stiffness[0,0]`` is finite and equal to forward mode's (reverse mode gave nan: the crossing's
    starting guess carried a derivative that divides by an underflowing square)."""
    model = jdpim.kanai_tajimi(jdpim.impact_damper(), omega_g=3.0, zeta_g=0.6)
    x0 = np.zeros(model.dimension)
    x0[1] = 0.1  # x2 - x1 = c: on the wall
    scene = jdpim.Scene(
        model,
        noise=jdpim.WhiteNoise(D=0.05),
        t_end=0.02,
        dt=0.01,
        x0=x0,
        v0=np.zeros(3),
        excitation=jdpim.SpectralRepresentation(),  # the forcing under which seed 31 gives that path
    )
    k0 = float(np.asarray(model.stiffness)[0, 0])

    def second_moment(k):
        s = scene.replace(model=model.replace(stiffness=jnp.asarray(model.stiffness).at[0, 0].set(k)))
        return jdpim.solve(s, jdpim.MonteCarlo(n_samples=7, seed=31)).moment("x1", 2, 0.02)

    @jax.jit
    def both(k):
        """Reverse mode as ``jax.grad`` runs it (``jax.vjp``: the transpose of the linearisation) and forward mode, from
        one linearisation: one program with one forward pass through the paths."""
        _, forward = jax.linearize(second_moment, k)
        (reverse,) = jax.linear_transpose(forward, k)(jnp.ones((), k.dtype))
        return reverse, forward(jnp.ones_like(k))

    with pytest.warns(jdpim.SensitivityWarning):
        reverse, forward = (float(d) for d in both(k0))
    assert np.isfinite(reverse)
    np.testing.assert_allclose(reverse, forward, rtol=1e-4)
