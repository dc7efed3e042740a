r"""``jdpim paper``: the seed paper's example on this machine (Figures 2-4 and Table 1), with a reference.

The system is ``x'' + alpha x' + gamma x'^3 + x = xi(t)`` on ``x >= 0`` with ``x'_+ = -r x'_-``,
``alpha = gamma = 0.03``, ``r = 0.98``, started at rest on the barrier, ``E[xi(t) xi(t+s)] = 2 D delta(s)``:

* Figure 2: marginal PDFs of ``x`` and ``x'`` at ``D = 0.03``, DPIM (lines) against MCS (dots);
* Figure 3: the joint PDF of ``(x, x')``, MCS beside DPIM (and the reference);
* Figure 4: the (nearly) stationary marginals for ``D`` in {0.01, 0.03, 0.08} overlaid;
* Table 1: the wall and CPU time of DPIM and MCS for each ``D``, measured here.

Each curve's L1 distance to the reference density (:func:`_reference`) is reported. Error bands: MCS
plus or minus two standard errors from its per-path kernel contributions; DPIM plus or minus two
standard deviations of randomised replicates (``jdpim.dpim_replicates``).

Example (tiny settings):
    >>> import jdpim.paper
    >>> jdpim.paper.QUICK.label()
    'QUICK settings: DPIM 1000 points, MCS 10000 samples, t_end = 200 s, dt = 0.01 s, 4 DPIM replicates'
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import pathlib
import time

import numpy as np

from . import figures, metrics
from ._models import VibroImpactOscillator
from ._noise import WhiteNoise
from ._scene import Scene
from .methods._path_integration import path_integration

ALPHA, GAMMA, R = 0.03, 0.03, 0.98
D_FIGURE_2 = 0.03


@dataclasses.dataclass(frozen=True)
class Settings:
    """Sizes of a reproduction. ``FULL`` is the paper's (1000 points, 1e5 samples); ``QUICK`` is smaller."""

    name: str = "full"
    noise_levels: tuple[float, ...] = (0.01, 0.03, 0.08)
    n_points: int = 1000
    n_samples: int = 100_000
    t_end: float = 200.0
    dt: float = 0.01
    save_at: tuple[float, ...] = (10.0, 50.0, 200.0)
    replicates: int = 4
    n_grid: int = 241

    def with_overrides(self, **changes) -> Settings:
        """A copy with the given fields replaced (``None`` values are ignored)."""
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if v is not None})

    def label(self) -> str:
        """One line stating the settings (figure titles, CSV and JSON carry it)."""
        head = "QUICK settings" if self.name == "quick" else "settings"
        reps = f", {self.replicates} DPIM replicates" if self.replicates else ""
        return (
            f"{head}: DPIM {self.n_points} points, MCS {self.n_samples} samples, t_end = {self.t_end:g} s, "
            f"dt = {self.dt:g} s{reps}"
        )


FULL = Settings()
QUICK = Settings(name="quick", n_samples=10_000)


def scene(D: float, settings: Settings) -> Scene:
    """The paper's scene at noise intensity ``D``."""
    model = VibroImpactOscillator(alpha=ALPHA, gamma=GAMMA, r=R)
    return Scene(model, noise=WhiteNoise(D=D), t_end=settings.t_end, dt=settings.dt, save_at=settings.save_at)


def _reference(scene: Scene, x_grid, v_grid) -> dict:
    """The best reference density available for ``scene``: path integration's stationary density.

    ``jdpim.path_integration(scene, stationary=True)`` on its default grid (docs/path_integration.md: within
    Monte Carlo sampling error on the paper's scenes). The curves are at ``t = 200 s``, about six relaxation
    times ``1 / alpha``, so the stationary density is their limit. Returns ``{"name", "x", "v", "joint"}``
    with the marginals on ``x_grid``, ``v_grid`` and the joint density on ``(x_grid, v_grid)``.
    """
    ref = path_integration(scene, stationary=True)
    return {
        "name": "path integration (stationary)",
        "x": np.asarray(ref.pdf("x", x_grid)),
        "v": np.asarray(ref.pdf("v", v_grid)),
        "joint": np.asarray(ref.joint_pdf(("x", "v"), (x_grid, v_grid))),
    }


