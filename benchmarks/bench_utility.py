"""Splat utility speed (goal: <= 50 ms for 180k splats per viewpoint) and table lookup time/error.

    .venv/bin/python benchmarks/bench_utility.py [--splats 180000] [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.camera_paths import walk_path  # noqa: E402
from l3gs_opt.scene_make import make_scene  # noqa: E402
from l3gs_opt.utility import UtilityScene, build_utility_table, object_layer_utility  # noqa: E402


def _grid(cams, per_axis: int) -> np.ndarray:
    centres = np.array([c.center for c in cams])
    lo, hi = centres.min(axis=0) - 0.5, centres.max(axis=0) + 0.5
    axes = [np.linspace(lo[k], hi[k], per_axis) for k in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def _table_figures(prepared: UtilityScene, cams, per_axis: int, yaw_steps: int) -> dict:
    """Build a grid table over the walk's bounding box; lookup time and error on the walk's cameras."""
    grid = _grid(cams, per_axis)
    t0 = time.perf_counter()
    table = build_utility_table(prepared, grid, yaw_steps=yaw_steps, pitches_deg=(-20.0, 0.0, 20.0),
                                width=320, height=240, progress=True)
    build_s = time.perf_counter() - t0
    out = {"positions": len(grid), "orientations": len(table.orientations), "build_s": build_s,
           "bytes": table.nbytes, "dense_bytes": 8 * table.values.shape[0] * table.values.shape[1]}
    for k in (1, 4):
        lookups, errors = [], []
        for cam in cams:
            small = cam.replace(width=320, height=240, fx=cam.fx * 0.4, fy=cam.fy * 0.4, cx=160.0, cy=120.0)
            t0 = time.perf_counter()
            approx = table.lookup(small, neighbours=k)
            lookups.append(time.perf_counter() - t0)
            exact = object_layer_utility(prepared, small)
            errors.append(float(np.abs(approx - exact).sum() / max(exact.sum(), 1e-12)))
        out[f"neighbours_{k}"] = {"lookup_ms_median": 1000 * float(np.median(lookups)),
                                  "relative_l1_error_median": float(np.median(errors)),
                                  "relative_l1_error_max": float(max(errors))}
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--splats", type=int, default=180_000)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args()
    scene = make_scene(args.splats, objects=8, sh_degree=3, seed=0)
    cams = walk_path(args.repeats + 1, width=800, height=600)
    # Preparation (world covariances, activated opacity) is per scene; the goal is per viewpoint.
    t0 = time.perf_counter()
    prepared = UtilityScene.from_scene(scene)
    prepare_ms = 1000 * (time.perf_counter() - t0)
    object_layer_utility(prepared, cams[0])  # warm-up
    times, unprepared = [], []
    for cam in cams[1:]:
        t0 = time.perf_counter()
        object_layer_utility(prepared, cam)
        times.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        object_layer_utility(scene, cam)
        unprepared.append(time.perf_counter() - t0)
    load = os.getloadavg()
    result = {
        "splats": args.splats, "image": [800, 600], "torch_threads": torch.get_num_threads(),
        "prepare_ms": prepare_ms,
        "utility_ms_median": 1000 * float(np.median(times)), "utility_ms_min": 1000 * float(np.min(times)),
        "utility_unprepared_ms_median": 1000 * float(np.median(unprepared)),
        "goal_ms": 50, "loadavg": load, "tables": [], "machine": machine_info(),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def save() -> None:  # after each step: a long run interrupted keeps what it measured
        (out / "utility.json").write_text(json.dumps(result, indent=2) + "\n")

    save()
    # Same positions, twice the yaw resolution: how the error depends on the orientation grid.
    for per_axis, yaw_steps in ((3, 12), (3, 24)):
        result["tables"].append(_table_figures(prepared, cams, per_axis, yaw_steps))
        result["tables"][-1]["loadavg"] = os.getloadavg()
        save()
    print(json.dumps({k: v for k, v in result.items() if k != "machine"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
