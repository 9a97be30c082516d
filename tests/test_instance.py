"""The instance contract: validation names the field and index; files round-trip."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3gs_opt import Instance, InstanceError, Options, instance_from_dict, load_instance, save_instance


def base() -> dict:
    return {
        "schema": "l3gs-opt/instance@1",
        "representation": "layered",
        "bandwidth": [10, 0, 7],
        "cost": [[3, 4], [2, 5]],
        "utility": [[[1.0, 0.5], [0.2, 0.1]], [[1.0, 0.5], [0.0, 0.0]], [[0.3, 0.5], [2.0, 1.0]]],
    }


@pytest.mark.parametrize("change, match", [
    ({"colour": 1}, r"^colour: unknown key"),
    ({"schema": "l3gs-opt/instance@2"}, r"^schema: .*expected 'l3gs-opt/instance@1'"),
    ({"representation": "stacked"}, r"^representation: 'stacked' is not one of layered, separate"),
    ({"bandwidth": [10, -1, 7]}, r"^bandwidth\[1\] = -1: must be a non-negative integer"),
    ({"bandwidth": [10, 1.5, 7]}, r"^bandwidth\[1\] = 1\.5: .*fractional bytes"),
    ({"bandwidth": []}, r"^bandwidth: must have at least one slot"),
    ({"cost": [[3, 4], [2, 0]]}, r"^cost\[1\]\[1\] = 0: must be a positive integer"),
    ({"cost": [[3, 4], [2]]}, r"^cost\[1\]: expected 2 entries \(layers\), got 1 \(cost\[0\] has 2\)"),
    ({"cost": [[3], [2, 4]]}, r"^cost\[1\]: expected 1 entries \(layers\), got 2 \(cost\[0\] has 1\)"),
    ({"cost": [[3, 4], [2, "5"]]}, r"^cost\[1\]\[1\] = '5': must be a number"),
    ({"cost": [[3, 4], [2, True]]}, r"^cost\[1\]\[1\] = True: must be a number"),
    ({"cost": [[3, 2**60], [2, 5]]}, r"^cost\[0\]\[1\] = .*at most 2\*\*53"),
    ({"utility": [[[1.0, 0.5], [0.2, 0.1]], [[1.0, 0.5], [0.0]], [[0.3, 0.5], [2.0, 1.0]]]},
     r"^utility\[1\]\[1\]: expected 2 entries \(layers\), got 1"),
    ({"utility": [[[1.0, 0.5], [0.2, 0.1]], [[1.0, 0.5], [0.0, 0.0]]]},
     r"^utility: has shape \(2, 2, 2\), expected \(T, J, L\) = \(3, 2, 2\)"),
    # Signed layer utilities are allowed in the layered form only (tests/test_signed_utilities.py).
    ({"representation": "separate",
      "utility": [[[1.0, -0.5], [0.2, 0.1]], [[1.0, 0.5], [0.0, 0.0]], [[0.3, 0.5], [2.0, 1.0]]]},
     r"^utility\[0\]\[0\]\[1\] = -0\.5: must be >= 0 \(a separate version's utility"),
    ({"utility": [[[1.0, float("nan")], [0.2, 0.1]], [[1.0, 0.5], [0.0, 0.0]], [[0.3, 0.5], [2.0, 1.0]]]},
     r"^utility\[0\]\[0\]\[1\] = nan: must be finite"),
    ({"utility": [[[1.0, 10**400], [0.2, 0.1]], [[1.0, 0.5], [0.0, 0.0]], [[0.3, 0.5], [2.0, 1.0]]]},
     r"^utility\[0\]\[0\]\[1\] = 1000.*: must be finite"),
    ({"held": [[0, 1], [0, 0]]}, r"^held\[0\]\[1\] = 1 but layer 0 below it is not held"),
    ({"held": [[2, 0], [0, 0]]}, r"^held\[0\]\[0\] = 2: must be 0 or 1"),
    ({"held": [[1, 0]]}, r"^held: has shape \(1, 2\), expected \(J, L\) = \(2, 2\)"),
    ({"options": {"budget": "weekly"}}, r"^options\.budget: 'weekly' is not one of per_slot, cumulative"),
    ({"options": {"availibility": "next_slot"}}, r"^options\.availibility: unknown option"),
    ({"options": {"same_slot_layers": "yes"}}, r"^options\.same_slot_layers: 'yes': must be true or false"),
    ({"slot_s": 0}, r"^slot_s: 0: must be a positive number of seconds"),
    ({"slot_s": 10**400}, r"^slot_s: 100000000000000000000\.\.\.: must be a positive number of seconds"),
    ({"names": ["a"]}, r"^names: has 1 entries, expected J = 2"),
    ({"names": ["a", 3]}, r"^names\[1\]: 3: must be a string"),
])
def test_bad_input_names_field_and_index(change, match):
    data = {**base(), **change}
    with pytest.raises(InstanceError, match=match):
        instance_from_dict(data)


def test_missing_key_is_named():
    data = base()
    del data["cost"]
    with pytest.raises(InstanceError, match=r"^cost: missing") as info:
        instance_from_dict(data)
    assert info.value.field == "cost"


def test_error_carries_field_and_index():
    data = {**base(), "cost": [[3, 4], [2, -5]]}
    with pytest.raises(InstanceError) as info:
        instance_from_dict(data)
    assert (info.value.field, info.value.index) == ("cost", (1, 1))


def test_separate_held_need_not_be_prefix():
    inst = instance_from_dict({**base(), "representation": "separate", "held": [[0, 1], [0, 0]]})
    assert inst.held.tolist() == [[False, True], [False, False]]


def test_empty_scene_and_integral_floats():
    inst = instance_from_dict({"schema": "l3gs-opt/instance@1", "representation": "layered",
                               "bandwidth": [5.0, 0], "cost": [], "utility": [[], []]})
    assert (inst.T, inst.J, inst.L) == (2, 0, 0)
    assert inst.bandwidth.dtype == np.int64 and inst.bandwidth.tolist() == [5, 0]


def test_instance_is_immutable():
    inst = instance_from_dict(base())
    with pytest.raises(ValueError):
        inst.cost[0, 0] = 9
    with pytest.raises(AttributeError):
        inst.representation = "separate"  # type: ignore[misc]


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_round_trip(tmp_path, suffix):
    inst = instance_from_dict({**base(), "held": [[1, 0], [0, 0]], "names": ["chair", "table"],
                               "options": {"availability": "next_slot", "budget": "cumulative"},
                               "meta": {"trace": "x", "window": [0, 3]}})
    path = save_instance(inst, tmp_path / f"i{suffix}")
    back = load_instance(path)
    assert back.to_dict() == inst.to_dict()
    np.testing.assert_array_equal(back.utility, inst.utility)
    assert back.options == Options(availability="next_slot", budget="cumulative")


def test_unreadable_files_are_instance_errors(tmp_path):
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(InstanceError, match=r"^file: .*not valid JSON"):
        load_instance(tmp_path / "bad.json")
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(InstanceError, match=r"^file: .*not a readable NPZ"):
        load_instance(tmp_path / "bad.npz")
    with pytest.raises(InstanceError, match=r"^file: .*no such file"):
        load_instance(tmp_path / "missing.json")


@pytest.mark.skipif(np.finfo(np.longdouble).max <= np.finfo(np.float64).max,
                    reason="this platform's long double has float64's range")
def test_a_long_double_beyond_float64_is_one_error_and_no_warning(tmp_path):
    data = {**base()}
    utility = np.asarray(data.pop("utility"), dtype=np.longdouble)
    utility[0, 1, 0] = np.longdouble("1e4000")
    np.savez(tmp_path / "i.npz", **{k: np.array(json.dumps(v)) for k, v in data.items()
                                     if k not in ("bandwidth", "cost")},
             bandwidth=np.asarray(data["bandwidth"]), cost=np.asarray(data["cost"]), utility=utility)
    with warnings.catch_warnings():
        warnings.simplefilter("error")   # numpy's cast warning was a second line before the error
        with pytest.raises(InstanceError, match=r"^utility\[0\]\[1\]\[0\] = inf: must be finite"):
            load_instance(tmp_path / "i.npz")


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_saving_under_a_file_says_so(tmp_path, suffix):
    (tmp_path / "afile").write_text("x")
    with pytest.raises(InstanceError, match=r"^file: .*afile/i\.(json|npz): cannot be written \(a file where a "
                                            r"folder is needed\)$"):
        save_instance(instance_from_dict(base()), tmp_path / "afile" / f"i{suffix}")


def test_an_integer_python_will_not_convert_is_one_named_error(tmp_path):
    # Python's json raises a bare ValueError (not a decoding error) past 4300 digits.
    digits = "9" * 5000
    (tmp_path / "big.json").write_text(json.dumps(base()).replace('"bandwidth": [', f'"bandwidth": [{digits}, ', 1))
    with pytest.raises(InstanceError, match=r"^file: .*an integer of 5000 digits"):
        load_instance(tmp_path / "big.json")
    (tmp_path / "neg.json").write_text(json.dumps({**base(), "meta": {"n": 0}}).replace('"n": 0', '"n": -1' + "0" * 4300))
    with pytest.raises(InstanceError, match=r"^file: .*an integer of 4301 digits"):
        load_instance(tmp_path / "neg.json")


def test_npz_unknown_key_rejected(tmp_path):
    inst = instance_from_dict(base())
    path = save_instance(inst, tmp_path / "i.npz")
    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files}
    np.savez(tmp_path / "j.npz", **arrays, extra=np.array([1]))
    with pytest.raises(InstanceError, match=r"^extra: unknown key"):
        load_instance(tmp_path / "j.npz")


# -- property tests: any mutation of a valid file is either valid or a named InstanceError ----------

json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-10, 10**20), st.floats(allow_nan=True),
                      st.text(max_size=3))
json_value = st.recursive(json_leaf, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
    st.text(max_size=5), inner, max_size=3), max_leaves=12)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(key=st.sampled_from(["schema", "representation", "bandwidth", "cost", "utility", "held", "options",
                            "names", "meta", "slot_s", "unknown"]), value=json_value)
def test_loader_never_raises_anything_but_instance_error(key, value):
    data = {**base(), key: value}
    try:
        inst = instance_from_dict(data)
    except InstanceError as exc:
        assert str(exc).split(":")[0].split("[")[0].split(".")[0] in data or str(exc).startswith("instance")
    else:
        assert isinstance(inst, Instance)


@settings(max_examples=100, deadline=None)
@given(text=st.text(max_size=60))
def test_loader_on_arbitrary_text(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("f") / "x.json"
    path.write_text(text)
    try:
        load_instance(path)
    except InstanceError:
        pass


def test_json_written_is_plain(tmp_path):
    path = save_instance(instance_from_dict(base()), tmp_path / "i.json")
    data = json.loads(path.read_text())
    assert data["schema"] == "l3gs-opt/instance@1" and "held" not in data


def test_replace_keeps_meta_and_copies_it():
    # Regression: replace() passed the stored read-only meta back in, and the JSON check refused it.
    base = Instance("layered", bandwidth=[5], cost=[[2]], utility=[[[1.0]]], meta={"trace": {"name": "t", "window": [0, 60]}})
    changed = base.replace(bandwidth=[7])
    assert changed.bandwidth.tolist() == [7]
    assert changed.meta == base.meta
    source = {"nested": [1, 2]}
    own = Instance("layered", bandwidth=[5], cost=[[2]], utility=[[[1.0]]], meta=source)
    source["nested"].append(3)
    assert own.meta["nested"] == [1, 2]
    with pytest.raises(InstanceError, match="meta"):
        base.replace(meta={"bad": float("nan")})
