"""Cameras as people have them: NeRF-synthetic files without a size (``--size WxH``), and lens
distortion in COLMAP models and ``transforms.json`` (one rule for both readers).

The real lego ``transforms_train.json`` is read from ``../shared`` (skipped when absent); a
hand-written file of the same shape runs everywhere.
"""

from __future__ import annotations

import json
import math
import re
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from l3gs_opt.cli.main import main
from l3gs_opt.renderer import render_scene
from l3gs_opt.scene.cameras import (MAX_DROPPED_DISTORTION_PX, Camera, CameraError, DistortionWarning,
                                    load_any_cameras, max_distortion_px, parse_image_size, read_blender,
                                    read_colmap, save_cameras, write_colmap)
from l3gs_opt.scene.splats import read_ply as read_ply_scene, write_ply
from renderer_helpers import random_scene

SHARED = Path(__file__).resolve().parents[2] / "shared"
LEGO = SHARED / "data" / "reference" / "cameras" / "nerf_synthetic_lego_transforms_train.json"
needs_lego = pytest.mark.skipif(not LEGO.is_file(), reason=f"real NeRF-synthetic camera file absent ({LEGO})")

# The CLI renders in float32 like render_scene; the same camera built two ways (from a file and by
# hand) differs by float64 rounding in the matrices only, so the images agree to float32 rounding.
IMAGE_ATOL = 1e-5


def _run(capsys, *argv) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


@pytest.fixture
def scene_file(tmp_path):
    # splats around the origin, which every camera below looks at from about 4 m
    path = tmp_path / "s.ply"
    write_ply(random_scene(60, seed=5), path)
    return path


def _c2w_at(z: float) -> list:
    """OpenGL camera-to-world of a camera at (0, 0, z) looking down -z (Blender's convention)."""
    m = np.eye(4)
    m[2, 3] = z
    return m.tolist()


def _synthetic_file(path: Path, **lens) -> Path:
    """A transforms.json shaped like the NeRF synthetic ones (camera_angle_x, no w/h) + ``lens``."""
    obj = {"camera_angle_x": 2 * math.atan(0.5), **lens,
           "frames": [{"file_path": "./train/r_0", "rotation": 0.0, "transform_matrix": _c2w_at(4.0)},
                      {"file_path": "./train/r_1", "rotation": 0.0, "transform_matrix": _c2w_at(5.0)}]}
    path.write_text(json.dumps(obj))
    return path


def _hand_camera(width: int, height: int, f: float, z: float) -> Camera:
    # OpenGL (x right, y up, z back) at (0, 0, z) is OpenCV R = diag(1, -1, -1), t = -R c = (0, 0, z)
    m = np.diag([1.0, -1.0, -1.0, 1.0])
    m[2, 3] = z
    return Camera(width=width, height=height, fx=f, fy=f, cx=width / 2, cy=height / 2, world_to_camera=m)


# ------------------------------------------------------------------------------ --size
@needs_lego
def test_real_lego_file_needs_and_takes_a_size():
    raw = json.loads(LEGO.read_text())
    assert "w" not in raw and "h" not in raw  # the reason this test exists
    with pytest.raises(CameraError, match=r"image size unknown.*--size WxH"):
        load_any_cameras(LEGO)
    cams = load_any_cameras(LEGO, width=800, height=800)
    assert len(cams) == len(raw["frames"]) == 100
    f = 0.5 * 800 / math.tan(raw["camera_angle_x"] / 2)  # ~1111.11 px
    for cam, fr in zip(cams, raw["frames"]):
        assert (cam.width, cam.height, cam.cx, cam.cy) == (800, 800, 400.0, 400.0)
        assert cam.fx == pytest.approx(f, rel=1e-12) and cam.fy == pytest.approx(f, rel=1e-12)
        c2w = np.array(fr["transform_matrix"])
        # the file's rotations are orthonormal to float32 rounding only (~1e-6), which the centre
        # -R^T t of the inverted matrix carries over ~4 m
        np.testing.assert_allclose(cam.center, c2w[:3, 3], atol=1e-4)
        # OpenCV forward (+z) is Blender's -z axis
        np.testing.assert_allclose(cam.camera_to_world[:3, 2], -c2w[:3, 2], atol=1e-5)
    # a smaller size scales the whole lens: the field of view stays
    small = load_any_cameras(LEGO, width=32, height=32)[0]
    assert small.tan_half_fov == pytest.approx(cams[0].tan_half_fov, rel=1e-12)


