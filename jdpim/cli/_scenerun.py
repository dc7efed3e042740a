"""Run a scene file: the named methods, the densities it asks for, stored as ``.npz`` + JSON + CSV + figures
(and each method's result, ``result.save``, with ``states = true``); with a ``[reliability]`` table also
first-passage probabilities, with a ``[fragility]`` table a fragility curve (``.npz`` + Markdown)."""

from __future__ import annotations

import functools
import pathlib

import numpy as np

from .. import _report as report
from ._scenefile import SceneFile

# the timing table of a scene-file run: a row per method, the wall and CPU time of ``jdpim.solve``
TIMING_COLUMNS = (
    ("method", "{method}", "l"),
    ("paths", "{paths}", "r"),
    ("steps", "{steps}", "r"),
    ("wall (s)", "{wall_s:.2f}", "r"),
    ("CPU (s)", "{cpu_s:.2f}", "r"),
)


def first_passage(sf: SceneFile, *, progress: bool = True, log=print) -> tuple[dict, str, dict]:
    """``jdpim.first_passage`` of ``sf.reliability`` by every method of ``sf`` at the scene's saved times.

    Returns ``(arrays, tables, wall_s)``: ``first_passage_levels`` ``(L,)`` and, per method,
    ``first_passage_<method>_probability``, ``_lost_mass`` and (Monte Carlo) ``_stderr``, each ``(S, L)``;
    a Markdown table per method (rows: saved times, columns: levels); the wall time per method in s.
    """
    import jdpim

    rel, scene = sf.reliability, sf.scene
    arrays, tables, wall = {"first_passage_levels": np.asarray(rel.levels)}, [], {}
    title = f"P(max over [0, t] of {rel.quantity} > level)"
    for m in sf.methods:
        fp, wall_s, _ = report.timed(
            functools.partial(jdpim.first_passage, scene, rel.quantity, rel.levels, m.method(progress=progress)),
            log,
            f"{m.name}: first passage of {rel.quantity}, {len(rel.levels)} level(s)",
        )
        wall[m.name] = round(wall_s, 3)
        key = f"first_passage_{m.name}"
        arrays[f"{key}_probability"], arrays[f"{key}_lost_mass"] = np.asarray(fp.probability), np.asarray(fp.lost_mass)
        if fp.probability_stderr is not None:
            arrays[f"{key}_stderr"] = np.asarray(fp.probability_stderr)
        se = fp.probability_stderr
        table = report.probability_table(scene.save_at, rel.levels, fp.probability, se, str(rel.quantity))
        tables.append(f"{report.NAME[m.name]} ({m.n_paths} paths): {title}\n\n{table}")
    return arrays, "\n\n".join(tables), wall


# the fragility table of a scene-file run: a row per intensity
FRAGILITY_COLUMNS = (
    ("intensity", "{s:.4g}", "r"),
    ("P(exceed)", "{p:.4g}", "r"),
    ("stderr", "{se:.2g}", "r"),
    ("interval", "[{lo:.4g}, {hi:.4g}]", "r"),
    ("lognormal fit", "{fit:.4g}", "r"),
)
FRAGILITY_FIELDS = (
    "intensities", "probability", "probability_stderr", "lower", "upper",
    "median", "median_stderr", "beta", "beta_stderr", "covariance", "fit_p_value", "n_evaluations",
)  # fmt: skip


def fragility(sf: SceneFile, *, progress: bool = True, log=print) -> tuple[dict, str, float]:
    """``jdpim.fragility`` of ``sf.fragility`` by the Monte Carlo method of ``sf``.

    Returns ``(arrays, table, wall_s)``: ``fragility_<field>`` for the fields of ``jdpim.Fragility`` (intensities,
    probabilities with standard errors and intervals, the lognormal fit with its standard errors and covariance),
    a Markdown table (a row per intensity, the fit under it) and the wall time in s.
    """
    import jdpim

    fr, m = sf.fragility, next(m for m in sf.methods if m.name == "monte_carlo")
    curve, wall_s, _ = report.timed(
        functools.partial(
            jdpim.fragility,
            sf.scene,
            fr.quantity,
            fr.level,
            fr.intensities,
            m.method(progress=progress),
            reference=fr.reference,
            confidence=fr.confidence,
        ),
        log,
        f"fragility of {fr.quantity} above {fr.level:g}: {len(fr.intensities)} intensities of {m.n_paths} paths",
    )
    arrays = {f"fragility_{k}": np.asarray(getattr(curve, k)) for k in FRAGILITY_FIELDS}
    fit, _ = curve.fitted(np.asarray(fr.intensities))
    rows = [
        {"s": s, "p": p, "se": se, "lo": lo, "hi": hi, "fit": f}
        for s, p, se, lo, hi, f in zip(
            fr.intensities,
            *(
                np.asarray(a).tolist()
                for a in (curve.probability, curve.probability_stderr, curve.lower, curve.upper, fit)
            ),
            strict=True,
        )
    ]
    table = (
        f"P(max over [0, {sf.scene.save_at[-1]:g}] of {fr.quantity} > {fr.level:g}) by Monte Carlo ({m.n_paths} paths "
        f"per intensity, {fr.confidence:g} intervals)\n\n{report.markdown(rows, FRAGILITY_COLUMNS)}\n\n"
        f"lognormal fit: median {float(curve.median):.4g} +- {float(curve.median_stderr):.2g}, "
        f"beta {float(curve.beta):.4g} +- {float(curve.beta_stderr):.2g} (goodness of fit: p = "
        f"{float(curve.fit_p_value):.2g})"
    )
    return arrays, table, round(wall_s, 3)


