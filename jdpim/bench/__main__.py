"""``python -m jdpim.bench {accuracy,budget,speed,sensitivity} [--quick] [--out DIR]``: accuracy vs time, error
budget, speed, sensitivity estimators."""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jdpim.bench", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    acc = sub.add_parser("accuracy", help="error against exact/reference PDFs versus warm wall time")
    acc.add_argument("--quick", action="store_true", help="small sweep that finishes in a few minutes on 2 cores")
    acc.add_argument("--case", nargs="+", default=["elastic", "paper"], choices=["elastic", "paper"])
    acc.add_argument("--t-end", type=float, default=None, help="override the sweep's end time (s)")
    acc.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    budget = sub.add_parser("budget", help="error budget: one knob at a time (N, dt, cutoff, dw, bandwidth, dtype)")
    budget.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    budget.add_argument("--quick", action="store_true")
    speed = sub.add_parser("speed", help="wall and compile times, split, memory, against a NumPy RK4 MCS")
    speed.add_argument("--quick", action="store_true", help="float32 only, MCS 1e4 only")
    speed.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    sens = sub.add_parser("sensitivity", help="sensitivity estimators: error against exact derivatives versus cost")
    sens.add_argument("--quick", action="store_true", help="short horizons and few paths: a few minutes on 2 cores")
    sens.add_argument("--out", type=pathlib.Path, default=pathlib.Path("jdpim_out/bench"))
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
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
        from .speed import run_speed

        files = run_speed(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    elif args.command == "sensitivity":
        from .sensitivity import run_sensitivity

        files = run_sensitivity(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    else:
        from .budget import run_budget

        files = run_budget(args.out, quick=args.quick, log=lambda s: print(s, flush=True))
    print(f"wrote {', '.join(files)} to {args.out}/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
