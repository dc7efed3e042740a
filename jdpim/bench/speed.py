"""Speed of the reference scene: jdpim's pipelines against plain vectorised NumPy and plain JAX RK4 Monte Carlo.

The baseline (:func:`numpy_mcs`) is the fastest plain NumPy we could write for the scene: in-place
ufuncs on contiguous ``(n_paths,)`` arrays, half-step Gaussian forcing from ``Generator(SFC64)``, the
mirror rule at the barrier, timed at 1e3, 1e4 and 1e5 paths per batch in float32 and float64 in the
same run; the best batch of each dtype is the baseline of jdpim's rows of that dtype (``x_numpy``).
jdpim's Monte Carlo is timed with its own mirror rule too (``ImpactRule(method="mirror")``), like for like,
and with its noise drawn inside the steps (``GaussianNodes``, the baseline's kind of forcing; ``forcing`` column).
The plain JAX baseline (:func:`jax_mcs`) is the same scheme as one jitted ``lax.scan`` on one device, at the
same batches and with JAX's threefry and rbg keys, the best of them (``x_jax``): what the library's machinery
(located impacts, chunks, devices, saved times, non-finite accounting) costs or gains over the few lines a JAX
user would write.

Reference scene: alpha = gamma = 0.03, r = 0.98, D = 0.03, t_end = 200 s, dt = 0.01 s (2e4 steps).
Protocol (``timing.timed``): AOT compile (timed apart), one warm-up run, ``repeats`` warm runs, median.
Each configuration runs on one device, and again on every local device when there are several (as
``python -m jdpim.bench`` sets up on a multi-core CPU: one device per core).
The split times the two stages of one chunk on their own (the excitation's synthesis; the integration under
that excitation, computed beforehand; spectral forcing only), times the number of chunks, and the densities
(``Result.pdf`` of x and v on 481 / 961 points at t_end).
Peak memory is the process's resident high-water mark (``resource.getrusage(...).ru_maxrss``), read
after each row: it only grows, so a row's figure bounds that row's own peak from above.
"""

from __future__ import annotations

import functools
import itertools
import json
import os
import pathlib
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from .._cpu import usable_cores
from .._excitation import GaussianNodes, SpectralRepresentation
from .._integrate import ImpactRule
from .._scene import Scene
from ..methods._paths import dpim_inputs, integrate_forcing, monte_carlo_inputs, path_forcing
from .accuracy import ALPHA, GAMMA, D, R, grids, paper_scene
from .processes import core_shares, device_env
from .record import record, record_lines, table_lines, write_record
from .timing import interleaved, prepared, protocol, timed

T_END, DT = 200.0, 0.01
BASELINE_BATCHES = (1_000, 10_000, 100_000)
# JAX's generators that the plain JAX baseline is timed with (its best is the baseline): "rbg" was the faster on a CPU
JAX_KEY_IMPLS = ("threefry2x32", "rbg")


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _median_time(fn, repeats: int) -> float:
    jax.block_until_ready(fn())
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        runs.append(time.perf_counter() - t0)
    return statistics.median(runs)


def split(scene, rows, kind: str, repeats: int, n_chunks: int) -> dict:
    """Warm median seconds of the excitation of one chunk ``rows`` and of its integration under that excitation
    (computed once beforehand), each timed on its own, times ``n_chunks``."""
    excite = jax.jit(lambda scene, rows: path_forcing(scene, kind, rows))
    integrate = jax.jit(integrate_forcing)
    forcing, rand = excite(scene, rows)
    return {
        "excitation_s": round(n_chunks * _median_time(lambda: excite(scene, rows), repeats), 4),
        "integration_s": round(n_chunks * _median_time(lambda: integrate(scene, forcing, rand), repeats), 4),
    }


def density_time(result, repeats: int) -> float:
    gx, gv = grids(1.0)
    t = result.times[-1]
    return _median_time(lambda: (result.pdf("x", gx, t), result.pdf("v", gv, t)), repeats)


