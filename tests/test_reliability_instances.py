"""Issue 19, instance side: time limits and slots checked once (item 6); instance and item files read
within limits, never hanging (item 7); no traceback on deep JSON, odd NPZ members, a folder as output,
``compare --slot 99`` (item 8); exact byte counts, ``meta`` an object or absent, no duplicate keys
(item 9).

CLI tests run the real ``main`` and check exit code 2 and exactly one stderr line naming the field.
"""

from __future__ import annotations

import io
import json
import math
import os
import struct
import threading
import zipfile
from pathlib import Path

import numpy as np
import pytest

from l3gs_opt import Instance, InstanceError, ItemInstance, ItemInstanceError, SolveError, solve
from l3gs_opt.methods import check_slot, check_time_limit
from l3gs_opt.cli.main import main
from l3gs_opt.input_files import MAX_JSON_DEPTH
from l3gs_opt.problem.instance_io import (MAX_JSON_BYTES, MAX_NPZ_BYTES, instance_from_dict, load_instance, save_instance)
from l3gs_opt.problem.items import items_from_instance
from l3gs_opt.problem.items_io import items_from_dict, load_items, load_problem, save_items
from l3gs_opt.pipeline.synth import MAX_SYNTH_ENTRIES, synth_instance


def base() -> dict:
    return {"schema": "l3gs-opt/instance@1", "representation": "layered", "bandwidth": [10, 0, 7],
            "cost": [[3, 4], [2, 5]],
            "utility": [[[1.0, 0.5], [0.2, 0.1]], [[1.0, 0.5], [0.0, 0.0]], [[0.3, 0.5], [2.0, 1.0]]]}


def items_base() -> dict:
    return {"schema": "l3gs-opt/items@1", "bandwidth": [5, 3], "object": [0, 0, 1, 1], "cost": [2, 1, 3, 4],
            "utility": [[1.0, 0.5, 0.3, 0.6], [1.0, 0.5, 0.3, 0.7]], "group": [0, 1, 2, 2], "requires": [[0, 1]]}


def cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(capsys, *argv: str, field: str) -> str:
    """Run the CLI; it must exit 2 with exactly one stderr line ``error: <field>...``."""
    code, _, err = cli(capsys, *argv)
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith(f"error: {field}"), err
    return err


@pytest.fixture
def files(tmp_path) -> dict[str, Path]:
    inst = instance_from_dict(base())
    return {"json": save_instance(inst, tmp_path / "i.json"), "npz": save_instance(inst, tmp_path / "i.npz"),
            "items": save_items(items_from_dict(items_base()), tmp_path / "items.json"),
            "one_slot": save_instance(inst.replace(bandwidth=[10], utility=inst.utility[:1]), tmp_path / "s.json")}


# -- item 6: time limits and slots -------------------------------------------------------------------

TINY = Instance("layered", bandwidth=[6, 3], cost=[[2, 3], [4, 1]], utility=np.arange(8.0).reshape(2, 2, 2) / 8)
METHODS = ["ilp", "lp", "brute", "exact", "bb", "dp", "greedy", "fptas:0.1", "rolling:bb", "rolling-future:dp",
           "mpc:2", "progressive", "slope", "static", "link-dp", "anneal"]
ITEM_METHODS = ["ilp", "lp", "brute", "bb", "dp", "greedy", "fptas:0.1", "rolling:bb", "mpc:2"]
SINGLE = {"bb", "dp", "greedy", "fptas:0.1"}


@pytest.mark.parametrize("bad", [-1, 0, 0.0, -0.0, math.nan, -math.inf, True, "5", np.float64(-2.0), [1]])
@pytest.mark.parametrize("method", METHODS)
def test_item6_time_limit_refused_by_every_method(method, bad):
    # Regression: bb, dp, greedy, rolling and exact took negative, zero and NaN limits
    # ("exact --time-limit -1" reported optimal).
    with pytest.raises(SolveError, match=r"^time_limit_s = .*: must be (> 0 seconds|a number of seconds)"):
        solve(TINY, method, slot=0 if method in SINGLE else None, time_limit_s=bad)


