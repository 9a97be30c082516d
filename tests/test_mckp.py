"""Single-slot MCKP methods (bb, dp, fptas:EPS, greedy) against brute force and the core's ILP.

Tolerances: objectives are float64 sums of the same utilities in different orders, so exact
solvers must agree to ``rtol=1e-9`` (``GAP_TOL``, the gap that counts as proven optimal).
"""

from __future__ import annotations

import re
import warnings
from unittest import mock

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import l3gs_opt
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.evaluate import is_feasible
from l3gs_opt.problem.instance import Instance
from l3gs_opt.models import build_model, solve_ilp, solve_model
from l3gs_opt.problem.presolve import mckp_options
from l3gs_opt.problem.solution import Status
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


@SETTINGS
@given(seed=st.integers(0, 10**6), family=st.sampled_from(("random", "ties", "held", "huge")),
       eps=st.sampled_from((1e-300, 1e-100, 1e-30, 1e-12)))
def test_fptas_with_a_tiny_eps_keeps_its_guarantee_or_refuses(seed: int, family: str, eps: float) -> None:
    # Regression: scaled profits beyond int64 were cast to garbage, and the answer fell below the
    # guarantee (rolling:fptas:1e-300 scored below rolling:fptas:0.1), with only numpy's warning.
    inst = mckp_instance(seed, family, J=4, L=3)
    opt = solve_brute_force(inst, slot=0).objective
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            sol = solve_fptas(inst, eps)
        except SolveError as exc:
            assert re.match(r"fptas: the table would have \d+ rows x .* cells, more than the limit", str(exc))
            return
    constant = slot_table(inst, 0)[1]
    assert is_feasible(inst, sol.arrivals, slot=0)
    assert sol.objective - constant >= (1 - eps) * (opt - constant) - 1e-9 * max(1.0, opt)
    assert sol.bound >= opt * (1 - 1e-12)


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
    from l3gs_opt.pipeline.synth import synth_instance

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
            from l3gs_opt.pipeline.synth import synth_instance

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


# -- strongly correlated classes: the integral cut and the compiled stage -----------------------

#: The compiled stage kernel needs numba (a declared dependency, but optional at run time).
needs_numba = pytest.mark.skipif(_mckp.compiled_kernels() is None, reason="numba is not installed")


def _strong_instance(seed: int, J: int, L: int, *, R: int = 1000, fractional: bool = False) -> Instance:
    """Pisinger's strongly correlated MCKP class as ``benchmarks/bench_solvers.py`` builds it:
    per object sorted ``w' ~ U[1, R]``, ``p' = w' + 10``, cumulative sums; budget half of
    ``sum_j (min_l w + max_l w)``. ``fractional`` adds ``U[0, 1)`` to the utilities (then the
    integral cut must stay off)."""
    rng = np.random.default_rng(seed)
    wp = np.sort(rng.integers(1, R + 1, size=(J, L)), axis=1)
    cost, profit = np.cumsum(wp, axis=1), np.cumsum(wp + 10, axis=1).astype(np.float64)
    if fractional:
        profit = profit + rng.random((J, L))
    return Instance(representation="separate", bandwidth=[int(0.5 * (cost.min(1) + cost.max(1)).sum())],
                    cost=cost, utility=profit[None])


def _check_table_result(table: _mckp.OptionTable, res: _mckp.MckpResult, opt: float) -> None:
    """Feasible in exact bytes, value recomputed from the choice, bound at least the optimum."""
    used, value = _mckp._pick(table, res.choice)
    assert used <= table.budget
    assert value == res.value
    assert res.bound >= opt * (1 - 1e-12)


@SETTINGS
@given(seed=st.integers(0, 10**6), J=st.integers(1, 5), L=st.integers(1, 3), R=st.sampled_from((5, 40, 1000)),
       compiled=st.booleans(), fractional=st.booleans(), switch=st.booleans())
def test_bb_strongly_correlated_equals_brute_force(seed: int, J: int, L: int, R: int, compiled: bool,
                                                   fractional: bool, switch: bool) -> None:
    inst = _strong_instance(seed, J, L, R=R, fractional=fractional)
    table, constant = slot_table(inst, 0)
    # switch: the one-switch completion after every stage, not only on large DPs.
    with mock.patch.object(_mckp, "_SWITCH_MIN_STATES", 0 if switch else _mckp._SWITCH_MIN_STATES):
        res = _mckp.branch_and_bound(table, compiled=compiled)
    ref = solve_brute_force(inst, slot=0).objective
    assert res.optimal
    assert res.stats.get("integral", not fractional) is not fractional
    _check_table_result(table, res, ref - constant)
    assert rel_close(res.value + constant, ref)


