r"""First passage: ``P(max_{0 <= s <= t} q(s) > level)`` for every saved time ``t`` and every level.

``q`` is a coordinate of the state or a function of it. Sampling methods carry the running maximum of ``q``
along every step of every path (the start and the end of each step, not only the saved times); path
integration absorbs the density where ``q > level``.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._io import Labelled
from .._pytree import check_int, concrete, pytree_dataclass, real_array, static_field
from .._scene import Scene, parameter_value, saved_index, static_times
from ..methods._base import AbstractMethod
from ..methods._paths import NonFiniteWarning
from ._failure import AbstractFailureMethod


@dataclasses.dataclass(frozen=True)
class Coordinate:
    """The state's entry ``index`` (named ``name``) as a function of the state (hashable)."""

    name: str
    index: int

    def __call__(self, state):
        return state[self.index]


@dataclasses.dataclass(frozen=True)
class FirstPassageQuery:
    """The checked arguments of :func:`first_passage` that a method's ``first_passage`` answers."""

    quantity: Callable  # state (n_state,) -> scalar; hashable
    levels: np.ndarray  # (L,)
    wrt: tuple = ()  # parameter names to differentiate with respect to
    values: dict = dataclasses.field(default_factory=dict)  # their nominal values (floats)
    estimators: dict = dataclasses.field(default_factory=dict)  # name -> estimator
    estimator: Any = None  # the one the user gave (None: each method's default)


@pytree_dataclass
class FirstPassage(Labelled):
    r"""First-passage probabilities ``P(max_{s <= t} q(s) > level)``.

    Attributes:
        times: saved times, s: a tuple of ``S`` floats (pytree structure).
        levels: the levels, shape ``(L,)``.
        probability: shape ``(S, L)``: the probability that ``q`` has exceeded each level by each saved time,
            counted over the paths (or grid mass) that stayed finite.
        stderr: shape ``(S, L)``, the sampling standard error of ``probability`` (Monte Carlo:
            ``sqrt(sum_i w_i^2 (1_i - p)^2)``, i.e. ``sqrt(p (1 - p) / N)`` for ``N`` equal weights), or
            ``None`` where the method has none (DPIM points are not independent samples).
        lost_mass: shape ``(S, L)``: the probability carried by paths whose state turned non-finite by
            each saved time before they exceeded the level; they are left out of ``probability``, so the true
            value lies in ``[probability, probability + lost_mass]`` (a path that exceeded the level first counts
            as passed).
        method: the method's name.
        derivative: ``{name: (S, L) array}``, ``dP/dtheta`` for each parameter of ``wrt`` (``None`` without).
        derivative_stderr: ``{name: (S, L) array}``, their sampling standard errors (``None`` for DPIM and
            path integration).
        grid_error: shape ``(S, L)``, path integration with ``estimate_error=True``: ``|probability - the same on
            a grid twice as coarse|``, the estimated discretisation error; else ``None``.
        n_evaluations: responses computed (paths integrated) by subset simulation; ``None`` otherwise.
        n_replicates: the number ``R`` of DPIM replicates averaged (``first_passage(..., replicates=R)``): then
            ``probability`` and ``derivative`` are their means and ``stderr``, ``derivative_stderr`` the standard
            errors of the means (``std / sqrt(R)``); ``None`` otherwise.

    A pytree (leaves: ``levels``, ``probability``, ``stderr``, ``lost_mass``, the derivatives and
    ``grid_error``): it passes through ``jax.jit``.
    """

    times: tuple = static_field()
    levels: Any = None
    probability: Any = None
    stderr: Any = None
    lost_mass: Any = None
    method: str = static_field(default="monte_carlo")
    derivative: Any = None
    derivative_stderr: Any = None
    grid_error: Any = None
    n_evaluations: int | None = static_field(default=None)
    n_replicates: int | None = static_field(default=None)

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))

    def at(self, t: float | None = None):
        """``(probability, stderr)`` at the saved time ``t`` (``None``: the last), each ``(L,)``;
        ``stderr`` is ``None`` where the method has none."""
        i = len(self.times) - 1 if t is None else saved_index(self.times, t)
        return self.probability[i], None if self.stderr is None else self.stderr[i]

    @classmethod
    def mean_of(cls, runs: list[FirstPassage]) -> FirstPassage:
        """The mean of ``R >= 2`` independent replicates, with the standard errors of the means."""
        first, r = runs[0], len(runs)

        def mean_and_stderr(values):
            stack = jnp.stack(values)
            return jnp.mean(stack, axis=0), jnp.std(stack, axis=0, ddof=1) / np.sqrt(r)

        p, se = mean_and_stderr([run.probability for run in runs])
        lost, _ = mean_and_stderr([run.lost_mass for run in runs])
        derivative = derivative_stderr = None
        if first.derivative is not None:
            pairs = {n: mean_and_stderr([run.derivative[n] for run in runs]) for n in first.derivative}
            derivative, derivative_stderr = ({n: pair[i] for n, pair in pairs.items()} for i in (0, 1))
        return cls(first.times, first.levels, p, se, lost, first.method, derivative, derivative_stderr, n_replicates=r)

    @staticmethod
    def passed(tracked, levels):
        """``(N, S, L)``: 1 where a path's running maximum (:class:`jdpim._integrate.RunningMax` values
        ``(N, S, 2)``) exceeds a level, else 0."""
        maxima = tracked[..., 0]
        return (maxima[..., None] > jnp.asarray(levels, maxima.dtype)[None, None]).astype(maxima.dtype)

    @classmethod
    def from_tracked(cls, times, levels, tracked, weights, method: str, *, stderr: bool) -> FirstPassage:
        """From :class:`jdpim._integrate.RunningMax` values ``(N, S, 2)`` of ``N`` paths with probabilities
        ``weights`` ``(N,)``: a path has passed a level once its running maximum exceeds it (also if its state
        turned non-finite afterwards); a non-finite path that has not is lost."""
        maxima, bad = tracked[..., 0], tracked[..., 1] > 0
        hit = cls.passed(tracked, levels)
        # over the total weight summed the same way: float32 rounding of a sum of many weights (1e-4 at 2e4
        # paths) then cancels, and a level every path passes gives exactly 1
        p = jnp.einsum("n,nsl->sl", weights, hit) / jnp.einsum("n,nsl->sl", weights, jnp.ones_like(hit))
        se = jnp.sqrt(jnp.einsum("n,nsl->sl", weights * weights, (hit - p[None]) ** 2)) if stderr else None
        lost = jnp.einsum("n,nsl->sl", weights, (1.0 - hit) * bad[..., None])
        return cls(times, jnp.asarray(levels, maxima.dtype), p, se, lost, method)