def _timed(fn, log, what):
    log(f"{what} ...")
    t0, c0 = time.perf_counter(), time.process_time()
    res = fn()
    import jax

    jax.block_until_ready(res.states if hasattr(res, "states") else [r.states for r in res])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    log(f"{what}: {wall:.1f} s wall, {cpu:.1f} s CPU")
    return res, wall, cpu


def reproduce(settings: Settings = QUICK, out="jdpim_out/paper", *, pdf: bool = False, log=print, progress=True):
    """Run the reproduction and write its figures, tables and arrays to ``out``; returns the summary dict."""
    import jdpim
    from jdpim.cli._scenerun import grids, versions

    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    log(settings.label())
    points = jdpim.dpim_points(scene(settings.noise_levels[0], settings), settings.n_points)
    runs, table, distances, arrays = {}, [], [], {}
    t_last = settings.save_at[-1]
    for i, D in enumerate(settings.noise_levels):
        sc = scene(D, settings)
        step = f"[D = {D:g}, {i + 1}/{len(settings.noise_levels)}]"
        dp, w_dp, c_dp = _timed(lambda sc=sc: jdpim.dpim(sc, points=points, progress=progress), log, f"{step} DPIM")
        mc, w_mc, c_mc = _timed(
            lambda sc=sc: jdpim.monte_carlo(sc, settings.n_samples, progress=progress), log, f"{step} MCS"
        )
        reps = []
        if settings.replicates >= 2:
            reps, w_rep, _ = _timed(
                lambda sc=sc: jdpim.dpim_replicates(sc, settings.n_points, settings.replicates, progress=False),
                log,
                f"{step} {settings.replicates} randomised DPIM replicates (error bands)",
            )
        first = i == 0
        table += [
            {
                "D": D,
                "method": "DPIM",
                "paths": settings.n_points,
                "wall_s": round(w_dp, 2),
                "cpu_s": round(c_dp, 2),
                "compilation_included": first,
            },
            {
                "D": D,
                "method": "MCS",
                "paths": settings.n_samples,
                "wall_s": round(w_mc, 2),
                "cpu_s": round(c_mc, 2),
                "compilation_included": first,
            },
        ]
        xg, vg = grids((dp, mc), 0.0, settings.n_grid)
        ref = _reference(sc, xg, vg)
        entry = {"scene": sc, "dpim": dp, "mcs": mc, "x": xg, "v": vg, "ref": ref}
        for var, g in (("x", xg), ("v", vg)):
            for t in settings.save_at:
                k = f"D{D:g}_t{t:g}_{var}"
                arrays[f"{k}_dpim"] = np.asarray(dp.pdf(var, g, t))
                arrays[f"{k}_mcs"] = np.asarray(mc.pdf(var, g, t))
                arrays[f"{k}_mcs_stderr"] = np.asarray(mc.pdf_error(var, g, t))
                if reps:
                    arrays[f"{k}_dpim_replicate_sd"] = np.std(
                        [np.asarray(r.pdf(var, g, t)) for r in reps], axis=0, ddof=1
                    )
            arrays[f"D{D:g}_{var}_grid"] = g
            arrays[f"D{D:g}_t{t_last:g}_{var}_reference"] = ref[var]
            k = f"D{D:g}_t{t_last:g}_{var}"
            for name in ("dpim", "mcs"):
                distances.append(
                    {
                        "D": D,
                        "t": t_last,
                        "var": var,
                        "curve": name.upper() if name == "mcs" else "DPIM",
                        "to": ref["name"],
                        "L1": round(metrics.l1(arrays[f"{k}_{name}"], ref[var], g), 4),
                    }
                )
            distances.append(
                {
                    "D": D,
                    "t": t_last,
                    "var": var,
                    "curve": "DPIM",
                    "to": "MCS",
                    "L1": round(metrics.l1(arrays[f"{k}_dpim"], arrays[f"{k}_mcs"], g), 4),
                }
            )
        xj, vj = xg[::2], vg[::2]
        arrays[f"D{D:g}_t{t_last:g}_joint_dpim"] = np.asarray(dp.joint_pdf(("x", "v"), (xj, vj), t_last))
        arrays[f"D{D:g}_t{t_last:g}_joint_mcs"] = np.asarray(mc.joint_pdf(("x", "v"), (xj, vj), t_last))
        arrays[f"D{D:g}_t{t_last:g}_joint_reference"] = _reference(sc, xj, vj)["joint"]
        arrays[f"D{D:g}_joint_x_grid"], arrays[f"D{D:g}_joint_v_grid"] = xj, vj
        runs[D] = entry
    log("figures ...")
    drawn = _figures_2_to_4(settings, arrays, out, pdf)
    files = drawn + ["table1.csv", "table1.md", "distances.csv", "paper.npz", "paper.json"]
    np.savez_compressed(out / "paper.npz", **arrays)
    _csv(out / "table1.csv", table, settings)
    _csv(out / "distances.csv", distances, settings)
    (out / "table1.md").write_text(_markdown(table, settings))
    summary = {
        "settings": dataclasses.asdict(settings),
        "label": settings.label(),
        "system": {"alpha": ALPHA, "gamma": GAMMA, "r": R, "x0": 0.0, "v0": 0.0},
        "reference": runs[settings.noise_levels[0]]["ref"]["name"],
        "versions": versions(),
        "load_average_at_end": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "cpu_count": os.cpu_count(),
        "table1": table,
        "paper_table1": "DPIM 24.5-31.9 s, MCS 2.0e3-1.4e4 s (CPU time on the paper's hardware)",
        "distances": distances,
        "total_wall_s": round(time.perf_counter() - t_start, 1),
        "files": files,
    }
    (out / "paper.json").write_text(json.dumps(summary, indent=2))
    print(_markdown(table, settings), flush=True)
    for d in distances:
        log(f"  L1({d['curve']}, {d['to']}) {d['var']} D={d['D']:g} t={d['t']:g}: {d['L1']:.4f}")
    print(f"wrote {', '.join(files)} to {out}/ in {summary['total_wall_s']:.0f} s", flush=True)
    return summary