@pytest.mark.parametrize("fractional", [False, True])
def test_bb_strongly_correlated_mid_size_paths_agree_with_dp(monkeypatch, fractional: bool) -> None:
    # The integral cut, the one-switch completion and the compiled stage against the plain path
    # (numpy stages, cut at z, completion by the LP choices only: bb as it was before them) and
    # the DP (exact; R = 60 keeps its table small).
    ran_compiled = 0
    for seed in range(3):
        inst = _strong_instance(seed, 120, 6, R=60, fractional=fractional)
        table, constant = slot_table(inst, 0)
        ref = _mckp.dynamic_programme(table).value
        results = {compiled: _mckp.branch_and_bound(table, compiled=compiled) for compiled in (None, True, False)}
        with monkeypatch.context() as mp:
            mp.setattr(_mckp, "_integral_values", lambda *_: False)
            mp.setattr(_mckp, "_SWITCH_MIN_STATES", 10**18)
            results["plain"] = _mckp.branch_and_bound(table, compiled=False)
        for name, res in results.items():
            assert res.optimal, name
            _check_table_result(table, res, ref)
            if fractional:
                assert rel_close(res.value, ref), (name, res.value, ref)
            else:
                assert res.value == ref, (name, res.value, ref)    # integer utilities: exact
        assert results[True].stats["integral"] is not fractional
        assert results[False].stats.get("compiled_stages", 0) == 0
        ran_compiled += results[True].stats.get("compiled_stages", 0)
    if _mckp.compiled_kernels() is not None:
        assert ran_compiled > 0      # the DP did run, so the kernel was exercised


@settings(max_examples=30, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), spread=st.sampled_from((0, 1, 3)))
def test_bb_weakly_correlated_ties_equal_dp(seed: int, spread: int) -> None:
    # p = w + U[-spread, spread]: many options of reduced profit exactly 0 at the break slope 1,
    # an LP optimum that is often integral, and bounds that tie with the incumbent + 1.
    rng = np.random.default_rng(seed)
    J, L = 40, 5
    cost = rng.integers(1, 31, size=(J, L))
    profit = np.maximum(1, cost + rng.integers(-spread, spread + 1, size=(J, L)))
    inst = Instance(representation="separate", bandwidth=[int(0.5 * (cost.min(1) + cost.max(1)).sum())],
                    cost=cost, utility=profit[None].astype(np.float64))
    table, _ = slot_table(inst, 0)
    ref = _mckp.dynamic_programme(table).value
    for compiled, switch_min in ((False, _mckp._SWITCH_MIN_STATES), (True, _mckp._SWITCH_MIN_STATES), (False, 0)):
        with mock.patch.object(_mckp, "_SWITCH_MIN_STATES", switch_min):
            res = _mckp.branch_and_bound(table, compiled=compiled)
        assert res.optimal
        _check_table_result(table, res, ref)
        assert res.value == ref


def test_integral_values_detection() -> None:
    def table(values, budget=10):
        values = np.asarray(values, dtype=np.float64)
        n, K = values.shape
        return _mckp.OptionTable(rows=np.arange(n), cost=np.tile(np.arange(1, K + 1), (n, 1)), value=values,
                                 valid=np.ones((n, K), bool), level=np.tile(np.arange(K), (n, 1)), budget=budget)

    assert _mckp._integral_values(table([[1.0, 3.0], [2.0, 5.0]]), 1e-9)
    assert not _mckp._integral_values(table([[1.0, 3.5], [2.0, 5.0]]), 1e-9)
    # Sums of the values must be exact in float64 ...
    assert not _mckp._integral_values(table([[2.0 ** 51, 2.0 ** 52], [1.0, 2.0]]), 1e-9)
    # ... and the bound's round-off well under one unit.
    assert not _mckp._integral_values(table([[1.0, 3.0], [2.0, 5.0]]), 0.3)


@pytest.mark.parametrize("compiled", [False, True])
def test_bb_state_cap_and_time_limit_keep_a_valid_bound(compiled: bool) -> None:
    inst = _strong_instance(0, 300, 6)
    table, _ = slot_table(inst, 0)
    full = _mckp.branch_and_bound(table, compiled=compiled)
    assert full.optimal
    for kwargs in ({"max_states": 50}, {"time_limit_s": 1e-3}):
        res = _mckp.branch_and_bound(table, compiled=compiled, **kwargs)
        assert not res.optimal and res.stats["stopped"]
        _check_table_result(table, res, full.value)
        assert res.value <= full.value


