"""Bad input to the scene and simulator API (the API sweep's findings A5, A6, B2, B4, C16-C23, D3-D8,
D13-D15, E8): each is refused with the module's own error, one message naming the field, or (A5)
read correctly."""

from __future__ import annotations

import numpy as np
import pytest

from l3gs_opt.errors import L3gsError
from l3gs_opt.scene.cameras import Camera, CameraError, look_at
from l3gs_opt.scene.procedural import make_scene
from l3gs_opt.scene.splats import SceneError, SplatScene, read_ply
from l3gs_opt.simulator.config import SimConfig, SimulationError
from l3gs_opt.simulator.link import Link, LinkError, max_min_shares, split_bytes

_BASE = ("x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
         "rot_0", "rot_1", "rot_2", "rot_3")
_ROW = "0 0 0 0.5 0.5 0.5 0 -2 -2 -2 1 0 0 0"


def _ascii_ply(tmp_path, name: str, extra: list[tuple[str, str]], rows: list[str], count: int | None = None):
    """An ASCII PLY of the reference properties plus ``extra`` ``(type, name)`` properties."""
    props = [("float", p) for p in _BASE] + list(extra)
    head = ["ply", "format ascii 1.0", f"element vertex {len(rows) if count is None else count}"]
    head += [f"property {t} {p}" for t, p in props] + ["end_header"]
    path = tmp_path / name
    path.write_text("\n".join(head + rows) + "\n")
    return path


def _binary_ply(tmp_path, name: str, id_type: str, prop: str, values):
    """A binary little-endian PLY of the reference properties plus one id property of ``id_type``."""
    np_type = {"float": "<f4", "int": "<i4", "double": "<f8"}[id_type]
    rec = np.zeros(len(values), dtype=[(p, "<f4") for p in _BASE] + [(prop, np_type)])
    rec["rot_0"] = 1.0
    rec["scale_0"] = rec["scale_1"] = rec["scale_2"] = -2.0
    rec[prop] = values
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(values)}"]
    head += [f"property float {p}" for p in _BASE] + [f"property {id_type} {prop}", "end_header"]
    path = tmp_path / name
    path.write_bytes(("\n".join(head) + "\n").encode() + rec.tobytes())
    return path


def _scene_kwargs(**over):
    kw = dict(means=[[0.0, 0.0, 0.0]], log_scales=[[0.0, 0.0, 0.0]], quats=[[1.0, 0.0, 0.0, 0.0]],
              opacity_logits=[0.0], sh=np.zeros((1, 1, 3)))
    kw.update(over)
    return kw


def _refused(error, match, fn, *args, **kwargs):
    with pytest.raises(error, match=match) as info:
        fn(*args, **kwargs)
    assert isinstance(info.value, L3gsError) and "\n" not in str(info.value)


# ---------------------------------------------------------------------- A5: float layer / object_id
@pytest.mark.parametrize("prop", ["layer", "object_id", "obj_id"])
@pytest.mark.parametrize("form", ["ascii", "binary", "binary_double"])
def test_float_ids_read_as_the_same_file_with_int_ids(tmp_path, prop, form):
    values = [0, 3, 1]
    if form == "ascii":
        rows = [f"{_ROW} {v}" for v in values]
        as_float = _ascii_ply(tmp_path, "f.ply", [("float", prop)], rows)
        as_int = _ascii_ply(tmp_path, "i.ply", [("int", prop)], rows)
    else:
        as_float = _binary_ply(tmp_path, "f.ply", "double" if form == "binary_double" else "float", prop, values)
        as_int = _binary_ply(tmp_path, "i.ply", "int", prop, values)
    a, b = read_ply(as_float), read_ply(as_int)
    field = "layers" if prop == "layer" else "object_ids"
    assert np.array_equal(getattr(a, field), values) and getattr(a, field).dtype == np.int32
    for name in ("means", "log_scales", "quats", "opacity_logits", "sh", "layers", "object_ids"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None and y is None) or np.array_equal(x, y), name


@pytest.mark.parametrize("prop, value, match", [
    ("layer", "1.5", r"^layer\[1\]: .*1\.5 is not an integer$"),
    ("layer", "-1", r"^layer\[1\]: .*-1: must be >= 0$"),
    ("object_id", "nan", r"^object_id\[1\]: .*nan is not an integer$"),
    ("obj_id", "2.25", r"^obj_id\[1\]: .*2\.25 is not an integer$"),
    ("layer", "1e20", r"^layer\[1\]: .*1e\+20: must fit in int32$"),
])
def test_bad_float_ids_name_the_property_and_row(tmp_path, prop, value, match):
    path = _ascii_ply(tmp_path, "bad.ply", [("float", prop)], [f"{_ROW} 0", f"{_ROW} {value}"])
    _refused(SceneError, match, read_ply, path)


