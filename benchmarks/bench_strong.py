"""``bb`` on Pisinger's strongly correlated MCKP (J=10,000, L=10, seeds 0..4), plus a spot check
of the other families, for iterating on the single-slot solver (issue 4: < 10 s per seed).

Each run is one :func:`l3gs_opt.solve` call (``method="bb"``, ``slot=0``) on the instances of
``bench_solvers.py`` (:func:`bench_solvers.make_instance`); it records wall time, CPU time of
this process, status, objective, bound and the 1-minute load average at its start (the
machine is shared: 2 cores, other jobs running). Results go to
``benchmarks/results/solvers_strong.json`` under ``--label`` (other labels in the file are
kept, so "before" and "after" sit side by side), with the machine facts.

    .venv/bin/python benchmarks/bench_strong.py --label after [--seeds 0,1,2,3,4] [--spot] [--repeat 5]

``--spot`` also times the other families (l3gs / l3gs-all at J = 1,000 and 10,000, unc / weak at
J = 10,000, seed 0..4, median of ``--repeat`` runs each) to check that nothing got slower.

``--against OLD.py`` compares the MCKP core with another version of it in the same process, which
is fairer on a shared machine than runs at different times: ``OLD.py`` is a copy of
``solvers/_mckp.py`` (e.g. ``git show HEAD:solvers/_mckp.py > /tmp/old_mckp.py``); each instance's
option table is built once and ``branch_and_bound`` of both versions runs ``--repeat`` times,
alternating, timed in CPU seconds (median). Stored under ``ab``, with the objectives checked equal.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_solvers import make_instance  # noqa: E402
from machine import machine_info  # noqa: E402

from l3gs_opt import solve  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.solvers import _mckp  # noqa: E402
from l3gs_opt.solvers.mckp import slot_table  # noqa: E402

SPOT = [("l3gs", 1000, 4), ("l3gs", 10000, 4), ("l3gs-all", 1000, 4), ("l3gs-all", 10000, 4),
        ("unc", 10000, 10), ("weak", 10000, 10)]


def run_once(family: str, J: int, L: int, seed: int) -> dict:
    inst = make_instance(family, J, L, seed)
    load = os.getloadavg()[0]
    cpu = time.process_time()
    started = time.perf_counter()
    sol = solve(inst, method="bb", slot=0)
    wall = time.perf_counter() - started
    return {"family": family, "J": J, "L": L, "seed": seed, "wall_s": wall, "cpu_s": time.process_time() - cpu,
            "runtime_s": sol.runtime_s, "status": sol.status.value, "objective": sol.objective, "bound": sol.bound,
            "gap": sol.gap, "loadavg_1min": load,
            "details": {k: v for k, v in sol.details.items() if isinstance(v, (int, float, str, bool))}}


def compare(old_path: Path, cases: list[tuple[str, int, int]], seeds: list[int], repeat: int) -> list[dict]:
    """CPU seconds of ``branch_and_bound`` in the current core and in ``old_path``, alternating."""
    spec = importlib.util.spec_from_file_location("old_mckp", old_path)
    old = importlib.util.module_from_spec(spec)
    sys.modules["old_mckp"] = old        # dataclasses look their module up while the class is built
    spec.loader.exec_module(old)
    out = []
    for family, J, L in cases:
        for seed in seeds:
            table, _ = slot_table(make_instance(family, J, L, seed), 0)
            times: dict[str, list[float]] = {"old": [], "new": []}
            values = {}
            load = os.getloadavg()[0]
            for r in range(repeat):
                order = (("old", old), ("new", _mckp)) if r % 2 == 0 else (("new", _mckp), ("old", old))
                for name, mod in order:
                    cpu = time.process_time()
                    res = mod.branch_and_bound(table)
                    times[name].append(time.process_time() - cpu)
                    values[name] = res.value
            same = abs(values["old"] - values["new"]) <= 1e-9 * max(1.0, abs(values["old"]))
            rec = {"family": family, "J": J, "L": L, "seed": seed, "old_cpu_s": float(np.median(times["old"])),
                   "new_cpu_s": float(np.median(times["new"])), "same_objective": same, "repeat": repeat,
                   "loadavg_1min": load}
            out.append(rec)
            print(f"A/B {family} J={J} seed {seed}: old {1e3 * rec['old_cpu_s']:.1f} ms, new "
                  f"{1e3 * rec['new_cpu_s']:.1f} ms CPU (x{rec['new_cpu_s'] / rec['old_cpu_s']:.2f}), "
                  f"same objective {same}, load {load:.2f}", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", default="current", help="key under which the runs are stored")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--spot", action="store_true", help="also time the other families")
    ap.add_argument("--no-strong", action="store_true", help="skip the strongly correlated runs")
    ap.add_argument("--repeat", type=int, default=5, help="runs per spot-check instance (median reported)")
    ap.add_argument("--against", type=Path, default=None, help="a copy of solvers/_mckp.py to compare with (A/B)")
    ap.add_argument("--out", default="benchmarks/results/solvers_strong.json")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s]
    out = Path(args.out)
    data = json.loads(out.read_text()) if out.exists() else {}
    entry: dict = {"machine": machine_info(), "strong": [], "spot": [], "ab": []}
    if not args.no_strong:
        for seed in seeds:
            rec = run_once("strong", 10000, 10, seed)
            entry["strong"].append(rec)
            print(f"strong J=10000 L=10 seed {seed}: wall {rec['wall_s']:.2f} s, cpu {rec['cpu_s']:.2f} s, "
                  f"{rec['status']}, objective {rec['objective']:.1f}, bound {rec['bound']:.4f}, "
                  f"load {rec['loadavg_1min']:.2f}", flush=True)
    if args.spot:
        for family, J, L in SPOT:
            for seed in seeds:
                recs = [run_once(family, J, L, seed) for _ in range(args.repeat)]
                walls = [r["wall_s"] for r in recs]
                rec = {**recs[0], "wall_s": float(np.median(walls)), "wall_min_s": min(walls),
                       "cpu_s": float(np.median([r["cpu_s"] for r in recs])),
                       "loadavg_1min": float(np.median([r["loadavg_1min"] for r in recs])), "repeat": args.repeat}
                entry["spot"].append(rec)
                print(f"{family} J={J} seed {seed}: median wall {1e3 * rec['wall_s']:.1f} ms (min "
                      f"{1e3 * rec['wall_min_s']:.1f}), {rec['status']}, load {rec['loadavg_1min']:.2f}", flush=True)
    if args.against is not None:
        entry["ab"] = compare(args.against, SPOT + [("strong", 1000, 10)], seeds, args.repeat)
    data[args.label] = entry
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(dumps(data, indent=1))
    print(f"wrote {out} [{args.label}]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
