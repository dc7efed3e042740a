"""Several degrees of freedom: an impact damper against a long small-dt reference, and its speed.

Scene: a primary structure (mass 1, ``omega = 1`` rad/s, damping ratio 0.01) excited by white noise on the
primary (``D = 0.01``), with a damper mass of 0.05 in a clearance of +-0.1 (two constraints, ``r = 0.5``), from
rest; densities of the primary displacement ``x1`` and of the relative displacement ``x2 - x1`` at ``t_end``.
Every run shares one excitation spectrum (cutoff 50 rad/s: ``w_u dt <= 2`` at the largest step), so that the
runs differ only in their time step and sampling.

Accuracy: Monte Carlo at ``dt`` in (0.04, 0.02, 0.01, 0.005) and DPIM at ``dt = 0.01`` against a Monte Carlo
reference at ``dt = 0.0025`` with four times the paths; the sampling floor is the distance between two Monte
Carlo runs of the same size at the reference's step (independent seeds), so an error near the floor is
sampling, and above it the time step.

Time-step error with common random numbers: Monte Carlo at every ``dt`` (float64) driven by the same continuous
excitation, the same spectral lines and time origin for every step (a period and an offset that are whole
numbers of the coarsest half-step), so that the paths at two steps differ only by the step, against
``dt = DT_REF / 2``: the RMS over paths of the differences of ``x1`` and ``x2 - x1`` (strong error) and the
differences of ``E[x1^2]`` and ``E[(x2 - x1)^2]`` with their standard errors (weak error), resolved with a few
thousand paths where independent runs are not.

Mirroring the slow impacts: the damper with ``ImpactRule(mirror_below=v)`` for several ``v`` and with the mirror
rule, timed, and its error against every impact located (common random numbers, float64): ``E[x1^2]`` with its
standard error and the RMS of ``x1``'s difference at ``t_end``.

Speed: Monte Carlo of the impact damper and of the reference one-degree-of-freedom scene (alpha = gamma = 0.03,
r = 0.98, D = 0.03), the same number of paths and steps and the same forcing (``GaussianNodes``), and the damper with
its spectral forcing, interleaved (:func:`.timing.interleaved`: AOT compile, warm-up, rounds, median) on one core and
on every device; path-steps per second per degree of freedom.
"""

from __future__ import annotations

import json
import math
import pathlib

import jax
import numpy as np

from .. import metrics
from .._cpu import usable_cores
from .._excitation import GaussianNodes, SpectralRepresentation
from .._integrate import ImpactRule
from .._models import VibroImpactOscillator
from .._noise import WhiteNoise
from .._scene import Scene
from ..systems import impact_damper
from .record import record, record_lines, table_lines
from .speed import on_one_core
from .timing import interleaved, prepared, protocol, timed

CUTOFF = 50.0  # rad/s: w_u dt = 2 at dt = 0.04
DTS = (0.04, 0.02, 0.01, 0.005)
DT_REF = 0.0025


def damper_scene(t_end: float, dt: float) -> Scene:
    return Scene(
        impact_damper(),  # the defaults: mass ratio 0.05, omega = 1, zeta = 0.01, clearance 0.1, r = 0.5
        noise=WhiteNoise(D=0.01),
        t_end=t_end,
        dt=dt,
        excitation=SpectralRepresentation(cutoff=CUTOFF),
    )


def _relative(state):
    return state[1] - state[0]


GRIDS = {"x1": np.linspace(-1.5, 1.5, 301), "x2 - x1": np.linspace(-0.1, 0.1, 201)}
# One kernel width per quantity for every run: a bandwidth rule would smooth the reference (four times the
# paths) less, and the sharp peaks of x2 - x1 at the clearance's walls would show that as an error.
BANDWIDTHS = {"x1": 0.06, "x2 - x1": 0.004}


def _densities(result, t) -> dict:
    out = {
        "x1": result.pdf("x1", GRIDS["x1"], t, bandwidth=BANDWIDTHS["x1"]),
        "x2 - x1": result.pdf(_relative, GRIDS["x2 - x1"], t, bandwidth=BANDWIDTHS["x2 - x1"]),
    }
    return {k: np.asarray(v) for k, v in out.items()}


