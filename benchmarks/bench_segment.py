"""Segmentation without ids against the ids a procedural room knows (issue 22).

    .venv/bin/python benchmarks/bench_segment.py [--sizes 20000,1000000]

The procedural room with 8 solids and its six surfaces as objects (``make_scene(..., objects=8,
room_parts=True)``: 14 true objects) has its ids dropped and found again by each setting of
:func:`l3gs_opt.scene.segment.segment_labels`; the adjusted Rand index scores the found partition
against the true one (1 = the same, ~0 = chance) and the time is one run's wall clock.

Writes ``benchmarks/results/segmentation.json`` and ``segmentation.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt.scene.procedural import make_scene  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.scene.segment import adjusted_rand_index, segment_labels  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
SETTINGS = (("components, auto", {}), ("components, 6 planes, auto", {"planes": 6}),
            ("components, 6 planes, 14 objects", {"planes": 6, "objects": 14}),
            ("k-means, 14 objects", {"method": "kmeans", "objects": 14}),
            ("k-means, 6 planes, 14 objects", {"method": "kmeans", "planes": 6, "objects": 14}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="20000,1000000")
    args = ap.parse_args(argv)
    rows = []
    for n in (int(s) for s in args.sizes.split(",")):
        scene = make_scene(n, objects=8, room_parts=True, sh_degree=0)
        for label, kw in SETTINGS:
            t0 = time.perf_counter()
            labels = segment_labels(scene, **kw)
            dt = time.perf_counter() - t0
            rows.append({"splats": n, "setting": label, "kwargs": kw, "objects": int(labels.max()) + 1,
                         "ari": adjusted_rand_index(scene.object_ids, labels), "seconds": dt,
                         "load": os.getloadavg()[0]})
            print(rows[-1], flush=True)
    m = machine_info()
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "segmentation.json").write_text(dumps({"machine": m, "rows": rows}, indent=1))
    lines = ["# Segmentation without ids, against the procedural room's 14 true objects", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}; 1-minute load in the table "
             "(shared machine). Adjusted Rand index (ARI) of the found objects against the true ones.", "",
             "| splats | setting | objects found | ARI | seconds | load |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['splats']:,} | {r['setting']} | {r['objects']} | {r['ari']:.3f} | {r['seconds']:.2f} | "
                     f"{r['load']:.1f} |")
    lines += ["", "Without planes the room is one connected piece (the solids stand on the floor), so `auto`",
              "finds few objects; splitting the floor, ceiling and walls off first (`--planes 6`) lets the",
              "components step find the solids. Touching solids stay merged (a component cannot tell them",
              "apart); k-means cuts by volume, not by boundary."]
    (OUT / "segmentation.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
