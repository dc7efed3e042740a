r"""First passage by path integration: the transient density on its grid, absorbed where ``q > level``.

Each step is the transient's step (``StepOperator.step``, at the step's intensity for a modulated noise,
renormalised to the mass it started with, as ``solve`` renormalises), after which every node keeps only the
part of its cell where ``q <= level`` (``keep``, the fraction of ``SUBCELLS**2`` points of the cell). The
surviving mass at a saved time is ``1 - P_f(t)``. The start density (a Gaussian at ``t0`` for a point start)
is absorbed too, so mass beyond the level at ``t0`` counts as having passed it.
"""

from __future__ import annotations

import functools
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._models import AbstractOscillator
from .._pytree import concrete
from .._scene import with_parameters
from ..methods._path_integration import (
    PathIntegration,
    PathIntegrationWarning,
    check_resolution,
    coarser,
    on_host,
    peak_weight,
    program_settings,
    resolved,
    saved_scan,
    setup,
    start_density,
    step_exponents,
    traced_parameters,
    typed_parameters,
    validate,
)
from ..methods._pi_operator import drift_and_diffusion, make_grid
from ..sensitivities._path_integration import check_noise_resolution, check_start
from ._passage import Coordinate, FirstPassage, FirstPassageQuery

SUBCELLS = 8  # points per axis and node cell at which the quantity is compared with the level
DEFECT_TOL = 1e-3  # mass that left the grid unabsorbed (and was put back by renormalisation) before a warning


def absorbing_first_passage(scene, settings: PathIntegration, query: FirstPassageQuery) -> FirstPassage:
    """``jdpim.first_passage`` by path integration (``PathIntegration.first_passage``)."""
    if settings.stationary:
        raise ValueError(
            "PathIntegration(stationary=True) cannot compute first-passage probabilities (first passage is "
            "transient): use stationary=False"
        )
    if not isinstance(scene.model, AbstractOscillator):
        n = getattr(scene.model, "dimension", None)
        raise ValueError(
            f"first passage by path integration needs a one-degree-of-freedom scene (the model has {n} degrees of "
            "freedom): use jdpim.MonteCarlo or jdpim.DPIM"
        )
    if query.wrt:
        _check_wrt(query)
    if scene.model.has_barrier and concrete(scene.model.barrier) is None:
        raise ValueError(
            "first passage by path integration starts its grid at the barrier, so the barrier cannot be traced "
            "(jit, grad or vmap over it): give it as a number; for dP/dbarrier use jdpim.MonteCarlo with "
            "jdpim.CentralDifference()"
        )
    initial = settings.initial
    validate(scene, settings, initial, stationary=False)
    settings, extents = resolved(scene, settings)
    check_resolution(scene, settings, extents, point_start=initial is None)
    probability, defect, leak, keep = _probability(scene, settings, extents, query, "")
    grid_error = None
    if settings.estimate_error:
        coarse = coarser(scene, settings, False, initial)
        p_coarse, *_ = _probability(scene, coarse, extents, query, " (the coarse grid of estimate_error=True)")
        grid_error = jax.lax.stop_gradient(jnp.abs(probability - p_coarse))
    _report(probability, defect, leak, settings)
    levels = jnp.asarray(query.levels, probability.dtype)
    lost = jnp.zeros_like(probability)  # a non-finite density makes its probabilities NaN (and warns) instead
    derivative = _derivative(scene, settings, extents, query, keep) if query.wrt else None
    return FirstPassage(
        scene.save_at, levels, probability, None, lost, settings.name, derivative, grid_error=grid_error
    )


def _check_wrt(query: FirstPassageQuery) -> None:
    if query.estimator is not None:
        raise ValueError(
            f"estimator is for the sampling methods; path integration differentiates by forward-mode AD, got "
            f"{query.estimator!r}"
        )
    if "barrier" in query.wrt:
        raise ValueError(
            "path integration cannot differentiate first passage with respect to the barrier (its grid starts at "
            "the barrier and is static): use jdpim.MonteCarlo with jdpim.CentralDifference()"
        )


def _derivative(scene, settings: PathIntegration, extents, query: FirstPassageQuery, keep) -> dict:
    """``{name: dP/dname (S, L)}`` by ``jax.jacfwd`` through the absorbed steps, with the grid, the order of the
    weights and the absorbed fractions ``keep`` held at the nominal parameters."""
    check_start(min(scene.save_at), settings)
    if "D" in query.wrt:
        _check_noise_resolution(scene, settings, extents)

    def probability(values):
        survival, _, _ = _survival(
            typed_parameters(with_parameters(scene, values)), program_settings(settings), extents, keep
        )
        return 1.0 - survival.T

    values = {n: jnp.asarray(v, scene.float_dtype) for n, v in query.values.items()}
    return jax.jacfwd(probability)(values)


