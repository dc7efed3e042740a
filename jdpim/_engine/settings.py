"""The static settings of the engine: how impacts are resolved (:class:`ImpactRule`) and how stiff steps are split
(:class:`Substeps`)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .._pytree import check_int, check_real


@dataclasses.dataclass(frozen=True)
class ImpactRule:
    """How impacts are resolved (static settings).

    Args:
        method: ``"locate"`` (fourth order: impact time located inside the step) or ``"mirror"``
            (first order: reflect the end-of-step state).
        max_impacts: located impacts per path and step (>= 1) before the mirror fallback.
        stick_velocity: outgoing speed (units of x per s, >= 0) below which a path whose net force
            points into the barrier sticks to it; 0 disables sticking.
        newton_iterations: bracketed Newton steps used to locate the impact (>= 1).
        mirror_below: normal speed (units of x per s, >= 0) below which a crossing is mirrored instead of
            located (``"locate"`` only): the speed ``|n . v|`` at both ends of the step is below it. The slow
            impacts of chattering then cost a plain step; each one's position error is at most about
            ``mirror_below * dt``. Sticking needs located impacts, so a path pressed against a constraint
            bounces in place instead of resting where ``mirror_below`` exceeds ``stick_velocity / r``. 0 (the
            default) locates every impact.
        hold: sticking per constraint for several degrees of freedom (one degree of freedom always sticks
            below ``stick_velocity``): whether a path may be held on a constraint after an impact slower than
            ``stick_velocity`` and slide along it until the free normal acceleration turns outward, one bool
            for every constraint or one per constraint. ``None`` (the default) lets the scene decide:
            constraints whose normal acceleration the white noise reaches (``n_j . M^-1 B != 0``) are not
            held, because there the contact force changes sign within every step and holding only adds
            departures to the impacts; the others (a structure driven through a filter, by a harmonic
            force, or not at all) are.
    """

    method: str = "locate"
    max_impacts: int = 2
    stick_velocity: float = 1e-3
    newton_iterations: int = 4
    mirror_below: float = 0.0
    hold: bool | tuple[bool, ...] | None = None
    scene_hold: tuple[bool, ...] | None = dataclasses.field(default=None, repr=False)  # set by the scene

    def __post_init__(self):
        if self.method not in ("locate", "mirror"):
            raise ValueError(f"method must be 'locate' or 'mirror', got {self.method!r}")
        check_int("max_impacts", self.max_impacts, low=1)
        check_int("newton_iterations", self.newton_iterations, low=1)
        check_real("stick_velocity", self.stick_velocity, low=0.0)
        check_real("mirror_below", self.mirror_below, low=0.0)
        if isinstance(self.hold, list):
            object.__setattr__(self, "hold", tuple(self.hold))
        flags = self.hold if isinstance(self.hold, tuple) else (self.hold,)
        if self.hold is not None and not (flags and all(isinstance(f, (bool, np.bool_)) for f in flags)):
            raise TypeError(f"hold must be None, a bool or a tuple of bools (one per constraint), got {self.hold!r}")
        if isinstance(self.hold, tuple):
            object.__setattr__(self, "hold", tuple(bool(f) for f in self.hold))

    def held(self, n_constraints: int) -> np.ndarray:
        """``(J,)`` bool: the constraints a path may be held on: ``hold``, or where it is ``None`` the scene's
        decision (none without one)."""
        if isinstance(self.hold, tuple):
            if len(self.hold) != n_constraints:
                raise ValueError(f"hold has {len(self.hold)} entries; the model has {n_constraints} constraints")
            return np.asarray(self.hold, bool)
        if self.hold is None and self.scene_hold is not None and len(self.scene_hold) == n_constraints:
            return np.asarray(self.scene_hold, bool)
        return np.full(n_constraints, bool(self.hold))


@dataclasses.dataclass(frozen=True)
class Substeps:
    r"""Sub-stepping of stiff steps (static settings).

    RK4 is stable on the real axis for ``h |lambda| < 2.785``; cubic damping ``gamma v^3`` has the rate
    ``|da/dv| = alpha + 3 gamma v^2``, which large velocities push past that. A path takes a step as
    ``k = min(max_substeps, ceil(h rho / limit))`` equal sub-steps of its own (the forcing quadratic
    resampled on each sub-interval) when the local rate ``rho = |da/dv| + sqrt(|da/dx|)`` at the start
    of the step, or at the end of its full step (a trial every path takes first), calls for it; a
    trial that blew up asks for ``max_substeps``. Each path's ``k`` is its own, so its result does not
    depend on which paths share its batch (chunk size, devices). The sub-steps run inside a
    ``while_loop`` of as many iterations as the largest ``k`` asks (one, the trial, where no path is
    stiff); paths with fewer sub-steps idle in them. Derivatives run the same iterations in a
    ``fori_loop`` of ``max_substeps + 1`` (static trip count, as reverse mode needs) whose iterations
    past the largest ``k`` are skipped. A step without a stiff path costs the trial and two rate
    evaluations per path. Paths still unstable at ``max_substeps`` blow up and are counted
    (``Result.n_nonfinite``), never hidden.

    ``limit`` trades accuracy for time: ``h rho`` near RK4's stability bound (2.785) is stable but
    inaccurate (RK4 damps a mode with ``h lambda = -2`` by 0.33 instead of ``e^-2 = 0.14``). The default
    0.5 keeps the error of the fastest mode per step below 1e-3; measured figures are in the hard-cases
    documentation.

    Args:
        max_substeps: largest number of sub-steps per step (>= 1); 1 disables sub-stepping. It is
            traced only for models that can be stiff (``model.may_be_stiff``), and only when the scene
            asks for it (``Scene(..., substeps=Substeps())``; the default ``None`` costs nothing).
        limit: target ``h rho`` per sub-step, in (0, 2.785).
    """

    max_substeps: int = 16
    limit: float = 0.5

    def __post_init__(self):
        check_int("max_substeps", self.max_substeps, low=1)
        check_real("limit", self.limit, low=0.0, high=2.785, low_open=True, high_open=True)
