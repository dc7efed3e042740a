"""The ``jdpim`` command line.

* ``jdpim paper [--quick]``: the seed paper's Figures 2-4 and Table 1 on this machine (see ``jdpim.paper``).
* ``jdpim run [scene.toml]``: a scene file's methods and outputs, or, without a file, the main job (the
  reference scene by DPIM and MCS: figures, a timing table and distances to the reference density).
* ``jdpim bench ...``: accuracy-versus-time, error-budget and speed benchmarks (``jdpim bench -h``).

A bad value is rejected in one line with exit status 2; ``--traceback`` shows the Python traceback.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys

PAPER_TABLE_1 = "paper's Table 1 (its own hardware, 1000 points vs 1e5 samples): DPIM 24.5-31.9 s, MCS 2.0e3-1.4e4 s"


class UsageError(Exception):
    """A user error found after parsing (one line, exit status 2)."""


def _number(kind, low=None, high=None, *, low_open=False, what=""):
    """An argparse type: a ``kind`` number in the stated range (the message states the range)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be finite, got {text}")
        too_low = low is not None and (value <= low if low_open else value < low)
        if kind is int and too_low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text}")
        if too_low or (high is not None and value > high):
            lo = "-inf" if low is None else f"{low:g}"
            hi = "inf" if high is None else f"{high:g}"
            rng = f"{'(' if low_open else '['}{lo}, {hi}{']' if high is not None else ')'}"
            raise argparse.ArgumentTypeError(f"must lie in {rng}{what}, got {text}")
        return value

    return parse


POSITIVE = _number(float, 0.0, low_open=True)
NON_NEGATIVE = _number(float, 0.0)
FRACTION = _number(float, 0.0, 1.0)


def _count(low: int):
    return _number(int, low)


class _Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    pass


