"""Shared fixtures for the renderer, scene I/O and camera tests (random tiny scenes, cameras)."""

from __future__ import annotations

import numpy as np
import torch

from l3gs_opt.scene.cameras import Camera, look_at
from l3gs_opt.scene.splats import SplatScene

PARAM_KEYS = ("means", "log_scales", "quats", "opacity_logits", "sh")


def random_scene(n: int = 40, *, sh_degree: int = 3, seed: int = 0, spread: float = 1.0,
                 log_scale=(-3.0, -1.0), logit=(-1.0, 3.0), object_ids: bool = False,
                 layers: int = 1) -> SplatScene:
    """Random splats around the origin (the cameras below look at it from about 4 m)."""
    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2
    return SplatScene(
        means=rng.normal(0.0, spread, (n, 3)),
        log_scales=rng.uniform(*log_scale, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        opacity_logits=rng.uniform(*logit, n),
        sh=rng.normal(0.0, 0.4, (n, k, 3)),
        object_ids=rng.integers(0, 4, n) if object_ids else None,
        layers=rng.integers(0, layers, n) if layers > 1 else None,
    )


def make_camera(width: int = 37, height: int = 29, *, eye=(0.3, -4.0, 1.2), target=(0.0, 0.0, 0.0),
                f: float | None = None, background=(0.1, 0.2, 0.3), cx=None, cy=None) -> Camera:
    """An off-centre camera (principal point not at the image centre) looking at ``target``."""
    f = float(width) * 1.1 if f is None else f
    return Camera(width=width, height=height, fx=f, fy=f * 1.05,
                  cx=width / 2.0 + 1.3 if cx is None else cx, cy=height / 2.0 - 0.7 if cy is None else cy,
                  world_to_camera=look_at(eye, target), background=background)


def params_of(scene: SplatScene, dtype=torch.float64, requires_grad=False) -> dict:
    """Scene parameters as tensors keyed as in ``render_gaussians``."""
    return {k: torch.tensor(np.array(getattr(scene, k)), dtype=dtype).requires_grad_(requires_grad)
            for k in PARAM_KEYS}


def psnr_db(a, b) -> float:
    """PSNR with peak 1 on raw (unclipped) images; inf when equal."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)
