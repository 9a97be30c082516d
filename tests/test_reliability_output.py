"""Issue 19, output items: one strict JSON serialiser (item 1, 9), one record writer that survives a
torn last line (item 2) and refuses a second writer (item 5), and one-line errors for bad bench and
report arguments (items 8, 9)."""

from __future__ import annotations

import enum
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import l3gs_opt
from l3gs_opt.cli.main import main
from l3gs_opt.problem.instance import Options
from l3gs_opt.jsonout import JsonOutputError, dumps, to_jsonable
from l3gs_opt.records import (OutputLock, OutputLockedError, RecordFileError, RecordLog, read_records,
                              repair_torn_tail)
from l3gs_opt.pipeline.synth import synth_instance

REPO = Path(__file__).resolve().parents[1]
TRACE = REPO / "l3gs_opt" / "data" / "traces" / "lumos-throughput-mid-11.txt"


def _no_constants(name: str):
    raise AssertionError(f"{name} in output: not JSON")


def strict_loads(text: str):
    """JSON as any strict parser reads it: NaN/Infinity are refused."""
    return json.loads(text, parse_constant=_no_constants)


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def one_error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


# ------------------------------------------------------------------------------- item 1: serialiser
def test_item1_solve_exact_json_is_strict_json(tmp_path, capsys):
    """The reproduction of the issue: exact's details hold numpy bools (``root.converged``)."""
    inst = synth_instance(objects=5, layers=3, slots=5, seed=0)
    path = l3gs_opt.save_instance(inst, tmp_path / "s5.json")
    code, out, err = run_cli(capsys, "solve", path, "--method", "exact", "--json", "--time-limit", "20")
    assert code == 0, err
    data = strict_loads(out)
    again = l3gs_opt.solve(inst, "exact", time_limit_s=20)
    assert data["status"] == again.status.value == "optimal"
    assert data["objective"] == pytest.approx(again.objective, rel=1e-9)
    assert l3gs_opt.evaluate_objective(inst, [tuple(a) for a in data["arrivals"]]) == pytest.approx(
        data["objective"], rel=1e-12)
    assert isinstance(data["details"]["root"]["converged"], bool)


#: Concrete values for the parameters of method_names() (``fptas:EPS``, ``mpc:H``, ``rolling:SOLVER``).
PARAMS = {"EPS": "0.2", "H": "2", "SOLVER": "greedy", "S": "greedy"}


def _label(name: str) -> str:
    base, _, param = name.partition(":")
    return base + (f":{PARAMS.get(param, param)}" if param else "")


def _same_json_value(original, parsed, where="value") -> None:
    """An independent walk: every number equal after conversion, non-finite ones null."""
    if isinstance(original, dict) or hasattr(original, "items"):
        assert isinstance(parsed, dict) and set(parsed) == {str(k) for k in original}, where
        for k, v in original.items():
            _same_json_value(v, parsed[str(k)], f"{where}.{k}")
    elif isinstance(original, (list, tuple, np.ndarray)):
        original = list(original)
        assert isinstance(parsed, list) and len(parsed) == len(original), where
        for i, (a, b) in enumerate(zip(original, parsed)):
            _same_json_value(a, b, f"{where}[{i}]")
    elif isinstance(original, (bool, np.bool_)):
        assert parsed is bool(original), where
    elif isinstance(original, (int, np.integer)):
        assert type(parsed) is int and parsed == int(original), where
    elif isinstance(original, (float, np.floating)):
        if math.isfinite(original):
            assert type(parsed) is float and parsed == float(original), where
        else:
            assert parsed is None, where
    elif isinstance(original, enum.Enum):
        assert parsed == original.value, where
    else:
        assert parsed == original, where


