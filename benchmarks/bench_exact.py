"""``exact`` against the generic MILPs at the paper's scale, bound quality, and every heuristic's gap.

Instances: the ``l3gs`` suite's T=60 specs (``suite_specs("l3gs", sizes=[J], seeds=S)``: layered,
L=4, bundled Lumos5G traces scaled to 11.8 Mbit/s, window starting at 60 s x seed), J=20 (five
seeds), J=50 (``--seeds-50``, none by default) and J=200 (``--seeds-200``). Per instance:

* methods ``exact``, ``ilp/highs``, ``ilp/cbc``, ``ilp/cpsat`` with the same time limit;
* bounds: LP relaxation (HiGHS), Lagrangian by subgradient (started from the LP duals, Polyak
  steps towards the best objective known, ``--subgradient-s`` seconds; from zero multipliers it
  was still 90-140% above the optimum after 15 s, so that start measures nothing) and the
  column-generation root bound that ``exact`` reports;
* the multi-slot heuristics of the bench suite (``rolling:bb``, ``rolling-future:bb``, ``mpc:3``,
  ``mpc:6``, ``progressive``, ``slope``, ``static``), ``mpc:H`` under the same time limit.

Records go to ``exact_runs.jsonl`` as they finish (resumable: a record already there is not run
again, so deleting one method's records re-runs only that method); ``--report`` writes
``exact.md`` (keeping the notes below its ``NOTES_MARK`` line), ``exact_summary.json`` and one
gap-against-time PNG per size.

    .venv/bin/python benchmarks/bench_exact.py [--time-limit 60] [--seeds-20 5] [--seeds-50 5] [--seeds-200 5]
    .venv/bin/python benchmarks/bench_exact.py --report
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import machine_info, machines_line  # noqa: E402

from l3gs_opt import Options, solve  # noqa: E402
from l3gs_opt.jsonout import dumps  # noqa: E402
from l3gs_opt.problem.solution import GAP_TOL  # noqa: E402
from l3gs_opt.bench.suites import split_method, suite_specs  # noqa: E402

EXACT_METHODS = ["exact", "ilp/highs", "ilp/cbc", "ilp/cpsat"]
#: ``--report`` keeps everything in exact.md from this line on (notes written by hand).
NOTES_MARK = "<!-- notes written by hand: kept by --report -->"
HEURISTICS = ["rolling:bb", "rolling-future:bb", "mpc:3", "mpc:6", "progressive", "slope", "static"]


def trace_gap(point: list, floor: float) -> float | None:
    """The relative gap of a trace point ``[seconds, schedule, bound]``, at least ``floor``; None
    while there is no finite positive bound (``null`` in the records, ``Infinity`` in files written
    before they became strict JSON)."""
    _, z, b = point
    if b is None or not math.isfinite(b) or b <= 0:
        return None
    return max((b - z) / b, floor)


def _prefix(args: argparse.Namespace) -> str:
    """File prefix of a budget's records and report: ``exact`` (per slot), ``exact_cumulative``."""
    return "exact" if args.budget == "per_slot" else f"exact_{args.budget}"


def bench_instance(spec, budget: str):
    """The spec's instance under ``budget`` ("per_slot" as the suite builds it, or "cumulative")."""
    inst = spec.build()
    if inst.options.budget == budget:
        return inst
    return inst.replace(options=Options.from_dict({**inst.options.to_dict(), "budget": budget}))


def specs(seeds_20: int, seeds_200: int, seeds_50: int = 0) -> list:
    out = []
    for J, seeds in ((20, seeds_20), (50, seeds_50), (200, seeds_200)):
        out += [s for s in suite_specs("l3gs", sizes=[J], seeds=seeds) if not s.single_slot]
    return out


