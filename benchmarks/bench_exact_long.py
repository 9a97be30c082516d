"""`exact` alone with a long time limit on chosen T=60 bench instances (those of bench_exact.py).

What a 60 s run leaves open is often not known: the optimum, and so whether the primal or the
dual side is short. A long run answers that per instance. Records are appended as they finish
(one JSON line each, with machine, load and time limit) and a finished instance is skipped when
the command is run again.

    python benchmarks/bench_exact_long.py --J 20 --seeds 5-9 --time-limit 300 \
        --out benchmarks/results/exact_long_runs.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_exact import bench_instance  # noqa: E402
from machine import machine_info  # noqa: E402

from l3gs_opt import solve  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.bench.suites import suite_specs  # noqa: E402


def seed_list(text: str) -> list[int]:
    """``"7"``, ``"5-9"`` or a comma list of those (``"1,4"``, ``"0,5-9"``): the seeds, sorted."""
    seeds: set[int] = set()
    for k, part in enumerate(text.split(",")):
        lo, dash, hi = part.strip().partition("-")
        try:
            a, b = int(lo), int(hi) if dash else int(lo)
        except ValueError:
            raise argparse.ArgumentTypeError(f"part {k} ({part!r}) is not a seed or a range like 5-9") from None
        if a < 0 or b < a:
            raise argparse.ArgumentTypeError(f"part {k} ({part!r}): seeds are >= 0 and a range runs upwards")
        seeds.update(range(a, b + 1))
    return sorted(seeds)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--J", type=int, required=True, help="objects (20, 50 or 200)")
    ap.add_argument("--seeds", required=True, type=seed_list, help="e.g. 7, 5-9 or 1,4")
    ap.add_argument("--time-limit", type=float, default=300.0, help="seconds per instance")
    ap.add_argument("--budget", choices=["per_slot", "cumulative"], default="per_slot")
    ap.add_argument("--out", default="benchmarks/results/exact_long_runs.jsonl",
                    help="the JSON-lines file, or a folder (then its exact_long_runs.jsonl)")
    args = ap.parse_args()
    seeds = args.seeds
    out = Path(args.out)
    if out.is_dir():
        out = out / "exact_long_runs.jsonl"
    done = set()
    if out.exists():
        done = {(r["instance_id"], r["budget"], r["time_limit_s"]) for r in map(json.loads, out.read_text().splitlines())}
    machine = machine_info()
    specs = [s for s in suite_specs("l3gs", sizes=[args.J], seeds=max(seeds) + 1)
             if not s.single_slot and s.params.get("seed") in seeds]
    if not specs:
        ap.error(f"--J {args.J} --seeds {args.seeds}: no T=60 bench instance matches")
    with out.open("a", encoding="utf-8") as fh:
        for spec in specs:
            if (spec.instance_id, args.budget, args.time_limit) in done:
                continue
            inst = bench_instance(spec, args.budget)
            load = os.getloadavg()
            sol = solve(inst, "exact", time_limit_s=args.time_limit)
            rec = {"instance_id": spec.instance_id, "budget": args.budget, "loadavg_before": load, **sol.to_dict(),
                   "machine": machine, "loadavg_after": os.getloadavg(), "time_limit_s": args.time_limit,
                   "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
            rec.pop("arrivals")
            fh.write(dumps(rec) + "\n")
            fh.flush()
            print(spec.instance_id, args.budget, sol.status, sol.objective, sol.bound, f"{sol.runtime_s:.1f}s",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
