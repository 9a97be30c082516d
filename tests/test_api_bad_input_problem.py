"""Bad input to the problem API (schedules, solve arguments, instance fields) raises the project's
own error naming the field and index: never a raw Python exception, a silent default or a wrong
number (api_sweep findings A1-A3, C1, C3-C7, D1, D2)."""

from __future__ import annotations

import math
import warnings

import highspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import l3gs_opt as L
from l3gs_opt import Instance, InstanceError, Options, SolveError
from l3gs_opt.models.backends import solve_model
from l3gs_opt.models.build import build_model
from l3gs_opt.problem.arguments import check_time_limit
from l3gs_opt.problem.items import ItemInstance
from l3gs_opt.problem.items_eval import evaluate_items, item_violations, items_feasible


def layered() -> Instance:
    return Instance("layered", [100, 100], [[10, 20], [30, 40]], np.arange(8.).reshape(2, 2, 2) + 1)


def separate() -> Instance:
    return Instance("separate", [100, 100], [[10, 20], [30, 40]], np.arange(8.).reshape(2, 2, 2) + 1)


def items() -> ItemInstance:
    return ItemInstance(bandwidth=[5, 5], object=[0, 0, 1], cost=[2, 3, 1], utility=[[1, .5, 2], [1, .5, 2]],
                        requires=[[0, 1]])


CHUNK_FUNCTIONS = [L.evaluate_objective, L.feasibility_violations, L.is_feasible]
ITEM_FUNCTIONS = [evaluate_items, item_violations, items_feasible]


# -- A1, A3, C7: malformed arrivals are refused, naming the arrival ---------------------------------

