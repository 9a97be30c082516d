"""Bad input to the instance forms and the simulator config, sweep s20 (C25, E2, E3, E4, E6, E7, D17):
each fault is the module's own error naming the field and index, never a raw Python exception."""

from __future__ import annotations

import math

import numpy as np
import pytest

from l3gs_opt.problem.instance import Instance, InstanceError
from l3gs_opt.problem.instance_io import instance_from_dict
from l3gs_opt.problem.items import ItemInstance, ItemInstanceError
from l3gs_opt.problem.items_io import items_from_dict
from l3gs_opt.simulator.config import SimConfig, SimulationError


def _instance_dict(**changes):
    return {"schema": "l3gs-opt/instance@1", "representation": "layered", "bandwidth": [10, 10],
            "cost": [[1, 2], [3, 4]], "utility": [[[1.0, 0.5], [1.0, 0.5]]] * 2, **changes}


def _items_dict(**changes):
    return {"schema": "l3gs-opt/items@1", "bandwidth": [10], "object": [0, 0], "cost": [1, 2],
            "utility": [[1.0, 0.5]], **changes}


def _deep(levels: int) -> list:
    top = inner = []
    for _ in range(levels):
        inner.append([])
        inner = inner[0]
    return top


# ---------------------------------------------------------------------- C25: lists nested 100,000 deep
@pytest.mark.parametrize("field, match", [
    ("bandwidth", r"^bandwidth\[0\] = \[\[\[.*: must be a number, not a list \(bandwidth nests 1 level of lists"),
    ("cost", r"^cost\[0\]\[0\] = \[\[\[.*: must be a number, not a list \(cost nests 2 levels"),
    ("utility", r"^utility\[0\]\[0\]\[0\] = \[\[\[.*: must be a number, not a list"),
    ("schema", r"^schema: \[\[\[.*: expected 'l3gs-opt/instance@1'$"),
    ("slot_s", r"^slot_s: \[\[\[.*: must be a positive number of seconds$"),
])
def test_deeply_nested_list_is_refused_by_name(field, match):
    with pytest.raises(InstanceError, match=match):
        instance_from_dict(_instance_dict(**{field: _deep(100_000)}))


def test_deeply_nested_name_and_huge_int_are_shown_briefly():
    with pytest.raises(InstanceError, match=r"^names\[1\]: \[\[\[.*: must be a string$"):
        instance_from_dict(_instance_dict(names=["a", _deep(100_000)]))
    with pytest.raises(InstanceError, match=r"^bandwidth\[1\] = <int too long to show>: out of range$"):
        instance_from_dict(_instance_dict(bandwidth=[10, 10**5000]))


# ---------------------------------------------------------------------- E2: numpy scalars in a dict
def test_instance_from_dict_takes_numpy_scalars_as_numbers():
    inst = instance_from_dict(_instance_dict(bandwidth=[np.int64(10), np.uint8(10)],
                                             cost=[[np.int32(1), np.float64(2.0)], [3, 4]],
                                             utility=[[[np.float32(1.0), 0.5], [1.0, np.int64(0)]]] * 2,
                                             slot_s=np.float64(0.5)))
    assert inst.bandwidth.tolist() == [10, 10] and inst.cost.tolist() == [[1, 2], [3, 4]]
    assert inst.cost.dtype == np.int64 and inst.utility[0, 1, 1] == 0.0 and inst.slot_s == 0.5


def test_items_from_dict_takes_numpy_scalars_as_numbers():
    inst = items_from_dict(_items_dict(cost=[np.int64(1), 2], object=[np.int64(0), 0],
                                       utility=[[np.float64(1.0), 0.5]], requires=[[np.int64(0), 1]]))
    assert inst.cost.tolist() == [1, 2] and inst.parents[1] == (0,)


@pytest.mark.parametrize("value, match", [
    (np.bool_(True), r"^cost\[0\]\[1\] = np\.True_: must be a number$"),
    (np.float64(1.5), r"^cost\[0\]\[1\] = 1\.5: must be a positive integer \(bytes\); fractional bytes$"),
    (np.uint64(2**64 - 1), r"^cost\[0\]\[1\] = 18446744073709551615: out of range$"),
])
def test_numpy_scalars_follow_the_rules_of_the_numbers_they_hold(value, match):
    with pytest.raises(InstanceError, match=match):
        instance_from_dict(_instance_dict(cost=[[1, value], [3, 4]]))


