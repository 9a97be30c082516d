"""The item form (``l3gs-opt/items@1``): contract, conversions, models, presolve and solvers.

Independent references: brute force (:func:`solve_items_brute_force` writes the rules out again),
the Problem I/II models and brute force on the same instances (the "special cases" proof), and
:mod:`l3gs_opt.problem.evaluate` for the objective and feasibility of converted schedules.
"""

from __future__ import annotations

import itertools
import json
import math
import pickle
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3gs_opt import (InstanceError, ItemInstance, ItemInstanceError, Options, SolveError, Status, evaluate_items,
                      evaluate_objective, feasibility_violations, hierarchy_items, distill_items,
                      instance_arrivals, item_violations, items_feasible, items_from_dict, items_from_instance,
                      load_items, save_items, solve)
from l3gs_opt.problem.solution import finish_solution as finish_items_solution
from l3gs_opt.problem.items_presolve import presolve_items
from l3gs_opt.models import Backend, build_items_model
from l3gs_opt.solvers.items import MAX_CLOSED_SETS, closed_sets, solve_items_brute_force

from core_helpers import ALL_OPTIONS, option_id, random_instance

REL = 1e-9  # objectives are fsum re-evaluations of the same terms; backends solve to zero gap


def close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=REL, abs_tol=1e-12)


def base() -> dict:
    """A valid file: one object with a compact -> upgrade pair, one object with two versions."""
    return {"schema": "l3gs-opt/items@1", "bandwidth": [5, 3], "object": [0, 0, 1, 1], "cost": [2, 1, 3, 4],
            "utility": [[1.0, 0.5, 0.3, 0.6], [1.0, 0.5, 0.3, 0.7]], "group": [0, 1, 2, 2],
            "requires": [[0, 1]]}


# -- random item instances -------------------------------------------------------------------------

def _closed_held(rng: np.random.Generator, inst_parents: list[list[int]], N: int, p: float) -> np.ndarray:
    held = rng.random(N) < p
    changed = True
    while changed:  # close under precedence: a held item's parents are held
        changed = False
        for c in range(N):
            if held[c]:
                for q in inst_parents[c]:
                    if not held[q]:
                        held[q] = changed = True
    return held


def random_items(rng: np.random.Generator, shape: str, *, T: int = 2, options: Options | None = None,
                 held_p: float = 0.0) -> ItemInstance:
    """Tiny item instances: ``distill`` (2 objects x 2 layers, compact + upgrade, an absent cell
    now and then), ``hierarchy`` (2 objects x 3 versions) or ``general`` (random DAG and groups)."""
    options = options or Options()
    zero = lambda shp: rng.random(shp) * (rng.random(shp) > 0.25)  # noqa: E731
    if shape == "distill":
        J, L = 2, 2
        present = rng.random((J, L)) > 0.15
        inst = distill_items(rng.integers(1, 6, (J, L)), rng.integers(1, 4, (J, L)), zero((T, J, L)),
                             zero((T, J, L)), [0] * T, present=present, options=options)
    elif shape == "hierarchy":
        J, L = 2, 3
        inst = hierarchy_items(rng.integers(1, 7, (J, L)), zero((T, J, L)), [0] * T,
                               present=rng.random((J, L)) > 0.1, options=options)
    else:
        objects, requires, groups = [], [], []
        for j in range(2):
            n = int(rng.integers(2, 5))
            start = len(objects)
            for k in range(n):
                i = start + k
                objects.append(j)
                for q in range(start, i):
                    if rng.random() < 0.35:
                        requires.append([q, i])
                # Join an earlier group of this object sometimes (a replacement group).
                same = [g for g, o in zip(groups, objects) if o == j]
                groups.append(int(rng.choice(same)) if same and rng.random() < 0.4 else i)
        N = len(objects)
        inst = ItemInstance(bandwidth=[0] * T, object=objects, cost=rng.integers(1, 6, N), utility=zero((T, N)),
                            group=groups, requires=requires, options=options)
    parents = [list(p) for p in inst.parents]
    held = _closed_held(rng, parents, inst.N, held_p)
    total = int(inst.cost.sum())
    bandwidth = rng.integers(0, max(2, int(0.7 * total)) + 1, size=T)
    return inst.replace(held=held, bandwidth=bandwidth)


