"""What accuracy costs in time: error against exact or reference densities versus warm wall time.

Cases:

* ``elastic``: r = 1, alpha = D = 0.03, gamma absent; exact folded-Gaussian marginals (``jdpim.exact``).
* ``paper``: alpha = gamma = 0.03, r = 0.98, D = 0.03; reference = path integration on a fine grid
  (``REFERENCE``: 241 x 481 nodes, tau = 0.025, start at t0 = 0.25), about 1e-4 or better where the exact
  solution is known (docs/path_integration.md). Its own error is bounded by its distance to the same solver
  on the default grid (121 x 241, tau = 0.05), reported as ``reference_l1``.

The error of a run is the L1 distance of the marginal PDFs of x and x', averaged over both variables and
the saved times. Every run is timed with the protocol of ``jdpim.bench.timed`` (AOT compile reported
apart, warm-up, repeats, median). DPIM replicates use different harmonic permutations (``seed`` of
``SpectralRepresentation``); MCS replicates use different seeds. Path-integration rows (deterministic,
one replicate; ``n_paths`` is the number of grid nodes) start from rest like the simulations and are
timed as a first call (compile and run) followed by warm repeats; their compile time is the difference.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import statistics
import time

import jax
import numpy as np

from .. import exact, metrics
from .._excitation import GaussianNodes, SpectralRepresentation
from .._models import VibroImpactOscillator
from .._noise import WhiteNoise
from .._scene import Scene
from ..methods._path_integration import PathIntegration, path_integration
from .record import record
from .timing import protocol as timing_protocol
from .timing import timed

ALPHA, GAMMA, R, D = 0.03, 0.03, 0.98, 0.03


@dataclasses.dataclass(frozen=True)
class Sweep:
    """Sizes and settings of one benchmark run."""

    t_end: float = 50.0
    dt: float = 0.01
    dpim_points: tuple[int, ...] = (125, 250, 500, 1000, 2000, 4000, 8000, 16000)
    mc_samples: tuple[int, ...] = (1000, 3000, 10_000, 30_000, 100_000)
    replicates: int = 2
    repeats: int = 3
    big_run: float = 1e8  # path-steps above which a configuration is timed once after its warm-up
    pi_grids: tuple[tuple[int, int], ...] = ((121, 241), (161, 321), (241, 481))  # (n_x, n_v) of path integration
    pi_tau: float = 0.05


QUICK = Sweep(
    t_end=50.0,
    dpim_points=(125, 250, 500, 1000, 2000, 4000),
    mc_samples=(1000, 3000, 10_000),
    replicates=2,
    repeats=1,
    pi_grids=((121, 241),),
)


def _scene(model, t_end: float, dt: float, excitation, scene_kw) -> Scene:
    excitation = excitation or SpectralRepresentation()
    save_at = (10.0, t_end) if t_end > 10.0 else (t_end,)
    return Scene(model, noise=WhiteNoise(D=D), t_end=t_end, dt=dt, save_at=save_at, excitation=excitation, **scene_kw)


def elastic_scene(t_end: float, dt: float, excitation: SpectralRepresentation | None = None, **scene_kw) -> Scene:
    """The exact-solution case (r = 1, linear damping), saved at t = 10 s (where ``t_end`` is later) and t_end."""
    return _scene(VibroImpactOscillator(alpha=ALPHA, gamma=None, r=1.0), t_end, dt, excitation, scene_kw)


def paper_scene(
    t_end: float, dt: float, excitation: SpectralRepresentation | GaussianNodes | None = None, **scene_kw
) -> Scene:
    """The reference example (alpha = gamma = 0.03, r = 0.98, D = 0.03), saved at t = 10 s (where ``t_end`` is later)
    and t_end."""
    return _scene(VibroImpactOscillator(alpha=ALPHA, gamma=GAMMA, r=R), t_end, dt, excitation, scene_kw)


def grids(scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Evaluation grids for x (``[0, 6 scale]``) and x' (``[-6 scale, 6 scale]``)."""
    return np.linspace(0.0, 6.0 * scale, 481), np.linspace(-6.0 * scale, 6.0 * scale, 961)


