"""A scene: model, noise, time grid, what to save, random parameters and numerical settings."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._constraints import clearances
from ._distributions import Distribution, LogNormal, Normal, Range, TruncatedNormal, Uniform
from ._engine.settings import ImpactRule, Substeps
from ._excitation import AbstractExcitation
from ._mdof import CONSTRAINT, MATRIX_ENTRY, MDOFOscillator
from ._models import RK4_RADIUS, AbstractOscillator, AbstractSystem, Oscillator, n_sources_of, rk4_step_limit
from ._noise import WhiteNoise
from ._pytree import array_leaf, check_real, concrete, pytree_dataclass, real_array, static_field
from ._warnings import StepSizeWarning
from .filters import check_harmonic_start

NOISE_PARAMETERS = ("D",)  # parameters of the excitation, beside the model's
_GRID_TOL = 1e-6  # relative tolerance (in steps) for times that must lie on the time grid
# share of RK4's stability bound above which dt is warned about (there an undamped mode loses 8 % of its energy
# per step to RK4 itself)
STEP_WARN = 0.5
# a clearance narrower than this many times the noise's motion across it within one step is refused (docs/mdof.md,
# "Clearances the step resolves": at 1.4 and 2.5 times saved states lie outside, at 4.2 times none)
CLEARANCE_STEPS = 4.0


def _n_constraints(model) -> int:
    """The number of unilateral constraints of ``model`` (a barrier of one degree of freedom counts one)."""
    return len(model.constraints) if hasattr(model, "constraints") else int(model.has_barrier)


@pytree_dataclass
class Scene:
    r"""Everything that defines one stochastic-response computation.

    Args:
        model: the oscillator (physical parameters are traced leaves).
        noise: the white noise (intensity, optional envelope); its number of sources must match the model's gains.
        t_end: end time in s (> 0, a multiple of ``dt``).
        dt: RK4 time step in s (0 < dt < t_end), within RK4's stability bound for the fastest mode of the model
            linearised at rest (filters included); above half of it a ``jdpim.StepSizeWarning``. A clearance
            between opposed constraints must be at least four times the noise's motion across it within one step.
        save_at: times in s at which the state is kept (strictly increasing, in [0, t_end], on the
            time grid). Only these are stored. Default: ``(t_end,)`` (which :meth:`replace` moves with ``t_end``).
        x0: initial displacement (traced); ``None`` starts at the barrier (or 0).
        v0: initial velocity (traced).
        random: random system parameters, ``{name: law}`` with a ``jdpim.Normal``, ``Uniform``, ``TruncatedNormal``
            or ``LogNormal`` law, where ``name`` is a model parameter or ``"x0"``/``"v0"``. Every value the law
            can take must be one the parameter may take (``r`` in [0, 1], ``x0`` at or above the barrier, ...;
            a truncated law bounds a normal one). They become extra DPIM input dimensions.
        excitation: how the white noise is generated at the integrator's nodes (a
            :class:`jdpim.AbstractExcitation`): ``jdpim.SpectralRepresentation()`` (DPIM needs it; Monte Carlo may
            use it) or ``jdpim.GaussianNodes()`` (Monte Carlo: Gaussian values drawn inside the steps), or ``None``
            (default) for each method's own (its ``default_excitation``): the spectral representation for DPIM,
            Gaussian nodes for Monte Carlo, as accurate and cheaper (docs/speed.md).
        impacts: impact-resolution settings.
        substeps: sub-stepping of stiff steps (cubic damping at large velocities), e.g. ``jdpim.Substeps()``;
            ``None`` (default) traces none: blow-up is then counted and warned about (``NonFiniteWarning``).
        dtype: ``"float32"`` or ``"float64"`` (needs ``jax_enable_x64``), or ``None`` for JAX's default.

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), noise=jdpim.WhiteNoise(D=0.03),
        ...                     t_end=10.0, dt=0.01, save_at=(5.0, 10.0))
        >>> scene.n_steps, scene.save_steps
        (1000, (500, 1000))
    """

    model: AbstractSystem
    noise: WhiteNoise = dataclasses.field(default_factory=WhiteNoise)
    x0: Any = None
    v0: Any = 0.0
    t_end: float = static_field(default=200.0)
    dt: float = static_field(default=0.01)
    save_at: tuple = static_field(default=None)
    random: Any = static_field(default=())
    excitation: AbstractExcitation | None = static_field(default=None)
    impacts: ImpactRule = static_field(default_factory=ImpactRule)
    substeps: Substeps | None = static_field(default=None)
    dtype: str | None = static_field(default=None)

    def __post_init__(self):
        if not isinstance(self.model, AbstractSystem):
            raise TypeError(
                f"model must be an oscillator (jdpim.VibroImpactOscillator, jdpim.MDOFOscillator, ...), "
                f"got {self.model!r}"
            )
        if not isinstance(self.noise, WhiteNoise):
            raise TypeError(f"noise must be a jdpim.WhiteNoise, got {self.noise!r}")
        check_real("t_end", self.t_end, low=0.0, low_open=True, scalar=True)
        check_real("dt", self.dt, low=0.0, low_open=True, scalar=True)
        if concrete(self.t_end) is None or concrete(self.dt) is None:
            raise TypeError(f"t_end and dt must be numbers (they fix the time grid), got {self.t_end!r}, {self.dt!r}")
        if not self.dt < self.t_end:
            raise ValueError(f"dt must lie in (0, t_end={self.t_end!r}), got {self.dt!r}")
        ratio = self.t_end / self.dt
        if abs(ratio - round(ratio)) > _GRID_TOL * max(1.0, ratio):
            raise ValueError(f"t_end={self.t_end!r} must be a whole number of steps dt={self.dt!r}")
        object.__setattr__(self, "t_end", float(self.t_end))
        object.__setattr__(self, "dt", float(self.dt))
        object.__setattr__(self, "save_at", self._checked_save_at(self.save_at))
        object.__setattr__(self, "random", self._checked_random(self.random))
        kinds = (
            ("excitation", AbstractExcitation),
            ("impacts", ImpactRule),
            ("substeps", Substeps),
        )
        for name, kind in kinds:
            optional = name in ("excitation", "substeps")  # None: the method's excitation; no sub-steps
            if not isinstance(getattr(self, name), kind) and not (optional and getattr(self, name) is None):
                what = kind.__name__
                raise TypeError(f"{name} must be a jdpim.{what}{' or None' * optional}, got {getattr(self, name)!r}")
        model = self.model
        n_constraints = _n_constraints(model)
        if self.impacts.hold is None and getattr(model, "dimension", 1) > 1 and n_constraints:
            reach = model.noise_reaches()  # sticking per constraint where the noise leaves the contact alone
            if reach is not None:  # else traced gains: the decision made where the scene was built stays
                decided = tuple(bool(not x) for x in reach)
                object.__setattr__(self, "impacts", dataclasses.replace(self.impacts, scene_hold=decided))
        self.impacts.held(n_constraints)  # a hold of one entry per constraint
        if self.excitation is not None:
            self.excitation.check(self)  # e.g. a spectral cutoff below the Nyquist frequency of the stage grid
        if self.dtype not in (None, "float32", "float64"):
            raise ValueError(f"dtype must be None, 'float32' or 'float64', got {self.dtype!r}")
        if self.dtype == "float64" and not jax.config.jax_enable_x64:
            raise ValueError("dtype='float64' needs jax.config.update('jax_enable_x64', True) before use")
        noise_arr = concrete(self.noise.D)
        if noise_arr is not None and n_sources_of(self.model) != self.noise.n_sources:
            raise ValueError(
                f"the model's gains expect {n_sources_of(self.model)} noise source(s) but noise.D "
                f"has {self.noise.n_sources}"
            )
        self._check_step()
        self._check_clearances()
        if isinstance(self.model, AbstractOscillator):
            check_real("v0", self.v0, scalar=True)
            if self.x0 is not None:
                check_real("x0", self.x0, scalar=True)
                x0, b = concrete(self.x0), concrete(self.model.barrier)
                if x0 is not None and b is not None and self.model.has_barrier and np.any(x0 < b):
                    raise ValueError(
                        f"x0={self.x0!r} lies beyond the barrier at {self.model.barrier!r}; it must be >= barrier"
                    )
        else:
            self._check_vector_start()

    def _check_step(self) -> None:
        """``dt`` against RK4's stability bound for the fastest mode of the model linearised at rest (filter
        coordinates included): beyond it a ``ValueError``, above ``STEP_WARN`` of it a ``StepSizeWarning``."""
        jac = self.model.linearised()
        if jac is None:
            return  # traced parameters: checked where the scene is built with numbers
        eigenvalues = np.linalg.eigvals(jac)
        if self.dt * np.max(np.abs(eigenvalues)) <= STEP_WARN * RK4_RADIUS:
            return  # the usual case, well inside the region: no search needed
        limit, lam = rk4_step_limit(eigenvalues)
        if self.dt <= STEP_WARN * limit:
            return
        mode = f"the mode with eigenvalue {lam:.4g} (|lambda| = {abs(lam):.4g} rad/s)"
        if self.dt > limit:
            raise ValueError(
                f"dt={self.dt!r} is beyond RK4's stability bound for {mode}: the largest stable dt is {limit:.4g}"
            )
        warnings.warn(
            f"dt={self.dt!r} is {self.dt / limit:.0%} of RK4's stability bound {limit:.4g} for {mode}: that mode "
            "is integrated inaccurately; reduce dt",
            StepSizeWarning,
            stacklevel=4,
        )

    def _check_clearances(self) -> None:
        """Each clearance between opposed constraints against what one step resolves: ``ValueError`` where it is
        narrower than ``CLEARANCE_STEPS`` times the motion the noise gives it inside one step,
        ``sqrt(2 u^T D u / 3) dt^(3/2)`` (``u = n . M^-1 B``: the noise's accelerations along the normal; the RMS
        of the displacement the noise of one step makes by its end)."""
        if not isinstance(self.model, MDOFOscillator) or len(self.model.constraints) < 2:
            return
        d, gains = concrete(self.noise.D), concrete(self.model.gains)
        position = [concrete(c.position) for c in self.model.constraints]
        if d is None or gains is None or any(b is None for b in position):
            return  # traced or placeholder leaves (jit, lower): checked where the scene is built
        d, normal = np.atleast_2d(d), np.array([c.normal for c in self.model.constraints])
        for i, j, width in clearances(normal, np.array(position, float)):
            if width <= 0:
                raise ValueError(f"constraints[{i}] and constraints[{j}] leave no room between them (width {width:g})")
            u = normal[i] @ self.model.inverse_mass() @ gains
            rate = np.sqrt(2.0 * float(u @ d @ u) / 3.0)  # per dt^(3/2)
            if width < CLEARANCE_STEPS * rate * self.dt**1.5:
                need = (width / (CLEARANCE_STEPS * rate)) ** (2.0 / 3.0)
                raise ValueError(
                    f"the clearance between constraints[{i}] and [{j}] ({width:.3g} wide) is below what dt={self.dt!r} "
                    f"resolves: the noise moves across it by {rate * self.dt**1.5:.3g} within one step (sqrt(2 D / 3) "
                    f"|n . M^-1 B| dt^1.5), and a step resolves clearances over {CLEARANCE_STEPS:g} times that; "
                    f"use dt <= {need:.3g}"
                )

    @property
    def held_constraints(self) -> tuple[bool, ...]:
        """Whether a path may be held on each constraint after a slow impact (``ImpactRule.hold``, or the scene's
        decision where it is ``None``: the constraints the white noise does not reach)."""
        return tuple(bool(h) for h in self.impacts.held(_n_constraints(self.model)))

    def _check_vector_start(self) -> None:
        """A model of ``n`` coordinates: ``x0``, ``v0`` scalars or ``(n,)``; ``x0`` admissible."""
        n = self.model.dimension
        for name in ("x0", "v0"):
            value = array_leaf(name, getattr(self, name))
            object.__setattr__(self, name, value)
            shape = getattr(value, "shape", None) if concrete(value) is None else np.shape(value)
            if value is not None and shape is not None:  # a placeholder (jit, lower) has no shape to check
                check_real(name, value)
                if len(shape) not in (0, 1) or len(shape) == 1 and shape[0] != n:
                    raise ValueError(f"{name} must be a scalar or have shape ({n},), got shape {list(shape)}")
        x0 = concrete(self.initial_state()[0])
        leaves = jax.tree_util.tree_leaves(self.model)
        if x0 is None or any(concrete(leaf) is None for leaf in leaves):
            cons = None  # traced or placeholder leaves (jit, lower): checked where the scene is built
        else:
            with jax.ensure_compile_time_eval():  # concrete also where the scene is built inside a jit trace
                cons = self.model.stacked_constraints()
        if x0 is not None and self.x0 is not None:
            check_harmonic_start(self.model, x0)
        if cons is not None:
            c = cons.normal @ np.broadcast_to(x0, (n,)) - concrete(cons.position)
            if np.any(c < 0):
                j = int(np.argmin(c))
                raise ValueError(
                    f"x0={np.broadcast_to(x0, (n,)).tolist()} violates constraints[{j}] (normal . x0 - position = "
                    f"{c[j]:.3g} < 0); start inside the admissible set"
                )

    def _checked_save_at(self, save_at) -> tuple[float, ...]:
        if save_at is None:
            return (self.t_end,)
        times = np.atleast_1d(real_array("save_at", save_at, "a sequence of times in s"))
        if times.ndim != 1 or times.size == 0:
            raise ValueError(f"save_at must be a non-empty 1-D sequence of times, got {save_at!r}")
        check_real("save_at", times, low=0.0, high=self.t_end)
        if np.any(np.diff(times) <= 0):
            raise ValueError(f"save_at must be strictly increasing, got {save_at!r}")
        steps = times / self.dt
        off = np.abs(steps - np.round(steps)) > _GRID_TOL * np.maximum(1.0, steps)
        if np.any(off):
            raise ValueError(f"save_at times {times[off].tolist()} are not multiples of dt={self.dt!r}")
        return tuple(float(t) for t in np.round(steps) * self.dt)

    def _checked_random(self, random) -> tuple[tuple[str, Distribution], ...]:
        items = tuple(random.items()) if isinstance(random, Mapping) else tuple(random)
        starts = {"x0", "v0"} if isinstance(self.model, AbstractOscillator) else set()  # vector starts: fixed
        allowed = set(model_parameter_names(self.model)) | starts
        laws = (Uniform, Normal, TruncatedNormal, LogNormal)
        for item in items:
            if not (isinstance(item, Sequence) and len(item) == 2):
                raise TypeError(f"random must map parameter names to distributions, got {random!r}")
            name, dist = item
            if name not in allowed:
                shown = sorted(allowed) if len(allowed) <= 12 else sorted(allowed)[:12] + ["..."]
                raise ValueError(f"random parameter {name!r} is not a model parameter; choose from {shown}")
            if not isinstance(dist, laws):
                names = ", ".join(f"jdpim.{k.__name__}" for k in laws)
                raise TypeError(f"random[{name!r}] must be one of {names}, got {dist!r}")
            self._random_range(name, dict(items)).check_law(name, dist)
        return tuple((str(n), d) for n, d in items)

    def _random_range(self, name: str, random: dict) -> Range:
        """The values a random parameter may take: the model's range; a start lies on the admissible side of a
        fixed barrier (``x0 >= barrier``), and a random barrier on the near side of a fixed start."""
        model = self.model
        if name == "v0":
            return Range()
        barrier = concrete(model.barrier) if isinstance(model, AbstractOscillator) and model.has_barrier else None
        if name == "x0":
            return Range() if barrier is None or "barrier" in random else Range(float(barrier))
        x0 = concrete(self.x0)
        if name == "barrier" and x0 is not None and "x0" not in random:
            return Range(high=float(x0))
        return model.parameter_range(name)

    # ---- derived, static quantities -------------------------------------------------------------
    @property
    def n_steps(self) -> int:
        return int(round(self.t_end / self.dt))

    @property
    def save_steps(self) -> tuple[int, ...]:
        return tuple(int(round(t / self.dt)) for t in self.save_at)

    @property
    def n_sources(self) -> int:
        return self.noise.n_sources

    @property
    def float_dtype(self):
        # JAX's default float (float64 under jax_enable_x64), found without running a computation
        return jax.dtypes.canonicalize_dtype(np.float64) if self.dtype is None else jnp.dtype(self.dtype)

    def replace(self, **changes) -> Scene:
        """A copy with fields replaced (``scene.replace(model=scene.model.replace(alpha=0.05))``). A ``save_at``
        that is ``(t_end,)`` (the default) follows a new ``t_end``."""
        if "t_end" in changes and "save_at" not in changes and self.save_at == (self.t_end,):
            changes["save_at"] = None
        return dataclasses.replace(self, **changes)

    def initial_state(self) -> tuple:
        """``(x0, v0)``: the start of every path; ``x0=None`` means the barrier (0 without one; for several
        degrees of freedom the model's ``start``, zeros if it has none)."""
        if not isinstance(self.model, AbstractOscillator):
            if self.x0 is not None:
                return self.x0, self.v0
            start = getattr(self.model, "start", None)
            return (0.0 if start is None else np.asarray(start)), self.v0
        x0 = self.x0 if self.x0 is not None else (self.model.barrier if self.model.has_barrier else 0.0)
        return x0, self.v0

    def time_index(self, t: float) -> int:
        """Index of the saved time ``t`` in ``save_at`` (error if ``t`` was not saved)."""
        return saved_index(self.save_at, t)


def static_times(times) -> tuple[float, ...]:
    """Saved times as a tuple of Python floats (pytree structure); float32 values at their own precision."""
    if isinstance(times, jax.core.Tracer):
        raise TypeError("times must be concrete (saved times are static structure), got a traced array")
    arr = np.asarray(times)
    if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"times must be a 1-D sequence of saved times, got {times!r}")
    if arr.dtype.kind == "f" and arr.dtype.itemsize < 8:  # 0.2 stored in float32 is read as 0.2
        return tuple(float(str(x)) for x in arr)
    return tuple(float(x) for x in arr)


