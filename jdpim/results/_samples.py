"""The result of a sampling method (DPIM or Monte Carlo): weighted states at the saved times, and their densities."""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import check_grid, check_int, check_points, check_real, concrete, plain, pytree_dataclass, static_field
from .._scene import static_times
from .._tangents import PROJECTIONS, projections, watch, watch_forward
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
class Planes:
    """The unilateral constraints ``n_j . q >= b_j`` a result's quantities are bounded by.

    Attributes:
        normals: the normals ``n_j``, a tuple of ``J`` tuples of floats, one per position coordinate (static).
        positions: the offsets ``b_j``, shape ``(J,)`` (a leaf: traced, batched by ``jax.vmap``).
    """

    normals: tuple = static_field(default=())
    positions: Any = None


def model_constraints(model) -> Planes | None:
    """The constraints of ``model`` (``model.stacked_constraints()``: those of a ``jdpim.MDOFOscillator``, or the
    barrier of one degree of freedom as the normal ``(1,)``) as :class:`Planes`; ``None`` for none."""
    stacked = model.stacked_constraints()
    if stacked is None:
        return None
    return Planes(tuple(tuple(float(a) for a in n) for n in np.asarray(stacked.normal)), stacked.position)


_PROBES = (0.0, 0.375, -0.8125)  # states (scaled by 1, 2, ... per entry) at which a function is tested for linearity


def position_coefficients(var, coordinates: tuple, dtype) -> tuple[np.ndarray, float] | None:
    """``(c, f0)`` with ``var(state) = c . q + f0`` (``q``: the positions, the first half of the state) where
    ``var`` is a coordinate of ``q`` or a function of the state that is affine in ``q`` alone, else ``None``.

    A function is evaluated (eagerly, also under ``jax.jit``) at three fixed probe states and differentiated at
    the first; it is affine when its values there match its linearisation to rounding.
    """
    n, d = len(coordinates), len(coordinates) // 2
    if isinstance(var, str):
        i = coordinates.index(var)
        return (np.eye(d)[i], 0.0) if i < d else None
    with jax.ensure_compile_time_eval():
        ramp = np.arange(1.0, n + 1.0) * np.where(np.arange(n) % 2, -1.0, 1.0)
        probes = [jax.device_put(np.asarray(a * ramp, dtype)) for a in _PROBES]  # no compiled cast
        grad = concrete(jax.grad(lambda s: jnp.asarray(var(s), dtype))(probes[0]))
        values = [concrete(var(p)) for p in probes]
    if grad is None or any(v is None or v.shape != () for v in values) or np.any(grad[d:] != 0):
        return None
    tol = 64 * np.finfo(dtype).eps * (1.0 + np.abs(grad) @ np.abs(np.asarray(probes[-1])) + abs(float(values[0])))
    if any(abs(float(v) - float(values[0]) - grad @ np.asarray(p)) > tol for v, p in zip(values, probes, strict=True)):
        return None
    return grad[:d].astype(np.float64), float(values[0])


def constraint_bounds(planes: Planes, coefficients: np.ndarray, offset: float = 0.0) -> tuple:
    """``(lower, upper)`` of ``c . q + offset`` implied by the constraints ``n_j . q >= b_j`` whose normals are
    parallel to ``c`` (``None`` for a side without one; the tightest where several bound one side)."""
    lower = upper = None
    for j, normal in enumerate(planes.normals):
        n = np.asarray(normal, np.float64)
        k = float(coefficients @ n / (n @ n))
        if k == 0 or np.max(np.abs(coefficients - k * n)) > 1e-12 * np.max(np.abs(coefficients)):
            continue
        value = _affine(planes.positions, j, k, offset)
        if k > 0:
            lower = value if lower is None else jnp.maximum(lower, value)
        else:
            upper = value if upper is None else jnp.minimum(upper, value)
    return lower, upper


