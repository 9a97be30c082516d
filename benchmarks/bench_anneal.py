"""The ``anneal`` heuristic at the paper's scale beside the other multi-slot heuristics.

Instances: ``paper_spec(J, seed)`` (Problem I, L=4, T=60, bundled Lumos5G traces scaled to 11.8
Mbit/s), J=20 seeds 0-9, J=50 and J=200 seeds 0-4: the instances of ``exact.md``. Per instance,
``anneal`` with its default rounds and with ``--time-limit`` seconds, and ``rolling-future:bb``
(its start) for reference; the gap is to the best bound known and to the best schedule known of
every record under ``benchmarks/results/`` (per-slot budget) and of this run. Records go to
``anneal_runs.jsonl`` as they finish (resumable); ``--report`` writes ``anneal.md``.

    .venv/bin/python benchmarks/bench_anneal.py [--time-limit 5]
    .venv/bin/python benchmarks/bench_anneal.py --report
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt import solve  # noqa: E402
from l3gs_opt.bench.suites import paper_spec  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
RUNS = RESULTS / "anneal_runs.jsonl"
SIZES = ((20, range(10)), (50, range(5)), (200, range(5)))


def _labels(time_limit: float) -> list[tuple[str, str, float | None]]:
    return [("rolling-future:bb", "rolling-future:bb", None), ("anneal", "anneal", None),
            (f"anneal {time_limit:g} s", "anneal", time_limit)]


def run(args: argparse.Namespace) -> None:
    done = set()
    if RUNS.exists():
        done = {(r["instance_id"], r["label"]) for r in map(json.loads, RUNS.read_text().splitlines())}
    with RUNS.open("a") as out:
        for J, seeds in SIZES:
            for seed in seeds:
                inst = paper_spec(J, seed).build()
                iid = f"T60-J{J}-s{seed}"
                for label, method, limit in _labels(args.time_limit):
                    if (iid, label) in done:
                        continue
                    load = os.getloadavg()[0]
                    sol = solve(inst, method, time_limit_s=limit, options={"bound": False})
                    rec = {"instance_id": iid, "label": label, "method": method, "time_limit_s": limit,
                           "status": sol.status.value, "objective": sol.objective, "runtime_s": sol.runtime_s,
                           "details": {k: v for k, v in sol.details.items() if k in ("start", "start_value")},
                           "loadavg_before": load, "loadavg_after": os.getloadavg()[0], "machine": machine_info(),
                           "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
                    out.write(dumps(rec) + "\n")
                    out.flush()
                    print(f"{iid} {label}: {sol.objective:.2f} in {sol.runtime_s:.1f} s", flush=True)


def _known() -> tuple[dict, dict]:
    """Best schedule and smallest bound per instance over every per-slot record under results/."""
    best: dict[str, float] = {}
    bound: dict[str, float] = {}
    for f in glob.glob(str(RESULTS / "*.jsonl")):
        if "cumulative" in f:
            continue
        for line in Path(f).read_text().splitlines():
            try:
                r = json.loads(line)
            except ValueError:
                continue
            iid = r.get("instance_id") or r.get("instance")
            if not isinstance(iid, str) or not iid.startswith("T60-J") or r.get("budget", "per_slot") != "per_slot":
                continue
            if r.get("params", {}).get("seed") not in (None, int(iid.split("-s")[1])):
                continue
            o, b = r.get("objective"), r.get("bound")
            if isinstance(o, (int, float)) and math.isfinite(o):
                best[iid] = max(best.get(iid, -math.inf), o)
            # Bounds only from the exact methods' records (a heuristic's LP bound is weaker anyway).
            if isinstance(b, (int, float)) and math.isfinite(b) and str(r.get("method", "")).startswith(("exact", "ilp")):
                bound[iid] = min(bound.get(iid, math.inf), b)
    return best, bound


def report(args: argparse.Namespace) -> None:
    recs = [json.loads(x) for x in RUNS.read_text().splitlines()]
    best, bound = _known()
    m = recs[0]["machine"]
    lines = ["# `anneal` at the paper's scale (Problem I, L=4, T=60)", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, packages {json.dumps(m['packages'])}; "
             f"runs one after another ({recs[0]['finished_utc']} to {recs[-1]['finished_utc']}), load average "
             f"(1 min) before/after each run in `anneal_runs.jsonl`. Gap to the best bound known (certified, from "
             "the `exact` and `ilp` records) and, in brackets, to the best schedule known (any record under "
             "`benchmarks/results/`, this run's included). `anneal` is a heuristic: its status is `feasible`. "
             "`anneal`: its default 8 rounds; `anneal N s`: the same, stopped at N seconds (the start heuristics "
             "included) when the rounds take longer. `rolling-future:bb` is its start.", "",
             "| instance | method | objective | gap to best bound | (to best known) | run time (s) |",
             "|---|---|---|---|---|---|"]
    per: dict[tuple[int, str], list[tuple[float, float]]] = {}
    for r in recs:
        iid, o = r["instance_id"], r["objective"]
        b, k = bound.get(iid), max(best.get(iid, o), o)
        gb = (b - o) / b if b else math.nan
        gk = (k - o) / k
        lines.append(f"| {iid} | {r['label']} | {o:.1f} | {gb:.2%} | ({gk:.2%}) | {r['runtime_s']:.1f} |")
        per.setdefault((int(iid.split("-J")[1].split("-")[0]), r["label"]), []).append((gk, r["runtime_s"]))
    lines += ["", "## Per size (median and largest gap to the best schedule known, median run time)", "",
              "| J | method | instances | median gap | largest gap | median run time (s) |", "|---|---|---|---|---|---|"]
    for (J, label), rows in sorted(per.items()):
        gaps = [g for g, _ in rows]
        lines.append(f"| {J} | {label} | {len(rows)} | {statistics.median(gaps):.3%} | {max(gaps):.3%} | "
                     f"{statistics.median(t for _, t in rows):.1f} |")
    (RESULTS / "anneal.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--time-limit", type=float, default=5.0, help="seconds, for the time-limited anneal row")
    ap.add_argument("--report", action="store_true")
    args = ap.parse_args(argv)
    report(args) if args.report else run(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
