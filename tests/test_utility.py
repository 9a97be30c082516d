"""The splat utility (Eq. 1) against a plain float64 per-splat loop; object sums; tables."""

from __future__ import annotations

import math

import numpy as np
import pytest

from l3gs_opt.camera_paths import orbit_path
from l3gs_opt.cameras import Camera
from l3gs_opt.scene_io import SplatScene
from l3gs_opt.scene_make import make_scene
from l3gs_opt.utility import (UtilityError, UtilityScene, build_utility_table, object_layer_utility,
                              splat_utility)


def reference_utility(scene: SplatScene, cam: Camera, floor: float = 0.01) -> np.ndarray:
    """Eq. 1 written plainly from the 3DGS conventions, one splat at a time, float64."""
    R, T = cam.world_to_camera[:3, :3], cam.world_to_camera[:3, 3]
    tanx, tany = cam.width / (2 * cam.fx), cam.height / (2 * cam.fy)
    out = np.zeros(scene.num_splats)
    for i in range(scene.num_splats):
        mu = scene.means[i].astype(np.float64)
        t = R @ mu + T
        if t[2] < 0.01:
            continue
        w, x, y, z = scene.quats[i].astype(np.float64) / np.linalg.norm(scene.quats[i].astype(np.float64))
        Rq = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                       [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                       [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        S = np.diag(np.exp(scene.log_scales[i].astype(np.float64)))
        Sigma = Rq @ S @ S.T @ Rq.T
        tx = min(max(t[0] / t[2], -1.3 * tanx), 1.3 * tanx) * t[2]
        ty = min(max(t[1] / t[2], -1.3 * tany), 1.3 * tany) * t[2]
        J = np.array([[cam.fx / t[2], 0, -cam.fx * tx / t[2] ** 2], [0, cam.fy / t[2], -cam.fy * ty / t[2] ** 2]])
        C = J @ R @ Sigma @ R.T @ J.T + 0.3 * np.eye(2)
        det = np.linalg.det(C)
        if det <= 0:
            continue
        m = (C[0, 0] + C[1, 1]) / 2
        lam = m + math.sqrt(max(0.1, m * m - det))
        r = math.ceil(3 * math.sqrt(lam))
        px, py = cam.fx * t[0] / t[2] + cam.cx, cam.fy * t[1] / t[2] + cam.cy
        # The rasteriser's cull (reference getRect, pixel-centre coordinates, C int truncation):
        # a splat whose square touches no 16x16 tile is never drawn, so it is worth nothing.
        gx, gy = (cam.width + 15) // 16, (cam.height + 15) // 16
        x0, x1 = (min(gx, max(0, int((px - 0.5 + k) / 16))) for k in (-r, r + 15))
        y0, y1 = (min(gy, max(0, int((py - 0.5 + k) / 16))) for k in (-r, r + 15))
        if (x1 - x0) * (y1 - y0) == 0:
            continue
        wx = max(0.0, min(px + r, cam.width) - max(px - r, 0.0))
        wy = max(0.0, min(py + r, cam.height) - max(py - r, 0.0))
        dist = max(np.linalg.norm(mu - cam.center), floor)
        opacity = 1 / (1 + math.exp(-float(scene.opacity_logits[i])))
        out[i] = wx * wy / dist * opacity
    return out


@pytest.fixture(scope="module")
def scene():
    return make_scene(3000, objects=4, sh_degree=1, seed=3)


@pytest.fixture(scope="module")
def cams():
    return orbit_path(4, width=160, height=120)


def test_matches_plain_float64_loop(scene, cams):
    for cam in cams[:2]:
        fast64 = splat_utility(scene, cam, dtype=__import__("torch").float64)
        ref = reference_utility(scene, cam)
        # Radii are ceil()'d: a float64 projection must agree exactly up to round-off.
        np.testing.assert_allclose(fast64, ref, rtol=1e-9, atol=1e-12)
        fast32 = splat_utility(scene, cam)
        # float32 can move a radius across an integer (ceil) for a handful of splats.
        assert np.mean(np.isclose(fast32, ref, rtol=1e-4)) > 0.99
        assert fast32.sum() == pytest.approx(ref.sum(), rel=1e-2)


def test_prepared_scene_gives_the_same_utilities(scene, cams):
    import torch

    prepared = UtilityScene.from_scene(scene)
    for cam in cams:
        np.testing.assert_array_equal(splat_utility(prepared, cam), splat_utility(scene, cam))
        np.testing.assert_array_equal(object_layer_utility(prepared, cam), object_layer_utility(scene, cam))
    with pytest.raises(UtilityError, match="prepared in torch.float32"):
        splat_utility(prepared, cams[0], dtype=torch.float64)


def test_culled_and_offscreen_splats_have_zero_utility(cams):
    cam = cams[0]
    forward = cam.world_to_camera[2, :3]
    c = cam.center
    means = np.stack([c - 2 * forward, c + 3 * forward, c + 3 * forward + 1000 * cam.world_to_camera[0, :3]])
    s = SplatScene(means=means, log_scales=np.full((3, 3), -2.0), quats=np.tile([1.0, 0, 0, 0], (3, 1)),
                   opacity_logits=np.zeros(3), sh=np.zeros((3, 1, 3)))
    u = splat_utility(s, cam)
    assert u[0] == 0.0 and u[2] == 0.0 and u[1] > 0
    assert u[1] == pytest.approx(reference_utility(s, cam)[1], rel=1e-5)


def test_object_layer_sums_and_options(scene, cams):
    cam = cams[1]
    per = splat_utility(scene, cam)
    table = object_layer_utility(scene, cam)
    assert table.shape == (scene.num_objects, 1)
    assert table.sum() == pytest.approx(per.sum(), rel=1e-9)
    for j in range(scene.num_objects):
        assert table[j, 0] == pytest.approx(per[scene.object_ids == j].sum(), rel=1e-9)
    ell = splat_utility(scene, cam, area="ellipse")
    on = per > 0
    # An ellipse inscribed in its 3-sigma square is smaller than the square.
    assert (ell[on] <= per[on] * 1.0001).all() and ell.sum() > 0
    with pytest.raises(UtilityError, match="area 'disc'"):
        splat_utility(scene, cam, area="disc")


def test_table_lookup_at_grid_points_is_exact_and_sparse(scene):
    positions = np.array([[0.0, 0.0, 1.5], [1.0, 0.5, 1.5]])
    table = build_utility_table(scene, positions, yaw_steps=6, pitches_deg=(0.0,), width=80, height=60)
    assert table.values.shape == (12, scene.num_objects)
    assert table.values.nnz < table.values.shape[0] * table.values.shape[1]  # some objects out of view
    cam = table.camera(1, 2)
    np.testing.assert_allclose(table.lookup(cam), object_layer_utility(scene, cam), rtol=1e-12)
    assert table.nearest(cam) == (1, 2)


def test_table_interpolates_between_grid_positions(scene):
    positions = np.array([[0.0, 0.0, 1.5], [1.0, 0.0, 1.5], [5.0, 5.0, 1.5]])
    table = build_utility_table(scene, positions, yaw_steps=4, pitches_deg=(0.0,), width=80, height=60)
    at_grid = table.camera(1, 3)
    np.testing.assert_allclose(table.lookup(at_grid, neighbours=3), table.lookup(at_grid), rtol=0, atol=0)
    # Halfway between the first two positions, same orientation: the plain mean of their entries.
    m = at_grid.world_to_camera.copy()
    rot = m[:3, :3]
    m[:3, 3] = -rot @ np.array([0.5, 0.0, 1.5])
    mid = at_grid.replace(world_to_camera=m)
    expect = (table.values[0 * 4 + 3].toarray() + table.values[1 * 4 + 3].toarray())[0] / 2
    np.testing.assert_allclose(table.lookup(mid, neighbours=2).ravel(), expect, rtol=1e-12)
    with pytest.raises(UtilityError, match="neighbours = 4"):
        table.lookup(mid, neighbours=4)
