"""Short time limits cover the whole call: the heuristics' LP bound, the ILP's model building, and
``exact``'s repair at the paper's largest scale (``benchmarks/results/time_limits_probe.md``).

Before, at J=200, T=60 under a 0.5 s limit, ``static`` took 2.4 s (its LP bound ran unlimited),
``exact`` 3.1 s (CP-SAT's repair model was built twice) and ``ilp`` on HiGHS 2.1 s (the naive
model was built before the solve, for its size).
"""

from __future__ import annotations

import time

import pytest

from l3gs_opt import solve
from l3gs_opt.bench.suites import paper_spec
from l3gs_opt.models.backends import MIN_SOLVE_S, time_left
from l3gs_opt.problem.evaluate import is_feasible
from l3gs_opt.solvers.bounds import lp_bound

#: Seconds past its limit a call may run here: room for a machine twice as slow as our 2-core box,
#: where the slowest case below took 1.05 s under a 0.5 s limit (before: exact 3.07 s, static 2.72 s;
#: the ilp case is held to its limit by the naive-size test above, not by this one).
SLACK_S = 2.0


@pytest.fixture(scope="module")
def j20():
    return paper_spec(20, 1).build()


@pytest.fixture(scope="module")
def j200():
    return paper_spec(200, 1).build()


@pytest.mark.parametrize("method", ["static", "slope", "progressive", "rolling:bb", "mpc:3", "anneal"])
def test_a_limit_spent_on_the_schedule_leaves_no_bound_rather_than_overrunning(j20, method):
    sol = solve(j20, method, time_limit_s=1e-6)
    assert sol.bound is None and sol.gap is None
    assert "no bound" in sol.message and "bound is the LP" not in sol.message
    assert is_feasible(j20, sol.arrivals)
    full = solve(j20, method)
    assert full.bound is not None and full.bound >= full.objective and "bound is the LP relaxation" in full.message


def test_lp_bound_within_a_limit(j20):
    assert lp_bound(j20, time_limit_s=1e-9)[0] is None
    bound, _ = lp_bound(j20, time_limit_s=30.0)
    assert bound is not None and bound == pytest.approx(lp_bound(j20)[0], rel=1e-12)


def test_a_model_built_past_the_limit_is_a_time_limit_without_its_naive_size(j20):
    sol = solve(j20, "ilp", backend="highs", time_limit_s=1e-6)
    assert sol.status.value == "time_limit" and sol.size_before is None and sol.size_after is not None
    full = solve(j20, "lp", backend="highs")
    assert full.size_before is not None


@pytest.mark.parametrize("method, kw", [("exact", {}), ("static", {}), ("ilp", {"backend": "highs"})])
def test_the_largest_paper_scale_keeps_a_short_limit(j200, method, kw):
    began = time.perf_counter()
    sol = solve(j200, method, time_limit_s=0.5, **kw)
    assert time.perf_counter() - began <= 0.5 + SLACK_S
    assert is_feasible(j200, sol.arrivals)


def test_time_left_counts_from_the_start_and_keeps_a_floor():
    now = time.perf_counter()
    assert time_left(None, now) is None
    assert time_left(5.0, now - 10.0) == MIN_SOLVE_S
    assert 3.9 <= time_left(5.0, now - 1.0) <= 4.0


def test_cp_sat_counts_its_own_model_building(j200):
    """CP-SAT's model is built in Python (~2 s at J=200): before, its solver got the whole limit on
    top of that (4.1 s under 2 s); now what is left of it."""
    began = time.perf_counter()
    sol = solve(j200, "ilp", backend="cpsat", time_limit_s=2.0)
    assert time.perf_counter() - began <= 2.0 + SLACK_S
    assert sol.status.value == "time_limit" and is_feasible(j200, sol.arrivals)
