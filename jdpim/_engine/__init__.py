r"""Batched RK4 over time with impacts located inside the step, on state vectors ``(q, v)`` with constraints.

Every step of every path is one classical RK4 step ``t_n -> t_n + h`` whose forcing is the quadratic
through the excitation at ``t_n``, ``t_n + h/2`` and ``t_n + h`` (exactly RK4's stage values). A path's
state is ``q``, ``v`` of shape ``(d,)``; its model's unilateral constraints ``c_j(q) = n_j . q - b_j >= 0``
(one for a single-degree-of-freedom oscillator with a barrier: ``x - b >= 0``) are stacked by
:mod:`jdpim._constraints`. Where the step ends with a constraint violated the impact is located and resolved:

1. ``s``: root of the cubic Hermite interpolant of each violated ``c_j`` (its values and rates at both ends),
   by a bracketed Newton iteration with a fixed number of steps and one final plain Newton step (so that
   derivatives follow the implicit function theorem and carry the event-time shift: the saltation
   matrix); the constraint crossed first is resolved;
2. redo the step as ``RK4(s h)`` -> impact (``q`` onto ``c_j = 0``, the generalised Newton law
   ``v+ = v- - (1 + r_j) (n_j . v-) M^-1 n_j / (n_j . M^-1 n_j)``; ``x = b``, ``v = -r v`` for one
   coordinate) -> ``RK4((1 - s) h)``;
3. repeat for up to ``max_impacts`` impacts in one step, then fall back to a mirror through every violated
   constraint (``c -> -c``, ``n . v -> -r n . v``), so that no stored state violates a constraint;
4. sticking (one degree of freedom): when the outgoing speed ``r |v_-|`` is below ``stick_velocity`` and
   the force at ``(b, 0)`` pushes into the barrier, the path rests at ``(b, 0)`` until the force (a
   quadratic in the step fraction) turns outward; that departure time is located inside the step, and a
   path that starts a step at rest with an inward force waits for it too. This holds for every ``r``
   (with ``r = 1`` a path pressed against the barrier at rest makes bounces of zero height: it rests too).
   Several degrees of freedom (on the constraints ``ImpactRule.hold`` allows): after such an impact the path
   is held on the constraint, ``n_j . q = b_j`` and ``n_j . v = 0``, and slides along it with the normal part
   of its acceleration taken out (:func:`held_rk4`) until the free normal acceleration turns outward; that
   departure is located inside the step on the quadratic through the held step's stage values. A held
   path that lets go or crosses another constraint inside a step is served with the crossing paths.
5. stiffness: a path whose local rate ``rho = |da/dv| + sqrt(|da/dq|)`` at the start of a step, or at
   the end of its full step, exceeds ``limit / h`` redoes that step as
   ``k = min(max_substeps, ceil(h rho / limit))`` equal sub-steps of its own (see :class:`Substeps`).

Only the crossing paths and those at rest on the barrier do the impact work, gathered into small batches, each path's
impacts resolved on the batch's small arrays and scattered back; the loops have static trip counts and skip their
iterations (``lax.cond``) once no path is pending, so the resolution is traced once whatever ``max_impacts``, and a step
without any crossing skips all of it. Compact batches of up to ``ceil(n / 64)`` crossing paths serve a step until none
is left. An accelerator's chunk of ``WIDE_CHUNK`` paths or more (where every branch costs a read by the host) has a
first batch of up to ``n / 16`` crossing paths in every step, without branches. The ``"mirror"`` method is the
first-order "flip after the step" rule, kept for comparison.

The parts, one module each: :mod:`.settings` (the static settings :class:`ImpactRule` and :class:`Substeps`),
:mod:`.rk4` (one path's RK4 step, free or held; the stiffness rate), :mod:`.locate` (impact location, 1),
:mod:`.resolve` (resolution, 2 and 3), :mod:`.sticking` (rest, hold and departure, 4), :mod:`.substeps`
(sub-stepping, 5), :mod:`.one_path` (one path's pieces of a step over the engine's static settings
:class:`Engine`), :mod:`.batches` (the crossing paths served in batches) and :mod:`.step` (the step of a batch of
paths, :func:`make_batch_step`); :mod:`.elementwise` holds their array helpers.
"""
