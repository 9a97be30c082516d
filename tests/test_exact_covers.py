"""Cover cuts of the arrived-by knapsacks (``solvers/exact/covers.py``) in ``exact``: the separation
against brute force over subsets, the cuts' validity against every schedule, the Lagrangian bound
with cover multipliers against the optimum, the master's cover rows against the master solution,
and ``exact`` with covers against the ILP."""

from __future__ import annotations

import itertools as it
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core_helpers import PER_SLOT_OPTIONS, random_instance
from solver_helpers import check_answer
from l3gs_opt import Instance, solve
from l3gs_opt.problem.solution import GAP_TOL, Status
from l3gs_opt.solvers.brute_force import solve_brute_force
from l3gs_opt.solvers.exact import search as exact_module
from l3gs_opt.solvers.exact.colgen import ColumnPool, Master, column_generation
from l3gs_opt.solvers.exact.covers import COVER_TOL, _most_violated, separate_covers
from l3gs_opt.solvers.exact.lagrange import Cover, Multipliers, gap_data, lagrangian_value, reduced_profits


def _subsets(n: int):
    for k in range(n + 1):
        yield from it.combinations(range(n), k)


@settings(max_examples=60, deadline=None)
@given(cost=st.lists(st.integers(1, 40), min_size=1, max_size=9), data=st.data())
def test_most_violated_cover_is_a_minimal_cover_of_least_slack(cost: list[int], data) -> None:
    """Brute force over every subset: the separation returns a cover (more bytes than the
    capacity) that is minimal (every item needed) and whose slack is the least of any cover."""
    c = np.asarray(cost, dtype=np.int64)
    gap = np.asarray(data.draw(st.lists(st.sampled_from([0.0, 0.1, 0.25, 0.5, 0.9, 1.0]),
                                        min_size=len(c), max_size=len(c))))
    capacity = data.draw(st.integers(0, int(c.sum()) + 2))
    covers = [s for s in _subsets(len(c)) if int(c[list(s)].sum()) > capacity]
    got = _most_violated(c, gap, capacity)
    if not covers:
        assert got is None
        return
    assert got is not None
    assert int(c[got].sum()) > capacity
    assert all(int(c[got].sum()) - int(c[k]) <= capacity for k in got)       # minimal
    best = min(float(gap[list(s)].sum()) for s in covers)
    assert float(gap[got].sum()) <= best + 1e-12


def _all_schedules(data):
    """Every feasible assignment of a tiny Problem A (slot per item, -1 never), by enumeration."""
    from l3gs_opt.solvers.exact.lagrange import assignment_feasible

    choices = [[-1] + np.nonzero(data.allowed[i])[0].tolist() for i in range(data.n)]
    for assign in it.product(*choices):
        a = np.asarray(assign, dtype=np.int64)
        if assignment_feasible(data, a):
            yield a


