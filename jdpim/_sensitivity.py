r"""Sensitivities of DPIM response PDFs to physical parameters, by differentiating the whole pipeline.

.. math::  \frac{\partial p(y, t)}{\partial \lambda}
           = \sum_q P_q \, \partial_{y_q} \mathcal{N}(y; y_q(t), \sigma^2) \, \frac{\partial y_q(t)}{\partial \lambda}

for a parameter ``lambda`` (``alpha``, ``gamma``, ``r``, ``barrier``, ``omega`` of the model, or the
noise intensity ``D``). The point set ``theta_q, P_q`` does not depend on ``lambda``; the trajectory
sensitivities ``dy_q / d lambda`` come from forward- or reverse-mode differentiation through the
excitation, the RK4 scan and the located impacts (whose event-time shift gives the saltation matrix,
README "Numerics"), and ``lambda = barrier`` also moves the reflection of the kernel.

Bandwidth: by default the rule-based ``sigma`` is evaluated at the nominal parameters and then held
fixed, so the result is the exact derivative of the computed (smoothed) density
``p * N(0, sigma^2)``, whose expectation is the smoothed true sensitivity. ``bandwidth="adaptive"``
differentiates the rule too (``dsigma / d lambda`` through the weighted spread of the samples), which
is what ``jax.grad`` of ``Result.pdf(..., bandwidth=None)`` gives.

Cost: forward mode (the default) costs about ``1 + len(wrt)`` forward runs whatever the grid size;
reverse mode costs one backward pass per grid output, with memory bounded by the ``jax.checkpoint``
around the scan step (the carry of each step is kept, RK4 stages are recomputed). Use forward mode for
few parameters and many grid outputs, reverse mode for a scalar functional of many parameters.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp

from ._pipelines import dpim, dpim_points
from ._points import PointSet
from ._result import Result
from ._scene import Scene

NOISE_PARAMETERS = ("D",)
VARIABLES = ("x", "v", "xv")


def parameter_names(scene: Scene) -> tuple[str, ...]:
    """Names that :func:`sensitivity` accepts for ``scene``: the model's traced fields and ``"D"``."""
    fields = dataclasses.fields(scene.model)
    model = tuple(f.name for f in fields if not f.metadata.get("static", False) and f.name != "params")
    return model + NOISE_PARAMETERS


def with_parameters(scene: Scene, values: dict) -> Scene:
    """``scene`` with named parameters replaced, e.g. ``{"alpha": 0.05, "D": 0.08}`` (values may be traced)."""
    allowed = parameter_names(scene)
    unknown = sorted(set(values) - set(allowed))
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}; choose from {list(allowed)}")
    model_changes = {k: v for k, v in values.items() if k not in NOISE_PARAMETERS}
    if model_changes:
        scene = scene.replace(model=scene.model.replace(**model_changes))
    if "D" in values:
        scene = scene.replace(noise=dataclasses.replace(scene.noise, D=values["D"]))
    return scene


def _nominal(scene: Scene, name: str):
    value = scene.noise.D if name == "D" else getattr(scene.model, name)
    if value is None:
        raise ValueError(f"parameter {name!r} is None (the term is left out); set it to a number to differentiate")
    return jnp.asarray(value, scene.float_dtype)


def _density(res: Result, var: str, grid, t, bandwidth, rule: str):
    """The PDF of ``var`` on ``grid`` with the bandwidth policy of :func:`sensitivity`."""
    dim = 2 if var == "xv" else 1
    names = ("x", "v") if var == "xv" else (var,)
    if bandwidth is None or bandwidth == "adaptive":
        sig = [res.bandwidth(n, t, rule, dim=dim) for n in names]
        if bandwidth is None:
            sig = [jax.lax.stop_gradient(s) for s in sig]
    else:
        sig = list(bandwidth) if var == "xv" else [bandwidth]
    if var == "xv":
        return res.joint_pdf(grid[0], grid[1], t, bandwidth=tuple(sig))
    return res.pdf(var, grid, t, bandwidth=sig[0])


def sensitivity(
    scene: Scene,
    wrt: Sequence[str] = ("alpha", "gamma", "r"),
    var: str = "x",
    grid=None,
    t: float | None = None,
    *,
    n_points: int = 1000,
    points: PointSet | None = None,
    bandwidth=None,
    rule: str = "chen",
    mode: str = "forward",
) -> dict:
    r"""Derivatives ``dp(y, t) / d lambda`` of the DPIM PDF on a grid, for each parameter in ``wrt``.

    Args:
        scene: the scene; its parameter values are the point of differentiation.
        wrt: parameter names (see :func:`parameter_names`: ``alpha``, ``gamma``, ``r``, ``barrier``,
            ``omega``, ``D`` for :class:`VibroImpactOscillator`).
        var: ``"x"``, ``"v"`` (marginal PDFs) or ``"xv"`` (joint PDF).
        grid: evaluation grid, 1-D for ``"x"``/``"v"``, a pair ``(x_grid, v_grid)`` for ``"xv"``. Keep
            ``x`` grid nodes off the barrier when differentiating with respect to ``barrier``: the
            density jumps to zero there.
        t: a saved time of the scene (default: the last one).
        n_points, points: the DPIM point set (common to every parameter value).
        bandwidth: ``None`` (rule-based at the nominal parameters, held fixed), ``"adaptive"`` (the
            rule is differentiated too), or fixed kernel standard deviation(s): a number, or a pair
            ``(sigma_x, sigma_v)`` for ``"xv"``.
        rule: bandwidth rule for ``None``/``"adaptive"`` (see ``jdpim.bandwidth``).
        mode: ``"forward"`` (``jax.jacfwd``; cheap for few parameters) or ``"reverse"`` (``jax.jacrev``).

    Returns:
        dict ``name -> array`` shaped like the PDF (``(G,)`` or ``(Gx, Gv)``), in PDF units per parameter unit.

    Example:
        >>> import jdpim, numpy as np
        >>> model = jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, barrier=None)  # cheap to compile
        >>> scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(D=0.05), t_end=2.0, dt=0.02)
        >>> points = jdpim.dpim_points(scene, 16)
        >>> dp = jdpim.sensitivity(scene, ("alpha",), "v", np.linspace(-1.0, 1.0, 9), points=points)
        >>> dp["alpha"].shape
        (9,)
    """
    if var not in VARIABLES:
        raise ValueError(f"var must be one of {VARIABLES}, got {var!r}")
    if mode not in ("forward", "reverse"):
        raise ValueError(f"mode must be 'forward' or 'reverse', got {mode!r}")
    if isinstance(bandwidth, str) and bandwidth != "adaptive":
        raise ValueError(f"bandwidth must be None, 'adaptive' or a number, got {bandwidth!r}")
    wrt = tuple(wrt)
    if not wrt:
        raise ValueError("wrt must name at least one parameter")
    bad = sorted(set(wrt) - set(parameter_names(scene)))
    if bad:
        raise ValueError(f"unknown parameter(s) {bad}; choose from {list(parameter_names(scene))}")
    if grid is None:
        raise ValueError("grid is required")
    t = scene.save_at[-1] if t is None else t
    scene.time_index(t)
    if points is None:
        points = dpim_points(scene, n_points)
    values = {name: _nominal(scene, name) for name in wrt}

    def pdf_of(values):
        return _density(dpim(with_parameters(scene, values), points=points), var, grid, t, bandwidth, rule)

    jac = jax.jacfwd if mode == "forward" else jax.jacrev
    return jac(pdf_of)(values)
