"""A machine's first `exact`: the quick bench's T=20, J=10 instance under a time limit, each run in a
fresh process, first with numba's cache empty (``NUMBA_CACHE_DIR``: as on a fresh install), then
again with the cache the first run left; and the compile / load time of each kernel alone.

    python benchmarks/probe_kernels_cold.py --time-limit 5 --out benchmarks/results/kernels_cold_start.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.jsonout import dumps  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

SOLVE = textwrap.dedent("""
    import json, sys, time
    from l3gs_opt import solve
    from l3gs_opt.bench.suites import suite_specs
    spec = [s for s in suite_specs("l3gs", sizes=[10], seeds=1, quick=True) if s.kind == "problem"][0]
    inst = spec.build()
    began = time.perf_counter()
    sol = solve(inst, "exact", time_limit_s=float(sys.argv[1]))
    print(json.dumps({"instance": spec.instance_id, "status": sol.status.value, "objective": sol.objective,
                      "bound": sol.bound, "runtime_s": sol.runtime_s, "wall_s": time.perf_counter() - began,
                      "kernels": sol.details.get("kernels")}))
""")

KERNELS = textwrap.dedent("""
    import json
    from l3gs_opt import warm_up
    print(json.dumps(warm_up()))
""")


def run(script: str, cache: str, *args: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    proc = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, env=env, cwd=ROOT,
                          check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-limit", type=float, default=5.0)
    ap.add_argument("--out", default="benchmarks/results/kernels_cold_start.jsonl")
    args = ap.parse_args()
    rows = []
    for what, script, extra in (("exact", SOLVE, (str(args.time_limit),)), ("warm_up", KERNELS, ())):
        with tempfile.TemporaryDirectory() as cache:
            for cache_state in ("empty", "left by the run before"):
                row = {"what": what, "cache": cache_state, "time_limit_s": args.time_limit if extra else None,
                       "loadavg_before": os.getloadavg(), **run(script, cache, *extra)}
                row["loadavg_after"] = os.getloadavg()
                print(row, flush=True)
                rows.append(row)
    machine = machine_info()
    with open(args.out, "a", encoding="utf-8") as fh:
        for row in rows:
            fh.write(dumps({**row, "machine": machine}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
