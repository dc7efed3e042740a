"""Run a scene file: the named methods, the densities it asks for, stored as ``.npz`` + JSON + CSV + figures."""

from __future__ import annotations

import pathlib

import numpy as np

from . import report
from ._scenefile import SceneFile

# the timing table of a scene-file run: a row per method, the wall and CPU time of ``jdpim.solve``
TIMING_COLUMNS = (
    ("method", "{method}", "l"),
    ("paths", "{paths}", "r"),
    ("steps", "{steps}", "r"),
    ("wall (s)", "{wall_s:.2f}", "r"),
    ("CPU (s)", "{cpu_s:.2f}", "r"),
)


def run(sf: SceneFile, out: pathlib.Path, *, progress: bool = True, log=print) -> dict:
    """Run every method of ``sf``, write ``<stem>.npz``, ``<stem>.json``, ``<stem>_timing.csv`` and figures to ``out``.

    The marginals of ``sf.outputs.marginals`` and the joint densities of the pairs ``sf.outputs.joint`` are
    taken at every saved time on common grids (``report.grids``; a joint density on every second node).
    Returns the metadata also written to the JSON file (parameters, versions, wall time per method in s,
    compilation included, array shapes, file names).
    """
    scene, stem, outputs = sf.scene, sf.path.stem, sf.outputs
    out.mkdir(parents=True, exist_ok=True)
    results, timings, rows = {}, {}, []
    for m in sf.methods:
        what = f"{m.name}: {m.n_paths} paths, {scene.n_steps} steps of {scene.dt:g} s"
        results[m.name], wall, cpu = report.solve_timed(scene, m.method(progress=progress), log, what)
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
    marginal_grids = {c: full[c] for c in used if c in outputs.marginals}
    joints = {pair: (half[pair[0]], half[pair[1]]) for pair in outputs.joint}
    arrays |= report.densities(results, scene.save_at, marginal_grids, joints, joint_times=scene.save_at)
    for name, res in results.items():
        if outputs.states:
            arrays[f"{name}_states"], arrays[f"{name}_weights"] = np.asarray(res.states), np.asarray(res.weights)
        arrays[f"{name}_nonfinite"] = np.asarray(res.n_nonfinite())
    files = [f"{stem}.npz", f"{stem}_timing.csv"]
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
        "arrays": {k: list(v.shape) for k, v in arrays.items()},
        "files": files + [f"{stem}.json"],
    }
    report.write_json(out / f"{stem}.json", meta)
    log(f"wrote {', '.join(meta['files'])} to {out}/")
    return meta