@on_host
def _check_noise_resolution(scene, settings: PathIntegration, extents) -> None:
    """``check_noise_resolution`` on the grid of ``extents``, built from concrete values (also inside a user's
    ``jax.jit``)."""
    grid = make_grid(scene.model, settings.n_x, settings.n_v, *extents, scene.float_dtype)
    check_noise_resolution(scene, settings, grid)


def _probability(scene, settings: PathIntegration, extents, query: FirstPassageQuery, which: str):
    """``(probability, defect, leak, keep)`` on the grid of ``settings``: each ``(S, L)``, and the absorbed
    fractions of :func:`_keep`."""
    keep = _checked_keep(scene, settings, extents, query, which)
    survival, defect, leak = _survival(typed_parameters(scene), program_settings(settings), extents, keep)
    return 1.0 - survival.T, defect.T, leak.T, keep


@on_host
def _checked_keep(scene, settings: PathIntegration, extents, query: FirstPassageQuery, which: str):
    """The absorbed fractions ``(L, n_x, n_v)`` of :func:`_keep` on the grid of ``settings``, its levels checked.

    The grid depends only on the extents, the sizes and the barrier (numbers, however the model's other parameters
    are traced), so the fractions and the checks are computed from concrete values, also inside a user's
    ``jax.jit``."""
    grid = make_grid(scene.model, settings.n_x, settings.n_v, *extents, scene.float_dtype)
    levels = jnp.asarray(query.levels, scene.float_dtype)
    keep, node_max = _keep(query.quantity, grid.x, grid.v, levels)
    node_max = concrete(node_max)
    if node_max is None:
        raise ValueError(
            "var depends on a traced value (jit, grad or vmap over what it closes over): path integration sets the "
            "part of every cell beyond the level before it steps; pass a function of the state alone, or use "
            "jdpim.MonteCarlo"
        )
    _check_levels(scene, settings, query, grid, float(node_max), which)
    return keep


@functools.partial(jax.jit, static_argnames=("quantity",))
def _keep(quantity, x, v, levels):
    """``(keep, node_max)``: the fraction ``(L, n_x, n_v)`` of each node's cell where ``quantity <= level``
    (``SUBCELLS**2`` points per cell, clipped to the grid), and the largest value of ``quantity`` on a node."""
    dx, dv = x[1] - x[0], v[1] - v[0]
    offsets = (jnp.arange(SUBCELLS, dtype=x.dtype) + 0.5) / SUBCELLS - 0.5
    xs, vs = x[:, None] + dx * offsets[None, :], v[:, None] + dv * offsets[None, :]  # (n_x, m), (n_v, m)
    tol = 1e-6 * jnp.maximum(dx, dv)
    inx = ((xs >= x[0] - tol) & (xs <= x[-1] + tol)).astype(x.dtype)
    inv = ((vs >= v[0] - tol) & (vs <= v[-1] + tol)).astype(x.dtype)
    weight = inx[:, None, :, None] * inv[None, :, None, :]  # (n_x, n_v, m, m)
    X, V = jnp.broadcast_arrays(xs[:, None, :, None], vs[None, :, None, :])
    q = jax.vmap(quantity)(jnp.stack([X.ravel(), V.ravel()], -1)).reshape(X.shape)
    nodes = jax.vmap(quantity)(jnp.stack(jnp.meshgrid(x, v, indexing="ij"), -1).reshape(-1, 2))
    total = jnp.sum(weight, axis=(2, 3))

    def fraction(level):
        return jnp.sum(weight * (q <= level), axis=(2, 3)) / total

    return jax.lax.map(fraction, levels), jnp.max(jnp.where(jnp.isfinite(nodes), nodes, -jnp.inf))


