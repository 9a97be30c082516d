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
from l3gs_opt.utility import build_utility_table, object_layer_utility, splat_utility  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--splats", type=int, default=180_000)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args()
    scene = make_scene(args.splats, objects=8, sh_degree=3, seed=0)
    cams = walk_path(args.repeats + 1, width=800, height=600)
    splat_utility(scene, cams[0])  # warm-up
    times = []
    for cam in cams[1:]:
        t0 = time.perf_counter()
        object_layer_utility(scene, cam)
        times.append(time.perf_counter() - t0)
    load = os.getloadavg()
    # Table: a coarse grid over the walk's bounding box; error of nearest-grid lookup on the walk.
    centres = np.array([c.center for c in cams])
    lo, hi = centres.min(axis=0) - 0.5, centres.max(axis=0) + 0.5
    axes = [np.linspace(lo[k], hi[k], 3) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    t0 = time.perf_counter()
    table = build_utility_table(scene, grid, yaw_steps=12, pitches_deg=(-20.0, 0.0, 20.0), width=320, height=240)
    build_s = time.perf_counter() - t0
    lookups, errors = [], []
    for cam in cams:
        small = cam.replace(width=320, height=240, fx=cam.fx * 0.4, fy=cam.fy * 0.4, cx=160.0, cy=120.0)
        t0 = time.perf_counter()
        approx = table.lookup(small)
        lookups.append(time.perf_counter() - t0)
        exact = object_layer_utility(scene, small)
        errors.append(float(np.abs(approx - exact).sum() / max(exact.sum(), 1e-12)))
    result = {
        "splats": args.splats, "image": [800, 600], "torch_threads": torch.get_num_threads(),
        "utility_ms_median": 1000 * float(np.median(times)), "utility_ms_min": 1000 * float(np.min(times)),
        "goal_ms": 50, "loadavg": load,
        "table": {"positions": len(grid), "orientations": len(table.orientations), "build_s": build_s,
                  "bytes": table.nbytes, "dense_bytes": 8 * table.values.shape[0] * table.values.shape[1],
                  "lookup_ms_median": 1000 * float(np.median(lookups)),
                  "relative_l1_error_median": float(np.median(errors)), "relative_l1_error_max": float(max(errors))},
        "machine": machine_info(),
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "utility.json").write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps({k: v for k, v in result.items() if k != "machine"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
