"""The ``l3gs-opt`` command line: JSON output, instance tools, one-line errors with exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from l3gs_opt import Instance, evaluate_objective, is_feasible, load_instance, save_instance
from l3gs_opt.cli.main import main

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def small(tmp_path):
    rng = np.random.default_rng(0)
    inst = Instance("layered", bandwidth=[6, 3, 8], cost=[[2, 3], [4, 1], [3, 3]], utility=rng.random((3, 3, 2)),
                    held=[[1, 0], [0, 0], [0, 0]])
    return inst, save_instance(inst, tmp_path / "small.json")


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("extra, problem", [([], "I"), (["--form", "gap"], "A"), (["--slot", "1"], "MCKP"),
                                            (["--method", "brute"], "I"), (["--backend", "cpsat"], "I")])
def test_solve_json(capsys, small, extra, problem):
    inst, path = small
    code, out, err = run(capsys, "solve", str(path), "--json", *extra)
    assert code == 0, err
    data = json.loads(out)
    for key in ("problem", "method", "backend", "status", "objective", "bound", "gap", "runtime_s", "arrivals",
                "model_size"):
        assert key in data
    assert data["problem"] == problem and data["status"] == "optimal"
    arrivals = [tuple(a) for a in data["arrivals"]]
    slot = 1 if "--slot" in extra else None
    assert is_feasible(inst, arrivals, slot=slot)
    assert data["objective"] == pytest.approx(evaluate_objective(inst, arrivals, slot=slot), rel=1e-12)
    assert data["objective"] >= float(inst.utility[:, 0, 0].sum()) * (slot is None)  # held chunk counted


def test_solve_table(capsys, small):
    code, out, _ = run(capsys, "solve", str(small[1]), "--time-limit", "5")
    assert code == 0 and "optimal" in out and "after presolve" in out


def test_bad_instance_one_line_exit_2(capsys, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"schema": "l3gs-opt/instance@1", "representation": "layered", "bandwidth": [1],
                               "cost": [[1, -2]], "utility": [[[1.0, 1.0]]]}))
    code, out, err = run(capsys, "solve", str(bad))
    assert code == 2 and out == ""
    assert err.strip() == "error: cost[0][1] = -2: must be a positive integer (bytes)"
    code, _, err = run(capsys, "instance", "check", str(tmp_path / "nope.json"))
    assert code == 2 and err.count("\n") == 1 and "no such file" in err


def test_bad_arguments_exit_2(capsys, small):
    with pytest.raises(SystemExit) as info:
        main(["solve", str(small[1]), "--backend", "gurobi"])
    assert info.value.code == 2
    code, _, err = run(capsys, "solve", str(small[1]), "--method", "magic")
    assert code == 2 and "method 'magic' is not one of" in err
    code, _, err = run(capsys, "solve", str(small[1]), "--slot", "9")
    assert code == 2 and "slot = 9" in err


def test_synth_and_check(capsys, tmp_path):
    out_file = tmp_path / "s.npz"
    code, out, err = run(capsys, "instance", "synth", "--objects", "5", "--layers", "3", "--slots", "10",
                         "--seed", "3", "--mbps", "11.8", "--start", "50", "--budget", "cumulative", "-o",
                         str(out_file))
    assert code == 0, err
    inst = load_instance(out_file)
    assert (inst.T, inst.J, inst.L) == (10, 5, 3) and inst.options.budget == "cumulative"
    assert inst.meta["window"] == {"start_s": 50, "length_s": 10} and inst.meta["target_mean_mbps"] == 11.8
    code, out, _ = run(capsys, "instance", "check", str(out_file))
    assert code == 0 and "valid" in out
    code, _, err = run(capsys, "instance", "synth", "--trace", "no-such-trace", "-o", str(tmp_path / "x.json"))
    assert code == 2 and "no such trace file" in err


def test_console_script_installed():
    exe = Path(sys.executable).parent / "l3gs-opt"
    assert exe.exists()
    proc = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "solve" in proc.stdout


def test_demo_runs_and_reports(tmp_path, capsys):
    # Step 5 (the paper's experiments on the real quick plan, ~9 min here) is the slow test below.
    code, out, err = run(capsys, "demo", "--out", str(tmp_path / "demo"), "--time-limit", "10", "--no-bench",
                         "--no-scene", "--no-experiments")
    assert code == 0, err
    assert "all agree" in out and "5. the paper's experiments" not in out
    lines = (tmp_path / "demo" / "results.jsonl").read_text().splitlines()
    assert len(lines) >= 12 and all(json.loads(line)["status"] in ("optimal", "feasible") for line in lines)


@pytest.mark.slow
def test_demo_step_five_on_the_real_quick_plan(tmp_path, capsys):
    """The demo's step 5 exactly as `scripts/demo.sh` runs it (the quick plan, not a tiny one)."""
    code, out, err = run(capsys, "demo", "--out", str(tmp_path / "demo"), "--time-limit", "10", "--no-bench",
                         "--no-scene")
    assert code == 0, err
    assert "5. the paper's experiments, quick" in out and "l3gs vs the baselines' mean" in out
    assert (tmp_path / "demo" / "experiments" / "report.md").is_file()


