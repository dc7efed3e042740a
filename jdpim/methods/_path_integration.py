r"""Path integration: the transition density of a one-degree-of-freedom scene on a phase-space grid.

``jdpim.path_integration(scene)`` evolves the joint density ``p(x, v, t)`` of the scene's oscillator with
the one-step operator of ``jdpim.methods._pi_operator`` (Strang splitting: half a Gaussian diffusion step in ``v``,
the deterministic flow by semi-Lagrangian back-tracing with the impact law, another half diffusion step)
and renormalises after every step, reporting the defect (a noise modulated by ``e(t)`` sets the kernels of
every step, ``intensity_weights``). ``stationary=True`` finds the fixed point of the
step by a Newton-Krylov solve (BiCGStab, GMRES where it stagnates; checked), differentiated implicitly
(``jax.lax.custom_root``: one checked linear solve per tangent or cotangent, no back-propagation through
the iterations).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.sparse.linalg import bicgstab, gmres

from .._models import AbstractOscillator, VibroImpactOscillator
from .._pytree import check_int, check_real, concrete
from .._scene import Scene
from ..results._grid import GridResult
from ._base import AbstractMethod, solve
from ._pi_operator import StepOperator, drift_and_diffusion, make_grid, state_dependent, step_operator

ENERGY_SPAN = 20.0  # default extents: the energy where the estimated stationary density falls by e^-20


# order=None takes linear weights below this r: measured (stationary, alpha = gamma = D = 0.03, 121 x 241), cubic
# weights leave a negative mass of 1e-11 at r = 0.3-0.4, 1.3e-8 at 0.25, 1.7e-5 at 0.2, 4.5e-4 at 0.15
LINEAR_BELOW_R = 0.25


# the tangent and adjoint solves of the stationary density run on the operator of this many steps (see
# _linear_solve and docs/path_integration.md, "Derivatives"): the cotangent of a pointwise density excites
# the weakly damped rotating modes of the step, whose eigenvalues crowd zero on both sides of the imaginary
# axis; over several steps the well-damped modes fold onto one, and BiCGStab no longer stalls
DERIVATIVE_STEPS = 16


class PathIntegrationWarning(RuntimeWarning):
    """The path-integration grid is too small or too coarse, or the solve did not converge."""


@dataclasses.dataclass(frozen=True)
class PathIntegration(AbstractMethod):
    r"""Path integration on a phase-space grid (settings; run it with ``jdpim.solve(scene, PathIntegration(...))``).

    Solves the Fokker-Planck equation of a one-degree-of-freedom scene ``x'' + g(x) + f(x, x') = h(x, x') . xi(t)``
    on ``x >= barrier`` with the impact law ``x'_+ = -r x'_-`` (white noise ``E[xi xi^T] = 2 D delta``,
    Stratonovich gains; modulated by the noise's envelope ``e(t)``, if any, for state-independent gains: each
    half-step kernel then takes the mean of ``e^2`` over its half step) by a mass-conservative splitting step
    on a grid (see ``docs/path_integration.md``),
    with renormalisation after each step (the defect is reported as ``GridResult.mass_defect``). The scene
    gives the physics: model, noise, start ``x0``/``v0`` (a point mass, see ``t0``), ``save_at`` (multiples of
    ``tau`` after the start) and ``dtype``; its ``dt``, excitation and impact settings are not used, and random
    parameters are not supported. ``solve`` returns a :class:`jdpim.GridResult`; a ``PathIntegrationWarning``
    is issued when mass reaches the grid's edges, the renormalisation defect is large, the solve did not
    converge, or densities are not finite.

    Args:
        n_x: grid nodes in ``x`` (from the barrier to ``barrier + x_max``, or ``[-x_max, x_max]`` without a
            barrier).
        n_v: grid nodes in ``v`` (``[-v_max, v_max]``); ``n_v`` odd puts a node at ``v = 0``.
        x_max: the grid's extent in ``x``; ``None`` estimates it (and ``v_max``) from the scene: the energy
            ``H*`` at which the stochastically averaged stationary density ``exp(-(a_e H + b H^2)/D)`` falls by
            ``e^-20`` (``a_e`` = linear damping + ``(1 - r^2)/pi``, ``b = 3 gamma / 4``), ``v_max = sqrt(2 H*)``,
            ``x_max = v_max / omega``; a start away from rest widens them. Give them explicitly when
            differentiating with respect to parameters that set them (D, alpha, gamma, r).
        v_max: the grid's extent in ``v``; ``None`` estimates it (see ``x_max``).
        tau: time step, s (saved times must be multiples of it, counted from the start).
        substeps: RK4 substeps of the back-trace over one step.
        order: interpolation points per axis (2: linear, 4: cubic, 6: quintic Lagrange), or ``None``:
            4, except 2 for a barrier with ``r < 0.25`` (there the outgoing density near ``(barrier, 0)`` is
            squeezed by ``r`` into a layer thinner than the grid, and only linear weights stay positive).
        t0: a point-mass start (the scene's ``x0``/``v0``) is replaced by the Gaussian of the system
            linearised at the start, at time ``t0`` (s, a multiple of ``tau``), folded at the barrier.
        newton: most Newton steps of the stationary solve (each one linear solve); it stops earlier once
            the L1 residual of a step is below 1e-8 (float64) or 3e-6 (float32).
        max_iter: BiCGStab iterations per attempt of every linear solve (Newton steps, and the tangent and
            adjoint solves of derivatives), which stops at a relative residual of 1e-9 (float64) or 1e-5
            (float32). The tangent and adjoint solves run on the operator of 16 steps (each iteration applies
            the linearised step 16 times; see ``docs/path_integration.md``, "Derivatives").
        max_restarts: BiCGStab attempts (each from the best iterate so far); where they do not reach the
            tolerance, up to ``max_restarts`` cycles of GMRES follow.
        restart: the Krylov dimension of those GMRES cycles. A solve that ends above 100 times the tolerance
            returns NaN (non-finite, with a ``PathIntegrationWarning``).
        warmup: plain steps before the Newton solve (from the averaged law ``exp(-(a_e H + b H^2)/q)``
            estimated as for the extents, or a Gaussian when the parameters are traced).
        leak_tol: largest mass allowed in the outermost node rows before a ``PathIntegrationWarning``.
        estimate_error: also solve on a grid twice as coarse in ``x`` and ``v`` (every other node) with twice
            the step ``tau`` where the saved times allow it, kept as ``GridResult.coarse``: then
            ``GridResult.pdf_error`` and ``l1_error`` estimate the discretisation error (about a tenth of
            the cost more; the coarse solve is not differentiated).
        stationary: solve for the stationary density instead (``t`` may then be left out everywhere, and
            ``GridResult.times`` is ``(inf,)``); refused for a modulated noise (it has none).
        initial: a density ``initial(x, v)`` at ``t = 0`` (vectorised over node arrays of shape
            ``(n_x, n_v)``, JAX-traceable) instead of the point-mass start; renormalised on the grid.

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, barrier=None),
        ...                     noise=jdpim.WhiteNoise(D=0.05), t_end=1.0, dt=0.02)
        >>> res = jdpim.solve(scene, jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1))
        >>> round(float(res.mass(t=1.0)), 4)
        1.0
    """

    n_x: int = 121
    n_v: int = 241
    x_max: float | None = None
    v_max: float | None = None
    tau: float = 0.05
    substeps: int = 2
    order: int | None = None
    t0: float = 1.0
    newton: int = 3
    max_iter: int = 1000
    max_restarts: int = 4
    restart: int = 100
    warmup: int = 200
    leak_tol: float = 1e-5
    estimate_error: bool = False
    stationary: bool = False
    initial: Callable | None = None
    name = "path_integration"

    def __post_init__(self):
        for name, low in (("n_x", 8), ("n_v", 8), ("substeps", 1), ("newton", 1), ("max_iter", 1), ("restart", 2)):
            check_int(name, getattr(self, name), low=low)
        check_int("max_restarts", self.max_restarts, low=1)
        check_int("warmup", self.warmup, low=0)
        if self.order not in (None, 2, 4, 6):
            raise ValueError(f"order must be 2, 4 or 6 interpolation points per axis, got {self.order!r}")
        for name in ("x_max", "v_max"):
            if getattr(self, name) is not None:
                check_real(name, getattr(self, name), low=0.0, low_open=True)
        check_real("tau", self.tau, low=0.0, low_open=True)
        check_real("t0", self.t0, low=0.0, low_open=True)
        check_real("leak_tol", self.leak_tol, low=0.0)
        for name in ("estimate_error", "stationary"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if self.initial is not None and not callable(self.initial):
            raise TypeError(f"initial must be a callable (x, v) -> density or None, got {self.initial!r}")
        k = self.t0 / self.tau
        if abs(k - round(k)) > 1e-6 * max(1.0, k):
            raise ValueError(f"t0={self.t0!r} must be a multiple of tau={self.tau!r}")

    def run(self, scene: Scene) -> GridResult:
        return _run(scene, self)


jax.tree_util.register_dataclass(
    PathIntegration, data_fields=[], meta_fields=[f.name for f in dataclasses.fields(PathIntegration)]
)


def _scalar(name, value) -> float:
    arr = concrete(value)
    if arr is None:
        raise ValueError(
            f"{name} is traced: give x_max and v_max in jdpim.PathIntegration explicitly "
            "(the grid extents are estimated from concrete parameter values)"
        )
    return float(arr)


def on_host(fn: Callable) -> Callable:
    """``fn``, its operations on concrete values (a scene of plain numbers) evaluated when it is called, also inside a
    user's ``jax.jit``, where they would be staged into the outer program and could not be read (``float``)."""

    @functools.wraps(fn)
    def evaluated(*args, **kwargs):
        with jax.ensure_compile_time_eval():
            return fn(*args, **kwargs)

    return evaluated


