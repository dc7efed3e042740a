r"""Excitations: how the white noise reaches the integrator's nodes.

:class:`AbstractExcitation` is what every method asks of an excitation (its elementary random inputs, the forcing
of a batch of paths), :class:`AbstractNodes` what the integrator reads (the forcing of every step at its start,
middle and end). Two excitations implement them: :class:`GaussianNodes` (independent normals at the nodes, drawn
inside the steps) and :class:`SpectralRepresentation`, below.

Spectral representation of white noise, generated for all paths at once with FFTs.

.. math::
    \xi(t) = \sqrt{S_0 \Delta\omega}\,X_0
           + \sum_{k=1}^{K} \sqrt{2 S_0 \Delta\omega}\,(X_k \cos \omega_k t + Y_k \sin \omega_k t),
    \qquad \omega_k = k \Delta\omega,\ S_0 = D / \pi,

so ``E[xi^2] = 2 S0 (w_u + dw / 2)`` for the cutoff ``w_u = K dw``. The constant term ``X_0`` (half
weight: the trapezoidal rule at ``w = 0``) matters: without it the autocorrelation carries a negative
offset ``-D dw / pi`` at every lag, and displacement variances at early times come out several per cent
low (measured: -8 % at t = 2 with dw = 0.25). Monte Carlo uses independent
standard normal ``X_k, Y_k``. DPIM uses the random functions of Liu, Liu & Peng (2016),
``X_k = sqrt2 cos(m_k Theta1 + pi/4)``, ``Y_k = sqrt2 cos(m_k Theta2 + pi/4)`` with
``Theta ~ U[-pi, pi)`` and ``m_k`` a fixed permutation of ``1..K``: orthonormal, so second-order
exact with two elementary variables per source.

The FFT form (Shinozuka & Deodatis 1991) evaluates the sum on a grid of spacing ``dt / 2`` (the RK4
stage times) with ``dw * dt / 2 = 2 pi / M``; the period ``2 pi / dw`` covers the simulated span plus
an offset on each side, because the representation is spiky near multiples of its period.

An evolutionary spectrum (``WhiteNoise(envelope=spectrum)``, :mod:`jdpim._evolutionary`) scales every term by
``A(w_k, t) = sqrt(|A(w_k, t)|^2)``, which no single FFT can do: the sum is then evaluated directly, as a product
of the coefficients with the basis ``A(w_k, t_j) exp(i w_k t_j)`` built block of times by block of times
(:func:`synthesize_evolutionary`), with the same coefficients and phases as the FFT.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._cpu import on_cpu
from ._distributions import ANGLE
from ._evolutionary import AbstractEvolutionarySpectrum
from ._normals import normal_pair
from ._pytree import check_int, check_real, pytree_dataclass, static_field
from ._turns import cos_sin_turns, fractional_multiples

RANDOM_FUNCTIONS = ("cosine", "rayleigh")
CUTOFF_STEP = 2.0  # default cutoff times dt


class AbstractNodes(abc.ABC):
    """The forcing of a batch of ``n`` paths at the integrator's nodes, step by step.

    Every RK4 step ``k`` (from ``t = k dt`` to ``(k + 1) dt``) reads the forcing at its start, middle and end
    (the quadratic through them is the forcing inside the step); ``carry`` is whatever one step hands the next
    (drawn values, or nothing). Subclasses are pytrees of arrays (they enter jitted code).
    """

    @property
    @abc.abstractmethod
    def shape(self) -> tuple[int, int]:
        """``(n, m)``: paths and noise sources."""

    @abc.abstractmethod
    def start(self):
        """The carry before step 0."""

    @abc.abstractmethod
    def step(self, k, carry):
        """``(e, carry)``: the forcing of step ``k`` (traced int) at its start, middle and end, a tuple of three
        ``(n, m)`` arrays, and the carry to step ``k + 1``."""


class AbstractExcitation(abc.ABC):
    r"""How the white noise of a scene is generated at the integrator's nodes (static settings, hashable).

    The scene's :class:`jdpim.WhiteNoise` is the physics (intensity ``D``, an optional envelope); an excitation
    is the numerical representation of its unit-envelope part. A method reads one through these calls:

    - ``check(scene)``: raise ``ValueError`` where the scene's time grid does not suit it (at scene construction);
    - ``input_distributions(n_sources)``: the elementary random variables of one path (DPIM's input space),
      or a ``ValueError`` saying why it has none;
    - ``from_inputs(scene, theta)``: the forcing (:class:`AbstractNodes`) of paths given their elementary
      variables ``theta`` ``(n, k)`` (DPIM);
    - ``from_keys(scene, keys)``: the forcing of paths given their noise keys ``(n, 2)`` (Monte Carlo);
    - ``values_per_path(scene)``: forcing values one path holds in memory (0 where drawn inside the steps:
      chunk sizes follow from it);
    - ``from_normals(scene, z)`` (optional): the forcing of standard normals at the nodes (subset simulation).

    The envelope of a modulated noise (``WhiteNoise(envelope=...)``) multiplies whatever forcing an excitation
    gives (:func:`modulate`), so an excitation knows nothing of it. An evolutionary spectrum, which depends on the
    frequency too, can only shape the harmonics of :class:`SpectralRepresentation`, which applies it itself.
    """

    @abc.abstractmethod
    def check(self, scene) -> None: ...

    @abc.abstractmethod
    def input_distributions(self, n_sources: int) -> tuple: ...

    @abc.abstractmethod
    def from_inputs(self, scene, theta) -> AbstractNodes: ...

    @abc.abstractmethod
    def from_keys(self, scene, keys) -> AbstractNodes: ...

    @abc.abstractmethod
    def values_per_path(self, scene) -> int: ...

    def from_normals(self, scene, z) -> AbstractNodes:
        """The forcing of independent standard normals ``z`` ``(n, 2 T + 1, m)``, one per node and source (subset
        simulation's input space), where the excitation has such a form."""
        raise ValueError(
            f"{type(self).__name__} has no input space of normals at the nodes (subset simulation samples them): "
            "use Scene(..., excitation=jdpim.GaussianNodes()) or the default, excitation=None"
        )


@dataclasses.dataclass(frozen=True)
class SpectralRepresentation(AbstractExcitation):
    r"""Settings of the band-limited spectral representation (static: they fix array shapes).

    Args:
        cutoff: upper cutoff frequency ``w_u`` in rad/s (> 0), or ``None`` for ``CUTOFF_STEP / dt``
            (``w_u dt = 2``; 64 pi at dt = 0.01). Impacts turn a cutoff into a bias of order ``1 / w_u``,
            largest at early times (README); raising the cutoff at fixed ``dt`` costs almost nothing
            (same steps, same FFT length) and RK4's Simpson-weighted forcing stays within 1 % of the
            exact step integral of a harmonic up to ``w dt = 2``. Measured on the r = 1 exact case
            (2e4 MC samples, dt = 0.01): L1 error 0.036, 0.021, 0.016, 0.012 for 8, 16, 32, 64 pi.
        dw: frequency step in rad/s, or ``None`` for the largest step whose period ``2 pi / dw``
            covers ``t_end + 2 offset``. The number of terms is ``K = round(cutoff / dw)``.
        offset: time shift in s of the simulated window inside the period, or ``None`` for
            ``10 * 2 pi / cutoff`` (ten cutoff periods away from the spiky origin).
        permute: map harmonic ``k`` to a fixed random index ``m_k`` (DPIM random functions). With
            ``m_k = k`` the DPIM excitation paths are travelling spikes (docs/accuracy.md).
        seed: seed of that permutation.
        random_functions: DPIM coefficients. ``"rayleigh"`` (default): Box-Muller pairs
            ``X_k + i Y_k = sqrt(-2 ln u_k) exp(i m_k Theta2)``, ``u_k = frac(m_k (Theta1 + pi) / 2 pi)``:
            orthonormal like the cosine form, and every pair is exactly Gaussian, so a response dominated
            by a few spectral lines (a lightly damped oscillator near stationarity) stays Gaussian.
            ``"cosine"``: ``sqrt2 cos(m_k Theta_j + pi/4)`` (Liu, Liu & Peng 2016): arcsine-distributed
            coefficients; measured kurtosis 2.3-2.5 and an L1 error that does not decrease with N
            (0.11-0.15) for the free oscillator at t = 100-200 s (docs/accuracy.md).

    Examples:
        >>> import jdpim
        >>> spec = jdpim.SpectralRepresentation(cutoff=4 * 3.14159)
        >>> spec.grid(t_end=100.0, dt=0.01).n_terms
        225
    """

    cutoff: float | None = None
    dw: float | None = None
    offset: float | None = None
    permute: bool = True
    seed: int = 0
    random_functions: str = "rayleigh"

    def __post_init__(self):
        if self.random_functions not in RANDOM_FUNCTIONS:
            raise ValueError(f"random_functions must be one of {RANDOM_FUNCTIONS}, got {self.random_functions!r}")
        if self.cutoff is not None:
            check_real("cutoff", self.cutoff, low=0.0, low_open=True)
        if self.dw is not None:
            check_real("dw", self.dw, low=0.0, low_open=True)
        if self.offset is not None:
            check_real("offset", self.offset, low=0.0)
        check_int("seed", self.seed, low=0)

    def grid(self, t_end: float, dt: float) -> SpectralGrid:
        """The FFT grid for a simulation over ``[0, t_end]`` with RK4 step ``dt``."""
        half = dt / 2.0
        cutoff = CUTOFF_STEP / dt if self.cutoff is None else self.cutoff
        offset = 10 * 2 * math.pi / cutoff if self.offset is None else self.offset
        start = int(math.ceil(offset / half - 1e-9))
        n_half = 2 * int(round(t_end / dt)) + 1
        span = (start * 2 + n_half) * half  # the window [offset, offset + t_end] with an offset on both sides
        period = span if self.dw is None else max(2 * math.pi / self.dw, span)
        n_fft = _next_fast_len(int(math.ceil(period / half - 1e-9)))
        dw = 2 * math.pi / (n_fft * half)
        n_terms = max(1, int(round(cutoff / dw)))
        if n_terms >= n_fft // 2:
            raise ValueError(
                f"cutoff={cutoff:g} rad/s is at or above the Nyquist frequency {math.pi / half:g} "
                f"of the RK4 stage grid (dt={dt:g}); lower the cutoff or dt"
            )
        return SpectralGrid(
            n_terms=n_terms,
            dw=dw,
            n_fft=n_fft,
            start=start,
            n_half=n_half,
            permute=self.permute,
            seed=self.seed,
            random_functions=self.random_functions,
        )

    def check(self, scene) -> None:
        """The cutoff must lie below the Nyquist frequency of the stage grid; an evolutionary spectrum must be finite
        and non-negative on the grid."""
        checked_grid(self, scene)

    def input_distributions(self, n_sources: int) -> tuple:
        """``(Theta1, Theta2)`` per source, each uniform on ``[-pi, pi)``."""
        return (ANGLE,) * (2 * n_sources)

    def from_inputs(self, scene, theta) -> ArrayNodes:
        """The forcing of the random functions of ``theta`` ``(n, 2 m)``, by one FFT (:func:`spectral_nodes`)."""
        grid = checked_grid(self, scene)
        mixing = scene.noise.mixing().astype(scene.float_dtype)
        return spectral_nodes(scene, theta, grid, jax.vmap(lambda t: random_function_coefficients(t, grid, mixing)))

    def from_keys(self, scene, keys) -> ArrayNodes:
        """The forcing of Gaussian coefficients drawn from each path's key ``(n, 2)``, by one FFT
        (:func:`spectral_nodes`)."""
        grid = checked_grid(self, scene)
        dtype = scene.float_dtype
        mixing = scene.noise.mixing().astype(dtype)

        def coefficients(key):
            return gaussian_coefficients(jax.random.wrap_key_data(key), scene.n_sources, grid, mixing, dtype)

        return spectral_nodes(scene, keys, grid, jax.vmap(coefficients))

    def values_per_path(self, scene) -> int:
        """The excitation over the FFT grid, for every source."""
        return scene.n_sources * self.grid(scene.t_end, scene.dt).n_fft


@dataclasses.dataclass(frozen=True)
class GaussianNodes(AbstractExcitation):
    r"""White noise as independent Gaussian values at the RK4 nodes, drawn inside the integration (Monte Carlo).

    The forcing holds values on the half-step grid (the start, middle and end of every step; the end of one
    step is the start of the next): independent standard normals ``z_j`` times ``sqrt(18 / (5 dt)) L``
    (``L L^T = D``), so that RK4's Simpson-weighted increment ``dt/6 (f_0 + 4 f_1/2 + f_1)`` carries the white
    noise's variance, ``2 D dt`` per step over many steps (end points weigh ``dt/3`` and midpoints ``2 dt/3``:
    ``(1/9 + 4/9) dt^2 Var f = 2 D dt``). The normals of a path come from a counter-based generator keyed by
    the path's key, the step and the source (:class:`NodeSource`): memory of order the number of paths (no
    array over the time grid), no FFT, and the same values whatever the chunks, devices and processes. Not
    band-limited: the forcing is white up to the step's resolution. DPIM needs the spectral representation
    (its two elementary variables per source).

    Examples:
        >>> import jdpim
        >>> scene = jdpim.Scene(jdpim.VibroImpactOscillator(), t_end=2.0, dt=0.02, excitation=jdpim.GaussianNodes())
        >>> jdpim.solve(scene, jdpim.MonteCarlo(n_samples=64, seed=0)).states.shape
        (64, 1, 2)
    """

    def check(self, scene) -> None:
        """Any time grid suits it; an evolutionary spectrum does not (:func:`modulate`)."""
        if scene.noise.spectrum is not None:
            raise ValueError(_NEEDS_SPECTRAL)

    def input_distributions(self, n_sources: int) -> tuple:
        raise ValueError(
            "DPIM needs the spectral representation (Scene(excitation=None), the default, or "
            "jdpim.SpectralRepresentation(...)): its random functions of two variables per source; GaussianNodes "
            "is for Monte Carlo"
        )

    def from_inputs(self, scene, theta) -> AbstractNodes:
        self.input_distributions(scene.n_sources)  # raises: no elementary variables of a few dimensions

    def from_keys(self, scene, keys) -> NodeSource:
        """The forcing of the ``n`` paths with noise key data ``keys`` ``(n, 2)``, drawn inside the steps."""
        dtype = scene.float_dtype
        return NodeSource(keys, node_scale(scene.noise.mixing().astype(dtype), scene.dt, dtype), dtype)

    def values_per_path(self, scene) -> int:
        """None: the nodes are drawn inside the steps."""
        return 0

    def from_normals(self, scene, z) -> ArrayNodes:
        """The forcing of standard normals ``z`` ``(n, 2 T + 1, m)`` at the half-step nodes (subset simulation's
        input space): ``sqrt(18 / (5 dt)) L z``."""
        dtype = scene.float_dtype
        scale = node_scale(scene.noise.mixing(), scene.dt, dtype)
        return ArrayNodes(jnp.einsum("ij,ntj->tni", scale, z.astype(dtype)))


def node_scale(mixing, dt: float, dtype):
    """``sqrt(18 / (5 dt)) L``, ``(m, m)``: the scale of unit normals at the half-step nodes that gives RK4's
    Simpson-weighted increment the white noise's variance ``2 D dt`` per step (:class:`GaussianNodes`)."""
    return (math.sqrt(18.0 / (5.0 * dt)) * mixing).astype(dtype)


@pytree_dataclass
class ArrayNodes(AbstractNodes):
    """The forcing held as one array over the half-step grid, time-major ``(2 T + 1, n, m)``."""

    values: jax.Array

    @property
    def shape(self) -> tuple[int, int]:
        return self.values.shape[1:]

    def start(self):
        return ()

    def step(self, k, carry):
        return tuple(jax.lax.dynamic_index_in_dim(self.values, 2 * k + i, keepdims=False) for i in range(3)), ()


@pytree_dataclass
class Modulated(AbstractNodes):
    """``nodes`` multiplied by ``envelope(t)`` at the node times ``t = k dt + i dt / 2`` (``i = 0, 1, 2``)."""

    nodes: AbstractNodes
    envelope: Callable = static_field()
    dt: float = static_field()

    @property
    def shape(self) -> tuple[int, int]:
        return self.nodes.shape

    def start(self):
        return self.nodes.start()

    def step(self, k, carry):
        e, carry = self.nodes.step(k, carry)
        t0 = k * self.dt
        return tuple(x * jnp.asarray(self.envelope(t0 + i * (0.5 * self.dt)), x.dtype) for i, x in enumerate(e)), carry


@pytree_dataclass
class Clock(AbstractNodes):
    """``nodes`` with the time appended as a last column, ``(n, m + 1)`` per node: the time channel of models whose
    acceleration depends on ``t`` (:class:`Clocked`). The quadratic through the three node times of a step is the
    time itself inside the step (to rounding), so impacts and sub-steps read their own time."""

    nodes: AbstractNodes
    dt: float = static_field()

    @property
    def shape(self) -> tuple[int, int]:
        n, m = self.nodes.shape
        return n, m + 1

    def start(self):
        return self.nodes.start()

    def step(self, k, carry):
        e, carry = self.nodes.step(k, carry)
        t0 = k * self.dt
        return tuple(
            jnp.concatenate([x, jnp.full((x.shape[0], 1), t0 + i * (0.5 * self.dt), x.dtype)], axis=1)
            for i, x in enumerate(e)
        ), carry


@dataclasses.dataclass(frozen=True)
class Clocked:
    """A time-dependent ``model`` as the integrator sees it: the time is the last entry of its forcing (:class:`Clock`),
    handed to ``model.state_acceleration_at(t, q, v, xi)``."""

    model: object

    def state_acceleration(self, q, v, xi):
        return self.model.state_acceleration_at(xi[-1], q, v, xi[:-1])

    def stacked_constraints(self):
        return self.model.stacked_constraints()

    @property
    def dimension(self) -> int:
        return self.model.dimension

    @property
    def may_be_stiff(self) -> bool:
        return self.model.may_be_stiff


_NEEDS_SPECTRAL = (
    "an evolutionary spectrum shapes the harmonics of the spectral representation: give the scene "
    "excitation=jdpim.SpectralRepresentation() (Monte Carlo's default, GaussianNodes, draws white values at the nodes)"
)


@pytree_dataclass
class ShapedNodes(ArrayNodes):
    """:class:`ArrayNodes` synthesised under an evolutionary spectrum (:func:`synthesize_evolutionary`): the noise's
    ``envelope`` is already in them."""


def modulate(nodes: AbstractNodes, envelope: Callable | None, dt: float) -> AbstractNodes:
    """``nodes`` under the noise's ``envelope`` (``None``: unmodulated, ``nodes`` itself). An evolutionary spectrum
    is in the nodes the spectral representation synthesised with it (:class:`ShapedNodes`), and no other nodes can
    carry it (``ValueError``)."""
    if isinstance(envelope, AbstractEvolutionarySpectrum):
        if isinstance(nodes, ShapedNodes):
            return nodes
        raise ValueError(_NEEDS_SPECTRAL)
    return nodes if envelope is None else Modulated(nodes, envelope, dt)


@pytree_dataclass
class NodeSource(AbstractNodes):
    """Gaussian forcing values at the half-step nodes of ``n`` paths, drawn on demand (see :class:`GaussianNodes`).

    Source ``i`` of a path with key ``(k1, k2)`` takes node 0 (the start of step 0) from the first word of
    ``threefry2x32(k1, k2, 0, i)``, and the middle and end nodes of step ``k`` from the two words of
    ``threefry2x32(k1, k2, k + 1, i)`` (:func:`jdpim._normals.normal_pair`): one hash per path, step and source.
    Each step draws the next step's nodes into the carry, scaled: drawn in the step that reads them, the hash
    would be fused into every RK4 stage that reads a node and computed several times per step, and the scaling
    fused into the stages would round differently from one compiled program to another. The normals are drawn
    in float32 and cast to ``dtype`` (a seed gives the same samples in float32 and float64 runs), then
    multiplied by ``scale`` ``(m, m)``.
    """

    keys: jax.Array  # (n, 2) key data
    scale: jax.Array  # (m, m)
    dtype: object = static_field()

    @property
    def shape(self) -> tuple[int, int]:
        return self.keys.shape[0], self.scale.shape[0]

    def _pair(self, counter):
        """``(n, m)`` complex: the nodes of every path and source for the counter word ``counter``, scaled, in
        ``dtype`` (the middle node in the real part, the end node in the imaginary part)."""
        shape = self.shape
        k1, k2 = (jnp.broadcast_to(self.keys[:, j, None], shape) for j in (0, 1))
        source = jax.lax.broadcasted_iota(np.uint32, shape, 1)
        z = normal_pair(k1, k2, jnp.full(shape, counter, np.uint32), source)
        return jax.lax.complex(self._scaled(jnp.real(z)), self._scaled(jnp.imag(z)))

    def _scaled(self, z):
        """``(n, m)``: float32 normals ``z`` in ``dtype``, times ``scale``."""
        return jnp.einsum("...j,ij->...i", z.astype(self.dtype), self.scale)

    def start(self):
        """Node 0 and the nodes of step 0."""
        return jnp.real(self._pair(0)), self._pair(1)

    def step(self, k, carry):
        e_start, nodes = carry
        e_end = jnp.imag(nodes)
        return (e_start, jnp.real(nodes), e_end), (e_end, self._pair(k + 2))


@dataclasses.dataclass(frozen=True)
class SpectralGrid:
    """Concrete sizes of a spectral representation for one time grid (all static).

    ``n_terms`` harmonics ``w_k = k dw`` (k = 1..n_terms), FFT length ``n_fft``, and the simulated
    half-step samples ``start .. start + n_half - 1`` of the FFT output.
    """

    n_terms: int
    dw: float
    n_fft: int
    start: int
    n_half: int
    permute: bool
    seed: int
    random_functions: str = "rayleigh"

    @property
    def cutoff(self) -> float:
        return self.n_terms * self.dw

    def harmonics(self) -> np.ndarray:
        """Indices ``m_k`` (k = 0..K) of the random-function representation, shape ``(K + 1,)``."""
        m = np.arange(1, self.n_terms + 2)
        if self.permute:
            m = np.random.default_rng(self.seed).permutation(m)
        return m

    def amplitude(self) -> np.ndarray:
        """``sqrt(2 S0 dw)`` per term, unit intensity (``S0 = 1 / pi``), half weight at k = 0; ``(K + 1,)``."""
        a = np.full(self.n_terms + 1, math.sqrt(2.0 * self.dw / math.pi))
        a[0] /= math.sqrt(2.0)
        return a


def random_function_coefficients(theta: jnp.ndarray, grid: SpectralGrid, mixing: jnp.ndarray) -> jnp.ndarray:
    """Complex coefficients ``c_k = a (X_k - i Y_k)`` of one DPIM path from its elementary variables.

    Args:
        theta: shape ``(2 m,)``, the pair ``(Theta1, Theta2)`` of every source, in ``[-pi, pi)``.
        grid: the spectral grid.
        mixing: ``L`` with ``L L^T = D``, shape ``(m, m)``.

    Returns:
        shape ``(m, K + 1)``, complex; column ``k`` multiplies ``exp(i w_k t)``, k = 0..K.
    """
    m_k = grid.harmonics()[None, :]
    turns = theta.reshape(-1, 2) * (1 / (2 * math.pi))  # (m, 2), in [-1/2, 1/2); a product, as XLA rounds it
    if grid.random_functions == "cosine":  # sqrt2 cos(x + pi/4) = cos x - sin x
        (c1, s1), (c2, s2) = (cos_sin_turns(fractional_multiples(turns[:, j : j + 1], m_k)) for j in (0, 1))
        X, Y = c1 - s1, c2 - s2
    else:  # "rayleigh": Box-Muller pairs, amplitude from Theta1, phase from Theta2
        u = fractional_multiples(turns[:, :1], m_k, offset=0.5)  # frac(m (Theta1 + pi) / 2 pi)
        radius = jnp.sqrt(-2.0 * jnp.log(jnp.maximum(u, jnp.finfo(u.dtype).eps / 4)))  # u rounded to 0: eps / 4
        cos, sin = cos_sin_turns(fractional_multiples(turns[:, 1:], m_k))
        X, Y = radius * cos, radius * sin
    return _mix(X, Y, grid, mixing)


def gaussian_coefficients(
    key: jax.Array, n_sources: int, grid: SpectralGrid, mixing: jnp.ndarray, dtype
) -> jnp.ndarray:
    """Complex coefficients of one Monte Carlo path: ``X_k, Y_k`` independent standard normals, ``(m, K + 1)``.

    The normals are drawn in float32 and cast to ``dtype``, so a seed gives the same samples in float32
    and float64 runs (precision comparisons are then free of sampling noise).
    """
    XY = jax.random.normal(key, (2, n_sources, grid.n_terms + 1), dtype=jnp.float32).astype(dtype)
    return _mix(XY[0], XY[1], grid, mixing)


def _mix(X, Y, grid: SpectralGrid, mixing):
    Y = jnp.where(jnp.arange(Y.shape[-1]) == 0, 0.0, Y)  # no sine term at w = 0 (a select fuses; a scatter is a pass)
    c = jnp.asarray(grid.amplitude(), X.dtype)[None, :] * jax.lax.complex(X, -Y)
    return jnp.einsum("ij,jk->ik", mixing.astype(c.dtype), c)


# on a CPU, the paths of a chunk go through the FFT in blocks whose arrays (the padded spectrum, the FFT's output and
# its time-major copy) take at most about this many bytes, shared by the CPU's devices (one per core, each running its
# own blocks), so that they stay in the last-level cache between the FFT and the copy; a block's paths are a multiple
# of SYNTHESIS_ROWS (XLA's CPU FFT and copies are slower otherwise) and at most SYNTHESIS_MAX_ROWS where that adds
# little redone work: blocks of more paths (short records, whose arrays per path are small) are slower, though they
# fit the cache, and overlapping blocks redo paths
SYNTHESIS_BLOCK_BYTES = 24 * 2**20
SYNTHESIS_ROWS = 16
SYNTHESIS_MAX_ROWS = 64


def synthesis_rows(n_paths: int, m: int, n_fft: int, itemsize: int) -> int:
    """Paths per block of :func:`synthesize`: the fewest equal blocks whose FFT arrays (about ``3 m n_fft`` values of
    ``itemsize`` bytes per path) fit a device's share of ``SYNTHESIS_BLOCK_BYTES``, and of at most
    ``SYNTHESIS_MAX_ROWS`` paths where that redoes at most a sixteenth of the paths (blocks overlap at the end),
    rounded up to a multiple of ``SYNTHESIS_ROWS``; every path at once off a CPU (an accelerator's FFT gains from
    the whole batch)."""
    if not on_cpu():
        return n_paths
    budget = SYNTHESIS_BLOCK_BYTES // jax.local_device_count()
    blocks = -(-n_paths * 3 * m * n_fft * itemsize // budget)
    capped = _block_rows(n_paths, max(blocks, -(-n_paths // SYNTHESIS_MAX_ROWS)))
    if -(-n_paths // capped) * capped - n_paths <= n_paths // 16:
        return capped
    return _block_rows(n_paths, blocks)


def _block_rows(n_paths: int, blocks: int) -> int:
    """Rows of ``blocks`` equal blocks of ``n_paths``, rounded up to a multiple of ``SYNTHESIS_ROWS``."""
    rows = -(-n_paths // blocks)
    return min(n_paths, -(-rows // SYNTHESIS_ROWS) * SYNTHESIS_ROWS)


def synthesize(inputs, grid: SpectralGrid, coefficients_of: Callable | None = None) -> jnp.ndarray:
    """Excitation on the half-step grid for a batch of paths, by one inverse real FFT per path.

    On a CPU the paths go through the FFT in blocks of :func:`synthesis_rows` (a ``fori_loop``), each block's
    coefficients computed from its rows of ``inputs`` into the block's spectrum and its FFT written into the
    time-major result: a chunk's coefficients are never held at once (a fresh buffer of that size costs its pages'
    first touch in every run). Each path's values are those of one FFT over the whole
    batch, bit for bit (the FFT transforms every path apart). The last block starts ``n_paths - rows`` paths in, so
    it may redo paths of the block before it, with the same values.

    Args:
        inputs: the coefficients, shape ``(n_paths, m, K + 1)``, complex (k = 0..K); or, with
            ``coefficients_of``, the per-path inputs it maps to them (an array or pytree of arrays of leading
            axis ``n_paths``).
        grid: the spectral grid.
        coefficients_of: ``None``, or a function of a block of rows of ``inputs`` giving their coefficients
            ``(rows, m, K + 1)``, row by row.

    Returns:
        ``xi(t_j)`` at ``t_j = j dt / 2``, j = 0..2 n_steps, time-major: shape ``(n_half, n_paths, m)``.
    """
    coefficients_of = (lambda c: c) if coefficients_of is None else coefficients_of
    n_paths = jax.tree_util.tree_leaves(inputs)[0].shape[0]
    shape = jax.eval_shape(coefficients_of, inputs)
    m, dtype = shape.shape[1], jnp.finfo(shape.dtype).dtype
    rows = synthesis_rows(n_paths, m, grid.n_fft, dtype.itemsize)
    if rows == n_paths:
        return _synthesize_block(coefficients_of(inputs), grid)

    def one_block(b, carry):
        x, spectrum = carry
        start = jnp.minimum(b * rows, n_paths - rows)
        block = jax.tree_util.tree_map(lambda a: jax.lax.dynamic_slice_in_dim(a, start, rows, axis=0), inputs)
        spectrum = jax.lax.dynamic_update_slice(spectrum, _doubled_dc(coefficients_of(block)), (0, 0, 0))
        return jax.lax.dynamic_update_slice_in_dim(x, _irfft_time_major(spectrum, grid), start, axis=1), spectrum

    x = jnp.zeros((grid.n_half, n_paths, m), dtype)
    spectrum = jnp.zeros((rows, m, grid.n_fft // 2 + 1), shape.dtype)  # its bins above K stay zero
    return jax.lax.fori_loop(0, -(-n_paths // rows), one_block, (x, spectrum))[0]


def _doubled_dc(coefficients: jnp.ndarray) -> jnp.ndarray:
    """``coefficients`` ``(..., K + 1)`` with the bin k = 0 doubled: ``irfft`` halves the (real) DC bin relative to
    the others."""
    dc = jnp.where(jnp.arange(coefficients.shape[-1]) == 0, 2.0, 1.0).astype(coefficients.real.dtype)
    return coefficients * dc.reshape((1,) * (coefficients.ndim - 1) + dc.shape)


def _irfft_time_major(spectrum: jnp.ndarray, grid: SpectralGrid) -> jnp.ndarray:
    """The half-step samples ``(n_half, rows, m)`` of the spectra ``(rows, m, n_fft // 2 + 1)``."""
    x = jnp.fft.irfft(spectrum, n=grid.n_fft, axis=-1) * (grid.n_fft / 2)
    return jnp.moveaxis(jax.lax.slice_in_dim(x, grid.start, grid.start + grid.n_half, axis=-1), -1, 0)


def _synthesize_block(coefficients: jnp.ndarray, grid: SpectralGrid) -> jnp.ndarray:
    """:func:`synthesize` of ``coefficients`` ``(rows, m, K + 1)`` in one inverse real FFT: ``(n_half, rows, m)``."""
    K1 = coefficients.shape[-1]
    spectrum = jnp.pad(_doubled_dc(coefficients), ((0, 0), (0, 0), (0, grid.n_fft // 2 + 1 - K1)))
    return _irfft_time_major(spectrum, grid)


def checked_grid(settings: SpectralRepresentation, scene) -> SpectralGrid:
    """``settings``' grid for ``scene``, its noise's evolutionary spectrum (if any) checked finite and non-negative on
    the grid's frequencies and half-step times (once per grid: the check is cached)."""
    grid = settings.grid(scene.t_end, scene.dt)
    spectrum = scene.noise.spectrum
    if spectrum is not None:
        spectrum.check(grid.dw * np.arange(grid.n_terms + 1), 0.5 * scene.dt * np.arange(grid.n_half))
    return grid


def spectral_nodes(scene, inputs, grid: SpectralGrid, coefficients_of: Callable) -> ArrayNodes:
    """The forcing of a batch of paths whose spectral coefficients ``(n, m, K + 1)`` are ``coefficients_of(inputs)``
    (row by row, ``inputs`` of leading axis ``n``): one FFT (:func:`synthesize`), or under the noise's evolutionary
    spectrum :func:`synthesize_evolutionary` (:class:`ShapedNodes`)."""
    dtype = scene.float_dtype
    spectrum = scene.noise.spectrum
    if spectrum is None:
        return ArrayNodes(synthesize(inputs, grid, coefficients_of).astype(dtype))
    return ShapedNodes(synthesize_evolutionary(coefficients_of(inputs), grid, spectrum, 0.5 * scene.dt, dtype))


BASIS_VALUES = 2**20  # most values of one block of the evolutionary basis (times by harmonics)


@functools.lru_cache(maxsize=16)
def _phasors(grid: SpectralGrid, block: int) -> tuple[np.ndarray, np.ndarray]:
    """``(outer, inner)``: ``exp(i w_k t)`` at the first FFT sample of every block of ``block`` half-steps,
    ``(n_blocks, K + 1)``, and over the offsets within a block, ``(block, K + 1)``; their products are the FFT's
    phases ``2 pi k j / n_fft`` (exact integer arithmetic modulo ``n_fft``)."""
    k = np.arange(grid.n_terms + 1, dtype=np.int64)
    starts = grid.start + block * np.arange(-(-grid.n_half // block), dtype=np.int64)
    outer = np.exp(2j * np.pi * (np.outer(starts, k) % grid.n_fft) / grid.n_fft)
    inner = np.exp(2j * np.pi * (np.outer(np.arange(block, dtype=np.int64), k) % grid.n_fft) / grid.n_fft)
    return outer, inner


def synthesize_evolutionary(
    coefficients: jnp.ndarray, grid: SpectralGrid, spectrum: AbstractEvolutionarySpectrum, half: float, dtype
) -> jnp.ndarray:
    r"""Excitation under an evolutionary spectrum on the half-step grid, ``Re sum_k A(w_k, t_j) c_k exp(i w_k t_j)``.

    The same sum as :func:`synthesize` (same coefficients, same phases, the FFT's time origin) with every term
    scaled by ``A(w_k, t_j) = sqrt(spectrum(w_k, t_j))`` at the simulated time ``t_j = j half``: a product with the
    basis ``A exp(i w_k t)``, built in blocks of at most ``BASIS_VALUES`` values (``lax.map`` over the blocks), so
    memory stays bounded whatever the record's length.

    Args:
        coefficients: ``(n_paths, m, K + 1)``, complex.
        grid: the spectral grid.
        spectrum: ``|A(omega, t)|^2``.
        half: the half step ``dt / 2``, s.
        dtype: the float dtype of the result.

    Returns:
        ``(n_half, n_paths, m)``, time-major.
    """
    n, m, K1 = coefficients.shape
    block = max(1, min(grid.n_half, BASIS_VALUES // K1))
    outer, inner = _phasors(grid, block)
    cdtype = jnp.result_type(dtype, jnp.complex64)
    omega = jnp.asarray(grid.dw * np.arange(K1), dtype)
    real, imag = (
        jnp.moveaxis(part, -1, 0).reshape(K1, n * m).astype(dtype) for part in (coefficients.real, coefficients.imag)
    )
    inner = jnp.asarray(inner, cdtype)

    def one_block(args):
        index, phase = args
        t = (index * block + jnp.arange(block)).astype(dtype) * half
        basis = jnp.sqrt(spectrum.on_grid(omega, t).astype(dtype)) * (phase[None, :] * inner)
        return basis.real @ real - basis.imag @ imag  # Re(basis c) = A (cos Re c - sin Im c)

    blocks = jax.lax.map(one_block, (jnp.arange(outer.shape[0]), jnp.asarray(outer, cdtype)))
    return blocks.reshape(-1, n, m)[: grid.n_half]


def _next_fast_len(n: int) -> int:
    """Smallest 5-smooth integer >= n (fast FFT length)."""
    best = 2 * n
    p2 = 1
    while p2 < best:
        p3 = p2
        while p3 < best:
            p5 = p3
            while p5 < n:
                p5 *= 5
            best = min(best, p5)
            p3 *= 3
        p2 *= 2
    return best
