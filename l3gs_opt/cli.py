"""The ``l3gs-opt`` command line: thin subcommands over the library API.

Every error the library raises on purpose (bad instance, bad option, unreadable file) is printed
as one line on stderr with exit code 2; argparse's own usage errors also exit 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Sequence

from .errors import L3gsError

__all__ = ["main", "build_parser"]


def _cmd_solve(args: argparse.Namespace) -> int:
    from .api import solve
    from .instance_io import load_instance
    from .report_table import comparison_table

    instance = load_instance(args.instance)
    solution = solve(instance, args.method, backend=args.backend, form=args.form, slot=args.slot,
                     time_limit_s=args.time_limit, presolve=not args.no_presolve)
    if args.json:
        print(json.dumps(solution.to_dict(), allow_nan=False))
    else:
        label = args.method + (f"/{solution.backend}" if solution.backend else "")
        print(comparison_table([(label, solution)]))
        if solution.message:
            print(f"note: {solution.message}")
    return 0


def _cmd_synth(args: argparse.Namespace) -> int:
    from .instance import Options
    from .instance_io import save_instance
    from .synth import synth_instance

    options = Options(availability=args.availability, same_slot_layers=not args.strict_layers, budget=args.budget)
    instance = synth_instance(objects=args.objects, layers=args.layers, slots=args.slots, seed=args.seed,
                              trace=args.trace, mbps=args.mbps, start=args.start,
                              representation=args.representation, options=options)
    path = save_instance(instance, args.output)
    print(f"wrote {path}: {instance!r}")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from .instance_io import load_instance
    from .presolve import presolve

    instance = load_instance(args.instance)
    red = presolve(instance)
    print(f"{args.instance}: valid {instance!r}")
    print(f"  total bytes {int(instance.cost.sum())}, bandwidth {int(instance.bandwidth.sum())} bytes over "
          f"{instance.T} slots of {instance.slot_s} s; held chunks {int(instance.held.sum())}")
    print(f"  presolve: {red.stats}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    return run_demo(out_dir=Path(args.out), time_limit_s=args.time_limit)


def build_parser() -> argparse.ArgumentParser:
    from .models.backends import Backend

    parser = argparse.ArgumentParser(prog="l3gs-opt", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("solve", help="solve an instance and print the answer")
    p.add_argument("instance", help="instance file (.json or .npz)")
    p.add_argument("--method", default="ilp", help="ilp (default), lp, brute, or a solver method name")
    p.add_argument("--backend", default="highs", choices=[b.value for b in Backend])
    p.add_argument("--form", default="standard", choices=["standard", "gap"])
    p.add_argument("--slot", type=int, default=None, help="solve the single-slot MCKP of this slot (0-based)")
    p.add_argument("--time-limit", type=float, default=None, metavar="S", help="seconds")
    p.add_argument("--no-presolve", action="store_true", help="build the naive model")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_cmd_solve)

    inst = sub.add_parser("instance", help="make or check instance files").add_subparsers(dest="action",
                                                                                           required=True)
    s = inst.add_parser("synth", help="a synthetic L3GS-like instance from a real bandwidth trace")
    s.add_argument("--objects", type=int, default=20)
    s.add_argument("--layers", type=int, default=4)
    s.add_argument("--slots", type=int, default=60)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--trace", default="lumos-throughput-mid-11", help="bundled trace name or a trace file")
    s.add_argument("--mbps", type=float, default=11.8, help="scale the trace to this mean (Mbit/s)")
    s.add_argument("--start", type=int, default=0, help="first second of the trace window")
    s.add_argument("--representation", default="layered", choices=["layered", "separate"])
    s.add_argument("--availability", default="same_slot", choices=["same_slot", "next_slot"])
    s.add_argument("--strict-layers", action="store_true", help="layer l only in a slot after layer l-1")
    s.add_argument("--budget", default="per_slot", choices=["per_slot", "cumulative"])
    s.add_argument("-o", "--output", required=True, help="output file (.json or .npz)")
    s.set_defaults(func=_cmd_synth)
    c = inst.add_parser("check", help="validate an instance file and summarise it")
    c.add_argument("instance")
    c.set_defaults(func=_cmd_check)

    d = sub.add_parser("demo", help="the README's demo: solve, compare and report on a real trace")
    d.add_argument("--out", default="demo-out", help="folder for the demo's files")
    d.add_argument("--time-limit", type=float, default=10.0, metavar="S", help="seconds per exact solve")
    d.set_defaults(func=_cmd_demo)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except L3gsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
