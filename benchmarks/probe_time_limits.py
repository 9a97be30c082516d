"""Every method under short time limits (0.5 s, 2 s): the wall time of ``solve`` against its limit.

Instances: the paper-scale T=60 specs J=20 and J=200 (seed 1) and the single slot
``slot-J10000-s0``; exact's kernels warmed first. One JSON line per call (the first line: the
machine), written as it goes.

    python benchmarks/probe_time_limits.py benchmarks/results/time_limits_probe.jsonl
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

import l3gs_opt  # noqa: E402
from l3gs_opt import solve  # noqa: E402
from l3gs_opt.bench.suites import paper_spec, suite_specs  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402

LIMITS = (0.5, 2.0)
MULTI = [("exact", {}), ("anneal", {}), ("mpc:3", {}), ("rolling:bb", {}), ("rolling-future:bb", {}),
         ("ilp", {"backend": "highs"}), ("ilp", {"backend": "cbc"}), ("ilp", {"backend": "cpsat"}),
         ("lp", {}), ("slope", {}), ("static", {}), ("progressive", {})]
SINGLE = ("bb", "dp", "greedy", "fptas:0.01")


def timed(inst, method: str, limit: float, **kw) -> tuple[float, str]:
    began = time.perf_counter()
    try:
        status = solve(inst, method, time_limit_s=limit, **kw).status.value
    except l3gs_opt.L3gsError as e:
        status = f"error {type(e).__name__}: {e}"[:80]
    return time.perf_counter() - began, status


def main() -> int:
    out = open(sys.argv[1], "w", encoding="utf-8")
    out.write(dumps({"machine": machine_info()}) + "\n")
    l3gs_opt.warm_up()
    cases = [(f"J{J}", paper_spec(J, 1).build(), method, kw, {}) for J in (20, 200) for method, kw in MULTI]
    single = [s for s in suite_specs("l3gs", sizes=[10000], seeds=1) if s.kind == "l3gs_slot"][0]
    cases += [(single.instance_id, single.build(), method, {}, {"slot": 0}) for method in SINGLE]
    for name, inst, method, kw, extra in cases:
        for limit in LIMITS:
            wall, status = timed(inst, method, limit, **kw, **extra)
            print(name, method, kw.get("backend", ""), limit, round(wall, 2), status,
                  "OVER" if wall > limit + 0.5 else "", flush=True)
            out.write(dumps({"instance": name, "method": method, "backend": kw.get("backend"), "time_limit_s": limit,
                             "wall_s": wall, "status": status, "loadavg": os.getloadavg()}) + "\n")
            out.flush()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
