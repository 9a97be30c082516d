"""Model sizes before/after presolve and run time of each ILP backend at the paper's scale.

J=20 objects, L=4 layers, T=60 slots, a real Lumos5G trace scaled to a mean of 11.8 Mbit/s,
standard form (Problem I) and GAP form (Problem A), every backend, a time limit per solve.
Resumable: records go to a JSONL file as they finish and finished ones are skipped.

    .venv/bin/python benchmarks/bench_models.py [--time-limit 60] [--out benchmarks/results]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info  # noqa: E402

from l3gs_opt import solve  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.models import installed_backends  # noqa: E402
from l3gs_opt.pipeline.synth import synth_instance  # noqa: E402

SETTINGS = {"objects": 20, "layers": 4, "slots": 60, "seed": 0, "trace": "lumos-throughput-mid-11",
            "mbps": 11.8, "start": 0}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--out", default="benchmarks/results")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "models_j20_l4_t60.jsonl"
    done = set()
    if path.exists():
        for line in path.read_text().splitlines():
            rec = json.loads(line)
            done.add((rec["backend"], rec["form"]))
    instance = synth_instance(**SETTINGS)
    runs = [(b.value, form) for form in ("standard", "gap") for b in installed_backends()]
    with path.open("a", encoding="utf-8") as fh:
        for backend, form in tqdm([r for r in runs if r not in done], desc="backends", unit="solve"):
            sol = solve(instance, "ilp", backend=backend, form=form, time_limit_s=args.time_limit)
            rec = {"backend": backend, "form": form, "time_limit_s": args.time_limit, "settings": SETTINGS,
                   "instance_meta": dict(instance.meta), "machine": machine_info(),
                   "loadavg_after": os.getloadavg(), **sol.to_dict()}
            rec.pop("arrivals")
            fh.write(dumps(rec) + "\n")
            fh.flush()
    write_markdown(path, out / "models_j20_l4_t60.md")
    return 0


def write_markdown(jsonl: Path, md: Path) -> None:
    recs = [json.loads(line) for line in jsonl.read_text().splitlines()]
    m = recs[0]["machine"]
    lines = ["# ILP backends at the paper's scale (J=20, L=4, T=60)", "",
             f"Instance: `synth_instance({', '.join(f'{k}={v!r}' for k, v in SETTINGS.items())})`: trace "
             f"{recs[0]['instance_meta']['trace']} scaled x{recs[0]['instance_meta']['scale_factor']:.5f} to a mean of "
             f"11.8 Mbit/s, window 0..60 s. Time limit {recs[0]['time_limit_s']} s per solve.", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, Python {m['python']}; packages {m['packages']}. "
             "Load average is recorded per run (other jobs shared the machine).", "",
             "| form | backend | status | objective | bound | gap | run time (s) | vars/rows/nnz before presolve "
             "| after presolve | load avg (1 min) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        b, a = r["model_size"]["before_presolve"], r["model_size"]["after_presolve"]
        gap = "-" if r["gap"] is None else f"{r['gap']:.2e}"
        bound = "-" if r["bound"] is None else f"{r['bound']:.6g}"
        lines.append(f"| {r['form']} | {r['backend']} | {r['status']} | {r['objective']:.6g} | {bound} | {gap} | "
                     f"{r['runtime_s']:.1f} | {b['variables']}/{b['constraints']}/{b['nonzeros']} | "
                     f"{a['variables']}/{a['constraints']}/{a['nonzeros']} | {r['loadavg_after'][0]:.2f} |")
    md.write_text("\n".join(lines) + "\n", encoding="utf-8")


if __name__ == "__main__":
    sys.exit(main())