def numpy_mcs(
    n_paths: int,
    *,
    t_end: float = T_END,
    dt: float = DT,
    alpha: float = ALPHA,
    gamma: float = GAMMA,
    r: float = R,
    D: float = D,
    seed: int = 0,
    dtype: str = "float64",
) -> tuple[np.ndarray, np.ndarray]:
    r"""The NumPy baseline: a vectorised RK4 Monte Carlo of ``x'' + alpha x' + gamma x'^3 + x = xi`` on ``x >= 0``.

    Written the way a competent NumPy user would write it for speed: one ``(n_paths,)`` array per
    quantity, preallocated and updated in place (``out=``), a Python loop over the steps. The forcing is
    held at values on the half-step grid, as jdpim's RK4 holds it (start, middle and end of each step;
    the end of one step is the start of the next), drawn as independent normals from ``Generator(SFC64)``
    with the variance that gives RK4's Simpson-weighted increment ``h/6 (f_0 + 4 f_{1/2} + f_1)`` the
    white noise's variance ``2 D`` per unit time:

    .. math::
        \operatorname{Var} f = \frac{18 D}{5 h},

    since over many steps each end-point value weighs ``h/3`` and each midpoint ``2h/3``
    (``(1/9 + 4/9) h^2 Var f = 2 D h``). Impacts use the mirror rule at the end of each step
    (``x < 0``: ``x <- -x``, ``v <- -r v``), first order in ``h``; jdpim locates each impact inside the
    step (``ImpactRule(method="locate")``) or applies the same mirror (``ImpactRule(method="mirror")``).
    Starts at rest on the barrier, as the reference scene does.

    Args:
        n_paths: paths integrated side by side.
        t_end, dt: end time and RK4 step, s.
        alpha, gamma, r, D: the oscillator (linear and cubic damping, restitution) and the noise intensity.
        seed: seed of the ``SFC64`` generator.
        dtype: ``"float64"`` or ``"float32"`` (arithmetic and normals).

    Returns:
        ``(x, v)`` at ``t_end``, each of shape ``(n_paths,)``.

    Examples:
        >>> x, v = numpy_mcs(100, t_end=1.0)
        >>> x.shape, bool((x >= 0).all())
        ((100,), True)
    """
    n_steps = int(round(t_end / dt))
    ty = np.dtype(dtype).type
    h, h2, h6, h26, scale = ty(dt), ty(dt / 2), ty(dt / 6), ty(dt * dt / 6), ty(np.sqrt(18.0 * D / (5.0 * dt)))
    alpha, gamma, minus_r = ty(alpha), ty(gamma), ty(-r)
    rng = np.random.Generator(np.random.SFC64(seed))
    x, v = np.zeros(n_paths, dtype), np.zeros(n_paths, dtype)
    xs, vs, a, tmp, k_sum, kv_sum = (np.empty(n_paths, dtype) for _ in range(6))
    hit = np.empty(n_paths, bool)
    forcing, next_forcing = np.empty((2, n_paths), dtype), np.empty((2, n_paths), dtype)
    rng.standard_normal(out=forcing[1], dtype=dtype)  # the start of the first step (row 1: "end of the previous")
    forcing[1] *= scale

    def acceleration(x, v, f, out):
        """``out = f - x - v (alpha + gamma v^2)``."""
        np.multiply(v, v, out=tmp)
        np.multiply(tmp, gamma, out=tmp)
        np.add(tmp, alpha, out=tmp)
        np.multiply(tmp, v, out=tmp)
        np.subtract(f, x, out=out)
        np.subtract(out, tmp, out=out)

    for _ in range(n_steps):
        f_start = forcing[1]
        rng.standard_normal(out=next_forcing, dtype=dtype)  # middle and end of this step
        np.multiply(next_forcing, scale, out=next_forcing)
        f_mid, f_end = next_forcing
        # RK4 in the form for x' = v (Nystrom): x_{n+1} = x + h v + h^2/6 (k1 + k2 + k3), stage k_i of v'
        acceleration(x, v, f_start, a)  # k1
        np.copyto(k_sum, a)
        np.copyto(kv_sum, a)
        np.multiply(v, h2, out=xs)
        np.add(xs, x, out=xs)  # x + h/2 v
        np.multiply(a, h2, out=vs)
        np.add(vs, v, out=vs)  # v + h/2 k1
        acceleration(xs, vs, f_mid, a)  # k2
        np.add(k_sum, a, out=k_sum)
        np.multiply(a, 2, out=tmp)
        np.add(kv_sum, tmp, out=kv_sum)
        np.multiply(vs, h2, out=xs)
        np.add(xs, x, out=xs)  # x + h/2 v2
        np.multiply(a, h2, out=vs)
        np.add(vs, v, out=vs)  # v + h/2 k2
        acceleration(xs, vs, f_mid, a)  # k3
        np.add(k_sum, a, out=k_sum)
        np.multiply(a, 2, out=tmp)
        np.add(kv_sum, tmp, out=kv_sum)
        np.multiply(vs, h, out=xs)
        np.add(xs, x, out=xs)  # x + h v3
        np.multiply(a, h, out=vs)
        np.add(vs, v, out=vs)  # v + h k3
        acceleration(xs, vs, f_end, a)  # k4
        np.add(kv_sum, a, out=kv_sum)
        np.multiply(v, h, out=tmp)
        np.add(x, tmp, out=x)
        np.multiply(k_sum, h26, out=k_sum)
        np.add(x, k_sum, out=x)  # x + h v + h^2/6 (k1 + k2 + k3)
        np.multiply(kv_sum, h6, out=kv_sum)
        np.add(v, kv_sum, out=v)  # v + h/6 (k1 + 2 k2 + 2 k3 + k4)
        np.less(x, 0, out=hit)  # the mirror rule
        np.abs(x, out=x)
        np.multiply(v, minus_r, out=v, where=hit)
        forcing, next_forcing = next_forcing, forcing
    return x, v