@pytest.mark.parametrize("name", l3gs_opt.method_names())
def test_item1_every_method_solution_serialises(name):
    """Every method's Solution (per-slot methods on slot 0; link-dp on a cumulative budget)."""
    label = _label(name)
    per_slot = synth_instance(objects=5, layers=3, slots=5, seed=0)
    cumulative = synth_instance(objects=5, layers=3, slots=5, seed=0, options=Options(budget="cumulative"))
    solved = []
    for inst in (per_slot, cumulative):
        for slot in (None, 0):
            try:
                sol = l3gs_opt.solve(inst, label, slot=slot, time_limit_s=2.0)
            except l3gs_opt.SolveError:
                continue   # a slot that does not apply, a budget the method does not take, a size limit
            data = sol.to_dict()
            text = dumps(data, where="solution")
            parsed = strict_loads(text)
            _same_json_value(data, parsed)
            assert parsed["status"] == sol.status.value and parsed["objective"] == sol.objective
            solved.append(sol)
    assert solved, f"{label}: no instance/slot combination solved"


def test_item1_every_ilp_backend_serialises():
    from l3gs_opt.models.backends import installed_backends

    inst = synth_instance(objects=5, layers=3, slots=5, seed=0)
    for backend in installed_backends():
        for method in ("ilp", "lp"):
            try:
                sol = l3gs_opt.solve(inst, method, backend=backend.value, time_limit_s=5.0)
            except l3gs_opt.SolveError:
                assert method == "lp"   # a backend without LP relaxations (cpsat)
                continue
            _same_json_value(sol.to_dict(), strict_loads(dumps(sol.to_dict())))


class _Colour(enum.Enum):
    RED = "red"


def test_item1_numpy_types_and_the_nonfinite_rule():
    value = {"b": np.bool_(True), "i8": np.int8(-3), "u64": np.uint64(2**63), "f32": np.float32(0.5),
             "f16": np.float16(-2.0), "nan": np.nan, "inf": np.float64(np.inf), "-inf": -math.inf,
             "zero_d": np.array(1.5), "two_d": np.arange(4).reshape(2, 2), "bools": np.array([True, False]),
             "tuple": (1, (2.5, np.int64(3))), "enum": _Colour.RED, "status": l3gs_opt.Status.OPTIMAL,
             "path": Path("a/b.json"), "text": "NaN and -Infinity stay text", np.int64(7): "int key"}
    parsed = strict_loads(dumps(value))
    assert parsed == {"b": True, "i8": -3, "u64": 2**63, "f32": 0.5, "f16": -2.0, "nan": None, "inf": None,
                      "-inf": None, "zero_d": 1.5, "two_d": [[0, 1], [2, 3]], "bools": [True, False],
                      "tuple": [1, [2.5, 3]], "enum": "red", "status": "optimal", "path": "a/b.json",
                      "text": "NaN and -Infinity stay text", "7": "int key"}
    assert type(parsed["b"]) is bool and type(parsed["u64"]) is int
    with pytest.raises(JsonOutputError, match=r"^solution\.details\.x\[1\] = nan: not a finite number"):
        dumps({"details": {"x": [1.0, np.float32("nan")]}}, nonfinite="error", where="solution")
    with pytest.raises(JsonOutputError, match=r"^value\.s: a value of type set has no JSON form"):
        dumps({"s": {1, 2}})
    with pytest.raises(JsonOutputError, match="keys must be text or integers"):
        dumps({(1, 2): 3})
    assert to_jsonable({"s": {1}}, other=sorted) == {"s": [1]}


def _leaves():
    """(value, the plain Python value a JSON parser gives back) for finite numpy and Python scalars."""
    finite = st.floats(allow_nan=False, allow_infinity=False)
    return st.one_of(
        st.none().map(lambda v: (v, v)), st.booleans().map(lambda b: (b, b)),
        st.booleans().map(lambda b: (np.bool_(b), b)),
        st.integers(-2**63, 2**63 - 1).map(lambda i: (np.int64(i), i)),
        st.integers(0, 2**64 - 1).map(lambda i: (np.uint64(i), i)),
        st.integers(-2**31, 2**31 - 1).map(lambda i: (np.int32(i), i)),
        st.integers(-10**30, 10**30).map(lambda i: (i, i)),
        finite.map(lambda x: (x, x)), finite.map(lambda x: (np.float64(x), x)),
        st.floats(width=32, allow_nan=False, allow_infinity=False).map(lambda x: (np.float32(x), float(np.float32(x)))),
        st.text(max_size=8).map(lambda s: (s, s)))


