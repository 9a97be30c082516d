"""``exact`` under the cumulative budget (solvers/exact/cumulative*.py): against brute force,
``link-dp`` and the ILP; the arrived-by Lagrangian bound for any multipliers; reduced-cost fixing
keeps every better schedule; stiff cases and time limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core_helpers import ALL_OPTIONS, option_id, random_instance
from solver_helpers import check_answer
from l3gs_opt import Instance, Options, solve
from l3gs_opt.problem.evaluate import evaluate_objective, is_feasible
from l3gs_opt.problem.solution import Status
from l3gs_opt.solvers.brute_force import solve_brute_force
from l3gs_opt.solvers.exact.cumulative import _lp_duals, lp_order, solve_cumulative
from l3gs_opt.solvers.exact.cumulative_data import (LinkMultipliers, Windows, fix_windows, link_data,
                                                    link_lagrangian, schedule_feasible)
from l3gs_opt.solvers.exact.lagrange import assignment_value

CUMULATIVE = [o for o in ALL_OPTIONS if o.budget == "cumulative"]
SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def close(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-9 * max(abs(a), abs(b), 1.0)


_check = check_answer


@pytest.mark.parametrize("opts", CUMULATIVE, ids=option_id)
@pytest.mark.parametrize("seed", range(8))
def test_equals_brute_force(opts: Options, seed: int) -> None:
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=4, J=2, L=2, options=opts, held_p=0.4 if seed % 2 else 0.0)
    ref = solve_brute_force(inst)
    sol = solve(inst, "exact")
    _check(inst, sol)
    assert sol.status is Status.OPTIMAL
    assert close(sol.objective, ref.objective)


@pytest.mark.parametrize("seed", range(6))
def test_equals_link_dp_and_the_ilp(seed: int) -> None:
    """Larger than brute force: ``link-dp`` (same-slot layers) and HiGHS on the standard model."""
    rng = np.random.default_rng(500 + seed)
    opts = CUMULATIVE[seed % 4]
    inst = random_instance(rng, T=8, J=4, L=3, options=opts, held_p=0.3 if seed % 3 == 0 else 0.0, tight=0.3)
    ref = solve(inst, "ilp")
    assert ref.status is Status.OPTIMAL
    sol = solve(inst, "exact")
    _check(inst, sol)
    assert sol.status is Status.OPTIMAL and close(sol.objective, ref.objective)
    if opts.same_slot_layers:
        assert close(solve(inst, "link-dp").objective, ref.objective)


def _multipliers(data, rng, scale: float) -> LinkMultipliers:
    return LinkMultipliers(rng.random((data.n, data.T)) * scale, rng.random((data.n, data.T)) * scale)


@settings(max_examples=40, **SETTINGS)
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), scale=st.sampled_from([0.0, 0.1, 1.0, 10.0]))
def test_lagrangian_bounds_the_optimum_at_any_multipliers(seed: int, opt: int, scale: float) -> None:
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=4, J=2, L=2, options=CUMULATIVE[opt], held_p=0.3)
    best = solve_brute_force(inst).objective
    data = link_data(inst)
    lv = link_lagrangian(data, _multipliers(data, rng, scale))
    assert lv.bound >= best - 1e-12 * max(1.0, abs(best))


@pytest.mark.parametrize("seed", range(6))
def test_lagrangian_at_the_lp_duals_lies_between_the_optimum_and_the_lp(seed: int) -> None:
    """Integer knapsacks at the LP's own duals: never above the LP value (a dual sign slip would
    put it above), never below the optimum."""
    rng = np.random.default_rng(700 + seed)
    inst = random_instance(rng, T=8, J=4, L=3, options=CUMULATIVE[seed % 4], tight=0.3)
    best = solve(inst, "ilp").objective
    data = link_data(inst)
    windows = Windows(data.first.copy(), np.full(data.n, data.T), closed=False)
    lp_value, mult, z = _lp_duals(data, windows, None)
    lv = link_lagrangian(data, mult)
    assert best - 1e-9 * abs(best) <= lv.bound <= lp_value + 1e-7 * max(1.0, abs(lp_value))
    order = lp_order(data, z)
    assert schedule_feasible(data, order)
    assert is_feasible(inst, data.arrivals(order))
    assert close(assignment_value(data, order), evaluate_objective(inst, data.arrivals(order)))


@settings(max_examples=40, **SETTINGS)
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), scale=st.sampled_from([0.0, 0.5, 5.0]),
       below=st.sampled_from([1e-6, 0.05, 0.5]))
def test_fixing_keeps_the_optimum_when_the_incumbent_is_worse(seed: int, opt: int, scale: float,
                                                              below: float) -> None:
    """Every schedule better than the incumbent lies in the windows: the brute-force optimum does
    whenever the incumbent is below it (and the windows are never empty then)."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=4, J=2, L=2, options=CUMULATIVE[opt], held_p=0.3, tight=0.4)
    ref = solve_brute_force(inst)
    data = link_data(inst)
    assign = data.assignment(ref.arrivals)
    assert schedule_feasible(data, assign)
    lv = link_lagrangian(data, _multipliers(data, rng, scale))
    incumbent = ref.objective - below * max(1.0, abs(ref.objective))
    w = fix_windows(data, lv, incumbent)
    assert not w.closed
    on = assign >= 0
    assert (assign[on] >= w.first[on]).all()
    assert ((assign >= 0) & (assign <= w.by) | (w.by >= data.T)).all()


