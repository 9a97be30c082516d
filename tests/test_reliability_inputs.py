"""Issue 19, input items: every reader refuses a FIFO and absurd sizes by name (item 7), no traceback
on ``--pw inf`` or a negative chunk offset (item 8), no silent garbage from huge traces, far poses,
NaN or 10 Hz CSV times, out-of-range backgrounds or chunk paths outside the bundle (item 9), and one
error line naming the input's own field (item 10).

CLI checks run the real ``l3gs_opt.cli.main.main``: exit code 2 and exactly one ``error:`` line on
stderr. Readers that could block (FIFOs) run in a daemon thread joined with a timeout; if one ever
blocks again, the test unblocks it by opening the FIFO for writing and fails.
"""

from __future__ import annotations

import dataclasses
import json
import os
import struct
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest

from l3gs_opt.scene.bundle import BundleError, read_bundle, write_bundle
from l3gs_opt.scene.cameras import (MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, CameraError, load_any_cameras, load_cameras,
                              read_colmap, save_cameras, write_colmap)
from l3gs_opt.simulator.link import Link, LinkError
from l3gs_opt.traces.poses import PoseError, PoseTrace, read_camera_path, read_pose_log, synthetic_poses, write_pose_log
from l3gs_opt.traces.predictors import PredictionError, viewport_errors
from l3gs_opt.pipeline.build import BuildError, build_bundle
from l3gs_opt.scene.splats import SceneError, read_ply, write_ply
from l3gs_opt.traces.bandwidth import MAX_MBPS, TraceError, mbps_to_bytes, read_bandwidth_trace
from cli_helpers import one_error_line
from renderer_helpers import make_camera, random_scene

POSE_LINE = ("2024-06-20 17:48:{s:02d}, Head Position: ({x}, 1.49, 0.52), Head Rotation: (3.92, 351.06, 359.03), "
             "Left Controller Position: (0.1, 0.2, 0.3), Left Controller Rotation: (1, 2, 3), "
             "Right Controller Position: (0.1, 0.2, 0.3), Right Controller Rotation: (1, 2, 3)")