SHAPES = ("distill", "hierarchy", "general")


# -- the contract ------------------------------------------------------------------------------------

def test_valid_file_and_structure():
    inst = items_from_dict(base())
    assert (inst.T, inst.N, inst.J, inst.G) == (2, 4, 2, 3)
    assert inst.parents == ((), (0,), (), ()) and inst.children[0] == (1,)
    assert inst.members == ((0,), (1,), (2, 3))
    assert inst.problem == "items"
    with pytest.raises(ValueError):
        inst.cost[0] = 9  # read-only arrays
    with pytest.raises(AttributeError):
        inst.slot_s = 2.0  # type: ignore[misc]


@pytest.mark.parametrize("change, pattern, field, index", [
    ({"requires": [[0, 1], [0, 7]]}, r"^requires\[1\] = \[0, 7\]: 7 is not an item index in 0\.\.3$", "requires", (1,)),
    ({"requires": [[2, 2]]}, r"^requires\[0\] = \[2, 2\]: an item cannot require itself$", "requires", (0,)),
    ({"requires": [[0, 2]]}, r"^requires\[0\] = \[0, 2\]: item 0 is of object 0, item 2 of object 1", "requires",
     (0,)),
    ({"requires": [[0, 1], [0, 1]]}, r"^requires\[1\] = \[0, 1\]: repeats requires\[0\]$", "requires", (1,)),
    ({"requires": [[0, 1], [1, 0]]}, r"^requires: cycle through item \d: (\d -> ){2}\d", "requires", None),
    ({"requires": [[0, 1, 2]]}, r"^requires\[0\]: must be a \[parent, child\] pair", "requires", (0,)),
    ({"group": [0, 1, 1, 2]}, r"^group\[2\] = 1: item 2 is of object 1 but group 1 holds item 1 of object 0",
     "group", (2,)),
    ({"held": [0, 1, 0, 0]}, r"^held\[1\] = 1 but item 0 it requires is not held", "held", (1,)),
    ({"held": [1, 1, 0, 2]}, r"^held\[3\] = 2: must be 0 or 1$", "held", (3,)),
    ({"cost": [2, 1, 0, 4]}, r"^cost\[2\] = 0: must be a positive integer \(bytes\)$", "cost", (2,)),
    ({"cost": [2, 1, 2.5, 4]}, r"^cost\[2\] = 2\.5: must be a positive integer \(bytes\); fractional", "cost", (2,)),
    ({"bandwidth": [5, -3]}, r"^bandwidth\[1\] = -3: must be a non-negative integer", "bandwidth", (1,)),
    ({"utility": [[1.0, 0.5, 0.3], [1.0, 0.5, 0.3]]}, r"^utility: has shape \(2, 3\), expected \(T, N\) = \(2, 4\)",
     "utility", None),
    ({"utility": [[1.0, 0.5, 0.3, -1.0], [1.0, 0.5, 0.3, 0.7]]}, r"^utility\[0\]\[3\] = -1\.0: must be >= 0$",
     "utility", (0, 3)),
    ({"utility": [[1.0, 0.5, 0.3, 0.6], [1.0, 0.5, 0.3]]}, r"^utility\[1\]: expected 4 entries \(items\), got 3",
     "utility", (1,)),
    ({"object": [0, 0, -1, 1]}, r"^object\[2\] = -1: must be an integer in 0\.\.", "object", (2,)),
    ({"object": [0, 0, 1]}, r"^object: has 3 entries, expected N = 4", "object", None),
    ({"names": ["a", "b"]}, r"^names: has 2 entries, expected N = 4$", "names", None),
    ({"options": {"budget": "cumulative", "typo": 1}}, r"^options\.typo: unknown option", "options.typo", None),
    ({"slot_s": 0}, r"^slot_s: 0: must be a positive number of seconds$", "slot_s", None),
    ({"schema": "l3gs-opt/instance@1"}, r"^schema: 'l3gs-opt/instance@1': expected 'l3gs-opt/items@1'$", "schema",
     None),
    ({"extra": 1}, r"^extra: unknown key", "extra", None),
])
def test_bad_input_names_field_and_index(change, pattern, field, index):
    with pytest.raises(ItemInstanceError, match=pattern) as info:
        items_from_dict({**base(), **change})
    assert (info.value.field, info.value.index) == (field, index)
    assert isinstance(info.value, InstanceError)


