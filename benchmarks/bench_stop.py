"""How soon a stop request (the first Ctrl-C of ``l3gs-opt solve``, :mod:`l3gs_opt.stop`) ends a
long solve, and what it returns.

Each run gets a 600 s limit; a timer requests the stop after ``stop at`` seconds; the table gives
when the solve returned, its status, gap and message. T=60 bench instances of bench_exact.py
(none of them is proven within 60 s by these methods). CBC, PuLP's child process, gets SIGINT from
its adapter, resent until it acts (it does only in its tree search), and then stops as at its time
limit: its bound, and its best integer schedule if it has one.

    python benchmarks/bench_stop.py --out benchmarks/results/stop_latency.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_exact import bench_instance  # noqa: E402
from machine import machine_info  # noqa: E402

from l3gs_opt import solve, stop  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.bench.suites import paper_spec  # noqa: E402

#: (method, backend, J, seed, budget, seconds until the request, time limit)
CASES = [
    ("exact", "highs", 20, 0, "per_slot", 0.5, 600.0),
    ("exact", "highs", 20, 0, "per_slot", 6.0, 600.0),
    ("exact", "highs", 20, 0, "per_slot", 15.0, 600.0),
    ("exact", "highs", 20, 0, "per_slot", 30.0, 600.0),
    ("exact", "highs", 50, 1, "per_slot", 10.0, 600.0),
    ("exact", "highs", 200, 1, "per_slot", 10.0, 600.0),
    ("exact", "highs", 200, 1, "per_slot", 30.0, 600.0),
    ("exact", "highs", 50, 1, "cumulative", 3.0, 600.0),
    ("ilp", "highs", 50, 1, "per_slot", 3.0, 600.0),
    ("ilp", "cpsat", 20, 0, "per_slot", 3.0, 600.0),
    ("ilp", "cbc", 20, 0, "per_slot", 3.0, 600.0),
    ("ilp", "cbc", 200, 1, "per_slot", 10.0, 600.0),
]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/results/stop_latency.md", help="the Markdown report (JSON lines beside it)")
    args = ap.parse_args()
    out = Path(args.out)
    machine = machine_info()
    rows, records = [], []
    for method, backend, J, seed, budget, after, limit in CASES:
        spec = paper_spec(J, seed)
        inst = bench_instance(spec, budget)
        stop.clear()
        load = os.getloadavg()
        timer = threading.Timer(after, stop.request)
        started = time.perf_counter()
        timer.start()
        try:
            sol = solve(inst, method, backend=backend, time_limit_s=limit)
        finally:
            timer.cancel()
            stop.clear()
        returned = time.perf_counter() - started
        gap = "-" if sol.gap is None else f"{sol.gap:.1e}"
        label = method if method == "exact" else f"{method}/{backend}"
        rows.append(f"| {spec.instance_id} | {budget} | {label} | {limit:.0f} | {after:.1f} | {returned:.2f} | "
                    f"{returned - after:.2f} | {sol.status} | {gap} | {sol.message} |")
        records.append({"instance_id": spec.instance_id, "budget": budget, "method": label, "time_limit_s": limit,
                        "stop_at_s": after, "returned_s": returned, "status": str(sol.status),
                        "objective": sol.objective, "bound": sol.bound, "gap": sol.gap, "message": sol.message,
                        "loadavg_before": load, "loadavg_after": os.getloadavg(),
                        "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
        print(rows[-1], flush=True)
    lines = ["# A stop request against long solves", "", __doc__.split("\n\n")[1].replace("\n", " "), "",
             f"Machine: {machine['cpu']}, {machine['cores']} cores, Python {machine['python']}, packages "
             f"{json.dumps(machine['packages'])}; runs one after another, "
             f"{records[0]['finished_utc']} to {records[-1]['finished_utc']}.", "",
             "| instance | budget | method | limit (s) | stop at (s) | returned at (s) | after the request (s) "
             "| status | gap | message |", "|---|---|---|---|---|---|---|---|---|---|", *rows]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out.with_suffix(".jsonl").write_text("".join(dumps(r) + "\n" for r in records), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
