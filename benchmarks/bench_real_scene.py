"""A trained scene through the whole pipeline: read -> segment -> layer -> bundle -> simulate (issue 22).

    .venv/bin/python benchmarks/bench_real_scene.py [--scene PLY] [--sizes 5000,10000,15000,20000]
        [--objects 8] [--out benchmarks/results/real_scene_donut] [--work DIR]

The scene is a user's file as it comes: no object ids used (dropped if present), no training images,
no cameras. Stages, each timed:

1. **read** the file (:func:`l3gs_opt.scene.scene_files.read_scene`);
2. **segment** it (:func:`l3gs_opt.scene.segment.segment_scene`): ``auto`` is reported, and the
   bundles use ``--objects`` (per-object delivery needs several objects; a single connected model such
   as the donut is one component, so ``auto`` gives 1 and the count is forced by 2-means splits);
3. **build** the ``layered``, ``separate`` and ``sort`` bundles at ``--sizes`` with the QUICK schedule,
   the teacher distilled from its own renders from ``--views`` cameras sampled around it
   (:func:`l3gs_opt.scene.camera_sampling.sample_cameras`);
4. **quality**: every version rendered from held-out cameras (another Fibonacci lattice, so no test
   pose is a training pose) against the teacher: PSNR and SSIM, as in the paper's appendix table;
5. **simulate**: 60 s of a bundled Lumos5G trace window (scaled to the scene's bytes as the
   experiments do: ``--mbps``), the viewer orbiting the scene once a minute at 30 Hz, each method on
   its bundle (``l3gs`` with the ``visibility`` utility on the layered bundle, ``sort``, ``separate``),
   SSIM against the teacher.

Writes ``<out>.json`` and ``<out>.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.pipeline.build import DEFAULT, QUICK, build_bundle  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.renderer.metrics import psnr, ssim  # noqa: E402
from l3gs_opt.renderer.render import render_scene  # noqa: E402
from l3gs_opt.renderer.train import TRAIN_THREADS, threads  # noqa: E402
from l3gs_opt.scene.bundle import read_bundle  # noqa: E402
from l3gs_opt.scene.camera_sampling import sample_cameras  # noqa: E402
from l3gs_opt.scene.scene_files import read_scene  # noqa: E402
from l3gs_opt.scene.segment import object_counts, segment_scene  # noqa: E402
from l3gs_opt.simulator.simulation import SimConfig, Simulation, trace_bytes  # noqa: E402
from l3gs_opt.traces.poses import PoseMapping, poses_from_cameras  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "reference" / "scenes"
METHODS = (("l3gs", "layered", "visibility"), ("l3gs", "layered", "eq1"), ("sort", "sort", "eq1"),
           ("separate", "separate", "eq1"))


def _render(scene, cam) -> np.ndarray:
    return render_scene(scene, cam).image.clamp(0.0, 1.0).numpy()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=str(SHARED / "gshairlod_donut_fused.ply"))
    ap.add_argument("--sizes", default="5000,10000,15000,20000")
    ap.add_argument("--objects", default="8", help="object count for the bundles, or 'auto'")
    ap.add_argument("--planes", type=int, default=0, help="dominant planes split off first (segmentation)")
    ap.add_argument("--camera-mode", default="outside", choices=["outside", "inside"])
    ap.add_argument("--variants", default="layered,separate,sort")
    ap.add_argument("--no-simulate", action="store_true")
    ap.add_argument("--orbit-distance", type=float, default=1.5,
                    help="the viewer's orbit radius in scene radii (below 1: inside the scene, for rooms)")
    ap.add_argument("--full", action="store_true", help="the DEFAULT schedule instead of QUICK")
    ap.add_argument("--views", type=int, default=32, help="training cameras sampled around the scene")
    ap.add_argument("--test", type=int, default=6, help="held-out cameras")
    ap.add_argument("--trace", default="lumos-throughput-mid-11")
    ap.add_argument("--mbps", type=float, default=None,
                    help="trace mean (default: the top version's bytes over 20 s, as a paper-like load)")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--out", default="benchmarks/results/real_scene_donut")
    ap.add_argument("--work", default="/tmp/l3gs_bench_real")
    ap.add_argument("--from-json", action="store_true", help="rewrite <out>.md from <out>.json and stop")
    args = ap.parse_args(argv)
    if args.from_json:
        out = Path(args.out)
        out.with_suffix(".md").write_text(_markdown(json.loads(out.with_suffix(".json").read_text())))
        return 0
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    sizes = [int(s) for s in args.sizes.split(",")]
    schedule = DEFAULT if args.full else QUICK
    objects = args.objects if args.objects == "auto" else int(args.objects)
    variants = args.variants.split(",")
    result = {"machine": machine_info(), "scene": args.scene, "sizes": sizes, "stages": {},
              "schedule": "default" if args.full else "quick", "variants": variants, "planes": args.planes,
              "camera_mode": args.camera_mode}
    st = result["stages"]

    t0 = time.perf_counter()
    scene = read_scene(args.scene, ignore_unknown=True)
    st["read_s"] = time.perf_counter() - t0
    scene = dataclasses.replace(scene, object_ids=None, layers=None)
    result.update(splats=scene.num_splats, sh_degree=scene.sh_degree, file_bytes=Path(args.scene).stat().st_size)
    print(f"read {scene!r} in {st['read_s']:.2f} s", flush=True)

    t0 = time.perf_counter()
    auto = segment_scene(scene, "auto", planes=args.planes)
    st["segment_auto_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    teacher = segment_scene(scene, objects, planes=args.planes)
    st["segment_s"] = time.perf_counter() - t0
    result["segment_auto_objects"] = object_counts(auto)
    result["objects"] = object_counts(teacher)
    print(f"segment: auto {len(object_counts(auto))} objects ({st['segment_auto_s']:.2f} s); "
          f"{args.objects} objects {object_counts(teacher)} ({st['segment_s']:.2f} s)", flush=True)

    w = schedule.max_width
    h = round(w * 3 / 4)
    train = sample_cameras(teacher, args.views, mode=args.camera_mode, width=w, height=h)
    test = sample_cameras(teacher, args.views + args.test + 1, mode=args.camera_mode, width=w, height=h,
                          seed=1)[::(args.views // args.test)]
    test = test[:args.test]
    with threads(TRAIN_THREADS):
        targets = [_render(teacher, c) for c in test]
    result["quality"] = {}
    for variant in variants:
        t0 = time.perf_counter()
        res = build_bundle(teacher, train, sizes, variant, work / variant, schedule=schedule, show_progress=False,
                           resume=True, log=lambda s: print(f"[{variant}] {s}", flush=True))
        st[f"build_{variant}_s"] = time.perf_counter() - t0
        st[f"build_{variant}_stages_s"] = res.stage_seconds
        b = read_bundle(work / variant)
        rows = []
        for lvl in range(b.num_levels):
            sc = b.scene(lvl)
            with threads(TRAIN_THREADS):
                imgs = [_render(sc, c) for c in test]
            rows.append({"level": lvl, "splats": sc.num_splats,
                         "psnr": float(np.mean([psnr(i, t) for i, t in zip(imgs, targets)])),
                         "ssim": float(np.mean([ssim(i, t) for i, t in zip(imgs, targets)]))})
        result["quality"][variant] = rows
        print(variant, [(r["splats"], round(r["psnr"], 2), round(r["ssim"], 4)) for r in rows], flush=True)

    if args.no_simulate:
        return _write(result, args)
    top_bytes = sum(c["bytes"] for c in read_bundle(work / "layered").manifest["chunks"])
    mbps = args.mbps or top_bytes * 8 / 1e6 / 20.0
    bandwidth, info = trace_bytes(args.trace, mbps=mbps, start=0, slots=60)
    path = sample_cameras(teacher, 1800, mode="orbit", width=args.width, height=args.height,
                          distance=args.orbit_distance)
    poses = poses_from_cameras(np.stack([c.world_to_camera for c in path]), np.arange(1800) / 30.0)
    result["simulate"] = {"trace": info, "mbps": mbps, "top_bytes": top_bytes, "methods": [],
                          "orbit_distance": args.orbit_distance}
    for method, variant, utility in (m for m in METHODS if m[1] in variants):
        cfg = SimConfig(width=args.width, height=args.height, fov_deg=60.0, utility=utility)
        t0 = time.perf_counter()
        sim = Simulation(work / variant, poses, bandwidth, config=cfg, reference=teacher, mapping=PoseMapping())
        s = sim.run(method).summary
        dt = time.perf_counter() - t0
        result["simulate"]["methods"].append({"method": method, "variant": variant, "utility": utility,
                                              "ssim_mean": s["ssim_mean"], "ssim_first_5s": float(np.mean(s["ssim_per_s"][:5])),
                                              "ssim_per_s": s["ssim_per_s"], "seconds": dt})
        print(f"simulate {method}[{utility}] on {variant}: SSIM {s['ssim_mean']:.4f} ({dt:.1f} s)", flush=True)
    st["simulate_s"] = sum(m["seconds"] for m in result["simulate"]["methods"])
    return _write(result, args)


def _write(result: dict, args) -> int:
    result["loadavg_at_end"] = list(os.getloadavg())
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(dumps(result, indent=1))
    out.with_suffix(".md").write_text(_markdown(result))
    print(_markdown(result))
    return 0


def _markdown(r: dict) -> str:
    m, st = r["machine"], r["stages"]
    lines = [f"# A trained scene through the pipeline: {Path(r['scene']).name}", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, torch {m['packages'].get('torch')}; "
             f"load at start {[round(x, 2) for x in m['loadavg_at_start']]}, at end "
             f"{[round(x, 2) for x in r['loadavg_at_end']]}.",
             f"Scene: {r['splats']:,} splats, SH degree {r['sh_degree']}, {r['file_bytes']:,} bytes; ids dropped, "
             f"no cameras given (sampled {r.get('camera_mode', 'outside')} the scene). Versions {r['sizes']} "
             f"({r['schedule'].upper()} schedule).", "",
             "| stage | seconds |", "|---|---|",
             f"| read | {st['read_s']:.2f} |",
             f"| segment, auto ({len(r['segment_auto_objects'])} objects) | {st['segment_auto_s']:.2f} |",
             f"| segment, {len(r['objects'])} objects {r['objects']} | {st['segment_s']:.2f} |"]
    variants = r.get("variants", ["layered", "separate", "sort"])
    for v in variants:   # the stages' own times: a resumed stage keeps its time
        stages = st[f"build_{v}_stages_s"]
        lines.append(f"| build {v} ({', '.join(f'{k} {x:.0f}' for k, x in stages.items())}) | "
                     f"{sum(stages.values()):.1f} |")
    if "simulate" in r:
        lines.append(f"| simulate ({len(r['simulate']['methods'])} runs of 60 slots) | {st['simulate_s']:.1f} |")
    lines += ["", "Quality against the teacher (held-out sampled cameras): PSNR dB / SSIM", "",
              "| version | splats | " + " | ".join(variants) + " |", "|---|---|" + "---|" * len(variants)]
    q = r["quality"]
    for i, row in enumerate(q[variants[0]]):
        cells = [f"{q[v][i]['psnr']:.2f} / {q[v][i]['ssim']:.4f}" for v in variants]
        lines.append(f"| {i + 1} | {row['splats']:,} | " + " | ".join(cells) + " |")
    if "simulate" not in r:
        return "\n".join(lines) + "\n"
    s = r["simulate"]
    lines += ["", f"Delivery: trace {s['trace']['trace']} scaled to {s['mbps']:.2f} Mbit/s (top version "
                  f"{s['top_bytes']:,} bytes over 20 s), 60 slots, orbiting viewer:", "",
              "| method | bundle | utility | mean SSIM | first 5 s |", "|---|---|---|---|---|"]
    for row in s["methods"]:
        lines.append(f"| {row['method']} | {row['variant']} | {row['utility']} | {row['ssim_mean']:.4f} | "
                     f"{row['ssim_first_5s']:.4f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