@pytest.mark.parametrize("name, value", [("object", [0, 0, 2**70, 1]), ("group", [0, 1, -2**70, 2])])
def test_labels_beyond_int64_are_named(name, value):
    """numpy holds such a list as dtype object: the entry is named, not the dtype."""
    fields = {k: v for k, v in base().items() if k in ("bandwidth", "object", "cost", "utility", "group")}
    pattern = rf"^{name}\[2\] = -?1180591620717411303424: must be an integer in 0\.\."
    with pytest.raises(ItemInstanceError, match=pattern):
        ItemInstance(**{**fields, name: value})


def test_missing_key_is_named():
    data = base()
    del data["cost"]
    with pytest.raises(ItemInstanceError, match=r"^cost: missing$"):
        items_from_dict(data)


def test_cycle_message_names_a_real_cycle():
    data = {**base(), "object": [0, 0, 0, 0], "group": [0, 1, 2, 3],
            "requires": [[0, 1], [1, 2], [2, 3], [3, 1]]}
    with pytest.raises(ItemInstanceError) as info:
        items_from_dict(data)
    path = [int(v) for v in str(info.value).split(": ", 2)[2].split(" (")[0].split(" -> ")]
    assert path[0] == path[-1] and set(path) == {1, 2, 3}
    edges = {tuple(e) for e in data["requires"]}
    assert all((a, b) in edges for a, b in zip(path, path[1:]))


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_round_trip(tmp_path, suffix):
    inst = items_from_dict({**base(), "held": [1, 0, 0, 1], "names": ["a", "b", "c", "d"],
                            "options": {"availability": "next_slot", "same_slot_layers": False},
                            "meta": {"variant": "distill", "window": [0, 2]}})
    back = load_items(save_items(inst, tmp_path / f"i{suffix}"))
    assert back.to_dict() == inst.to_dict()
    assert pickle.loads(pickle.dumps(inst)).to_dict() == inst.to_dict()
    assert json.loads((save_items(inst, tmp_path / "j.json")).read_text())["schema"] == "l3gs-opt/items@1"


def test_unreadable_files_are_item_errors(tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ItemInstanceError, match=r"^file: .*not valid JSON"):
        load_items(tmp_path / "bad.json")
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(ItemInstanceError, match=r"^file: .*not a readable NPZ"):
        load_items(tmp_path / "bad.npz")
    path = save_items(items_from_dict(base()), tmp_path / "i.npz")
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez(tmp_path / "x.npz", **arrays, extra=np.array([1]))
    with pytest.raises(ItemInstanceError, match=r"^extra: unknown key"):
        load_items(tmp_path / "x.npz")


json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-10, 10**20), st.floats(allow_nan=True),
                      st.text(max_size=3))
json_value = st.recursive(json_leaf, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
    st.text(max_size=5), inner, max_size=3), max_leaves=12)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(["schema", "bandwidth", "object", "cost", "utility", "group", "requires", "held",
                            "options", "names", "meta", "slot_s", "unknown"]), value=json_value)
def test_loader_never_raises_anything_but_a_named_item_error(key, value):
    data = {**base(), key: value}
    try:
        inst = items_from_dict(data)
    except ItemInstanceError as exc:
        assert exc.field.split(".")[0] in data or exc.field == "instance"
        assert str(exc).startswith(exc.field)
    else:
        assert isinstance(inst, ItemInstance)


@settings(max_examples=200, deadline=None)
@given(edges=st.lists(st.lists(st.integers(-2, 6), min_size=2, max_size=2), max_size=8),
       held=st.lists(st.integers(0, 1), min_size=4, max_size=4))
def test_random_edges_are_valid_or_named(edges, held):
    data = {**base(), "object": [0, 0, 0, 0], "group": [0, 1, 2, 3], "requires": edges, "held": held}
    try:
        inst = items_from_dict(data)
    except ItemInstanceError as exc:
        assert exc.field in ("requires", "held")
    else:  # valid: acyclic and held closed, as a plain check confirms
        assert all(inst.held[p] or not inst.held[c] for p, c in edges)
        pos = {int(i): k for k, i in enumerate(inst.order)}
        assert all(pos[p] < pos[c] for p, c in edges)


