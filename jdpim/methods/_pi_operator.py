r"""The one-step operator of path integration on a phase-space grid (pure functions of the model).

One step of length ``tau`` is the Strang splitting of the Fokker-Planck operator

.. math::
    \partial_t p = -\partial_x(v p) - \partial_v(a(x, v) p) + \partial_v^2(q(x, v) p),
    \quad a = -g - f + \underbrace{h^T D \partial_v h}_{\text{Wong-Zakai}},\quad q = h^T D h,

into half a diffusion step in ``v``, the deterministic flow over ``tau``, and another half diffusion step:

* **Diffusion.** Column ``x_i`` of the density is multiplied by the kernel
  ``K_jk = N(v_j - v_k; 2 q(x_i, v_k) tau / 2)`` sampled on the grid and normalised by its sum over the
  infinite grid, so no mass is created, and what the kernel puts beyond the grid's velocity edges is lost
  (and reported).
* **Flow** (forward semi-Lagrangian, mass-conservative). The mass of every node (density times the
  node's area) is carried to the node's image under the flow over ``tau`` (RK4 in Zhuravlev's unfolded
  coordinates ``x - b = |s|``, ``v = sign(s) u``; a crossing of ``s = 0`` inside a substep is an impact,
  ``u -> r u`` and ``s -> r s`` for the rest of it) and deposited on the surrounding nodes with
  tensor-product weights (``stencil``: Catmull-Rom, or linear in x and a quadratic B-spline in v, both
  continuously differentiable in the image, or quintic Lagrange; the transpose of interpolation). The
  weights sum to one, so mass is conserved exactly; no Jacobian or ``1/r^2`` factor is needed, because
  mass, not density, is moved. Stencils are centred and shifted inwards at the grid's edges, except at
  the barrier: images never lie beyond it, so linear stencils stay on the grid there, and higher-order
  ones reach ghost columns whose mass is folded back through the impact law (``_fold``).

The images and weights do not depend on time: they are computed once per solve (traced, hence
differentiable in the model's parameters), and a step is a scatter-add plus two small matrix products.

**Modulated noise** ``e(t) xi(t)`` (state-independent gains): the half-step kernels take the intensity
``D e^2`` averaged over their half step, as exponents computed for all steps at once (``exponents``) and fed
to the steps (``step(p, exponents)``), which rebuild their kernels from one sampled row (``kernel_of``: the
kernel is a Toeplitz matrix, so ``2 n_v - 1`` exponentials per half step, against the ``n_x n_v^2``
multiply-adds of applying it); the flow does not involve the noise and stays as built.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._models import AbstractOscillator, Oscillator
from .._stencils import BSPLINE_VARIANCE, catmull_rom, catmull_rom_mirrored, stencil


@dataclasses.dataclass(frozen=True)
class Grid:
    """Nodes ``x_i = b + i dx`` (barrier ``b``) or ``(i - (n_x - 1) / 2) dx``, ``v_j = (j - (n_v - 1) / 2) dv``."""

    x: Any  # (n_x,)
    v: Any  # (n_v,)
    dx: Any
    dv: Any

    def axis_weights(self, order: int, folded: bool):
        """Quadrature weights ``(n_x,)`` and ``(n_v,)`` of the nodes: integrals of the cardinal functions
        (see ``cardinal_areas``) times the spacing.

        ``folded``: the lower ``x`` edge is a barrier whose ghost nodes are folded back onto the grid
        (then the barrier node has half an area, as the fold line of the unfolded grid).
        """
        wx = cardinal_areas(self.x.shape[0], order, "x")
        if folded:
            wx = np.concatenate([[0.5], np.ones(order), wx[order + 1 :]])
        wx = jnp.asarray(wx, self.x.dtype) * self.dx
        wv = jnp.asarray(cardinal_areas(self.v.shape[0], order, "v"), self.v.dtype) * self.dv
        return wx, wv

    def mass_weights(self, order: int, folded: bool):
        """Node areas ``(n_x, n_v)``: the outer product of ``axis_weights``."""
        wx, wv = self.axis_weights(order, folded)
        return wx[:, None] * wv[None, :]


jax.tree_util.register_dataclass(Grid, data_fields=["x", "v", "dx", "dv"], meta_fields=[])


@functools.lru_cache(maxsize=32)
def cardinal_areas(n: int, order: int, axis: str) -> np.ndarray:
    """``int L_k(t) dt`` over ``[0, n - 1]`` for the cardinal functions of the ``order``-point ``stencil`` on ``axis``.

    These are the quadrature weights (in units of the spacing) that make depositing mass with the
    interpolation weights consistent with the density: 1 in the interior, different near the edges.
    Gauss-Legendre on half spacings is exact for these piecewise polynomials (breaks at nodes and midpoints).
    """
    nodes, gw = np.polynomial.legendre.leggauss(4)
    t = (0.5 * np.arange(2 * (n - 1))[:, None] + 0.25 * (nodes[None, :] + 1)).ravel()
    start, w = stencil(t, n, order, axis, xp=np)
    out = np.zeros(n)
    for m in range(w.shape[-1]):
        np.add.at(out, start + m, w[:, m] * np.tile(0.25 * gw, 2 * (n - 1)))
    return out


def make_grid(model: AbstractOscillator, n_x: int, n_v: int, x_max, v_max, dtype) -> Grid:
    """Nodes: ``x`` in ``[b, b + x_max]`` (barrier ``b``) or ``[-x_max, x_max]``; ``v`` in ``[-v_max, v_max]``.

    The extents are values (traced inside a solve's program, so that one program serves every extent); the
    sizes ``n_x``, ``n_v`` set the shapes. Symmetric ranges are counted from their middle, ``v_j = (j - (n_v - 1)
    / 2) dv``: exactly symmetric, with an exact 0 for an odd size, however the program rounds (the impact's fold
    treats ``v < 0`` and ``v >= 0`` differently).
    """
    x_max, v_max = jnp.asarray(x_max, dtype), jnp.asarray(v_max, dtype)

    def centred(n, dz):
        return dz * (jnp.arange(n, dtype=dtype) - (n - 1) / 2)

    dv = 2 * v_max / (n_v - 1)
    if model.has_barrier:
        dx = x_max / (n_x - 1)
        x = jnp.asarray(model.barrier, dtype) + dx * jnp.arange(n_x, dtype=dtype)
    else:
        dx = 2 * x_max / (n_x - 1)
        x = centred(n_x, dx)
    return Grid(x, centred(n_v, dv), dx, dv)


def state_dependent(model: AbstractOscillator) -> bool:
    """Whether the noise gains depend on the state (then the diffusion kernel differs per node)."""
    return isinstance(model, Oscillator) and model.h is not None


def drift_and_diffusion(model: AbstractOscillator, D):
    """``(a(x, v), q(x, v))``: Fokker-Planck drift of ``v`` (with the Wong-Zakai term) and diffusion coefficient."""
    D = jnp.atleast_2d(jnp.asarray(D))
    dependent = state_dependent(model)

    def q(x, v):
        h = model.gains(x, v)
        return h @ D.astype(h.dtype) @ h

    def a(x, v):
        out = -model.restoring(x) - model.damping(x, v)
        if dependent:
            h = model.gains(x, v)
            out = out + h @ D.astype(h.dtype) @ jax.jacfwd(model.gains, argnums=1)(x, v)
        return out

    return a, q


def trace(model: AbstractOscillator, a, grid: Grid, tau: float, substeps: int):
    """Images ``(x, v)`` of every node under the deterministic flow over ``tau`` (impacts included), ``(n_x, n_v)``."""
    X, V = jnp.meshgrid(grid.x, grid.v, indexing="ij")
    dtype = X.dtype
    h = jnp.asarray(tau / substeps, dtype)
    if model.has_barrier:
        b = jnp.asarray(model.barrier, dtype)
        r = jnp.asarray(model.r, dtype)

        def field(s, u):
            sg = jnp.where(s >= 0, 1.0, -1.0).astype(dtype)
            x, v = b + jnp.abs(s), sg * u
            return u, sg * a(x, v)

        s, u = X - b, V
    else:

        def field(s, u):
            return u, a(s, u)

        s, u = X, V
    field = jax.vmap(jax.vmap(field))

    def rk4(s, u):
        k1 = field(s, u)
        k2 = field(s + 0.5 * h * k1[0], u + 0.5 * h * k1[1])
        k3 = field(s + 0.5 * h * k2[0], u + 0.5 * h * k2[1])
        k4 = field(s + h * k3[0], u + h * k3[1])
        return [h / 6 * (p + 2 * q + 2 * w + z) for p, q, w, z in zip(k1, k2, k3, k4, strict=True)]

    for _ in range(substeps):
        ds, du = rk4(s, u)
        s_new, u_new = s + ds, u + du
        if model.has_barrier:
            # an impact inside the substep: the rest of it is flown at r times the speed (force-free)
            crossed = (s_new < 0) != (s < 0)
            s_new = jnp.where(crossed, r * s_new, s_new)
            u_new = jnp.where(crossed, r * u_new, u_new)
        s, u = s_new, u_new
    if model.has_barrier:
        return b + jnp.abs(s), jnp.where(s >= 0, u, -u)
    return s, u


@dataclasses.dataclass(frozen=True)
class StepOperator:
    """Precomputed pieces of one path-integration step (see the module docstring)."""

    ix: Any  # (n_x, n_v) stencil start in x (from -ghost)
    iv: Any  # (n_x, n_v) stencil start in v
    wx: Any  # (n_x, n_v, points of the x stencil)
    wv: Any  # (n_x, n_v, points of the v stencil)
    area: Any  # (n_x, n_v) quadrature weight of each node (mass = density * area)
    kernel: Any  # (n_v, n_v) or (n_x, n_v, n_v) half-step diffusion kernel [target, source]
    fold: Any  # (2 targets, ghost column -k, node v_j) -> start x, start v, weights x (4,), weights v (4,); or None
    order: int
    variance: Any = None  # () half-step variance q tau of state-independent gains (for exponents); else None
    smoothing: Any = 0.0  # () the variance that deposition adds per half step (subtracted from the kernel's)
    dv: Any = None  # () the velocity spacing

    def flow(self, p):
        """Deposit every node's mass at its image with the interpolation weights (mass-conservative)."""
        ghost = 0 if self.fold is None else self.order // 2
        kx, kv = jnp.arange(self.wx.shape[-1])[None, None, :], jnp.arange(self.wv.shape[-1])[None, None, :]
        rows = (self.ix[..., None] + kx + ghost)[..., :, None]
        cols = (self.iv[..., None] + kv)[..., None, :]
        mass = (p * self.area)[..., None, None] * self.wx[..., :, None] * self.wv[..., None, :]
        out = jnp.zeros((p.shape[0] + ghost, p.shape[1]), p.dtype).at[rows, cols].add(mass)
        if ghost:
            fi, fj, fwx, fwv = self.fold
            jx, jv = jnp.arange(fwx.shape[-1])[None, None, None, :], jnp.arange(fwv.shape[-1])[None, None, None, :]
            # ghost columns fold back through the impact map; the barrier column is the fold line itself:
            # half of its mass stays, half is mirrored (as the unfolded grid's two nodes at s = 0 would be)
            edge = out[: ghost + 1].at[ghost].multiply(0.5)
            out = out.at[ghost].multiply(0.5)
            spill = edge[None, ..., None, None] * fwx[..., :, None] * fwv[..., None, :]
            out = out[ghost:].at[(fi[..., None] + jx)[..., :, None], (fj[..., None] + jv)[..., None, :]].add(spill)
        return out / self.area

    def diffuse(self, p, kernel=None):
        kernel = self.kernel if kernel is None else kernel
        if kernel.ndim == 2:
            return p @ kernel.T
        return jnp.einsum("ijk,ik->ij", kernel, p)

    def exponents(self, weights):
        """``z`` (shaped like ``weights``) of the half-step kernels at the intensities ``D * weights``
        (state-independent gains; see ``node_exponent`` and ``kernel_of``)."""
        return node_exponent((weights * self.variance - self.smoothing) / self.dv**2)

    def kernel_of(self, z):
        """The half-step kernel ``(n_v, n_v)`` of exponent ``z``: the kernel of a constant variance is Toeplitz,
        ``K_jk = row[j - k]``, so one row ``exp(-z k^2)`` over every node-to-node distance is normalised (as
        ``step_operator`` normalises) and gathered."""
        n_v = self.kernel.shape[-1]
        row = jnp.exp(-z * jnp.arange(-(n_v - 1), n_v, dtype=self.kernel.dtype) ** 2)
        return (row / jnp.sum(row))[_toeplitz(n_v)]

    def step(self, p, exponents=None):
        """One step of ``p`` ``(n_x, n_v)``; ``exponents`` ``(2,)``: the ``z`` of the two half-step kernels for a
        modulated noise (``exponents`` of the mean ``e(t)^2`` over each half; ``None``: the operator's kernel)."""
        if exponents is None:
            return self.diffuse(self.flow(self.diffuse(p)))
        first, second = self.kernel_of(exponents[0]), self.kernel_of(exponents[1])
        return self.diffuse(self.flow(self.diffuse(p, first)), second)


GAUSSIAN_ABOVE = 4.0  # node variances (in dv^2) from which exp(-k^2 / (2 var)) has the variance var (to e^-79)
ASYMPTOTE_BELOW = 1e-6  # node variances below which z = ln(2 / var) (the nearest neighbours alone; relative error var)


def node_exponent(var):
    r"""``z`` with which ``g_k = exp(-z k^2)``, normalised over the integers ``k``, has the variance ``var`` (in squared
    spacings, any shape; ``var <= 0`` gives the identity's ``z``, a very large number).

    From ``GAUSSIAN_ABOVE`` up, the sampled Gaussian ``z = 1 / (2 var)``. Below about one spacing a sampled
    Gaussian's variance on the nodes falls short of its parameter (``2 exp(-1 / (2 var))`` as ``var -> 0``), so a
    half step at a low intensity (a modulated noise's rise and decay) would inject too little: there ``z`` solves
    ``sum k^2 g_k / sum g_k = var`` by Newton on the logarithm (5 iterations, converged to rounding from
    ``ASYMPTOTE_BELOW`` to ``GAUSSIAN_ABOVE``), and ``z = ln(2 / var)`` below.
    """
    dtype = jnp.result_type(var)
    v = jnp.clip(var, jnp.finfo(dtype).tiny, GAUSSIAN_ABOVE)
    mid = jnp.clip(v, ASYMPTOTE_BELOW, GAUSSIAN_ABOVE)  # Newton's range (clipped: no NaN in the unused branch)
    k2 = jnp.reshape(jnp.arange(-24, 25, dtype=dtype) ** 2, (1,) * jnp.ndim(var) + (-1,))

    def moment(g, k):  # sum over the last axis of k2^k g
        return jnp.sum(k2**k * g, axis=-1)

    z = jnp.where(mid < 0.5, jnp.log(2 / mid), 1 / (2 * mid))
    for _ in range(5):  # a fixed, small count: unrolled
        g = jnp.exp(-k2 * z[..., None])
        m0, m2, m4 = moment(g, 0), moment(g, 1), moment(g, 2)
        z = z + (jnp.log(m2 / m0) - jnp.log(mid)) / (m4 / m2 - m2 / m0)
    z = jnp.where(v < ASYMPTOTE_BELOW, jnp.log(2.0) - jnp.log(v), z)
    return jnp.where(var >= GAUSSIAN_ABOVE, 1 / (2 * jnp.maximum(var, GAUSSIAN_ABOVE)), z)


@functools.lru_cache(maxsize=32)
def _toeplitz(n: int) -> np.ndarray:
    """``(n, n)`` indices ``j - k + n - 1`` of a row over the distances ``-(n - 1) .. n - 1``."""
    return np.subtract.outer(np.arange(n), np.arange(n)) + n - 1


def step_operator(
    model: AbstractOscillator, D, grid: Grid, tau: float, substeps: int, order: int, n_x: int, n_v: int
) -> StepOperator:
    """Build the step operator of ``model`` with noise intensity ``D`` on ``grid``."""
    a, q = drift_and_diffusion(model, D)
    xe, ve = trace(model, a, grid, tau, substeps)
    # linear stencils of images (all at x >= b) stay on the grid: no fold, so the barrier column keeps its
    # incoming and outgoing states as they are (measured: the fold line's half-mirror to the 1/r faster
    # pre-image put 38 % too much kinetic energy into the stationary density at r = 0.05)
    ghost = order // 2 if model.has_barrier and order > 2 else 0
    ix, wx = stencil((xe - grid.x[0]) / grid.dx, n_x, order, "x", ghost)
    iv, wv = stencil((ve - grid.v[0]) / grid.dv, n_v, order, "v")
    dtype = grid.x.dtype
    offsets = grid.dv * jnp.arange(-(n_v - 1), n_v, dtype=dtype)  # every node-to-node distance, both signs
    diff = grid.v[:, None] - grid.v[None, :]

    def kernel(var):  # var: variance of the half step, shape broadcastable to the source axis
        var = jnp.maximum(var, jnp.finfo(dtype).tiny)
        total = jnp.sum(jnp.exp(-0.5 * offsets[:, None] ** 2 / jnp.reshape(var, (1, -1))), axis=0)
        return jnp.exp(-0.5 * diff**2 / var) / jnp.reshape(total, var.shape)

    # each half step diffuses with variance q tau, less half the variance that B-spline deposition adds
    smoothing = BSPLINE_VARIANCE * grid.dv**2 / 2 if order == 2 else 0.0
    variance = None
    if state_dependent(model):
        qs = jax.vmap(jax.vmap(q))(*jnp.meshgrid(grid.x, grid.v, indexing="ij"))  # (n_x, n_v) at the source
        K = jax.vmap(lambda qi: kernel(qi[None, :] * tau - smoothing))(qs)
    else:
        variance = q(grid.x[0], jnp.zeros((), dtype)) * tau
        K = kernel((variance - smoothing) * jnp.ones((1, n_v), dtype))
    fold = _fold(model, grid, ghost, n_v) if ghost else None
    area = grid.mass_weights(order, bool(ghost))
    return StepOperator(ix, iv, wx, wv, area, K, fold, order, variance, smoothing, grid.dv)


def _fold(model, grid: Grid, ghost: int, n_v: int):
    """Where the mass deposited on ghost node ``(b - k dx, v_j)``, k = g .. 0, goes.

    The weights are Catmull-Rom's (mirrored at the barrier in x), continuously differentiable in the
    target, hence in r.

    Ghost nodes carry the part of a deposit that the interpolation stencil spreads beyond the barrier,
    i.e. the smooth continuation of the density there. Moving with ``v_j < 0`` it continues the incoming
    density, which the impact maps to ``(b + r k dx, -r v_j)``; with ``v_j > 0`` it continues the outgoing
    density, which came from ``(b + k dx / r, -v_j / r)`` (mirrored instead where ``v_j / r`` lies beyond
    the grid, blended with that over the last tenth of the grid's speeds). For ``r = 1`` both are the
    mirror image. Mass is conserved whatever r. Returns arrays with a leading axis of the two targets.
    """
    r = jnp.asarray(model.r, grid.x.dtype)
    k = jnp.arange(ghost, -1, -1, dtype=grid.x.dtype)[:, None]  # rows: -g .. 0
    v = grid.v[None, :]
    # outgoing ghosts whose source -v / r lies near or beyond the grid's speeds are mirrored instead (nothing is
    # lost), blended over the last tenth of the source's range with a smoothstep, so the map is C^1 in r
    u = jnp.clip((v / (r * grid.v[-1]) - 0.9) / 0.1, 0.0, 1.0)
    sourced = jnp.where(v < 0, 1.0, 1.0 - u * u * (3 - 2 * u))
    ones = jnp.ones_like(k * v)
    scale = jnp.stack([jnp.where(v < 0, r, 1.0 / r) * ones, ones])  # (2, rows, n_v): sourced, mirrored
    fi, fwx = catmull_rom_mirrored(scale * k[None], grid.x.shape[0])
    fj, fwv = catmull_rom((-scale * v[None] - grid.v[0]) / grid.dv, n_v)
    share = jnp.stack([sourced * ones, (1.0 - sourced) * ones])
    return fi, fj, fwx * share[..., None], fwv