@functools.partial(jax.jit, static_argnames=("n_paths", "n_steps", "dtype"))
def jax_mcs(n_paths: int, n_steps: int, key, *, dtype: str = "float32", dt: float = DT):
    """The plain JAX baseline: :func:`numpy_mcs` written as one jitted ``lax.scan`` over the steps.

    What a JAX user writes for the scene without jdpim: ``(n_paths,)`` arrays, one ``jax.random.normal`` of
    ``(2, n_paths)`` per step (the middle and end nodes; the key of step ``k`` is ``fold_in(key, k)``), the same
    Nystrom RK4 and mirror rule (``jnp.where``). Returns ``(x, v)`` at the end, each ``(n_paths,)``.

    Examples:
        >>> x, v = jax_mcs(100, 100, jax.random.key(0))
        >>> x.shape, bool((x >= 0).all())
        ((100,), True)
    """
    ty = np.dtype(dtype).type
    h, scale = ty(dt), ty(np.sqrt(18.0 * D / (5.0 * dt)))

    def acc(x, v, f):
        return f - x - v * (ALPHA + GAMMA * v * v)

    def step(carry, k):
        x, v, f0 = carry
        fm, f1 = scale * jax.random.normal(jax.random.fold_in(key, k), (2, n_paths), dtype)
        k1 = acc(x, v, f0)
        k2 = acc(x + h / 2 * v, v + h / 2 * k1, fm)
        k3 = acc(x + h / 2 * (v + h / 2 * k1), v + h / 2 * k2, fm)
        k4 = acc(x + h * (v + h / 2 * k2), v + h * k3, f1)
        x = x + h * v + h * h / 6 * (k1 + k2 + k3)
        v = v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return (jnp.abs(x), jnp.where(x < 0, -R * v, v), f1), None

    zero = jnp.zeros(n_paths, dtype)
    f0 = scale * jax.random.normal(jax.random.fold_in(key, n_steps), (n_paths,), dtype)
    (x, v, _), _ = jax.lax.scan(step, (zero, zero, f0), jnp.arange(n_steps))
    return x, v


def jax_baseline(dtype: str, n_steps: int, *, log=print) -> list[dict]:
    """Path-steps per second of :func:`jax_mcs` on one device for each batch in ``BASELINE_BATCHES`` and each key
    implementation in ``JAX_KEY_IMPLS``: compile (timed apart), one warm-up run, 3 timed runs, median."""
    rows = []
    for impl, n in itertools.product(JAX_KEY_IMPLS, BASELINE_BATCHES):
        key = jax.random.key(0, impl=impl)
        t0 = time.perf_counter()
        compiled = jax_mcs.lower(n, n_steps, key, dtype=dtype).compile()
        compile_s = time.perf_counter() - t0
        median = _median_time(lambda compiled=compiled, key=key: jax.block_until_ready(compiled(key)), 3)
        rows.append(
            {
                "dtype": dtype,
                "key": impl,
                "n_paths": n,
                "n_steps": n_steps,
                "compile_s": round(compile_s, 2),
                "median_s": round(median, 3),
                "path_steps_per_s": float(f"{n * n_steps / median:.3g}"),
            }
        )
        log(f"[speed]   plain jax {rows[-1]}")
    return rows


