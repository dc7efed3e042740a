r"""Design by gradient: minimise a statistic estimated with standard errors over bounded design parameters.

An objective built from jdpim statistics (a failure probability, an RMS, an expected number of impacts) is
known only through estimates: a value and a gradient, each with a standard error. :func:`minimise` runs an
optax optimiser on them with

- common random numbers: the objective is asked for batch ``k`` with the seed ``seed + k`` at every design, so
  the difference between two designs carries no sampling noise of its own;
- a sample size that grows as the optimiser converges: the batches at a design are averaged (their standard
  errors combined as those of independent means); while every component of the projected gradient lies within
  two standard errors of zero, the number of batches doubles, up to ``max_batches``, at the same design (the
  batches already drawn are kept). Batches of one size keep one compiled program: growing them never
  recompiles;
- bounds: after every step the design is projected onto the box (``x <- clip(x, low, high)``), and a gradient
  component that points out of an active bound counts as zero (a component that does so by more than two
  standard errors is settled: it asks for no larger sample).

The run stops when no component of the projected gradient is more than two standard errors from zero and either
every component's sign is settled or the sample is the largest (``max_batches``); or after ``max_steps`` steps.
Such a stop shows only that no slope larger than two standard errors is there: with ``gradient_tol`` it counts as
``converged`` only where those two standard errors are within ``gradient_tol``, so that a gradient lost in the
noise of too small a sample is not taken for a flat one (``converged=False``, and a :class:`DesignWarning` says
how large a slope the sample could have missed).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable

import numpy as np
import optax

from ._pytree import check_int, real_array

Z_STOP = 2.0  # a gradient component within this many standard errors of zero is not distinguished from it


class DesignWarning(UserWarning):
    """:func:`minimise` stopped where the gradient is not distinguished from zero, but its sample could miss a
    slope larger than ``gradient_tol``."""


@dataclasses.dataclass(frozen=True)
class Design:
    """The result of :func:`minimise`: the last design and its estimates, and the path the optimiser took.

    Attributes:
        x: ``(P,)``, the last design (inside the bounds).
        value, value_stderr: the objective at ``x`` and its standard error (the average of ``batches[-1]``
            batches).
        gradient, gradient_stderr: ``(P,)``, its gradient and their standard errors at ``x``.
        converged: ``True`` when the projected gradient is within two standard errors of zero, at the largest
            sample (``max_batches``) unless only active bounds stop it, and (with ``gradient_tol``) those two
            standard errors are within ``gradient_tol``; ``False`` when the run stopped after ``max_steps`` steps
            or on a gradient its sample does not resolve.
        history_x: ``(K, P)``, the designs visited (one row per step, the last is ``x``).
        history_value, history_value_stderr: ``(K,)``, the objective at each.
        batches: ``(K,)``, the number of batches averaged at each.
        n_evaluations: the number of calls of the objective (batches drawn), the cost of the run.
    """

    x: np.ndarray
    value: float
    value_stderr: float
    gradient: np.ndarray
    gradient_stderr: np.ndarray
    converged: bool
    history_x: np.ndarray
    history_value: np.ndarray
    history_value_stderr: np.ndarray
    batches: np.ndarray
    n_evaluations: int


def _bounds(x0, bounds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x = real_array("x0", x0, "a number or a 1-D sequence of numbers")
    x = np.atleast_1d(x)
    if x.ndim != 1 or not np.all(np.isfinite(x)):
        raise ValueError(f"x0 must be a finite number or 1-D sequence of finite numbers, got {np.asarray(x0).tolist()}")
    b = real_array("bounds", bounds, "a sequence of (low, high) pairs, one per design parameter")
    b = b.reshape(1, -1) if b.ndim == 1 else b
    if b.shape != (x.size, 2):
        raise ValueError(f"bounds must be {x.size} (low, high) pairs (one per entry of x0), got shape {b.shape}")
    low, high = b[:, 0], b[:, 1]
    if np.any(np.isnan(b)) or np.any(low >= high):
        raise ValueError(f"bounds must be pairs with low < high, got {b.tolist()}")
    if np.any(x < low) or np.any(x > high):
        raise ValueError(f"x0 {x.tolist()} must lie inside bounds {b.tolist()}")
    return x, low, high


def _estimate(objective: Callable, x: np.ndarray, seed: int) -> np.ndarray:
    """One batch ``(value, value_stderr, *gradient, *gradient_stderr)`` as a ``(2 + 2P,)`` row, checked."""
    out = objective(x.copy(), seed)
    if not isinstance(out, (tuple, list)) or len(out) != 4:
        raise ValueError(
            f"objective(x, seed) must return (value, value_stderr, gradient, gradient_stderr), got {type(out).__name__}"
        )
    value, value_se, grad, grad_se = (np.asarray(o, dtype=float) for o in out)
    p = x.size
    if value.size != 1 or value_se.size != 1 or grad.size != p or grad_se.size != p:
        raise ValueError(
            f"objective(x, seed) must return a value, its stderr and a gradient and its stderrs of {p} entries, got "
            f"sizes {value.size}, {value_se.size}, {grad.size}, {grad_se.size}"
        )
    row = np.concatenate([value.ravel(), value_se.ravel(), grad.ravel(), grad_se.ravel()])
    if not np.all(np.isfinite(row)) or np.any(row[1] < 0) or np.any(grad_se < 0):
        raise ValueError(f"objective(x={x.tolist()}, seed={seed}) returned a non-finite or negative-stderr estimate")
    return row


def _average(rows: list[np.ndarray], p: int):
    """The mean of independent batch estimates and its standard errors ``sqrt(sum se_k^2) / K``."""
    rows = np.stack(rows)
    k = rows.shape[0]
    value, grad = rows[:, 0].mean(), rows[:, 2 : 2 + p].mean(axis=0)
    value_se = np.sqrt(np.sum(rows[:, 1] ** 2)) / k
    grad_se = np.sqrt(np.sum(rows[:, 2 + p :] ** 2, axis=0)) / k
    return value, value_se, grad, grad_se


def _projected(grad: np.ndarray, x: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The gradient with the components that point out of an active bound set to zero (descent: ``-grad``)."""
    out_low = (x <= low) & (grad > 0)
    out_high = (x >= high) & (grad < 0)
    return np.where(out_low | out_high, 0.0, grad)