@jax.jit
def _affine(positions, j, k, offset):
    """``k * positions[j] + offset``: a constraint's bound on a quantity, one compiled program for every one."""
    return k * positions[j] + offset


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
            Used where ``constraints`` is empty.
        method: the name of the method that made it, ``"dpim"`` or ``"monte_carlo"`` (a label).
        coordinates: names of the state's entries, ``("x", "v")`` for one degree of freedom.
        constraints: the model's unilateral constraints as :class:`Planes` (the barrier of one degree of freedom
            as the normal ``(1,)``), or ``None``: they bound coordinates and derived quantities (see
            :meth:`bounds`), whose densities are reflected at both ends, with the probability held at a bound
            reported by :meth:`atoms`.
        independent: whether the paths are independent samples (Monte Carlo), so that estimates from them have
            sampling standard errors (:meth:`pdf_error`, ``jdpim.response_moments``); set by the method that
            made the result (its class attribute ``independent``). DPIM points are chosen together: ``False``.

    Results are pytrees (leaves: ``states``, ``weights``, ``barrier``, the constraints' positions and
    restitutions): they pass through ``jax.jit`` and ``jax.vmap`` as arguments and outputs. The interface is
    shared with ``jdpim.GridResult`` (``jdpim.results.AbstractResult``).
    """

    times: tuple = static_field()
    states: Any = None
    weights: Any = None
    barrier: Any = None
    method: str = static_field(default="dpim")
    coordinates: tuple = static_field(default=COORDINATES)
    constraints: Planes | None = None
    independent: bool = static_field(default=False)

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))
        object.__setattr__(self, "coordinates", tuple(self.coordinates))

    @property
    def n_paths(self) -> int:
        return int(np.shape(self.weights)[0])

    def samples(self, var, t: float | None = None):
        """The values of ``var`` (a coordinate name or a function of the state) of every path at ``t``; ``(N,)``."""
        which, index = self._coordinate(var), self._index(t)
        if callable(which):
            return jax.vmap(which)(_state_and_motion(self.states, index)[0])
        return _entry(self.states, index, which)

    def bounds(self, var):
        """``(lower, upper)``: the range of ``var`` the model's constraints imply (``None`` for a side without one).

        A coordinate, or a function of the state affine in the positions (e.g. the relative displacement
        ``lambda s: s[1] - s[0]`` of ``jdpim.impact_damper()``: ``(-c, c)``), is bounded by each constraint
        ``n . q >= b`` whose normal is parallel to its coefficients (see :func:`position_coefficients`); other
        quantities (velocities, nonlinear functions) have no known bounds: give ``bounds=`` to :meth:`pdf`.
        """
        if self.constraints is None:
            return reflection(self.barrier, var), None
        found = position_coefficients(var, self.coordinates, self.states.dtype)
        return (None, None) if found is None else constraint_bounds(self.constraints, *found)

    def _limits(self, var, t, bounds):
        """The kernel's ``(lower, upper)`` for ``var``: ``bounds`` (checked against the samples where concrete)
        or :meth:`bounds`."""
        if bounds is None:
            return self.bounds(var)
        lim = _density.limits(None, bounds)
        y, held = concrete(self.samples(var, t)), [concrete(b) for b in lim]
        if y is not None:
            y = y[np.isfinite(y)]
            tol = 64 * np.finfo(y.dtype).eps * np.max(np.abs(y), initial=1.0)
            out = np.sum(y < held[0] - tol) if held[0] is not None else 0
            out += np.sum(y > held[1] + tol) if held[1] is not None else 0
            if out:
                name = var if isinstance(var, str) else "the function"
                raise ValueError(
                    f"bounds={plain(bounds)!r} do not hold: {int(out)} of {y.size} samples of {name} lie outside"
                )
        return lim

    def _held(self, var, t, lower, upper):
        """``(N,)`` bools per bound: paths held at ``lower`` and at ``upper`` at ``t`` (``None`` where no bound).

        Held: the value on the bound and its rate of change along the motion (``d var / dq . v``) zero, both to
        rounding (``16 eps`` times the path's largest position or velocity): a path resting on a constraint,
        not one passing through it.
        """
        which, index = self._coordinate(var), self._index(t)
        if not callable(which):
            return _held_entry(self.states, index, which, lower, upper)
        at, tangent, q, v = _state_and_motion(self.states, index)
        rate = jax.vmap(lambda s, ds: jax.jvp(which, (s,), (ds,))[1])(at, tangent)
        return _held_at(self.samples(var, t), rate, q, v, lower, upper)

    def _continuous(self, var, t, lower, upper, weights=None):
        """``weights`` (default: the paths') with the paths held at a bound of ``var`` set to zero."""
        weights = self.weights if weights is None else weights
        if _unbounded((lower, upper)):
            return weights
        which = self._coordinate(var)
        if callable(which):
            return _without(weights, self._held(var, t, lower, upper))
        return _continuous_entry(self.states, weights, self._index(t), which, lower, upper)

    def atoms(self, var, t: float | None = None, *, bounds=None):
        """Probability held at the bounds of ``var`` at ``t``: ``[at lower, at upper]``, shape ``(2,)``.

        Paths resting on a constraint (sticking; a damper mass held against a wall) put a point mass at a bound
        of the quantity the constraint bounds. :meth:`pdf` leaves it out and reports it here: the density
        integrates to ``mass(t) - sum(atoms(var, t))``. ``bounds``: as in :meth:`pdf` (default
        :meth:`bounds`); a side without a bound holds 0. Works under ``jax.jit``.
        """
        lim = self._limits(var, t, bounds)
        return _held_mass(self.samples(var, t), self.weights, self._held(var, t, *lim))

    def n_nonfinite(self):
        """Number of paths with a non-finite state, per saved time; shape ``(S,)``."""
        return nonfinite_counts(self.states)

    def lost_mass(self):
        """Probability carried by paths with non-finite states, per saved time; shape ``(S,)``.

        Densities leave this mass out (they integrate to ``1 - lost_mass``).
        """
        return _lost_mass(self.states, self.weights)

    def mass(self, t: float | None = None):
        """Probability carried by the paths with finite states at saved time ``t`` (``1 - lost_mass``)."""
        return _mass(self.states, self.weights, self._index(t))

    def bandwidth(self, var, t: float | None = None, rule: str = "chen", *, dim: int = 1, c: float | None = None):
        """The rule-based kernel standard deviation for ``var`` at time ``t`` (see ``jdpim.bandwidth``), of the
        paths not held at a bound of ``var`` (:meth:`atoms`): the one :meth:`pdf` uses."""
        w = self._continuous(var, t, *self.bounds(var))
        return _density.bandwidth(self.samples(var, t), w, rule, dim=dim, c=c)

    def pdf(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        r"""Marginal PDF of ``var`` at saved time ``t`` on ``grid``.

        ``p(y) = sum_q P_q K(y; y_q)``: Gaussian kernels of standard deviation ``sigma``, reflected at the bounds
        of ``var`` (both ends of an interval, with the images of images where ``sigma`` is comparable to its
        width; ``jdpim.kde``), zero outside them. Paths held at a bound (:meth:`atoms`) are left out: their
        probability is a point mass there, not a density, and ``pdf`` integrates to
        ``mass(t) - sum(atoms(var, t))``.

        Args:
            var: a coordinate name (``"x"``: displacement, ``"v"``: velocity) or a function of the state.
            grid: evaluation points: a scalar or 1-D (one point or more), strictly increasing.
            t: a saved time, s (may be left out when the result holds one).
            bandwidth: kernel standard deviation (> 0), or ``None`` to use ``rule``.
            rule: bandwidth rule, one of ``"chen"``, ``"silverman"``, ``"scott"``.
            bounds: ``(a, b)``, the range of ``var`` (either side ``None`` for no bound), or ``None`` for the
                range the model's constraints imply (:meth:`bounds`: the barrier of ``"x"``, a coordinate or a
                function affine in the positions that a constraint bounds, e.g. a relative displacement within a
                clearance). Given bounds are checked against the samples (outside them: ``ValueError``).

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
        lim = self._limits(var, t, bounds)
        y, w = self.samples(var, t), self._continuous(var, t, *lim)
        sigma = self._sigma(bandwidth, lambda: _density.bandwidth(y, w, rule, dim=1))
        grid = _density.program_input(grid)
        y = watch_forward(y, jax.tree_util.Partial(_kernel_contributions, w, grid, sigma, lim))
        return _density.kde(y, w, grid, sigma, bounds=lim)

    def pdf_error(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        r"""Sampling standard error of :meth:`pdf` (same arguments): Monte Carlo results only.

        From the per-path kernel contributions ``K_q(y)``: ``se(y)^2 = sum_q K_q(y)^2 / n^2 - p(y)^2 / n``
        up to the factor ``n / (n - 1)`` (see ``jdpim.kde_stderr``), at the same bandwidth as ``pdf``.
        DPIM points are not independent samples: their error comes from randomised point sets
        (``jdpim.dpim_replicates``).
        """
        if not self.independent:
            raise ValueError(
                f"pdf_error of a sampling result needs independent samples (Result.independent, Monte Carlo), got "
                f"method {self.method!r}; for DPIM use jdpim.dpim_replicates"
            )
        check_points("grid", grid)
        lim = self._limits(var, t, bounds)
        y, w = self.samples(var, t), self._continuous(var, t, *lim)
        sigma = self._sigma(bandwidth, lambda: _density.bandwidth(y, w, rule, dim=1))
        return _density.kde_stderr(y, w, grid, sigma, bounds=lim)

    def joint_pdf(self, vars, grids, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        """Joint PDF of two quantities at saved time ``t``; shape ``(len(grids[0]), len(grids[1]))``.

        Each kernel factor is reflected at the bounds of its quantity, and paths held at a bound of either
        quantity (:meth:`atoms`) are left out, as in :meth:`pdf`.

        Args:
            vars: a pair of coordinate names or functions of the state, e.g. ``("x", "v")``.
            grids: a pair of grids (each a scalar or 1-D; a scalar grid drops its axis).
            t: a saved time, s (may be left out when the result holds one).
            bandwidth: ``None`` (rule-based, 2-D exponent) or a pair ``(sigma_1, sigma_2)``.
            rule: bandwidth rule for ``None``.
            bounds: ``None`` (each quantity's :meth:`bounds`) or a pair of ranges, each ``(a, b)`` or ``None``
                (that quantity's :meth:`bounds`), as ``bounds`` of :meth:`pdf`.
        """
        (va, vb), (ga, gb) = _pair("vars", vars), _pair("grids", grids)
        for name, g in (("grids[0]", ga), ("grids[1]", gb)):
            check_points(name, g)
        ba, bb = (None, None) if bounds is None else _pair("bounds", bounds)
        lim_a, lim_b = self._limits(va, t, ba), self._limits(vb, t, bb)
        a, b = self.samples(va, t), self.samples(vb, t)
        w = self._continuous(vb, t, *lim_b, self._continuous(va, t, *lim_a))
        if bandwidth is None:
            sa = _density.bandwidth(a, w, rule, dim=2)
            sb = _density.bandwidth(b, w, rule, dim=2)
        else:
            if np.ndim(bandwidth) != 1 or len(bandwidth) != 2:
                raise ValueError(f"bandwidth must be None or a pair (sigma_1, sigma_2), got {plain(bandwidth)!r}")
            sa, sb = (self._sigma(s, None) for s in bandwidth)
        ga, gb = _density.program_input(ga), _density.program_input(gb)
        a, b = watch_forward((a, b), jax.tree_util.Partial(_joint_contributions, w, (ga, gb), (sa, sb), (lim_a, lim_b)))
        if _unbounded(lim_a) and not _unbounded(lim_b):  # the bounded quantity goes first
            return _density.kde_2d(b, a, w, gb, ga, sb, sa, x_bounds=lim_b).T
        return _density.kde_2d(a, b, w, ga, gb, sa, sb, x_bounds=lim_a, v_bounds=lim_b)

    def histogram(self, var, edges, t: float | None = None):
        """Weighted histogram density of ``var`` at time ``t`` on bin ``edges``; shape ``(len(edges) - 1,)``."""
        check_grid("edges", edges)
        return _density.histogram(watch(self.samples(var, t), HISTOGRAM), self.weights, jnp.asarray(edges))

    def moment(self, var, order: int, t: float | None = None):
        """Weighted raw moment ``E[var^order]`` at time ``t`` over the paths with finite states."""
        return _moment(self.samples(var, t), self.weights, check_int("order", order, low=0))

    @staticmethod
    def _sigma(bandwidth, default):
        if bandwidth is None:
            return default()
        check_real("bandwidth", bandwidth, low=0.0, low_open=True)
        arr = concrete(bandwidth)
        return bandwidth if arr is None else _density.program_input(arr)


def _kernel_contributions(weights, grid, sigma, lim, y, y_dot):
    """Per-path contributions ``(N, G)`` to the forward-mode derivative of :meth:`Result.pdf`."""
    ok = jnp.isfinite(y)
    y = jnp.where(ok, y, 0.0)
    dk = jax.jvp(lambda s: _density.kernel_matrix(jnp.atleast_1d(grid), s, sigma, *lim), (y,), (y_dot,))[1]
    return jnp.where(ok[:, None], (weights[None, :] * dk).T, 0.0)


def _joint_contributions(weights, grids, sigmas, lims, y, y_dot):
    """Per-path contributions to the forward-mode derivative of :meth:`Result.joint_pdf`: ``(N, Ga Gb)``, or
    their ``(N, PROJECTIONS)`` projections (``jdpim._tangents.projections``) on more than ``PROJECTIONS`` nodes,
    formed without the ``(N, Ga, Gb)`` array."""
    ok = jnp.isfinite(y[0]) & jnp.isfinite(y[1])

    def kernel(i):  # (G_i, N) kernel matrix of quantity i and its tangent
        g, h, lim = jnp.atleast_1d(grids[i]), sigmas[i], lims[i]
        return jax.jvp(lambda s: _density.kernel_matrix(g, s, h, *lim), (jnp.where(ok, y[i], 0.0),), (y_dot[i],))

    (ka, dka), (kb, dkb) = kernel(0), kernel(1)
    ga, gb = ka.shape[0], kb.shape[0]
    if ga * gb <= PROJECTIONS:
        c = (jnp.einsum("an,bn->nab", dka, kb) + jnp.einsum("an,bn->nab", ka, dkb)).reshape(-1, ga * gb)
    else:
        r = jnp.asarray(projections(ga * gb).reshape(ga, gb, PROJECTIONS), ka.dtype)
        c = jnp.einsum("an,abk,bn->nk", dka, r, kb) + jnp.einsum("an,abk,bn->nk", ka, r, dkb)
    return jnp.where(ok[:, None], weights[:, None] * c, 0.0)


@functools.partial(jax.jit, static_argnums=2)
def _moment(y, weights, order: int):
    """``E[y^order]`` over the finite values of ``y`` ``(N,)`` with ``weights`` ``(N,)``: one compiled program."""
    ok = jnp.isfinite(y)
    w = jnp.where(ok, weights, 0.0)
    y = watch_forward(y, jax.tree_util.Partial(_moment_contributions, w, order))
    return jnp.sum(w * jnp.where(ok, y, 0.0) ** order) / jnp.sum(w)


def _moment_contributions(weights, order, y, y_dot):
    """Per-path contributions ``(N,)`` to the forward-mode derivative of :meth:`Result.moment`."""
    ok = jnp.isfinite(y)
    return jnp.where(ok, weights * order * jnp.where(ok, y, 0.0) ** (order - 1) * y_dot, 0.0)


def _unbounded(lim) -> bool:
    """Whether a kernel's ``(lower, upper)`` has no bound on either side."""
    return lim[0] is None and lim[1] is None


def _pair(name: str, value) -> tuple:
    """``value`` as a pair (``vars`` or ``grids`` of a joint density), with a clear error otherwise."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ValueError(f"{name} must be a pair, e.g. ('x', 'v') and (x_grid, v_grid), got {plain(value)!r}")
    return tuple(value)


@jax.jit
def nonfinite_counts(states):
    """``(S,)``: the number of paths of ``states`` ``(N, S, n_state)`` with a non-finite state at each saved time."""
    return jnp.sum(~jnp.all(jnp.isfinite(states), axis=-1), axis=0)


@jax.jit
def _lost_mass(states, weights):
    bad = ~jnp.all(jnp.isfinite(states), axis=-1)
    return jnp.sum(jnp.where(bad, weights[:, None], 0.0), axis=0)


@jax.jit
def _held_mass(y, weights, held):
    """``(2,)``: the probability of the paths with a finite value ``y`` ``(N,)`` held at each bound (``held``: per
    bound ``(N,)`` bools, or ``None`` for no bound: 0); one compiled program."""
    ok = jnp.isfinite(y)
    w = jnp.where(ok, weights, 0.0)
    return jnp.stack([jnp.zeros((), w.dtype) if h is None else jnp.sum(jnp.where(h & ok, w, 0.0)) for h in held])


@jax.jit
def _mass(states, weights, index):
    """``1 - lost_mass()[index]``: one compiled program."""
    return 1.0 - _lost_mass(states, weights)[index]


@jax.jit
def _state_and_motion(states, index):
    """``(state, motion, q, v)``: every path's state ``(q, v)`` at saved time ``index`` and its rate along the
    positions ``(v, 0)``, ``(N, n_state)`` each, and its halves ``(N, n)``: one compiled program (a function of the
    state is evaluated on them outside it)."""
    at = states[:, index]
    d = at.shape[-1] // 2
    q, v = at[:, :d], at[:, d:]
    return at, jnp.concatenate([v, jnp.zeros_like(v)], axis=-1), q, v


@functools.partial(jax.jit, static_argnums=2)
def _entry(states, index, which: int):
    """``(N,)``: entry ``which`` of every path's state in ``states`` ``(N, S, n_state)`` at saved time ``index``."""
    return states[:, index, which]


@functools.partial(jax.jit, static_argnums=2)
def _held_entry(states, index, which: int, lower, upper):
    """:func:`_held_at` of the state's entry ``which`` (its rate: the matching velocity for a position, zero for a
    velocity) at saved time ``index``: one compiled program."""
    at = states[:, index]
    d = at.shape[-1] // 2
    rate = at[:, which + d] if which < d else jnp.zeros(at.shape[0], at.dtype)
    return _held_at(at[:, which], rate, at[:, :d], at[:, d:], lower, upper)


@functools.partial(jax.jit, static_argnums=3)
def _continuous_entry(states, weights, index, which: int, lower, upper):
    """``weights`` with the paths held at a bound of the state's entry ``which`` (:func:`_held_entry`) set to zero:
    one compiled program."""
    return _without(weights, _held_entry(states, index, which, lower, upper))


@jax.jit
def _without(weights, held):
    """``weights`` ``(N,)`` set to zero where any of ``held`` (a tuple of ``(N,)`` bools or ``None``) is true."""
    for h in held:
        if h is not None:
            weights = jnp.where(h, 0.0, weights)
    return weights


@jax.jit
def _held_at(y, rate, q, v, lower, upper):
    """Per bound (``None`` where there is none): whether each path's value ``y`` ``(N,)`` lies on it and its rate
    ``(N,)`` is zero, both to ``16 eps`` times the path's largest position ``q`` or velocity ``v`` ``(N, n)``."""
    eps = 16 * jnp.finfo(q.dtype).eps
    still = jnp.abs(rate) <= eps * jnp.max(jnp.abs(v), axis=-1)
    scale = jnp.max(jnp.abs(q), axis=-1)
    return tuple(None if b is None else still & (jnp.abs(y - b) <= eps * (jnp.abs(b) + scale)) for b in (lower, upper))
