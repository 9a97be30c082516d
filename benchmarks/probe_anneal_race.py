"""Probe (issue 23 item 2, thirty-fourth session): `exact` with one annealing chain at the root or
two raced on the two cores (``search.ANNEAL_SEEDS``), A/B, one JSON line per run appended to
``--out``; ``--report`` prints the per-arm table. Also ``--chains``: each seed's chain alone from
the start heuristics' schedule, under the root's annealing share (its value against the optimum).

``--arm race`` is the code as it is (one seed per usable core: 0 and 1 on 2 cores); ``--arm single``
patches ANNEAL_SEEDS to (0,), the code before. Runs are meant to be made one after another on an otherwise idle machine.

    .venv/bin/python benchmarks/probe_anneal_race.py --arm single --seeds 0-9 --reps 2 --out runs.jsonl
    .venv/bin/python benchmarks/probe_anneal_race.py --out runs.jsonl --report
    .venv/bin/python benchmarks/probe_anneal_race.py --chains 8 --seeds 0,1,4 --out chains.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from l3gs_opt import solve, warm_up  # noqa: E402
from l3gs_opt.bench.suites import paper_spec  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.solvers.exact import search  # noqa: E402
from l3gs_opt.solvers.exact.anneal import anneal_schedule  # noqa: E402
from l3gs_opt.solvers.exact.lagrange import assignment_value  # noqa: E402
from machine import machine_info  # noqa: E402


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def run(args: argparse.Namespace) -> None:
    if args.arm == "single":
        search.ANNEAL_SEEDS = (0,)
    machine = machine_info()
    with open(args.out, "a", encoding="utf-8") as fh:
        for rep in range(args.reps):
            for seed in _seeds(args.seeds):
                inst = paper_spec(args.J, seed).build()
                load = os.getloadavg()
                sol = solve(inst, "exact", time_limit_s=args.time_limit)
                d = sol.details
                z_at = next((p[0] for p in d["trace"] if p[1] >= sol.objective - 1e-9), None)
                rec = {"J": args.J, "seed": seed, "rep": rep, "arm": args.arm,
                       "seeds_annealed": list(search.ANNEAL_SEEDS or search.mip_seeds()),
                       "status": sol.status.value, "objective": sol.objective, "bound": sol.bound,
                       "runtime_s": sol.runtime_s, "schedule_found_s": z_at, "after_anneal": d.get("after_anneal"),
                       "nodes": d.get("nodes"), "loadavg_before": load, "loadavg_after": os.getloadavg(),
                       "machine": machine, "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
                fh.write(dumps(rec) + "\n")
                fh.flush()
                print(args.arm, seed, rep, rec["status"], round(sol.objective, 2), f"{sol.runtime_s:.1f}s", flush=True)


def chains(args: argparse.Namespace) -> None:
    """Each annealing seed alone, from the schedule `exact` anneals from, for the root's share."""
    machine = machine_info()
    share = search.ANNEAL_SHARE * args.time_limit
    with open(args.out, "a", encoding="utf-8") as fh:
        for seed in _seeds(args.seeds):
            inst = paper_spec(args.J, seed).build()
            s = search._Search(inst, started=time.perf_counter(), time_limit_s=args.time_limit, max_nodes=None,
                               lns_width=8, branching="both")
            search.ANNEAL_SHARE, keep = 0.0, search.ANNEAL_SHARE   # the start and its local search only
            s.start(None)
            search.ANNEAL_SHARE = keep
            for k in range(args.chains):
                began = time.perf_counter()
                out = anneal_schedule(s.data, s.assign, deadline=began + share, seed=k, patience=search.ANNEAL_PATIENCE)
                rec = {"J": args.J, "seed": seed, "anneal_seed": k, "value": assignment_value(s.data, out),
                       "start": s.z, "seconds": time.perf_counter() - began, "machine": machine}
                fh.write(dumps(rec) + "\n")
                fh.flush()
                print(seed, k, round(rec["value"], 2), f"{rec['seconds']:.1f}s", flush=True)


def report(path: str) -> None:
    recs = [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]
    print("| J | arm | rep | proven | median time (s) | times by seed (s; * open, with its final gap) |")
    print("|---|---|---|---|---|---|")
    for J, arm, rep in sorted({(r["J"], r["arm"], r["rep"]) for r in recs}):
        rows = sorted((r for r in recs if (r["J"], r["arm"], r["rep"]) == (J, arm, rep)), key=lambda r: r["seed"])
        proven = sum(r["status"] == "optimal" for r in rows)
        med = statistics.median(r["runtime_s"] for r in rows)
        cells = ", ".join(f"s{r['seed']} {r['runtime_s']:.1f}" + ("" if r["status"] == "optimal" else
                          f"* ({(r['bound'] - r['objective']) / r['bound']:.1e})") for r in rows)
        print(f"| {J} | {arm} | {rep} | {proven} of {len(rows)} | {med:.1f} | {cells} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arm", choices=("race", "single"), default="race")
    ap.add_argument("--J", type=int, default=20)
    ap.add_argument("--seeds", default="0-9")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--chains", type=int, default=0, help="run each annealing seed alone instead (this many seeds)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--report", action="store_true")
    args = ap.parse_args()
    if args.report:
        report(args.out)
        return
    warm_up()
    chains(args) if args.chains else run(args)


if __name__ == "__main__":
    main()