@pytest.mark.parametrize("method", ITEM_METHODS)
def test_item6_time_limit_refused_on_the_item_form(method):
    inst = items_from_instance(TINY)
    for bad in (-1, 0, math.nan):
        with pytest.raises(SolveError, match=r"^time_limit_s = "):
            solve(inst, method, slot=0 if method in SINGLE else None, time_limit_s=bad)


def test_item6_the_limit_is_checked_before_anything_else():
    # A bad limit is named even where the slot or the method is also wrong.
    with pytest.raises(SolveError, match=r"^time_limit_s = -1"):
        solve(TINY, "exact", slot=0, time_limit_s=-1)
    with pytest.raises(SolveError, match=r"^time_limit_s = nan"):
        solve(TINY, "no-such-method", slot=99, time_limit_s=math.nan)


@pytest.mark.parametrize("method, backend", [("ilp", "highs"), ("ilp", "scip"), ("ilp", "cpsat"), ("ilp", "cbc"),
                                             ("lp", "scip"), ("exact", "highs"), ("bb", "highs"),
                                             ("rolling:ilp", "scip"), ("mpc:2", "scip")])
def test_item6_inf_means_no_limit(method, backend):
    # Regression: --time-limit inf crashed scip (int(inf * 1000)) and bench.
    slot = 1 if method == "bb" else None
    free = solve(TINY, method, backend=backend, slot=slot)
    inf = solve(TINY, method, backend=backend, slot=slot, time_limit_s=math.inf)
    assert (inf.status, inf.objective) == (free.status, free.objective)
    assert check_time_limit(math.inf) is None and check_time_limit(np.float64("inf")) is None


def test_item6_valid_limits_pass_through():
    assert check_time_limit(None) is None
    assert check_time_limit(3) == 3.0 and isinstance(check_time_limit(np.int32(3)), float)
    assert check_time_limit(1e-300) == 1e-300


@pytest.mark.parametrize("method", ["ilp", "brute", "bb", "dp", "greedy", "fptas:0.1"])
def test_item6_one_slot_check_for_every_method(method):
    # Regression: four slot checks disagreed on numpy integers (models/build refused np.int64).
    ref = solve(TINY, method, slot=1)
    for slot in (np.int64(1), np.int32(1), np.uint8(1)):
        sol = solve(TINY, method, slot=slot)
        assert sol.slot == 1 and type(sol.slot) is int and sol.objective == ref.objective
    for bad in (True, 1.0, -1, 2, np.int64(7), "1"):
        with pytest.raises(SolveError, match=r"^slot = .*: must be an integer in 0\.\.1$"):
            solve(TINY, method, slot=bad)
    items = items_from_instance(TINY)
    assert solve(items, method, slot=np.int64(1)).objective == pytest.approx(ref.objective, rel=1e-12)
    with pytest.raises(SolveError, match=r"^slot = True"):
        solve(items, method, slot=True)
    assert check_slot(None, 3) is None


@pytest.mark.parametrize("value, shown", [("-1", "-1.0"), ("0", "0.0"), ("nan", "nan"), ("-inf", "-inf")])
def test_item6_cli_time_limit(capsys, files, value, shown):
    err = one_line_error(capsys, "solve", files["json"], "--method", "exact", f"--time-limit={value}",
                         field="--time-limit")
    assert f"--time-limit = {shown}: must be > 0 seconds" in err
    one_line_error(capsys, "compare", files["json"], "--methods", "bb", f"--time-limit={value}", "--out",
                   files["json"].parent / "c", field="--time-limit")


