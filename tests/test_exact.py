"""``exact`` (branch-and-price on Problem A): equal to brute force and the ILP, valid bounds, feasible
incumbents, stiff cases, time limits, and the options it rejects."""

from __future__ import annotations

import itertools as it
import math
import threading

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from core_helpers import PER_SLOT_OPTIONS, random_instance
from solver_helpers import check_answer
from l3gs_opt import Instance, Options, solve
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.evaluate import evaluate_objective, is_feasible
from l3gs_opt.problem.solution import GAP_TOL, Status
from l3gs_opt.solvers.brute_force import solve_brute_force
from l3gs_opt.solvers.exact.colgen import ColumnPool, Master, column_generation
import l3gs_opt.solvers.exact.search as exact_module
from l3gs_opt.solvers.exact.search import _split_masks, local_search, reduced_cost_fixing, round_schedule, solve_exact
from l3gs_opt.solvers.exact.lagrange import (Multipliers, assignment_feasible, assignment_value, gap_data,
                                       lagrangian_value, subgradient)
from l3gs_opt.solvers.exact.lns import improve_window, lp_neighbourhood, reduced_mip

#: Options ``exact`` accepts: both availabilities, same-slot and strict layers (per-slot budget).
ACCEPTED = PER_SLOT_OPTIONS


def rel_close(a: float, b: float, rtol: float = 1e-9) -> bool:
    """Objectives of the same schedule value re-summed in another order agree to 1e-9 (GAP_TOL)."""
    return abs(a - b) <= rtol * max(abs(a), abs(b), 1.0)


_check = check_answer


@pytest.mark.parametrize("opts", ACCEPTED, ids=lambda o: f"{o.availability}-{o.same_slot_layers}")
@pytest.mark.parametrize("seed", range(6))
def test_equals_brute_force(opts: Options, seed: int) -> None:
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=3, J=2, L=2, options=opts, held_p=0.4 if seed % 2 else 0.0)
    ref = solve_brute_force(inst)
    sol = solve(inst, "exact")
    _check(inst, sol)
    assert sol.status is Status.OPTIMAL
    assert rel_close(sol.objective, ref.objective)
    assert sol.gap <= GAP_TOL


@pytest.mark.parametrize("branching", ["both", "mip", "price"])
@pytest.mark.parametrize("seed", range(5))
def test_equals_core_ilp(branching: str, seed: int) -> None:
    rng = np.random.default_rng(1000 + seed)
    inst = random_instance(rng, T=7, J=4, L=3, options=ACCEPTED[seed % 4], held_p=0.3 if seed % 3 == 0 else 0.0,
                           tight=0.3)
    ref = solve(inst, "ilp")
    assert ref.status is Status.OPTIMAL
    sol = solve(inst, "exact", options={"branching": branching})
    _check(inst, sol)
    assert sol.status is Status.OPTIMAL
    assert rel_close(sol.objective, ref.objective)


def test_price_branching_alone_proves_optimality() -> None:
    """Our own branch-and-price (no HiGHS MIP) closes the tree on a small instance where the root
    bound is not tight."""
    for seed in range(40):
        rng = np.random.default_rng(seed)
        inst = random_instance(rng, T=6, J=4, L=2, tight=0.3)
        sol = solve_exact(inst, branching="price", heuristics=())
        ref = solve(inst, "ilp")
        assert sol.status is Status.OPTIMAL
        assert rel_close(sol.objective, ref.objective)
        if sol.details["nodes"] > 1:
            assert "tree closed" in sol.details["bound_kind"]
            return
    pytest.skip("no instance needed branching")


def test_unconverged_root_leaves_the_branching_to_highs(monkeypatch) -> None:
    """Where the root column generation did not converge (its time share ran out), no
    branch-and-price runs beside HiGHS: the MIP side alone closes the gap at the ILP optimum."""
    import dataclasses

    real = exact_module.column_generation
    calls = []

    def unconverged_root(*args, **kwargs):
        calls.append(kwargs.get("start_bound", math.inf))
        result = real(*args, **kwargs)
        return dataclasses.replace(result, converged=False) if len(calls) == 1 else result

    monkeypatch.setattr(exact_module, "column_generation", unconverged_root)
    for seed in range(40):
        inst = random_instance(np.random.default_rng(seed), T=8, J=5, L=3, tight=0.3)
        sol = solve_exact(inst, heuristics=())
        calls.clear()
        if sol.details.get("reduced_mip"):
            break
    else:
        pytest.fail("no instance reached the branching")
    assert sol.details["nodes"] == 0
    assert sol.status is Status.OPTIMAL
    assert rel_close(sol.objective, solve(inst, "ilp").objective)