@settings(max_examples=25, **SETTINGS)
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3))
def test_signed_utilities_equal_brute_force(seed: int, opt: int) -> None:
    rng = np.random.default_rng(seed)
    T, J, L = 3, 2, 2
    cost = rng.integers(1, 7, (J, L))
    inst = Instance("layered", bandwidth=rng.integers(0, int(0.6 * cost.sum()) + 1, T), cost=cost,
                    utility=rng.integers(-6, 9, (T, J, L)) / 4.0, options=CUMULATIVE[opt])
    ref = solve_brute_force(inst)
    sol = solve(inst, "exact")
    _check(inst, sol)
    assert sol.status is Status.OPTIMAL and math.isclose(sol.objective, ref.objective, abs_tol=1e-9)


STIFF = {
    "zero_bandwidth": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)), utility=rng.random((4, 3, 2)),
                                       bandwidth=np.zeros(4, dtype=np.int64)),
    "bandwidth_late": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)), utility=rng.random((4, 3, 2)),
                                       bandwidth=[0, 0, 0, 40]),
    "huge_bytes": lambda rng: dict(cost=rng.integers(10**11, 10**12, (3, 2)), utility=rng.random((4, 3, 2)),
                                   bandwidth=np.full(4, 10**12)),
    "tiny_utilities": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)), utility=rng.random((4, 3, 2)) * 1e-12,
                                       bandwidth=np.full(4, 6)),
    "empty_scene": lambda rng: dict(cost=np.zeros((0, 2), dtype=np.int64), utility=np.zeros((4, 0, 2)),
                                    bandwidth=np.full(4, 5)),
    "one_slot": lambda rng: dict(cost=rng.integers(1, 9, (3, 2)), utility=rng.random((1, 3, 2)), bandwidth=[7]),
}


@pytest.mark.parametrize("case", sorted(STIFF))
def test_stiff_cases(case: str) -> None:
    rng = np.random.default_rng(3)
    inst = Instance("layered", **STIFF[case](rng), options=Options(budget="cumulative"))
    sol = solve(inst, "exact")
    _check(inst, sol)
    assert sol.status is Status.OPTIMAL
    assert close(sol.objective, solve_brute_force(inst).objective)


def test_all_held() -> None:
    rng = np.random.default_rng(4)
    inst = Instance("layered", bandwidth=[5, 5], cost=rng.integers(1, 5, (2, 2)), utility=rng.random((2, 2, 2)),
                    held=np.ones((2, 2), bool), options=Options(budget="cumulative"))
    sol = solve(inst, "exact")
    assert sol.status is Status.OPTIMAL and sol.arrivals == ()


@pytest.fixture(scope="module")
def mid_instance():
    """16 objects x 4 layers x 40 slots: ``exact`` proves it in a few seconds where HiGHS on the
    standard model does not in 60 s; its optimum is checked against HiGHS's own bound."""
    from l3gs_opt.pipeline.synth import synth_instance

    inst = synth_instance(objects=16, layers=4, slots=40, seed=2).replace(options=Options(budget="cumulative"))
    ref = solve(inst, "exact", time_limit_s=120)
    _check(inst, ref)
    assert ref.status is Status.OPTIMAL
    ilp = solve(inst, "ilp", time_limit_s=10)
    assert ilp.objective <= ref.objective * (1 + 1e-9) and ilp.bound >= ref.objective * (1 - 1e-9)
    return inst, ref.objective