@needs_lego
def test_cli_renders_the_real_lego_file(tmp_path, scene_file, capsys):
    out = tmp_path / "lego.npy"
    code, err = _run(capsys, "render", scene_file, "--camera", LEGO, "--out", out)
    assert code == 2 and "--size WxH" in err and len(err.strip().splitlines()) == 1
    code, err = _run(capsys, "render", scene_file, "--camera", LEGO, "--out", out, "--size", "24x24",
                     "--index", "3")
    assert code == 0, err
    img = np.load(out)
    assert img.shape == (24, 24, 3)
    expect = render_scene(read_ply_scene(scene_file), load_any_cameras(LEGO, width=24, height=24)[3])
    np.testing.assert_array_equal(img, expect.image.numpy())


def test_hand_written_synthetic_file_and_cli(tmp_path, scene_file, capsys):
    path = _synthetic_file(tmp_path / "transforms_train.json")
    with pytest.raises(CameraError, match=r"image size unknown.*--size WxH"):
        read_blender(path)
    cams = read_blender(path, width=40, height=30)
    # camera_angle_x = 2 atan(0.5): fx = 0.5 * 40 / 0.5 = 40 px; fy follows fx (square pixels)
    for c in cams:
        assert (c.fx, c.fy) == pytest.approx((40.0, 40.0), rel=1e-14) and (c.cx, c.cy) == (20.0, 15.0)
    out = tmp_path / "a.npy"
    code, err = _run(capsys, "render", scene_file, "--camera", path, "--out", out)
    assert code == 2 and "--size WxH" in err
    code, err = _run(capsys, "render", scene_file, "--camera", path, "--out", out, "--size", "40x30", "--index", "1")
    assert code == 0, err
    hand = render_scene(read_ply_scene(scene_file), _hand_camera(40, 30, 40.0, 5.0)).image.numpy()
    np.testing.assert_allclose(np.load(out), hand, rtol=0, atol=IMAGE_ATOL)
    assert hand.std() > 0.01  # the scene is in view: the comparison means something


def test_size_rescales_a_file_with_its_own_size(tmp_path, scene_file, capsys):
    # an instant-ngp style file of 64 x 48 with an off-centre principal point
    obj = {"w": 64, "h": 48, "fl_x": 60.0, "fl_y": 62.0, "cx": 33.0, "cy": 23.0,
           "frames": [{"file_path": "a", "transform_matrix": _c2w_at(4.0)}]}
    path = tmp_path / "transforms.json"
    path.write_text(json.dumps(obj))
    (own,) = load_any_cameras(path)
    assert (own.width, own.height, own.fx, own.cx) == (64, 48, 60.0, 33.0)
    (half,) = load_any_cameras(path, width=32, height=24)
    assert (half.width, half.height, half.fx, half.fy, half.cx, half.cy) == (32, 24, 30.0, 31.0, 16.5, 11.5)
    # a half-size camera sees the same view: each half-size pixel is the mean of 2 x 2 full-size
    # ones to first order, so a point projects to half its pixel coordinates
    p = np.array([0.3, -0.2, 0.0, 1.0])
    for cam, s in ((own, 1.0), (half, 0.5)):
        x, y, z = (cam.world_to_camera @ p)[:3]
        assert (cam.fx * x / z + cam.cx) == pytest.approx(s * (own.fx * x / z + own.cx))
        assert (cam.fy * y / z + cam.cy) == pytest.approx(s * (own.fy * y / z + own.cy))
    # the same through a COLMAP model and a camera JSON
    write_colmap([own], tmp_path / "colmap")
    save_cameras([own], tmp_path / "cams.json")
    for src in (tmp_path / "colmap", tmp_path / "cams.json"):
        (c,) = load_any_cameras(src, width=32, height=24)
        assert (c.fx, c.fy, c.cx, c.cy) == (30.0, 31.0, 16.5, 11.5)
    # a changed aspect ratio is refused by name, in the library and on the command line
    with pytest.raises(CameraError, match=r"32x32 changes the aspect ratio .* 64x48 .* e\.g\. 32x24"):
        load_any_cameras(path, width=32, height=32)
    code, err = _run(capsys, "render", scene_file, "--camera", path, "--out", tmp_path / "x.npy", "--size", "32x32")
    assert code == 2 and "aspect ratio" in err
    code, err = _run(capsys, "render", scene_file, "--camera", path, "--out", tmp_path / "x.npy", "--size", "32x24")
    assert code == 0 and np.load(tmp_path / "x.npy").shape == (24, 32, 3)


