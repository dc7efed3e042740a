r"""Systems with several degrees of freedom: ``M q'' + C q' + K q = f(q, q') + B xi(t)``, ``q`` in R^n.

Unilateral constraints ``n_j . q >= b_j`` (:class:`Barrier`), each with its own restitution ``r_j``, act
through the generalised Newton impact law (``jdpim._constraints``): a mass against a wall is
``normal = e_i``, two masses closing a gap ``normal = e_i - e_k``, a clearance two constraints.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np

from ._constraints import Constraints, dot
from ._distributions import Range
from ._models import RESTITUTION, AbstractSystem, stack_scalars
from ._pytree import array_leaf, check_real, concrete, plain, pytree_dataclass, static_field


@pytree_dataclass
class Barrier:
    r"""The unilateral constraint ``normal . q >= position``, with restitution ``r``.

    Args:
        normal: the constraint's normal, one number per coordinate (constant structure: a tuple of floats),
            not all zero. ``(1, 0)``: the first mass stays right of ``position``; ``(-1, 1)``: the second mass
            stays at least ``position`` right of the first (a gap; ``(1, -1)`` with ``-position``: at most).
        position: the offset ``b`` (units of ``q``; traced).
        r: the coefficient of restitution in [0, 1] (traced).

    Examples:
        >>> import jdpim
        >>> jdpim.Barrier(normal=(-1.0, 1.0), position=-0.1, r=0.6).normal
        (-1.0, 1.0)
    """

    normal: tuple = static_field(default=(1.0,))
    position: Any = 0.0
    r: Any = 1.0

    def __post_init__(self):
        arr = concrete(self.normal)
        if arr is None or arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.number):
            raise TypeError(f"normal must be a sequence of numbers, one per coordinate, got {self.normal!r}")
        check_real("normal", arr)
        if not np.any(arr != 0):
            raise ValueError(f"normal must not be zero, got {plain(self.normal)!r}")
        object.__setattr__(self, "normal", tuple(float(a) for a in arr))
        check_real("position", self.position, scalar=True)
        RESTITUTION.check("r", self.r)


MATRIX_ENTRY = re.compile(r"^(damping|stiffness|gains)\[(\d+),\s*(\d+)\]$")  # a parameter's name: "damping[0,1]"
CONSTRAINT = re.compile(r"^constraints\[(\d+)\]\.(r|position)$")  # "constraints[0].r"


def linear_state_matrix(mass, damping, stiffness) -> np.ndarray:
    """``[[0, I], [-M^-1 K, -M^-1 C]]``, ``(2n, 2n)``: the first-order form of ``M q'' + C q' + K q = 0``
    (``None`` for an absent ``C`` or ``K``)."""
    n = mass.shape[0]
    m_inv = np.linalg.inv(mass)
    k = np.zeros((n, n)) if stiffness is None else np.asarray(stiffness, float)
    c = np.zeros((n, n)) if damping is None else np.asarray(damping, float)
    return np.block([[np.zeros((n, n)), np.eye(n)], [-m_inv @ k, -m_inv @ c]])


def _matrix(name: str, value, n: int, square: bool = True) -> None:
    """Check ``value`` is a real ``(n, n)`` matrix (``(n, m)`` unless ``square``) where it is an array."""
    if isinstance(value, (str, bytes)):
        raise TypeError(f"{name} must be a matrix of numbers, got {value!r}")
    arr = concrete(value)
    shape = arr.shape if arr is not None else getattr(value, "shape", None)
    if shape is None:
        return  # a placeholder JAX put in while rebuilding the model
    if len(shape) != 2 or shape[0] != n or (square and shape[1] != n) or shape[1] == 0:
        want = f"({n}, {n})" if square else f"({n}, m)"
        raise ValueError(f"{name} must be a matrix of shape {want}, got shape {list(shape)}")
    if arr is not None:
        check_real(name, arr)


@pytree_dataclass
class MDOFOscillator(AbstractSystem):
    r"""``M q'' + C q' + K q = f(q, q', params) + B xi(t)`` with unilateral constraints ``n_j . q >= b_j``.

    Args:
        mass: ``M``, ``(n, n)`` symmetric positive definite (constant structure: not traced, not differentiable).
        gains: ``B``, ``(n, m)`` for ``m`` white-noise sources (traced).
        damping: ``C``, ``(n, n)`` (traced), or ``None`` for none.
        stiffness: ``K``, ``(n, n)`` (traced), or ``None`` for none.
        constraints: a tuple of :class:`Barrier`, each with a normal of length ``n``.
        force: an extra force ``f(q, v, params) -> (n,)`` (JAX-traceable, one path), or ``None``.
        params: a pytree of parameters of ``force`` (traced).
        names: the coordinates' names (``n`` strings), or ``None`` for ``x1 .. xn``; a velocity is named
            ``v`` + what follows the ``x`` of a name that starts with one (``x1`` -> ``v1``), else ``v_`` + the name.
        start: the coordinates every path starts from where the scene gives no ``x0`` (``n`` numbers, constant
            structure), or ``None`` for zeros (a harmonic filter, :func:`jdpim.harmonic`, starts at 1).

    The impact law on constraint ``j`` is ``v+ = v- - (1 + r_j) (n_j . v-) M^-1 n_j / (n_j . M^-1 n_j)``.

    Examples:
        >>> import jdpim
        >>> two = jdpim.MDOFOscillator(mass=[[1.0, 0.0], [0.0, 0.5]], gains=[[1.0], [0.0]],
        ...                            damping=[[0.1, 0.0], [0.0, 0.05]], stiffness=[[2.0, -1.0], [-1.0, 1.0]],
        ...                            constraints=(jdpim.Barrier(normal=(1.0, 0.0), position=-0.5, r=0.8),))
        >>> two.coordinates
        ('x1', 'x2', 'v1', 'v2')
    """

    mass: tuple = static_field()
    gains: Any = None
    damping: Any = None
    stiffness: Any = None
    constraints: tuple = ()
    force: Callable | None = static_field(default=None)
    params: Any = None
    names: tuple | None = static_field(default=None)
    start: tuple | None = static_field(default=None)

    def __post_init__(self):
        m = concrete(self.mass)
        if m is None or m.ndim != 2 or m.shape[0] != m.shape[1] or m.shape[0] == 0:
            raise ValueError(f"mass must be a square (n, n) matrix of numbers, got {plain(self.mass)!r}")
        check_real("mass", m)
        if not np.allclose(m, m.T, rtol=1e-12, atol=0.0) or np.linalg.eigvalsh(m).min() <= 0:
            raise ValueError(f"mass must be symmetric positive definite, got {m.tolist()}")
        object.__setattr__(self, "mass", tuple(tuple(float(a) for a in row) for row in m))
        n = m.shape[0]
        if self.gains is None:
            raise ValueError("gains must be given: the (n, m) matrix B of the noise sources' forces")
        for name in ("gains", "damping", "stiffness"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, array_leaf(name, getattr(self, name)))
                _matrix(name, getattr(self, name), n, square=name != "gains")
        self._check_dissipative()
        constraints = self.constraints
        if not isinstance(constraints, (tuple, list)) or not all(isinstance(c, Barrier) for c in constraints):
            raise TypeError(f"constraints must be a tuple of jdpim.Barrier, got {constraints!r}")
        object.__setattr__(self, "constraints", tuple(constraints))
        for j, c in enumerate(self.constraints):
            if len(c.normal) != n:
                raise ValueError(f"constraints[{j}].normal has {len(c.normal)} entries; the system has {n} coordinates")
        if self.force is not None and not callable(self.force):
            raise TypeError(f"force must be callable or None, got {self.force!r}")
        if self.names is not None:
            names = tuple(self.names)
            if len(names) != n or not all(isinstance(s, str) and s for s in names) or len(set(names)) != n:
                raise ValueError(f"names must be {n} distinct non-empty strings, got {self.names!r}")
            object.__setattr__(self, "names", names)
        if self.start is not None:
            start = concrete(self.start)
            if start is None or start.shape != (n,) or not np.issubdtype(start.dtype, np.number):
                raise ValueError(f"start must be {n} numbers (one per coordinate), got {self.start!r}")
            check_real("start", start)
            object.__setattr__(self, "start", tuple(float(a) for a in start))

    def _check_dissipative(self) -> None:
        """A symmetric damping matrix must be positive semi-definite: it dissipates, as ``alpha >= 0`` for one
        degree of freedom. Not checked: a filter's damping (:mod:`jdpim.filters`), not symmetric because the
        structure feels the filter and not the other way round; and the stiffness, whose negative directions are
        unstable rest states that constraints or a ``force`` may confine (an inverted pendulum between stops)."""
        c = concrete(self.damping)
        if c is None or not np.allclose(c, c.T, rtol=1e-12, atol=0.0):
            return  # traced (checked where the model is built with numbers) or not symmetric
        low = float(np.linalg.eigvalsh(c).min())
        if low < -1e-12 * max(1.0, float(np.abs(c).max())):
            raise ValueError(
                f"damping must be positive semi-definite (it dissipates energy); its smallest eigenvalue is "
                f"{low:.4g}: {plain(c)!r}"
            )

    def parameter_range(self, name: str) -> Range:
        """A diagonal entry of ``damping`` is >= 0, a restitution in [0, 1]; other entries any real value."""
        if (m := MATRIX_ENTRY.match(name)) and m[1] == "damping" and m[2] == m[3]:
            return Range(0.0)
        m = CONSTRAINT.match(name)
        return RESTITUTION if m and m[2] == "r" else Range()

    def linearised(self) -> np.ndarray | None:
        """``[[0, I], [-M^-1 K, -M^-1 C]]`` without a ``force`` (filters included: they are coordinates); with one,
        the Jacobian at rest (:meth:`jdpim.AbstractSystem.linearised`)."""
        if self.force is not None:
            return super().linearised()
        mats = [concrete(getattr(self, name)) for name in ("damping", "stiffness")]
        if any(a is None and b is not None for a, b in zip(mats, (self.damping, self.stiffness), strict=True)):
            return None
        return linear_state_matrix(np.asarray(self.mass), *mats)

    @property
    def dimension(self) -> int:
        return len(self.mass)

    @property
    def n_sources(self) -> int:
        return int(np.shape(self.gains)[1])

    @property
    def coordinates(self) -> tuple[str, ...]:
        """``(x1 .. xn, v1 .. vn)``, or the given names and their velocities."""
        names = self.names or tuple(f"x{i + 1}" for i in range(self.dimension))
        vel = tuple("v" + s[1:] if s[0] == "x" else "v_" + s for s in names)
        return names + vel

    @property
    def has_barrier(self) -> bool:
        return bool(self.constraints)

    def bounds(self) -> dict | None:
        """``{name: lower bound}`` of the coordinates a constraint bounds from below (``normal = c e_i``, ``c > 0``):
        density kernels are reflected there. ``None`` if there are none."""
        out = {}
        for c in self.constraints:
            nz = [i for i, a in enumerate(c.normal) if a != 0]
            if len(nz) == 1 and c.normal[nz[0]] > 0:
                name, bound = self.coordinates[nz[0]], c.position / c.normal[nz[0]]
                out[name] = bound if name not in out else jnp.maximum(out[name], bound)
        return out or None

    def inverse_mass(self) -> np.ndarray:
        return np.linalg.inv(np.asarray(self.mass))

    def state_acceleration(self, q, v, xi):
        """``q'' = M^-1 (f - C v - K q + B xi)`` for one path: ``q``, ``v`` ``(n,)``, ``xi`` ``(m,)``."""
        dtype = jnp.result_type(q)
        force = dot(jnp.asarray(self.gains, dtype), xi)
        if self.damping is not None:
            force = force - dot(jnp.asarray(self.damping, dtype), v)
        if self.stiffness is not None:
            force = force - dot(jnp.asarray(self.stiffness, dtype), q)
        if self.force is not None:
            force = force + jnp.reshape(self.force(q, v, self.params), (self.dimension,))
        return dot(jnp.asarray(self.inverse_mass(), dtype), force)

    def noise_reaches(self) -> np.ndarray | None:
        """``(J,)`` bool: whether the white noise acts on each constraint's normal acceleration
        (``n_j . M^-1 B != 0``); ``None`` where the gains are not concrete numbers (traced)."""
        gains = concrete(self.gains)
        if gains is None or not self.constraints:
            return None
        reach = np.array([c.normal for c in self.constraints]) @ self.inverse_mass() @ gains
        return np.any(np.abs(reach) > 1e-12 * max(1.0, float(np.abs(gains).max())), axis=1)

    def stacked_constraints(self) -> Constraints | None:
        if not self.constraints:
            return None
        normal = np.array([c.normal for c in self.constraints])
        m_inv_n = normal @ self.inverse_mass()  # rows M^-1 n_j (M symmetric)
        push = m_inv_n / np.sum(m_inv_n * normal, axis=1, keepdims=True)
        position, r = stack_scalars(tuple(c.position for c in self.constraints), tuple(c.r for c in self.constraints))
        return Constraints(normal, position, r, push)
