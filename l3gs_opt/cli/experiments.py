"""CLI subcommand ``experiments``: the paper's evaluation on procedural scenes, resumable, with a report.

Wire into the main parser with ``register(subparsers)``. Bad input raises
:class:`l3gs_opt.errors.L3gsError` subclasses, which the main CLI prints as one line (exit 2).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

__all__ = ["register"]


def _list(text: str | None, option: str, what: str) -> list[str] | None:
    """The comma-separated names of ``option``; None when it is not given. An empty list is refused
    rather than read as "the default" or "none": an empty shell variable must not change the plan."""
    from l3gs_opt.experiments.plan import ExperimentError

    if text is None:
        return None
    parts = [part.strip() for part in text.split(",")]
    if not any(parts):
        raise ExperimentError(option, f"{text!r}: names no {what}")
    for i, part in enumerate(parts):
        if not part:
            raise ExperimentError(option, f"{text!r}: an empty {what} name (a comma too many?)", i)
    return parts


def _sizes(text: str | None) -> tuple[int, ...] | None:
    from l3gs_opt.experiments.plan import ExperimentError

    names = _list(text, "--sizes", "size")
    if names is None:
        return None
    out = []
    for i, v in enumerate(names):
        try:
            out.append(int(v))
        except ValueError:
            raise ExperimentError("--sizes", f"{v!r}: expected a whole number of splats", i) from None
    return tuple(out)


def _check_runs(path: Path) -> None:
    """Refuse a runs file without experiment records: the report of one would say "0 simulations"
    and look like a finished run."""
    from l3gs_opt.experiments.plan import ExperimentError
    from l3gs_opt.records import read_records

    records = read_records(path)
    if not records:
        raise ExperimentError("--out", f"{path}: holds no records (expected the runs.jsonl of l3gs-opt experiments)")
    # read_records skips blank lines: number the others to name the line of a stray record.
    numbers = [n for n, line in enumerate(path.read_bytes().split(b"\n"), start=1) if line.strip()]
    for number, rec in zip(numbers, records):
        if rec.get("kind") not in ("sim", "ceiling") or not isinstance(rec.get("record_id"), str):
            raise ExperimentError("--out", f"{path}: line {number} is not an experiment record (kind "
                                           f"{rec.get('kind')!r}; expected the runs.jsonl of l3gs-opt experiments)")


def _cmd_experiments(args: argparse.Namespace) -> int:
    from l3gs_opt.experiments.plan import RUNS_FILE, ExperimentError, SceneSpec, make_plan
    from l3gs_opt.experiments.run import plan_fidelity, run_experiments
    from l3gs_opt.executors import check_executor
    from l3gs_opt.experiments.report import write_report

    out = Path(args.out)
    for option, folder in (("--out", args.out), ("--cache", args.cache)):
        if folder and Path(folder).exists() and not Path(folder).is_dir():
            raise ExperimentError(option, f"{folder} is a file: expected a folder")
    if args.report_only:
        if not (out / RUNS_FILE).exists():
            raise ExperimentError("--out", f"{out / RUNS_FILE}: no such results file (run without --report-only first)")
        _check_runs(out / RUNS_FILE)
        print(f"report: {write_report(out / RUNS_FILE, out)}")
        return 0
    traces = args.traces
    # Path("") is the current folder: an empty --traces must not read it as a folder of traces.
    if traces is not None and not (traces.strip() and Path(traces).is_dir()):
        traces = _list(traces, "--traces", "trace")
    lists = {name: _list(getattr(args, name), "--" + name.replace("_", "-"), what)
             for name, what in (("variants", "variant"), ("paths", "path"), ("methods", "method"),
                                ("ablations", "condition"), ("ablation_methods", "method"), ("utilities", "utility"))
             if not (name == "ablations" and args.ablations is not None and args.ablations.strip() == "none")}
    if "ablations" not in lists:   # the one way to ask for no ablations (an empty list is refused)
        lists["ablations"] = []
    lists["last_chunks"] = _list(args.last_chunk, "--last-chunk", "value")
    check_executor(args.executor, args.jobs, args.address)   # before the plan builds anything
    sizes = _sizes(args.sizes)
    scenes = None
    if args.splats is not None or args.objects is not None or args.room_parts or sizes or args.sh_degree != 1:
        splats = args.splats if args.splats is not None else (8000 if args.quick else 20_000)
        if splats < 1000:
            raise ExperimentError("--splats", f"{splats}: must be >= 1000")
        objects = args.objects if args.objects is not None else 4
        if not 1 <= objects <= 12:
            raise ExperimentError("--objects", f"{objects}: must be in 1..12")
        if args.sh_degree not in (0, 1, 2, 3):
            raise ExperimentError("--sh-degree", f"{args.sh_degree}: must be 0, 1, 2 or 3")
        # The name keys the bundle cache: a different segmentation is a different scene.
        name = f"room{splats // 1000}k" + (f"-o{objects}" if objects != 4 else "") + \
            ("-parts" if args.room_parts else "") + (f"-sh{args.sh_degree}" if args.sh_degree != 1 else "") + \
            ("-L" + "-".join(str(v // 1000) + "k" for v in sizes) if sizes else "")
        scenes = [SceneSpec(name, splats, objects=objects, sh_degree=args.sh_degree, seed=0, room_parts=args.room_parts,
                            sizes=sizes or ())]
    plan = make_plan(quick=args.quick, scenes=scenes, traces=traces, starts=args.starts, window_s=args.window,
                     width=args.width, height=args.height, ceiling_time_limit_s=args.time_limit,
                     ceiling_check_s=args.check_time, seed=args.seed, **lists)
    n = len(plan.tasks())
    load = os.getloadavg()[0]
    print(f"plan: {n} records ({len(plan.scenes)} scene(s), {len(plan.windows())} window(s), {len(plan.paths)} "
          f"path(s), methods {', '.join(m for m, _ in plan.methods)}); load {load:.2f}", flush=True)
    for note in plan.notes:
        print(f"note: {note}")
    t0 = time.perf_counter()
    runs = run_experiments(plan, out, resume=args.resume, cache_dir=args.cache, progress=not args.no_progress,
                           jobs=args.jobs, executor=args.executor, address=args.address)
    fidelity = plan_fidelity(plan, out, cache_dir=args.cache) if not args.no_fidelity else {}
    report = write_report(runs, out)
    if args.json:
        from l3gs_opt.bench.run import read_records
        from l3gs_opt.experiments.report import summarize
        from l3gs_opt.jsonout import dumps

        s = summarize(read_records(runs))
        keep = ("variant", "utility", "runs", "ssim_mean", "ssim_first5", "ssim_std", "psnr_mean")
        print(dumps({"methods": {m: {k: v.get(k) for k in keep} for m, v in s["methods"].items()},
                     "headline": s["headline"], "utilities": s.get("utilities", {}), "fidelity": fidelity,
                     "records": str(runs), "report": str(report)}, where="experiments"))
        return 0
    print(f"records: {runs}\nreport: {report}\ntime: {time.perf_counter() - t0:.0f} s (load {load:.2f} -> "
          f"{os.getloadavg()[0]:.2f})")
    return 0


def register(subparsers) -> None:
    """Add ``experiments`` to an argparse subparsers object."""
    p = subparsers.add_parser("experiments", help="the paper's evaluation: SSIM per method over real traces, "
                                                  "ablations, latency, exact ceilings; runs.jsonl + report.md")
    p.add_argument("--quick", action="store_true",
                   help="one 8k-splat room, one trace per class, one window, one path, 128x96 (~15 min on 2 cores)")
    p.add_argument("--out", default="experiments-out", help="folder for runs.jsonl, report.md and the plots")
    p.add_argument("--cache", default=None, help="folder for teachers, bundles and pose logs (default OUT/cache)")
    p.add_argument("--resume", action="store_true", help="continue OUT/runs.jsonl, skipping recorded runs")
    p.add_argument("--report-only", action="store_true", help="rewrite report.md and the plots from OUT/runs.jsonl")
    p.add_argument("--traces", default=None,
                   help="comma-separated trace names or files, or a folder of traces (default: every Lumos5G "
                        "trace of ../shared/data, else the bundled ones; --quick: one per class)")
    p.add_argument("--starts", type=int, default=None, help="random window starts per trace (default 3, quick 1)")
    p.add_argument("--window", type=int, default=60, help="window length, seconds (default 60)")
    p.add_argument("--paths", default=None, help="comma-separated: orbit, orbit-log, turns, turns-log "
                                                 "(default orbit,turns-log; quick: orbit)")
    p.add_argument("--variants", default=None,
                   help="bundle variants to build: layered, sort, separate, distill, hierarchy (default all)")
    p.add_argument("--methods", default=None, help="comma-separated simulator methods (default: every one of "
                                                   "l3gs-opt simulate, each on its bundle)")
    p.add_argument("--ablations", default=None,
                   help="conditions: true_bandwidth, true_viewport, true_both, nofill, nofill_true_... (default all; "
                        "'none': no ablations)")
    p.add_argument("--ablation-methods", default=None,
                   help="methods run under the ablations (default: l3gs; full runs: every predicting method)")
    p.add_argument("--splats", type=int, default=None, help="one room of this many splats instead of the default")
    p.add_argument("--objects", type=int, default=None,
                   help="solids in the room, 1..12 (default 4); with --splats or --room-parts")
    p.add_argument("--sizes", default=None, metavar="A,B,..",
                   help="level sizes in splats, increasing to at most --splats (default 1/8, 1/4, 1/2, all; the "
                        "paper: 45000,90000,135000,180000)")
    p.add_argument("--sh-degree", type=int, default=1, help="SH degree of the room (default 1; the paper's scenes: 3)")
    p.add_argument("--room-parts", action="store_true",
                   help="the room's floor, ceiling and four walls as six objects of their own (a finer "
                        "segmentation: no chunk holds most of the bytes)")
    p.add_argument("--width", type=int, default=None, help="render width in pixels (default 160, quick 128)")
    p.add_argument("--height", type=int, default=None, help="render height in pixels (default 120, quick 96)")
    p.add_argument("--time-limit", type=float, default=None, metavar="S",
                   help="seconds per ceiling solved by exact when the DP is too large (default 60, quick 20)")
    p.add_argument("--check-time", type=float, default=None, metavar="S",
                   help="seconds of the ilp/highs cross-check of each DP ceiling, 0 = none (default 10, quick 3)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random window starts")
    p.add_argument("--json", action="store_true",
                   help="print the per-method means, the per-utility headline and fidelity as one JSON object")
    p.add_argument("--no-fidelity", action="store_true",
                   help="skip the utility fidelity check on the layered bundles (fidelity.json)")
    p.add_argument("--jobs", type=int, default=0,
                   help="0 (default): records one by one here; N >= 1: the records of each window run as one task "
                        "on N workers (--executor)")
    p.add_argument("--executor", default="local", choices=["local", "dask"],
                   help="local: forked processes; dask: a local Dask cluster, or the scheduler at --address")
    p.add_argument("--address", default=None, help="Dask scheduler address (executor dask)")
    p.add_argument("--utilities", default=None, metavar="A,B",
                   help="comma-separated splat utilities; every method that schedules by a utility runs once per "
                        "utility (default eq1; e.g. eq1,visibility)")
    p.add_argument("--last-chunk", default=None, metavar="A,B",
                   help="what l3gs counts of each slot's last chunk, as simulate --last-chunk: whole (default), prefix, "
                        "or whole,prefix (it runs once per value; ablations and other methods: whole)")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=_cmd_experiments)
