"""Probe (issue 23 item 1, twenty-sixth session): which simplex re-solves `exact`'s path master on
Problem II (separate versions), A/B, one JSON line per run appended to ``--out``.

``--arm now`` is the code as it is (after its first solve a path master re-solves by primal
simplex: it only ever gains columns); ``--arm dual`` patches every solve back to dual simplex.
Instances: ``bench_exact_separate.py``'s (``II-T60-J{J}-s{seed}``). Runs are meant to be made one
after another on an otherwise idle machine; ``--report`` prints the table.

    .venv/bin/python benchmarks/probe_separate_primal.py --cases 16:1,20:0,50:0 --arm dual --out runs.jsonl
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_exact_separate import specs  # noqa: E402
from l3gs_opt.bench.suites import _problem  # noqa: E402
from l3gs_opt.solvers.exact import colgen, separate_master  # noqa: E402
from l3gs_opt.solvers.exact.search import solve_exact  # noqa: E402
from machine import machine_info  # noqa: E402
from probe_exact_lean_root import ab_parser, arm_table  # noqa: E402


def report(path: Path) -> str:
    return "\n".join(arm_table(path)[2])


def main(argv=None) -> int:
    ap = ab_parser(__doc__, ("now", "dual"))
    ap.add_argument("--cases", default="16:1,20:0,50:0,50:1", help="J:seed,...")
    args = ap.parse_args(argv)
    if args.report:
        print(report(args.out))
        return 0
    if args.arm == "dual":
        separate_master.PRIMAL_SIMPLEX = colgen.DUAL_SIMPLEX
    cpu = machine_info()["cpu"]
    for case in args.cases.split(","):
        J, seed = (int(v) for v in case.split(":"))
        iid, params = next((i, p) for i, p in specs([J], seed + 1) if p["seed"] == seed)
        inst = _problem(**params)
        load = os.getloadavg()[0]
        started = time.perf_counter()
        sol = solve_exact(inst, time_limit_s=args.time_limit)
        rec = {"instance": iid, "arm": args.arm, "status": sol.status.value, "objective": round(sol.objective, 3),
               "bound": round(sol.bound, 3), "seconds": round(time.perf_counter() - started, 1),
               "nodes": sol.details.get("nodes"), "load_before": round(load, 2),
               "load_after": round(os.getloadavg()[0], 2), "cpu": cpu}
        print(json.dumps(rec), flush=True)
        with args.out.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(rec) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
