"""Scene file formats: size, write/read time and render fidelity of each lossy format.

Usage::

    .venv/bin/python benchmarks/bench_formats.py [--splats 50000] [--views 3] [--repeats 3]
        [--out benchmarks/results/formats]

Scenes: (a) the procedural room (:func:`l3gs_opt.scene.procedural.make_scene`, SH degree 3, seed 0)
and (b) each real PLY in ``../shared/data/reference/scenes/`` (skipped when absent). For every
format of :data:`l3gs_opt.scene.scene_files.SCENE_FORMATS`: bytes per splat of the file written,
write and read time (median of ``--repeats``, seconds), and PSNR/SSIM (``l3gs_opt.renderer.metrics``)
of 256x192 renders of the decoded scene against renders of the full-precision scene, from
``--views`` cameras orbiting the scene's centre (median position) at 2.2x its 90th-percentile
radius, 60 degree horizontal field of view; the table gives the mean and the minimum over views.
Writes ``<out>.json`` and ``<out>.md`` with the machine, load average, versions and date.
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from l3gs_opt.renderer.metrics import psnr, ssim
from l3gs_opt.jsonout import dumps
from l3gs_opt.renderer.render import render_scene
from l3gs_opt.scene.cameras import Camera, look_at
from l3gs_opt.scene.procedural import make_scene
from l3gs_opt.scene.scene_files import SCENE_FORMATS, read_scene, write_scene
from l3gs_opt.scene.splats import read_ply

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

SHARED_SCENES = Path(__file__).resolve().parents[2] / "shared" / "data" / "reference" / "scenes"


def orbit_cameras(scene, k: int, *, up, width: int = 256, height: int = 192) -> list[Camera]:
    """``k`` cameras on a circle around the median position, 2.2x the 90th-percentile radius away,
    half a radius above it (along ``up``), 60 degree horizontal field of view."""
    c = np.median(scene.means, axis=0)
    r = float(np.percentile(np.linalg.norm(scene.means - c, axis=1), 90))
    up = np.asarray(up, np.float64)
    a = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(up, a)
    f = width / (2 * math.tan(math.radians(30)))
    cams = []
    for t in np.linspace(0, 2 * np.pi, k, endpoint=False):
        eye = c + 2.2 * r * (math.cos(t) * a + math.sin(t) * b) + 0.5 * r * up
        cams.append(Camera(width=width, height=height, fx=f, fy=f, cx=width / 2, cy=height / 2,
                           world_to_camera=look_at(eye, c, up)))
    return cams


def _image(scene, cam) -> np.ndarray:
    return np.clip(render_scene(scene, cam).image.numpy(), 0.0, 1.0)


def bench_scene(name: str, scene, *, up, views: int, repeats: int, folder: Path) -> list[dict]:
    cams = orbit_cameras(scene, views, up=up)
    refs = [_image(scene, c) for c in cams]
    rows = []
    for fmt in SCENE_FORMATS:
        path = folder / f"{name}{fmt.extension}"
        writes, reads, loads = [], [], []
        for _ in range(repeats):
            t = time.perf_counter()
            write_scene(scene, path)
            writes.append(time.perf_counter() - t)
            t = time.perf_counter()
            back = read_scene(path)
            reads.append(time.perf_counter() - t)
            loads.append(os.getloadavg()[0])
        size = path.stat().st_size
        p, s = [], []
        for cam, ref in zip(cams, refs):
            img = _image(back, cam)
            p.append(psnr(img, ref))
            s.append(ssim(img, ref))
        rows.append({"scene": name, "splats": scene.num_splats, "sh_degree": scene.sh_degree,
                     "format": fmt.extension, "lossy": fmt.lossy, "file_bytes": size,
                     "bytes_per_splat": size / max(scene.num_splats, 1),
                     "write_s": statistics.median(writes), "read_s": statistics.median(reads),
                     "psnr_db": p, "ssim": s, "load_1min": loads})
        print(f"{name:40s} {fmt.extension:16s} {size / scene.num_splats:8.2f} B/splat  "
              f"write {statistics.median(writes):.3f} s  read {statistics.median(reads):.3f} s  "
              f"PSNR {min(p):.1f}-{max(p):.1f} dB  SSIM {min(s):.4f}", flush=True)
    return rows


def _fmt_db(v: float) -> str:
    return "inf" if math.isinf(v) else f"{v:.1f}"


def write_report(rows: list[dict], meta: dict, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    m = meta["machine"]
    lines = ["# Scene file formats benchmark", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, load average (1/5/15 min) at start "
             f"{', '.join(f'{x:.2f}' for x in m['loadavg_at_start'])}, at end "
             f"{', '.join(f'{x:.2f}' for x in meta['loadavg_at_end'])}, {meta['elapsed_s']:.0f} s in all; "
             f"Python {m['python']}, numpy {m['packages'].get('numpy')}, torch {m['packages'].get('torch')}; "
             f"run {meta['date']}.", "",
             f"Renders {meta['width']}x{meta['height']}, {meta['views']} views orbiting each scene's centre "
             f"(2.2x its 90th-percentile radius, 60 degree FoV), against the full-precision scene; PSNR and SSIM "
             f"as mean (min) over the views. Times: median of {meta['repeats']} runs (shared machine: "
             f"`load` is the 1-minute load average after each run). `.ply` is lossless (PSNR inf).", "",
             "| scene | splats | SH | format | bytes/splat | write s | read s | PSNR dB mean (min) "
             "| SSIM mean (min) | load |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        p, s = r["psnr_db"], r["ssim"]
        lines.append(f"| {r['scene']} | {r['splats']:,} | {r['sh_degree']} | `{r['format']}` | "
                     f"{r['bytes_per_splat']:.2f} | {r['write_s']:.3f} | {r['read_s']:.3f} | "
                     f"{_fmt_db(float(np.mean(p)))} ({_fmt_db(min(p))}) | {np.mean(s):.4f} ({min(s):.4f}) | "
                     f"{', '.join(f'{x:.2f}' for x in r['load_1min'])} |")
    lines += ["", "Notes:", "",
              "* `.compressed.ply` sorts the splats in Morton order before cutting 256-splat chunks "
              "(as PlayCanvas splat-transform); its size is `16 + 3 (K-1) + 72/256` bytes a splat plus the header.",
              "* `.splat` keeps SH degree 0 only: on degree-3 scenes its PSNR mostly measures the lost "
              "view-dependent colour, not quantisation.",
              "* `.spz` is gzip (level 6) of 24-bit positions and 8-bit attributes (v3 rotations); its size "
              "depends on the data.",
              "* The real scenes (`../shared/data/reference/scenes/`) are read with `ignore_unknown=True` "
              "(the SuperSplat file has an extra `transform` property) and rendered with `up = -y` (3DGS/COLMAP "
              "axes); the procedural room with `up = +z`.", ""]
    out.with_suffix(".md").write_text("\n".join(lines))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--splats", type=int, default=50_000, help="procedural room size (splats)")
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results" / "formats")
    args = ap.parse_args(argv)
    started = time.time()
    meta = {"machine": machine_info(), "date": datetime.datetime.now(datetime.timezone.utc).strftime(
        "%Y-%m-%d %H:%M:%S UTC"), "width": 256, "height": 192, "views": args.views, "repeats": args.repeats,
        "python": platform.python_version(), "numpy": np.__version__}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        room = make_scene(args.splats, sh_degree=3, seed=0)
        rows += bench_scene(f"procedural room ({args.splats // 1000}k)", room, up=(0.0, 0.0, 1.0), views=args.views,
                            repeats=args.repeats, folder=Path(tmp))
        if SHARED_SCENES.is_dir():
            for ply in sorted(SHARED_SCENES.glob("*.ply")):
                scene = read_ply(ply, ignore_unknown=True)
                rows += bench_scene(ply.stem, scene, up=(0.0, -1.0, 0.0), views=args.views, repeats=args.repeats,
                                    folder=Path(tmp))
        else:
            print(f"skipping the real scenes: {SHARED_SCENES} not found", flush=True)
    meta["elapsed_s"] = time.time() - started
    meta["loadavg_at_end"] = os.getloadavg()
    write_report(rows, meta, args.out)
    print(f"wrote {args.out.with_suffix('.md')} and .json in {meta['elapsed_s']:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