# -- the compiled stage kernel mirrors the numpy stage ----------------------------------------

def _random_stage(seed: int, m: int, k: int, q: int, integral: bool) -> tuple:
    """Inputs of one DP stage as branch_and_bound makes them: ``m`` Pareto states, ``k`` options
    of a row (any order: "none", cost 0, comes last), the Lagrangian lines of ``q`` multipliers
    of some rows still to add, and a cut at the 40th percentile of the candidates' bounds."""
    rng = np.random.default_rng(seed)
    W = np.cumsum(rng.integers(1, 20, size=m)).astype(np.int64)
    steps = rng.integers(1, 30, size=m).astype(np.float64) if integral else rng.random(m) * 30 + 1e-3
    P = np.cumsum(steps)
    c = rng.integers(0, 200, size=k).astype(np.int64)
    v = (c + rng.integers(-5, 40, size=k)).astype(np.float64) if integral else c * 1.1 + rng.random(k) * 20 - 5
    lams = np.unique(rng.random(q) * 2)
    rc, rv = rng.integers(1, 100, size=(25, 4)), rng.random((25, 4)) * 120
    F = np.maximum(0.0, (rv[:, :, None] - rc[:, :, None] * lams).max(axis=1)).sum(axis=0)
    budget = int(W[-1] if m else 0) + int(rng.integers(0, 300))
    cap = budget - int(rng.integers(0, 100))
    d = (budget - (W[None, :] + c[:, None])).astype(np.float64)
    ub = (P[None, :] + v[:, None]) + (F[None, None, :] + d[:, :, None] * lams[None, None, :]).min(axis=2)
    cut = float(np.quantile(ub, 0.4)) if ub.size else 0.0
    opt_ids = rng.permutation(20)[:k].astype(np.uint8)       # the options' columns in the table
    return W, P, c, v, budget, cap, F, lams, cut, opt_ids


@needs_numba
@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), m=st.integers(0, 400), k=st.integers(1, 7), q=st.integers(1, 9),
       integral=st.booleans())
def test_compiled_stage_equals_numpy_stage(seed: int, m: int, k: int, q: int, integral: bool) -> None:
    args = _random_stage(seed, m, k, q, integral)
    kern = _mckp.compiled_kernels().stage(*args)
    # The kernel mirrors the numpy stage's envelope path (the direct path takes the minimum
    # over the multipliers in another order, which may differ in the last ulp).
    with mock.patch.object(_mckp, "_DIRECT_BOUND_CELLS", 0):
        ref = _mckp._stage_numpy(*args)
    for name, a, b in zip(("W", "P", "parent", "pick"), kern[:4], ref[:4]):
        assert np.array_equal(a, b) and a.dtype == b.dtype, name
    assert kern[4] == ref[4]


@needs_numba
@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), m=st.integers(1, 150), k=st.integers(1, 5), integral=st.booleans())
def test_compiled_stage_equals_its_definition(seed: int, m: int, k: int, integral: bool) -> None:
    # Independent of both implementations: every candidate (state + option) that fits ``cap`` and
    # whose bound (the minimum over the multipliers' lines) exceeds the cut, then the ones no
    # other candidate dominates (no more bytes and more value, or fewer bytes and as much).
    W, P, c, v, budget, cap, F, lams, cut, ids = args = _random_stage(seed, m, k, 5, integral)
    cw = (W[None, :] + c[:, None]).ravel()
    cp = (P[None, :] + v[:, None]).ravel()
    ub = cp + (F[None, :] + (budget - cw)[:, None].astype(np.float64) * lams[None, :]).min(axis=1)
    fits = cw <= cap
    # Skip examples whose bounds tie the cut to round-off (the two orders of evaluation may differ).
    assume(not (fits & np.isclose(ub, cut, rtol=1e-12, atol=1e-9)).any())
    live = fits & (ub > cut)
    lw, lp = cw[live], cp[live]
    dominated = (((lw[None, :] <= lw[:, None]) & (lp[None, :] > lp[:, None]))
                 | ((lw[None, :] < lw[:, None]) & (lp[None, :] >= lp[:, None]))).any(axis=1)
    expected = sorted(set(zip(lw[~dominated].tolist(), lp[~dominated].tolist())))
    nW, nP, parent, pick, dead = _mckp.compiled_kernels().stage(*args)
    assert list(zip(nW.tolist(), nP.tolist())) == expected
    # Each state is its parent plus its option, exactly.
    assert set(pick.tolist()) <= set(ids.tolist())
    pos = np.argsort(ids)[np.searchsorted(np.sort(ids), pick)]
    assert np.array_equal(nW, W[parent] + c[pos]) and np.array_equal(nP, P[parent] + v[pos])
    cut_ub = ub[fits & ~live]
    assert dead == (cut_ub.max() if cut_ub.size else -np.inf) or np.isclose(dead, cut_ub.max(), rtol=1e-12)