@settings(max_examples=100, deadline=None)
@given(text=st.text(max_size=60))
def test_loader_on_arbitrary_text(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("f") / "x.json"
    path.write_text(text)
    try:
        load_items(path)
    except ItemInstanceError:
        pass


# -- Problems I/II as special cases ------------------------------------------------------------------

def test_conversion_structure():
    inst = random_instance(np.random.default_rng(0), representation="layered", T=2, J=2, L=3)
    it = items_from_instance(inst)
    assert it.requires.tolist() == [[0, 1], [1, 2], [3, 4], [4, 5]] and it.G == 6
    sep = items_from_instance(inst.replace(representation="separate"))
    assert sep.requires.shape == (0, 2) and sep.members == ((0, 1, 2), (3, 4, 5))
    np.testing.assert_array_equal(sep.utility, inst.utility.reshape(2, 6))


@pytest.mark.parametrize("representation", ["layered", "separate"])
def test_evaluation_and_feasibility_agree_with_the_instance_rules(representation):
    """On every candidate schedule of small instances, feasible and objective agree with evaluate.py."""
    rng = np.random.default_rng(zlib.crc32(representation.encode()))
    for options in ALL_OPTIONS:
        inst = random_instance(rng, representation=representation, options=options, T=2, J=2, L=2, held_p=0.3)
        it = items_from_instance(inst)
        unheld = [(j, l) for j in range(2) for l in range(2) if not inst.held[j, l]]
        for pick in itertools.product([None, 0, 1], repeat=len(unheld)):
            chunks = [(j, l, t) for (j, l), t in zip(unheld, pick) if t is not None]
            items = [(j, j * 2 + l, t) for j, l, t in chunks]
            assert instance_arrivals(items, 2) == chunks
            assert (not item_violations(it, items)) == (not feasibility_violations(inst, chunks)), chunks
            if not item_violations(it, items):
                assert close(evaluate_items(it, items), evaluate_objective(inst, chunks))


@pytest.mark.parametrize("options", ALL_OPTIONS, ids=option_id)
@pytest.mark.parametrize("representation", ["layered", "separate"])
def test_problems_i_ii_are_special_cases(representation, options):
    """Same optimum from the Problem I/II model, its brute force, the item ILP and the item brute force."""
    rng = np.random.default_rng(zlib.crc32(f"{representation}-{option_id(options)}".encode()))
    for trial in range(4):
        inst = random_instance(rng, representation=representation, options=options, T=3, J=2, L=2,
                               held_p=0.3 if trial % 2 else 0.0)
        it = items_from_instance(inst)
        ref = solve(inst, "brute")
        assert close(solve(inst, "ilp").objective, ref.objective)
        assert close(solve(it, "brute").objective, ref.objective)
        for presolve in (True, False):
            sol = solve(it, "ilp", presolve=presolve)
            assert sol.status is Status.OPTIMAL and sol.problem == "items", sol.message
            assert close(sol.objective, ref.objective), (presolve, inst.to_dict())
            back = instance_arrivals(sol.arrivals, inst.L)
            assert not feasibility_violations(inst, back)
            assert close(evaluate_objective(inst, back), sol.objective)


@pytest.mark.parametrize("representation", ["layered", "separate"])
def test_special_case_single_slot_and_rolling(representation):
    """Per-slot MCKP and rolling schedulers on the item form reproduce those of Problems I/II."""
    rng = np.random.default_rng(11)
    for options in ALL_OPTIONS:
        inst = random_instance(rng, representation=representation, options=options, T=3, J=3, L=3, held_p=0.3)
        it = items_from_instance(inst)
        for slot in range(inst.T):
            ref = solve(inst, "bb", slot=slot).objective
            for method in ("bb", "dp", "ilp"):
                assert close(solve(it, method, slot=slot).objective, ref), (method, slot)
        # Same options in the same order: the schedulers take the same decisions.
        for method in ("rolling:bb", "rolling-future:bb"):
            assert close(solve(it, method).objective, solve(inst, method).objective), method


# -- the general form against brute force ------------------------------------------------------------

@pytest.mark.parametrize("options", ALL_OPTIONS, ids=option_id)
@pytest.mark.parametrize("shape", SHAPES)
def test_item_ilp_equals_brute_force(shape, options):
    rng = np.random.default_rng(zlib.crc32(f"{shape}-{option_id(options)}".encode()))
    for trial in range(4):
        inst = random_items(rng, shape, T=2, options=options, held_p=0.35 if trial % 2 else 0.0)
        ref = solve_items_brute_force(inst)
        assert items_feasible(inst, ref.arrivals)
        for presolve in (True, False):
            sol = solve(inst, "ilp", presolve=presolve)
            assert sol.status is Status.OPTIMAL, sol.message
            assert close(sol.objective, ref.objective), (presolve, inst.to_dict())
            assert items_feasible(inst, sol.arrivals)
        lp = solve(inst, "lp")
        assert lp.bound >= ref.objective - 1e-9 and lp.arrivals == ()


@pytest.mark.parametrize("backend", [b.value for b in Backend])
def test_every_backend_solves_the_item_form(backend):
    rng = np.random.default_rng(5)
    for shape, options in zip(SHAPES, (ALL_OPTIONS[0], ALL_OPTIONS[3], ALL_OPTIONS[6])):
        inst = random_items(rng, shape, T=2, options=options, held_p=0.3)
        ref = solve_items_brute_force(inst)
        sol = solve(inst, "ilp", backend=backend)
        assert sol.status is Status.OPTIMAL and sol.backend == backend, sol.message
        assert close(sol.objective, ref.objective) and items_feasible(inst, sol.arrivals)
        one = solve(inst, "ilp", backend=backend, slot=1)
        assert close(one.objective, solve_items_brute_force(inst, slot=1).objective)


@pytest.mark.parametrize("options", ALL_OPTIONS[:4], ids=option_id)
@pytest.mark.parametrize("shape", SHAPES)
def test_per_slot_mckp_equals_brute_force(shape, options):
    rng = np.random.default_rng(zlib.crc32(f"slot-{shape}-{option_id(options)}".encode()))
    for _ in range(5):
        inst = random_items(rng, shape, T=2, options=options, held_p=0.3)
        for slot in range(inst.T):
            ref = solve_items_brute_force(inst, slot=slot)
            for method in ("bb", "dp", "ilp"):
                sol = solve(inst, method, slot=slot)
                assert sol.problem == "MCKP" and sol.slot == slot and sol.status is Status.OPTIMAL
                assert close(sol.objective, ref.objective), (method, slot, inst.to_dict())
                assert items_feasible(inst, sol.arrivals, slot=slot)
                assert all(t == slot for _, _, t in sol.arrivals)
            for method in ("greedy", "fptas:0.1"):
                sol = solve(inst, method, slot=slot)
                assert items_feasible(inst, sol.arrivals, slot=slot)
                assert sol.objective <= ref.objective + 1e-9 <= sol.bound + 2e-9
            assert solve(inst, "fptas:0.1", slot=slot).objective >= 0.9 * ref.objective - 1e-9


@pytest.mark.parametrize("options", [o for o in ALL_OPTIONS if o.availability == "same_slot"], ids=option_id)
@pytest.mark.parametrize("shape", SHAPES)
def test_rolling_at_one_slot_is_exact(shape, options):
    rng = np.random.default_rng(zlib.crc32(f"roll-{shape}-{option_id(options)}".encode()))
    for _ in range(4):
        inst = random_items(rng, shape, T=1, options=options, held_p=0.3)
        ref = solve(inst, "ilp")
        sol = solve(inst, "rolling:bb")
        assert sol.status is Status.OPTIMAL and close(sol.objective, ref.objective)
        assert close(solve_items_brute_force(inst).objective, ref.objective)


@pytest.mark.parametrize("options", ALL_OPTIONS, ids=option_id)
def test_schedulers_are_feasible_and_below_the_optimum(options):
    rng = np.random.default_rng(zlib.crc32(f"sched-{option_id(options)}".encode()))
    for shape in SHAPES:
        inst = random_items(rng, shape, T=4, options=options, held_p=0.2)
        best = solve(inst, "ilp")
        for method in ("rolling:bb", "rolling-future:greedy", "rolling:dp", "mpc:2"):
            sol = solve(inst, method)
            assert items_feasible(inst, sol.arrivals), (method, sol.message)
            assert sol.objective <= best.objective + 1e-9 <= sol.bound + 1e-6, method
        assert close(solve(inst, "mpc:4").objective, best.objective)  # the window is the horizon


# -- presolve ------------------------------------------------------------------------------------------

def test_presolve_drops_what_cannot_matter():
    # Object 0: a chain 0 -> 1 -> 2 where item 1 never fits (so 2 cannot come either); item 3 is worth
    # nothing and nothing requires it; item 4 is held. Slot 1 has no bandwidth.
    inst = ItemInstance(bandwidth=[4, 0], object=[0, 0, 0, 0, 1], cost=[2, 9, 1, 1, 3],
                        utility=[[1.0, 1.0, 1.0, 0.0, 0.5], [1.0, 1.0, 5.0, 0.0, 0.5]],
                        requires=[[0, 1], [1, 2]], held=[0, 0, 0, 0, 1])
    red = presolve_items(inst)
    assert red.active.tolist() == [True, False, False, False, False]
    assert red.stats["never_fit"] == 2 and red.stats["no_utility"] == 1 and red.stats["held"] == 1
    assert red.arrive[:, 1].sum() == 0
    sol = solve(inst, "ilp")
    naive = solve(inst, "ilp", presolve=False)
    assert sol.size_after.variables < naive.size_after.variables == sol.size_before.variables
    assert close(sol.objective, naive.objective) and close(sol.objective, solve_items_brute_force(inst).objective)


def test_models_report_sizes():
    inst = random_items(np.random.default_rng(2), "distill", T=3, held_p=0.3)
    model = build_items_model(inst)
    assert model.problem == "items" and "active_items" in model.stats
    assert all(name[0] in "xywr" for name in model.var_names)
    one = build_items_model(inst, slot=2)
    assert one.problem == "MCKP" and all(t == 2 for _, chunks in one.decode for _, _, t in chunks)


# -- the shapes -----------------------------------------------------------------------------------------

def test_distill_shape():
    T, J, L = 2, 2, 3
    present = np.array([[True, False, True], [True, True, True]])
    inst = distill_items(np.full((J, L), 4), np.full((J, L), 2), np.ones((T, J, L)), np.ones((T, J, L)), [10, 10],
                         present=present)
    assert inst.N == 2 * int(present.sum()) and inst.G == inst.N   # all additive
    assert inst.names[:4] == ("o0_l0_compact", "o0_l0_sh_upgrade", "o0_l2_compact", "o0_l2_sh_upgrade")
    name = {n: i for i, n in enumerate(inst.names)}
    edges = {(inst.names[p], inst.names[c]) for p, c in inst.requires.tolist()}
    assert ("o0_l0_compact", "o0_l2_compact") in edges        # the absent layer 1 is skipped
    assert ("o1_l1_compact", "o1_l1_sh_upgrade") in edges
    assert not any(p.endswith("upgrade") for p, _ in edges)   # an upgrade requires no upgrade
    # Upgrading layer 0 alone, without the layers above, is a valid schedule.
    up = name["o1_l0_sh_upgrade"]
    assert items_feasible(inst, [(1, name["o1_l0_compact"], 0), (1, up, 1)])
    assert not items_feasible(inst, [(1, name["o1_l1_compact"], 0)])


def test_hierarchy_shape():
    cost = np.array([[3, 5, 9], [2, 4, 8]])
    utility = np.random.default_rng(0).random((2, 2, 3))
    present = np.array([[True, True, True], [True, False, True]])
    inst = hierarchy_items(cost, utility, [10, 10], present=present, held=[[1, 0, 0], [0, 0, 0]])
    assert inst.members == ((0, 1, 2), (3, 4)) and inst.requires.shape == (0, 2)
    assert inst.cost.tolist() == [3, 5, 9, 2, 8] and inst.names[4] == "o1_l2_full"
    # A version replaces the held one: the object shows the better of the two.
    value = evaluate_items(inst, [(0, 1, 0)])
    assert close(value, sum(max(utility[t, 0, 0], utility[t, 0, 1]) for t in range(2)))



@pytest.mark.parametrize("build", ["distill", "hierarchy"])
def test_variant_masks_are_zero_or_one(build):
    """``present`` and the held masks of the bundle variants take 0/1 numbers (floats too), and a
    2 is named by field and index: it was once read as True."""
    cost, T = np.array([[3, 5], [2, 4]]), 2
    utility = np.ones((T, 2, 2))

    def make(**masks):
        if build == "distill":
            return distill_items(cost, cost, utility, utility, [10, 10], **masks)
        return hierarchy_items(cost, utility, [10, 10], **masks)

    held = "held_compact" if build == "distill" else "held"
    assert make(present=[[1.0, 1.0], [1.0, 0.0]]).N == make(present=[[True, True], [True, False]]).N
    with pytest.raises(ItemInstanceError, match=r"^present\[0\]\[1\] = 2: must be 0 or 1$"):
        make(present=[[1, 2], [1, 1]])
    with pytest.raises(ItemInstanceError, match=rf"^{held}\[1\]\[0\] = -1: must be 0 or 1$"):
        make(**{held: [[0, 0], [-1, 0]]})
    with pytest.raises(ItemInstanceError, match=r"^present: has shape \(2,\), expected \(J, L\) = \(2, 2\)$"):
        make(present=[1, 1])


# -- solver limits and dispatch -------------------------------------------------------------------------

def test_closed_sets_enumerate_downsets_and_cap():
    inst = distill_items(np.full((1, 3), 2), np.ones((1, 3)), np.ones((1, 1, 3)), np.ones((1, 1, 3)), [5])
    held = np.zeros(inst.N, dtype=bool)
    sets = closed_sets(inst, list(map(int, inst.order)), held, held)
    # compact prefix of k layers plus any subset of their upgrades: sum_k 2^k for k = 1..3.
    assert len(sets) == 2 + 4 + 8
    brute = [S for r in range(1, inst.N + 1) for S in itertools.combinations(range(inst.N), r)
             if all(p in S for i in S for p in inst.parents[i])]
    assert sorted(sets) == sorted(brute)
    with pytest.raises(SolveError, match=r"object 0: more than 5 precedence-closed item sets"):
        closed_sets(inst, list(map(int, inst.order)), held, held, limit=5)
    assert MAX_CLOSED_SETS >= 2**16


def test_dispatch_errors():
    inst = random_items(np.random.default_rng(1), "general", T=2)
    with pytest.raises(SolveError, match=r"method 'bb' solves one slot's MCKP: pass slot"):
        solve(inst, "bb")
    with pytest.raises(SolveError, match=r"method 'slope' does not take an item instance"):
        solve(inst, "slope")
    with pytest.raises(SolveError, match=r"form 'gap'"):
        solve(inst, "ilp", form="gap")
    with pytest.raises(SolveError, match=r"slot does not apply"):
        solve(inst, "rolling:bb", slot=0)
    with pytest.raises(SolveError, match=r"slot = 5"):
        solve(inst, "ilp", slot=5)


def test_finish_repairs_an_infeasible_schedule():
    inst = ItemInstance(bandwidth=[3], object=[0, 0, 1], cost=[2, 1, 2], utility=[[1.0, 1.0, 0.1]],
                        requires=[[0, 1]])
    bad = [(0, 1, 0), (1, 2, 0), (0, 0, 0)]   # 5 bytes in a 3-byte slot
    sol = finish_items_solution(inst, bad, problem="items", method="test", status=Status.OPTIMAL, bound=2.0,
                                runtime_s=0.0)
    assert sol.status is Status.FEASIBLE and "repaired" in sol.message
    assert items_feasible(inst, sol.arrivals) and close(sol.objective, 2.0)
    orphan = finish_items_solution(inst, [(0, 1, 0)], problem="items", method="test", status=Status.FEASIBLE,
                                   bound=None, runtime_s=0.0)
    assert orphan.arrivals == ()


# -- property: answers are always feasible -------------------------------------------------------------

@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**32 - 1), shape=st.sampled_from(SHAPES), options=st.sampled_from(ALL_OPTIONS),
       held_p=st.sampled_from([0.0, 0.4]))
