r"""Sensitivities ``dp(y, t) / d theta`` by forward-mode AD through path integration.

``jax.jacfwd`` over the parameter values (set with ``with_parameters``) of ``jdpim.path_integration``:
through the steps from the scene's start to ``t``, or, for the stationary density, implicitly through its
fixed point (one linear solve per parameter and Newton system). The result is the derivative of the
discrete solver: it has no sampling error, only the grid's discretisation error (measured in
docs/gradients.md).

The grid extents are static, so they are read from a run at the nominal parameters (which also raises
what path integration refuses and reports its ``PathIntegrationWarning`` for the nominal grid) and held
fixed while the parameters move.
"""

from __future__ import annotations

import dataclasses
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._scene import Scene
from ..methods._path_integration import LINEAR_BELOW_R, PathIntegration, path_integration
from ..results._density import _kernel_matrix
from ._estimators import SensitivityWarning, with_parameters

START_HORIZONS = 10.0  # t / t0 below which the point start's approximation shows in dp/dgamma, dp/dr (measured)
D_RESOLUTION = 0.85  # sqrt(q tau) / dv below which dp/dD degrades (measured: 4e-2 at 0.67, 1.5e-3 at 0.89)
# default settings for transient derivatives within START_HORIZONS x PathIntegration().t0 of a point start:
# a 4x earlier start on a 2x finer grid (measured at t = 5: reference scene within 0.5-3.5 % of 2e6 paths, r = 1
# linear case 2.5e-5 against the exact derivative)
SHORT_HORIZON = PathIntegration(t0=0.25, n_x=241, n_v=481, tau=0.025)


def default_settings(t: float, stationary: bool) -> PathIntegration:
    """``PathIntegration()``, or :data:`SHORT_HORIZON` for a transient ``t`` within 10 default ``t0`` of the start."""
    short = not stationary and t < START_HORIZONS * PathIntegration().t0
    return SHORT_HORIZON if short else PathIntegration()


def nominal_run(scene: Scene, settings: PathIntegration | None, t: float, stationary: bool):
    """``(scene saving only t, settings with the nominal grid's extents and order, nominal GridResult)``."""
    settings = default_settings(t, stationary) if settings is None else settings
    if not isinstance(settings, PathIntegration):
        raise TypeError(f"settings must be a jdpim.PathIntegration, got {settings!r}")
    if not stationary:
        scene = scene.replace(save_at=(t,))
    nominal = path_integration(scene, settings, stationary)
    x, v = np.asarray(nominal.x, float), np.asarray(nominal.v, float)
    order = settings.order
    if order is None:  # under jacfwd a traced r cannot choose the weights: choose them from the nominal r
        r = float(np.max(np.asarray(scene.model.r))) if scene.model.has_barrier else 1.0
        order = 2 if r < LINEAR_BELOW_R else 4
    x_max = x[-1] - x[0] if scene.model.has_barrier else x[-1]
    return scene, dataclasses.replace(settings, x_max=float(x_max), v_max=float(v[-1]), order=order), nominal


def _check_start(t: float, settings: PathIntegration) -> None:
    """Warn when ``t`` is so close to the start that the linearised start density at ``t0`` shows."""
    if t < START_HORIZONS * settings.t0:
        fix = (
            "a smaller t0 on a grid that resolves its start density (see PathIntegrationWarning)"
            if settings.t0 <= SHORT_HORIZON.t0
            else f"settings=jdpim.PathIntegration(t0=0.25, n_x=241, n_v=481, tau=0.025) (the default below "
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


def _check_noise_resolution(scene: Scene, settings: PathIntegration, res) -> None:
    """Warn when one half step's diffusion spans too few velocity spacings for a derivative in ``D``."""
    model = scene.model
    gains = jnp.atleast_1d(model.gains(res.x[0], jnp.zeros((), res.x.dtype)))
    q = float(gains @ jnp.atleast_2d(jnp.asarray(scene.noise.D, res.x.dtype)) @ gains)
    ratio = (q * settings.tau) ** 0.5 / float(res.v[1] - res.v[0])
    if ratio < D_RESOLUTION:
        warnings.warn(
            f"dp/dD by path integration: one step's diffusion (sd sqrt(q tau) = {(q * settings.tau) ** 0.5:.3g}) spans "
            f"{ratio:.2f} velocity spacings (< {D_RESOLUTION}): the derivative in D is then off by per cents; raise "
            "n_v or tau",
            SensitivityWarning,
            stacklevel=4,
        )


def _trapezoid(nodes):
    return jnp.ones_like(nodes).at[0].set(0.5).at[-1].set(0.5) * (nodes[1] - nodes[0])


def grid_density(res, var: str, grid, t, bandwidth, barrier):
    """Density of ``var`` on ``grid``: interpolated between nodes (``bandwidth=None``), or the nodal density
    smoothed with the reflected Gaussian kernel of the sampling methods (trapezoidal rule over the nodes)."""
    t = None if res.stationary else t
    dtype = res.density.dtype
    if bandwidth is None:
        return res.joint_pdf(grid[0], grid[1], t) if var == "xv" else res.pdf(var, grid, t)
    if var == "xv":
        kx = _kernel_matrix(jnp.asarray(grid[0], dtype), res.x, bandwidth[0], barrier)
        kv = _kernel_matrix(jnp.asarray(grid[1], dtype), res.v, bandwidth[1], None)
        return kx @ (res.joint(t) * _trapezoid(res.x)[:, None] * _trapezoid(res.v)[None, :]) @ kv.T
    nodes = res.x if var == "x" else res.v
    k = _kernel_matrix(jnp.asarray(grid, dtype), nodes, bandwidth, barrier if var == "x" else None)
    return k @ (_trapezoid(nodes) * res.nodal_marginal(var, t))


def path_integration_sensitivity(nominal, values: dict, var: str, grid, t, bandwidth, stationary):
    """``({name: dp/dname on grid}, settings used)`` by ``jax.jacfwd`` through ``path_integration``.

    ``nominal`` is what :func:`nominal_run` returns.
    """
    run_scene, fixed, res = nominal
    if not stationary:
        _check_start(t, fixed)
    if "D" in values:
        _check_noise_resolution(run_scene, fixed, res)

    def pdf_of(vals):
        s = with_parameters(run_scene, vals)
        res = path_integration(s, fixed, stationary)
        return grid_density(res, var, grid, t, bandwidth, s.model.barrier if s.model.has_barrier else None)

    derivative = jax.jacfwd(pdf_of)(values)
    bad = {n: int(jnp.sum(~jnp.isfinite(d))) for n, d in derivative.items()}
    bad = {n: k for n, k in bad.items() if k}
    if bad:
        warnings.warn(
            f"path-integration derivatives are not finite at {bad} grid points", SensitivityWarning, stacklevel=3
        )
    return derivative, fixed
