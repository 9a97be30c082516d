"""Bad input to simulate, utility check, bundle tables, instance from-scene and replay: one line that
names the field (and the record), never a traceback, a hang or silent acceptance.

Regression tests, one per bug; a tiny procedural bundle (1000 splats, 16x12 pixels, 2 slots).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from l3gs_opt.delivery.replay import ReplayError, write_replay
from l3gs_opt.errors import InstanceError
from l3gs_opt.pipeline.counts import MAX_SAMPLES_PER_SLOT, CountError, check_count
from l3gs_opt.pipeline.fidelity import FidelityError, utility_fidelity
from l3gs_opt.pipeline.scene_instance import viewer_cameras
from l3gs_opt.pipeline.splat_utility import UtilityError, build_utility_table, grid_positions
from l3gs_opt.pipeline.utilities import UtilityNameError, get_utility
from l3gs_opt.simulator.simulation import SimConfig, SimulationError
from cli_helpers import one_error_line, tiny_sort_bundle
from renderer_helpers import make_camera


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    w = tiny_sort_bundle(tmp_path_factory.mktemp("bad"))
    return {**w, "ok": w["bundle"]}


def _sim_args(world, bundle=None) -> list:
    return ["simulate", bundle or world["ok"], "--trace", "lumos-throughput-mid-11", "--mbps", "0.2",
            "--path", world["log"], "--width", "16", "--height", "12", "--no-progress", "--no-cache",
            "--method", "l3gs", "--slots", "2"]


def _edited_bundle(world, tmp_path, edit) -> str:
    """A copy of the tiny bundle with its manifest changed by ``edit(manifest)``."""
    out = tmp_path / "b"
    shutil.copytree(world["ok"], out)
    m = json.loads((out / "manifest.json").read_text())
    edit(m)
    (out / "manifest.json").write_text(json.dumps(m))
    return str(out)


# -- 1: a MODULE:NAME utility that cannot be called as f(scene, camera)
def test_utility_with_wrong_signature_is_one_line_naming_it(world, capsys):
    with pytest.raises(UtilityNameError, match=r"^utility: 'os:getcwd' could not be called as a utility .*TypeError"):
        get_utility("os:getcwd").splat_values(world["scene"], [make_camera(16, 12)])
    line = one_error_line(capsys, *_sim_args(world), "--utility", "os:system")
    assert line.startswith("error: --utility: 'os:system' could not be called as a utility") and "TypeError" in line


# -- 2: a negative seed
def test_fidelity_negative_seed_is_named(tmp_path):
    with pytest.raises(FidelityError, match=r"^seed = -1: must be an integer >= 0"):
        utility_fidelity(tmp_path / "none", tmp_path / "none.log", seed=-1)


@pytest.mark.parametrize("field, value, high", [("samples", 10_001, 10_000), ("samples_per_slot", 1_001, 1_000),
                                                ("slots", 10**6 + 1, 10**6), ("width", 16_385, 16_384),
                                                ("height", 10, 16_384)])
def test_fidelity_counts_have_upper_limits(tmp_path, field, value, high):
    """A mistyped count (``--samples 100000000``) rendered for days: refused before the bundle is read."""
    lo = 11 if field in ("width", "height") else 1
    with pytest.raises(FidelityError, match=rf"^{field}: {value}: must be an integer in \[{lo}, {high}\]$"):
        utility_fidelity(tmp_path / "none", tmp_path / "none.log", **{field: value})


def test_fidelity_samples_limit_on_the_command_line(capsys, tmp_path):
    line = one_error_line(capsys, "utility", "check", tmp_path / "none", "--path", tmp_path / "none.log",
                          "--samples", "100000000", "--out", tmp_path / "o")
    assert line == "error: --samples: 100000000: must be an integer in [1, 10000]", line
    assert not (tmp_path / "o").exists()


# -- 3: a grid of petabytes
def test_huge_grid_is_refused_before_allocating():
    with pytest.raises(UtilityError, match=r"^counts = \[100000, 100000, 100000\]: .*MAX_GRID_POSITIONS"):
        grid_positions([0, 0, 0], [1, 1, 1], [100_000] * 3)


# -- 4: counts that would hang
def test_check_count_limits():
    assert check_count("n", 3, high=5) == 3
    for bad in (0, 6, 2.0, True, None):
        with pytest.raises(CountError, match=r"^n: .* must be an integer in \[1, 5\]"):
            check_count("n", bad, high=5)


@pytest.mark.parametrize("field", ["samples_per_slot", "substeps"])
def test_simconfig_huge_counts_are_named(field):
    with pytest.raises(SimulationError, match=rf"^{field}: 100000000: must be an integer in \[1, 1000\]"):
        SimConfig(**{field: 100_000_000})


def test_viewer_cameras_huge_samples_per_slot(world):
    # Where the samples are made: instance from-scene, utility check and the experiments all get it.
    with pytest.raises(InstanceError, match=rf"^samples_per_slot: 100000000: .*\[1, {MAX_SAMPLES_PER_SLOT}\]"):
        viewer_cameras(world["log"], slots=1, samples_per_slot=100_000_000)


def test_cli_huge_samples_per_slot_and_substeps(world, capsys):
    for flag in ("--samples-per-slot", "--substeps"):
        line = one_error_line(capsys, *_sim_args(world), flag, "100000000")
        assert line.startswith(f"error: {flag}: 100000000"), line


def test_huge_yaw_steps_is_named(world):
    with pytest.raises(UtilityError, match=r"^yaw_steps = 100000000: must be an integer in \[1, 3600\]"):
        build_utility_table(world["scene"], np.zeros((1, 3)), yaw_steps=100_000_000)


# -- 5: bundles that bundle export refuses
@pytest.mark.parametrize("edit, match", [
    (lambda m: m["chunks"].append(m["chunks"][0]), r"^error: chunks\[\d+\]: .*also chunk 0"),
    (lambda m: m["levels"][1].update(cumulative_splats=1), r"^error: levels\[1\]: cumulative_splats 1 must be"),
    (lambda m: m["build"].update(teacher="/nonexistent/teacher.ply"), r"^error: build.teacher: /nonexistent/teacher"),
], ids=["duplicate-chunk", "cumulative-splats", "teacher-missing"])
def test_simulate_refuses_bundles_export_refuses(world, tmp_path, capsys, edit, match):
    line = one_error_line(capsys, *_sim_args(world, _edited_bundle(world, tmp_path, edit)))
    assert __import__("re").match(match, line), line


def test_instance_from_scene_refuses_duplicate_chunk(world, tmp_path, capsys):
    bundle = _edited_bundle(world, tmp_path, lambda m: m["chunks"].append(m["chunks"][0]))
    line = one_error_line(capsys, "instance", "from-scene", bundle, "--path", world["log"], "--trace",
                          "lumos-throughput-mid-11", "--window", "0:2", "-o", tmp_path / "i.json")
    assert line.startswith("error: chunks["), line


# -- 7: --slots 0
def test_simulate_zero_slots_names_slots(world, capsys):
    line = one_error_line(capsys, *_sim_args(world)[:-2], "--slots", "0")
    assert line.startswith("error: --slots: 0: must be an integer in [1, "), line


# -- 4 and 6: replay records
def _run_dir(tmp_path, **change) -> str:
    """A two-slot run folder (records as simulate writes them, minus what the page does not read)."""
    records = [{"method": "l3gs", "solver": None, "utility": "eq1", "slot": t, "time_s": t + 1.0, "ssim": 0.9,
                "psnr": 30.0, "bytes_delivered": 100, "bytes_trace": 200, "requests": [[0, 0]],
                "completed": [[0, 0]], "in_flight": []} for t in range(2)]
    records[1].update(change)
    summary = {"method": "l3gs", "solver": None, "utility": "eq1", "slots": 2, "slot_s": 1.0, "units": [2, 2]}
    (tmp_path / "slots.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    (tmp_path / "summary.jsonl").write_text(json.dumps(summary) + "\n")
    return str(tmp_path)


def test_replay_of_good_records_works(tmp_path):
    assert write_replay(_run_dir(tmp_path), tmp_path / "page").is_file()


@pytest.mark.parametrize("change, match", [
    ({"ssim": 5.0}, r"^ssim\[2\]: 5.0 must be in \[-1, 1\]"),
    ({"requests": [[999, 999]]}, r"^requests\[2\]: \[999, 999\]: no such chunk"),
    ({"in_flight": [[0, 7, 10]]}, r"^in_flight\[2\]: \[0, 7, 10\]: no such chunk"),
    ({"slot": 1_000_000_000_000}, r"^slot\[2\]: 1000000000000 must be below 2"),
], ids=["ssim", "requests", "in-flight", "slot"])
def test_replay_refuses_bad_records(tmp_path, change, match):
    with pytest.raises(ReplayError, match=match):
        write_replay(_run_dir(tmp_path, **change), tmp_path / "page")


def test_replay_cli_huge_slot_is_one_line(tmp_path, capsys):
    line = one_error_line(capsys, "replay", _run_dir(tmp_path, slot=1_000_000_000_000), "--out", tmp_path / "p")
    assert line.startswith("error: slot[2]: 1000000000000 must be below 2"), line


def test_utility_check_negative_seed_is_one_line(world, tmp_path, capsys):
    line = one_error_line(capsys, "utility", "check", world["ok"], "--path", world["log"], "--slots", "2",
                          "--samples", "1", "--seed", "-1", "--out", tmp_path / "f")
    assert line == "error: --seed = -1: must be an integer >= 0", line