def test_answers_always_feasible(seed, shape, options, held_p):
    inst = random_items(np.random.default_rng(seed), shape, T=3, options=options, held_p=held_p)
    best = solve(inst, "ilp")
    assert best.status is Status.OPTIMAL and items_feasible(inst, best.arrivals)
    for method in ("rolling:bb", "rolling:greedy"):
        sol = solve(inst, method, options={"bound": False})
        assert items_feasible(inst, sol.arrivals) and sol.objective <= best.objective + 1e-9
    sol = solve(inst, "greedy", slot=1)
    assert items_feasible(inst, sol.arrivals, slot=1)


def test_regression_cumulative_budget_rows_dropped_as_redundant():
    """models/_common.add_budget summed every (chunk, slot) arrival variable against the last slot's
    cumulative budget and dropped the rows: two chunks that fit slot 0's 3 bytes one by one (3 + 1
    bytes) then both arrived there, and the answer came back repaired, not optimal."""
    inst = random_instance(np.random.default_rng(0), T=2, J=2, L=1, options=Options(budget="cumulative"))
    inst = inst.replace(bandwidth=[3, 14], cost=[[3], [1]], utility=np.ones((2, 2, 1)))
    for problem in (inst, items_from_instance(inst)):
        sol = solve(problem, "ilp")
        assert sol.status is Status.OPTIMAL and close(sol.objective, 3.0), sol.message


