"""``exact`` on Problems II/IV (separate versions): against brute force, the HiGHS ILP, and path
enumeration; time limits, stiff inputs and refusals."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3gs_opt import Instance, Options, Status, is_feasible, solve
from l3gs_opt.errors import SolveError
from l3gs_opt.solvers.exact.separate import solve_separate
from l3gs_opt.solvers.exact.separate_data import (MAX_VERSIONS, lagrangian_bound, path_value, price_paths,
                                                  separate_data)
from l3gs_opt.solvers.exact.separate_mip import forced_values

ALL_OPTIONS = [Options(availability=a, budget=b) for a in ("same_slot", "next_slot")
               for b in ("per_slot", "cumulative")]


def _close(a: float, b: float, rtol: float = 1e-9) -> bool:
    """Objectives agree to ``rtol`` (GAP_TOL: the same terms summed in other orders)."""
    return abs(a - b) <= rtol * max(abs(a), abs(b), 1e-300)


def _instance(rng: np.random.Generator, *, T: int, J: int, L: int, options: Options, tight: float = 0.4,
              held: float = 0.2) -> Instance:
    cost = rng.integers(1, 20, size=(J, L))
    utility = rng.random((T, J, L)) * rng.integers(1, 10, size=(1, J, L))
    utility[rng.random((T, J, L)) < 0.2] = 0.0     # out of view for a slot
    bandwidth = rng.integers(0, max(2, int(tight * cost.sum())), size=T)
    return Instance("separate", bandwidth=bandwidth, cost=cost, utility=utility, held=rng.random((J, L)) < held,
                    options=options)


def _check(inst: Instance, sol, reference: float) -> None:
    assert is_feasible(inst, sol.arrivals)
    assert sol.status is Status.OPTIMAL, sol.message
    assert _close(sol.objective, reference), (sol.objective, reference)
    assert sol.bound >= sol.objective


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), T=st.integers(1, 3), J=st.integers(1, 2), L=st.integers(1, 3),
       option=st.integers(0, 3), held=st.sampled_from([0.0, 0.3]))
def test_equals_brute_force_on_small_instances(seed, T, J, L, option, held) -> None:
    """Every option pair, held versions or not: the proven optimum is brute force's."""
    inst = _instance(np.random.default_rng(seed), T=T, J=J, L=L, options=ALL_OPTIONS[option], held=held)
    _check(inst, solve(inst, "exact"), solve(inst, "brute").objective)


@pytest.mark.parametrize("option", range(4))
@pytest.mark.parametrize("branching", ["both", "price", "mip"])
def test_equals_highs_ilp_on_medium_instances(option: int, branching: str) -> None:
    """Every way of closing the gap reaches the HiGHS ILP's optimum (a second implementation)."""
    for seed in range(2):
        inst = _instance(np.random.default_rng(100 * option + seed), T=8, J=5, L=3, options=ALL_OPTIONS[option],
                         tight=0.3)
        ref = solve(inst, "ilp", backend="highs")
        assert ref.status is Status.OPTIMAL
        _check(inst, solve_separate(inst, branching=branching), ref.objective)


def test_problem_iv_one_object() -> None:
    inst = _instance(np.random.default_rng(5), T=10, J=1, L=4, options=Options(), tight=0.5)
    assert inst.problem == "IV"
    sol = solve(inst, "exact")
    _check(inst, sol, solve(inst, "ilp", backend="highs").objective)
    assert sol.problem == "IV"


def test_stopped_run_returns_a_valid_bound_and_time_limit() -> None:
    """A node limit (as a time limit) ends with status time_limit and a bound >= the ILP optimum."""
    for seed in range(40):
        inst = _instance(np.random.default_rng(seed), T=8, J=5, L=3, options=Options(), tight=0.25)
        sol = solve_separate(inst, branching="price", heuristics=(), max_nodes=1)
        assert is_feasible(inst, sol.arrivals)
        opt = solve(inst, "ilp", backend="highs").objective
        assert sol.bound >= opt * (1 - 1e-9)
        if sol.status is not Status.OPTIMAL:
            assert sol.status is Status.TIME_LIMIT and sol.gap > 0
            return
    pytest.fail("every instance closed within one node: the limit was never tested")