def test_item6_cli_inf(capsys, files, tmp_path):
    code, out, err = cli(capsys, "solve", files["json"], "--backend", "scip", "--time-limit", "inf", "--json")
    assert code == 0, err
    assert json.loads(out)["status"] == "optimal"
    code, out, err = cli(capsys, "compare", files["one_slot"], "--methods", "bb,ilp/scip", "--time-limit", "inf",
                         "--out", tmp_path / "c", "--no-progress")
    assert code == 0, err
    assert "optimal" in out


def test_item6_item8_compare_slot_checked_before_workers(capsys, files, tmp_path):
    # Regression: "compare --slot 99" printed a worker's traceback before the error line.
    for slot in ("99", "-1", "3"):
        err = one_line_error(capsys, "compare", files["json"], "--slot", slot, "--out", tmp_path / "c",
                             field="--slot")
        assert "must be an integer in 0..2" in err
    assert not (tmp_path / "c" / "compare.jsonl").exists()
    one_line_error(capsys, "solve", files["json"], "--method", "bb", "--slot", "-1", field="--slot")
    # An item file was blamed for its first item key ("object: unknown key"): say what it is.
    err = one_line_error(capsys, "compare", files["items"], "--out", tmp_path / "c", field="instance")
    assert "is an item instance" in err
    one_line_error(capsys, "solve", files["items"], "--method", "bb", "--slot", "2", field="--slot")


@pytest.mark.parametrize("label, message", [
    ("ilp/gurobi", "backend 'gurobi' is not one of cbc, highs, cpsat, scip"),
    ("ilp/", "method 'ilp/': an empty part"),
    ("lp/nosuch", "backend 'nosuch' is not one of"),
    ("slope/highs", "method 'slope/highs': slope does not use a backend ('highs')"),
    ("exact/gap", "method 'exact/gap': exact does not use a form ('gap')"),
    ("ilp/highs/cbc", "method 'ilp/highs/cbc': gives a backend or a form twice"),
    ("rolling:fptas:0", "EPS = 0.0 must be in (0, 1)"),
])
def test_compare_refuses_a_method_label_it_would_run_otherwise(capsys, files, tmp_path, label, message):
    # Regression: unknown backends became 'declined' rows (exit 0), a backend given to a heuristic
    # was dropped in silence, and a bad parameter was called an unknown method.
    err = one_line_error(capsys, "compare", files["json"], "--methods", f"bb,{label}", "--out", tmp_path / "c",
                         field="")
    assert message in err
    assert not (tmp_path / "c" / "compare.jsonl").exists()


# -- item 7: hangs and unbounded reads ---------------------------------------------------------------

def run_with_timeout(fn, *args, seconds: float = 20):
    """``fn(*args)`` in a daemon thread: its exception or result, or a failure if it is still
    running after ``seconds`` (a FIFO opened for reading blocks until a writer comes)."""
    box: dict = {}

    def target():
        try:
            box["result"] = fn(*args)
        except BaseException as exc:  # noqa: BLE001 - handed back to the test
            box["error"] = exc

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"{fn.__name__} hung on {args}"
    return box


@pytest.mark.parametrize("load, error", [(load_instance, InstanceError), (load_items, ItemInstanceError),
                                         (load_problem, InstanceError)])
@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_item7_fifo_is_refused_not_read(tmp_path, load, error, suffix):
    fifo = tmp_path / f"pipe{suffix}"
    os.mkfifo(fifo)
    box = run_with_timeout(load, fifo)
    assert isinstance(box.get("error"), error), box
    assert box["error"].field == "file" and "not a regular file" in str(box["error"])


def test_item7_cli_fifo_and_devices(capsys, tmp_path):
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    box = run_with_timeout(cli, capsys, "instance", "check", fifo)
    assert box["result"][0] == 2 and "not a regular file" in box["result"][2]
    for device in ("/dev/zero", "/dev/null"):
        one_line_error(capsys, "instance", "check", device, field="file")
    (tmp_path / "zero.npz").symlink_to("/dev/zero")
    one_line_error(capsys, "solve", tmp_path / "zero.npz", field="file")
    one_line_error(capsys, "instance", "check", tmp_path, field="file")   # a folder


