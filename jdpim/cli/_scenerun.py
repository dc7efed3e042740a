"""Run a scene file: the named methods, the densities it asks for, stored as ``.npz`` + JSON + figures."""

from __future__ import annotations

import json
import pathlib
import platform
import time

import numpy as np

from .. import figures
from ._scenefile import SceneFile


def versions() -> dict:
    """Versions of jdpim, JAX, NumPy and Python, and the JAX backend (for the metadata of every output)."""
    import jax

    import jdpim

    return {
        "jdpim": jdpim.__version__,
        "jax": jax.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "backend": jax.default_backend(),
        "devices": len(jax.devices()),
    }


def grids(results, barrier, n_grid: int, q: float = 0.999):
    """Displacement and velocity grids covering the central ``q`` of the mass at every saved time, all methods."""
    xs, vs = [], []
    for res in results:
        x, v = np.asarray(res.states[..., 0]), np.asarray(res.states[..., 1])
        w = np.broadcast_to(np.asarray(res.weights)[:, None], x.shape)
        xs.append(figures.mass_range(x, w, q=q, lower=barrier))
        vs.append(figures.mass_range(v, w, q=q))
    x_lo = barrier if barrier is not None else min(a for a, _ in xs)
    v_half = max(max(abs(a), abs(b)) for a, b in vs)
    return np.linspace(x_lo, max(b for _, b in xs), n_grid), np.linspace(-v_half, v_half, n_grid)


def run(sf: SceneFile, out: pathlib.Path, *, progress: bool = True, log=print) -> dict:
    """Run every method of ``sf``, write ``<stem>.npz``, ``<stem>.json`` and figures to ``out``.

    Returns the metadata also written to the JSON file (parameters, versions, timings, file names).
    """
    import jax

    import jdpim

    scene, stem = sf.scene, sf.path.stem
    out.mkdir(parents=True, exist_ok=True)
    results, timings = {}, {}
    for m in sf.methods:
        log(f"{m.name}: {m.n_paths} paths, {scene.n_steps} steps of {scene.dt:g} s ...")
        t0 = time.perf_counter()
        if m.name == "dpim":
            res = jdpim.dpim(scene, m.n_paths, progress=progress)
        else:
            res = jdpim.monte_carlo(scene, m.n_paths, seed=m.seed, progress=progress)
        jax.block_until_ready(res.states)
        timings[m.name] = round(time.perf_counter() - t0, 3)
        log(f"{m.name}: done in {timings[m.name]:.1f} s (compilation included)")
        results[m.name] = res
    barrier = scene.model.barrier if scene.model.has_barrier else None
    barrier = None if barrier is None else float(barrier)
    xg, vg = grids(results.values(), barrier, sf.outputs.n_grid)
    xj, vj = xg[::2], vg[::2]
    arrays = {"times": np.asarray(scene.save_at)}
    if {"x", "joint"} & set(sf.outputs.densities):
        arrays["x_grid"] = xg if "x" in sf.outputs.densities else xj
    if {"v", "joint"} & set(sf.outputs.densities):
        arrays["v_grid"] = vg if "v" in sf.outputs.densities else vj
    if "joint" in sf.outputs.densities:
        arrays["x_grid_joint"], arrays["v_grid_joint"] = xj, vj
    for name, res in results.items():
        for var, g in (("x", xg), ("v", vg)):
            if var in sf.outputs.densities:
                arrays[f"{name}_pdf_{var}"] = np.stack([np.asarray(res.pdf(var, g, t)) for t in scene.save_at])
                if name == "monte_carlo":
                    arrays[f"{name}_stderr_{var}"] = np.stack(
                        [np.asarray(res.pdf_error(var, g, t)) for t in scene.save_at]
                    )
        if "joint" in sf.outputs.densities:
            arrays[f"{name}_joint"] = np.stack(
                [np.asarray(res.joint_pdf(("x", "v"), (xj, vj), t)) for t in scene.save_at]
            )
        if sf.outputs.states:
            arrays[f"{name}_states"], arrays[f"{name}_weights"] = np.asarray(res.states), np.asarray(res.weights)
        arrays[f"{name}_nonfinite"] = np.asarray(res.n_nonfinite())
    files = [f"{stem}.npz"]
    np.savez_compressed(out / files[0], **arrays)
    if sf.outputs.figures:
        files += _figures_of(sf, results, arrays, out)
    meta = {
        "scene_file": str(sf.path),
        "parameters": sf.table,
        "versions": versions(),
        "wall_time_s": timings,
        "arrays": {k: list(v.shape) for k, v in arrays.items()},
        "files": files + [f"{stem}.json"],
    }
    (out / f"{stem}.json").write_text(json.dumps(meta, indent=2))
    log(f"wrote {', '.join(meta['files'])} to {out}/")
    return meta


def _figures_of(sf: SceneFile, results, arrays, out: pathlib.Path) -> list[str]:
    plt = figures.pyplot()
    scene, stem = sf.scene, sf.path.stem
    model = scene.model
    title = figures.scene_title(model.alpha, model.gamma, model.r, scene.noise.D)
    names = []
    for var in ("x", "v"):
        if var not in sf.outputs.densities:
            continue
        g = arrays[f"{var}_grid"]
        fig, axes = plt.subplots(1, len(scene.save_at), figsize=(3.2 * len(scene.save_at), 2.8), squeeze=False)
        for i, (ax, t) in enumerate(zip(axes[0], scene.save_at, strict=True)):
            curves = [
                (
                    name,
                    f"{figures.NAME[name]} ({res.n_paths} paths)",
                    arrays[f"{name}_pdf_{var}"][i],
                    arrays[f"{name}_stderr_{var}"][i] if name == "monte_carlo" else None,
                )
                for name, res in results.items()
            ]
            figures.marginal(ax, g, curves, var)
            ax.set_title(f"$t = {t:g}$ s")
        axes[0, 0].legend()
        fig.suptitle(title)
        fig.tight_layout()
        names.append(f"{stem}_marginal_{var}.png")
        fig.savefig(out / names[-1], dpi=150)
        plt.close(fig)
    if "joint" in sf.outputs.densities:
        t = scene.save_at[-1]
        panels = [(f"{figures.NAME[n]}, $t = {t:g}$ s", arrays[f"{n}_joint"][-1]) for n in results]
        fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels) + 0.8, 3.2), layout="constrained")
        axes = np.atleast_1d(axes)
        figures.joint(fig, axes, arrays["x_grid_joint"], arrays["v_grid_joint"], panels)
        fig.suptitle(title)
        names.append(f"{stem}_joint.png")
        fig.savefig(out / names[-1], dpi=150)
        plt.close(fig)
    return names
