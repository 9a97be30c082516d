"""SplatScene validation and PLY I/O (reference 3DGS layout)."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from l3gs_opt.errors import L3gsError
from l3gs_opt.scene.splats import SceneError, SplatScene, bytes_per_splat, read_ply, write_ply
from renderer_helpers import random_scene


def _props(path):
    return [p.name for p in PlyData.read(str(path))["vertex"].properties]


def _assert_same(a: SplatScene, b: SplatScene):
    for k in ("means", "log_scales", "quats", "opacity_logits", "sh", "object_ids", "layers", "normals"):
        x, y = getattr(a, k), getattr(b, k)
        assert (x is None) == (y is None), k
        if x is not None:
            assert x.dtype == y.dtype and np.array_equal(x, y), k


@pytest.mark.parametrize("sh_degree", [0, 1, 2, 3])
@pytest.mark.parametrize("segmented,layers", [(False, 1), (True, 3)])
def test_round_trip_bit_exact(tmp_path, sh_degree, segmented, layers):
    scene = random_scene(50, sh_degree=sh_degree, seed=sh_degree, object_ids=segmented, layers=layers)
    p1 = write_ply(scene, tmp_path / "a.ply")
    back = read_ply(p1)
    _assert_same(scene, back)
    p2 = write_ply(back, tmp_path / "b.ply")
    assert p1.read_bytes() == p2.read_bytes()


def test_writer_keeps_only_what_the_scene_has(tmp_path):
    plain = random_scene(10, sh_degree=0)
    names = _props(write_ply(plain, tmp_path / "p.ply"))
    assert names == ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                     "rot_0", "rot_1", "rot_2", "rot_3"]
    full = random_scene(10, sh_degree=3, object_ids=True, layers=2)
    names = _props(write_ply(full, tmp_path / "f.ply"))
    assert names[:6] == ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert names[6:51] == [f"f_rest_{i}" for i in range(45)]
    assert names[-2:] == ["object_id", "layer"]
    assert (tmp_path / "p.ply").stat().st_size < (tmp_path / "f.ply").stat().st_size
    assert bytes_per_splat(0) == 56 and bytes_per_splat(3) == 236


def _reference_style_ply(path, n=7, k=16, seed=0, drop=(), extra=()):
    """A file laid out exactly as the reference 3DGS ``save_ply`` writes it (with zero normals)."""
    rng = np.random.default_rng(seed)
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    names = [n_ for n_ in names if n_ not in drop] + list(extra)
    rec = np.empty(n, dtype=[(n_, "f4") for n_ in names])
    for n_ in names:
        rec[n_] = rng.normal(size=n).astype(np.float32)
    for n_ in ("nx", "ny", "nz"):
        if n_ in names:
            rec[n_] = 0.0
    PlyData([PlyElement.describe(rec, "vertex")]).write(str(path))
    return rec


def test_reads_reference_layout_with_normals_and_channel_major_rest(tmp_path):
    rec = _reference_style_ply(tmp_path / "r.ply")
    s = read_ply(tmp_path / "r.ply")
    assert s.sh_degree == 3 and s.normals is not None and s.object_ids is None and s.layers is None
    # f_rest is channel-major: f_rest_0..14 = red coefficients 1..15, 15..29 green, 30..44 blue
    assert s.sh[3, 1, 0] == rec["f_rest_0"][3] and s.sh[3, 15, 0] == rec["f_rest_14"][3]
    assert s.sh[3, 1, 1] == rec["f_rest_15"][3] and s.sh[3, 2, 2] == rec["f_rest_31"][3]
    assert s.sh[3, 0, 2] == rec["f_dc_2"][3]
    assert np.array_equal(s.quats[:, 0], rec["rot_0"])
    write_ply(s, tmp_path / "again.ply")
    assert (tmp_path / "again.ply").read_bytes() == (tmp_path / "r.ply").read_bytes()


def test_reads_file_without_normals(tmp_path):
    _reference_style_ply(tmp_path / "r.ply", k=4, drop=("nx", "ny", "nz"))
    s = read_ply(tmp_path / "r.ply")
    assert s.normals is None and s.sh_degree == 1


def test_missing_property_is_named(tmp_path):
    _reference_style_ply(tmp_path / "r.ply", k=1, drop=("scale_1",))
    with pytest.raises(SceneError, match="^scale_1: .*missing vertex property"):
        read_ply(tmp_path / "r.ply")


def test_gap_in_f_rest_is_named(tmp_path):
    _reference_style_ply(tmp_path / "r.ply", k=4, drop=("f_rest_4",))
    with pytest.raises(SceneError, match="^f_rest_4: "):
        read_ply(tmp_path / "r.ply")


def test_unknown_property_is_an_error_unless_ignored(tmp_path):
    _reference_style_ply(tmp_path / "r.ply", k=1, extra=("red",))
    with pytest.raises(SceneError, match="^red: .*unknown vertex property"):
        read_ply(tmp_path / "r.ply")
    assert read_ply(tmp_path / "r.ply", ignore_unknown=True).num_splats == 7


def test_nan_is_named_with_index(tmp_path):
    scene = random_scene(5, sh_degree=0)
    write_ply(scene, tmp_path / "s.ply")
    data = PlyData.read(str(tmp_path / "s.ply"))
    data["vertex"]["opacity"][3] = np.nan
    data.write(str(tmp_path / "nan.ply"))
    with pytest.raises(SceneError, match=r"^opacity\[3\]: .*nan is not finite"):
        read_ply(tmp_path / "nan.ply")


def test_truncated_and_garbage_files(tmp_path):
    write_ply(random_scene(50), tmp_path / "s.ply")
    raw = (tmp_path / "s.ply").read_bytes()
    (tmp_path / "trunc.ply").write_bytes(raw[: len(raw) // 2])
    (tmp_path / "junk.ply").write_bytes(b"this is not a ply file\n" * 10)
    for name in ("trunc.ply", "junk.ply", "missing.ply"):
        with pytest.raises(SceneError, match="^file: ") as info:
            read_ply(tmp_path / name)
        assert isinstance(info.value, L3gsError) and isinstance(info.value, ValueError)


@pytest.mark.parametrize("field,value,match", [
    ("means", np.zeros((3, 2)), r"^means: shape \(3, 2\)"),
    ("log_scales", np.zeros((2, 3)), r"^log_scales: shape"),
    ("sh", np.zeros((3, 5, 3)), r"^sh: 5 coefficients"),
    ("opacity_logits", np.array([0.0, np.inf, 0.0]), r"^opacity_logits\[1\]: inf is not finite"),
    ("quats", np.array([[1.0, 0, 0, 0], [0, 0, 0, 0], [1, 0, 0, 0]]), r"^quats\[1\]: zero quaternion"),
    ("object_ids", np.array([0, -1, 2]), r"^object_ids\[1\]: -1: must be >= 0"),
    ("layers", np.array([0.0, 1.5, 0.0]), r"^layers\[1\]: 1.5 is not an integer"),
])
def test_validation_names_field_and_index(field, value, match):
    kw = dict(means=np.zeros((3, 3)), log_scales=np.zeros((3, 3)), quats=np.tile([1.0, 0, 0, 0], (3, 1)),
              opacity_logits=np.zeros(3), sh=np.zeros((3, 1, 3)))
    kw[field] = value
    with pytest.raises(SceneError, match=match):
        SplatScene(**kw)


def test_scene_is_immutable_and_single_layer_is_canonical():
    s = random_scene(6, sh_degree=1)
    with pytest.raises(ValueError):
        s.means[0, 0] = 1.0
    s2 = SplatScene(means=s.means, log_scales=s.log_scales, quats=s.quats, opacity_logits=s.opacity_logits,
                    sh=s.sh, layers=np.zeros(6, int))
    assert s2.layers is None and s2.num_layers == 1
    assert s.with_sh_degree(0).sh.shape == (6, 1, 3) and s.with_sh_degree(3).sh.shape == (6, 16, 3)
    assert s.subset(np.arange(6) < 2).num_splats == 2
