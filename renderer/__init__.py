"""The bundled CPU splat renderer (PyTorch, differentiable), image metrics, procedural scenes and the trainer.

Public API
----------
render_gaussians, render_scene, scene_tensors, RenderOutput
    Splat parameters or a ``SplatScene`` + ``Camera`` -> image, alpha, depth, per-splat weights.
project_gaussians, covariances_from_params, quat_to_rotmat, Projection
    The projection step on its own (reuse one projection for rendering and utilities).
rasterize, Raster
    Compositing of already projected splats: a vectorised torch autograd path and, when numba is
    installed (chosen automatically), compiled per-pixel forward and backward kernels.
eval_sh, sh_to_color
    Spherical-harmonic colour.
psnr, ssim
    Image metrics (scikit-image; LPIPS is not available offline).

Scene and camera I/O live in :mod:`l3gs_opt.scene.splats`, :mod:`l3gs_opt.scene.cameras`,
:mod:`l3gs_opt.scene.procedural` and :mod:`l3gs_opt.scene.camera_paths`.
"""

from ._kernels import HAVE_NUMBA
from .metrics import MetricError, psnr, ssim
from .projection import (NEAR_PLANE, TILE_SIZE, Projection, covariances_from_params, project_gaussians,
                         quat_to_rotmat)
from .rasterize import Raster, rasterize
from .render import RenderOutput, render_gaussians, render_scene, scene_tensors
from .sh import eval_sh, sh_to_color

__all__ = ["render_gaussians", "render_scene", "scene_tensors", "RenderOutput",
           "project_gaussians", "covariances_from_params", "quat_to_rotmat", "Projection",
           "NEAR_PLANE", "TILE_SIZE", "rasterize", "Raster", "eval_sh", "sh_to_color",
           "psnr", "ssim", "MetricError", "HAVE_NUMBA"]

# Trainer (Prune2TargetSize, ProgressiveTraining, significance, densification, SH distillation).
from .densify import densify_and_prune, reset_opacity  # noqa: E402
from .distill import distill_sh  # noqa: E402
from .progressive import SizeError, check_sizes, progressive_training, prune_to_target_size, train_layer  # noqa: E402
from .significance import global_significance, significance_order  # noqa: E402
from .train import (LAMBDA_SSIM, TrainConfig, TrainResult, View, finetune, recovery, scene_extent,  # noqa: E402
                    ssim_torch, teacher_views, train)

__all__ += ["TrainConfig", "TrainResult", "View", "train", "recovery", "finetune", "teacher_views",
            "scene_extent", "ssim_torch", "LAMBDA_SSIM", "global_significance", "significance_order",
            "prune_to_target_size", "progressive_training", "train_layer", "check_sizes", "SizeError",
            "densify_and_prune", "reset_opacity", "distill_sh"]
