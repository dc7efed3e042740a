r"""Sensitivities ``dp(y, t) / d theta`` of response PDFs at any horizon: path integration, DPIM or Monte Carlo.

Path integration (``method=jdpim.PathIntegration()``, what ``method=None`` picks for the one-degree-of-freedom scenes
it accepts) differentiates ``jdpim.path_integration`` with ``jax.jacfwd`` (``sensitivities._path_integration``): no
sampling error. The sampling methods write

.. math::  \frac{\partial p(y, t)}{\partial \theta} \approx \sum_i w_i \, c_i(y)

with per-path contributions ``c_i`` from an estimator per parameter (``jdpim.sensitivities._estimators``; each
computes its own from the common paths of a :class:`PathContext`): a likelihood
ratio (Girsanov score) for drift parameters, the exact noise scaling for ``D``, central differences with
common random numbers for ``r``, or pathwise AD through the pipeline (exact for the computed density, but
only over short horizons when there are impacts; flagged where few paths carry it). ``estimator="auto"`` picks
the pathwise derivative for models without a barrier (it is exact and bounded there) and otherwise the bounded
estimators.
docs/gradients.md says which to use when.

Bandwidth: ``None`` uses the rule-based ``sigma`` at the nominal parameters, held fixed, so every estimator
targets the derivative of the same smoothed density ``p * K_sigma`` (path integration: no smoothing).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp

from .._io import Persistent
from .._models import AbstractOscillator
from .._pytree import check_real, concrete, real_array
from .._scene import Scene, parameter_names, parameter_value, with_parameters
from .._tangents import effective_paths, warn_if_unreliable
from ..methods._base import AbstractMethod
from ..methods._monte_carlo import MonteCarlo
from ..methods._path_integration import PathIntegration
from ..methods._paths import SamplingMethod, is_traced
from ..results._density import bandwidth as rule_bandwidth
from ..results._density import kernel_matrix
from ..results._samples import Result
from ..tracking import Sums
from ._estimators import (
    CentralDifference,
    LikelihoodRatio,
    NoiseScaling,
    Pathwise,
    Score,
    SensitivityWarning,
    check_likelihood_ratio,
    noise_scaling_applies,
    warn_if_noisy,
)
from ._path_integration import default_settings, grid_sensitivity, nominal_run
from ._scores import CHUNK, centred_scores, finite_weights, moments, score_windows
from ._several_dof import several_dof_sensitivity

VARIABLES = ("x", "v", "xv")
DEFAULT_PATHS = 100_000  # Monte Carlo paths of method=None where path integration does not apply: ~5 %
EXPLOSION = 1e3  # |theta dp/dtheta| / max p above which a pathwise result is flagged


def _nominal(scene: Scene, name: str):
    value = parameter_value(scene, name)
    if value is None:
        raise ValueError(f"parameter {name!r} is None (the term is left out); set it to a number to differentiate")
    return jnp.asarray(value, scene.float_dtype)


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True, eq=False)
class Sensitivity(Persistent, Mapping):
    """Derivatives ``name -> dp/dtheta`` on the grid (a read-only mapping), with standard errors.

    Attributes:
        value: ``{name: array}``, shaped like the PDF, in PDF units per parameter unit.
        value_stderr: ``{name: array}`` of the same shapes: the sampling error (NaN for ``Pathwise(mode="reverse")``,
            which does not estimate it; zero for path integration, which has none).
        estimators: ``{name: estimator}`` actually used (the ``PathIntegration`` settings for path integration).
        times: ``(t,)``, the time of the derivative, s (``inf`` for a stationary density).
        method: ``"path_integration"``, ``"dpim"`` or ``"monte_carlo"``.

    A pytree (leaves: the arrays of ``value`` and ``value_stderr``): it passes through ``jax.jit`` and ``jax.vmap``.
    """

    value: dict
    value_stderr: dict
    estimators: dict
    times: tuple
    method: str = "dpim"

    def tree_flatten(self):
        """Leaves: the arrays of ``value`` and ``value_stderr``; estimators, ``times`` and ``method``: structure."""
        return (self.value, self.value_stderr), (tuple(self.estimators.items()), self.times, self.method)

    @classmethod
    def tree_unflatten(cls, aux, children):
        estimators, times, method = aux
        return cls(*children, dict(estimators), times, method)

    def __getitem__(self, name):
        return self.value[name]

    def __iter__(self):
        return iter(self.value)

    def __len__(self):
        return len(self.value)


def _sigmas(res: Result, var: str, t, bandwidth, rule: str) -> list:
    """The kernel standard deviations of :func:`sensitivity`'s bandwidth policy (one per axis of ``var``)."""
    dim = 2 if var == "xv" else 1
    names = ("x", "v") if var == "xv" else (var,)
    if bandwidth is None or bandwidth == "adaptive":
        sig = [res.bandwidth(n, t, rule, dim=dim) for n in names]
        return [jax.lax.stop_gradient(s) for s in sig] if bandwidth is None else sig
    return list(bandwidth) if var == "xv" else [bandwidth]


