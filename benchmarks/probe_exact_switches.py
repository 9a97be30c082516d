"""Probe (issue 23 item 2, twenty-third session): one `exact` run on a paper-scale instance with its
module switches set, one line of results.

``--covers`` sets ``search.COVER_CUTS`` (off / root / nodes); ``--no-mip-covers`` keeps the cover
rows out of HiGHS's reduced model (the master keeps them); ``--skip-root-improvement`` replaces
the root's repair and window LNS with the fixing alone (what :meth:`_Search.improve_at_root` does
after them); ``--start-from-proof`` starts the run from a proven optimum; ``--root-primal`` sets
``search.ROOT_PRIMAL`` (anneal / lns: the twenty-fourth session's A/B). Runs are meant to be made one after another on an otherwise idle machine.

    .venv/bin/python benchmarks/probe_exact_switches.py --J 20 --seed 4 --covers root
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from l3gs_opt.bench.suites import paper_spec  # noqa: E402
from l3gs_opt.solvers.exact import lns, search  # noqa: E402
from machine import machine_info  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--J", type=int, default=20)
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--time-limit", type=float, default=60.0, help="seconds")
    ap.add_argument("--covers", choices=("off", "root", "nodes"), default="off")
    ap.add_argument("--no-mip-covers", action="store_true")
    ap.add_argument("--skip-root-improvement", action="store_true")
    ap.add_argument("--root-primal", choices=("anneal", "lns"), default=search.ROOT_PRIMAL)
    ap.add_argument("--start-from-proof", type=float, default=None, metavar="SECONDS",
                    help="first prove the instance with default switches within SECONDS, then start the measured "
                         "run from that optimum (what the proof needs besides finding the schedule)")
    args = ap.parse_args(argv)
    inst = paper_spec(args.J, args.seed).build()
    if args.start_from_proof is not None:
        first = search.solve_exact(inst, time_limit_s=args.start_from_proof)
        if first.status.value != "optimal":
            print(f"no proof within {args.start_from_proof} s", file=sys.stderr)
            return 1
        known = first.arrivals

        def start_at_optimum(instance, data, heuristics, deadline):
            return data.assignment(known), "optimum", {}
        search.best_start = start_at_optimum
    search.COVER_CUTS = args.covers
    search.ROOT_PRIMAL = args.root_primal
    if args.no_mip_covers:
        plain = lns.reduced_mip
        search.reduced_mip = lambda *a, covers=(), **k: plain(*a, **k)
    if args.skip_root_improvement:
        def fixing_only(self) -> None:
            self.allowed_root = self.fixed_at(self.z, self.allowed0, exact=True)
            self.details["root"]["fixed_pairs"] = int(self.allowed0.sum() - self.allowed_root.sum())
            self.details["root"]["incumbent"] = self.z
        search._Search.improve_at_root = fixing_only
    load = os.getloadavg()[0]
    started = time.perf_counter()
    sol = search.solve_exact(inst, time_limit_s=args.time_limit)
    d = sol.details
    print(json.dumps({
        "instance": f"T60-J{args.J}-s{args.seed}", "covers": args.covers, "mip_covers": not args.no_mip_covers,
        "skip_root_improvement": args.skip_root_improvement, "root_primal": args.root_primal,
        "after_anneal": None if "after_anneal" not in d else round(float(d["after_anneal"]), 2), "start_from_optimum": args.start_from_proof is not None,
        "status": sol.status.value,
        "objective": round(sol.objective, 2), "bound": round(sol.bound, 2),
        "seconds": round(time.perf_counter() - started, 1), "root_bound": round(float(d["root"]["bound"]), 2),
        "cover_rounds": {k: (round(float(v), 2) if isinstance(v, float) else v) for k, v in d.get("covers", {}).items()},
        "node_covers": d.get("node_covers"), "fixed_pairs": d["root"].get("fixed_pairs"), "nodes": d["nodes"],
        "load_before": round(load, 2), "load_after": round(os.getloadavg()[0], 2),
        "cpu": machine_info()["cpu"]}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