@pytest.mark.parametrize("limit_s", [0.3, 1.5, 4.0])
def test_time_limit_returns_valid_bound_and_feasible_schedule(mid_instance, limit_s: float) -> None:
    inst, best = mid_instance
    sol = solve(inst, "exact", time_limit_s=limit_s)
    _check(inst, sol)
    assert sol.status in (Status.TIME_LIMIT, Status.OPTIMAL)
    assert sol.bound >= best * (1 - 1e-9) and sol.objective <= best * (1 + 1e-9)
    if sol.status is Status.OPTIMAL:
        assert close(sol.objective, best)
    else:
        assert sol.runtime_s < limit_s + 2.0
    # Every trace point is a valid (schedule, bound) pair, and the trace only improves (the raced
    # HiGHS runs report their own dual bounds; the trace keeps the smallest so far).
    trace = np.array(sol.details["trace"], dtype=np.float64)
    assert len(trace) and (np.diff(trace[:, 0]) >= 0).all()
    assert (trace[:, 1] <= best * (1 + 1e-9)).all() and (trace[:, 2] >= best * (1 - 1e-9)).all()
    # (the first points' bound is inf: compare neighbours, not differences)
    assert (trace[1:, 1] >= trace[:-1, 1] - 1e-9 * best).all() and (trace[1:, 2] <= trace[:-1, 2] + 1e-9 * best).all()


def test_start_heuristics_option_and_no_start() -> None:
    rng = np.random.default_rng(9)
    inst = random_instance(rng, T=6, J=3, L=3, options=Options(budget="cumulative"), tight=0.3)
    ref = solve(inst, "ilp").objective
    for heuristics in ((), ("slope",)):
        sol = solve_cumulative(inst, heuristics=heuristics)
        _check(inst, sol)
        assert sol.status is Status.OPTIMAL and close(sol.objective, ref)


def test_rejects_slot_and_unknown_branching_and_start() -> None:
    from l3gs_opt.errors import SolveError

    inst = random_instance(np.random.default_rng(0), options=Options(budget="cumulative"))
    with pytest.raises(SolveError, match="slot does not apply"):
        solve(inst, "exact", slot=0)
    with pytest.raises(SolveError, match="branching"):
        solve(inst, "exact", options={"branching": "dfs"})
    with pytest.raises(SolveError, match="start heuristic"):
        solve(inst, "exact", options={"heuristics": ["nope"]})


@settings(max_examples=40, **SETTINGS)
@given(seed=st.integers(0, 10_000), next_slot=st.booleans(), held=st.booleans())
def test_order_search_keeps_schedules_feasible_and_never_loses(seed: int, next_slot: bool, held: bool) -> None:
    """From any feasible schedule (a heuristic's, brute force's optimum): a feasible schedule,
    never worse with utilities >= 0, and the optimum stays optimal."""
    from l3gs_opt.solvers.exact.cumulative_order import improve_order

    rng = np.random.default_rng(seed)
    opts = Options(budget="cumulative", availability="next_slot" if next_slot else "same_slot")
    inst = random_instance(rng, T=4, J=3, L=2, options=opts, held_p=0.4 if held else 0.0, tight=0.4)
    data = link_data(inst)
    ref = solve_brute_force(inst)
    for start in (data.assignment(solve(inst, "static").arrivals), data.assignment(ref.arrivals),
                  np.full(data.n, -1, dtype=np.int64)):
        out = improve_order(data, start)
        assert schedule_feasible(data, out) and is_feasible(inst, data.arrivals(out))
        assert assignment_value(data, out) >= assignment_value(data, start) - 1e-12
        assert assignment_value(data, out) <= ref.objective + 1e-9


def test_order_search_leaves_strict_layers_alone() -> None:
    from l3gs_opt.solvers.exact.cumulative_order import improve_order

    inst = random_instance(np.random.default_rng(2), T=4, J=3, L=2,
                           options=Options(budget="cumulative", same_slot_layers=False))
    data = link_data(inst)
    start = data.assignment(solve(inst, "static").arrivals)
    assert (improve_order(data, start) == start).all()


def test_polyak_step_halves_after_five_stalls_and_is_spent_below_its_floor() -> None:
    """The step both Lagrangians share: Polyak's size, theta halved after 5 iterations without a
    better bound (a better one resets the count), spent below 1e-4 (after 14 halvings)."""
    from l3gs_opt.solvers.exact.lagrange import PolyakStep

    step = PolyakStep()
    assert step.size(10.0, 6.0, 2.0) == 2.0
    for _ in range(4):
        assert step.record(False)
    assert step.record(True) and step.theta == 1.0
    records = [step.record(False) for _ in range(5 * 14)]
    assert all(records[:-1]) and not records[-1] and step.theta == 0.5 ** 14


def _solve_model(lp) -> float | None:
    """Minus the optimum of a HiGHS model (None: infeasible)."""
    import highspy

    if lp.num_col_ == 0:
        return 0.0
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    h.passModel(lp)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        return None
    return -float(h.getInfo().objective_function_value)


