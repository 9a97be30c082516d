"""Bundles: round trip per variant, bytes as stored, only what the scene needs, manifest checks."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from l3gs_opt.scene.bundle import (BUNDLE_SCHEMA, BundleError, effective_sh_degree, read_bundle, record_fields,
                             split_layers, write_bundle)
from l3gs_opt.scene.splats import bytes_per_splat
from renderer_helpers import random_scene

_KEYS = ("means", "log_scales", "quats", "opacity_logits", "sh", "object_ids")


def _by_object(scene):
    """Rows grouped by object id (stable): the order chunks store them in."""
    return scene.subset(np.argsort(scene.object_ids, kind="stable")) if scene.object_ids is not None else scene


def _same(a, b):
    for k in _KEYS:
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.tobytes() == y.tobytes(), k


def test_layered_round_trip_and_bytes(tmp_path):
    scene = random_scene(60, sh_degree=2, seed=1, object_ids=True, layers=3)
    scene = scene.subset(np.argsort(scene.layers, kind="stable"))
    levels = split_layers(scene)
    write_bundle(tmp_path / "b", levels, variant="layered", build={"note": "test"})
    b = read_bundle(tmp_path / "b")
    m = b.manifest
    assert m["schema"] == BUNDLE_SCHEMA and m["representation"] == "layered" and m["sh_degree"] == 2
    assert [lv["splats"] for lv in m["levels"]] == [lv.num_splats for lv in levels]
    assert m["levels"][-1]["cumulative_splats"] == 60
    for lvl, want in enumerate(levels):
        _same(b.level_scene(lvl), _by_object(want))
    full = b.scene(2)
    assert full.num_splats == 60 and full.layers.tolist() == sorted(full.layers.tolist())
    total = 0
    for c in m["chunks"]:
        f = tmp_path / "b" / c["file"]
        assert f.stat().st_size == c["bytes"] == c["splats"] * bytes_per_splat(2)
        total += c["bytes"]
    assert total == 60 * 152  # 4 * (3 + 27 + 1 + 3 + 4)
    assert m["bytes_per_splat"] == {"full": 152}


def test_only_what_the_scene_needs(tmp_path):
    # degree-3 storage but only DC used, no ids: one object, 56 bytes per splat
    s = random_scene(20, sh_degree=3, seed=2)
    s = dataclasses.replace(s, sh=np.concatenate([s.sh[:, :1], np.zeros((20, 15, 3), np.float32)], 1))
    assert effective_sh_degree(s.sh) == 0
    write_bundle(tmp_path / "b", [s.subset(np.arange(8)), s.subset(np.arange(8, 20))], variant="sort")
    b = read_bundle(tmp_path / "b")
    assert b.manifest["objects"] == [0] and not b.manifest["segmented"]
    assert b.manifest["bytes_per_splat"] == {"full": 56}
    got = b.scene(1)
    assert got.object_ids is None and got.sh_degree == 0
    np.testing.assert_array_equal(got.sh[:, 0], s.sh[:, 0])
    assert "object_id" not in json.dumps(b.manifest["chunks"][0]["fields"])


def test_distill_round_trip(tmp_path):
    s = random_scene(30, sh_degree=1, seed=4, object_ids=True)
    compact = [np.asarray(s.sh[:10, :1]) * 0.5, np.asarray(s.sh[10:, :1]) * 0.5]
    write_bundle(tmp_path / "b", [s.subset(np.arange(10)), s.subset(np.arange(10, 30))], variant="distill",
                 compact_sh=compact)
    b = read_bundle(tmp_path / "b")
    m = b.manifest
    assert m["compact_sh_degree"] == 0 and m["bytes_per_splat"] == {"compact": 56, "sh_upgrade": 48}
    forms = {c["sh_form"] for c in m["chunks"]}
    assert forms == {"compact", "sh_upgrade"}
    _same(b.level_scene(1), _by_object(s.subset(np.arange(10, 30))))  # geometry + upgraded SH = full
    comp = b.level_scene(0, sh_form="compact")
    want = _by_object(dataclasses.replace(s.subset(np.arange(10)), sh=compact[0]))
    _same(comp, want)
    up = [c for c in m["chunks"] if c["sh_form"] == "sh_upgrade"]
    assert all(c["bytes"] == c["splats"] * 48 for c in up)


def test_hierarchy_parents_round_trip(tmp_path):
    v0 = random_scene(10, sh_degree=0, seed=5, object_ids=True)
    v1 = random_scene(25, sh_degree=0, seed=6, object_ids=True)
    # parent of each v1 splat: first v0 row of the same object (or -1 if the object is absent)
    par = np.array([np.flatnonzero(v0.object_ids == j)[0] if (v0.object_ids == j).any() else -1
                    for j in v1.object_ids])
    write_bundle(tmp_path / "b", [v0, v1], variant="hierarchy", parents=[None, par])
    b = read_bundle(tmp_path / "b")
    assert b.manifest["representation"] == "separate" and b.manifest["bytes_per_splat"] == {"full": 60}
    _same(b.scene(1), _by_object(v1))
    for j in b.manifest["objects"]:
        got = b.parents(1, j)
        rows = np.flatnonzero(v1.object_ids == j)
        want = [0 if par[r] >= 0 else -1 for r in rows]  # first row of the object's v0 chunk
        assert got.tolist() == want
        assert (b.parents(0, j) == -1).all()
    bad = par.copy()
    i = int(np.flatnonzero(par >= 0)[0])
    bad[i] = int(np.flatnonzero(v0.object_ids != v1.object_ids[i])[0])
    with pytest.raises(BundleError, match=r"parents\[1\]: a parent belongs to another object"):
        write_bundle(tmp_path / "c", [v0, v1], variant="hierarchy", parents=[None, bad])


def test_manifest_errors(tmp_path):
    s = random_scene(5, sh_degree=0, seed=7)
    with pytest.raises(BundleError, match="variant: 'tree'"):
        write_bundle(tmp_path / "x", [s], variant="tree")
    with pytest.raises(BundleError, match="compact_sh"):
        write_bundle(tmp_path / "x", [s], variant="distill")
    write_bundle(tmp_path / "b", [s], variant="separate")
    mp = tmp_path / "b" / "manifest.json"
    m = json.loads(mp.read_text())
    m["extra"] = 1
    mp.write_text(json.dumps(m))
    with pytest.raises(BundleError, match="extra: unknown manifest key"):
        read_bundle(tmp_path / "b")
    del m["extra"]
    m["chunks"][0]["bytes"] += 4
    mp.write_text(json.dumps(m))
    with pytest.raises(BundleError, match=r"chunks\[0\]: bytes"):
        read_bundle(tmp_path / "b")


def test_record_sizes_documented():
    # the table in the module docstring
    for d, full in zip(range(4), (56, 92, 152, 236)):
        assert np.dtype(record_fields("full", d)).itemsize == full
        assert np.dtype(record_fields("sh_upgrade", d)).itemsize == 12 * (d + 1) ** 2
        assert np.dtype(record_fields("full", d, parent=True)).itemsize == full + 4