def minimise(
    objective: Callable,
    x0,
    bounds,
    optimiser: optax.GradientTransformation,
    *,
    max_steps: int = 20,
    batches: int = 1,
    max_batches: int = 8,
    seed: int = 0,
    gradient_tol=None,
) -> Design:
    """Minimise an estimated objective over a box with optax, common random numbers and growing samples.

    Args:
        objective: ``objective(x, seed) -> (value, value_stderr, gradient, gradient_stderr)``: one independent
            estimate (a batch) at the design ``x`` (``(P,)`` NumPy array) drawn with the random ``seed`` (an
            int): e.g. ``jdpim.first_passage(scene_of(x), var, level, jdpim.MonteCarlo(n_samples=N,
            seed=seed), wrt=...)`` with its ``probability``, ``probability_stderr``, ``derivative`` and
            ``derivative_stderr``. Gradient and standard errors: ``(P,)``, in objective units per unit of ``x``.
        x0: ``(P,)`` or a number: the starting design, inside ``bounds``.
        bounds: ``(P, 2)``: ``(low, high)`` of each design parameter, ``low < high`` (``+-inf`` allowed).
        optimiser: an optax transformation, e.g. ``optax.adam(0.05)`` (its steps are in units of ``x``:
            scale ``x`` so that its entries vary over similar ranges).
        max_steps: the most optimiser steps (>= 1).
        batches: the batches averaged at the start (>= 1); each is one call of the objective.
        max_batches: the most batches averaged at a design (>= ``batches``): ``max_batches`` times the batch
            size is the largest sample.
        seed: the seed of batch 0; batch ``k`` uses ``seed + k`` at every design (common random numbers).
        gradient_tol: ``None``, or the largest slope (objective units per unit of ``x``, > 0; a number or ``(P,)``)
            that may be taken for zero: a stop on a gradient within two standard errors of zero is ``converged``
            only where two standard errors are within it.

    Returns:
        :class:`Design`.

    Examples:
        >>> import numpy as np, optax, jdpim
        >>> def objective(x, seed):  # (x - 0.3)^2 estimated with noise of standard error 0.01
        ...     e = np.random.default_rng(seed).normal(size=2) * 0.01
        ...     return (x[0] - 0.3) ** 2 + e[0], 0.01, [2 * (x[0] - 0.3) + e[1]], [0.01]
        >>> d = jdpim.design.minimise(objective, [0.9], [(0.0, 1.0)], optax.sgd(0.3), max_steps=40)
        >>> bool(abs(d.x[0] - 0.3) < 0.05)
        True
    """
    if not callable(objective):
        raise TypeError(f"objective must be a function objective(x, seed), got {objective!r}")
    if not (hasattr(optimiser, "init") and hasattr(optimiser, "update")):
        raise TypeError(f"optimiser must be an optax transformation such as optax.adam(0.05), got {optimiser!r}")
    x, low, high = _bounds(x0, bounds)
    max_steps = check_int("max_steps", max_steps, low=1)
    batches = check_int("batches", batches, low=1)
    max_batches = check_int("max_batches", max_batches, low=batches)
    seed = check_int("seed", seed, low=0)
    tol = None
    if gradient_tol is not None:
        tol = real_array("gradient_tol", gradient_tol, "a positive number or (P,) of them")
        if tol.shape not in ((), x.shape) or not np.all(np.isfinite(tol)) or np.any(tol <= 0):
            raise ValueError(f"gradient_tol must be a positive number or {x.size} of them, got {gradient_tol!r}")
        tol = np.broadcast_to(tol, x.shape)

    p = x.size
    state = optimiser.init(x)
    history, rows_at_x, n_evaluations, converged = [], [], 0, False
    for step in range(max_steps + 1):
        while True:  # draw batches at x until the gradient is distinguished from zero or the sample is largest
            while len(rows_at_x) < batches:
                rows_at_x.append(_estimate(objective, x, seed + len(rows_at_x)))
                n_evaluations += 1
            value, value_se, grad, grad_se = _average(rows_at_x, p)
            g = _projected(grad, x, low, high)
            descent = np.any(np.abs(g) > Z_STOP * grad_se)  # some component says where to go
            unresolved = np.any(np.abs(grad) <= Z_STOP * grad_se)  # some sign is lost in the noise
            if descent or not unresolved or batches == max_batches:
                break
            batches = min(2 * batches, max_batches)
        history.append((x.copy(), value, value_se, batches))
        if not descent:
            # a component that points out of an active bound is settled there; the others resolved within tol
            missed = np.where((g == 0) & (grad != 0), 0.0, Z_STOP * grad_se)
            converged = tol is None or bool(np.all(missed <= tol))
            if not converged:
                warnings.warn(
                    f"minimise stopped at x = {x.tolist()} on a gradient within {Z_STOP:g} standard errors of zero "
                    f"at {batches} batches, but a slope up to {np.max(missed):.3g} could hide "
                    f"in that noise (gradient_tol = {np.min(tol):.3g}): raise max_batches or the batch size",
                    DesignWarning,
                    stacklevel=2,
                )
            break
        if step == max_steps:
            converged = False
            break
        updates, state = optimiser.update(g, state, x)
        x = np.clip(np.asarray(optax.apply_updates(x, updates), dtype=float), low, high)
        rows_at_x = []
    xs, values, stderrs, sizes = zip(*history, strict=True)
    return Design(
        x=x,
        value=float(value),
        value_stderr=float(value_se),
        gradient=grad,
        gradient_stderr=grad_se,
        converged=bool(converged),
        history_x=np.stack(xs),
        history_value=np.asarray(values),
        history_value_stderr=np.asarray(stderrs),
        batches=np.asarray(sizes),
        n_evaluations=n_evaluations,
    )
