"""Impact resolution: convergence order in dt, the impact map, sticking, chattering down to r = 0.

Deterministic problems call the integrator directly (``jdpim._integrate.integrate``) with an excitation
array we write ourselves, in float64 (``jax.enable_x64`` context, so nothing leaks into other tests).
Measured numbers quoted in the tolerances are in ``docs/hard_cases.md``.
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim._engine.batches import (
    PREFIX_MAX,
    compact_depth,
    compact_rows,
    first_in_lanes,
    first_true,
    pending_in_runs,
    tree,
    until_done,
)
from jdpim._engine.locate import locate_crossing
from jdpim._engine.resolve import resolve_one
from jdpim._engine.sticking import departure
from jdpim._integrate import ImpactRule, integrate


@functools.partial(jax.jit, static_argnames=("rule", "n_save"))
def _integrate_paths(model, rule, h, x0, v0, e, slots, n_save):
    n = x0.shape[0]
    return integrate(lambda r: model, rule, h, x0, v0, e, jnp.zeros((n, 0), x0.dtype), slots, n_save, n_save)


def run_paths(model, rule, dt, t_end, x0, v0, xi=None, save_every=None, n_steps=None):
    """Integrate ``len(x0)`` paths of ``model`` with excitation ``xi(t)`` (vectorised, or zero); float64.

    ``dt`` and the model's parameters are traced: calls that share the shapes (``n_steps`` scan steps,
    default ``t_end / dt``; extra steps after ``t_end`` are not saved) share one compilation.
    Returns the states ``(n, S, 2)`` at ``t_end`` (or every ``save_every`` steps) and the saved times.
    """
    steps = int(round(t_end / dt))
    total = steps if n_steps is None else n_steps
    n = len(x0)
    t_half = np.arange(2 * total + 1) * dt / 2
    e = np.zeros((2 * total + 1, n, 1)) if xi is None else np.repeat(xi(t_half)[:, None, None], n, axis=1)
    every = steps if save_every is None else save_every
    n_save = steps // every
    slots = np.full(total, n_save, dtype=np.int32)
    slots[every - 1 : steps : every] = np.arange(n_save)
    f64 = functools.partial(jnp.asarray, dtype=jnp.float64)
    q0, v0 = f64(x0)[:, None], f64(v0)[:, None]  # one coordinate per path
    out = _integrate_paths(model, rule, f64(dt), q0, v0, f64(e), jnp.asarray(slots), n_save)
    return np.asarray(out), dt * every * np.arange(1, n_save + 1)


def damped_exact(x, v, t, alpha, r):
    """State at ``t`` of ``x'' + alpha x' + x = 0`` on ``x >= 0`` with impacts ``v+ = -r v-`` (analytic events)."""
    a = alpha / 2
    wd = math.sqrt(1 - a * a)
    while True:
        A, B = x, (v + a * x) / wd
        theta = (math.atan2(B, A) + math.pi / 2) % math.pi  # first zero of A cos + B sin after 0
        s = (theta if theta > 1e-14 else math.pi) / wd
        tt = min(s, t)
        e, c, sn = math.exp(-a * tt), math.cos(wd * tt), math.sin(wd * tt)
        xx, vv = e * (A * c + B * sn), e * (-a * (A * c + B * sn) + wd * (-A * sn + B * c))
        if s >= t:
            return xx, vv
        x, v, t = 0.0, -r * vv, t - s


ALPHA, R, T_DET = 0.1, 0.8, 10.0
PHASES = np.linspace(0.0, np.pi / 2, 8, endpoint=False) + 0.01  # x0 = cos(phase): impacts at varied step fractions


