"""Why L3GS loses the first seconds, and what counting the slot's last chunk by its first splats buys.

The per-slot MCKP counts a chunk only when all of it arrives in the slot. Early on, the most useful
chunks are larger than a slot's bytes, so it buys the small chunks that fit, while the link would
stream a large chunk's most useful splats first and the viewer would show them
(``SimConfig.last_chunk="prefix"``, :mod:`l3gs_opt.simulator.last_chunk`). This runs ``l3gs`` and
``l3gs-noseg`` with both models beside ``progressive`` (every object's base layer first, the same
chunks) on the experiments' rooms, windows and paths: the quick plan's three Lumos5G windows (one
per variance class), the orbit and the logged head turns, 160x120, the experiments' scaling of the
trace to the scene; SSIM over the 60 s window, its first 5 and 10 s.

Scenes (built on first use with the experiments' schedule, cached under ``--cache``): ``room8k``
(the quick plan's room: 4 solids, the shell one object holding 65% of the bytes) and
``room20k-o8-parts`` (8 solids, the shell cut into its six surfaces: 14 objects). Records are
appended as they finish (``runs.jsonl``; a run already recorded is skipped), then ``README.md``'s
table (``table.md``) and ``first_seconds.png`` are rewritten (``--report-only``: from ``runs.jsonl`` alone).

    .venv/bin/python benchmarks/bench_last_chunk.py [--cache DIR] [--out benchmarks/results/last_chunk]
        [--scenes room8k,room20k-o8-parts] [--paths orbit,turns-log] [--utilities visibility]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402

SCENES = {"room8k": dict(splats=8000, objects=4, room_parts=False),
          "room20k-o8-parts": dict(splats=20_000, objects=8, room_parts=True)}
#: (label, method, last_chunk): the two models of l3gs and l3gs-noseg, and the isolating method.
RUNS = (("l3gs", "l3gs", "whole"), ("l3gs prefix", "l3gs", "prefix"), ("l3gs-noseg", "l3gs-noseg", "whole"),
        ("l3gs-noseg prefix", "l3gs-noseg", "prefix"), ("progressive", "progressive", "whole"))


def _record_id(r: dict) -> str:
    return f"{r['scene']}/{r['path']}/{r['trace']}@{r['start_s']}/{r['utility']}/{r['label']}"


def run(args) -> list[dict]:
    from l3gs_opt.experiments.plan import SceneSpec, make_plan, scaled_mbps
    from l3gs_opt.experiments.run import _Scene   # the experiments' cached teacher, bundles and paths
    from l3gs_opt.simulator.simulation import SimConfig, Simulation, trace_bytes

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    runs_file = out / "runs.jsonl"
    done = {_record_id(json.loads(line)) for line in runs_file.read_text().splitlines() if line.strip()} \
        if runs_file.exists() else set()
    machine = machine_info()
    for name in args.scenes:
        spec = SceneSpec(name, sh_degree=1, seed=0, **SCENES[name])
        plan = make_plan(quick=True, scenes=[spec], variants=["layered"], paths=args.paths,
                         methods=["l3gs"], ablations=[], width=160, height=120)
        scene = _Scene(spec, plan, Path(args.cache), lambda line: print(line, flush=True))
        bundle = scene.bundle("layered")
        mbps = scaled_mbps(scene.scene_bytes())
        for path in plan.paths:
            poses = scene.poses(path, plan.window_s)
            for trace, starts in zip(plan.traces, plan.starts):
                for start in starts:
                    bandwidth, info = trace_bytes(trace.path, mbps=mbps, start=start, slots=plan.window_s)
                    sims = {}
                    for utility in args.utilities:
                        for label, method, mode in RUNS:
                            base = {"scene": name, "path": path.name, "trace": trace.name, "trace_class": trace.klass,
                                    "start_s": start, "utility": utility, "label": label}
                            if _record_id(base) in done:
                                continue
                            if mode not in sims:
                                config = SimConfig(width=160, height=120, samples_per_slot=plan.samples_per_slot,
                                                   last_chunk=mode)
                                sims[mode] = Simulation(bundle, poses, bandwidth, config=config,
                                                        reference=str(scene.teacher), info=info)
                            t0 = time.perf_counter()
                            load = os.getloadavg()[0]
                            res = sims[mode].run(method, utility=utility)
                            s = res.summary
                            per = [float(v) for v in s["ssim_per_s"]]
                            rec = {**base, "method": method, "last_chunk": mode, "mbps": mbps,
                                   "ssim_mean": float(s["ssim_mean"]), "first5": float(np.mean(per[:5])),
                                   "first10": float(np.mean(per[:10])), "ssim_per_s": per,
                                   "bytes_delivered": s["bytes_delivered"], "run_s": time.perf_counter() - t0,
                                   "loadavg_start": load, "machine": machine,
                                   "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
                            with open(runs_file, "a", encoding="utf-8") as fh:
                                fh.write(dumps(rec) + "\n")
                            done.add(_record_id(base))
                            print(f"{_record_id(base)}: SSIM {rec['ssim_mean']:.4f}, first 5 s {rec['first5']:.4f} "
                                  f"({rec['run_s']:.1f} s)", flush=True)
    return [json.loads(line) for line in runs_file.read_text().splitlines() if line.strip()]


def report(recs: list[dict], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in recs:
        groups[(r["scene"], r["path"], r["utility"], r["label"])].append(r)
    labels = [label for label, _, _ in RUNS]
    keys = sorted({k[:3] for k in groups})
    lines = ["| scene | path | utility | method | runs | SSIM (60 s) | first 5 s | first 10 s |", "|---|---|---|---|---|---|---|---|"]
    for key in keys:
        for label in labels:
            rs = groups.get((*key, label), [])
            if rs:
                lines.append(f"| {key[0]} | {key[1]} | {key[2]} | {label} | {len(rs)} | "
                             f"{np.mean([r['ssim_mean'] for r in rs]):.4f} | {np.mean([r['first5'] for r in rs]):.4f} "
                             f"| {np.mean([r['first10'] for r in rs]):.4f} |")
    lines.append("")
    lines.append("Per utility, over every scene, path and window (mean of the runs; the change against the same "
                 "method with whole chunks):")
    lines.append("")
    lines.append("| utility | method | runs | SSIM (60 s) | first 5 s | first 10 s |")
    lines.append("|---|---|---|---|---|---|")
    for utility in sorted({r["utility"] for r in recs}):
        means, counts = {}, {}
        for label in labels:
            rs = [r for r in recs if r["label"] == label and r["utility"] == utility]
            if rs:
                means[label] = tuple(float(np.mean([r[k] for r in rs])) for k in ("ssim_mean", "first5", "first10"))
                counts[label] = len(rs)
        for label, m in means.items():
            ref = means.get(label.replace(" prefix", "")) if label.endswith(" prefix") else None
            cells = [f"{v:.4f}" + (f" ({100 * (v / r - 1):+.1f}%)" if ref else "") for v, r in zip(m, ref or m)]
            lines.append(f"| {utility} | {label} | {counts[label]} | {' | '.join(cells)} |")
    machines = sorted({(r["machine"]["cpu"], r["machine"]["cores"]) for r in recs})
    lines.append("")
    lines.append("Machine: " + "; ".join(f"{cpu}, {cores} cores" for cpu, cores in machines) +
                 f"; Python {recs[0]['machine']['python']}, numpy {recs[0]['machine']['packages']['numpy']}; "
                 f"runs finished {min(r['finished_utc'] for r in recs)} to {max(r['finished_utc'] for r in recs)}; "
                 f"load at each run's start {min(r['loadavg_start'] for r in recs):.1f}-"
                 f"{max(r['loadavg_start'] for r in recs):.1f}.")
    (out / "table.md").write_text("\n".join(lines) + "\n")

    # (l3gs-noseg's whole-scene layers are larger than a slot from the start: its prefix runs gave
    # the same SSIM as its whole-chunk runs in every record here, so one line stands for both.)
    shown = {"l3gs": ("tab:blue", "--"), "l3gs prefix": ("tab:blue", "-"), "l3gs-noseg": ("tab:red", ":"),
             "progressive": ("tab:purple", "-.")}
    cols = 2
    rows_n = -(-len(keys) // cols)
    fig, axes = plt.subplots(rows_n, cols, figsize=(10, 3.3 * rows_n), squeeze=False, sharey=True)
    for ax, key in zip(axes.flat, keys):
        for label, (colour, style) in shown.items():
            rs = groups.get((*key, label), [])
            if rs:
                curve = np.mean([r["ssim_per_s"][:20] for r in rs], axis=0)
                ax.plot(np.arange(1, len(curve) + 1), curve, marker=".", color=colour, linestyle=style, label=label)
        ax.set_title(f"{key[0]}, {key[1]} (utility {key[2]})", fontsize=9)
        ax.set_xlabel("time (s)")
        ax.set_xticks(range(0, 21, 5))
        ax.grid(alpha=0.3)
        ax.set_ylabel("SSIM (mean of 3 windows)")
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8)
    fig.suptitle("The first 20 s: the slot's last chunk counted whole (l3gs) or by its first splats (l3gs prefix)",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "first_seconds.png", dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cache", default="/tmp/l3gs-last-chunk", help="folder for teachers, bundles and pose logs")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results" / "last_chunk"))
    ap.add_argument("--scenes", default=",".join(SCENES), type=lambda s: s.split(","))
    ap.add_argument("--paths", default="orbit,turns-log", type=lambda s: s.split(","))
    ap.add_argument("--utilities", default="visibility", type=lambda s: s.split(","))
    ap.add_argument("--report-only", action="store_true", help="rewrite table.md and the plot from runs.jsonl")
    args = ap.parse_args()
    for s in args.scenes:
        if s not in SCENES:
            ap.error(f"--scenes: {s!r} is not one of {', '.join(SCENES)}")
    if args.report_only:
        recs = [json.loads(line) for line in (Path(args.out) / "runs.jsonl").read_text().splitlines() if line.strip()]
    else:
        recs = run(args)
    report(recs, Path(args.out))
    print((Path(args.out) / "table.md").read_text())


if __name__ == "__main__":
    main()