@pytest.mark.parametrize("text", ["0x5", "5x0", "axb", "800", "800x", "x600", "-800x600", "800x-600", "+800x600",
                                  "800.0x600", "800 x 600", " 800x600", "800x600 ", "0800x600", "800*600",
                                  "800x600x3", "", "\u0663x3", "20000x10", "8000x8000"])
def test_size_is_parsed_strictly(text, tmp_path, scene_file, capsys):
    with pytest.raises(CameraError, match=r"^--size"):
        parse_image_size(text)
    # --size=TEXT: argparse would read a separate "-800x600" as an option
    code, err = _run(capsys, "render", scene_file, "--camera", tmp_path / "absent.json", "--out", tmp_path / "x.npy",
                     f"--size={text}")
    # refused before the camera file is even opened (it does not exist)
    assert code == 2 and err.startswith("error: --size") and len(err.strip().splitlines()) == 1


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet="0123456789xX -+.\u0663", max_size=12))
def test_size_parser_accepts_exactly_wxh(text):
    try:
        w, h = parse_image_size(text)
    except CameraError:
        return
    assert re.fullmatch(r"[1-9][0-9]*[xX][1-9][0-9]*", text)  # what was accepted looks like WxH ...
    assert f"{w}x{h}" == text.lower()  # ... and reads back to itself


@given(st.integers(1, 16384), st.integers(1, 2048))
def test_size_round_trip(w, h):
    assert parse_image_size(f"{w}x{h}") == (w, h)


# ------------------------------------------------------------------------------ distortion
def _reference_distortion_px(width, height, fx, fy, cx, cy, k=(0, 0, 0, 0), p=(0, 0), b=(0, 0, 0), n=65):
    """Point by point, as COLMAP's OpenCVCameraModel / FullOpenCVCameraModel::Distortion write it."""
    worst = 0.0
    for v in np.linspace(0.0, height, n):
        for u in np.linspace(0.0, width, n):
            x, y = (u - cx) / fx, (v - cy) / fy
            r2 = x * x + y * y
            radial = (1 + k[0] * r2 + k[1] * r2**2 + k[2] * r2**3 + k[3] * r2**4) / (1 + b[0] * r2 + b[1] * r2**2
                                                                                     + b[2] * r2**3)
            du = x * (radial - 1) + 2 * p[0] * x * y + p[1] * (r2 + 2 * x * x)
            dv = y * (radial - 1) + 2 * p[1] * x * y + p[0] * (r2 + 2 * y * y)
            worst = max(worst, math.hypot(fx * du, fy * dv))
    return worst


def test_distortion_pixel_error_by_hand():
    # SIMPLE_RADIAL f = 100 on 200 x 200 (cx = cy = 100): the corners are at x = y = +-1, r^2 = 2,
    # moved by k1 r^2 (x, y) = 0.002 (1, 1) normalised, 100 * 0.002 * sqrt(2) px
    assert max_distortion_px(200, 200, 100, 100, 100, 100, radial=[0.001]) == pytest.approx(0.2 * math.sqrt(2))
    # p1 alone: (2 p1 x y, p1 (r^2 + 2 y^2)) is largest at a corner: p1 (2, 4), i.e. 100 p1 sqrt(20) px
    assert max_distortion_px(200, 200, 100, 100, 100, 100, tangential=[0.001, 0]) == pytest.approx(0.1 * math.sqrt(20))
    # FULL_OPENCV's k4 alone (denominator): rho - 1 = -2 k4 / (1 + 2 k4) at the corners
    assert max_distortion_px(200, 200, 100, 100, 100, 100, rational=[0.01]) == pytest.approx(
        100 * math.sqrt(2) * 0.02 / 1.02)
    assert max_distortion_px(200, 200, 100, 100, 100, 100) == 0.0
    assert max_distortion_px(200, 200, 100, 100, 100, 100, rational=[-0.5]) == math.inf  # 1 - r^2/2 = 0 at a corner


