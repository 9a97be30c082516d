"""Multi-slot methods: rolling:SOLVER, rolling-future:SOLVER, mpc:H, progressive, slope, static.

Every answer must be feasible in exact bytes without repair, never beat the optimum (brute
force), and carry a bound (the LP relaxation) that is at least the optimum. Where theory says
a method is exact (rolling with an exact solver at T=1, mpc over the whole horizon, the
divisible slope greedy under static utilities) it must match.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import linprog

import l3gs_opt
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.evaluate import is_feasible
from l3gs_opt.problem.instance import Instance, Options
from l3gs_opt.models import solve_ilp
from l3gs_opt.problem.solution import Status
from l3gs_opt.solvers import slope_fractional_value
from l3gs_opt.solvers.brute_force import solve_brute_force

from solver_helpers import OPTIONS, multi_instance, rel_close

HEURISTICS = ["rolling:bb", "rolling:dp", "rolling:greedy", "rolling:fptas:0.2", "rolling:ilp",
              "rolling-future:bb", "rolling-future:greedy", "mpc:2", "progressive", "slope", "static"]
#: HiGHS solves the LP bound to 1e-7 relative tolerances (LP_BOUND_SLACK covers it).
BOUND_RTOL = 1e-9


def _check(inst: Instance, sol, opt: float) -> None:
    assert is_feasible(inst, sol.arrivals), sol.arrivals
    assert "repaired" not in sol.message, sol.message
    assert sol.objective <= opt * (1 + 1e-12) + 1e-12
    assert sol.bound is not None and sol.bound >= opt * (1 - BOUND_RTOL)
    assert sol.gap is not None and sol.gap >= 0


@pytest.mark.parametrize("options", OPTIONS, ids=lambda o: f"{o.availability}-{o.same_slot_layers}-{o.budget}")
@pytest.mark.parametrize("representation", ["layered", "separate"])
def test_heuristics_feasible_and_bounded(options: Options, representation: str) -> None:
    for seed in range(6):
        inst = multi_instance(seed, representation=representation, options=options, held=seed % 3 == 0)
        opt = solve_brute_force(inst).objective
        for method in HEURISTICS:
            sol = l3gs_opt.solve(inst, method=method)
            _check(inst, sol, opt)
            assert sol.status in (Status.FEASIBLE, Status.OPTIMAL)


@pytest.mark.parametrize("options", OPTIONS, ids=lambda o: f"{o.availability}-{o.same_slot_layers}-{o.budget}")
def test_rolling_exact_at_one_slot(options: Options) -> None:
    for seed in range(8):
        inst = multi_instance(seed, J=3, L=2, T=1, options=options, held=seed % 2 == 0)
        opt = solve_brute_force(inst).objective
        for method in ("rolling:bb", "rolling:dp", "rolling:ilp", "rolling-future:bb"):
            sol = l3gs_opt.solve(inst, method=method)
            _check(inst, sol, opt)
            assert rel_close(sol.objective, opt), (method, sol.objective, opt)
            if options.availability == "same_slot":
                assert sol.status is Status.OPTIMAL


@pytest.mark.parametrize("options", OPTIONS, ids=lambda o: f"{o.availability}-{o.same_slot_layers}-{o.budget}")
def test_mpc_over_the_whole_horizon_is_exact(options: Options) -> None:
    # Re-planning after committing the first slot of an optimal plan can only keep or improve it.
    for seed in range(5):
        inst = multi_instance(seed, options=options)
        opt = solve_brute_force(inst).objective
        sol = l3gs_opt.solve(inst, method=f"mpc:{inst.T}")
        _check(inst, sol, opt)
        assert rel_close(sol.objective, opt, rtol=1e-7)   # the ILP's own tolerance


def test_rolling_future_uses_future_utility() -> None:
    # Object 0 is worth a lot now, object 1 a lot later; one of them fits per slot, in slot 0 only.
    utility = np.array([[[2.0], [0.0]], [[0.0], [1.5]], [[0.0], [1.5]]])
    inst = Instance(representation="layered", bandwidth=[5, 0, 0], cost=[[5], [5]], utility=utility)
    assert l3gs_opt.solve(inst, method="rolling:bb").arrivals == ((0, 0, 0),)
    assert l3gs_opt.solve(inst, method="rolling-future:bb").arrivals == ((1, 0, 0),)


def test_cumulative_budget_sends_a_chunk_larger_than_one_slot() -> None:
    inst = Instance(representation="layered", bandwidth=[4, 4, 4, 4], cost=[[10]], utility=np.ones((4, 1, 1)),
                    options=Options(budget="cumulative"))
    for method in ("rolling:bb", "rolling-future:greedy", "slope", "progressive", "static", "mpc:3"):
        sol = l3gs_opt.solve(inst, method=method)
        assert sol.arrivals == ((0, 0, 2),), method
        assert sol.objective == 2.0


def test_per_slot_budget_never_sends_a_chunk_larger_than_a_slot() -> None:
    inst = Instance(representation="layered", bandwidth=[4, 4, 4, 4], cost=[[10]], utility=np.ones((4, 1, 1)))
    for method in ("rolling:bb", "slope", "progressive", "static"):
        assert l3gs_opt.solve(inst, method=method).arrivals == ()


def test_separate_upgrade_replaces_the_held_version() -> None:
    # Version 1 (whole cost 6) replaces the held version 0: its gain is 5 - 2 per slot.
    inst = Instance(representation="separate", bandwidth=[6, 6], cost=[[4, 6]], utility=np.array([[[2.0, 5.0]]] * 2),
                    held=[[True, False]])
    for method in ("rolling:bb", "rolling:greedy", "slope", "progressive", "static", "mpc:2"):
        sol = l3gs_opt.solve(inst, method=method)
        assert sol.arrivals == ((0, 1, 0),), method
        assert sol.objective == 10.0


def test_strict_layers_one_layer_per_slot() -> None:
    inst = Instance(representation="layered", bandwidth=[10, 10, 10], cost=[[1, 1, 1]], utility=np.ones((3, 1, 3)),
                    options=Options(same_slot_layers=False))
    for method in ("rolling:bb", "rolling:dp", "slope", "progressive", "static"):
        sol = l3gs_opt.solve(inst, method=method)
        assert sol.arrivals == ((0, 0, 0), (0, 1, 1), (0, 2, 2)), method


def _independent_lp(inst: Instance) -> float:
    """LP relaxation of Problem I (same-slot availability and layers), written from docs/design.md
    with y[j,l,t] only: x[t] = y[t] - y[t-1] >= 0, budgets, y[l] <= y[l-1]."""
    T, J, L = inst.T, inst.J, inst.L
    idx = {k: i for i, k in enumerate(itertools.product(range(J), range(L), range(T)))}
    n = len(idx)
    c = np.zeros(n)
    rows, rhs = [], []
    bounds = []
    for (j, l, t), i in idx.items():
        c[i] = -inst.utility[t, j, l]
        bounds.append((1.0, 1.0) if inst.held[j, l] else (0.0, 1.0))
        if t > 0:                                      # y[t-1] - y[t] <= 0
            r = np.zeros(n); r[idx[(j, l, t - 1)]] = 1; r[i] = -1; rows.append(r); rhs.append(0.0)
        if l > 0:                                      # y[l] - y[l-1] <= 0
            r = np.zeros(n); r[i] = 1; r[idx[(j, l - 1, t)]] = -1; rows.append(r); rhs.append(0.0)
    for t in range(T):
        r = np.zeros(n)
        for j in range(J):
            for l in range(L):
                if inst.held[j, l]:
                    continue
                r[idx[(j, l, t)]] += inst.cost[j, l]
                if t > 0:
                    r[idx[(j, l, t - 1)]] -= inst.cost[j, l]
        rows.append(r); rhs.append(float(inst.bandwidth[t]))
    res = linprog(c, A_ub=np.array(rows), b_ub=np.array(rhs), bounds=bounds, method="highs")
    assert res.status == 0
    return -res.fun


@pytest.mark.parametrize("seed", range(8))
def test_divisible_slope_equals_the_lp_under_static_utilities(seed: int) -> None:
    rng = np.random.default_rng(seed)
    J, L, T = 3, 3, 4
    cost = rng.integers(1, 10, size=(J, L))
    u = rng.integers(0, 10, size=(J, L)) + rng.random((J, L))
    h = rng.integers(0, 2, size=J) if seed % 2 else np.zeros(J, int)
    held = np.arange(L)[None, :] < h[:, None]
    inst = Instance(representation="layered", bandwidth=[int(rng.integers(1, 12))] * T, cost=cost,
                    utility=np.broadcast_to(u, (T, J, L)), held=held)
    assert slope_fractional_value(inst) == pytest.approx(_independent_lp(inst), rel=1e-8)
    # The core's LP relaxation of the naive model agrees too; with presolve (chunks larger than
    # any slot dropped) it can only be tighter.
    naive = l3gs_opt.solve(inst, method="lp", presolve=False).bound
    assert slope_fractional_value(inst) == pytest.approx(naive, rel=1e-7)
    assert l3gs_opt.solve(inst, method="lp").bound <= naive * (1 + 1e-7)


@pytest.mark.parametrize("seed", range(5))
def test_slope_equals_the_lp_when_chunks_align_with_slots(seed: int) -> None:
    # Static utilities, every chunk exactly one slot's bytes, utilities decreasing per layer:
    # the LP optimum is integral and the whole-chunk greedy reaches it.
    rng = np.random.default_rng(seed)
    J, L, T, B = 3, 3, 5, 7
    u = -np.sort(-rng.random((J, L)) * 10, axis=1)
    inst = Instance(representation="layered", bandwidth=[B] * T, cost=np.full((J, L), B),
                    utility=np.broadcast_to(u, (T, J, L)))
    sol = l3gs_opt.solve(inst, method="slope")
    lp = _independent_lp(inst)
    assert sol.objective == pytest.approx(lp, rel=1e-9)
    assert sol.objective == pytest.approx(slope_fractional_value(inst), rel=1e-12)


def test_slope_fractional_value_refuses_dynamic_utilities() -> None:
    inst = multi_instance(0, representation="layered")
    with pytest.raises(SolveError, match="utilities must be static"):
        slope_fractional_value(inst)


@pytest.mark.parametrize("method", ["rolling:bb", "rolling-future:dp", "mpc:2", "progressive", "slope", "static"])
def test_multi_slot_methods_refuse_a_slot(method: str) -> None:
    inst = multi_instance(1)
    with pytest.raises(SolveError, match="schedules the whole horizon: slot does not apply"):
        l3gs_opt.solve(inst, method=method, slot=0)


def test_bound_can_be_skipped_and_times_are_reported() -> None:
    inst = multi_instance(2)
    sol = l3gs_opt.solve(inst, method="rolling:bb", options={"bound": False})
    assert sol.bound is None and sol.gap is None
    sol = l3gs_opt.solve(inst, method="rolling:bb")
    assert {"schedule_s", "bound_s"} <= set(sol.details)


def test_rolling_bb_l3gs_like_scale_against_ilp() -> None:
    from l3gs_opt.pipeline.synth import synth_instance

    inst = synth_instance(objects=30, layers=4, slots=8, seed=3, total_splats=30 * 180)
    exact = solve_ilp(inst, backend="highs", time_limit_s=60)
    for method in ("rolling:bb", "rolling-future:bb", "slope", "progressive", "static"):
        sol = l3gs_opt.solve(inst, method=method)
        assert is_feasible(inst, sol.arrivals)
        assert sol.objective <= exact.objective * (1 + 1e-9)
        assert sol.bound >= exact.objective * (1 - 1e-7)
