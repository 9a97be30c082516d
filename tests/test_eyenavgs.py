"""EyeNavGS traces: small hand-made files with hand-computed poses, scipy as a second quaternion
implementation, the simulator's PoseMapping as a second camera implementation, and the real
sample in ``../shared`` (skipped when absent)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from l3gs_opt.traces.eyenavgs import (EyeNavError, EyeNavTrace, SceneAlignment, quaternion_to_matrix,
                                      read_eyenavgs, read_scene_settings)
from l3gs_opt.traces.poses import PoseMapping, euler_to_matrix

SHARED = Path(__file__).resolve().parents[2] / "shared"
EYENAV = SHARED / "data" / "reference" / "eyenavgs"
needs_sample = pytest.mark.skipif(not (EYENAV / "scene_setting.csv").is_file(),
                                  reason=f"EyeNavGS sample absent ({EYENAV})")
HEADER = ("ViewIndex,FOV1,FOV2,FOV3,FOV4,PositionX,PositionY,PositionZ,QuaternionX,QuaternionY,QuaternionZ,"
          "QuaternionW,GazePosX,GazePosY,GazePosZ,GazeQX,GazeQY,GazeQZ,GazeQW,Timestamp")
S45 = math.sqrt(0.5)
YAW90 = (0.0, S45, 0.0, S45)  # +90 degrees about +y (OpenXR up)
# Matrices are built from 3-decimal-like inputs in float64: 1e-12 is rounding, not physics.
ATOL = 1e-12


def _row(view, pos, q=(0, 0, 0, 1), t=0.0, gaze_pos=None, gaze_q=(0, 0, 0, 1), fov=(-0.9, 0.7, -0.9, 0.7)):
    gaze_pos = pos if gaze_pos is None else gaze_pos
    return ",".join(str(v) for v in (view, *fov, *pos, *q, *gaze_pos, *gaze_q, t))


def _csv(tmp_path, rows, header=HEADER, name="user1_test.csv"):
    path = tmp_path / name
    path.write_text("\ufeff" + header + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return path


# ------------------------------------------------------------------------------- hand-made files
def test_centre_merges_each_frame_and_counts_an_unpaired_row(tmp_path):
    path = _csv(tmp_path, [_row(0, (0.968, 1.6, 2), t=0), _row(1, (1.032, 1.6, 2), t=4),
                           _row(0, (1.968, 1.6, 2), t=14), _row(1, (2.032, 1.6, 2), t=18),
                           _row(0, (2.968, 1.6, 2), t=28)])
    trace = read_eyenavgs(path)
    np.testing.assert_allclose(trace.timestamps_s, [0.002, 0.016], atol=ATOL)
    np.testing.assert_allclose(trace.positions, [[1, 1.6, 2], [2, 1.6, 2]], atol=ATOL)
    assert trace.unpaired == 1 and trace.eye == "centre" and trace.name == "user1_test"
    left = read_eyenavgs(path, eye="left")
    np.testing.assert_allclose(left.positions[:, 0], [0.968, 1.968, 2.968], atol=ATOL)
    assert len(read_eyenavgs(path, eye="right")) == 2
    # Frozen data: the arrays cannot be edited in place.
    with pytest.raises(ValueError):
        trace.positions[0, 0] = 5.0


def test_centre_fov_is_the_union_of_the_two_eyes(tmp_path):
    path = _csv(tmp_path, [_row(0, (0, 0, 0), fov=(-0.942, 0.698, -0.942, 0.733)),
                           _row(1, (0.1, 0, 0), t=4, fov=(-0.698, 0.942, -0.942, 0.733))])
    np.testing.assert_allclose(read_eyenavgs(path).fov_rad, [[-0.942, 0.942, -0.942, 0.733]])


def test_identity_pose_camera_by_hand(tmp_path):
    # Identity orientation at p: the OpenXR head looks along -z, i.e. along +z of the 3DGS world
    # F = diag(1, -1, -1); camera centre F p; world_to_camera = [I | -F p].
    trace = read_eyenavgs(_csv(tmp_path, [_row(0, (1, 2, 3)), _row(1, (1, 2, 3), t=4)]))
    w2c = trace.world_to_camera()[0]
    np.testing.assert_allclose(w2c[:3, :3], np.eye(3), atol=ATOL)
    np.testing.assert_allclose(w2c[:3, 3], [-1, 2, 3], atol=ATOL)
    # Without the viewer's flip the OpenGL camera's -z view maps to OpenCV: diag(1, -1, -1).
    np.testing.assert_allclose(trace.world_to_camera(flip_y=False)[0][:3, :3], np.diag([1, -1, -1]), atol=ATOL)


def test_yaw_90_turns_the_view_direction(tmp_path):
    # +90 degrees about OpenXR +y turns the view (-z) to -x; F keeps x, so the OpenCV camera's
    # +z axis (row 2 of world_to_camera) is world -x, and its x axis (right) is world -z -> F: +z.
    trace = read_eyenavgs(_csv(tmp_path, [_row(0, (0, 0, 0), YAW90), _row(1, (0, 0, 0), YAW90, t=4)]))
    w2c = trace.world_to_camera()[0]
    np.testing.assert_allclose(w2c[2, :3], [-1, 0, 0], atol=ATOL)
    np.testing.assert_allclose(w2c[0, :3], [0, 0, 1], atol=ATOL)
    np.testing.assert_allclose(w2c[1, :3], [0, 1, 0], atol=ATOL)  # image down = world +y (3DGS y down)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(q=st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1))
def test_quaternion_matrix_matches_scipy(q):
    q = np.asarray(q) / np.linalg.norm(q)
    np.testing.assert_allclose(quaternion_to_matrix(q), Rotation.from_quat(q).as_matrix(), atol=1e-12)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6))
def test_pose_trace_with_default_mapping_gives_the_same_cameras(seed):
    rng = np.random.default_rng(seed)
    n = 8
    q = Rotation.random(n, random_state=seed).as_quat()
    trace = EyeNavTrace("r", "centre", np.arange(n) / 72.0, rng.normal(0, 2, (n, 3)), q, np.zeros((n, 4)))
    poses = trace.to_pose_trace()
    np.testing.assert_allclose(PoseMapping().world_to_camera(poses.position, poses.rotation_deg),
                               trace.world_to_camera(), atol=1e-9)
    # The Euler angles are Unity's ZXY: rebuilding the matrix gives the z-mirrored rotation.
    mirror = np.diag([1.0, 1.0, -1.0])
    np.testing.assert_allclose(euler_to_matrix(poses.rotation_deg, "ZXY"),
                               mirror @ quaternion_to_matrix(q) @ mirror, atol=1e-9)


def test_resampled_interpolates_positions_and_slerps_orientations(tmp_path):
    rows = [_row(0, (0, 0, 0), (0, 0, 0, 1), t=0), _row(1, (0, 0, 0), (0, 0, 0, 1), t=0),
            _row(0, (1, 0, 0), YAW90, t=1000), _row(1, (1, 0, 0), YAW90, t=1000)]
    # Equal times per frame are fine: the merged time is their mean.
    trace = read_eyenavgs(_csv(tmp_path, rows)).resampled(2.0)
    np.testing.assert_allclose(trace.timestamps_s, [0.0, 0.5, 1.0], atol=ATOL)
    np.testing.assert_allclose(trace.positions[:, 0], [0.0, 0.5, 1.0], atol=ATOL)
    half = Rotation.from_quat(trace.orientations[1]).as_rotvec()
    np.testing.assert_allclose(half, [0, math.pi / 4, 0], atol=1e-12)  # 45 degrees about y


def test_gaze_absent_when_eye_tracking_was_off(tmp_path):
    rows = [_row(0, (0, 1, 0), gaze_pos=(0, 0, 0)), _row(1, (0.06, 1, 0), t=4, gaze_pos=(0, 0, 0))]
    trace = read_eyenavgs(_csv(tmp_path, rows))
    assert trace.gaze_positions is None and trace.gaze_orientations is None and trace.gaze_valid is None
    rows[1] = _row(1, (0.06, 1, 0), t=4, gaze_q=YAW90)
    rows += [_row(0, (0, 1, 0), t=14, gaze_q=YAW90), _row(1, (0.06, 1, 0), t=18, gaze_q=YAW90)]
    trace = read_eyenavgs(_csv(tmp_path, rows))
    assert trace.gaze_valid.tolist() == [False, True]
    np.testing.assert_allclose(trace.gaze_orientations[1], YAW90, atol=ATOL)


def test_no_gaze_columns_is_fine(tmp_path):
    header = ",".join(h for h in HEADER.split(",") if not h.startswith("Gaze"))
    row = "0,-0.9,0.7,-0.9,0.7,0,1,0,0,0,0,1,0"
    trace = read_eyenavgs(_csv(tmp_path, [row, "1" + row[1:-1] + "4"], header=header))
    assert trace.gaze_positions is None and len(trace) == 1


@pytest.mark.parametrize("rows, header, message", [
    ([_row(0, (0, 0, 0)), _row(1, ("abc", 0, 0), t=4)], HEADER, r"line 3: column PositionX = 'abc': not a number"),
    ([_row(2, (0, 0, 0))], HEADER, r"line 2: column ViewIndex = 2.0: must be 0 \(left\) or 1 \(right\)"),
    ([_row(0, (0, 0, 0), q=(0, 0, 0, 2))], HEADER, r"line 2: columns QuaternionX..W: quaternion = .*norm 2"),
    ([_row(0, (0, 0, 0), t=10), _row(1, (0, 0, 0), t=12), _row(0, (0, 0, 0), t=5), _row(1, (0, 0, 0), t=6)],
     HEADER, r"line 4: column Timestamp = 5.0 ms: must increase \(previous sample's line 2\)"),
    ([_row(0, (0, 0, 0), t=math.inf)], HEADER, r"line 2: column Timestamp = inf: must be finite"),
    ([_row(0, (0, 0, 0))], HEADER.replace("PositionY", "PosY"), r"line 1 \(header\): missing PositionY; unknown PosY"),
    ([_row(0, (0, 0, 0))], HEADER.replace("GazeQW", "GazeW"), r"gaze columns incomplete: missing GazeQW"),
    ([_row(0, (0, 0, 0))], HEADER, r"no left/right row pair"),
    (["0,1,2"], HEADER, r"line 2: 3 fields, the header has 20"),
])
def test_errors_name_the_line_and_column(tmp_path, rows, header, message):
    with pytest.raises(EyeNavError, match=message):
        read_eyenavgs(_csv(tmp_path, rows, header=header))


def test_bad_arguments_are_named(tmp_path):
    path = _csv(tmp_path, [_row(0, (0, 0, 0)), _row(1, (0, 0, 0), t=4)])
    with pytest.raises(EyeNavError, match="eye = 'both': must be one of centre, left, right"):
        read_eyenavgs(path, eye="both")
    with pytest.raises(EyeNavError, match="rate_hz = 0"):
        read_eyenavgs(path).resampled(0)
    with pytest.raises(EyeNavError, match="no such file"):
        read_eyenavgs(tmp_path / "missing.csv")


# ------------------------------------------------------------------------------- scene settings
SETTINGS = ('\ufeffScene_Name,Quaternion,Scale,Initial_Position\n'
            'truck,"-0.0896, 0.0000, 0.0000, 0.9960",0.76,"0,2.1,-4"\n'
            'london,"0, 0, 0, 1",0.53,"18,12,-11"\n')


def test_scene_settings_read(tmp_path):
    (tmp_path / "s.csv").write_text(SETTINGS, encoding="utf-8")
    s = read_scene_settings(tmp_path / "s.csv")
    assert list(s) == ["truck", "london"]
    assert s["london"] == SceneAlignment("london", (0.0, 0.0, 0.0, 1.0), 0.53, (18.0, 12.0, -11.0))
    assert abs(np.linalg.norm(s["truck"].quaternion) - 1) < 1e-15  # normalised on reading


@pytest.mark.parametrize("line, message", [
    ('x,"0, 0, 1",1,"0,0,0"', r"line 4: column Quaternion = '0, 0, 1': must be 4 finite numbers"),
    ('x,"0, 0, 0, 1",0,"0,0,0"', r"line 4: column Scale = 0.0: must be > 0"),
    ('x,"0, 0, 0, 1",1,"0,0"', r"line 4: column Initial_Position = '0,0': must be 3 finite numbers"),
    ('truck,"0, 0, 0, 1",1,"0,0,0"', r"line 4: column Scene_Name = 'truck': repeated scene"),
    ('x,"0, 0, 0, 3",1,"0,0,0"', r"line 4: column Quaternion: .*norm 3"),
])
def test_scene_settings_errors(tmp_path, line, message):
    (tmp_path / "s.csv").write_text(SETTINGS + line + "\n", encoding="utf-8")
    with pytest.raises(EyeNavError, match=message):
        read_scene_settings(tmp_path / "s.csv")


def test_identity_alignment_leaves_positions_alone():
    a = SceneAlignment("id", (0, 0, 0, 1), 1.0, (0.0, 0.0, 0.0))
    p = np.array([[1.0, 1.6, -0.5], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(a.stage_from_recorded(p), p, atol=ATOL)
    np.testing.assert_allclose(a.stage_orientation(np.array(YAW90)), YAW90, atol=ATOL)
    # A translation alone: the viewer world's origin sits at t in the room (OpenXR's
    # poseInReferenceSpace), so the recorded start p is the room point p + t.
    moved = SceneAlignment("t", (0, 0, 0, 1), 1.0, (3.0, -2.0, 7.0))
    np.testing.assert_allclose(moved.stage_from_recorded(p), p + [3.0, -2.0, 7.0], atol=ATOL)


def test_alignment_by_hand():
    # Scale 2 about t = (1, 0, 0), yaw 90 degrees: p = (3, 0, 0) -> (p - t) / 2 + t = (2, 0, 0)
    # -> R (2, 0, 0) = (0, 0, -2) -> + t = (1, 0, -2).
    a = SceneAlignment("hand", YAW90, 2.0, (1.0, 0.0, 0.0))
    np.testing.assert_allclose(a.stage_from_recorded(np.array([3.0, 0.0, 0.0])), [1, 0, -2], atol=ATOL)


@settings(max_examples=50, deadline=None, derandomize=True)
@given(seed=st.integers(0, 10**6), scale=st.floats(0.1, 5))
def test_alignment_round_trip(seed, scale):
    rng = np.random.default_rng(seed)
    a = SceneAlignment("r", tuple(Rotation.random(random_state=seed).as_quat()), scale, tuple(rng.normal(0, 3, 3)))
    p = rng.normal(0, 3, (5, 3))
    np.testing.assert_allclose(a.recorded_from_stage(a.stage_from_recorded(p)), p, atol=1e-9)


# ------------------------------------------------------------------------------- the real sample
@pytest.fixture(scope="module")
def sample():
    settings_ = read_scene_settings(EYENAV / "scene_setting.csv")
    files = sorted(EYENAV.glob("*/user*_*.csv"))
    return settings_, {f: read_eyenavgs(f) for f in files}


# A 3 m x 3 m play area (the paper's set-up) has |x|, |z| <= 1.5 m about its centre; 0.25 m more
# for leaning over the guardian boundary and tracking noise. Standing head height is 1.2-2.0 m;
# crouching reaches lower, so all samples get 0.5-2.1 m.
HALF_AREA_M = 1.5 + 0.25


@needs_sample
def test_sample_all_files_load(sample):
    settings_, traces = sample
    assert len(settings_) == 12 and len(traces) == 12
    for path, trace in traces.items():
        assert path.parent.name in settings_
        assert len(trace) > 2000 and np.all(np.diff(trace.timestamps_s) > 0)
        assert 30 < trace.rate_hz < 80  # the Quest Pro at 72 Hz (bicycle rendered at 36 Hz)
        assert trace.unpaired <= 1


@needs_sample
def test_sample_conventions_eye_offset_and_scale(sample):
    settings_, traces = sample
    for path in traces:
        left, right = read_eyenavgs(path, eye="left"), read_eyenavgs(path, eye="right")
        n = min(len(left), len(right))
        offset = right.positions[:n] - left.positions[:n]
        # The right eye is along the head's +x: (x, y, z, w) quaternions, head to world, +x right.
        x_axis = quaternion_to_matrix(left.orientations[:n])[:, :, 0]
        cos = np.sum(offset * x_axis, axis=1) / np.linalg.norm(offset, axis=1)
        assert np.min(cos) > 0.99, path.name
        # The alignment scale is already in the positions: IPD / scale is a human IPD (54-74 mm).
        ipd_mm = 1000 * np.median(np.linalg.norm(offset, axis=1)) / settings_[path.parent.name].scale
        assert 54 < ipd_mm < 74, (path.name, ipd_mm)


@needs_sample
def test_sample_stage_positions_are_in_the_play_area(sample):
    """The aligned start position is not scene_setting's Initial_Position: that is the alignment's
    translation, not a place a camera stands. What the alignment must do is put every recorded
    head back in the room: inside the play area, at standing height."""
    settings_, traces = sample
    for path, trace in traces.items():
        a = settings_[path.parent.name]
        stage = a.stage_from_recorded(trace.positions)
        assert np.all(np.abs(stage[:, [0, 2]]) <= HALF_AREA_M), path.name
        assert np.all((0.5 <= stage[:, 1]) & (stage[:, 1] <= 2.1)), path.name
        assert 1.2 <= stage[0, 1] <= 2.0, path.name
        # The recorded start is far from Initial_Position in general (e.g. truck: 6 units).
        if path.parent.name == "truck":
            assert np.linalg.norm(trace.positions[0] - np.asarray(a.initial_position)) > 3


@needs_sample
def test_sample_stage_matches_the_authors_convert_tool(sample):
    # A second implementation: EyeNavGS utils/WorldCoordConvert/coord_convert.py's formula, with scipy.
    settings_, traces = sample
    for path, trace in traces.items():
        a = settings_[path.parent.name]
        t = np.asarray(a.initial_position)
        theirs = Rotation.from_quat(a.quaternion).apply((trace.positions - t) / a.scale + t) + t
        np.testing.assert_allclose(a.stage_from_recorded(trace.positions), theirs, atol=1e-12)


@needs_sample
def test_sample_alignment_rotation_makes_heads_upright(sample):
    # People hold their heads upright on average: the mean head-up vector is within 8 degrees of
    # vertical in the stage frame, and farther off when the tilt is applied the other way round.
    settings_, traces = sample

    def tilt_deg(q: np.ndarray) -> float:
        up = quaternion_to_matrix(q)[:, :, 1].mean(axis=0)
        return math.degrees(math.acos(up[1] / np.linalg.norm(up)))

    for path, trace in traces.items():
        a = settings_[path.parent.name]
        stage = tilt_deg(a.stage_orientation(trace.orientations))
        wrong = tilt_deg(SceneAlignment("inv", tuple(np.array(a.quaternion) * [-1, -1, -1, 1]), 1.0,
                                        (0, 0, 0)).stage_orientation(trace.orientations))
        assert stage < 8 and wrong > stage, (path.name, stage, wrong)


@needs_sample
def test_sample_cameras_via_pose_trace_and_resampling(sample):
    _, traces = sample
    trace = next(iter(traces.values()))
    poses = trace.to_pose_trace()
    np.testing.assert_allclose(PoseMapping().world_to_camera(poses.position, poses.rotation_deg),
                               trace.world_to_camera(), atol=1e-9)
    at30 = trace.resampled(30.0)
    assert abs(at30.rate_hz - 30.0) < 1e-6
    w2c = at30.world_to_camera()
    rot = w2c[:, :3, :3]
    np.testing.assert_allclose(rot @ np.swapaxes(rot, 1, 2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-9)
