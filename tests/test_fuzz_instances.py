"""Property-based fuzz test of the instance readers (issue 19): ``load_instance``, ``load_items`` and
``load_problem`` on JSON and NPZ files, from bytes mutated from valid files and from generated
structures. Every file gives either a valid instance or the project's own error type with a
non-empty ``field`` - never another exception, never a hang.

A hang is caught twice: hypothesis' ``deadline`` (per example, generous because two cores are
shared) and a SIGALRM watchdog (``alarm``) that interrupts a read stuck for :data:`WATCHDOG_S` seconds.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from datetime import timedelta
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from l3gs_opt import Instance, InstanceError, ItemInstance, ItemInstanceError
from l3gs_opt.problem.instance_io import load_instance, save_instance
from l3gs_opt.problem.items_io import load_items, load_problem, save_items

from test_fuzz_readers import alarm   # the SIGALRM watchdog the other readers' fuzz test uses

#: Seconds one read may take before the watchdog calls it a hang (a valid tiny file reads in ms).
WATCHDOG_S = 20
#: Examples per test (FUZZ_N=3000 for a longer hunt).
SETTINGS = settings(max_examples=int(os.environ.get("FUZZ_N", 150)), deadline=timedelta(seconds=5),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])

INSTANCE = {"schema": "l3gs-opt/instance@1", "representation": "layered", "bandwidth": [10, 0, 7],
            "cost": [[3, 4], [2, 5]], "held": [[1, 0], [0, 0]], "names": ["a", "b"],
            "options": {"availability": "next_slot", "budget": "cumulative"}, "meta": {"trace": "x", "w": [0, 3]},
            "utility": [[[1.0, 0.5], [0.2, 0.1]], [[1.0, 0.5], [0.0, 0.0]], [[0.3, 0.5], [2.0, 1.0]]]}
ITEMS = {"schema": "l3gs-opt/items@1", "bandwidth": [5, 3], "object": [0, 0, 1, 1], "cost": [2, 1, 3, 4],
         "utility": [[1.0, 0.5, 0.3, 0.6], [1.0, 0.5, 0.3, 0.7]], "group": [0, 1, 2, 2], "requires": [[0, 1]],
         "held": [1, 0, 0, 0], "meta": {"variant": "distill"}}
INSTANCE_KEYS = ["schema", "representation", "bandwidth", "slot_s", "cost", "utility", "held", "options", "names",
                 "meta"]
ITEM_KEYS = ["schema", "bandwidth", "slot_s", "object", "cost", "utility", "group", "requires", "held", "options",
             "names", "meta"]
#: (loader, the error type it must raise, the result types it may return)
LOADERS = [(load_instance, InstanceError, (Instance,)), (load_items, ItemInstanceError, (ItemInstance,)),
           (load_problem, InstanceError, (Instance, ItemInstance))]


def check_file(path: Path) -> None:
    """Every loader on ``path``: a valid object or its own named error, nothing else, no hang."""
    for load, error, kinds in LOADERS:
        with alarm(WATCHDOG_S):
            try:
                result = load(path)
            except error as exc:
                assert isinstance(exc.field, str) and exc.field, f"{load.__name__}: error without a field: {exc!r}"
                assert str(exc).startswith(exc.field)
            except InstanceError as exc:
                # load_items may only raise ItemInstanceError; load_instance/load_problem InstanceError.
                raise AssertionError(f"{load.__name__} raised {type(exc).__name__}, expected {error.__name__}: "
                                     f"{exc}") from None
            else:
                assert isinstance(result, kinds), f"{load.__name__} returned {type(result).__name__}"


def check_bytes(path: Path, data: bytes) -> None:
    path.write_bytes(data)
    check_file(path)


def json_bytes(data: dict) -> bytes:
    return json.dumps(data).encode()


def npz_bytes(data: dict) -> bytes:
    """A valid NPZ file of ``data`` (either form), as the writers make it."""
    buf = io.BytesIO()
    is_items = data["schema"] == ITEMS["schema"]
    dims = ("bandwidth", "object", "cost", "utility", "group", "held", "requires") if is_items else \
        ("bandwidth", "cost", "utility", "held")
    arrays = {k: np.asarray(v) if k in dims else np.array(json.dumps(v)) for k, v in data.items()}
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


# -- mutated bytes -----------------------------------------------------------------------------------

#: Tokens spliced into JSON text: each a known way in which readers used to fail.
TOKENS = [b"[", b"]", b"{", b"}", b",", b":", b"null", b"true", b"NaN", b"Infinity", b"-Infinity", b"1e400",
          b"9007199254740993", b"9007199254740993.0", b"-1", b"0.5", b"\"x\"", b"\"meta\": 1,", b"[" * 80,
          b"\"cost\": [1],", b"\"\\ud800\"", b"\xff", b"1" * 30]


@st.composite
def mutated(draw, source: bytes, tokens: list[bytes]) -> bytes:
    data = bytearray(source)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "insert", "delete", "truncate", "token"]))
        pos = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "flip" and data:
            data[pos] = draw(st.integers(0, 255))
        elif op == "insert":
            data[pos:pos] = bytes([draw(st.integers(0, 255))])
        elif op == "delete" and data:
            del data[pos:pos + draw(st.integers(1, 8))]
        elif op == "truncate":
            del data[pos:]
        elif tokens:
            data[pos:pos] = draw(st.sampled_from(tokens))
    return bytes(data)


@SETTINGS
@given(data=st.sampled_from([INSTANCE, ITEMS]).flatmap(lambda d: mutated(json_bytes(d), TOKENS)))
def test_fuzz_mutated_json(tmp_path, data):
    check_bytes(tmp_path / "f.json", data)


@SETTINGS
@given(data=st.sampled_from([INSTANCE, ITEMS]).flatmap(lambda d: mutated(npz_bytes(d), [b"\0" * 8, b"\xff" * 8])))
def test_fuzz_mutated_npz(tmp_path, data):
    check_bytes(tmp_path / "f.npz", data)


@st.composite
def mutated_npy_member(draw) -> bytes:
    """A valid NPZ whose one member's ``.npy`` bytes (header included) are mutated, stored
    uncompressed so that the zip's own CRC is recomputed and the member reaches the array reader."""
    source = draw(st.sampled_from([INSTANCE, ITEMS]))
    with zipfile.ZipFile(io.BytesIO(npz_bytes(source))) as zf:
        members = {info.filename: zf.read(info) for info in zf.infolist()}
    name = draw(st.sampled_from(sorted(members)))
    members[name] = draw(mutated(members[name], [b"(1000000, 1000000)", b"'|O'", b"'<U9'", b"True", b"-1"]))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for member, payload in members.items():
            zf.writestr(member, payload)
    return buf.getvalue()


