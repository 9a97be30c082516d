"""Splat utilities (``l3gs_opt.pipeline.utilities``) and the weights behind them
(``l3gs_opt.renderer.weights``), held to identities and to independent computations:

* the per-pixel float64 reference renderer (``renderer/_reference.py``) and the gradient of the
  summed image with respect to each splat's colour (torch autograd), which is exactly its weight;
* ``sum_i w_i + sum_p T_final(p) = W H`` against the torch compositing path's alpha;
* no overlap: a splat's weight equals its weight alone; occluded splats get ~0;
* held-aware weights: all held = the renderer's; none held = each splat alone; monotone in the
  held set (property test);
* the counterfactual gain of a chunk equals a direct render difference.

Tolerance: ``F64_ATOL`` (1e-9 pixels) between float64 computations that differ only in summation
order.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from l3gs_opt.pipeline import utilities as U
from l3gs_opt.renderer import project_gaussians, covariances_from_params, rasterize, render_gaussians, render_scene
from l3gs_opt.renderer._reference import _render_reference
from l3gs_opt.renderer.weights import WeightScene, projection_weights, scene_weights, splat_weights
from l3gs_opt.renderer.metrics import ssim
from l3gs_opt.scene.splats import SplatScene
from renderer_helpers import make_camera, params_of, random_scene

F64_ATOL = 1e-9


def _weights_by_gradient(scene: SplatScene, camera) -> np.ndarray:
    """d(sum of the red channel over the picture) / d(red colour of splat i) = sum_p alpha_i T_i."""
    p = params_of(scene, dtype=torch.float64)
    covars = covariances_from_params(p["log_scales"], p["quats"])
    proj = project_gaussians(p["means"], covars, camera)
    colors = torch.zeros(len(scene.means), 3, dtype=torch.float64, requires_grad=True)
    ras = rasterize(proj.means2d, proj.conics, torch.sigmoid(p["opacity_logits"]), colors, proj.depths,
                    proj.radii, camera.width, camera.height, backend="torch")
    ras.image[..., 0].sum().backward()
    return colors.grad[:, 0].numpy()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_weights_equal_gradient_and_reference(seed):
    scene = random_scene(60, seed=seed, sh_degree=0)
    cam = make_camera(41, 33)
    fast = scene_weights(WeightScene.from_scene(scene), cam)
    grad = _weights_by_gradient(scene, cam)
    ref = _render_reference(scene.means, scene.log_scales, scene.quats, scene.opacity_logits, scene.sh, cam)["weights"]
    assert np.abs(fast - grad).max() < F64_ATOL
    assert np.abs(fast - ref).max() < F64_ATOL
    assert fast.sum() > 1.0   # the scene is in view


def test_weights_plus_final_transmittance_fill_every_pixel():
    scene = random_scene(80, seed=3, sh_degree=0)
    cam = make_camera(48, 40)
    w = scene_weights(WeightScene.from_scene(scene), cam)
    with torch.no_grad():
        out = render_gaussians(**params_of(scene), camera=cam, backend="torch")
    transmittance = (1.0 - out.alpha.numpy()).sum()
    assert w.sum() + transmittance == pytest.approx(cam.width * cam.height, abs=1e-6)


def test_same_weights_as_the_renderer_float32():
    scene = random_scene(120, seed=4)
    cam = make_camera(64, 48)
    assert np.array_equal(splat_weights(scene, cam), render_scene(scene, cam).weights.numpy())


def _separate_splats() -> SplatScene:
    """Four small splats far apart on the picture (no pixel sees two)."""
    xs = [(-1.2, 0.0), (1.2, 0.0), (0.0, 0.9), (0.0, -0.9)]
    n = len(xs)
    return SplatScene(means=np.array([[x, 0.0, z] for x, z in xs]), log_scales=np.full((n, 3), -3.0),
                      quats=np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), opacity_logits=np.full(n, 2.0),
                      sh=np.zeros((n, 1, 3)))


def test_no_overlap_weight_is_own_coverage():
    scene = _separate_splats()
    cam = make_camera(64, 48, eye=(0.0, -4.0, 0.0))
    w = scene_weights(WeightScene.from_scene(scene), cam)
    for i in range(len(scene.means)):
        alone = scene_weights(WeightScene.from_scene(scene.subset([i])), cam)[0]
        assert w[i] == pytest.approx(alone, abs=F64_ATOL) and alone > 0.5


def test_occluded_splat_gets_almost_nothing():
    # a small splat straight behind two large, nearly opaque ones (alpha is clamped at 0.99, so
    # one occluder leaves 1% of the light; two leave none: compositing stops)
    scene = SplatScene(means=np.array([[0.0, -0.5, 0.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                       log_scales=np.array([[-1.0, -1.0, -1.0], [-1.0, -1.0, -1.0], [-3.0, -3.0, -3.0]]),
                       quats=np.tile([1.0, 0.0, 0.0, 0.0], (3, 1)), opacity_logits=np.array([8.0, 8.0, 8.0]),
                       sh=np.zeros((3, 1, 3)))
    cam = make_camera(64, 48, eye=(0.0, -4.0, 0.0))
    w = scene_weights(WeightScene.from_scene(scene), cam)
    alone = scene_weights(WeightScene.from_scene(scene.subset([2])), cam)[0]
    assert alone > 1.0 and w[2] < 1e-3 * alone


def test_held_all_is_visibility_and_held_none_is_each_alone():
    scene = random_scene(40, seed=5, sh_degree=0)
    cam = make_camera(40, 30)
    prep = WeightScene.from_scene(scene)
    n = len(scene.means)
    assert np.array_equal(scene_weights(prep, cam, held=np.ones(n, bool)), scene_weights(prep, cam))
    none = scene_weights(prep, cam, held=np.zeros(n, bool))
    for i in range(0, n, 7):
        assert none[i] == pytest.approx(scene_weights(WeightScene.from_scene(scene.subset([i])), cam)[0],
                                        abs=F64_ATOL)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), share=st.floats(0.0, 1.0))
def test_held_aware_weights_shrink_as_more_is_held(seed, share):
    """Holding more splats only adds occluders: every weight shrinks or stays; the compiled walk
    equals the Python one."""
    scene = random_scene(30, seed=seed, sh_degree=0)
    cam = make_camera(24, 20)
    rng = np.random.default_rng(seed)
    more = rng.random(30) < share
    fewer = more & (rng.random(30) < 0.5)
    prep = WeightScene.from_scene(scene)
    w_fewer, w_more = scene_weights(prep, cam, held=fewer), scene_weights(prep, cam, held=more)
    assert np.all(w_fewer >= w_more - F64_ATOL)
    with torch.no_grad():
        p = params_of(scene)
        proj = project_gaussians(p["means"], covariances_from_params(p["log_scales"], p["quats"]), cam)
        opac = torch.sigmoid(p["opacity_logits"])
    python = projection_weights(proj, opac, cam.width, cam.height, held=more, compiled=False)
    assert np.abs(python - w_more).max() < F64_ATOL


def test_pixel_weight_scales_each_pixel():
    scene = random_scene(30, seed=6, sh_degree=0)
    cam = make_camera(32, 24)
    prep = WeightScene.from_scene(scene)
    assert np.allclose(scene_weights(prep, cam, pixel_weight=np.full((24, 32), 0.25)),
                       0.25 * scene_weights(prep, cam), atol=F64_ATOL)
    with pytest.raises(ValueError, match="pixel_weight"):
        scene_weights(prep, cam, pixel_weight=np.ones((3, 3)))


# -- the utilities ---------------------------------------------------------------------------------

def test_eq1_is_the_splat_utility():
    from l3gs_opt.pipeline.splat_utility import splat_utility

    scene = random_scene(50, seed=7)
    cams = [make_camera(40, 30), make_camera(40, 30, eye=(2.0, -3.0, 1.0))]
    u = U.get_utility("eq1")
    got = u.splat_values(u.prepare(scene), cams)
    assert np.allclose(got, np.mean([splat_utility(scene, c) for c in cams], axis=0), rtol=1e-12, atol=0)


def test_visibility_counts_in_camera_pixels_at_any_scale():
    scene = random_scene(200, seed=8, sh_degree=0, log_scale=(-2.0, -1.0))
    cam = make_camera(96, 72)
    full = U.VisibilityUtility(scale=1.0)
    half = U.VisibilityUtility(scale=0.5)
    a = full.splat_values(full.prepare(scene), [cam])
    b = half.splat_values(half.prepare(scene), [cam])
    assert a.sum() <= cam.width * cam.height + 1e-6
    assert b.sum() == pytest.approx(a.sum(), rel=0.1)   # the same picture, counted coarser
    assert np.array_equal(a, scene_weights(WeightScene.from_scene(scene), cam))


def test_chunk_values_sum_splat_values():
    scene = random_scene(60, seed=9, sh_degree=0)
    cam = make_camera(40, 30)
    u = U.get_utility("visibility")
    prep = u.prepare(scene)
    chunks = [np.arange(0, 20), np.arange(20, 60), np.array([], dtype=np.int64)]
    v = u.splat_values(prep, [cam])
    assert np.allclose(u.chunk_values(prep, [cam], chunks), [v[:20].sum(), v[20:].sum(), 0.0], atol=F64_ATOL)


def test_coverage_is_zero_when_all_is_held_and_visibility_held_when_nothing_is():
    scene = random_scene(40, seed=10, sh_degree=0)
    cam = make_camera(40, 30, background=(0.0, 0.0, 0.0))
    cov = U.get_utility("coverage")
    prep = cov.prepare(scene)
    n = len(scene.means)
    assert np.abs(cov.splat_values(prep, [cam], held=np.ones(n, bool))).max() < 1e-6
    assert cov.splat_values(prep, [cam], held=np.zeros(n, bool)).sum() > 0


def test_counterfactual_gain_is_a_render_difference():
    scene = random_scene(50, seed=11, sh_degree=0, log_scale=(-2.0, -1.0))
    cam = make_camera(48, 36)
    cf = U.CounterfactualUtility(scale=1.0)
    prep = cf.prepare(scene)
    held = np.zeros(50, bool)
    held[:20] = True
    chunks = [np.arange(20, 35), np.arange(35, 50), np.arange(0, 10)]
    gains = U.chunk_gains(prep, [cam], chunks, held=held, scale=1.0)

    def picture(rows):
        return np.clip(render_scene(scene.subset(rows), cam).image.numpy().astype(np.float64), 0, 1)

    full = picture(np.arange(50))
    base = ssim(picture(np.arange(20)), full)
    for k, rows in enumerate(chunks[:2]):
        want = ssim(picture(np.union1d(np.arange(20), rows)), full) - base
        assert gains["ssim"][k] == pytest.approx(want, abs=1e-12)
    assert gains["ssim"][2] == 0.0   # already held: adds nothing
    assert np.array_equal(cf.chunk_values(prep, [cam], chunks, held=held), np.maximum(gains["ssim"], 0.0))


def test_register_a_function_and_a_class():
    def brightest(scene, camera):
        return np.abs(scene.sh[:, 0, :]).sum(axis=1)

    U.register_utility("test-brightest", brightest, unit="sh")
    try:
        u = U.get_utility("test-brightest")
        scene = random_scene(10, seed=12)
        assert np.allclose(u.splat_values(u.prepare(scene), [make_camera()]), brightest(scene, None))
        assert "test-brightest" in U.utility_names() and u.describe() == {"name": "test-brightest", "unit": "sh"}
        with pytest.raises(U.UtilityNameError, match="already registered"):
            U.register_utility("test-brightest", brightest)
    finally:
        U._REGISTRY.pop("test-brightest", None)

    class Flat(U.SplatUtility):
        unit = "splats"

        def splat_values(self, prepared, cameras, *, held=None):
            return np.ones(len(prepared.means))

    U.register_utility("test-flat", Flat)
    try:
        assert U.get_utility("test-flat").name == "test-flat"
    finally:
        U._REGISTRY.pop("test-flat", None)


@pytest.mark.parametrize("bad", ["nope", "", None, 3])
def test_unknown_utility_names(bad):
    with pytest.raises(U.UtilityNameError, match="utility"):
        U.get_utility(bad)


def test_a_bad_user_function_is_named():
    U.register_utility("test-bad", lambda scene, camera: -np.ones(len(scene.means)))
    try:
        u = U.get_utility("test-bad")
        with pytest.raises(ValueError, match="^utility: 'test-bad' returned"):
            u.splat_values(random_scene(5), [make_camera()])
    finally:
        U._REGISTRY.pop("test-bad", None)


def test_prefix_weights_are_those_of_the_picture_a_layer_arrives_into():
    """visibility-prefix: a splat of object j, layer l weighs what it weighs in a render of every
    other object whole and j's layers <= l (checked by those renders); one layer: visibility."""
    scene = random_scene(90, seed=13, sh_degree=0, object_ids=True, layers=3)
    cam = make_camera(40, 30)
    prep = WeightScene.from_scene(scene)
    obj = np.unique(scene.object_ids, return_inverse=True)[1].astype(np.int64)
    lay = scene.layers.astype(np.int64)
    got = scene_weights(prep, cam, prefix=(obj, lay))
    for j in range(obj.max() + 1):
        for l in range(3):
            rows = np.flatnonzero((obj != j) | (lay <= l))
            direct = np.zeros(len(obj))
            direct[rows] = scene_weights(WeightScene.from_scene(scene.subset(rows)), cam)
            mine = (obj == j) & (lay == l)
            assert np.abs(direct[mine] - got[mine]).max() < F64_ATOL
    flat = scene_weights(prep, cam, prefix=(obj, np.zeros(len(obj), np.int64)))
    assert np.abs(flat - scene_weights(prep, cam)).max() < F64_ATOL
    u = U.PrefixVisibilityUtility(scale=1.0)
    assert np.array_equal(u.splat_values(u.prepare(scene), [cam]), got)
    with pytest.raises(ValueError, match="prefix"):
        scene_weights(prep, cam, prefix=(obj, lay), held=np.ones(len(obj), bool))
