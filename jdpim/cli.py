"""Command line: ``jdpim run`` (the main job: reference scene by DPIM and MCS, figures and a timing table)
and ``jdpim bench`` (accuracy-versus-time benchmarks, see ``jdpim.bench``)."""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import sys

import numpy as np

PAPER_TABLE_1 = "paper's Table 1 (its own hardware, 1000 points vs 1e5 samples): DPIM 24.5-31.9 s, MCS 2.0e3-1.4e4 s"


def _run_parser(sub) -> None:
    p = sub.add_parser("run", help="reference scene by DPIM and Monte Carlo: PDFs, figures, timing table")
    p.add_argument("--D", type=float, default=0.03, help="noise intensity (default 0.03)")
    p.add_argument("--alpha", type=float, default=0.03)
    p.add_argument("--gamma", type=float, default=0.03)
    p.add_argument("--r", type=float, default=0.98)
    p.add_argument("--points", type=int, default=1000, help="DPIM representative points (default 1000)")
    p.add_argument("--samples", type=int, default=10_000, help="Monte Carlo samples (default 10000)")
    p.add_argument("--t-end", type=float, default=200.0)
    p.add_argument("--dt", type=float, default=0.01)
    p.add_argument("--save-at", type=float, nargs="+", default=[10.0, 50.0, 200.0])
    p.add_argument("--repeats", type=int, default=3, help="timed DPIM repeats (MCS is timed once)")
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out"))


def run(args) -> dict:
    """The main job. Returns the summary it also writes to ``<out>/summary.json``."""
    import jdpim
    from jdpim import exact, metrics
    from jdpim.bench import timed

    model = jdpim.VibroImpactOscillator(alpha=args.alpha, gamma=args.gamma, r=args.r)
    scene = jdpim.Scene(
        model, noise=jdpim.WhiteNoise(D=args.D), t_end=args.t_end, dt=args.dt, save_at=tuple(args.save_at)
    )
    args.out.mkdir(parents=True, exist_ok=True)
    print(
        f"scene: alpha={args.alpha} gamma={args.gamma} r={args.r} D={args.D}, t in [0, {args.t_end}] s, "
        f"dt={args.dt} s, w_u={scene.spectral_grid().cutoff:.3g} rad/s, K={scene.spectral_grid().n_terms}",
        flush=True,
    )
    dp, t_dp = timed("dpim", scene, args.points, repeats=args.repeats)
    mc, t_mc = timed("monte_carlo", scene, args.samples, repeats=1, warmup=False)
    rows = [t_dp.row(), t_mc.row()]
    table = _timing_table(rows, scene.n_steps)
    print(table, flush=True)
    print(PAPER_TABLE_1)

    t_last = scene.save_at[-1]
    spread = math.sqrt(max(float(mc.moment("x", 2, t)) for t in scene.save_at))
    xg = np.linspace(0.0, 5.0 * spread, 301)
    vg = np.linspace(-5.0 * spread, 5.0 * spread, 401)
    dist = {}
    for t in scene.save_at:
        for var, g in (("x", xg), ("v", vg)):
            dist[f"L1(dpim, mcs) {var} t={t:g}"] = metrics.l1(
                np.asarray(dp.pdf(var, g, t)), np.asarray(mc.pdf(var, g, t)), g
            )
    ref_x = exact.averaging_pdf_x(xg, args.alpha, args.gamma, args.r, args.D)
    ref_v = exact.averaging_pdf_v(vg, args.alpha, args.gamma, args.r, args.D)
    for name, res in (("dpim", dp), ("mcs", mc)):
        dist[f"L1({name}, averaging) x t={t_last:g}"] = metrics.l1(np.asarray(res.pdf("x", xg, t_last)), ref_x, xg)
        dist[f"L1({name}, averaging) v t={t_last:g}"] = metrics.l1(np.asarray(res.pdf("v", vg, t_last)), ref_v, vg)
    for k, v in dist.items():
        print(f"  {k}: {v:.4f}")
    figures = _figures(scene, dp, mc, xg, vg, ref_x, ref_v, args)
    summary = {
        "scene": {k: (str(v) if isinstance(v, pathlib.Path) else v) for k, v in vars(args).items() if k != "func"},
        "timing": rows,
        "distances": dist,
        "figures": figures,
        "paper_table_1": PAPER_TABLE_1,
    }
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    (args.out / "timing.md").write_text(table + "\n")
    print(f"wrote {', '.join(figures)}, timing.md and summary.json to {args.out}/")
    return summary


