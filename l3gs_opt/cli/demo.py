"""The README's demo: which method should a scheduler use, how far from optimal, at what cost?

1. The quick benchmark (``l3gs-opt bench --quick``): every suite, exact ILPs against the fast
   solvers and schedulers, a table per suite and plots in ``OUT/bench/``.
2. One L3GS-like scene on a real 5G trace solved by every backend in both forms, with the
   single-slot knapsack, compared in one table (``OUT/instance.json``, ``OUT/results.jsonl``).
3. and 4. Scene -> schedule -> picture, then the same scene through the online simulator
   (:mod:`.demo_scene`, ``OUT/scene/``).
5. The paper's experiments, quick (``l3gs-opt experiments --quick``): SSIM per method over real
   traces, ablations, latency and exact ceilings (``OUT/experiments/report.md``). Resumable: a
   second ``demo`` with the same ``OUT`` skips the records already there.
"""

from __future__ import annotations

import time
from pathlib import Path

from tqdm import tqdm

from l3gs_opt.methods import solve
from l3gs_opt.problem.instance_io import save_instance
from l3gs_opt.models.backends import installed_backends
from l3gs_opt.records import RecordLog
from l3gs_opt.bench.report_table import comparison_table
from l3gs_opt.pipeline.synth import synth_instance

__all__ = ["run_demo", "DEMO_SETTINGS"]

#: The built-in default: small enough that every backend finishes in seconds.
DEMO_SETTINGS = {"objects": 8, "layers": 4, "slots": 20, "seed": 0, "trace": "lumos-throughput-mid-11",
                 "mbps": 11.8, "start": 100}


def _quick_bench(out_dir: Path) -> None:
    from l3gs_opt.bench.run import BenchTask, read_records, run_bench
    from l3gs_opt.bench.report import annotate, summarise, write_report
    from l3gs_opt.bench.suites import ALL_SUITES, default_methods, suite_specs

    bench_dir = out_dir / "bench"
    tasks = [BenchTask(spec, m) for suite in ALL_SUITES for spec in suite_specs(suite, seeds=1, quick=True)
             for m in default_methods(spec, quick=True)]
    print(f"1. quick benchmark: {len(tasks)} records (instance x method), 5 s per record at most")
    path = run_bench(tasks, bench_dir / "results.jsonl", time_limit_s=5.0, jobs=1, resume=True)
    report = write_report(path, bench_dir, title="l3gs-opt quick benchmark")
    records = annotate(read_records(path))
    for suite, methods in summarise(records).items():
        print(f"\n  suite {suite}:  method / records / proven optimal / median time s / median error / max error")
        for m, s in sorted(methods.items(), key=lambda kv: kv[1]["median_time_s"] or 0):
            err = "bound only" if s["bound_only"] else (f"{s['median_error']:.1e} / {s['max_error']:.1e}"
                                                        if s["median_error"] is not None else "-")
            t = "-" if s["median_time_s"] is None else f"{s['median_time_s']:.4f}"
            # "declined": a method refusing an instance it cannot take (e.g. a DP table too large).
            flags = (f"  FLAGS: {', '.join(s['flags'])}" if s["flags"] else "") + \
                (f"  (declined {s['declined']})" if s["declined"] else "")
            print(f"    {m:<20} {s['records']:>3} {s['optimal']:>3}  {t:>9}  {err}{flags}")
    print(f"\n  report with plots: {report}\n")


