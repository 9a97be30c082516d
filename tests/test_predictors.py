"""Predictors against hand-computed cases; pose logs and camera paths on good and bad files."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from l3gs_opt.cli.main import main
from l3gs_opt.traces.poses import (PoseError, PoseMapping, PoseTrace, euler_to_matrix, read_camera_path, read_pose_log,
                            synthetic_poses, write_camera_path, write_pose_log)
from l3gs_opt.traces.predictors import (PredictionError, bandwidth_errors, predict_bandwidth, predict_viewport,
                                 viewport_errors, wrap_deg)

LOG = """2024-06-20 17:48:41, Head Position: (0.00, 0.00, 0.00), Head Rotation: (0.00, 0.00, 0.00), Left Controller Position: (0.00, 0.00, 0.00), Left Controller Rotation: (0.00, 0.00, 0.00), Right Controller Position: (0.00, 0.00, 0.00), Right Controller Rotation: (0.00, 0.00, 0.00)
2024-06-20 17:48:42, Head Position: (0.00, 1.49, 0.52), Head Rotation: (3.92, 351.06, 359.03), Left Controller Position: (0.1, 0.2, 0.3), Left Controller Rotation: (1, 2, 3), Right Controller Position: (0.1, 0.2, 0.3), Right Controller Rotation: (1, 2, 3)
2024-06-20 17:48:42, Head Position: (0.01, 1.49, 0.53), Head Rotation: (3.90, 352.00, 359.50), Left Controller Position: (0.1, 0.2, 0.3), Left Controller Rotation: (1, 2, 3), Right Controller Position: (0.1, 0.2, 0.3), Right Controller Rotation: (1, 2, 3)
garbage line
2024-06-20 17:48:43, Head Position: (0.02, 1.50, 0.54), Head Rotation: (3.88, 353.00, 0.10), Left Controller Position: (0.1, 0.2, 0.3), Left Controller Rotation: (1, 2, 3), Right Controller Position: (0.1, 0.2, 0.3), Right Controller Rotation: (1, 2, 3)
"""


def test_pose_log_parse_spreads_seconds_and_drops_untracked(tmp_path):
    path = tmp_path / "log.txt"
    path.write_text(LOG)
    with pytest.warns(UserWarning, match="skipped 1 line"):
        trace = read_pose_log(path)
    assert trace.time_s.tolist() == [0.0, 0.5, 1.0]
    assert trace.position[0].tolist() == [0.0, 1.49, 0.52]
    assert trace.rotation_deg[2].tolist() == [3.88, 353.0, 0.1]


def test_pose_log_errors(tmp_path):
    with pytest.raises(PoseError, match="no such pose log"):
        read_pose_log(tmp_path / "missing.txt")
    (tmp_path / "empty.txt").write_text("")
    with pytest.raises(PoseError, match="no tracked pose sample"):
        read_pose_log(tmp_path / "empty.txt")
    (tmp_path / "trunc.txt").write_text(LOG.splitlines()[1][:60] + "\n")
    with warnings.catch_warnings():  # issue 19 item 10: the error alone, no "skipped" warning before it
        warnings.simplefilter("error")
        with pytest.raises(PoseError, match=r"no tracked pose sample found \(1 line\(s\) are not pose samples\)"):
            read_pose_log(tmp_path / "trunc.txt")


def test_linear_walk_is_predicted_exactly():
    t = np.arange(40) / 20.0
    feats = np.stack([0.5 * t, 1.6 + 0 * t, -0.3 * t, 2 * t, 10 + 30 * t, 0 * t], axis=1)
    trace = PoseTrace(time_s=t, position=feats[:, :3], rotation_deg=wrap_deg(feats[:, 3:]))
    err = viewport_errors(trace, hw_s=0.5, pw_s=1.0, method="lr")
    assert err.mae_position_m < 1e-9 and err.mae_rotation_deg < 1e-9
    assert err.rate_hz == pytest.approx(20.0)
    # every sample time with a full 10-sample history, each with up to 20 predicted samples
    assert err.samples == sum(min(20, 40 - end) for end in range(10, 40))
    assert viewport_errors(trace, method="oracle").mae_position_m == 0.0
    assert viewport_errors(trace, method="last").mae_position_m > 0.01


def test_angle_crossing_359_to_1_has_no_jump():
    history = np.zeros((5, 6))
    history[:, 4] = [355.0, 357.0, 359.0, 1.0, 3.0]  # yaw crossing north, 2 degrees per sample
    pred = predict_viewport(history, 3)
    np.testing.assert_allclose(pred[:, 4], [5.0, 7.0, 9.0], atol=1e-9)
    history[:, 4] = [5.0, 3.0, 1.0, 359.0, 357.0]
    pred = predict_viewport(history, 2)
    np.testing.assert_allclose(wrap_deg(pred[:, 4]), wrap_deg(np.array([355.0, 353.0])), atol=1e-9)


def test_harmonic_mean_zero_and_robust():
    x = np.array([10.0, 20.0, 40.0, 0.0, 10.0, 10.0, 10.0])
    pred = predict_bandwidth(x, window=3)
    assert np.isnan(pred[:3]).all()
    assert pred[3] == pytest.approx(3 / (1 / 10 + 1 / 20 + 1 / 40))
    assert pred[4] == 0.0 and pred[5] == 0.0 and pred[6] == 0.0  # a zero in the window predicts 0
    const = np.full(10, 8.0)
    assert bandwidth_errors(const, window=5)["mae_mbps"] == 0.0
    ramp = np.arange(1.0, 21.0)
    plain, robust = predict_bandwidth(ramp, window=3), predict_bandwidth(ramp, window=3, robust=True)
    assert (robust[6:] < plain[6:]).all()  # discounted by past over-estimates... and under-estimates
    worst = max(abs(plain[k] - ramp[k]) / ramp[k] for k in range(3, 6))
    assert robust[6] == pytest.approx(plain[6] / (1 + worst))
    e = bandwidth_errors(ramp, window=3)
    assert e["samples"] == 17 and e["mae_mbps"] == pytest.approx(np.mean(np.abs(plain[3:] - ramp[3:])))
    with pytest.raises(PredictionError, match="window = 0"):
        predict_bandwidth(ramp, window=0)


def test_pose_mapping_identity_pose_looks_forward():
    m = PoseMapping()
    w2c = m.world_to_camera(np.array([[1.0, 2.0, 3.0]]), np.array([[0.0, 0.0, 0.0]]))[0]
    # Camera centre maps to the origin of the camera frame.
    centre = np.array([1.0, -2.0, 3.0, 1.0])  # world = diag(1,-1,1) @ log
    np.testing.assert_allclose(w2c @ centre, [0, 0, 0, 1], atol=1e-12)
    # A point 1 m in front of the viewer (log +z) is on the optical axis, in front.
    ahead = np.array([1.0, -2.0, 4.0, 1.0])
    np.testing.assert_allclose(w2c @ ahead, [0, 0, 1, 1], atol=1e-12)
    # A point above the viewer (log +y) is at negative camera y (OpenCV: y down).
    above = np.array([1.0, -3.0, 4.0, 1.0])
    assert (w2c @ above)[1] < 0
    assert np.linalg.det(w2c[:3, :3]) == pytest.approx(1.0)
    with pytest.raises(PoseError, match="determinant -1"):
        PoseMapping(world_from_log=((1, 0, 0), (0, 1, 0), (0, 0, 1)))


def test_euler_order_zxy():
    a = np.array([30.0, 40.0, 50.0])
    R = euler_to_matrix(a, "ZXY")
    Rx, Ry, Rz = (euler_to_matrix(np.array(v), "XYZ") for v in ([30.0, 0, 0], [0, 40.0, 0], [0, 0, 50.0]))
    np.testing.assert_allclose(R, Ry @ Rx @ Rz, atol=1e-12)


def test_camera_path_round_trip_and_errors(tmp_path):
    mats = np.stack([np.eye(4), np.diag([1.0, -1.0, -1.0, 1.0])])
    path = write_camera_path(mats, tmp_path / "path.txt")
    np.testing.assert_array_equal(read_camera_path(path), mats)
    (tmp_path / "bad.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    with pytest.raises(PoseError, match="matrix 0: expected 4 rows"):
        read_camera_path(tmp_path / "bad.txt")


@pytest.mark.parametrize("kind", ["walk", "orbit", "fast_turns"])
def test_synthetic_logs_round_trip_through_the_parser(tmp_path, kind):
    trace = synthetic_poses(kind, seconds=6, rate_hz=10, seed=1)
    path = write_pose_log(trace, tmp_path / f"{kind}.txt")
    back = read_pose_log(path)
    assert len(back.time_s) == len(trace.time_s)
    np.testing.assert_allclose(back.position, trace.position, atol=1e-4)
    assert np.abs(wrap_deg(back.rotation_deg - trace.rotation_deg)).max() < 1e-3


def test_predict_cli(tmp_path, capsys):
    trace = synthetic_poses("walk", seconds=5, rate_hz=20, seed=0)
    log = write_pose_log(trace, tmp_path / "walk.txt")
    assert main(["predict", "viewport", str(log), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) == {"mae_position_m", "mae_rotation_deg", "samples", "rate_hz"} and data["rate_hz"] == pytest.approx(20.0, rel=1e-5)
    assert main(["predict", "bandwidth", "lumos-throughput-low-47", "--window", "5", "--robust", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert set(data) == {"mae_mbps", "samples"} and data["samples"] > 700
    assert main(["predict", "viewport", str(tmp_path / "none.txt")]) == 2
    assert "no such pose log" in capsys.readouterr().err