@pytest.fixture(scope="module")
def deterministic_errors():
    """RMS state error at t = 10 over 8 initial phases, per method and dt = 2^-k (damped free vibration, r = 0.8)."""
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, r=R)
    x0, v0 = np.cos(PHASES), -np.sin(PHASES)
    exact = np.array([damped_exact(a, b, T_DET, ALPHA, R) for a, b in zip(x0, v0, strict=True)])
    ladders = {"locate": (3, 4, 5, 6), "mirror": (4, 5, 6, 7, 8)}
    errors = {}
    with jax.enable_x64(True):
        for method, ks in ladders.items():
            rule = ImpactRule(method=method)
            errs = []
            for k in ks:
                out, _ = run_paths(model, rule, 2.0**-k, T_DET, x0, v0, n_steps=int(T_DET * 2 ** max(ks)))
                errs.append(np.sqrt(np.mean(np.sum((out[:, -1] - exact) ** 2, axis=1))))
            errors[method] = (2.0 ** -np.array(ks), np.array(errs))
    return errors


def fitted_order(dts, errs):
    return float(np.polyfit(np.log(dts), np.log(errs), 1)[0])


def test_located_impacts_are_fourth_order(deterministic_errors):
    dts, errs = deterministic_errors["locate"]
    # measured: 5.9e-6, 3.7e-7, 2.3e-8, 1.44e-9 for dt = 2^-3..2^-6; fitted order 3.997
    assert 3.8 < fitted_order(dts, errs) < 4.2
    assert errs[-1] < 3e-9  # dt = 2^-6: measured 1.44e-9


def test_mirror_is_first_order(deterministic_errors):
    dts, errs = deterministic_errors["mirror"]
    # measured: 8.7e-3, 3.7e-3, 2.2e-3, 1.1e-3, 6.8e-4 for dt = 2^-4..2^-8 (single ratios 0.7-1.3: the error
    # depends on where the impact falls inside the step); fitted order 0.98 over 2^-3..2^-9
    assert 0.75 < fitted_order(dts, errs) < 1.25
    assert errs[0] > 1e4 * deterministic_errors["locate"][1][1]  # both at dt = 2^-4: 8.7e-3 vs 3.7e-7


@jax.jit
def _resolve_each(model, h, y0, tau0, y1, last, e):
    """``resolve_one`` per path (leading axis), compiled once for every restitution (a traced leaf of ``model``)."""
    return jax.vmap(lambda *a: resolve_one(model, ImpactRule(), h, *a))(y0, tau0, y1, last, e)