def saved_index(save_at: Sequence[float], t: float) -> int:
    """Index of ``t`` among the saved times, with a clear error when it was not saved.

    ``t`` is a Python or NumPy number, or a concrete 0-d array; a traced ``t`` cannot pick a saved time.
    """
    if isinstance(t, jax.core.Tracer):
        raise TypeError("t must be a concrete saved time (it picks an index), got a traced value")
    if np.ndim(t) != 0:
        raise ValueError(f"t must be one saved time (a scalar), got shape {list(np.shape(t))}")
    check_real("t", t)
    times = np.asarray(save_at)
    rel = max(1e-9, 4 * float(np.finfo(times.dtype).eps)) if times.dtype.kind == "f" else 1e-9  # float32 times
    i = int(np.argmin(np.abs(times - float(t))))
    if abs(float(times[i]) - float(t)) > rel * max(1.0, abs(float(t))):
        raise ValueError(f"t={t!r} was not saved; saved times are {times.tolist()}")
    return i


# ---- parameters by name -------------------------------------------------------------------------


_MATRIX_ENTRY, _CONSTRAINT = MATRIX_ENTRY, CONSTRAINT


def _has_params_key(model, name: str) -> bool:
    return isinstance(model, (Oscillator, MDOFOscillator)) and isinstance(model.params, dict) and name in model.params


