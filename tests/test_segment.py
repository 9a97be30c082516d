"""Segmentation by k-means on splat centres (scipy) and the ``scene segment`` CLI."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

from l3gs_opt.cli.scene import register
from l3gs_opt.scene.splats import SceneError, read_ply, write_ply
from l3gs_opt.scene.segment import segment_scene
from renderer_helpers import random_scene


def _blobs():
    s = random_scene(90, sh_degree=0, seed=1, spread=0.1)
    shift = np.zeros((90, 3), np.float32)
    shift[:30, 0] = 10.0  # 30 splats far along +x, 60 at the origin
    return dataclasses.replace(s, means=s.means + shift)


def test_separated_blobs_get_their_own_ids():
    out = segment_scene(_blobs(), 2, seed=0)
    # ids by decreasing size: the 60-splat blob is object 0
    assert out.object_ids[:30].tolist() == [1] * 30 and out.object_ids[30:].tolist() == [0] * 60
    again = segment_scene(_blobs(), 2, seed=0)
    np.testing.assert_array_equal(out.object_ids, again.object_ids)  # deterministic
    np.testing.assert_array_equal(out.means, _blobs().means)  # splats untouched


def test_one_object_and_bad_counts():
    s = _blobs()
    assert segment_scene(s, 1).object_ids.tolist() == [0] * 90
    for bad in (0, 91, 2.5, True):
        with pytest.raises(SceneError, match=r"^objects: "):
            segment_scene(s, bad)


def test_cli_segment(tmp_path, capsys):
    write_ply(_blobs(), tmp_path / "in.ply")
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["scene", "segment", str(tmp_path / "in.ply"), "--objects", "2",
                              "--out", str(tmp_path / "out.ply")])
    assert args.func(args) == 0
    assert read_ply(tmp_path / "out.ply").num_objects == 2
    assert "[60, 30]" in capsys.readouterr().out
