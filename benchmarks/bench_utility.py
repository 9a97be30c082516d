"""Splat utility speed (goal: <= 50 ms per viewpoint for 180k splats) and utility-table trade-offs.

    .venv/bin/python benchmarks/bench_utility.py [--splats 180000] [--quick] [--out benchmarks/results]

Part 1 times Eq. 1 per viewpoint on a prepared scene (8 objects x 4 layers, 800 x 600 walk
cameras) with the compiled backend and the torch reference, and splits the time into stages.
Part 2 builds utility tables at a few grid densities and measures, on a walk that lies off every
grid (positions, yaws and pitches), the lookup time and the relative L1 error of the looked-up
``[J, L]`` utilities against exact computation (tables and walk at 800 x 600); it also reports why
tables are not built at a small image size (utilities at 160 x 120 scaled by the pixel ratio
against the display's, and the cost of a pass at each size).
Every timing carries the 1-minute load average (the machine is shared).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.scene.camera_paths import walk_path  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.renderer.projection import project_gaussians  # noqa: E402
from l3gs_opt.scene.procedural import make_scene  # noqa: E402
from l3gs_opt.pipeline.splat_utility import (UtilityScene, build_utility_table, grid_positions,  # noqa: E402
                              object_layer_utility, splat_utility)

LAYERS = 4
#: The walk's heights are 1.6 m; the table covers a head-height band around it and the walk's
#: floor-plan extent plus half a metre, as a table for a walking viewer would.
BOX_LO, BOX_HI = (-3.9, -3.3, 1.35), (3.9, 3.3, 1.85)
#: (name, positions per axis, yaw steps, pitches in degrees). The walk looks 20-25 degrees down.
TABLES = [
    ("coarse", (5, 5, 2), 24, (-50.0, -30.0, -10.0, 10.0)),
    ("medium", (9, 8, 2), 24, (-50.0, -30.0, -10.0, 10.0)),
    ("fine", (17, 14, 2), 24, (-50.0, -30.0, -10.0, 10.0)),
    ("medium, fine orientations", (9, 8, 2), 48, (-50.0, -40.0, -30.0, -20.0, -10.0, 0.0, 10.0)),
]
QUICK_TABLES = [("quick", (5, 4, 2), 12, (-40.0, -10.0))]
#: Tables are built at the display's size: a pass costs the same at any image size (no pixels
#: are touched), and a smaller image is not a rescaled one (see _resolution_error).
TABLE_SIZE = (800, 600)
SMALL_SIZE = (160, 120)


def _layered(scene):
    """Split each object's splats into LAYERS layers by significance (opacity x volume), the most
    significant first, as L3GS's layering does."""
    sig = (1 / (1 + np.exp(-scene.opacity_logits.astype(np.float64)))) * np.exp(scene.log_scales.sum(axis=1))
    rank = np.empty(scene.num_splats, np.int64)
    rank[np.argsort(-sig, kind="stable")] = np.arange(scene.num_splats)
    return dataclasses.replace(scene, layers=(rank * LAYERS // scene.num_splats).astype(np.int32))


def _timed(fn, cams) -> list[float]:
    out = []
    for cam in cams:
        t0 = time.perf_counter()
        fn(cam)
        out.append(1000 * (time.perf_counter() - t0))
    return out


def _stats(ms: list[float]) -> dict:
    return {"median_ms": float(np.median(ms)), "best_ms": float(np.min(ms)), "runs": len(ms),
            "loadavg_1min": os.getloadavg()[0]}


def _speed(scene, cams, torch_repeats: int) -> dict:
    from l3gs_opt.pipeline.splat_utility import _numba_pass

    t0 = time.perf_counter()
    prep = UtilityScene.from_scene(scene)
    prepare_ms = 1000 * (time.perf_counter() - t0)
    t0 = time.perf_counter()
    object_layer_utility(prep, cams[0])  # compiles on the first run, loads the cache afterwards
    first_ms = 1000 * (time.perf_counter() - t0)
    views = cams[1:]
    res = {"prepare_ms": prepare_ms, "first_call_ms": first_ms,
           "object_layer_utility": _stats(_timed(lambda c: object_layer_utility(prep, c), views)),
           "splat_utility": _stats(_timed(lambda c: splat_utility(prep, c), views)),
           "object_layer_utility_ellipse": _stats(_timed(lambda c: object_layer_utility(prep, c, area="ellipse"),
                                                         views)),
           "no_early_cull": _stats(_timed(lambda c: _numba_pass(prep, c, "square", 0.01, per_splat=False,
                                                                   sums=True, cull=False), views)),
           "unprepared": _stats(_timed(lambda c: object_layer_utility(scene, c), views[:3]))}
    prep32 = UtilityScene.from_scene(scene, torch.float32)
    res["float32_prepared"] = _stats(_timed(lambda c: object_layer_utility(prep32, c), views))
    # The torch reference, and its projection alone (where its time goes).
    few = views[:torch_repeats]
    means, covars, _ = prep32._tensors
    res["torch_float32"] = _stats(_timed(lambda c: object_layer_utility(prep32, c, backend="torch"), few))
    res["torch_float32_projection_only"] = _stats(_timed(lambda c: project_gaussians(means, covars, c), few))
    # How much the early cull leaves: splats in front of the camera, and those it projects.
    cam = views[0]
    z = prep.means @ cam.world_to_camera[2, :3] + cam.world_to_camera[2, 3]
    res["in_front_fraction"] = float(np.mean(z >= 0.01))
    res["visible_fraction"] = float(np.mean(splat_utility(prep, cam) > 0))
    return res


def _table(prep: UtilityScene, name, counts, yaw_steps, pitches, walk) -> dict:
    positions = grid_positions(BOX_LO, BOX_HI, counts)
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    table = build_utility_table(prep, positions, yaw_steps=yaw_steps, pitches_deg=pitches, width=TABLE_SIZE[0],
                                height=TABLE_SIZE[1], fov_deg=70.0, progress=True)
    build_s = time.perf_counter() - t0
    views = len(positions) * yaw_steps * len(pitches)
    out = {"name": name, "positions_per_axis": list(counts), "positions": len(positions), "yaw_steps": yaw_steps,
           "pitches_deg": [float(p) for p in pitches], "viewpoints": views, "build_s": build_s,
           "build_ms_per_viewpoint": 1000 * build_s / views, "build_loadavg_1min": [load0, os.getloadavg()[0]],
           "csr_bytes": table.nbytes, "dense_float64_bytes": 8 * table.values.shape[0] * table.values.shape[1],
           "nonzero_fraction": table.values.nnz / max(1, table.values.shape[0] * table.values.shape[1])}
    exact = [object_layer_utility(prep, cam) for cam in walk]
    for mode, interpolate in (("interpolated", True), ("nearest", False)):
        times, errors = [], []
        for cam, e in zip(walk, exact):
            t0 = time.perf_counter()
            approx = table.lookup(cam, interpolate=interpolate)
            times.append(1000 * (time.perf_counter() - t0))
            errors.append(float(np.abs(approx - e).sum() / e.sum()))
        out[mode] = {"lookup_ms_median": float(np.median(times)),
                     "relative_l1_error_median": float(np.median(errors)),
                     "relative_l1_error_p90": float(np.quantile(errors, 0.9)),
                     "relative_l1_error_max": float(np.max(errors))}
    out["lookup_loadavg_1min"] = os.getloadavg()[0]
    return out


def _resolution_error(prep: UtilityScene, walk_small, walk_full) -> dict:
    """Would a table at a small image size do? Its utilities scaled by the pixel ratio against the
    display's (the 0.3 px^2 dilation and integer radii weigh small splats differently), and the
    time of one pass at each size."""
    ratio = (walk_full[0].width * walk_full[0].height) / (walk_small[0].width * walk_small[0].height)
    errors, share_errors, t_small, t_full = [], [], [], []
    for small, full in zip(walk_small, walk_full):
        t0 = time.perf_counter()
        e = object_layer_utility(prep, full)
        t1 = time.perf_counter()
        a = object_layer_utility(prep, small)
        t_small.append(1000 * (time.perf_counter() - t1))
        t_full.append(1000 * (t1 - t0))
        errors.append(float(np.abs(ratio * a - e).sum() / e.sum()))
        share_errors.append(float(np.abs(a / a.sum() - e / e.sum()).sum()))
    return {"small_image": [walk_small[0].width, walk_small[0].height], "pixel_ratio": ratio,
            "relative_l1_error_median": float(np.median(errors)), "relative_l1_error_max": float(np.max(errors)),
            "share_l1_error_median": float(np.median(share_errors)),
            "pass_ms_median_small": float(np.median(t_small)), "pass_ms_median_display": float(np.median(t_full)),
            "loadavg_1min": os.getloadavg()[0]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--splats", type=int, default=180_000)
    ap.add_argument("--repeats", type=int, default=30, help="walk viewpoints timed")
    ap.add_argument("--walk", type=int, default=60, help="walk viewpoints for the table error")
    ap.add_argument("--quick", action="store_true", help="one small table only")
    ap.add_argument("--skip-tables", action="store_true")
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args()

    from l3gs_opt.renderer import HAVE_NUMBA

    scene = _layered(make_scene(args.splats, objects=8, sh_degree=3, seed=0))
    cams = walk_path(args.repeats + 1, width=800, height=600)
    result = {"splats": args.splats, "objects_layers": [scene.num_objects, LAYERS], "image": [800, 600],
              "goal_ms": 50, "numba": HAVE_NUMBA,
              "threads": {"torch": torch.get_num_threads(),
                          "numba": __import__("numba").get_num_threads() if HAVE_NUMBA else None},
              "machine": machine_info()}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / ("utility_quick.json" if args.quick else "utility.json")

    def save() -> None:  # after each step: a long run interrupted keeps what it measured
        path.write_text(dumps(result, indent=2) + "\n")

    result["speed"] = _speed(scene, cams, torch_repeats=5)
    save()
    s = result["speed"]["object_layer_utility"]
    print(f"object_layer_utility: median {s['median_ms']:.2f} ms, best {s['best_ms']:.2f} ms "
          f"(goal 50 ms; load {s['loadavg_1min']:.2f}); torch reference median "
          f"{result['speed']['torch_float32']['median_ms']:.1f} ms", flush=True)
    if args.skip_tables:
        return 0
    prep = UtilityScene.from_scene(scene)
    walk = walk_path(args.walk, width=TABLE_SIZE[0], height=TABLE_SIZE[1])
    result["tables_walk"] = {"viewpoints": args.walk, "image": list(TABLE_SIZE), "box": [BOX_LO, BOX_HI],
                             "error": "sum_jl |lookup - exact| / sum_jl exact, per walk viewpoint"}
    result["table_resolution_vs_display"] = _resolution_error(
        prep, walk_path(args.walk, width=SMALL_SIZE[0], height=SMALL_SIZE[1]), walk)
    result["tables"] = []
    for spec in (QUICK_TABLES if args.quick else TABLES):
        result["tables"].append(_table(prep, *spec, walk))
        save()
        t = result["tables"][-1]
        print(f"table {t['name']}: {t['positions']} positions x {t['viewpoints'] // t['positions']} orientations, "
              f"build {t['build_s']:.1f} s, {t['csr_bytes'] / 1e6:.2f} MB; interpolated error median "
              f"{t['interpolated']['relative_l1_error_median']:.3f} (max "
              f"{t['interpolated']['relative_l1_error_max']:.3f}), nearest "
              f"{t['nearest']['relative_l1_error_median']:.3f}; lookup "
              f"{t['interpolated']['lookup_ms_median']:.2f} ms", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