@pytest.mark.parametrize("r", [0.0, 0.3, 0.8, 0.98, 1.0])
def test_impact_map_energy_loss(r):
    """One step across the barrier of ``x'' + x = 0``: the energy after is ``r^2`` times the energy before."""
    with jax.enable_x64(True):
        model = jdpim.VibroImpactOscillator(alpha=None, gamma=None, r=r)
        h = 0.05
        s = jnp.linspace(0.05, 0.95, 19)  # impact at fraction s of the step, speed 1..3
        speed = jnp.linspace(1.0, 3.0, 19)
        x0, v0 = speed * jnp.sin(s * h), -speed * jnp.cos(s * h)  # the free path hits x = 0 at s h
        x1, v1 = x0 * jnp.cos(h) + v0 * jnp.sin(h), -x0 * jnp.sin(h) + v0 * jnp.cos(h)
        e = jnp.zeros((19, 3, 1))
        (_, v_plus), theta, (x2, v2), _ = _resolve_each(
            model, h, (x0[:, None], v0[:, None]), jnp.zeros(19), (x1[:, None], v1[:, None]), jnp.full(19, -1), e
        )
        v_plus, x2, v2 = v_plus[:, 0], x2[:, 0], v2[:, 0]
        energy_before = 0.5 * (x0**2 + v0**2)
        lost = energy_before - 0.5 * (x2**2 + v2**2)
        v_minus = -speed  # analytic impact velocity
        # theta is the root of the cubic Hermite interpolant: |x - p| <= h^4 max|x^(4)| / 384 = 5e-8 here, i.e.
        # <= 1e-6 in step fraction (measured max 3.5e-7)
        if r > 0:  # with r = 0 the path sticks (zero force at rest) and theta is its departure: never (1)
            np.testing.assert_allclose(theta, s, atol=2e-6)
        np.testing.assert_allclose(v_plus, r * speed, rtol=1e-9)
        assert np.all(np.abs(v_plus) <= np.abs(v_minus))
        # RK4 over the two sub-steps keeps energy to O(h^5): measured |error| < 2e-9
        np.testing.assert_allclose(lost, (1 - r * r) * v_minus**2 / 2, atol=1e-8)
        assert np.all(x2 >= 0)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_located_crossing_is_the_exact_root(dtype):
    """Under a constant acceleration the cubic Hermite interpolant is the trajectory itself, so the located
    fraction must be its exact root: for ordinary crossings, and for steps that leave the barrier and come
    back (second impacts, departures), where the root at s = 0 has to be stepped past. Measured: largest
    error 2.5e-7 / 1.2e-7 (float32); before, steps from the barrier were off by up to 3.1e-2.
    """
    rng = np.random.default_rng(0)
    h, n = 0.01, 20000
    v_in, a_in = -rng.uniform(0.01, 2.0, n), rng.normal(0.0, 1.0, n)
    x_in = rng.uniform(0.0, 1.0, n) * (-v_in * h) * 0.99
    v_out, a_out = rng.uniform(1e-6, 0.02, n), -rng.uniform(5.0, 400.0, n)
    for x0, v0, a in ((x_in, v_in, a_in), (np.zeros(n), v_out, a_out)):
        keep = x0 + v0 * h + 0.5 * a * h * h < 0
        x0, v0, a = x0[keep], v0[keep], a[keep]
        x1, v1 = x0 + v0 * h + 0.5 * a * h * h, v0 + a * h
        # the first root after s = 0 of x0 + v0 h s + a h^2 s^2 / 2 (stable form; from the barrier: -2 v0 / (a h))
        if np.all(x0 == 0):
            exact = -2 * v0 / (a * h)
        else:
            exact = 2 * x0 / (h * (np.sqrt(v0**2 - 2 * a * x0) - v0))
        with jax.enable_x64(dtype == jnp.float64):
            args = [jnp.asarray(q, dtype) for q in (x0, v0, x1, v1)]
            s = np.asarray(jax.jit(jax.vmap(lambda *q: locate_crossing(*q, h, 4)))(*args))
        assert np.max(np.abs(s - exact)) < (1e-6 if dtype == jnp.float32 else 1e-12)


def test_departure_root_of_force_quadratic():
    """The force at rest is a quadratic in the step fraction; departure is its first upward zero crossing."""
    model = jdpim.Oscillator(r=0.5)  # a = xi: the force at rest is the excitation itself
    forces = ([-1.0, 0.5, 1.0], [-1.0, -0.5, -0.1], [0.3, -1.0, 1.0], [-1.0, 1.0, -1.0], [0.2, 0.1, 0.2])
    with jax.enable_x64(True):
        rest, normal = jnp.zeros(1), jnp.ones(1)  # at rest on the barrier x >= 0
        roots = [float(departure(model, jnp.asarray(f)[:, None], 0.0, normal, rest)) for f in forces]
    # f = -1 + 3 tau - ... : quadratic through (0,-1), (1/2, 1/2), (1, 1) -> q = -1 + 4 tau - 2 tau^2, root 1 - 1/sqrt2
    assert roots[0] == pytest.approx(1 - 1 / math.sqrt(2), abs=1e-12)
    assert roots[1] == 1.0  # never pulls away within the step
    assert roots[2] == 0.0  # already pulling away
    assert roots[3] == pytest.approx(0.5 - math.sqrt(2) / 4, abs=1e-12)  # first of two roots of -1 + 8 tau - 8 tau^2
    assert roots[4] == 0.0


