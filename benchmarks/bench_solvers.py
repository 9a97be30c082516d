"""Single-slot MCKP solvers vs the MILP backends, and the rolling scheduler's speed.

Families (one slot each):

* ``l3gs`` - L3GS-like: :func:`l3gs_opt.pipeline.synth.synth_instance` with J objects, L=4 layers,
  180 splats per object on average (Dirichlet shares), byte costs = splats x 248 B, the budget
  of 1 s at 11.8 Mbit/s = 1,475,000 bytes; a 90 degree field of view, so only the objects in
  view (about 40 %) have utility at the slot.
* ``l3gs-all`` - the same with a 360 degree view: every object has utility (the harder case;
  its MILP times match the ones quoted in issue 4).
* ``unc`` / ``weak`` / ``strong`` - Pisinger's MCKP classes (R = 1000, "A minimal algorithm for
  the multiple-choice knapsack problem", EJOR 1995): uncorrelated ``w, p ~ U[1, R]``; weakly
  correlated ``p ~ U[w - 10, w + 10]`` (>= 1); strongly correlated: per class sorted
  ``w' ~ U[1, R]``, ``p' = w' + 10`` and cumulative sums. Budget ``0.5 * sum_j (min_l w + max_l
  w)``. Our MCKP lets an object take no option ("at most one"), Pisinger's takes exactly one.

Methods: ``bb``, ``dp`` (where its table fits), ``greedy``, ``fptas:0.1`` (where it fits) and
the ILP on CBC, HiGHS and CP-SAT with a time limit. Plus ``rolling:bb`` on T=60 slots,
J=200, L=4 (synth instance, Lumos5G trace at 11.8 Mbit/s), scheduling time without the LP bound.

Resumable: every run is appended to ``solvers_runs.jsonl`` as it finishes (with the load
average at that moment) and skipped next time; ``solvers.md`` and ``solvers_summary.json`` are
rewritten from the JSONL at the end (``--report`` rewrites them only). The machine is shared
(2 cores, other jobs running): timings are noisy, so the load average is recorded with each.

    .venv/bin/python benchmarks/bench_solvers.py [--quick] [--time-limit 60] [--max-minutes M]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt import solve  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.errors import SolveError  # noqa: E402
from l3gs_opt.problem.instance import Instance  # noqa: E402
from l3gs_opt.pipeline.synth import synth_instance  # noqa: E402

BUDGET_L3GS = 1_475_000          # 1 s at 11.8 Mbit/s, bytes
SPLATS_PER_OBJECT = 180
BACKENDS = ("highs", "cbc", "cpsat")


def l3gs_instance(J: int, seed: int, *, fov_deg: float = 90.0) -> Instance:
    base = synth_instance(objects=J, layers=4, slots=1, seed=seed, total_splats=SPLATS_PER_OBJECT * J,
                          fov_deg=fov_deg)
    family = "l3gs" if fov_deg == 90.0 else "l3gs-all"
    return Instance(representation="layered", bandwidth=[BUDGET_L3GS], cost=base.cost, utility=base.utility,
                    meta={"family": family, "J": J, "seed": seed, "fov_deg": fov_deg})


def pisinger_instance(kind: str, J: int, L: int, seed: int, R: int = 1000) -> Instance:
    rng = np.random.default_rng(seed)
    if kind == "unc":
        w = rng.integers(1, R + 1, (J, L))
        p = rng.integers(1, R + 1, (J, L))
    elif kind == "weak":
        w = rng.integers(1, R + 1, (J, L))
        p = np.maximum(1, w + rng.integers(-10, 11, (J, L)))
    elif kind == "strong":
        wp = np.sort(rng.integers(1, R + 1, (J, L)), axis=1)
        w, p = np.cumsum(wp, axis=1), np.cumsum(wp + 10, axis=1)
    else:
        raise ValueError(kind)
    budget = int(0.5 * (w.min(axis=1) + w.max(axis=1)).sum())
    return Instance(representation="separate", bandwidth=[budget], cost=w, utility=p[None].astype(np.float64),
                    meta={"family": kind, "J": J, "L": L, "seed": seed, "R": R})


def make_instance(family: str, J: int, L: int, seed: int) -> Instance:
    if family == "l3gs":
        return l3gs_instance(J, seed)
    if family == "l3gs-all":
        return l3gs_instance(J, seed, fov_deg=360.0)
    return pisinger_instance(family, J, L, seed)


def plan(quick: bool) -> list[dict]:
    """Runs in priority order (the ones the goals need first)."""
    seeds = [0] if quick else [0, 1, 2, 3, 4]
    sizes = [100, 1000] if quick else [100, 1000, 10000]
    runs: list[dict] = []
    fams = [("l3gs", 4), ("l3gs-all", 4), ("unc", 10), ("weak", 10), ("strong", 10)]
    pis = fams[2:]
    for J in sizes:
        for fam, L in fams:
            for seed in seeds:
                for method in ("bb", "greedy", "dp", "fptas:0.1"):
                    runs.append({"kind": "slot", "family": fam, "J": J, "L": L, "seed": seed, "method": method})
    for seed in seeds:
        runs.append({"kind": "rolling", "family": "synth", "J": 200, "L": 4, "T": 60, "seed": seed,
                     "method": "rolling:bb"})
    backends = ["highs"] if quick else list(BACKENDS)
    # MILPs: the L3GS-like family first (the speed goals are stated on it), then Pisinger's
    # classes by size; the J = 10,000 Pisinger MILPs (60 s each, mostly time limits) last.
    order = [(fam, J) for fam in ("l3gs", "l3gs-all") for J in sizes] \
        + [(fam, J) for J in sizes for fam, _ in pis if J < 10000] \
        + [(fam, J) for J in sizes for fam, _ in pis if J >= 10000]
    Ls = dict(fams)
    for fam, J in order:
        for seed in seeds:
            for b in backends:
                runs.append({"kind": "slot", "family": fam, "J": J, "L": Ls[fam], "seed": seed, "method": "ilp",
                             "backend": b})
    return runs


def key_of(run: dict) -> str:
    return "|".join(f"{k}={run[k]}" for k in sorted(run))


def execute(run: dict, time_limit: float) -> dict:
    rec = dict(run)
    rec["key"] = key_of(run)
    if run["kind"] == "rolling":
        inst = synth_instance(objects=run["J"], layers=run["L"], slots=run["T"], seed=run["seed"])
        load = os.getloadavg()
        cpu = time.process_time()
        started = time.perf_counter()
        sol = solve(inst, method="rolling:bb", options={"bound": False})
        rec.update(wall_s=time.perf_counter() - started, cpu_s=time.process_time() - cpu, runtime_s=sol.runtime_s,
                   objective=sol.objective,
                   status=sol.status.value, loadavg=load)
        return rec
    inst = make_instance(run["family"], run["J"], run["L"], run["seed"])
    load = os.getloadavg()
    cpu = time.process_time()
    started = time.perf_counter()
    try:
        sol = solve(inst, method=run["method"], backend=run.get("backend", "highs"), slot=0,
                    time_limit_s=time_limit)
    except SolveError as exc:
        rec.update(error=str(exc), loadavg=load, wall_s=time.perf_counter() - started)
        return rec
    rec.update(wall_s=time.perf_counter() - started, runtime_s=sol.runtime_s, objective=sol.objective,
               cpu_s=time.process_time() - cpu,   # this process only: not CBC's solver process
               bound=sol.bound, gap=sol.gap, status=sol.status.value, loadavg=load,
               backend_version=sol.backend_version, time_limit_s=time_limit if run["method"] == "ilp" else None,
               details={k: v for k, v in sol.details.items() if isinstance(v, (int, float, str))})
    return rec


# -- report --------------------------------------------------------------------------------------

def _med(xs: list[float]) -> float:
    return float(np.median(xs)) if xs else math.nan


def summarise(recs: list[dict]) -> dict:
    """Per (family, J, L, method/backend): median and max runtime, statuses, agreement with bb."""
    by: dict[tuple, list[dict]] = defaultdict(list)
    for r in recs:
        if r["kind"] != "slot":
            continue
        name = r["method"] if r["method"] != "ilp" else f"ilp/{r['backend']}"
        by[(r["family"], r["J"], r["L"], name)].append(r)
    bb = {(r["family"], r["J"], r["L"], r["seed"]): r for r in recs
          if r["kind"] == "slot" and r["method"] == "bb" and "objective" in r}
    rows = []
    for (fam, J, L, name), rs in sorted(by.items()):
        ok = [r for r in rs if "objective" in r]
        agree, worse_than_bb, better_than_bb = 0, 0, 0
        for r in ok:
            ref = bb.get((fam, J, L, r["seed"]))
            if ref is None:
                continue
            diff = r["objective"] - ref["objective"]
            tol = 1e-9 * max(1.0, abs(ref["objective"]))
            agree += abs(diff) <= tol
            worse_than_bb += diff < -tol
            better_than_bb += diff > tol
        rows.append({"family": fam, "J": J, "L": L, "method": name, "runs": len(rs), "solved": len(ok),
                     "errors": [r["error"][:80] for r in rs if "error" in r][:1],
                     "median_s": _med([r["runtime_s"] for r in ok]),
                     "max_s": max([r["runtime_s"] for r in ok], default=math.nan),
                     "median_cpu_s": _med([r["cpu_s"] for r in ok if "cpu_s" in r]),
                     "statuses": sorted({r["status"] for r in ok}),
                     "same_as_bb": agree, "worse_than_bb": worse_than_bb, "better_than_bb": better_than_bb,
                     "median_gap": _med([r["gap"] for r in ok if r.get("gap") is not None]),
                     "median_load": _med([r["loadavg"][0] for r in rs])})
    rolling = [r for r in recs if r["kind"] == "rolling"]
    ratios = []
    for fam, J, L in sorted({(r["family"], r["J"], r["L"]) for r in recs if r["kind"] == "slot"}):
        seeds = sorted({r["seed"] for r in recs if r["kind"] == "slot" and r["family"] == fam and r["J"] == J})
        per_seed = []
        for s in seeds:
            b = bb.get((fam, J, L, s))
            milps = [r for r in recs if r["kind"] == "slot" and r["method"] == "ilp" and r["family"] == fam
                     and r["J"] == J and r["seed"] == s and r.get("status") == "optimal"]
            if b is None or not milps:
                continue
            fastest = min(milps, key=lambda r: r["runtime_s"])
            per_seed.append({"seed": s, "bb_s": b["runtime_s"], "bb_cpu_s": b.get("cpu_s", math.nan),
                             "fastest_milp": fastest["backend"],
                             "milp_s": fastest["runtime_s"], "ratio": fastest["runtime_s"] / b["runtime_s"],
                             "same_optimum": abs(fastest["objective"] - b["objective"])
                             <= 1e-9 * max(1.0, abs(b["objective"]))})
        if per_seed:
            ratios.append({"family": fam, "J": J, "L": L, "seeds": per_seed,
                           "median_ratio": _med([p["ratio"] for p in per_seed]),
                           "min_ratio": min(p["ratio"] for p in per_seed),
                           "median_bb_s": _med([p["bb_s"] for p in per_seed])})
    return {"rows": rows, "speedups": ratios,
            "rolling": [{"seed": r["seed"], "runtime_s": r["runtime_s"], "cpu_s": r.get("cpu_s", math.nan),
                         "loadavg": r["loadavg"]} for r in rolling]}


def _verdict(median: float, worst: float, goal: float) -> str:
    if worst >= goal:
        return "met on every seed"
    if median >= goal:
        return "met on the median, not on every seed"
    return "MISSED"


def goal_lines(recs: list[dict], summary: dict) -> list[str]:
    """One line per goal of issue 4, met or missed, from the recorded runs only."""
    out = []
    for fam in ("l3gs", "l3gs-all"):
        for J, ratio_goal, time_goal in ((1000, 50, 0.010), (10000, 200, 0.050)):
            sp = next((x for x in summary["speedups"] if x["family"] == fam and x["J"] == J), None)
            if sp is None:
                out.append(f"- {fam}, J={J}: no MILP finished with a proof yet.")
                continue
            bb_med = sp["median_bb_s"]
            bb_cpu = _med([p["bb_cpu_s"] for p in sp["seeds"]])
            same = sum(p["same_optimum"] for p in sp["seeds"])
            out.append(f"- {fam}, J={J}: bb median {1e3 * bb_med:.1f} ms wall / {1e3 * bb_cpu:.1f} ms CPU "
                       f"(goal < {1e3 * time_goal:.0f} ms: {'met' if bb_med < time_goal else 'MISSED'}); speed-up "
                       f"over the fastest proving MILP median {sp['median_ratio']:.0f}x, min {sp['min_ratio']:.0f}x "
                       f"(goal >= {ratio_goal}x: {_verdict(sp['median_ratio'], sp['min_ratio'], ratio_goal)}); "
                       f"same optimum on {same}/{len(sp['seeds'])} seeds.")
    strong = [r for r in recs if r["kind"] == "slot" and r["family"] == "strong" and r["J"] == 10000
              and r["method"] == "bb" and "objective" in r]
    if strong:
        walls = [r["runtime_s"] for r in strong]
        cpus = [r.get("cpu_s", math.nan) for r in strong]
        proven = sum(r["status"] == "optimal" for r in strong)
        out.append(f"- strongly correlated, J=10,000, L=10: bb proved optimality on {proven}/{len(strong)} seeds; "
                   f"wall s {', '.join(f'{w:.1f}' for w in walls)}; CPU s {', '.join(f'{c:.1f}' for c in cpus)} "
                   f"(goal < 10 s: {sum(w < 10 for w in walls)}/{len(walls)} by wall time, "
                   f"{sum(c < 10 for c in cpus)}/{len(cpus)} by CPU time).")
    if summary["rolling"]:
        worst = max(r["runtime_s"] for r in summary["rolling"])
        out.append(f"- rolling:bb, T=60, J=200, L=4: at most {worst:.3f} s per schedule over "
                   f"{len(summary['rolling'])} seeds (goal < 1 s: {'met' if worst < 1 else 'MISSED'}).")
    return out


def write_report(jsonl: Path, out: Path, machine: dict) -> None:
    recs = [json.loads(line) for line in jsonl.read_text().splitlines() if line.strip()]
    summary = summarise(recs)
    summary["machine"] = machine
    (out / "solvers_summary.json").write_text(dumps(summary, indent=1, other=str))
    lines = ["# Single-slot MCKP solvers vs MILP backends", "",
             "Written by `benchmarks/bench_solvers.py` from `solvers_runs.jsonl` (every run, with the 1-minute "
             "load average at its start). Times are `Solution.runtime_s` (model build + solve, before the "
             "library's exact re-check), in seconds. **Shared machine**: other jobs ran on the same 2 cores, so "
             "the times are noisy; the load average is given per row, and `cpu s` is the CPU time of this "
             "process (a lower bound on an idle machine's wall time for the in-process solvers; CBC runs in "
             "its own process, so its CPU time is not counted).", "",
             f"Machine: {machine.get('cpu')}, {machine.get('cores')} cores, Python {machine.get('python')}; "
             f"packages {machine.get('packages')}.", "",
             "## bb vs the fastest MILP that proved optimality (per seed)", "",
             "| family | J | L | seeds | bb median s | bb median cpu s | fastest MILP s (median) | speed-up median | "
             "min | same optimum |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for s in summary["speedups"]:
        lines.append(f"| {s['family']} | {s['J']} | {s['L']} | {len(s['seeds'])} | {s['median_bb_s']:.4f} | "
                     f"{_med([p['bb_cpu_s'] for p in s['seeds']]):.4f} | "
                     f"{_med([p['milp_s'] for p in s['seeds']]):.3f} | {s['median_ratio']:.0f}x | "
                     f"{s['min_ratio']:.0f}x | {sum(p['same_optimum'] for p in s['seeds'])}/{len(s['seeds'])} |")
    lines += ["", "## Every method", "",
              "| family | J | L | method | runs | solved | median s | max s | median cpu s | statuses | = bb | < bb | "
              "> bb | median gap | load | note |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in summary["rows"]:
        note = r["errors"][0] if r["errors"] else ""
        lines.append(f"| {r['family']} | {r['J']} | {r['L']} | {r['method']} | {r['runs']} | {r['solved']} | "
                     f"{r['median_s']:.4f} | {r['max_s']:.4f} | {r['median_cpu_s']:.4f} | {', '.join(r['statuses'])} | "
                     f"{r['same_as_bb']} | "
                     f"{r['worse_than_bb']} | {r['better_than_bb']} | {r['median_gap']:.2e} | "
                     f"{r['median_load']:.2f} | {note} |")
    lines += ["", "## Issue 4's speed goals, as measured here", ""] + goal_lines(recs, summary)
    if summary["rolling"]:
        lines += ["", "## rolling:bb, T=60 slots, J=200, L=4 (scheduling only, no LP bound)", "",
                  "| seed | seconds | cpu s | load |", "|---|---|---|---|"]
        for r in summary["rolling"]:
            lines.append(f"| {r['seed']} | {r['runtime_s']:.3f} | {r['cpu_s']:.3f} | {r['loadavg'][0]:.2f} |")
    (out / "solvers.md").write_text("\n".join(lines) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="J <= 1000, one seed, HiGHS only, 10 s limit")
    ap.add_argument("--time-limit", type=float, default=None, help="seconds per MILP (default 60, quick 10)")
    ap.add_argument("--max-minutes", type=float, default=None, help="stop starting new runs after this long")
    ap.add_argument("--report", action="store_true", help="only rewrite the report from the JSONL")
    ap.add_argument("--redo", default="", help="comma-separated methods whose finished runs are dropped and rerun "
                                               "(e.g. bb,greedy after a solver change)")
    ap.add_argument("--only", default="", help="comma-separated methods to run now (others are left for later)")
    ap.add_argument("--families", default="", help="comma-separated families that --redo and this run touch "
                                                   "(e.g. l3gs,l3gs-all to re-time bb and the MILPs side by side)")
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = "solvers_quick" if args.quick else "solvers"
    jsonl = out / f"{name}_runs.jsonl"
    machine = machine_info()
    if not args.report:
        time_limit = args.time_limit or (10.0 if args.quick else 60.0)
        done = set()
        redo = {m for m in args.redo.split(",") if m}
        families = {f for f in args.families.split(",") if f}

        def touched(rec: dict) -> bool:
            return not families or rec["family"] in families

        if redo and jsonl.exists():
            kept = [line for line in jsonl.read_text().splitlines()
                    if line.strip() and not (json.loads(line)["method"] in redo and touched(json.loads(line)))]
            jsonl.write_text("".join(line + "\n" for line in kept))
        if jsonl.exists():
            done = {json.loads(line)["key"] for line in jsonl.read_text().splitlines() if line.strip()}
        only = {m for m in args.only.split(",") if m}
        todo = [r for r in plan(args.quick)
                if key_of(r) not in done and (not only or r["method"] in only) and touched(r)]
        started = time.monotonic()
        with jsonl.open("a", encoding="utf-8") as fh:
            for run in tqdm(todo, desc="solver runs", unit="run"):
                if args.max_minutes is not None and time.monotonic() - started > 60 * args.max_minutes:
                    break
                rec = execute(run, time_limit)
                fh.write(dumps(rec) + "\n")
                fh.flush()
    if args.quick:
        # The quick report goes to solvers_quick.md so it never overwrites the full one.
        tmp = out / "_quick"
        tmp.mkdir(exist_ok=True)
        write_report(jsonl, tmp, machine)
        (out / "solvers_quick.md").write_text((tmp / "solvers.md").read_text())
        (out / "solvers_quick_summary.json").write_text((tmp / "solvers_summary.json").read_text())
        for p in tmp.iterdir():
            p.unlink()
        tmp.rmdir()
    else:
        write_report(jsonl, out, machine)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