@on_host
def averaged_energy_law(scene: Scene) -> tuple[float, float, float, float]:
    """``(a_e, b, q, k)`` of the averaged stationary law ``exp(-(a_e H + b H^2) / q)``, ``H = (k x^2 + v^2) / 2``.

    ``a_e`` = linear damping at the barrier (or 0) + ``(1 - r^2) / pi``, ``b = 3 gamma / 4`` (reference model
    only), ``q = h^T D h`` and ``k = g'`` there. Needs concrete parameters; raises ``ValueError`` otherwise.
    """
    model = scene.model
    b = _scalar("barrier", model.barrier) if model.has_barrier else 0.0
    D = concrete(scene.noise.D)
    if D is None:
        _scalar("D", scene.noise.D)
    a_fn, q_fn = drift_and_diffusion(model, D)
    q = float(q_fn(jnp.asarray(b), jnp.asarray(0.0)))
    lin = -float(jax.grad(a_fn, argnums=1)(jnp.asarray(b), jnp.asarray(0.0)))
    stiff = -float(jax.grad(a_fn, argnums=0)(jnp.asarray(b), jnp.asarray(0.0)))
    cubic = 0.75 * _scalar("gamma", model.gamma) if isinstance(model, VibroImpactOscillator) and model.gamma else 0.0
    a_e = lin + ((1 - _scalar("r", model.r) ** 2) / math.pi if model.has_barrier else 0.0)
    if not (q > 0 and stiff > 0 and (a_e > 0 or cubic > 0)):
        raise ValueError(
            "cannot estimate the grid extents for this model (needs noise, a positive stiffness and damping "
            f"at the start; got q={q:g}, stiffness={stiff:g}, damping={a_e:g}): give x_max and v_max"
        )
    return a_e, cubic, q, stiff


