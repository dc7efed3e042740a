r"""Sensitivities ``dp(y, t) / d theta`` by forward-mode AD through path integration.

``jax.jacfwd`` over the parameter values (set with ``with_parameters``) of ``jdpim.path_integration``:
through the steps from the scene's start to ``t``, or, for the stationary density, implicitly through its
fixed point (one linear solve per parameter and Newton system). The result is the derivative of the
discrete solver: it has no sampling error, only the grid's discretisation error (measured in
docs/gradients.md).

The grid extents and the order of the weights are chosen from the nominal parameters (where path
integration also refuses what it cannot solve, before tracing) and held while the parameters move. The
nominal density is the primal of the same forward-mode run (``has_aux``): its ``PathIntegrationWarning`` is
reported from there, with no separate nominal solve.
"""

from __future__ import annotations

import dataclasses
import warnings

import jax
import jax.numpy as jnp

from .._pytree import concrete
from .._scene import Scene, with_parameters
from ..methods._base import solve
from ..methods._path_integration import PathIntegration, check_resolution, report, resolved, validate
from ..methods._pi_operator import make_grid
from ._estimators import SensitivityWarning

START_HORIZONS = 10.0  # t / t0 below which the point start's approximation shows in dp/dgamma, dp/dr (measured)
D_RESOLUTION = 0.85  # sqrt(q tau) / dv below which dp/dD degrades (measured: 4e-2 at 0.67, 1.5e-3 at 0.89)
# default settings for transient derivatives within START_HORIZONS x PathIntegration().t0 of a point start:
# a 4x earlier start on a 2x finer grid (measured at t = 5: reference scene within 0.5-3.5 % of 2e6 paths, r = 1
# linear case 2.5e-5 against the exact derivative)
SHORT_HORIZON = PathIntegration(t0=0.25, n_x=241, n_v=481, tau=0.025)


def default_settings(t: float, stationary: bool = False) -> PathIntegration:
    """``PathIntegration()``, or :data:`SHORT_HORIZON` for a transient ``t`` within 10 default ``t0`` of the start."""
    short = not stationary and t < START_HORIZONS * PathIntegration().t0
    return SHORT_HORIZON if short else PathIntegration()


def nominal_run(scene: Scene, settings: PathIntegration, t: float):
    """``(scene saving only t, settings with the nominal grid's extents and order, the nominal grid)``.

    Raises what path integration refuses (``ValueError``/``TypeError``) and warns where the grid is too coarse,
    as a solve would, without solving.
    """
    if not settings.stationary:
        scene = scene.replace(save_at=(t,))
    validate(scene, settings, settings.initial, settings.stationary)
    settings, extents = resolved(scene, settings)
    check_resolution(scene, settings, extents, point_start=settings.initial is None and not settings.stationary)
    grid = _grid(scene.model, settings.n_x, settings.n_v, *extents, scene.float_dtype)
    return scene, dataclasses.replace(settings, x_max=extents[0], v_max=extents[1]), grid


# the nodes as a solve computes them (compiled, with the extents as values, as inside the solve's program)
_grid = jax.jit(make_grid, static_argnums=(1, 2, 5))


def grid_sensitivity(scene: Scene, settings: PathIntegration, query, nominal=None):
    """``(value, stderr, estimators)`` of ``jdpim.sensitivity`` by path integration (``nominal``: a nominal_run)."""
    if not (isinstance(query.estimator, str) and query.estimator == "auto"):
        raise ValueError(f"estimator is for the sampling methods, not path integration; got {query.estimator!r}")
    if isinstance(query.bandwidth, str):
        raise ValueError(f"path integration takes bandwidth=None (grid density) or a number, got {query.bandwidth!r}")
    nominal = nominal_run(scene, settings, query.t) if nominal is None else nominal
    bandwidth = tuple(query.bandwidth) if query.var == "xv" and query.bandwidth is not None else query.bandwidth
    value, used = path_integration_sensitivity(nominal, query.values, query.var, query.grid, query.t, bandwidth)
    stderr = {n: jnp.zeros_like(d) for n, d in value.items()}
    return value, stderr, dict.fromkeys(query.wrt, used)