@pytest.mark.parametrize("r", [0.0, 0.5, 1.0])
def test_rest_until_the_force_pulls_away(r):
    """``x'' = -cos t`` from rest on the barrier: pressed in until ``t = pi/2``, then ``x = t - pi/2 + cos t``."""
    with jax.enable_x64(True):
        out, t = run_paths(jdpim.Oscillator(r=r), ImpactRule(), 0.05, 4.0, [0.0], [0.0], lambda t: -np.cos(t), 1)
    x, v = out[0, :, 0], out[0, :, 1]
    before = t < np.pi / 2
    assert np.all(x[before] == 0.0) and np.all(v[before] == 0.0)  # rests exactly, never penetrates
    exact_x = np.where(before, 0.0, t - np.pi / 2 + np.cos(t))
    exact_v = np.where(before, 0.0, 1 - np.sin(t))
    # the departure time is located inside the step: measured max error 1.6e-9 (x), 2.6e-8 (v)
    np.testing.assert_allclose(x, exact_x, atol=1e-7)
    np.testing.assert_allclose(v, exact_v, atol=1e-6)


def _unit_gravity(x, params):
    return jnp.ones_like(x)


@pytest.mark.parametrize("r", [0.0, 0.3, 0.5])
def test_bouncing_ball_chatters_to_rest(r):
    """``x'' = -1`` from ``x0 = 0.5``: impacts accumulate at ``t_inf = 1 + 2 r / (1 - r)`` (Zeno), then rest."""
    gravity = jdpim.Oscillator(g=_unit_gravity, r=r)
    with jax.enable_x64(True):
        out, t = run_paths(gravity, ImpactRule(), 0.01, 6.0, [0.5], [0.0], save_every=1)
    x, v = out[0, :, 0], out[0, :, 1]
    assert np.all(np.isfinite(out)) and np.all(x >= 0.0)
    energy = x + 0.5 * v * v
    assert np.all(np.diff(energy) <= 1e-12)  # energy never grows (measured: non-increasing to 1e-15)
    t_inf = 1 + 2 * r / (1 - r)
    late = t > t_inf + 0.05
    assert np.all(x[late] == 0.0) and np.all(v[late] == 0.0)
    # first flight after the first impact (t in (1, 1 + 2r)): x = r (t - 1) - (t - 1)^2 / 2
    first = (t > 1) & (t < 1 + 2 * r)
    np.testing.assert_allclose(x[first], r * (t[first] - 1) - 0.5 * (t[first] - 1) ** 2, atol=1e-9)


@pytest.mark.parametrize(("n", "lanes"), [(1, 1), (7, 3), (64, 1), (500, 8), (513, 9)])
def test_first_in_lanes_is_the_first_true_entry_of_each_run(n, lanes):
    rng = np.random.default_rng(n)
    for density in (0.0, 0.01, 0.3, 1.0):
        mask = rng.random(n) < density
        group = -(-n // lanes)
        starts = range(0, lanes * group, group)
        expected = [next((i for i in range(lo, min(lo + group, n)) if mask[i]), n) for lo in starts]
        np.testing.assert_array_equal(np.asarray(first_in_lanes(jnp.asarray(mask), lanes)), expected)


@pytest.mark.parametrize(
    ("m", "size"),
    [(1, 1), (2, 8), (32, 8), (33, 16), (640, 160), (1000, 1000), (PREFIX_MAX, 1024), (PREFIX_MAX + 1, 64)],
)
def test_first_true_gives_the_indices_of_nonzero(m, size):
    """The first ``size`` true entries in order, ``m`` past the last, as NumPy finds them: by population counts up
    to ``PREFIX_MAX`` entries (one word, several, a partial last word), by ``jnp.nonzero`` beyond."""
    rng = np.random.default_rng(m)
    pick = jax.jit(first_true, static_argnums=1)
    for density in (0.0, 0.02, 0.3, 1.0):
        mask = rng.random(m) < density
        expected = np.full(size, m)
        found = np.flatnonzero(mask)[:size]
        expected[: found.size] = found
        np.testing.assert_array_equal(np.asarray(pick(jnp.asarray(mask), size)), expected)


def test_a_batch_crossing_together_matches_its_paths_alone():
    """320 paths, 40 copies of 8 initial states, interleaved: in every lane of 64 paths 8 copies of each state
    cross in the same step, so a step takes at least 8 rounds (and a second impact in one step, 16)."""
    model = jdpim.VibroImpactOscillator(alpha=ALPHA, gamma=None, r=R)
    x0, v0 = np.cos(PHASES), -np.sin(PHASES)
    with jax.enable_x64(True):
        alone, _ = run_paths(model, ImpactRule(), 0.25, 12.0, x0, v0, save_every=1)
        together, _ = run_paths(model, ImpactRule(), 0.25, 12.0, np.tile(x0, 40), np.tile(v0, 40), save_every=1)
    np.testing.assert_allclose(together, np.tile(alone, (40, 1, 1)), rtol=0, atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 3, 8, 31, 32, 33, 64, 100])