def test_strict_precedence_sets_hold_only_children_of_held_items():
    opts = Options(same_slot_layers=False)
    inst = distill_items(np.full((1, 2), 2), np.ones((1, 2)), np.ones((1, 1, 2)), np.ones((1, 1, 2)), [9],
                         options=opts, held_compact=[[True, False]])
    held = inst.held.copy()
    sets = closed_sets(inst, list(map(int, inst.order)), held, held)
    # Held: compact of layer 0. Strict: only its direct children (its upgrade, the next compact) may come.
    assert sorted(sets) == [(1,), (1, 2), (2,)]


def test_shape_errors_name_the_grid_index():
    ones = np.ones((1, 2, 2))
    with pytest.raises(ItemInstanceError, match=r"^upgrade_cost\[1\]\[0\] = 0: must be a positive integer"):
        distill_items([[2, 2], [2, 2]], [[1, 1], [0, 1]], ones, ones, [5])
    # An absent cell may say 0 bytes and NaN utility: it makes no item.
    utility = np.ones((1, 2, 2))
    utility[0, 1, 0] = np.nan
    inst = distill_items([[2, 2], [2, 2]], [[1, 1], [0, 1]], ones, utility, [5], present=[[1, 1], [0, 1]])
    assert inst.N == 6
    bad = np.ones((1, 2, 3))
    bad[0, 1, 2] = -1.0
    with pytest.raises(ItemInstanceError, match=r"^utility\[0\]\[1\]\[2\] = -1\.0: must be finite and >= 0"):
        hierarchy_items(np.ones((2, 3), int), bad, [4])


@pytest.mark.parametrize("options", [o for o in ALL_OPTIONS if o.budget == "cumulative"], ids=option_id)
@pytest.mark.parametrize("shape", SHAPES)
def test_cumulative_event_slots_keep_the_optimum(shape, options):
    """Under one link presolve keeps only the slots where an item adds something (or an item
    requiring it needs it by): fewer pairs, brute force's optimum, on three slots with zeros."""
    rng = np.random.default_rng(zlib.crc32(f"events-{shape}-{option_id(options)}".encode()))
    dropped = 0
    for trial in range(4):
        inst = random_items(rng, shape, T=3, options=options, held_p=0.35 if trial % 2 else 0.0)
        dropped += int(presolve_items(inst, enabled=False).arrive.sum() - presolve_items(inst).arrive.sum())
        ref = solve_items_brute_force(inst)
        sol = solve(inst, "ilp")
        assert sol.status is Status.OPTIMAL and close(sol.objective, ref.objective), inst.to_dict()
        assert items_feasible(inst, sol.arrivals)
    assert dropped > 0