@pytest.mark.parametrize("band", [0.0, exact_module.BOUND_BAND, 1.0])
def test_bound_band_orders_the_tree_and_nothing_else(monkeypatch, band: float) -> None:
    """BOUND_BAND only orders the open nodes (0: plain best-first; 1: one band, a depth-first
    dive). With the primal moves off (the annealing too), so that the tree itself must find the optimum: whatever the
    width, a closed tree ends at the ILP optimum, and a run stopped after two nodes carries a
    bound no smaller than it (the nodes' own bounds, not their band)."""
    monkeypatch.setattr(exact_module, "BOUND_BAND", band)
    monkeypatch.setattr(exact_module, "ROOT_PRIMAL", "lns")
    monkeypatch.setattr(exact_module._Search, "neighbourhood", lambda self, *a, **k: None)
    monkeypatch.setattr(exact_module._Search, "repair", lambda self: None)
    monkeypatch.setattr(exact_module, "window_sweep", lambda data, assign, allowed, **k: assign)
    monkeypatch.setattr(exact_module, "local_search", lambda data, assign, allowed, **k: assign)
    found_in_tree = 0
    for seed in range(30):
        inst = random_instance(np.random.default_rng(seed), T=8, J=5, L=3, tight=0.3)
        ref = solve(inst, "ilp")
        assert ref.status is Status.OPTIMAL
        sol = solve_exact(inst, branching="price", heuristics=())
        _check(inst, sol)
        assert sol.status is Status.OPTIMAL
        assert rel_close(sol.objective, ref.objective)
        found_in_tree += sol.details.get("root", {}).get("incumbent", ref.objective) < ref.objective * (1 - 1e-9)
        cut = solve_exact(inst, branching="price", heuristics=(), max_nodes=2)
        _check(inst, cut)
        assert cut.bound >= ref.objective * (1 - 1e-9) - 1e-9
    assert found_in_tree >= 3, "too few instances left the optimum to the tree"


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), held=st.booleans())
def test_bound_above_optimum_and_feasible(seed: int, opt: int, held: bool) -> None:
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=3, J=2, L=2, options=ACCEPTED[opt], held_p=0.4 if held else 0.0)
    ref = solve_brute_force(inst).objective
    data = gap_data(inst)
    # Any multipliers >= 0 give a bound >= the optimum (random ones included).
    for scale in (0.0, 0.3, 3.0):
        mult = Multipliers(scale * rng.random(data.n), scale * rng.random((data.n, data.T)))
        assert lagrangian_value(data, mult).bound >= ref * (1 - 1e-12)
    bound, _, val = subgradient(data, target=0.0, iterations=30)
    assert bound >= ref * (1 - 1e-12)
    sol = solve(inst, "exact")
    _check(inst, sol)
    assert sol.bound >= ref * (1 - 1e-12)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
