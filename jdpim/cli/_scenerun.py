"""Run a scene file: the named methods, the densities it asks for, stored as ``.npz`` + JSON + figures."""

from __future__ import annotations

import pathlib

import numpy as np

from . import report
from ._scenefile import SceneFile


def run(sf: SceneFile, out: pathlib.Path, *, progress: bool = True, log=print) -> dict:
    """Run every method of ``sf``, write ``<stem>.npz``, ``<stem>.json`` and figures to ``out``.

    Returns the metadata also written to the JSON file (parameters, versions, wall time per method in s,
    compilation included, array shapes, file names).
    """
    scene, stem, asked = sf.scene, sf.path.stem, sf.outputs.densities
    out.mkdir(parents=True, exist_ok=True)
    results, timings = {}, {}
    for m in sf.methods:
        what = f"{m.name}: {m.n_paths} paths, {scene.n_steps} steps of {scene.dt:g} s"
        results[m.name], wall, _ = report.solve_timed(scene, m.method(progress=progress), log, what)
        timings[m.name] = round(wall, 3)
    xg, vg = report.grids(scene, results.values(), sf.outputs.n_grid)
    xj, vj = xg[::2], vg[::2]
    arrays = {"times": np.asarray(scene.save_at)}
    if {"x", "joint"} & set(asked):
        arrays["x_grid"] = xg if "x" in asked else xj
    if {"v", "joint"} & set(asked):
        arrays["v_grid"] = vg if "v" in asked else vj
    if "joint" in asked:
        arrays["x_grid_joint"], arrays["v_grid_joint"] = xj, vj
    marginal_grids = {var: g for var, g in (("x", xg), ("v", vg)) if var in asked}
    joint = {"joint_grids": (xj, vj)} if "joint" in asked else {}
    arrays |= report.densities(results, scene.save_at, marginal_grids, **joint, joint_times=scene.save_at)
    for name, res in results.items():
        if sf.outputs.states:
            arrays[f"{name}_states"], arrays[f"{name}_weights"] = np.asarray(res.states), np.asarray(res.weights)
        arrays[f"{name}_nonfinite"] = np.asarray(res.n_nonfinite())
    files = [f"{stem}.npz"]
    np.savez_compressed(out / files[0], **arrays)
    if sf.outputs.figures:
        labels = report.labels(results)
        files += report.draw(scene, arrays, marginal_grids, labels, out, prefix=f"{stem}_", **joint)
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
