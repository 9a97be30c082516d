"""Trainer: loss, SSIM, significance, densification rules, Prune2TargetSize, ProgressiveTraining."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from l3gs_opt.renderer._reference import _render_reference
from l3gs_opt.renderer.densify import (RESET_OPACITY, SPLIT_N, SPLIT_SCALE_DIV, densify_and_prune,
                                       reset_opacity, view_space_grad)
from l3gs_opt.renderer.metrics import ssim
from l3gs_opt.renderer.progressive import (SizeError, check_sizes, progressive_training,
                                           prune_to_target_size)
from l3gs_opt.renderer.significance import global_significance, significance_order
from l3gs_opt.renderer.train import (TrainConfig, View, finetune, recovery, ssim_torch, teacher_views,
                                     train, training_loss)
from renderer_helpers import make_camera, random_scene

TINY = TrainConfig(iterations=2)


def _cams(k: int = 3, w: int = 24, h: int = 20):
    eyes = [(0.3, -4.0, 1.2), (3.5, -1.5, 1.0), (-3.0, -2.5, 0.5), (0.0, 4.0, 1.5)]
    return [make_camera(w, h, eye=eyes[i % len(eyes)]) for i in range(k)]


@pytest.fixture(scope="module")
def tiny():
    scene = random_scene(40, sh_degree=1, seed=3, object_ids=True, log_scale=(-2.5, -1.2), logit=(0.0, 3.0))
    return scene, teacher_views(scene, _cams())


def test_ssim_torch_matches_metric():
    # same window, constants and valid-area mean as skimage: agree to float32 rounding
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 1, (23, 31, 3)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1).astype(np.float32)
    got = float(ssim_torch(torch.tensor(a), torch.tensor(b)))
    assert got == pytest.approx(ssim(a, b), abs=1e-5)
    assert float(ssim_torch(torch.tensor(a), torch.tensor(a))) == pytest.approx(1.0, abs=1e-6)


def test_loss_is_l1_plus_dssim():
    a, b = torch.rand(16, 16, 3), torch.rand(16, 16, 3)
    want = 0.8 * float((a - b).abs().mean()) + 0.2 * (1 - float(ssim_torch(a, b)))
    assert float(training_loss(a, b)) == pytest.approx(want, rel=1e-6)


def test_training_loss_decreases_on_tiny_scene(tiny):
    scene, views = tiny
    rng = np.random.default_rng(1)
    start = dataclasses.replace(scene, means=scene.means + rng.normal(0, 0.05, scene.means.shape),
                                sh=scene.sh + rng.normal(0, 0.3, scene.sh.shape))
    res = train(start, views, config=TrainConfig(iterations=60, lr_means=1.6e-3, lr_means_final=1.6e-4))
    first, last = res.losses[:6].mean(), res.losses[-6:].mean()
    assert last < 0.8 * first, (first, last)
    np.testing.assert_array_equal(res.scene.object_ids, scene.object_ids)


def test_sh_degree_raised_over_time(tiny, monkeypatch):
    import importlib

    # the module, not the ``train`` function the package re-exports under the same name
    train_mod = importlib.import_module("l3gs_opt.renderer.train")

    seen = []
    real = train_mod.render_gaussians
    monkeypatch.setattr(train_mod, "render_gaussians", lambda *a, **k: seen.append(k["sh_degree"]) or real(*a, **k))
    scene, views = tiny
    train(scene, views, config=TrainConfig(iterations=5, sh_degree_start=0, sh_up_every=2))
    assert seen == [0, 0, 1, 1, 1]  # scene degree is 1: capped there


def test_significance_matches_float64_reference():
    scene = random_scene(12, sh_degree=0, seed=5, log_scale=(-2.0, -0.8), logit=(-0.5, 2.5))
    cams = _cams(2, 20, 16)
    weights = np.zeros(scene.num_splats)
    for cam in cams:
        weights += _render_reference(scene.means, scene.log_scales, scene.quats, scene.opacity_logits,
                                     scene.sh, cam)["weights"]
    vol = np.prod(np.exp(scene.log_scales.astype(np.float64)), axis=1)
    ref_v = np.sort(vol)[::-1][int(0.9 * len(vol))]
    want = weights * (vol / ref_v) ** 0.1
    assert (want > 0).sum() >= 6  # the check is not vacuous
    # float64 render path: identical maths, so only summation order differs
    np.testing.assert_allclose(global_significance(scene, cams, dtype=torch.float64), want, rtol=1e-9, atol=1e-12)
    # default float32 render: projection/alpha in float32 (relative error ~1e-6 per weight)
    np.testing.assert_allclose(global_significance(scene, cams), want, rtol=2e-4, atol=1e-6)


def _params(means, log_scales, logits, n_sh=1):
    n = len(means)
    return {"means": torch.tensor(means, dtype=torch.float32),
            "log_scales": torch.tensor(log_scales, dtype=torch.float32),
            "quats": torch.tensor([[1.0, 0, 0, 0]] * n), "opacity_logits": torch.tensor(logits, dtype=torch.float32),
            "sh": torch.arange(n * n_sh * 3, dtype=torch.float32).reshape(n, n_sh, 3)}


def test_densify_rules_hand_made():
    # extent 10, percent_dense 0.01: boundary 0.1 world units
    small, large = np.log(0.05), np.log(0.5)
    p = _params([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]],
                [[small] * 3, [large] * 3, [small] * 3, [large] * 3],
                [2.0, 2.0, 2.0, -8.0])  # splat 3 is near-transparent (opacity 3e-4)
    grad_sum = torch.tensor([3e-4, 6e-4, 1e-4, 0.0], dtype=torch.float64)
    count = torch.tensor([1.0, 2.0, 1.0, 0.0], dtype=torch.float64)  # averages 3e-4, 3e-4, 1e-4, 0
    ids = np.array([7, 8, 9, 10])
    res = densify_and_prune(p, ids, grad_sum, count, grad_threshold=2e-4, extent=10.0,
                            generator=torch.Generator().manual_seed(0))
    assert (res.cloned, res.split, res.pruned) == (1, 1, 1)
    # rows: kept old (0, 2), clone of 0, SPLIT_N children of 1 (3 pruned)
    assert res.source.tolist() == [0, 2, 0] + [1] * SPLIT_N
    assert res.is_new.tolist() == [False, False, True] + [True] * SPLIT_N
    np.testing.assert_array_equal(res.object_ids, [7, 9, 7] + [8] * SPLIT_N)
    np.testing.assert_array_equal(res.params["means"][2], p["means"][0])  # clone: identical
    kids = res.params["log_scales"][3:]
    np.testing.assert_allclose(kids, torch.full((SPLIT_N, 3), large - np.log(SPLIT_SCALE_DIV)), rtol=1e-6)
    np.testing.assert_array_equal(res.params["sh"][3:], p["sh"][[1] * SPLIT_N])
    # children are drawn from the parent's Gaussian: within 5 sigma of its mean, not on it
    off = (res.params["means"][3:] - p["means"][1]).abs()
    assert (off < 5 * 0.5).all() and (off > 0).any()


def test_densify_caps_growth_and_floor():
    p = _params([[i, 0, 0] for i in range(4)], [[np.log(0.05)] * 3] * 4, [2.0, 2.0, -9.0, -9.0])
    g = torch.tensor([1e-3, 5e-4, 0, 0], dtype=torch.float64)
    res = densify_and_prune(p, None, g, torch.ones(4, dtype=torch.float64), grad_threshold=2e-4, extent=10.0,
                            max_new=1, min_splats=4)
    assert res.cloned == 1 and res.source.tolist()[-1] == 0  # the largest gradient wins the one slot
    assert res.params["means"].shape[0] == 4  # 5 rows, 2 transparent, but never fewer than 4
    assert res.object_ids is None


def test_view_space_grad_and_reset():
    g = view_space_grad(torch.tensor([[1.0, 0.0], [0.0, 2.0]]), 200, 100)
    np.testing.assert_allclose(g, [100.0, 100.0])
    logits = torch.tensor([-10.0, 0.0, 5.0])
    out = torch.sigmoid(reset_opacity(logits))
    np.testing.assert_allclose(out, [torch.sigmoid(torch.tensor(-10.0)), RESET_OPACITY, RESET_OPACITY], rtol=1e-5)


def test_recovery_carries_object_ids_through_clone_and_split(tiny):
    scene, views = tiny
    cfg = TrainConfig(iterations=4, densify_from=0, densify_every=2, grad_threshold=0.0, min_opacity=0.0)
    res = recovery(scene, views, config=cfg)
    assert res.scene.num_splats > scene.num_splats  # threshold 0: everything visible densified
    assert res.densify_log and res.densify_log[0]["cloned"] + res.densify_log[0]["split"] > 0
    assert set(np.unique(res.scene.object_ids)) <= set(np.unique(scene.object_ids))


@pytest.mark.parametrize("which", ["1", "n-1", "n"])
def test_prune_to_target_size_exact_counts(tiny, which):
    scene, views = tiny
    n = scene.num_splats
    d = {"1": 1, "n-1": n - 1, "n": n}[which]
    res = prune_to_target_size(scene, d, views, r=0.5, recovery_config=TINY, finetune_config=TINY)
    assert res.scene.num_splats == d
    assert np.all(np.diff(res.significance) <= 0)
    # the stored order is the order of the result's own significance
    np.testing.assert_allclose(global_significance(res.scene, [v.camera for v in views]), res.significance)
    if d == n:
        assert res.rounds == []
        np.testing.assert_array_equal(np.sort(res.scene.means, 0), np.sort(scene.means, 0))
    else:
        assert res.rounds[-1]["action"] == "finetune"
    assert res.scene.object_ids is not None


@pytest.mark.parametrize("sizes, msg", [([0, 5], r"d\[0\]|layers\[0\]: 0 must be > 0"),
                                        ([5, 5], r"layers\[1\]: 5 must be greater"),
                                        ([5, 41], r"layers\[1\]: 41 is more than the 40"),
                                        ([2.5], r"layers\[0\]: 2.5 is not an integer")])
def test_check_sizes_errors(sizes, msg):
    with pytest.raises(SizeError, match=msg):
        check_sizes(sizes, 40)


def test_prune_rejects_bad_target(tiny):
    scene, views = tiny
    with pytest.raises(SizeError, match=r"d\[0\]: 0 must be > 0"):
        prune_to_target_size(scene, 0, views)
    with pytest.raises(SizeError, match=r"^r: "):
        prune_to_target_size(scene, 5, views, r=1.0)


def test_progressive_training_freezes_lower_layers(tiny):
    scene, views = tiny
    order = significance_order(global_significance(scene, [v.camera for v in views]))
    srt = scene.subset(order)
    snaps = {}
    out = progressive_training(srt, [10, 25, 40], views, config=TrainConfig(iterations=6),
                               on_layer=lambda i, s: snaps.__setitem__(i, s))
    assert out.num_splats == 40 and out.layers.tolist() == [0] * 10 + [1] * 15 + [2] * 15
    for key in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        final, base = getattr(out, key), getattr(snaps[0], key)
        assert final[:10].tobytes() == base.tobytes()  # bit-identical after two more layers
        assert final[:25].tobytes() == getattr(snaps[1], key).tobytes()
    # the new layers were trained (not a no-op), and layer 1 alone was trained too
    assert not np.array_equal(out.means[25:], srt.means[25:])
    assert not np.array_equal(snaps[0].means, srt.means[:10])
    np.testing.assert_array_equal(out.object_ids, srt.object_ids)


def test_frozen_argument_checked(tiny):
    scene, views = tiny
    with pytest.raises(ValueError, match=r"frozen: 41 must be in \[0, 40\]"):
        finetune(scene, views, frozen=41)
    with pytest.raises(ValueError, match="views"):
        train(scene, [])
    assert isinstance(views[0], View)
