"""``l3gs-opt experiments``: the plan, resumable runs, the exact ceiling, the report, the CLI.

The runs use a tiny room (1500 splats, 2 objects, 3 levels), bundles trained for 2 iterations,
4-slot windows and 64x48 renders: seconds, not minutes. Checked against independent facts: an
interrupted-then-resumed run gives the records of an uninterrupted one; every scheduler's summed
true utility is a feasible schedule of the ceiling instance and never above its exact optimum;
the report's tables against numbers computed by hand.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from l3gs_opt.cli.main import main
from l3gs_opt.experiments.plan import PAPER_SCENE_BYTES, ExperimentError, SceneSpec, make_plan, scaled_mbps, trace_class
from l3gs_opt.experiments.run import _arrivals, run_experiments
from l3gs_opt.experiments.report import summarize, write_report
from l3gs_opt.problem.instance import Instance, Options
from l3gs_opt.pipeline.build import BuildSchedule
from l3gs_opt.simulator.simulation import SIM_METHODS

TINY_BUILD = BuildSchedule(max_width=32, prune_ratio=0.3, recovery_iterations=2, finetune_iterations=2,
                           layer_iterations=2)


def _tiny_plan(**kw):
    args = dict(scenes=[SceneSpec("tiny", 1500, objects=2, sh_degree=1, seed=0, sizes=(300, 700, 1500))],
                traces=["lumos-throughput-low-47", "lumos-throughput-high-31"], starts=1, window_s=4,
                paths=["orbit-log"], ablations=["true_both"], ablation_methods=["l3gs"], width=64, height=48,
                samples_per_slot=1, schedule=TINY_BUILD, ceiling_check_s=2.0)
    args.update(kw)
    return make_plan(**args)


class _Stop(Exception):
    pass


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """One uninterrupted run of the tiny plan (bundles cached for the other tests)."""
    root = tmp_path_factory.mktemp("exp")
    plan = _tiny_plan()
    runs = run_experiments(plan, root / "full", cache_dir=root / "cache", progress=False, log=lambda s: None)
    return {"root": root, "plan": plan, "records": [json.loads(line) for line in runs.read_text().splitlines()]}


# ---------------------------------------------------------------------------------------- plan
def test_plan_is_deterministic_and_covers_every_method():
    a, b = make_plan(quick=True), make_plan(quick=True)
    assert a.to_dict() == b.to_dict() and a.tasks() == b.tasks()
    assert [t.klass for t in a.traces] == ["high", "low", "mid"]   # one trace per class
    assert all(len(s) == 1 for s in a.starts) and [p.name for p in a.paths] == ["orbit"]
    for tr, (start,) in zip(a.traces, a.starts):
        from l3gs_opt.traces.bandwidth import read_bandwidth_trace

        assert 0 <= start <= len(read_bandwidth_trace(tr.path).mbps) - a.window_s
    ids = [t.record_id for t in a.tasks()]
    assert len(ids) == len(set(ids))
    planned = {m for m, _ in a.methods} | {m for m, _ in a.variant_methods}
    assert set(SIM_METHODS) <= planned   # every simulator method runs somewhere
    assert make_plan(quick=True, seed=5).starts != a.starts
    full = make_plan(starts=3)
    assert len(full.traces) == 9 and all(len(s) == 3 and len(set(s)) == 3 for s in full.starts)


def test_scale_keeps_the_papers_ratio():
    assert scaled_mbps(PAPER_SCENE_BYTES) == pytest.approx(11.8)
    for scene_bytes in (736_000, 5_000_000):
        window_bytes = scaled_mbps(scene_bytes) * 1e6 / 8 * 60
        assert scene_bytes / window_bytes == pytest.approx(44.64e6 / (11.8e6 / 8 * 60))   # 0.504
    assert [trace_class(n) for n in ("lumos-throughput-mid-11", "lumos-throughput-low-47", "x")] == \
        ["mid", "low", "other"]


@pytest.mark.parametrize("kw, match", [
    (dict(variants=["layered", "nope"]), r"variants\[1\]: 'nope' is not one of"),
    (dict(paths=["walk"]), r"paths\[0\]: 'walk' is not one of"),
    (dict(methods=["l3gs", "bogus"]), r"methods\[1\]: 'bogus': no bundle"),
    (dict(methods=["sort"], variants=["layered"]), r"methods\[0\]: 'sort': no bundle among layered"),
    (dict(ablations=["none"]), r"ablations\[0\]: 'none' is not one of"),
    (dict(traces=["no-such-trace"]), r"traces\[0\]: 'no-such-trace': no such trace"),
    (dict(starts=0), r"starts: 0: must be an integer >= 1"),
    (dict(window_s=900), r"window_s: 900 s does not fit trace"),
])
def test_bad_arguments_are_named_errors(kw, match):
    with pytest.raises(ExperimentError, match=match):
        make_plan(quick=True, **kw)


def test_cli_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["experiments", "--quick", "--paths", "walk", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --paths[0]: 'walk' is not one of")
    assert main(["experiments", "--report-only", "--out", str(tmp_path / "none")]) == 2
    assert "error: --out:" in capsys.readouterr().err
    assert main(["experiments", "--quick", "--objects", "13", "--room-parts", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: --objects: 13: must be in 1..12")
    assert main(["experiments", "--quick", "--splats", "2000", "--sizes", "500,3000", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: scene.sizes: [500, 3000]: must increase")
    assert main(["experiments", "--quick", "--sh-degree", "5", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: --sh-degree: 5: must be 0, 1, 2 or 3")
    assert main(["experiments", "--quick", "--utilities", "eq1,nope", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: --utilities[1]: utility 'nope'")


# ---------------------------------------------------------------------------------------- runs
def test_records_are_complete_and_the_log_path_is_used(tiny):
    recs, plan = tiny["records"], tiny["plan"]
    assert [r["record_id"] for r in recs] == [t.record_id for t in plan.tasks()]
    assert (tiny["root"] / "cache" / "tiny" / "orbit-log.log").exists()   # written, then read back
    sims = [r for r in recs if r["kind"] == "sim"]
    assert all(len(r["ssim_per_s"]) == 4 and 0 <= min(r["ssim_per_s"]) <= max(r["ssim_per_s"]) <= 1 for r in sims)
    assert {r["role"] for r in sims} == {"main", "ablation", "variant"}


def test_every_scheduler_stays_below_the_exact_ceiling(tiny):
    recs = tiny["records"]
    ceilings = {(r["variant"], r["trace"], r["start_s"]): r for r in recs if r["kind"] == "ceiling"}
    assert ceilings and all(c["status"] == "optimal" and c["method"] == "link-dp" for c in ceilings.values())
    # The DP agrees with the ILP: its incumbent <= the DP optimum <= its bound.
    assert all(c["check"]["consistent"] for c in ceilings.values())
    for r in (r for r in recs if r["kind"] == "sim"):
        c = ceilings[(r["variant"], r["trace"], r["start_s"])]
        assert r["schedule_violations"] == [], r["record_id"]
        if r["method"] == "preload":
            assert r["utility_sum"] >= c["objective"] * (1 - 1e-12)
        else:
            assert r["utility_sum"] <= c["objective"] * (1 + 1e-9) + 1e-9, r["record_id"]


def test_resume_after_an_interruption_loses_and_redoes_nothing(tiny, tmp_path):
    plan = tiny["plan"]
    out = tmp_path / "run"
    seen: list[str] = []

    def stop_after_three(rec):
        seen.append(rec["record_id"])
        if len(seen) == 3:
            raise _Stop

    with pytest.raises(_Stop):
        run_experiments(plan, out, cache_dir=tiny["root"] / "cache", progress=False, on_record=stop_after_three)
    first = (out / "runs.jsonl").read_text().splitlines()
    assert len(first) == 3
    with pytest.raises(ExperimentError, match="pass --resume"):
        run_experiments(plan, out, cache_dir=tiny["root"] / "cache", progress=False)
    with pytest.raises(ExperimentError, match=r"different plan \(.*window_s"):
        run_experiments(_tiny_plan(window_s=3), out, resume=True, cache_dir=tiny["root"] / "cache", progress=False)
    with open(out / "runs.jsonl", "a") as fh:
        fh.write('{"record_id": "torn')   # a write cut off by a kill
    again: list[str] = []
    run_experiments(plan, out, resume=True, cache_dir=tiny["root"] / "cache", progress=False,
                    on_record=lambda r: again.append(r["record_id"]))
    lines = (out / "runs.jsonl").read_text().splitlines()
    assert lines[:3] == first
    ids = [t.record_id for t in plan.tasks()]
    assert again == ids[3:]                                   # nothing finished was redone
    got = [json.loads(line) for line in lines]
    assert [r["record_id"] for r in got] == ids               # nothing lost, no torn line left
    # The same numbers as the uninterrupted run (timings aside).
    for a, b in zip(got, tiny["records"]):
        for key in ("ssim_per_s", "utility_sum", "objective", "predicted_bytes", "bytes_delivered"):
            if b.get(key) is None:
                assert a.get(key) is None
            else:
                assert a[key] == pytest.approx(b[key], rel=1e-12), (a["record_id"], key)
    sessions = (out / "sessions.jsonl").read_text().splitlines()
    assert [json.loads(s)["records_written"] for s in sessions] == [3, len(ids) - 3]


# ---------------------------------------------------------------------------------------- mapping
def test_completed_units_map_to_problem_one_arrivals():
    inst = Instance("layered", bandwidth=[100] * 4, cost=[[10, 20], [1, 30]], utility=np.ones((4, 2, 2)),
                    options=Options(budget="cumulative"), meta={"empty_chunks": [[1, 0]]})
    # Whole-scene layers: unit (0, l) completes every object's layer l.
    scene = [{"slot": 0, "completed": [[0, 0]]}, {"slot": 1, "completed": []}, {"slot": 2, "completed": [[0, 1]]}]
    got, why = _arrivals({"view": "scene", "units": [1, 2]}, scene, inst)
    assert why is None and got == [(0, 0, 0), (0, 1, 2), (1, 0, 2), (1, 1, 2)]
    # Distill: a layer counts once compact and upgrade are both there, and after the layers below.
    distill = [{"slot": 0, "completed": [[0, 0, 0], [0, 1, 0]]}, {"slot": 1, "completed": [[0, 1, 1]]},
               {"slot": 3, "completed": [[0, 0, 1], [1, 1, 0], [1, 1, 1]]}]
    got, _ = _arrivals({"view": "distill", "units": [2, 2, 2]}, distill, inst)
    assert got == [(0, 0, 3), (0, 1, 3), (1, 0, 3), (1, 1, 3)]
    got, why = _arrivals({"view": "mystery", "units": [2, 2]}, scene, inst)
    assert got is None and "mystery" in why


# ---------------------------------------------------------------------------------------- report
def _rec(method, variant, window, ssim, *, role="main", ablation="none", utility=None, timings=None, fresh=None):
    trace, klass, start, pred, true, cv = window
    return {"kind": "sim", "record_id": f"{method}/{variant}/{trace}/{ablation}", "scene": "s", "variant": variant,
            "trace": trace, "trace_class": klass, "start_s": start, "path": "orbit", "method": method,
            "ablation": ablation, "role": role, "ssim_per_s": ssim, "ssim_mean": float(np.mean(ssim)),
            "psnr_mean": 20.0, "predicted_bytes": pred, "trace_bytes": true, "bandwidth_cv": cv,
            "timings_mean_s": timings or dict(prediction=0.001, utility=0.002, scheduling=0.003, rendering=0.010,
                                              reference=0.1, metrics=0.01),
            "bytes_model": 1000, "bytes_wasted": 0, "utility_sum": utility, "schedule_violations": [],
            "scene_bytes": 736_000, "mbps": 0.1946, "window_s": 2, "render_fresh_s": fresh}


def _ceil(variant, window, objective, status="optimal", bound=None):
    trace, _, start = window[:3]
    return {"kind": "ceiling", "scene": "s", "variant": variant, "trace": trace, "start_s": start, "path": "orbit",
            "method": "link-dp", "status": status, "objective": objective,
            "bound": objective if bound is None else bound, "check": None}


W1 = ("lumos-throughput-low-47", "low", 0, [100, 80], [100, 100], 0.5)
W2 = ("lumos-throughput-high-31", "high", 10, [50, 60], [50, 40], 0.2)


def _hand_records():
    t2 = dict(prediction=0.001, utility=0.002, scheduling=0.003, rendering=0.020, reference=0.0, metrics=0.01)
    return [
        _ceil("layered", W1, 100.0), _ceil("layered", W2, 200.0), _ceil("sort", W1, 50.0), _ceil("sort", W2, 50.0),
        _ceil("separate", W1, 100.0), _ceil("separate", W2, 100.0, status="time_limit", bound=120.0),
        _ceil("distill", W1, 100.0), _ceil("distill", W2, 100.0),
        # l3gs rendered 2 of its 4 slots, 50 ms in all (the other 2 came from the render cache).
        _rec("l3gs", "layered", W1, [0.4, 0.8], utility=80.0, fresh=[0.05, 2]),
        _rec("l3gs", "layered", W2, [0.6, 1.0], utility=150.0, timings=t2, fresh=[0.0, 0]),
        _rec("sort", "sort", W1, [0.2, 0.6], utility=25.0), _rec("sort", "sort", W2, [0.4, 0.4], utility=40.0),
        _rec("separate", "separate", W1, [0.1, 0.3], utility=90.0),
        _rec("separate", "separate", W2, [0.4, 0.6], utility=60.0),
        _rec("preload", "layered", W1, [1.0, 1.0], utility=300.0), _rec("preload", "layered", W2, [0.9, 0.9],
                                                                         utility=300.0),
        _rec("l3gs", "layered", W1, [0.6, 0.7], role="ablation", ablation="true_both", utility=70.0),
        _rec("l3gs", "layered", W2, [0.8, 0.9], role="ablation", ablation="true_both", utility=70.0),
        _rec("distill", "distill", W1, [0.5, 0.5], role="variant", utility=50.0),
        _rec("distill", "distill", W2, [0.7, 0.7], role="variant", utility=100.0),
    ]


def test_report_tables_match_a_hand_computation(tmp_path):
    s = summarize(_hand_records())
    m = s["methods"]
    assert {k: v["ssim_mean"] for k, v in m.items()} == pytest.approx(
        {"l3gs": 0.7, "sort": 0.4, "separate": 0.35, "preload": 0.95})
    assert m["l3gs"]["ssim_over_time"] == pytest.approx([0.5, 0.9])
    assert m["separate"]["ssim_over_time"] == pytest.approx([0.25, 0.45])
    assert m["l3gs"]["ssim_std"] == pytest.approx(0.1)
    h = s["headline"]
    assert h["baselines"] == pytest.approx({"sort": 75.0, "separate": 100.0})
    assert h["best_baseline"] == "sort" and h["vs_best_pct"] == pytest.approx(75.0)
    assert h["vs_mean_of_baselines_pct"] == pytest.approx(87.5) and h["preload_above_all"] is True
    assert s["ablations"] == {"l3gs": pytest.approx({"none": 0.7, "true_both": 0.75})}
    low, high = s["classes"]["low"], s["classes"]["high"]
    assert low["bw_error_pct"] == pytest.approx(20.0) and high["bw_error_pct"] == pytest.approx(50.0)
    assert low["ssim"]["sort"] == pytest.approx(0.4) and high["ssim"]["separate"] == pytest.approx(0.5)
    assert s["latency_ms"]["l3gs"] == pytest.approx(dict(prediction=1.0, utility=2.0, scheduling=3.0, rendering=25.0,
                                                         reference=50.0, metrics=10.0, cached_pct=50.0))
    # Records without the fresh-render split: the mean over all slots (10 ms).
    assert s["latency_ms"]["sort"]["rendering"] == pytest.approx(10.0) and "cached_pct" not in s["latency_ms"]["sort"]
    assert s["variants"]["distill (distill)"]["vs_layered_pct"] == pytest.approx(100 * (0.6 / 0.7 - 1))
    c = s["ceiling"]
    assert c["l3gs (layered)"]["gap_pct"] == pytest.approx(22.5)          # (20% + 25%) / 2
    assert c["sort (sort)"]["gap_pct"] == pytest.approx(35.0)             # (50% + 20%) / 2
    # A time-limited ceiling is replaced by its bound (120): (10% + 50%) / 2, and not "proven optimal".
    assert c["separate (separate)"]["gap_pct"] == pytest.approx(30.0)
    assert c["separate (separate)"]["all_optimal"] is False and c["l3gs (layered)"]["all_optimal"] is True
    assert c["distill (distill)"]["gap_pct"] == pytest.approx(25.0) and c["preload (layered)"]["preload"]

    path = write_report(_hand_records(), tmp_path)
    text = path.read_text()
    assert "| l3gs | layered | 2 | 0.7000 | 0.7000 | 0.1000 | 20.00 | - |" in text
    assert "| sort | sort | 2 | 0.4000 | 0.4000 | 0.0000 | 20.00 | +75.0% |" in text
    assert "l3gs vs the best baseline (sort): +75.0%" in text and "+87.5%" in text
    assert "| l3gs | 0.7000 | 0.7500 |" in text
    assert "| low | low-47 | 1 | 0.500 | 20.0% | 0.6000 | 0.4000 | 0.2000 | 1.0000 |" in text
    assert "| l3gs | 1.00 | 2.00 | 3.00 | 25.00 | 31.00 | 50% | 50.00 | 10.00 |" in text
    assert "| distill (distill) | 2 | 0.6000 | -14.3% |" in text
    assert "| l3gs (layered) | 2 | 0.7000 | 115 | 150 | 22.5% | yes | 0 |" in text
    assert "| separate (separate) | 2 | 0.3500 | 75 | 110 | 30.0% | no | 0 |" in text
    for name in ("ssim_over_time", "ssim_mean", "ablations", "classes", "latency", "variants", "ceiling"):
        png = tmp_path / f"{name}.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
        assert f"({name}.png)" in text


def test_report_of_a_real_run(tiny, tmp_path):
    path = write_report(tiny["root"] / "full" / "runs.jsonl", tmp_path)
    text = path.read_text()
    for section in ("## 1.", "## 2.", "## 3.", "## 4.", "## 5.", "## 6."):
        assert section in text
    assert "proven optimal" in text and "Scale." in text and "Run time:" in text
    assert main(["experiments", "--report-only", "--out", str(tiny["root"] / "full")]) == 0


# ---------------------------------------------------------------------------------------- executors, utilities
_SAME = ("ssim_per_s", "utility_sum", "objective", "predicted_bytes", "bytes_delivered")


@pytest.mark.parametrize("executor", ["local", "dask"])
def test_parallel_runs_give_the_sequential_records(tiny, tmp_path, executor):
    """--jobs 2: each window's records run as one task on forked workers (or a local Dask cluster);
    the records are those of the sequential run, in groups."""
    if executor == "dask":
        pytest.importorskip("distributed")
    plan = tiny["plan"]
    runs = run_experiments(plan, tmp_path / "par", cache_dir=tiny["root"] / "cache", progress=False, jobs=2,
                           executor=executor)
    got = {r["record_id"]: r for r in map(json.loads, runs.read_text().splitlines())}
    want = {r["record_id"]: r for r in tiny["records"]}
    assert set(got) == set(want)
    for rid, r in want.items():
        for key in _SAME:
            assert got[rid].get(key) == r.get(key), (rid, key)


def test_a_plan_of_two_utilities(tiny, tmp_path):
    """Methods that schedule by a utility run once per utility (their own records and ceilings);
    sort and preload once. The eq1 records are those of the one-utility plan."""
    plan = _tiny_plan(utilities=["eq1", "visibility-held"], traces=["lumos-throughput-low-47"], ablations=[])
    tasks = plan.tasks()
    ids = [t.record_id for t in tasks]
    assert any(i.endswith("/ceiling[visibility]") for i in ids) and any(i.endswith("/ceiling") for i in ids)
    assert any(i.endswith("l3gs/none[visibility-held]") for i in ids)
    assert not any("sort/none[" in i or "preload/none[" in i for i in ids)
    assert plan.to_dict()["utilities"] == ["eq1", "visibility-held"]
    assert "utilities" not in _tiny_plan().to_dict()     # one-utility plans keep their old form
    runs = run_experiments(plan, tmp_path / "u", cache_dir=tiny["root"] / "cache", progress=False)
    got = {r["record_id"]: r for r in map(json.loads, runs.read_text().splitlines())}
    want = {r["record_id"]: r for r in tiny["records"]}
    for rid, r in got.items():
        if rid in want and r["kind"] == "sim":
            assert r["ssim_per_s"] == want[rid]["ssim_per_s"], rid
    held = [r for r in got.values() if r.get("utility") == "visibility-held"]
    assert held and all(r["method"].endswith("[visibility-held]") and r["truth_utility"] == "visibility"
                        for r in held)
    ceil = {(r["variant"], r["truth_utility"]): r for r in got.values() if r["kind"] == "ceiling"}
    for r in held:
        assert r["utility_sum"] <= ceil[(r["variant"], "visibility")]["objective"] * (1 + 1e-9) + 1e-9
    summary = summarize(list(got.values()))
    assert "l3gs[visibility-held]" in summary["methods"] and "l3gs" in summary["methods"]
    with pytest.raises(ExperimentError, match=r"utilities\[0\]: utility 'nope'"):
        _tiny_plan(utilities=["nope"])


def test_a_plan_that_also_counts_the_last_chunks_first_splats(tiny, tmp_path):
    """--last-chunk whole,prefix: l3gs runs once per value in experiment 1 (its
    prefix records tagged ``+prefix``), everything else once; the whole-chunk records are those of
    the plain plan, and the prefix runs stay feasible schedules below the exact ceiling."""
    kw = dict(traces=["lumos-throughput-low-47"], ablations=[], utilities=["eq1", "visibility", "counterfactual"])
    plan = _tiny_plan(last_chunks=["whole", "prefix"], **kw)
    plain = _tiny_plan(**kw)
    ids = [t.record_id for t in plan.tasks()]
    extra = sorted(set(ids) - {t.record_id for t in plain.tasks()})
    assert all(i.endswith("+prefix") for i in extra) and len(extra) == len(set(ids)) - len(plain.tasks())
    assert {i.split("/")[-2] for i in extra} == {"l3gs"}
    assert not any("counterfactual]+prefix" in i for i in ids)   # (it values whole chunks)
    assert any("counterfactual" in n for n in plan.notes)
    assert plan.to_dict()["last_chunks"] == ["whole", "prefix"] and "last_chunks" not in plain.to_dict()
    only_l3gs = _tiny_plan(last_chunks=["whole", "prefix"], methods=["l3gs", "sort"], utilities=["visibility"],
                           traces=["lumos-throughput-low-47"])
    assert not any("+prefix" in t.record_id for t in only_l3gs.tasks() if t.role != "main")   # ablations: whole
    runs = run_experiments(_tiny_plan(last_chunks=["whole", "prefix"], methods=["l3gs", "sort"],
                                      traces=["lumos-throughput-low-47"], ablations=[]),
                           tmp_path / "lc", cache_dir=tiny["root"] / "cache", progress=False)
    got = {r["record_id"]: r for r in map(json.loads, runs.read_text().splitlines())}
    want = {r["record_id"]: r for r in tiny["records"]}
    prefix = [r for r in got.values() if r["record_id"].endswith("+prefix")]
    assert [r["method"] for r in prefix] == ["l3gs+prefix"] and prefix[0]["last_chunk"] == "prefix"
    for rid, r in got.items():
        if rid in want and r["kind"] == "sim":
            assert r["ssim_per_s"] == want[rid]["ssim_per_s"] and r["last_chunk"] == "whole", rid
    ceiling = next(r for r in got.values() if r["kind"] == "ceiling" and r["variant"] == "layered")
    assert prefix[0]["utility_sum"] <= ceiling["objective"] * (1 + 1e-9) + 1e-9
    assert prefix[0]["schedule_violations"] == []
    summary = summarize(list(got.values()))
    assert summary["methods"]["l3gs+prefix"]["last_chunk"] == "prefix"
    assert set(summary["utilities"]["by_utility"]) == {"eq1", "eq1+prefix"}
    with pytest.raises(ExperimentError, match=r"^last_chunks\[1\]: 'bogus' is not one of whole, prefix$"):
        _tiny_plan(last_chunks=["whole", "bogus"])
    with pytest.raises(ExperimentError, match=r"^last_chunks: prefix applies to l3gs only"):
        _tiny_plan(last_chunks=["prefix"], methods=["sort"])


def test_plan_fidelity_and_its_report_section(tiny, tmp_path):
    from l3gs_opt.experiments.run import plan_fidelity

    plan = _tiny_plan(utilities=["eq1", "visibility"])
    out = tmp_path / "f"
    out.mkdir()
    got = plan_fidelity(plan, out, cache_dir=tiny["root"] / "cache", samples=3)
    assert set(got["tiny"]["utilities"]) == {"eq1", "visibility"}
    assert json.loads((out / "fidelity.json").read_text()) == json.loads(json.dumps(got))
    for c in got["tiny"]["utilities"].values():
        assert c["ms_per_viewpoint"] > 0
    report = write_report(tiny["records"], out, fidelity=got).read_text()
    assert "### Utility fidelity" in report and "| tiny | visibility |" in report


def test_by_utility_headline_by_hand():
    from l3gs_opt.experiments.report import _by_utility

    def m(name, u, mean, first5):
        return {"method_name": name, "utility": u, "ssim_mean": mean, "ssim_first5": first5}

    methods = {"l3gs": m("l3gs", "eq1", 0.5, 0.1), "l3gs[visibility]": m("l3gs", "visibility", 0.6, 0.3),
               "sort": m("sort", "eq1", 0.4, 0.2), "separate": m("separate", "eq1", 0.3, 0.0),
               "l3gs-noseg": m("l3gs-noseg", "eq1", 0.55, 0.2),
               "l3gs-noseg[visibility]": m("l3gs-noseg", "visibility", 0.66, 0.25)}
    u = _by_utility(methods)
    assert u["best"] == "visibility"
    vis = u["by_utility"]["visibility"]
    assert set(vis["baselines"]) == {"sort", "separate", "l3gs-noseg", "l3gs-noseg[visibility]"}
    assert vis["baselines"]["sort"]["l3gs_vs_pct"] == pytest.approx(50.0)
    assert vis["baselines"]["l3gs-noseg[visibility]"]["l3gs_vs_pct"] == pytest.approx(100 * (0.6 / 0.66 - 1))
    assert vis["vs_mean_of_paper_baselines_pct"] == pytest.approx((50.0 + 100.0) / 2)
    # one entry per baseline in the mean: l3gs-noseg by the same utility
    assert vis["vs_mean_of_baselines_pct"] == pytest.approx((50.0 + 100.0 + 100 * (0.6 / 0.66 - 1)) / 3)
    assert vis["matches_every_baseline"] is False and vis["beats_every_baseline_first5"] is True
    assert u["by_utility"]["eq1"]["matches_every_baseline"] is False


@pytest.mark.parametrize("method", ["exact", "ilp"])
def test_a_ceiling_whose_solver_hangs_is_killed_and_still_valid(monkeypatch, method):
    """The ceiling's solve (``exact``; ``ilp/highs`` for the DP's cross-check) is guarded: in a
    child process (here it finishes: the answer is brute force's optimum), and when the child is
    killed the answer is a feasible schedule with the LP bound, status time_limit, saying why."""
    import l3gs_opt.executors as executors
    from l3gs_opt.experiments import run as run_mod
    from l3gs_opt.problem.evaluate import feasibility_violations
    from l3gs_opt.solvers.brute_force import solve_brute_force

    inst = Instance("layered", bandwidth=[3, 2, 4], cost=[[2, 2], [1, 3]],
                    utility=np.array([[[1.0, 2.0], [0.5, 3.0]]] * 3), options=Options(budget="cumulative"))
    best = solve_brute_force(inst).objective
    guarded = run_mod._guarded_ceiling(inst, 5.0, method=method)
    assert guarded.method == method
    assert guarded.objective == pytest.approx(best) and str(guarded.status) == "optimal"
    monkeypatch.setattr(executors, "run_guarded", lambda *a, **k: None)   # as if killed
    killed = run_mod._guarded_ceiling(inst, 5.0, method=method)
    assert str(killed.status) == "time_limit" and "killed" in killed.message and killed.method == method
    assert killed.bound is not None and killed.bound >= best - 1e-9 >= killed.objective - 1e-9
    assert feasibility_violations(inst, killed.arrivals) == []

def test_a_ceiling_too_large_for_the_dp_is_proven_by_exact(monkeypatch):
    """Past the DP's state limit the ceiling is ``exact`` (guarded), proven optimal: the DP's own
    optimum (the limit lowered so that the DP is skipped) is the reference."""
    import l3gs_opt.solvers.link_dp as link_dp
    from l3gs_opt.experiments import run as run_mod

    rng = np.random.default_rng(5)
    inst = Instance("layered", bandwidth=rng.integers(0, 6, 8), cost=rng.integers(1, 5, (4, 3)),
                    utility=rng.random((8, 4, 3)), options=Options(budget="cumulative"))
    best = link_dp.solve_link_dp(inst).objective
    monkeypatch.setattr(link_dp, "MAX_STATES", 1)
    rec = run_mod._ceiling_record(None, inst, {"record_id": "c"}, 20.0, 0.0)
    assert rec["method"] == "exact" and rec["status"] == "optimal" and rec["time_limit_s"] == 20.0
    assert rec["objective"] == pytest.approx(best, rel=1e-9)