def traced_parameters(scene: Scene) -> list[str]:
    """Names of the scene's physical parameters that are traced (differentiated or vmapped), e.g. ``["alpha"]``."""
    named = [(f.name, getattr(scene.model, f.name)) for f in dataclasses.fields(scene.model)]
    named += [("D", scene.noise.D), ("x0", scene.x0), ("v0", scene.v0)]
    traced = []
    for name, value in named:
        leaves = jax.tree.leaves(value)
        if any(isinstance(leaf, jax.core.Tracer) for leaf in leaves):
            traced.append(name)
    return traced


@on_host
def default_extents(scene: Scene, settings: PathIntegration) -> tuple[float, float]:
    """``(x_max, v_max)``: the settings' extents, or estimates from the scene (see ``PathIntegration``)."""
    if settings.x_max is not None and settings.v_max is not None:
        return float(settings.x_max), float(settings.v_max)
    traced = traced_parameters(scene)
    if traced:
        raise ValueError(
            f"path integration estimates its grid extents from the parameters, but {', '.join(traced)} "
            "is traced (differentiated or vmapped): give x_max and v_max in jdpim.PathIntegration (the grid "
            "does not move with the parameter), or use jdpim.sensitivity, which fixes them at the nominal values"
        )
    a_e, cubic, q, stiff = averaged_energy_law(scene)
    c = ENERGY_SPAN * q * peak_weight(scene, settings.tau)  # (a_e H + cubic H^2) / q = ENERGY_SPAN
    H = c / a_e if cubic == 0 else (-a_e + math.sqrt(a_e * a_e + 4 * cubic * c)) / (2 * cubic)
    v_max = math.sqrt(2 * H)
    x_max = v_max / math.sqrt(stiff)
    model = scene.model
    b = _scalar("barrier", model.barrier) if model.has_barrier else 0.0
    x0, v0 = scene.initial_state()
    x0, v0 = float(np.max(np.abs(concrete(x0) - b))), float(np.max(np.abs(concrete(v0))))
    x_max = max(x_max, 1.5 * x0 + 0.5 * x_max) if x0 else x_max
    v_max = max(v_max, 1.5 * v0 + 0.5 * v_max) if v0 else v_max
    return float(settings.x_max or x_max), float(settings.v_max or v_max)


def validate(scene: Scene, settings: PathIntegration, initial, stationary: bool) -> None:
    """Refuse, in one line, a scene or settings path integration cannot solve (before tracing)."""
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a jdpim.Scene, got {scene!r}")
    if not isinstance(settings, PathIntegration):
        raise TypeError(f"settings must be a jdpim.PathIntegration, got {settings!r}")
    if not isinstance(scene.model, AbstractOscillator):
        n = getattr(scene.model, "dimension", None)
        raise ValueError(
            f"path integration needs a grid of dimension 2n, here {2 * n} (the model has {n} degrees of freedom): "
            "it solves one-degree-of-freedom scenes; use jdpim.DPIM or jdpim.MonteCarlo"
        )
    if scene.random:
        raise ValueError(
            f"path integration does not take random parameters (scene.random={dict(scene.random)!r}); "
            "use jdpim.dpim or jdpim.monte_carlo"
        )
    if stationary:
        scene.noise.require_stationary(
            "PathIntegration(stationary=True) (a stationary density)",
            "a modulated noise has none; use stationary=False",
        )
    if scene.noise.spectrum is not None:
        raise ValueError(
            f"path integration takes white noise, modulated or not, not an evolutionary spectrum "
            f"({scene.noise.envelope!r}): its steps assume one intensity for every frequency; use jdpim.DPIM or "
            "jdpim.MonteCarlo(excitation=jdpim.SpectralRepresentation())"
        )
    if scene.noise.envelope is not None and state_dependent(scene.model):
        raise ValueError(
            "path integration of a modulated noise needs state-independent gains (h=None): with gains h(x, v) every "
            "node's kernel and the Wong-Zakai drift of the flow would change at every step; use jdpim.DPIM or "
            "jdpim.MonteCarlo"
        )
    if scene.model.time_dependent:
        raise ValueError("path integration needs a model whose forces do not depend on the time; use jdpim.DPIM")
    if scene.model.has_barrier:
        check_real("r", scene.model.r, low=0.0, low_open=True, high=1.0)
    if initial is not None and not callable(initial):
        raise TypeError(f"initial must be a callable (x, v) -> density or None, got {initial!r}")
    if stationary:
        return
    start = 0.0 if initial is not None else settings.t0
    for t in scene.save_at:
        k = (t - start) / settings.tau
        if k < -1e-9 or abs(k - round(k)) > 1e-6 * max(1.0, k):
            where = "t = 0 (initial density)" if initial is not None else f"t0={settings.t0!r}"
            raise ValueError(
                f"saved time {t!r} must be {where} plus a whole number of steps tau={settings.tau!r}; "
                f"saved times are {list(scene.save_at)}"
            )