def _random_covers(data, rng, count: int) -> list[Cover]:
    """Random valid covers: random sets of chunks, kept when they exceed slots 0..t's bytes."""
    capacity = np.cumsum(data.budget)
    out = []
    for _ in range(20 * count):
        t = int(rng.integers(0, data.T))
        items = np.nonzero(rng.random(data.n) < 0.6)[0]
        if len(items) and int(data.cost[items].sum()) > int(capacity[t]):
            out.append(Cover(items.astype(np.int64), t))
            if len(out) == count:
                break
    return out


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
def test_covers_hold_at_every_schedule_and_their_multipliers_keep_the_bound(seed: int, opt: int) -> None:
    """Every schedule (enumerated) satisfies every cover, separated or random; the Lagrangian
    with cover multipliers >= 0 stays at least the optimum (brute force)."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=3, J=2, L=2, options=PER_SLOT_OPTIONS[opt], tight=0.3)
    data = gap_data(inst)
    ref = solve_brute_force(inst).objective
    covers = _random_covers(data, rng, 4) + separate_covers(data, rng.random((data.n, data.T)) / 2)
    for a in _all_schedules(data):
        for cov in covers:
            arrived = (a[cov.items] >= 0) & (a[cov.items] <= cov.slot)
            assert int(arrived.sum()) <= len(cov.items) - 1
    for scale in (0.0, 0.3, 3.0):
        mult = Multipliers(scale * rng.random(data.n), scale * rng.random((data.n, data.T)),
                           scale * rng.random(len(covers)), tuple(covers))
        assert lagrangian_value(data, mult).bound >= ref * (1 - 1e-12) - 1e-12


def test_cover_charge_lowers_reduced_profits_by_hand() -> None:
    """A cover of items {0, 2} by slot 1 with multiplier 0.5 takes 0.5 from those items' reduced
    profits in slots 0 and 1 and nothing elsewhere; its Lagrangian term is (2 - 1) x 0.5."""
    inst = Instance("layered", bandwidth=np.full(3, 5), cost=np.full((3, 1), 2), utility=np.ones((3, 3, 1)),
                    held=np.zeros((3, 1), dtype=bool))
    data = gap_data(inst)
    assert data.n == 3 and data.allowed.all()
    plain = Multipliers.zeros(data)
    cover = Cover(np.asarray([0, 2]), 1)
    cut = Multipliers(plain.mu, plain.pi, np.asarray([0.5]), (cover,))
    diff = np.where(data.allowed, reduced_profits(data, plain) - reduced_profits(data, cut), 0.0)
    expected = np.zeros((3, 3))
    expected[[0, 2], :2] = 0.5
    assert np.allclose(diff, expected)
    assert cut.cover_constant() == [0.5]


def test_blend_pads_the_shorter_cover_list_with_zeros() -> None:
    rng = np.random.default_rng(0)
    data = gap_data(random_instance(rng, T=3, J=2, L=2))
    c1, c2 = Cover(np.asarray([0]), 0), Cover(np.asarray([1]), 1)
    a = Multipliers(np.ones(data.n), np.zeros((data.n, data.T)), np.asarray([2.0]), (c1,))
    b = Multipliers(np.zeros(data.n), np.zeros((data.n, data.T)), np.asarray([4.0, 6.0]), (c1, c2))
    m = a.blend(b, 0.25)
    assert m.covers == (c1, c2)
    assert np.allclose(m.cover, [0.25 * 2 + 0.75 * 4, 0.75 * 6])
    assert np.allclose(m.mu, 0.25)


#: Instances on which the converged master breaks covers of 5 of 16 seeds: chunks of up to
#: half the bytes of a few slots (with smaller chunks, or one layer, rarely any).
COVER_SEEDS = range(16)


def _tight_instance(seed: int):
    rng = np.random.default_rng(seed)
    return random_instance(rng, T=6, J=6, L=2, options=PER_SLOT_OPTIONS[seed % 4], tight=0.5, cost_range=(1, 20),
                           zero_p=0.0)


@pytest.mark.parametrize("seed", COVER_SEEDS)
def test_master_cover_rows_agree_with_the_master_solution_and_keep_a_valid_bound(seed: int) -> None:
    """After cover rows enter the master: each row's activity (HiGHS) equals ``sum_{i in S}
    y[i,t]`` of the master solution in arrival terms and is at most ``|S| - 1``; the converged
    master value and the Lagrangian bound stay at least the optimum (brute force) and at most
    the bound without covers; a column added later gets its cover coefficients too."""
    inst = _tight_instance(seed)
    data = gap_data(inst)
    ref = solve(inst, "ilp").objective   # (too many chunks for brute force)
    pool, rows = ColumnPool(data), []
    master = Master(data, pool, rows, allowed=data.allowed, forced={})
    plain = column_generation(data, pool, rows, allowed=data.allowed, forced={}, incumbent=-math.inf,
                              master=master, max_iterations=10_000, stall_iterations=10_000)
    assert plain.converged
    covers = separate_covers(data, plain.xbar)
    for cov in covers:
        y = np.cumsum(plain.xbar, axis=1)[cov.items, cov.slot].sum()
        assert y > len(cov.items) - 1 + COVER_TOL
    master.add_covers(covers)
    cut = column_generation(data, pool, rows, allowed=data.allowed, forced={}, incumbent=-math.inf, master=master,
                            max_iterations=10_000, stall_iterations=10_000, start=(plain.mult, plain.value))
    assert cut.converged
    activity = np.asarray(master.h.getSolution().row_value)
    y = np.cumsum(cut.xbar, axis=1)
    for cov, r in zip(master.covers, master.cover_rows):
        assert activity[r] == pytest.approx(y[cov.items, cov.slot].sum(), abs=1e-7)
        assert activity[r] <= len(cov.items) - 1 + 1e-7
    assert cut.bound >= ref * (1 - 1e-12) - 1e-9
    assert cut.master >= ref * (1 - 1e-9) - 1e-9
    assert cut.bound <= plain.bound + 1e-9 * abs(plain.bound)


def test_covers_are_found_on_tight_instances() -> None:
    """The cases above are not vacuous: covers are violated at the converged master of most."""
    found = 0
    for seed in COVER_SEEDS:
        data = gap_data(_tight_instance(seed))
        pool, rows = ColumnPool(data), []
        cg = column_generation(data, pool, rows, allowed=data.allowed, forced={}, incumbent=-math.inf,
                               max_iterations=10_000, stall_iterations=10_000)
        found += bool(separate_covers(data, cg.xbar))
    assert found >= 3


@pytest.mark.parametrize("branching, mode", [("both", "root"), ("price", "root"), ("price", "nodes")])
def test_exact_with_covers_equals_the_ilp(monkeypatch, branching: str, mode: str) -> None:
    """With cover rounds at the root (and at every node), ``exact`` proves the ILP's optimum; the
    rounds added covers on several of these instances (else the check would say nothing)."""
    monkeypatch.setattr(exact_module, "COVER_CUTS", mode)
    added = 0
    for seed in COVER_SEEDS:
        inst = _tight_instance(seed)
        ref = solve(inst, "ilp")
        sol = exact_module.solve_exact(inst, branching=branching, heuristics=())
        check_answer(inst, sol)
        assert sol.status is Status.OPTIMAL
        assert abs(sol.objective - ref.objective) <= 1e-9 * max(1.0, abs(ref.objective))
        assert sol.gap <= GAP_TOL
        added += sol.details.get("covers", {}).get("covers", 0) > 0
        if mode == "nodes":
            added += sol.details["node_covers"]["covers"] > 0
    assert added >= 3


@pytest.mark.parametrize("seed", COVER_SEEDS)
def test_reduced_mip_with_cover_rows_keeps_the_optimum(seed: int) -> None:
    """Cover rows in HiGHS's model of Problem A (separated at the converged master and at random
    points) cut off no schedule: the model still reaches the ILP's optimum."""
    from l3gs_opt.solvers.exact.lns import reduced_mip

    inst = _tight_instance(seed)
    data = gap_data(inst)
    ref = solve(inst, "ilp").objective
    cg = column_generation(data, ColumnPool(data), [], allowed=data.allowed, forced={}, incumbent=-math.inf,
                           max_iterations=10_000, stall_iterations=10_000)
    rng = np.random.default_rng(seed)
    covers = separate_covers(data, cg.xbar) + separate_covers(data, rng.random((data.n, data.T)) / 3)
    outcome, assign, bound = reduced_mip(data, data.allowed, -math.inf, time_limit_s=None, covers=covers)
    assert outcome == "optimal"
    assert abs(bound - ref) <= 1e-9 * max(1.0, abs(ref))


def test_cover_keeps_its_items_sorted_distinct_and_read_only() -> None:
    cov = Cover(np.asarray([2, 1, 2]), np.int64(1))
    assert cov.items.tolist() == [1, 2] and cov.slot == 1 and isinstance(cov.slot, int)
    with pytest.raises(ValueError):
        cov.items[0] = 5
    for items, slot in (([], 0), ([-1, 2], 0), ([1], -1)):
        with pytest.raises(ValueError, match="Cover: items must be"):
            Cover(np.asarray(items, dtype=np.int64), slot)