def exact_references(scene: Scene) -> dict:
    """``{(var, t): (grid, pdf)}`` from the exact r = 1 solution."""
    scale = math.sqrt(D / ALPHA)
    xg, vg = grids(scale)
    out = {}
    for t in scene.save_at:
        out[("x", t)] = (xg, exact.elastic_linear_pdf_x(xg, ALPHA, D, t))
        out[("v", t)] = (vg, exact.elastic_linear_pdf_v(vg, ALPHA, D, t))
    return out


def pdf_error(result, references: dict) -> float:
    """Mean L1 distance over the reference's (variable, time) pairs."""
    errs = [metrics.l1(np.asarray(result.pdf(var, g, t)), ref, g) for (var, t), (g, ref) in references.items()]
    return float(np.mean(errs))


REFERENCE = PathIntegration(n_x=241, n_v=481, tau=0.025, t0=0.25)  # the paper case's reference grid


def path_integration_reference(scene: Scene) -> tuple[dict, float]:
    """Reference densities by path integration on the :data:`REFERENCE` grid, and a bound on their L1 error.

    The bound is the distance (as in :func:`pdf_error`) between the reference and the default grid's
    solution: the finer grid is the closer one (measured on the exact case: 2.4e-5 against 3.4e-4).
    """
    ref_run = path_integration(scene, REFERENCE)
    scale = math.sqrt(max(float(ref_run.moment("x", 2, t)) for t in scene.save_at))
    xg, vg = grids(scale)
    refs = {
        (var, t): (g, np.asarray(ref_run.pdf(var, g, t))) for t in scene.save_at for var, g in (("x", xg), ("v", vg))
    }
    return refs, pdf_error(path_integration(scene, PathIntegration()), refs)


def timed_path_integration(scene: Scene, settings: PathIntegration, repeats: int = 3):
    """Path integration of ``scene`` under the timing protocol; returns the result and ``(median_s, compile_s)``.

    JAX's caches are cleared first, so that the first call compiles even where the same grid ran before.
    """
    jax.clear_caches()
    t0 = time.perf_counter()
    res = jax.block_until_ready(path_integration(scene, settings))
    first = time.perf_counter() - t0
    runs = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        res = jax.block_until_ready(path_integration(scene, settings))
        runs.append(time.perf_counter() - t0)
    median = statistics.median(runs)
    return res, (median, max(first - median, 0.0))


def sweep(case: str, cfg: Sweep, *, log=print, on_row=None) -> dict:
    """Run the sweep for ``case`` (``"elastic"`` or ``"paper"``); returns rows and the reference's error.

    ``on_row(partial_result)`` is called after every configuration (to save partial results).
    """
    make = elastic_scene if case == "elastic" else paper_scene
    base = make(cfg.t_end, cfg.dt)
    if case == "elastic":
        refs, ref_err = exact_references(base), 0.0
    else:
        log(f"[{case}] reference: path integration, {REFERENCE.n_x} x {REFERENCE.n_v} nodes, tau {REFERENCE.tau}")
        refs, ref_err = path_integration_reference(base)
        log(f"[{case}] reference error (L1) below {ref_err:.2e}")
    rows = []
    for method, sizes in (("dpim", cfg.dpim_points), ("monte_carlo", cfg.mc_samples)):
        for n in sizes:
            errs, times, compile_s = [], [], []
            repeats = cfg.repeats if n * base.n_steps <= cfg.big_run else 1
            for rep in range(cfg.replicates):
                if method == "dpim":
                    scene = make(cfg.t_end, cfg.dt, SpectralRepresentation(seed=rep))
                    res, tm = timed("dpim", scene, n, repeats=repeats)
                else:
                    res, tm = timed("monte_carlo", base, n, seed=rep, repeats=repeats)
                errs.append(pdf_error(res, refs))
                times.append(tm.median_s)
                compile_s.append(tm.compile_s)
            row = {
                "case": case,
                "method": method,
                "n_paths": n,
                "l1_mean": float(np.mean(errs)),
                "l1_min": float(np.min(errs)),
                "l1_max": float(np.max(errs)),
                "replicates": cfg.replicates,
                "time_s": statistics.median(times),
                "compile_s": statistics.median(compile_s),
                "path_steps_per_s": n * base.n_steps / statistics.median(times),
            }
            rows.append(row)
            if on_row is not None:
                on_row({"case": case, "rows": rows, "reference_l1": ref_err, "sweep": dataclasses.asdict(cfg)})
            log(
                f"[{case}] {method:11s} n={n:>7d}  L1={row['l1_mean']:.4f} [{row['l1_min']:.4f}, {row['l1_max']:.4f}]"
                f"  time={row['time_s']:.3f}s  compile={row['compile_s']:.1f}s"
            )
    for n_x, n_v in cfg.pi_grids:
        settings = PathIntegration(n_x=n_x, n_v=n_v, tau=cfg.pi_tau)
        res, (median, compile_s) = timed_path_integration(base, settings, repeats=cfg.repeats)
        err = pdf_error(res, refs)
        steps = round((base.t_end - settings.t0) / settings.tau)
        row = {
            "case": case,
            "method": "path_integration",
            "n_paths": n_x * n_v,
            "l1_mean": err,
            "l1_min": err,
            "l1_max": err,
            "replicates": 1,
            "time_s": median,
            "compile_s": compile_s,
            "path_steps_per_s": n_x * n_v * steps / median,
        }
        rows.append(row)
        if on_row is not None:
            on_row({"case": case, "rows": rows, "reference_l1": ref_err, "sweep": dataclasses.asdict(cfg)})
        log(f"[{case}] path_int.   {n_x}x{n_v}  L1={err:.2e}  time={median:.3f}s  compile={compile_s:.1f}s")
    return {"case": case, "rows": rows, "reference_l1": ref_err, "sweep": dataclasses.asdict(cfg)}


