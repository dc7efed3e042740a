r"""Estimators of PDF sensitivities ``dp(y, t) / d theta`` that stay bounded at every horizon.

Each estimator writes the derivative as a weighted sum of per-path contributions
``dp/dtheta(y) ~ sum_i w_i c_i(y)`` (``w_i = 1/N`` for Monte Carlo, ``P_q`` for DPIM), which also gives a
standard error ``sqrt(sum_i w_i^2 (c_i - dp/dtheta)^2)`` (exact for Monte Carlo; a heuristic for DPIM's
deterministic points). ``K(y, Y)`` is the density's kernel (reflected at the barrier).

- :class:`LikelihoodRatio` (drift parameters: ``alpha``, ``gamma``, ``omega``, drift entries of
  ``Oscillator.params``): ``c_i = K(y, Y_i) (S_i - Sbar)`` with the Girsanov score of the last window
  ``tau``, ``S = [sum d_theta b / h * dW - c D sum h d_v(d_theta b / h) dt] / (2 D)``.
- :class:`NoiseScaling` (``D`` of :class:`VibroImpactOscillator` with the barrier at 0, started at rest):
  ``p(x; D, gamma) = D^-1/2 q(x / sqrt D; gamma D)`` gives
  ``dp/dD = -(1/2D) sum_j d_j(y_j p) + (gamma / D) dp/dgamma``, so ``c_i = Y_i . grad_Y K / (2 D) + gamma/D c_i^gamma``.
- :class:`CentralDifference` (any parameter but ``barrier``; the default for ``r``): common random numbers,
  ``c_i = (K(y, Y_i(theta + d)) - K(y, Y_i(theta - d))) / 2d``.
- :class:`Pathwise`: AD through the whole pipeline, ``c_i = grad_Y K(y, Y_i) . dY_i/dtheta``; exact for the
  computed density but its tangents grow without bound across impacts, so trusted only over short horizons (a
  warning beyond, and wherever few paths carry the derivative).

Each estimator carries its own behaviour (:class:`AbstractEstimator`): ``check`` refuses a parameter or scene it
does not apply to, ``scores_needed`` names the Girsanov score sums to accumulate along the common paths, and
``estimate`` returns ``(value, stderr)`` from the shared paths (``sensitivities._sensitivity.PathContext``).
:class:`Pathwise` is ``joint``: its parameters are differentiated together through the pipeline instead.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np

from .._models import AbstractOscillator, Oscillator, VibroImpactOscillator
from .._pytree import check_real, concrete
from .._scene import get_parameter, set_parameter
from .._tangents import STDERR_WARN
from .._warnings import SensitivityWarning as SensitivityWarning

DRIFT_EXCLUDED = ("r", "barrier", "D")


class AbstractEstimator:
    """Base of the estimators of ``dp(y, t) / d theta`` for one parameter.

    A per-path estimator (``joint = False``) implements ``estimate(ctx, name) -> (value, stderr)``: arrays shaped
    like the PDF, in PDF units per parameter unit, from the common paths of ``ctx``
    (``sensitivities._sensitivity.PathContext``). A joint one (:class:`Pathwise`) is differentiated with the
    other joint parameters through the whole pipeline.
    """

    joint: ClassVar[bool] = False

    def check(self, scene, name: str) -> None:
        """Raise ``ValueError`` unless the estimator applies to parameter ``name`` of ``scene``."""

    def scores_needed(self, name: str, scene) -> dict:
        """``{parameter: LikelihoodRatio}``: score sums to accumulate along the paths, with their settings."""
        return {}

    def check_first_passage(self) -> None:
        """Raise ``ValueError`` unless the estimator gives first-passage derivatives (overrides
        :meth:`first_passage`): checked when the question is asked, before any path runs."""
        if type(self).first_passage is AbstractEstimator.first_passage:
            self.first_passage(None, "")

    def first_passage(self, ctx, name: str):
        """``(N, S, L)`` per-path contributions to ``dP/dtheta`` of first-passage probabilities
        (``ctx``: ``reliability._sampled.PassageContext``)."""
        raise ValueError(
            f"{type(self).__name__} does not estimate first-passage derivatives; use jdpim.LikelihoodRatio() "
            "(drift parameters) or jdpim.CentralDifference()"
        )


@dataclasses.dataclass(frozen=True)
class Pathwise(AbstractEstimator):
    """Differentiate the pipeline itself: exact for the computed density.

    Forward mode gives each path's tangent at ``t``, so the derivative is a sum of per-path contributions
    ``c_i = grad_Y K(y, Y_i) . dY_i/dtheta`` with a standard error like the other estimators'; a derivative carried
    by few paths is flagged (``jdpim._tangents``).

    Args:
        mode: ``"forward"`` (cheap for few parameters; with a standard error) or ``"reverse"`` (``jax.jacrev`` of
            the density; no standard error: NaN).
        horizon: seconds (> 0) beyond which pathwise derivatives of a model with a barrier are not trusted
            (tangents grow across impacts: about 1e-5 relative error at t = 2, 6e-3 at t = 8, O(10) at t = 12);
            later times give a :class:`SensitivityWarning`.
    """

    joint: ClassVar[bool] = True
    mode: str = "forward"
    horizon: float = 4.0

    def __post_init__(self):
        if self.mode not in ("forward", "reverse"):
            raise ValueError(f"mode must be 'forward' or 'reverse', got {self.mode!r}")
        check_real("horizon", self.horizon, low=0.0, low_open=True)


@dataclasses.dataclass(frozen=True)
class LikelihoodRatio(AbstractEstimator):
    r"""Centred, truncated likelihood-ratio (Girsanov score) estimator for drift parameters.

    Args:
        window: length ``tau`` in s of the score window, or ``None`` for ``4 / alpha`` (the truncation bias
            decays like ``exp(-alpha tau)``; ``alpha`` is the model's field or ``Oscillator.params["alpha"]``),
            or the whole history when there is no positive ``alpha``.
            For ``t <= tau`` the whole history is used (exact from a deterministic start).
        ito_correction: subtract the Wong-Zakai term ``c D sum h d_v(d_theta b / h) dt``; the fraction
            ``c = 1 - Var(dW) / (2 D dt)`` (about 0.43 at the default cutoff ``2 / dt``) measures how far
            left-point sums over the band-limited excitation are from Ito sums.
    """

    window: float | None = None
    ito_correction: bool = True

    def __post_init__(self):
        if self.window is not None:
            check_real("window", self.window, low=0.0, low_open=True)

    def check(self, scene, name: str) -> None:
        check_likelihood_ratio(scene, name)

    def scores_needed(self, name: str, scene) -> dict:
        return {name: self}

    def first_passage(self, ctx, name: str):
        """``c_i = (1_i - P) (S_i - Sbar)``: the centred passage indicator times the centred score of the whole
        history. Its mean is that of ``1_i (S_i - Sbar)`` (the scores' mean is zero); its spread is the sample
        covariance's, whose variance ``1_i (S_i - Sbar)`` overstates by about ``1 / (1 - P)``."""
        return (ctx.passed - ctx.probability[None]) * ctx.scores[name][..., None]

    def check_first_passage(self) -> None:
        """First passage depends on the whole history: a windowed score does not apply."""
        if self.window is not None:
            raise ValueError(
                f"first passage depends on the whole history: LikelihoodRatio(window={self.window!r}) does not "
                "apply; leave window=None"
            )

    def estimate(self, ctx, name: str):
        """``c_i = K(y, Y_i) (S_i - Sbar)`` with the centred score of ``name``."""

        def contribution(x, v, s):
            return ctx.kern(x, v) * ctx.per_path(s)

        return ctx.moments(contribution, (ctx.x, ctx.v, ctx.scores[name]))


@dataclasses.dataclass(frozen=True)
class NoiseScaling(AbstractEstimator):
    """``dp/dD`` from the exact scaling of :class:`VibroImpactOscillator` (barrier 0, start at rest).

    Args:
        gamma: estimator of the ``dp/dgamma`` term (used when the model has cubic damping).
    """

    gamma: LikelihoodRatio = LikelihoodRatio()

    def check(self, scene, name: str) -> None:
        if name != "D":
            raise ValueError(f"NoiseScaling estimates dp/dD only, not {name!r}")
        reason = noise_scaling_applies(scene)
        if reason is not None:
            raise ValueError(f"NoiseScaling does not apply: {reason}; use CentralDifference for D")
        if scene.model.gamma is not None:
            self.gamma.check(scene, "gamma")

    def scores_needed(self, name: str, scene) -> dict:
        return {} if scene.model.gamma is None else {"gamma": self.gamma}

    def estimate(self, ctx, name: str):
        """``c_i = Y_i . grad_Y K / (2 D) + gamma / D c_i^gamma``."""
        dtype = ctx.scene.float_dtype
        D = jnp.asarray(ctx.scene.noise.D, dtype)
        gamma = ctx.scene.model.gamma
        coef = 0.0 if gamma is None else jnp.asarray(gamma, dtype) / D

        def contribution(x, v, s):
            k, ydk = jax.jvp(ctx.kern, (x, v), (x, v))
            return ydk / (2.0 * D) + coef * k * ctx.per_path(s)

        return ctx.moments(contribution, (ctx.x, ctx.v, ctx.scores.get("gamma", jnp.zeros_like(ctx.x))))


@dataclasses.dataclass(frozen=True)
class CentralDifference(AbstractEstimator):
    """Central differences with common random numbers (the same seed or the same point set).

    Args:
        step: half step ``d`` (> 0) in parameter units, or ``None`` for ``0.01`` for ``r`` and ``0.05 max(|theta|,
            1e-2)`` otherwise. Near a bound (``r <= 1``, ``alpha >= 0``) the pair is shifted inside it. Paths that
            switch (stick or not, graze or not) make per-path differences jump, with a variance ~ 1/d: a 1 %
            step gave a standard error of 4.9 (relative) for dp/dalpha at t = 10 from rest with 2000 paths.
    """

    step: float | None = None

    def __post_init__(self):
        if self.step is not None:
            check_real("step", self.step, low=0.0, low_open=True)

    def check(self, scene, name: str) -> None:
        if name == "barrier":
            raise ValueError(
                "CentralDifference with respect to the barrier moves the kernel's reflection: not supported"
            )

    def estimate(self, ctx, name: str):
        """``c_i = (K(y, Y_i(hi)) - K(y, Y_i(lo))) / (hi - lo)`` over the common paths rerun at both ends."""
        lo, hi = self.pair(name, float(ctx.values[name]))
        w, (a, b) = ctx.rerun(name, (lo, hi))

        def contribution(xa, va, xb, vb):
            return (ctx.kern(xb, vb) - ctx.kern(xa, va)) / (hi - lo)

        return ctx.moments(contribution, (a[:, 0], a[:, 1], b[:, 0], b[:, 1]), w)

    def first_passage(self, ctx, name: str):
        """``c_i = (1_i(hi) - 1_i(lo)) / (hi - lo)`` over the common paths rerun at both ends."""
        lo, hi = self.pair(name, ctx.values[name])
        return (ctx.rerun(name, hi) - ctx.rerun(name, lo)) / (hi - lo)

    def pair(self, name: str, value: float) -> tuple[float, float]:
        """The two parameter values ``(lo, hi)`` of the difference, inside the parameter's range."""
        restitution = name == "r" or name.endswith("].r")  # the oscillator's r, or a constraint's
        d = self.step if self.step is not None else (0.01 if restitution else 0.05 * max(abs(value), 1e-2))
        bounds = {"alpha": (0.0, math.inf), "gamma": (0.0, math.inf), "D": (0.0, math.inf)}
        low, high = (0.0, 1.0) if restitution else bounds.get(name, (-math.inf, math.inf))
        lo, hi = value - d, value + d
        if hi > high:
            lo, hi = high - 2 * d, high
        if lo < low:
            lo, hi = low, low + 2 * d
        return lo, hi


def drift_derivative(model, name: str, x, v):
    """``d_theta b(x, v)`` with ``b = -g(x) - f(x, v)`` the deterministic acceleration (one path).

    One degree of freedom: ``x``, ``v`` scalars, a scalar result; several (``x``, ``v`` of shape ``(d,)``): the
    derivative of the acceleration without noise, ``(d,)``.
    """
    value = jnp.asarray(get_parameter(model, name), jnp.result_type(v))

    def b(p):
        changed = set_parameter(model, name, p)
        if isinstance(model, AbstractOscillator):
            return changed.acceleration(x, v, jnp.zeros((1,), jnp.result_type(v)))
        return changed.state_acceleration(x, v, jnp.zeros((model.n_sources,), jnp.result_type(v)))

    return jax.jvp(b, (value,), (jnp.ones_like(value),))[1]


def noise_direction(model, q, v):
    """``g``, ``(d,)``: the acceleration per unit of the single noise source of a model of several degrees of
    freedom (``M^-1 B[:, 0]``; the acceleration is affine in the noise)."""
    dtype = jnp.result_type(v)

    def a(xi):
        return model.state_acceleration(q, v, xi)

    return jax.jvp(a, (jnp.zeros((1,), dtype),), (jnp.ones((1,), dtype),))[1]


@dataclasses.dataclass(frozen=True)
class Score:
    """Per-step increments of the score sums (hashable, for ``jdpim._integrate.Sums``).

    For each name, with ``u = d_theta b / h`` the drift's change per unit of noise: ``sum u dW`` and
    ``sum (h . grad_v u) dt``; then ``sum dW^2``. One degree of freedom: ``h`` the gain; several: ``h`` the
    noise direction ``g`` (:func:`noise_direction`) and ``u = g . d_theta b / |g|^2``, exact where
    ``d_theta b`` lies along ``g`` (:func:`check_likelihood_ratio`).
    """

    names: tuple[str, ...]
    dt: float

    def __call__(self, model, x, v, dw):
        if not isinstance(model, AbstractOscillator):
            return self._several(model, x, v, dw)
        x, v = x[0], v[0]  # one degree of freedom: the state's vectors have one entry
        h = model.gains(x, v)[0]
        out = []
        for name in self.names:

            def g(v, name=name):
                return drift_derivative(model, name, x, v) / model.gains(x, v)[0]

            gv, dgv = jax.jvp(g, (v,), (jnp.ones_like(v),))
            out += [gv * dw[0], h * dgv * self.dt]
        return jnp.stack([*out, dw[0] ** 2])

    def _several(self, model, q, v, dw):
        g = noise_direction(model, q, v)
        out = []
        for name in self.names:

            def u(v, name=name):
                return jnp.dot(g, drift_derivative(model, name, q, v)) / jnp.dot(g, g)

            uv, duv = jax.jvp(u, (v,), (g,))
            out += [uv * dw[0], duv * self.dt]
        return jnp.stack([*out, dw[0] ** 2])


def check_likelihood_ratio(scene, name: str) -> None:
    """Raise unless the score applies: one noise source, a drift parameter that leaves the gains alone and, for
    several degrees of freedom, changes the acceleration only along the noise's direction."""
    if name in DRIFT_EXCLUDED or name.startswith("constraints["):
        raise ValueError(f"LikelihoodRatio applies to drift parameters only, not {name!r}; use CentralDifference")
    if scene.n_sources != 1:
        raise ValueError(f"LikelihoodRatio needs one noise source, the scene has {scene.n_sources}")
    scene.noise.require_stationary("LikelihoodRatio (its score divides by D)", "use CentralDifference")
    if scene.model.time_dependent:
        raise ValueError("LikelihoodRatio needs a model whose forces do not depend on the time; use CentralDifference")
    if any(n == name for n, _ in scene.random):
        raise ValueError(f"parameter {name!r} is random in this scene; use CentralDifference")
    D = concrete(scene.noise.D)
    if D is not None and not np.any(D != 0):
        raise ValueError("the noise intensity D is 0: no likelihood ratio (its score divides by D)")
    model = scene.model
    value = jnp.asarray(get_parameter(model, name), scene.float_dtype)
    if isinstance(model, AbstractOscillator):

        def gain(p):
            return set_parameter(model, name, p).gains(jnp.asarray(0.3, value.dtype), jnp.asarray(0.7, value.dtype))

    else:
        d = model.dimension
        q = 0.3 + 0.1 * jnp.arange(d, dtype=value.dtype)  # test states: the checks are structural
        v = 0.7 - 0.2 * jnp.arange(d, dtype=value.dtype)

        def gain(p):
            return noise_direction(set_parameter(model, name, p), q, v)

    if jnp.any(jax.jvp(gain, (value,), (jnp.ones_like(value),))[1] != 0):
        raise ValueError(f"parameter {name!r} changes the noise gains: no likelihood ratio; use CentralDifference")
    if not isinstance(model, AbstractOscillator):
        g, db = noise_direction(model, q, v), drift_derivative(model, name, q, v)
        if not jnp.any(g != 0):
            raise ValueError("the noise gains are zero: no likelihood ratio; use CentralDifference")
        off = db - g * jnp.dot(g, db) / jnp.dot(g, g)
        if jnp.max(jnp.abs(off)) > 1e-5 * jnp.max(jnp.abs(db)):
            driven = [c for c, gc in zip(model.coordinates, g, strict=False) if gc != 0]
            raise ValueError(
                f"parameter {name!r} changes the acceleration of coordinates the noise does not drive (it drives "
                f"{driven}): no likelihood ratio; use CentralDifference"
            )


def warn_if_noisy(name: str, value, stderr, stacklevel: int) -> None:
    """Warn (:class:`SensitivityWarning`) where the standard error of a sampled ``dp/d name`` exceeds
    ``STDERR_WARN`` of its size (relative L2); ``stacklevel`` points the warning at the user's call."""
    size, error = float(jnp.linalg.norm(value)), float(jnp.linalg.norm(stderr))
    rel = error / size if size > 0 else (0.0 if error == 0 else math.inf)  # zero with no error: not noisy
    if not rel < STDERR_WARN:
        warnings.warn(
            f"dp/d{name}: standard error {rel:.2g} of the value (relative L2): it falls like 1/sqrt(paths); "
            f"5 % at stationarity takes about 1e5 paths or points for drift parameters and 3e5 for D at "
            "bandwidth 0.1 (n_samples / n_points), a wider bandwidth, or method=jdpim.PathIntegration() "
            "(one-degree-of-freedom scenes, no sampling error)",
            SensitivityWarning,
            stacklevel=stacklevel + 1,
        )


def noise_scaling_applies(scene) -> str | None:
    """``None`` if :class:`NoiseScaling` applies to ``scene``, else the reason."""
    m = scene.model
    if not isinstance(m, VibroImpactOscillator):
        return "the model is not a VibroImpactOscillator"
    if m.barrier is not None and (not isinstance(m.barrier, (int, float)) or m.barrier != 0):
        return f"the barrier is at {m.barrier!r}, not 0"
    if scene.x0 not in (None, 0, 0.0) or not isinstance(scene.v0, (int, float)) or scene.v0 != 0:
        return "the start is not at rest at 0"
    if scene.random:
        return "the scene has random parameters"
    if scene.n_sources != 1:
        return "the noise has several sources"
    if scene.noise.envelope is not None:
        return "the noise is modulated (its intensity varies in time)"
    if m.time_dependent:
        return "the model's forces depend on the time"
    return None


def window_of(estimator: LikelihoodRatio, model) -> float:
    """The score window in s (``inf`` for the whole history)."""
    if estimator.window is not None:
        return float(estimator.window)
    alpha = getattr(model, "alpha", None)
    if isinstance(model, Oscillator) and isinstance(model.params, dict):
        alpha = model.params.get("alpha")
    try:
        alpha = float(alpha)
    except (TypeError, ValueError):
        return math.inf
    return 4.0 / alpha if alpha > 0 else math.inf