def _density(res: Result, var: str, grid, t, bandwidth, rule: str):
    """The PDF of ``var`` on ``grid`` with the bandwidth policy of :func:`sensitivity`."""
    sig = _sigmas(res, var, t, bandwidth, rule)
    if var == "xv":
        return res.joint_pdf(("x", "v"), grid, t, bandwidth=tuple(sig))
    return res.pdf(var, grid, t, bandwidth=sig[0])


def _auto_estimator(scene: Scene, name: str):
    if not scene.model.has_barrier:
        return Pathwise()
    if name == "D":
        return NoiseScaling() if noise_scaling_applies(scene) is None else CentralDifference()
    try:
        check_likelihood_ratio(scene, name)
    except ValueError:
        return CentralDifference()
    return LikelihoodRatio()


def _estimators(scene: Scene, wrt, estimator) -> dict:
    kinds = (Pathwise, LikelihoodRatio, NoiseScaling, CentralDifference)
    out = {}
    for name in wrt:
        est = estimator.get(name, "auto") if isinstance(estimator, Mapping) else estimator
        if isinstance(est, str) and est == "auto":
            est = _auto_estimator(scene, name)
        if not isinstance(est, kinds):
            raise TypeError(
                f"estimator for {name!r} must be 'auto' or one of {[k.__name__ for k in kinds]}, got {est!r}"
            )
        est.check(scene, name)
        out[name] = est
    return out


def _kernel(var: str, grid, sigma, barrier):
    """Per-path kernels: ``(x, v)`` chunks ``(c,)`` -> ``(c, *grid_shape)``."""

    def kern(x, v):
        if var == "x":
            return kernel_matrix(grid, x, sigma, barrier).T
        if var == "v":
            return kernel_matrix(grid, v, sigma, None).T
        kx = kernel_matrix(grid[0], x, sigma[0], barrier).T
        kv = kernel_matrix(grid[1], v, sigma[1], None).T
        return kx[:, :, None] * kv[:, None, :]

    return kern


@dataclasses.dataclass(frozen=True)
class Query:
    """The checked arguments of :func:`sensitivity` that a method's ``sensitivity`` answers."""

    wrt: tuple
    values: dict  # nominal parameter values
    var: str
    grid: Any
    t: float
    bandwidth: Any
    rule: str
    estimator: Any