def test_primal_moves_keep_schedules_feasible(seed: int, opt: int) -> None:
    """Rounding, local search, window LNS and reduced-cost fixing never break a schedule or cut
    off a better one."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=5, J=3, L=3, options=ACCEPTED[opt], tight=0.4)
    data = gap_data(inst)
    score = rng.random((data.n, data.T))
    a = round_schedule(data, score, data.allowed)
    assert assignment_feasible(data, a)
    b = local_search(data, a, data.allowed)
    assert assignment_feasible(data, b)
    assert assignment_value(data, b) >= assignment_value(data, a) - 1e-12
    c = improve_window(data, b, data.allowed, 1, 4)
    if c is not None:
        assert assignment_feasible(data, c)
    assert is_feasible(inst, data.arrivals(b))
    assert rel_close(assignment_value(data, b), evaluate_objective(inst, data.arrivals(b)))
    # Fixing against an incumbent keeps every better schedule: the optimum stays reachable.
    pool = ColumnPool(data)
    pool.add_assignment(b)
    z = assignment_value(data, b)
    cg = column_generation(data, pool, [], allowed=data.allowed, forced={}, incumbent=z)
    mask = reduced_cost_fixing(data, cg.value, cg.value.bound, z, data.allowed)
    ref = solve(inst, "ilp")
    if ref.objective > z * (1 + 1e-9) + 1e-12:
        opt_assign = data.assignment(ref.arrivals)
        on = opt_assign >= 0
        assert mask[np.nonzero(on)[0], opt_assign[on]].all()
        outcome, cand, mip_bound = reduced_mip(data, mask, z, time_limit_s=None)
        assert outcome == "optimal" and cand is not None
        assert rel_close(assignment_value(data, cand), ref.objective)


@pytest.mark.parametrize("opts", ACCEPTED, ids=lambda o: f"{o.availability}-{o.same_slot_layers}")
@pytest.mark.parametrize("seed", range(4))
def test_reduced_mip_sparse_and_dense_rows_equal_the_ilp(opts: Options, seed: int) -> None:
    """The cumulative-column (sparse) and the summed (dense) layer-order rows give the same optimum
    as the core's ILP; with the cut-off at that optimum nothing better is returned, yet the run
    closes (a point found on the way that is no better is not an answer)."""
    rng = np.random.default_rng(2000 + seed)
    inst = random_instance(rng, T=6, J=4, L=3, options=opts, held_p=0.3 if seed % 2 else 0.0, tight=0.3)
    data = gap_data(inst)
    ref = solve(inst, "ilp")
    assert ref.status is Status.OPTIMAL
    for sparse in (True, False):
        outcome, cand, bound = reduced_mip(data, data.allowed, -math.inf, time_limit_s=None, sparse=sparse)
        assert outcome == "optimal"
        if cand is None:   # nothing can arrive: the optimum is the held constant
            assert rel_close(ref.objective, data.constant)
            continue
        assert assignment_feasible(data, cand)
        assert rel_close(assignment_value(data, cand), ref.objective)
        assert rel_close(bound, ref.objective)
        outcome, again, _ = reduced_mip(data, data.allowed, assignment_value(data, cand), time_limit_s=None,
                                        sparse=sparse, start=cand)
        assert outcome == "optimal" and again is None


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
def test_lp_neighbourhood_is_feasible_and_contains_its_centre(seed: int, opt: int) -> None:
    """Around the LP solution: feasible and better than the cut-off, or None. Around an optimal
    schedule's own x (every chunk wholly in one slot): that schedule's value is found again."""
    from l3gs_opt.solvers.exact.lagrange import lp_multipliers

    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=5, J=3, L=3, options=ACCEPTED[opt], tight=0.4)
    data = gap_data(inst)
    _, _, x = lp_multipliers(data)
    ref = solve(inst, "ilp")
    if x is not None:
        cand = lp_neighbourhood(data, x, data.allowed, -math.inf, time_limit_s=None)
        if cand is not None:
            assert assignment_feasible(data, cand)
            assert assignment_value(data, cand) <= ref.objective * (1 + 1e-9) + 1e-12
    best = data.assignment(ref.arrivals)
    centre = np.zeros((data.n, data.T))
    on = best >= 0
    centre[np.nonzero(on)[0], best[on]] = 1.0
    cand = lp_neighbourhood(data, centre, data.allowed, -math.inf, time_limit_s=None)
    value = data.constant if cand is None else assignment_value(data, cand)
    assert rel_close(value, ref.objective)


def test_column_generation_bound_at_least_as_tight_as_lp() -> None:
    from l3gs_opt.solvers.bounds import lp_bound

    rng = np.random.default_rng(7)
    inst = random_instance(rng, T=8, J=5, L=3, tight=0.3)
    data = gap_data(inst)
    cg = column_generation(data, ColumnPool(data), [], allowed=data.allowed, forced={}, incumbent=-math.inf)
    lp, _ = lp_bound(inst)
    ref = solve(inst, "ilp").objective
    assert cg.converged
    assert ref * (1 - 1e-12) <= cg.bound <= lp * (1 + 1e-6)


@pytest.mark.parametrize("fail_after", [0, 1, 3])
def test_column_generation_stopped_by_its_master_keeps_a_valid_bound(monkeypatch, fail_after: int) -> None:
    """A master LP that stops short of its optimum (time limit, undecided status: ``solve`` gives
    None) ends column generation unconverged, with a bound still at least the ILP's optimum."""
    from l3gs_opt.solvers.exact import colgen

    rng = np.random.default_rng(11)
    inst = random_instance(rng, T=8, J=5, L=3, tight=0.3)
    data = gap_data(inst)
    real, calls = colgen.Master.solve, []

    def stopping(self):
        calls.append(1)
        return None if len(calls) > fail_after else real(self)

    monkeypatch.setattr(colgen.Master, "solve", stopping)
    cg = column_generation(data, ColumnPool(data), [], allowed=data.allowed, forced={}, incumbent=-math.inf)
    assert not cg.converged and math.isfinite(cg.bound)
    assert cg.bound >= solve(inst, "ilp").objective * (1 - 1e-12)