def get_parameter(model, name: str):
    """A model parameter by name: a field, a key of a dict ``params``, or for :class:`MDOFOscillator` a matrix
    entry ``"damping[i,j]"`` (``stiffness``, ``gains``) or a constraint's ``"constraints[j].r"`` (``.position``)."""
    if _has_params_key(model, name):
        return model.params[name]
    if isinstance(model, MDOFOscillator):
        if m := _MATRIX_ENTRY.match(name):
            return _matrix_entry(getattr(model, m[1]), int(m[2]), int(m[3]))
        if m := _CONSTRAINT.match(name):
            return getattr(model.constraints[int(m[1])], m[2])
    return getattr(model, name)


def set_parameter(model, name: str, value):
    """``model`` with the parameter ``name`` (as for :func:`get_parameter`) replaced by ``value`` (may be traced)."""
    if _has_params_key(model, name):
        return model.replace(params={**model.params, name: value})
    if isinstance(model, MDOFOscillator):
        if m := _MATRIX_ENTRY.match(name):
            return model.replace(**{m[1]: _with_matrix_entry(getattr(model, m[1]), int(m[2]), int(m[3]), value)})
        if m := _CONSTRAINT.match(name):
            j = int(m[1])
            changed = dataclasses.replace(model.constraints[j], **{m[2]: value})
            return model.replace(constraints=model.constraints[:j] + (changed,) + model.constraints[j + 1 :])
    return model.replace(**{name: value})


