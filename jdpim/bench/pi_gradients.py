"""Path-integration derivatives: ``jax.grad`` (one adjoint solve) against ``jax.jacfwd`` (one tangent solve per
parameter) through the stationary density, over a matrix of scenes, grids and weights.

Functional: ``f = p_x(0.3) + p_x(0.8)`` of the stationary density of the reference oscillator (alpha = 0.06),
float64, differentiated with respect to (alpha, gamma, r, D); gamma only where gamma > 0 (at gamma = 0 the
derivative is one-sided). Matrix: gamma in {0, 0.02, 0.04}, D in {0.03, 0.05}, r in {0.15, 0.6, 0.95}, extents
``default`` (estimated from the nominal scene, then fixed) and ``narrow`` (0.8 times those), order 2 and 4, plus
the cell alpha = 0.06, gamma = 0.04, r = 0.95, D = 0.04, x_max = v_max = 4.5, order 4, on 121 x 241 nodes;
``quick``: 17 cells in which every value of every axis appears, and the extra cell, on 81 x 161 nodes. The full
matrix runs in covering order (``covering_order``): every value of every axis within its first 4 cells, every pair
of values of two axes within its first 9, so that a run cut short still covers the matrix.
Per cell: the largest relative difference ``|grad - jacfwd| / |jacfwd|`` over the parameters, whether any
derivative is not finite, and the warnings raised; in the first ``central`` cells also central differences
(step ``H`` in each parameter, one compiled forward solve) against ``jax.jacfwd``.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
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
AXES = ((0.0, 0.02, 0.04), (0.03, 0.05), (0.15, 0.6, 0.95), ("default", "narrow"), (2, 4))
H = 1e-4  # central-difference step in every parameter


def covering_order(cells) -> tuple:
    """``cells`` reordered greedily: each next cell covers the most combinations of values of two axes not yet
    covered, then of three, then of four (ties: first in ``cells``), so that every prefix of the order spreads
    over the values of every axis and over their pairs."""
    subsets = lambda c, k: set(itertools.combinations(enumerate(c), k))  # noqa: E731
    left, covered, order = list(cells), set(), []
    while left:
        best = max(left, key=lambda c: tuple(len(subsets(c, k) - covered) for k in (2, 3, 4)))
        left.remove(best)
        covered |= set().union(*(subsets(best, k) for k in (2, 3, 4)))
        order.append(best)
    return tuple(order)


@dataclasses.dataclass(frozen=True)
class Plan:
    cells: tuple  # (gamma, D, r, extents, order): extents "default", "narrow" or (x_max, v_max)
    n_x: int = 121
    n_v: int = 241


FULL = Plan((*covering_order(itertools.product(*AXES)), *EXTRA))
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


def _row(plan: Plan, gamma, D, r, extents, order, central: bool = False) -> dict:
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
    used = [i for i, name in enumerate(NAMES) if name != "gamma" or gamma > 0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rev, fwd = (np.asarray(d) for d in jax.jit(lambda p: (jax.grad(f)(p), jax.jacfwd(f)(p)))(jnp.asarray(theta)))
        fd = _central(jax.jit(f), theta, used) if central else None
    rel = np.abs(rev - fwd)[used] / np.abs(fwd)[used]
    rel_fd = None if fd is None else np.abs(fd - fwd)[used] / np.abs(fwd)[used]
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
        "central": None if fd is None else fd.tolist(),
        "max_rel_diff_central": None if rel_fd is None or not np.all(np.isfinite(rel_fd)) else float(np.max(rel_fd)),
        "finite": bool(np.all(np.isfinite(rev)) and np.all(np.isfinite(fwd))),
        "warnings": sorted({str(w.message)[:100] for w in caught}),
        "seconds": time.perf_counter() - t0,
    }


def _central(f, theta, used) -> np.ndarray:
    """Central differences of ``f`` at ``theta`` (step ``H``) in the parameters ``used``; NaN in the others."""
    out = np.full(theta.size, np.nan)
    for i in used:
        e = np.zeros(theta.size)
        e[i] = H
        out[i] = (float(f(jnp.asarray(theta + e))) - float(f(jnp.asarray(theta - e)))) / (2 * H)
    return out


def _key(row: dict) -> tuple:
    extents = row["extents"] if row["extents"] != "fixed" else (row["x_max"], row["v_max"])
    return (row["gamma"], row["D"], row["r"], extents, row["order"])


def run_pi_gradients(
    out: pathlib.Path, *, quick: bool = False, central: int = 3, resume: bool = False, log=print
) -> list[str]:
    """Run the matrix and write ``pi_gradients[_quick].json`` and ``.md`` to ``out`` after every cell; returns the
    file names. ``central``: how many cells (the first) also get central differences; ``resume``: keep the rows of
    cells already in ``out``'s record (same nodes) and run only the others."""
    plan = QUICK if quick else FULL
    rows = []
    out.mkdir(parents=True, exist_ok=True)
    stem = "pi_gradients_quick" if quick else "pi_gradients"
    if resume and (out / f"{stem}.json").exists():
        old = json.loads((out / f"{stem}.json").read_text())
        if (old["settings"]["n_x"], old["settings"]["n_v"]) == (plan.n_x, plan.n_v):
            rows = [r for r in old["rows"] if _key(r) in {tuple(c) for c in plan.cells}]
            log(f"resuming: {len(rows)} cells kept")
    done = {_key(r) for r in rows}
    with jax.enable_x64(True):
        for k, cell in enumerate(plan.cells):
            if tuple(cell) in done:
                continue
            rows.append(_row(plan, *cell, central=k < central))
            log(json.dumps(rows[-1]))
            _write(out, stem, plan, rows)
    return [f"{stem}.json", f"{stem}.md"]


