r"""``jdpim paper``: the seed paper's example on this machine (Figures 2-4 and Table 1), with a reference.

The system is ``x'' + alpha x' + gamma x'^3 + x = xi(t)`` on ``x >= 0`` with ``x'_+ = -r x'_-``,
``alpha = gamma = 0.03``, ``r = 0.98``, started at rest on the barrier, ``E[xi(t) xi(t+s)] = 2 D delta(s)``:

* Figure 2: marginal PDFs of ``x`` and ``x'`` at ``D = 0.03``, DPIM (lines) against MCS (dots);
* Figure 3: the joint PDF of ``(x, x')``, MCS beside DPIM (and the reference);
* Figure 4: the (nearly) stationary marginals for ``D`` in {0.01, 0.03, 0.08} overlaid;
* Table 1: the wall and CPU time of DPIM and MCS for each ``D``, measured here.

Each curve's L1 distance to the reference density (``REFERENCE_METHOD``, solved once per D) is reported.
Error bands: MCS plus or minus two standard errors from its per-path kernel contributions; DPIM plus or minus two
standard deviations of randomised replicates (``jdpim.dpim_replicates``).

Example (tiny settings):
    >>> import jdpim.paper
    >>> jdpim.paper.QUICK.label()
    'QUICK settings: DPIM 1000 points, MCS 10000 samples, t_end = 200 s, dt = 0.01 s, 4 DPIM replicates'
"""

from __future__ import annotations

import dataclasses
import os
import pathlib
import time

import numpy as np

from . import _report as report
from . import figures
from ._excitation import SpectralRepresentation
from ._models import VibroImpactOscillator
from ._noise import WhiteNoise
from ._scene import Scene
from .methods._path_integration import PathIntegration

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
    excitation: SpectralRepresentation | None = None  # the scenes' (None: each method's own forcing)

    def with_overrides(self, **changes) -> Settings:
        """A copy with the given fields replaced (``None`` values are ignored)."""
        return dataclasses.replace(self, **{k: v for k, v in changes.items() if v is not None})

    def label(self) -> str:
        """One line stating the settings (figure titles, CSV and JSON carry it)."""
        head = "QUICK settings" if self.name == "quick" else "settings"
        reps = f", {self.replicates} DPIM replicates" if self.replicates else ""
        forcing = "" if self.excitation is None else ", MCS on the spectral forcing"
        return (
            f"{head}: DPIM {self.n_points} points, MCS {self.n_samples} samples, t_end = {self.t_end:g} s, "
            f"dt = {self.dt:g} s{reps}{forcing}"
        )


FULL = Settings()
QUICK = Settings(name="quick", n_samples=10_000)


def scene(D: float, settings: Settings) -> Scene:
    """The paper's scene at noise intensity ``D``."""
    model = VibroImpactOscillator(alpha=ALPHA, gamma=GAMMA, r=R)
    return Scene(
        model,
        noise=WhiteNoise(D=D),
        t_end=settings.t_end,
        dt=settings.dt,
        save_at=settings.save_at,
        excitation=settings.excitation,
    )


# The reference density: path integration's stationary density on its default grid (docs/path_integration.md:
# within Monte Carlo sampling error on the paper's scenes), solved once per D. The curves compared with it are
# at t = 200 s, about six relaxation times 1 / alpha, so the stationary density is their limit.
REFERENCE = "path integration (stationary)"
REFERENCE_METHOD = PathIntegration(stationary=True)
NAME = {"dpim": "DPIM", "monte_carlo": "MCS", "reference": REFERENCE}  # curves in distances.csv
SHORT = {"dpim": "dpim", "monte_carlo": "mcs", "reference": "reference"}  # curves in paper.npz's keys
TABLE_1 = (
    ("D", "{D:g}", "r"),
    ("method", "{method}", "l"),
    ("paths", "{paths}", "r"),
    ("wall (s)", "{wall_s:.3g}{note}", "r"),
    ("CPU (s)", "{cpu_s:.3g}", "r"),
)


