"""Dense per-pixel torch compositing: every visible splat against every pixel (no tiles, no culling).

Same rules and the same result as :func:`l3gs_opt.renderer.rasterize.rasterize` (the 16 x 16
tile-rectangle rule is applied as a mask), but the work is ``visible splats x pixels``.  It is
the baseline the benchmark's speed-up is measured against, and a second reference in tests.
"""

from __future__ import annotations

import torch

from .projection import TILE_SIZE, tile_rects
from .rasterize import ALPHA_MAX, ALPHA_MIN, T_MIN

__all__ = ["_rasterize_dense"]


def _rasterize_dense(means2d, conics, opacities, colors, depths, radii, width, height, background=None,
                     *, pixels_per_chunk: int = 1024):
    """Returns ``(image [H, W, 3], alpha [H, W], depth [H, W])``; arguments as ``rasterize``."""
    dtype, dev = means2d.dtype, means2d.device
    if background is None:
        background = torch.zeros(3, dtype=dtype, device=dev)
    vis = torch.nonzero(radii > 0).flatten()
    order = vis[torch.sort(depths.detach()[vis], stable=True).indices]
    rect = tile_rects(means2d[order], radii[order], width, height)
    m, con, op = means2d[order], conics[order], opacities[order]
    feats = torch.cat([colors[order], torch.ones_like(depths[order])[:, None], depths[order][:, None]], 1)
    ys, xs = torch.meshgrid(torch.arange(height, device=dev), torch.arange(width, device=dev), indexing="ij")
    xs, ys = xs.flatten(), ys.flatten()
    outs = []
    for p0 in range(0, xs.numel(), pixels_per_chunk):
        x, y = xs[p0:p0 + pixels_per_chunk], ys[p0:p0 + pixels_per_chunk]
        tx, ty = x // TILE_SIZE, y // TILE_SIZE
        cover = ((rect[:, 0:1] <= tx) & (tx < rect[:, 1:2]) & (rect[:, 2:3] <= ty) & (ty < rect[:, 3:4]))
        dx = m[:, 0:1] - (x.to(dtype) + 0.5)
        dy = m[:, 1:2] - (y.to(dtype) + 0.5)
        power = -0.5 * (con[:, 0:1] * dx * dx + con[:, 2:3] * dy * dy) - con[:, 1:2] * dx * dy
        alpha = torch.clamp_max(op[:, None] * torch.exp(power), ALPHA_MAX)
        alpha = torch.where(cover & (power <= 0) & (alpha >= ALPHA_MIN), alpha, torch.zeros_like(alpha))
        log1m = torch.log1p(-alpha).to(torch.float64)
        incl = torch.cumsum(log1m, 0)
        t_before = torch.exp(incl - log1m)
        keep = incl >= torch.log(torch.tensor(T_MIN, dtype=torch.float64))
        w = alpha * torch.where(keep, t_before, torch.zeros_like(t_before)).to(dtype)  # [Nv, Pc]
        outs.append(w.T @ feats)  # [Pc, 5]
    out = torch.cat(outs, 0).reshape(height, width, 5)
    alpha_img = out[..., 3]
    image = out[..., :3] + (1.0 - alpha_img)[..., None] * background.to(dtype)
    return image, alpha_img, out[..., 4]