def _csv(path: pathlib.Path, rows: list[dict], settings: Settings) -> None:
    with path.open("w", newline="") as fh:
        fh.write(f"# {settings.label()}\n")
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _markdown(table: list[dict], settings: Settings) -> str:
    lines = [
        f"Table 1 ({settings.label()}; wall and CPU time in s, measured here)",
        "",
        "| D | method | paths | wall (s) | CPU (s) |",
        "|---:|---|---:|---:|---:|",
    ]
    for r in table:
        note = " (incl. compilation)" if r["compilation_included"] else ""
        lines.append(f"| {r['D']:g} | {r['method']} | {r['paths']} | {r['wall_s']:.1f}{note} | {r['cpu_s']:.1f} |")
    lines.append("")
    lines.append("The paper's Table 1 (its hardware): DPIM 24.5-31.9 s, MCS 2.0e3-1.4e4 s.")
    return "\n".join(lines) + "\n"


def _curves(arrays, k, with_reference=True):
    sd = arrays.get(f"{k}_dpim_replicate_sd")
    curves = [
        ("monte_carlo", "MCS", arrays[f"{k}_mcs"], arrays[f"{k}_mcs_stderr"]),
        ("dpim", "DPIM", arrays[f"{k}_dpim"], sd),
    ]
    if with_reference and f"{k}_reference" in arrays:
        curves.append(("reference", "path integration", arrays[f"{k}_reference"], None))
    return curves


def _save(fig, out, stem, pdf) -> list[str]:
    names = [f"{stem}.png"] + ([f"{stem}.pdf"] if pdf else [])
    for n in names:
        fig.savefig(out / n, dpi=150)
    return names