def plain_scan(n_paths: int, n_steps: int, devices, *, dtype: str = "float32"):
    """``(compile_s, run)``: :func:`jax_mcs` (threefry keys) on ``devices``, the paths split equally over them.

    On several devices each runs ``n_paths / len(devices)`` paths under its own key (``shard_map`` over a mesh
    of the devices), as a JAX user spreads the plain scan over the cores; ``run()`` returns ``(x, v)``.
    """
    mesh = jax.sharding.Mesh(np.asarray(devices), ("d",))
    spec = jax.sharding.PartitionSpec("d")
    per_device = n_paths // len(devices)

    def local(key_data):
        return jax_mcs(per_device, n_steps, jax.random.wrap_key_data(key_data[0]), dtype=dtype)

    fn = jax.jit(jax.shard_map(local, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False))
    keys = jax.device_put(
        jax.random.key_data(jax.random.split(jax.random.key(0), len(devices))),
        jax.sharding.NamedSharding(mesh, spec),
    )
    t0 = time.perf_counter()
    compiled = fn.lower(keys).compile()
    compile_s = time.perf_counter() - t0
    return compile_s, lambda: jax.block_until_ready(compiled(keys))


# a barrier that no path of the reference scene reaches from x = 0 (x stays within a few units of it)
UNREACHED_BARRIER = -50.0


def layers(t_end: float) -> list[tuple[str, Scene]]:
    """``(impacts, scene)`` of jdpim's rows in :func:`versus`, each adding one layer of the impact handling to the
    last: the reference oscillator without a barrier (``"none"``), with the mirror rule, with located impacts and a
    barrier no path reaches (``"locate, unreached"``, from ``x = 0`` at rest: the test of every step, no batch),
    and the reference scene with located impacts (the batches of crossing paths too). All four start at rest at
    ``x = 0``."""
    scene = paper_scene(t_end, DT, GaussianNodes())
    model = scene.model
    return [
        ("none", scene.replace(model=model.replace(barrier=None))),
        ("mirror", scene.replace(impacts=ImpactRule(method="mirror"))),
        ("locate, unreached", scene.replace(model=model.replace(barrier=UNREACHED_BARRIER), x0=0.0, v0=0.0)),
        ("locate", scene.replace(impacts=ImpactRule(method="locate"))),
    ]


def versus(n_paths: int, t_end: float, repeats: int, *, log=print) -> list[dict]:
    """Path-steps per second of jdpim's Monte Carlo against the NumPy and plain JAX scan baselines, interleaved.

    The reference scene in float32 from rest, ``n_paths`` paths to ``t_end``: :func:`numpy_mcs` (one core),
    :func:`plain_scan` and jdpim's Monte Carlo (``GaussianNodes``; without a barrier, with the mirror rule, with
    located impacts and a barrier no path reaches, and with located impacts: :func:`layers`), each on one device
    and on every local device. Every configuration is compiled ahead of time (``compile_s``) and
    run once to warm up; then ``repeats`` rounds run each configuration once in turn, so that a load that
    comes and goes weighs on all alike; the median wall time and the median process CPU time (``cpu_s``, all
    threads) of the rounds. ``x_plain_scan``: path-steps per second over the plain scan's on as many devices;
    ``x_numpy``: over NumPy's on one core. ``cores``: the cores this process may use (one device may use several:
    XLA's thread pool runs part of a program on the other cores; :func:`versus_on_one_core` times one core).
    """
    n_steps = int(round(t_end / DT))
    cores = usable_cores()
    device_sets = [jax.local_devices()[:1]] + ([jax.local_devices()] if jax.local_device_count() > 1 else [])
    configs = [("numpy", "mirror", 1, 0.0, lambda: numpy_mcs(n_paths, t_end=t_end, dtype="float32"))]
    for devices in device_sets:
        compile_s, run = plain_scan(n_paths, n_steps, devices)
        configs.append(("plain scan", "mirror", len(devices), compile_s, run))
        for impacts, scene in layers(t_end):
            compile_s, run, _ = prepared("monte_carlo", scene, n_paths, devices=None if len(devices) == 1 else devices)
            configs.append(("jdpim monte_carlo", impacts, len(devices), compile_s, run))
    rows = []
    for (code, impacts, n_dev, compile_s, _), (median, cpu) in zip(
        configs, interleaved([c[-1] for c in configs], repeats), strict=True
    ):
        rows.append(
            {
                "code": code,
                "impacts": impacts,
                "devices": n_dev,
                "cores": cores,
                "n_paths": n_paths,
                "n_steps": n_steps,
                "compile_s": round(compile_s, 2) if code != "numpy" else None,
                "median_s": round(median, 3),
                "cpu_s": round(cpu, 3),
                "path_steps_per_s": float(f"{n_paths * n_steps / median:.3g}"),
            }
        )
    numpy_rate = rows[0]["path_steps_per_s"]
    plain = {r["devices"]: r["path_steps_per_s"] for r in rows if r["code"] == "plain scan"}
    for r in rows:
        r["x_plain_scan"] = round(r["path_steps_per_s"] / plain[r["devices"]], 2)
        r["x_numpy"] = round(r["path_steps_per_s"] / numpy_rate, 2)
        log(f"[speed]   {r}")
    return rows