def sensitivity(
    scene: Scene,
    wrt: Sequence[str] = ("alpha", "gamma", "r"),
    var: str = "x",
    grid=None,
    t: float | None = None,
    *,
    method: AbstractMethod | None = None,
    bandwidth=None,
    rule: str = "chen",
    estimator="auto",
) -> Sensitivity:
    r"""Derivatives ``dp(y, t) / d theta`` of the PDF on a grid, with standard errors, for each name in ``wrt``.

    Args:
        scene: the scene; its parameter values are the point of differentiation.
        wrt: a parameter name or a sequence of them (see :func:`jdpim.parameter_names`: ``alpha``, ``gamma``,
            ``r``, ``barrier``, ``omega``, ``D`` for :class:`VibroImpactOscillator`; keys of a dict
            ``Oscillator.params``).
        var: ``"x"``, ``"v"`` (marginal PDFs) or ``"xv"`` (joint PDF). Several degrees of freedom
            (:class:`jdpim.MDOFOscillator`): a coordinate name (``"x1"``, ``"v2"``) or a function of the state;
            the estimator is then :class:`CentralDifference` (``estimator="auto"`` picks it) or, for drift
            parameters whose change of the acceleration lies along the single noise source's direction,
            :class:`LikelihoodRatio` (whole history unless given a ``window``), by Monte Carlo (default
            ``MonteCarlo(n_samples=DEFAULT_PATHS)``) or DPIM.
        grid: evaluation grid, 1-D for ``"x"``/``"v"``, a pair ``(x_grid, v_grid)`` for ``"xv"``. Keep
            ``x`` nodes off the barrier when differentiating with respect to ``barrier``.
        t: a saved time of the scene (default: the last one); leave it out for a stationary density.
        method: the method whose density is differentiated, as for ``jdpim.solve``:

            - ``jdpim.PathIntegration(...)``: ``jax.jacfwd`` through path integration (transient from the
              scene's start, or with ``stationary=True`` the stationary density, by implicit differentiation
              of its fixed point); no sampling error. The grid extents are those of the nominal parameters.
            - ``jdpim.DPIM(...)`` (weights ``P_q``) or ``jdpim.MonteCarlo(...)`` (weights ``1/N``): per-path
              estimators (``estimator``). DPIM's points are worth about as many Monte Carlo paths: at t = 200
              (r = 1, bandwidth 0.1) 1e5 give standard errors of about 2.5 % (drift parameters) and 6 % (D).
            - ``None`` (default): path integration where it accepts the scene (no random parameters,
              ``0 < r <= 1``, ``t`` its start ``t0`` plus whole steps ``tau``), with ``PathIntegration()`` or, for
              ``t < 10`` s, the finer, earlier start ``PathIntegration(t0=0.25, n_x=241, n_v=481, tau=0.025)``
              (about 4x dearer); else, or when a sampling ``estimator`` or ``bandwidth="adaptive"`` is asked
              for, ``MonteCarlo(n_samples=DEFAULT_PATHS)`` (1e5 paths: about 5 % at stationarity).
        bandwidth: ``None`` (sampling methods: the rule's value at the nominal parameters, held fixed; path
            integration: no smoothing, the derivative of the grid density interpolated to ``grid``),
            ``"adaptive"`` (pathwise only: the rule is differentiated too), or fixed kernel standard
            deviation(s) (a number, or a pair ``(sigma_x, sigma_v)`` for ``"xv"``): every method then
            differentiates the density smoothed with the same kernel (reflected at the barrier).
        rule: bandwidth rule for ``None``/``"adaptive"`` (see ``jdpim.bandwidth``).
        estimator: ``"auto"``, an estimator (:class:`Pathwise`, :class:`LikelihoodRatio`,
            :class:`NoiseScaling`, :class:`CentralDifference`) for every name, or a dict ``name -> estimator``
            (sampling methods only).

    Returns:
        :class:`Sensitivity`: ``name -> array`` shaped like the PDF (``(G,)`` or ``(Gx, Gv)``), with
        ``.value``, ``.value_stderr``, ``.estimators`` and ``.method``. Path integration has no sampling error:
        its ``value_stderr`` is zero and ``estimators`` holds the ``PathIntegration`` settings used (its grid
        error, measured in docs/gradients.md, is about 1e-3 relative at the defaults). A
        :class:`SensitivityWarning` flags pathwise results beyond their horizon, exploding or carried by few
        paths, results whose standard error exceeds a quarter of their size, non-finite path-integration
        derivatives, transient ones within ``10 t0`` of the start (its linearised start density shows there) and
        ``dp/dD`` on a velocity grid too coarse for one step's diffusion; path integration's own
        ``PathIntegrationWarning`` reports its nominal grid.

    Raises:
        TypeError: under a JAX transformation (``jit``, ``vmap``, ``grad``): the method is picked and the
            estimates checked on concrete values.

    Examples:
        >>> import jdpim, numpy as np
        >>> model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, barrier=None)  # cheap to compile
        >>> scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.05), t_end=2.0, dt=0.02)
        >>> grid = np.linspace(-1.0, 1.0, 9)
        >>> dp = jdpim.sensitivity(scene, ("alpha",), "v", grid, method=jdpim.MonteCarlo(n_samples=2000))
        >>> dp["alpha"].shape, type(dp.estimators["alpha"]).__name__, bool(np.all(dp.value_stderr["alpha"] > 0))
        ((9,), 'Pathwise', True)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if isinstance(jnp.zeros(()), jax.core.Tracer) or is_traced((scene, grid)):
        raise TypeError(
            "jdpim.sensitivity cannot run under a JAX transformation (jit, vmap, grad): it picks its method and "
            "checks its estimates on concrete values; call it outside, or transform jdpim.solve or "
            "jdpim.path_integration of jdpim.with_parameters(scene, ...) yourself"
        )
    several = not isinstance(scene.model, AbstractOscillator)
    if var not in VARIABLES and not several:
        raise ValueError(f"var must be one of {VARIABLES}, got {var!r}")
    if method is not None and not isinstance(method, AbstractMethod):
        raise TypeError(
            "method must be None or a jdpim method (jdpim.PathIntegration(), jdpim.DPIM(), jdpim.MonteCarlo()), "
            f"got {method!r}"
        )
    if isinstance(bandwidth, str) and bandwidth != "adaptive":
        raise ValueError(f"bandwidth must be None, 'adaptive' or a number, got {bandwidth!r}")
    if bandwidth is not None and not isinstance(bandwidth, str):
        check_real("bandwidth", bandwidth, low=0.0, low_open=True)
    wrt = (wrt,) if isinstance(wrt, str) else tuple(wrt)  # one name, as first_passage takes it
    if not wrt:
        raise ValueError("wrt must name at least one parameter")
    bad = sorted(set(wrt) - set(parameter_names(scene)))
    if bad:
        raise ValueError(f"unknown parameter(s) {bad}; choose from {list(parameter_names(scene))}")
    if grid is None:
        raise ValueError("grid is required")
    for axis in grid if var == "xv" and isinstance(grid, (tuple, list)) else (grid,):
        if isinstance(axis, (str, bytes)) or concrete(axis) is not None:
            real_array("grid", axis, "numbers: a 1-D array, or a pair of them for var='xv'")
    if getattr(method, "stationary", False):
        if t is not None:
            raise ValueError(f"t={t!r} with a stationary method: the stationary density has no time; leave t out")
        t = math.inf
    else:
        t = scene.save_at[-1] if t is None else t
        t = scene.save_at[scene.time_index(t)]
    if several:
        value, stderr, estimators, method = several_dof_sensitivity(
            scene, wrt, var, grid, t, method, bandwidth, rule, estimator
        )
        return Sensitivity(value, stderr, estimators, (float(t),), method.name)
    values = {name: _nominal(scene, name) for name in wrt}
    query = Query(wrt, values, var, grid, t, bandwidth, rule, estimator)
    if method is None:
        method, answer = _default_method(scene, query)
    else:
        answer = _answer(scene, method, query)
    value, stderr, estimators = answer
    return Sensitivity({n: value[n] for n in wrt}, {n: stderr[n] for n in wrt}, estimators, (float(t),), method.name)


def _default_method(scene: Scene, query: Query):
    """``(method, answer)`` of ``method=None``: path integration where it accepts the scene, else Monte Carlo."""
    sampling_only = not (isinstance(query.estimator, str) and query.estimator == "auto")
    if not (sampling_only or isinstance(query.bandwidth, str)):
        settings = default_settings(query.t, stationary=False)
        try:
            nominal = nominal_run(scene, settings, query.t)
        except (TypeError, ValueError):
            pass  # path integration refuses the scene (random parameters, r = 0, t off its steps)
        else:
            return settings, grid_sensitivity(scene, settings, query, nominal)
    method = MonteCarlo(n_samples=DEFAULT_PATHS)
    return method, sampled_sensitivity(scene, method, query)


def _answer(scene: Scene, method: AbstractMethod, query: Query):
    """``(value, stderr, estimators)`` of ``query`` through the primitive ``method`` offers: a sampling method's
    paths, or path integration's solver."""
    if isinstance(method, SamplingMethod):
        return sampled_sensitivity(scene, method, query)
    if isinstance(method, PathIntegration):
        return grid_sensitivity(scene, method, query)
    raise ValueError(f"{type(method).__name__} has no density derivatives; use jdpim.MonteCarlo or jdpim.DPIM")


