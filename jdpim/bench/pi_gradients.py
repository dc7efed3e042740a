"""Path-integration derivatives: ``jax.grad`` (one adjoint solve) against ``jax.jacfwd`` (one tangent solve per
parameter) through the stationary density, over a matrix of scenes, grids and weights.

Functional: ``f = p_x(0.3) + p_x(0.8)`` of the stationary density of the reference oscillator (alpha = 0.06),
float64, differentiated with respect to (alpha, gamma, r, D); gamma only where gamma > 0 (at gamma = 0 the
derivative is one-sided). Matrix: gamma in {0, 0.02, 0.04}, D in {0.03, 0.05}, r in {0.15, 0.6, 0.95}, extents
``default`` (estimated from the nominal scene, then fixed) and ``narrow`` (0.8 times those), order 2 and 4, plus
the cell alpha = 0.06, gamma = 0.04, r = 0.95, D = 0.04, x_max = v_max = 4.5, order 4, on 121 x 241 nodes;
``quick``: 17 cells in which every value of every axis appears, and the extra cell, on 81 x 161 nodes. Per cell:
the largest relative difference ``|grad - jacfwd| / |jacfwd|`` over the parameters, whether any derivative is
not finite, and the warnings raised.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import pathlib
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from .._models import VibroImpactOscillator
from .._noise import WhiteNoise
from .._scene import Scene
from ..methods._base import solve
from ..methods._path_integration import PathIntegration, default_extents
from .record import record, record_lines

ALPHA = 0.06
XS = (0.3, 0.8)
NAMES = ("alpha", "gamma", "r", "D")
NARROW = 0.8
EXTRA = ((0.04, 0.04, 0.95, (4.5, 4.5), 4),)  # (gamma, D, r, extents, order): the cell of the original report


@dataclasses.dataclass(frozen=True)
class Plan:
    cells: tuple  # (gamma, D, r, extents, order): extents "default", "narrow" or (x_max, v_max)
    n_x: int = 121
    n_v: int = 241


FULL = Plan(
    (*itertools.product((0.0, 0.02, 0.04), (0.03, 0.05), (0.15, 0.6, 0.95), ("default", "narrow"), (2, 4)), *EXTRA)
)
# every value of every axis in at least one cell, on 81 x 161 nodes (where the original cell stalled)
QUICK = Plan(
    (
        (0.0, 0.03, 0.15, "default", 2),
        (0.02, 0.05, 0.15, "narrow", 4),
        (0.04, 0.05, 0.15, "default", 4),
        (0.04, 0.03, 0.6, "narrow", 2),
        (0.0, 0.05, 0.6, "default", 4),
        (0.02, 0.03, 0.95, "default", 4),
        (0.04, 0.05, 0.95, "default", 2),
        (0.0, 0.03, 0.95, "narrow", 4),
        (0.0, 0.05, 0.15, "narrow", 4),
        (0.02, 0.03, 0.15, "default", 2),
        (0.04, 0.03, 0.15, "narrow", 2),
        (0.02, 0.05, 0.6, "default", 2),
        (0.02, 0.03, 0.6, "narrow", 4),
        (0.04, 0.05, 0.6, "default", 4),
        (0.04, 0.03, 0.95, "narrow", 4),
        (0.02, 0.05, 0.95, "narrow", 2),
        (0.0, 0.05, 0.95, "default", 2),
        *EXTRA,
    ),
    n_x=81,
    n_v=161,
)


def _scene(theta) -> Scene:
    alpha, gamma, r, D = theta
    model = VibroImpactOscillator(alpha=alpha, gamma=gamma, r=r)
    return Scene(model, noise=WhiteNoise(D=D), t_end=1.0, dt=0.01, dtype="float64")


def _row(plan: Plan, gamma, D, r, extents, order) -> dict:
    theta = np.array([ALPHA, gamma, r, D])
    if isinstance(extents, str):
        x_max, v_max = default_extents(_scene(theta), PathIntegration())
        if extents == "narrow":
            x_max, v_max = NARROW * x_max, NARROW * v_max
    else:
        x_max, v_max = extents
    settings = PathIntegration(n_x=plan.n_x, n_v=plan.n_v, x_max=x_max, v_max=v_max, order=order, stationary=True)

    def f(p):
        return jnp.sum(solve(_scene(p), settings).pdf("x", jnp.asarray(XS)))

    t0 = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rev = np.asarray(jax.jit(jax.grad(f))(jnp.asarray(theta)))
        fwd = np.asarray(jax.jit(jax.jacfwd(f))(jnp.asarray(theta)))
    used = [i for i, name in enumerate(NAMES) if name != "gamma" or gamma > 0]
    rel = np.abs(rev - fwd)[used] / np.abs(fwd)[used]
    return {
        "gamma": gamma,
        "D": D,
        "r": r,
        "extents": extents if isinstance(extents, str) else "fixed",
        "x_max": x_max,
        "v_max": v_max,
        "order": order,
        "grad": rev.tolist(),
        "jacfwd": fwd.tolist(),
        "max_rel_diff": float(np.max(rel)) if np.all(np.isfinite(rel)) else None,
        "finite": bool(np.all(np.isfinite(rev)) and np.all(np.isfinite(fwd))),
        "warnings": sorted({str(w.message)[:100] for w in caught}),
        "seconds": time.perf_counter() - t0,
    }


def run_pi_gradients(out: pathlib.Path, *, quick: bool = False, log=print) -> list[str]:
    """Run the matrix and write ``pi_gradients[_quick].json`` and ``.md`` to ``out``; returns the file names."""
    plan = QUICK if quick else FULL
    rows = []
    out.mkdir(parents=True, exist_ok=True)
    stem = "pi_gradients_quick" if quick else "pi_gradients"
    with jax.enable_x64(True):
        for cell in plan.cells:
            rows.append(_row(plan, *cell))
            log(json.dumps(rows[-1]))
            _write(out, stem, plan, rows)
    return [f"{stem}.json", f"{stem}.md"]


PROTOCOL = (
    "per cell one jitted program gives jax.grad and jax.jacfwd of f in float64; no timing: the record is of accuracy"
)


def _write(out: pathlib.Path, stem: str, plan: Plan, rows: list) -> None:
    rec = record(PROTOCOL)
    settings = {"alpha": ALPHA, "n_x": plan.n_x, "n_v": plan.n_v}
    (out / f"{stem}.json").write_text(json.dumps({"record": rec, "settings": settings, "rows": rows}, indent=1))
    worst = max((r["max_rel_diff"] for r in rows if r["max_rel_diff"] is not None), default=float("nan"))
    lines = [
        f"# Path-integration derivatives: grad against jacfwd ({plan.n_x} x {plan.n_v} nodes)",
        "",
        *record_lines(rec),
        f"f = p_x(0.3) + p_x(0.8), stationary, alpha = {ALPHA}, float64; largest relative difference over "
        f"(alpha, gamma if > 0, r, D). Cells: {len(rows)}, not finite: {sum(not r['finite'] for r in rows)}, "
        f"worst: {worst:.1e}.",
        "",
        "| gamma | D | r | extents | x_max = v_max | order | max rel. diff | warnings |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        diff = "not finite" if r["max_rel_diff"] is None else f"{r['max_rel_diff']:.0e}"
        warned = "; ".join(r["warnings"]) or "-"
        lines.append(
            f"| {r['gamma']:g} | {r['D']:g} | {r['r']:g} | {r['extents']} | {r['x_max']:.2f} | {r['order']} | "
            f"{diff} | {warned} |"
        )
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
