"""The result of a DPIM or Monte Carlo run: weighted states at the saved times, and their densities."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from .._pytree import check_grid, check_points, check_real, concrete, plain, pytree_dataclass, static_field
from .._scene import saved_index, static_times
from . import _density

VARIABLES = ("x", "v")


@pytree_dataclass
class Result:
    """Weighted response states of ``N`` paths (DPIM points or Monte Carlo samples).

    Attributes:
        times: saved times, s: a tuple of ``S`` floats. They are pytree structure, not leaves: a saved time
            picks an index, so a result passed into ``jax.jit`` or ``jax.vmap`` keeps them concrete and
            every method works there (an array given here is converted; float32 values are read at their
            own precision, so ``0.2`` stored in float32 is ``0.2``).
        states: ``(x, v)`` per path and saved time, shape ``(N, S, 2)`` (path axis leading).
        weights: probability of each path, shape ``(N,)``, summing to 1.
        barrier: barrier position (the displacement kernel is reflected there), or ``None``.
        method: ``"dpim"`` or ``"monte_carlo"``.

    Results are pytrees (leaves: ``states``, ``weights``, ``barrier``): they pass through ``jax.jit`` and
    ``jax.vmap`` as arguments and outputs.
    """

    times: tuple = static_field()
    states: Any = None
    weights: Any = None
    barrier: Any = None
    method: str = static_field(default="dpim")

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))

    @property
    def n_paths(self) -> int:
        return int(np.shape(self.weights)[0])

    def _index(self, t) -> int:
        return saved_index(self.times, t)

    def samples(self, var: str, t: float):
        """The values of ``var`` (``"x"`` or ``"v"``) of every path at saved time ``t``; shape ``(N,)``."""
        if var not in VARIABLES:
            raise ValueError(f"var must be one of {VARIABLES}, got {var!r}")
        return self.states[:, self._index(t), VARIABLES.index(var)]

    def n_nonfinite(self):
        """Number of paths with a non-finite state, per saved time; shape ``(S,)``."""
        return jnp.sum(~jnp.all(jnp.isfinite(self.states), axis=-1), axis=0)

    def lost_mass(self):
        """Probability carried by paths with non-finite states, per saved time; shape ``(S,)``.

        Densities leave this mass out (they integrate to ``1 - lost_mass``).
        """
        bad = ~jnp.all(jnp.isfinite(self.states), axis=-1)
        return jnp.sum(jnp.where(bad, self.weights[:, None], 0.0), axis=0)

    def mass(self, t: float):
        """Probability carried by the paths with finite states at saved time ``t`` (``1 - lost_mass``)."""
        return 1.0 - self.lost_mass()[self._index(t)]

    def bandwidth(self, var: str, t: float, rule: str = "chen", *, dim: int = 1, c: float | None = None):
        """The rule-based kernel standard deviation for ``var`` at time ``t`` (see ``jdpim.bandwidth``)."""
        return _density.bandwidth(self.samples(var, t), self.weights, rule, dim=dim, c=c)

    def pdf(self, var: str, grid, t: float, *, bandwidth=None, rule: str = "chen"):
        r"""Marginal PDF of ``var`` (``"x"`` or ``"v"``) at saved time ``t`` on ``grid``.

        ``p(y) = sum_q P_q N(y; y_q, sigma^2)``, reflected at the barrier for ``"x"``.

        Args:
            var: ``"x"`` (displacement) or ``"v"`` (velocity).
            grid: evaluation points: a scalar or 1-D (one point or more), strictly increasing.
            t: a saved time, s.
            bandwidth: kernel standard deviation (> 0), or ``None`` to use ``rule``.
            rule: bandwidth rule, one of ``"chen"``, ``"silverman"``, ``"scott"``.

        Returns:
            array shaped like ``grid``.

        A one-point grid gives a scalar functional that ``jax.grad`` differentiates through the pipeline
        (``tests/test_cli.py`` checks it against central differences)::

            pts = jdpim.dpim_points(scene, 64)
            f = lambda D: jdpim.dpim(scene.replace(noise=jdpim.WhiteNoise(D=D)), points=pts).pdf(
                "x", jnp.array([0.5]), t)[0]
            jax.grad(f)(0.03)
        """
        check_points("grid", grid)
        y = self.samples(var, t)
        sigma = self._sigma(bandwidth, lambda: _density.bandwidth(y, self.weights, rule, dim=1))
        return _density.kde(y, self.weights, jnp.asarray(grid), sigma, self.barrier if var == "x" else None)

    def pdf_stderr(self, var: str, grid, t: float, *, bandwidth=None, rule: str = "chen"):
        r"""Sampling standard error of :meth:`pdf` (same arguments), Monte Carlo results only.

        From the per-path kernel contributions ``K_q(y)``: ``se(y)^2 = sum_q K_q(y)^2 / n^2 - p(y)^2 / n``
        up to the factor ``n / (n - 1)`` (see ``jdpim.kde_stderr``), at the same bandwidth as ``pdf``.
        DPIM points are not independent samples: their error comes from randomised point sets
        (``jdpim.dpim_replicates``).
        """
        if self.method != "monte_carlo":
            raise ValueError(
                f"pdf_stderr needs independent samples (method 'monte_carlo'), got method {self.method!r}; "
                "for DPIM use jdpim.dpim_replicates"
            )
        check_points("grid", grid)
        y = self.samples(var, t)
        sigma = self._sigma(bandwidth, lambda: _density.bandwidth(y, self.weights, rule, dim=1))
        return _density.kde_stderr(y, self.weights, jnp.asarray(grid), sigma, self.barrier if var == "x" else None)

    def joint_pdf(self, x_grid, v_grid, t: float, *, bandwidth=None, rule: str = "chen"):
        """Joint PDF of ``(x, v)`` at saved time ``t``; shape ``(len(x_grid), len(v_grid))``.

        A scalar grid drops its axis.

        ``bandwidth`` is ``None`` (rule-based, 2-D exponent) or a pair ``(sigma_x, sigma_v)``.
        """
        check_points("x_grid", x_grid)
        check_points("v_grid", v_grid)
        x, v = self.samples("x", t), self.samples("v", t)
        if bandwidth is None:
            sx = _density.bandwidth(x, self.weights, rule, dim=2)
            sv = _density.bandwidth(v, self.weights, rule, dim=2)
        else:
            if np.ndim(bandwidth) != 1 or len(bandwidth) != 2:
                raise ValueError(f"bandwidth must be None or a pair (sigma_x, sigma_v), got {plain(bandwidth)!r}")
            sx, sv = (self._sigma(b, None) for b in bandwidth)
        return _density.kde_2d(x, v, self.weights, jnp.asarray(x_grid), jnp.asarray(v_grid), sx, sv, self.barrier)

    def histogram(self, var: str, edges, t: float):
        """Weighted histogram density of ``var`` at time ``t`` on bin ``edges``; shape ``(len(edges) - 1,)``."""
        check_grid("edges", edges)
        return _density.histogram(self.samples(var, t), self.weights, jnp.asarray(edges))

    def moment(self, var: str, order: int, t: float):
        """Weighted raw moment ``E[var^order]`` at time ``t`` over the paths with finite states."""
        y = self.samples(var, t)
        ok = jnp.isfinite(y)
        w = jnp.where(ok, self.weights, 0.0)
        return jnp.sum(w * jnp.where(ok, y, 0.0) ** order) / jnp.sum(w)

    @staticmethod
    def _sigma(bandwidth, default):
        if bandwidth is None:
            return default()
        check_real("bandwidth", bandwidth, low=0.0, low_open=True)
        arr = concrete(bandwidth)
        return bandwidth if arr is None else jnp.asarray(arr)
