"""The result of path integration: densities on a phase-space grid, with the same interface as ``Result``."""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import check_int, check_points, check_real, plain, pytree_dataclass, static_field
from .._scene import static_times
from .._stencils import catmull_rom, lagrange
from . import _density
from ._base import COORDINATES, AbstractResult
from ._samples import _pair


def _program(*static: str):
    """The method as one compiled program per value of its ``static`` arguments and per shapes and dtypes of the
    others (the result itself traced): a question compiles once, and the same question again, at another saved
    time, grid or bandwidth of the same shapes, compiles nothing. The public methods check their arguments and
    turn a saved time into its index before they call one."""
    return functools.partial(jax.jit, static_argnames=static)


@pytree_dataclass
class GridResult(AbstractResult):
    r"""Joint densities ``p(x_i, v_j, t)`` on a grid, from ``jdpim.solve(scene, jdpim.PathIntegration())``.

    The interface is shared with ``jdpim.Result`` (``jdpim.results.AbstractResult``): densities of the
    coordinates interpolate the grid density with the solver's own functions, or smooth it with the sampling
    methods' kernel when a ``bandwidth`` is given; functions of the state are kernel densities of the nodes
    weighted by their probabilities.

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
        has_barrier: whether ``x[0]`` is a barrier (kernel densities of ``"x"`` are then reflected there).
        coordinates: ``("x", "v")``.

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
    has_barrier: bool = static_field(default=False)
    coordinates: tuple = static_field(default=COORDINATES)
    method = "path_integration"

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))

    def joint(self, t: float | None = None):
        """Nodal joint density at ``t``, shape ``(n_x, n_v)``."""
        return self._joint_at(self._index(t))

    @_program()
    def _joint_at(self, index):
        return self.density[index]

    def _axis(self, var: str):
        """Nodes and quadrature weights of the coordinate ``var``."""
        if callable(self._coordinate(var)):
            raise ValueError(f"{var!r} must be a coordinate name {self.coordinates} here, not a function of the state")
        return (self.x, self.x_weights) if var == "x" else (self.v, self.v_weights)

    def _node_masses(self, index):
        """Probability of every node at saved time ``index`` (density times the quadrature weights), shape
        ``(n_x, n_v)``."""
        return self.density[index] * self.x_weights[:, None] * self.v_weights[None, :]

    def _node_values(self, var):
        """``var`` (a coordinate or a function of the state) on every node, shape ``(n_x, n_v)``."""
        which = self._coordinate(var)
        xx, vv = jnp.meshgrid(self.x, self.v, indexing="ij")
        if not callable(which):
            return (xx, vv)[which]
        return jax.vmap(which)(jnp.stack([xx.ravel(), vv.ravel()], axis=-1)).reshape(xx.shape)

    def bounds(self, var):
        """``(lower, upper)`` of ``var``: the barrier ``x[0]`` below ``"x"`` where there is one, else ``None``. The
        grid's open edges bound no quantity (what reaches them is lost: ``edge_mass``)."""
        self._coordinate(var)
        return (self.x[0] if var == "x" and self.has_barrier else None), None

    def _limits(self, var, bounds):
        """``bounds`` checked, as the kernel's ``(lower, upper)``; ``None`` (``var`` checked) for :meth:`bounds`, which
        the compiled question takes (:meth:`_kernel_limits`)."""
        self._coordinate(var)
        return None if bounds is None else _density.limits(None, bounds)

    def _kernel_limits(self, var, lim):
        """The kernel's ``(lower, upper)`` for ``var``: ``lim`` from :meth:`_limits`, or :meth:`bounds`."""
        return self.bounds(var) if lim is None else lim

    def atoms(self, var, t: float | None = None, *, bounds=None):
        """Probability held at the bounds of ``var`` at ``t``: ``[0, 0]``, a grid density holds no point mass."""
        self._index(t)
        self._limits(var, bounds)
        return jnp.zeros(2, self.density.dtype)

    def nodal_marginal(self, var: str, t: float | None = None):
        """Marginal density of ``var`` on its grid nodes (the solver's quadrature over the other variable)."""
        self._axis(var)
        return self._marginal(var, self._index(t))

    @_program("var")
    def _marginal(self, var: str, index):
        p = self.density[index]
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

    def pdf(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        """Marginal PDF of ``var`` at ``t`` on ``grid`` (a scalar or 1-D, one point or more); shaped like ``grid``.

        Args:
            var: a coordinate name (``"x"``, ``"v"``) or a function of the state.
            grid: evaluation points, strictly increasing.
            t: a saved time, s (may be left out for a stationary density or a single saved time).
            bandwidth: ``None``: a coordinate's density is interpolated between the nodes with the solver's
                functions (no smoothing). A number (> 0): the grid density smoothed with the Gaussian kernel
                of that standard deviation, the density the sampling methods estimate at that bandwidth.
            rule: for a function of the state without ``bandwidth``: the bandwidth rule applied to the nodes
                weighted by their probabilities (see ``jdpim.bandwidth``).
            bounds: ``(a, b)``, the range of ``var`` at whose ends kernels are reflected (``None``: :meth:`bounds`,
                the barrier for ``"x"``); for kernel densities (a ``bandwidth``, or a function of the state).
        """
        return self._pdf_at(var, self._index(t), *self._pdf_arguments(var, grid, bandwidth, rule, bounds))

    def _pdf_arguments(self, var, grid, bandwidth, rule, bounds):
        """The checked ``(grid, bandwidth, rule, lim)`` of :meth:`pdf` for :meth:`_pdf_at`."""
        check_points("grid", grid)
        _check_rule(rule)
        lim = self._limits(var, bounds)
        if bandwidth is not None:
            bandwidth = _checked(bandwidth)
        elif not callable(self._coordinate(var)):
            _interpolated(var, bounds)
        return _density.program_input(grid), bandwidth, rule, lim

    @_program("var", "rule")
    def _pdf_at(self, var, index, grid, bandwidth, rule: str, lim):
        """:meth:`pdf` at saved time ``index`` (checked arguments)."""
        lim = self._kernel_limits(var, lim)
        if callable(self._coordinate(var)):
            y, w = self._node_values(var).ravel(), self._node_masses(index).ravel()
            sigma = _density.bandwidth(y, w, rule, dim=1) if bandwidth is None else bandwidth
            return _density.kde(y, w, jnp.asarray(grid, y.dtype), sigma, bounds=lim)
        if bandwidth is not None:
            nodes, weights = self._axis(var)
            g = jnp.atleast_1d(jnp.asarray(grid, nodes.dtype))
            k = _density.kernel_matrix(g, nodes, bandwidth, *lim)
            return jnp.reshape(k @ (weights * self._marginal(var, index)), jnp.shape(grid))
        out = self._interpolate(self._marginal(var, index), var, grid)
        return jnp.reshape(out, jnp.shape(grid))

    def joint_pdf(self, vars, grids, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        """Joint PDF of ``vars`` at ``t``; shape ``(len(grids[0]), len(grids[1]))`` (a scalar grid drops its axis).

        The coordinates ``("x", "v")`` (or ``("v", "x")``) are interpolated without ``bandwidth``, or smoothed with
        the pair of kernel standard deviations ``bandwidth`` (as in :meth:`pdf`). A pair with a function of the
        state is the product-kernel density of the nodes weighted by their probabilities (``bandwidth`` ``None``:
        ``rule`` with the 2-D exponent). ``bounds``: a pair of ranges, each ``(a, b)`` or ``None`` (that quantity's
        :meth:`bounds`), for kernel densities.
        """
        (va, vb), (ga, gb) = _pair("vars", vars), _pair("grids", grids)
        for name, g in (("grids[0]", ga), ("grids[1]", gb)):
            check_points(name, g)
        _check_rule(rule)
        ba, bb = (None, None) if bounds is None else _pair("bounds", bounds)
        lims = self._limits(va, ba), self._limits(vb, bb)
        if bandwidth is not None:
            if np.ndim(bandwidth) != 1 or len(bandwidth) != 2:
                raise ValueError(f"bandwidth must be None or a pair (sigma_1, sigma_2), got {plain(bandwidth)!r}")
            bandwidth = tuple(_checked(h) for h in bandwidth)
        if not (callable(self._coordinate(va)) or callable(self._coordinate(vb))):
            if sorted((va, vb)) != ["v", "x"]:
                raise ValueError(
                    f"vars of a grid result's joint density must be ('x', 'v'), ('v', 'x') or hold a function of the "
                    f"state, got {vars!r}"
                )
            if bandwidth is None:
                _interpolated(vars, bounds)
        grids = _density.program_input(ga), _density.program_input(gb)
        return self._joint_pdf_at((va, vb), self._index(t), grids, bandwidth, rule, lims)

    @_program("vars", "rule")
    def _joint_pdf_at(self, vars, index, grids, bandwidth, rule: str, lims):
        """:meth:`joint_pdf` at saved time ``index`` (checked arguments; ``bandwidth`` ``None`` or a pair)."""
        (va, vb), (ga, gb) = vars, grids
        lim_a, lim_b = (self._kernel_limits(var, lim) for var, lim in zip(vars, lims, strict=True))
        if callable(self._coordinate(va)) or callable(self._coordinate(vb)):
            w = self._node_masses(index).ravel()
            a, b = self._node_values(va).ravel(), self._node_values(vb).ravel()
            if bandwidth is None:
                sa, sb = _density.bandwidth(a, w, rule, dim=2), _density.bandwidth(b, w, rule, dim=2)
            else:
                sa, sb = bandwidth
            ga, gb = jnp.asarray(ga, a.dtype), jnp.asarray(gb, a.dtype)
            return _density.kde_2d(a, b, w, ga, gb, sa, sb, x_bounds=lim_a, v_bounds=lim_b)
        if va == "v":
            swapped = None if bandwidth is None else bandwidth[::-1]
            out = self._joint_pdf_at(("x", "v"), index, (gb, ga), swapped, rule, lims[::-1])
            return jnp.swapaxes(out, 0, -1) if jnp.ndim(out) == 2 else out
        if bandwidth is not None:
            dtype = self.x.dtype
            kx = _density.kernel_matrix(jnp.atleast_1d(jnp.asarray(ga, dtype)), self.x, bandwidth[0], *lim_a)
            kv = _density.kernel_matrix(jnp.atleast_1d(jnp.asarray(gb, dtype)), self.v, bandwidth[1], *lim_b)
            out = kx @ self._node_masses(index) @ kv.T
        else:
            px = self._interpolate(self.density[index], "x", ga)  # (Gx, n_v)
            out = self._interpolate(px.T, "v", gb).T  # (Gx, Gv)
        return jnp.reshape(out, jnp.shape(ga) + jnp.shape(gb))

    def moment(self, var, order: int, t: float | None = None):
        """Raw moment ``E[var^order]`` at ``t`` (the solver's quadrature on the nodes)."""
        check_int("order", order, low=0)
        if not callable(self._coordinate(var)):
            self._axis(var)
        return self._moment_at(var, order, self._index(t))

    @_program("var", "order")
    def _moment_at(self, var, order: int, index):
        if callable(self._coordinate(var)):
            return jnp.sum(self._node_masses(index) * self._node_values(var) ** order)
        nodes, weights = self._axis(var)
        return jnp.sum(weights * self._marginal(var, index) * nodes**order)

    def mass(self, t: float | None = None):
        """Total probability on the grid at ``t`` (1 up to rounding: densities are renormalised)."""
        return self._mass_at(self._index(t))

    @_program()
    def _mass_at(self, index):
        return jnp.sum(self.x_weights * self._marginal("x", index))

    @_program()
    def n_nonfinite(self):
        """Number of non-finite values among the result's carriers of probability (here grid nodes) per saved
        time; shape ``(S,)``. Path integration renormalises every step, so one non-finite node spoils the step."""
        return jnp.sum(~jnp.isfinite(self.density), axis=(1, 2))

    def _coarse(self) -> GridResult:
        if self.coarse is None:
            raise ValueError(
                "this result carries no error estimate: solve with jdpim.PathIntegration(estimate_error=True)"
            )
        return self.coarse

    def pdf_error(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        """Estimated discretisation error of :meth:`pdf` (same arguments): ``|pdf - pdf on the coarse grid|`` at the
        same bandwidth, shaped like ``grid``; it takes the place of a standard error (path integration has no
        sampling error). Needs ``jdpim.PathIntegration(estimate_error=True)``.

        For a scheme that converges at first order or faster in the spacings and the step, this bounds the
        error of the fine grid (asymptotically); ``docs/path_integration.md`` measures how far it covers it.
        """
        self._coarse()
        return self._pdf_error_at(var, self._index(t), *self._pdf_arguments(var, grid, bandwidth, rule, bounds))

    @_program("var", "rule")
    def _pdf_error_at(self, var, index, grid, bandwidth, rule: str, lim):
        if bandwidth is None and callable(self._coordinate(var)):
            w = self._node_masses(index).ravel()
            bandwidth = _density.bandwidth(self._node_values(var).ravel(), w, rule, dim=1)
        fine = self._pdf_at(var, index, grid, bandwidth, rule, lim)
        return jnp.abs(fine - self.coarse._pdf_at(var, index, grid, bandwidth, rule, lim))

    def l1_error(self, var: str, t: float | None = None):
        """Estimated L1 error of the marginal of ``var``: ``int |p - p_coarse|`` over the fine grid's nodes."""
        self._axis(var)
        self._coarse()
        return self._l1_error_at(var, self._index(t))

    @_program("var")
    def _l1_error_at(self, var: str, index):
        nodes, weights = self._axis(var)
        coarse = self.coarse._pdf_at(var, index, nodes, None, "chen", None)
        return jnp.sum(weights * jnp.abs(self._marginal(var, index) - coarse))


def _check_rule(rule):
    if rule not in _density.RULES:
        raise ValueError(f"rule must be one of {_density.RULES}, got {rule!r}")


def _interpolated(var, bounds):
    """Refuse ``bounds`` for an interpolated density (no kernel to reflect)."""
    if bounds is not None:
        raise ValueError(
            f"bounds={plain(bounds)!r} for the interpolated grid density of {var!r}: bounds apply to kernel densities; "
            "give a bandwidth (or leave bounds out: the grid density is zero below the barrier)"
        )


def _checked(bandwidth):
    check_real("bandwidth", bandwidth, low=0.0, low_open=True)
    return bandwidth