def test_the_tree_of_compact_batches_serves_every_step(n):
    """However the crossing paths of a step lie, ``2**compact_depth(n)`` compact batches resolve them all; a chunk of
    at most two paths takes one batch."""
    pick = jax.jit(pending_in_runs, static_argnums=1)
    lanes = -(-n // 32)  # run l holds the paths l, l + lanes, l + 2 lanes, ...
    patterns = {
        "every path": np.ones(n, bool),
        "one full run": np.arange(n) % lanes == 0,
        "the first 32 paths": np.arange(n) < 32,
        "every other path": np.arange(n) % 2 == 0,
        "the last path of each run": np.arange(n) >= 31 * lanes,
        "every 32nd path": np.arange(n) % 32 == 31,
    }
    for name, todo in patterns.items():
        todo, count = todo.copy(), 0
        while todo.any():
            idx = np.asarray(pick(jnp.asarray(todo), compact_rows(n)))
            todo[idx[idx < n]] = False
            count += 1
        assert count <= 2 ** compact_depth(n), name
    assert (compact_depth(n) == 0) == (n <= 2)


def test_batches_run_in_a_loop_and_differentiate_as_the_tree():
    """Batches until none is pending (``until_done``): the tree's values bit for bit, and derivatives with respect to
    a value the batch closes over (as it closes over the model's parameters) in reverse mode, raw and jitted, equal to
    the tree's and to the exact ones. A plain ``while_loop`` has no reverse mode; a ``custom_jvp`` that closed over
    the parameter would refuse it."""
    x0 = jnp.linspace(0.1, 0.8, 8)
    todo0 = jnp.arange(8) % 3 == 0  # 3 of 8 pending: three batches of one path each

    def run(p, loop):
        def leaf(c):  # one batch: the first pending entry, moved to sin(p x) + p
            x, todo, _ = c
            i = jnp.argmax(todo)
            x = x.at[i].set(jnp.where(todo[i], jnp.sin(p * x[i]) + p, x[i]))
            todo = todo.at[i].set(False)
            return x, todo, jnp.any(todo)

        return jnp.sum(loop(leaf, (x0, todo0, jnp.any(todo0)), 2)[0])  # a tree of 2**2 batches serves them

    p = 0.7
    jitted = jax.jit(run, static_argnums=1)
    assert float(jitted(p, until_done)) == float(jitted(p, tree))
    exact = float(jnp.sum(jnp.where(todo0, x0 * jnp.cos(p * x0) + 1.0, 0.0)))
    by_tree = float(jax.jit(jax.grad(run), static_argnums=1)(p, tree))
    for grad in (jax.grad(run), jax.jit(jax.grad(run), static_argnums=1), jax.grad(jitted)):
        assert float(grad(p, until_done)) == by_tree
    np.testing.assert_allclose(by_tree, exact, rtol=1e-6)
    np.testing.assert_allclose(float(jax.jit(jax.jacfwd(run), static_argnums=1)(p, until_done)), exact, rtol=1e-6)