PROTOCOL = (
    "per cell one jitted program gives jax.grad and jax.jacfwd of f in float64 (central differences: one jitted f); "
    "no timing: the record is of accuracy"
)


def _worst(rows: list, field: str = "max_rel_diff") -> str:
    """The largest ``field`` over ``rows`` ("not finite" if any is missing, "-" if none has it)."""
    values = [r[field] for r in rows if field != "max_rel_diff_central" or r["central"] is not None]
    if not values:
        return "-"
    return "not finite" if any(v is None for v in values) else f"{max(values):.1e}"


def _write(out: pathlib.Path, stem: str, plan: Plan, rows: list) -> None:
    flags = os.environ.get("XLA_FLAGS")
    rec = record(PROTOCOL + (f"; XLA_FLAGS={flags}" if flags else ""))
    settings = {"alpha": ALPHA, "n_x": plan.n_x, "n_v": plan.n_v, "h": H}
    (out / f"{stem}.json").write_text(json.dumps({"record": rec, "settings": settings, "rows": rows}, indent=1))
    lines = [
        f"# Path-integration derivatives: grad against jacfwd ({plan.n_x} x {plan.n_v} nodes)",
        "",
        *record_lines(rec),
        f"f = p_x(0.3) + p_x(0.8), stationary, alpha = {ALPHA}, float64; largest relative difference over "
        f"(alpha, gamma if > 0, r, D). Cells run: {len(rows)} of {len(plan.cells)} (in the plan's order), not "
        f"finite: {sum(not r['finite'] for r in rows)}, worst grad against jacfwd: {_worst(rows)}; central "
        f"differences (step {H:g}) against jacfwd in {sum(r['central'] is not None for r in rows)} cells, worst: "
        f"{_worst(rows, 'max_rel_diff_central')}.",
        "",
        "Worst cell per value of each axis (cells run):",
        "",
        "| axis | value | cells | worst grad vs jacfwd |",
        "|---|---|---|---|",
    ]
    for name, values in zip(("gamma", "D", "r", "extents", "order"), AXES, strict=True):
        for value in values:
            some = [r for r in rows if r[name] == value]
            shown = value if isinstance(value, str) else f"{value:g}"
            lines.append(f"| {name} | {shown} | {len(some)} | {_worst(some)} |")
    lines += [
        "",
        "| gamma | D | r | extents | x_max = v_max | order | grad vs jacfwd | central vs jacfwd | warnings |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        diff = "not finite" if r["max_rel_diff"] is None else f"{r['max_rel_diff']:.0e}"
        fd = "-" if r["central"] is None else _worst([r], "max_rel_diff_central")
        warned = "; ".join(r["warnings"]) or "-"
        lines.append(
            f"| {r['gamma']:g} | {r['D']:g} | {r['r']:g} | {r['extents']} | {r['x_max']:.2f} | {r['order']} | "
            f"{diff} | {fd} | {warned} |"
        )
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n")