def test_item7_json_over_the_size_limit_is_refused_before_reading(tmp_path):
    big = tmp_path / "big.json"
    with open(big, "wb") as fh:   # sparse: nothing is written, the size is what is checked
        fh.truncate(MAX_JSON_BYTES + 1)
    with pytest.raises(InstanceError, match=rf"^file: .*{MAX_JSON_BYTES + 1:,} bytes, more than the limit"):
        load_instance(big)
    with pytest.raises(ItemInstanceError, match=r"^file: .*more than the limit"):
        load_items(big)


def test_item7_writers_refuse_what_the_readers_would(tmp_path, monkeypatch):
    import l3gs_opt.problem.instance_io as instance_io

    inst = instance_from_dict(base())
    monkeypatch.setattr(instance_io, "MAX_JSON_BYTES", 100)
    with pytest.raises(InstanceError, match=r"^file: .*bytes of JSON, more than the readers' limit of 100: write "
                                            r"\.npz"):
        save_instance(inst, tmp_path / "i.json")
    monkeypatch.setattr(instance_io, "MAX_NPZ_BYTES", 100)
    with pytest.raises(ItemInstanceError, match=r"^file: .*bytes of arrays, more than the readers' limit of 100"):
        save_items(items_from_dict(items_base()), tmp_path / "i.npz")
    assert not list(tmp_path.iterdir())


def npy_header(shape: tuple[int, ...], descr: str = "<f8") -> bytes:
    header = ("{'descr': '%s', 'fortran_order': False, 'shape': %r, }" % (descr, shape)).encode("latin1")
    header += b" " * (63 - (10 + len(header)) % 64) + b"\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header


def npz_of(tmp_path: Path, name: str, members: dict[str, bytes], *, deflate: bool = False) -> Path:
    path = tmp_path / name
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED if deflate else zipfile.ZIP_STORED) as zf:
        for member, payload in members.items():
            zf.writestr(member, payload)
    return path


def valid_members(data: dict) -> dict[str, bytes]:
    out = {}
    for key, value in data.items():
        buf = io.BytesIO()
        np.save(buf, np.asarray(value) if isinstance(value, list) else np.array(json.dumps(value)))
        out[f"{key}.npy"] = buf.getvalue()
    return out


@pytest.mark.parametrize("load", [load_instance, load_problem])
def test_item7_npz_header_claiming_1e12_entries(tmp_path, load):
    members = {**valid_members(base()), "utility.npy": npy_header((10**6, 10**6)) + b"\0" * 64}
    path = npz_of(tmp_path, "claim.npz", members)
    with pytest.raises(InstanceError, match=r"^utility: .*header claims shape \(1000000, 1000000\) of float64, more "
                                            r"than the limit of 1,073,741,824 bytes"):
        load(path)


def test_item7_zip_bomb_refused_before_decompressing(tmp_path):
    # A 4 GiB bomb, built cheaply: the zip directory of a small member claims 4 GiB - 1 uncompressed.
    path = npz_of(tmp_path, "bomb.npz", valid_members(base()), deflate=True)
    raw = bytearray(path.read_bytes())
    at = raw.index(b"PK\x01\x02")                                  # the first central directory entry
    raw[at + 24:at + 28] = struct.pack("<I", 2**32 - 1)           # its uncompressed size
    path.write_bytes(bytes(raw))
    with pytest.raises(InstanceError, match=r"^file: .*members claim [\d,]+ bytes uncompressed, more than the "
                                            r"limit of 1,073,741,824"):
        load_instance(path)
    # A small, highly compressible member whose .npy header claims 4 GiB of float64.
    members = {**valid_members(items_base()), "utility.npy": npy_header((2**29,)) + b"\0" * 2**20}
    path = npz_of(tmp_path, "bomb2.npz", members, deflate=True)
    assert path.stat().st_size < 2**16
    with pytest.raises(ItemInstanceError, match=r"^utility: .*header claims shape \(536870912,\) of float64"):
        load_items(path)
    assert MAX_NPZ_BYTES == 2**30