class _Parser(argparse.ArgumentParser):
    """``ArgumentParser`` whose errors are one line: ``jdpim run: error: argument --r: must lie in [0, 1], got 1.5``."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message}\n")


def _common(p) -> None:
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out"), help="output folder")
    p.add_argument("--quiet", action="store_true", help="no progress lines (results and file names only)")
    p.add_argument("--traceback", action="store_true", help="show Python tracebacks of errors (for bug reports)")
    p.add_argument(
        "--cpu-devices",
        type=_count(1),
        default=None,
        help="split the CPU into this many JAX devices, run side by side (default: one per usable core)",
    )


def _run_parser(sub) -> None:
    p = sub.add_parser(
        "run",
        help="a scene file, or the reference scene by DPIM and MCS: PDFs, figures, timing table",
        description="Run a TOML scene file (`jdpim run scene.toml`, see docs/cli.md), or, without one, the "
        "main job: the reference scene by DPIM and Monte Carlo, with figures, a timing table and distances to the "
        "reference density. The options below set the main job's scene; a scene file carries its own.",
        formatter_class=_Formatter,
    )
    p.add_argument("scene_file", nargs="?", type=pathlib.Path, default=None, help="TOML scene file (optional)")
    p.add_argument("--D", type=NON_NEGATIVE, default=0.03, help="noise intensity D, E[xi(t) xi(t+s)] = 2 D delta(s)")
    p.add_argument("--alpha", type=NON_NEGATIVE, default=0.03, help="linear damping coefficient alpha")
    p.add_argument("--gamma", type=NON_NEGATIVE, default=0.03, help="cubic damping coefficient gamma")
    p.add_argument("--r", type=FRACTION, default=0.98, help="coefficient of restitution r")
    p.add_argument("--points", type=_count(2), default=1000, help="DPIM representative points")
    p.add_argument("--samples", type=_count(2), default=10_000, help="Monte Carlo samples")
    p.add_argument("--t-end", type=POSITIVE, default=200.0, help="end time in s (a whole number of steps dt)")
    p.add_argument("--dt", type=POSITIVE, default=0.01, help="RK4 time step in s")
    p.add_argument(
        "--save-at", type=NON_NEGATIVE, nargs="+", default=[10.0, 50.0, 200.0], help="saved times in s (<= t_end)"
    )
    p.add_argument("--repeats", type=_count(1), default=3, help="timed DPIM repeats after a warm-up (MCS: one run)")
    _forcing_option(p)
    _common(p)


def _forcing_option(p) -> None:
    from jdpim.cli._scenefile import FORCINGS

    p.add_argument(
        "--forcing",
        choices=FORCINGS,
        default=FORCINGS[0],
        help="Monte Carlo's forcing: Gaussian values at the RK4 nodes, drawn inside the steps, or DPIM's spectral "
        "representation with Gaussian coefficients",
    )


# options of `jdpim run` that set the main job's scene (refused with a scene file, which carries its own)
MAIN_JOB_OPTIONS = (
    "--D",
    "--alpha",
    "--gamma",
    "--r",
    "--points",
    "--samples",
    "--t-end",
    "--dt",
    "--save-at",
    "--repeats",
    "--forcing",
)


def _paper_parser(sub) -> None:
    p = sub.add_parser(
        "paper",
        help="the seed paper's Figures 2-4 and Table 1 on this machine",
        description="Reproduce the seed paper's example (alpha = gamma = 0.03, r = 0.98): Figure 2 (marginals of x "
        "and x' at D = 0.03, DPIM as lines, MCS as dots), Figure 3 (joint PDF, MCS beside DPIM), Figure 4 "
        "(stationary marginals for D = 0.01, 0.03, 0.08) and Table 1 (times measured here), with a reference "
        "density and each curve's distance to it. Writes PNG (PDF with --pdf), CSV, JSON and .npz.",
        formatter_class=_Formatter,
    )
    p.add_argument("--quick", action="store_true", help="smaller settings (MCS 1e4 samples instead of 1e5), labelled")
    p.add_argument("--pdf", action="store_true", help="also write the figures as PDF")
    p.add_argument("--points", type=_count(2), default=None, help="DPIM points (default: 1000)")
    p.add_argument("--samples", type=_count(2), default=None, help="MCS samples (default: 1e5; 1e4 with --quick)")
    p.add_argument("--replicates", type=_count(0), default=None, help="randomised DPIM replicates for error bands")
    _forcing_option(p)
    _common(p)


def run(args) -> dict:
    """The main job. Returns the summary it also writes to ``<out>/summary.json``."""
    import jdpim
    from jdpim import _report as report
    from jdpim.cli._scenefile import excitation_of

    if max(args.save_at) > args.t_end:
        raise UsageError(f"--save-at times must lie in [0, --t-end={args.t_end:g}], got {max(args.save_at):g}")
    log = report.logger(args.quiet)
    model = jdpim.VibroImpactOscillator(alpha=args.alpha, gamma=args.gamma, r=args.r)
    scene = jdpim.Scene(
        model,
        noise=jdpim.WhiteNoise(D=args.D),
        t_end=args.t_end,
        dt=args.dt,
        save_at=tuple(args.save_at),
        excitation=excitation_of(args.forcing),
    )
    args.out.mkdir(parents=True, exist_ok=True)
    grid = jdpim.DPIM().excitation(scene).grid(scene.t_end, scene.dt)  # the spectral representation DPIM runs on
    log(
        f"scene: alpha={args.alpha} gamma={args.gamma} r={args.r} D={args.D}, t in [0, {args.t_end}] s, "
        f"dt={args.dt} s, w_u={grid.cutoff:.3g} rad/s, K={grid.n_terms}"
    )
    log(f"DPIM: {args.points} points, compile + warm-up + {args.repeats} timed runs ...")
    dp, t_dp = report.timed_protocol(scene, jdpim.DPIM(n_points=args.points), repeats=args.repeats)
    log(f"MCS: {args.samples} samples ({args.forcing} forcing), compile + one timed run ...")
    mc, t_mc = report.timed_protocol(scene, jdpim.MonteCarlo(n_samples=args.samples), repeats=1, warmup=False)
    rows = [t_dp.row(), t_mc.row()]
    table = report.markdown([{**r, "steps": scene.n_steps} for r in rows], TIMING_COLUMNS)
    print(table, flush=True)
    log(PAPER_TABLE_1)

    results = {"dpim": dp, "monte_carlo": mc}
    what = "path integration (reference): transient from the same start"
    ref = report.reference(scene, jdpim.PathIntegration(), log, what)
    if ref is not None:
        results["reference"] = ref
    grids = report.grids(scene, (dp, mc), 301)
    joints = {("x", "v"): (grids["x"][::2], grids["v"][::2])}
    arrays = report.densities(results, scene.save_at, grids, joints, scene.save_at[-1:])
    # every saved time: DPIM against MCS first, then each against the reference
    pairs = [("dpim", "monte_carlo")] + [(n, "reference") for n in ("dpim", "monte_carlo") if ref is not None]
    dist = {
        f"L1({SHORT[a]}, {SHORT[b]}) {var} t={t:g}": report.l1(arrays, a, b, var, g, i)
        for a, b in pairs
        for i, t in enumerate(scene.save_at)
        for var, g in grids.items()
    }
    for k, v in dist.items():
        print(f"  {k}: {v:.4f}")
    drawn = report.draw(scene, arrays, grids, report.labels(results), args.out, joints=joints)
    summary = {
        "scene": {
            k: (str(v) if isinstance(v, pathlib.Path) else v)
            for k, v in vars(args).items()
            if k not in ("func", "scene_file", "quiet", "traceback", "command")
        },
        "versions": report.versions(),
        "timing": rows,
        "distances": dist,
        "figures": drawn,
        "paper_table_1": PAPER_TABLE_1,
    }
    report.write_json(args.out / "summary.json", summary)
    (args.out / "timing.md").write_text(table + "\n")
    print(f"wrote {', '.join(drawn)}, timing.md and summary.json to {args.out}/")
    return summary


# the main job's timing table: a row per method (``jdpim.bench.Timing.row()`` and the number of steps)
TIMING_COLUMNS = (
    ("method", "{method}", "l"),
    ("paths", "{n_paths}", "r"),
    ("steps", "{steps}", "r"),
    ("devices", "{devices}", "r"),
    ("compile (s)", "{compile_s:.2f}", "r"),
    ("run, median (s)", "{median_s:.3f}", "r"),
    ("path-steps/s", "{path_steps_per_s:.3g}", "r"),
)
SHORT = {"dpim": "dpim", "monte_carlo": "mcs", "reference": "path integration"}  # names in the distances


def _run_scene(args) -> dict:
    from jdpim._report import logger
    from jdpim.cli import _scenefile, _scenerun

    sf = _scenefile.load(args.scene_file)
    return _scenerun.run(sf, args.out, progress=not args.quiet, log=logger(args.quiet))


def _paper(args) -> dict:
    from jdpim import paper
    from jdpim._report import logger
    from jdpim.cli._scenefile import excitation_of

    settings = paper.QUICK if args.quick else paper.FULL
    settings = settings.with_overrides(n_points=args.points, n_samples=args.samples, replicates=args.replicates)
    settings = dataclasses.replace(settings, excitation=excitation_of(args.forcing))
    return paper.reproduce(settings, args.out, pdf=args.pdf, log=logger(args.quiet), progress=not args.quiet)


def _version() -> str:
    import importlib.metadata

    try:
        return importlib.metadata.version("jdpim")
    except importlib.metadata.PackageNotFoundError:
        return "0.0.0 (source tree)"


def parser() -> argparse.ArgumentParser:
    p = _Parser(prog="jdpim", description=__doc__, formatter_class=_Formatter)
    p.add_argument("--version", action="version", version=f"jdpim {_version()}", help="show the version and exit")
    sub = p.add_subparsers(dest="command", parser_class=_Parser, metavar="{paper,run,bench}")
    _paper_parser(sub)
    _run_parser(sub)
    sub.add_parser(
        "bench", help="accuracy-versus-time, error-budget and speed benchmarks (`jdpim bench -h`)", add_help=False
    )
    return p


def main(argv=None) -> int:
    """Entry point: ``jdpim paper|run|bench ...``; returns the exit status (2 for user errors).

    Run as a program (``argv=None``) it splits the CPU into one JAX device per usable core (``--cpu-devices``
    to choose); called from Python with ``argv`` it leaves JAX's devices as they are unless ``--cpu-devices``
    is given.
    """
    from_program = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "bench":
        from jdpim.bench.__main__ import main as bench_main

        return bench_main(argv[1:], from_program=from_program)
    p = parser()
    if not argv or argv[0] not in ("paper", "run", "-h", "--help", "--version"):
        argv = ["run", *argv]  # `python -m jdpim` alone is the main job, as before
    try:
        args = p.parse_args(argv)
    except SystemExit as exit_:  # argparse: --help (0) or a bad value (2, one line already printed)
        return int(exit_.code or 0)
    if args.command == "run" and args.scene_file is not None:
        given = sorted({a.split("=")[0] for a in argv if a.split("=")[0] in MAIN_JOB_OPTIONS})
        if given:
            print(
                f"jdpim run: error: {', '.join(given)} set{'s' if len(given) == 1 else ''} the main job's scene; "
                f"a scene file carries its own settings: edit {args.scene_file}",
                file=sys.stderr,
            )
            return 2
    from jdpim._cpu import start_devices
    from jdpim.cli._scenefile import SceneFileError

    try:
        if from_program or args.cpu_devices is not None:
            devices = start_devices(args.cpu_devices)
            if not args.quiet:
                print(f"jdpim {args.command}: running on {devices}", flush=True)
        if args.command == "paper":
            _paper(args)
        elif args.scene_file is not None:
            _run_scene(args)
        else:
            run(args)
    except (SceneFileError, UsageError, ValueError, TypeError) as err:
        if args.traceback:
            raise
        message = str(err).splitlines()[0] if str(err) else type(err).__name__
        print(f"jdpim {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"jdpim {args.command}: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
