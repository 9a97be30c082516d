"""Cameras sampled around or inside a scene (a teacher that comes without its own cameras)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from l3gs_opt.renderer import render_scene
from l3gs_opt.scene.camera_sampling import sample_cameras
from l3gs_opt.scene.cameras import CameraError
from renderer_helpers import random_scene


def _ball(n=400, centre=(1.0, -2.0, 0.5), seed=0):
    s = random_scene(n, sh_degree=0, seed=seed, spread=1.0)
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    pts = np.asarray(centre) + d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0, 1, (n, 1)) ** (1 / 3)
    return dataclasses.replace(s, means=pts.astype(np.float32))


def test_outside_cameras_ring_the_scene_and_see_it():
    scene = _ball()
    cams = sample_cameras(scene, 20, width=32, height=24, distance=2.0)
    centre = np.median(scene.means, axis=0)
    radius = np.quantile(np.linalg.norm(scene.means - centre, axis=1), 0.9)
    for cam in cams:
        eye = cam.center
        assert np.linalg.norm(eye - centre) == pytest.approx(2.0 * radius, rel=1e-6)
        # the centre projects to the principal point: the camera looks at it
        p = cam.world_to_camera @ np.append(centre, 1.0)
        assert p[2] > 0 and abs(cam.fx * p[0] / p[2]) < 1e-6 and abs(cam.fy * p[1] / p[2]) < 1e-6
    dirs = np.stack([c.center - centre for c in cams])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    assert np.abs(dirs.mean(axis=0)).max() < 0.1        # spread over the whole sphere
    img = render_scene(scene, cams[0]).image
    assert float(np.asarray(img).max()) > 0              # the scene is in the picture


def test_inside_cameras_stay_in_the_box_and_far_background_is_ignored():
    scene = _ball(centre=(0, 0, 0))
    far = dataclasses.replace(scene, means=np.concatenate([scene.means[:-20], np.full((20, 3), 1e4, np.float32)]))
    for s in (scene, far):
        cams = sample_cameras(s, 12, mode="inside", width=32, height=24, seed=3)
        eyes = np.stack([c.center for c in cams])
        assert np.abs(eyes).max() < 1.0
        again = sample_cameras(s, 12, mode="inside", width=32, height=24, seed=3)
        np.testing.assert_array_equal(eyes, np.stack([c.center for c in again]))


@pytest.mark.parametrize("kw, field", [(dict(mode="above"), "mode"), (dict(count=0), "count"),
                                       (dict(distance=-1.0), "distance"), (dict(count=True), "count")])
def test_bad_arguments(kw, field):
    with pytest.raises(CameraError, match=rf"^{field}: "):
        sample_cameras(_ball(), **{"count": 4, **kw})


def test_orbit_is_a_smooth_ring_at_the_outside_distance():
    scene = _ball()
    cams = sample_cameras(scene, 24, mode="orbit", width=32, height=24, distance=2.0, up=(0, 0, 1))
    centre = np.median(scene.means, axis=0)
    eyes = np.stack([c.center for c in cams])
    r = np.linalg.norm(eyes - centre, axis=1)
    np.testing.assert_allclose(r, r[0], rtol=1e-9)
    np.testing.assert_allclose(eyes[:, 2] - centre[2], r[0] * np.sin(np.radians(20.0)), rtol=1e-9)
    steps = np.linalg.norm(np.diff(eyes, axis=0), axis=1)
    np.testing.assert_allclose(steps, steps[0], rtol=1e-9)   # evenly spaced: a path, not a lattice


def test_poses_from_cameras_inverts_each_mapping():
    from l3gs_opt.pipeline.scene_instance import Z_UP_MAPPING
    from l3gs_opt.traces.poses import PoseMapping, poses_from_cameras

    cams = sample_cameras(_ball(), 16, width=32, height=24) + sample_cameras(_ball(), 8, mode="orbit", width=32,
                                                                               height=24)
    w2c = np.stack([c.world_to_camera for c in cams])
    for mapping in (PoseMapping(), Z_UP_MAPPING, PoseMapping(scale=2.5, offset=(1.0, -2.0, 0.5))):
        trace = poses_from_cameras(w2c, np.arange(len(cams)) / 10.0, mapping)
        np.testing.assert_allclose(mapping.world_to_camera(trace.position, trace.rotation_deg), w2c, atol=1e-9)
