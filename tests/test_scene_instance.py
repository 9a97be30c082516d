"""Instances from a tiny bundle: costs from the manifest, utilities from the viewer path, bandwidth from the trace."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from l3gs_opt import InstanceError, load_instance, solve
from l3gs_opt.scene.bundle import split_layers, write_bundle
from l3gs_opt.scene.cameras import camera_to_dict, look_at
from l3gs_opt.traces.poses import PoseTrace, write_pose_log
from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING, instance_from_bundle, viewer_cameras
from l3gs_opt.traces.bandwidth import mbps_to_bytes, read_bandwidth_trace
from l3gs_opt.pipeline.splat_utility import splat_utility
from renderer_helpers import random_scene

from l3gs_opt.scene.cameras import Camera

SLOTS = 3


def _cameras(n):
    return [Camera(width=64, height=48, fx=60.0, fy=60.0, cx=32.0, cy=24.0,
                   world_to_camera=look_at((4.0 * np.cos(a), 4.0 * np.sin(a), 1.0), (0.0, 0.0, 0.0)))
            for a in np.linspace(0.0, 1.5, n)]


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    scene = random_scene(80, sh_degree=1, seed=2, object_ids=True, layers=3)
    scene = scene.subset(np.argsort(scene.layers, kind="stable"))
    root = tmp_path_factory.mktemp("b")
    write_bundle(root / "layered", split_layers(scene), variant="layered")
    cams = root / "cams.json"
    cams.write_text(json.dumps([camera_to_dict(c) for c in _cameras(SLOTS)]))
    return scene, root / "layered", cams


def test_layered_costs_utilities_and_bandwidth(layered):
    scene, bundle, cams = layered
    inst = instance_from_bundle(bundle, cams, "lumos-throughput-mid-11", mbps=11.8, start=5, slots=SLOTS)
    manifest = json.loads((bundle / "manifest.json").read_text())
    objects = manifest["objects"]
    assert inst.representation == "layered" and (inst.T, inst.J, inst.L) == (SLOTS, len(objects), 3)
    for c in manifest["chunks"]:
        assert inst.cost[objects.index(c["object"]), c["level"]] == c["bytes"]
    # Utilities: the plain per-splat sum over (object, layer), camera by camera (the bundle stores
    # float32, hence the tolerance).
    for t, cam in enumerate(_cameras(SLOTS)):
        u = splat_utility(scene, cam)
        for j, obj in enumerate(objects):
            for level in range(3):
                mask = (scene.object_ids == obj) & (scene.layers == level)
                assert inst.utility[t, j, level] == pytest.approx(u[mask].sum(), rel=1e-6, abs=1e-12)
    raw = read_bandwidth_trace("lumos-throughput-mid-11")
    scaled, factor = raw.scaled(11.8)
    assert inst.bandwidth.tolist() == mbps_to_bytes(scaled.window(5, SLOTS).mbps).tolist()
    assert inst.meta["scale_factor"] == factor and inst.meta["window"] == {"start_s": 5, "length_s": SLOTS}
    sol = solve(inst, "ilp")
    assert sol.status.value == "optimal" and sol.objective > 0


def test_separate_bundle_gives_whole_versions(tmp_path):
    v0 = random_scene(30, sh_degree=0, seed=4, object_ids=True)
    v1 = random_scene(60, sh_degree=0, seed=5, object_ids=True)
    write_bundle(tmp_path / "sep", [v0, v1], variant="separate")
    cams = tmp_path / "cams.json"
    cams.write_text(json.dumps([camera_to_dict(c) for c in _cameras(2)]))
    inst = instance_from_bundle(tmp_path / "sep", cams, "lumos-throughput-mid-11", slots=2)
    assert inst.representation == "separate"
    objects = inst.meta["objects"]
    for t, cam in enumerate(_cameras(2)):
        for level, version in enumerate((v0, v1)):
            u = splat_utility(version, cam)
            for j, obj in enumerate(objects):
                assert inst.utility[t, j, level] == pytest.approx(u[version.object_ids == obj].sum(), rel=1e-6,
                                                                  abs=1e-12)


def test_pose_log_true_and_predicted(layered, tmp_path):
    _, bundle, _ = layered
    # A head at 4 m on the scene's -y axis (log z forward -> world y), turning slowly: y up in the log.
    t = np.arange(0, 4.0, 1 / 30)
    trace = PoseTrace(time_s=t, position=np.stack([0.2 * t, np.full_like(t, 1.0), np.full_like(t, -4.0)], 1),
                      rotation_deg=np.stack([np.zeros_like(t), 3.0 * t, np.zeros_like(t)], 1))
    log = write_pose_log(trace, tmp_path / "head.log")
    true = instance_from_bundle(bundle, log, "lumos-throughput-mid-11", slots=SLOTS, width=64, height=48)
    pred = instance_from_bundle(bundle, log, "lumos-throughput-mid-11", slots=SLOTS, width=64, height=48,
                                predict=True)
    assert true.utility.sum() > 0 and pred.utility.sum() > 0
    assert pred.meta["viewport"] == "predicted (lr)"
    # A slow linear motion is predicted almost exactly once there is history (slots >= 1).
    np.testing.assert_allclose(pred.utility[1:], true.utility[1:], rtol=0.2, atol=1e-9)
    cams = viewer_cameras(log, slots=1, samples_per_slot=2, mapping=Z_UP_MAPPING, width=64, height=48)
    assert len(cams) == 1 and len(cams[0]) == 2


def test_bad_paths_are_named_errors(layered, tmp_path):
    _, bundle, cams = layered
    with pytest.raises(InstanceError, match="path.*2 cameras for 3 slots"):
        short = tmp_path / "short.json"
        short.write_text(json.dumps([camera_to_dict(c) for c in _cameras(2)]))
        instance_from_bundle(bundle, short, "lumos-throughput-mid-11", slots=3)
    with pytest.raises(InstanceError, match="predict"):
        instance_from_bundle(bundle, cams, "lumos-throughput-mid-11", slots=3, predict=True)


def test_cli_from_scene(layered, tmp_path):
    _, bundle, cams = layered
    out = tmp_path / "inst.json"
    run = subprocess.run([sys.executable, "-m", "l3gs_opt.cli.main", "instance", "from-scene", str(bundle), "--path",
                          str(cams), "--window", f"0:{SLOTS}", "-o", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert load_instance(out).T == SLOTS
    bad = subprocess.run([sys.executable, "-m", "l3gs_opt.cli.main", "instance", "from-scene", str(bundle), "--path",
                          str(cams), "--window", "0:0", "-o", str(out)], capture_output=True, text=True)
    assert bad.returncode == 2 and "window" in bad.stderr