def no_warnings(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, failing on any warning it gives."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fn(*args, **kwargs)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """A tiny segmented scene, its two-level bundle, cameras and a pose log (shared, read-only)."""
    root = tmp_path_factory.mktemp("inputs")
    scene = random_scene(60, sh_degree=1, seed=2, object_ids=True)
    write_ply(scene, root / "s.ply")
    write_bundle(root / "bundle", [scene.subset(np.arange(30)), scene.subset(np.arange(30, 60))], variant="layered")
    save_cameras([make_camera(24, 16), make_camera(24, 16, eye=(2.0, -3.0, 1.0))], root / "cams.json")
    write_pose_log(synthetic_poses("orbit", seconds=4, rate_hz=10, seed=0), root / "viewer.log")
    (root / "trace.txt").write_text("5\n" * 10)
    return root


def copy_bundle(world, dest: Path, **chunk0) -> Path:
    """The world's bundle copied to ``dest`` with chunk 0's manifest entries replaced by ``chunk0``."""
    import shutil

    shutil.copytree(world / "bundle", dest)
    m = json.loads((dest / "manifest.json").read_text())
    m["chunks"][0].update(chunk0)
    (dest / "manifest.json").write_text(json.dumps(m))
    return dest


# ----------------------------------------------------------------------------- item 7: FIFOs, sizes
def _fifo_readers(world):
    return {
        "trace": lambda p: read_bandwidth_trace(p),
        "pose log": lambda p: read_pose_log(p),
        "camera path": lambda p: read_camera_path(p),
        "camera JSON": lambda p: load_cameras(p),
        "any cameras": lambda p: load_any_cameras(p),
        "PLY": lambda p: read_ply(p),
    }


@pytest.mark.parametrize("reader", ["trace", "pose log", "camera path", "camera JSON", "any cameras", "PLY"])
def test_item7_fifo_is_refused_not_waited_on(world, tmp_path, reader):
    fifo = tmp_path / "input.fifo"
    os.mkfifo(fifo)
    outcome: dict = {}

    def call():
        try:
            _fifo_readers(world)[reader](fifo)
        except Exception as exc:  # noqa: BLE001 - the type is checked below
            outcome["error"] = exc

    thread = threading.Thread(target=call, daemon=True)
    thread.start()
    thread.join(timeout=20)
    if thread.is_alive():  # blocked in open(): give it a writer so it ends, then fail
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
        pytest.fail(f"{reader} reader waited on a FIFO")
    exc = outcome.get("error")
    assert exc is not None and "not a regular file" in str(exc), exc
    assert type(exc).__name__ in ("TraceError", "PoseError", "CameraError", "SceneError")


def test_item7_fifo_manifest_and_chunk_refused(world, tmp_path):
    bundle = tmp_path / "b"
    (bundle / "chunks").mkdir(parents=True)
    os.mkfifo(bundle / "manifest.json")
    with pytest.raises(BundleError, match="manifest: .*not a regular file"):
        read_bundle(bundle)
    copy_bundle(world, tmp_path / "c")
    chunk = tmp_path / "c" / json.loads((tmp_path / "c" / "manifest.json").read_text())["chunks"][0]["file"]
    chunk.unlink()
    os.mkfifo(chunk)
    with pytest.raises(BundleError, match=r"chunks\[0\]: .*not a regular file"):
        read_bundle(tmp_path / "c")


def test_item7_fifo_on_the_cli_is_one_line(world, tmp_path, capsys):
    fifo = tmp_path / "t.fifo"
    os.mkfifo(fifo)
    assert "not a regular file" in one_error_line(capsys, "predict", "bandwidth", fifo)
    assert "not a regular file" in one_error_line(capsys, "predict", "viewport", fifo)
    assert "not a regular file" in one_error_line(capsys, "scene", "info", fifo)


def test_item7_huge_camera_refused_before_allocating(world, tmp_path, capsys):
    d = json.loads((world / "cams.json").read_text())[0]
    (tmp_path / "big.json").write_text(json.dumps(dict(d, width=10**6, height=10**6)))
    line = one_error_line(capsys, "render", world / "s.ply", "--camera", tmp_path / "big.json", "--out",
                          tmp_path / "x.png")
    assert f"width: 1000000 must be a positive integer <= {MAX_IMAGE_SIDE}" in line
    cam = make_camera(24, 16)
    with pytest.raises(CameraError, match=r"width: 16384 x 16384 = .* pixels, more than"):
        cam.replace(width=16384, height=16384, cx=8192.0, cy=8192.0)
    assert 16384 * 16384 > MAX_IMAGE_PIXELS
    for value in (10**400, "64", 64.5, True, float("inf")):
        with pytest.raises(CameraError, match="height: .* must be a positive integer"):
            cam.replace(height=value)
    with pytest.raises(CameraError, match=r"fx: 1e\+20 must be > 0 and <= 1e\+09 pixels"):
        cam.replace(fx=1e20)
    with pytest.raises(CameraError, match="fy: .* is not a number"):
        cam.replace(fy=10**400)
    # a simulation's image size fails before any slot runs
    assert "width: 1000000 must be" in one_error_line(
        capsys, "simulate", world / "bundle", "--trace", world / "trace.txt", "--path", world / "viewer.log",
        "--method", "l3gs", "--slots", "2", "--width", 10**6, "--height", 20, "--no-progress")


def test_item7_ply_header_claiming_more_than_the_file_holds(tmp_path, capsys):
    for fmt, body in (("ascii", b"1 2\n"), ("binary_little_endian", b"\0" * 8)):
        path = tmp_path / f"{fmt}.ply"
        path.write_bytes(f"ply\nformat {fmt} 1.0\nelement vertex {10**12}\nproperty float x\nproperty float y\n"
                         f"end_header\n".encode() + body)
        with pytest.raises(SceneError, match=r"^file: .*header claims 1,000,000,000,000 'vertex' elements"):
            read_ply(path)
    (tmp_path / "noend.ply").write_bytes(b"ply\n" + b"comment x\n" * 200_000)
    assert "no 'end_header'" in one_error_line(capsys, "scene", "info", tmp_path / "noend.ply")


def test_item7_colmap_binary_with_absurd_point_count(tmp_path):
    folder = write_colmap([make_camera(24, 16)], tmp_path / "m", binary=True)
    raw = bytearray((folder / "images.bin").read_bytes())
    raw[-8:] = struct.pack("<Q", 2**62)  # the 2D point count of the only image
    (folder / "images.bin").write_bytes(bytes(raw))
    with pytest.raises(CameraError, match=r"images.bin image 0: file truncated in the 2D points \(4,611,"):
        read_colmap(folder)


def test_item7_size_limits_of_text_readers(world, tmp_path, monkeypatch):
    import l3gs_opt.traces.bandwidth as traces

    monkeypatch.setattr(traces, "MAX_TRACE_FILE_BYTES", 100)
    (tmp_path / "long.txt").write_text("5\n" * 100)
    with pytest.raises(TraceError, match=r"trace: .*200 bytes, more than the limit of 100 bytes"):
        read_bandwidth_trace(tmp_path / "long.txt")
    monkeypatch.setattr(traces, "MAX_TRACE_SAMPLES", 10)
    (tmp_path / "many.txt").write_text("5\n" * 11)
    with pytest.raises(TraceError, match=r"line 11: more than 10 samples"):
        read_bandwidth_trace(tmp_path / "many.txt")
    (tmp_path / "span.csv").write_text("0,5\n1e9,6\n")
    with pytest.raises(TraceError, match=r"time_s spans .* more than 10 one-second samples"):
        read_bandwidth_trace(tmp_path / "span.csv")


# ------------------------------------------------------------------------- item 8: no tracebacks
@pytest.mark.parametrize("flag, value", [("--pw", "inf"), ("--pw", "nan"), ("--hw", "inf"), ("--hw", "-1")])
def test_item8_predict_viewport_infinite_window(world, capsys, flag, value):
    line = one_error_line(capsys, "predict", "viewport", world / "viewer.log", flag, value)
    assert line.startswith(f"error: {flag} = ") and "finite number of seconds > 0" in line


def test_item8_predict_viewport_window_longer_than_the_log_is_capped(world):
    trace = read_pose_log(world / "viewer.log")
    capped = viewport_errors(trace, pw_s=1e308)
    assert capped == viewport_errors(trace, pw_s=trace.time_s[-1] * 2)
    with pytest.raises(PredictionError, match="pw = inf"):
        viewport_errors(trace, pw_s=float("inf"))


@pytest.mark.parametrize("entry, match", [
    ({"offset": -5}, r"chunks\[0\]: offset -5 must be a whole number >= 0"),
    ({"offset": 10**20}, r"chunks\[0\]: .*shorter than offset \+ bytes"),
    ({"bytes": 100.0}, r"chunks\[0\]: bytes 100.0 must be a whole number"),
    ({"splats": -1}, r"chunks\[0\]: splats -1 must be"),
    ({"level": 9}, r"chunks\[0\]: level 9 must be below 2"),
    ({"object": 99}, r"chunks\[0\]: object 99 is not in 'objects'"),
    ({"fields": [["x", "<q9"]]}, r"chunks\[0\]: fields must be the full records"),
    ({"sh_form": "sh_upgrade"}, r"chunks\[0\]: sh_form 'sh_upgrade'"),
    ({"file": None}, r"chunks\[0\]: file None must be a path"),
])
def test_item8_bundle_chunk_entries(world, tmp_path, capsys, entry, match):
    bundle = copy_bundle(world, tmp_path / "b", **entry)
    with pytest.raises(BundleError, match=match):
        read_bundle(bundle)
    line = one_error_line(capsys, "simulate", bundle, "--trace", world / "trace.txt", "--path",
                          world / "viewer.log", "--method", "l3gs", "--slots", "2", "--no-progress")
    assert line.startswith("error: chunks[0]: ")


def test_item8_corrupt_chunk_data_names_chunk_record_and_field(world, tmp_path):
    bundle = copy_bundle(world, tmp_path / "b")
    c = json.loads((bundle / "manifest.json").read_text())["chunks"][0]
    with open(bundle / c["file"], "r+b") as fh:
        fh.seek(c["offset"] + 4)  # record 0, field y
        fh.write(struct.pack("<f", float("nan")))
    with pytest.raises(BundleError, match=r"chunks\[0\]: chunks/.*\.bin: record 0: y: nan is not finite"):
        read_bundle(bundle).level_scene(0)


# ------------------------------------------------------------------------ item 9: silent garbage
def test_item9_huge_trace_refused_up_front(world, tmp_path, capsys):
    (tmp_path / "huge.txt").write_text("5\n1e308\n" + "5\n" * 10)
    line = one_error_line(capsys, "predict", "bandwidth", tmp_path / "huge.txt")
    assert "line 2: throughput 1e+308 Mbit/s must be finite, >= 0 and <= 1e+07" in line
    line = one_error_line(capsys, "simulate", world / "bundle", "--trace", tmp_path / "huge.txt", "--path",
                          world / "viewer.log", "--method", "l3gs", "--slots", "2", "--no-progress")
    assert "line 2: throughput 1e+308" in line
    # the largest sample accepted stays exact in bytes; scaling and long slots are checked too
    assert mbps_to_bytes(np.array([MAX_MBPS])).tolist() == [1_250_000_000_000]
    with pytest.raises(TraceError, match=r"mbps\[1\] = 10000000000.0 Mbit/s over a 1000.0 s slot: .* more than 2\^53"):
        mbps_to_bytes(np.array([1.0, 1e10]), slot_s=1000.0)
    with pytest.raises(TraceError, match=r"mbps\[0\] = nan"):
        mbps_to_bytes(np.array([np.nan]))
    with pytest.raises(TraceError, match=r"mbps = 1e\+308 \(the target mean"):
        read_bandwidth_trace(world / "trace.txt").scaled(1e308)
    with pytest.raises(LinkError, match=r"bandwidth\[0\] = 9007199254740993: more than 2\^53"):
        Link([2**53 + 1])


def test_item9_far_head_position_refused(world, tmp_path, capsys):
    lines = [POSE_LINE.format(s=s, x="0.00") for s in range(10, 14)]
    lines[2] = POSE_LINE.format(s=12, x="1e308")
    (tmp_path / "far.log").write_text("\n".join(lines) + "\n")
    with pytest.raises(PoseError, match=r"far.log: line 3: Head Position\[0\] = 1e\+308: must be finite and "
                                        r"within \+-1e\+06 m"):
        read_pose_log(tmp_path / "far.log")
    assert "line 3: Head Position[0] = 1e+308" in one_error_line(capsys, "predict", "viewport", tmp_path / "far.log")
    assert "line 3: Head Position[0]" in one_error_line(
        capsys, "simulate", world / "bundle", "--trace", world / "trace.txt", "--path", tmp_path / "far.log",
        "--method", "l3gs", "--slots", "2", "--no-progress")
    lines[2] = POSE_LINE.format(s=12, x="1e999")  # inf: refused too, not skipped
    (tmp_path / "inf.log").write_text("\n".join(lines) + "\n")
    with pytest.raises(PoseError, match=r"line 3: Head Position\[0\] = inf"):
        read_pose_log(tmp_path / "inf.log")
    with pytest.raises(PoseError, match=r"sample 1: rotation_deg\[2\] = 1e\+300"):
        PoseTrace(time_s=np.arange(2.0), position=np.zeros((2, 3)), rotation_deg=np.array([[0, 0, 0], [0, 0, 1e300]]))


def test_item9_csv_time_column(tmp_path, capsys):
    (tmp_path / "nan.csv").write_text("time_s,mbps\n0,5\nnan,6\n2,7\n")
    assert "line 3: time_s nan must be finite" in one_error_line(capsys, "predict", "bandwidth", tmp_path / "nan.csv")
    (tmp_path / "back.csv").write_text("0,5\n2,6\n1,7\n")
    with pytest.raises(TraceError, match=r"line 3: time_s 1.0 must increase \(previous 2.0\)"):
        read_bandwidth_trace(tmp_path / "back.csv")
    # 10 Hz: the time column sets the time base; 100 lines are 10 one-second samples, each the mean
    (tmp_path / "10hz.csv").write_text("".join(f"{k / 10},{k % 10 + 10 * (k // 10)}\n" for k in range(100)))
    trace = read_bandwidth_trace(tmp_path / "10hz.csv")
    np.testing.assert_allclose(trace.mbps, 4.5 + 10 * np.arange(10), rtol=1e-12)
    assert trace.sample_s == 1.0
    # 1 Hz is kept exactly; 0.5 Hz holds each sample for two seconds; the start time is the origin
    (tmp_path / "1hz.csv").write_text("100,5\n101,6\n102,7\n")
    assert read_bandwidth_trace(tmp_path / "1hz.csv").mbps.tolist() == [5.0, 6.0, 7.0]
    (tmp_path / "half.csv").write_text("0,5\n2,6\n4,7\n")
    assert read_bandwidth_trace(tmp_path / "half.csv").mbps.tolist() == [5.0, 5.0, 6.0, 6.0, 7.0, 7.0]
    (tmp_path / "short.csv").write_text("0,5\n0.25,6\n")
    with pytest.raises(TraceError, match="less than one whole second"):
        read_bandwidth_trace(tmp_path / "short.csv")


@pytest.mark.parametrize("background", ["2,2,2", "0.5,-0.1,0", "nan,0,0"])
def test_item9_render_background_channels_in_0_1(world, tmp_path, capsys, background):
    line = one_error_line(capsys, "render", world / "s.ply", "--camera", world / "cams.json", "--out",
                          tmp_path / "x.png", "--background", background)
    assert line.startswith("error: --background[") and "must be in [0, 1]" in line
    assert not (tmp_path / "x.png").exists()


def test_item9_bundle_chunk_outside_the_folder(world, tmp_path):
    first = json.loads((world / "bundle" / "manifest.json").read_text())["chunks"][0]["file"]
    outside = tmp_path / "elsewhere.bin"
    outside.write_bytes((world / "bundle" / first).read_bytes())
    for i, file in enumerate(("../elsewhere.bin", str(outside))):
        bundle = copy_bundle(world, tmp_path / f"b{i}", file=file)
        with pytest.raises(BundleError, match=r"chunks\[0\]: file .* outside the bundle folder"):
            read_bundle(bundle)
    bundle = copy_bundle(world, tmp_path / "link")
    (bundle / first).unlink()
    (bundle / first).symlink_to(outside)
    with pytest.raises(BundleError, match=r"chunks\[0\]: file .* outside the bundle folder"):
        read_bundle(bundle)


# --------------------------------------------------------------------- item 10: one line, right field
def test_item10_pose_log_error_is_one_line_without_warnings(tmp_path, capsys):
    (tmp_path / "junk.log").write_text("garbage\nmore garbage\n" + POSE_LINE.format(s=10, x="0.00")[:60] + "\n")
    line = one_error_line(capsys, "predict", "viewport", tmp_path / "junk.log")
    assert "no tracked pose sample found (3 line(s) are not pose samples)" in line
    with pytest.raises(PoseError, match="no tracked pose sample"):
        no_warnings(read_pose_log, tmp_path / "junk.log")
    (tmp_path / "junk.txt").write_text("abc\n-1\n")  # traces: same rule
    assert "line 2: throughput -1.0" in one_error_line(capsys, "predict", "bandwidth", tmp_path / "junk.txt")


def test_item10_float64_ply_names_the_property(tmp_path, capsys):
    from plyfile import PlyData, PlyElement

    names = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3")
    rec = np.zeros(3, dtype=[(n, "<f8") for n in names] + [("object_id", "<u4")])
    rec["rot_0"] = 1.0
    rec["x"][0] = 1e300
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(tmp_path / "big.ply"))
    with pytest.raises(SceneError, match=r"^x\[0\]: .*1e\+300 does not fit in float32"):
        no_warnings(read_ply, tmp_path / "big.ply")
    assert one_error_line(capsys, "scene", "info", tmp_path / "big.ply").startswith("error: x[0]: ")
    # the scene's own checks are named by PLY property too
    rec["x"][0] = 0.0
    rec["object_id"][2] = 2**32 - 1
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(tmp_path / "id.ply"))
    with pytest.raises(SceneError, match=r"^object_id\[2\]: .*must fit in int32"):
        read_ply(tmp_path / "id.ply")
    rec["object_id"][2] = 0
    rec["rot_0"][1] = 1e-30
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(tmp_path / "q.ply"))
    with pytest.raises(SceneError, match=r"^rot_0..3\[1\]: .*norm 1e-30 is below 1e-15"):
        read_ply(tmp_path / "q.ply")


@pytest.mark.parametrize("field, value, match", [
    ("log_scales", 44.0, r"teacher: scale_1\[3\] = 44.0: must be <= 20"),
    ("sh", 1e20, r"teacher: f_rest_2\[3\] = 1.0000000200408773e\+20: must be within \+-1e\+06"),
])
def test_item10_scene_build_names_the_teacher_value(world, tmp_path, capsys, field, value, match):
    """These values make training overflow to NaN (found by bisection: log-scale 44, SH 1e20, focal
    length 1e20 px); the build now names the input before any stage runs."""
    scene = read_ply(world / "s.ply")
    a = getattr(scene, field).copy()
    a[(3, 1) if field == "log_scales" else (3, 3, 0)] = value  # sh [3, 3, 0]: red coefficient 3 = f_rest_2
    teacher = dataclasses.replace(scene, **{field: a})
    with pytest.raises(BuildError, match=match):
        build_bundle(teacher, load_cameras(world / "cams.json"), [30, 60], "layered", tmp_path / "out",
                     show_progress=False)
    write_ply(teacher, tmp_path / "t.ply")
    line = one_error_line(capsys, "scene", "build", tmp_path / "t.ply", "--cameras", world / "cams.json",
                          "--layers", "30,60", "--variant", "layered", "--out", tmp_path / "out", "--no-progress")
    assert line.startswith("error: teacher: ")
    assert not (tmp_path / "out" / "manifest.json").exists()
