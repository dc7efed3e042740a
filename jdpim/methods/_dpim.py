"""The Direct Probability Integral Method: representative points with assigned probabilities."""

from __future__ import annotations

import dataclasses
from typing import Any

from .._excitation import SpectralRepresentation
from .._points import PointSet
from .._pytree import check_int, pytree_dataclass, static_field
from .._replicates import randomised_points
from .._scene import Scene
from ..results._samples import Result
from ._base import solve
from ._paths import SamplingMethod, check_run_settings, dpim_input_distributions, dpim_inputs


@pytree_dataclass
class DPIM(SamplingMethod):
    r"""The Direct Probability Integral Method (settings; run it with ``jdpim.solve(scene, DPIM(...))``).

    Representative points ``theta_q`` of the input space (two elementary variables per noise source,
    then any random parameters) with assigned probabilities ``P_q`` are integrated as deterministic
    trajectories; densities are ``p(y, t) = sum_q P_q N(y; y_q(t), sigma^2)`` (``Result.pdf``).

    Defaults come from the accuracy study (``docs/accuracy.md``): the scene's cutoff ``2 / dt``, the
    Box-Muller ("rayleigh") random functions and the bandwidth constant ``c = 1.25``. With them, N points
    are worth about N Monte Carlo samples (the accuracy bench's record, ``docs/bench/accuracy.json``).

    Args:
        n_points: number of representative points (>= 2), if ``points`` is not given.
        points: a precomputed :class:`jdpim.PointSet` matching ``DPIM.input_distributions(scene)`` (a pytree
            leaf of the method: tuned point sets pass through ``jax.jit``).
        chunk_size: most paths per chunk (each device's paths are split into equal chunks no larger), or
            ``None`` for a memory-based default.
        devices: devices to split the points over (``None``: every local device); the states are the
            same whatever the devices, to rounding (docs/speed.md).
        progress: progress line on stderr (``None``: only for runs of more than one block of paths).

    ``solve`` returns a :class:`jdpim.Result` with ``weights = P_q``; its ``states`` are sharded over
    ``devices`` (over several CPU devices, gathered on the first one).

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.02)
        >>> jdpim.solve(scene, jdpim.DPIM(n_points=64)).states.shape
        (64, 1, 2)

    References: Chen & Yang (2019), CMAME 357; Chen, Yang & Li (2016), Structural Safety 59.
    """

    n_points: int = static_field(default=1000)
    points: Any = None
    chunk_size: int | None = static_field(default=None)
    devices: tuple | None = static_field(default=None)
    progress: bool | None = static_field(default=None)
    name = "dpim"
    independent = False  # the points are chosen together: no sampling error (replicates give one)
    default_excitation = SpectralRepresentation()  # two elementary variables per source

    def __post_init__(self):
        if self.points is None:
            check_int("n_points", self.n_points, low=2)
        elif not isinstance(self.points, PointSet):
            raise TypeError(f"points must be a jdpim.PointSet, got {type(self.points).__name__}")
        check_run_settings(self)

    def replicate(self, scene: Scene, k: int) -> DPIM:
        """This method with the randomised point set of seed ``k`` (:func:`jdpim.randomised_points`) of the
        same size: replicates ``k = 0, 1, ...`` are independent and identically distributed."""
        n = self.n_points if self.points is None else self.points.theta.shape[0]
        return dataclasses.replace(self, points=randomised_points(self.input_distributions(scene), n, k))

    @staticmethod
    def input_distributions(scene: Scene) -> tuple:
        """Distributions of the input space of ``scene``: its excitation's elementary variables (``(Theta1, Theta2)``
        per noise source for the spectral representation), then its random parameters."""
        return dpim_input_distributions(scene)

    def inputs(self, scene: Scene) -> tuple:
        return dpim_inputs(scene, self.n_points, points=self.points, chunk_size=self.chunk_size)


def dpim(
    scene: Scene,
    n_points: int = 1000,
    *,
    points: PointSet | None = None,
    chunk_size: int | None = None,
    devices=None,
    progress: bool | None = None,
) -> Result:
    """``jdpim.solve(scene, jdpim.DPIM(n_points, ...))``: response PDFs by DPIM (see :class:`DPIM`).

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.02)
        >>> jdpim.dpim(scene, n_points=64).states.shape
        (64, 1, 2)
    """
    method = DPIM(n_points, points, chunk_size=chunk_size, devices=devices, progress=progress)
    return solve(scene, method)


def dpim_replicates(scene, n_points: int = 1000, n_replicates: int = 4, *, seed: int = 0, progress=None) -> list:
    """``n_replicates`` DPIM results of ``scene``, each with its own randomised point set (seeds ``seed + k``,
    :func:`jdpim.randomised_points`).

    The spread of their densities is the error of one run: ``np.std(pdfs, axis=0, ddof=1)``.

    Example (``notebooks/quickstart.ipynb`` runs it)::

        runs = jdpim.dpim_replicates(scene, 1000, 4)
        sd = np.std([r.pdf("x", grid, t) for r in runs], axis=0, ddof=1)  # the error of one run, on grid
    """
    n_replicates = check_int("n_replicates", n_replicates, low=2)
    seed = check_int("seed", seed, low=0)
    dists = DPIM.input_distributions(scene)
    return [
        dpim(scene, points=randomised_points(dists, n_points, seed + k), progress=progress) for k in range(n_replicates)
    ]
