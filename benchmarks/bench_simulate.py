"""Delivery simulation on the demo's procedural room: SSIM per method, run time, latency breakdown.

The scene of the README's scene story (a 12k-splat room, 4 objects, SH degree 1), its ``sort``
bundle (4 layers: 1.5k/3k/6k/12k splats) and a ``separate`` bundle trained with the QUICK
schedule at the same sizes, a synthetic orbiting viewer, the Lumos5G trace ``mid-11`` scaled so
that the whole sort bundle takes about 12 s, 60 one-second slots at 160x120 pixels; with
``--variants`` also ``distill`` and ``hierarchy`` bundles (trained with the QUICK schedule too) and
their item-form methods. Goal: a 60-slot run well under a minute. Each method runs in a fresh
:class:`Simulation`; by default the process-wide render caches are cleared before each run, so a
run pays for its teacher renders as a lone ``l3gs-opt simulate`` would (``--warm-cache``: keep
them, as a sweep over methods on one path sees them). The first run of the process also pays
numba's compilation, so a warm-up run comes first and is not recorded.

    .venv/bin/python benchmarks/bench_simulate.py [--work /tmp/l3gs-sim] [--slots 60] [--methods l3gs,sort,...]
        [--variants sort,separate,distill,hierarchy] [--warm-cache]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402

LAYERED = ("l3gs", "l3gs-noseg", "sort", "preload", "rolling:bb", "rolling-future:bb", "slope", "progressive",
           "static", "mpc:3")
SEPARATE = ("separate", "preload")
DISTILL = ("distill", "l3gs", "preload")
HIERARCHY = ("hierarchy", "separate", "preload")
SIZES = [1500, 3000, 6000, 12_000]


def _prepare(work: Path, variants) -> None:
    from l3gs_opt.scene.camera_paths import orbit_path
    from l3gs_opt.traces.poses import synthetic_poses, write_pose_log
    from l3gs_opt.pipeline.build import QUICK, build_bundle
    from l3gs_opt.scene.splats import write_ply
    from l3gs_opt.scene.procedural import make_scene

    work.mkdir(parents=True, exist_ok=True)
    if not (work / "teacher.ply").exists():
        write_ply(make_scene(12_000, objects=4, sh_degree=1, seed=0), work / "teacher.ply")
    if not (work / "viewer.log").exists():
        write_pose_log(synthetic_poses("orbit", seconds=62, rate_hz=30, seed=0), work / "viewer.log")
    cams = orbit_path(12, width=160, height=120)
    for variant in variants:
        if not (work / variant / "manifest.json").exists():
            t0 = time.perf_counter()
            build_bundle(work / "teacher.ply", cams, SIZES, variant, work / variant, schedule=QUICK,
                         show_progress=False, resume=True)
            print(f"built {variant} in {time.perf_counter() - t0:.1f} s (load {os.getloadavg()[0]:.2f})", flush=True)


def write_markdown(record: dict, path: Path) -> None:
    """The table of ``simulate.md`` from the ``simulate.json`` record."""
    machine, rows, mbps = record["machine"], record["runs"], record["mbps"]
    early = min(20, record["slots"])
    lines = ["# Delivery simulation: the demo's procedural room", "",
             f"{record['slots']} slots of 1 s, 160x120, trace mid-11 scaled to {mbps:.3f} Mbit/s (the sort bundle "
             "in ~12 s at the mean), per-slot budget, lr viewport, harmonic bandwidth, exact utilities; reference: "
             f"the teacher. Machine: {machine['cpu']}, {machine['cores']} cores, shared with other jobs (the "
             "1-minute load average at each run's start is in the last column; run times scale with it).", "",
             f"| bundle | method | SSIM mean | SSIM mean 0-{early - 1} s | PSNR mean | run s | delivered MB | "
             "wasted kB | idle MB | predict / utility / schedule / render / reference / metrics (ms per slot) | "
             "renders view / reference (cached) | load |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        t = r["timings_mean_ms"]
        psnr = "-" if r["psnr_mean"] is None else f"{r['psnr_mean']:.2f}"
        head = sum(r["ssim_per_s"][:early]) / early
        lines.append(f"| {r['bundle']} | {r['method']} | {r['ssim_mean']:.4f} | {head:.4f} | {psnr} | "
                     f"{r['wall_s']:.1f} | {r['bytes_delivered'] / 1e6:.3f} | {r['bytes_wasted'] / 1e3:.1f} | "
                     f"{r['bytes_idle'] / 1e6:.3f} | "
                     + " / ".join(f"{t[k]:.1f}" for k in ("prediction", "utility", "scheduling", "rendering",
                                                          "reference", "metrics"))
                     + (" | {view} ({view_reused}) / {reference} ({reference_reused})".format(**r["renders"])
                        if r.get("renders") else " | -")
                     + f" | {r['loadavg_start']:.2f} |")
    path.write_text("\n".join(lines) + "\n")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="/tmp/l3gs-sim", help="folder for the teacher, bundles and viewer log")
    ap.add_argument("--slots", type=int, default=60)
    ap.add_argument("--methods", default=None, help="comma-separated layered methods (default: a standard set)")
    ap.add_argument("--no-separate", action="store_true", help="skip the separate bundle (its build trains)")
    ap.add_argument("--variants", default=None,
                    help="bundles to run (sort, separate, distill, hierarchy; default sort,separate)")
    ap.add_argument("--warm-cache", action="store_true", help="keep render caches between runs")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    ap.add_argument("--report-only", action="store_true", help="rewrite simulate.md from simulate.json")
    args = ap.parse_args()
    if args.report_only:
        out = Path(args.out)
        write_markdown(json.loads((out / "simulate.json").read_text()), out / "simulate.md")
        return 0

    from l3gs_opt.scene.bundle import read_bundle
    from l3gs_opt.simulator.render import REFERENCE_CACHE, VIEW_CACHE
    from l3gs_opt.simulator.simulation import SimConfig, Simulation, trace_bytes

    work = Path(args.work)
    variants = args.variants.split(",") if args.variants else ["sort"] + ([] if args.no_separate else ["separate"])
    _prepare(work, sorted(set(variants) | {"sort"}))
    total = sum(c["bytes"] for c in read_bundle(work / "sort").manifest["chunks"])
    mbps = total * 8 / 1e6 / 12.0   # the whole sort bundle in ~12 s at the trace's mean, as in the demo
    bandwidth, info = trace_bytes("lumos-throughput-mid-11", mbps=mbps, start=0, slots=args.slots)
    config = SimConfig()   # 160x120, per-slot budget, lr viewport, harmonic bandwidth, exact utilities
    machine = machine_info()
    methods = {"sort": args.methods.split(",") if args.methods else LAYERED, "separate": SEPARATE,
               "distill": DISTILL, "hierarchy": HIERARCHY}
    plan = [(v, m) for v in variants for m in methods[v]]
    warm = Simulation(work / "sort", work / "viewer.log", bandwidth[:2], config=config,
                      reference=str(work / "teacher.ply"))
    warm.run("l3gs")   # numba compilation, imports
    rows = []
    for bundle, method in plan:
        if not args.warm_cache:
            REFERENCE_CACHE.clear()
            VIEW_CACHE.clear()
        t0 = time.perf_counter()
        sim = Simulation(work / bundle, work / "viewer.log", bandwidth, config=config,
                         reference=str(work / "teacher.ply"), info=info)
        r = sim.run(method, out_dir=work / "records")
        wall = time.perf_counter() - t0
        s = r.summary
        rows.append({"bundle": bundle, "method": method, "ssim_mean": s["ssim_mean"], "psnr_mean": s["psnr_mean"],
                     "wall_s": wall, "bytes_delivered": s["bytes_delivered"], "bytes_wasted": s["bytes_wasted"],
                     "bytes_idle": s["bytes_idle"], "bytes_model": s["bytes_model"],
                     "timings_mean_ms": {k: 1e3 * v for k, v in s["timings_mean_s"].items()},
                     "loadavg_start": s["loadavg_start"][0], "loadavg_end": s["loadavg_end"][0],
                     "ssim_per_s": s["ssim_per_s"], "renders": s["renders"]})
        print(f"{bundle:9} {method:18} SSIM {s['ssim_mean']:.4f}  {wall:5.1f} s  load {s['loadavg_start'][0]:.2f}",
              flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    record = {"machine": machine, "slots": args.slots, "mbps": mbps, "trace": info,
              "config": dataclasses.asdict(config), "warm_cache": args.warm_cache, "runs": rows}
    (out / "simulate.json").write_text(dumps(record, indent=1, other=str))
    write_markdown(record, out / "simulate.md")
    print(f"wrote {out / 'simulate.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