def _small_master(seed: int, opt: int, T: int):
    """A random small instance's Problem A, a pool seeded with one rounded schedule, and a master
    over it: ``(rng, data, pool, rows, master)``."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=T, J=3, L=3, options=ACCEPTED[opt], tight=0.4)
    data = gap_data(inst)
    pool, rows = ColumnPool(data), []
    pool.add_assignment(round_schedule(data, rng.random((data.n, data.T)), data.allowed))
    return rng, data, pool, rows, Master(data, pool, rows, allowed=data.allowed, forced={})


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
def test_master_kept_across_nodes_equals_a_fresh_one(seed: int, opt: int) -> None:
    """A master moved from node to node (:meth:`Master.focus`: bounds on columns, convexity rows
    and artificials) converges to the same master value as one built for each node alone."""
    from l3gs_opt.solvers.exact.search import _propagate

    rng, data, pool, rows, kept = _small_master(seed, opt, T=5)
    pairs = np.argwhere(data.allowed)
    used = np.zeros(data.allowed.shape, dtype=bool)
    for _ in range(4):
        # (Half the pairs the last node's master used are ruled out: its columns must leave.)
        mask = data.allowed & (rng.random(data.allowed.shape) < 0.8) & ~(used & (rng.random(used.shape) < 0.5))
        forced: dict[int, int] = {}
        for i, t in pairs[rng.choice(len(pairs), size=min(len(pairs), int(rng.integers(0, 3))), replace=False)]:
            forced.setdefault(int(i), int(t))
            mask[i, t] = True
        node = _propagate(data, mask, forced)
        if node is None:
            continue
        a = column_generation(data, pool, rows, allowed=node, forced=forced, incumbent=-math.inf, master=kept)
        b = column_generation(data, pool, rows, allowed=node, forced=forced, incumbent=-math.inf)
        assert a.infeasible == b.infeasible
        if a.infeasible:
            continue
        assert (a.xbar[~node] <= 1e-9).all()     # no mass on a pair the node rules out
        pos = np.nonzero(np.asarray(kept.cols) >= 0)[0]
        # The node's rule, written out per column: every item may arrive in the column's slot,
        # and the column holds every item forced into that slot.
        def allows(c: int) -> bool:
            t, items = pool.slot[c], set(pool.items[c].tolist())
            return (all(node[i, t] for i in items)
                    and all(i in items for i, ti in forced.items() if ti == t))
        expected = [allows(kept.cols[k]) for k in pos]
        assert kept._compatible_all(pos).tolist() == expected
        assert [kept.compatible(kept.cols[k]) for k in pos] == expected
        used = a.xbar > 1e-9
        artificial = np.asarray(kept.h.getSolution().col_value)[np.r_[kept.slot_art, kept.row_art].astype(int)]
        if a.converged and artificial.max(initial=0.0) <= 1e-9:   # a forced item arrives wholly in its slot
            assert all(a.xbar[i, t] >= 1 - 1e-6 for i, t in forced.items())
        if a.converged and b.converged:
            assert abs(a.master - b.master) <= 1e-6 * max(1.0, abs(b.master))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
def test_master_resolves_primal_after_new_columns_only_and_agrees_with_dual(seed: int, opt: int) -> None:
    """A master re-solve after new columns only runs primal simplex (the last basis is still
    primal feasible), after new rows or a node's bound changes dual simplex; either way the
    master's value is the one a fresh master over the same columns and rows reaches with dual
    simplex alone, and column generation converges to the same value with both rules."""
    from l3gs_opt.solvers.exact import colgen

    rng, data, pool, rows, kept = _small_master(seed, opt, T=6)

    def fresh_value() -> float:
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(colgen, "PRIMAL_SIMPLEX", colgen.DUAL_SIMPLEX)
            other = Master(data, pool, list(kept.rows), allowed=kept.allowed, forced=dict(kept.forced))
            solved = other.solve()
        assert solved is not None
        return solved[0]

    def solve_and_check(strategy: int) -> None:
        solved = kept.solve()
        assert solved is not None
        assert kept.h.getOptionValue("simplex_strategy")[1] == strategy
        assert abs(solved[0] - fresh_value()) <= 1e-7 * max(1.0, abs(solved[0]))
        assert kept.changes == set()

    solve_and_check(colgen.DUAL_SIMPLEX)          # (the first solve follows the node's bounds)
    for _ in range(3):
        for t in range(data.T):                   # new columns only: primal
            pool.add(t, np.nonzero(data.allowed[:, t] & (rng.random(data.n) < 0.5))[0])
        new_columns = [c for c in range(len(pool)) if c not in kept.held]
        kept.add_columns(new_columns)
        solve_and_check(colgen.PRIMAL_SIMPLEX if new_columns else colgen.DUAL_SIMPLEX)
        lam = np.asarray(kept.h.getSolution().col_value)
        new_rows = kept.violated_rows(kept.xbar(lam))
        if new_rows:                              # new rows: dual
            kept.add_rows(new_rows)
            solve_and_check(colgen.DUAL_SIMPLEX)
    kept.focus(data.allowed & (rng.random(data.allowed.shape) < 0.7), {})   # a node's bounds: dual
    solve_and_check(colgen.DUAL_SIMPLEX)

    mixed = column_generation(data, ColumnPool(data), [], allowed=data.allowed, forced={}, incumbent=-math.inf)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(colgen, "PRIMAL_SIMPLEX", colgen.DUAL_SIMPLEX)
        dual = column_generation(data, ColumnPool(data), [], allowed=data.allowed, forced={}, incumbent=-math.inf)
    if mixed.converged and dual.converged:
        assert abs(mixed.master - dual.master) <= 1e-6 * max(1.0, abs(dual.master))


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
@example(seed=4053, opt=1)   # (3 pivots after the restore)
def test_master_restored_to_a_nodes_basis_resolves_there_at_once(seed: int, opt: int) -> None:
    """A node's basis (:meth:`Master.snapshot`), restored after the master has moved to another
    node, is HiGHS's basis again and optimal there: the re-solve takes a few pivots at most and
    gives the node's value; with a column the snapshot does not know, the value matches a fresh
    master's (the restored basis only starts the solve)."""
    import highspy

    rng, data, pool, rows, kept = _small_master(seed, opt, T=6)
    column_generation(data, pool, rows, allowed=data.allowed, forced={}, incumbent=-math.inf, master=kept)
    value_a = kept.solve()[0]
    basis = kept.snapshot()
    other = data.allowed & (rng.random(data.allowed.shape) < 0.6)
    kept.focus(other, {})
    kept.solve()                                   # (the master's basis is now the other node's)
    kept.focus(data.allowed, {}, basis=basis)
    # HiGHS took the snapshot as it was: nonbasic columns at 0, nonbasic rows at their upper
    # bound, and the pool columns the master took in since (at its focus) nonbasic.
    held, st = kept.h.getBasis(), highspy.HighsBasisStatus
    assert held.valid
    new_cols = len(held.col_status) - len(basis.cols)
    assert list(held.col_status) == [st.kLower if c == st.kUpper else c for c in basis.cols] + [st.kLower] * new_cols
    assert list(held.row_status) == [st.kUpper if r == st.kLower else r for r in basis.rows]
    assert kept.solve()[0] == pytest.approx(value_a, rel=1e-9, abs=1e-9)
    # (a few pivots at most: HiGHS may clean up its cost perturbation; seen 3 on one instance)
    assert kept.h.getInfo().simplex_iteration_count <= 5
    column_generation(data, pool, rows, allowed=other, forced={}, incumbent=-math.inf, master=kept)
    kept.focus(data.allowed, {}, basis=basis)     # (columns and rows the snapshot does not know)
    value = kept.solve()[0]
    assert value >= value_a - 1e-7 * max(1.0, abs(value_a))
    fresh = Master(data, pool, list(kept.rows), allowed=data.allowed, forced={})
    assert fresh.solve()[0] == pytest.approx(value, rel=1e-7, abs=1e-7)