@pytest.mark.parametrize("opts", CUMULATIVE, ids=option_id)
@pytest.mark.parametrize("seed", range(6))
def test_arrivals_on_event_slots_keep_the_optimum(opts: Options, seed: int) -> None:
    """The arrived-by MIP with arrivals only in presolve's event slots has brute force's optimum
    (utilities with zeros in half the (slot, object, layer) entries, so layers of one object
    differ), and its LP has the value of the LP with a column in every slot."""
    from l3gs_opt.solvers.exact.cumulative import arrived_by_model

    rng = np.random.default_rng(900 + seed)
    inst = random_instance(rng, T=5, J=2, L=3, options=opts, held_p=0.3 if seed % 2 else 0.0, zero_p=0.5, tight=0.4)
    data = link_data(inst)
    ref = solve_brute_force(inst).objective
    full = Windows(data.first.copy(), np.full(data.n, data.T, dtype=np.int64), closed=False)
    events = data.allowed
    lp, var, _ = arrived_by_model(data, full, relax=False, events=events)
    assert lp.num_col_ == int((events & (np.arange(data.T)[None, :] >= data.first[:, None])).sum())
    assert close(data.constant + _solve_model(lp), ref)
    relaxed = [_solve_model(arrived_by_model(data, full, relax=True, events=e)[0]) for e in (None, events)]
    assert abs(relaxed[0] - relaxed[1]) <= 1e-7 * max(1.0, abs(relaxed[0]))


@settings(max_examples=150, **SETTINGS)
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), zero_p=st.sampled_from([0.0, 0.3, 0.7]))
def test_delaying_arrivals_to_event_slots_keeps_value_and_feasibility(seed: int, opt: int, zero_p: float) -> None:
    """Any feasible schedule (random send order, each chunk in the first slot the link allows),
    normalised: still feasible in exact bytes, every arrival in an event slot, the same value
    (summed independently by ``evaluate_objective``)."""
    from l3gs_opt.solvers.exact.lagrange import into_presolve_slots

    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=6, J=3, L=3, options=CUMULATIVE[opt], held_p=0.3 if seed % 2 else 0.0,
                           zero_p=zero_p, tight=0.5)
    data = link_data(inst)
    assign = lp_order(data, (rng.random((data.n, 1)) * np.ones((1, data.T)) > 0.3).astype(float)
                      * (np.arange(data.T)[None, :] >= rng.integers(0, data.T, size=(data.n, 1))))
    assert schedule_feasible(data, assign)
    out = into_presolve_slots(data, assign, wait=True)
    assert schedule_feasible(data, out) and is_feasible(inst, data.arrivals(out))
    on = out >= 0
    assert data.allowed[np.nonzero(on)[0], out[on]].all()
    assert ((out >= assign) | (out < 0)).all() and ((assign >= 0) | (out < 0)).all()
    a, b = evaluate_objective(inst, data.arrivals(assign)), evaluate_objective(inst, data.arrivals(out))
    assert abs(a - b) <= 1e-9 * max(1.0, abs(a))


def test_windows_on_events_close_when_a_needed_chunk_has_no_event_slot() -> None:
    from l3gs_opt.solvers.exact.cumulative_data import windows_on_events

    events = np.array([[False, True, False, True], [False, False, False, False]])
    w = windows_on_events(Windows(np.array([0, 0]), np.array([4, 4]), closed=False), events)
    assert w.first.tolist() == [1, 4] and not w.closed
    w = windows_on_events(Windows(np.array([2, 0]), np.array([2, 4]), closed=False), events)
    assert w.closed   # chunk 0 must arrive by slot 2, and slot 3 is its first event slot from 2
    w = windows_on_events(Windows(np.array([0, 0]), np.array([2, 4]), closed=False), events)
    assert not w.closed and w.by.tolist() == [1, 4]


@pytest.mark.parametrize("opts", CUMULATIVE, ids=option_id)
@pytest.mark.parametrize("seed", range(6))
def test_presolve_event_slots_keep_every_method_at_brute_force(opts: Options, seed: int) -> None:
    """The standard ILP (HiGHS) and brute force without presolve agree with ``exact``; presolve
    left out pairs (utilities with zeros in half the entries)."""
    from l3gs_opt.problem.presolve import presolve

    rng = np.random.default_rng(1200 + seed)
    inst = random_instance(rng, T=5, J=2, L=3, options=opts, held_p=0.3 if seed % 3 == 0 else 0.0, zero_p=0.5,
                           tight=0.4)
    red = presolve(inst)
    assert red.arrive.sum() < presolve(inst, enabled=False).arrive.sum()
    ref = solve_brute_force(inst).objective
    for method in ("ilp", "exact"):
        sol = solve(inst, method)
        _check(inst, sol)
        assert sol.status is Status.OPTIMAL and close(sol.objective, ref), method