@needs_numba
@settings(max_examples=60, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), q=st.integers(1, 12), ties=st.booleans())
def test_compiled_envelope_equals_numpy_envelope(seed: int, q: int, ties: bool) -> None:
    rng = np.random.default_rng(seed)
    b = np.sort(rng.integers(0, 4, size=q).astype(float) if ties else rng.random(q) * 3)
    a = rng.random(q) * 10 if not ties else rng.integers(0, 5, size=q).astype(float)
    ref = _mckp._envelope(a, b)
    out = _mckp.compiled_kernels().envelope(a, b)
    for x, y in zip(out, ref):
        assert np.array_equal(x, y)
    # The envelope is the minimum of the lines at every x >= 0 (checked on a grid).
    x = np.linspace(0, 20, 101)
    piece = np.searchsorted(ref[2], x, side="right") - 1
    assert np.allclose(ref[0][piece] + ref[1][piece] * x, (a[None, :] + b[None, :] * x[:, None]).min(axis=1))


@needs_numba
def test_compiled_stage_with_every_option_cut_returns_no_state() -> None:
    # Regression: a row whose options the incumbent had all removed reached the kernel with no
    # option and read past its arrays (a segfault on the weakly correlated J=10,000 instances).
    W, P = np.array([0, 5], np.int64), np.array([0.0, 2.0])
    out = _mckp.compiled_kernels().stage(W, P, np.zeros(0, np.int64), np.zeros(0), 10, 10, np.array([1.0]),
                                         np.array([0.5]), 0.0, np.zeros(0, np.uint8))
    assert all(len(a) == 0 for a in out[:4]) and out[4] == -np.inf


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), m=st.integers(1, 30), n_rest=st.integers(1, 6))
def test_switch_completion_is_the_best_single_move(seed: int, m: int, n_rest: int) -> None:
    # Against enumeration of every (state, rest row, other allowed option) triple.
    rng = np.random.default_rng(seed)
    K = 3
    n = n_rest + 2
    costs_ext = np.concatenate([np.sort(rng.integers(1, 40, size=(n, K)), axis=1), np.zeros((n, 1), np.int64)], 1)
    vals_ext = np.concatenate([np.sort(rng.integers(1, 60, size=(n, K)), axis=1).astype(float), np.zeros((n, 1))], 1)
    allowed = rng.random((n, K + 1)) < 0.7
    a_idx = rng.integers(0, K + 1, size=n)
    allowed[np.arange(n), a_idx] = True
    a_cost, a_val = costs_ext[np.arange(n), a_idx], vals_ext[np.arange(n), a_idx]
    rest = np.sort(rng.choice(n, size=n_rest, replace=False))
    W = np.cumsum(rng.integers(1, 10, size=m)).astype(np.int64)
    P = np.cumsum(rng.integers(1, 12, size=m)).astype(float)
    spare0, comp_v = int(rng.integers(0, 120)), 7.0
    best = None
    for k in range(m):
        for i in rest:
            for o in np.nonzero(allowed[i])[0]:
                if o == a_idx[i] or costs_ext[i, o] - a_cost[i] > spare0 - W[k]:
                    continue
                value = P[k] + comp_v + vals_ext[i, o] - a_val[i]
                if best is None or value > best:
                    best = value
    found = _mckp._switch_completion(W, P, rest, allowed, costs_ext, vals_ext, a_idx, a_cost, a_val, spare0, comp_v)
    if best is None:
        assert found is None
        return
    value, k, i, o = found
    assert value == best
    # The move it names is one of the rest, allowed, not the LP choice, fits, and is worth that.
    assert i in rest and allowed[i, o] and o != a_idx[i]
    assert costs_ext[i, o] - a_cost[i] <= spare0 - W[k]
    assert P[k] + comp_v + vals_ext[i, o] - a_val[i] == value