# ---------------------------------------------------------------------- A6 / C18: flags and degrees
@pytest.mark.parametrize("call, match", [
    (lambda: make_scene(1000, objects=1, room_parts="no"), r"^room_parts: 'no': must be true or false$"),
    (lambda: make_scene(1000, objects=1, room_parts=1), r"^room_parts: 1: must be true or false$"),
    (lambda: make_scene(1000, objects=1, sh_degree=True), r"^sh_degree: True: must be an integer in \[0, 3\]$"),
    (lambda: make_scene(1000, objects=1, sh_degree=1.0), r"^sh_degree: 1\.0: must be an integer in \[0, 3\]$"),
    (lambda: make_scene(1000, objects=1).with_sh_degree(True), r"^sh_degree: True: must be an integer in \[0, 3\]$"),
    (lambda: make_scene(1000, objects=1).with_sh_degree(2.0), r"^sh_degree: 2\.0: must be an integer in \[0, 3\]$"),
    (lambda: SimConfig(robust="no"), r"^robust: 'no': must be true or false$"),
    (lambda: SimConfig(fill="no"), r"^fill: 'no': must be true or false$"),
    (lambda: SimConfig(fill=0), r"^fill: 0: must be true or false$"),
])
def test_flags_and_degrees_are_not_read_by_truthiness(call, match):
    _refused(L3gsError, match, call)


def test_valid_flags_and_degrees_still_work():
    assert make_scene(1000, objects=1, room_parts=np.bool_(True), sh_degree=np.int64(1)).num_objects == 7
    assert make_scene(1000, objects=1, sh_degree=0).with_sh_degree(np.int32(2)).sh_degree == 2
    cfg = SimConfig(robust=np.bool_(True), fill=False)
    assert cfg.robust is True and cfg.fill is False


# ---------------------------------------------------------------------- B2: split_bytes parts
@pytest.mark.parametrize("parts", [10**10, 1001, 0, True, 2.0])
def test_split_bytes_parts_is_bounded(parts):
    _refused(LinkError, r"^parts = .*: must be an integer in \[1, 1000\] \(MAX_SUBSTEPS\)$", split_bytes, 10, parts)


# ---------------------------------------------------------------------- B4: SimConfig work sizes
@pytest.mark.parametrize("kw, match", [
    (dict(width=10**9), r"^width: 1000000000 must be a positive integer <= 16384 \(MAX_IMAGE_SIDE\)$"),
    (dict(height=16385), r"^height: 16385 must be .*\(MAX_IMAGE_SIDE\)$"),
    (dict(width=16384, height=16384), r"^width: 16384 x 16384 = .* \(MAX_IMAGE_PIXELS\)$"),
    (dict(horizon=10**18), r"^horizon: 1000000000000000000: must be an integer in \[1, 1000000\] slots"),
    (dict(bandwidth_window=10**18), r"^bandwidth_window: 1000000000000000000: .*\(MAX_TRACE_SAMPLES\)$"),
    (dict(hw_s=1e300), r"^hw_s: 1e\+300: must be at most 1e\+06 seconds \(MAX_HW_S\)$"),
])
def test_simconfig_work_sizes_are_bounded(kw, match):
    _refused(SimulationError, match, SimConfig, **kw)


# ---------------------------------------------------------------------- C16 / D3 / D4: look_at
@pytest.mark.parametrize("args, match", [
    (([0, 0], [1, 0]), r"^look_at: eye: shape \(2,\) must be \[3\]"),
    (("abc", [1, 0, 0]), r"^look_at: eye: 'abc' must be 3 numbers$"),
    ((["0", "1", "2"], [1, 0, 0]), r"^look_at: eye: .* must be 3 numbers$"),
    (([0, 0, 0], [[1, 0], [0]]), r"^look_at: target: .* must be 3 numbers$"),
    (([float("nan"), 0, 0], [1, 0, 0]), r"^look_at: eye\[0\]: nan is not finite$"),
    (([0, 0, 0], [1, 0, 0], [0, float("inf"), 0]), r"^look_at: up\[1\]: inf is not finite$"),
    (([1e200, 0, 0], [-1e200, 0, 0]), r"^look_at: eye: .*must be within \+-1e\+18 world units \(MAX_ABS_MEAN\)$"),
    (([0, 0, 0], [1, 0, 0], [0, 0, 0]), r"^look_at: up: \[0\.0, 0\.0, 0\.0\] must be a non-zero direction$"),
    (([0, 0, 0], [1, 0, 0], [-3, 0, 0]), r"^look_at: up: .* is parallel to the view direction"),
    (([0, 0, 2], [0, 0, 0]), r"^look_at: up: \[0\.0, 0\.0, 1\.0\] is parallel to the view direction"),
])
def test_look_at_refuses_bad_vectors(args, match):
    _refused(CameraError, match, look_at, *args)