def test_item7_leaner_json_parse_and_exact_shapes(tmp_path):
    # The arrays are built from the decoded lists by numpy directly (no flat copy); the result is
    # the same, including empty axes.
    inst = instance_from_dict({**base(), "bandwidth": [5.0, 0, 7], "held": [[1, 0], [0, 0]]})
    assert inst.bandwidth.dtype == np.int64 and inst.bandwidth.tolist() == [5, 0, 7]
    empty = instance_from_dict({**base(), "cost": [], "utility": [[], [], []]})
    assert (empty.T, empty.J, empty.L) == (3, 0, 0)
    assert items_from_dict({**items_base(), "requires": []}).requires.shape == (0, 2)


# -- item 8: tracebacks --------------------------------------------------------------------------------

def deep(levels: int) -> str:
    return "[" * levels + "]" * levels


@pytest.mark.parametrize("where", ["top", "meta", "utility"])
def test_item8_deep_json_is_a_named_error(tmp_path, capsys, where):
    # Regression: RecursionError, also inside meta.
    for levels in (MAX_JSON_DEPTH + 1, 100_000):
        text = {"top": deep(levels), "meta": json.dumps(base())[:-1] + f', "meta": {{"x": {deep(levels)}}}}}',
                "utility": json.dumps(base()).replace('"utility": [', f'"utility": [{deep(levels)}, ', 1)}[where]
        path = tmp_path / f"deep-{where}.json"
        path.write_text(text)
        with pytest.raises(InstanceError, match=r"^file: .*nested more than 64 levels deep"):
            load_instance(path)
        one_line_error(capsys, "instance", "check", path, field="file")


def test_item8_deep_meta_in_npz_and_in_python(tmp_path):
    members = {**valid_members(base()), "meta.npy": _npy_text('{"x": ' + deep(5000) + "}")}
    with pytest.raises(InstanceError, match=r"^meta: nested more than 64 levels deep"):
        load_instance(npz_of(tmp_path, "deep.npz", members))
    nested: dict = {}
    cur = nested
    for _ in range(5000):
        cur["a"] = {}
        cur = cur["a"]
    with pytest.raises(InstanceError, match=r"^meta: must be JSON-serialisable"):
        Instance("layered", bandwidth=[5], cost=[[2]], utility=[[[1.0]]], meta=nested)
    with pytest.raises(InstanceError, match=r"^meta: nested more than 63 levels deep"):
        Instance("layered", bandwidth=[5], cost=[[2]], utility=[[[1.0]]], meta=json.loads(
            "{\"a\": " + deep(63) + "}"))


def _npy_text(text: str) -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.array(text))
    return buf.getvalue()


@pytest.mark.parametrize("order", ["<", ">"])
def test_npz_text_member_with_a_code_point_above_unicode(tmp_path, order):
    """Regression (found by test_fuzz_mutated_npy_members): a .npy string may hold UCS-4 units above
    U+10FFFF; numpy makes a Python string of it that raises SystemError when read. One clear line."""
    units = np.array([ord(c) for c in '["a", "b"]'], dtype=np.uint32)
    units[2] = 0x110061
    arr = np.frombuffer(units.astype(order + "u4").tobytes(), dtype=order + "U10").reshape(())
    buf = io.BytesIO()
    np.save(buf, arr)
    path = npz_of(tmp_path, "odd.npz", {**valid_members(base()), "names.npy": buf.getvalue()})
    with pytest.raises(InstanceError, match=r"^names: holds a character code 0x110061 above U\+10FFFF"):
        load_instance(path)