def _point_start(scene: Scene, grid, dtype, t0: float, n: int = 200):
    """Density at ``t0`` of the system linearised at the start point, folded at the barrier with the impact law
    (its covariance driven by ``2 q e(t)^2`` for a noise modulated by ``e(t)``)."""
    model = scene.model
    envelope = scene.noise.envelope
    a, q = drift_and_diffusion(model, scene.noise.D)
    x0, v0 = (jnp.asarray(z, dtype) for z in scene.initial_state())
    a0 = a(x0, v0)
    ax, av = jax.grad(a, argnums=(0, 1))(x0, v0)
    A = jnp.stack([jnp.stack([jnp.zeros_like(ax), jnp.ones_like(ax)]), jnp.stack([ax, av])])
    Q = jnp.zeros((2, 2), dtype).at[1, 1].set(2 * q(x0, v0))

    def rhs(state, t):
        m, C = state
        dm = jnp.stack([m[1], a0 + ax * (m[0] - x0) + av * (m[1] - v0)])
        forcing = Q if envelope is None else Q * jnp.asarray(envelope(t), dtype) ** 2
        return dm, A @ C + C @ A.T + forcing

    def rk4(state, k):
        h = t0 / n
        t = k * h
        k1 = rhs(state, t)
        k2 = rhs(jax.tree.map(lambda s, k: s + 0.5 * h * k, state, k1), t + 0.5 * h)
        k3 = rhs(jax.tree.map(lambda s, k: s + 0.5 * h * k, state, k2), t + 0.5 * h)
        k4 = rhs(jax.tree.map(lambda s, k: s + h * k, state, k3), t + h)
        return jax.tree.map(lambda s, p, q_, w, z: s + h / 6 * (p + 2 * q_ + 2 * w + z), state, k1, k2, k3, k4), None

    init = (jnp.stack([x0, v0]), jnp.zeros((2, 2), dtype))
    (m, C), _ = jax.lax.scan(rk4, init, jnp.arange(n, dtype=dtype))
    det = C[0, 0] * C[1, 1] - C[0, 1] ** 2
    X, V = jnp.meshgrid(grid.x, grid.v, indexing="ij")

    def gauss(x, v):
        dx, dv = x - m[0], v - m[1]
        return jnp.exp(-0.5 * (C[1, 1] * dx * dx - 2 * C[0, 1] * dx * dv + C[0, 0] * dv * dv) / det) / (
            2 * jnp.pi * jnp.sqrt(det)
        )

    if not model.has_barrier:
        return gauss(X, V), C
    b = jnp.asarray(model.barrier, dtype)
    r = jnp.asarray(model.r, dtype)
    # Gaussian mass beyond the barrier has impacted: from (b - d, v) it went to (b + r d, -r v) (area factor r^2)
    return gauss(X, V) + gauss(b - (X - b) / r, -V / r) / r**2, C


def _edge_mask(n_x: int, n_v: int, has_barrier: bool, dtype):
    mask = np.zeros((n_x, n_v))
    mask[-2:, :] = 1.0
    if not has_barrier:
        mask[:2, :] = 1.0
    mask[:, :2] = 1.0
    mask[:, -2:] = 1.0
    return jnp.asarray(mask, dtype)


def setup(scene: Scene, settings: PathIntegration, extents):
    """``(grid, ops, weights, edge)``: the grid of ``extents`` ``(x_max, v_max)``, its step operator, its quadrature
    weights and its edge mask."""
    dtype = scene.float_dtype
    # values, never constants: a solve traced inside a user's jit rounds as the same solve called directly
    scene, extents = jax.lax.optimization_barrier((scene, tuple(jnp.asarray(e, dtype) for e in extents)))
    grid = make_grid(scene.model, settings.n_x, settings.n_v, *extents, dtype)
    D = jnp.asarray(scene.noise.D, dtype)
    ops = step_operator(
        scene.model, D, grid, settings.tau, settings.substeps, settings.order, settings.n_x, settings.n_v
    )
    weights = ops.area
    edge = _edge_mask(settings.n_x, settings.n_v, scene.model.has_barrier, dtype) * weights
    return grid, ops, weights, edge


def start_density(scene: Scene, settings: PathIntegration, grid, weights, initial):
    """``(p, t_start)``: the transient's start density ``(n_x, n_v)`` (mass 1 on the grid) and its time, s."""
    dtype = grid.x.dtype
    if initial is None:
        p, _ = _point_start(scene, grid, dtype, settings.t0)
        start = settings.t0
    else:
        X, V = jnp.meshgrid(grid.x, grid.v, indexing="ij")
        p = jnp.asarray(initial(X, V), dtype)
        start = 0.0
    if p.shape != (settings.n_x, settings.n_v):
        raise ValueError(f"initial(x, v) must return the grid's shape {(settings.n_x, settings.n_v)}, got {p.shape}")
    return p / jnp.sum(weights * p), start


