"""Segmentation by k-means on splat centres (scipy) and the ``scene segment`` CLI."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from l3gs_opt.cli.scene import register
from l3gs_opt.scene.splats import SceneError, read_ply, write_ply
from l3gs_opt.scene.segment import adjusted_rand_index, segment_scene
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
    for bad in (0, 91, 2.5, True, "auto2"):
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


def _box(n, centre, size, rng):
    return rng.uniform(-0.5, 0.5, (n, 3)) * size + centre


def _scene_of(points, seed=0):
    s = random_scene(len(points), sh_degree=0, seed=seed)
    return dataclasses.replace(s, means=np.asarray(points, np.float32))


def test_auto_count_finds_separated_groups_and_ids_by_size():
    rng = np.random.default_rng(0)
    pts = np.concatenate([_box(400, (0, 0, 0), 1, rng), _box(300, (5, 0, 0), 1, rng), _box(200, (0, 5, 0), 1, rng)])
    out = segment_scene(_scene_of(pts))
    assert out.object_ids.tolist() == [0] * 400 + [1] * 300 + [2] * 200


def test_floor_plane_splits_objects_standing_on_it():
    rng = np.random.default_rng(1)
    floor = np.column_stack([rng.uniform(-4, 4, (3000, 2)), np.zeros(3000)])
    a = _box(600, (-2, 0, 0.5), 1, rng)
    b = _box(600, (2, 0, 0.5), 1, rng)
    a[:, 2] = np.abs(a[:, 2])   # both boxes rest on the floor, touching it
    b[:, 2] = np.abs(b[:, 2])
    scene = _scene_of(np.concatenate([floor, a, b]))
    truth = np.repeat([0, 1, 2], [3000, 600, 600])
    assert segment_scene(scene).num_objects == 1          # joined through the floor
    got = segment_scene(scene, planes=1)
    assert got.num_objects == 3
    assert adjusted_rand_index(truth, got.object_ids) > 0.95


def test_background_shell_is_one_object():
    rng = np.random.default_rng(2)
    near = _box(2000, (0, 0, 0), 1, rng)
    direction = rng.normal(size=(500, 3))
    far = 50 * direction / np.linalg.norm(direction, axis=1, keepdims=True)
    got = segment_scene(_scene_of(np.concatenate([near, far])), background=True)
    assert set(got.object_ids[2000:].tolist()) == {1} and set(got.object_ids[:2000].tolist()) == {0}


@pytest.mark.parametrize("method", ["components", "kmeans"])
def test_count_is_met_by_merging_or_splitting(method):
    rng = np.random.default_rng(3)
    pts = np.concatenate([_box(300, (i * 4.0, 0, 0), 1, rng) for i in range(5)])
    for k in (1, 2, 5, 9):
        got = segment_scene(_scene_of(pts), k, method=method, seed=4)
        assert got.num_objects == k
        np.testing.assert_array_equal(got.object_ids, segment_scene(_scene_of(pts), k, method=method, seed=4).object_ids)
        assert np.all(np.diff(np.bincount(got.object_ids)) <= 0)   # ids by decreasing size


def test_bad_arguments_name_the_field():
    s = _blobs()
    for kw, field in ((dict(method="dbscan"), "method"), (dict(planes=-1), "planes"), (dict(planes=2.0), "planes")):
        with pytest.raises(SceneError, match=rf"^{field}: "):
            segment_scene(s, **kw)
    with pytest.raises(SceneError, match="^objects: "):
        segment_scene(s, "many")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 3)), min_size=2, max_size=30))
def test_adjusted_rand_index_against_pair_counting(pairs):
    a, b = np.array(pairs).T
    n = len(a)
    same_a = a[:, None] == a[None, :]
    same_b = b[:, None] == b[None, :]
    iu = np.triu_indices(n, 1)
    both, in_a, in_b, total = (same_a & same_b)[iu].sum(), same_a[iu].sum(), same_b[iu].sum(), len(iu[0])
    expected = in_a * in_b / total
    top = 0.5 * (in_a + in_b) - expected
    want = 1.0 if top == 0 else (both - expected) / top
    assert adjusted_rand_index(a, b) == pytest.approx(want, abs=1e-12)
    assert adjusted_rand_index(a, a) == pytest.approx(1.0)


def test_gaussian_grouping_identity_encodings_segment_the_scene(tmp_path, capsys):
    """A PLY with obj_dc_* encodings (Gaussian Grouping): read_ply skips them, segmentation clusters
    them, so two objects that touch in space are told apart by their encodings."""
    from plyfile import PlyData, PlyElement

    from l3gs_opt.scene import splats
    from l3gs_opt.scene.splats import read_identity_features

    rng = np.random.default_rng(7)
    pts = np.concatenate([_box(300, (0, 0, 0), 1, rng), _box(300, (0.9, 0, 0), 1, rng)])   # overlapping boxes
    scene = _scene_of(pts)
    codes = np.zeros((600, 16), np.float32)
    codes[:300, 3], codes[300:, 11] = 1.0, 1.0
    codes += rng.normal(0, 0.05, codes.shape).astype(np.float32)
    base = np.empty(600, splats._ply_dtype(scene))
    write_ply(scene, tmp_path / "plain.ply")
    plain = PlyData.read(str(tmp_path / "plain.ply"))["vertex"].data
    rec = np.zeros(600, base.dtype.descr + [(f"obj_dc_{i}", "<f4") for i in range(16)])
    for name in plain.dtype.names:
        rec[name] = plain[name]
    for i in range(16):
        rec[f"obj_dc_{i}"] = codes[:, i]
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(tmp_path / "gg.ply"))
    assert read_ply(tmp_path / "gg.ply").num_splats == 600          # encodings are not unknown properties
    np.testing.assert_array_equal(read_identity_features(tmp_path / "gg.ply"), codes)
    assert read_identity_features(tmp_path / "plain.ply") is None
    assert segment_scene(scene, 2).num_objects == 2
    got = segment_scene(scene, 2, features=read_identity_features(tmp_path / "gg.ply"))
    assert adjusted_rand_index(np.repeat([0, 1], 300), got.object_ids) == 1.0
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(["scene", "segment", str(tmp_path / "gg.ply"), "--objects", "2",
                              "--out", str(tmp_path / "out.ply")])
    assert args.func(args) == 0 and "identity encodings" in capsys.readouterr().out
    np.testing.assert_array_equal(read_ply(tmp_path / "out.ply").object_ids, got.object_ids)
