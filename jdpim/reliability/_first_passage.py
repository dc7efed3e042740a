r"""First passage: ``P(max_{0 <= s <= t} q(s) > level)`` for every saved time ``t`` and every level.

``q`` is a coordinate of the state or a function of it. Sampling methods carry the running maximum of ``q``
along every step of every path (the start and the end of each step, not only the saved times); path
integration absorbs the density where ``q > level``.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable

import jax
import numpy as np

from .._checkpoint import session
from .._pytree import check_int, concrete, real_array
from .._scene import Scene, parameter_value
from ..methods._base import AbstractMethod
from ..methods._path_integration import PathIntegration
from ..methods._paths import NonFiniteWarning, SamplingMethod
from ._absorbing import absorbing_first_passage
from ._failure import AbstractFailureMethod
from ._passage import Coordinate, FirstPassage, FirstPassageQuery
from ._sampled import sampled_first_passage


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


def checked_levels(scene: Scene, var, level) -> np.ndarray:
    """``level`` as a 1-D array of finite levels above the lower bound of ``var`` (refused in one line otherwise)."""
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
        est.check_first_passage()  # before any path runs
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
    checkpoint=None,
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
        checkpoint: Monte Carlo, DPIM and subset simulation: a directory or a :class:`jdpim.Checkpoint` where
            every finished block of paths (subset simulation: every level) is written; the same call after an
            interruption loads them and runs only the rest, with the same result bit for bit. The part files are
            deleted when the run finishes (``docs/persistence.md``).

    Returns:
        :class:`FirstPassage`: ``probability`` and ``probability_stderr`` of shape ``(S, L)``.

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.01, save_at=(1.0, 2.0))
        >>> fp = jdpim.first_passage(scene, "x", [0.1, 0.2], jdpim.MonteCarlo(n_samples=400, seed=0))
        >>> fp.probability.shape, bool(fp.probability[1, 0] >= fp.probability[0, 0])
        ((2, 2), True)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if not isinstance(method, (AbstractMethod, AbstractFailureMethod)):
        raise TypeError(f"method must be a jdpim method object, e.g. jdpim.MonteCarlo(), got {method!r}")
    query = FirstPassageQuery(
        _quantity(scene, var), checked_levels(scene, var, level), *_derivatives(scene, wrt, estimator), estimator
    )
    if replicates is not None:
        replicates = check_int("replicates", replicates, low=2)
    if checkpoint is not None and not method.resumable:
        raise ValueError(
            "checkpoint applies to jdpim.MonteCarlo, jdpim.DPIM and jdpim.SubsetSimulation, not "
            f"{type(method).__name__}"
        )
    question = ("first_passage", var if isinstance(var, str) else getattr(var, "__qualname__", repr(var)),
                query.levels, query.wrt, repr(estimator), replicates)  # fmt: skip
    with session(checkpoint, scene=scene, method=method, question=question) as ses:
        query = dataclasses.replace(query, checkpoint=ses)
        if replicates is None:
            out = _answer(scene, method, query)
        else:
            out = FirstPassage.mean_of([_answer(scene, method.replicate(scene, k), query) for k in range(replicates)])
    lost = concrete(out.lost_mass)
    if lost is not None and lost.any():
        warnings.warn(
            f"probability up to {float(lost.max()):.3g} is carried by paths whose state turned non-finite or "
            "diverged before they passed a level; it is left out of FirstPassage.probability "
            "(FirstPassage.lost_mass). Reduce dt or the excitation level, or sub-step stiff steps "
            "(Scene(..., substeps=jdpim.Substeps())).",
            NonFiniteWarning,
            stacklevel=2,
        )
    return out


def _answer(scene: Scene, method: AbstractMethod | AbstractFailureMethod, query: FirstPassageQuery) -> FirstPassage:
    """``query`` answered through the primitive ``method`` offers: a sampling method's paths with the running
    maximum tracked along them, path integration's step operator with absorption, or a method for failure
    probabilities (subset simulation) that answers it itself."""
    if isinstance(method, SamplingMethod):
        return sampled_first_passage(method, scene, query)
    if isinstance(method, PathIntegration):
        return absorbing_first_passage(scene, method, query)
    if isinstance(method, AbstractFailureMethod):
        return method.first_passage(scene, query)
    raise ValueError(
        f"{type(method).__name__} does not compute first-passage probabilities; use jdpim.MonteCarlo or jdpim.DPIM"
    )