def sampled_sensitivity(scene: Scene, method, query: Query):
    """``(value, stderr, estimators)`` from the paths of a sampling method (DPIM or Monte Carlo)."""
    wrt, bandwidth = query.wrt, query.bandwidth
    estimators = _estimators(scene, wrt, query.estimator)
    if bandwidth == "adaptive" and not all(e.joint for e in estimators.values()):
        raise ValueError("bandwidth='adaptive' needs the Pathwise estimator for every parameter")
    rows, weights, chunk = method.inputs(scene)
    value, stderr = {}, {}
    pathwise = [n for n in wrt if estimators[n].joint]
    if pathwise:
        v, e = _pathwise(scene, pathwise, estimators, query, method, rows, weights, chunk)
        value.update(v)
        stderr.update(e)
    rest = [n for n in wrt if n not in pathwise]
    if rest:
        v, e = _sampled(scene, rest, estimators, query, method, rows, weights, chunk)
        value.update(v)
        stderr.update(e)
        for name in rest:
            warn_if_noisy(name, v[name], e[name], stacklevel=4)
    return value, stderr, estimators


def _pathwise(scene, names, estimators, query: Query, method, rows, weights, chunk):
    """``(value, stderr)`` of pathwise derivatives (with the guards against exploding tangents).

    Forward mode: each path's tangent ``dY_i/dtheta`` at ``t`` (one ``jax.jacfwd`` of the paths' states), so that
    ``dp/dtheta = sum_i w_i c_i`` with ``c_i = dK(y, Y_i)/dY . dY_i/dtheta`` gives the standard error like the
    other estimators (``bandwidth="adaptive"`` adds the rule's ``dsigma/dtheta`` term to the value, not to the
    error). Reverse mode: ``jax.jacrev`` of the density, without a standard error (NaN).
    """
    var, grid, t, values, bandwidth, rule = query.var, query.grid, query.t, query.values, query.bandwidth, query.rule
    barrier = scene.model.barrier if scene.model.has_barrier else None
    sub = {n: values[n] for n in names}
    horizon = min(estimators[n].horizon for n in names)

    def result(states):
        return Result(
            times=scene.save_at,
            states=states,
            weights=weights,
            barrier=barrier,
            method=method.name,
            independent=method.independent,
        )

    def paths(vals):
        s = method.paths(with_parameters(scene, vals), rows, chunk)
        return s, s

    def density(states):
        return _density(result(states), var, grid, t, bandwidth, rule)

    if estimators[names[0]].mode == "reverse":
        out, p = jax.jacrev(lambda vals: (density(paths(vals)[0]),) * 2, has_aux=True)(sub)
        pathwise_guard(scene.model.has_barrier, t, horizon, values, out, p)
        return out, {n: jnp.full_like(out[n], jnp.nan) for n in names}

    tangents, states = jax.jacfwd(paths, has_aux=True)(sub)
    res = result(states)
    index = scene.time_index(t)
    w, (x, v) = finite_weights(weights, states[:, index, 0], states[:, index, 1])
    p = density(states)
    sigma = [jax.lax.stop_gradient(s) for s in _sigmas(res, var, t, bandwidth, rule)]  # "adaptive": its error
    kern = _kernel(var, grid, sigma if var == "xv" else sigma[0], barrier)

    def contribution(x, v, dx, dv):
        return jax.jvp(kern, (x, v), (dx, dv))[1]

    value, stderr = {}, {}
    for n in names:
        dx, dv = (jnp.where(w > 0, tangents[n][:, index, k], 0.0) for k in (0, 1))
        value[n], stderr[n] = jax.jit(moments, static_argnums=0)(contribution, (x, v, dx, dv), w)
        n_eff = effective_paths(jax.jit(_squared_norms, static_argnums=0)(contribution, (x, v, dx, dv), w))
        size = float(jnp.linalg.norm(value[n]))
        warn_if_unreliable(w.shape[0], n_eff, float(jnp.linalg.norm(stderr[n])) / size if size > 0 else math.inf, 5)
        if bandwidth == "adaptive":  # the rule's own derivative, through the same tangents
            value[n] = jax.jvp(density, (states,), (tangents[n],))[1]
    pathwise_guard(scene.model.has_barrier, t, horizon, values, value, p)
    for n in names:
        warn_if_noisy(n, value[n], stderr[n], stacklevel=5)
    return value, stderr


