"""``benchmarks/bench_exact.py``'s per-size summary: seed groups kept apart, counts from the records."""

from __future__ import annotations

import pytest
from script_helpers import load_script


@pytest.fixture(scope="module")
def bench():
    return load_script("bench_exact")


def _rec(seed: int, label: str, status: str, gap: float, seconds: float, objective: float = 100.0) -> dict:
    return {"J": 20, "params": {"seed": seed}, "label": label, "status": status, "gap": gap, "runtime_s": seconds,
            "objective": objective, "bound": objective, "loadavg_before": [1.0], "loadavg_after": [1.0]}


def test_size_summary_keeps_seed_groups_apart(bench):
    by_inst = {
        "s0": {"exact": _rec(0, "exact", "optimal", 0.0, 10.0)},
        "s1": {"exact": _rec(1, "exact", "time_limit", 5e-5, 60.0)},
        "s5": {"exact": _rec(5, "exact", "time_limit", 2e-3, 60.0)},
        "s6": {"exact": _rec(6, "exact", "optimal", 0.0, 4.0), "ilp/highs": _rec(6, "ilp/highs", "time_limit", 1e-2, 61.0)},
    }
    summary: dict = {}
    lines = bench._size_summary(by_inst, summary)
    groups = summary["sizes"]["20"]
    assert set(groups) == {"0-4", "5-9"}
    assert groups["0-4"]["exact"] == {"proven": 1, "wrong": 0, "runs": 2, "proof_times_s": [10.0],
                                      "within_1e-4": 2, "median_time_s": 35.0, "largest_gap": 5e-5}
    assert groups["5-9"]["exact"]["proven"] == 1 and groups["5-9"]["exact"]["within_1e-4"] == 1
    assert groups["5-9"]["exact"]["median_time_s"] == 32.0
    assert "ilp/highs" not in groups["0-4"] and groups["5-9"]["ilp/highs"]["proven"] == 0
    rows = [line for line in lines if line.startswith("| 20 |")]
    assert len(rows) == 3 and rows[0].startswith("| 20 | 0-4 | exact | 1 of 2 | 0 | 2 | 35.0 | 10.0 |")


def test_claimed_optimum_below_a_known_schedule_is_wrong_not_proven(bench):
    by_inst = {"s6": {"exact": _rec(6, "exact", "optimal", 0.0, 3.0, objective=297194.76),
                      "ilp/cbc": _rec(6, "ilp/cbc", "optimal", 0.0, 3.6, objective=297116.33)}}
    summary: dict = {"instances": {}}
    table = "\n".join(bench._proof_table(by_inst, summary))
    assert "| s6 | ilp/cbc | optimal **(wrong: below best known)** |" in table
    assert summary["instances"]["s6"]["methods"]["exact"]["wrong_optimum"] is False
    bench._size_summary(by_inst, summary)
    cbc = summary["sizes"]["20"]["5-9"]["ilp/cbc"]
    assert (cbc["proven"], cbc["wrong"], cbc["within_1e-4"]) == (0, 1, 0)
    assert summary["sizes"]["20"]["5-9"]["exact"]["proven"] == 1


def test_seed_group(bench):
    assert [bench._seed_group({"params": {"seed": s}}) for s in (0, 4, 5, 9, 10)] == ["0-4", "0-4", "5-9", "5-9",
                                                                                      "10-14"]


def test_trace_gap_waits_for_a_finite_positive_bound(bench):
    """Trace points before the first bound hold null (strict JSON) or, in older files, Infinity: no gap."""
    assert bench.trace_gap([0.1, 90.0, None], 1e-9) is None
    assert bench.trace_gap([0.1, 90.0, float("inf")], 1e-9) is None
    assert bench.trace_gap([0.1, -5.0, 0.0], 1e-9) is None
    assert bench.trace_gap([0.2, 90.0, 100.0], 1e-9) == pytest.approx(0.1)
    assert bench.trace_gap([0.3, 100.0, 100.0], 1e-9) == 1e-9
