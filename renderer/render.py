"""The renderer's entry points: splat parameters (or a :class:`SplatScene`) + camera -> image.

``render_gaussians`` = :func:`covariances_from_params` -> :func:`project_gaussians` ->
:func:`sh_to_color` -> :func:`rasterize`, all torch autograd, so gradients flow to means,
log-scales, quaternions, opacity logits and SH coefficients.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np
import torch

from .projection import NEAR_PLANE, Projection, camera_tensors, covariances_from_params, project_gaussians
from .rasterize import rasterize
from .sh import sh_to_color

__all__ = ["RenderOutput", "render_gaussians", "render_scene", "scene_tensors"]


class RenderOutput(NamedTuple):
    """What :func:`render_gaussians` returns.

    Attributes
    ----------
    image : Tensor, shape [H, W, 3]
        RGB including the background (not clamped; clamp to [0, 1] to display or score).
    alpha : Tensor, shape [H, W]
        Accumulated opacity ``1 - T_final``.
    depth : Tensor, shape [H, W]
        ``sum_i w_i z_i`` (camera z in world units, not normalised: divide by ``alpha``).
    weights : Tensor, shape [N], float64
        Blending weight ``sum over pixels of alpha_i T_i`` of each splat (0 when culled); no gradient.
    projection : Projection
        The screen-space splats used (reuse it rather than projecting again).
    """

    image: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    weights: torch.Tensor
    projection: Projection


def render_gaussians(means: torch.Tensor, log_scales: torch.Tensor, quats: torch.Tensor,
                     opacity_logits: torch.Tensor, sh: torch.Tensor, camera, *,
                     background=None, sh_degree: Optional[int] = None,
                     near: float = NEAR_PLANE, backend: str = "auto") -> RenderOutput:
    """Render splats seen by ``camera`` (differentiable).

    Parameters
    ----------
    means : Tensor, shape [N, 3]
        World positions.
    log_scales : Tensor, shape [N, 3]
        Natural log of the standard deviations (world units).
    quats : Tensor, shape [N, 4]
        ``(w, x, y, z)``, normalised here.
    opacity_logits : Tensor, shape [N]
        Opacity before the sigmoid.
    sh : Tensor, shape [N, K, 3]
        SH coefficients, ``K`` in {1, 4, 9, 16}.
    camera : l3gs_opt.scene.cameras.Camera
    background : array_like, shape [3], keyword-only
        Defaults to ``camera.background``.
    sh_degree : int, keyword-only
        Use only degrees ``<= sh_degree`` (default: all of ``K``).
    near : float, keyword-only
        Near plane (camera z).
    backend : {"auto", "torch", "numba"}, keyword-only
        Compositing backend (see :func:`rasterize`): ``"auto"`` uses the compiled numba kernel
        when no gradient is recorded and numba is installed, the torch autograd path otherwise.

    Returns
    -------
    RenderOutput
        In the dtype of ``means`` (float32 or float64).

    Examples
    --------
    >>> out = render_gaussians(means, log_scales, quats, logits, sh, cam)  # doctest: +SKIP
    >>> out.image.sum().backward()                                          # doctest: +SKIP
    """
    dtype, dev = means.dtype, means.device
    covars = covariances_from_params(log_scales, quats)
    proj = project_gaussians(means, covars, camera, near=near)
    _, center = camera_tensors(camera, dtype, dev)
    colors = sh_to_color(sh, means, center, sh_degree)
    bg = torch.tensor(np.array(camera.background if background is None else background, dtype=np.float64),
                      dtype=dtype, device=dev)
    ras = rasterize(proj.means2d, proj.conics, torch.sigmoid(opacity_logits), colors, proj.depths,
                    proj.radii, camera.width, camera.height, bg, backend=backend)
    return RenderOutput(image=ras.image, alpha=ras.alpha, depth=ras.depth, weights=ras.weights,
                        projection=proj)


def scene_tensors(scene, dtype=torch.float32, requires_grad: bool = False) -> dict:
    """The parameters of a :class:`l3gs_opt.scene.splats.SplatScene` as tensors (keys as in
    :func:`render_gaussians`: ``means``, ``log_scales``, ``quats``, ``opacity_logits``, ``sh``)."""
    out = {}
    for k in ("means", "log_scales", "quats", "opacity_logits", "sh"):
        t = torch.tensor(np.asarray(getattr(scene, k)), dtype=dtype)
        out[k] = t.requires_grad_(requires_grad)
    return out


def render_scene(scene, camera, *, background=None, sh_degree: Optional[int] = None,
                 backend: str = "auto") -> RenderOutput:
    """Render a :class:`SplatScene` in float32 without gradients (see :func:`render_gaussians`)."""
    with torch.no_grad():
        return render_gaussians(**scene_tensors(scene), camera=camera, background=background,
                                sh_degree=sh_degree, backend=backend)
