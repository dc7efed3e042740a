r"""Example systems with several degrees of freedom, built as :class:`jdpim.MDOFOscillator`.

Each function returns a linear model ``M q'' + C q' + K q = B xi(t)`` with its unilateral constraints; the
white noise ``xi`` (``E[xi(t) xi(t+s)] = 2 D delta(s)``) is set by the scene (``jdpim.WhiteNoise(D)``).
Their parameters are numbers; to vary or differentiate one, use its name in the scene
(``jdpim.with_parameters(scene, {"constraints[0].r": 0.7})``, ``jdpim.parameter_names(scene)``).
"""

from __future__ import annotations

import numpy as np

from ._mdof import Barrier, MDOFOscillator
from ._pytree import check_int, check_real


def _number(name: str, value, **bounds) -> float:
    """``value`` as a float, after ``check_real`` (one number, in range; not traced: it sets a matrix)."""
    if not isinstance(value, (int, float, np.integer, np.floating)) or isinstance(value, bool):
        raise TypeError(f"{name} must be a number, got {value!r}")
    check_real(name, value, scalar=True, **bounds)
    return float(value)


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
    mu = _number("mass_ratio", mass_ratio, low=0.0, low_open=True)
    w = _number("frequency", frequency, low=0.0, low_open=True)
    zeta = _number("damping_ratio", damping_ratio, low=0.0)
    c = _number("clearance", clearance, low=0.0, low_open=True)
    r = _number("r", r, low=0.0, high=1.0)
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
    w = _number("frequency", frequency, low=0.0, low_open=True)
    zeta = _number("damping_ratio", damping_ratio, low=0.0)
    g = _number("gap", gap, low=0.0, low_open=True)
    r = _number("r", r, low=0.0, high=1.0)
    s = n if storey is None else storey
    check_int("storey", s, low=1)
    if s > n:
        raise ValueError(f"storey must lie in [1, {n}] (the storeys of the frame), got {s}")
    k = (w / (2.0 * np.sin(np.pi / (2 * (2 * n + 1))))) ** 2
    K = k * (2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1))
    K[-1, -1] = k
    normal = np.zeros(n)
    normal[s - 1] = -1.0
    return MDOFOscillator(
        mass=np.eye(n),
        gains=-np.ones((n, 1)),
        damping=2.0 * zeta / w * K,
        stiffness=K,
        constraints=(Barrier(tuple(normal), -g, r),),
    )


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
    m2 = _number("mass_ratio", mass_ratio, low=0.0, low_open=True)
    c2 = _number("drag", drag, low=0.0, low_open=True)
    c1 = _number("bearing_damping", bearing_damping, low=0.0)
    b = _number("backlash", backlash, low=0.0, low_open=True)
    r = _number("r", r, low=0.0, high=1.0)
    return MDOFOscillator(
        mass=np.diag([1.0, m2]),
        gains=[[1.0], [0.0]],
        damping=np.diag([c1, c2]),
        constraints=(Barrier((1.0, -1.0), -b, r), Barrier((-1.0, 1.0), -b, r)),
    )
