"""Reports from benchmark records: ``report.md`` plus PNG plots (matplotlib).

* **error against run time** per suite: each method's records as points, relative error to the best
  known optimum (log; exact answers drawn at the floor ``ERROR_FLOOR``) against run time (log); knob
  families (``fptas:EPS``, ``mpc:H``) joined by a line through their medians; the Pareto front of
  the method medians marked;
* **run time against size** (J for single-slot suites, J*T for multi-slot) per method, log-log, with
  the fitted slope;
* **stability table** for the stiff suite: status, error, feasibility and bound validity;
* a recommendation per suite: the fastest method within 1% of optimal, the fastest exact one;
* every flagged record (mismatch, infeasible, objective mismatch, invalid bound, killed, crashed).

The best known optimum of an instance is recomputed here from all its records (the best proven
optimum, else the best feasible objective, marked unproven).
"""

from __future__ import annotations

import math
import os
import re
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from l3gs_opt.bench.run import AGREE_TOL, BenchError, check_records, is_declined, read_records, recheck

__all__ = ["ERROR_FLOOR", "annotate", "write_report", "summarise", "known_optima_summary", "known_optima_lines"]

#: Relative errors below this are drawn at it on log axes (exact answers have error 0).
ERROR_FLOOR = 1e-12


def annotate(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Recompute the cross-record flags, best known optimum, relative error and bound validity per
    instance from all records; suites mixing single-slot and multi-slot instances are split into
    ``SUITE-single-slot`` and ``SUITE-multi-slot``."""
    by_instance: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in recheck(records):
        by_instance[(r["suite"], r["instance_id"])].append(r)
    out = []
    for group in by_instance.values():
        good = [r for r in group if r.get("objective") is not None and r.get("feasible") and r.get("objective_ok")]
        proven = [r["objective"] for r in good if r["status"] == "optimal"]
        best = max(proven) if proven else (max(r["objective"] for r in good) if good else None)
        for r in group:
            r = dict(r)
            r["best_known"] = best
            r["best_known_proven"] = bool(proven)
            obj = r.get("objective")
            if obj is not None and r.get("feasible") and r.get("objective_ok"):
                r["rel_error"] = 0.0 if best in (None, obj) else max(0.0, (best - obj) / abs(best)) if best else math.inf
            else:
                r["rel_error"] = None
            bound = r.get("bound")
            r["bound_valid"] = None if bound is None or best is None else \
                bool(bound >= best - AGREE_TOL * max(abs(best), 1e-12))
            out.append(r)
    # A suite with single-slot and multi-slot instances is reported as two groups, so that a
    # method run on one kind only is never ranked against one run on both.
    kinds: dict[str, set[bool]] = defaultdict(set)
    for r in out:
        kinds[r["suite"]].add(r.get("problem") == "MCKP")
    for r in out:
        if len(kinds[r["suite"]]) > 1:
            r["suite"] = f"{r['suite']}-{'single-slot' if r.get('problem') == 'MCKP' else 'multi-slot'}"
    return out


def _family(method: str) -> tuple[str, float | None]:
    """``fptas:0.01`` -> (``fptas``, 0.01); methods without a numeric knob -> (method, None)."""
    m = re.fullmatch(r"([a-z-]+):([0-9.eE+-]+)", method)
    if m:
        try:
            return m.group(1), float(m.group(2))
        except ValueError:
            pass
    return method, None


def summarise(records: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per suite, per method: count, median run time, median and max error, proven-optimal share, flags."""
    table: dict[str, dict[str, dict[str, Any]]] = defaultdict(dict)
    groups: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for r in records:
        groups[(r["suite"], r["method"])].append(r)
    for (suite, method), rs in sorted(groups.items()):
        errors = [r["rel_error"] for r in rs if r.get("rel_error") is not None and not r.get("bound_only")]
        bound_gaps = [(r["bound"] - r["best_known"]) / abs(r["best_known"]) for r in rs
                      if r.get("bound") is not None and r.get("best_known_proven") and r["best_known"]]
        times = [r["runtime_s"] for r in rs if r.get("runtime_s") is not None]
        loads = [r["loadavg_1m"] for r in rs if r.get("loadavg_1m") is not None]
        table[suite][method] = {
            "records": len(rs),
            "median_time_s": float(np.median(times)) if times else None,
            "median_load": float(np.median(loads)) if loads else None,
            "median_error": float(np.median(errors)) if errors else None,
            "max_error": float(max(errors)) if errors else None,
            "answered": len(errors),
            "bound_only": all(r.get("bound_only") for r in rs),
            "median_bound_gap": float(np.median(bound_gaps)) if bound_gaps else None,
            "optimal": sum(r["status"] == "optimal" for r in rs),
            "declined": sum(is_declined(r) for r in rs),
            "all_feasible": all(r.get("feasible") is not False for r in rs),
            "flags": sorted({f for r in rs for f in r.get("flags", []) if f != "declined"}),
        }
    return table


def _known_optimum(record: dict[str, Any]) -> int | None:
    """The published optimum a record's spec carries (``knapsack-sets``), or None."""
    params = (record.get("spec") or {}).get("params") or {}
    opt = params.get("optimum")
    return opt if isinstance(opt, int) and not isinstance(opt, bool) else None


def _equals_int(value: float | None, target: int) -> bool:
    # Objectives are float sums of integer profits below 2**53: exact, so compare exactly.
    return value is not None and math.isfinite(value) and value == int(value) and int(value) == target


def known_optima_summary(records: list[dict[str, Any]], *, slow_s: float = 20.0) -> dict[tuple[str, str, str], dict]:
    """Per (suite, set, method), over records whose spec carries a published optimum: how many
    reach it (feasible, objective re-evaluated equal, value equal in exact integers), how many are
    proven optimal, how many are labelled optimal with another value (must be 0), how many report a
    bound below the optimum (must be 0), median and max run time (s), and how many are not proven
    within ``slow_s`` seconds (not optimal, or slower)."""
    groups: dict[tuple[str, str, str], list[dict]] = defaultdict(list)
    for r in records:
        opt = _known_optimum(r)
        if opt is None:
            continue
        params = r["spec"]["params"]
        groups[(r["suite"], str(params.get("set", "-")), r["method"])].append(r)
    out: dict[tuple[str, str, str], dict] = {}
    for key, rs in sorted(groups.items()):
        reached = proven = wrong = low_bound = slow = 0
        for r in rs:
            opt = _known_optimum(r)
            ok = bool(r.get("feasible")) and bool(r.get("objective_ok"))
            hit = ok and _equals_int(r.get("objective"), opt)
            reached += hit
            is_opt = r.get("status") == "optimal"
            proven += is_opt and hit
            wrong += is_opt and not hit
            b = r.get("bound")
            low_bound += b is not None and b < opt
            slow += not (is_opt and hit and (r.get("runtime_s") or 0.0) <= slow_s)
        times = [r["runtime_s"] for r in rs if r.get("runtime_s") is not None]
        out[key] = {"records": len(rs), "reached": reached, "proven": proven, "wrong_optimal": wrong,
                    "bound_below_optimum": low_bound,
                    "median_time_s": float(np.median(times)) if times else None,
                    "max_time_s": float(max(times)) if times else None, "not_proven_within": slow,
                    "slow_s": slow_s}
    return out


def known_optima_lines(summary: dict[tuple[str, str, str], dict]) -> list[str]:
    """Markdown table of :func:`known_optima_summary` (empty when no record has a known optimum)."""
    if not summary:
        return []
    slow = next(iter(summary.values()))["slow_s"]
    lines = ["| suite | set | method | records | reach optimum | proven optimal | optimal but wrong | bound below "
             f"optimum | median time (s) | max time (s) | not proven in {slow:g} s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for (suite, set_, method), s in summary.items():
        lines.append(f"| {suite} | {set_} | {method} | {s['records']} | {s['reached']} | {s['proven']} | "
                     f"{s['wrong_optimal']} | {s['bound_below_optimum']} | {_fmt(s['median_time_s'])} | "
                     f"{_fmt(s['max_time_s'])} | {s['not_proven_within']} |")
    return lines


def _pareto(points: list[tuple[float, float, str]]) -> list[tuple[float, float, str]]:
    front, best_err = [], math.inf
    for t, e, m in sorted(points):
        if e < best_err:
            front.append((t, e, m))
            best_err = e
    return front


def _plot_error_vs_time(suite: str, records: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5))
    methods = sorted({r["method"] for r in records})
    cmap = plt.get_cmap("tab20")
    medians: list[tuple[float, float, str]] = []
    families: dict[str, list[tuple[float, float, float]]] = defaultdict(list)
    for i, m in enumerate(methods):
        rs = [r for r in records if r["method"] == m and r.get("rel_error") is not None and r.get("runtime_s")
              and not r.get("bound_only")]
        if not rs:
            continue
        t = np.array([r["runtime_s"] for r in rs])
        e = np.maximum(np.array([r["rel_error"] for r in rs]), ERROR_FLOOR)
        ax.scatter(t, e, s=18, alpha=0.6, color=cmap(i % 20), label=m)
        medians.append((float(np.median(t)), float(np.median(e)), m))
        fam, knob = _family(m)
        if knob is not None:
            families[fam].append((knob, float(np.median(t)), float(np.median(e))))
    for fam, pts in families.items():
        if len(pts) > 1:
            pts.sort()
            ax.plot([p[1] for p in pts], [p[2] for p in pts], "--", color="grey", linewidth=1)
            ax.annotate(fam, (pts[-1][1], pts[-1][2]), fontsize=8, color="grey")
    front = _pareto(medians)
    if front:
        ax.step([p[0] for p in front], [p[1] for p in front], where="post", color="black", linewidth=1.5,
                label="Pareto front (medians)")
        ax.scatter([p[0] for p in front], [p[1] for p in front], marker="*", s=120, color="black", zorder=5)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("run time (s)")
    ax.set_ylabel(f"relative error to best known optimum (exact drawn at {ERROR_FLOOR:g})")
    ax.set_title(f"suite '{suite}': error against run time")
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:   # no answered record: no legend (and no warning)
        ax.legend(fontsize=7, ncol=2, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _size(r: dict) -> float:
    return float(r["J"] * (r["T"] if r.get("problem") != "MCKP" else 1) * max(r.get("L", 1), 1))


def _plot_time_vs_size(suite: str, records: list[dict], path: Path) -> dict[str, float]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 5.5))
    cmap = plt.get_cmap("tab20")
    slopes: dict[str, float] = {}
    for i, m in enumerate(sorted({r["method"] for r in records})):
        rs = [r for r in records if r["method"] == m and r.get("runtime_s") and r["J"] > 0]
        if not rs:
            continue
        x = np.array([_size(r) for r in rs])
        y = np.array([r["runtime_s"] for r in rs])
        label = m
        if len(set(x)) > 1:
            slope, icpt = np.polyfit(np.log(x), np.log(y), 1)
            slopes[m] = float(slope)
            xs = np.geomspace(x.min(), x.max(), 20)
            ax.plot(xs, np.exp(icpt) * xs**slope, color=cmap(i % 20), linewidth=1)
            label = f"{m} (slope {slope:.2f})"
        ax.scatter(x, y, s=16, color=cmap(i % 20), label=label, alpha=0.7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("size: chunks J*L (single slot) or chunk-slots J*L*T")
    ax.set_ylabel("run time (s)")
    ax.set_title(f"suite '{suite}': run time against size (log-log, fitted slope)")
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:   # no answered record: no legend (and no warning)
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return slopes


def _fmt(v: Any, spec: str = ".3g") -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return format(v, spec)
    return str(v)


def _recommend(stats: dict[str, dict[str, Any]]) -> list[str]:
    lines = []
    stats = {m: s for m, s in stats.items() if not s["bound_only"]}
    near = [(s["median_time_s"], m) for m, s in stats.items()
            if s["max_error"] is not None and s["max_error"] <= 0.01 and s["answered"] == s["records"]
            and s["all_feasible"] and s["median_time_s"] is not None]
    exact = [(s["median_time_s"], m) for m, s in stats.items()
             if s["optimal"] == s["records"] and s["records"] > 0 and s["median_time_s"] is not None]
    if near:
        t, m = min(near)
        lines.append(f"fastest method within 1% of optimal on every instance: **{m}** (median {t:.3g} s)")
    else:
        lines.append("no method stayed within 1% of optimal on every instance")
    if exact:
        t, m = min(exact)
        lines.append(f"fastest method proven optimal on every instance: **{m}** (median {t:.3g} s)")
    else:
        lines.append("no method proved optimality on every instance of this suite")
    return lines


def write_report(records_path: str | os.PathLike[str] | Iterable[dict], out_dir: str | os.PathLike[str],
                 *, title: str = "l3gs-opt benchmark report") -> Path:
    """Write ``report.md`` and PNG plots for the records; returns the report's path.

    Raises
    ------
    BenchError
        A record is not a bench record (``records[i]``), or ``out_dir`` is a file.
    RecordFileError
        A line of the records file (other than a torn last one) is not a JSON record.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise BenchError("--out", f"{out} is a file: expected a folder (for report.md and the plots)")
    if isinstance(records_path, (str, os.PathLike)):
        raw = check_records(read_records(records_path), field=str(records_path))
    else:
        raw = check_records(list(records_path))
    out.mkdir(parents=True, exist_ok=True)
    records = annotate(raw)
    summary = summarise(records)
    lines = [f"# {title}", "", f"{len(records)} records, {len({r['instance_id'] for r in records})} instances.", ""]
    for suite in sorted(summary):
        rs = [r for r in records if r["suite"] == suite]
        err_png, size_png = f"{suite}-error-vs-time.png", f"{suite}-time-vs-size.png"
        _plot_error_vs_time(suite, rs, out / err_png)
        slopes = _plot_time_vs_size(suite, rs, out / size_png)
        lines += [f"## Suite `{suite}`", ""]
        lines += [f"- {line}" for line in _recommend(summary[suite])]
        lines += ["", "Error: (best known optimum - objective) / best known optimum. Bound gap: (bound - best "
                      "known optimum) / best known optimum, over instances with a proven optimum; `lp` rows answer "
                      "with a bound only. Load: median 1-minute load average when the records started "
                      "(2 cores; '-' where records predate it).", "",
                  "| method | records | proven optimal | declined | median time (s) | median error | max error | "
                  "median bound gap | time-size slope | load | flags |", "|---|---|---|---|---|---|---|---|---|---|---|"]
        for m, s in summary[suite].items():
            med = "bound only" if s["bound_only"] else _fmt(s["median_error"], ".2e")
            mx = "bound only" if s["bound_only"] else _fmt(s["max_error"], ".2e")
            lines.append(f"| {m} | {s['records']} | {s['optimal']} | {s['declined']} | {_fmt(s['median_time_s'])} | "
                         f"{med} | {mx} | "
                         f"{_fmt(s['median_bound_gap'], '.2e')} | {_fmt(slopes.get(m), '.2f')} | "
                         f"{_fmt(s['median_load'], '.1f')} | {', '.join(s['flags']) or '-'} |")
        lines += ["", f"![error against run time]({err_png})", "", f"![run time against size]({size_png})", ""]
        if suite.startswith("stiff"):
            lines += ["### Stability (stiff cases)", "", "| case | method | status | error | feasible | bound valid |",
                      "|---|---|---|---|---|---|"]
            for r in sorted(rs, key=lambda r: (r["instance_id"], r["method"])):
                err = "bound only" if r.get("bound_only") else _fmt(r.get("rel_error"), ".2e")
                lines.append(f"| {r['instance_id']} | {r['method']} | {r['status']} | {err} "
                             f"| {_fmt(r.get('feasible'))} | {_fmt(r.get('bound_valid'))} |")
            lines.append("")
    known = known_optima_lines(known_optima_summary(records))
    if known:
        lines += ["## Published optima", "", "Records whose instance has a published optimum (e.g. `knapsack-sets`): "
                  "reach = feasible with exactly that value; proven = also labelled optimal; optimal but wrong and "
                  "bound below optimum must be 0.", "", *known, ""]
    flagged = [r for r in records if [f for f in r.get("flags", []) if f != "declined"] or r.get("bound_valid") is False]
    lines += ["## Flagged records", ""]
    if flagged:
        lines += ["| record | status | flags | bound valid | message |", "|---|---|---|---|---|"]
        for r in flagged:
            msg = (r.get("message") or "").splitlines()[0][:100] if r.get("message") else ""
            lines.append(f"| {r['record_id']} | {r['status']} | {', '.join(r.get('flags', [])) or '-'} | "
                         f"{_fmt(r.get('bound_valid'))} | {msg} |")
    else:
        lines.append("None: every answer was feasible in exact bytes, every objective re-evaluated equal, exact "
                     "methods agreed and no bound cut off the best known optimum.")
    versions = next((r.get("versions") for r in records if r.get("versions")), {})
    lines += ["", f"Versions: {versions}.", ""]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
