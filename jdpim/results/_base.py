"""What every result shares: saved times, named coordinates, and how a quantity and a time are picked."""

from __future__ import annotations

import math
from collections.abc import Callable

from .._io import Labelled
from .._scene import saved_index

COORDINATES = ("x", "v")  # the state of a one-degree-of-freedom model: displacement, velocity


class AbstractResult(Labelled):
    """The interface every method's result shares (``jdpim.Result``, ``jdpim.GridResult``).

    ``times`` (a tuple of saved times, s; ``(inf,)`` for a stationary density) and ``coordinates`` (the
    names of the state's entries, ``("x", "v")`` for one degree of freedom) are pytree structure; results
    pass through ``jax.jit`` and ``jax.vmap``. A quantity ``var`` is a coordinate name or a function of the
    state ``f(state) -> scalar`` (``state``: shape ``(n_state,)``, in the order of ``coordinates``), e.g. the
    energy ``lambda s: 0.5 * s[1] ** 2 + 0.5 * s[0] ** 2``. ``t`` is a saved time; it may be left out when
    there is one (a single saved time, or a stationary density).

    Methods: ``pdf(var, grid, t=None)``, ``joint_pdf(vars, grids, t=None)``, ``pdf_error(var, grid, t=None)``,
    ``moment(var, order, t=None)``, ``mass(t=None)``, ``n_nonfinite()``, ``save(path, scene=, method=)``
    (read back by ``jdpim.load``) and ``to_xarray()``.
    """

    times: tuple
    coordinates: tuple
    stationary: bool = False

    def _index(self, t) -> int:
        """Index of the saved time ``t`` (``None``: the only one, or the stationary density, whose time is ``inf``)."""
        if self.stationary:
            if t is not None and not (isinstance(t, (int, float)) and math.isinf(t) and t > 0):
                raise ValueError(f"t={t!r} for a stationary density (t = inf): leave t out, or pass t=math.inf")
            return 0
        if t is None:
            if len(self.times) == 1:
                return 0
            raise ValueError(f"t is required: this result holds {len(self.times)} saved times {list(self.times)}")
        return saved_index(self.times, t)

    def _coordinate(self, var) -> int | Callable:
        """The index of the coordinate ``var``, or ``var`` itself if it is a function of the state."""
        if callable(var):
            return var
        if var not in self.coordinates:
            raise ValueError(
                f"var must be one of the coordinates {self.coordinates} or a function of the state, got {var!r}"
            )
        return self.coordinates.index(var)
