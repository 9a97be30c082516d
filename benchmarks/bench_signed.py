"""Signed layer utilities at the paper's scale: ``exact`` and the heuristics beside HiGHS, CBC and CP-SAT.

Instances: the ``l3gs`` suite's Problem I specs (``suite_specs("l3gs", sizes=[J], seeds=S)``, T=60:
layered, L=4, bundled Lumos5G traces scaled to 11.8 Mbit/s), made signed by one documented rule:
in a seeded ``--share`` of the objects the finest layer's utility becomes ``-factor`` times what it
was, in every slot (the finest refinement layer making the picture worse, as measured in layered
splat streaming). The rest of the instance is unchanged. Per instance: the unsigned original
(reference) and the signed one, each with ``exact``, ``ilp/highs``, ``ilp/cbc``, ``ilp/cpsat`` at
the same time limit and the multi-slot heuristics. Every objective is re-evaluated from the instance;
a heuristic never reports optimal. Records go to ``signed_runs.jsonl`` as they finish (resumable);
``--report`` writes ``signed.md``, ``signed_summary.json`` and a gap-against-time plot.

    .venv/bin/python benchmarks/bench_signed.py [--sizes 20] [--seeds 2] [--time-limit 60]
    .venv/bin/python benchmarks/bench_signed.py --report
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt import solve  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.bench.suites import split_method, suite_specs  # noqa: E402

EXACT_METHODS = ["exact", "ilp/highs", "ilp/cbc", "ilp/cpsat"]
HEURISTICS = ["rolling:bb", "rolling-future:bb", "mpc:3", "slope", "static"]
OUT = Path(__file__).resolve().parent / "results"


def signed(inst, *, share: float, factor: float, seed: int):
    """``inst`` with the finest layer of a seeded ``share`` of the objects worth ``-factor`` times as much."""
    rng = np.random.default_rng(seed)
    J = inst.J
    chosen = np.sort(rng.choice(J, size=max(1, int(round(share * J))), replace=False))
    u = np.array(inst.utility, dtype=np.float64)
    u[:, chosen, -1] *= -factor
    return inst.replace(utility=u), chosen.tolist()


def run(args: argparse.Namespace) -> None:
    path = Path(args.out) / "signed_runs.jsonl"
    done = set()
    if path.exists():
        for line in path.read_text().splitlines():
            rec = json.loads(line)
            done.add((rec["instance_id"], rec["form"], rec["label"]))
    machine = machine_info()
    specs = [s for s in suite_specs("l3gs", sizes=[int(x) for x in args.sizes.split(",")], seeds=args.seeds)
             if not s.single_slot]
    with path.open("a", encoding="utf-8") as fh:
        for spec in specs:
            original = spec.build()
            neg, chosen = signed(original, share=args.share, factor=args.factor, seed=args.seed)
            for form, inst in (("unsigned", original), ("signed", neg)):
                for label in EXACT_METHODS + HEURISTICS:
                    if (spec.instance_id, form, label) in done:
                        continue
                    name, kw = split_method(label)
                    load = os.getloadavg()
                    sol = solve(inst, name, time_limit_s=args.time_limit, **kw)
                    rec = {"instance_id": spec.instance_id, "form": form, "label": label, "J": inst.J, "T": inst.T,
                           "L": inst.L, "negative_objects": chosen if form == "signed" else [],
                           "share": args.share, "factor": args.factor, "loadavg_before": load,
                           "loadavg_after": os.getloadavg(), "time_limit_s": args.time_limit, "machine": machine,
                           "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **sol.to_dict()}
                    rec.pop("arrivals")
                    fh.write(dumps(rec) + "\n")
                    fh.flush()
                    print(spec.instance_id, form, label, rec["status"], rec["objective"], rec["bound"], rec["gap"],
                          f"{rec['runtime_s']:.1f}s", flush=True)


def report(args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(args.out)
    recs = [json.loads(x) for x in (out / "signed_runs.jsonl").read_text().splitlines()]
    m = recs[0]["machine"]
    lines = ["# Signed layer utilities at the paper's scale (issue 23, item 3)", "",
             f"Instances: the `l3gs` suite's Problem I specs (layered, L=4, T=60, bundled Lumos5G traces scaled to "
             f"11.8 Mbit/s); in {recs[0]['share']:.0%} of the objects (seeded) the finest layer's utility is "
             f"multiplied by -{recs[0]['factor']} in every slot. Each instance also runs unsigned (the original) as "
             f"the reference. Same time limit for every method ({recs[0]['time_limit_s']} s), runs sequential.", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}; packages {m['packages']}. The machine "
             "was shared (1-minute load before/after each run in the table).", "",
             "| instance | form | method | status | objective | bound | gap | time (s) | load |",
             "|---|---|---|---|---|---|---|---|---|"]
    summary: dict = {}
    for r in recs:
        gap = "-" if r["gap"] is None else f"{r['gap']:.2e}"
        bound = "-" if r["bound"] is None else f"{r['bound']:.7g}"
        lines.append(f"| {r['instance_id']} | {r['form']} | {r['label']} | {r['status']} | {r['objective']:.7g} | "
                     f"{bound} | {gap} | {r['runtime_s']:.1f} | {r['loadavg_before'][0]:.1f}/"
                     f"{r['loadavg_after'][0]:.1f} |")
        summary.setdefault(r["instance_id"], {}).setdefault(r["form"], {})[r["label"]] = {
            k: r[k] for k in ("status", "objective", "bound", "gap", "runtime_s")}
    lines += ["", "## Checks", ""]
    for iid, forms in summary.items():
        for form, d in forms.items():
            best = max(v["objective"] for v in d.values())
            bounds = [v["bound"] for k, v in d.items() if v["bound"] is not None and k in EXACT_METHODS]
            tight = min(bounds) if bounds else None
            above = [k for k, v in d.items() if tight is not None and v["objective"] > tight * (1 + 1e-9) + 1e-9]
            lines.append(f"- {iid} {form}: best objective {best:.7g}, smallest exact-method bound "
                         f"{'-' if tight is None else f'{tight:.7g}'}; methods above that bound: {above or 'none'}; "
                         f"proven optimal by: {[k for k, v in d.items() if v['status'] == 'optimal'] or 'none'}.")
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, marker in zip(EXACT_METHODS, "os^D"):
        pts = [(r["runtime_s"], max(r["gap"], 1e-10)) for r in recs
               if r["label"] == label and r["form"] == "signed" and r["gap"] is not None]
        if pts:
            ax.scatter(*zip(*pts), marker=marker, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("run time (s)")
    ax.set_ylabel("final gap (1e-10 = proven)")
    ax.set_title("Problem I with signed layer utilities: gap against run time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "signed_gap_vs_time.png", dpi=110)
    plt.close(fig)
    (out / "signed_summary.json").write_text(dumps(summary, indent=1))
    (out / "signed.md").write_text("\n".join(lines) + "\n\n![gap against time](signed_gap_vs_time.png)\n")
    print(f"wrote {out / 'signed.md'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="20")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--share", type=float, default=0.4, help="share of objects whose finest layer turns negative")
    ap.add_argument("--factor", type=float, default=0.5, help="the negative layer is worth -factor x its utility")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--report", action="store_true")
    args = ap.parse_args()
    (report if args.report else run)(args)


if __name__ == "__main__":
    main()
