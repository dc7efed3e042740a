"""The distribution of the peak of a response over the record, from first passage.

The peak ``Q(t) = max_{0 <= s <= t} q(s)`` stays at or below ``level`` exactly when ``q`` has not passed the level
by ``t``, so its distribution function is one minus the first-passage probability over a grid of levels:
``F(level; t) = P(Q(t) <= level) = 1 - P(max_{s <= t} q(s) > level)``. Its standard error is the first passage's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._io import Persistent
from .._pytree import pytree_dataclass, real_array, static_field
from ._first_passage import first_passage


@pytree_dataclass
class PeakDistribution(Persistent):
    r"""The distribution function of the peak ``max_{0 <= s <= t} q(s)`` at every saved time ``t``.

    Attributes:
        times: saved times, s: a tuple of ``S`` floats (pytree structure).
        levels: ``(L,)``, increasing levels.
        cdf: ``(S, L)``, ``P(max_{s <= t} q(s) <= level)`` over the paths (or grid mass) that stayed finite:
            nondecreasing along the levels, nonincreasing along the times.
        cdf_stderr: ``(S, L)``, its sampling standard error (Monte Carlo), or ``None`` where the method has none.
        lost_mass: ``(S, L)``, the probability of paths that turned non-finite before passing the level: the
            true value lies in ``[cdf - lost_mass, cdf]``.
        method: the method's name.

    ``save`` writes it (``jdpim.load`` reads it back); a pytree: it passes through ``jax.jit``.
    """

    times: tuple = static_field()
    levels: Any = None
    cdf: Any = None
    cdf_stderr: Any = None
    lost_mass: Any = None
    method: str = static_field(default="monte_carlo")


def peak_distribution(scene, var, levels, method, *, replicates: int | None = None) -> PeakDistribution:
    r"""The distribution of the peak of ``var`` over ``[0, t]`` at every saved ``t``, from first passage.

    ``F(level; t) = 1 - P_f(level; t)``, with ``P_f`` of :func:`jdpim.first_passage` (same arguments): one run
    that tracks the running maximum over every step of every path at all the levels together. For the peak of
    ``|q|`` (the two-sided peak an engineer reads from a record), pass ``lambda s: abs(s[0])``.

    Args:
        scene: the physics (:class:`jdpim.Scene`).
        var: a coordinate name or a function of the state (as for :func:`jdpim.first_passage`).
        levels: ``(L,)``, ``L >= 2`` increasing finite levels (above the lower bound of a coordinate that a
            barrier bounds).
        method: any method :func:`jdpim.first_passage` takes (``jdpim.MonteCarlo`` gives standard errors).
        replicates: DPIM only: ``R >= 2`` randomised replicates, as for :func:`jdpim.first_passage`.

    Returns:
        :class:`PeakDistribution`.

    Examples:
        >>> import jdpim
        >>> model = jdpim.VibroImpactOscillator(alpha=0.2, gamma=None, barrier=None)
        >>> scene = jdpim.Scene(model, noise=jdpim.WhiteNoise(0.1), t_end=2.0, dt=0.02)
        >>> peak = jdpim.peak_distribution(scene, "x", [0.1, 0.3, 0.6], jdpim.MonteCarlo(n_samples=200, seed=0))
        >>> peak.cdf.shape, bool(peak.cdf[-1, 0] <= peak.cdf[-1, -1])
        ((1, 3), True)
    """
    grid = real_array("levels", levels, "a 1-D sequence of increasing levels")
    if grid.ndim != 1 or grid.size < 2 or not np.all(np.diff(grid) > 0):
        raise ValueError(f"levels must be a 1-D sequence of at least two increasing levels, got {levels!r}")
    fp = first_passage(scene, var, levels, method, replicates=replicates)
    return PeakDistribution(
        times=fp.times,
        levels=fp.levels,
        cdf=1.0 - fp.probability,
        cdf_stderr=fp.probability_stderr,
        lost_mass=fp.lost_mass,
        method=fp.method,
    )
