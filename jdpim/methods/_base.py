"""The method interface and the one entry point, ``solve(scene, method)``.

A method is a small frozen object of numerical settings (no physics): the scene says what is computed,
the method how. Every method returns a result with the same interface (``jdpim.results``).
"""

from __future__ import annotations

import abc

from .._checkpoint import session
from .._scene import Scene


class AbstractMethod(abc.ABC):
    """A way to compute response densities of a :class:`jdpim.Scene`: DPIM, Monte Carlo or path integration.

    Subclasses are frozen dataclasses of numerical settings. ``run(scene)`` computes the result. A method knows
    no question: questions (``jdpim.first_passage``, ``jdpim.sensitivity``, ``jdpim.impact_statistics``) ask it
    for its primitives, a sampling method's inputs and paths (``SamplingMethod.inputs``, ``SamplingMethod.paths``)
    or path integration's step operator.
    """

    name: str  # the name results carry in ``Result.method``
    resumable = False  # whether ``run(scene, checkpoint=...)`` keeps finished work (``solve(..., checkpoint=...)``)

    @abc.abstractmethod
    def run(self, scene: Scene):
        """The result of this method on ``scene`` (after the checks of :func:`solve`)."""

    def replicate(self, scene: Scene, k: int) -> AbstractMethod:
        """The ``k``-th of a set of independent, identically distributed randomisations of this method on
        ``scene`` (for an error from the spread of replicates)."""
        raise ValueError(
            f"replicates apply to jdpim.DPIM (its point set has no error of its own); {type(self).__name__} "
            "states its own error"
        )


def solve(scene: Scene, method: AbstractMethod, *, checkpoint=None):
    r"""Response densities of ``scene`` by ``method``: the one entry point for every method.

    Args:
        scene: the physics (:class:`jdpim.Scene`): model, excitation, initial state, random parameters,
            time grid and saved times.
        method: the numerics: ``jdpim.DPIM(...)``, ``jdpim.MonteCarlo(...)`` or ``jdpim.PathIntegration(...)``.
        checkpoint: DPIM and Monte Carlo: a directory or a :class:`jdpim.Checkpoint` where every finished block
            of paths is written; the same call after an interruption loads them and runs only the rest, with the
            same result bit for bit. The part files are deleted when the run finishes (``docs/persistence.md``).

    Returns:
        a result with the shared interface (``pdf``, ``joint_pdf``, ``moment``, ``mass``, ``n_nonfinite``,
        ``times``, ``pdf_error``): :class:`jdpim.Result` (paths) for DPIM and Monte Carlo,
        :class:`jdpim.GridResult` (a phase-space grid) for path integration.

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.02)
        >>> res = jdpim.solve(scene, jdpim.MonteCarlo(n_samples=64, seed=1))
        >>> res.states.shape, res.coordinates
        ((64, 1, 2), ('x', 'v'))
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {type(scene).__name__}")
    if not isinstance(method, AbstractMethod):
        what = f"the class {method.__name__}" if isinstance(method, type) else repr(method)
        raise TypeError(
            f"method must be a jdpim method object, e.g. jdpim.DPIM(), jdpim.MonteCarlo() or jdpim.PathIntegration(); "
            f"got {what}"
        )
    if checkpoint is None:
        return method.run(scene)
    if not method.resumable:
        raise ValueError(f"checkpoint applies to jdpim.DPIM and jdpim.MonteCarlo, not {type(method).__name__}")
    with session(checkpoint, scene=scene, method=method, question="solve") as ses:
        return method.run(scene, checkpoint=ses)
