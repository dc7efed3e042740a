"""One result interface: every density result implements ``AbstractResult``'s abstract methods with its
signatures, a class lacking one cannot be built, and the grid result answers what the sampled one does."""

import inspect

import jax.numpy as jnp
import numpy as np
import pytest

import jdpim
from jdpim._pytree import pytree_dataclass, static_field
from jdpim.results import AbstractResult

RESULTS = (jdpim.Result, jdpim.GridResult)


def test_every_public_result_class_implements_the_interface_with_its_signatures():
    public = {c for c in vars(jdpim).values() if isinstance(c, type) and issubclass(c, AbstractResult)}
    assert public == set(RESULTS)
    assert {"pdf", "pdf_error", "joint_pdf", "moment", "mass", "bounds", "atoms"} <= AbstractResult.__abstractmethods__
    for cls in RESULTS:
        assert not cls.__abstractmethods__, cls
        for name in sorted(AbstractResult.__abstractmethods__):
            assert inspect.signature(getattr(cls, name)) == inspect.signature(getattr(AbstractResult, name)), (
                cls,
                name,
            )
        assert "times" in {f for f in cls.__dataclass_fields__} and not hasattr(cls, "saved_times")


def test_a_result_lacking_a_method_cannot_be_built():
    @pytree_dataclass
    class Partial(AbstractResult):
        times: tuple = static_field()

        def pdf(self, var, grid, t=None, *, bandwidth=None, rule="chen", bounds=None):
            return grid

    with pytest.raises(TypeError, match="abstract"):
        Partial(times=(1.0,))


def _grid_result(has_barrier=False, coarse=None, seed=0):
    """A hand-made grid result: a positive density on 9 x 11 nodes with trapezoidal weights."""
    x, v = np.linspace(0.0, 2.0, 9), np.linspace(-1.5, 1.5, 11)
    wx, wv = 0.25 * np.r_[0.5, np.ones(7), 0.5], 0.3 * np.r_[0.5, np.ones(9), 0.5]
    p = np.random.default_rng(seed).uniform(0.5, 1.0, (1, 9, 11))
    p /= np.einsum("sij,i,j->s", p, wx, wv)[:, None, None]
    arr = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return jdpim.GridResult(
        times=(1.0,), density=arr(p), x=arr(x), v=arr(v), x_weights=arr(wx), v_weights=arr(wv), coarse=coarse,
        has_barrier=has_barrier,
    )  # fmt: skip


def test_grid_kernel_densities_of_functions_match_those_of_coordinates():
    res = _grid_result()
    gx, gv, h = jnp.linspace(0.1, 1.9, 4), jnp.linspace(-1.0, 1.0, 3), (0.3, 0.4)
    by_name = np.asarray(res.joint_pdf(("x", "v"), (gx, gv), bandwidth=h))
    by_function = np.asarray(res.joint_pdf((lambda s: s[0], "v"), (gx, gv), bandwidth=h))
    np.testing.assert_allclose(by_function, by_name, rtol=1e-5, atol=1e-7)
    swapped = np.asarray(res.joint_pdf(("v", lambda s: s[0]), (gv, gx), bandwidth=h[::-1]))
    np.testing.assert_allclose(swapped.T, by_name, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(
        np.asarray(res.pdf(lambda s: s[1], gv, bandwidth=0.4)), np.asarray(res.pdf("v", gv, bandwidth=0.4)), rtol=1e-5
    )


def test_grid_bounds_atoms_and_error():
    res = _grid_result(has_barrier=True, coarse=_grid_result(has_barrier=True, seed=1))
    assert float(res.bounds("x")[0]) == 0.0 and res.bounds("x")[1] is None and res.bounds("v") == (None, None)
    np.testing.assert_array_equal(np.asarray(res.atoms("x")), [0.0, 0.0])
    g = jnp.linspace(0.1, 1.9, 5)
    for kw in ({}, {"bandwidth": 0.3}, {"bandwidth": 0.3, "bounds": (0.0, 2.0)}):
        expect = np.abs(np.asarray(res.pdf("x", g, **kw)) - np.asarray(res.coarse.pdf("x", g, **kw)))
        np.testing.assert_array_equal(np.asarray(res.pdf_error("x", g, **kw)), expect)
    reflected = np.asarray(res.pdf("x", g, bandwidth=0.3, bounds=(0.0, 2.0)))
    assert not np.allclose(reflected, np.asarray(res.pdf("x", g, bandwidth=0.3)))  # the upper end reflects too
    with pytest.raises(ValueError, match=r"bounds=\[0.0, 2.0\] for the interpolated grid density of 'x'"):
        res.pdf("x", g, bounds=[0.0, 2.0])
    with pytest.raises(ValueError, match="rule must be one of"):
        res.pdf("x", g, rule="sturges")
    with pytest.raises(ValueError, match="carries no error estimate"):
        _grid_result().pdf_error("x", g)