def reproduce(settings: Settings = QUICK, out="jdpim_out/paper", *, pdf: bool = False, log=print, progress=True):
    """Run the reproduction and write its figures, tables and arrays to ``out``; returns the summary dict.

    Per noise level D: DPIM and MCS (timed: Table 1), the DPIM replicates, one solve of the reference, and
    their densities on common grids, from which every figure, distance and array is taken.
    """
    import jdpim

    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    log(settings.label())
    points = jdpim.dpim_points(scene(settings.noise_levels[0], settings), settings.n_points)  # the same for every D
    methods = {
        "dpim": ("DPIM", settings.n_points, jdpim.DPIM(points=points, progress=progress)),
        "monte_carlo": ("MCS", settings.n_samples, jdpim.MonteCarlo(n_samples=settings.n_samples, progress=progress)),
    }
    table, distances, arrays, dens = [], [], {}, {}
    t_last = settings.save_at[-1]
    for i, D in enumerate(settings.noise_levels):
        sc = scene(D, settings)
        step = f"[D = {D:g}, {i + 1}/{len(settings.noise_levels)}]"
        results = {}
        for name, (what, n, method) in methods.items():
            results[name], wall, cpu = report.solve_timed(sc, method, log, f"{step} {what}")
            table.append(
                {"D": D, "method": what, "paths": n, "wall_s": round(wall, 4), "cpu_s": round(cpu, 4),
                 "compilation_included": i == 0}
            )  # fmt: skip
        reps = []
        if settings.replicates >= 2:
            reps, _, _ = report.timed(
                lambda sc=sc: jdpim.dpim_replicates(sc, settings.n_points, settings.replicates, progress=False),
                log,
                f"{step} {settings.replicates} randomised DPIM replicates (error bands)",
            )
        results["reference"], _, _ = report.solve_timed(sc, REFERENCE_METHOD, log, f"{step} {REFERENCE}")
        grids = report.grids(sc, (results["dpim"], results["monte_carlo"]), settings.n_grid)
        joints = {("x", "v"): (grids["x"][::2], grids["v"][::2])}
        d = report.densities(results, settings.save_at, grids, joints, (t_last,))
        for var, g in grids.items():
            if reps:  # DPIM's error band: the spread of the replicates
                runs = report.densities(dict(enumerate(reps)), settings.save_at, {var: g})
                d[f"dpim_stderr_{var}"] = np.std([runs[f"{k}_pdf_{var}"] for k in range(len(reps))], axis=0, ddof=1)
            distances += [
                {"D": D, "t": t_last, "var": var, "curve": NAME[a], "to": NAME[b],
                 "L1": round(report.l1(d, a, b, var, g, -1), 4)}
                for a, b in (("dpim", "reference"), ("monte_carlo", "reference"), ("dpim", "monte_carlo"))
            ]  # fmt: skip
        dens[D] = d, grids
        arrays |= _arrays(D, d, grids, settings.save_at)
    log("figures ...")
    drawn = _figures_2_to_4(settings, dens, out, pdf)
    files = drawn + ["table1.csv", "table1.md", "distances.csv", "paper.npz", "paper.json"]
    np.savez_compressed(out / "paper.npz", **arrays)
    report.write_csv(out / "table1.csv", table, settings.label())
    report.write_csv(out / "distances.csv", distances, settings.label())
    (out / "table1.md").write_text(_markdown(table, settings))
    summary = {
        "settings": dataclasses.asdict(settings),
        "label": settings.label(),
        "system": {"alpha": ALPHA, "gamma": GAMMA, "r": R, "x0": 0.0, "v0": 0.0},
        "reference": REFERENCE,
        "versions": report.versions(),
        "load_average_at_end": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "cpu_count": os.cpu_count(),
        "table1": table,
        "paper_table1": "DPIM 24.5-31.9 s, MCS 2.0e3-1.4e4 s (CPU time on the paper's hardware)",
        "distances": distances,
        "total_wall_s": round(time.perf_counter() - t_start, 1),
        "files": files,
    }
    report.write_json(out / "paper.json", summary)
    print(_markdown(table, settings), flush=True)
    for row in distances:
        log(f"  L1({row['curve']}, {row['to']}) {row['var']} D={row['D']:g} t={row['t']:g}: {row['L1']:.4f}")
    print(f"wrote {', '.join(files)} to {out}/ in {summary['total_wall_s']:.0f} s", flush=True)
    return summary


def _arrays(D: float, d: dict, grids: dict, save_at) -> dict:
    """``paper.npz``'s arrays of noise level ``D`` from the ``jdpim._report.densities`` arrays ``d``.

    ``D<D>_t<t>_<var>_{dpim,mcs,mcs_stderr,dpim_replicate_sd}`` at every saved time ``t``; at the last one the
    reference marginals ``D<D>_t<t>_<var>_reference`` and the joint densities ``D<D>_t<t>_joint_{dpim,mcs,
    reference}``; the grids ``D<D>_<var>_grid`` and ``D<D>_joint_{x,v}_grid``.
    """
    arrays, t_last = {}, save_at[-1]
    for var, g in grids.items():
        for i, t in enumerate(save_at):
            k = f"D{D:g}_t{t:g}_{var}"
            arrays[f"{k}_dpim"], arrays[f"{k}_mcs"] = d[f"dpim_pdf_{var}"][i], d[f"monte_carlo_pdf_{var}"][i]
            arrays[f"{k}_mcs_stderr"] = d[f"monte_carlo_stderr_{var}"][i]
            if f"dpim_stderr_{var}" in d:
                arrays[f"{k}_dpim_replicate_sd"] = d[f"dpim_stderr_{var}"][i]
        arrays[f"D{D:g}_{var}_grid"] = g
        arrays[f"D{D:g}_t{t_last:g}_{var}_reference"] = d[f"reference_pdf_{var}"][-1]
    for name, short in SHORT.items():
        arrays[f"D{D:g}_t{t_last:g}_joint_{short}"] = d[f"{name}_joint"][-1]
    arrays[f"D{D:g}_joint_x_grid"], arrays[f"D{D:g}_joint_v_grid"] = grids["x"][::2], grids["v"][::2]
    return arrays