def _nested(leaf):
    keys = st.text(max_size=5)
    return st.one_of(
        st.lists(leaf, max_size=4).map(lambda pairs: ([a for a, _ in pairs], [b for _, b in pairs])),
        st.lists(leaf, max_size=4).map(lambda pairs: (tuple(a for a, _ in pairs), [b for _, b in pairs])),
        st.dictionaries(keys, leaf, max_size=4).map(lambda d: ({k: a for k, (a, _) in d.items()},
                                                               {k: b for k, (_, b) in d.items()})))


@settings(max_examples=150, deadline=None)
@given(st.recursive(_leaves(), _nested, max_leaves=20))
def test_item1_roundtrip_of_any_finite_nested_structure(pair):
    value, expected = pair
    text = dumps(value)
    assert strict_loads(text) == expected


@settings(max_examples=80, deadline=None)
@given(st.lists(st.one_of(st.floats(), st.floats(width=32).map(np.float32)), max_size=6))
def test_item1_nonfinite_numbers_are_null(values):
    parsed = strict_loads(dumps(values))
    assert parsed == [float(v) if math.isfinite(v) else None for v in values]


# ------------------------------------------------------------------------------ item 9: silent garbage
def test_item9_predict_json_with_nonfinite_errors_is_strict_json(capsys, monkeypatch):
    import l3gs_opt.traces.predictors as predictors

    monkeypatch.setattr(predictors, "bandwidth_errors",
                        lambda *a, **k: {"mae_mbps": float("nan"), "worst_mbps": float("inf"),
                                         "samples": np.int64(3)})
    code, out, err = run_cli(capsys, "predict", "bandwidth", TRACE, "--json")
    assert code == 0, err
    assert strict_loads(out) == {"mae_mbps": None, "worst_mbps": None, "samples": 3}


def test_item9_predict_json_real_run_is_strict_json(capsys):
    code, out, err = run_cli(capsys, "predict", "bandwidth", TRACE, "--json", "--method", "last")
    assert code == 0, err
    data = strict_loads(out)
    assert data["samples"] > 0 and data["mae_mbps"] >= 0


@pytest.mark.parametrize("argv, field", [(["--seeds", "-1"], "--seeds"), (["--seeds", "0"], "--seeds"),
                                         (["--methods", ","], "--methods"), (["--methods", " , ,"], "--methods")])
def test_item9_bench_empty_plans_are_errors(tmp_path, capsys, argv, field):
    code, out, err = run_cli(capsys, "bench", "--suite", "l3gs", "--quick", "--out", tmp_path / "b",
                             "--no-progress", *argv)
    assert code == 2
    assert one_error_line(err).startswith(f"error: {field}")
    assert not (tmp_path / "b" / "results.jsonl").exists()


def test_item9_run_bench_refuses_an_empty_task_list(tmp_path):
    from l3gs_opt.bench.run import BenchError, run_bench

    with pytest.raises(BenchError, match="^tasks: nothing to run"):
        run_bench([], tmp_path / "r.jsonl", progress=False)


# ------------------------------------------------------------------------------ item 8: tracebacks
@pytest.mark.parametrize("sizes, message", [("-5", r"error: --sizes\[0\] = -5: an object count must be >= 1"),
                                            ("10,0", r"error: --sizes\[1\] = 0: an object count must be >= 1"),
                                            (",", "error: --sizes: names no size")])
def test_item8_bench_bad_sizes(tmp_path, capsys, sizes, message):
    code, _, err = run_cli(capsys, "bench", "--suite", "pisinger", f"--sizes={sizes}", "--out", tmp_path / "b")
    assert code == 2
    assert re.match(message, one_error_line(err))