def test_column_generation_master_gets_the_node_time_limit() -> None:
    """The master's HiGHS carries the node's time limit (its own limit and the wall-clock
    interrupt: :func:`new_highs`); without one, none."""
    from l3gs_opt.solvers.exact.colgen import Master

    rng = np.random.default_rng(7)
    data = gap_data(random_instance(rng, T=8, J=5, L=3, tight=0.3))
    timed = Master(data, ColumnPool(data), [], allowed=data.allowed, forced={}, big_m=1e6, time_limit_s=2.5)
    free = Master(data, ColumnPool(data), [], allowed=data.allowed, forced={}, big_m=1e6)
    assert timed.h.getOptionValue("time_limit")[1] == 2.5      # (status, value)
    assert free.h.getOptionValue("time_limit")[1] > 1e9


STIFF = {
    "utility_orders": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)),
                                       utility=10.0 ** rng.uniform(-9, 9, (4, 3, 2)),
                                       bandwidth=rng.integers(2, 12, 4)),
    "ties": lambda rng: dict(cost=np.full((3, 2), 4), utility=np.ones((4, 3, 2)), bandwidth=np.full(4, 9)),
    "zero_bandwidth": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)), utility=rng.random((4, 3, 2)),
                                       bandwidth=np.zeros(4, dtype=np.int64)),
    "huge_bandwidth": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)), utility=rng.random((4, 3, 2)),
                                       bandwidth=np.full(4, 10**15)),
    "huge_costs": lambda rng: dict(cost=rng.integers(10**12, 10**13, (3, 2)), utility=rng.random((4, 3, 2)),
                                   bandwidth=rng.integers(10**12, 3 * 10**13, 4)),
    "single_object": lambda rng: dict(cost=rng.integers(1, 9, (1, 3)), utility=rng.random((4, 1, 3)),
                                      bandwidth=rng.integers(0, 12, 4)),
    "empty_scene": lambda rng: dict(cost=np.zeros((0, 2), dtype=np.int64), utility=np.zeros((4, 0, 2)),
                                    bandwidth=np.full(4, 5)),
    "one_slot": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)), utility=rng.random((1, 3, 2)),
                                 bandwidth=[7]),
}


@pytest.mark.parametrize("case", sorted(STIFF))
def test_stiff_cases(case: str) -> None:
    rng = np.random.default_rng(3)
    inst = Instance("layered", **STIFF[case](rng))
    sol = solve(inst, "exact")
    _check(inst, sol)
    assert sol.status is Status.OPTIMAL
    ref = solve_brute_force(inst) if inst.J * inst.L <= 6 else solve(inst, "ilp")
    assert rel_close(sol.objective, ref.objective)


def test_all_held() -> None:
    rng = np.random.default_rng(4)
    inst = Instance("layered", bandwidth=[5, 5], cost=rng.integers(1, 5, (2, 2)), utility=rng.random((2, 2, 2)),
                    held=np.ones((2, 2), bool))
    sol = solve(inst, "exact")
    assert sol.status is Status.OPTIMAL and sol.arrivals == ()
    assert rel_close(sol.objective, float(inst.utility.sum()))


@pytest.mark.parametrize("objects, slots, seed, limit_s", [(12, 30, 1, 0.5), (16, 40, 2, 6.0)],
                         ids=["before-the-mip", "inside-the-mip"])
def test_time_limit_returns_valid_bound_and_feasible_schedule(objects, slots, seed, limit_s) -> None:
    """A limit that stops the run early, or long enough to reach the reduced MIP but (usually) too
    short to close it: a feasible answer, ``time_limit`` with a gap or ``optimal`` (never
    ``feasible``), and a bound no smaller than the ILP's optimum."""
    from l3gs_opt.pipeline.synth import synth_instance

    inst = synth_instance(objects=objects, layers=4, slots=slots, seed=seed)
    sol = solve(inst, "exact", time_limit_s=limit_s)
    _check(inst, sol)
    assert sol.status in (Status.TIME_LIMIT, Status.OPTIMAL)
    if sol.status is Status.TIME_LIMIT:
        assert sol.gap > GAP_TOL
    ilp = solve(inst, "ilp", time_limit_s=30)
    if ilp.status is Status.OPTIMAL:
        assert sol.bound >= ilp.objective * (1 - 1e-9)


