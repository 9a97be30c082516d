"""The ``knapsack-sets`` suite (Pisinger's large-scale and Jooken et al.'s hard 0-1 knapsack files
with published optima): ``bb`` against HiGHS, CBC and CP-SAT at one time limit.

Runs through the bench machinery (:func:`l3gs_opt.bench.run.run_bench`: a forked process per record,
killed past the hard limit, each answer re-checked in exact bytes) and reports with
:func:`l3gs_opt.bench.report.known_optima_summary`. Resumable: each ``run`` appends to its own
records file (one lock per file, so a slow MILP run and a ``bb`` run can go side by side);
``report`` merges the files into ``benchmarks/results/knapsack_sets.jsonl`` and writes
``knapsack_sets.md`` and ``knapsack_sets.json``. The machine is shared: the ``uptime`` load is
logged at each run's start and end (``RECORDS.meta.jsonl``) and every record has its own.

    .venv/bin/python benchmarks/bench_knapsack_sets.py run --methods bb --records /tmp/ks-bb.jsonl
    .venv/bin/python benchmarks/bench_knapsack_sets.py report /tmp/ks-bb.jsonl /tmp/ks-ilp.jsonl
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from machine import machine_info  # noqa: E402

from l3gs_opt.bench.report import known_optima_lines, known_optima_summary, annotate  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.bench.run import BenchTask, check_records, read_records, run_bench  # noqa: E402
from l3gs_opt.bench.suites import default_methods, suite_specs  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
SUITE = "knapsack-sets"


def _uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip()


def _meta(records: Path, **fields: object) -> None:
    with open(f"{records}.meta.jsonl", "a", encoding="utf-8") as fh:
        fh.write(dumps({"time": time.strftime("%Y-%m-%d %H:%M:%S"), "uptime": _uptime(), **fields}) + "\n")


def cmd_run(args: argparse.Namespace) -> None:
    specs = suite_specs(SUITE, quick=args.quick)
    if args.only:
        specs = [s for s in specs if s.params["set"] == args.only]
    methods = args.methods.split(",") if args.methods else None
    tasks = [BenchTask(s, m) for s in specs for m in (methods or default_methods(s))]
    if not tasks:
        return
    records = Path(args.records)
    _meta(records, event="start", methods=methods, tasks=len(tasks), time_limit_s=args.time_limit,
          machine=machine_info())
    run_bench(tasks, records, time_limit_s=args.time_limit, jobs=args.jobs, resume=True, progress=not args.quiet)
    _meta(records, event="end")


def cmd_report(args: argparse.Namespace) -> None:
    records = []
    meta = []
    for path in args.records:
        records += check_records(read_records(path), field=path)
        meta_path = Path(f"{path}.meta.jsonl")
        if meta_path.exists():
            meta += [json.loads(line) for line in meta_path.read_text().splitlines() if line.strip()]
    # One record per (instance, method): the last one written wins (a re-run after a change).
    last = {r["record_id"]: r for r in records}
    records = list(last.values())
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_suffix(".jsonl"), "w", encoding="utf-8") as fh:
        for r in records:
            fh.write(dumps(r) + "\n")
    summary = known_optima_summary(annotate(records), slow_s=args.slow)
    machine = machine_info()
    doc = {"machine": machine, "runs": meta, "uptime_at_report": _uptime(),
           "summary": [{"suite": k[0], "set": k[1], "method": k[2], **v} for k, v in summary.items()]}
    out.with_suffix(".json").write_text(dumps(doc, indent=1) + "\n", encoding="utf-8")
    print("\n".join(known_optima_lines(summary)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--methods", default=None, help="comma-separated labels (default: bb and the three MILPs)")
    r.add_argument("--records", required=True)
    r.add_argument("--time-limit", type=float, default=20.0)
    r.add_argument("--jobs", type=int, default=1)
    r.add_argument("--only", choices=["pisinger", "jooken"], default=None)
    r.add_argument("--quick", action="store_true")
    r.add_argument("--quiet", action="store_true")
    p = sub.add_parser("report")
    p.add_argument("records", nargs="+")
    p.add_argument("--out", default=str(RESULTS / "knapsack_sets.md"))
    p.add_argument("--slow", type=float, default=20.0)
    args = ap.parse_args(argv)
    {"run": cmd_run, "report": cmd_report}[args.cmd](args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