def test_look_at_takes_any_up_length():
    ref = look_at([0, 0, 0], [1, 0, 0], [0, 0, 1])
    assert np.allclose(look_at([0, 0, 0], [1, 0, 0], [0, 0, 1e-300]), ref)
    assert np.allclose(look_at([0, 0, 0], [1, 0, 0], [0, 0, 1e300]), ref)


# ---------------------------------------------------------------------- C17 / D13: SplatScene arrays
@pytest.mark.parametrize("field, value, match", [
    ("means", [[0, 0, 0], [1, 1]], r"^means: must be an array of numbers with rows of equal length$"),
    ("means", [[1j, 0, 0]], r"^means: dtype complex128: must hold real numbers$"),
    ("means", [["0", "1", "2"]], r"^means: dtype <U1: must hold real numbers$"),
    ("quats", [[True, False, False, False]], r"^quats: dtype bool: must hold real numbers$"),
    ("sh", np.zeros((1, 1, 3), dtype=object), r"^sh: dtype object: must hold real numbers$"),
    ("normals", [["a", "b", "c"]], r"^normals: dtype <U1: must hold real numbers$"),
    ("layers", [[0], []], r"^layers: must be an array of integers \[N\]$"),
])
def test_splat_arrays_must_hold_real_numbers(field, value, match):
    _refused(SceneError, match, SplatScene, **_scene_kwargs(**{field: value}))


# ---------------------------------------------------------------------- C19: subset
@pytest.mark.parametrize("index, match", [
    ([10**6], r"^index\[0\]: 1000000 is not a row of the scene \(rows 0\.\.999\)$"),
    ([0, -1], r"^index\[1\]: -1 is not a row of the scene"),
    (np.ones(3, bool), r"^index: boolean mask of shape \(3,\): must be \[N\] \(N = 1000\)$"),
    ([0.5], r"^index: \[0\.5\]: must be a boolean mask \[N\], integer rows \[k\] or a slice$"),
    ("a", r"^index: 'a': must be a boolean mask"),
])
def test_subset_refuses_rows_outside_the_scene(index, match):
    _refused(SceneError, match, make_scene(1000, objects=1).subset, index)


def test_subset_still_takes_masks_rows_and_slices():
    scene = make_scene(1000, objects=1)
    assert len(scene.subset(np.arange(10)[::-1])) == 10 and len(scene.subset([])) == 0
    assert len(scene.subset(scene.object_ids == 0)) == int((scene.object_ids == 0).sum())
    assert len(scene.subset(slice(0, 5))) == 5


# ---------------------------------------------------------------------- C20 / C21 / C22: Link
@pytest.mark.parametrize("call, match", [
    (lambda: max_min_shares(10, 5), r"^demands = 5: must be a sequence of integer byte counts$"),
    (lambda: max_min_shares(10, None), r"^demands = None: must be a sequence"),
    (lambda: max_min_shares(10, {3: 5, 1: 5}), r"^demands = \{3: 5, 1: 5\}: must be a sequence"),
    (lambda: Link(5), r"^bandwidth = 5: must be a sequence of integer byte counts$"),
    (lambda: Link("10"), r"^bandwidth = '10': must be a sequence"),
    (lambda: Link([10]).step([([1], 5)]), r"^requests\[0\]: key \[1\] must be hashable"),
    (lambda: Link([10]).step(None), r"^requests = None: must be a sequence of \(key, bytes\) pairs$"),
    (lambda: Link([10]).demand([("a", "x")]), r"^requests\[0\] = 'x': must be an integer number of bytes$"),
    (lambda: Link([10]).demand([("a", -5)]), r"^requests\[0\] = -5: must be > 0 bytes$"),
    (lambda: Link([10]).demand([("a", 2.5)]), r"^requests\[0\] = 2\.5: must be an integer number of bytes$"),
    (lambda: Link([10]).demand([("a", 1), ("a", 2)]), r"^requests\[1\]: key 'a' is requested twice"),
    (lambda: Link([10]).demand([{"a": 1}]), r"^requests\[0\] = \{'a': 1\}: must be a \(key, bytes\) pair$"),
])
def test_link_refuses_malformed_arguments(call, match):
    _refused(LinkError, match, call)


def test_link_demand_counts_valid_requests():
    link = Link(np.array([10, 10]))
    assert link.demand([("a", np.int64(15)), ("b", 3)]) == 18
    link.step([("a", 15)])
    assert link.demand([("b", 3)]) == 8 and max_min_shares(10, (3, 20)) == [3, 7]


