"""What every result shares: saved times, named coordinates, and how a quantity and a time are picked."""

from __future__ import annotations

import abc
import math
from collections.abc import Callable

from .._io import Labelled
from .._scene import saved_index

COORDINATES = ("x", "v")  # the state of a one-degree-of-freedom model: displacement, velocity


class AbstractResult(Labelled, abc.ABC):
    """The interface every density result implements (``jdpim.Result``, ``jdpim.GridResult``), with one set of
    signatures: a result lacking one of its abstract methods cannot be instantiated.

    ``times`` (a tuple of saved times, s; ``(inf,)`` for a stationary density) and ``coordinates`` (the
    names of the state's entries, ``("x", "v")`` for one degree of freedom) are pytree structure; results
    pass through ``jax.jit`` and ``jax.vmap``. A quantity ``var`` is a coordinate name or a function of the
    state ``f(state) -> scalar`` (``state``: shape ``(n_state,)``, in the order of ``coordinates``), e.g. the
    energy ``lambda s: 0.5 * s[1] ** 2 + 0.5 * s[0] ** 2``. ``t`` is a saved time; it may be left out when
    there is one (a single saved time, or a stationary density). ``bandwidth`` is a kernel standard deviation
    (``None``: the result's default, from ``rule``, one of ``"chen"``, ``"silverman"``, ``"scott"``), and
    ``bounds = (a, b)`` the range of ``var`` (``None``: :meth:`bounds`), at whose ends kernels are reflected.

    Besides the abstract methods, every result has ``save(path, scene=, method=)`` (read back by
    ``jdpim.load``) and ``to_xarray()``.
    """

    times: tuple
    coordinates: tuple
    stationary: bool = False

    @abc.abstractmethod
    def pdf(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        """Marginal density of ``var`` at ``t`` on ``grid`` (a scalar or 1-D, strictly increasing); shaped like
        ``grid``. It integrates to ``mass(t) - sum(atoms(var, t))``."""

    @abc.abstractmethod
    def pdf_error(self, var, grid, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        """The error of :meth:`pdf` (same arguments), shaped like ``grid``: the sampling standard error of Monte
        Carlo, the estimated discretisation error of path integration; a ``ValueError`` that names the remedy
        where the result carries none."""

    @abc.abstractmethod
    def joint_pdf(self, vars, grids, t: float | None = None, *, bandwidth=None, rule: str = "chen", bounds=None):
        """Joint density of the pair ``vars`` at ``t`` on the pair ``grids``; shape ``(len(grids[0]),
        len(grids[1]))`` (a scalar grid drops its axis). ``bandwidth`` and ``bounds``: pairs, one per quantity."""

    @abc.abstractmethod
    def moment(self, var, order: int, t: float | None = None):
        """Raw moment ``E[var^order]`` at ``t`` over the probability the result carries."""

    @abc.abstractmethod
    def mass(self, t: float | None = None):
        """Probability the result carries at ``t`` (1 less what non-finite paths or the grid's edges lost)."""

    @abc.abstractmethod
    def bounds(self, var):
        """``(lower, upper)``: the range of ``var`` the model implies (``None`` for a side without a bound)."""

    @abc.abstractmethod
    def atoms(self, var, t: float | None = None, *, bounds=None):
        """Probability held at the lower and upper bound of ``var`` at ``t`` (left out of :meth:`pdf`); ``(2,)``."""

    @abc.abstractmethod
    def n_nonfinite(self):
        """Number of non-finite carriers of probability (paths, grid nodes) per saved time; shape ``(S,)``."""

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