def run(sf: SceneFile, out: pathlib.Path, *, progress: bool = True, log=print) -> dict:
    """Run every method of ``sf``, write ``<stem>.npz``, ``<stem>.json``, ``<stem>_timing.csv`` and figures to ``out``.

    The marginals of ``sf.outputs.marginals`` and of the derived quantities ``sf.outputs.derived`` and the joint
    densities of the pairs ``sf.outputs.joint`` are taken at every saved time on common grids (``report.grids``,
    ``report.quantity_grids``; a joint density on every second node). With ``sf.outputs.states`` every method's
    result goes to ``<stem>_<method>.npz`` (``result.save``, with the scene and the method; ``jdpim.load`` reads it).
    With ``sf.reliability``, the :func:`first_passage` arrays go to the same ``.npz`` and its tables to
    ``<stem>_first_passage.md`` (and the log); with ``sf.fragility`` likewise :func:`fragility`'s, to
    ``<stem>_fragility.md``. Returns the metadata also written to the JSON file (parameters,
    versions, wall time per method in s, compilation included, array shapes, file names).
    """
    scene, stem, outputs = sf.scene, sf.path.stem, sf.outputs
    out.mkdir(parents=True, exist_ok=True)
    results, methods, timings, rows = {}, {}, {}, []
    for m in sf.methods:
        what = f"{m.name}: {m.n_paths} paths, {scene.n_steps} steps of {scene.dt:g} s"
        methods[m.name] = m.method(progress=progress)
        results[m.name], wall, cpu = report.solve_timed(scene, methods[m.name], log, what)
        timings[m.name] = round(wall, 3)
        row = {"method": m.name, "paths": m.n_paths, "steps": scene.n_steps}
        rows.append(row | {"wall_s": round(wall, 3), "cpu_s": round(cpu, 3)})
    log(report.markdown(rows, TIMING_COLUMNS))
    # the coordinates with a marginal or in a joint density, in the model's order
    paired = {c for pair in outputs.joint for c in pair}
    used = [c for c in scene.model.coordinates if c in outputs.marginals or c in paired]
    full = report.grids(scene, results.values(), outputs.n_grid, used)
    half = {c: g[::2] for c, g in full.items()}  # joint densities: every second node
    arrays = {"times": np.asarray(scene.save_at)}
    arrays |= {f"{c}_grid": full[c] if c in outputs.marginals else half[c] for c in used}
    arrays |= {f"{c}_grid_joint": half[c] for c in used if c in paired}
    derived = {str(quantity): quantity for quantity in outputs.derived}
    derived_grids = report.quantity_grids(results.values(), derived, scene.save_at, outputs.n_grid)
    arrays |= {f"{name}_grid": g for name, g in derived_grids.items()}
    marginal_grids = {c: full[c] for c in used if c in outputs.marginals} | derived_grids
    joints = {pair: (half[pair[0]], half[pair[1]]) for pair in outputs.joint}
    arrays |= report.densities(
        results, scene.save_at, marginal_grids, joints, joint_times=scene.save_at, quantities=derived
    )
    files = [f"{stem}.npz", f"{stem}_timing.csv"]
    for name, res in results.items():
        arrays[f"{name}_nonfinite"] = np.asarray(res.n_nonfinite())
        if outputs.states:  # the whole result, which jdpim.load reads back with the scene and the method
            files.append(f"{stem}_{name}.npz")
            res.save(out / files[-1], scene=scene, method=methods[name])
    if sf.reliability is not None:
        fp_arrays, fp_tables, fp_wall = first_passage(sf, progress=progress, log=log)
        arrays |= fp_arrays
        log(report.terminal(fp_tables))
        files.append(f"{stem}_first_passage.md")
        (out / files[-1]).write_text(f"# {sf.path.name}: first passage\n\n{fp_tables}\n")
    if sf.fragility is not None:
        fr_arrays, fr_table, fr_wall = fragility(sf, progress=progress, log=log)
        arrays |= fr_arrays
        log(report.terminal(fr_table))
        files.append(f"{stem}_fragility.md")
        (out / files[-1]).write_text(f"# {sf.path.name}: fragility\n\n{fr_table}\n")
    np.savez_compressed(out / files[0], **arrays)
    report.write_csv(
        out / files[1], rows, f"{sf.path.name}: wall and CPU time of jdpim.solve in s, compilation included"
    )
    if outputs.figures:
        labels = report.labels(results)
        files += report.draw(scene, arrays, marginal_grids, labels, out, prefix=f"{stem}_", joints=joints)
    meta = {
        "scene_file": str(sf.path),
        "parameters": sf.table,
        "versions": report.versions(),
        "wall_time_s": timings,
        **({} if sf.reliability is None else {"first_passage_wall_time_s": fp_wall}),
        **({} if sf.fragility is None else {"fragility_wall_time_s": fr_wall}),
        "arrays": {k: list(v.shape) for k, v in arrays.items()},
        "files": files + [f"{stem}.json"],
    }
    report.write_json(out / f"{stem}.json", meta)
    log(f"wrote {', '.join(meta['files'])} to {out}/")
    return meta