def _distances(p: dict, q: dict) -> dict:
    return {k: round(metrics.l1(p[k], q[k], GRIDS[k]), 4) for k in GRIDS}


def convergence(t_end: float, n: int, log=print) -> list[dict]:
    """L1 distances to the small-dt reference of Monte Carlo at each step and of DPIM at ``dt = 0.01``."""
    ref_scene = damper_scene(t_end, DT_REF)
    ref, ref_time = timed("monte_carlo", ref_scene, 4 * n, seed=100, repeats=1, warmup=False)
    reference = _densities(ref, t_end)
    log(f"reference: Monte Carlo {4 * n} paths at dt = {DT_REF}, {ref_time.median_s:.1f} s")
    rows = []
    floor_a, _ = timed("monte_carlo", ref_scene, n, seed=1, repeats=1, warmup=False)
    floor_b, _ = timed("monte_carlo", ref_scene, n, seed=2, repeats=1, warmup=False)
    floor = _distances(_densities(floor_a, t_end), _densities(floor_b, t_end))
    rows.append({"method": "sampling floor", "dt": DT_REF, "n_paths": n, **floor, "median_s": None})
    log(f"floor (two MC runs of {n} at dt = {DT_REF}): {floor}")
    runs = [("monte_carlo", dt) for dt in DTS] + [("dpim", 0.01)]
    for method, dt in runs:
        res, timing = timed(method, damper_scene(t_end, dt), n, seed=3, repeats=1)
        row = {"method": method, "dt": dt, "n_paths": n, **_distances(_densities(res, t_end), reference)}
        row.update(median_s=round(timing.median_s, 3), n_nonfinite=int(np.sum(res.n_nonfinite())))
        rows.append(row)
        log(str(row))
    return rows


def common_excitation(t_end: float) -> SpectralRepresentation:
    """The excitation of :func:`common_noise_convergence`: the same lines and time origin at every step of ``DTS``."""
    coarsest = max(DTS) / 2.0  # the coarsest half-step; the finer ones divide it
    offset = 64 * coarsest  # 1.28 s: ten periods of the cutoff and a whole number of every half-step
    period = coarsest * 2 ** math.ceil(math.log2((t_end + 2 * offset) / coarsest))
    return SpectralRepresentation(cutoff=CUTOFF, offset=offset, dw=2 * math.pi / period)


def common_noise_convergence(t_end: float, n: int, log=print) -> list[dict]:
    """Strong and weak time-step errors at ``t_end / 4`` and ``t_end`` against ``DT_REF / 2``, common random numbers."""
    times = (t_end / 4, t_end)
    dts = (*DTS, DT_REF, DT_REF / 2)
    states = {}
    with jax.enable_x64(True):
        for dt in dts:
            scene = damper_scene(t_end, dt).replace(excitation=common_excitation(t_end), save_at=times, dtype="float64")
            res, timing = timed("monte_carlo", scene, n, seed=3, repeats=1, warmup=False)
            states[dt] = np.asarray(res.states, np.float64)
            log(f"dt = {dt}: {timing.median_s:.1f} s, {int(np.sum(res.n_nonfinite()))} non-finite")
    ref = states[dts[-1]]
    rows = []
    for i, t in enumerate(times):
        for dt in dts[:-1]:
            a, b = states[dt][:, i], ref[:, i]
            gap_a, gap_b = a[:, 1] - a[:, 0], b[:, 1] - b[:, 0]
            row = {"t": t, "dt": dt}
            row["rms_x1"] = float(f"{np.sqrt(np.mean((a[:, 0] - b[:, 0]) ** 2)):.3g}")
            row["rms_gap"] = float(f"{np.sqrt(np.mean((gap_a - gap_b) ** 2)):.3g}")
            for name, d in (("x1^2", a[:, 0] ** 2 - b[:, 0] ** 2), ("gap^2", gap_a**2 - gap_b**2)):
                row[f"dE[{name}]"] = float(f"{d.mean():.3g}")
                row[f"se[{name}]"] = float(f"{d.std() / math.sqrt(n):.2g}")
            rows.append(row)
            log(str(row))
    return rows


