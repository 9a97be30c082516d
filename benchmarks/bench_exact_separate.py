"""``exact`` on Problem II (separate versions) against the generic MILPs at the paper's scale.

Instances: ``_problem(representation="separate", ...)`` of the bench suites (``synth_instance``:
L=4 versions, T=60 one-second slots, bundled Lumos5G traces scaled to a mean of 11.8 Mbit/s, the
window starting at 60 s x seed, the trace picked by seed as in the ``l3gs`` suite), J in
``--sizes`` (default 8, 14, 20) and ``--seeds`` seeds each. Per instance ``exact``, ``ilp/highs``,
``ilp/cbc`` and ``ilp/cpsat`` run one after the other with the same time limit.

Records go to ``exact_separate.runs.jsonl`` as they finish (resumable); ``--report`` writes
``exact_separate.md``, ``exact_separate.json`` and ``exact_separate.gap_vs_time.png`` (the
incumbent/bound gap of ``exact`` over time from its trace, with the final gap of each MILP).

    .venv/bin/python benchmarks/bench_exact_separate.py [--time-limit 60] [--sizes 8 14 20] [--seeds 2]
    .venv/bin/python benchmarks/bench_exact_separate.py --report
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_exact import trace_gap  # noqa: E402
from machine import machine_info, machines_line  # noqa: E402

from l3gs_opt import solve  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.bench.suites import _problem, _traces, split_method  # noqa: E402

METHODS = ["exact", "ilp/highs", "ilp/cbc", "ilp/cpsat"]
RUNS = "exact_separate.runs.jsonl"


def specs(sizes: list[int], seeds: int) -> list[tuple[str, dict]]:
    traces = _traces()
    return [(f"II-T60-J{J}-s{s}", {"representation": "separate", "objects": J, "slots": 60, "seed": s,
                                   "trace": traces[s % len(traces)], "start": 60 * s})
            for J in sizes for s in range(seeds)]


def _uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def run(args: argparse.Namespace) -> None:
    out = Path(args.out)
    path = out / RUNS
    done = set()
    if path.exists():
        for line in path.read_text().splitlines():
            rec = json.loads(line)
            if "instance_id" in rec:    # (not the uptime lines)
                done.add((rec["instance_id"], rec["label"]))
    machine = machine_info()
    with path.open("a", encoding="utf-8") as fh:
        fh.write(dumps({"label": "uptime:start", "uptime": _uptime(), "machine": machine}) + "\n")
        for iid, params in specs(args.sizes, args.seeds):
            inst = _problem(**params)
            for label in METHODS:
                if (iid, label) in done:
                    continue
                name, kw = split_method(label)
                load_before = os.getloadavg()
                sol = solve(inst, name, time_limit_s=args.time_limit, **kw)
                rec = {"instance_id": iid, "params": params, "J": inst.J, "T": inst.T, "L": inst.L, "label": label,
                       "loadavg_before": load_before, "loadavg_after": os.getloadavg(),
                       "time_limit_s": args.time_limit, "machine": machine,
                       "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **sol.to_dict()}
                rec.pop("arrivals")
                fh.write(dumps(rec) + "\n")
                fh.flush()
                print(iid, label, rec["status"], rec["objective"], rec["bound"], rec["gap"],
                      f"{rec['runtime_s']:.1f}s", flush=True)
        fh.write(dumps({"label": "uptime:end", "uptime": _uptime()}) + "\n")


def report(args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(args.out)
    lines_all = [json.loads(x) for x in (out / RUNS).read_text().splitlines()]
    uptimes = [r for r in lines_all if r["label"].startswith("uptime:")]
    recs = [r for r in lines_all if "instance_id" in r]
    by_inst: dict[str, dict[str, dict]] = {}
    for r in recs:
        by_inst.setdefault(r["instance_id"], {})[r["label"]] = r
    m = recs[0]["machine"]
    summary: dict = {"machine": m, "uptime": [u["uptime"] for u in uptimes], "instances": {}}
    md = ["# `exact` on Problem II (separate versions) at the paper's scale", "",
          "Instances: `l3gs_opt.bench.suites._problem(representation=\"separate\", ...)` (synthetic L3GS-like scene, "
          "L=4 versions whose costs and utilities are cumulative over the layers, T=60 one-second slots, "
          "bundled Lumos5G traces scaled to a mean of 11.8 Mbit/s, window from 60 s x seed). Every method "
          f"got the same time limit ({recs[0]['time_limit_s']} s); runs were sequential, in one process.", "",
          f"{machines_line(recs)} `uptime` at the start and end of each run, and the 1-minute load "
          "before/after each record, are below: a load above 2 means the 2 cores were shared with other work "
          "(the first runs shared theirs with a long benchmark).", ""]
    md += [f"- `{u['label']}`: {u['uptime']}" for u in uptimes] + [""]
    md += ["Gap = (bound - objective) / bound, each method's own certified bound. `status` optimal = gap <= 1e-9.",
           "", "| instance | method | status | objective | bound | gap | run time (s) | load before/after |",
           "|---|---|---|---|---|---|---|---|"]
    for iid, d in by_inst.items():
        summary["instances"][iid] = {}
        for label in METHODS:
            r = d.get(label)
            if r is None:
                continue
            gap = "-" if r["gap"] is None else f"{r['gap']:.2e}"
            bound = "-" if r["bound"] is None else f"{r['bound']:.9g}"
            md.append(f"| {iid} | {label} | {r['status']} | {r['objective']:.9g} | {bound} | {gap} | "
                      f"{r['runtime_s']:.1f} | {r['loadavg_before'][0]:.1f}/{r['loadavg_after'][0]:.1f} |")
            summary["instances"][iid][label] = {k: r[k] for k in ("status", "objective", "bound", "gap", "runtime_s")}
    md += ["", "## Per method and size", "",
           "Proven = status optimal within the limit; time = median run time of all runs (a run that hits the limit "
           "counts as the limit); gap = largest final gap.", "",
           "| J | method | proven | median time (s) | largest gap |", "|---|---|---|---|---|"]
    per: dict = {}
    for iid, d in by_inst.items():
        for label in METHODS:
            r = d.get(label)
            if r is not None:
                per.setdefault((r["J"], label), []).append(r)
    for (J, label), rs in sorted(per.items(), key=lambda kv: (kv[0][0], METHODS.index(kv[0][1]))):
        proven = sum(r["status"] == "optimal" for r in rs)
        times = sorted(r["runtime_s"] for r in rs)
        gaps = [r["gap"] for r in rs if r["gap"] is not None]
        median = times[len(times) // 2] if len(times) % 2 else 0.5 * (times[len(times) // 2 - 1] + times[len(times) // 2])
        md.append(f"| {J} | {label} | {proven}/{len(rs)} | {median:.1f} | {max(gaps):.2e} |" if gaps else
                  f"| {J} | {label} | {proven}/{len(rs)} | {median:.1f} | - |")
        summary.setdefault("per_size", {}).setdefault(str(J), {})[label] = {
            "proven": proven, "runs": len(rs), "median_runtime_s": median, "largest_gap": max(gaps) if gaps else None}
    md += ["", "## Inside `exact`", "",
           "Root: column generation over per-object paths (bound = Lagrangian over the budget rows). Fixed: "
           "(version, slot) arrivals the root certificate rules out at the incumbent before the HiGHS side. "
           "Nodes: branch-and-price nodes run beside HiGHS.", "",
           "| instance | start (best heuristic, value) | after local search | root bound (s) | root incumbent "
           "| fixed arrivals | nodes | paths | bound kind |", "|---|---|---|---|---|---|---|---|---|"]
    for iid, d in by_inst.items():
        r = d.get("exact")
        if r is None:
            continue
        det = r["details"]
        root = det.get("root", {})
        st = det.get("start", {})
        best = st.get("best")
        md.append(f"| {iid} | {best} {st.get('values', {}).get(best, float('nan')):.9g} | "
                  f"{det.get('after_local_search', float('nan')):.9g} | {root.get('bound', float('nan')):.9g} "
                  f"({root.get('seconds', 0):.1f}) | {root.get('incumbent', float('nan')):.9g} | "
                  f"{root.get('fixed_arrivals', '-')} | {det.get('nodes')} | {det.get('paths')} | "
                  f"{det.get('bound_kind')} |")
        summary["instances"][iid]["exact"]["details"] = {k: det.get(k) for k in ("start", "after_local_search",
                                                                                 "root", "nodes", "paths",
                                                                                 "bound_kind")}
    fig, ax = plt.subplots(figsize=(8, 5))
    colours = [plt.cm.tab20(i) for i in range(20)]   # one colour per instance (up to 20)
    for n, (iid, d) in enumerate(by_inst.items()):
        r = d.get("exact")
        if r is None:
            continue
        c = colours[n % len(colours)]
        pts = [(p[0], trace_gap(p, 1e-10)) for p in r["details"].get("trace", [])]
        pts = [p for p in pts if p[1] is not None]
        if r["status"] == "optimal":
            pts.append((r["runtime_s"], 1e-10))
        if pts:
            ax.step([p[0] for p in pts], [p[1] for p in pts], where="post", color=c, label=f"exact {iid}")
        for label, marker in (("ilp/highs", "o"), ("ilp/cbc", "s"), ("ilp/cpsat", "^")):
            o = d.get(label)
            if o is not None and o["gap"] is not None:
                ax.scatter([o["runtime_s"]], [max(o["gap"], 1e-10)], color=c, marker=marker, s=30)
    for label, marker in (("ilp/highs (final)", "o"), ("ilp/cbc (final)", "s"), ("ilp/cpsat (final)", "^")):
        ax.scatter([], [], color="grey", marker=marker, label=label)
    ax.set_yscale("log")
    ax.set_xscale("log")
    ax.set_xlabel("seconds (log)")
    ax.set_ylabel("gap (bound - incumbent) / bound; 1e-10 = proven")
    ax.set_title("Problem II, L=4, T=60: exact's gap over time (lines), MILPs' final gap (markers)")
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(out / "exact_separate.gap_vs_time.png", dpi=120)
    md += ["", "![gap against time](exact_separate.gap_vs_time.png)", "",
           "Notes (measured on these instances when this script was written): the path (Dantzig-Wolfe) root bound "
           "equals the LP relaxation's to ~1e-7 - the per-object path problem is nearly integral and the gap "
           "sits in the per-slot knapsacks - so branch-and-price alone closes J <= 12 but not J = 20 in 60 s "
           "(J20-s0: gap 5.6e-3 after 2,151 nodes); what proves J = 16-20 is the HiGHS side on the model "
           "reduced by the path certificate's fixing, with the start heuristics, exact per-object local "
           "search and the restricted-master MIP as its incumbent. At J = 50 no method proves; `exact` carries "
           "the smallest bound, HiGHS the better schedule on one of the two seeds.", ""]
    (out / "exact_separate.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    (out / "exact_separate.json").write_text(dumps(summary, indent=1) + "\n", encoding="utf-8")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--sizes", type=int, nargs="+", default=[8, 14, 20])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    ap.add_argument("--report", action="store_true")
    args = ap.parse_args()
    if args.report:
        report(args)
    else:
        run(args)


if __name__ == "__main__":
    main()