def _squared_norms(contribution, inputs, weights):
    """``(N,)`` squared norms over the grid of the per-path contributions ``w_i c_i``, chunk by chunk."""
    n = weights.shape[0]
    size = min(CHUNK, n)
    pad = (-n) % size
    chunks = jax.tree_util.tree_map(
        lambda a: jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)).reshape(-1, size, *a.shape[1:]), (inputs, weights)
    )

    def one(chunk):
        inp, w = chunk
        c = contribution(*inp)
        return jnp.sum((w.reshape((-1,) + (1,) * (c.ndim - 1)) * c) ** 2, axis=tuple(range(1, c.ndim)))

    return jax.lax.map(one, chunks).reshape(-1)[:n]


def pathwise_guard(has_barrier: bool, t: float, horizon: float, values: dict, derivatives: dict, pdf) -> None:
    """Warn (:class:`SensitivityWarning`) about pathwise derivatives past the horizon or exploding."""
    if has_barrier and t > horizon:
        warnings.warn(
            f"pathwise derivatives at t = {t:g} s (beyond the Pathwise horizon {horizon:g} s) through impacts are "
            "not reliable: tangents grow without bound across impacts; use estimator='auto' (likelihood ratio, "
            "noise scaling, central differences)",
            SensitivityWarning,
            stacklevel=4,
        )
    pmax = float(jnp.max(jnp.abs(pdf)))
    for n, d in derivatives.items():
        scale = float(jnp.max(jnp.abs(d))) * max(abs(float(values[n])), 1e-12)
        if not scale <= EXPLOSION * pmax:
            warnings.warn(
                f"pathwise dp/d{n} explodes (max |{n} dp/d{n}| = {scale:.3g} against max p = {pmax:.3g}); "
                "use estimator='auto'",
                SensitivityWarning,
                stacklevel=4,
            )