def write(results: list[dict], out: pathlib.Path) -> list[str]:
    """Write ``accuracy.json`` (the record and the ``cases``), ``accuracy.csv`` and ``accuracy.png`` (error against
    time, log-log) to ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    protocol = timing_protocol(f"{results[0]['sweep']['repeats']} (once for the largest runs)" if results else 0)
    (out / "accuracy.json").write_text(json.dumps({"record": record(protocol), "cases": results}, indent=2))
    keys = [
        "case",
        "method",
        "n_paths",
        "l1_mean",
        "l1_min",
        "l1_max",
        "replicates",
        "time_s",
        "compile_s",
        "path_steps_per_s",
    ]
    lines = [",".join(keys)] + [",".join(str(r[k]) for k in keys) for res in results for r in res["rows"]]
    (out / "accuracy.csv").write_text("\n".join(lines) + "\n")
    fig, axes = plt.subplots(1, len(results), figsize=(5.5 * len(results), 4.2), squeeze=False)
    for ax, res in zip(axes[0], results, strict=True):
        for method, style in (("dpim", "ro-"), ("monte_carlo", "ks-"), ("path_integration", "b^-")):
            rows = [r for r in res["rows"] if r["method"] == method]
            t = [r["time_s"] for r in rows]
            ax.errorbar(
                t,
                [r["l1_mean"] for r in rows],
                yerr=[[r["l1_mean"] - r["l1_min"] for r in rows], [r["l1_max"] - r["l1_mean"] for r in rows]],
                fmt=style,
                capsize=2,
                label={"dpim": "DPIM", "monte_carlo": "MCS", "path_integration": "path integration (grid nodes)"}[
                    method
                ],
            )
            for r in rows:
                ax.annotate(
                    f"{r['n_paths']:g}",
                    (r["time_s"], r["l1_mean"]),
                    fontsize=6,
                    xytext=(3, 3),
                    textcoords="offset points",
                )
        if res["reference_l1"]:
            ax.axhline(res["reference_l1"], color="0.6", ls=":", label="bound on the reference's error")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("warm wall time, median (s)")
        ax.set_ylabel("L1 error of marginal PDFs (mean over x, x', times)")
        ax.set_title(f"{res['case']}: t_end = {res['sweep']['t_end']:g} s, dt = {res['sweep']['dt']:g} s")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "accuracy.png", dpi=120)
    plt.close(fig)
    return ["accuracy.json", "accuracy.csv", "accuracy.png"]
