r"""Example systems with several degrees of freedom, built as :class:`jdpim.MDOFOscillator`.

Each function returns a linear model ``M q'' + C q' + K q = B xi(t)`` with its unilateral constraints; the
white noise ``xi`` (``E[xi(t) xi(t+s)] = 2 D delta(s)``) is set by the scene (``jdpim.WhiteNoise(D)``).
Their parameters are numbers; to vary or differentiate one, use its name in the scene
(``jdpim.with_parameters(scene, {"constraints[0].r": 0.7})``, ``jdpim.parameter_names(scene)``).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ._mdof import Barrier, MDOFOscillator
from ._pytree import check_int, check_number


def _shear_frame(n: int, frequency: float, damping_ratio: float, mass: float) -> tuple:
    """``(M, C, K)`` of an ``n``-storey shear frame: storey masses ``m``, equal storey stiffnesses ``m k`` with
    ``k`` giving the first mode the ``frequency``, stiffness-proportional damping with ``damping_ratio`` in it."""
    k = mass * (frequency / (2.0 * np.sin(np.pi / (2 * (2 * n + 1))))) ** 2
    K = k * (2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1))
    K[-1, -1] = k
    return mass * np.eye(n), 2.0 * damping_ratio / frequency * K, K


def impact_damper(
    mass_ratio: float = 0.05,
    frequency: float = 1.0,
    damping_ratio: float = 0.01,
    clearance: float = 0.1,
    r: float = 0.5,
) -> MDOFOscillator:
    r"""A primary structure with an impact damper: a free mass in a clearance inside it.

    .. math::
        x_1'' + 2 \zeta \omega x_1' + \omega^2 x_1 = \xi(t),\qquad \mu x_2'' = 0,\qquad |x_2 - x_1| \le c,

    with impacts (restitution ``r``) where the damper mass reaches either end of the clearance. Coordinates
    ``x1`` (primary, mass 1) and ``x2`` (damper mass); constraints ``[0]``: ``x2 - x1 >= -c``,
    ``[1]``: ``x2 - x1 <= c``.

    Args:
        mass_ratio: ``mu``, the damper mass over the primary mass, > 0.
        frequency: the primary's natural frequency ``omega``, rad/s, > 0.
        damping_ratio: the primary's damping ratio ``zeta``, >= 0.
        clearance: ``c``, the half-width of the clearance (units of ``x``), > 0.
        r: the coefficient of restitution of both ends, in [0, 1].

    Examples:
        >>> import jdpim
        >>> jdpim.impact_damper(clearance=0.2).coordinates
        ('x1', 'x2', 'v1', 'v2')
    """
    mu = check_number("mass_ratio", mass_ratio, low=0.0, low_open=True)
    w = check_number("frequency", frequency, low=0.0, low_open=True)
    zeta = check_number("damping_ratio", damping_ratio, low=0.0)
    c = check_number("clearance", clearance, low=0.0, low_open=True)
    r = check_number("r", r, low=0.0, high=1.0)
    return MDOFOscillator(
        mass=np.diag([1.0, mu]),
        gains=[[1.0], [0.0]],
        damping=np.diag([2.0 * zeta * w, 0.0]),
        stiffness=np.diag([w * w, 0.0]),
        constraints=(Barrier((-1.0, 1.0), -c, r), Barrier((1.0, -1.0), -c, r)),
    )


def pounding_frame(
    n_storeys: int = 3,
    frequency: float = 1.0,
    damping_ratio: float = 0.02,
    gap: float = 0.5,
    r: float = 0.6,
    storey: int | None = None,
) -> MDOFOscillator:
    r"""An ``n``-storey shear frame shaken at its base, one storey pounding against a rigid barrier.

    .. math::
        M q'' + C q' + K q = -M \iota\, \xi(t),\qquad q_s \le g,

    with equal storey masses ``M = I``, equal storey stiffnesses ``k`` (``K`` tridiagonal: ``2k`` on the
    diagonal, ``k`` at the top, ``-k`` beside it), ``k`` chosen so that the first mode has the frequency
    ``omega_1 = 2 sqrt(k) sin(pi / (2 (2 n + 1)))`` asked for, stiffness-proportional damping
    ``C = (2 zeta / omega_1) K`` (damping ratio ``zeta`` in the first mode, larger in the higher ones),
    ``iota = (1, ..., 1)`` (``xi`` is the ground acceleration) and the barrier ``g`` away from storey
    ``s`` (restitution ``r``): the constraint ``-q_s >= -g``. Coordinates ``x1`` (first storey) .. ``xn``.

    Args:
        n_storeys: ``n`` >= 1.
        frequency: ``omega_1``, rad/s, > 0.
        damping_ratio: ``zeta`` of the first mode, >= 0.
        gap: ``g``, the distance from the storey at rest to the barrier, > 0.
        r: the coefficient of restitution, in [0, 1].
        storey: the pounding storey, 1 .. n (``None``: the top, ``n``).

    Examples:
        >>> import jdpim
        >>> jdpim.pounding_frame(n_storeys=2).constraints[0].normal
        (0.0, -1.0)
    """
    check_int("n_storeys", n_storeys, low=1)
    n = int(n_storeys)
    w = check_number("frequency", frequency, low=0.0, low_open=True)
    zeta = check_number("damping_ratio", damping_ratio, low=0.0)
    g = check_number("gap", gap, low=0.0, low_open=True)
    r = check_number("r", r, low=0.0, high=1.0)
    s = n if storey is None else storey
    check_int("storey", s, low=1)
    if s > n:
        raise ValueError(f"storey must lie in [1, {n}] (the storeys of the frame), got {s}")
    mass, damping, stiffness = _shear_frame(n, w, zeta, 1.0)
    normal = np.zeros(n)
    normal[s - 1] = -1.0
    return MDOFOscillator(
        mass=mass,
        gains=-np.ones((n, 1)),
        damping=damping,
        stiffness=stiffness,
        constraints=(Barrier(tuple(normal), -g, r),),
    )


def _pair(name: str, value, **bounds) -> tuple:
    """``value`` (one number for both buildings, or two) as two floats, each checked by :func:`check_number`."""
    values = value if isinstance(value, (tuple, list)) else (value, value)
    if len(values) != 2:
        raise ValueError(f"{name} must be one number or two (building a, building b), got {value!r}")
    return tuple(check_number(name, v, **bounds) for v in values)


def adjacent_buildings(
    n_storeys=(1, 1),
    frequency=(1.0, 1.5),
    damping_ratio=0.05,
    mass=1.0,
    gap: float | None = 0.1,
    r: float = 0.6,
) -> MDOFOscillator:
    r"""Two adjacent shear frames ``a`` and ``b`` on common ground, pounding where a facing pair of storeys closes
    the gap between them.

    .. math::
        M q'' + C q' + K q = -M \iota\, \xi(t),\qquad x_{a,s} - x_{b,s} \le g \quad (s = 1 .. \min(n_a, n_b)),

    each building a frame as in :func:`pounding_frame` (equal storey masses ``m``, equal storey stiffnesses giving
    the first mode the frequency asked for, stiffness-proportional damping with the damping ratio asked for in
    it), ``iota = (1, ..., 1)`` (``xi`` is the ground acceleration, common to both) and building ``b`` standing
    ``g`` to the right of building ``a``: storey ``s`` of ``a`` strikes storey ``s`` of ``b`` where
    ``x_{a,s} - x_{b,s}`` reaches ``g``. An impact exchanges momentum between the two storeys with restitution
    ``r`` (the law of :class:`jdpim.MDOFOscillator`). Coordinates ``xa1 .. xa{n_a}``, ``xb1 .. xb{n_b}``;
    constraint ``[s - 1]``: ``x_{b,s} - x_{a,s} >= -g``.

    Args:
        n_storeys: ``(n_a, n_b)``, each >= 1 (one integer: both).
        frequency: the first-mode frequencies ``(omega_a, omega_b)``, rad/s, > 0 (one number: both).
        damping_ratio: ``(zeta_a, zeta_b)``, each >= 0 (one number: both).
        mass: the storey masses ``(m_a, m_b)``, > 0 (one number: both).
        gap: ``g`` > 0, the separation at rest, or ``None`` for two free frames (no constraint: the scene on
            which the probability of pounding is a first passage, :func:`closing`).
        r: the coefficient of restitution, in [0, 1].

    Examples:
        >>> import jdpim
        >>> jdpim.adjacent_buildings(n_storeys=(2, 1)).coordinates
        ('xa1', 'xa2', 'xb1', 'va1', 'va2', 'vb1')
    """
    counts = n_storeys if isinstance(n_storeys, (tuple, list)) else (n_storeys, n_storeys)
    if len(counts) != 2:
        raise ValueError(f"n_storeys must be one integer or two (building a, building b), got {n_storeys!r}")
    na, nb = (int(check_int("n_storeys", c, low=1)) for c in counts)
    frames = [
        _shear_frame(n, w, zeta, m)
        for n, w, zeta, m in zip(
            (na, nb),
            _pair("frequency", frequency, low=0.0, low_open=True),
            _pair("damping_ratio", damping_ratio, low=0.0),
            _pair("mass", mass, low=0.0, low_open=True),
            strict=True,
        )
    ]
    M, C, K = (np.block([[a, np.zeros((na, nb))], [np.zeros((nb, na)), b]]) for a, b in zip(*frames, strict=True))
    constraints = ()
    if gap is not None:
        g = check_number("gap", gap, low=0.0, low_open=True)
        r = check_number("r", r, low=0.0, high=1.0)
        normals = np.zeros((min(na, nb), na + nb))
        for s in range(min(na, nb)):
            normals[s, s], normals[s, na + s] = -1.0, 1.0
        constraints = tuple(Barrier(tuple(normal), -g, r) for normal in normals)
    names = tuple(f"xa{i + 1}" for i in range(na)) + tuple(f"xb{i + 1}" for i in range(nb))
    return MDOFOscillator(
        mass=M, gains=-np.diag(M)[:, None], damping=C, stiffness=K, constraints=constraints, names=names
    )


@dataclasses.dataclass(frozen=True)
class _Closing:
    """``max_j (-n_j . q)`` over the normals ``n_j`` (hashable: a first passage compiles once per model)."""

    normals: tuple

    def __call__(self, state):
        normals = jnp.asarray(self.normals, state.dtype)
        return jnp.max(-(normals @ state[: normals.shape[1]]))


def closing(model: MDOFOscillator):
    r"""The closing of the model's gaps, ``c(q) = max_j (-n_j . q)`` over its constraints ``n_j . q >= -g_j``, as
    a function of the state for :func:`jdpim.first_passage`.

    Constraint ``j`` is reached where ``-n_j . q`` reaches ``g_j``; with one gap ``g`` for all of them (the facing
    storeys of :func:`adjacent_buildings`, the barrier of :func:`pounding_frame`), the first impact happens when
    ``c`` first reaches ``g``. Until then a path does not feel the constraints, so the probability of an impact
    by ``t`` is the first-passage probability ``P(max_{s <= t} c(q(s)) > g)`` on the scene without them
    (``model.replace(constraints=())``, or ``adjacent_buildings(..., gap=None)``), for every gap at once.

    Args:
        model: a :class:`jdpim.MDOFOscillator` with constraints (filters appended or not).

    Examples:
        >>> import jdpim
        >>> import jax.numpy as jnp
        >>> c = jdpim.systems.closing(jdpim.adjacent_buildings(gap=0.1))
        >>> round(float(c(jnp.array([0.3, 0.1, 0.0, 0.0]))), 6)  # xa1 - xb1
        0.2
    """
    if not isinstance(model, MDOFOscillator):
        raise TypeError(f"model must be a jdpim.MDOFOscillator, got {type(model).__name__}")
    if not model.constraints:
        raise ValueError("model has no constraints: there is no gap to close (build it with its gap)")
    return _Closing(tuple(c.normal for c in model.constraints))


def gear_pair(
    mass_ratio: float = 1.0,
    drag: float = 0.05,
    bearing_damping: float = 0.0,
    backlash: float = 0.1,
    r: float = 0.7,
) -> MDOFOscillator:
    r"""A gear pair rattling in its backlash: two gears coupled only by impacts of rigid teeth.

    In coordinates along the line of action (``y_i = rho_i phi_i``, base radius ``rho_i``, rotation ``phi_i``,
    equivalent masses ``m_i = J_i / rho_i^2`` with ``m_1 = 1``):

    .. math::
        y_1'' + c_1 y_1' = \xi(t),\qquad m_2 y_2'' + c_2 y_2' = 0,\qquad |y_1 - y_2| \le b,

    a fluctuating driving torque ``xi`` on the first gear, a viscous drag ``c_2`` on the second (the load of
    an unloaded, rattling stage), bearing damping ``c_1``, and impacts with restitution ``r`` where the teeth
    close the backlash ``b`` on either flank. The teeth are rigid (no mesh stiffness): the model of gear
    rattle, not of a loaded mesh. The positions ``y_i`` wander without bound (the gears turn); the relative
    displacement ``y_1 - y_2`` and the velocities are stationary. Coordinates ``x1``, ``x2``; constraints
    ``[0]``: ``x1 - x2 >= -b``, ``[1]``: ``x1 - x2 <= b``.

    Args:
        mass_ratio: ``m_2 / m_1`` > 0.
        drag: ``c_2`` > 0 (per unit of ``m_1``), 1/s.
        bearing_damping: ``c_1`` >= 0, 1/s.
        backlash: ``b`` > 0 (units of ``y``).
        r: the coefficient of restitution, in [0, 1].

    Examples:
        >>> import jdpim
        >>> [c.position for c in jdpim.gear_pair(backlash=0.2).constraints]
        [-0.2, -0.2]
    """
    m2 = check_number("mass_ratio", mass_ratio, low=0.0, low_open=True)
    c2 = check_number("drag", drag, low=0.0, low_open=True)
    c1 = check_number("bearing_damping", bearing_damping, low=0.0)
    b = check_number("backlash", backlash, low=0.0, low_open=True)
    r = check_number("r", r, low=0.0, high=1.0)
    return MDOFOscillator(
        mass=np.diag([1.0, m2]),
        gains=[[1.0], [0.0]],
        damping=np.diag([c1, c2]),
        constraints=(Barrier((1.0, -1.0), -b, r), Barrier((-1.0, 1.0), -b, r)),
    )
