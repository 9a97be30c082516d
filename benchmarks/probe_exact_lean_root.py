"""Probe (issue 23 item 2, twenty-fifth session): `exact`'s root after the annealing, A/B, one JSON
line per run appended to ``--out``.

``--arm lean`` is the code as it is: after the annealing (which stops after ANNEAL_PATIENCE rounds
that find nothing) no LP neighbourhood MIPs where n * T <= LEAN_ROOT_MAX_PAIRS and no ``mpc:3``
start, and the fixing runs the knapsack test with the tightest certificate only.
``--arm base`` patches back what eac5920 did: both LP neighbourhoods (after the LP and after the
root column generation, each up to NEIGHBOURHOOD_SHARE of the time left), ``mpc:3`` among the
start heuristics (J * L <= MPC_MAX_CHUNKS), and the knapsack test with every certificate in turn
under one deadline. ``--branching`` is `exact`'s option. Runs are meant to be made one after
another on an otherwise idle machine.

    .venv/bin/python benchmarks/probe_exact_lean_root.py --J 20 --seeds 0-13 --arm base --out runs.jsonl
    .venv/bin/python benchmarks/probe_exact_lean_root.py --out runs.jsonl --report   # the tables
"""

from __future__ import annotations

import argparse
import json
import statistics
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from l3gs_opt.bench.suites import paper_spec  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.models.backends.highs_race import mip_seeds  # noqa: E402
from l3gs_opt.solvers.exact import search  # noqa: E402
from l3gs_opt.solvers.exact.lns import lp_neighbourhood  # noqa: E402
from machine import machine_info  # noqa: E402


def _neighbourhood_before(self, x, band=0, share=search.NEIGHBOURHOOD_SHARE) -> None:
    left = self.left()
    if (left is not None and left <= 0) or search._closed(self.bound, self.z):
        return
    cand = lp_neighbourhood(self.data, x, self.allowed0, self.z, time_limit_s=None if left is None else share * left,
                            start=self.assign, band=band, seeds=mip_seeds())
    if cand is not None:
        self.try_incumbent(cand, self.allowed0, {})


def _fixed_at_before(self, value, mask, exact=False):
    exact = exact and self.data.n * self.data.T <= search.COLGEN_MAX_PAIRS
    deadline = None if self.deadline is None else \
        time.perf_counter() + search.EXACT_FIXING_SHARE * max(self.deadline - time.perf_counter(), 0.0)
    for lv in self.certificates:
        mask = search.reduced_cost_fixing(self.data, lv, lv.bound, value, mask, exact_knapsack=exact,
                                          deadline=deadline)
    return mask


def _seeds(text: str) -> list[int]:
    lo, _, hi = text.partition("-")
    return list(range(int(lo), int(hi) + 1)) if hi else [int(s) for s in text.split(",")]


def arm_table(path: Path, order=None) -> tuple[list[str], dict[str, dict], list[str]]:
    """The records of ``path`` as a Markdown table: one row per instance (in ``order``'s order, else
    as met), one column per arm (as met); an open run shows schedule / bound (gap). Returns
    (arms, records by instance and arm, the table's lines)."""
    recs = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    arms = list(dict.fromkeys(r["arm"] for r in recs))
    by: dict[str, dict] = {}
    for r in recs:
        by.setdefault(r["instance"], {})[r["arm"]] = r

    def cell(r: dict | None) -> str:
        if r is None:
            return "-"
        if r["status"] == "optimal":
            return f"**optimal {r['seconds']:.1f} s**"
        return f"{r['objective']:,.2f} / {r['bound']:,.2f} ({(r['bound'] - r['objective']) / r['bound']:.1e})"

    lines = ["| instance | " + " | ".join(arms) + " |", "|---" * (len(arms) + 1) + "|"]
    lines += [f"| {i} | " + " | ".join(cell(by[i].get(a)) for a in arms) + " |"
              for i in (sorted(by, key=order) if order else by)]
    return arms, by, lines