def _quantity(scene: Scene, var) -> Callable:
    names = scene.model.coordinates
    if callable(var):
        try:
            shape = jax.eval_shape(var, jax.ShapeDtypeStruct((len(names),), scene.float_dtype)).shape
        except Exception as e:  # noqa: BLE001  (any failure of the user's function on a state is reported as one)
            raise ValueError(
                f"var must be a function of the state (shape ({len(names)},)); calling it failed: {e}"
            ) from None
        if shape not in ((), (1,)):
            raise ValueError(f"var must return a scalar for a state of shape ({len(names)},), got shape {shape}")
        return var
    if not isinstance(var, str) or var not in names:
        raise ValueError(f"var must be one of the coordinates {names} or a function of the state, got {var!r}")
    return Coordinate(var, names.index(var))


def _levels(scene: Scene, var, level) -> np.ndarray:
    levels = np.atleast_1d(real_array("level", level, "a number or a 1-D sequence of numbers"))
    if levels.ndim != 1 or levels.size == 0:
        raise ValueError(f"level must be a number or a non-empty 1-D sequence of numbers, got shape {levels.shape}")
    if not np.all(np.isfinite(levels)):
        raise ValueError(f"level must be finite, got {levels.tolist()}")
    bounds = scene.model.bounds()
    bound = bounds.get(var) if isinstance(bounds, dict) and isinstance(var, str) else (bounds if var == "x" else None)
    bound = None if bound is None else concrete(bound)
    if bound is not None and np.any(levels <= float(bound)):
        low = levels[levels <= float(bound)].tolist()
        raise ValueError(
            f"level {low} is at or below the lower bound of {var!r} ({float(bound):g}, a barrier): {var} exceeds it "
            "on every path from the start; choose levels above it"
        )
    return levels


def _derivatives(scene: Scene, wrt, estimator) -> tuple:
    """``(wrt, values, estimators)``: the checked names, their nominal values and each one's estimator."""
    from ..sensitivities._estimators import AbstractEstimator, CentralDifference, LikelihoodRatio

    wrt = (wrt,) if isinstance(wrt, str) else wrt
    if not isinstance(wrt, (tuple, list)) or not all(isinstance(n, str) for n in wrt):
        raise TypeError(f"wrt must be a parameter name or a sequence of them, got {wrt!r}")
    if estimator is not None and not isinstance(estimator, AbstractEstimator):
        raise TypeError(f"estimator must be None or an estimator such as jdpim.CentralDifference(), got {estimator!r}")
    values, estimators = {}, {}
    for name in dict.fromkeys(wrt):
        value = concrete(parameter_value(scene, name))
        if any(n == name for n, _ in scene.random):
            raise ValueError(f"parameter {name!r} is random in this scene: no derivative with respect to it")
        if value is None or np.ndim(value) != 0:
            raise ValueError(f"parameter {name!r} must be a number to differentiate with respect to")
        values[name] = float(value)
        est = estimator
        if est is None:  # the likelihood ratio where it applies (no step, no 1/step variance), else differences
            est = CentralDifference()
            try:
                LikelihoodRatio().check(scene, name)
                est = LikelihoodRatio()
            except ValueError:
                pass
        est.check(scene, name)
        estimators[name] = est
    return tuple(values), values, estimators