def test_item8_bench_out_on_a_file(tmp_path, capsys):
    afile = tmp_path / "taken.txt"
    afile.write_text("not a folder\n")
    code, _, err = run_cli(capsys, "bench", "--suite", "stiff", "--methods", "greedy", "--out", afile)
    assert code == 2 and one_error_line(err).startswith("error: --out: ")
    assert afile.read_text() == "not a folder\n"
    # The library refuses the same paths by name: a folder as the records file, a file as its folder.
    from l3gs_opt.bench.run import BenchTask, run_bench
    from l3gs_opt.bench.suites import suite_specs

    task = BenchTask(suite_specs("stiff")[0], "greedy")
    with pytest.raises(RecordFileError, match="is a folder"):
        run_bench([task], tmp_path, jobs=0, progress=False)
    with pytest.raises(RecordFileError, match=r"results\.jsonl: its folder .*taken\.txt is a file"):
        run_bench([task], afile / "results.jsonl", jobs=0, progress=False)


def test_item8_report_on_foreign_records(tmp_path, capsys):
    foreign = tmp_path / "slots.jsonl"
    foreign.write_text(json.dumps({"method": "l3gs", "slot": 0, "ssim": 0.9}) + "\n")
    code, _, err = run_cli(capsys, "report", foreign, "--out", tmp_path / "rep")
    assert code == 2
    assert one_error_line(err).startswith(f"error: {foreign}[0]: not a bench record")
    other = tmp_path / "other.jsonl"
    other.write_text(json.dumps({"schema": "someone-else@1", "record_id": "a", "suite": "s", "instance_id": "i",
                                 "method": "m", "status": "optimal"}) + "\n")
    code, _, err = run_cli(capsys, "report", other, "--out", tmp_path / "rep")
    assert code == 2 and "schema 'someone-else@1'" in one_error_line(err)
    code, _, err = run_cli(capsys, "report", tmp_path, "--out", tmp_path / "rep")   # a folder as records
    assert code == 2 and "is a folder" in one_error_line(err)


# ------------------------------------------------------------------------------ item 2: torn lines
def _records(n: int) -> list[dict]:
    return [{"record_id": f"r{i}", "objective": i / 3, "text": "é" * (i % 3), "flags": ["x"] * (i % 2)}
            for i in range(n)]


def _write(path: Path, records: list[dict]) -> bytes:
    data = "".join(json.dumps(r) + "\n" for r in records).encode("utf-8")
    path.write_bytes(data)
    return data


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 5), cut=st.floats(0, 1))
def test_item2_torn_file_cut_at_any_byte_resumes_without_losing_a_record(tmp_path, n, cut):
    path = tmp_path / "torn.jsonl"
    records = _records(n)
    data = _write(path, records)
    offset = int(cut * len(data))
    path.write_bytes(data[:offset])
    # Independently: the records whose text (without its newline) lies wholly before the cut.
    ends = np.cumsum([len((json.dumps(r) + "\n").encode()) for r in records])
    complete = [r for r, end in zip(records, ends) if end - 1 <= offset]
    assert read_records(path) == complete          # readers skip the fragment
    notes: list[str] = []
    with RecordLog(path, log=notes.append) as log:
        assert log.records() == complete
        log.append({"record_id": "new", "objective": np.float64(1.5)})
    assert read_records(path) == complete + [{"record_id": "new", "objective": 1.5}]
    assert path.read_bytes().endswith(b"\n")
    torn = offset not in (0, *ends)
    assert bool(notes) == torn