def test_price_branching_node_limit_is_labelled_time_limit() -> None:
    rng = np.random.default_rng(11)
    for seed in range(30):
        inst = random_instance(np.random.default_rng(seed), T=6, J=4, L=2, tight=0.3)
        sol = solve_exact(inst, branching="price", heuristics=(), max_nodes=1)
        _check(inst, sol)
        if sol.status is not Status.OPTIMAL:
            assert sol.status is Status.TIME_LIMIT
            assert sol.bound >= solve(inst, "ilp").objective * (1 - 1e-9)
            return
    del rng
    pytest.skip("every instance closed at the root")


def test_both_sides_run_together_join_and_pass_errors_on(monkeypatch) -> None:
    """``branching="both"``: the MIP thread ends with the call, and its failure is the caller's."""
    for seed in range(40):
        inst = random_instance(np.random.default_rng(seed), T=8, J=5, L=3, tight=0.3)
        sol = solve_exact(inst, heuristics=())
        assert not any(t.name == "exact-mip" for t in threading.enumerate())
        if sol.details.get("reduced_mip") and sol.details["nodes"]:
            break
    else:   # 40 seeds without one that runs both sides would mean the sides no longer run together
        pytest.fail("no instance ran both the MIP side and branch-and-price")
    assert sol.status is Status.OPTIMAL
    assert sol.objective == pytest.approx(solve(inst, "ilp").objective, rel=1e-9, abs=1e-9)

    def failing(*args, **kwargs):
        raise RuntimeError("the MIP side failed")

    monkeypatch.setattr(exact_module, "reduced_mip", failing)
    with pytest.raises(RuntimeError, match="the MIP side failed"):
        solve_exact(inst, heuristics=())
    assert not any(t.name == "exact-mip" for t in threading.enumerate())


def test_rejects_slot_and_unknown_branching() -> None:
    inst = random_instance(np.random.default_rng(0))
    with pytest.raises(SolveError, match="slot does not apply"):
        solve(inst, "exact", slot=0)
    with pytest.raises(SolveError, match="branching"):
        solve_exact(inst, branching="dfs")
    with pytest.warns(UserWarning, match="unknown"):
        solve(inst, "exact", options={"colour": 1})


@pytest.mark.slow
def test_paper_scale_short_run_is_certified() -> None:
    """J=20, L=4, T=60 (the l3gs suite's first T=60 spec) under a 20 s limit: a feasible
    schedule, a valid bound, and a gap far below the heuristics' (no timed assertion)."""
    from l3gs_opt.bench.suites import suite_specs

    spec = [s for s in suite_specs("l3gs", sizes=[20], seeds=1) if not s.single_slot][0]
    inst = spec.build()
    sol = solve(inst, "exact", time_limit_s=20)
    _check(inst, sol)
    heur = solve(inst, "rolling-future:bb")
    assert sol.objective >= heur.objective
    assert sol.bound <= heur.bound * (1 + 1e-6)   # at least as tight as the LP bound


@pytest.mark.parametrize("seed", range(4))
def test_reduced_mip_restart_returns_feasible_schedule_and_valid_bound(seed: int) -> None:
    """``restart_if`` true at every improving schedule: HiGHS stops at the first one (or closes
    first); the schedule is feasible in exact bytes and the bound is still >= the optimum."""
    rng = np.random.default_rng(3000 + seed)
    inst = random_instance(rng, T=7, J=5, L=3, options=ACCEPTED[seed], tight=0.3)
    data = gap_data(inst)
    ref = solve(inst, "ilp")
    seen: list[float] = []
    outcome, cand, bound = reduced_mip(data, data.allowed, -math.inf, time_limit_s=None,
                                       restart_if=lambda v: seen.append(v) or True)
    assert outcome in ("restart", "optimal")
    if cand is not None:
        assert assignment_feasible(data, cand)
        assert assignment_value(data, cand) <= ref.objective * (1 + 1e-9) + 1e-12
    assert bound >= ref.objective * (1 - 1e-9)
    if outcome == "restart":
        assert seen and cand is not None
        assert rel_close(seen[-1], assignment_value(data, cand), rtol=1e-6)   # HiGHS's value vs. ours


@pytest.mark.parametrize("seed", range(4))
def test_lp_neighbourhood_bands_are_nested(seed: int) -> None:
    """Band 0 within band 1 within band T (which is the whole problem): solved exactly, their
    optima never decrease, and band T equals the core's ILP."""
    from l3gs_opt.solvers.exact.lagrange import lp_multipliers

    rng = np.random.default_rng(4000 + seed)
    inst = random_instance(rng, T=6, J=4, L=3, options=ACCEPTED[seed], tight=0.3)
    data = gap_data(inst)
    _, _, x = lp_multipliers(data)
    ref = solve(inst, "ilp")
    values = []
    for band in (0, 1, data.T):
        cand = lp_neighbourhood(data, x, data.allowed, -math.inf, time_limit_s=None, band=band)
        if cand is not None:
            assert assignment_feasible(data, cand)
        values.append(data.constant if cand is None else assignment_value(data, cand))
    assert values[0] <= values[1] * (1 + 1e-9) + 1e-12 and values[1] <= values[2] * (1 + 1e-9) + 1e-12
    assert rel_close(values[2], ref.objective)