def test_item8_npz_member_without_npy(tmp_path, capsys):
    # Regression: AttributeError.
    path = npz_of(tmp_path, "odd.npz", {**valid_members(base()), "notes.txt": b"hello"})
    with pytest.raises(InstanceError, match=r"^file: .*member 'notes.txt' is not a \.npy array"):
        load_instance(path)
    one_line_error(capsys, "instance", "check", path, field="file")
    damaged = npz_of(tmp_path, "damaged.npz", {**valid_members(base()), "cost.npy": b"\x93NUMPY\x01\x00\x10\x00{'d"})
    with pytest.raises(InstanceError, match=r"^cost: .*no readable \.npy header"):
        load_instance(damaged)
    twice = valid_members(base())
    path = tmp_path / "twice.npz"
    with pytest.warns(UserWarning, match="Duplicate name"), zipfile.ZipFile(path, "w") as zf:
        for member, payload in [*twice.items(), ("cost.npy", twice["cost.npy"])]:
            zf.writestr(member, payload)
    with pytest.raises(InstanceError, match=r"^cost: .*appears twice"):
        load_instance(path)


def test_item8_synth_output_on_a_folder(capsys, tmp_path):
    # Regression: IsADirectoryError traceback.
    folder = tmp_path / "out.json"
    folder.mkdir()
    err = one_line_error(capsys, "instance", "synth", "--objects", "2", "--layers", "2", "--slots", "2", "-o",
                         folder, field="file")
    assert "is a folder" in err
    (tmp_path / "plain").write_text("x")
    one_line_error(capsys, "instance", "synth", "--slots", "2", "-o", tmp_path / "plain" / "i.json", field="file")


@pytest.mark.parametrize("args, field", [(["--objects", "-1"], "--objects"), (["--layers", "0"], "--layers"),
                                         (["--slots", "0"], "--slots"), (["--seed", "-1"], "--seed"),
                                         (["--objects", "100000000"], "--objects"),
                                         (["--layers", "100000000"], "--objects")])
def test_item8_synth_counts(capsys, tmp_path, args, field):
    one_line_error(capsys, "instance", "synth", *args, "-o", tmp_path / "s.json", field=field)
    assert MAX_SYNTH_ENTRIES == 2**24
    with pytest.raises(InstanceError, match=r"^seed = 1\.5: must be an integer >= 0"):
        synth_instance(objects=2, layers=2, slots=2, seed=1.5)


# -- item 9: silent garbage ----------------------------------------------------------------------------

@pytest.mark.parametrize("form", ["instance", "items"])
def test_item9_bytes_stay_exact_beside_a_float(form):
    # Regression: [2**53 + 1, 1.0] became float64 and 2**53 + 1 was read as 2**53 (accepted).
    data, build, error = ((base(), instance_from_dict, InstanceError) if form == "instance" else
                          (items_base(), items_from_dict, ItemInstanceError))
    bandwidth = [2**53 + 1, 1.0] + data["bandwidth"][2:]
    with pytest.raises(error, match=r"^bandwidth\[0\] = 9007199254740993: must be at most 2\*\*53"):
        build({**data, "bandwidth": bandwidth})
    ok = build({**data, "bandwidth": [2**53, 1.0] + data["bandwidth"][2:]})
    assert ok.bandwidth.dtype == np.int64 and ok.bandwidth.tolist()[:2] == [2**53, 1]
    # A float in an integer field: only whole and below 2**53 (at 2**53 it may be a rounded 2**53 + 1).
    for value in (2.0**53, 1e300):
        with pytest.raises(error, match=r"^bandwidth\[0\] = .*a whole number written as a float must be below 2\*\*53"):
            build({**data, "bandwidth": [value] + data["bandwidth"][1:]})
    with pytest.raises(error, match=r"^bandwidth\[1\] = 1\.5: .*fractional bytes"):
        build({**data, "bandwidth": [2**53 + 1, 1.5] + data["bandwidth"][2:]})