@pytest.mark.slow
def test_full_demo_with_quick_bench(tmp_path, capsys):
    # Step 5 (the quick experiments, minutes) is checked on a tiny plan by the test below.
    code, out, err = run(capsys, "demo", "--out", str(tmp_path / "demo"), "--no-experiments")
    assert code == 0, err
    assert out.startswith("1. quick benchmark") and "suite stiff" in out and "all agree" in out
    assert "FLAGS" not in out
    report = (tmp_path / "demo" / "bench" / "report.md").read_text()
    assert "## Suite `pisinger`" in report and "error against run time" in report
    assert "3. scene -> schedule -> picture" in out and (tmp_path / "demo" / "scene" / "scene-story.png").is_file()


@pytest.mark.slow
def test_demo_step_five_runs_the_experiments_and_resumes(tmp_path, capsys, monkeypatch):
    """The demo's last step on the tiny experiments plan: a report with plots, one line per method,
    and a second demo in the same folder redoes nothing."""
    import l3gs_opt.experiments.plan as experiments
    from test_experiments import _tiny_plan

    plan = _tiny_plan()
    monkeypatch.setattr(experiments, "make_plan", lambda **kw: plan)
    args = ("demo", "--out", str(tmp_path / "demo"), "--no-bench", "--no-scene", "--time-limit", "5")
    code, out, err = run(capsys, *args)
    assert code == 0, err
    assert "5. the paper's experiments, quick" in out and "l3gs vs the baselines' mean" in out
    folder = tmp_path / "demo" / "experiments"
    runs = (folder / "runs.jsonl").read_text().splitlines()
    assert len(runs) == len(plan.tasks())
    assert (folder / "report.md").is_file() and (folder / "ssim_over_time.png").is_file()
    for method in {m for m, _ in plan.methods}:
        assert f"    {method} " in out
    code, out, err = run(capsys, *args)
    assert code == 0, err
    assert (folder / "runs.jsonl").read_text().splitlines() == runs


def test_item_instances_go_through_solve_and_check(capsys, tmp_path):
    """An ``l3gs-opt/items@1`` file is read by its schema: solved by the item ILP, equal to brute force."""
    from l3gs_opt.problem.items import distill_items
    from l3gs_opt.problem.items_io import save_items

    rng = np.random.default_rng(3)
    T, J, L = 3, 2, 2
    inst = distill_items(rng.integers(1, 5, (J, L)), rng.integers(1, 4, (J, L)), rng.random((T, J, L)),
                         rng.random((T, J, L)), [4, 3, 6])
    path = save_items(inst, tmp_path / "items.json")
    code, out, _ = run(capsys, "solve", str(path), "--json")
    assert code == 0
    ilp = json.loads(out)
    code, out, _ = run(capsys, "solve", str(path), "--method", "brute", "--json")
    brute = json.loads(out)
    assert ilp["status"] == brute["status"] == "optimal"
    assert ilp["objective"] == pytest.approx(brute["objective"], rel=1e-9)
    code, out, _ = run(capsys, "instance", "check", str(path))
    assert code == 0 and "valid" in out and "presolve" in out
    # A broken item file is a one-line named error, exit 2.
    data = json.loads(path.read_text())
    data["requires"] = [[0, 99]]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    code, _, err = run(capsys, "solve", str(tmp_path / "bad.json"))
    assert code == 2 and err.startswith("error: requires[0]") and len(err.strip().splitlines()) == 1


def test_a_closed_pipe_stops_quietly(monkeypatch, capsys):
    """``l3gs-opt ... | head``: the reader leaves; the command stops with 141 and no traceback."""
    import os

    r, w = os.pipe()
    os.close(r)
    out = os.fdopen(w, "w", buffering=1)
    monkeypatch.setattr(sys, "stdout", out)
    assert main(["utility", "list"]) == 141
    err = capsys.readouterr().err
    assert "Traceback" not in err
