"""PLY read and write speed at 1 M splats: l3gs-opt's reader against gsply and plyfile (issue 22).

    .venv/bin/python benchmarks/bench_ply_read.py [--splats 1000000] [--repeats 3] [--work DIR]

Writes a synthetic scene in the reference 3DGS layout (SH degree 3 and normals: 62 float32
properties, 248 bytes a splat) and reads it back in a fresh process per reader and repeat, so that
each run's peak resident memory (``ru_maxrss``) is its own. Every reader must end with the same
in-memory arrays (centres, scales, rotations, opacities, SH [N, 16, 3]): plyfile's lazily mapped
record is turned into those arrays, gsply's ``GSData`` already holds them. gsply is not a dependency of
l3gs-opt (its reader was slower and larger here); install it to compare. The file is in the page
cache (the first run warms it; the table gives the median of the repeats after it): this measures
the readers, not the disk. Import time is excluded and reported apart.

Writes ``benchmarks/results/ply_read.json`` and ``ply_read.md``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402

import numpy  # noqa: E402
from importlib.metadata import version  # noqa: E402

OUT = Path(__file__).resolve().parents[1] / "benchmarks" / "results"

_CHILD = r'''
import json, resource, sys, time
which, path, out = sys.argv[1], sys.argv[2], sys.argv[3]
t0 = time.perf_counter()
import numpy as np
if which == "l3gs-opt":
    from l3gs_opt.scene.splats import read_ply, write_ply
elif which == "gsply":
    import gsply
else:
    from plyfile import PlyData
t_import = time.perf_counter() - t0
t0 = time.perf_counter()
if which == "l3gs-opt":
    s = read_ply(path)
    arrays = [s.means, s.log_scales, s.quats, s.opacity_logits, s.sh]
elif which == "gsply":
    d = gsply.plyread(path)
    arrays = [d.means, d.scales, d.quats, d.opacities, d.sh0, d.shN]
else:
    v = PlyData.read(path)["vertex"].data
    col = lambda names: np.stack([np.asarray(v[n], np.float32) for n in names], axis=1)
    k = 1 + sum(1 for n in v.dtype.names if n.startswith("f_rest_")) // 3
    arrays = [col("xyz"), col([f"scale_{i}" for i in range(3)]), col([f"rot_{i}" for i in range(4)]),
              np.asarray(v["opacity"], np.float32),
              col([f"f_dc_{c}" if j == 0 else f"f_rest_{c * (k - 1) + j - 1}" for j in range(k) for c in range(3)])]
t_read = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024   # the reader's high-water mark
checksum = float(sum(float(np.asarray(a).sum(dtype=np.float64)) for a in arrays))
t_write = None
if out != "-":
    t0 = time.perf_counter()
    if which == "l3gs-opt":
        write_ply(s, out)
    elif which == "gsply":
        gsply.plywrite(out, d)
    t_write = time.perf_counter() - t0
print(json.dumps({"import_s": t_import, "read_s": t_read, "write_s": t_write, "checksum": checksum,
                  "maxrss_bytes": peak}))
'''


def make_file(path: Path, n: int) -> None:
    import numpy as np

    from l3gs_opt.scene.splats import SplatScene, write_ply

    rng = np.random.default_rng(0)
    f = lambda *shape: rng.standard_normal(shape, dtype=np.float32)  # noqa: E731
    write_ply(SplatScene(means=f(n, 3), log_scales=f(n, 3) * 0.5 - 4, quats=f(n, 4) + 1, opacity_logits=f(n),
                         sh=f(n, 16, 3) * 0.3, normals=np.zeros((n, 3), np.float32)), path)


def run(which: str, path: Path, out: str) -> dict:
    got = subprocess.run([sys.executable, "-c", _CHILD, which, str(path), out], capture_output=True, text=True,
                         check=True)
    return json.loads(got.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--splats", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--work", default="/tmp/l3gs_bench_ply")
    args = ap.parse_args(argv)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    path = work / f"synthetic_{args.splats}.ply"
    if not path.exists():
        make_file(path, args.splats)
    size = path.stat().st_size
    load_before = os.getloadavg()
    rows = []
    for which in ("l3gs-opt", "gsply", "plyfile"):
        if importlib.util.find_spec(which.replace("l3gs-opt", "l3gs_opt")) is None:
            print(f"{which}: not installed (pip install {which}), skipped", flush=True)
            continue
        run(which, path, "-")   # warms the page cache and numba's on-disk cache
        runs = [run(which, path, str(work / f"out_{which}.ply") if which != "plyfile" else "-")
                for _ in range(args.repeats)]
        med = lambda k: statistics.median(r[k] for r in runs) if runs[0][k] is not None else None  # noqa: E731
        rows.append({"reader": which, "read_s": med("read_s"), "write_s": med("write_s"), "import_s": med("import_s"),
                     "maxrss_bytes": max(r["maxrss_bytes"] for r in runs), "checksum": runs[0]["checksum"],
                     "runs": runs})
        print(f"{which}: read {rows[-1]['read_s']:.3f} s, peak {rows[-1]['maxrss_bytes'] / 2**20:.0f} MiB", flush=True)
    sums = {r["checksum"] for r in rows if r["reader"] != "gsply"}
    result = {"machine": machine_info(), "load_before": load_before, "load_after": os.getloadavg(),
              "splats": args.splats, "file_bytes": size, "repeats": args.repeats, "rows": rows,
              "same_arrays": len(sums) == 1}
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "ply_read.json").write_text(dumps(result, indent=1))
    m = result["machine"]
    lines = ["# PLY read and write at 1 M splats", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {numpy.__version__}, gsply "
             f"{version('gsply')}, plyfile {version('plyfile')}. Load average before "
             f"{[round(x, 2) for x in load_before]}, after {[round(x, 2) for x in result['load_after']]}.",
             f"File: {args.splats:,} splats, SH degree 3 with normals, {size:,} bytes ({size / 2**20:.0f} MiB), in "
             f"the page cache. Median of {args.repeats} fresh processes after one warm-up; peak = the process's maximum resident set right after reading (interpreter and imports included).",
             "", "| reader | read (s) | splats/s | peak memory (MiB) | peak / file size | write (s) | import (s) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        w = f"{r['write_s']:.3f}" if r["write_s"] is not None else "-"
        lines.append(f"| {r['reader']} | {r['read_s']:.3f} | {args.splats / r['read_s'] / 1e6:.0f} M | "
                     f"{r['maxrss_bytes'] / 2**20:.0f} | {r['maxrss_bytes'] / size:.2f} | {w} | {r['import_s']:.2f} |")
    lines += ["", "l3gs-opt and plyfile end with the same arrays (checksum equal: "
              f"{result['same_arrays']}); gsply keeps SH DC and rest apart (`sh0`, `shN`), same values."]
    (OUT / "ply_read.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
