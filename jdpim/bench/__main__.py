"""``python -m jdpim.bench {accuracy,budget,speed,throughput,sensitivity,pi-gradients,mdof,forcing,processes} ...``:
benchmarks."""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text}")
    return value


def main(argv=None, *, from_program=None) -> int:
    """Run one benchmark; as a program (``argv=None``) on one CPU device per usable core (``--cpu-devices``)."""
    parser = argparse.ArgumentParser(prog="python -m jdpim.bench", description=__doc__)
    parser.add_argument(
        "--cpu-devices",
        type=_positive_int,
        default=None,
        help="split the CPU into this many JAX devices (default: one per usable core when run as a program)",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    acc = sub.add_parser("accuracy", help="error against exact/reference PDFs versus warm wall time")
    acc.add_argument(
        "--quick",
        action="store_true",
        help="small sweep: DPIM up to 4000 points, MCS up to 1e4, one path-integration grid, one timed repeat",
    )
    acc.add_argument("--case", nargs="+", default=["elastic", "paper"], choices=["elastic", "paper"])
    acc.add_argument("--t-end", type=float, default=None, help="override the sweep's end time (s)")
    acc.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    budget = sub.add_parser("budget", help="error budget: one knob at a time (N, dt, cutoff, dw, bandwidth, dtype)")
    budget.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    budget.add_argument("--quick", action="store_true")
    speed = sub.add_parser("speed", help="wall and compile times, split, memory, against a NumPy RK4 MCS")
    speed.add_argument(
        "--quick", action="store_true", help="float32 only, MCS 1e4 only; the NumPy baseline over 2000 steps"
    )
    speed.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    speed.add_argument(
        "--versus", action="store_true", help="only jdpim against the NumPy and plain-scan baselines, interleaved"
    )
    speed.add_argument(
        "--first-solve", action="store_true", help="only the first solve in a new process against warm solves"
    )
    speed.add_argument(
        "--kernels", action="store_true", help="only the kernels of a run, grouped per step, batch and impact round"
    )
    speed.add_argument("--note", default=None, help="a note for the record (e.g. that the machine was shared)")
    mdof = sub.add_parser("mdof", help="impact damper: dt convergence against a small-dt reference, speed per dof")
    mdof.add_argument("--quick", action="store_true", help="t_end 20 s, 4000 paths; speed at 1e4 paths, t = 50 s")
    mdof.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    forcing = sub.add_parser(
        "forcing", help="Monte Carlo forcing: spectral against drawn in the step, weak error and time"
    )
    forcing.add_argument("--quick", action="store_true", help="t_end 10 s, 2e4 paths (else 20 s, 1e5)")
    forcing.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    procs = sub.add_parser("processes", help="one process against one per core (jax.distributed), same host")
    procs.add_argument(
        "--quick", action="store_true", help="t_end 50 s, 2e4 paths, 4000 points (else 100 s, 4e4, 8000)"
    )
    procs.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    thr = sub.add_parser("throughput", help="path-steps per second against batch and chunk size, all devices")
    thr.add_argument("--sizes", type=_positive_int, nargs="+", default=[1000, 10_000], help="numbers of paths")
    thr.add_argument(
        "--chunk-sizes", type=_positive_int, nargs="+", default=None, help="paths per chunk (default: memory rule)"
    )
    thr.add_argument("--methods", nargs="+", default=["dpim", "monte_carlo"], choices=["dpim", "monte_carlo"])
    thr.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    thr.add_argument("--forcing", default="spectral", choices=["spectral", "nodes"], help="Monte Carlo's forcing")
    thr.add_argument("--impacts", default="locate", choices=["locate", "mirror"], help="impact rule")
    thr.add_argument("--t-end", type=float, default=200.0, help="end time (s)")
    thr.add_argument("--repeats", type=_positive_int, default=3, help="warm repeats (median)")
    thr.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    sens = sub.add_parser("sensitivity", help="sensitivity estimators: error against exact derivatives versus cost")
    sens.add_argument("--quick", action="store_true", help="short horizons (t = 10, 50) and few paths (2000, 8000)")
    sens.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    pig = sub.add_parser("pi-gradients", help="path integration: jax.grad against jax.jacfwd over a matrix of scenes")
    pig.add_argument(
        "--quick",
        action="store_true",
        help="18 cells (every axis value, and the reported one), 81 x 161 nodes (else 73 cells, 121 x 241)",
    )
    pig.add_argument(
        "--central", type=int, default=3, help="cells (the first) that also get central differences (default 3)"
    )
    pig.add_argument("--resume", action="store_true", help="keep the cells already in --out's record, run the others")
    pig.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    if (argv is None if from_program is None else from_program) or args.cpu_devices is not None:
        from .._cpu import start_devices

        print(f"jdpim bench: running on {start_devices(args.cpu_devices)}", flush=True)
    if args.command == "accuracy":
        from .accuracy import QUICK, Sweep, sweep, write

        cfg = QUICK if args.quick else Sweep()
        if args.t_end is not None:
            cfg = dataclasses.replace(cfg, t_end=args.t_end)
        results = []
        for case in args.case:
            results.append(None)
            results[-1] = sweep(
                case,
                cfg,
                log=lambda s: print(s, flush=True),
                on_row=lambda partial: (results.__setitem__(-1, partial), write(results, args.out)),
            )
        files = write(results, args.out)
    elif args.command == "speed":
        from .speed import run_speed, run_versus

        if args.first_solve:
            from .first_solve import run_first_solve

            files = run_first_solve(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
        elif args.kernels:
            from .kernels import run_kernels

            files = run_kernels(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
        elif args.versus:
            files = run_versus(args.out, quick=args.quick, note=args.note, log=lambda s: print(s, flush=True))
        else:
            files = run_speed(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    elif args.command == "mdof":
        from .mdof import run_mdof

        files = run_mdof(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    elif args.command == "forcing":
        from .forcing import run_forcing

        files = run_forcing(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    elif args.command == "processes":
        from .processes import run_processes

        sizes = {"t_end": 50.0, "n_samples": 20_000, "n_points": 4000} if args.quick else {}
        files = run_processes(args.out, **sizes, log=lambda s: print(s, flush=True))
    elif args.command == "throughput":
        from .throughput import run_throughput

        if args.forcing == "nodes" and set(args.methods) == {"dpim"}:
            parser.error("--methods dpim needs the spectral forcing (DPIM refuses --forcing nodes)")

        files = run_throughput(
            args.out,
            sizes=args.sizes,
            chunk_sizes=args.chunk_sizes or [None],
            methods=args.methods,
            dtype=args.dtype,
            forcing=args.forcing,
            impacts=args.impacts,
            t_end=args.t_end,
            repeats=args.repeats,
            log=lambda s: print(s, flush=True),
        )
    elif args.command == "sensitivity":
        from .sensitivity import run_sensitivity

        files = run_sensitivity(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    elif args.command == "pi-gradients":
        from .pi_gradients import run_pi_gradients

        files = run_pi_gradients(
            args.out,
            quick=args.quick,
            central=args.central,
            resume=args.resume,
            log=lambda s: print(s, flush=True),
        )
    else:
        from .budget import run_budget

        files = run_budget(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    print(f"wrote {', '.join(files)} to {args.out}/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
