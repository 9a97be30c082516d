"""Cameras: JSON, COLMAP (text + binary) and Blender transforms.json render the same view."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from l3gs_opt.scene.camera_paths import orbit_path, walk_path
from l3gs_opt.scene.cameras import (Camera, CameraError, camera_to_dict, load_camera, load_cameras, look_at,
                              read_blender, read_colmap, save_cameras, write_blender, write_colmap)
from l3gs_opt.errors import L3gsError
from l3gs_opt.renderer import render_scene
from renderer_helpers import make_camera, random_scene

# COLMAP stores the rotation as a quaternion and Blender as OpenGL camera-to-world: converting
# back and forth costs float64 rounding only (~1e-15 relative); images agree to float32 rounding.
IMAGE_ATOL = 1e-5


def _cams():
    return [make_camera(48, 32, eye=(0.3, -4.0, 1.2)).replace(name="a.png"),
            make_camera(48, 32, eye=(-3.0, -2.5, 0.8), target=(0.2, 0.1, 0.0)).replace(name="b.png")]


def test_json_round_trip_exact(tmp_path):
    cams = _cams()
    save_cameras(cams, tmp_path / "path.json")
    back = load_cameras(tmp_path / "path.json")
    for a, b in zip(cams, back):
        assert camera_to_dict(a) == camera_to_dict(b)
    save_cameras(cams[0], tmp_path / "one.json")
    assert camera_to_dict(load_camera(tmp_path / "one.json")) == camera_to_dict(cams[0])


@pytest.mark.parametrize("fmt", ["colmap_text", "colmap_binary", "blender"])
def test_other_formats_render_the_same_view(tmp_path, fmt):
    cams = _cams()
    if fmt == "blender":
        other = read_blender(write_blender(cams, tmp_path / "transforms.json"), background=cams[0].background)
    else:
        folder = write_colmap(cams, tmp_path / fmt, binary=fmt == "colmap_binary")
        other = read_colmap(folder, background=cams[0].background)
    scene = random_scene(60, seed=1)
    for a, b in zip(cams, other):
        np.testing.assert_allclose(b.world_to_camera, a.world_to_camera, rtol=0, atol=1e-12)
        assert (b.width, b.height, b.fx, b.fy, b.cx, b.cy) == (a.width, a.height, a.fx, a.fy, a.cx, a.cy)
        ia, ib = render_scene(scene, a).image.numpy(), render_scene(scene, b).image.numpy()
        np.testing.assert_allclose(ib, ia, rtol=0, atol=IMAGE_ATOL)
        assert ia.std() > 0.01


def test_colmap_text_written_by_hand(tmp_path):
    # identity rotation, camera at (0, 0, -5): world origin is 5 m in front, at the principal point
    (tmp_path / "cameras.txt").write_text("# c\n1 SIMPLE_PINHOLE 64 48 50.0 32.0 24.0\n")
    (tmp_path / "images.txt").write_text("# i\n7 1 0 0 0 0 0 5 1 img 1.jpg\n1.0 2.0 -1\n")
    (cam,) = read_colmap(tmp_path)
    assert cam.name == "img 1.jpg" and cam.fx == cam.fy == 50.0
    np.testing.assert_allclose(cam.center, [0, 0, -5])


def test_blender_synthetic_style(tmp_path):
    # Blender: camera at +z looking down -z (OpenGL identity rotation)
    c2w = np.eye(4)
    c2w[2, 3] = 4.0
    (tmp_path / "t.json").write_text(json.dumps({"camera_angle_x": 2 * math.atan(0.5),
                                                 "frames": [{"file_path": "./r_0", "transform_matrix": c2w.tolist()}]}))
    with pytest.raises(CameraError, match="image size unknown"):
        read_blender(tmp_path / "t.json")
    (cam,) = read_blender(tmp_path / "t.json", width=800, height=800)
    assert cam.fx == pytest.approx(800.0) and cam.cx == 400.0
    # OpenCV z (forward) must point along world -z; y (down) along world -y
    np.testing.assert_allclose(cam.world_to_camera[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    p = cam.world_to_camera @ [0.0, 0.0, 0.0, 1.0]
    assert p[2] == pytest.approx(4.0)


@pytest.mark.parametrize("obj,match", [
    ({"width": 0}, r"width: 0 must be a positive integer"),
    ({"fx": -1.0}, r"fx: -1.0 must be > 0"),
    ({"cy": float("nan")}, r"NaN is not valid JSON"),  # strict JSON (issue 19); 1e999 -> inf: see below
    ({"cy": 1.5e300}, r"cy: inf is not finite"),  # written as 1e999, which JSON reads as inf
    ({"world_to_camera": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, r"not a rotation"),
    ({"world_to_camera": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]]}, r"world_to_camera\[3\]"),
    ({"background": [0, 1]}, r"background"),
    ({"fov": 3}, r"\[1\]\.fov: unknown key"),
])
def test_camera_json_errors_name_the_field(tmp_path, obj, match):
    good = camera_to_dict(make_camera())
    bad = dict(good, **obj)
    (tmp_path / "c.json").write_text(json.dumps([good, bad]).replace("1.5e+300", "1e999"))
    with pytest.raises(CameraError, match=match) as info:
        load_cameras(tmp_path / "c.json")
    assert isinstance(info.value, L3gsError) and isinstance(info.value, ValueError)


def test_bad_files(tmp_path):
    (tmp_path / "x.json").write_text("{not json")
    with pytest.raises(CameraError, match="not valid JSON"):
        load_cameras(tmp_path / "x.json")
    with pytest.raises(CameraError, match="no such file"):
        load_cameras(tmp_path / "nope.json")
    with pytest.raises(CameraError, match="no COLMAP model"):
        read_colmap(tmp_path)
    (tmp_path / "cameras.txt").write_text("1 OPENCV_FISHEYE 10 10 1 1 5 5 0 0 0 0\n")
    (tmp_path / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n")
    with pytest.raises(CameraError, match="OPENCV_FISHEYE is not supported"):
        read_colmap(tmp_path)
    folder = write_colmap(_cams(), tmp_path / "bin", binary=True)
    raw = (folder / "images.bin").read_bytes()
    (folder / "images.bin").write_bytes(raw[:-5])
    with pytest.raises(CameraError, match="truncated"):
        read_colmap(folder)


def test_paths_look_at_the_room():
    for cams in (orbit_path(6, width=64, height=48), walk_path(6, width=64, height=48)):
        assert len(cams) == 6
        for c in cams:
            # the room centre (slightly above the floor) is in front of every camera
            assert (c.world_to_camera @ [0.0, 0.0, 0.5, 1.0])[2] > 0
    a = look_at([1.0, 2.0, 3.0], [0.0, 0.0, 0.0])
    assert np.allclose(a[:3, :3] @ a[:3, :3].T, np.eye(3))
    Camera(width=4, height=4, fx=1, fy=1, cx=2, cy=2, world_to_camera=a)