def _markdown(table: list[dict], settings: Settings) -> str:
    """Table 1 in Markdown: a title line with the settings, the table, the paper's own times."""
    rows = [{**r, "note": " (incl. compilation)" if r["compilation_included"] else ""} for r in table]
    head = f"Table 1 ({settings.label()}; wall and CPU time in s, measured here)"
    foot = "The paper's Table 1 (its hardware): DPIM 24.5-31.9 s, MCS 2.0e3-1.4e4 s."
    return f"{head}\n\n{report.markdown(rows, TABLE_1)}\n\n{foot}\n"


def _figures_2_to_4(settings: Settings, dens: dict, out: pathlib.Path, pdf: bool) -> list[str]:
    """Figures 2-4 from ``dens``: D -> (densities, grids) of :func:`reproduce`; returns the file names."""
    plt = figures.pyplot()
    t_last = settings.save_at[-1]
    D2 = D_FIGURE_2 if D_FIGURE_2 in settings.noise_levels else settings.noise_levels[0]
    sizes = f"DPIM {settings.n_points} points, MCS {settings.n_samples} samples"
    band = "bands: $\\pm 2$ standard errors"
    quick = settings.name == "quick"
    d, grids = dens[D2]

    def curves(var, i):  # the reference is stationary: drawn at the last saved time only
        labels = {"monte_carlo": "MCS", "dpim": "DPIM"} | (
            {"reference": "path integration"} if i == len(settings.save_at) - 1 else {}
        )
        return report.curves(d, labels, var, i)

    title = f"Figure 2: {figures.scene_title(ALPHA, GAMMA, R, D2)}; {sizes}; {band}\n" + (
        "QUICK settings" if quick else ""
    )
    names = report.save(
        report.marginal_figure(grids, settings.save_at, curves, title, title_size=8), out, "figure2", pdf=pdf
    )

    panels = [
        (f"MCS ({settings.n_samples} samples)", d["monte_carlo_joint"][-1]),
        (f"DPIM ({settings.n_points} points)", d["dpim_joint"][-1]),
        ("path integration", d["reference_joint"][-1]),
    ]
    title = f"Figure 3: joint PDF at $t = {t_last:g}$ s, {figures.scene_title(ALPHA, GAMMA, R, D2)}" + (
        " (QUICK settings)" if quick else ""
    )
    fig = report.joint_figure(grids["x"][::2], grids["v"][::2], panels, title, title_size=8)
    names += report.save(fig, out, "figure3", pdf=pdf)

    fig, axes = plt.subplots(1, 2, figsize=(7.5, 3.0))
    for i, D in enumerate(settings.noise_levels):
        d, grids = dens[D]
        for ax, (var, g) in zip(axes, grids.items(), strict=True):
            colour = f"C{i}"
            every = max(1, len(g) // 30)
            mcs, se = d[f"monte_carlo_pdf_{var}"][-1], d[f"monte_carlo_stderr_{var}"][-1]
            ax.errorbar(g[::every], mcs[::every], yerr=2 * se[::every], fmt="o", ms=2.4, color=colour, elinewidth=0.6)
            p = d[f"dpim_pdf_{var}"][-1]
            ax.plot(g, p, "-", color=colour, lw=1.2, label=f"$D = {D:g}$")
            if f"dpim_stderr_{var}" in d:
                sd = d[f"dpim_stderr_{var}"][-1]
                ax.fill_between(g, p - 2 * sd, p + 2 * sd, color=colour, alpha=0.2, lw=0)
            ax.plot(g, d[f"reference_pdf_{var}"][-1], "--", color=colour, lw=0.8)
    for ax, (var, g) in zip(axes, dens[max(settings.noise_levels)][1].items(), strict=True):
        ax.set_xlim(g[0], g[-1])
        ax.set_ylim(bottom=0)
        ax.set_xlabel(f"{figures.LABEL[var]} {figures.UNIT}")
        ax.set_ylabel(f"$p$({figures.LABEL[var]})")
    axes[0].legend(title="DPIM lines, MCS dots,\npath integration dashed", title_fontsize=7)
    fig.suptitle(
        f"Figure 4: marginals at $t = {t_last:g}$ s, {figures.scene_title(ALPHA, GAMMA, R, None)}; {sizes}"
        + (" (QUICK)" if quick else ""),
        fontsize=8,
    )
    fig.tight_layout()
    return names + report.save(fig, out, "figure4", pdf=pdf)
