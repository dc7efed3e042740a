"""Sensitivities of the densities of systems with several degrees of freedom: central differences.

The paths are rerun at two values of the parameter with the same random inputs (the same seed, or the same
DPIM points), so the per-path differences of the kernel estimate have a small variance; the kernel width is
held at its value for the nominal run. Pathwise derivatives are not offered: through impacts between masses
they are not validated (see ``jdpim.methods._ad_guard``).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._pytree import check_real
from .._scene import Scene, get_parameter, with_parameters
from ..methods._base import AbstractMethod, solve
from ..methods._monte_carlo import MonteCarlo
from ..methods._path_integration import PathIntegration
from ..results import _density
from ._estimators import CentralDifference


def several_dof_sensitivity(
    scene: Scene, wrt: tuple[str, ...], var, grid, t: float, method: AbstractMethod | None, bandwidth, rule, estimator
):
    """``(value, stderr, estimators, method)`` for a scene whose model has several degrees of freedom."""
    if isinstance(method, PathIntegration):
        raise ValueError("path integration takes one degree of freedom; use jdpim.MonteCarlo() or jdpim.DPIM()")
    method = MonteCarlo(n_samples=100_000) if method is None else method
    estimators = {name: _central_difference(name, estimator) for name in wrt}
    if not (callable(var) or var in scene.model.coordinates):
        raise ValueError(
            f"var must be one of the coordinates {scene.model.coordinates} or a function of the state, got {var!r}"
        )
    if isinstance(bandwidth, str):
        raise ValueError("bandwidth='adaptive' needs the Pathwise estimator: one degree of freedom only")
    grid = jnp.asarray(grid)
    nominal = solve(scene, method)
    if bandwidth is None:
        y = nominal.samples(var, t)
        bandwidth = float(_density.bandwidth(y, nominal.weights, rule, dim=1))
    else:
        check_real("bandwidth", bandwidth, low=0.0, low_open=True)
    reflect = nominal._reflect(var)
    value, stderr = {}, {}
    for name, est in estimators.items():
        nominal_value = scene.noise.D if name == "D" else get_parameter(scene.model, name)
        lo, hi = est.pair(name, float(nominal_value))
        runs = [solve(with_parameters(scene, {name: p}), method) for p in (lo, hi)]
        d, se = _density.kde_difference(
            runs[0].samples(var, t), runs[1].samples(var, t), nominal.weights, grid, bandwidth, reflect
        )
        value[name], stderr[name] = d / (hi - lo), se / (hi - lo)
    return value, stderr, estimators, method


def _central_difference(name: str, estimator) -> CentralDifference:
    est = estimator.get(name, "auto") if isinstance(estimator, dict) else estimator
    if isinstance(est, str) and est == "auto":
        return CentralDifference()
    if not isinstance(est, CentralDifference):
        raise ValueError(
            f"estimator for {name!r}: several degrees of freedom take CentralDifference only (pathwise derivatives "
            f"through impacts between masses are not validated; the likelihood ratio takes one), got {est!r}"
        )
    return est
