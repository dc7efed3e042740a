"""The result of a sampling method (DPIM or Monte Carlo): weighted states at the saved times, and their densities."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import check_grid, check_points, check_real, concrete, plain, pytree_dataclass, static_field
from .._scene import static_times
from .._tangents import watch, watch_forward
from . import _density
from ._base import COORDINATES, AbstractResult

HISTOGRAM = (
    "the derivative of a histogram is zero: each path's bin is piecewise constant in the parameters; "
    "differentiate Result.pdf (a kernel density) or use jdpim.sensitivity"
)


def reflection(bounds, var):
    """Where the kernel of ``var`` is reflected, given a model's ``bounds()`` (the barrier of ``x``, or
    ``{coordinate: lower bound}``): the bound of a coordinate ``var``, else ``None``."""
    if isinstance(bounds, dict):
        return bounds.get(var) if isinstance(var, str) else None
    return bounds if var == "x" else None


@pytree_dataclass
class Result(AbstractResult):
    """Weighted response states of ``N`` paths (DPIM points or Monte Carlo samples).

    Attributes:
        times: saved times, s: a tuple of ``S`` floats. They are pytree structure, not leaves: a saved time
            picks an index, so a result passed into ``jax.jit`` or ``jax.vmap`` keeps them concrete and
            every method works there (an array given here is converted; float32 values are read at their
            own precision, so ``0.2`` stored in float32 is ``0.2``).
        states: the state of every path at every saved time, shape ``(N, S, n_state)`` (path axis leading;
            ``n_state = 2``, ``(x, v)``, for one degree of freedom).
        weights: probability of each path, shape ``(N,)``, summing to 1.
        barrier: barrier position (the displacement kernel is reflected there), or ``None``; for several
            degrees of freedom a mapping ``{coordinate: lower bound}`` of the coordinates a constraint bounds.
        method: ``"dpim"`` or ``"monte_carlo"``.
        coordinates: names of the state's entries, ``("x", "v")`` for one degree of freedom.

    Results are pytrees (leaves: ``states``, ``weights``, ``barrier``): they pass through ``jax.jit`` and
    ``jax.vmap`` as arguments and outputs. The interface is shared with ``jdpim.GridResult``
    (``jdpim.results.AbstractResult``).
    """

    times: tuple = static_field()
    states: Any = None
    weights: Any = None
    barrier: Any = None
    method: str = static_field(default="dpim")
    coordinates: tuple = static_field(default=COORDINATES)

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))
        object.__setattr__(self, "coordinates", tuple(self.coordinates))

    @property
    def n_paths(self) -> int:
        return int(np.shape(self.weights)[0])

    def samples(self, var, t: float | None = None):
        """The values of ``var`` (a coordinate name or a function of the state) of every path at ``t``; ``(N,)``."""
        which = self._coordinate(var)
        at = self.states[:, self._index(t)]
        return jax.vmap(which)(at) if callable(which) else at[:, which]

    def _reflect(self, var):
        """Where the kernel of ``var`` is reflected (the barrier of ``x``, a bounded coordinate), or ``None``."""
        return reflection(self.barrier, var)

    def n_nonfinite(self):
        """Number of paths with a non-finite state, per saved time; shape ``(S,)``."""
        return jnp.sum(~jnp.all(jnp.isfinite(self.states), axis=-1), axis=0)

    def lost_mass(self):
        """Probability carried by paths with non-finite states, per saved time; shape ``(S,)``.

        Densities leave this mass out (they integrate to ``1 - lost_mass``).
        """
        bad = ~jnp.all(jnp.isfinite(self.states), axis=-1)
        return jnp.sum(jnp.where(bad, self.weights[:, None], 0.0), axis=0)

    def mass(self, t: float | None = None):
        """Probability carried by the paths with finite states at saved time ``t`` (``1 - lost_mass``)."""
        return 1.0 - self.lost_mass()[self._index(t)]

    def bandwidth(self, var, t: float | None = None, rule: str = "chen", *, dim: int = 1, c: float | None = None):
        """The rule-based kernel standard deviation for ``var`` at time ``t`` (see ``jdpim.bandwidth``)."""
        return _density.bandwidth(self.samples(var, t), self.weights, rule, dim=dim, c=c)

    def pdf(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen"):
        r"""Marginal PDF of ``var`` at saved time ``t`` on ``grid``.

        ``p(y) = sum_q P_q N(y; y_q, sigma^2)``, reflected at the barrier for ``"x"``.

        Args:
            var: a coordinate name (``"x"``: displacement, ``"v"``: velocity) or a function of the state
                (its kernel is not reflected).
            grid: evaluation points: a scalar or 1-D (one point or more), strictly increasing.
            t: a saved time, s (may be left out when the result holds one).
            bandwidth: kernel standard deviation (> 0), or ``None`` to use ``rule``.
            rule: bandwidth rule, one of ``"chen"``, ``"silverman"``, ``"scott"``.

        Returns:
            array shaped like ``grid``.

        A one-point grid gives a scalar functional that ``jax.grad`` differentiates through the pipeline
        (``tests/test_cli.py`` checks it against central differences)::

            pts = jdpim.dpim_points(scene, 64)
            f = lambda D: jdpim.solve(scene.replace(noise=jdpim.WhiteNoise(D=D)), jdpim.DPIM(points=pts)).pdf(
                "x", jnp.array([0.5]), t)[0]
            jax.grad(f)(0.03)
        """
        check_points("grid", grid)
        y = self.samples(var, t)
        sigma = self._sigma(bandwidth, lambda: _density.bandwidth(y, self.weights, rule, dim=1))
        grid, reflect = jnp.asarray(grid), self._reflect(var)
        y = watch_forward(y, jax.tree_util.Partial(_kernel_contributions, self.weights, grid, sigma, reflect))
        return _density.kde(y, self.weights, grid, sigma, reflect)

    def pdf_error(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen"):
        r"""Sampling standard error of :meth:`pdf` (same arguments): Monte Carlo results only.

        From the per-path kernel contributions ``K_q(y)``: ``se(y)^2 = sum_q K_q(y)^2 / n^2 - p(y)^2 / n``
        up to the factor ``n / (n - 1)`` (see ``jdpim.kde_stderr``), at the same bandwidth as ``pdf``.
        DPIM points are not independent samples: their error comes from randomised point sets
        (``jdpim.dpim_replicates``).
        """
        if self.method != "monte_carlo":
            raise ValueError(
                f"pdf_error of a sampling result needs independent samples (method 'monte_carlo'), got method "
                f"{self.method!r}; for DPIM use jdpim.dpim_replicates"
            )
        check_points("grid", grid)
        y = self.samples(var, t)
        sigma = self._sigma(bandwidth, lambda: _density.bandwidth(y, self.weights, rule, dim=1))
        return _density.kde_stderr(y, self.weights, jnp.asarray(grid), sigma, self._reflect(var))

    def joint_pdf(self, vars, grids, t: float | None = None, *, bandwidth=None, rule: str = "chen"):
        """Joint PDF of two quantities at saved time ``t``; shape ``(len(grids[0]), len(grids[1]))``.

        Args:
            vars: a pair of coordinate names or functions of the state, e.g. ``("x", "v")``.
            grids: a pair of grids (each a scalar or 1-D; a scalar grid drops its axis).
            t: a saved time, s (may be left out when the result holds one).
            bandwidth: ``None`` (rule-based, 2-D exponent) or a pair ``(sigma_1, sigma_2)``.
            rule: bandwidth rule for ``None``.
        """
        (va, vb), (ga, gb) = _pair("vars", vars), _pair("grids", grids)
        for name, g in (("grids[0]", ga), ("grids[1]", gb)):
            check_points(name, g)
        a, b = self.samples(va, t), self.samples(vb, t)
        if bandwidth is None:
            sa = _density.bandwidth(a, self.weights, rule, dim=2)
            sb = _density.bandwidth(b, self.weights, rule, dim=2)
        else:
            if np.ndim(bandwidth) != 1 or len(bandwidth) != 2:
                raise ValueError(f"bandwidth must be None or a pair (sigma_1, sigma_2), got {plain(bandwidth)!r}")
            sa, sb = (self._sigma(s, None) for s in bandwidth)
        if self._reflect(vb) is not None and self._reflect(va) is None:  # the reflected quantity goes first
            return _density.kde_2d(b, a, self.weights, jnp.asarray(gb), jnp.asarray(ga), sb, sa, self._reflect(vb)).T
        return _density.kde_2d(a, b, self.weights, jnp.asarray(ga), jnp.asarray(gb), sa, sb, self._reflect(va))

    def histogram(self, var, edges, t: float | None = None):
        """Weighted histogram density of ``var`` at time ``t`` on bin ``edges``; shape ``(len(edges) - 1,)``."""
        check_grid("edges", edges)
        return _density.histogram(watch(self.samples(var, t), HISTOGRAM), self.weights, jnp.asarray(edges))

    def moment(self, var, order: int, t: float | None = None):
        """Weighted raw moment ``E[var^order]`` at time ``t`` over the paths with finite states."""
        y = self.samples(var, t)
        ok = jnp.isfinite(y)
        w = jnp.where(ok, self.weights, 0.0)
        y = watch_forward(y, jax.tree_util.Partial(_moment_contributions, w, order))
        return jnp.sum(w * jnp.where(ok, y, 0.0) ** order) / jnp.sum(w)

    @staticmethod
    def _sigma(bandwidth, default):
        if bandwidth is None:
            return default()
        check_real("bandwidth", bandwidth, low=0.0, low_open=True)
        arr = concrete(bandwidth)
        return bandwidth if arr is None else jnp.asarray(arr)


def _kernel_contributions(weights, grid, sigma, reflect, y, y_dot):
    """Per-path contributions ``(N, G)`` to the forward-mode derivative of :meth:`Result.pdf`."""
    ok = jnp.isfinite(y)
    y = jnp.where(ok, y, 0.0)
    dk = jax.jvp(lambda s: _density._kernel_matrix(jnp.atleast_1d(grid), s, sigma, reflect), (y,), (y_dot,))[1]
    return jnp.where(ok[:, None], (weights[None, :] * dk).T, 0.0)


def _moment_contributions(weights, order, y, y_dot):
    """Per-path contributions ``(N,)`` to the forward-mode derivative of :meth:`Result.moment`."""
    ok = jnp.isfinite(y)
    return jnp.where(ok, weights * order * jnp.where(ok, y, 0.0) ** (order - 1) * y_dot, 0.0)


def _pair(name: str, value) -> tuple:
    """``value`` as a pair (``vars`` or ``grids`` of a joint density), with a clear error otherwise."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a pair, e.g. ('x', 'v') and (x_grid, v_grid), got {plain(value)!r}")
    return tuple(value)
