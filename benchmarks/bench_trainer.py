"""Trainer quality (the paper's Table 5 shape) and build times: layered vs separate vs sort.

Usage::

    .venv/bin/python benchmarks/bench_trainer.py --quick [--out benchmarks/results/trainer_quick]

Teacher: :func:`l3gs_opt.scene.procedural.make_scene` (seed 0, SH degree 3, ``--splats`` splats,
4 objects).  Training cameras: an orbit of ``--views`` cameras; held-out cameras: the orbit
angles half-way between training cameras (every other one of a twice-as-dense orbit, ``--test``
of them), so no test pose is a training pose.  Each variant is built with
:func:`l3gs_opt.pipeline.build.build_bundle` (the ``QUICK`` or ``DEFAULT`` schedule), read back from
its bundle, and every version (layered: layers ``0..l`` stacked; separate: version ``l``;
sort: the first ``d_l`` splats by significance) is rendered at the training resolution from
the held-out cameras and scored against the teacher's render from the same camera (PSNR and
SSIM of :mod:`l3gs_opt.renderer.metrics`, images clipped to [0, 1], mean over the views).

Writes ``<out>.json`` (everything), ``<out>.md`` (the table) and ``<out>_views.png`` (one held-out
view: teacher, then the smallest and largest version of each variant).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.scene.bundle import read_bundle  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.scene.camera_paths import orbit_path  # noqa: E402
from l3gs_opt.renderer.metrics import psnr, ssim  # noqa: E402
from l3gs_opt.renderer.render import render_scene  # noqa: E402
from l3gs_opt.renderer.train import TRAIN_THREADS, threads  # noqa: E402
from l3gs_opt.pipeline.build import DEFAULT, QUICK, build_bundle, scale_camera  # noqa: E402
from l3gs_opt.scene.splats import write_ply  # noqa: E402
from l3gs_opt.scene.procedural import make_scene  # noqa: E402

#: Bundles built and scored: the label, the bundle variant and the schedule's ``layered_base``.
VARIANTS = {"layered": ("layered", "top"), "layered-pruned": ("layered", "pruned"), "separate": ("separate", "top"),
            "sort": ("sort", "top")}


def _render(scene, cam) -> np.ndarray:
    return render_scene(scene, cam).image.clamp(0.0, 1.0).numpy()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="QUICK schedule and a 10k-splat teacher")
    ap.add_argument("--splats", type=int, default=None, help="teacher splats (default 10000 quick, 60000 full)")
    ap.add_argument("--sizes", default=None, help="version sizes (default 10,20,35,50 %% of the teacher)")
    ap.add_argument("--views", type=int, default=24, help="training cameras (orbit)")
    ap.add_argument("--test", type=int, default=6, help="held-out cameras")
    ap.add_argument("--out", default=None, help="output prefix (default benchmarks/results/trainer[_quick])")
    ap.add_argument("--work", default="/tmp/l3gs_bench_trainer", help="scratch folder for the bundles")
    ap.add_argument("--objects", type=int, default=4, help="objects in the procedural room (default 4)")
    ap.add_argument("--width", type=int, default=None, help="training/test view width (default: the schedule's)")
    args = ap.parse_args(argv)
    schedule = QUICK if args.quick else DEFAULT
    if args.width is not None:
        schedule = dataclasses.replace(schedule, max_width=args.width)
    n = args.splats or (10_000 if args.quick else 60_000)
    sizes = [int(s) for s in args.sizes.split(",")] if args.sizes else [int(n * f) for f in (0.1, 0.2, 0.35, 0.5)]
    out = Path(args.out or f"benchmarks/results/trainer{'_quick' if args.quick else ''}")
    work = Path(args.work)
    info = machine_info()
    t_all = time.perf_counter()
    teacher = make_scene(n, objects=args.objects, sh_degree=3, seed=0)
    teacher_path = write_ply(teacher, work / "teacher.ply")
    w, h = 320, 240
    train_cams = orbit_path(args.views, width=w, height=h)
    dense = orbit_path(2 * args.views, width=w, height=h)
    test_cams = [scale_camera(c, schedule.max_width) for c in dense[1::2][::max(1, args.views // args.test)]][:args.test]
    with threads(TRAIN_THREADS):
        targets = [_render(teacher, c) for c in test_cams]
    results = {"machine": info, "teacher_splats": n, "teacher_sh_degree": 3, "sizes": sizes, "objects": args.objects,
               "schedule": "quick" if args.quick else "default", "train_views": args.views,
               "test_views": len(test_cams), "resolution": [test_cams[0].width, test_cams[0].height],
               "variants": {}}
    strip, labels = [targets[0]], ["teacher"]
    for label, (variant, base) in VARIANTS.items():
        t0 = time.perf_counter()
        res = build_bundle(teacher_path, train_cams, sizes, variant, work / label,
                           schedule=dataclasses.replace(schedule, layered_base=base), show_progress=False,
                           log=lambda s: print(f"[{label}] {s}", flush=True))
        build_s = time.perf_counter() - t0
        b = read_bundle(work / label)
        rows = []
        for lvl in range(b.num_levels):
            sc = b.scene(lvl)
            with threads(TRAIN_THREADS):
                imgs = [_render(sc, c) for c in test_cams]
            nbytes = sum(c["bytes"] for c in b.manifest["chunks"]
                         if (c["level"] <= lvl if b.manifest["representation"] == "layered" else c["level"] == lvl))
            rows.append({"level": lvl, "splats": sc.num_splats, "bytes": nbytes,
                         "psnr": float(np.mean([psnr(i, t) for i, t in zip(imgs, targets)])),
                         "ssim": float(np.mean([ssim(i, t) for i, t in zip(imgs, targets)]))})
            if lvl in (0, b.num_levels - 1):
                strip.append(imgs[0])
                labels.append(f"{label} {sc.num_splats}")
        results["variants"][label] = {"build_seconds": round(build_s, 2), "stage_seconds": res.stage_seconds,
                                        "levels": rows, "loadavg_after": list(os.getloadavg())}
        print(f"{label}: {build_s:.1f} s", [(r["splats"], round(r["psnr"], 2), round(r["ssim"], 4)) for r in rows],
              flush=True)
    results["total_seconds"] = round(time.perf_counter() - t_all, 2)
    results["loadavg_at_end"] = list(os.getloadavg())
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(dumps(results, indent=1))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(strip), figsize=(2.2 * len(strip), 2.1))
    for ax, img, label in zip(np.atleast_1d(axes), strip, labels):
        ax.imshow(np.clip(img, 0, 1))
        ax.set_title(label, fontsize=8)
        ax.axis("off")
    fig.suptitle("held-out view: teacher, then each variant's smallest and largest version (splats)", fontsize=9)
    fig.tight_layout()
    fig.savefig(f"{out}_views.png", dpi=120)
    plt.close(fig)
    out.with_suffix(".md").write_text(_markdown(results))
    print(f"wrote {out}.json, {out}.md, {out}_views.png ({results['total_seconds']:.0f} s)")
    return 0


def _markdown(r: dict) -> str:
    m = r["machine"]
    lines = [f"# Trainer quality ({r['schedule']} schedule)", "",
             f"Machine: {m['cores']} cores, {m['cpu']}; torch {m['packages'].get('torch')}, Python {m['python']}; "
             f"load average at start {[round(x, 2) for x in m['loadavg_at_start']]}, at end "
             f"{[round(x, 2) for x in r['loadavg_at_end']]} (shared machine).",
             f"Teacher: procedural room, {r['teacher_splats']} splats, SH degree 3, {r.get('objects', 4)} objects. "
             f"{r['train_views']} orbit training views, {r['test_views']} held-out views between them, "
             f"{r['resolution'][0]}x{r['resolution'][1]} pixels. PSNR (dB) / SSIM against the teacher's render, "
             f"mean over the held-out views. Bytes: what a client has received to show that version "
             f"(layered/sort: layers 0..l; separate: version l alone).", "",
             "| version | splats | " + " | ".join(f"{k} PSNR" for k in r["variants"]) + " | "
             + " | ".join(f"{k} SSIM" for k in r["variants"]) + " | layered bytes | separate bytes |",
             "|---|---|" + "---|" * (2 * len(r["variants"]) + 2)]
    v = r["variants"]
    for i, d in enumerate(r["sizes"]):
        row = [v[k]["levels"][i] for k in v]
        lines.append(f"| {i + 1} | {d} | " + " | ".join(f"{x['psnr']:.2f}" for x in row) + " | "
                     + " | ".join(f"{x['ssim']:.4f}" for x in row)
                     + f" | {v['layered']['levels'][i]['bytes']} | {v['separate']['levels'][i]['bytes']} |")
    lines += ["", "Build times (wall clock, s):", "", "| variant | total | stages |", "|---|---|---|"]
    for k in v:
        st = ", ".join(f"{s} {t:.1f}" for s, t in v[k]["stage_seconds"].items())
        lines.append(f"| {k} | {v[k]['build_seconds']:.1f} | {st} |")
    lines += ["", f"Total benchmark time {r['total_seconds']:.0f} s.", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