def first_passage(
    scene: Scene,
    var,
    level,
    method: AbstractMethod | AbstractFailureMethod,
    *,
    wrt=(),
    estimator=None,
    replicates: int | None = None,
) -> FirstPassage:
    r"""The probability that ``var`` has exceeded ``level`` at some time in ``[0, t]``, for every saved ``t``.

    ``P_f(t) = P(max_{0 <= s <= t} q(s) > level)``, the first-passage (failure) probability of the safe domain
    ``q <= level``. For a lower level, pass ``-q`` (e.g. ``lambda s: -s[0]``); for a two-sided domain
    ``|q| <= level``, ``lambda s: abs(s[0])``.

    Args:
        scene: the physics (:class:`jdpim.Scene`); the probabilities are given at its saved times.
        var: a coordinate name (``"x"``, ``"v"``, ``"x1"``, ...) or a function of the state
            ``f(state) -> scalar`` (``state``: shape ``(n_state,)``, as for densities).
        level: one level or a 1-D sequence of levels (finite; above the lower bound of a coordinate that a
            barrier bounds).
        method: ``jdpim.MonteCarlo(...)`` (with standard errors) or ``jdpim.DPIM(...)``: the running maximum
            of ``var`` over the start and the end of every time step of every path; or
            ``jdpim.PathIntegration(...)`` (one degree of freedom): the transient density absorbed where
            ``var > level`` after every step (``estimate_error=True`` adds ``FirstPassage.grid_error``); or
            ``jdpim.SubsetSimulation(...)`` for small probabilities at the last saved time (its derivatives:
            ``docs/reliability.md``).
        wrt: parameter names (``jdpim.parameter_names(scene)``) to differentiate ``P`` with respect to.
        estimator: how, for every name of ``wrt``: ``None`` (the default) takes ``jdpim.LikelihoodRatio()`` for
            drift parameters with one noise source (``E[1 (S - Sbar)]`` with the score ``S`` of the whole
            history; no step), for several degrees of freedom those whose change of the acceleration lies along
            the noise's direction (``damping[0,0]`` of a primary mass the noise drives), and
            ``jdpim.CentralDifference()`` otherwise (``r``, ``D``, the gains, constraints, entries acting on
            coordinates the noise does not drive: two runs with common random numbers, the same seed or point
            set). Standard errors (Monte Carlo) come from the per-path contributions. Path integration takes no
            estimator: it differentiates its absorbed steps by ``jax.jacfwd`` (every parameter but the barrier),
            holding its grid fixed.
        replicates: DPIM only: ``R >= 2`` runs on independent randomised point sets of the method's size
            (:func:`jdpim.randomised_points`, seeds ``0 .. R - 1``), averaged, with the standard errors of the
            means from their spread (``R`` times the cost of one run). ``None``: one run on the method's points,
            without an error estimate.

    Returns:
        :class:`FirstPassage`: ``probability`` and ``stderr`` of shape ``(S, L)``.

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=5.0, dt=0.01, save_at=(1.0, 5.0))
        >>> fp = jdpim.first_passage(scene, "x", [0.1, 0.3], jdpim.MonteCarlo(n_samples=2000, seed=0))
        >>> fp.probability.shape, bool(fp.probability[1, 0] >= fp.probability[0, 0])
        ((2, 2), True)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if not isinstance(method, (AbstractMethod, AbstractFailureMethod)):
        raise TypeError(f"method must be a jdpim method object, e.g. jdpim.MonteCarlo(), got {method!r}")
    query = FirstPassageQuery(
        _quantity(scene, var), _levels(scene, var, level), *_derivatives(scene, wrt, estimator), estimator
    )
    if replicates is None:
        out = method.first_passage(scene, query)
    else:
        replicates = check_int("replicates", replicates, low=2)
        out = FirstPassage.mean_of([method.replicate(scene, k).first_passage(scene, query) for k in range(replicates)])
    lost = concrete(out.lost_mass)
    if lost is not None and lost.any():
        warnings.warn(
            f"probability up to {float(lost.max()):.3g} is carried by paths whose state turned non-finite before "
            "they passed a level; it is left out of FirstPassage.probability (FirstPassage.lost_mass). Reduce dt "
            "or the excitation level, or sub-step stiff steps (Scene(..., substeps=jdpim.Substeps())).",
            NonFiniteWarning,
            stacklevel=2,
        )
    return out