@SETTINGS
@given(data=mutated_npy_member())
def test_fuzz_mutated_npy_members(tmp_path, data):
    check_bytes(tmp_path / "f.npz", data)


# -- generated structures ----------------------------------------------------------------------------

json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-3, 10), st.integers(-2**70, 2**70),
                      st.floats(allow_nan=False, allow_infinity=False), st.text(max_size=4),
                      st.sampled_from([2**53, 2**53 + 1, 2.0**53, 1e308, 5e-324, -0.0, 0.5, "layered",
                                       "l3gs-opt/instance@1", "l3gs-opt/items@1"]))
json_value = st.recursive(json_leaf, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
    st.text(max_size=5), inner, max_size=3), max_leaves=16)


def edit(draw, fields: dict, source: dict, values) -> dict:
    """``fields`` (of the valid file ``source``) with up to three keys, known or not, replaced by a
    drawn value or dropped."""
    keys = INSTANCE_KEYS if source["schema"] == INSTANCE["schema"] else ITEM_KEYS
    for key in draw(st.lists(st.sampled_from([*keys, "unknown"]), max_size=3)):
        if draw(st.booleans()):
            fields[key] = draw(values)
        else:
            fields.pop(key, None)
    return fields


@st.composite
def structure(draw) -> dict:
    """A valid file with some keys replaced, dropped or added."""
    source = draw(st.sampled_from([INSTANCE, ITEMS]))
    return edit(draw, dict(source), source, json_value)


@SETTINGS
@given(data=structure())
def test_fuzz_generated_json(tmp_path, data):
    check_bytes(tmp_path / "f.json", json_bytes(data))


arrays = st.one_of(
    st.integers(-2, 3).flatmap(lambda n: st.just(np.arange(max(n, 0)))),
    st.lists(st.integers(-2**63, 2**63 - 1), max_size=4).map(lambda v: np.array(v, dtype=np.int64)),
    st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), max_size=4).map(np.array),
    st.lists(st.integers(0, 2**64 - 1), max_size=3).map(lambda v: np.array(v, dtype=np.uint64)),
    st.sampled_from([np.zeros((2, 0, 3)), np.ones((3, 2, 2)), np.ones((2, 4)), np.array(True), np.array(3.5),
                     np.array(["a", "b"]), np.array("not json"), np.array('"layered"'), np.array("[[[[1]]]]"),
                     np.zeros(3, dtype=np.complex128), np.zeros(2, dtype=[("a", "<i4")]), np.array(b"bytes"),
                     np.array([[0, 1]]), np.array([[1, 1]]), np.array([2**53 + 1, 0], dtype=np.uint64)]),
)


@st.composite
def npz_structure(draw) -> bytes:
    """A valid NPZ with some members replaced by arrays of other shapes and dtypes, dropped or added."""
    source = draw(st.sampled_from([INSTANCE, ITEMS]))
    with zipfile.ZipFile(io.BytesIO(npz_bytes(source))) as zf:
        members = {info.filename[:-4]: np.load(io.BytesIO(zf.read(info))) for info in zf.infolist()}
    buf = io.BytesIO()
    np.savez(buf, **edit(draw, members, source, arrays))
    return buf.getvalue()


@SETTINGS
@given(data=npz_structure())
def test_fuzz_generated_npz(tmp_path, data):
    check_bytes(tmp_path / "f.npz", data)


@pytest.mark.parametrize("data", [INSTANCE, ITEMS], ids=["instance", "items"])
@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_fuzz_sources_are_valid(tmp_path, data, suffix):
    """The files the fuzzers start from load, and read back what the writers write."""
    path = tmp_path / f"f{suffix}"
    path.write_bytes(json_bytes(data) if suffix == ".json" else npz_bytes(data))
    inst = load_problem(path)
    assert isinstance(inst, ItemInstance if data is ITEMS else Instance)
    again = (save_items if data is ITEMS else save_instance)(inst, tmp_path / f"g{suffix}")
    assert load_problem(again).to_dict() == inst.to_dict()