SLOW_IMPACTS = (1e-3, 1e-2, 3e-2, 0.1)  # the mirror_below values of slow_impacts, units of x per s


def slow_impacts(t_end: float, n: int, t_speed: float, n_speed: int, repeats: int, log=print) -> list[dict]:
    """Time (``n_speed`` paths to ``t_speed``) and error at ``t_end`` (``n`` paths, against every impact located) of
    the damper with each ``mirror_below`` of ``SLOW_IMPACTS`` and with the mirror rule, at dt = 0.01."""
    rules = [("locate", ImpactRule())]
    rules += [(f"mirror_below={v:g}", ImpactRule(mirror_below=v)) for v in SLOW_IMPACTS]
    rules += [("mirror", ImpactRule(method="mirror"))]
    rows, states = [], {}
    for name, rule in rules:
        scene = damper_scene(t_speed, 0.01).replace(impacts=rule)
        _, timing = timed("monte_carlo", scene, n_speed, repeats=repeats, warmup=False)
        rows.append(
            {
                "rule": name,
                "median_s": round(timing.median_s, 3),
                "path_steps_per_s": float(f"{timing.path_steps_per_s:.3g}"),
            }
        )
        with jax.enable_x64(True):
            exact = damper_scene(t_end, 0.01).replace(impacts=rule, dtype="float64")
            res, _ = timed("monte_carlo", exact, n, seed=3, repeats=1, warmup=False)
            states[name] = np.asarray(res.states, np.float64)[:, -1]
        log(str(rows[-1]))
    ref = states["locate"][:, 0]
    for row in rows[1:]:
        x1 = states[row["rule"]][:, 0]
        d = x1**2 - ref**2
        row["dE[x1^2]"] = float(f"{d.mean():.3g}")
        row["se"] = float(f"{d.std() / math.sqrt(n):.2g}")
        row["rms_x1"] = float(f"{np.sqrt(np.mean((x1 - ref) ** 2)):.3g}")
    return rows


def speed_scenes(t_end: float) -> list[tuple[str, str, Scene, int]]:
    """``(name, forcing, scene, degrees of freedom)`` of :func:`speed`'s rows: the reference scene and the impact
    damper with Monte Carlo's default forcing (``GaussianNodes``), and the damper with its spectral forcing."""
    reference = Scene(VibroImpactOscillator(), noise=WhiteNoise(D=0.03), t_end=t_end, dt=0.01)
    spectral = damper_scene(t_end, 0.01)
    nodes = Scene(spectral.model, noise=spectral.noise, t_end=t_end, dt=0.01, excitation=GaussianNodes())
    return [
        ("reference scene", "nodes", reference, 1),
        ("impact damper", "nodes", nodes, 2),
        ("impact damper", "spectral", spectral, 2),
    ]


def speed(t_end: float, n: int, repeats: int, log=print) -> list[dict]:
    """Path-steps per second per degree of freedom: the impact damper against the reference scene, like for like.

    The rows of one core (a process of its own, restricted to one core before JAX started:
    :func:`.speed.on_one_core`) and of every device of this process (:func:`speed_here`). A single device of a
    process with several cores runs the reference scene's large kernels on all of them and the damper's small
    batches of crossing paths on one, so it would not compare the two scenes like for like.
    """
    code = (
        "import json, sys\n"
        "from jdpim.bench.mdof import speed_here\n"
        "log = lambda s: print(s, flush=True)\n"
        "rows = speed_here(float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), log=log)\n"
        "json.dump(rows, open(sys.argv[4], 'w'))\n"
    )
    one = on_one_core(code, repr(float(t_end)), str(n), str(repeats))
    if one is None:
        log("[mdof] one core: not measured (this process cannot be restricted to one of several cores)")
    return (one or []) + speed_here(t_end, n, repeats, log=log)


