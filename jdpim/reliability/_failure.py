"""The interface of methods for failure probabilities alone (no response densities): subset simulation."""

from __future__ import annotations

import abc


class AbstractFailureMethod(abc.ABC):
    """A way to compute first-passage (failure) probabilities of a :class:`jdpim.Scene` that gives no response
    densities: ``jdpim.first_passage`` accepts it, ``jdpim.solve`` does not (it takes density methods,
    :class:`jdpim.AbstractMethod`).

    Subclasses are frozen dataclasses of numerical settings with a class attribute ``name`` (the name results
    carry in ``FirstPassage.method``).
    """

    name: str
    resumable = False  # whether its first_passage keeps finished work in the query's checkpoint

    @abc.abstractmethod
    def first_passage(self, scene, query):
        """The ``jdpim.FirstPassage`` of ``jdpim.first_passage`` (``query``: its checked arguments)."""

    def replicate(self, scene, k: int):
        """Refused: a failure-probability method states its own error."""
        raise ValueError(
            f"replicates apply to jdpim.DPIM (its point set has no error of its own); {type(self).__name__} "
            "states its own error"
        )
