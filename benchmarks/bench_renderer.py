"""Renderer speed: forward and forward+backward on procedural scenes, dense-path speed-up, scaling.

Usage::

    .venv/bin/python benchmarks/bench_renderer.py [--threads 1 2] [--repeats 3] [--quick]
        [--out benchmarks/results/renderer]

Writes ``<out>.json`` and ``<out>.md``.  ``backend="auto"`` (scaling tables) is the numba kernel
when numba is installed, the torch path otherwise.  Every timing is the median of ``--repeats`` runs after
one warm-up run, with ``os.getloadavg()`` recorded next to it (the machine is shared; a load
above the core count inflates the times, most of all with 2 torch threads, whose OpenMP
workers then wait on each other).  Scenes: :func:`l3gs_opt.scene.procedural.make_scene` (seed 0),
camera: the first orbit view (70 degree horizontal field of view).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import torch

from l3gs_opt.scene.camera_paths import orbit_path
from l3gs_opt.jsonout import dumps
from l3gs_opt.renderer import render_gaussians, scene_tensors
from l3gs_opt.renderer._dense import _rasterize_dense
from l3gs_opt.renderer._kernels import HAVE_NUMBA
from l3gs_opt.renderer.projection import camera_tensors, covariances_from_params, project_gaussians
from l3gs_opt.renderer.rasterize import rasterize
from l3gs_opt.renderer.sh import sh_to_color
from l3gs_opt.scene.procedural import make_scene

_SCENES: dict[int, object] = {}


def _scene(n):
    if n not in _SCENES:
        _SCENES[n] = make_scene(n, seed=0)
    return _SCENES[n]


def _cam(w, h):
    return orbit_path(1, width=w, height=h)[0]


def _time(fn, repeats):
    fn()  # warm-up
    times, loads = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
        loads.append(os.getloadavg()[0])
    return {"median_s": round(statistics.median(times), 4), "min_s": round(min(times), 4),
            "times_s": [round(t, 4) for t in times], "loadavg_1min": [round(v, 2) for v in loads]}


def forward(n, w, h, repeats, backend="auto"):
    p = scene_tensors(_scene(n))
    cam = _cam(w, h)

    def run():
        with torch.no_grad():
            return render_gaussians(**p, camera=cam, backend=backend)

    r = _time(run, repeats)
    out = run()
    r["visible"] = int(out.projection.visible.sum())
    return r


def forward_backward(n, w, h, repeats, backend="auto"):
    cam = _cam(w, h)
    scene = _scene(n)

    def run():
        p = scene_tensors(scene, requires_grad=True)
        out = render_gaussians(**p, camera=cam, backend=backend)
        (out.image.sum() + out.alpha.sum()).backward()

    return _time(run, repeats)


def tiled_vs_dense(n, w, h, repeats):
    """Rasterisation only (projection and colours shared), forward, tiled vs dense."""
    p = scene_tensors(_scene(n))
    cam = _cam(w, h)
    with torch.no_grad():
        proj = project_gaussians(p["means"], covariances_from_params(p["log_scales"], p["quats"]), cam)
        colors = sh_to_color(p["sh"], p["means"], camera_tensors(cam)[1])
        args = (proj.means2d, proj.conics, torch.sigmoid(p["opacity_logits"]), colors, proj.depths, proj.radii,
                w, h)

        tiled = _time(lambda: rasterize(*args, backend="torch"), repeats)
        dense = _time(lambda: _rasterize_dense(*args), max(1, repeats // 2))
        a = rasterize(*args, backend="torch").image
        b = _rasterize_dense(*args)[0]
        res = {"tiled": tiled, "dense": dense, "speedup": round(dense["median_s"] / tiled["median_s"], 1),
               "max_abs_diff": float((a - b).abs().max())}
        if HAVE_NUMBA:
            res["numba"] = _time(lambda: rasterize(*args, backend="numba"), repeats)
            res["speedup_numba"] = round(dense["median_s"] / res["numba"]["median_s"], 1)
            res["max_abs_diff_numba"] = float((rasterize(*args, backend="numba").image - b).abs().max())
    return res


def machine():
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"nproc": os.cpu_count(), "cpu_model": model, "torch": torch.__version__,
            "python": platform.python_version(), "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, nargs="+", default=[2, 1])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="goals and dense comparison only")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "renderer"))
    args = ap.parse_args(argv)
    res = {"machine": machine(), "runs": []}
    for th in args.threads:
        torch.set_num_threads(th)
        run = {"torch_threads": th}
        print(f"== {th} thread(s), load {os.getloadavg()}", flush=True)
        run["goal_forward_180k_800x600"] = forward(180_000, 800, 600, args.repeats, "torch")
        print("forward 180k 800x600 torch", run["goal_forward_180k_800x600"], flush=True)
        if HAVE_NUMBA:
            run["goal_forward_180k_800x600_numba"] = forward(180_000, 800, 600, args.repeats, "numba")
            print("forward 180k 800x600 numba", run["goal_forward_180k_800x600_numba"], flush=True)
        run["goal_fwd_bwd_45k_256x256"] = forward_backward(45_000, 256, 256, args.repeats, "torch")
        print("fwd+bwd 45k 256x256 torch", run["goal_fwd_bwd_45k_256x256"], flush=True)
        if HAVE_NUMBA:
            run["goal_fwd_bwd_45k_256x256_numba"] = forward_backward(45_000, 256, 256, args.repeats, "numba")
            print("fwd+bwd 45k 256x256 numba", run["goal_fwd_bwd_45k_256x256_numba"], flush=True)
        run["tiled_vs_dense"] = {}
        for n, w, h in [(10_000, 128, 96), (20_000, 160, 120)]:
            key = f"{n}_{w}x{h}"
            run["tiled_vs_dense"][key] = tiled_vs_dense(n, w, h, args.repeats)
            print("tiled vs dense", key, run["tiled_vs_dense"][key], flush=True)
        if not args.quick:
            run["scaling_splats_800x600"] = {}
            for n in (10_000, 45_000, 180_000, 500_000):
                run["scaling_splats_800x600"][n] = forward(n, 800, 600, args.repeats)
                print("splats", n, run["scaling_splats_800x600"][n], flush=True)
            run["scaling_resolution_180k"] = {}
            for w, h in ((256, 192), (512, 384), (800, 600), (1600, 1200)):
                run["scaling_resolution_180k"][f"{w}x{h}"] = forward(180_000, w, h, args.repeats)
                print("res", w, h, run["scaling_resolution_180k"][f"{w}x{h}"], flush=True)
        res["runs"].append(run)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(dumps(res, indent=1))
    out.with_suffix(".md").write_text(to_markdown(res))
    print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.md')}")


def to_markdown(res) -> str:
    m = res["machine"]
    lines = ["# Renderer benchmark", "",
             f"Machine: {m['nproc']} cores, {m['cpu_model']}; torch {m['torch']}, Python {m['python']}; "
             f"run {m['date_utc']} UTC.  Scenes: procedural room (`make_scene(n, seed=0)`, SH degree 3), "
             "first orbit camera, 70 degree FoV.  Median of the repeats after a warm-up; "
             "`load` = 1-minute load average after each repeat (shared machine).", ""]
    fmt = lambda r: f"{r['median_s']:.3f} s (min {r['min_s']:.3f}; load {', '.join(map(str, r['loadavg_1min']))})"  # noqa: E731
    for run in res["runs"]:
        lines += [f"## torch threads = {run['torch_threads']}", "",
                  "| case | goal | measured |", "|---|---|---|",
                  f"| forward, 180k splats, 800x600, torch path | <= 2 s | {fmt(run['goal_forward_180k_800x600'])} |",
                  *([f"| forward, 180k splats, 800x600, numba kernel | <= 2 s | "
                     f"{fmt(run['goal_forward_180k_800x600_numba'])} |"] if "goal_forward_180k_800x600_numba" in run else []),
                  f"| forward + backward, 45k splats, 256x256, torch autograd | <= 1 s | {fmt(run['goal_fwd_bwd_45k_256x256'])} |",
                  *([f"| forward + backward, 45k splats, 256x256, numba kernels | <= 1 s | "
                     f"{fmt(run['goal_fwd_bwd_45k_256x256_numba'])} |"] if "goal_fwd_bwd_45k_256x256_numba" in run else []),
                  "",
                  "Tiled vs dense per-pixel torch path (rasterisation only, forward):", "",
                  "| splats_resolution | tiled torch | dense torch | speed-up | numba kernel | speed-up | max abs diff |",
                  "|---|---|---|---|---|---|---|"]
        for k, v in run["tiled_vs_dense"].items():
            nb = (fmt(v["numba"]), f"{v['speedup_numba']}x") if "numba" in v else ("-", "-")
            lines.append(f"| {k} | {fmt(v['tiled'])} | {fmt(v['dense'])} | {v['speedup']}x | {nb[0]} | {nb[1]} | "
                         f"{max(v['max_abs_diff'], v.get('max_abs_diff_numba', 0)):.1e} |")
        if "scaling_splats_800x600" in run:
            lines += ["", "Scaling with splat count (forward, 800x600, `backend='auto'`):", "", "| splats | visible | time |", "|---|---|---|"]
            for k, v in run["scaling_splats_800x600"].items():
                lines.append(f"| {k} | {v['visible']} | {fmt(v)} |")
            lines += ["", "Scaling with resolution (forward, 180k splats, `backend='auto'`):", "", "| resolution | time |", "|---|---|"]
            for k, v in run["scaling_resolution_180k"].items():
                lines.append(f"| {k} | {fmt(v)} |")
        lines.append("")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