def test_item2_bad_line_in_the_middle_is_a_named_error(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text('{"a": 1}\n{"a": 2\n{"a": 3}\n')
    with pytest.raises(RecordFileError, match=r"r\.jsonl\[2\]: line 2 is not a JSON record"):
        read_records(path)
    path.write_text('{"a": 1}\n[1, 2]\n')
    with pytest.raises(RecordFileError, match=r"\[2\]: line 2 is not a JSON record \(a JSON list"):
        read_records(path)
    path.write_bytes(b'{"a": 1}\n{"a": "\xff"}\n')
    with pytest.raises(RecordFileError, match=r"\[2\]: line 2 is not a JSON record"):
        read_records(path)
    assert repair_torn_tail(tmp_path / "missing.jsonl") is None


def test_item2_complete_record_without_newline_is_kept(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text('{"a": 1}\n{"a": 2}')
    notes: list[str] = []
    assert repair_torn_tail(path, log=notes.append) is not None and "newline added" in notes[0]
    assert path.read_text() == '{"a": 1}\n{"a": 2}\n'


def test_item2_bench_resume_after_a_torn_last_line(tmp_path, capsys):
    """The issue's reproduction: bench --out D, cut the file inside its last line, --resume."""
    out = tmp_path / "D"
    argv = ["bench", "--quick", "--suite", "stiff", "--methods", "greedy,bb", "--out", out, "--no-progress"]
    code, _, err = run_cli(capsys, *argv)
    assert code == 0, err
    results = out / "results.jsonl"
    data = results.read_bytes()
    lines = data.splitlines(keepends=True)
    before = [json.loads(x) for x in lines[:-1]]
    results.write_bytes(b"".join(lines[:-1]) + lines[-1][:len(lines[-1]) // 2])
    code, _, err = run_cli(capsys, *argv, "--resume")
    assert code == 0, err
    assert "note: " in err and "dropped a torn last line" in err
    after = read_records(results)
    ids = [r["record_id"] for r in after]
    assert len(ids) == len(set(ids)) == len(lines)          # the cut record re-run once, none twice
    assert after[:len(before)] == before
    code, _, err = run_cli(capsys, "report", results, "--out", tmp_path / "rep")
    assert code == 0, err


def test_item2_simulate_records_share_the_writer(tmp_path):
    """simulate's RecordWriter: a torn last line repaired, a bad line in the middle refused."""
    from l3gs_opt.simulator.records import RecordWriter

    slots = tmp_path / "slots.jsonl"
    keep = {"method": "sort", "solver": None, "slot": 0, "run_id": "x"}
    slots.write_text(json.dumps(keep) + "\n" + '{"method": "l3gs", "sol')
    w = RecordWriter(tmp_path, "l3gs", None, run="r", resume=True)
    w.slot({"method": "l3gs", "solver": None, "slot": 0, "run_id": "r", "ssim": np.float32(0.5)})
    w.summary({"method": "l3gs", "solver": None, "ssim_mean": float("nan")})
    assert read_records(slots) == [keep, {"method": "l3gs", "solver": None, "slot": 0, "run_id": "r", "ssim": 0.5}]
    assert read_records(tmp_path / "summary.jsonl") == [{"method": "l3gs", "solver": None, "ssim_mean": None}]
    slots.write_text(json.dumps(keep) + "\nnot json\n" + json.dumps(keep) + "\n")
    with pytest.raises(RecordFileError, match=r"slots\.jsonl\[2\]: line 2"):
        RecordWriter(tmp_path, "l3gs", None, run="r", resume=True)
    assert main(["simulate", "missing-bundle", "--trace", "x", "--path", "y", "--method", "l3gs",
                 "--out", str(slots)]) == 2   # --out on a file: one line, before anything runs


# ------------------------------------------------------------------------------ item 5: one writer
def test_item5_second_writer_in_this_process_is_refused(tmp_path):
    path = tmp_path / "r.jsonl"
    first = RecordLog(path, what="bench")
    with pytest.raises(OutputLockedError, match=r"r\.jsonl: process \d+ \(this process\) is writing here"):
        RecordLog(path, what="bench")
    first.append({"a": 1})
    first.close()
    with RecordLog(path) as second:
        second.append({"a": 2})
    assert read_records(path) == [{"a": 1}, {"a": 2}]
    assert (tmp_path / "r.jsonl.lock").read_text().strip() == str(os.getpid())


_HOLDER = """
import sys, time
from l3gs_opt.records import RecordLog
log = RecordLog(sys.argv[1], what="a test holder")
print("locked", flush=True)
time.sleep(120)
"""


def _start_holder(path: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(path)], stdout=subprocess.PIPE, text=True,
                            cwd=REPO)
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_item5_second_bench_process_is_refused_until_the_first_is_killed(tmp_path, capsys):
    out = tmp_path / "b"
    argv = ["bench", "--quick", "--suite", "stiff", "--methods", "greedy", "--out", out, "--no-progress"]
    holder = _start_holder(out / "results.jsonl")
    try:
        code, _, err = run_cli(capsys, *argv)
        assert code == 2
        line = one_error_line(err)
        assert f"process {holder.pid} is writing here" in line and "results.jsonl.lock" in line
        assert read_records(out / "results.jsonl") == []
    finally:
        holder.send_signal(signal.SIGKILL)   # flock goes with the process, even on SIGKILL
        holder.wait(timeout=30)
    code, _, err = run_cli(capsys, *argv)
    assert code == 0, err
    ids = [r["record_id"] for r in read_records(out / "results.jsonl")]
    assert ids and len(ids) == len(set(ids))


def test_item5_forked_children_do_not_keep_the_lock(tmp_path):
    path = tmp_path / "r.jsonl"
    log = RecordLog(path)
    pid = os.fork()
    if pid == 0:   # a child, as bench's workers are: outlives the writer's close
        time.sleep(3)
        os._exit(0)
    try:
        log.close()
        with RecordLog(path) as again:    # free although the child still runs
            again.append({"ok": True})
    finally:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)


def test_item5_simulate_same_method_refused_other_methods_allowed(tmp_path):
    from l3gs_opt.simulator.records import RecordWriter

    first = RecordWriter(tmp_path, "l3gs", "bb", run="r")
    with pytest.raises(OutputLockedError, match="simulate of method 'l3gs', solver 'bb'"):
        RecordWriter(tmp_path, "l3gs", "bb", run="r")
    other = RecordWriter(tmp_path, "sort", None, run="s")        # another method: its own lines
    first.slot({"method": "l3gs", "solver": "bb", "slot": 0, "run_id": "r"})
    other.slot({"method": "sort", "solver": None, "slot": 0, "run_id": "s"})
    first.summary({"method": "l3gs", "solver": "bb"})             # the end of the run: lock released
    other.summary({"method": "sort", "solver": None})
    again = RecordWriter(tmp_path, "l3gs", "bb", run="r", resume=True)
    assert [r["slot"] for r in again.resumed] == [0]
    again.close()
    assert len(read_records(tmp_path / "slots.jsonl")) == 2


def test_item5_experiments_refuse_a_second_writer(tmp_path, capsys):
    from l3gs_opt.experiments.plan import make_plan
    from l3gs_opt.experiments.run import run_experiments

    lock = OutputLock(tmp_path / "runs.jsonl.lock", field="test").acquire()
    try:
        with pytest.raises(OutputLockedError, match=r"runs\.jsonl: process \d+ \(this process\)"):
            run_experiments(make_plan(quick=True), tmp_path, progress=False)
        code, _, err = run_cli(capsys, "experiments", "--quick", "--out", tmp_path, "--no-progress")
        assert code == 2 and "is writing here" in one_error_line(err)
    finally:
        lock.release()
    assert not (tmp_path / "runs.jsonl").exists() and not (tmp_path / "plan.json").exists()


def test_item9_compare_methods_empty_is_an_error(tmp_path, capsys):
    path = l3gs_opt.save_instance(synth_instance(objects=3, layers=2, slots=2, seed=0), tmp_path / "i.json")
    code, _, err = run_cli(capsys, "compare", path, "--methods", ",", "--out", tmp_path / "c", "--no-progress")
    assert code == 2 and one_error_line(err).startswith("error: --methods: names no method")
    assert not (tmp_path / "c" / "compare.jsonl").exists()


def _bench_record() -> dict:
    return {"schema": "l3gs-opt/bench-record@1", "record_id": "stiff/i/bb", "suite": "stiff", "instance_id": "i",
            "method": "bb", "status": "optimal", "J": 3, "T": 1, "L": 2, "problem": "MCKP", "objective": 5.0,
            "bound": 5.0, "runtime_s": 0.01, "feasible": True, "objective_ok": True, "flags": [],
            "bound_only": False, "loadavg_1m": 1.0, "spec": {"params": {"set": "s"}}, "message": None}


_JSON_VALUES = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(-5, 5), st.floats(-10, 10),
                                      st.sampled_from([math.inf, -math.inf]), st.text(max_size=3)),
                            lambda inner: st.one_of(st.lists(inner, max_size=2),
                                                    st.dictionaries(st.text(max_size=2), inner, max_size=2)),
                            max_leaves=4)