def test_restarting_the_reduced_mip_keeps_the_optimum(monkeypatch) -> None:
    """With RESTART_SHRINK = 1 HiGHS is restarted at every improving schedule it finds (no start
    heuristics, no annealing, one-slot windows: the primal side leaves it some to find; the MIP side alone, so that
    no race with branch-and-price decides whether it gets to find one, and no MIP beside the root
    column generation finds them first): the answers still equal the core's ILP, and at least one
    run restarted."""
    import l3gs_opt.solvers.exact.search as exact_mod

    monkeypatch.setattr(exact_mod, "RESTART_SHRINK", 1.0)
    monkeypatch.setattr(exact_mod, "ROOT_MIP", False)
    monkeypatch.setattr(exact_mod, "ROOT_PRIMAL", "lns")
    outcomes = []
    for seed in range(16):
        inst = random_instance(np.random.default_rng(6000 + seed), T=10, J=8, L=3, tight=0.25)
        ref = solve(inst, "ilp")
        sol = solve_exact(inst, heuristics=(), lns_width=1, branching="mip")
        _check(inst, sol)
        assert sol.status is Status.OPTIMAL
        assert rel_close(sol.objective, ref.objective)
        outcomes += [run["outcome"] for run in sol.details.get("reduced_mip", {}).get("runs", [])]
    assert "restart" in outcomes


def test_root_mip_beside_column_generation(monkeypatch) -> None:
    """ROOT_MIP: HiGHS searches beside the root column generation. Its thread ends with the root,
    the answers equal the core's ILP with it and without it, and on some instance its run is
    recorded with a schedule it found or the gap it closed."""
    helped = False
    for seed in range(12):
        inst = random_instance(np.random.default_rng(7000 + seed), T=10, J=8, L=3, tight=0.25)
        ref = solve(inst, "ilp")
        assert ref.status is Status.OPTIMAL
        sol = solve_exact(inst, heuristics=(), lns_width=1)
        _check(inst, sol)
        assert not any(t.name == "exact-root-mip" for t in threading.enumerate())
        assert sol.status is Status.OPTIMAL
        assert rel_close(sol.objective, ref.objective)
        runs = sol.details.get("root_mip", {}).get("runs", [])
        helped |= any(r["outcome"] in ("optimal", "restart") for r in runs)
    assert helped
    monkeypatch.setattr(exact_module, "ROOT_MIP", False)
    sol = solve_exact(inst, heuristics=(), lns_width=1)
    assert "root_mip" not in sol.details
    assert rel_close(sol.objective, ref.objective)