def _figures_2_to_4(settings: Settings, arrays, out: pathlib.Path, pdf: bool) -> list[str]:
    plt = figures.pyplot()
    t_last = settings.save_at[-1]
    D2 = D_FIGURE_2 if D_FIGURE_2 in settings.noise_levels else settings.noise_levels[0]
    sizes = f"DPIM {settings.n_points} points, MCS {settings.n_samples} samples"
    band = "bands: $\\pm 2$ standard errors"
    names = []

    fig, axes = plt.subplots(2, len(settings.save_at), figsize=(3.1 * len(settings.save_at), 5.2), squeeze=False)
    for row, var in enumerate(("x", "v")):
        for col, t in enumerate(settings.save_at):
            ax = axes[row, col]
            figures.marginal(ax, arrays[f"D{D2:g}_{var}_grid"], _curves(arrays, f"D{D2:g}_t{t:g}_{var}"), var)
            ax.set_title(f"$t = {t:g}$ s")
    axes[0, -1].legend()
    fig.suptitle(
        f"Figure 2: {figures.scene_title(ALPHA, GAMMA, R, D2)}; {sizes}; {band}\n"
        + ("QUICK settings" if settings.name == "quick" else ""),
        fontsize=8,
    )
    fig.tight_layout()
    names += _save(fig, out, "figure2", pdf)
    plt.close(fig)

    k = f"D{D2:g}_t{t_last:g}_joint"
    panels = [
        (f"MCS ({settings.n_samples} samples)", arrays[f"{k}_mcs"]),
        (f"DPIM ({settings.n_points} points)", arrays[f"{k}_dpim"]),
        ("path integration", arrays[f"{k}_reference"]),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(10.5, 3.3), sharey=True, layout="constrained")
    figures.joint(fig, axes, arrays[f"D{D2:g}_joint_x_grid"], arrays[f"D{D2:g}_joint_v_grid"], panels)
    fig.suptitle(
        f"Figure 3: joint PDF at $t = {t_last:g}$ s, {figures.scene_title(ALPHA, GAMMA, R, D2)}"
        + (" (QUICK settings)" if settings.name == "quick" else ""),
        fontsize=8,
    )
    names += _save(fig, out, "figure3", pdf)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(7.5, 3.0))
    for i, D in enumerate(settings.noise_levels):
        for ax, var in zip(axes, ("x", "v"), strict=True):
            kk = f"D{D:g}_t{t_last:g}_{var}"
            g = arrays[f"D{D:g}_{var}_grid"]
            colour = f"C{i}"
            every = max(1, len(g) // 30)
            mcs, se = arrays[f"{kk}_mcs"], arrays[f"{kk}_mcs_stderr"]
            ax.errorbar(g[::every], mcs[::every], yerr=2 * se[::every], fmt="o", ms=2.4, color=colour, elinewidth=0.6)
            ax.plot(g, arrays[f"{kk}_dpim"], "-", color=colour, lw=1.2, label=f"$D = {D:g}$")
            sd = arrays.get(f"{kk}_dpim_replicate_sd")
            if sd is not None:
                p = arrays[f"{kk}_dpim"]
                ax.fill_between(g, p - 2 * sd, p + 2 * sd, color=colour, alpha=0.2, lw=0)
            ax.plot(g, arrays[f"{kk}_reference"], "--", color=colour, lw=0.8)
    D_max = max(settings.noise_levels)
    for ax, var in zip(axes, ("x", "v"), strict=True):
        g = arrays[f"D{D_max:g}_{var}_grid"]
        ax.set_xlim(g[0], g[-1])
        ax.set_ylim(bottom=0)
        ax.set_xlabel(f"{figures.LABEL[var]} {figures.UNIT}")
        ax.set_ylabel(f"$p$({figures.LABEL[var]})")
    axes[0].legend(title="DPIM lines, MCS dots,\npath integration dashed", title_fontsize=7)
    fig.suptitle(
        f"Figure 4: marginals at $t = {t_last:g}$ s, {figures.scene_title(ALPHA, GAMMA, R, None)}; {sizes}"
        + (" (QUICK)" if settings.name == "quick" else ""),
        fontsize=8,
    )
    fig.tight_layout()
    names += _save(fig, out, "figure4", pdf)
    plt.close(fig)
    return names
