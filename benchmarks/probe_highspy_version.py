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

``exact --pool N`` (thirty-first session) first makes HiGHS's per-process thread pool with N threads
(a one-variable LP with ``threads=N``; every later solve with the default count uses that pool).
1.16's default pool on a 2-core machine has 2 threads, 1.14's has 1: ``--pool 1`` runs the race of
one-thread seeds under 1.16 as it runs under 1.14.

``exact --log DIR`` (thirtieth session) also writes each HiGHS MIP's own log to ``DIR`` and, after
the run, one JSON line per MIP to ``DIR/phases.jsonl``: when it started (seconds into the run), its
size, its presolve time, when its first node line was printed (HiGHS's clock: presolve and the
set-up before the root LP) and its total time. That is where a run past its limit spends the time
no callback reaches.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import highspy  # noqa: E402


def _on_mips(setup) -> None:
    """Call ``setup(h)`` on every HiGHS MIP `exact` builds (wraps its ``new_highs``; stacks)."""
    from l3gs_opt.solvers.exact import lns

    plain = lns.new_highs

    def new_highs(**kw):
        h = plain(**kw)
        if kw.get("mip"):
            setup(h)
        return h

    lns.new_highs = new_highs


def _parallel_mips() -> None:
    """One HiGHS run per MIP with two tree-search threads instead of the race of two seeds."""
    from l3gs_opt.models.backends import highs_race

    highs_race.RACE_RUNS = 1

    def parallel(h) -> None:
        h.setOptionValue("parallel", "on")
        h.setOptionValue("threads", 2)

    _on_mips(parallel)


def _make_pool(threads: int) -> None:
    """HiGHS's thread pool of this process, made now with ``threads`` threads."""
    highspy.Highs.resetGlobalScheduler(True)
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("threads", threads)
    h.addVar(0.0, 1.0)
    if h.run() != highspy.HighsStatus.kOk:
        raise SystemExit(f"--pool {threads}: HiGHS refused that thread count")


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


def _logging_mips(directory: Path) -> list[tuple[Path, float]]:
    """Give every MIP `exact` builds its own HiGHS log in ``directory``; returns the (log, start in
    seconds from now) of each, filled as they are built."""
    logs: list[tuple[Path, float]] = []
    started = time.perf_counter()

    def log(h) -> None:
        path = directory / f"mip_{len(logs)}.log"
        h.setOptionValue("output_flag", True)
        h.setOptionValue("log_to_console", False)
        h.setOptionValue("log_file", str(path))
        logs.append((path, time.perf_counter() - started))

    _on_mips(log)
    return logs


#: A node line of HiGHS's branch-and-bound log ends with its clock ("... 15.6s").
_NODE_LINE = re.compile(r"^\s*[A-Za-z]?\s+\d+\s+\d+\s+\d+\s+\S+%.*\s(\d+(?:\.\d+)?)s\s*$")


def log_phases(path: Path, start_s: float) -> dict:
    """The phases of one HiGHS MIP log (seconds on HiGHS's clock; None: not in the log)."""
    text = path.read_text(errors="replace")
    size = re.search(r"MIP has (\d+) rows; (\d+) cols", text)
    first = next((float(m.group(1)) for m in map(_NODE_LINE.match, text.splitlines()) if m), None)
    total = re.search(r"^  Timing\s+(\S+)", text, re.M)
    # Presolve's last progress line ("... nonzeros 9s"; HiGHS 1.14 reports no presolve time).
    steps = re.findall(r"nonzeros (\d+(?:\.\d+)?)s\s*$", text.split("Presolve reductions")[0], re.M)
    reported = re.search(r"^\s+(\S+) \(Presolve\)", text, re.M)   # (1.15 and newer)
    status = re.search(r"^  Status\s+(.+)$", text, re.M)
    return {"log": path.name, "start_s": round(start_s, 2),
            "rows": int(size.group(1)) if size else None, "cols": int(size.group(2)) if size else None,
            "presolve_s": float(reported.group(1)) if reported else float(steps[-1]) if steps else None,
            "first_node_line_s": first,
            "total_s": float(total.group(1)) if total else None,
            "status": status.group(1).strip() if status else None}


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
    ap.add_argument("--pool", type=int, help="exact: HiGHS's thread pool made first with this many threads")
    ap.add_argument("--log", type=Path, help="exact: each HiGHS MIP's log and DIR/phases.jsonl go here")
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
    if args.pool is not None:
        _make_pool(args.pool)
    arm = ("highspy-" + highspy.Highs().version() + ("-parallel" if args.parallel else "")
           + (f"-pool{args.pool}" if args.pool is not None else ""))
    logs = None
    if args.log is not None:
        args.log.mkdir(parents=True, exist_ok=True)
        logs = _logging_mips(args.log)   # (its clock includes run()'s instance build: under a second)
    run(args.J, [args.seed], arm, "both", args.time_limit, args.out)
    if logs is not None:
        with (args.log / "phases.jsonl").open("a", encoding="utf-8") as fh:
            for path, start in logs:
                line = json.dumps(dict(log_phases(path, start), instance=f"T60-J{args.J}-s{args.seed}", arm=arm))
                print(line)
                fh.write(line + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