def intensity_weights(noise, start: float, tau: float, n: int, dtype):
    r"""``(n, 2)``: the mean of ``e(t)^2`` over the first and the second half of each of ``n`` steps from ``start``
    (3-point Gauss-Legendre on each half: exact for ``e^2`` polynomial of degree 5 there); ``None`` for a
    stationary noise.

    Each half-step diffusion then adds exactly the velocity variance ``2 q int e^2 dt`` of its half step: the
    diffusion operators ``q e(t)^2 d^2/dv^2`` at different times commute, so the diffusion sub-steps are exact
    and the step keeps the second-order error of the Strang splitting (``O(tau^2)`` at a fixed time), also for
    envelopes with kinks (Jennings') where a midpoint value would lose an order in the steps that hold the kink.
    """
    if noise.envelope is None:
        return None
    nodes, w = np.polynomial.legendre.leggauss(3)
    offsets = tau / 2 * (np.arange(2)[:, None] + (nodes[None, :] + 1) / 2)  # (2, 3) within a step
    t = start + tau * jnp.arange(n, dtype=dtype)[:, None, None] + jnp.asarray(offsets, dtype)[None]
    e = jax.vmap(noise.envelope)(t.ravel()).reshape(t.shape)
    return jnp.sum(jnp.asarray(e, dtype) ** 2 * jnp.asarray(w / 2, dtype)[None, None, :], axis=-1)


def step_exponents(scene: Scene, settings: PathIntegration, ops: StepOperator, start: float, n: int):
    """``(n, 2)``: the exponents of the half-step kernels of ``n`` steps from ``start`` (``StepOperator.exponents``
    of ``intensity_weights``); ``None`` for a stationary noise."""
    weights = intensity_weights(scene.noise, start, settings.tau, n, ops.kernel.dtype)
    return None if weights is None else ops.exponents(weights)


def peak_weight(scene: Scene, tau: float) -> float:
    """The largest mean of ``e(t)^2`` over the half steps from 0 to the last saved time (1 for a stationary noise):
    sizes the grid and checks its resolution at the noise's strongest."""
    if scene.noise.envelope is None:
        return 1.0
    n = max(1, math.ceil(max(t for t in scene.save_at if math.isfinite(t)) / tau - 1e-9))
    return float(np.max(np.asarray(intensity_weights(scene.noise, 0.0, tau, n, scene.float_dtype))))


def saved_scan(body, carry, steps, xs=None):
    """The carries of ``lax.scan(body, carry)`` after each of ``steps`` (counts of steps), a list; ``xs``
    (leading axis: at least ``max(steps)``): the per-step inputs, ``None`` for none.

    One scan over ``max(steps)`` steps that writes its carry into a buffer row after each saved count: the
    program holds one copy of the step, however many times are saved.
    """
    counts = sorted({k for k in steps if k > 0})
    if not counts:
        return [carry for _ in steps]
    n = counts[-1]
    slot = np.zeros(n, np.int32)  # after step i + 1: the buffer row it is saved to (if saved)
    saved = np.zeros(n, bool)
    for row, k in enumerate(counts):
        slot[k - 1], saved[k - 1] = row, True
    slot = np.maximum.accumulate(slot)  # unsaved steps point at the row written last (rewritten unchanged)
    rows = jax.tree.map(lambda c: jnp.zeros((len(counts), *jnp.shape(c)), jnp.result_type(c)), carry)

    def step(state, inputs):
        c, buffer = state
        x, keep, row = inputs
        c, _ = body(c, x)
        buffer = jax.tree.map(lambda b, v: b.at[row].set(jnp.where(keep, v, b[row])), buffer, c)
        return (c, buffer), None

    xs = None if xs is None else jax.tree.map(lambda z: z[:n], xs)
    (_, rows), _ = jax.lax.scan(step, (carry, rows), (xs, jnp.asarray(saved), jnp.asarray(slot)), length=n)
    at = {k: row for row, k in enumerate(counts)}
    return [carry if k <= 0 else jax.tree.map(lambda b, r=at[k]: b[r], rows) for k in steps]


def program_settings(settings: PathIntegration) -> PathIntegration:
    """The settings as a solve's program sees them (static: sizes, order, steps, solver limits): the extents travel
    as values beside them, and ``leak_tol`` and ``estimate_error`` act outside it, so one program serves every
    extent, tolerance and error estimate (a sweep over D or r compiles once)."""
    return dataclasses.replace(
        settings, x_max=None, v_max=None, leak_tol=PathIntegration.leak_tol, estimate_error=False
    )


def typed_parameters(scene: Scene) -> Scene:
    """``scene`` with its weakly typed array parameters (a Python number under ``jax.jacfwd`` or ``jax.grad``) in the
    scene's float dtype, strongly typed: a derivative taken at a number and one taken at an array (``wrt=``) then
    run one program. Python numbers, as a scene is built, stay as they are."""

    def strong(leaf):
        if isinstance(leaf, jax.Array) and jax.typeof(leaf).weak_type and jnp.issubdtype(leaf.dtype, jnp.floating):
            return jnp.asarray(leaf, scene.float_dtype)
        return leaf

    return jax.tree.map(strong, scene)