def check_start(t: float, settings: PathIntegration) -> None:
    """Warn when ``t`` is so close to the start that the linearised start density at ``t0`` shows."""
    if t < START_HORIZONS * settings.t0:
        fix = (
            "a smaller t0 on a grid that resolves its start density (see PathIntegrationWarning)"
            if settings.t0 <= SHORT_HORIZON.t0
            else f"method=jdpim.PathIntegration(t0=0.25, n_x=241, n_v=481, tau=0.025) (the default below "
            f"t = {START_HORIZONS * PathIntegration().t0:g} s)"
        )
        warnings.warn(
            f"path-integration derivatives at t = {t:g} s, within {START_HORIZONS:g} x t0 = {settings.t0:g} s of the "
            "start: the point start is replaced by the linearised Gaussian at t0 (no cubic damping, one fold through "
            "the impact law), which moved dp/dgamma and dp/dr of the reference scene by 5-8 % at t = 5 and up to 50 % "
            f"at t = 2 with t0 = 1 (0.2 % at t = 10); pass {fix}",
            SensitivityWarning,
            stacklevel=4,
        )


def check_noise_resolution(scene: Scene, settings: PathIntegration, res) -> None:
    """Warn when one half step's diffusion spans too few velocity spacings for a derivative in ``D`` (``res``: the
    grid, or anything with its nodes ``x`` and ``v``)."""
    model = scene.model
    gains = jnp.atleast_1d(model.gains(res.x[0], jnp.zeros((), res.x.dtype)))
    q = concrete(gains @ jnp.atleast_2d(jnp.asarray(scene.noise.D, res.x.dtype)) @ gains)
    if q is None:
        return  # traced gains: nothing to check here
    q = float(q)
    ratio = (q * settings.tau) ** 0.5 / float(res.v[1] - res.v[0])
    if ratio < D_RESOLUTION:
        warnings.warn(
            f"dp/dD by path integration: one step's diffusion (sd sqrt(q tau) = {(q * settings.tau) ** 0.5:.3g}) spans "
            f"{ratio:.2f} velocity spacings (< {D_RESOLUTION}): the derivative in D is then off by per cents; raise "
            "n_v or tau",
            SensitivityWarning,
            stacklevel=4,
        )


def grid_density(res, var: str, grid, t, bandwidth):
    """Density of ``var`` (``"x"``, ``"v"`` or ``"xv"``) on ``grid``: interpolated (``bandwidth=None``) or smoothed."""
    if var == "xv":
        return res.joint_pdf(("x", "v"), grid, t, bandwidth=bandwidth)
    return res.pdf(var, grid, t, bandwidth=bandwidth)


def path_integration_sensitivity(nominal, values: dict, var: str, grid, t, bandwidth):
    """``({name: dp/dname on grid}, settings used)`` by ``jax.jacfwd`` through ``path_integration``.

    ``nominal`` is what :func:`nominal_run` returns.
    """
    run_scene, fixed, nodes = nominal
    if not fixed.stationary:
        check_start(t, fixed)
    if "D" in values:
        check_noise_resolution(run_scene, fixed, nodes)

    def pdf_of(vals):
        s = with_parameters(run_scene, vals)
        res = solve(s, fixed)
        return grid_density(res, var, grid, None if fixed.stationary else t, bandwidth), res

    derivative, res = jax.jacfwd(pdf_of, has_aux=True)(values)
    report(res, fixed)  # the nominal density's warnings (traced inside the run, so not reported there)
    bad = {n: int(jnp.sum(~jnp.isfinite(d))) for n, d in derivative.items()}
    bad = {n: k for n, k in bad.items() if k}
    if bad:
        warnings.warn(
            f"path-integration derivatives are not finite at {bad} grid points", SensitivityWarning, stacklevel=3
        )
    return derivative, fixed