def _quick_experiments(out_dir: Path) -> None:
    from l3gs_opt.experiments.plan import make_plan
    from l3gs_opt.experiments.run import run_experiments
    from l3gs_opt.experiments.report import summarize, write_report
    from l3gs_opt.bench.run import read_records

    plan = make_plan(quick=True, utilities=("eq1", "visibility"))
    print(f"5. the paper's experiments, quick: {len(plan.tasks())} records ({len(plan.windows())} windows of "
          f"real traces, methods {', '.join(m for m, _ in plan.methods)}); resumable", flush=True)
    started = time.perf_counter()
    runs = run_experiments(plan, out_dir, resume=True)
    report = write_report(runs, out_dir)
    summary = summarize(read_records(runs))
    print("\n  method / runs / mean SSIM (± std over windows)")
    for m, s in sorted(summary["methods"].items(), key=lambda kv: -kv[1]["ssim_mean"]):
        print(f"    {m:<24} {s['runs']:>3}  {s['ssim_mean']:.3f} ± {s['ssim_std']:.3f}")
    head = summary["headline"]
    if head.get("baselines"):
        print(f"  l3gs vs the baselines' mean: {head['vs_mean_of_baselines_pct']:+.1f}% "
              f"(paper: +16.9%); vs the best, {head['best_baseline']}: {head['vs_best_pct']:+.1f}%")
    for u, row in summary.get("utilities", {}).get("by_utility", {}).items():
        if row.get("baselines"):
            worst = min(row["baselines"], key=lambda b: row["baselines"][b]["l3gs_vs_pct"])
            print(f"  l3gs by {u}: {row['ssim_mean']:.3f} (first 5 s {row['ssim_first5']:.3f}); vs the baselines' "
                  f"mean {row['vs_mean_of_baselines_pct']:+.1f}%, vs sort and separate "
                  f"{row['vs_mean_of_paper_baselines_pct']:+.1f}%; weakest against {worst} "
                  f"({row['baselines'][worst]['l3gs_vs_pct']:+.1f}%)")
    print(f"  report with plots: {report} ({time.perf_counter() - started:.0f} s)\n")


def run_demo(out_dir: Path = Path("demo-out"), time_limit_s: float = 10.0, bench: bool = True,
             scene: bool = True, experiments: bool = True) -> int:
    out_dir.mkdir(parents=True, exist_ok=True)
    if bench:
        _quick_bench(out_dir)
        print("2. one scene, every exact backend and form")
    instance = synth_instance(**DEMO_SETTINGS)
    save_instance(instance, out_dir / "instance.json")
    meta = instance.meta
    print(f"l3gs-opt demo: {instance!r}")
    print(f"  bandwidth: trace {meta['trace']} scaled x{meta['scale_factor']:.4f} to a mean of "
          f"{meta['target_mean_mbps']} Mbit/s, window {meta['window']['start_s']}..+{meta['window']['length_s']} s "
          f"(window mean {meta['window_mean_mbps']:.2f} Mbit/s)")
    print(f"  scene: {meta['total_splats']} splats, {int(instance.cost.sum())} bytes in {instance.J} objects x "
          f"{instance.L} layers\n")
    runs = [("lp", b.value, "standard", None) for b in installed_backends()[:1]]
    for backend in installed_backends():
        runs += [("ilp", backend.value, "standard", None), ("ilp", backend.value, "gap", None),
                 ("ilp", backend.value, "standard", 0)]
    rows = []
    records = out_dir / "results.jsonl"
    started = time.perf_counter()
    with RecordLog(records, fresh=True, what="demo") as log:
        for method, backend, form, slot in tqdm(runs, desc="solving", unit="solve", leave=False):
            sol = solve(instance, method, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s)
            label = f"{method}/{backend}" + ("/gap" if form == "gap" else "") + (f"/slot{slot}" if slot is not None
                                                                                 else "")
            rows.append((label, sol))
            log.append({"label": label, **sol.to_dict()}, where=label)
    table = comparison_table(rows)
    (out_dir / "results.md").write_text(f"# l3gs-opt demo\n\n{instance!r}\n\n```\n{table}\n```\n", encoding="utf-8")
    print(table)
    exact = [s for _, s in rows if s.method == "ilp" and s.slot is None and s.proven_optimal]
    if exact:
        best = max(s.objective for s in exact)
        agree = all(abs(s.objective - best) <= 1e-6 * max(1.0, best) for s in exact)
        print(f"\n{len(exact)} proven optima of Problem {instance.problem} / its GAP form: "
              f"{'all agree' if agree else 'DISAGREE'} at {best:.6g} (Lemma 1: both forms have the same optimum)")
    print(f"total {time.perf_counter() - started:.1f} s; records in {records}\n")
    if scene:
        from l3gs_opt.cli.demo_scene import scene_story

        scene_story(out_dir / "scene", time_limit_s=time_limit_s)
    if experiments:
        _quick_experiments(out_dir / "experiments")
    return 0