@jax.jit
def _matrix_entry(matrix, i, j):
    """``matrix[i, j]``: one compiled program per matrix shape and dtype."""
    return jnp.asarray(matrix)[i, j]


@jax.jit
def _with_matrix_entry(matrix, i, j, value):
    """``matrix`` with entry ``(i, j)`` set to ``value`` (may be traced): one compiled program per shape and dtype."""
    return jnp.asarray(matrix).at[i, j].set(value)


def with_model_parameters(model, names: tuple[str, ...], values) -> Any:
    """``model`` with the parameters ``names`` set to ``values[i]`` (one path's random parameters)."""
    for i, name in enumerate(names):
        model = set_parameter(model, name, values[i])
    return model


def model_parameter_names(model) -> tuple[str, ...]:
    """Names :func:`get_parameter` accepts for ``model`` (its traced scalars; matrices entry by entry)."""
    if isinstance(model, MDOFOscillator):
        names = []
        for field in ("damping", "stiffness", "gains"):
            if getattr(model, field) is not None:
                rows, cols = np.shape(getattr(model, field))
                names += [f"{field}[{i},{j}]" for i in range(rows) for j in range(cols)]
        names += [f"constraints[{j}].{key}" for j in range(len(model.constraints)) for key in ("r", "position")]
        keys = model.params if isinstance(model.params, dict) else {}
        return tuple(names) + tuple(k for k in keys if isinstance(k, str) and k not in names)
    fields = dataclasses.fields(model)
    names = tuple(f.name for f in fields if not f.metadata.get("static", False) and f.name != "params")
    if isinstance(model, Oscillator) and isinstance(model.params, dict):
        names = names + tuple(k for k in model.params if k not in names and isinstance(k, str))
    return names


