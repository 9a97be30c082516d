"""Procedural scenes (``l3gs_opt.scene.procedural``): deterministic, segmented, and rich enough that
dropping splats visibly hurts SSIM."""

from __future__ import annotations

import numpy as np
import pytest

from l3gs_opt.scene.camera_paths import orbit_path, walk_path
from l3gs_opt.renderer import render_scene, ssim
from l3gs_opt.scene.splats import SceneError
from l3gs_opt.scene.procedural import make_scene


def test_deterministic_and_segmented():
    a = make_scene(4000, objects=4, seed=7)
    b = make_scene(4000, objects=4, seed=7)
    c = make_scene(4000, objects=4, seed=8)
    for k in ("means", "log_scales", "quats", "opacity_logits", "sh", "object_ids"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    assert not np.array_equal(a.means, c.means)
    assert a.num_splats == 4000 and a.sh_degree == 3
    assert set(np.unique(a.object_ids)) == {0, 1, 2, 3, 4}
    # objects are denser than the room: together they hold a large share of the splats
    assert (a.object_ids > 0).mean() > 0.3
    assert make_scene(4000, sh_degree=0).sh.shape == (4000, 1, 3)


def test_room_parts_split_the_room_by_surface_and_keep_the_splats():
    from l3gs_opt.scene.procedural import ROOM_HALF, ROOM_HEIGHT, ROOM_PARTS

    whole = make_scene(4000, objects=3, seed=2)
    parts = make_scene(4000, objects=3, seed=2, room_parts=True)
    for k in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        assert np.array_equal(getattr(whole, k), getattr(parts, k)), k
    room = whole.object_ids == 0
    # the solids keep their order, shifted past the six surfaces
    assert np.array_equal(parts.object_ids[~room], whole.object_ids[~room] + ROOM_PARTS - 1)
    # each surface id holds exactly the room splats on that plane (independent of the sampler's faces)
    m = parts.means[room]
    planes = [m[:, 2] == 0, np.isclose(m[:, 2], ROOM_HEIGHT), m[:, 1] == -ROOM_HALF, m[:, 1] == ROOM_HALF,
              m[:, 0] == -ROOM_HALF, m[:, 0] == ROOM_HALF]
    ids = parts.object_ids[room]
    for face, on_plane in enumerate(planes):
        assert np.all(on_plane[ids == face]) and (ids == face).any()
    assert ids.max() < ROOM_PARTS


def test_view_dependent_colour():
    s = make_scene(3000, seed=1)
    assert np.abs(s.sh[:, 1:4]).max() > 0.1  # degree-1 terms are not zero


def test_dropping_splats_hurts_ssim():
    scene = make_scene(12_000, seed=0)
    cam = orbit_path(4, width=112, height=84)[1]
    full = render_scene(scene, cam).image.clamp(0, 1).numpy()
    rng = np.random.default_rng(0)
    scores = []
    for frac in (0.9, 0.5):
        img = render_scene(scene.subset(rng.uniform(size=scene.num_splats) < frac), cam).image.clamp(0, 1).numpy()
        scores.append(ssim(img, full))
    assert scores[0] > scores[1] and scores[1] < 0.85
    walk = render_scene(scene, walk_path(6, width=64, height=48)[2])
    assert float(walk.alpha.mean()) > 0.95  # inside the room every ray hits a surface


@pytest.mark.parametrize("kw,match", [({"num_splats": 10}, "num_splats"), ({"objects": 0}, "objects"),
                                      ({"sh_degree": 4}, "sh_degree")])
def test_arguments_are_checked(kw, match):
    args = {"num_splats": 2000, **kw}
    with pytest.raises(SceneError, match=match):
        make_scene(args.pop("num_splats"), **args)
