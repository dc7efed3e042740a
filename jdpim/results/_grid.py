"""The result of path integration: densities on a phase-space grid, with the same interface as ``Result``."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from .._pytree import check_int, check_points, pytree_dataclass, static_field
from .._scene import saved_index, static_times
from ..methods._pi_operator import catmull_rom, lagrange

VARIABLES = ("x", "v")


@pytree_dataclass
class GridResult:
    r"""Joint densities ``p(x_i, v_j, t)`` on a grid, from ``jdpim.path_integration``.

    Attributes:
        times: saved times, s, a tuple of floats (``(inf,)`` for a stationary solve); pytree structure, as
            in ``jdpim.Result``, so that results pass through ``jax.jit`` and ``jax.vmap``.
        density: joint density on the nodes, shape ``(S, n_x, n_v)``, normalised to unit mass.
        x, v: grid nodes, shapes ``(n_x,)`` and ``(n_v,)`` (``x[0]`` is the barrier when there is one).
        x_weights, v_weights: the solver's quadrature weights of the nodes (the integrals of its
            interpolation functions), shapes ``(n_x,)`` and ``(n_v,)``: masses, marginals and moments use
            them, and ``pdf`` interpolates with the functions they integrate, so an interpolated marginal
            integrates to ``mass()`` exactly (up to the outermost spacing of the v axis with ``order=2``).
        mass_defect: per saved time, the sum over the steps so far of ``|1 - mass|`` before the
            renormalisation of each step (interpolation defect and mass leaving the grid), shape ``(S,)``.
        edge_mass: per saved time, the largest mass seen so far in the two outermost node rows along
            the open edges (``x = x_max``, ``v = +-v_max``); large values mean the grid is too small.
        residual: stationary solve only: ``||T p - p||_1`` of the one-step operator ``T`` (else ``nan``).
        step_gain: stationary solve only: mass kept by one step before renormalisation (1 = nothing lost).
        newton_steps: stationary solve only: Newton steps taken (0 for a transient result).
        virial: stationary solve only: ``(E[v^2] + E[(x - b) a(x, v)]) / E[v^2]`` with ``a`` the drift of ``v``
            and ``b`` the barrier (0 without one), which is exactly zero for every stationary density (the
            time derivative of ``E[(x - b) v]``; impacts happen at ``x = b`` and add nothing): a check of the
            grid's resolution, chiefly of the velocity marginal (``nan`` for a transient result).
        coarse: the same solve on a grid twice as coarse (``PathIntegration(estimate_error=True)``), from
            which ``pdf_error`` and ``l1_error`` estimate the discretisation error; else ``None``.
        order: interpolation points per axis of the solve (2, 4 or 6; see ``jdpim.PathIntegration``).
        folded: whether the solve folded ghost nodes back at the barrier (``order > 2`` with a barrier):
            then the density's continuation beyond the barrier is its mirror image.
        stationary: whether this is a stationary density (then ``t`` may be left out).

    Densities are zero outside the grid (and below the barrier).
    """

    times: tuple = static_field()
    density: Any = None
    x: Any = None
    v: Any = None
    x_weights: Any = None
    v_weights: Any = None
    mass_defect: Any = None
    edge_mass: Any = None
    residual: Any = None
    step_gain: Any = None
    newton_steps: Any = None
    virial: Any = None
    coarse: Any = None
    order: int = static_field(default=4)
    folded: bool = static_field(default=False)
    stationary: bool = static_field(default=False)

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))

    def _index(self, t) -> int:
        if t is None:
            if not self.stationary:
                raise ValueError(f"t is required for a transient result (saved times: {list(self.times)})")
            return 0
        if self.stationary:
            return 0
        return saved_index(self.times, t)

    @property
    def saved_times(self) -> tuple[float, ...]:
        return self.times

    def joint(self, t: float | None = None):
        """Nodal joint density at ``t``, shape ``(n_x, n_v)``."""
        return self.density[self._index(t)]

    def _axis(self, var: str):
        if var not in VARIABLES:
            raise ValueError(f"var must be one of {VARIABLES}, got {var!r}")
        return (self.x, self.x_weights) if var == "x" else (self.v, self.v_weights)

    def nodal_marginal(self, var: str, t: float | None = None):
        """Marginal density of ``var`` on its grid nodes (the solver's quadrature over the other variable)."""
        self._axis(var)
        p = self.joint(t)
        return p @ self.v_weights if var == "x" else self.x_weights @ p

    def _interpolate(self, values, var: str, points):
        """``values`` on the nodes of ``var`` (first axis) at ``points`` with the solver's interpolation."""
        nodes, _ = self._axis(var)
        g = jnp.atleast_1d(jnp.asarray(points, dtype=values.dtype))
        t = (g - nodes[0]) / (nodes[1] - nodes[0])
        ghost = self.order // 2 if self.folded and var == "x" else 0
        if ghost:  # the mirror image beyond the barrier, which the folded solve's areas integrate
            values = jnp.concatenate([values[ghost:0:-1], values])
        if self.order == 4:
            start, w = catmull_rom(t, nodes.shape[0], ghost)
        else:
            start, w = lagrange(t, nodes.shape[0], self.order, ghost)
        w = jnp.where((t >= 0)[:, None], w, 0.0)
        rows = values[start[:, None] + ghost + jnp.arange(w.shape[-1])[None, :]]  # (G, points, ...)
        return jnp.einsum("gk...,gk->g...", rows, w)

    def pdf(self, var: str, grid, t: float | None = None):
        """Marginal PDF of ``var`` (``"x"`` or ``"v"``) at ``t`` on ``grid`` (a scalar or 1-D, one point or more).

        Returns an array shaped like ``grid``.
        """
        check_points("grid", grid)
        out = self._interpolate(self.nodal_marginal(var, t), var, grid)
        return jnp.reshape(out, jnp.shape(grid))

    def joint_pdf(self, x_grid, v_grid, t: float | None = None):
        """Joint PDF at ``t``; shape ``(len(x_grid), len(v_grid))`` (a scalar grid drops its axis)."""
        check_points("x_grid", x_grid)
        check_points("v_grid", v_grid)
        px = self._interpolate(self.joint(t), "x", x_grid)  # (Gx, n_v)
        out = self._interpolate(px.T, "v", v_grid).T  # (Gx, Gv)
        return jnp.reshape(out, jnp.shape(x_grid) + jnp.shape(v_grid))

    def moment(self, var: str, order: int, t: float | None = None):
        """Raw moment ``E[var^order]`` at ``t`` (the solver's quadrature on the nodes)."""
        check_int("order", order, low=0)
        nodes, weights = self._axis(var)
        return jnp.sum(weights * self.nodal_marginal(var, t) * nodes**order)

    def mass(self, t: float | None = None):
        """Total probability on the grid at ``t`` (1 up to rounding: densities are renormalised)."""
        return jnp.sum(self.x_weights * self.nodal_marginal("x", t))

    def n_nonfinite(self):
        """Number of non-finite nodal densities per saved time; shape ``(S,)``."""
        return jnp.sum(~jnp.isfinite(self.density), axis=(1, 2))

    def _coarse(self) -> GridResult:
        if self.coarse is None:
            raise ValueError(
                "this result carries no error estimate: solve with jdpim.PathIntegration(estimate_error=True)"
            )
        return self.coarse

    def pdf_error(self, var: str, grid, t: float | None = None):
        """Estimated discretisation error of :meth:`pdf`: ``|pdf - pdf on the coarse grid|``, shaped like ``grid``.

        For a scheme that converges at first order or faster in the spacings and the step, this bounds the
        error of the fine grid (asymptotically); ``docs/path_integration.md`` measures how far it covers it.
        """
        return jnp.abs(self.pdf(var, grid, t) - self._coarse().pdf(var, grid, t))

    def l1_error(self, var: str, t: float | None = None):
        """Estimated L1 error of the marginal of ``var``: ``int |p - p_coarse|`` over the fine grid's nodes."""
        nodes, weights = self._axis(var)
        coarse = self._coarse().pdf(var, nodes, t)
        return jnp.sum(weights * jnp.abs(self.nodal_marginal(var, t) - coarse))
