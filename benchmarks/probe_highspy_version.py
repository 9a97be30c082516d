"""Probe (issue 23 item 2, twenty-ninth session): `exact` and its HiGHS models under another highspy
release, with HiGHS 1.15's parallel branch-and-cut as an option.

The project pins highspy 1.14 (constraints.txt). To try another release without touching the venv,
install it beside it and put it first on the path:

    .venv/bin/pip install --target /tmp/hs16 --no-deps highspy==1.16.0
    PYTHONPATH=/tmp/hs16 .venv/bin/python benchmarks/probe_highspy_version.py exact --J 20 --seed 0 --out runs.jsonl

Three commands, each run alone on an otherwise idle machine:

* ``exact``: one 60 s `exact` run, a JSON line appended to ``--out`` (as probe_exact_lean_root.py),
  the arm named by the highspy release loaded; ``--parallel`` replaces the race of two one-thread
  HiGHS runs (:mod:`l3gs_opt.models.backends.highs_race`) by one HiGHS run with ``parallel=on``,
  ``threads=2`` (HiGHS 1.15 and newer search the tree with several workers).
* ``export``: one `exact` run that writes every raced HiGHS model (the first seed's) as an MPS file
  and its cut-off and tolerances beside it (``<model>.mps.json``) into ``--dir``.
* ``solve``: HiGHS alone on one exported model, with its cut-off, serial (``threads=1``) or
  ``--parallel``; one JSON line on stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import highspy  # noqa: E402


def _parallel_mips() -> None:
    """One HiGHS run per MIP with two tree-search threads instead of the race of two seeds."""
    from l3gs_opt.models.backends import highs_race
    from l3gs_opt.solvers.exact import lns

    highs_race.RACE_RUNS = 1
    plain = lns.new_highs

    def new_highs(**kw):
        h = plain(**kw)
        if kw.get("mip"):
            h.setOptionValue("parallel", "on")
            h.setOptionValue("threads", 2)
        return h

    lns.new_highs = new_highs


def _export(directory: Path, tag: str) -> list:
    """Make every raced HiGHS model be written to ``directory`` as it is built; returns the list of
    paths written (filled as they are)."""
    from l3gs_opt.models.backends import highs_race
    from l3gs_opt.solvers.exact import lns

    race, written = highs_race.race_mip, []

    def exporting(build, seeds, *, stop=None):
        seeds = tuple(seeds)

        def built(seed):
            h = build(seed)
            if seed == seeds[0]:
                path = directory / f"{tag}_{len(written)}.mps"
                h.writeModel(str(path))
                meta = {o: h.getOptionValue(o)[1] for o in
                        ("objective_bound", "presolve_rule_off", "mip_feasibility_tolerance")}
                meta.update(cols=h.getNumCol(), rows=h.getNumRow())
                path.with_suffix(".mps.json").write_text(json.dumps(meta))
                written.append(path)
            return h
        return race(built, seeds, stop=stop)

    highs_race.race_mip = lns.race_mip = exporting
    return written


def _instance(J: int, seed: int, budget: str):
    from bench_exact import bench_instance
    from l3gs_opt.bench.suites import paper_spec
    return bench_instance(paper_spec(J, seed), budget)


def solve_model(path: Path, parallel: bool, seed: int, time_limit_s: float) -> dict:
    """HiGHS set up as `exact` sets up its MIPs (:func:`new_highs`), with the run's cut-off and
    tolerances as exported, on the model at ``path``."""
    from l3gs_opt.models.backends.highs import new_highs

    meta = json.loads(path.with_suffix(".mps.json").read_text())
    h = new_highs(time_limit_s=time_limit_s, mip=True, proof=True)
    h.readModel(str(path))
    for key, value in (("mip_feasibility_tolerance", float(meta["mip_feasibility_tolerance"])),
                       ("presolve_rule_off", int(meta["presolve_rule_off"])),
                       ("objective_bound", float(meta["objective_bound"])), ("random_seed", seed)):
        h.setOptionValue(key, value)
    if parallel:
        h.setOptionValue("parallel", "on")
        h.setOptionValue("threads", 2)
    else:
        h.setOptionValue("threads", 1)
    started = time.perf_counter()
    h.run()
    info = h.getInfo()
    # (kOptimal under the cut-off: nothing beats it; the point HiGHS returns then means nothing.)
    return {"model": path.name, "highspy": h.version(), "parallel": parallel, "seed": seed,
            "status": h.getModelStatus().name, "seconds": round(time.perf_counter() - started, 1),
            "dual_bound": -info.mip_dual_bound, "nodes": info.mip_node_count}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("command", choices=("exact", "export", "solve"))
    ap.add_argument("--J", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0, help="instance seed (exact, export); HiGHS seed (solve)")
    ap.add_argument("--budget", choices=("per_slot", "cumulative"), default="per_slot")
    ap.add_argument("--parallel", action="store_true")
    ap.add_argument("--time-limit", type=float, default=60.0, help="seconds")
    ap.add_argument("--out", type=Path, help="exact: JSON lines appended here")
    ap.add_argument("--dir", type=Path, default=Path("/tmp/highs_models"), help="export: where the models go")
    ap.add_argument("--model", type=Path, help="solve: an exported .mps file")
    args = ap.parse_args(argv)
    if args.command == "solve":
        print(json.dumps(solve_model(args.model, args.parallel, args.seed, args.time_limit)), flush=True)
        return 0
    if args.parallel:
        _parallel_mips()
    if args.command == "export":
        from l3gs_opt import solve
        args.dir.mkdir(parents=True, exist_ok=True)
        tag = f"{'c' if args.budget == 'cumulative' else 'p'}{args.J}s{args.seed}"
        written = _export(args.dir, tag)
        sol = solve(_instance(args.J, args.seed, args.budget), "exact", time_limit_s=args.time_limit)
        print(tag, sol.status.value, sol.objective, sol.bound, [p.name for p in written])
        return 0
    if args.out is None:
        ap.error("exact needs --out")
    if args.budget != "per_slot":
        ap.error("exact runs the per-slot instances (probe_exact_lean_root.run)")
    from probe_exact_lean_root import run
    arm = "highspy-" + highspy.Highs().version() + ("-parallel" if args.parallel else "")
    run(args.J, [args.seed], arm, "both", args.time_limit, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