@pytest.mark.parametrize("fn", CHUNK_FUNCTIONS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("arrivals, match", [
    ([(-1, 0, 0)], r"^arrivals\[0\] = \(-1, 0, 0\): object -1 is out of range 0\.\.1$"),
    ([(0, 0, 0), (0, 5, 1)], r"^arrivals\[1\] = \(0, 5, 1\): layer 5 is out of range 0\.\.1$"),
    ([(0, -1, 0)], r"^arrivals\[0\] = \(0, -1, 0\): layer -1 is out of range"),
    ([(5, 0, 0)], r"^arrivals\[0\] = \(5, 0, 0\): object 5 is out of range"),
    ([(0, 0, 2)], r"^arrivals\[0\] = \(0, 0, 2\): slot 2 is out of range 0\.\.1$"),
    ([(0, 0, -1)], r"^arrivals\[0\] = \(0, 0, -1\): slot -1 is out of range"),
    ([(True, True, False)], r"^arrivals\[0\] = \(True, True, False\): object True is not an integer$"),
    ([(0, np.True_, 0)], r"^arrivals\[0\] = .*: layer True is not an integer$"),
    ([(0.7, 0, 0)], r"^arrivals\[0\] = \(0\.7, 0, 0\): object 0\.7 is not an integer$"),
    ([(0, 1.0, 0)], r"^arrivals\[0\] = \(0, 1\.0, 0\): layer 1\.0 is not an integer$"),
    ([(float("nan"), 0, 0)], r"^arrivals\[0\] = \(nan, 0, 0\): object nan is not an integer$"),
    ([("0", 0, 0)], r"^arrivals\[0\] = \('0', 0, 0\): object '0' is not an integer$"),
    ([(0, 0)], r"^arrivals\[0\] = \(0, 0\): must be a \(object, layer, slot\) tuple of 3 integers$"),
    ([(0, 0, 0, 0)], r"^arrivals\[0\] = \(0, 0, 0, 0\): must be a \(object, layer, slot\) tuple"),
    ([(0, 0, 0), 5], r"^arrivals\[1\] = 5: must be a \(object, layer, slot\) tuple"),
    ([{0, 1, 2}], r"^arrivals\[0\] = .*must be a \(object, layer, slot\) tuple"),
    (np.zeros((2, 2)), r"^arrivals\[0\] = \(0\.0, 0\.0\): must be a"),
    (np.zeros((1, 3)), r"^arrivals\[0\] = \(0\.0, 0\.0, 0\.0\): object 0\.0 is not an integer$"),
    (None, r"^arrivals: must be a list of \(object, layer, slot\) arrivals, got NoneType$"),
    (5, r"^arrivals: must be a list of .* got int$"),
    ("abc", r"^arrivals: must be a list of .* got str$"),
    ({(0, 0): 0}, r"^arrivals: must be a list of .* got dict$"),
])
def test_malformed_chunk_arrivals_raise_naming_the_arrival(fn, arrivals, match):
    with pytest.raises(InstanceError, match=match) as info:
        fn(layered(), arrivals)
    assert info.value.field == "arrivals"


def test_separate_instances_name_versions():
    with pytest.raises(InstanceError, match=r"^arrivals\[0\] = \(0, 2, 0\): version 2 is out of range 0\.\.1$"):
        L.evaluate_objective(separate(), [(0, 2, 0)])


@pytest.mark.parametrize("fn", ITEM_FUNCTIONS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("arrivals, match", [
    ([(1, -1, 0)], r"^arrivals\[0\] = \(1, -1, 0\): item -1 is out of range 0\.\.2$"),
    ([(0, 9, 0)], r"^arrivals\[0\] = \(0, 9, 0\): item 9 is out of range 0\.\.2$"),
    ([(1, 2, 5)], r"^arrivals\[0\] = \(1, 2, 5\): slot 5 is out of range 0\.\.1$"),
    ([(1, 2.9, 0)], r"^arrivals\[0\] = \(1, 2\.9, 0\): item 2\.9 is not an integer$"),
    ([(1.0, 2, 0)], r"^arrivals\[0\] = \(1\.0, 2, 0\): object 1\.0 is not an integer$"),
    ([(False, 0, 0)], r"^arrivals\[0\] = \(False, 0, 0\): object False is not an integer$"),
    ([(2, 0)], r"^arrivals\[0\] = \(2, 0\): must be a \(object, item, slot\) tuple of 3 integers$"),
    (None, r"^arrivals: must be a list of \(object, item, slot\) arrivals, got NoneType$"),
])
def test_malformed_item_arrivals_raise_naming_the_arrival(fn, arrivals, match):
    with pytest.raises(InstanceError, match=match):
        fn(items(), arrivals)


def test_evaluate_refuses_a_chunk_given_twice_whatever_the_order():
    """It once took the last arrival: 6.0 one way round, 5.0 the other."""
    for arrivals in ([(0, 0, 1), (0, 0, 0)], [(0, 0, 0), (0, 0, 1)], [(0, 0, 0), (0, 0, 0)]):
        with pytest.raises(InstanceError, match=r"^arrivals\[1\] = .*: chunk \(0, 0\) is given twice "
                                                r"\(also as arrivals\[0\]\)"):
            L.evaluate_objective(layered(), arrivals)


def test_evaluate_items_refuses_an_item_given_twice_or_under_another_object():
    with pytest.raises(InstanceError, match=r"^arrivals\[1\] = \(1, 2, 1\): item 2 is given twice"):
        evaluate_items(items(), [(1, 2, 0), (1, 2, 1)])
    with pytest.raises(InstanceError, match=r"^arrivals\[0\] = \(7, 2, 0\): item 2 is of object 1, not 7$"):
        evaluate_items(items(), [(7, 2, 0)])


def test_violations_still_report_infeasible_but_well_formed_schedules():
    """Malformed input raises; a schedule that merely breaks a rule is reported, as before."""
    inst = layered()
    assert L.feasibility_violations(inst, [(0, 0, 0), (0, 0, 1)]) == ["chunk (0, 0) arrives twice (slots 0 and 1)"]
    assert "layer 0 does not arrive" in L.feasibility_violations(inst, [(0, 1, 0)])[0]
    tight = inst.replace(bandwidth=[10, 10])
    assert L.feasibility_violations(tight, [(0, 0, 0), (1, 0, 0)]) == ["slot 0: 40 bytes arrive, budget is 10 bytes"]
    assert L.feasibility_violations(inst, [(0, 0, 1)], slot=0) == ["arrival (0, 0, 1) is not in slot 0"]
    it = items()
    assert item_violations(it, [(0, 2, 0)]) == ["arrival (0, 2, 0): item 2 is of object 1"]
    assert item_violations(it, [(0, 1, 0)])[0].startswith("item 1 arrives in slot 0 but item 0")
    assert not items_feasible(it, [(1, 2, 0), (1, 2, 1)])


def test_evaluate_values_a_broken_precedence_by_the_documented_formula():
    """Documented choice: evaluate_objective does not check feasibility; each chunk counts from
    its arrival (layer 1 of object 0 in both slots, U = 2 + 6, without its layer 0)."""
    assert L.evaluate_objective(layered(), [(0, 1, 0)]) == 8.0


def test_numpy_integers_and_arrays_are_accepted():
    inst = layered()
    plain = [(0, 0, 0), (1, 0, 1)]
    assert L.evaluate_objective(inst, np.array(plain)) == L.evaluate_objective(inst, plain)
    assert L.evaluate_objective(inst, [tuple(np.int32(v) for v in a) for a in plain]) == \
        L.evaluate_objective(inst, plain)
    assert L.evaluate_objective(inst, [list(a) for a in plain]) == L.evaluate_objective(inst, plain)
    assert L.is_feasible(inst, np.array(plain, dtype=np.uint8), slot=np.int64(0)) is False
    assert evaluate_items(items(), np.array([[1, 2, 0]])) == evaluate_items(items(), [(1, 2, 0)])
    assert L.is_feasible(inst, (a for a in plain))
    assert L.evaluate_objective(inst, ()) == L.evaluate_objective(inst, np.zeros((0, 3), dtype=np.int64))


def test_finished_solutions_still_check_and_value():
    inst = layered()
    sol = L.solve(inst, "brute")
    assert L.is_feasible(inst, sol.arrivals) and sol.objective == L.evaluate_objective(inst, sol.arrivals)


# -- A2: the slot is checked everywhere ---------------------------------------------------------------

@pytest.mark.parametrize("slot", [5, 2, -1, "0", 1.0, np.float64(0), True, [0]])
def test_a_bad_slot_is_refused_by_every_schedule_function(slot):
    for fn, inst in [(L.evaluate_objective, separate()), (L.evaluate_objective, layered()),
                     (L.feasibility_violations, layered()), (L.is_feasible, layered()),
                     (evaluate_items, items()), (item_violations, items()), (items_feasible, items())]:
        with pytest.raises(SolveError, match=r"^slot = .*: must be an integer in 0\.\.1$"):
            fn(inst, [], slot=slot)


def test_a_numpy_slot_is_accepted():
    assert L.evaluate_objective(layered(), [(0, 0, 1)], slot=np.int64(1)) == 5.0   # U[1, 0, 0]


# -- C5: not an instance --------------------------------------------------------------------------------

@pytest.mark.parametrize("bad", [None, {"a": 1}, 5, "instance.json"])
def test_not_an_instance_is_a_solve_error(bad):
    with pytest.raises(SolveError, match=r"^instance must be an Instance or ItemInstance, got "):
        L.solve(bad, "ilp")
    for fn in (L.is_feasible, L.feasibility_violations, L.evaluate_objective):
        with pytest.raises(SolveError, match=r"^instance must be an Instance, got "):
            fn(bad, [])
    with pytest.raises(SolveError, match=r"^instance must be an Instance, got "):
        L.presolve(bad)
    for fn in ITEM_FUNCTIONS:
        with pytest.raises(SolveError, match=r"^instance must be an ItemInstance, got "):
            fn(bad, [])


def test_the_wrong_instance_form_is_named():
    with pytest.raises(SolveError, match=r"^instance must be an Instance, got ItemInstance$"):
        L.evaluate_objective(items(), [])
    with pytest.raises(SolveError, match=r"^instance must be an ItemInstance, got Instance$"):
        evaluate_items(layered(), [])


# -- C3, C4, D1: options ---------------------------------------------------------------------------------

@pytest.mark.parametrize("options, match", [
    ([1], r"^options = \[1\]: must be a mapping of option names \(str\) to values, got list$"),
    ("x", r"^options = 'x': must be a mapping .* got str$"),
    ([("threads", 1)], r"^options = .*: must be a mapping .* got list$"),
    ({1: 2}, r"^options: key 1 must be an option name \(str\), got int$"),
])
def test_options_must_be_a_mapping_with_string_keys(options, match):
    with pytest.raises(SolveError, match=match):
        L.solve(layered(), "ilp", options=options)
    with pytest.raises(SolveError, match=match):
        solve_model(build_model(layered()), "highs", options=options)


@pytest.mark.parametrize("options, match", [
    ({"threads": "x"}, r"^options\['threads'\] = 'x': HiGHS refuses this value for its int option 'threads'$"),
    ({"presolve": "bogus"}, r"^options\['presolve'\] = 'bogus': HiGHS refuses .* string option 'presolve'$"),
    ({"threads": [1]}, r"^options\['threads'\] = \[1\]: HiGHS refuses"),
    ({"random_seed": -5}, r"^options\['random_seed'\] = -5: HiGHS refuses"),
])
def test_a_value_highs_refuses_is_an_error_naming_the_option(options, match):
    with pytest.raises(SolveError, match=match):
        L.solve(layered(), "ilp", backend="highs", options=options)


def test_highs_options_it_takes_still_work_and_unknown_names_still_warn():
    inst = layered()
    best = L.solve(inst, "brute").objective
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert L.solve(inst, "ilp", options={"threads": np.int64(1), "presolve": "off"}).objective == best
    with pytest.warns(UserWarning, match=r"unknown option 'mip_rel_gap' passed through to HiGHS"):
        assert L.solve(inst, "ilp", options={"mip_rel_gap": 0.0}).objective == best
    with pytest.warns(UserWarning, match=r"unknown option 'fancy': HiGHS has no such option either; ignored"):
        assert L.solve(inst, "ilp", options={"fancy": 1}).objective == best


def test_a_threads_option_is_honoured_after_other_solves_in_the_process():
    # HiGHS makes one thread pool per process at its first solve; a later solve asking for another
    # count used to end at once as "error" with no schedule. Three counts: at least two differ
    # from whatever pool this test process has, on any machine.
    inst = layered()
    best = L.solve(inst, "brute").objective
    try:
        for threads in (1, 2, 3, None):
            options = {} if threads is None else {"threads": threads}
            sol = L.solve(inst, "ilp", backend="highs", options=options)
            assert (sol.status, sol.objective) == ("optimal", best), threads
    finally:   # the next solve of this process makes the default pool again, as before this test
        highspy.Highs.resetGlobalScheduler(True)


# -- C6: a time limit beyond float's range -----------------------------------------------------------------

def test_a_time_limit_beyond_float_range_means_no_limit():
    assert check_time_limit(10**400) is None
    assert check_time_limit(10**300) == 1e300
    sol = L.solve(layered(), "ilp", time_limit_s=10**400)
    assert sol.status.value == "optimal"
    with pytest.raises(SolveError, match=r"must be > 0"):
        check_time_limit(-10**400)


# -- D2: representation --------------------------------------------------------------------------------------

@pytest.mark.parametrize("bad", [np.array(["layered"]), ["layered"], b"layered", 1, None])
def test_representation_must_be_a_str(bad):
    with pytest.raises(InstanceError, match=r"^representation: must be a str, one of layered, separate; got "):
        Instance(bad, [10], [[1]], [[[1]]])


def test_a_numpy_str_representation_is_stored_as_a_plain_str():
    inst = Instance(np.str_("layered"), [10], [[1]], [[[1]]])
    assert type(inst.representation) is str and inst.layered is True
    assert type(inst.replace(representation=np.str_("separate")).representation) is str
    assert L.instance_from_dict(inst.to_dict()).representation == "layered"


# -- C1: ragged nested lists ------------------------------------------------------------------------------------

@pytest.mark.parametrize("fields, match", [
    (dict(cost=[[1, 2], [3]]), r"^cost\[1\]: rows of unequal length: expected 2 entries, got 1 \(cost\[0\] has 2\)$"),
    (dict(bandwidth=[[100], [1, 2]]), r"^bandwidth\[1\]: rows of unequal length"),
    (dict(utility=[[[1, 1], [1, 1]], [[1, 1], [1]]]),
     r"^utility\[1\]\[1\]: rows of unequal length: expected 2 entries, got 1 \(utility\[0\]\[0\] has 2\)$"),
    (dict(held=[[1, 0], [1]]), r"^held\[1\]: rows of unequal length"),
    (dict(held=[[1, [0]], [0, 0]]), r"^held\[0\]\[0\]: rows of unequal length: a number where the other entries"),
])
def test_ragged_lists_name_the_field_and_row(fields, match):
    args = dict(representation="layered", bandwidth=[100, 100], cost=[[1, 2], [3, 4]], utility=np.ones((2, 2, 2)))
    args.update(fields)
    with pytest.raises(InstanceError, match=match):
        Instance(**args)


# -- Properties: the objective against an independent sum; order never matters ------------------------------------

def brute_objective(inst: Instance, arrivals: list[tuple[int, int, int]], slot: int | None) -> float:
    """The objective straight from its definition (docs/design.md), written independently."""
    T, J, Lc = inst.utility.shape
    arrive = {(j, l): t for j, l, t in arrivals}
    same = inst.options.availability == "same_slot"

    def shown(t: int, j: int, l: int) -> bool:
        if inst.held[j, l]:
            return True
        a = arrive.get((j, l))
        if a is None:
            return False
        if slot is not None:
            return a == slot
        return a <= t if same else a < t

    terms = []
    for t in ([slot] if slot is not None else range(T)):
        for j in range(J):
            if inst.layered:
                terms += [float(inst.utility[t, j, l]) for l in range(Lc) if shown(t, j, l)]
            else:
                terms.append(max([0.0] + [float(inst.utility[t, j, l]) for l in range(Lc) if shown(t, j, l)]))
    return math.fsum(terms)


@st.composite
def instance_and_schedule(draw):
    T, J, Lc = draw(st.integers(1, 3)), draw(st.integers(0, 3)), draw(st.integers(1, 3))
    representation = draw(st.sampled_from(["layered", "separate"]))
    low = -5.0 if representation == "layered" else 0.0
    utility = draw(st.lists(st.floats(low, 5.0, allow_nan=False), min_size=T * J * Lc, max_size=T * J * Lc))
    held = np.zeros((J, Lc), dtype=bool)
    for j in range(J):
        if representation == "layered":
            held[j, :draw(st.integers(0, Lc))] = True
        else:
            held[j] = draw(st.lists(st.booleans(), min_size=Lc, max_size=Lc))
    options = Options(availability=draw(st.sampled_from(["same_slot", "next_slot"])))
    inst = Instance(representation, [10] * T, np.ones((J, Lc), dtype=int),
                    np.array(utility, dtype=float).reshape(T, J, Lc), held=held, options=options)
    chunks = [(j, l) for j in range(J) for l in range(Lc)]
    picked = draw(st.lists(st.sampled_from(chunks), unique=True)) if chunks else []
    arrivals = [(j, l, draw(st.integers(0, T - 1))) for j, l in picked]
    slot = draw(st.none() | st.integers(0, T - 1))
    return inst, arrivals, slot


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(case=instance_and_schedule(), data=st.data())
def test_objective_matches_brute_force_and_ignores_order(case, data):
    inst, arrivals, slot = case
    value = L.evaluate_objective(inst, arrivals, slot=slot)
    assert value == brute_objective(inst, arrivals, slot)
    shuffled = data.draw(st.permutations(arrivals))
    assert L.evaluate_objective(inst, shuffled, slot=slot) == value
    assert L.is_feasible(inst, shuffled, slot=slot) == L.is_feasible(inst, arrivals, slot=slot)
    if arrivals:
        # A chunk given twice is refused, whichever copy comes first.
        k = data.draw(st.integers(0, len(arrivals) - 1))
        j, l, t = arrivals[k]
        again = data.draw(st.permutations(arrivals + [(j, l, data.draw(st.integers(0, inst.T - 1)))]))
        with pytest.raises(InstanceError, match="is given twice"):
            L.evaluate_objective(inst, again, slot=slot)
        # Any entry out of range, or not an integer, is refused by every function.
        pos = data.draw(st.integers(0, 2))
        size = (inst.J, inst.L, inst.T)[pos]
        bad_value = data.draw(st.sampled_from([-1, size, size + 7, -size - 1, float(arrivals[k][pos]), True]))
        bad = list(arrivals[k])
        bad[pos] = bad_value
        broken = list(arrivals)
        broken[k] = tuple(bad)
        for fn in CHUNK_FUNCTIONS:
            with pytest.raises(InstanceError, match=rf"^arrivals\[{k}\] = "):
                fn(inst, broken, slot=slot)


# -- a dict built from numpy arrays (noticed in the twentieth session: "got ndarray")
def _as_arrays(d: dict, keys) -> dict:
    return {k: (np.asarray(v) if k in keys else v) for k, v in d.items()}


def test_instance_from_dict_reads_numpy_arrays_as_the_lists_they_hold():
    d = layered().to_dict()
    want = L.instance_from_dict(d)
    for keys in (("bandwidth", "cost", "utility"), ("utility",)):
        got = L.instance_from_dict(_as_arrays(d, keys))
        for k in ("bandwidth", "cost", "utility"):
            a, b = np.asarray(getattr(want, k)), np.asarray(getattr(got, k))
            assert a.dtype == b.dtype and np.array_equal(a, b), k
    rows = dict(d, cost=[np.asarray(r) for r in d["cost"]])          # arrays inside a list
    assert np.array_equal(np.asarray(L.instance_from_dict(rows).cost), np.asarray(want.cost))
    it = items().to_dict()
    got = L.items_from_dict(_as_arrays(it, ("bandwidth", "cost", "utility", "object", "requires")))
    assert got.to_dict() == L.items_from_dict(it).to_dict()


@pytest.mark.parametrize("field, value, match", [
    ("cost", np.array([[True, False], [True, True]]), r"^cost\[0\]\[0\] = True: must be a number"),
    ("cost", np.array([[10, 20.5], [30, 40]]), r"^cost\[0\]\[1\] = 20\.5: .*fractional bytes"),
    ("cost", np.array([[10, 20, 5], [30, 40, 5]]), r"^utility: has shape"),
    ("cost", np.array([["10", "20"], ["30", "40"]]), r"^cost\[0\]\[0\] = '10': must be a number"),
    ("bandwidth", np.array(100), r"^bandwidth: must be a list over slots, got int"),
    ("utility", np.full((2, 2, 2), np.nan), r"^utility\[0\]\[0\]\[0\]"),
])
def test_numpy_arrays_in_a_dict_are_checked_entry_by_entry(field, value, match):
    with pytest.raises(InstanceError, match=match):
        L.instance_from_dict(dict(layered().to_dict(), **{field: value}))
