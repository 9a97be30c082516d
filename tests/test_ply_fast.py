"""The memory-mapped PLY path against plyfile's parser, on every layout the fast path accepts
or hands over (byte order, property types, element order, ASCII)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from plyfile import PlyData, PlyElement

from l3gs_opt.scene import splats
from l3gs_opt.scene.splats import SceneError, SplatScene, read_ply, write_ply


def _scene(n: int, degree: int, seed: int, *, ids: bool = False, normals: bool = False) -> SplatScene:
    rng = np.random.default_rng(seed)
    return SplatScene(means=rng.normal(size=(n, 3)), log_scales=rng.normal(-3, 1, (n, 3)),
                      quats=rng.normal(size=(n, 4)) + 2.0, opacity_logits=rng.normal(size=n),
                      sh=rng.normal(size=(n, (degree + 1) ** 2, 3)),
                      object_ids=rng.integers(0, 5, n) if ids else None,
                      normals=rng.normal(size=(n, 3)) if normals else None)


def _same(a: SplatScene, b: SplatScene) -> None:
    for f in ("means", "log_scales", "quats", "opacity_logits", "sh", "object_ids", "layers", "normals"):
        x, y = getattr(a, f), getattr(b, f)
        assert (x is None) == (y is None), f
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=f)


def _records(scene: SplatScene, types: dict | None = None) -> np.ndarray:
    """The scene as a PLY vertex record in the reference layout, with per-property type overrides."""
    dt = [(n, (types or {}).get(n, t)) for n, t in splats._ply_dtype(scene)]
    rec = np.empty(scene.num_splats, dtype=dt)
    path_free = {n: None for n, _ in dt}
    k = scene.sh.shape[1]
    for i, c in enumerate("xyz"):
        rec[c] = scene.means[:, i]
    for name in path_free:
        if name.startswith("f_dc_"):
            rec[name] = scene.sh[:, 0, int(name[5:])]
        elif name.startswith("f_rest_"):
            j = int(name[7:])
            rec[name] = scene.sh[:, 1 + j % (k - 1), j // (k - 1)]
        elif name.startswith("scale_"):
            rec[name] = scene.log_scales[:, int(name[6:])]
        elif name.startswith("rot_"):
            rec[name] = scene.quats[:, int(name[4:])]
        elif name in ("nx", "ny", "nz"):
            rec[name] = scene.normals[:, "xyz".index(name[1])]
    rec["opacity"] = scene.opacity_logits
    if scene.object_ids is not None:
        rec["object_id"] = scene.object_ids
    return rec


def _write(path: Path, rec: np.ndarray, *, byte_order: str = "<", text: bool = False, extra_first: bool = False) -> Path:
    elements = [PlyElement.describe(rec, "vertex")]
    if extra_first:
        elements.insert(0, PlyElement.describe(np.zeros(2, [("v", "<f4")]), "meta"))
    PlyData(elements, text=text, byte_order=byte_order).write(str(path))
    return path


def test_fast_path_is_taken_on_the_reference_layout(tmp_path, monkeypatch):
    path = write_ply(_scene(50, 3, 0, ids=True, normals=True), tmp_path / "a.ply")
    monkeypatch.setattr(splats._VertexTable, "parsed", classmethod(lambda cls, p: pytest.fail("plyfile path taken")))
    read_ply(path)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(0, 40), degree=st.integers(0, 3), seed=st.integers(0, 10**6), ids=st.booleans(),
       normals=st.booleans(), order=st.sampled_from(["<", ">"]), double_xyz=st.booleans(),
       extra_first=st.booleans())
def test_mapped_equals_plyfile(tmp_path_factory, n, degree, seed, ids, normals, order, double_xyz, extra_first):
    scene = _scene(n, degree, seed, ids=ids, normals=normals)
    types = {c: order + "f8" for c in "xyz"} if double_xyz else {}
    rec = _records(scene, types)
    path = _write(tmp_path_factory.mktemp("p") / "s.ply", rec, byte_order=order, extra_first=extra_first)
    got = read_ply(path)
    ref_table = splats._VertexTable.parsed(path)
    assert ref_table.n == n
    _same(got, scene)   # float64 x/y/z hold float32 values exactly, so both paths give the scene back


def test_ascii_and_fallback_equal(tmp_path):
    scene = _scene(12, 2, 3, ids=True)
    a = _write(tmp_path / "a.ply", _records(scene), text=True)
    b = write_ply(scene, tmp_path / "b.ply")
    _same(read_ply(a), read_ply(b))


def test_mapped_names_non_finite_and_float64_overflow(tmp_path):
    scene = _scene(8, 1, 1)
    rec = _records(scene)
    rec["f_rest_4"][5] = np.nan
    with pytest.raises(SceneError, match=r"f_rest_4\[5\]"):
        read_ply(_write(tmp_path / "nan.ply", rec))
    rec = _records(scene, {"y": "<f8"})
    rec["y"][3] = 1e300
    with pytest.raises(SceneError, match=r"y\[3\]: .*does not fit in float32"):
        read_ply(_write(tmp_path / "big.ply", rec))


def test_extra_uchar_property_needs_ignore_unknown(tmp_path):
    scene = _scene(6, 0, 2)
    base = _records(scene)
    dt = base.dtype.descr + [("red", "u1")]
    rec = np.zeros(6, dt)
    for name in base.dtype.names:
        rec[name] = base[name]
    path = _write(tmp_path / "rgb.ply", rec)
    with pytest.raises(SceneError, match="red"):
        read_ply(path)
    _same(read_ply(path, ignore_unknown=True), scene)


def test_truncated_binary_is_refused(tmp_path):
    path = write_ply(_scene(30, 3, 4), tmp_path / "t.ply")
    data = path.read_bytes()
    path.write_bytes(data[:-100])
    with pytest.raises(SceneError, match="file"):
        read_ply(path)


@pytest.mark.parametrize("prop", ["obj_id", "instance_id", "segment_id"])
def test_other_tools_object_ids_are_read(tmp_path, prop):
    scene = _scene(10, 0, 5, ids=True)
    rec = _records(scene)
    rec = rec.astype([(n if n != "object_id" else prop, t) for n, t in rec.dtype.descr])
    got = read_ply(_write(tmp_path / "ids.ply", rec))
    np.testing.assert_array_equal(got.object_ids, scene.object_ids)
    both = np.zeros(10, rec.dtype.descr + [("object_id", "<i4")])
    for name in rec.dtype.names:
        both[name] = rec[name]
    with pytest.raises(SceneError, match=rf"^object_id: .*beside {prop!r}|^{prop}: .*beside 'object_id'"):
        read_ply(_write(tmp_path / "two.ply", both))
