"""Monte Carlo forcing: the spectral representation against Gaussian values drawn inside the steps.

Scene: the reference oscillator (alpha = gamma = 0.03, r = 0.98, D = 0.03) from rest, densities at ``t_end``.
Reference: path integration on the fine grid of ``jdpim.bench.accuracy`` (``REFERENCE``), whose own error
(its distance to the default grid) is reported. For each forcing (``SpectralRepresentation()``,
``GaussianNodes()``) and each step dt in (0.02, 0.01, 0.005): Monte Carlo with the same number of paths,
the weak error of ``E[x^2]`` and ``E[v^2]`` in units of its standard error, the mean L1 distance of the
``x`` and ``v`` marginals (at the sampling level of the run), and the warm wall time (``timing.timed``).
"""

from __future__ import annotations

import json
import pathlib

import numpy as np

from .._excitation import GaussianNodes, SpectralRepresentation
from .._models import VibroImpactOscillator
from .._noise import WhiteNoise
from .._scene import Scene
from ..methods._path_integration import path_integration
from .accuracy import REFERENCE, path_integration_reference, pdf_error
from .record import record, record_lines
from .timing import protocol, timed

DTS = (0.02, 0.01, 0.005)
FORCINGS = {"spectral": SpectralRepresentation(), "nodes": GaussianNodes()}


def _scene(t_end: float, dt: float, excitation) -> Scene:
    model = VibroImpactOscillator(alpha=0.03, gamma=0.03, r=0.98)
    return Scene(model, noise=WhiteNoise(D=0.03), t_end=t_end, dt=dt, excitation=excitation)


def _moment(states, k: int) -> tuple[float, float]:
    y = np.asarray(states[:, -1, k], float) ** 2
    return float(np.mean(y)), float(np.std(y) / np.sqrt(y.size))


def run_forcing(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    """The table; ``quick``: t_end 10 s and 2e4 paths (else 20 s and 1e5)."""
    t_end, n = (10.0, 20_000) if quick else (20.0, 100_000)
    base = _scene(t_end, 0.01, SpectralRepresentation())
    refs, ref_l1 = path_integration_reference(base)
    ref = path_integration(base, REFERENCE)
    exact = {k: float(ref.moment(v, 2, t_end)) for k, v in ((0, "x"), (1, "v"))}
    log(f"reference: path integration, E[x^2] = {exact[0]:.5f}, E[v^2] = {exact[1]:.5f}, own L1 <= {ref_l1:.1e}")
    rows = []
    for dt in DTS:
        for name, forcing in FORCINGS.items():
            res, timing = timed("monte_carlo", _scene(t_end, dt, forcing), n, seed=1, repeats=1)
            row = {"forcing": name, "dt": dt, "n_paths": n, "median_s": round(timing.median_s, 3)}
            for k, var in ((0, "x"), (1, "v")):
                m, se = _moment(res.states, k)
                row[f"E[{var}^2]"] = round(m, 5)
                row[f"err_{var}_se"] = round((m - exact[k]) / se, 2)
                row[f"rel_err_{var}"] = round(m / exact[k] - 1.0, 4)
            row["L1"] = round(pdf_error(res, refs), 4)
            rows.append(row)
            log(str(row))
    out.mkdir(parents=True, exist_ok=True)
    stem = "forcing_quick" if quick else "forcing"
    summary = {
        "record": record(protocol(1)),
        "t_end": t_end,
        "reference": {"E[x^2]": exact[0], "E[v^2]": exact[1], "own_L1": ref_l1},
        "rows": rows,
    }
    (out / f"{stem}.json").write_text(json.dumps(summary, indent=1))
    keys = list(rows[0])
    lines = [
        *record_lines(summary["record"]),
        f"Monte Carlo forcing at t = {t_end:g} s, {n} paths: weak error against path integration "
        f"(E[x^2] = {exact[0]:.5f}, E[v^2] = {exact[1]:.5f}; its own L1 error <= {ref_l1:.1e})",
        "",
        "| " + " | ".join(keys) + " |",
        "|" + "---|" * len(keys),
    ]
    lines += ["| " + " | ".join(str(r[k]) for k in keys) + " |" for r in rows]
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
    return [f"{stem}.json", f"{stem}.md"]