# ---------------------------------------------------------------------- E3: ints beyond int64 in Instance
@pytest.mark.parametrize("field, value, match", [
    ("bandwidth", [10, 10**30], r"^bandwidth\[1\] = 1000.*: out of range: must be at most 2\*\*53 = \d+ bytes$"),
    ("bandwidth", [10, -10**30], r"^bandwidth\[1\] = -1000.*: out of range: must be a non-negative integer"),
    ("cost", [[1, 2], [10**30, 4]], r"^cost\[1\]\[0\] = 1000.*: out of range: must be at most 2\*\*53"),
    ("cost", [[1, 2], [3, None]], r"^cost\[1\]\[1\] = None: must be a positive integer \(bytes\)$"),
])
def test_instance_names_an_int_out_of_range(field, value, match):
    fields = dict(representation="layered", bandwidth=[10, 10], cost=[[1, 2], [3, 4]],
                  utility=[[[1.0, 0.5], [1.0, 0.5]]] * 2)
    with pytest.raises(InstanceError, match=match):
        Instance(**{**fields, field: value})


def test_item_instance_names_a_cost_out_of_range():
    with pytest.raises(ItemInstanceError, match=r"^cost\[1\] = 1000.*: out of range: must be at most 2\*\*53"):
        ItemInstance(bandwidth=[10], object=[0, 0], cost=[1, 10**30], utility=[[1.0, 0.5]])


# ---------------------------------------------------------------------- E4: names given as one str/bytes
@pytest.mark.parametrize("names, got", [(b"ab", "bytes"), (bytearray(b"ab"), "bytearray"), ("ab", "str")])
def test_names_as_one_string_or_bytes_are_refused(names, got):
    with pytest.raises(InstanceError, match=rf"^names: must be a list of J strings, got {got}$"):
        Instance("layered", [10], [[1], [2]], [[[1.0], [1.0]]], names=names)
    with pytest.raises(ItemInstanceError, match=rf"^names: must be a list of N strings, got {got}$"):
        ItemInstance(bandwidth=[10], object=[0, 0], cost=[1, 2], utility=[[1.0, 0.5]], names=names)


# ---------------------------------------------------------------------- E6: a cycle through 3000 items
def test_long_precedence_cycle_message_is_cut():
    n = 3000
    with pytest.raises(ItemInstanceError) as info:
        ItemInstance(bandwidth=[10], object=[0] * n, cost=[1] * n, utility=[[1.0] * n],
                     requires=[[i, (i + 1) % n] for i in range(n)])
    message = str(info.value)
    assert message.startswith("requires: cycle through item 0: 1 -> 2 -> ") and len(message) < 200
    assert message.endswith(f" -> 10 -> ... ({n} items) (parent -> child)")


# ---------------------------------------------------------------------- D17: names are labels
def test_duplicate_names_are_labels_and_allowed():
    # Names label objects and items in reports and conversions; nothing looks them up.
    assert Instance("layered", [10], [[1], [2]], [[[1.0], [1.0]]], names=["a", "a"]).names == ("a", "a")
    assert items_from_dict(_items_dict(names=["a", "a"])).names == ("a", "a")


# ---------------------------------------------------------------------- E7: SimConfig time limit and pose start
@pytest.mark.parametrize("value, stored", [(math.inf, None), (np.float64(math.inf), None), (None, None),
                                           (5, 5.0), (np.float32(2.5), 2.5), (10**400, None)])
def test_simconfig_time_limit_follows_solve(value, stored):
    assert SimConfig(time_limit_s=value).time_limit_s == stored


@pytest.mark.parametrize("value", [-math.inf, math.nan, 0, -1, True, "5"])
def test_simconfig_refuses_bad_time_limit(value):
    with pytest.raises(SimulationError, match=r"^time_limit_s: .*: must be .*\(or inf for no limit\)$"):
        SimConfig(time_limit_s=value)


@pytest.mark.parametrize("value", [np.int64(3), np.float32(3.0), np.uint16(3)])
def test_simconfig_pose_start_takes_numpy_scalars(value):
    assert SimConfig(pose_start_s=value).pose_start_s == 3


@pytest.mark.parametrize("value", [np.bool_(False), True, np.int64(-1), np.float64(math.nan)])
def test_simconfig_pose_start_refuses_bools_and_bad_numbers(value):
    with pytest.raises(SimulationError, match=r"^pose_start_s: .*: must be a number >= 0 \(seconds\)$"):
        SimConfig(pose_start_s=value)