def report(path: Path) -> str:
    """Markdown: :func:`arm_table`, then per size the proofs and the median run time (an open run
    counted at its time limit)."""

    def size_seed(name: str) -> tuple[int, int]:
        return int(name.split("-J")[1].split("-")[0]), int(name.split("-s")[1])

    arms, by, lines = arm_table(path, size_seed)
    lines.append("")
    for J in sorted({size_seed(i)[0] for i in by}):
        seeds = sorted(size_seed(i)[1] for i in by if size_seed(i)[0] == J)
        groups = [s for s in (seeds[:10], seeds) if s]
        for group in dict.fromkeys(tuple(g) for g in groups):
            for a in arms:
                rs = [by[f"T60-J{J}-s{s}"].get(a) for s in group]
                if any(r is None for r in rs):
                    continue
                t = [r["seconds"] if r["status"] == "optimal" else 60.0 for r in rs]
                lines.append(f"- J={J}, seeds {group[0]}-{group[-1]}, {a}: proven {sum(r['status'] == 'optimal' for r in rs)}"
                             f" of {len(rs)}, median {statistics.median(t):.1f} s")
    return "\n".join(lines)


def run(J: int, seeds: list[int], arm: str, branching: str, time_limit_s: float, out: Path, **kw) -> None:
    """One `exact` run per seed of ``T60-J{J}``, each a JSON line printed and appended to ``out``."""
    cpu = machine_info()["cpu"]
    for seed in seeds:
        inst = paper_spec(J, seed).build()
        load = os.getloadavg()[0]
        started = time.perf_counter()
        sol = search.solve_exact(inst, time_limit_s=time_limit_s, branching=branching, **kw)
        rec = {"instance": f"T60-J{J}-s{seed}", "arm": arm, "branching": branching,
               "status": sol.status.value,
               "objective": round(sol.objective, 2), "bound": round(sol.bound, 2),
               "seconds": round(time.perf_counter() - started, 1),
               "after_anneal": round(float(sol.details.get("after_anneal", float("nan"))), 2),
               "root_seconds": round(float(sol.details.get("root", {}).get("seconds", float("nan"))), 1),
               "root_converged": sol.details.get("root", {}).get("converged"),
               "nodes": sol.details.get("nodes"), "bound_kind": sol.details.get("bound_kind"),
               "load_before": round(load, 2), "load_after": round(os.getloadavg()[0], 2), "cpu": cpu}
        line = dumps(rec)   # (no annealing: after_anneal is NaN, written as null)
        print(line, flush=True)
        with out.open("a", encoding="utf-8") as fh:
            fh.write(line + "\n")


def ab_parser(doc: str, arms: tuple[str, ...]) -> argparse.ArgumentParser:
    """What every A/B probe's command line has: ``--arm`` (one of ``arms``), ``--time-limit``,
    ``--out`` and ``--report``."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--arm", choices=arms, default=arms[0])
    ap.add_argument("--time-limit", type=float, default=60.0, help="seconds")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--report", action="store_true", help="print the tables of --out and run nothing")
    return ap


def arguments(doc: str, arms: tuple[str, ...], seeds: str, argv=None) -> argparse.Namespace | None:
    """The A/B probes' command line over ``T60-J{J}`` seeds (:func:`ab_parser`); None when
    ``--report`` printed the tables of ``--out`` and nothing is to be run."""
    ap = ab_parser(doc, arms)
    ap.add_argument("--J", type=int, default=20)
    ap.add_argument("--seeds", default=seeds, help="'0-13' or '1,3,4'")
    ap.add_argument("--branching", choices=search.BRANCHING, default="both")
    args = ap.parse_args(argv)
    if args.report:
        print(report(args.out))
        return None
    return args


def main(argv=None) -> int:
    args = arguments(__doc__, ("lean", "base"), "0-13", argv)
    if args is None:
        return 0
    kw = {}
    if args.arm == "base":
        search._Search.neighbourhood = _neighbourhood_before
        search._Search.fixed_at = _fixed_at_before
        mpc = ("mpc:3",) if args.J * 4 <= search.MPC_MAX_CHUNKS else ()
        kw = {"heuristics": search.START_HEURISTICS + mpc}
    run(args.J, _seeds(args.seeds), args.arm, args.branching, args.time_limit, args.out, **kw)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
