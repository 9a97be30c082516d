"""The utility fidelity check (``l3gs_opt.pipeline.fidelity``, ``l3gs-opt utility check``).

Independent reference: a utility that *is* the measured gain (the counterfactual at full size)
must rank the candidates exactly as the measurement does (Spearman and Kendall 1); the measured
gains are re-computed here by direct renders.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from l3gs_opt.cli.main import main
from l3gs_opt.pipeline.fidelity import FidelityError, utility_fidelity
from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING
from l3gs_opt.pipeline.utilities import CounterfactualUtility
from l3gs_opt.renderer.metrics import ssim
from l3gs_opt.renderer.render import render_scene
from l3gs_opt.scene.bundle import read_bundle, write_bundle
from l3gs_opt.scene.camera_paths import intrinsics_from_fov
from l3gs_opt.scene.cameras import Camera
from l3gs_opt.scene.procedural import make_scene
from l3gs_opt.traces.poses import read_pose_log, synthetic_poses, write_pose_log


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    root = tmp_path_factory.mktemp("fid")
    teacher = make_scene(3000, objects=5, sh_degree=1, seed=3)
    order = np.random.default_rng(0).permutation(teacher.num_splats)
    bounds = (0, 600, 1200, 2400)
    write_bundle(root / "layered", [teacher.subset(order[bounds[i]:bounds[i + 1]]) for i in range(3)],
                 variant="layered")
    write_bundle(root / "separate", [teacher.subset(order[:d]) for d in bounds[1:]], variant="separate")
    log = write_pose_log(synthetic_poses("orbit", seconds=12, rate_hz=30, seed=0), root / "viewer.log")
    return {"root": root, "log": log}


def test_the_measured_gain_ranks_itself_perfectly(world):
    exact = CounterfactualUtility(scale=1.0)
    rep = utility_fidelity(world["root"] / "layered", world["log"], utilities=["eq1", "visibility", exact],
                           samples=4, slots=10, width=48, height=36)
    assert rep.setup["candidates"] > 0 and len(rep.samples) == 4
    c = rep.correlations["counterfactual"]
    assert c["spearman_ssim"] == pytest.approx(1.0) and c["kendall_ssim"] == pytest.approx(1.0)
    assert c["spearman_ssim_pooled"] == pytest.approx(1.0)
    assert set(rep.seconds_per_viewpoint) == {"eq1", "visibility", "counterfactual"}
    for name in ("eq1", "visibility"):
        assert -1.0 <= rep.correlations[name]["spearman_ssim"] <= 1.0


def test_a_sample_gain_is_a_direct_render_difference(world):
    rep = utility_fidelity(world["root"] / "layered", world["log"], utilities=["eq1"], samples=1, slots=1,
                           width=48, height=36)
    s = rep.samples[0]
    bundle = read_bundle(world["root"] / "layered")
    scene = bundle.scene(bundle.num_levels - 1)
    pose = read_pose_log(world["log"])
    t = 0.5   # slot 0's one viewpoint: the middle of the slot
    feats = np.array([np.interp(t, pose.time_s, pose.features[:, i]) for i in range(6)])
    w2c = Z_UP_MAPPING.world_to_camera(feats[None, :3], feats[None, 3:])[0]
    cam = Camera(**intrinsics_from_fov(48, 36, 70.0), world_to_camera=w2c)

    def picture(mask):
        return np.clip(render_scene(scene.subset(np.flatnonzero(mask)), cam).image.numpy().astype(np.float64), 0, 1)

    full = picture(np.ones(scene.num_splats, bool))
    held = np.zeros(scene.num_splats, bool)
    for j, h in s["held_layers"].items():
        held |= (scene.object_ids == int(j)) & (scene.layers < h)
    base = ssim(picture(held), full)
    j, l = s["candidates"][0]
    add = (scene.object_ids == j) & (scene.layers == l)
    assert s["gain_ssim"][0] == pytest.approx(ssim(picture(held | add), full) - base, abs=1e-9)


def test_bad_arguments_are_named(world):
    with pytest.raises(FidelityError, match="needs a layered one"):
        utility_fidelity(world["root"] / "separate", world["log"])
    with pytest.raises(FidelityError, match=r"^samples: 0: must be an integer in \[1, 10000\]$"):
        utility_fidelity(world["root"] / "layered", world["log"], samples=0)
    with pytest.raises(FidelityError, match="utility 'nope'"):
        utility_fidelity(world["root"] / "layered", world["log"], utilities=["nope"])


def test_cli_check_and_list(world, tmp_path, capsys):
    out = tmp_path / "fid"
    assert main(["utility", "check", str(world["root"] / "layered"), "--path", str(world["log"]), "--samples", "2",
                 "--slots", "4", "--width", "32", "--height", "24", "--utilities", "eq1,visibility", "--out",
                 str(out), "--no-progress", "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert set(printed["correlations"]) == {"eq1", "visibility"}
    assert (out / "fidelity.png").stat().st_size > 0
    assert json.loads((out / "fidelity.json").read_text())["setup"]["samples"] == 2
    assert main(["utility", "check", str(world["root"] / "separate"), "--path", str(world["log"]), "--out",
                 str(tmp_path / "x"), "--no-progress"]) == 2
    assert "needs a layered one" in capsys.readouterr().err
    assert main(["utility", "list"]) == 0
    listed = capsys.readouterr().out
    assert "visibility-held" in listed and "held-aware" in listed
