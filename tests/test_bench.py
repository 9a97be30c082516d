"""Benchmark records: schema, resume after an interrupted run, flagged mismatches, the report."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

from l3gs_opt import Status
from l3gs_opt.bench.run import RECORD_SCHEMA, BenchTask, read_records, run_bench
from l3gs_opt.cli.main import main
from l3gs_opt.bench.report import annotate, write_report
from l3gs_opt.problem.solution import Solution
from l3gs_opt.bench.suites import STIFF_CASES, InstanceSpec, suite_specs

SPEC = InstanceSpec("stiff", "ties-T1", "stiff", {"case": "ties", "slots": 1}, True)
MULTI = InstanceSpec("stiff", "cost_7_orders-T5", "stiff", {"case": "cost_7_orders", "slots": 5}, False)


def wrong_objective(instance, *, slot=None, **_):
    """A deliberately broken method: claims optimal, reports twice the true value."""
    from l3gs_opt import solve

    true = solve(instance, "ilp", slot=slot)
    return Solution(problem=true.problem, method="liar", status=Status.OPTIMAL, arrivals=true.arrivals,
                    objective=2 * true.objective, bound=2 * true.objective, gap=0.0, runtime_s=0.0, slot=slot)


def over_budget(instance, *, slot=None, **_):
    """A deliberately broken method: everything arrives in the first slot, budget or not."""
    arrivals = tuple((j, l, 0) for j in range(instance.J) for l in range(instance.L) if not instance.held[j, l])
    return Solution(problem="I", method="greedy-glutton", status=Status.OPTIMAL, arrivals=arrivals, objective=1e9,
                    bound=1e9, gap=0.0, runtime_s=0.0, slot=slot)


def suboptimal_claim(instance, *, slot=None, **_):
    """Claims optimality for the empty schedule (a wrong exact method)."""
    from l3gs_opt.problem.evaluate import evaluate_objective

    value = evaluate_objective(instance, (), slot=slot)
    return Solution(problem="I", method="lazy", status=Status.OPTIMAL, arrivals=(), objective=value, bound=value,
                    gap=0.0, runtime_s=0.0, slot=slot)


def test_record_schema(tmp_path):
    out = run_bench([BenchTask(SPEC, "ilp/highs"), BenchTask(SPEC, "lp/highs"), BenchTask(MULTI, "ilp/cbc/gap")],
                    tmp_path / "r.jsonl", time_limit_s=30, jobs=1, progress=False)
    recs = read_records(out)
    assert len(recs) == 3
    for r in recs:
        assert r["schema"] == RECORD_SCHEMA
        for key in ("record_id", "suite", "instance_id", "spec", "method", "status", "objective", "bound",
                    "best_known", "rel_error", "runtime_s", "model_size", "feasible", "objective_ok", "versions",
                    "flags"):
            assert key in r, key
        assert r["feasible"] and r["objective_ok"] and r["flags"] == []
        assert InstanceSpec.from_dict(r["spec"]).build().to_dict() == (SPEC if r["spec"]["single_slot"]
                                                                       else MULTI).build().to_dict()
    by_method = {r["method"]: r for r in recs}
    assert by_method["ilp/highs"]["status"] == "optimal" and by_method["ilp/highs"]["rel_error"] == 0.0
    assert by_method["lp/highs"]["bound_only"] and by_method["lp/highs"]["bound"] >= by_method["ilp/highs"]["objective"]
    assert by_method["ilp/cbc/gap"]["problem"] == "A"


def test_existing_results_need_resume(tmp_path):
    path = tmp_path / "r.jsonl"
    run_bench([BenchTask(SPEC, "ilp/highs")], path, jobs=0, progress=False)
    from l3gs_opt import SolveError

    with pytest.raises(SolveError, match="pass --resume"):
        run_bench([BenchTask(SPEC, "ilp/highs")], path, jobs=0, progress=False)
    run_bench([BenchTask(SPEC, "ilp/highs"), BenchTask(SPEC, "ilp/scip")], path, jobs=0, progress=False,
              resume=True)
    assert [r["method"] for r in read_records(path)] == ["ilp/highs", "ilp/scip"]


def test_wrong_methods_are_flagged_not_dropped(tmp_path):
    tasks = [BenchTask(MULTI, m) for m in ("ilp/highs", "liar", "glutton", "lazy")]
    path = run_bench(tasks, tmp_path / "r.jsonl", jobs=1, progress=False,
                     custom={"liar": wrong_objective, "glutton": over_budget, "lazy": suboptimal_claim})
    recs = {r["method"]: r for r in read_records(path)}
    assert len(recs) == 4
    assert "objective_mismatch" in recs["liar"]["flags"]
    assert "infeasible" in recs["glutton"]["flags"] and recs["glutton"]["violations"]
    assert "mismatch" in recs["lazy"]["flags"] and recs["lazy"]["mismatch_with"] == ["ilp/highs"]
    assert "bound_invalid" in recs["lazy"]["flags"]
    assert recs["ilp/highs"]["flags"] == []
    report = write_report(path, tmp_path / "rep").read_text()
    for method in ("liar", "glutton", "lazy"):
        assert f"stiff/cost_7_orders-T5/{method}" in report.split("## Flagged records")[1]


def test_recheck_replays_cross_flags_after_a_rerun():
    """Records flagged against a wrong answer lose the flag once that answer is gone from the file."""
    from l3gs_opt.bench.run import recheck

    def rec(method, objective, bound, flags=()):
        return {"suite": "s", "instance_id": "i", "record_id": f"s/i/{method}", "method": method,
                "status": "optimal", "objective": objective, "bound": bound, "feasible": True,
                "objective_ok": True, "flags": list(flags)}

    wrong, right = rec("wrong", 9.0, 9.0), rec("right", 10.0, 10.0, ["mismatch", "cuts_bound_of_others", "killed"])
    replayed = {r["method"]: r for r in recheck([wrong, right])}
    assert "mismatch" in replayed["right"]["flags"] and "killed" in replayed["right"]["flags"]
    assert "bound_invalid" not in replayed["wrong"]["flags"]  # nothing better was known before it
    alone = recheck([right])[0]
    assert alone["flags"] == ["killed"] and "mismatch_with" not in alone
    later = {r["method"]: r for r in recheck([right, wrong])}
    assert {"mismatch", "bound_invalid"} <= set(later["wrong"]["flags"])
    assert right["flags"] == ["mismatch", "cuts_bound_of_others", "killed"]  # inputs are not modified


def test_hung_method_is_killed(tmp_path):
    def hang(instance, **_):
        time.sleep(60)

    t0 = time.perf_counter()
    path = run_bench([BenchTask(SPEC, "hang")], tmp_path / "r.jsonl", time_limit_s=0.2, jobs=1, progress=False,
                     custom={"hang": hang})
    (rec,) = read_records(path)
    assert rec["status"] == "time_limit" and "killed" in rec["flags"] and rec["feasible"]
    assert time.perf_counter() - t0 < 30


def test_interrupted_run_resumes_without_losing_records(tmp_path):
    out = tmp_path / "bench"
    cmd = [sys.executable, "-m", "l3gs_opt.cli.main", "bench", "--suite", "stiff", "--methods", "ilp/highs,ilp/cbc",
           "--out", str(out), "--no-progress", "--time-limit", "30"]
    # As from a terminal: a suite started as a background job (`pytest ... &`) ignores SIGINT, and
    # Python then leaves it ignored in the child, so Ctrl-C would never arrive.
    err = tmp_path / "stderr.txt"
    with open(err, "wb") as err_file:
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err_file,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    results = out / "results.jsonl"
    deadline = time.time() + 120
    while time.time() < deadline and (not results.exists() or len(results.read_text().splitlines()) < 5):
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)  # Ctrl-C
    proc.wait(timeout=60)
    before = read_records(results)
    expected = 2 * len(STIFF_CASES) * 2   # each stiff case at T=1 and T=5, two methods
    assert 5 <= len(before) < expected, (proc.returncode, err.read_text()[-500:])
    assert proc.returncode == 130
    assert main(["bench", "--suite", "stiff", "--methods", "ilp/highs,ilp/cbc", "--out", str(out), "--no-progress",
                 "--resume", "--time-limit", "30"]) == 0
    after = read_records(results)
    ids = [r["record_id"] for r in after]
    assert len(ids) == len(set(ids)) == expected  # every stiff record once, none twice
    assert after[:len(before)] == before  # finished records untouched
    assert (out / "report.md").exists()


def test_report_on_tiny_results(tmp_path):
    path = run_bench([BenchTask(SPEC, m) for m in ("ilp/highs", "ilp/cpsat", "lp/highs")] +
                     [BenchTask(MULTI, m) for m in ("ilp/highs", "ilp/highs/gap")],
                     tmp_path / "r.jsonl", jobs=0, progress=False)
    report = write_report(path, tmp_path / "rep")
    text = report.read_text()
    for png in ("stiff-single-slot-error-vs-time.png", "stiff-single-slot-time-vs-size.png",
                "stiff-multi-slot-error-vs-time.png"):
        assert (tmp_path / "rep" / png).stat().st_size > 5000
        assert png in text
    rows = {line.split("|")[1].strip(): line for line in text.splitlines() if line.startswith("| ilp/")}
    assert "ilp/cpsat" in rows and "| 1 | 1 |" in rows["ilp/cpsat"]
    assert "None: every answer was feasible" in text
    annotated = annotate(read_records(path))
    assert all(r["rel_error"] == 0.0 for r in annotated if not r["bound_only"])


def test_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["bench", "--suite", "stiff", "--methods", "nonsense", "--out", str(tmp_path)]) == 2
    assert "method 'nonsense' is not one of ilp, lp, anneal, bb" in capsys.readouterr().err
    assert main(["bench", "--suite", "stiff", "--jobs", "-1", "--methods", "ilp/highs", "--out", str(tmp_path)]) == 2
    assert main(["report", str(tmp_path / "missing.jsonl"), "--out", str(tmp_path)]) == 2
    with pytest.raises(SystemExit) as info:
        main(["bench", "--suite", "galaxy"])
    assert info.value.code == 2
    with pytest.raises(SystemExit):
        main(["bench", "--sizes", "ten"])


def test_compare_one_instance(tmp_path, capsys):
    from l3gs_opt import save_instance

    inst = MULTI.build()
    path = save_instance(inst, tmp_path / "i.json")
    assert main(["compare", str(path), "--methods", "ilp/highs,ilp/scip,lp/highs", "--out", str(tmp_path / "c"),
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "ilp/scip" in out and "report:" in out
    assert (tmp_path / "c" / "compare-error-vs-time.png").exists()


def test_dask_executor_local_cluster(tmp_path):
    pytest.importorskip("distributed")
    path = run_bench([BenchTask(SPEC, "ilp/highs"), BenchTask(SPEC, "ilp/scip")], tmp_path / "r.jsonl",
                     executor="dask", jobs=2, progress=False, time_limit_s=30)
    recs = read_records(path)
    assert sorted(r["method"] for r in recs) == ["ilp/highs", "ilp/scip"]
    assert all(r["status"] == "optimal" and not r["flags"] for r in recs)


def test_suites_are_deterministic():
    for suite in ("l3gs", "pisinger", "stiff", "problems"):
        specs = suite_specs(suite, quick=True, seeds=1)
        assert specs
        a, b = specs[0].build(), specs[0].build()
        assert a.to_dict() == b.to_dict()
        assert json.loads(json.dumps(specs[0].to_dict())) == specs[0].to_dict()


def test_every_seed_gets_a_trace_window_that_fits():
    """Regression: from seed 13 (``l3gs``, a window 60 s x seed into the trace) and seed 7
    (``problems``, 120 s x seed) the window ran past the trace's end and the spec failed to build.
    Windows are wrapped into the trace; a seed whose window fitted keeps it (the bench instances)."""
    from l3gs_opt.traces.bandwidth import read_bandwidth_trace

    for suite, step in (("l3gs", 60), ("problems", 120)):
        specs = [s for s in suite_specs(suite, sizes=[20], seeds=30) if not s.single_slot]
        for spec in specs:
            p = spec.params
            samples = len(read_bandwidth_trace(p["trace"]).mbps)
            assert 0 <= p["start"] and p["start"] + p["slots"] <= samples, spec.instance_id
            if step * p["seed"] + p["slots"] <= samples:
                assert p["start"] == step * p["seed"], spec.instance_id
    late = next(s for s in suite_specs("l3gs", sizes=[20], seeds=14) if s.instance_id == "T60-J20-s13")
    assert late.build().T == 60


def test_regression_jsonable_negative_infinity_in_details():
    """A method's details with -inf, nan, numpy scalars and odd objects become strict JSON
    (text replacement once turned ``-Infinity`` into ``-null`` and crashed the worker)."""
    import json as _json

    import numpy as np
    import math as _math

    from l3gs_opt.bench.run import _jsonable

    details = {"bound": -_math.inf, "x": [_math.nan, _math.inf, np.float64(2.5)], "n": np.int64(3),
               "flag": np.bool_(True), "arr": np.array([1.0, -np.inf]), "what": "NaN and -Infinity in text",
               "obj": object, 4: (1, 2)}
    out = _jsonable(details)
    text = _json.dumps(out, allow_nan=False)
    back = _json.loads(text)
    assert back["bound"] is None and back["x"] == [None, None, 2.5] and back["n"] == 3 and back["flag"] is True
    assert back["arr"] == [1.0, None] and back["what"] == "NaN and -Infinity in text" and back["4"] == [1, 2]


def declines(instance, *, slot=None, **_):
    """Refuses every instance, as dp does when its table would be too large."""
    from l3gs_opt.errors import SolveError

    raise SolveError("dp: the table would need 1e12 cells (more than MAX_DP_CELLS)")


def test_a_refusal_is_declined_not_an_error(tmp_path):
    path = run_bench([BenchTask(SPEC, m) for m in ("ilp/highs", "refuser")], tmp_path / "r.jsonl", jobs=1,
                     progress=False, custom={"refuser": declines})
    recs = {r["method"]: r for r in read_records(path)}
    assert recs["refuser"]["status"] == "declined" and recs["refuser"]["flags"] == []
    assert "MAX_DP_CELLS" in recs["refuser"]["message"]
    text = write_report(path, tmp_path / "rep").read_text()
    row = next(line for line in text.splitlines() if line.startswith("| refuser |"))
    assert row.split("|")[2:5] == [" 1 ", " 0 ", " 1 "]       # records, proven optimal, declined
    assert "None: every answer was feasible" in text           # a refusal is not a flagged record
    from l3gs_opt.bench.report import summarise

    old = dict(recs["refuser"], status="error", flags=["declined"])   # a record from before the status
    (suite,) = summarise(annotate([old])).values()
    assert suite["refuser"]["declined"] == 1 and suite["refuser"]["flags"] == []