def parameter_names(scene: Scene) -> tuple[str, ...]:
    """Names of a scene's parameters (what ``with_parameters`` and ``jdpim.sensitivity`` accept).

    The model's traced fields, the keys of a dict ``params``, for :class:`jdpim.MDOFOscillator` its matrix
    entries (``"damping[0,1]"``) and constraint parameters (``"constraints[0].r"``), and the noise intensity
    ``"D"``.
    """
    return model_parameter_names(scene.model) + NOISE_PARAMETERS


def parameter_value(scene: Scene, name: str):
    """The value of the parameter ``name`` of ``scene`` (one of :func:`parameter_names`; ``"D"`` is the noise's)."""
    if name not in parameter_names(scene):
        raise ValueError(f"unknown parameter {name!r}; choose from {list(parameter_names(scene))}")
    return scene.noise.D if name in NOISE_PARAMETERS else get_parameter(scene.model, name)


def with_parameters(scene: Scene, values: dict) -> Scene:
    """``scene`` with named parameters replaced, e.g. ``{"alpha": 0.05, "D": 0.08}`` (values may be traced)."""
    allowed = parameter_names(scene)
    unknown = sorted(set(values) - set(allowed))
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}; choose from {list(allowed)}")
    model = scene.model
    for name, value in values.items():
        if name not in NOISE_PARAMETERS:
            model = set_parameter(model, name, value)
    scene = scene.replace(model=model)
    if "D" in values:
        scene = scene.replace(noise=dataclasses.replace(scene.noise, D=values["D"]))
    return scene