@functools.partial(jax.jit, static_argnames=("settings", "initial"))
def _transient(scene: Scene, settings: PathIntegration, extents, initial):
    grid, ops, weights, edge = setup(scene, settings, extents)
    dtype = grid.x.dtype
    p, start = start_density(scene, settings, grid, weights, initial)
    zero = jnp.zeros((), dtype)
    carry = (p, zero, jnp.sum(edge * p))

    def body(carry, exponents):
        p, defect, leak = carry
        p = ops.step(p, exponents)
        m = jnp.sum(weights * p)
        p = p / m
        return (p, defect + jnp.abs(1 - m), jnp.maximum(leak, jnp.sum(edge * p))), None

    steps = [int(round((t - start) / settings.tau)) for t in scene.save_at]
    outs = saved_scan(body, carry, steps, step_exponents(scene, settings, ops, start, max(steps)))
    density, defect, leak = (jnp.stack(z) for z in zip(*outs, strict=True))
    nan = jnp.full(density.shape[:1], jnp.nan, dtype)
    none = jnp.zeros(density.shape[:1], dtype)
    return _grid_result(
        scene.model.has_barrier,
        scene.save_at,
        density,
        grid,
        ops,
        mass_defect=defect,
        edge_mass=leak,
        residual=nan,
        step_gain=nan,
        newton_steps=none,
        virial=nan,
        stationary=False,
    )


def _grid_result(has_barrier: bool, times, density, grid, ops: StepOperator, **fields) -> GridResult:
    folded = ops.fold is not None
    x_weights, v_weights = grid.axis_weights(ops.order, folded)
    return GridResult(
        times,
        density,
        grid.x,
        grid.v,
        x_weights,
        v_weights,
        order=ops.order,
        folded=folded,
        has_barrier=has_barrier,
        **fields,
    )


def _warn_unsolved(relres, solved) -> None:
    if np.all(solved):
        return
    warnings.warn(
        f"path integration: a linear solve stopped at relative residual {float(np.max(relres)):.2e}; its result "
        "(a Newton step, or a derivative) is NaN: raise max_iter, max_restarts or restart, or refine the grid",
        PathIntegrationWarning,
        stacklevel=2,
    )


def _linear_solve(settings: PathIntegration, matvec, b, steps: int = 1):
    """``x`` with ``matvec(x) = b`` by BiCGStab, restarted from its best iterate, then GMRES; NaN if unsolved.

    Restarted GMRES stagnates on the adjoint of the stationary step (the transposed flow gathers where the
    flow scatters): measured, relative residual 3e-2 after 6 restarts of 60 (121 x 241 nodes, alpha = 0.05,
    gamma = 0.03, r = 0.9, D = 0.05), which made reverse-mode derivatives 9 % wrong; BiCGStab reaches 4e-10.

    ``steps > 1``: ``matvec`` is ``B - I`` for a linearised step ``B`` (or its transpose), and the Krylov
    solver runs on ``(I - B^steps) x = -(I + B + ... + B^(steps - 1)) b`` instead, which has the same solution
    (polynomial preconditioning; see ``DERIVATIVE_STEPS``). Convergence is checked on ``matvec(x) = b``.
    """
    tol = 1e-9 if b.dtype == jnp.float64 else 1e-5
    norm_b = jnp.maximum(jnp.linalg.norm(b), jnp.finfo(b.dtype).tiny)

    def relres(x):
        return jnp.linalg.norm(matvec(x) - b) / norm_b

    operator, rhs = matvec, b
    if steps > 1:

        def powers(x):  # B^steps x, and (I + B + ... + B^(steps - 1)) x
            def body(_, c):
                y, total = c
                return matvec(y) + y, total + y

            return jax.lax.fori_loop(0, steps, body, (x, jnp.zeros_like(x)))

        def operator(x):
            return x - powers(x)[0]

        rhs = -powers(b)[1]

    def attempt(solver):
        def body(carry):
            k, x, err = carry
            y = solver(x)
            e = relres(y)
            better = e < err  # False for a breakdown's NaN
            return k + 1, jnp.where(better, y, x), jnp.where(better, e, err)

        return body

    def bicg(x):
        return bicgstab(operator, rhs, x0=x, tol=tol, maxiter=settings.max_iter)[0]

    def krylov(x):
        return gmres(operator, rhs, x0=x, tol=tol, restart=settings.restart, maxiter=1)[0]

    def unsolved(c):
        return (c[0] < settings.max_restarts) & (c[2] > tol)

    carry = (0, jnp.zeros_like(b), jnp.ones((), b.dtype))
    _, x, err = jax.lax.while_loop(unsolved, attempt(bicg), carry)
    # where BiCGStab stagnates or breaks down (rarely: measured once in 40 adjoint solves), GMRES polishes its
    # best iterate; under vmap this loop runs only while some solve in the batch is unsolved
    _, x, err = jax.lax.while_loop(unsolved, attempt(krylov), (0, x, err))
    solved = err <= 100 * tol
    jax.debug.callback(_warn_unsolved, err, solved)
    return jnp.where(solved, x, jnp.nan)


