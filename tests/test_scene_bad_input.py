"""Bad input to the scene commands and readers (fuzzing sweep s18): each is refused as one line naming
the field and index, never a traceback, a run that does not end, or silent acceptance.

1. a negative ``--seed`` (``scene make``, ``scene segment``, sampled cameras);
2. a ``--views`` count beyond :data:`MAX_PATH_VIEWS`, refused before any camera is built;
3. PLY values whose float32 arithmetic overflows (``scale_0 = 1e30``, ``x = 3e38``), named by property;
4. ``render --index -1`` (no Python negative indexing);
5. ``scene make --background 2,0,0`` (the check ``render`` uses) and ``scene make --out m.txt``;
6. a camera whose principal point lies far outside the image, or whose name is not text;
7. a camera translation beyond float32's reach (an empty picture with exit 0 before, s19).

CLI checks run the real ``l3gs_opt.cli.main.main``: exit code 2 and exactly one ``error:`` line.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from l3gs_opt.scene.camera_paths import MAX_PATH_VIEWS, orbit_path, walk_path
from l3gs_opt.scene.camera_sampling import sample_cameras
from l3gs_opt.scene.cameras import (MAX_PRINCIPAL_POINT_OUTSIDE, CameraError, camera_from_dict, camera_to_dict,
                                    save_cameras)
from l3gs_opt.scene.procedural import make_scene
from l3gs_opt.scene.segment import segment_scene
from l3gs_opt.scene.splats import MAX_ABS_MEAN, MAX_LOG_SCALE, SceneError, read_ply, write_ply
from cli_helpers import one_error_line, run_cli
from renderer_helpers import make_camera, random_scene


@pytest.fixture
def scene_file(tmp_path) -> Path:
    """A 200-splat PLY (SH degree 0) the cameras of ``make_camera`` see."""
    return write_ply(random_scene(200, sh_degree=0), tmp_path / "s.ply")


@pytest.fixture
def camera_file(tmp_path) -> Path:
    return save_cameras([make_camera(), make_camera(eye=(4.0, 0.3, 1.0))], tmp_path / "cams.json")


def _patched_ply(src: Path, dst: Path, prop: str, value: float, row: int = 0) -> Path:
    """``src`` (binary little-endian, float32/int32 properties) with ``prop`` of vertex ``row`` set to ``value``."""
    data = src.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = [ln.split() for ln in data[:end].split(b"\n") if ln.startswith(b"property")]
    dtype = np.dtype([(ln[2].decode(), "<f4" if ln[1] == b"float" else "<i4") for ln in lines])
    rows = np.frombuffer(data[end:], dtype).copy()
    rows[prop][row] = value
    dst.write_bytes(data[:end] + rows.tobytes())
    return dst


# ------------------------------------------------------------------ 1. negative seed
def test_negative_seed_is_refused_by_name(capsys, tmp_path, scene_file):
    want = "error: --seed = -1: must be an integer >= 0"
    assert one_error_line(capsys, "scene", "make", "--out", tmp_path / "m.ply", "--splats", 1000, "--seed", -1) == want
    assert not (tmp_path / "m.ply").exists()
    assert one_error_line(capsys, "scene", "segment", scene_file, "--seed", -1, "--out", tmp_path / "g.ply") == want
    with pytest.raises(SceneError, match=r"^seed = -1: must be an integer >= 0$"):
        make_scene(1000, seed=-1)
    with pytest.raises(SceneError, match=r"^seed = -2: "):
        segment_scene(random_scene(50), 2, seed=-2)
    with pytest.raises(CameraError, match=r"^seed = -1: "):
        sample_cameras(random_scene(50), 2, mode="inside", seed=-1)


# ------------------------------------------------------------------ 2. --views limit
def test_views_beyond_the_limit_are_refused_before_any_work(capsys, tmp_path):
    line = one_error_line(capsys, "scene", "make", "--out", tmp_path / "m.ply", "--splats", 1000,
                          "--orbit", tmp_path / "o.json", "--views", MAX_PATH_VIEWS + 1)
    assert line.startswith(f"error: --views: {MAX_PATH_VIEWS + 1}: must be an integer in [1, ")
    assert "MAX_PATH_VIEWS" in line
    assert not (tmp_path / "m.ply").exists() and not (tmp_path / "o.json").exists()
    for path in (orbit_path, walk_path):
        with pytest.raises(CameraError, match="MAX_PATH_VIEWS"):
            path(MAX_PATH_VIEWS + 1, width=8, height=6)
    with pytest.raises(CameraError, match=r"^count: 100000000: must be an integer in \[1, "):
        sample_cameras(random_scene(50), 100_000_000)
    assert len(orbit_path(3, width=8, height=6)) == 3


# ------------------------------------------------------------------ 3. float32 overflow in a PLY
@pytest.mark.parametrize("prop, value, field", [("scale_0", 1e30, "scale_0[0]"), ("scale_2", 45.0, "scale_2[0]"),
                                                ("x", 3e38, "x[0]"), ("z", -2e18, "z[0]")])
def test_ply_values_that_overflow_float32_are_named(capsys, tmp_path, scene_file, camera_file, prop, value, field):
    bad = _patched_ply(scene_file, tmp_path / "bad.ply", prop, value)
    rule = "MAX_LOG_SCALE" if prop.startswith("scale") else "MAX_ABS_MEAN"
    with pytest.raises(SceneError, match=rf"^{re.escape(field)}: .*bad.ply: .*\({rule}\)") as info:
        read_ply(bad)
    assert info.value.field == prop and info.value.index == (0,)
    for argv in (("scene", "info", bad), ("render", bad, "--camera", camera_file, "--out", tmp_path / "x.png"),
                 ("scene", "convert", bad, tmp_path / "x.spz")):
        assert one_error_line(capsys, *argv).startswith(f"error: {field}: ")
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "x.spz").exists()


def test_ply_values_just_inside_the_float32_limits_load(capsys, tmp_path, scene_file):
    ok = _patched_ply(scene_file, tmp_path / "a.ply", "scale_0", 44.0)   # MAX_LOG_SCALE = 44.36
    ok = _patched_ply(ok, tmp_path / "b.ply", "x", 0.9 * MAX_ABS_MEAN)
    ok = _patched_ply(ok, tmp_path / "c.ply", "scale_1", -1e30)          # underflows to a point: drawn
    scene = read_ply(ok)
    assert scene.log_scales[0, 0] == np.float32(44.0) < MAX_LOG_SCALE
    code, out, err = run_cli(capsys, "scene", "info", ok)
    assert code == 0 and err == "" and "inf" not in out


def test_scene_info_of_a_hugely_negative_opacity_gives_no_warning(capsys, tmp_path, scene_file):
    # the sigmoid 1 / (1 + exp(-x)) overflowed below x = -709 and printed "warning: overflow in exp"
    bad = _patched_ply(scene_file, tmp_path / "o.ply", "opacity", -1e30)
    code, out, err = run_cli(capsys, "scene", "info", bad)
    assert code == 0 and err == "" and "mean_opacity: " in out


# ------------------------------------------------------------------ 4. render --index -1
def test_render_refuses_a_negative_index(capsys, tmp_path, scene_file, camera_file):
    line = one_error_line(capsys, "render", scene_file, "--camera", camera_file, "--index", -1,
                          "--out", tmp_path / "x.png")
    assert line.startswith("error: --index: -1 out of range") and "holds 2 cameras, indices 0..1" in line
    assert not (tmp_path / "x.png").exists()
    code, _, err = run_cli(capsys, "render", scene_file, "--camera", camera_file, "--index", 1,
                           "--out", tmp_path / "y.png")
    assert code == 0 and err == "" and (tmp_path / "y.png").exists()


# ------------------------------------------------------------------ 5. scene make --background, --out
def test_scene_make_checks_background_and_output_suffix(capsys, tmp_path):
    make = ("scene", "make", "--splats", 1000, "--sh-degree", 0)
    assert one_error_line(capsys, *make, "--out", tmp_path / "m.ply", "--background", "2,0,0") == \
        "error: --background[0]: 2.0 must be in [0, 1] (r, g, b)"
    assert "--background: " in one_error_line(capsys, *make, "--out", tmp_path / "m.ply", "--background", "0,0")
    assert not (tmp_path / "m.ply").exists()
    line = one_error_line(capsys, *make, "--out", tmp_path / "m.txt")
    assert "m.txt: unknown scene file extension" in line
    assert "must end in .ply" in one_error_line(capsys, *make, "--out", tmp_path / "m.spz")
    assert not (tmp_path / "m.txt").exists() and not (tmp_path / "m.spz").exists()
    code, _, err = run_cli(capsys, *make, "--out", tmp_path / "m.ply", "--background", "0.1,0.2,0.3")
    assert code == 0 and err == ""


def test_scene_segment_refuses_an_unknown_output_suffix(capsys, tmp_path, scene_file):
    assert "s.txt: unknown scene file extension" in one_error_line(capsys, "scene", "segment", scene_file,
                                                                     "--out", tmp_path / "s.txt")


# ------------------------------------------------------------------ 6. camera JSON: principal point, name
@pytest.mark.parametrize("key, value, match", [
    ("cx", 1e20, r"^cams.json\[1\]\.cx: 1e\+20 must be in \[-37, 74\] pixels"),
    ("cy", -30.0, r"^cams.json\[1\]\.cy: -30 must be in \[-29, 58\] pixels"),
    ("name", 5, r"^cams.json\[1\]\.name: 5 must be text$"),
])
def test_camera_json_principal_point_and_name(capsys, tmp_path, scene_file, key, value, match):
    cams = [camera_to_dict(make_camera()), {**camera_to_dict(make_camera()), key: value}]
    path = tmp_path / "cams.json"
    path.write_text(json.dumps(cams))
    line = one_error_line(capsys, "render", scene_file, "--camera", path, "--out", tmp_path / "x.png")
    assert pytest.raises(CameraError, camera_from_dict, cams[1], where="cams.json[1]").match(match)
    assert line.startswith("error: cams.json[1].")
    assert not (tmp_path / "x.png").exists()


def test_principal_point_limit_is_one_image_outside():
    d = camera_to_dict(make_camera(width=40, height=30))
    assert MAX_PRINCIPAL_POINT_OUTSIDE == 1.0
    for cx, cy in ((-40.0, -30.0), (80.0, 60.0), (20.0, 15.0)):
        camera_from_dict({**d, "cx": cx, "cy": cy})
    for cx in (-40.5, 80.5):
        with pytest.raises(CameraError, match=r"^camera\.cx: .*MAX_PRINCIPAL_POINT_OUTSIDE"):
            camera_from_dict({**d, "cx": cx})
    # a resized camera keeps its principal point inside the limit (cx scales with the width)
    assert make_camera(width=40, height=30, cx=-40.0).resized(80, 60).cx == -80.0


def _moved(cam: dict, translation: float) -> dict:
    m = [list(row) for row in cam["world_to_camera"]]
    m[2][3] = translation
    return {**cam, "world_to_camera": m}


def test_camera_translation_beyond_float32_reach_is_refused(capsys, tmp_path, scene_file):
    """A camera 1e30 units away used to render an empty picture with exit 0: its float32 distances
    overflow. It is refused by the splats' own position limit, MAX_ABS_MEAN; 1e17 is accepted."""
    d = camera_to_dict(make_camera())
    path = tmp_path / "cams.json"
    path.write_text(json.dumps([d, _moved(d, 1e30)]))
    line = one_error_line(capsys, "render", scene_file, "--camera", path, "--index", 1, "--out", tmp_path / "x.png")
    assert line.startswith("error: cams.json[1].world_to_camera[2][3]: 1e+30 must be within +-1e+18 world units")
    assert "MAX_ABS_MEAN" in line and not (tmp_path / "x.png").exists()
    assert MAX_ABS_MEAN == 1e18
    camera_from_dict(_moved(d, 1e17))
    with pytest.raises(CameraError, match=r"^camera\.world_to_camera\[2\]\[3\]: -2e\+18 must be within"):
        camera_from_dict(_moved(d, -2e18))
