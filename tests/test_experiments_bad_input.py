"""Bad input to ``l3gs-opt experiments``: one ``error:`` line naming the option, exit 2, before the
plan runs (no scene or bundle is built: running the plan fails these tests at once)."""

from __future__ import annotations

import json

import pytest

from cli_helpers import one_error_line, run_cli


class _Ran(Exception):
    """The plan was accepted and would have run."""


@pytest.fixture(autouse=True)
def no_run(monkeypatch):
    """Stand-ins for the run: record the plan it got, then stop (building a scene takes ~20 s)."""
    import l3gs_opt.experiments.run as run

    got = {}

    def fake_run(plan, *_args, **_kwargs):
        got["plan"] = plan
        raise _Ran

    monkeypatch.setattr(run, "run_experiments", fake_run)
    monkeypatch.setattr(run, "plan_fidelity", fake_run)
    return got


def _base(tmp_path, **over) -> list[str]:
    """A tiny plan: one 1000-splat room, one 2 s window, one method, one ablation."""
    opts = {"--out": tmp_path / "out", "--traces": "lumos-throughput-mid-11", "--starts": 1, "--window": 2,
            "--paths": "orbit", "--variants": "layered", "--methods": "l3gs", "--ablations": "true_bandwidth",
            "--width": 16, "--height": 12, "--splats": 1000, "--objects": 1}
    opts.update(over)
    argv = ["experiments", "--no-progress", "--no-fidelity"]
    for k, v in opts.items():
        argv += [k, v]
    return argv


def test_good_lists_still_reach_the_plan(tmp_path, capsys, no_run):
    with pytest.raises(_Ran):
        run_cli(capsys, *_base(tmp_path, **{"--sizes": "500, 1000", "--ablation-methods": "l3gs"}))
    plan = no_run["plan"]
    assert plan.scenes[0].sizes == (500, 1000)
    assert plan.ablations == ("true_bandwidth",) and [m for m, _ in plan.ablation_methods] == ["l3gs"]


@pytest.mark.parametrize("sizes, message", [
    ("a,b", "error: --sizes[0]: 'a': expected a whole number of splats"),
    ("500,1000.5", "error: --sizes[1]: '1000.5': expected a whole number of splats"),
    (",", "error: --sizes: ',': names no size"),
    ("", "error: --sizes: '': names no size"),
])
def test_sizes(tmp_path, capsys, sizes, message):
    assert one_error_line(capsys, *_base(tmp_path, **{"--sizes": sizes})) == message


@pytest.mark.parametrize("over, start", [
    ({"--width": 100000}, "error: --width: 100000: must be an integer in [11, 16384]"),
    ({"--height": 100000}, "error: --height: 100000: must be an integer in [11, 16384]"),
    ({"--width": 16384, "--height": 16384}, "error: --width: 16384 x 16384 = 268,435,456 pixels, more than"),
    ({"--jobs": -1}, "error: --jobs = -1: must be an integer >= 0"),
    ({"--jobs": 1, "--executor": "dask", "--address": "not an address"},
     "error: --address 'not an address': not a Dask scheduler address"),
])
def test_picture_size_and_jobs_before_the_plan_runs(tmp_path, capsys, over, start):
    line = one_error_line(capsys, *_base(tmp_path, **over))
    assert line.startswith(start), line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("traces, message", [
    ("", "error: --traces: '': names no trace"),
    (",", "error: --traces: ',': names no trace"),
    ("lumos-throughput-mid-11,,lumos-throughput-low-47",
     "error: --traces[1]: 'lumos-throughput-mid-11,,lumos-throughput-low-47': an empty trace name (a comma too many?)"),
])
def test_empty_traces(tmp_path, capsys, monkeypatch, traces, message):
    # The current folder holds a trace-like file: "" must not read it.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "t.txt").write_text("1\n2\n3\n4\n")
    assert one_error_line(capsys, *_base(tmp_path, **{"--traces": traces})) == message


@pytest.mark.parametrize("option, what", [
    ("--ablations", "condition"), ("--ablation-methods", "method"), ("--methods", "method"),
    ("--paths", "path"), ("--variants", "variant"), ("--utilities", "utility"), ("--last-chunk", "value"),
])
@pytest.mark.parametrize("text", ["", ","])
def test_empty_lists(tmp_path, capsys, option, what, text):
    assert one_error_line(capsys, *_base(tmp_path, **{option: text})) == f"error: {option}: {text!r}: names no {what}"


def test_check_time_inf(tmp_path, capsys):
    line = one_error_line(capsys, *_base(tmp_path, **{"--check-time": "inf"}))
    assert line == "error: --check-time: inf: must be a finite number of seconds >= 0"


def _sim(i: int) -> dict:
    return {"kind": "sim", "record_id": f"s/layered/t@0/orbit/l3gs/none/{i}", "method": "l3gs"}


@pytest.mark.parametrize("lines, message", [
    ([], "holds no records (expected the runs.jsonl of l3gs-opt experiments)"),
    (["", "  "], "holds no records (expected the runs.jsonl of l3gs-opt experiments)"),
    # a bench results record, after a good one and a blank line
    ([json.dumps(_sim(0)), "", json.dumps({"suite": "l3gs", "instance_id": "slot-J2-s0", "kind": "slot",
                                            "record_id": "l3gs/slot-J2-s0/greedy"})],
     "line 3 is not an experiment record (kind 'slot'; expected the runs.jsonl of l3gs-opt experiments)"),
    # a fetch's slots record: no kind, no record_id
    ([json.dumps({"slot": 0, "bytes": 1000, "ssim": 0.5})],
     "line 1 is not an experiment record (kind None; expected the runs.jsonl of l3gs-opt experiments)"),
])
def test_report_only_without_experiment_records(tmp_path, capsys, lines, message):
    out = tmp_path / "out"
    out.mkdir()
    runs = out / "runs.jsonl"
    runs.write_text("".join(line + "\n" for line in lines))
    line = one_error_line(capsys, "experiments", "--report-only", "--out", out)
    assert line == f"error: --out: {runs}: {message}"
    assert not (out / "report.md").exists()


def test_ablations_none_is_the_way_to_ask_for_none(tmp_path, capsys, no_run):
    with pytest.raises(_Ran):
        run_cli(capsys, *_base(tmp_path, **{"--ablations": "none"}))
    assert no_run["plan"].ablations == ()
