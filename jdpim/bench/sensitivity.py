"""Sensitivity estimators: error against exact derivatives versus cost, per estimator and horizon.

Case: r = 1, gamma = 0 (the linear oscillator mirrored at the barrier), alpha = D = 0.05, start at rest on
the barrier, dt = 0.02, Monte Carlo paths for the sampling estimators; path integration (``jax.jacfwd``
through ``jdpim.path_integration``, no sampling error) on two grids. The exact PDF at time t is the folded
Gaussian with the variance of ``jdpim.exact.linear_covariance``; smoothed with the reflected kernel of fixed
width h = 0.1 it stays a folded Gaussian (variance + h^2), so ``dp/dalpha`` and ``dp/dD`` of the smoothed
density are closed-form. Error: relative L2 over x in [0, 3]; ``stderr``: the estimator's own standard error, same norm.
Protocol: one warm-up call (compilation), then ``repeats`` timed calls, median wall time.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import statistics
import time
import warnings

import numpy as np

from .. import exact
from .._models import VibroImpactOscillator
from .._noise import WhiteNoise
from .._scene import Scene
from ..methods._monte_carlo import MonteCarlo
from ..methods._path_integration import PathIntegration
from ..sensitivities._estimators import CentralDifference, LikelihoodRatio, NoiseScaling, Pathwise, SensitivityWarning
from ..sensitivities._sensitivity import sensitivity
from .record import record, record_lines

ALPHA, D, DT, H = 0.05, 0.05, 0.02, 0.1
XS = np.linspace(0.0, 3.0, 61)


@dataclasses.dataclass(frozen=True)
class Plan:
    horizons: tuple = (20.0, 200.0)
    paths: tuple = (10_000, 100_000)
    pathwise_paths: int = 1000
    repeats: int = 3
    grids: tuple = (PathIntegration(n_x=61, n_v=121, tau=0.1), PathIntegration())


QUICK = Plan(horizons=(10.0, 50.0), paths=(2000, 8000), pathwise_paths=500, repeats=1)


def _reference(name: str, t: float) -> np.ndarray:
    def smoothed(a, d):
        s2 = float(exact.linear_covariance(a, d, t)[0]) + H**2
        return 2 * np.exp(-0.5 * XS**2 / s2) / np.sqrt(2 * np.pi * s2)

    e = 1e-6
    if name == "alpha":
        return (smoothed(ALPHA + e, D) - smoothed(ALPHA - e, D)) / (2 * e)
    return (smoothed(ALPHA, D + e) - smoothed(ALPHA, D - e)) / (2 * e)


def _row(t, name, estimator, n, repeats):
    scene = Scene(VibroImpactOscillator(alpha=ALPHA, gamma=None, r=1.0), noise=WhiteNoise(D=D), t_end=t, dt=DT)
    if isinstance(estimator, PathIntegration):
        kwargs = {"method": estimator}
        label = f"PathIntegration {estimator.n_x}x{estimator.n_v}, tau {estimator.tau:g}"
    else:
        kwargs = {"method": MonteCarlo(n_samples=n), "estimator": estimator}
        label = type(estimator).__name__

    def call():
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SensitivityWarning)
            out = sensitivity(scene, (name,), "x", XS, bandwidth=H, **kwargs)
            np.asarray(out[name])
        return out, [str(w.message)[:60] for w in caught if issubclass(w.category, SensitivityWarning)]

    t0 = time.perf_counter()
    call()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out, warned = call()
        times.append(time.perf_counter() - t0)
    ref = _reference(name, t)
    value, err = np.asarray(out[name], float), np.asarray(out.value_stderr[name], float)
    scale = np.linalg.norm(ref)
    return {
        "t": t,
        "parameter": name,
        "estimator": label,
        "paths": n,
        "rel_l2_error": float(np.linalg.norm(value - ref) / scale),
        "rel_stderr": float(np.linalg.norm(err) / scale) if np.all(np.isfinite(err)) and n else None,
        "first_call_s": first,
        "median_s": statistics.median(times),
        "warned": bool(warned),
    }


def run_sensitivity(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    """Run the plan and write ``sensitivity[_quick].json`` and ``.md`` to ``out``; returns the file names."""
    plan = QUICK if quick else Plan()
    rows = []
    for t in plan.horizons:
        cases = [(name, grid, 0) for grid in plan.grids for name in ("alpha", "D")]
        cases += [("alpha", Pathwise(), plan.pathwise_paths)]
        for n in plan.paths:
            cases += [("alpha", LikelihoodRatio(), n), ("alpha", CentralDifference(), n), ("D", NoiseScaling(), n)]
        for name, est, n in cases:
            rows.append(_row(t, name, est, n, plan.repeats))
            log(json.dumps(rows[-1]))
    out.mkdir(parents=True, exist_ok=True)
    stem = "sensitivity_quick" if quick else "sensitivity"
    rec = record(f"one warm-up call (compilation), then {plan.repeats} timed calls, the median wall time")
    meta = {"alpha": ALPHA, "D": D, "dt": DT, "bandwidth": H}
    (out / f"{stem}.json").write_text(json.dumps({"record": rec, "meta": meta, "rows": rows}, indent=1))
    lines = [
        f"# Sensitivity estimators{' (quick)' if quick else ''}",
        "",
        *record_lines(rec),
        f"r = 1, gamma = 0, alpha = D = {ALPHA}, dt = {DT}, h = {H}; Monte Carlo paths for the sampling estimators, "
        "path integration (no paths, no sampling error) on two grids.",
        "",
        "| t | parameter | estimator | paths | rel. L2 error | rel. stderr | first call s | median s | warned |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        se = "-" if r["rel_stderr"] is None else f"{r['rel_stderr']:.3f}"
        lines.append(
            f"| {r['t']:g} | {r['parameter']} | {r['estimator']} | {r['paths'] or '-'} | {r['rel_l2_error']:.3g} | "
            f"{se} | "
            f"{r['first_call_s']:.1f} | {r['median_s']:.1f} | {'yes' if r['warned'] else 'no'} |"
        )
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    return [f"{stem}.json", f"{stem}.md"]
