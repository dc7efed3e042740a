"""Only the effects a scene calls for are traced, and changing a physical parameter does not recompile."""

import jax
import jax.extend
import jax.numpy as jnp
import pytest
from conftest import DT_SMALL, N_SMALL, T_SMALL

import jdpim
from jdpim.methods._paths import simulate


def primitives(scene, n=4):
    rows = jnp.asarray(jdpim.dpim_points(scene, n).theta, scene.float_dtype)
    jaxpr = jax.make_jaxpr(lambda s, r: simulate(s, r, kind="dpim", chunk_size=n))(scene, rows)
    names = []

    def walk(jpr):
        for eqn in jpr.eqns:
            names.append((eqn.primitive.name, eqn.params.get("y")))
            for sub in jax.extend.core.jaxprs_in_params(eqn.params):
                walk(sub)

    walk(jaxpr.jaxpr)
    return names


def scene_with(**model_kw):
    return jdpim.Scene(jdpim.VibroImpactOscillator(**model_kw), t_end=0.1, dt=0.05)


def test_cubic_damping_is_traced_only_when_present():
    assert ("integer_pow", 3) in primitives(scene_with(gamma=0.03))
    assert ("integer_pow", 3) not in primitives(scene_with(gamma=None))


def test_impact_logic_is_traced_only_with_a_barrier():
    with_barrier = [p for p, _ in primitives(scene_with(barrier=0.0))]
    without = [p for p, _ in primitives(scene_with(barrier=None))]
    assert "cond" in with_barrier
    assert "cond" not in without


@pytest.mark.parametrize("method", ["dpim", "monte_carlo"])
def test_new_parameter_values_do_not_recompile(method):
    """On the scene and sizes of the methods' examples (their programs, compiled once a session)."""
    base = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=T_SMALL, dt=DT_SMALL)
    run = (
        (lambda s: jdpim.dpim(s, n_points=N_SMALL))
        if method == "dpim"
        else (lambda s: jdpim.monte_carlo(s, n_samples=N_SMALL))
    )
    run(base)
    before = simulate._cache_size()
    for alpha, r, D in [(0.05, 0.9, 0.1), (0.2, 0.5, 0.02)]:
        run(base.replace(model=base.model.replace(alpha=alpha, r=r), noise=jdpim.WhiteNoise(D=D)))
    assert simulate._cache_size() == before