def speed_here(t_end: float, n: int, repeats: int, log=print) -> list[dict]:
    """The rows of :func:`speed` on every device of this process, interleaved (:func:`.timing.interleaved`): Monte
    Carlo of ``n`` paths to ``t_end`` of each of :func:`speed_scenes`. Each row's ``ratio``: its path-steps per second
    per degree of freedom over the reference scene's. The spectral forcing's excitation arrays (an FFT per path,
    chunks of at most ``CPU_CHUNK_BYTES`` on a CPU) cost more than its steps."""
    devices = jax.local_devices()
    configs = []
    for name, forcing, scene, dof in speed_scenes(t_end):
        compile_s, run, _ = prepared("monte_carlo", scene, n, devices=devices if len(devices) > 1 else None)
        configs.append((name, forcing, dof, scene.n_steps, compile_s, run))
    rows, reference = [], None
    for (name, forcing, dof, n_steps, compile_s, _), (wall, cpu) in zip(
        configs, interleaved([c[-1] for c in configs], repeats), strict=True
    ):
        rate = n * n_steps * dof / wall
        reference = reference or rate
        row = {"scene": name, "forcing": forcing, "dof": dof, "cores": usable_cores(), "devices": len(devices)}
        row.update(n_paths=n, n_steps=n_steps, compile_s=round(compile_s, 2), median_s=round(wall, 4))
        row.update(cpu_s=round(cpu, 3), path_dof_steps_per_s=float(f"{rate:.3g}"), ratio=round(rate / reference, 3))
        rows.append(row)
        log(f"[mdof] {row}")
    return rows


def _table(rows: list[dict]) -> str:
    """A Markdown table of ``rows`` in the union of their keys."""
    return "\n".join(table_lines(rows, list(dict.fromkeys(k for r in rows for k in r))))


def run_mdof(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    """Every part; ``quick``: t_end 20 s, 4000 paths, speed at 1e4 paths and t = 50 (else 50 s, 2e4; 1e5, 200)."""
    t_end, n = (20.0, 4000) if quick else (50.0, 20_000)
    conv = convergence(t_end, n, log=log)
    common = common_noise_convergence(t_end, n, log=log)
    slow = slow_impacts(t_end, n, 50.0, 10_000, 3, log=log)
    fast = speed(50.0, 10_000, 3, log=log) if quick else speed(200.0, 100_000, 3, log=log)
    out.mkdir(parents=True, exist_ok=True)
    stem = "mdof_quick" if quick else "mdof"
    rec = record(
        protocol("3 (the mirroring rows, without the warm-up run; the accuracy rows once)")
        + "; the speed rows: each configuration compiled ahead of time and run once to warm up, then 3 rounds, each "
        "running every configuration once in turn (interleaved), the median wall time (median_s) and process CPU "
        "time (cpu_s); the rows of one core ran so in a process of their own, restricted to one core before JAX "
        "started"
    )
    data = {"record": rec, "convergence": conv, "common_noise_convergence": common, "slow_impacts": slow, "speed": fast}
    (out / f"{stem}.json").write_text(json.dumps(data, indent=1))
    text = (
        "\n".join(record_lines(rec))
        + f"\nImpact damper at t = {t_end:g} s: L1 distances to a Monte Carlo reference ({4 * n} paths, "
        + f"dt = {DT_REF})\n\n"
        + _table(conv)
        + f"\n\nTime-step errors with common random numbers ({n} paths, float64) against dt = {DT_REF / 2}\n\n"
        + _table(common)
        + f"\n\nMirroring the slow impacts: time of 10000 paths to t = 50 s; error at t = {t_end:g} s ({n} paths, "
        + "float64) against every impact located\n\n"
        + _table(slow)
        + "\n\nMonte Carlo speed, impact damper against the reference scene (same paths and steps; ratio: path-steps "
        + "per second per degree of freedom over the reference scene's on the same cores and devices)\n\n"
        + _table(fast)
        + "\n"
    )
    (out / f"{stem}.md").write_text(text)
    return [f"{stem}.json", f"{stem}.md"]