def run(args: argparse.Namespace) -> None:
    from l3gs_opt.solvers.bounds import lp_bound
    from l3gs_opt.solvers.exact.lagrange import gap_data, lp_multipliers, subgradient

    path = Path(args.out) / f"{_prefix(args)}_runs.jsonl"
    done = set()
    if path.exists():
        for line in path.read_text().splitlines():
            rec = json.loads(line)
            done.add((rec["instance_id"], rec["label"]))
    machine = machine_info()
    with path.open("a", encoding="utf-8") as fh:
        def write(rec: dict) -> None:
            rec.update({"machine": machine, "loadavg_after": os.getloadavg(), "time_limit_s": args.time_limit,
                        "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
            fh.write(dumps(rec) + "\n")
            fh.flush()
            print(rec["instance_id"], rec["label"], rec.get("status"), rec.get("objective"), rec.get("bound"),
                  rec.get("gap"), f"{rec.get('runtime_s', 0):.1f}s", flush=True)

        for spec in specs(args.seeds_20, args.seeds_200, args.seeds_50):
            inst = bench_instance(spec, args.budget)
            base = {"instance_id": spec.instance_id, "params": spec.params, "J": inst.J, "T": inst.T, "L": inst.L,
                    "budget": args.budget}
            best_obj = -math.inf
            for label in EXACT_METHODS + HEURISTICS:
                if (spec.instance_id, label) in done:
                    continue
                name, kw = split_method(label)
                load_before = os.getloadavg()
                sol = solve(inst, name, time_limit_s=args.time_limit, options=None, **kw)
                rec = {**base, "label": label, "loadavg_before": load_before, **sol.to_dict()}
                rec.pop("arrivals")
                write(rec)
                best_obj = max(best_obj, sol.objective)
            if (spec.instance_id, "bound:lp") not in done:
                t0 = time.perf_counter()
                value, _ = lp_bound(inst)
                write({**base, "label": "bound:lp", "bound": value, "runtime_s": time.perf_counter() - t0})
            # (The per-slot Lagrangian of Problem A; under the cumulative budget exact reports its own.)
            if args.budget == "per_slot" and (spec.instance_id, "bound:subgradient") not in done:
                recs = [json.loads(x) for x in path.read_text().splitlines()]
                best_obj = max([r["objective"] for r in recs if r["instance_id"] == spec.instance_id
                                and r.get("objective") is not None] + [best_obj])
                t0 = time.perf_counter()
                data = gap_data(inst)
                _, lp_mult, _ = lp_multipliers(data)
                trace: list = []
                t1 = time.perf_counter()
                bound, _, _ = subgradient(data, target=best_obj, start=lp_mult, iterations=100_000,
                                          time_limit_s=args.subgradient_s, trace=trace)
                # "converged": stopped by a vanishing step or by reaching the target, not by the clock
                # (a vanishing step is not a proof that the Lagrangian dual is reached).
                timed_out = time.perf_counter() - t1 >= args.subgradient_s
                write({**base, "label": "bound:subgradient", "bound": bound, "runtime_s": time.perf_counter() - t0,
                       "iterations": len(trace), "target": best_obj, "start": "lp_duals",
                       "converged": bool(not timed_out or bound <= best_obj + GAP_TOL * abs(bound))})


def _load(out: Path, prefix: str) -> tuple[list, dict, dict]:
    recs = [json.loads(x) for x in (out / f"{prefix}_runs.jsonl").read_text().splitlines()]
    by_inst: dict[str, dict[str, dict]] = {}
    for r in recs:
        by_inst.setdefault(r["instance_id"], {})[r["label"]] = r
    return recs, by_inst, {"instances": {}}


def _best_known(d: dict) -> float:
    return max(r["objective"] for r in d.values() if r.get("objective") is not None)


def _wrong_optimum(r: dict, best_known: float) -> bool:
    """A claimed optimum below a schedule another method found (each re-evaluated from the
    instance): the claim is wrong (CBC and HiGHS did this on the cumulative budget's old carry rows)."""
    return r.get("status") == "optimal" and r["objective"] < best_known - GAP_TOL * max(1.0, abs(best_known))


def _proof_table(by_inst: dict, summary: dict) -> list[str]:
    lines = ["Gap = (bound - objective) / bound, certified by each method's own bound. `best known` = best objective "
             "of any method on the instance; `best bound` = smallest valid bound of any method or bound.", ""]
    lines += ["## Time to proof or final gap", "",
              "| instance | method | status | objective | bound | gap | run time (s) | load before/after |",
              "|---|---|---|---|---|---|---|---|"]
    for iid, d in by_inst.items():
        best_known = _best_known(d)
        bounds = [r["bound"] for k, r in d.items() if r.get("bound") is not None
                  and r.get("status") != "error" and (k.startswith("bound:") or k in EXACT_METHODS + HEURISTICS)]
        best_bound = min(b for b in bounds if b >= best_known * (1 - 1e-12)) if bounds else None
        summary["instances"][iid] = {"best_known": best_known, "best_bound": best_bound, "methods": {}}
        for label in EXACT_METHODS:
            r = d.get(label)
            if r is None:
                continue
            gap = "-" if r["gap"] is None else f"{r['gap']:.2e}"
            bound = "-" if r["bound"] is None else f"{r['bound']:.7g}"
            wrong = _wrong_optimum(r, best_known)
            status = f"{r['status']} **(wrong: below best known)**" if wrong else r["status"]
            lines.append(f"| {iid} | {label} | {status} | {r['objective']:.7g} | {bound} | {gap} | "
                         f"{r['runtime_s']:.1f} | {r['loadavg_before'][0]:.1f}/{r['loadavg_after'][0]:.1f} |")
            summary["instances"][iid]["methods"][label] = {**{k: r[k] for k in ("status", "objective", "bound", "gap",
                                                                                "runtime_s")}, "wrong_optimum": wrong}
    return lines


def _heuristics_table(by_inst: dict, summary: dict) -> list[str]:
    lines: list[str] = []
    lines += ["", "## Every multi-slot heuristic's gap at the paper's scale", "",
              "Gap to the best bound known (certified) and to the best objective known (in brackets).", "",
              "| instance | " + " | ".join(HEURISTICS) + " |", "|---|" + "---|" * len(HEURISTICS)]
    for iid, d in by_inst.items():
        s = summary["instances"][iid]
        cells = []
        s["heuristics"] = {}
        for h in HEURISTICS:
            r = d.get(h)
            if r is None:
                cells.append("-")
                continue
            gb = (s["best_bound"] - r["objective"]) / s["best_bound"] if s["best_bound"] else None
            gk = (s["best_known"] - r["objective"]) / s["best_known"]
            s["heuristics"][h] = {"objective": r["objective"], "gap_to_best_bound": gb, "gap_to_best_known": gk,
                                  "runtime_s": r["runtime_s"], "status": r["status"]}
            mark = "" if r["status"] != "time_limit" else " (time limit)"
            cells.append(f"{100 * gb:.2f}% ({100 * gk:.2f}%), {r['runtime_s']:.1f} s{mark}")
        lines.append(f"| {iid} | " + " | ".join(cells) + " |")
    return lines


def _gap_plots(by_inst: dict, out: Path, prefix: str, title: str) -> list[str]:
    """One gap-against-time PNG per size (``exact``'s trace, the MILPs' final points)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines: list[str] = []
    # Gap against time, one plot per size.
    sizes = sorted({d["exact"]["J"] for d in by_inst.values() if "exact" in d})
    colours = {"exact": "C0", "ilp/highs": "C1", "ilp/cbc": "C2", "ilp/cpsat": "C3"}
    lines += ["", "## Gap against time", ""]
    for J in sizes:
        fig, ax = plt.subplots(figsize=(9.5, 4.5))
        wrong_drawn: set[str] = set()
        for iid, d in by_inst.items():
            if "exact" not in d or d["exact"]["J"] != J:
                continue
            pts = [(p[0], trace_gap(p, 1e-9)) for p in d["exact"]["details"].get("trace", [])]
            pts = [p for p in pts if p[1] is not None]
            if pts:
                ax.step([p[0] for p in pts], [p[1] for p in pts], where="post", color=colours["exact"], alpha=0.8,
                        label="exact (trace)" if iid.endswith("s0") else None)
            for label in EXACT_METHODS[1:]:
                r = d.get(label)
                if r is None:
                    continue
                bk = _best_known(d)
                if _wrong_optimum(r, bk):
                    # Not a proof: drawn at its shortfall to the best schedule known, as a triangle.
                    ax.scatter([r["runtime_s"]], [max((bk - r["objective"]) / bk, 1e-9)], color=colours[label],
                               marker="v", s=60, label=None if label in wrong_drawn else
                               f"{label}: wrong 'optimal' (shortfall to best known)")
                    wrong_drawn.add(label)
                    continue
                g = r["gap"] if r["gap"] is not None and math.isfinite(r["gap"]) else 1.0
                ax.scatter([r["runtime_s"]], [max(min(g, 1.0), 1e-9)], color=colours[label], marker="x",
                           label=f"{label} (final)" if iid.endswith("s0") else None)
        ax.set_yscale("log")
        ax.axhline(1e-3, color="grey", lw=0.8, ls=":")
        ax.set_xlabel("seconds")
        ax.set_ylabel("certified gap (bound - objective) / bound")
        ax.set_title(f"J={J}, L=4, T=60{title}: gap against time (1e-9 = proven)")
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))   # outside: no point hidden
        fig.tight_layout()
        png = out / f"{prefix}_gap_vs_time_J{J}.png"
        fig.savefig(png, dpi=110)
        plt.close(fig)
        lines.append(f"![J={J}]({png.name})")
    lines += ["", "The generic MILPs report only their final (objective, bound); they are drawn as one point at "
              "their run time. `exact`'s trace starts when its LP relaxation (and the Lagrangian bound at its duals) is done.", ""]
    return lines


#: Seeds per group in the per-size summary. Seeds 0-4 are the instances ``exact`` was developed
#: and tuned on; 5-9 were first run on 2026-11-26, after that work (held out).
SEED_GROUP = 5


def _seed_group(rec: dict) -> str:
    seed = int(rec.get("params", {}).get("seed", 0))
    first = seed - seed % SEED_GROUP
    return f"{first}-{first + SEED_GROUP - 1}"


def _size_summary(by_inst: dict, summary: dict) -> list[str]:
    """Per size, seed group (:data:`SEED_GROUP`) and method: proven within the limit, median time
    of all runs (an unproven run counts as the limit), median time of the proofs, largest final gap.
    A claimed optimum below the best schedule known is counted as wrong, not as proven."""
    lines = ["", "## Per size", "",
             f"Seeds 0-{SEED_GROUP - 1} are the instances `exact` was developed and tuned on; later groups are "
             "held out (first run after that work). `median time` counts a run that ends unproven as its time "
             "(the limit); `wrong` counts claimed optima below a schedule another method found.", "",
             "| J | seeds | method | proven | wrong | within 0.01 % | median time (s) | median time of the proofs (s) "
             "| largest final gap |", "|---|---|---|---|---|---|---|---|---|"]
    sizes = sorted({r["J"] for d in by_inst.values() for r in d.values() if "J" in r})
    summary["sizes"] = {}
    for J in sizes:
        groups = sorted({_seed_group(r) for d in by_inst.values() for r in d.values() if r.get("J") == J},
                        key=lambda g: int(g.split("-")[0]))
        for group in groups:
            for label in EXACT_METHODS:
                ds = [d for d in by_inst.values()
                      if label in d and d[label]["J"] == J and _seed_group(d[label]) == group]
                if not ds:
                    continue
                rs = [d[label] for d in ds]
                bad = [_wrong_optimum(d[label], _best_known(d)) for d in ds]
                wrong = sum(bad)
                kept = [r for r, b in zip(rs, bad) if not b]   # a wrong claim is neither a proof nor a gap
                proven = sorted(r["runtime_s"] for r in kept if r["status"] == "optimal")
                gaps = [r["gap"] for r in kept if r["gap"] is not None]
                med = f"{statistics.median(proven):.1f}" if proven else "-"
                med_all = statistics.median(r["runtime_s"] for r in rs)
                worst = max(gaps) if gaps else None
                close = sum(1 for g in gaps if g <= 1e-4)
                summary["sizes"].setdefault(str(J), {}).setdefault(group, {})[label] = {
                    "proven": len(proven), "wrong": wrong, "runs": len(rs), "proof_times_s": proven,
                    "within_1e-4": close,
                    "median_time_s": med_all, "largest_gap": worst}
                lines.append(f"| {J} | {group} | {label} | {len(proven)} of {len(rs)} | {wrong} | {close} | "
                             f"{med_all:.1f} | {med} | "
                             f"{'-' if worst is None else f'{worst:.2e}'} |")
    return lines


def _write(out: Path, prefix: str, lines: list[str], summary: dict) -> None:
    """``{prefix}.md`` (keeping the notes below NOTES_MARK) and ``{prefix}_summary.json``."""
    md = out / f"{prefix}.md"
    old = md.read_text(encoding="utf-8") if md.exists() else ""
    notes = old[old.index(NOTES_MARK):] if NOTES_MARK in old else ""
    md.write_text("\n".join(lines) + "\n" + ("\n" + notes if notes else ""), encoding="utf-8")
    (out / f"{prefix}_summary.json").write_text(dumps(summary, indent=1) + "\n", encoding="utf-8")


def report_cumulative(args: argparse.Namespace) -> None:
    """``exact_cumulative.md``: the same instances under the cumulative budget."""
    out, prefix = Path(args.out), _prefix(args)
    recs, by_inst, summary = _load(out, prefix)
    lines = ["# `exact` under the cumulative budget (Problem I, L=4, T=60, one sequential link)", "",
             "Instances: the T=60 specs of `exact.md` (`suite_specs(\"l3gs\", sizes=[J], seeds=S)`, layered, L=4, "
             "bundled Lumos5G traces scaled to a mean of 11.8 Mbit/s) with `budget=\"cumulative\"`: the bytes "
             "arriving by slot t are at most the trace's bytes up to t (the experiments' ceiling). `exact` solves "
             "them in the arrived-by form (solvers/exact/cumulative.py): per-slot knapsack Lagrangian at the LP "
             "duals, reduced-cost arrival windows, HiGHS on what is left. Every method got the same time limit "
             f"({recs[0]['time_limit_s']} s); runs were sequential (which run each row is from: the notes "
             "below and each record's `finished_utc`).", "",
             f"{machines_line(recs)} The 1-minute load average before/after each run is recorded.", ""]
    lines += _proof_table(by_inst, summary)
    lines += _size_summary(by_inst, summary)
    lines += ["", "## Bounds", "",
              "Relative excess over the best objective known. `Lagrangian` = one exact 0-1 knapsack per slot "
              "(capacity: bytes up to that slot) with the linking rows (arrived stays arrived, layer order) "
              "dualised, at the LP duals and after subgradient steps from them.", "",
              "| instance | best known | LP | Lagrangian at the LP duals | after subgradient | exact final "
              "| ilp/highs final |", "|---|---|---|---|---|---|---|"]
    for iid, d in by_inst.items():
        bk = summary["instances"][iid]["best_known"]

        def ex(b):
            return "-" if b is None or not math.isfinite(b) else f"{b:.7g} ({(b - bk) / bk:.1e})"
        det = d.get("exact", {}).get("details", {})
        summary["instances"][iid]["bounds"] = {
            "lp": d.get("bound:lp", {}).get("bound"), "lagrangian_at_lp_duals": det.get("lagrangian_at_lp_duals"),
            "subgradient": det.get("lagrangian_subgradient"), "exact_final": d.get("exact", {}).get("bound")}
        lines.append(f"| {iid} | {bk:.7g} | {ex(d.get('bound:lp', {}).get('bound'))} | "
                     f"{ex(det.get('lagrangian_at_lp_duals'))} | {ex(det.get('lagrangian_subgradient'))} | "
                     f"{ex(d.get('exact', {}).get('bound'))} | {ex(d.get('ilp/highs', {}).get('bound'))} |")
    lines += ["", "## Where `exact` spends its time", "",
              "`start`: the start heuristics (best value, and where the incumbent finally came from); `root`: "
              "the LP, its order as a schedule, the order search, the Lagrangian at its duals and the subgradient "
              "steps; then the "
              "(chunk, slot) variables of the arrived-by model before and after reduced-cost fixing, the "
              "columns HiGHS was given (one per event slot in each window: a chunk arrives only where it is "
              "worth something, or where the layer above needs it; each run's model), and the "
              "HiGHS runs on what is left (restart: stopped at a schedule where the fixing, redone, drops a "
              "tenth of the variables).", "",
              "| instance | start done (s) | root done (s) | variables -> after fixing | HiGHS columns | HiGHS runs | "
              "incumbent from | bound kind |", "|---|---|---|---|---|---|---|---|"]
    for iid, d in by_inst.items():
        r = d.get("exact")
        if r is None:
            continue
        det = r.get("details", {})
        tr = det.get("trace", [])
        runs = det.get("mip_runs", [])
        mip = ", ".join(f"{x['outcome']} at {x['seconds']:.1f} s" for x in runs) or "none (closed at the root)"
        # Trace points: start, LP and order search, Lagrangian at the LP duals, subgradient, HiGHS.
        root_t = max((p[0] for p in tr[:4]), default=0.0)
        lines.append(f"| {iid} | {tr[0][0]:.1f} | {root_t:.1f} | "
                     f"{det.get('items', 0) * det.get('slots', 0)} -> {det.get('windows_after_root', '-')} | "
                     f"{', '.join(map(str, det.get('mip_columns', []))) or '-'} | {mip} | "
                     f"{det.get('incumbent_from', '-')} | {det.get('bound_kind', '-')} |")
    lines += _heuristics_table(by_inst, summary)
    lines += _gap_plots(by_inst, out, prefix, ", cumulative budget")
    _write(out, prefix, lines, summary)


def _load_line(recs: list) -> str:
    """What the recorded 1-minute load averages say about the machine during the runs (above 2.5
    on 2 cores: something else ran too)."""
    loads = [r[key][0] for r in recs for key in ("loadavg_before", "loadavg_after") if r.get(key)]
    lo, hi = min(loads, default=0.0), max(loads, default=0.0)
    said = (f"the 1-minute load average before/after each run is recorded ({lo:.1f}-{hi:.1f}; 2 cores: about 2 "
            "is a run on both cores, 4 means each process got roughly half a core).")
    return f"**The machine was shared** with other work: {said}" if hi > 2.5 else said[0].upper() + said[1:]


def report(args: argparse.Namespace) -> None:
    if args.budget == "cumulative":
        report_cumulative(args)
        return
    out = Path(args.out)
    recs, by_inst, summary = _load(out, _prefix(args))
    lines = ["# `exact` at the paper's scale (Problem I, L=4, T=60)", "",
             "Instances: `suite_specs(\"l3gs\", sizes=[J], seeds=S)` T=60 specs (layered, L=4, bundled Lumos5G "
             "traces scaled to a mean of 11.8 Mbit/s, window from 60 s x seed). Every method got the same "
             f"time limit ({recs[0]['time_limit_s']} s); runs were sequential.", "",
             f"{machines_line(recs)} {_load_line(recs)}", ""]
    lines += _proof_table(by_inst, summary)
    lines += _size_summary(by_inst, summary)
    lines += ["", "## Bound quality: LP vs Lagrangian (subgradient) vs column generation", "",
              "Relative excess over the best objective known: (bound - best known) / best known. The "
              "subgradient method (Polyak steps towards the best objective known, step halved after 5 "
              "non-improving iterations, stopped when it falls below 1e-4 of the first or at the clock) starts "
              "from the LP duals; from zero multipliers it was still 90-140% above the optimum after 15 s.", "",
              "| instance | best known | LP | Lagrangian at the LP duals "
              "| Lagrangian, subgradient from the LP duals (s, iterations) | column generation root (s) "
              "| final bound of exact |", "|---|---|---|---|---|---|---|"]
    for iid, d in by_inst.items():
        s = summary["instances"][iid]
        bk = s["best_known"]

        def ex(b):
            return "-" if b is None else f"{b:.7g} ({(b - bk) / bk:.2e})"
        lp = d.get("bound:lp", {}).get("bound")
        sg = d.get("bound:subgradient", {})
        root = d.get("exact", {}).get("details", {}).get("root", {})
        at_lp = d.get("exact", {}).get("details", {}).get("lp", {}).get("lagrangian_at_lp_duals")
        s["bounds"] = {"lp": lp, "lagrangian_at_lp_duals": at_lp, "subgradient": sg.get("bound"),
                       "colgen_root": root.get("bound"), "colgen_root_converged": root.get("converged"),
                       "exact_final": d.get("exact", {}).get("bound")}
        conv = "" if root.get("converged") else ", not converged"
        cg_cell = (f"{ex(root.get('bound'))} ({root.get('seconds', 0):.0f} s{conv})" if not root.get("colgen_skipped")
                   else "skipped (n*T > COLGEN_MAX_PAIRS)")
        if root.get("colgen_skipped"):
            s["bounds"]["colgen_root"] = None
        # No run reached the Lagrangian dual: it ends when the step vanishes or at the clock.
        sg_note = ", stopped: step vanished" if sg.get("converged") else ", stopped: time limit"
        lines.append(f"| {iid} | {bk:.7g} | {ex(lp)} | {ex(at_lp)} | {ex(sg.get('bound'))} "
                     f"({sg.get('runtime_s', 0):.0f} s, {sg.get('iterations', 0)}{sg_note}) | "
                     f"{cg_cell} | "
                     f"{ex(d.get('exact', {}).get('bound'))} |")
    lines += ["", "## Where `exact` spends its time", "",
              "Seconds since the start at the end of each phase: `LP done` after the start heuristics, local "
              "search and the LP relaxation; `root done` after the LP neighbourhood MIP and the root column "
              "generation; `primal done` after the master neighbourhood (large instances: the band "
              "neighbourhood), the level-keeping repairs (small instances) and the window LNS, with the "
              "incumbent branching starts from. Then the (chunk, slot) pairs before and after reduced-cost fixing, and how "
              "the HiGHS branch-and-cut on what is left ended (it runs to its time budget, a little short of the "
              "limit, unless it closes; restarts: stopped at a better schedule and started again on the model "
              "fixed there). `root MIP`: HiGHS beside the root column generation (`ROOT_MIP`; how its runs ended, "
              "and the incumbent when column generation returned, against the one before it).", "",
              "| instance | LP done (s) | root done (s) | CG iterations | root MIP | primal done (s) | incumbent then "
              "| pairs allowed -> after fixing | reduced MIP | bound kind |", "|---|---|---|---|---|---|---|---|---|---|"]
    for iid, d in by_inst.items():
        r = d.get("exact")
        if r is None:
            continue
        det = r.get("details", {})
        root, tr = det.get("root", {}), det.get("trace", [])
        # Trace points: LP, one per root MIP run, root, then one per primal phase run (each repair,
        # the window LNS).
        root_runs = det.get("root_mip", {}).get("runs", [])
        n_primal = len(root.get("repair", [])) + ("after_lns" in root)
        k = 1 + len(root_runs) + n_primal
        primal_t = tr[k][0] if n_primal and len(tr) > k else None
        rm = det.get("root_mip")
        root_mip = "-" if rm is None else (f"{', '.join(x['outcome'] for x in root_runs) or 'none'}: "
                                           f"{rm['incumbent_before']:.7g} -> {rm['incumbent_after']:.7g}")
        cg = "skipped" if root.get("colgen_skipped") else \
            f"{root.get('iterations')}{'' if root.get('converged') else ' (not converged)'}"
        red = det.get("reduced_mip", {})
        n_runs = len(red.get("runs", []))
        restarts = f" ({n_runs - 1} restart{'s' if n_runs != 2 else ''})" if n_runs > 1 else ""
        left = red.get("variables")
        pairs = "-" if left is None else f"{left + root.get('fixed_pairs', 0)} -> {left}"
        lines.append(f"| {iid} | {det.get('lp', {}).get('seconds', 0):.1f} | "
                     f"{root.get('seconds', 0):.1f} | {cg} | {root_mip} | {'-' if primal_t is None else f'{primal_t:.1f}'} | "
                     f"{root.get('incumbent', float('nan')):.7g} | {pairs} | "
                     f"{red.get('outcome', '-')}{restarts} | {det.get('bound_kind', '-')} |")
    lines += _heuristics_table(by_inst, summary)
    lines += _gap_plots(by_inst, out, "exact", "")
    # Notes written by hand below NOTES_MARK survive the regeneration.
    _write(out, "exact", lines, summary)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--seeds-20", type=int, default=5)
    ap.add_argument("--seeds-200", type=int, default=5)
    ap.add_argument("--seeds-50", type=int, default=0, help="J=50 instances (issue 23's next size; none by default)")
    ap.add_argument("--subgradient-s", type=float, default=15.0)
    ap.add_argument("--out", default="benchmarks/results")
    ap.add_argument("--report", action="store_true", help="only write exact.md, the summary and the plots")
    ap.add_argument("--budget", choices=["per_slot", "cumulative"], default="per_slot",
                    help="cumulative: the same instances on one sequential link (exact_cumulative*.{jsonl,md,json,png})")
    args = ap.parse_args()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    if not args.report:
        run(args)
    report(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