def one_core() -> int | None:
    """The CPU that :func:`on_one_core` runs on: the first of this process's (:func:`.processes.core_shares`);
    ``None`` where the OS cannot restrict a process to some cores or this process has one core already."""
    share = core_shares(1, 1)[0]
    return int(share) if share else None


def on_one_core(code: str, *args: str):
    """Run the Python ``code`` in a new process restricted to :func:`one_core` before JAX starts (so that XLA's
    thread pool has one thread), with one JAX device: ``sys.argv[1:]`` are ``args`` and then the path of a file, to
    which ``code`` writes its result as JSON. Returns that result, or ``None`` where :func:`one_core` is ``None``."""
    cpu = one_core()
    if cpu is None:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        path = pathlib.Path(tmp) / "result.json"
        bound = f"import os\nos.sched_setaffinity(0, {{{cpu}}})\n" + code  # before JAX starts its thread pool
        subprocess.run([sys.executable, "-c", bound, *args, str(path)], env=device_env(1), check=True)
        return json.loads(path.read_text())


def versus_on_one_core(n_paths: int, t_end: float, repeats: int, *, log=print) -> list[dict]:
    """:func:`versus` on one core (:func:`on_one_core`): every code on that core; ``[]`` where :func:`one_core` is
    ``None``. A process of several cores cannot stand for one: a device of it runs part of its program on the other
    cores, and its threads restricted to one core afterwards wait for each other."""
    code = (
        "import json, sys\n"
        "from jdpim.bench.speed import versus\n"
        "rows = versus(int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), log=lambda s: print(s, flush=True))\n"
        "json.dump(rows, open(sys.argv[4], 'w'))\n"
    )
    if one_core() is None:
        log("[speed] one core: not measured (this process cannot be restricted to one of several cores)")
        return []
    log(f"[speed] one core: core {one_core()} alone, in a new process")
    return on_one_core(code, str(n_paths), repr(float(t_end)), str(repeats))


def run_versus(out: pathlib.Path, *, quick: bool = False, note: str | None = None, log=print) -> list[str]:
    """:func:`versus` at 1e4 paths (and 1e5 unless ``quick``) to t = 20 s (``quick``) or 50 s, 5 rounds;
    writes ``versus.json`` and ``versus.md`` (``versus_quick.*``) under ``out``, with ``note`` in the record."""
    t_end, sizes = (20.0, (10_000,)) if quick else (50.0, (10_000, 100_000))
    rows = []
    for n in sizes:
        log(f"[speed] interleaved: {n} paths to t = {t_end:g} s ...")
        rows += versus_on_one_core(n, t_end, 5, log=log) + versus(n, t_end, 5, log=log)
    rec = record(
        "each configuration compiled ahead of time (compile_s, apart) and run once to warm up; then 5 rounds, each "
        "running every configuration once in turn (interleaved); the median wall time of the rounds (median_s) "
        "and the median process CPU time (cpu_s, all threads); the clock covers the whole run and the transfer "
        "of the final states; the rows of one core ran so in a process of their own, restricted to one core "
        "before JAX started"
    )
    if note:
        rec["note"] = note
    info = {"record": rec, "scene": {"alpha": ALPHA, "gamma": GAMMA, "r": R, "D": D, "dt": DT}, "rows": rows}
    cols = ["code", "impacts", "cores", "devices", "n_paths", "n_steps", "compile_s", "median_s", "cpu_s"]
    cols += ["path_steps_per_s", "x_plain_scan", "x_numpy"]
    lines = record_lines(rec) + [
        f"The reference scene (alpha = gamma = 0.03, r = 0.98, D = 0.03, dt = {DT:g} s) from rest, float32: "
        "in-place NumPy RK4 (`numpy_mcs`, one core), the plain JAX `lax.scan` (`jax_mcs`, threefry normals per "
        "step; `shard_map` over the devices) and jdpim's Monte Carlo (`GaussianNodes`), path-steps per second. "
        "jdpim's `impacts`, one layer of impact handling after another: `none`, the oscillator without its barrier; "
        "`mirror`, the mirror rule; `locate, unreached`, located impacts and a barrier at x = "
        f"{UNREACHED_BARRIER:g} that no path reaches (the test in every step, no crossing to resolve); `locate`, the "
        "reference scene with located impacts (the default). `cores`: the CPU cores the process could use; one "
        "device of a process with several cores runs part of its program on the others (`cpu_s` above "
        "`median_s`), so the rows of one core are those of a process restricted to it.",
        "",
        *table_lines(rows, cols),
    ]
    return write_record(out, "versus_quick" if quick else "versus", info, lines, log=log)


