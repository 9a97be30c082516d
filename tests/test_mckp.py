"""Single-slot MCKP methods (bb, dp, fptas:EPS, greedy) against brute force and the core's ILP.

Tolerances: objectives are float64 sums of the same utilities in different orders, so exact
solvers must agree to ``rtol=1e-9`` (``GAP_TOL``, the gap that counts as proven optimal).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import l3gs_opt
from l3gs_opt.errors import SolveError
from l3gs_opt.evaluate import is_feasible
from l3gs_opt.instance import Instance, Options
from l3gs_opt.models import build_model, solve_ilp, solve_model
from l3gs_opt.presolve import mckp_options
from l3gs_opt.solution import Status
from l3gs_opt.solvers import _mckp
from l3gs_opt.solvers.brute_force import solve_brute_force
from l3gs_opt.solvers.mckp import slot_table, solve_bb, solve_dp, solve_fptas, solve_greedy

from solver_helpers import FAMILIES, mckp_instance, rel_close

SETTINGS = settings(max_examples=40, deadline=None, derandomize=True)


def _check_exact(inst: Instance, sol, reference) -> None:
    assert sol.status is Status.OPTIMAL, sol.message
    assert is_feasible(inst, sol.arrivals, slot=0)
    assert rel_close(sol.objective, reference.objective), (sol.objective, reference.objective)
    assert sol.bound >= reference.objective * (1 - 1e-12)


# -- the option table is the core presolve's, vectorised --------------------------------------

@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(FAMILIES), strict=st.booleans())
def test_table_matches_core_mckp_options(seed: int, family: str, strict: bool) -> None:
    inst = mckp_instance(seed, family, J=4, L=3, same_slot_layers=not strict)
    table, constant = slot_table(inst, 0)
    ref = mckp_options(inst, 0)
    assert constant == ref.constant
    assert [int(j) for j in table.rows] == list(ref.objects)
    for i in range(table.n):
        k = int(table.valid[i].sum())
        assert tuple(int(c) for c in table.cost[i, :k]) == ref.cost[i]
        assert tuple(float(v) for v in table.value[i, :k]) == ref.value[i]   # bit for bit


@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(("random", "ties", "held")))
def test_lp_relaxation_matches_highs(seed: int, family: str) -> None:
    inst = mckp_instance(seed, family, J=4, L=3)
    table, constant = slot_table(inst, 0)
    lp = _mckp.lp_relaxation(table)
    model = build_model(inst, slot=0)
    highs = solve_model(model, "highs", relax=True).bound
    # HiGHS's LP optimum carries its 1e-7 feasibility tolerances.
    assert lp.value + constant == pytest.approx(highs + model.constant, rel=1e-7, abs=1e-7)


# -- exact methods ----------------------------------------------------------------------------

@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(FAMILIES))
def test_bb_equals_brute_force(seed: int, family: str) -> None:
    inst = mckp_instance(seed, family, J=4, L=3)
    _check_exact(inst, solve_bb(inst), solve_brute_force(inst, slot=0))


@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(FAMILIES))
def test_bb_strict_layers_equals_brute_force(seed: int, family: str) -> None:
    inst = mckp_instance(seed, family, J=5, L=3, representation="layered", same_slot_layers=False)
    _check_exact(inst, solve_bb(inst), solve_brute_force(inst, slot=0))


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), family=st.sampled_from(("random", "stiff", "ties", "held")))
def test_bb_equals_ilp(seed: int, family: str) -> None:
    inst = mckp_instance(seed, family, J=12, L=4)
    ilp = solve_ilp(inst, slot=0, backend="highs")
    sol = solve_bb(inst)
    assert sol.status is Status.OPTIMAL
    assert is_feasible(inst, sol.arrivals, slot=0)
    # The MILP proves optimality only to its own tolerances: bb must be at least as good.
    assert sol.objective >= ilp.objective * (1 - 1e-9)
    if family != "stiff":
        assert rel_close(sol.objective, ilp.objective)


@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(("random", "ties", "zero", "huge", "held")))
def test_dp_equals_brute_force(seed: int, family: str) -> None:
    inst = mckp_instance(seed, family, J=4, L=3)
    _check_exact(inst, solve_dp(inst), solve_brute_force(inst, slot=0))


@SETTINGS
@given(seed=st.integers(0, 10**6))
def test_dp_and_bb_on_stiff_utilities_with_splat_costs(seed: int) -> None:
    # Costs as L3GS has them (splats x 248 B, here 248 B .. 0.5 MB), utilities 1e-9..1e9.
    rng = np.random.default_rng(seed)
    J, L = 4, 3
    cost = 248 * rng.integers(1, 2000, size=(J, L))
    utility = 10.0 ** rng.uniform(-9, 9, size=(1, J, L))
    inst = Instance(representation="layered" if seed % 2 else "separate",
                    bandwidth=[int(rng.integers(0, cost.sum()))], cost=cost, utility=utility)
    ref = solve_brute_force(inst, slot=0)
    _check_exact(inst, solve_dp(inst), ref)
    _check_exact(inst, solve_bb(inst), ref)


@settings(max_examples=15, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6))
def test_dp_on_stiff_family_is_exact_or_refuses(seed: int) -> None:
    inst = mckp_instance(seed, "stiff", J=3, L=3)
    try:
        sol = solve_dp(inst)
    except SolveError as exc:
        assert "cells" in str(exc) and "limit" in str(exc)
        return
    _check_exact(inst, sol, solve_brute_force(inst, slot=0))


def test_dp_refuses_a_table_too_large() -> None:
    inst = Instance(representation="layered", bandwidth=[10**12], cost=[[10**9 + 7, 3]] * 5,
                    utility=np.ones((1, 5, 2)))
    with pytest.raises(SolveError, match=r"dp: the table would have .* cells, more than the limit"):
        solve_dp(inst)


def test_dp_divides_by_gcd() -> None:
    inst = Instance(representation="layered", bandwidth=[248 * 1000], cost=248 * np.array([[300, 400], [500, 600]]),
                    utility=np.array([[[3.0, 1.0], [4.0, 2.0]]]))
    sol = solve_dp(inst)
    assert sol.details["gcd"] == 248 * 100
    assert rel_close(sol.objective, solve_brute_force(inst, slot=0).objective)


# -- approximations and bounds ----------------------------------------------------------------

@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(("random", "ties", "held", "huge")),
       eps=st.sampled_from((0.5, 0.2, 0.05)))
def test_fptas_guarantee(seed: int, family: str, eps: float) -> None:
    inst = mckp_instance(seed, family, J=4, L=3)
    opt = solve_brute_force(inst, slot=0).objective
    sol = solve_fptas(inst, eps)
    assert is_feasible(inst, sol.arrivals, slot=0)
    assert sol.status is Status.FEASIBLE
    constant = slot_table(inst, 0)[1]
    # The guarantee is on the part the slot's choices add, above the held constant.
    assert sol.objective - constant >= (1 - eps) * (opt - constant) - 1e-9 * max(1.0, opt)
    assert sol.bound >= opt * (1 - 1e-12)


@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(FAMILIES))
def test_greedy_feasible_with_valid_bound(seed: int, family: str) -> None:
    inst = mckp_instance(seed, family, J=4, L=3)
    opt = solve_brute_force(inst, slot=0).objective
    sol = solve_greedy(inst)
    assert sol.status is Status.FEASIBLE
    assert is_feasible(inst, sol.arrivals, slot=0)
    assert sol.objective <= opt * (1 + 1e-12) + 1e-300
    assert sol.bound >= opt * (1 - 1e-12)
    constant = slot_table(inst, 0)[1]
    # LP-greedy with the break option tried alone: at least half the LP value.
    assert sol.objective - constant >= 0.5 * (sol.bound - constant) * (1 - 1e-9) - 1e-300


def test_fptas_rejects_bad_eps() -> None:
    inst = mckp_instance(0, "random")
    with pytest.raises(SolveError, match=r"fptas: eps = 1.5: must be in \(0, 1\)"):
        solve_fptas(inst, 1.5)
    with pytest.raises(SolveError, match=r"EPS = 'x' must be a number"):
        l3gs_opt.solve(inst, method="fptas:x")


def test_bb_time_limit_keeps_a_valid_bound() -> None:
    # A strongly correlated instance the exact search cannot finish in 1 ms.
    rng = np.random.default_rng(0)
    J, L = 300, 6
    wp = np.sort(rng.integers(1, 1001, size=(J, L)), axis=1)
    cost, profit = np.cumsum(wp, axis=1), np.cumsum(wp + 10, axis=1)
    inst = Instance(representation="separate", bandwidth=[int(0.5 * (cost.min(1) + cost.max(1)).sum())],
                    cost=cost, utility=profit[None].astype(float))
    quick = solve_bb(inst, time_limit_s=1e-3)
    full = solve_bb(inst)
    assert full.status is Status.OPTIMAL
    assert quick.status in (Status.TIME_LIMIT, Status.OPTIMAL)
    assert is_feasible(inst, quick.arrivals, slot=0)
    assert quick.bound >= full.objective * (1 - 1e-12)
    assert quick.objective <= full.objective * (1 + 1e-12)


def test_bb_strongly_correlated_matches_ilp() -> None:
    rng = np.random.default_rng(3)
    J, L = 60, 5
    wp = np.sort(rng.integers(1, 1001, size=(J, L)), axis=1)
    cost, profit = np.cumsum(wp, axis=1), np.cumsum(wp + 10, axis=1)
    inst = Instance(representation="separate", bandwidth=[int(0.5 * (cost.min(1) + cost.max(1)).sum())],
                    cost=cost, utility=profit[None].astype(float))
    sol = solve_bb(inst)
    ilp = solve_ilp(inst, slot=0, backend="highs")
    assert sol.status is Status.OPTIMAL and ilp.status is Status.OPTIMAL
    assert sol.objective == ilp.objective   # integer utilities: exact


# -- slots and names --------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["bb", "dp", "greedy", "fptas:0.1"])
def test_single_slot_methods_need_a_slot_on_multi_slot_instances(method: str) -> None:
    inst = Instance(representation="layered", bandwidth=[5, 5], cost=[[2, 3]], utility=np.ones((2, 1, 2)))
    with pytest.raises(SolveError, match=r"solves one slot's MCKP: pass slot \(0..1\)"):
        l3gs_opt.solve(inst, method=method)
    with pytest.raises(SolveError, match=r"slot = 2: must be an integer in 0..1"):
        l3gs_opt.solve(inst, method=method, slot=2)
    sol = l3gs_opt.solve(inst, method=method, slot=1)
    assert sol.problem == "MCKP" and sol.slot == 1
    assert sol.arrivals == ((0, 0, 1), (0, 1, 1))


def test_single_slot_on_a_later_slot_uses_that_slots_utility_and_budget() -> None:
    utility = np.array([[[5.0, 0.0], [0.0, 0.0]], [[0.0, 0.0], [7.0, 0.0]]])
    inst = Instance(representation="layered", bandwidth=[3, 4], cost=[[3, 1], [4, 1]], utility=utility)
    for method in ("bb", "dp", "greedy"):
        sol = l3gs_opt.solve(inst, method=method, slot=1)
        assert sol.arrivals == ((1, 0, 1),)
        assert sol.objective == 7.0


def test_empty_and_all_held() -> None:
    inst = Instance(representation="layered", bandwidth=[10], cost=[[2, 3]], utility=[[[1.0, 2.0]]],
                    held=[[True, True]])
    for method in ("bb", "dp", "greedy", "fptas:0.5"):
        sol = l3gs_opt.solve(inst, method=method)
        assert sol.arrivals == () and sol.objective == 3.0
        if method in ("bb", "dp"):
            assert sol.status is Status.OPTIMAL


def test_large_l3gs_like_slot_bb_matches_dp() -> None:
    from l3gs_opt.synth import synth_instance

    inst = synth_instance(objects=400, layers=4, slots=1, seed=5, total_splats=400 * 180)
    inst = Instance(representation=inst.representation, bandwidth=[1_475_000], cost=inst.cost,
                    utility=inst.utility)
    bb, dp = solve_bb(inst), solve_dp(inst)
    assert bb.status is Status.OPTIMAL and dp.status is Status.OPTIMAL
    assert rel_close(bb.objective, dp.objective)


@pytest.mark.parametrize("path", ["direct", "envelope"])
@pytest.mark.parametrize("kind", ["strong", "weak", "l3gs"])
def test_bb_bound_paths_match_dp(monkeypatch, path: str, kind: str) -> None:
    # Both ways of bounding a stage's candidates (every multiplier, or the lower envelope of the
    # multiplier lines) must give the exact optimum; dp is the reference (integer costs fit).
    monkeypatch.setattr(_mckp, "_DIRECT_BOUND_CELLS", 10**12 if path == "direct" else 0)
    for seed in range(3):
        rng = np.random.default_rng(seed)
        if kind == "l3gs":
            from l3gs_opt.synth import synth_instance

            base = synth_instance(objects=150, layers=4, slots=1, seed=seed, total_splats=150 * 180)
            inst = Instance(representation="layered", bandwidth=[150_000 * 248 // 180], cost=base.cost,
                            utility=base.utility)
        else:
            J, L, R = 120, 6, 60
            if kind == "strong":
                wp = np.sort(rng.integers(1, R + 1, size=(J, L)), axis=1)
                cost, profit = np.cumsum(wp, axis=1), np.cumsum(wp + 5, axis=1)
            else:
                cost = rng.integers(1, R + 1, size=(J, L))
                profit = np.maximum(1, cost + rng.integers(-5, 6, size=(J, L)))
            inst = Instance(representation="separate", bandwidth=[int(0.5 * (cost.min(1) + cost.max(1)).sum())],
                            cost=cost, utility=profit[None] + rng.random((1, J, L)))
        bb, dp = solve_bb(inst), solve_dp(inst)
        assert bb.status is Status.OPTIMAL
        assert is_feasible(inst, bb.arrivals, slot=0)
        assert rel_close(bb.objective, dp.objective), (bb.objective, dp.objective, bb.details)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), family=st.sampled_from(("random", "ties", "held", "huge")),
       strict=st.booleans())
def test_bb_equals_dp_on_mid_size(seed: int, family: str, strict: bool) -> None:
    # Too large for brute force (J x L = 160 chunks); the DP is exact on these small integer costs.
    inst = mckp_instance(seed, family, J=40, L=4, same_slot_layers=not strict)
    bb, dp = solve_bb(inst), solve_dp(inst)
    assert bb.status is Status.OPTIMAL and dp.status is Status.OPTIMAL
    assert is_feasible(inst, bb.arrivals, slot=0)
    assert rel_close(bb.objective, dp.objective)
    assert bb.bound >= dp.objective * (1 - 1e-12)


@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), family=st.sampled_from(("random", "ties", "held")),
       eps=st.sampled_from((0.3, 0.1, 0.01)))
def test_fptas_guarantee_on_mid_size(seed: int, family: str, eps: float) -> None:
    inst = mckp_instance(seed, family, J=40, L=4)
    opt = solve_dp(inst).objective
    constant = slot_table(inst, 0)[1]
    sol = solve_fptas(inst, eps)
    assert is_feasible(inst, sol.arrivals, slot=0)
    assert sol.objective - constant >= (1 - eps) * (opt - constant) - 1e-9 * max(1.0, opt)
    assert sol.bound >= opt * (1 - 1e-12)