def _timing_table(rows, n_steps) -> str:
    lines = [
        "| method | paths | steps | compile (s) | run, median (s) | path-steps/s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['method']} | {r['n_paths']} | {n_steps} | {r['compile_s']:.2f} | {r['median_s']:.3f} "
            f"| {r['path_steps_per_s']:.3g} |"
        )
    return "\n".join(lines)


def _figures(scene, dp, mc, xg, vg, ref_x, ref_v, args) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jdpim import exact

    t_last = scene.save_at[-1]
    names = []
    for var, g, ref, label in (("x", xg, ref_x, "x"), ("v", vg, ref_v, "x'")):
        fig, axes = plt.subplots(1, len(scene.save_at), figsize=(4.2 * len(scene.save_at), 3.4), squeeze=False)
        for ax, t in zip(axes[0], scene.save_at, strict=True):
            edges = np.linspace(g[0], g[-1], 61)
            ax.stairs(np.asarray(mc.histogram(var, edges, t)), edges, color="0.75", fill=True, label="MCS histogram")
            ax.plot(g, np.asarray(mc.pdf(var, g, t)), "k-", lw=1.2, label=f"MCS ({mc.n_paths})")
            ax.plot(g, np.asarray(dp.pdf(var, g, t)), "r--", lw=1.5, label=f"DPIM ({dp.n_paths})")
            if t == t_last:
                ax.plot(g, ref, "b:", lw=1.5, label="averaging (approx.)")
            ax.set_title(f"t = {t:g} s")
            ax.set_xlabel(label)
        axes[0, 0].set_ylabel(f"p({label}, t)")
        axes[0, -1].legend(fontsize=7)
        fig.suptitle(f"marginal PDF of {label}: alpha={args.alpha}, gamma={args.gamma}, r={args.r}, D={args.D}")
        fig.tight_layout()
        name = f"marginal_{var}.png"
        fig.savefig(args.out / name, dpi=110)
        plt.close(fig)
        names.append(name)
    xj, vj = xg[xg <= 0.6 * xg[-1]][::2], vg[np.abs(vg) <= 0.6 * vg[-1]][::2]
    panels = [
        ("DPIM", np.asarray(dp.joint_pdf(xj, vj, t_last))),
        ("MCS", np.asarray(mc.joint_pdf(xj, vj, t_last))),
        ("averaging (approx.)", exact.averaging_joint_pdf(xj, vj, args.alpha, args.gamma, args.r, args.D)),
    ]
    levels = np.linspace(0, max(p.max() for _, p in panels), 12)[1:]
    fig, axes = plt.subplots(1, 3, figsize=(12.5, 3.8), sharey=True, layout="constrained")
    for ax, (title, p) in zip(axes, panels, strict=True):
        cs = ax.contourf(xj, vj, p.T, levels=levels, cmap="viridis", extend="max")
        ax.set_title(f"{title}, t = {t_last:g} s")
        ax.set_xlabel("x")
    axes[0].set_ylabel("x'")
    fig.colorbar(cs, ax=axes, shrink=0.85, label="p(x, x')")
    fig.savefig(args.out / "joint.png", dpi=110)
    plt.close(fig)
    return names + ["joint.png"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="jdpim", description=__doc__)
    sub = parser.add_subparsers(dest="command")
    _run_parser(sub)
    bench = sub.add_parser("bench", help="accuracy-versus-time benchmarks (see `jdpim bench -h`)", add_help=False)
    bench.add_argument("rest", nargs=argparse.REMAINDER)
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if args.command == "bench":
        from jdpim.bench.__main__ import main as bench_main

        return bench_main(args.rest)
    if args.command is None:
        args = parser.parse_args(["run", *(sys.argv[1:] if argv is None else argv)])
    run(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