# ---------------------------------------------------------------------- C23: huge ints in SimConfig
@pytest.mark.parametrize("field", ["slot_s", "fov_deg", "hw_s", "bandwidth_bias", "decision_s",
                                   "pose_start_s", "sh_upgrade_utility"])   # (time_limit_s: no limit, as solve())
def test_simconfig_huge_int_is_refused_by_name(field):
    _refused(SimulationError, rf"^{field}: 1{'0' * 56}\.\.\.: must be ", SimConfig,   # shown() cuts it to 60
             **{field: 10**400})


# ---------------------------------------------------------------------- D5 / D6: Camera focal lengths
@pytest.mark.parametrize("kw, match", [
    (dict(fx=1e-300, fy=1e-300), r"^fx: 1e-300 pixels gives a 180 degree field of view across the 640 pixel width; "
                                 r"it must be at most 179 \(MAX_FOV_DEG\)$"),
    (dict(fy=2.0), r"^fy: 2 pixels gives a 179\.\d+ degree field of view across the 480 pixel height"),
    (dict(fx="500"), r"^fx: '500' is not a number$"),
    (dict(fx=True), r"^fx: True is not a number$"),
    (dict(cy=np.bool_(False)), r"^cy: .*False_? is not a number$"),
    (dict(cx=[320]), r"^cx: \[320\] is not a number$"),
])
def test_camera_refuses_focal_lengths_that_are_not_numbers_or_too_wide(kw, match):
    base = dict(width=640, height=480, fx=500, fy=500, cx=320, cy=240, world_to_camera=np.eye(4))
    _refused(CameraError, match, Camera, **{**base, **kw})


def test_camera_still_takes_numpy_and_wide_focal_lengths():
    cam = Camera(640, 480, np.float32(500), np.int64(500), 320.0, 240, np.eye(4))
    assert cam.fx == 500.0 and isinstance(cam.fy, float)
    assert Camera(640, 480, 3.0, 3.0, 320, 240, np.eye(4)).tan_half_fov[0] < 107   # about 178.9 degrees


# ---------------------------------------------------------------------- D7 / D8: SimConfig fov and backend
@pytest.mark.parametrize("kw, match", [
    (dict(fov_deg=180), r"^fov_deg: 180 must be in \[1, 170\]$"),
    (dict(fov_deg=720), r"^fov_deg: 720 must be in \[1, 170\]$"),
    (dict(fov_deg=0.5), r"^fov_deg: 0\.5 must be in \[1, 170\]$"),
    (dict(backend="gurobi"), r"^backend: 'gurobi' is not one of cbc, highs, cpsat, scip$"),
    (dict(backend=None), r"^backend: None is not one of "),
    (dict(backend=["highs"]), r"^backend: \['highs'\] is not one of "),
])
def test_simconfig_fov_and_backend_are_checked_at_construction(kw, match):
    _refused(SimulationError, match, SimConfig, **kw)


def test_simconfig_valid_backend_and_fov():
    from l3gs_opt.models import Backend

    assert SimConfig(backend="cbc", fov_deg=170).backend == "cbc"
    assert SimConfig(backend=Backend.SCIP).backend == Backend.SCIP


# ---------------------------------------------------------------------- D14 / D15 / E8: PLY bodies
@pytest.mark.parametrize("case, match", [
    ("partial_normals", r"^ny: .*: missing beside nx \(normals need all of nx, ny, nz\)$"),
    ("two_normals", r"^nz: .*: missing beside nx, ny \(normals need all of nx, ny, nz\)$"),
    ("extra_rows", r"^file: .*: text after the 1 rows the header declares \(line 2 of the body\)"),
    ("short_row", r"^file: .*: header claims 1 'vertex' elements \(rows of 14 values\), more than the 10 characters "
                  r"of text after the header can hold"),
])
def test_ascii_ply_bodies_that_do_not_match_the_header(tmp_path, case, match):
    if case == "partial_normals":
        path = _ascii_ply(tmp_path, "p.ply", [("float", "nx")], [f"{_ROW} 0"])
    elif case == "two_normals":
        path = _ascii_ply(tmp_path, "p.ply", [("float", "nx"), ("float", "ny")], [f"{_ROW} 0 0"])
    elif case == "extra_rows":
        path = _ascii_ply(tmp_path, "p.ply", [], [_ROW, _ROW], count=1)
    else:
        path = _ascii_ply(tmp_path, "p.ply", [], ["0 0 0 0.5"], count=1)
    _refused(SceneError, match, read_ply, path)


def test_ascii_ply_with_trailing_blank_lines_still_reads(tmp_path):
    path = _ascii_ply(tmp_path, "p.ply", [], [_ROW, _ROW, "", "  "], count=2)
    assert len(read_ply(path)) == 2