@functools.partial(jax.jit, static_argnames=("settings",))
def _stationary(scene: Scene, settings: PathIntegration, extents, law):
    grid, ops, weights, edge = setup(scene, settings, extents)
    X, V = jnp.meshgrid(grid.x, grid.v, indexing="ij")
    centre = grid.x[0] if scene.model.has_barrier else 0.0
    a_e, cubic, q, stiff = law
    H = 0.5 * (stiff * (X - centre) ** 2 + V**2)
    guess = jnp.exp(-(a_e * H + cubic * H * H) / q)  # the averaged stationary law: a close start
    guess = guess / jnp.sum(weights * guess)

    def normalised_step(ops: StepOperator, p):
        q = ops.step(p)
        return q / jnp.sum(weights * q)

    def residual(p):
        return normalised_step(ops, p) - p

    tol = 1e-8 if guess.dtype == jnp.float64 else 3e-6  # L1 residual of one step at which Newton stops

    def solve(f, p):
        p = jax.lax.fori_loop(0, settings.warmup, lambda _, p: normalised_step(ops, p), p)

        def newton(carry):
            k, p, _ = carry
            r, jvp = jax.linearize(f, p)
            p = p + _linear_solve(settings, jvp, -r)
            return k + 1, p, jnp.sum(weights * jnp.abs(f(p)))

        first = jnp.sum(weights * jnp.abs(f(p)))
        zero = jnp.zeros((), p.dtype)  # a float count: custom_root gives its aux a tangent
        k, p, _ = jax.lax.while_loop(lambda c: (c[0] < settings.newton) & (c[2] > tol), newton, (zero, p, first))
        return p, k

    def tangent_solve(g, y):
        return jax.lax.custom_linear_solve(
            g,
            y,
            solve=functools.partial(_linear_solve, settings, steps=DERIVATIVE_STEPS),
            transpose_solve=functools.partial(_linear_solve, settings, steps=DERIVATIVE_STEPS),
        )

    p, newton_steps = jax.lax.custom_root(residual, guess, solve, tangent_solve, has_aux=True)
    p_ = jax.lax.stop_gradient(p)
    q = ops.step(p_)
    gain = jnp.sum(weights * q)
    res = jnp.sum(weights * jnp.abs(q / gain - p_))
    dtype = grid.x.dtype
    a, _ = drift_and_diffusion(scene.model, jnp.asarray(scene.noise.D, dtype))
    drift = jax.vmap(a)(X.ravel(), V.ravel()).reshape(X.shape)
    kinetic = jnp.sum(weights * V**2 * p_)
    virial = (kinetic + jnp.sum(weights * (X - centre) * drift * p_)) / kinetic
    one = jnp.ones((1,), dtype)
    return _grid_result(
        scene.model.has_barrier,
        (math.inf,),
        p[None],
        grid,
        ops,
        mass_defect=one * jnp.abs(1 - gain),
        edge_mass=one * jnp.sum(edge * p_),
        residual=one * res,
        step_gain=one * gain,
        newton_steps=jnp.reshape(jax.lax.stop_gradient(newton_steps), (1,)),
        virial=one * virial,
        stationary=True,
    )


def path_integration(
    scene: Scene,
    settings: PathIntegration | None = None,
    stationary: bool | None = None,
    *,
    initial: Callable | None = None,
) -> GridResult:
    r"""``jdpim.solve(scene, settings)``, with ``stationary`` and ``initial`` set where given (see PathIntegration).

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(alpha=0.1, gamma=None, r=1.0),
        ...                     noise=jdpim.WhiteNoise(D=0.01), t_end=2.0, dt=0.1)
        >>> res = jdpim.path_integration(scene, jdpim.PathIntegration(n_x=61, n_v=121, tau=0.1), stationary=True)
        >>> res.times
        (inf,)
    """
    settings = PathIntegration() if settings is None else settings
    if not isinstance(settings, PathIntegration):
        raise TypeError(f"settings must be a jdpim.PathIntegration, got {settings!r}")
    changes = {"stationary": stationary} if stationary is not None else {}
    if initial is not None:
        changes["initial"] = initial
    return solve(scene, dataclasses.replace(settings, **changes))


def resolved(scene: Scene, settings: PathIntegration) -> tuple[PathIntegration, tuple[float, float]]:
    """``(settings, extents)``: the settings with ``order`` chosen where it is ``None``, and ``(x_max, v_max)``."""
    extents = default_extents(scene, settings)
    if settings.order is None:
        r = concrete(scene.model.r) if scene.model.has_barrier else np.ones(())
        if r is None:
            raise ValueError(
                f"PathIntegration(order=None) takes linear weights for r < {LINEAR_BELOW_R} and cubic ones above, "
                f"but r is traced (differentiated or vmapped): give order=2 (r < {LINEAR_BELOW_R}) or order=4"
            )
        settings = dataclasses.replace(settings, order=2 if float(np.max(r)) < LINEAR_BELOW_R else 4)
    return settings, extents


def _run(scene: Scene, settings: PathIntegration) -> GridResult:
    stationary, initial = settings.stationary, settings.initial
    validate(scene, settings, initial, stationary)
    settings, extents = resolved(scene, settings)
    check_resolution(scene, settings, extents, point_start=initial is None and not stationary)
    res = _solve(scene, settings, extents, stationary, initial)
    report(res, settings)
    if settings.estimate_error:
        coarse = _solve(scene, coarser(scene, settings, stationary, initial), extents, stationary, initial)
        res = dataclasses.replace(res, coarse=jax.lax.stop_gradient(coarse))
    return res


def _solve(scene: Scene, settings: PathIntegration, extents, stationary: bool, initial) -> GridResult:
    if not stationary:
        return _transient(typed_parameters(scene), program_settings(settings), extents, initial)
    try:
        law = averaged_energy_law(scene)
    except (ValueError, TypeError, jax.errors.ConcretizationTypeError):  # traced or not estimable: a Gaussian
        x_max, v_max = extents  # as wide as the grid allows
        law = (2 * ENERGY_SPAN / v_max**2, 0.0, 1.0, (v_max / x_max) ** 2)
    return _stationary(typed_parameters(scene), program_settings(settings), extents, law)