@pytest.mark.parametrize("seed", range(4))
def test_distortion_pixel_error_against_a_pointwise_reference(seed):
    rng = np.random.default_rng(seed)
    w, h = int(rng.integers(20, 90)), int(rng.integers(20, 90))
    fx, fy = rng.uniform(30, 120, 2)
    cx, cy = w / 2 + rng.uniform(-3, 3), h / 2 + rng.uniform(-3, 3)
    k, p, b = rng.normal(0, 0.05, 4), rng.normal(0, 0.01, 2), rng.normal(0, 0.02, 3)
    got = max_distortion_px(w, h, fx, fy, cx, cy, radial=k, tangential=p, rational=b)
    # same formula evaluated differently: agreement to float64 rounding
    assert got == pytest.approx(_reference_distortion_px(w, h, fx, fy, cx, cy, k, p, b), rel=1e-9)


def _colmap_text(folder: Path, camera_line: str, images: int = 1) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.txt").write_text(f"# hand-made\n{camera_line}\n")
    lines = [f"{i + 1} 1 0 0 0 0 0 4 1 im{i}.png\n\n" for i in range(images)]
    (folder / "images.txt").write_text("".join(lines))
    return folder


def _colmap_binary(folder: Path, model_id: int, width: int, height: int, params) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "cameras.bin").write_bytes(struct.pack("<Q", 1) + struct.pack("<iiQQ", 1, model_id, width, height)
                                         + struct.pack("<" + "d" * len(params), *params))
    (folder / "images.bin").write_bytes(struct.pack("<Q", 1) + struct.pack("<idddddddi", 1, 1, 0, 0, 0, 0, 0, 4, 1)
                                        + b"im0.png\x00" + struct.pack("<Q", 0))
    return folder


def _blender(path: Path, frame_lens=None, **lens) -> Path:
    obj = {"w": 200, "h": 200, "fl_x": 100.0, **lens,
           "frames": [{"file_path": "a", "transform_matrix": _c2w_at(4.0)},
                      {"file_path": "b", "transform_matrix": _c2w_at(5.0), **(frame_lens or {})}]}
    path.write_text(json.dumps(obj))
    return path


# the same lens (f = 100 px, 200 x 200, centred) in every format; k = 0.001 moves the corners by
# 0.283 px (below MAX_DROPPED_DISTORTION_PX), k = 0.01 by 2.83 px (above)
def _small(tmp, fmt):
    if fmt == "colmap text":
        return _colmap_text(tmp / "m", "1 SIMPLE_RADIAL 200 200 100 100 100 0.001", images=3)
    if fmt == "colmap binary":
        return _colmap_binary(tmp / "m", 2, 200, 200, [100, 100, 100, 0.001])
    if fmt == "colmap OPENCV":
        return _colmap_text(tmp / "m", "1 OPENCV 200 200 100 100 100 100 0.001 0 0 0")
    if fmt == "blender file-level":
        return _blender(tmp / "t.json", k1=0.001)
    return _blender(tmp / "t.json", frame_lens={"k1": 0.001, "camera_model": "OPENCV"})