def test_time_limit_at_paper_scale_is_labelled_and_bounded() -> None:
    from l3gs_opt.pipeline.synth import synth_instance

    inst = synth_instance(objects=20, layers=4, slots=60, seed=0, representation="separate",
                          trace="lumos-throughput-mid-11")
    sol = solve(inst, "exact", time_limit_s=0.5)
    assert is_feasible(inst, sol.arrivals)
    assert sol.status in (Status.TIME_LIMIT, Status.OPTIMAL)
    # The optimum of this instance: HiGHS's ILP proves it in ~3 s (measured when this test was written).
    assert sol.bound >= 116099.15617528863 * (1 - 1e-9)


# -- the path DP against enumeration ----------------------------------------------------------------

def _all_paths(T: int, V: int):
    return itertools.product(range(-1, T), repeat=V)


@pytest.mark.parametrize("option", range(4))
def test_pricing_equals_path_enumeration(option: int) -> None:
    """The DP's best reduced path, and the best path through each (version, slot) arrival
    (``forced_values``), equal the maximum over every path, enumerated."""
    rng = np.random.default_rng(7 + option)
    inst = _instance(rng, T=4, J=2, L=3, options=ALL_OPTIONS[option], tight=0.8, held=0.0)
    data = separate_data(inst)
    rho = rng.random(data.T) * 0.3
    res = price_paths(data, rho)
    forced = forced_values(data, rho, data.allowed)
    for k in range(data.K):
        best = -math.inf
        through = np.full((data.V, data.T), -np.inf)
        for path in _all_paths(data.T, data.V):
            spent = [0] * data.T
            if any(t >= 0 and not (int(data.allowed[k, t]) >> b) & 1 for b, t in enumerate(path)):
                continue
            for b, t in enumerate(path):
                if t >= 0:
                    spent[t] += int(data.cost[k, b])
            if any(s > int(data.rhs[t]) for t, s in enumerate(spent)):
                continue
            value = path_value(data, k, path) - sum(rho[t] * s for t, s in enumerate(spent))
            best = max(best, value)
            for b, t in enumerate(path):
                if t >= 0:
                    through[b, t] = max(through[b, t], value)
        assert res.value[k] == pytest.approx(best, rel=1e-12, abs=1e-12)
        assert path_value(data, k, res.paths[k]) - sum(
            rho[t] * data.cost[k, b] for b, t in enumerate(res.paths[k]) if t >= 0) == pytest.approx(best, abs=1e-12)
        finite = np.isfinite(through)
        assert (np.isfinite(forced[k]) == finite).all()
        assert np.allclose(forced[k][finite], through[finite], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("option", range(4))
def test_lagrangian_bound_holds_at_any_multipliers(option: int) -> None:
    rng = np.random.default_rng(30 + option)
    inst = _instance(rng, T=3, J=2, L=2, options=ALL_OPTIONS[option], tight=0.4)
    opt = solve(inst, "brute").objective
    data = separate_data(inst)
    for scale in (0.0, 0.01, 0.1, 1.0, 10.0):
        bound, _ = lagrangian_bound(data, rng.random(data.T) * scale)
        assert bound >= opt * (1 - 1e-12)


def test_path_master_gets_the_node_time_limit() -> None:
    """The path master's HiGHS carries the node's deadline (as Problem I's master); none without."""
    from l3gs_opt.solvers.exact.separate_master import PathMaster, PathPool

    rng = np.random.default_rng(5)
    data = separate_data(_instance(rng, T=3, J=2, L=2, options=ALL_OPTIONS[0]))
    must = np.zeros(data.K, dtype=np.int8)
    timed = PathMaster(data, PathPool(data), allowed=data.allowed, must=must, time_limit_s=2.5)
    free = PathMaster(data, PathPool(data), allowed=data.allowed, must=must)
    assert timed.h.getOptionValue("time_limit")[1] == 2.5      # (status, value)
    assert free.h.getOptionValue("time_limit")[1] > 1e9


# -- stiff inputs -----------------------------------------------------------------------------------

def test_zero_bandwidth_slot_and_a_version_that_never_fits() -> None:
    rng = np.random.default_rng(3)
    T, J, L = 3, 2, 3
    cost = np.array([[3, 5, 1000], [4, 6, 9]])         # version 2 of object 0 never fits
    utility = rng.random((T, J, L)) + 0.1
    utility[:, 0, 2] = 100.0
    inst = Instance("separate", bandwidth=[10, 0, 9], cost=cost, utility=utility)
    sol = solve(inst, "exact")
    _check(inst, sol, solve(inst, "brute").objective)
    assert all(t != 1 for _, _, t in sol.arrivals)
    assert (0, 2) not in {(j, l) for j, l, _ in sol.arrivals}


def test_everything_held_or_nothing_fits() -> None:
    rng = np.random.default_rng(4)
    inst = Instance("separate", bandwidth=[0, 0], cost=[[2, 3]], utility=rng.random((2, 1, 2)),
                    held=[[True, False]])
    sol = solve(inst, "exact")
    assert sol.status is Status.OPTIMAL and sol.arrivals == ()
    assert _close(sol.objective, float(inst.utility[:, 0, 0].sum()))


@pytest.mark.parametrize("option", [0, 3])
def test_utilities_over_twelve_orders_of_magnitude(option: int) -> None:
    rng = np.random.default_rng(11)
    for _ in range(3):
        T, J, L = 3, 2, 2
        cost = rng.integers(1, 50, size=(J, L))
        utility = np.exp(rng.uniform(math.log(1e-6), math.log(1e6), size=(T, J, L)))
        bandwidth = rng.integers(0, 60, size=T)
        inst = Instance("separate", bandwidth=bandwidth, cost=cost, utility=utility, options=ALL_OPTIONS[option])
        _check(inst, solve(inst, "exact"), solve(inst, "brute").objective)


@pytest.mark.parametrize("option", [0, 2])
def test_huge_bytes_are_feasible_in_exact_integers(option: int) -> None:
    """Costs and budgets up to 1e12 bytes, a budget that one byte less would break: the schedule
    is feasible in exact integers and brute force's optimum."""
    rng = np.random.default_rng(12)
    for _ in range(3):
        T, J, L = 3, 2, 2
        cost = rng.integers(10**11, 10**12, size=(J, L))
        bandwidth = np.array([cost[0, 0] + cost[1, 0], cost[0, 1], cost[1, 1] - 1])
        utility = rng.random((T, J, L)) + 0.5
        inst = Instance("separate", bandwidth=bandwidth, cost=cost, utility=utility, options=ALL_OPTIONS[option])
        sol = solve(inst, "exact")
        _check(inst, sol, solve(inst, "brute").objective)


# -- refusals ---------------------------------------------------------------------------------------

def test_refuses_slot_unknown_heuristic_and_branching() -> None:
    inst = _instance(np.random.default_rng(0), T=3, J=2, L=2, options=Options())
    with pytest.raises(SolveError, match="slot does not apply"):
        solve(inst, "exact", slot=0)
    with pytest.raises(SolveError, match="start heuristic"):
        solve_separate(inst, heuristics=("greedy",))
    with pytest.raises(SolveError, match="branching"):
        solve_separate(inst, branching="dfs")


def test_refuses_more_versions_than_the_path_dp_takes() -> None:
    L = MAX_VERSIONS + 1
    inst = Instance("separate", bandwidth=[100, 100], cost=np.ones((1, L), int),
                    utility=np.tile(np.arange(1, L + 1, dtype=float), (2, 1, 1)))
    with pytest.raises(SolveError, match=f"object 0 has {L} versions"):
        solve(inst, "exact")


@pytest.mark.parametrize("options", ALL_OPTIONS, ids=lambda o: f"{o.availability}-{o.budget}")
@pytest.mark.parametrize("seed", range(4))
def test_heuristic_starts_are_mapped_inside_presolve_slots_at_the_same_value(options: Options, seed: int) -> None:
    """``static`` sends every version that fits, also where it adds nothing: its paths lie in
    presolve's slots (per slot: such arrivals dropped; one link: they wait for an event slot), are
    feasible in exact bytes and worth what the schedule is worth (summed independently)."""
    from l3gs_opt.solvers.exact.separate_data import schedule_feasible

    rng = np.random.default_rng(700 + seed)
    inst = _instance(rng, T=6, J=3, L=3, options=options, tight=0.5)
    utility = np.array(inst.utility)
    utility[4:] = 0.0                                  # nobody looks after slot 3
    inst = Instance("separate", bandwidth=inst.bandwidth, cost=inst.cost, utility=utility, held=inst.held,
                    options=options)
    data = separate_data(inst)
    start = solve(inst, "static")
    paths = data.paths_of(start.arrivals)
    assert schedule_feasible(data, paths)
    value = data.constant + math.fsum(path_value(data, k, p) for k, p in paths.items())
    assert _close(value, start.objective) or abs(value - start.objective) <= 1e-12