@dataclasses.dataclass(frozen=True)
class PathContext:
    """What the per-path estimators share: the common paths at time ``t``, their weights, kernel and scores.

    Attributes:
        scene: the scene at its nominal parameters.
        values: ``{name: nominal value}`` of the parameters differentiated.
        x, v: ``(N,)`` position and velocity of each path at ``t`` (zero where not finite).
        weights: ``(N,)`` path weights (``1/N`` or ``P_q``), zero for paths not finite at ``t``.
        kern: per-path kernels ``(x, v)`` chunks ``(c,)`` -> ``(c, *grid_shape)``, in PDF units.
        grid_ndim: number of grid axes (1, or 2 for ``"xv"``).
        scores: ``{name: (N,)}`` centred Girsanov scores (per parameter unit) of the names in ``scores_needed``.
        run_scene: ``scene`` saving only at ``t`` and the score windows' starts; ``index``: ``t``'s save slot.
        rows, path_weights, chunk: the sampling method's inputs (``method.inputs``); method: the method.
    """

    scene: Scene
    values: dict
    x: Any
    v: Any
    weights: Any
    kern: Callable
    grid_ndim: int
    scores: dict
    run_scene: Scene
    index: int
    rows: Any
    path_weights: Any
    method: SamplingMethod
    chunk: Any

    def per_path(self, s):
        """``(N,)`` or ``(c,)`` per-path values shaped to broadcast against the kernel's grid axes."""
        return s.reshape((-1,) + (1,) * self.grid_ndim)

    def moments(self, contribution, inputs: tuple, weights=None):
        """``(value, stderr)`` of the per-path ``contribution(*inputs)``, weighted by ``weights`` or ``.weights``."""
        return jax.jit(moments, static_argnums=0)(contribution, inputs, self.weights if weights is None else weights)

    def rerun(self, name: str, values: Sequence[float]):
        """``(weights, [states])``: the common paths with ``name`` at each value in turn, states ``(N, 2)`` at ``t``.

        Paths not finite at any of the values get zero weight.
        """
        ends = []
        for val in values:
            s = with_parameters(self.run_scene, {name: val})
            ends.append(self.method.paths(s, self.rows, self.chunk)[:, self.index])
        return finite_weights(self.path_weights, *ends)