FORMATS = ["colmap text", "colmap binary", "colmap OPENCV", "blender file-level", "blender frame-level"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_small_distortion_is_dropped_with_one_warning_stating_the_error(tmp_path, fmt):
    src = _small(tmp_path, fmt)
    with pytest.warns(DistortionWarning) as record:
        cams = load_any_cameras(src)
    assert len(record) == 1  # one per file, however many images share the lens
    msg = str(record[0].message)
    assert "0.283 px" in msg and ("k1=0.001" in msg or "k=0.001" in msg)
    assert all((c.fx, c.fy, c.cx, c.cy) == (100.0, 100.0, 100.0, 100.0) for c in cams)
    if fmt == "blender frame-level":
        assert "frames[1]" in msg


def _big(tmp, fmt):
    if fmt == "colmap text":
        return (_colmap_text(tmp / "m", "1 SIMPLE_RADIAL 200 200 100 100 100 0.01"),
                r"cameras.txt line 2 \(camera id 1, SIMPLE_RADIAL\): lens distortion k=0.01")
    if fmt == "colmap binary":
        return (_colmap_binary(tmp / "m", 2, 200, 200, [100, 100, 100, 0.01]),
                r"cameras.bin camera 0 \(camera id 1, SIMPLE_RADIAL\): lens distortion k=0.01")
    if fmt == "colmap OPENCV":
        return (_colmap_text(tmp / "m", "1 OPENCV 200 200 100 100 100 100 0.01 0 0 0"),
                r"\(camera id 1, OPENCV\): lens distortion k1=0.01, k2=0, p1=0, p2=0")
    if fmt == "blender file-level":
        return _blender(tmp / "t.json", k1=0.01), r"t.json: lens distortion k1=0.01"
    return (_blender(tmp / "t.json", frame_lens={"k1": 0.01, "p2": 0.0}),
            r"t.json: frames\[1\]: lens distortion k1=0.01, p2=0")


@pytest.mark.parametrize("fmt", FORMATS)
def test_large_distortion_is_refused_naming_file_camera_and_coefficients(tmp_path, fmt, scene_file, capsys):
    src, where = _big(tmp_path, fmt)
    with pytest.raises(CameraError, match=where + r" moves pixels by up to 2.83 px over the 200x200 image.*"
                                                  r"image_undistorter") as info:
        load_any_cameras(src)
    assert str(src) in str(info.value)  # names the file or folder by its path
    code, err = _run(capsys, "render", scene_file, "--camera", src, "--out", tmp_path / "x.npy")
    assert code == 2 and "image_undistorter" in err and len(err.strip().splitlines()) == 1


def test_threshold_is_inclusive_and_measured_at_the_files_own_size(tmp_path):
    # k chosen so the corner moves by exactly the threshold: 100 * k * 2 * sqrt(2) = 0.5
    k = MAX_DROPPED_DISTORTION_PX / (200 * math.sqrt(2)) * (1 - 1e-12)
    with pytest.warns(DistortionWarning):
        read_colmap(_colmap_text(tmp_path / "a", f"1 SIMPLE_RADIAL 200 200 100 100 100 {k!r}"))
    with pytest.raises(CameraError, match="moves pixels"):
        read_colmap(_colmap_text(tmp_path / "b", f"1 SIMPLE_RADIAL 200 200 100 100 100 {k * 1.01!r}"))
    # a smaller --size does not let a too distorted camera through: the photographs are what counts
    with pytest.raises(CameraError, match="over the 200x200 image"):
        read_colmap(tmp_path / "b", width=20, height=20)


@pytest.mark.parametrize("fmt", ["colmap", "blender"])
def test_zero_distortion_is_accepted_silently(tmp_path, fmt):
    if fmt == "colmap":
        src = _colmap_text(tmp_path / "m", "1 FULL_OPENCV 200 200 100 100 100 100 0 0 0 0 0 0 0 0")
    else:
        src = _blender(tmp_path / "t.json", k1=0, k2=0.0, p1=0, p2=0, k3=0, camera_model="OPENCV",
                       frame_lens={"k1": 0.0})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cams = load_any_cameras(src)
    assert cams[0].fx == 100.0


@pytest.mark.parametrize("fmt,match", [
    ("colmap", r"OPENCV_FISHEYE is not supported: not a pinhole projection"),
    ("blender", r"t.json: frames\[1\].camera_model: 'OPENCV_FISHEYE' is not a pinhole model"),
])
def test_fisheye_is_refused_even_without_distortion(tmp_path, fmt, match):
    if fmt == "colmap":
        src = _colmap_text(tmp_path / "m", "1 OPENCV_FISHEYE 200 200 100 100 100 100 0 0 0 0")
    else:
        src = _blender(tmp_path / "t.json", frame_lens={"camera_model": "OPENCV_FISHEYE"})
    with pytest.raises(CameraError, match=match):
        load_any_cameras(src)


def test_cli_warns_in_one_line_and_renders(tmp_path, scene_file, capsys):
    src = _colmap_text(tmp_path / "m", "1 SIMPLE_RADIAL 200 200 100 100 100 0.001")
    code, err = _run(capsys, "render", scene_file, "--camera", src, "--out", tmp_path / "x.npy", "--size", "40x40")
    assert code == 0
    (line,) = [ln for ln in err.splitlines() if ln]
    assert line.startswith("warning: ") and "0.283 px" in line
    assert np.load(tmp_path / "x.npy").shape == (40, 40, 3)