def test_item9_bytes_from_a_json_file(tmp_path, capsys):
    path = tmp_path / "i.json"
    path.write_text(json.dumps(base()).replace("[10, 0, 7]", "[9007199254740993, 0.0, 7]"))
    one_line_error(capsys, "instance", "check", path, field="bandwidth[0]")
    path.write_text(json.dumps(base()).replace("[10, 0, 7]", "[9007199254740993.0, 0, 7]"))
    one_line_error(capsys, "solve", path, field="bandwidth[0]")


@pytest.mark.parametrize("value", [False, 0, "", [], None, "x"])
@pytest.mark.parametrize("form", ["instance", "items"])
def test_item9_meta_must_be_an_object_or_absent(form, value):
    # Regression: meta false/0/"" was taken as {}.
    data, build, error = ((base(), instance_from_dict, InstanceError) if form == "instance" else
                          (items_base(), items_from_dict, ItemInstanceError))
    with pytest.raises(error, match=r"^meta: (must be a JSON object|is null)") as info:
        build({**data, "meta": value})
    assert info.value.field == "meta"
    assert dict(build(data).meta) == {} and dict(build({**data, "meta": {"a": [1]}}).meta) == {"a": [1]}


@pytest.mark.parametrize("key", ["held", "options", "names", "slot_s"])
def test_item9_null_optional_keys_are_refused(key):
    with pytest.raises(InstanceError, match=rf"^{key}: "):
        instance_from_dict({**base(), key: None})


def test_item9_duplicate_keys_refused(tmp_path, capsys):
    # Regression: the last of two keys silently won, although unknown keys are errors.
    text = json.dumps(base())
    path = tmp_path / "dup.json"
    path.write_text(text[:-1] + ', "bandwidth": [1, 1, 1]}')
    with pytest.raises(InstanceError, match=r"^bandwidth: .*duplicate key"):
        load_instance(path)
    one_line_error(capsys, "solve", path, field="bandwidth")
    path.write_text(text[:-1] + ', "meta": {"trace": "a", "trace": "b"}}')
    with pytest.raises(InstanceError, match=r"^trace: .*duplicate key"):
        load_problem(path)
    items = tmp_path / "items.json"
    items.write_text(json.dumps(items_base())[:-1] + ', "cost": [1, 1, 1, 1]}')
    with pytest.raises(ItemInstanceError, match=r"^cost: .*duplicate key"):
        load_items(items)
    members = {**valid_members(base()), "options.npy": _npy_text('{"budget": "per_slot", "budget": "cumulative"}')}
    with pytest.raises(InstanceError, match=r"^budget: .*duplicate key"):
        load_instance(npz_of(tmp_path, "dup.npz", members))
    with pytest.raises(InstanceError, match=r"^meta: duplicate key"):   # keys 1 and "1" collide in JSON
        Instance("layered", bandwidth=[5], cost=[[2]], utility=[[[1.0]]], meta={1: "a", "1": "b"})


def test_item9_odd_keys_give_one_line(capsys, tmp_path):
    path = tmp_path / "k.json"
    for key in ("", "a\nb", "x" * 500):
        path.write_text(json.dumps({**base(), key: 1}))
        with pytest.raises(InstanceError, match=r"unknown key") as info:
            load_instance(path)
        assert info.value.field and "\n" not in str(info.value) and len(info.value.field) <= 40
        code, _, err = cli(capsys, "instance", "check", path)
        assert code == 2 and err.count("\n") == 1


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_item9_round_trip_still_exact(tmp_path, suffix):
    inst = instance_from_dict({**base(), "bandwidth": [2**53, 0, 7], "meta": {"m": {"n": [1, 2]}},
                               "options": {"budget": "cumulative"}, "names": ["a", "b"]})
    back = load_problem(save_instance(inst, tmp_path / f"i{suffix}"))
    assert back.to_dict() == inst.to_dict() and back.bandwidth[0] == 2**53
    items = items_from_dict({**items_base(), "held": [1, 0, 0, 0]})
    again = load_problem(save_items(items, tmp_path / f"j{suffix}"))
    assert isinstance(again, ItemInstance) and again.to_dict() == items.to_dict()