def coarser(scene: Scene, settings: PathIntegration, stationary: bool, initial) -> PathIntegration:
    """Every other node in ``x`` and ``v``, and twice the step where the start and the saved times allow it."""
    start = 0.0 if initial is not None else settings.t0
    times = [] if stationary else [start, *scene.save_at]
    doubled = all(abs(k - round(k)) < 1e-6 for k in (t / (2 * settings.tau) for t in times))
    return dataclasses.replace(
        settings,
        n_x=(settings.n_x - 1) // 2 + 1,
        n_v=(settings.n_v - 1) // 2 + 1,
        tau=2 * settings.tau if doubled else settings.tau,
        estimate_error=False,
    )


@on_host
def check_resolution(scene: Scene, settings: PathIntegration, extents, point_start: bool) -> None:
    """Warn when the grid cannot resolve the diffusion of one step or the Gaussian of a point start."""
    model, D = scene.model, concrete(scene.noise.D)
    b = concrete(model.barrier) if model.has_barrier else np.zeros(())
    if D is None or b is None:
        return  # traced: nothing to check here
    _, q_fn = drift_and_diffusion(model, D)
    q = concrete(q_fn(jnp.asarray(float(b)), jnp.asarray(0.0)))
    if q is None:
        return  # traced gains: nothing to check here
    q = float(q)
    peak = math.sqrt(q * peak_weight(scene, settings.tau) * settings.tau)  # at the noise's strongest
    span_x = extents[0] if model.has_barrier else 2 * extents[0]
    dx, dv = span_x / (settings.n_x - 1), 2 * extents[1] / (settings.n_v - 1)
    problems = []
    if peak < 0.6 * dv:  # below that the sampled kernel loses its variance
        problems.append(
            f"the half-step diffusion (sd sqrt(q tau) = {peak:.3g}) is below 0.6 times "
            f"the velocity spacing dv = {dv:.3g}: raise n_v or tau"
        )
    if point_start:
        # a free particle's spread: 2 q int_0^t0 (t0 - s)^k e(s)^2 ds, k = 2 (x) and 0 (v)
        sx, sv = math.sqrt(2 * q * settings.t0**3 / 3), math.sqrt(2 * q * settings.t0)
        if scene.noise.envelope is not None:  # by the midpoint rule
            s = (np.arange(200) + 0.5) * settings.t0 / 200
            e2 = np.asarray(jax.vmap(scene.noise.envelope)(jnp.asarray(s, scene.float_dtype)), float) ** 2
            sx = math.sqrt(2 * q * settings.t0 * np.mean((settings.t0 - s) ** 2 * e2))
            sv = math.sqrt(2 * q * settings.t0 * np.mean(e2))
        # measured (r = 1, alpha = 0.1, D = 0.05, t = 5, float64): L1 error 1e-5 for sx >= 0.9 dx, 6e-4 at 0.6 dx,
        # 5e-3 to 1e-2 below 0.45 dx
        if sx < dx or sv < 1.5 * dv:
            problems.append(
                f"the start density at t0 = {settings.t0:g} (sd {sx:.3g} in x, {sv:.3g} in v) is narrower than one "
                f"spacing dx = {dx:.3g} or 1.5 spacings dv = {dv:.3g}: raise n_x/n_v or t0"
            )
    if problems:
        warnings.warn("path integration: grid too coarse: " + "; ".join(problems), PathIntegrationWarning, stacklevel=3)


VIRIAL_TOL = 1e-2  # measured: velocity marginal within 1.5 % of 2e4-path MCS where the defect was 1.3 % (r = 0.3)


def report(res: GridResult, settings: PathIntegration) -> None:
    """Warn (``PathIntegrationWarning``) about what a solved ``res`` shows: leaks, defects, unsolved or unbalanced."""
    leak, defect = concrete(res.edge_mass), concrete(res.mass_defect)
    if leak is None or defect is None:
        return  # traced: nothing to inspect here
    bad = int(np.sum(concrete(res.n_nonfinite())))
    problems = []
    if bad:
        problems.append(f"{bad} non-finite nodal densities")
    if np.max(leak) > settings.leak_tol:
        problems.append(
            f"mass {np.max(leak):.2e} reached the grid's edges (> leak_tol={settings.leak_tol:g}): enlarge x_max/v_max"
        )
    if np.max(defect) > 1e-2:
        problems.append(f"renormalisation defect {np.max(defect):.2e} (> 1e-2): refine the grid or the step tau")
    residual = concrete(res.residual)
    if res.stationary and not np.all(residual <= 1e-3):
        problems.append(
            f"stationary solve residual {float(residual[0]):.2e} (> 1e-3): raise newton, max_iter or max_restarts"
        )
    virial = concrete(res.virial)
    if res.stationary and not np.all(np.abs(virial) <= VIRIAL_TOL):
        problems.append(
            f"the stationary balance E[v^2] + E[(x - b) a] = 0 is off by {float(virial[0]):+.1%} of E[v^2] "
            f"(> {VIRIAL_TOL:.0%}): the grid does not resolve the density (at small r with cubic weights, "
            "near the barrier): refine n_x/n_v, or take order=2 (linear weights: balanced, but more diffusive)"
        )
    if problems:
        warnings.warn("path integration: " + "; ".join(problems), PathIntegrationWarning, stacklevel=3)