@settings(max_examples=150, deadline=None)
@given(key=st.sampled_from(sorted(_bench_record()) + ["extra"]), value=_JSON_VALUES, drop=st.booleans())
def test_item8_report_on_altered_records_is_a_report_or_a_named_error(key, value, drop):
    """A bench record with one value replaced (or removed): the report's summary, or BenchError."""
    from l3gs_opt.bench.run import BenchError, check_records
    from l3gs_opt.bench.report import annotate, known_optima_summary, summarise

    good = _bench_record()
    other = dict(good, record_id="stiff/i/greedy", method="greedy", status="feasible", objective=4.0, bound=None)
    bad = dict(good)
    if drop:
        bad.pop(key, None)
    else:
        bad[key] = value
    try:
        records = check_records([other, bad])
    except BenchError as exc:
        assert str(exc).startswith("records[1]: not a bench record (")
        return
    summary = summarise(annotate(records))
    assert sum(s["records"] for methods in summary.values() for s in methods.values()) == 2
    known_optima_summary(annotate(records))


@pytest.mark.parametrize("key, value, why", [
    ("spec", "abc", "spec = 'abc' is not an object or null"),
    ("spec", {"params": [1]}, "spec.params = [1] is not an object or null"),
    ("runtime_s", "1e400", "runtime_s = inf is not a finite number or null"),
    ("runtime_s", -1.0, "runtime_s = -1.0 is negative"),
    ("T", -3, "T = -3 is negative"),
    ("versions", "x" * 100, "versions = 'xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx... is not an object or null"),
])
def test_item8_report_names_a_field_it_cannot_use(tmp_path, capsys, key, value, why):
    """Each of these used to reach the report's code and end in a traceback (a string spec, an
    infinite run time on a log axis) or in a report of nonsense (a negative size or run time)."""
    rec = _bench_record()
    rec[key] = "@" if value == "1e400" else value
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps(rec).replace('"@"', "1e400") + "\n")
    code, _, err = run_cli(capsys, "report", path, "--out", tmp_path / "rep")
    assert code == 2
    assert one_error_line(err) == (f"error: {path}[0]: not a bench record ({why}; expected "
                                   "l3gs-opt/bench-record@1 records from l3gs-opt bench or compare)")