def numpy_baseline(dtype: str, n_steps: int, *, quick: bool, log=print) -> list[dict]:
    """Path-steps per second of :func:`numpy_mcs` for each batch in ``BASELINE_BATCHES``, over ``n_steps`` steps.

    One short warm-up run, then 3 timed runs (1 for 1e5 paths unless ``quick``), median. The loop is
    branch-free, so its cost per step does not depend on the horizon.
    """
    rows = []
    for n in BASELINE_BATCHES:
        numpy_mcs(n, t_end=10 * DT, dtype=dtype)
        runs = []
        for seed in range(1 if n > 10_000 and not quick else 3):
            t0 = time.perf_counter()
            numpy_mcs(n, t_end=n_steps * DT, seed=seed, dtype=dtype)
            runs.append(time.perf_counter() - t0)
        median = statistics.median(runs)
        rows.append(
            {
                "dtype": dtype,
                "n_paths": n,
                "n_steps": n_steps,
                "repeats": len(runs),
                "median_s": round(median, 3),
                "path_steps_per_s": float(f"{n * n_steps / median:.3g}"),
            }
        )
        log(f"[speed]   numpy {rows[-1]}")
    return rows


def run_speed(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    """Run the speed table; writes ``speed.json`` and ``speed.md`` (``speed_quick.*``) under ``out``.

    The NumPy baseline (:func:`numpy_mcs`) runs first, in float32 and float64, at each batch size of
    ``BASELINE_BATCHES`` (over 2000 steps with ``quick``, the whole 2e4 otherwise); the best batch of each
    dtype is the baseline that ``x_numpy`` divides by for the jdpim rows of that dtype.
    """
    repeats = 3
    dtypes = ("float32",) if quick else ("float32", "float64")
    mcs_sizes = (10_000,) if quick else (10_000, 100_000)
    n_steps = int(round(T_END / DT))
    baseline_rows, best = [], {}
    for dtype in ("float32", "float64"):
        log(f"[speed] numpy baseline {dtype} ...")
        baseline_rows += numpy_baseline(dtype, n_steps // 10 if quick else n_steps, quick=quick, log=log)
        best[dtype] = max((r for r in baseline_rows if r["dtype"] == dtype), key=lambda r: r["path_steps_per_s"])
    load_after_baseline = [round(x, 2) for x in os.getloadavg()]
    rows = []
    # one device (the protocol's rows, with the split), then every local device (what dpim and monte_carlo use)
    device_sets = [None] + ([jax.local_devices()] if jax.local_device_count() > 1 else [])
    jax_rows, best_jax = [], {}
    for dtype in dtypes:
        if dtype == "float64":
            jax.config.update("jax_enable_x64", True)
        log(f"[speed] plain JAX baseline {dtype} ...")
        jax_rows += jax_baseline(dtype, n_steps // 10 if quick else n_steps, log=log)
        best_jax[dtype] = max((r for r in jax_rows if r["dtype"] == dtype), key=lambda r: r["path_steps_per_s"])
        configs = [("dpim", 1000, "locate", "spectral")] + [("monte_carlo", m, "locate", "spectral") for m in mcs_sizes]
        configs += [("monte_carlo", 10_000, "mirror", "spectral"), ("monte_carlo", 10_000, "locate", "nodes")]
        for method, n, impacts, forcing in configs:
            excitation = GaussianNodes() if forcing == "nodes" else SpectralRepresentation()
            scene = paper_scene(T_END, DT, excitation, dtype=dtype, impacts=ImpactRule(method=impacts))
            for devices in device_sets:
                n_dev = 1 if devices is None else len(devices)
                log(f"[speed] {dtype} {method} n={n} impacts={impacts} forcing={forcing} on {n_dev} device(s) ...")
                res, tm = timed(method, scene, n, repeats=repeats if n <= 10_000 else 1, devices=devices)
                row = {"dtype": dtype, "impacts": impacts, "forcing": forcing, **tm.row()}
                if n <= 10_000 and devices is None and forcing == "spectral":  # the split of one chunk of the same size
                    inputs = dpim_inputs(scene, n) if method == "dpim" else monte_carlo_inputs(scene, n)
                    chunk = inputs[0][: inputs[2]]
                    row.update(split(scene, chunk, method, repeats, -(-n // inputs[2])))
                if n <= 10_000 and devices is None:
                    row["densities_s"] = round(density_time(res, repeats), 4)
                row["x_numpy"] = round(row["path_steps_per_s"] / best[dtype]["path_steps_per_s"], 2)
                row["x_jax"] = round(row["path_steps_per_s"] / best_jax[dtype]["path_steps_per_s"], 2)
                row["peak_rss_mib"] = round(_peak_mib())
                row["n_nonfinite"] = int(np.max(np.asarray(res.n_nonfinite())))
                rows.append(row)
                log(f"[speed]   {row}")
    info = {
        "record": record(
            protocol("3" if quick else "3 (once at 1e5 paths)")
            + "; the densities (densities_s) timed apart; excitation_s and integration_s (one device, spectral "
            + "forcing): one chunk's excitation and its integration under that excitation, each timed on its own, "
            + "times the number of chunks; the NumPy and plain JAX baselines: one warm-up run, "
            + ("then 3 timed runs over 2000 steps, the median" if quick else "then 3 timed runs (NumPy: once at 1e5)")
        ),
        "scene": {"alpha": ALPHA, "gamma": GAMMA, "r": R, "D": D, "t_end": T_END, "dt": DT},
        "numpy_baseline": {"best": best, "batches": baseline_rows},
        "jax_baseline": {"best": best_jax, "batches": jax_rows},
        "rows": rows,
        "load_average_after_baseline": load_after_baseline,
        "quick": quick,
    }
    out.mkdir(parents=True, exist_ok=True)
    name = "speed_quick" if quick else "speed"
    (out / f"{name}.json").write_text(json.dumps(info, indent=1) + "\n")
    cols = [
        "dtype",
        "method",
        "impacts",
        "forcing",
        "n_paths",
        "devices",
        "compile_s",
        "median_s",
        "excitation_s",
        "integration_s",
        "densities_s",
        "path_steps_per_s",
        "x_numpy",
        "x_jax",
        "peak_rss_mib",
    ]
    lines = record_lines(info["record"]) + table_lines(rows, cols)
    lines.append("\nNumPy baseline (`numpy_mcs`: RK4, half-step Gaussian forcing, mirror rule; one core), per batch:\n")
    lines += table_lines(baseline_rows, ["dtype", "n_paths", "n_steps", "repeats", "median_s", "path_steps_per_s"])
    lines.append("\nPlain JAX baseline (`jax_mcs`: the same scheme as one jitted `lax.scan`; one device), per batch:\n")
    lines += table_lines(jax_rows, ["dtype", "key", "n_paths", "n_steps", "compile_s", "median_s", "path_steps_per_s"])
    for dtype, b in best.items():
        lines.append(f"\nBaseline {dtype} (`x_numpy` of the {dtype} rows): {b['n_paths']} paths per batch, ")
        lines[-1] += f"{b['path_steps_per_s']:.3g} path-steps/s."
        if dtype in best_jax:
            lines[-1] += (
                f" Plain JAX (`x_jax`): {best_jax[dtype]['n_paths']} paths per batch, {best_jax[dtype]['key']} keys, "
            )
            lines[-1] += f"{best_jax[dtype]['path_steps_per_s']:.3g} path-steps/s."
    lines.append(f"\nLoad average (1, 5, 15 min) after the baseline: {load_after_baseline}.")
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    log("\n".join(lines))
    return [f"{name}.json", f"{name}.md"]
