"""Projection of 3D Gaussians to the screen (EWA splatting), with the standard 3DGS conventions.

One projection serves the rasteriser and the splat-utility code: call
:func:`project_gaussians` once and reuse its :class:`Projection`.

Conventions (reference 3DGS ``forward.cu``, ``preprocessCUDA`` / ``computeCov2D``):

* camera coordinates ``t = R mu + T`` (OpenCV: x right, y down, z forward); splats with
  ``t_z < near`` (0.01) are culled;
* screen mean ``(fx t_x / t_z + cx, fy t_y / t_z + cy)`` in pixels, pixel ``(i, j)`` sampled at
  ``(i + 0.5, j + 0.5)``;
* ``Sigma = R_q S S^T R_q^T`` with ``S = diag(exp(log_scale))`` and ``R_q`` from the normalised
  quaternion ``(w, x, y, z)``;
* ``Sigma_2D = J R Sigma R^T J^T + 0.3 I`` with the perspective Jacobian
  ``J = [[fx/z, 0, -fx x'/z^2], [0, fy/z, -fy y'/z^2]]`` where ``x'/z`` and ``y'/z`` are clamped
  to ``+-1.3 tan(fov/2)`` (``tan(fov_x/2) = W / (2 fx)``);
* radius ``ceil(3 sqrt(lambda_1))``, ``lambda_1 = m + sqrt(max(0.1, m^2 - det))``,
  ``m = (a + c) / 2``; a splat is visible when it is in front of the near plane, ``det > 0`` and
  its square ``mean +- radius`` touches at least one 16 x 16 tile of the image.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

__all__ = ["NEAR_PLANE", "TILE_SIZE", "Projection", "quat_to_rotmat", "covariances_from_params",
           "project_gaussians", "tile_rects", "camera_tensors"]

#: Splats closer than this (camera z, world units) are culled.
NEAR_PLANE = 0.01
#: Tile edge in pixels: a splat is rasterised on every pixel of each 16 x 16 tile its square touches.
TILE_SIZE = 16
#: Added to both diagonal entries of the 2D covariance (low-pass filter, pixels^2).
COV2D_DILATION = 0.3
#: Clamp of x/z and y/z in the Jacobian, as a multiple of tan(fov / 2).
JACOBIAN_CLAMP = 1.3


class Projection(NamedTuple):
    """Screen-space splats; entries of culled splats are finite but meaningless.

    Attributes
    ----------
    means2d : Tensor, shape [N, 2]
        Pixel coordinates (x right, y down) of the projected means.
    covars2d : Tensor, shape [N, 2, 2]
        2D covariances in pixels^2, including the +0.3 dilation.
    conics : Tensor, shape [N, 3]
        Inverse covariance ``(a, b, c)`` = ``[[a, b], [b, c]]``.
    radii : Tensor, shape [N], int64
        Extent in pixels (``ceil(3 sigma_max)``), 0 when culled.
    depths : Tensor, shape [N]
        Camera z (world units).
    visible : Tensor, shape [N], bool
        Not culled (``radii > 0``).
    """

    means2d: torch.Tensor
    covars2d: torch.Tensor
    conics: torch.Tensor
    radii: torch.Tensor
    depths: torch.Tensor
    visible: torch.Tensor


def camera_tensors(camera, dtype=torch.float32, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """``(world_to_camera [4, 4], camera centre [3])`` of a :class:`l3gs_opt.scene.cameras.Camera` as tensors."""
    w2c = torch.tensor(np.array(camera.world_to_camera, dtype=np.float64))
    center = -(w2c[:3, :3].T @ w2c[:3, 3])
    return w2c.to(dtype=dtype, device=device), center.to(dtype=dtype, device=device)


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """Rotation matrices of quaternions ``(w, x, y, z)`` (normalised first).

    Parameters
    ----------
    quats : Tensor, shape [N, 4]

    Returns
    -------
    Tensor, shape [N, 3, 3]
    """
    q = quats / torch.linalg.vector_norm(quats, dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def covariances_from_params(log_scales: torch.Tensor, quats: torch.Tensor) -> torch.Tensor:
    """World covariances ``R S S^T R^T``.

    Parameters
    ----------
    log_scales : Tensor, shape [N, 3]
        Natural log of the standard deviations (world units).
    quats : Tensor, shape [N, 4]
        ``(w, x, y, z)``, need not be normalised.

    Returns
    -------
    Tensor, shape [N, 3, 3]
        World units squared.
    """
    m = quat_to_rotmat(quats) * torch.exp(log_scales)[..., None, :]  # R S
    return m @ m.transpose(-1, -2)


def tile_rects(means2d: torch.Tensor, radii: torch.Tensor, width: int, height: int,
               tile_size: int = TILE_SIZE) -> torch.Tensor:
    """Tiles touched by each splat's square ``mean +- radius`` (reference ``getRect``).

    Parameters
    ----------
    means2d : Tensor, shape [N, 2]
        Pixel coordinates (pixel centres at +0.5).
    radii : Tensor, shape [N]
    width, height : int
        Image size in pixels.

    Returns
    -------
    Tensor, shape [N, 4], int64
        ``(x_min, x_max, y_min, y_max)`` tile indices, max exclusive; empty when min == max.
    """
    gx = (width + tile_size - 1) // tile_size
    gy = (height + tile_size - 1) // tile_size
    p = means2d.detach().to(torch.float64) - 0.5  # the reference works in pixel-centre coordinates
    r = radii.to(torch.float64)
    x0 = torch.floor((p[:, 0] - r) / tile_size).clamp(0, gx)
    x1 = torch.floor((p[:, 0] + r + tile_size - 1) / tile_size).clamp(0, gx)
    y0 = torch.floor((p[:, 1] - r) / tile_size).clamp(0, gy)
    y1 = torch.floor((p[:, 1] + r + tile_size - 1) / tile_size).clamp(0, gy)
    return torch.stack([x0, x1, y0, y1], dim=-1).to(torch.int64)


def project_gaussians(means: torch.Tensor, covars: torch.Tensor, camera, *,
                      near: float = NEAR_PLANE) -> Projection:
    """Project 3D Gaussians into ``camera`` (differentiable w.r.t. ``means`` and ``covars``).

    Parameters
    ----------
    means : Tensor, shape [N, 3]
        World positions.
    covars : Tensor, shape [N, 3, 3]
        World covariances (e.g. from :func:`covariances_from_params`).
    camera : l3gs_opt.scene.cameras.Camera
        Pinhole camera, OpenCV convention.
    near : float, keyword-only
        Near plane (camera z); closer splats are culled.

    Returns
    -------
    Projection
        In the dtype of ``means``.
    """
    dtype = means.dtype
    w2c, _ = camera_tensors(camera, dtype, means.device)
    rot, trans = w2c[:3, :3], w2c[:3, 3]
    t = means @ rot.T + trans
    z = t[:, 2]
    in_front = z >= near
    zs = torch.where(in_front, z, torch.ones_like(z))  # safe divisor for culled splats
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    tan_x, tan_y = camera.tan_half_fov
    lim_x, lim_y = JACOBIAN_CLAMP * tan_x, JACOBIAN_CLAMP * tan_y
    tx = torch.clamp(t[:, 0] / zs, -lim_x, lim_x) * zs
    ty = torch.clamp(t[:, 1] / zs, -lim_y, lim_y) * zs
    zero = torch.zeros_like(zs)
    jac = torch.stack([fx / zs, zero, -fx * tx / (zs * zs),
                       zero, fy / zs, -fy * ty / (zs * zs)], dim=-1).reshape(-1, 2, 3)
    tmat = jac @ rot  # [N, 2, 3]
    cov2d = tmat @ covars @ tmat.transpose(-1, -2)
    cov2d = cov2d + COV2D_DILATION * torch.eye(2, dtype=dtype, device=means.device)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det = a * c - b * b
    ok = in_front & (det > 0)
    det_s = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], dim=-1)
    means2d = torch.stack([fx * t[:, 0] / zs + cx, fy * t[:, 1] / zs + cy], dim=-1)
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam1 = mid + torch.sqrt(torch.clamp_min(mid * mid - det, 0.1))
        radii = torch.ceil(3.0 * torch.sqrt(torch.clamp_min(lam1, 0.0)))
        radii = torch.where(ok & torch.isfinite(radii), radii, torch.zeros_like(radii)).to(torch.int64)
        rect = tile_rects(torch.where(ok[:, None], means2d, torch.zeros_like(means2d)), radii,
                          camera.width, camera.height)
        touches = (rect[:, 1] > rect[:, 0]) & (rect[:, 3] > rect[:, 2])
        visible = ok & (radii > 0) & touches
        radii = torch.where(visible, radii, torch.zeros_like(radii))
    return Projection(means2d=means2d, covars2d=cov2d, conics=conics, radii=radii, depths=z,
                      visible=visible)
