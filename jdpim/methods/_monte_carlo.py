"""Monte Carlo simulation: independent sample paths under Gaussian white-noise forcing."""

from __future__ import annotations

from .._excitation import GaussianNodes
from .._pytree import check_int, pytree_dataclass, static_field
from .._scene import Scene
from ..results._samples import Result
from ._base import solve
from ._paths import SamplingMethod, check_run_settings, monte_carlo_inputs


@pytree_dataclass
class MonteCarlo(SamplingMethod):
    """Monte Carlo simulation (settings; run it with ``jdpim.solve(scene, MonteCarlo(...))``).

    Independent sample paths, each under its own draw of the forcing: by default (``Scene(excitation=None)``,
    ``default_excitation``) Gaussian values at the RK4 nodes drawn inside the steps (:class:`jdpim.GaussianNodes`),
    or with
    ``excitation=jdpim.SpectralRepresentation()`` Gaussian spectral coefficients on DPIM's excitation grid.
    Densities are kernel estimates with weights ``1 / n_samples``, with sampling standard errors
    (``Result.pdf_error``).

    Args:
        n_samples: number of sample paths (>= 2).
        seed: PRNG seed (>= 0); the same seed gives the same paths whatever ``chunk_size`` and ``devices``, to
            rounding (chunks of other sizes may resolve impacts in batches of other widths: docs/speed.md).
        chunk_size: most paths per chunk (each device's paths are split into equal chunks no larger), or
            ``None`` for a memory-based default.
        devices: devices to split the samples over (``None``: every local device).
        progress: progress line on stderr (``None``: only for runs of more than one block of paths).

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.02)
        >>> jdpim.solve(scene, jdpim.MonteCarlo(n_samples=64, seed=1)).states.shape
        (64, 1, 2)
    """

    n_samples: int = static_field(default=10_000)
    seed: int = static_field(default=0)
    chunk_size: int | None = static_field(default=None)
    devices: tuple | None = static_field(default=None)
    progress: bool | None = static_field(default=None)
    name = "monte_carlo"
    independent = True
    default_excitation = GaussianNodes()  # as accurate as the spectral representation, and cheaper (docs/speed.md)

    def __post_init__(self):
        check_int("n_samples", self.n_samples, low=2)
        check_int("seed", self.seed, low=0)
        check_run_settings(self)

    def inputs(self, scene: Scene) -> tuple:
        return monte_carlo_inputs(scene, self.n_samples, seed=self.seed, chunk_size=self.chunk_size)


def monte_carlo(
    scene: Scene,
    n_samples: int = 10_000,
    *,
    seed: int = 0,
    chunk_size: int | None = None,
    devices=None,
    progress: bool | None = None,
) -> Result:
    """``jdpim.solve(scene, jdpim.MonteCarlo(n_samples, seed, ...))``: response PDFs by Monte Carlo simulation.

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.02)
        >>> jdpim.monte_carlo(scene, n_samples=64, seed=1).states.shape
        (64, 1, 2)
    """
    method = MonteCarlo(n_samples, seed, chunk_size=chunk_size, devices=devices, progress=progress)
    return solve(scene, method)
