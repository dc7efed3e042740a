"""The result of path integration: densities on a phase-space grid, with the same interface as ``Result``."""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from ._pi_operator import lagrange
from ._pytree import check_grid, check_int, pytree_dataclass, static_field
from ._scene import saved_index

VARIABLES = ("x", "v")


@pytree_dataclass
class GridResult:
    r"""Joint densities ``p(x_i, v_j, t)`` on a grid, from ``jdpim.path_integration``.

    Attributes:
        times: saved times, shape ``(S,)``, s (``(inf,)`` for a stationary solve).
        density: joint density on the nodes, shape ``(S, n_x, n_v)``, normalised to unit mass.
        x, v: grid nodes, shapes ``(n_x,)`` and ``(n_v,)`` (``x[0]`` is the barrier when there is one).
        mass_defect: per saved time, the sum over the steps so far of ``|1 - mass|`` before the
            renormalisation of each step (interpolation defect and mass leaving the grid), shape ``(S,)``.
        edge_mass: per saved time, the largest mass seen so far in the two outermost node rows along
            the open edges (``x = x_max``, ``v = +-v_max``); large values mean the grid is too small.
        residual: stationary solve only: ``||T p - p||_1`` of the one-step operator ``T`` (else ``nan``).
        step_gain: stationary solve only: mass kept by one step before renormalisation (1 = nothing lost).
        newton_steps: stationary solve only: Newton (GMRES) steps taken (0 for a transient result).
        virial: stationary solve only: ``(E[v^2] + E[(x - b) a(x, v)]) / E[v^2]`` with ``a`` the drift of ``v``
            and ``b`` the barrier (0 without one), which is exactly zero for every stationary density (the
            time derivative of ``E[(x - b) v]``; impacts happen at ``x = b`` and add nothing): a check of the
            grid's resolution, chiefly of the velocity marginal (``nan`` for a transient result).
        stationary: whether this is a stationary density (then ``t`` may be left out).

    Densities and moments use the trapezoidal rule on the nodes; ``pdf``/``joint_pdf`` interpolate
    linearly between nodes and are zero outside the grid (and below the barrier).
    """

    times: Any
    density: Any
    x: Any
    v: Any
    mass_defect: Any
    edge_mass: Any
    residual: Any
    step_gain: Any
    newton_steps: Any
    virial: Any
    stationary: bool = static_field(default=False)

    def _index(self, t) -> int:
        if t is None:
            if not self.stationary:
                raise ValueError(f"t is required for a transient result (saved times: {self.saved_times})")
            return 0
        if self.stationary:
            return 0
        return saved_index(self.saved_times, t)

    @property
    def saved_times(self) -> tuple[float, ...]:
        return tuple(float(t) for t in np.asarray(self.times))

    def joint(self, t: float | None = None):
        """Nodal joint density at ``t``, shape ``(n_x, n_v)``."""
        return self.density[self._index(t)]

    def _weights(self, axis_nodes):
        w = jnp.ones_like(axis_nodes).at[0].set(0.5).at[-1].set(0.5)
        return w * (axis_nodes[1] - axis_nodes[0])

    def nodal_marginal(self, var: str, t: float | None = None):
        """Marginal density of ``var`` on its grid nodes (trapezoidal rule over the other variable)."""
        if var not in VARIABLES:
            raise ValueError(f"var must be one of {VARIABLES}, got {var!r}")
        p = self.joint(t)
        return p @ self._weights(self.v) if var == "x" else self._weights(self.x) @ p

    def pdf(self, var: str, grid, t: float | None = None):
        """Marginal PDF of ``var`` (``"x"`` or ``"v"``) at saved time ``t`` on ``grid``; shaped like ``grid``."""
        check_grid("grid", grid)
        nodes = self.x if var == "x" else self.v
        m = self.nodal_marginal(var, t)
        start, w = _stencil(jnp.asarray(grid, dtype=m.dtype), nodes)
        return jnp.sum(m[start[:, None] + jnp.arange(w.shape[-1])[None, :]] * w, axis=-1)

    def joint_pdf(self, x_grid, v_grid, t: float | None = None):
        """Joint PDF at ``t`` (cubic interpolation between nodes); shape ``(len(x_grid), len(v_grid))``."""
        check_grid("x_grid", x_grid)
        check_grid("v_grid", v_grid)
        p = self.joint(t)
        sx, wx = _stencil(jnp.asarray(x_grid, dtype=p.dtype), self.x)
        sv, wv = _stencil(jnp.asarray(v_grid, dtype=p.dtype), self.v)
        k = jnp.arange(wx.shape[-1])[None, :]
        rows = p[sx[:, None] + k]  # (Gx, 4, n_v)
        px = jnp.einsum("gkn,gk->gn", rows, wx)  # (Gx, n_v)
        return jnp.einsum("gvk,vk->gv", px[:, sv[:, None] + k], wv)

    def moment(self, var: str, order: int, t: float | None = None):
        """Raw moment ``E[var^order]`` at ``t`` (trapezoidal rule on the nodes)."""
        check_int("order", order, low=0)
        nodes = self.x if var == "x" else self.v
        m = self.nodal_marginal(var, t)
        return jnp.sum(self._weights(nodes) * m * nodes**order)

    def mass(self, t: float | None = None):
        """Total probability on the grid at ``t`` (1 up to rounding: densities are renormalised)."""
        return jnp.sum(self._weights(self.x) * self.nodal_marginal("x", t))

    def n_nonfinite(self):
        """Number of non-finite nodal densities per saved time; shape ``(S,)``."""
        return jnp.sum(~jnp.isfinite(self.density), axis=(1, 2))


def _stencil(g, nodes):
    """Cubic Lagrange stencils of points ``g`` on uniform ``nodes`` (zero weights outside the nodes)."""
    return lagrange((g - nodes[0]) / (nodes[1] - nodes[0]), nodes.shape[0], 4)
