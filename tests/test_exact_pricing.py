"""The compiled pricing knapsack of ``exact`` against brute force and against ``bb``."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from l3gs_opt.solvers.exact import pricing
from l3gs_opt.solvers.exact.lagrange import knapsack
from l3gs_opt.solvers import _mckp

pytestmark = pytest.mark.skipif(not pricing.available(), reason="numba is not installed")


def _brute(cost, value, cap):
    best, arg = 0.0, ()
    n = len(cost)
    for r in range(n + 1):
        for sub in itertools.combinations(range(n), r):
            if sum(int(cost[i]) for i in sub) <= cap:
                v = math.fsum(float(value[i]) for i in sub)
                if v > best:
                    best, arg = v, sub
    return best, arg


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 60), st.floats(-5, 50, allow_nan=False)), min_size=0, max_size=11),
       st.integers(0, 200))
def test_equals_brute_force(items, cap):
    cost = np.array([c for c, _ in items], np.int64)
    value = np.array([v for _, v in items], np.float64)
    chosen, best, done = pricing.solve_kp01_float(cost, value, cap)
    ref, _ = _brute(cost, value, cap)
    assert done
    assert int(cost[chosen].sum()) <= cap and (value[chosen] > 0).all()
    assert best == pytest.approx(ref, rel=1e-12, abs=1e-12)
    assert math.fsum(value[chosen].tolist()) == pytest.approx(best, rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_equals_bb_on_pricing_sized_knapsacks(seed):
    """80 items of L3GS-like bytes (1e3..1e6) and float profits: the optimum bb proves."""
    rng = np.random.default_rng(seed)
    n = 80
    cost = rng.integers(1_000, 1_000_000, size=n)
    value = cost * rng.uniform(0.5, 1.5, size=n) * 1e-3 - rng.uniform(0, 200, size=n)
    cap = int(cost.sum() * rng.uniform(0.1, 0.4))
    chosen, best, done = pricing.solve_kp01_float(cost, value, cap)
    take = np.flatnonzero((value > 0) & (cost <= cap))
    table = _mckp.build_table(layered=False, cost=cost[take, None], gain=value[take, None],
                              held=np.zeros((len(take), 1), bool), budget=cap)
    res = _mckp.branch_and_bound(table)
    assert done and res.optimal
    ref = math.fsum(value[take[table.rows[res.choice >= 0]]].tolist())
    assert best == pytest.approx(ref, rel=1e-12) and best <= res.bound * (1 + 1e-12)
    assert int(cost[chosen].sum()) <= cap


def test_node_limit_says_unfinished_and_the_caller_falls_back():
    """With a 1-node limit the search gives up; lagrange.knapsack then asks bb (same answer)."""
    rng = np.random.default_rng(7)
    cost = rng.integers(100, 1_000, size=40)
    value = cost * rng.uniform(0.9, 1.1, size=40)
    cap = int(cost.sum() // 3)
    chosen, best, done = pricing.solve_kp01_float(cost, value, cap, max_nodes=1)
    assert not done and int(cost[chosen].sum()) <= cap
    full, fbest, fdone = pricing.solve_kp01_float(cost, value, cap)
    picked, bound, optimal = knapsack(cost, value, cap)
    assert fdone and optimal and fbest <= bound * (1 + 1e-9) and fbest == pytest.approx(bound, rel=1e-6)
