"""CLI handlers ``render``, ``scene make``, ``scene info`` (through ``l3gs_opt.cli.scene.register``)."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
from PIL import Image

from l3gs_opt.scene.cameras import save_cameras, write_blender, write_colmap
from l3gs_opt.cli.scene import register
from l3gs_opt.errors import L3gsError
from l3gs_opt.renderer import render_scene
from l3gs_opt.scene.splats import read_ply, write_ply
from renderer_helpers import make_camera, random_scene


def _run(*argv) -> int:
    parser = argparse.ArgumentParser(prog="l3gs-opt")
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args([str(a) for a in argv])
    return args.func(args)


@pytest.fixture
def files(tmp_path):
    scene = random_scene(60, seed=3, object_ids=True)
    cam = make_camera(40, 30)
    write_ply(scene, tmp_path / "s.ply")
    save_cameras([cam, make_camera(40, 30, eye=(2.0, -3.0, 1.0))], tmp_path / "cams.json")
    return tmp_path, scene, cam


def test_render_npy_png_and_camera_formats(files, capsys):
    tmp, scene, cam = files
    assert _run("render", tmp / "s.ply", "--camera", tmp / "cams.json", "--out", tmp / "a.npy") == 0
    img = np.load(tmp / "a.npy")
    assert img.dtype == np.float32 and img.shape == (30, 40, 3)
    np.testing.assert_array_equal(img, render_scene(scene, cam).image.numpy())
    assert _run("render", tmp / "s.ply", "--camera", tmp / "cams.json", "--out", tmp / "a.png") == 0
    png = np.asarray(Image.open(tmp / "a.png"))
    assert png.shape == (30, 40, 3) and png.dtype == np.uint8
    assert np.abs(png.astype(float) - np.clip(img, 0, 1) * 255).max() <= 0.5 + 1e-3
    # COLMAP folder and transforms.json give the same image
    write_colmap([cam], tmp / "colmap", binary=True)
    write_blender([cam], tmp / "transforms.json")
    for src in (tmp / "colmap", tmp / "transforms.json"):
        _run("render", tmp / "s.ply", "--camera", src, "--out", tmp / "b.npy", "--background", "0.1,0.2,0.3")
        np.testing.assert_allclose(np.load(tmp / "b.npy"), img, atol=1e-5)
    assert "wrote" in capsys.readouterr().out


@pytest.mark.parametrize("case,match", [
    ("bad_out", "must end in .png or .npy"),
    ("bad_index", "--index: 5 out of range"),
    ("corrupt_ply", "^file: "),
    ("bad_camera", "not valid JSON"),
])
def test_render_errors_are_l3gs_errors(files, case, match):
    tmp, _, _ = files
    argv = ["render", tmp / "s.ply", "--camera", tmp / "cams.json", "--out", tmp / "x.png"]
    if case == "bad_out":
        argv[-1] = tmp / "x.jpg"
    elif case == "bad_index":
        argv += ["--index", "5"]
    elif case == "corrupt_ply":
        (tmp / "c.ply").write_bytes((tmp / "s.ply").read_bytes()[:300])
        argv[1] = tmp / "c.ply"
    elif case == "bad_camera":
        (tmp / "bad.json").write_text("[{")
        argv[3] = tmp / "bad.json"
    with pytest.raises(L3gsError, match=match) as info:
        _run(*argv)
    assert isinstance(info.value, ValueError)


def test_scene_make_and_info(tmp_path, capsys):
    out = tmp_path / "room.ply"
    assert _run("scene", "make", "--out", out, "--splats", 5000, "--objects", 3, "--sh-degree", 1, "--seed", 4,
                "--orbit", tmp_path / "orbit.json", "--walk", tmp_path / "walk.json", "--views", 5,
                "--width", 64, "--height", 48) == 0
    scene = read_ply(out)
    assert scene.num_splats == 5000 and scene.sh_degree == 1 and scene.num_objects == 4
    assert len(json.loads((tmp_path / "orbit.json").read_text())) == 5
    assert len(json.loads((tmp_path / "walk.json").read_text())) == 5
    capsys.readouterr()
    assert _run("scene", "info", out, "--json") == 0
    info = json.loads(capsys.readouterr().out)
    assert info["splats"] == 5000 and info["objects"] == 4 and info["layers"] == 1
    assert sum(info["splats_per_object"].values()) == 5000
    assert _run("scene", "info", out) == 0
    assert "sh_degree: 1" in capsys.readouterr().out
    with pytest.raises(L3gsError, match="num_splats"):
        _run("scene", "make", "--out", out, "--splats", 10)
