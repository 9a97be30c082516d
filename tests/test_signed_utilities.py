"""Signed layer utilities (issue 23, item 3): ``dU < 0`` in the layered form, every method.

The reference is brute force (``solvers/brute_force.py``): it enumerates every schedule and values
it from the definitions, with no assumption on signs. Every method ``solve`` offers is held to it
on small random layered instances with some negative ``dU`` (hypothesis, derandomised so a run is
repeatable), across the options each method accepts: exact methods equal it, heuristics are
feasible, never above it and never labelled optimal unless they reach it, bounds are at least
it. Utilities are multiples of 1/4 so every sum is exact in float64 and "equal" means equal up to
the re-evaluation's round-off. Hand-made cases pin presolve's signed rule (a negative layer kept
as a step to a better one, a trailing one dropped) and the validator's named errors.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3gs_opt import Instance, InstanceError, Options, Status, is_feasible, solve
from l3gs_opt.models import installed_backends
from l3gs_opt.problem.evaluate import evaluate_objective, trim_losing_layers
from l3gs_opt.problem.items import ItemInstanceError, items_from_instance
from l3gs_opt.problem.presolve import mckp_options, presolve
from l3gs_opt.solvers.registry import TABLE

ALL_OPTIONS = [Options(availability=a, same_slot_layers=s, budget=b)
               for a, s, b in itertools.product(("same_slot", "next_slot"), (True, False), ("per_slot", "cumulative"))]
#: Objectives are re-evaluated with math.fsum from multiples of 1/4: exact, so only a backend's own
#: numbers (bounds) carry round-off; this absorbs the LP bound's documented 1e-7 relative slack.
TOL = 1e-6
#: Brute force enumerates (T + 1) ** chunks schedules: keep each example well under a second.
MAX_SCHEDULES = 4_000

# Every family of the method table, by what it promises (a new family must be placed here).
EXACT_HORIZON = ("ilp", "exact", "link-dp", "brute")
HEURISTIC_HORIZON = ("mpc:2", "progressive", "slope", "static",
                     *(f"{kind}:{s}" for kind in ("rolling", "rolling-future")
                       for s in ("bb", "dp", "greedy", "fptas:0.1", "ilp")))
#: Heuristics of the per-slot budget only.
PER_SLOT_HEURISTIC = ("anneal",)
SLOT_EXACT = ("bb", "dp", "brute", "ilp")
SLOT_HEURISTIC = ("greedy", "fptas:0.1")
BOUNDS = ("lp",)


def _family(name: str) -> str:
    return name.split(":", 1)[0]


def test_every_method_family_is_covered():
    covered = {_family(m) for m in (*EXACT_HORIZON, *HEURISTIC_HORIZON, *PER_SLOT_HEURISTIC, *SLOT_EXACT, *SLOT_HEURISTIC, *BOUNDS)}
    assert covered == set(TABLE), set(TABLE) ^ covered


@st.composite
def signed_instances(draw, options: Options | None = None) -> Instance:
    """A layered instance with at least one negative ``dU`` and at most MAX_SCHEDULES schedules."""
    T = draw(st.integers(1, 3))
    J = draw(st.integers(1, 2))
    L = draw(st.integers(1, 3))
    held_levels = [draw(st.integers(0, L)) if draw(st.booleans()) else 0 for _ in range(J)]
    free = J * L - sum(held_levels)
    while (T + 1) ** free > MAX_SCHEDULES:   # shrink the horizon rather than reject the example
        T -= 1
    cost = np.array(draw(st.lists(st.integers(1, 6), min_size=J * L, max_size=J * L))).reshape(J, L)
    quarters = st.integers(-8, 8)
    utility = np.array(draw(st.lists(quarters, min_size=T * J * L, max_size=T * J * L)), dtype=float)
    utility = utility.reshape(T, J, L) / 4.0
    if not (utility < 0).any():
        t, j, l = draw(st.tuples(st.integers(0, T - 1), st.integers(0, J - 1), st.integers(0, L - 1)))
        utility[t, j, l] = -draw(st.integers(1, 8)) / 4.0
    top = int(cost.sum())
    bandwidth = draw(st.lists(st.integers(0, top), min_size=T, max_size=T))
    held = np.zeros((J, L), dtype=bool)
    for j, h in enumerate(held_levels):
        held[j, :h] = True
    options = options if options is not None else draw(st.sampled_from(ALL_OPTIONS))
    return Instance("layered", bandwidth=bandwidth, cost=cost, utility=utility, held=held, options=options)


SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def _check_heuristic(inst: Instance, sol, best: float, label: str, *, slot: int | None = None) -> None:
    assert is_feasible(inst, sol.arrivals, slot=slot), (label, sol.arrivals)
    assert sol.objective <= best + TOL, (label, sol.objective, best, inst.to_dict())
    if sol.status is Status.OPTIMAL:
        assert math.isclose(sol.objective, best, abs_tol=TOL), (label, "labelled optimal", sol.objective, best)
    if sol.bound is not None:
        assert sol.bound >= best - TOL, (label, "bound below the optimum", sol.bound, best)


@settings(max_examples=60, **SETTINGS)
@given(signed_instances())
def test_ilp_highs_every_form_equals_brute_force(inst):
    best = solve(inst, "brute").objective
    for form, presolved in itertools.product(("standard", "gap"), (True, False)):
        sol = solve(inst, "ilp", backend="highs", form=form, presolve=presolved)
        assert is_feasible(inst, sol.arrivals)
        assert math.isclose(sol.objective, best, abs_tol=TOL), (form, presolved, sol.objective, best, inst.to_dict())
        assert sol.status in (Status.OPTIMAL, Status.FEASIBLE), sol.message
    bound = solve(inst, "lp", backend="highs").bound
    assert bound is not None and bound >= best - TOL


@pytest.mark.parametrize("backend", [b.value for b in installed_backends() if b.value != "highs"])
@settings(max_examples=12, **SETTINGS)
@given(inst=signed_instances())
def test_ilp_other_backends_equal_brute_force(backend, inst):
    best = solve(inst, "brute").objective
    sol = solve(inst, "ilp", backend=backend)
    assert is_feasible(inst, sol.arrivals)
    assert math.isclose(sol.objective, best, abs_tol=TOL), (backend, sol.objective, best, inst.to_dict())


@settings(max_examples=25, **SETTINGS)
@given(signed_instances(options=None))
def test_exact_equals_brute_force(inst):
    best = solve(inst, "brute").objective
    sol = solve(inst, "exact", time_limit_s=20)
    assert is_feasible(inst, sol.arrivals)
    assert math.isclose(sol.objective, best, abs_tol=TOL), (sol.objective, best, inst.to_dict())
    assert sol.bound is not None and sol.bound >= best - TOL


@settings(max_examples=40, **SETTINGS)
@given(signed_instances().filter(lambda i: i.options.budget == "cumulative" and i.options.same_slot_layers))
def test_link_dp_equals_brute_force(inst):
    best = solve(inst, "brute").objective
    sol = solve(inst, "link-dp")
    assert sol.status is Status.OPTIMAL
    assert is_feasible(inst, sol.arrivals)
    assert math.isclose(sol.objective, best, abs_tol=TOL), (sol.objective, best, inst.to_dict())


@settings(max_examples=30, **SETTINGS)
@given(signed_instances())
def test_heuristics_feasible_never_above_brute_force(inst):
    best = solve(inst, "brute").objective
    for method in HEURISTIC_HORIZON + (PER_SLOT_HEURISTIC if inst.options.budget == "per_slot" else ()):
        sol = solve(inst, method)
        _check_heuristic(inst, sol, best, method)
        # No object keeps a run of top layers that loses value (a negative layer only as a step).
        assert trim_losing_layers(inst, sol.arrivals) == sol.arrivals, (method, sol.arrivals)


@settings(max_examples=30, **SETTINGS)
@given(signed_instances())
def test_single_slot_methods_against_brute_force(inst):
    for slot in range(inst.T):
        best = solve(inst, "brute", slot=slot).objective
        for method in SLOT_EXACT:
            sol = solve(inst, method, slot=slot)
            assert is_feasible(inst, sol.arrivals, slot=slot), (method, slot)
            assert math.isclose(sol.objective, best, abs_tol=TOL), (method, slot, sol.objective, best, inst.to_dict())
        for method in SLOT_HEURISTIC:
            _check_heuristic(inst, solve(inst, method, slot=slot), best, method, slot=slot)
        bound = solve(inst, "lp", slot=slot).bound
        assert bound is not None and bound >= best - TOL


def _option_id(o: Options) -> str:
    return f"{o.availability}-{'same' if o.same_slot_layers else 'strict'}-{o.budget}"


@pytest.mark.parametrize("options", ALL_OPTIONS, ids=_option_id)
def test_seeded_tight_instances_every_method(options):
    """Beside hypothesis (which favours small, often trivial, examples): two objects, budgets
    that bind, about a third of the layer utilities negative, a held prefix now and then."""
    rng = np.random.default_rng(sum(map(ord, _option_id(options))))
    for trial in range(3):
        T, L = (3, 2) if trial < 2 else (2, 3)
        cost = rng.integers(1, 7, (2, L))
        bandwidth = rng.integers(0, int(0.6 * cost.sum()) + 1, T)
        held = np.zeros((2, L), dtype=bool)
        held[0, :int(rng.integers(0, L + 1))] = trial == 1
        inst = Instance("layered", bandwidth=bandwidth, cost=cost, utility=rng.integers(-6, 9, (T, 2, L)) / 4.0,
                        held=held, options=options)
        best = solve(inst, "brute").objective
        exact = [("ilp", dict(backend="highs", form=f, presolve=p)) for f in ("standard", "gap") for p in (True, False)]
        exact += [("exact", dict(time_limit_s=20))]
        exact += [("link-dp", {})] if options.budget == "cumulative" and options.same_slot_layers else []
        for method, kw in exact:
            sol = solve(inst, method, **kw)
            assert is_feasible(inst, sol.arrivals)
            assert math.isclose(sol.objective, best, abs_tol=TOL), (method, kw, sol.objective, best, inst.to_dict())
        for method in HEURISTIC_HORIZON + (PER_SLOT_HEURISTIC if options.budget == "per_slot" else ()):
            _check_heuristic(inst, solve(inst, method), best, method)
        for slot in range(T):
            at_slot = solve(inst, "brute", slot=slot).objective
            for method in SLOT_EXACT:
                assert math.isclose(solve(inst, method, slot=slot).objective, at_slot, abs_tol=TOL), (method, slot)


# -- hand-made cases -------------------------------------------------------------------------------

def _one_object(utility, *, bandwidth=(10,), cost=None, held=None, options=None) -> Instance:
    utility = np.asarray(utility, dtype=float)
    T, L = utility.shape
    return Instance("layered", bandwidth=list(bandwidth), cost=cost if cost is not None else [[1] * L],
                    utility=utility[:, None, :], held=held, options=options or Options())


def test_presolve_keeps_a_negative_layer_that_is_a_step_to_a_better_one():
    inst = _one_object([[-1.0, 3.0]])
    assert presolve(inst).active.tolist() == [[True, True]]
    for method in ("brute", "ilp", "exact", "slope", "rolling:bb", "static", "progressive"):
        sol = solve(inst, method)
        assert sol.objective == 2.0 and sorted(sol.arrivals) == [(0, 0, 0), (0, 1, 0)], method
    # Two negative layers under one that recovers them both: all three are kept.
    assert presolve(_one_object([[-1.0, -1.0, 3.0]], cost=[[1, 1, 1]])).active.tolist() == [[True, True, True]]


def test_presolve_drops_a_trailing_negative_layer_nothing_recovers():
    inst = _one_object([[2.0, -1.0]])
    red = presolve(inst)
    assert red.active.tolist() == [[True, False]]
    assert red.stats["no_utility"] == 1
    for method in ("brute", "ilp", "exact", "slope", "rolling:bb", "static", "progressive", "mpc:2"):
        sol = solve(inst, method)
        assert sol.objective == 2.0 and sol.arrivals == ((0, 0, 0),), method
    # A negative layer whose recovery is too small goes, with everything above it.
    assert presolve(_one_object([[1.0, -2.0, 1.0]], cost=[[1, 1, 1]])).active.tolist() == [[True, False, False]]
    assert presolve(_one_object([[-3.0, 1.0]])).active.tolist() == [[False, False]]


def test_presolve_values_a_layer_by_its_best_arrival_slot():
    # Negative at first, positive later: worth arriving late (2), not early (-1 + 2 = 1).
    inst = _one_object([[-1.0], [2.0]], bandwidth=(5, 5))
    assert presolve(inst).active.tolist() == [[True]]
    for method in ("brute", "ilp", "exact"):
        assert solve(inst, method).arrivals == ((0, 0, 1),), method


def test_cumulative_zero_bandwidth_slot_kept_for_a_negative_layer():
    # One link, no bytes in slot 1: the layer is best delivered there (2), not in slot 0 (1).
    opts = Options(budget="cumulative")
    inst = _one_object([[-1.0], [2.0]], bandwidth=(1, 0), options=opts)
    assert presolve(inst).arrive[0, 0].tolist() == [True, True]
    for method in ("brute", "ilp", "link-dp", "exact"):
        sol = solve(inst, method)
        assert sol.objective == 2.0 and sol.arrivals == ((0, 0, 1),), method
    # A slot where the layer is worth nothing (0) takes no arrival: waiting for the next one is as
    # good under one link; a negative slot is kept (it is worth something: less).
    idle = _one_object([[0.0], [-1.0], [2.0]], bandwidth=(1, 0, 0), options=opts)
    assert presolve(idle).arrive[0, 0].tolist() == [False, True, True]
    for method in ("brute", "ilp", "exact"):
        assert solve(idle, method).objective == 2.0, method


def test_mckp_options_are_cumulative_levels():
    inst = _one_object([[-1.0, 3.0, -5.0]], cost=[[1, 2, 4]])
    opts = mckp_options(inst, 0)
    # Level 0 alone is worth -1 (no option); level 1 is worth 2; level 2 (-3) is dominated.
    assert opts.value == ((2.0,),) and opts.cost == ((3,),)
    assert opts.arrivals == ((((0, 0), (0, 1)),),)
    assert opts.stats["no_value"] == 2


def test_negative_held_layer_counts_and_brute_force_finds_a_negative_optimum():
    inst = _one_object([[-1.0, -0.5], [-1.0, -0.5]], bandwidth=(5, 5), held=[[True, False]])
    for method in ("brute", "ilp", "exact", "slope", "rolling:bb"):
        sol = solve(inst, method)
        assert sol.objective == -2.0 and sol.arrivals == (), method
    assert evaluate_objective(inst, [(0, 1, 0)]) == -3.0


def test_heuristics_do_not_buy_a_trailing_negative_layer():
    # Bandwidth for everything: each heuristic would have sent every chunk before signed utilities.
    inst = Instance("layered", bandwidth=[20, 20], cost=[[2, 1], [3, 2]],
                    utility=[[[1.0, -0.25], [0.5, 1.0]], [[1.0, -0.25], [0.5, 1.0]]])
    best = solve(inst, "brute")
    assert best.objective == 5.0
    for method in HEURISTIC_HORIZON:
        sol = solve(inst, method)
        assert (0, 1) not in {(j, l) for j, l, _ in sol.arrivals}, method
        assert sol.objective == 5.0, method


def test_trim_losing_layers_keeps_the_best_prefix():
    inst = _one_object([[1.0, -2.0, 1.5, -0.5]], cost=[[1, 1, 1, 1]])
    every = [(0, l, 0) for l in range(4)]
    # Prefix values 1, -1, 0.5, 0: the best is the first layer alone.
    assert trim_losing_layers(inst, every) == ((0, 0, 0),)
    plain = _one_object([[1.0, 0.0]])
    assert trim_losing_layers(plain, [(0, 0, 0), (0, 1, 0)]) == ((0, 0, 0), (0, 1, 0))   # dU >= 0: unchanged


# -- validation -------------------------------------------------------------------------------------

def test_separate_form_refuses_negative_utility_by_name():
    utility = [[[1.0, -0.5]]]
    Instance("layered", bandwidth=[5], cost=[[1, 2]], utility=utility)   # the layered form takes it
    with pytest.raises(InstanceError, match=r"^utility\[0\]\[0\]\[1\] = -0\.5: must be >= 0 \(a separate") as info:
        Instance("separate", bandwidth=[5], cost=[[1, 2]], utility=utility)
    assert info.value.field == "utility" and info.value.index == (0, 0, 1)


@pytest.mark.parametrize("bad, shown", [(float("nan"), "nan"), (float("inf"), "inf"), (-float("inf"), "-inf")])
def test_layered_form_still_refuses_non_finite(bad, shown):
    with pytest.raises(InstanceError, match=rf"^utility\[0\]\[0\]\[1\] = {shown}: must be finite") as info:
        Instance("layered", bandwidth=[5], cost=[[1, 2]], utility=[[[-1.0, bad]]])
    assert info.value.index == (0, 0, 1)


def test_layered_form_bounds_the_magnitudes():
    # +1e300 and -1e300 sum to 0, but a schedule holding only the first is worth 1e300 per slot.
    with pytest.raises(InstanceError, match=r"^utility: sums to 2e\+300: all \|utilities\| together"):
        Instance("layered", bandwidth=[5], cost=[[1, 2]], utility=[[[1e300, -1e300]]])


def test_item_form_refuses_a_signed_layered_instance_by_name():
    inst = _one_object([[1.0, -0.5]])
    with pytest.raises(ItemInstanceError, match=r"^utility\[0\]\[0\]\[1\] = -0\.5: a negative layer utility"):
        items_from_instance(inst)


def test_a_zero_optimum_of_nonzero_terms_is_proven():
    """One layer pair worth [-1, 1] in slot 0 and [-0.3, 0.3] in slot 1: the optimum is 0 (or a pair
    summing to 0), and a bound a round-off above it must not read as a gap of 1 (the gap is taken
    against the sum of the utilities' magnitudes, ``utility_scale``)."""
    from l3gs_opt.problem.solution import relative_gap, utility_scale

    inst = Instance("layered", bandwidth=[10, 10], cost=[[1, 1]], utility=[[[-1.0, 1.0]], [[-0.3, 0.3]]])
    ref = solve(inst, "brute")
    assert ref.objective == pytest.approx(0.0, abs=1e-12)
    assert utility_scale(inst) == pytest.approx(2.6) and relative_gap(0.0, 3.3e-16, 2.6) < 1e-15
    assert relative_gap(0.0, 3.3e-16) == 1.0              # without the scale: the old reading
    runs = [("exact", {}), *((("ilp", {"backend": b}) for b in installed_backends()))]
    for method, kw in runs:
        sol = solve(inst, method, **kw)
        assert sol.status is Status.OPTIMAL and sol.objective == pytest.approx(0.0, abs=1e-12), (method, kw, sol.status)
    nonneg = Instance("layered", bandwidth=[10], cost=[[1]], utility=[[[1.0]]])
    assert utility_scale(nonneg) is None                  # non-negative instances: gaps unchanged


def test_per_slot_presolve_stops_at_the_last_event_slot():
    # Layer 0 is worth something in slots 0-1, layer 1 in slot 2: layer 0 may still arrive in slot
    # 2 (a step to layer 1 there), neither in slot 3. A negative utility is worth something too.
    inst = _one_object([[1.0, 0.0], [1.0, 0.0], [0.0, 2.0], [0.0, 0.0]], bandwidth=(1, 1, 1, 1))
    assert presolve(inst).arrive[0].tolist() == [[True, True, True, False]] * 2
    signed = _one_object([[1.0, 0.0], [1.0, 0.0], [0.0, 2.0], [0.0, -1.0]], bandwidth=(1, 1, 1, 1))
    assert presolve(signed).arrive[0].tolist() == [[True] * 4] * 2
    for case in (inst, signed):
        ref = solve(case, "brute").objective
        for method in ("ilp", "exact"):
            assert solve(case, method).objective == ref, method


def test_exact_starts_from_a_heuristic_that_sends_worthless_chunks():
    """``static`` sends every chunk that fits, also after its object left the view for good: per
    slot those arrivals are dropped (worth nothing), under one link they wait for an event slot;
    either way the start keeps its value and ``exact`` reaches brute force's optimum."""
    from l3gs_opt.solvers.exact.lagrange import assignment_value, gap_data
    from l3gs_opt.solvers.exact.search import solve_exact

    rng = np.random.default_rng(3)
    utility = rng.random((5, 2, 2))
    utility[2:] = 0.0                      # nobody looks after slot 1
    utility[0, 1] = 0.0                    # object 1 out of view in slot 0
    for budget in ("per_slot", "cumulative"):
        inst = Instance("layered", bandwidth=[1, 1, 1, 1, 1], cost=[[1, 1], [1, 1]], utility=utility,
                        options=Options(budget=budget))
        start = solve(inst, "static")
        if budget == "per_slot":
            data = gap_data(inst)
            assign = data.assignment(start.arrivals)
            assert (assign >= 0).sum() < len(start.arrivals)      # something was worth nothing
            assert abs(assignment_value(data, assign) - start.objective) <= 1e-12
        sol = solve_exact(inst, heuristics=("static",))
        assert abs(sol.objective - solve(inst, "brute").objective) <= 1e-12, budget
