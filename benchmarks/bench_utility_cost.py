"""Cost of each splat utility per viewpoint at the paper's scale (issue 21's goal: the picture-based
utility within 50 ms per viewpoint for 180k splats on 2 cores).

    .venv/bin/python benchmarks/bench_utility_cost.py [--splats 180000] [--views 24] [--width 256 --height 192]

Scene: the procedural room (``make_scene``, 8 objects, SH degree 3, seed 0), labelled 4 layers by
a random split (labels do not change the cost). Viewpoints: an orbit of ``--views`` cameras at the
render size. Each utility is prepared once (timed separately: camera-independent, cached by the
simulator), then timed per viewpoint after two warm-up calls; median and 90th percentile. The
held-aware ones are given a held set of half the splats (random, seeded). ``visibility`` is timed at
several picture scales (the default is 0.5 of the camera's size). The 1-minute load average is
recorded before and after each utility (the machine is shared).

Writes ``benchmarks/results/utility_cost.json`` and ``utility_cost.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.pipeline.utilities import (CoverageUtility, Eq1Utility, VisibilityUtility,  # noqa: E402
                                         get_utility)
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.scene.camera_paths import orbit_path  # noqa: E402
from l3gs_opt.scene.procedural import make_scene  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def _cases() -> list[tuple[str, object]]:
    return [("eq1", Eq1Utility()),
            ("visibility (scale 1)", VisibilityUtility(scale=1.0)),
            ("visibility (scale 0.5, default)", get_utility("visibility")),
            ("visibility (scale 0.25)", VisibilityUtility(scale=0.25)),
            ("visibility-held (scale 0.5)", get_utility("visibility-held")),
            ("coverage (scale 0.5)", CoverageUtility())]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--splats", type=int, default=180_000)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--height", type=int, default=192)
    ap.add_argument("--out", default=str(OUT / "utility_cost"))
    args = ap.parse_args(argv)
    info = machine_info()
    scene = make_scene(args.splats, objects=8, sh_degree=3, seed=0)
    rng = np.random.default_rng(0)
    scene = dataclasses.replace(scene, layers=rng.integers(0, 4, scene.num_splats).astype(np.int32))
    held = rng.random(scene.num_splats) < 0.5
    cams = orbit_path(args.views, width=args.width, height=args.height)
    rows = []
    for name, u in _cases():
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        prep = u.prepare(scene)
        prep_s = time.perf_counter() - t0
        kw = {"held": held} if u.held_aware else {}
        for c in cams[:2]:
            u.splat_values(prep, [c], **kw)
        times = []
        for c in cams:
            t0 = time.perf_counter()
            u.splat_values(prep, [c], **kw)
            times.append(time.perf_counter() - t0)
        times.sort()
        row = {"utility": name, "prepare_s": prep_s, "median_ms": 1e3 * statistics.median(times),
               "p90_ms": 1e3 * times[int(0.9 * (len(times) - 1))], "min_ms": 1e3 * times[0],
               "views": len(times), "loadavg_before": load0, "loadavg_after": os.getloadavg()[0]}
        rows.append(row)
        print(f"{name:<34} prepare {prep_s:6.2f} s  median {row['median_ms']:7.1f} ms  p90 {row['p90_ms']:7.1f} ms  "
              f"(load {load0:.2f} -> {row['loadavg_after']:.2f})", flush=True)
    result = {"machine": info, "splats": args.splats, "camera": [args.width, args.height], "rows": rows}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(dumps(result, indent=1) + "\n")
    m = info
    lines = [f"# Splat utility cost per viewpoint ({args.splats} splats, {args.width}x{args.height} camera)", "",
             f"Machine: {m['cores']} cores, {m['cpu']}; Python {m['python']}, numpy {m['packages'].get('numpy')}, "
             f"torch {m['packages'].get('torch')}. Written by `benchmarks/bench_utility_cost.py` "
             f"({time.strftime('%Y-%m-%d')}). Median and 90th percentile over {args.views} orbit viewpoints after "
             "two warm-up calls; `prepare` is camera-independent (once per scene). Held-aware utilities hold half "
             "the splats. Goal (issue 21): the picture-based utility within 50 ms per viewpoint.", "",
             "| utility | prepare (s) | median (ms) | p90 (ms) | load before -> after |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['utility']} | {r['prepare_s']:.2f} | {r['median_ms']:.1f} | {r['p90_ms']:.1f} | "
                     f"{r['loadavg_before']:.2f} -> {r['loadavg_after']:.2f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out}.json, {out}.md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
