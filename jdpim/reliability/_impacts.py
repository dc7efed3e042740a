r"""Impact statistics: the probability of an impact by ``t``, the mean number of impacts, their speeds.

Every path carries, along every step, whether it has hit a constraint yet, how many steps with an impact it
has had, and a histogram of its impact speeds (``jdpim._integrate.Impacts``). With path probabilities ``w_i``:

    P_impact(t) = sum_i w_i 1[path i hit by t],     E[N(t)] = sum_i w_i N_i(t),

and the density of impact speeds over ``[0, t]`` is the weighted histogram of every impact, normalised. The
first impact does not depend on the restitution: before it, a path is the same for every ``r``.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from .._io import Labelled
from .._pytree import check_grid, pytree_dataclass, static_field
from .._scene import Scene, static_times
from ..methods._ad_guard import INDICATOR, watch
from ..methods._paths import SamplingMethod
from ..tracking import ImpactCounts, weighted_mean


@pytree_dataclass
class ImpactStatistics(Labelled):
    """Impact statistics at the saved times.

    Attributes:
        times: saved times, s (pytree structure).
        probability: ``(S,)``, the probability of at least one impact in ``[0, t]``.
        probability_stderr: ``(S,)``, its sampling standard error (Monte Carlo), or ``None`` (DPIM).
        mean_count: ``(S,)``, the expected number of steps with an impact in ``[0, t]`` (several impacts in one
            step count once: at least the impacts' number when they are more than a step apart).
        mean_count_stderr: ``(S,)`` or ``None``, as for ``probability``.
        speed_edges: ``(K + 1,)``, the bin edges of the impact speed (``-n . v`` at the crossing), or ``None``.
        speed_density: ``(S, K)``, the density of the impact speeds of every impact in ``[0, t]`` (integrates to
            the fraction of impacts inside the edges; ``nan`` before the first impact), or ``None``.
        method: the method's name.

    ``rate(t)`` is ``mean_count / t``, impacts per second.
    """

    times: tuple = static_field()
    probability: Any = None
    probability_stderr: Any = None
    mean_count: Any = None
    mean_count_stderr: Any = None
    speed_edges: Any = None
    speed_density: Any = None
    method: str = static_field(default="monte_carlo")

    def __post_init__(self):
        object.__setattr__(self, "times", static_times(self.times))

    def rate(self):
        """``(S,)``: the mean number of impacts per second in ``[0, t]`` (``nan`` at ``t = 0``)."""
        t = jnp.asarray(self.times, self.mean_count.dtype)
        return jnp.where(t > 0, self.mean_count / jnp.where(t > 0, t, 1.0), jnp.nan)


def impact_statistics(scene: Scene, method: SamplingMethod, speed_edges=None) -> ImpactStatistics:
    r"""Impact statistics of ``scene`` by a sampling method, at every saved time.

    Args:
        scene: a scene with at least one constraint (a barrier, or ``MDOFOscillator`` constraints).
        method: ``jdpim.MonteCarlo(...)`` (with standard errors) or ``jdpim.DPIM(...)``.
        speed_edges: increasing bin edges ``(K + 1,)`` of the impact speed (units of velocity) for
            ``ImpactStatistics.speed_density``, or ``None`` for none.

    Returns:
        :class:`ImpactStatistics`.

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=1.0, dt=0.02, save_at=(0.5, 1.0))
        >>> st = jdpim.impact_statistics(scene, jdpim.MonteCarlo(n_samples=50, seed=0))
        >>> st.probability.shape, bool(st.probability[1] >= st.probability[0])
        ((2,), True)
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if not isinstance(method, SamplingMethod):
        raise ValueError(
            f"impact statistics are sampled: use jdpim.MonteCarlo or jdpim.DPIM, not {type(method).__name__}"
        )
    if scene.model.stacked_constraints() is None:
        raise ValueError("the scene has no constraint (no barrier): there are no impacts to count")
    edges = () if speed_edges is None else check_grid("speed_edges", speed_edges)
    if edges is None:
        raise ValueError("speed_edges must be concrete numbers, not traced")
    rows, weights, chunk = method.inputs(scene)
    counts = ImpactCounts(scene.impacts, np.asarray(edges, float) if len(edges) else ())  # edges traced, count static
    _, tracked = method.paths(scene, rows, chunk, track=counts)
    tracked = watch(tracked, INDICATOR)  # counts and indicators: no pathwise derivative
    p, p_se = weighted_mean(weights, tracked[..., 0], method.independent)
    count, count_se = weighted_mean(weights, tracked[..., 1], method.independent)
    density = None
    if len(edges):
        binned = jnp.einsum("n,nsk->sk", weights, tracked[..., 2:])
        widths = jnp.asarray(np.diff(edges), binned.dtype)
        total = jnp.einsum("n,ns->s", weights, tracked[..., 1])[:, None]
        density = jnp.where(total > 0, binned / jnp.where(total > 0, total, 1.0) / widths[None], jnp.nan)
    edges = None if speed_edges is None else jnp.asarray(edges, p.dtype)
    return ImpactStatistics(scene.save_at, p, p_se, count, count_se, edges, density, method.name)