def test_subgradient_from_lp_duals_is_a_valid_bound_no_worse_than_its_start() -> None:
    from l3gs_opt.solvers.exact.lagrange import lp_multipliers

    rng = np.random.default_rng(8)
    inst = random_instance(rng, T=8, J=5, L=3, tight=0.3)
    data = gap_data(inst)
    _, mult, _ = lp_multipliers(data)
    start = lagrangian_value(data, mult).bound
    ref = solve(inst, "ilp").objective
    bound, _, _ = subgradient(data, target=ref, start=mult, iterations=50)
    assert ref * (1 - 1e-12) <= bound <= start


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), shortfall=st.sampled_from([1e-9, 1e-3, 1e-2]))
def test_exact_knapsack_fixing_keeps_every_better_schedule(seed: int, opt: int, shortfall: float) -> None:
    """Fixing with the knapsack solved exactly removes at least what the Dantzig test removes, and
    never a pair of the optimum when the incumbent value is below it (at the LP duals and at the
    column-generation duals)."""
    from l3gs_opt.solvers.exact.lagrange import lp_multipliers

    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=6, J=4, L=3, options=ACCEPTED[opt], tight=0.3)
    data = gap_data(inst)
    ref = solve(inst, "ilp")
    z = ref.objective * (1 - shortfall) - 1e-12
    opt_assign = data.assignment(ref.arrivals)
    on = np.nonzero(opt_assign >= 0)[0]
    _, mult, _ = lp_multipliers(data)
    cg = column_generation(data, ColumnPool(data), [], allowed=data.allowed, forced={}, incumbent=-math.inf)
    for lv in ([lagrangian_value(data, mult)] if mult is not None else []) + [cg.value]:
        cheap = reduced_cost_fixing(data, lv, lv.bound, z, data.allowed)
        exact = reduced_cost_fixing(data, lv, lv.bound, z, data.allowed, exact_knapsack=True)
        assert not (exact & ~cheap).any()
        assert exact[on, opt_assign[on]].all()


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
def test_cumulative_branch_children_cover_every_schedule(seed: int, opt: int) -> None:
    """A cumulative branch (item i by slot t, or after it) loses no feasible schedule: every one in
    the parent's mask lies in a child, and each child keeps only its side of t for i."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=4, J=2, L=3, options=ACCEPTED[opt], tight=0.8)
    data = gap_data(inst)
    if data.n == 0:
        return
    schedules = np.array([a for a in it.product(range(-1, data.T), repeat=data.n)
                          if assignment_feasible(data, np.asarray(a))])
    on = schedules >= 0
    items = np.broadcast_to(np.arange(data.n), schedules.shape)

    def inside(mask: np.ndarray) -> np.ndarray:   # per schedule: every arrival allowed by mask
        return np.where(on, mask[items, np.maximum(schedules, 0)], True).all(axis=1)

    for i in range(data.n):
        for t in range(data.T):
            by, after = _split_masks(data, data.allowed, i, t)
            assert not by[i, t + 1:].any() and not after[i, :t + 1].any()
            lost = ~(inside(by) | inside(after))
            assert not lost.any(), (i, t, schedules[lost][0])


def test_start_heuristics_checked_first_then_run_while_time_is_left(monkeypatch) -> None:
    """``run_starts``, shared by the three searches: a bad name anywhere in the list is refused before
    any heuristic runs, a passed deadline runs none, and each runs with the time left."""
    import time

    from l3gs_opt.solvers.exact import starts

    ran: list = []
    monkeypatch.setattr(starts, "run_start", lambda name, inst, left: ran.append((name, left)) or name)
    with pytest.raises(SolveError, match="start heuristic 'nope'"):
        list(starts.run_starts(["slope", "nope"], None, None))
    assert ran == []
    assert list(starts.run_starts(["slope"], None, time.perf_counter() - 1.0)) == [] and ran == []
    assert list(starts.run_starts(["slope", "static"], None, None)) == [("slope", "slope"), ("static", "static")]
    assert ran == [("slope", None), ("static", None)]
    ran.clear()
    list(starts.run_starts(["slope"], None, time.perf_counter() + 30.0))
    assert 0 < ran[0][1] <= 30.0
    inst = random_instance(np.random.default_rng(0), options=Options())
    with pytest.raises(SolveError, match="start heuristic"):
        solve(inst, "exact", options={"heuristics": ["slope", "nope"]})


def test_closed_needs_a_finite_bound() -> None:
    """No bound yet (``inf``) closes nothing, though the relative tolerance of ``inf`` is ``inf``;
    a bound at the incumbent, or within CLOSE_TOL of it, does; an infeasible node (``-inf``) does."""
    closed = exact_module._closed
    assert not closed(math.inf, 0.0) and not closed(math.inf, 1e300)
    assert closed(5.0, 5.0) and closed(5.0 * (1 + 0.5 * exact_module.CLOSE_TOL), 5.0)
    assert not closed(5.0 * (1 + 10 * exact_module.CLOSE_TOL), 5.0)
    assert closed(-math.inf, 0.0)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), shortfall=st.sampled_from([1e-9, 1e-3, 1e-2]))
def test_fixing_at_the_root_keeps_the_optimum_and_uses_every_certificate(seed: int, opt: int,
                                                                        shortfall: float) -> None:
    """After the root, fixing at a value below the optimum (the knapsack test with the tightest
    certificate, the cheap test with every one) keeps every pair of the ILP optimum, and keeps no
    pair that some certificate's cheap test drops."""
    inst = random_instance(np.random.default_rng(seed), T=6, J=4, L=3, options=ACCEPTED[opt], tight=0.3)
    ref = solve(inst, "ilp")
    s = exact_module._Search(inst, started=0.0, time_limit_s=None, max_nodes=None, lns_width=3, branching="both")
    s.start(())
    if s.data.n == 0:
        return
    s.root()
    z = ref.objective * (1 - shortfall) - 1e-12
    mask = s.fixed_at(z, s.allowed0, exact=True)
    opt_assign = s.data.assignment(ref.arrivals)
    on = np.nonzero(opt_assign >= 0)[0]
    assert mask[on, opt_assign[on]].all()
    for lv in s.certificates:
        assert not (mask & ~reduced_cost_fixing(s.data, lv, lv.bound, z, s.allowed0)).any()


def test_after_the_annealing_no_lp_neighbourhood_and_no_mpc_start(monkeypatch) -> None:
    """With ROOT_PRIMAL = "anneal" the root runs no LP neighbourhood MIP (on instances with n * T <=
    LEAN_ROOT_MAX_PAIRS) and the start heuristics leave out ``mpc:3``; with "lns" both run, and above
    LEAN_ROOT_MAX_PAIRS the neighbourhoods run after the annealing too."""
    inst = random_instance(np.random.default_rng(7), T=8, J=5, L=3, tight=0.3)
    calls: list[int] = []
    real = exact_module.lp_neighbourhood
    monkeypatch.setattr(exact_module, "lp_neighbourhood", lambda *a, **k: calls.append(1) or real(*a, **k))
    for primal, lean_max, neighbourhoods, mpc in (("anneal", exact_module.LEAN_ROOT_MAX_PAIRS, False, False),
                                                  ("lns", exact_module.LEAN_ROOT_MAX_PAIRS, True, True),
                                                  ("anneal", 0, True, False)):
        monkeypatch.setattr(exact_module, "ROOT_PRIMAL", primal)
        monkeypatch.setattr(exact_module, "LEAN_ROOT_MAX_PAIRS", lean_max)
        calls.clear()
        sol = solve_exact(inst)
        _check(inst, sol)
        assert sol.status is Status.OPTIMAL
        assert bool(calls) is neighbourhoods
        assert ("mpc:3" in sol.details["start"]["values"]) is mpc