def test_item8_report_refuses_nan_in_a_records_file(tmp_path, capsys):
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps(_bench_record()).replace("5.0", "NaN", 1) + "\n" + json.dumps(_bench_record()) + "\n")
    code, _, err = run_cli(capsys, "report", path, "--out", tmp_path / "rep")
    assert code == 2 and re.search(r"r\.jsonl\[1\]: line 1 is not a JSON record: NaN is not JSON", one_error_line(err))


def test_an_output_path_under_a_file_is_one_error_line(tmp_path, capsys):
    """An OSError no command foresaw (here: report's folder under a file; also render's --out) is one
    line naming the path, exit 2, not a traceback."""
    records = tmp_path / "r.jsonl"
    records.write_text(json.dumps(_bench_record()) + "\n")
    (tmp_path / "afile").write_text("x")
    code, _, err = run_cli(capsys, "report", records, "--out", tmp_path / "afile" / "sub")
    assert code == 2
    assert one_error_line(err) == f"error: {tmp_path / 'afile' / 'sub'}: Not a directory"


def test_os_error_line_names_the_paths():
    from l3gs_opt.cli.main import os_error_line

    assert os_error_line(FileExistsError(17, "File exists", "out/a")) == "out/a: a file where a folder is needed"
    assert os_error_line(PermissionError(13, "Permission denied", "a", None, "b")) == "a -> b: Permission denied"
    assert os_error_line(OSError("no path")) == "no path"


def test_report_of_an_empty_records_file_is_an_error(tmp_path, capsys):
    path = tmp_path / "r.jsonl"
    path.write_text("\n")
    code, _, err = run_cli(capsys, "report", path, "--out", tmp_path / "rep")
    assert code == 2
    assert one_error_line(err) == (f"error: {path}: holds no records (expected the results.jsonl of l3gs-opt "
                                   "bench or compare)")
    assert not (tmp_path / "rep").exists()