def _check_levels(scene, settings: PathIntegration, query: FirstPassageQuery, grid, node_max: float, which: str):
    """One-line errors where a level is not exceeded on the grid, or a coordinate's level is too near its end."""
    levels, quantity = np.asarray(query.levels), query.quantity
    name = quantity.name if isinstance(quantity, Coordinate) else "the quantity"
    x_lo, x_hi, v_hi = float(grid.x[0]), float(grid.x[-1]), float(grid.v[-1])
    ranges = f"x in [{x_lo:.4g}, {x_hi:.4g}], v in [{-v_hi:.4g}, {v_hi:.4g}]"
    high = levels[levels >= node_max]
    if high.size:
        raise ValueError(
            f"level {high.tolist()} is not exceeded anywhere on the path-integration grid{which} ({name} <= "
            f"{node_max:.4g} on {ranges}): raise x_max/v_max in jdpim.PathIntegration so that the grid reaches "
            "past the level"
        )
    if not isinstance(quantity, Coordinate):
        return
    dx, dv = float(grid.dx), float(grid.dv)
    if quantity.index == 0:  # a node below the level moves at most v_max tau in a step (plus the stencil)
        reach, end = v_hi * settings.tau + 2 * dx, x_hi
    else:  # diffusion over a step (5 standard deviations), plus the stencil
        _, q = drift_and_diffusion(scene.model, scene.noise.D)
        b = float(grid.x[0]) if scene.model.has_barrier else 0.0
        q_b = concrete(q(jnp.asarray(b), jnp.asarray(0.0)))
        if q_b is None:
            raise ValueError(
                f"a level of {name!r} is checked against the grid's velocity end with the diffusion q = h^T D h, "
                f"but {', '.join(traced_parameters(scene))} is traced (jit, grad or vmap): give D and the gains' "
                'parameters as numbers (for dP/dD pass wrt="D")'
            )
        q_peak = float(q_b) * peak_weight(scene, settings.tau)
        reach = 5 * math.sqrt(2 * q_peak * settings.tau) + 2 * dv
        end = v_hi
    near = levels[levels > end - reach]
    if near.size:
        raise ValueError(
            f"level {near.tolist()} of {name!r} lies within {reach:.3g} (one step's reach) of the path-integration "
            f"grid's end {name} = {end:.4g}{which} ({ranges}): mass could leave the grid before it is absorbed; "
            "raise x_max/v_max in jdpim.PathIntegration"
        )


@functools.partial(jax.jit, static_argnames=("settings",))
def _survival(scene, settings: PathIntegration, extents, keep):
    """``(survival, defect, leak)``, each ``(L, S)``: the mass kept at every saved time for each ``keep``
    ``(L, n_x, n_v)``, the mass the steps lost at the grid's edges (put back by renormalisation), and the
    largest mass in the outermost node rows, on the grid of ``extents`` ``(x_max, v_max)``."""
    grid, ops, weights, edge = setup(scene, settings, extents)
    p0, start = start_density(scene, settings, grid, weights, settings.initial)
    steps = [int(round((t - start) / settings.tau)) for t in scene.save_at]
    exponents = step_exponents(scene, settings, ops, start, max(steps))

    def absorbed(keep):
        def body(carry, z):
            p, defect, leak = carry
            before = jnp.sum(weights * p)
            p = ops.step(p, z)
            after = jnp.sum(weights * p)
            p = p * jnp.where(after > 0, before / after, 0.0) * keep
            return (p, defect + jnp.abs(before - after), jnp.maximum(leak, jnp.sum(edge * p))), None

        p = p0 * keep
        outs = saved_scan(body, (p, jnp.zeros((), p.dtype), jnp.sum(edge * p)), steps, exponents)
        return tuple(jnp.stack(z) for z in zip(*[(jnp.sum(weights * p), d, e) for p, d, e in outs], strict=True))

    return jax.vmap(absorbed)(keep)


def _report(probability, defect, leak, settings: PathIntegration) -> None:
    probability, defect, leak = concrete(probability), concrete(defect), concrete(leak)
    if probability is None or defect is None or leak is None:
        return  # traced (differentiated by the caller): nothing to inspect here
    problems = []
    if not np.all(np.isfinite(probability)):
        problems.append("non-finite probabilities (the density became non-finite)")
    if np.max(defect) > DEFECT_TOL:
        problems.append(
            f"mass {np.max(defect):.2e} left the grid unabsorbed and was put back by renormalisation "
            f"(> {DEFECT_TOL:g}): enlarge x_max/v_max"
        )
    if np.max(leak) > settings.leak_tol:
        problems.append(
            f"mass {np.max(leak):.2e} reached the grid's edges (> leak_tol={settings.leak_tol:g}): enlarge x_max/v_max"
        )
    if problems:
        warnings.warn("path integration first passage: " + "; ".join(problems), PathIntegrationWarning, stacklevel=4)