def _sampled(scene, names, estimators, query: Query, method, rows, weights, chunk):
    """``(value, stderr)`` dicts of the per-path estimators, from one common set of paths."""
    ctx = _context(scene, names, estimators, query, method, rows, weights, chunk)
    value, stderr = {}, {}
    for n in names:
        value[n], stderr[n] = estimators[n].estimate(ctx, n)
    return value, stderr


def _context(scene, names, estimators, query: Query, method, rows, weights, chunk) -> PathContext:
    """Run the common paths once (accumulating the score sums ``names``' estimators need) up to ``query.t``."""
    settings = _score_settings(scene, names, estimators)
    k_t, starts, times, run_scene = score_windows(scene, settings, query.t)
    score = Sums(Score(tuple(settings), scene.dt)) if settings else None
    out = method.paths(run_scene, rows, chunk, track=score)
    states, sums = out if score is not None else (out, None)
    it = times.index(k_t)
    w, (x, v) = finite_weights(weights, states[:, it, 0], states[:, it, 1])
    scores = centred_scores(scene, settings, sums, w, times, k_t, starts) if score is not None else {}
    return PathContext(
        scene=scene,
        values=query.values,
        x=x,
        v=v,
        weights=w,
        kern=_sampled_kernel(scene, query, x, v, w),
        grid_ndim=2 if query.var == "xv" else 1,
        scores=scores,
        run_scene=run_scene,
        index=it,
        rows=rows,
        path_weights=weights,
        method=method,
        chunk=chunk,
    )


def _score_settings(scene, names, estimators) -> dict:
    """``{name: LikelihoodRatio}``: scores to accumulate, with a name's own settings, else the first asker's."""
    asked = [(n, k, e) for n in names for k, e in estimators[n].scores_needed(n, scene).items()]
    settings = {k: e for n, k, e in asked if k == n}
    for _, k, e in asked:
        settings.setdefault(k, e)
    return settings


def _sampled_kernel(scene, query: Query, x, v, w):
    """The per-path kernel on ``query.grid`` with the fixed bandwidth (the rule's at the nominal paths for ``None``)."""
    dtype = scene.float_dtype
    var, grid, bandwidth = query.var, query.grid, query.bandwidth
    if bandwidth is None:
        dim = 2 if var == "xv" else 1
        samples = (x, v) if var == "xv" else (x if var == "x" else v,)
        sig = [rule_bandwidth(s, w, query.rule, dim=dim) for s in samples]
        sigma = tuple(sig) if var == "xv" else sig[0]
    else:
        sigma = tuple(bandwidth) if var == "xv" else bandwidth
    g = (jnp.asarray(grid[0], dtype), jnp.asarray(grid[1], dtype)) if var == "xv" else jnp.asarray(grid, dtype)
    barrier = scene.model.barrier if scene.model.has_barrier else None
    return _kernel(var, g, sigma, barrier)
