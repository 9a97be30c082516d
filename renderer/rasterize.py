"""Tile-based, vectorised front-to-back alpha compositing of projected splats (torch, CPU).

Rules (reference 3DGS ``renderCUDA``), per pixel ``p`` with centre ``(i + 0.5, j + 0.5)``:

* candidates: every visible splat whose 16 x 16 tile rectangle (:func:`tile_rects`) contains
  the pixel's tile, in increasing camera depth (ties: splat index);
* ``alpha_i = min(0.99, o_i exp(-0.5 d^T Sigma_i^-1 d))``, ``d = mean_i - p``; splats with
  ``alpha_i < 1/255`` are skipped;
* with ``T_i = prod_{k < i} (1 - alpha_k)`` over the splats not skipped, compositing stops
  at the first splat with ``T_i (1 - alpha_i) < 1e-4`` (that splat is not blended);
* ``C = sum_i alpha_i T_i c_i + T_final * background``, ``A = 1 - T_final``,
  ``D = sum_i alpha_i T_i z_i``.

How it is vectorised: every (splat, 8 x 8 sub-tile) pair inside the splat's tile rectangle is
listed; pairs whose best possible alpha over the sub-tile is below 1/255 are dropped (an exact
cull: the bound ``o exp(-0.5 lambda_min(conic) dist^2)`` never under-estimates alpha, so only
pixels that would be skipped anyway are dropped).  Pairs are sorted by (sub-tile, depth) and
evaluated in chunks as a [pairs, 64] array; the per-pixel transmittance is a segmented
cumulative sum of ``log(1 - alpha)`` (float64), and the early stop is the mask
``T_i (1 - alpha_i) >= 1e-4`` (transmittance only decreases, so this keeps exactly the prefix
the sequential loop blends).  Everything is torch autograd, so the result is differentiable
with respect to means2d, conics, opacities, colours and depths.

When numba is installed, ``backend="auto"`` instead runs the compiled kernels of
:mod:`l3gs_opt.renderer._kernels` on the same sorted pair list (per pixel, sequential, with the
early stop, and an analytic backward wrapped in a ``torch.autograd.Function``); they are
several times faster on two cores and agree with the torch path to float64 rounding.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch

from .projection import TILE_SIZE, tile_rects

__all__ = ["ALPHA_MIN", "ALPHA_MAX", "T_MIN", "SUBTILE", "Raster", "rasterize"]

#: Splats with alpha below this at a pixel are skipped there.
ALPHA_MIN = 1.0 / 255.0
#: Alpha is clamped to this from above.
ALPHA_MAX = 0.99
#: Compositing stops before the transmittance drops below this.
T_MIN = 1e-4
LOG_T_MIN = float(torch.log(torch.tensor(T_MIN, dtype=torch.float64)))
#: Edge of the sub-tiles used as the unit of work (divides TILE_SIZE).
SUBTILE = 8
#: Elements of one [pairs, SUBTILE^2] chunk; bounds the working memory (about 40 bytes each).
CHUNK_ELEMENTS = 1 << 21


class Raster(NamedTuple):
    """Rasteriser output.

    Attributes
    ----------
    image : Tensor, shape [H, W, 3]
        Composited colour including ``T_final * background`` (not clamped).
    alpha : Tensor, shape [H, W]
        ``1 - T_final``.
    depth : Tensor, shape [H, W]
        ``sum_i alpha_i T_i z_i`` (camera z, world units; divide by ``alpha`` for the mean depth).
    weights : Tensor, shape [N], float64, no gradient
        Per splat, ``sum over pixels of alpha_i T_i`` (its blending weight summed over the image).
    num_pairs : int
        (splat, sub-tile) pairs evaluated (a work measure).
    """

    image: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    weights: torch.Tensor
    num_pairs: int


def _pairs(means2d, conics, opacities, depths, radii, width, height, sub):
    """Sorted (splat, sub-tile) pairs: returns (splat index [P], sub-tile id [P]) sorted by (tile, depth)."""
    dev = means2d.device
    vis = torch.nonzero(radii > 0).flatten()
    if vis.numel() == 0:
        empty = torch.zeros(0, dtype=torch.int64, device=dev)
        return empty, empty
    order = vis[torch.sort(depths.detach()[vis], stable=True).indices]
    f = TILE_SIZE // sub
    gsx, gsy = (width + sub - 1) // sub, (height + sub - 1) // sub
    rect = tile_rects(means2d[order], radii[order], width, height)
    sx0 = (rect[:, 0] * f).clamp(max=gsx)
    sx1 = (rect[:, 1] * f).clamp(max=gsx)
    sy0 = (rect[:, 2] * f).clamp(max=gsy)
    sy1 = (rect[:, 3] * f).clamp(max=gsy)
    from . import _kernels

    if _kernels.HAVE_NUMBA:  # same list, two passes and a counting sort in compiled code
        f64 = lambda t: t.detach().cpu().to(torch.float64).numpy()  # noqa: E731
        s, k = _kernels.list_pairs(order.cpu().numpy(), f64(means2d), f64(conics), f64(opacities),
                                   sx0.numpy(), sx1.numpy(), sy0.numpy(), sy1.numpy(), width, height, sub,
                                   gsx, gsx * gsy, ALPHA_MIN * (1.0 - 1e-4))
        return torch.from_numpy(s).to(dev), torch.from_numpy(k).to(dev)
    wid = sx1 - sx0
    counts = wid * (sy1 - sy0)
    total = int(counts.sum())
    ps = torch.repeat_interleave(torch.arange(order.numel(), device=dev), counts)
    start = torch.cumsum(counts, 0) - counts
    local = torch.arange(total, device=dev) - start[ps]
    px = sx0[ps] + local % wid[ps]
    py = sy0[ps] + local // wid[ps]
    # exact cull: best alpha over the sub-tile's pixel centres is below ALPHA_MIN
    m = means2d.detach()[order].to(torch.float64)[ps]
    con = conics.detach()[order].to(torch.float64)[ps]
    x_lo = px * sub + 0.5
    x_hi = torch.clamp(px * sub + sub, max=width) - 0.5
    y_lo = py * sub + 0.5
    y_hi = torch.clamp(py * sub + sub, max=height) - 0.5
    dx = torch.clamp_min(torch.maximum(x_lo - m[:, 0], m[:, 0] - x_hi), 0.0)
    dy = torch.clamp_min(torch.maximum(y_lo - m[:, 1], m[:, 1] - y_hi), 0.0)
    half_tr = 0.5 * (con[:, 0] + con[:, 2])
    det = con[:, 0] * con[:, 2] - con[:, 1] ** 2
    lam_min = det / (half_tr + torch.sqrt(torch.clamp_min(half_tr ** 2 - det, 0.0)))
    lam_min = torch.clamp_min(lam_min, 0.0) * (1.0 - 1e-6)
    op = opacities.detach()[order].to(torch.float64)[ps]
    keep = op * torch.exp(-0.5 * lam_min * (dx * dx + dy * dy)) >= ALPHA_MIN * (1.0 - 1e-4)
    ps, px, py = ps[keep], px[keep], py[keep]
    key = py * gsx + px
    key, perm = torch.sort(key, stable=True)
    return order[ps[perm]], key


def rasterize(means2d: torch.Tensor, conics: torch.Tensor, opacities: torch.Tensor,
              colors: torch.Tensor, depths: torch.Tensor, radii: torch.Tensor,
              width: int, height: int, background: torch.Tensor | None = None, *,
              chunk_elements: int = CHUNK_ELEMENTS, backend: str = "auto") -> Raster:
    """Composite projected splats front to back into an image (differentiable).

    Parameters
    ----------
    means2d : Tensor, shape [N, 2]
        Pixel coordinates of the means (pixel centres at +0.5).
    conics : Tensor, shape [N, 3]
        Inverse 2D covariances ``(a, b, c)``, pixels^-2.
    opacities : Tensor, shape [N]
        In [0, 1] (after the sigmoid).
    colors : Tensor, shape [N, 3]
        Per-splat RGB (after SH evaluation).
    depths : Tensor, shape [N]
        Camera z, world units (sort key and depth output).
    radii : Tensor, shape [N], int
        Pixel extent; 0 = culled.
    width, height : int
        Image size in pixels.
    background : Tensor, shape [3], optional
        Background colour (default black).
    chunk_elements : int, keyword-only
        Working-set size per chunk (memory/speed trade-off only; the result does not depend on it).
    backend : {"auto", "torch", "numba"}, keyword-only
        ``"torch"``: the vectorised autograd path.  ``"numba"``: the compiled per-pixel kernels of
        :mod:`l3gs_opt.renderer._kernels` (sequential front to back with the early stop, and the
        reference rasteriser's analytic backward; needs numba).  ``"auto"`` (default): numba when
        it is installed, else torch.

    Returns
    -------
    Raster
    """
    dtype, dev = means2d.dtype, means2d.device
    n = means2d.shape[0]
    if backend not in ("auto", "torch", "numba"):
        raise ValueError(f"backend: {backend!r} must be 'auto', 'torch' or 'numba'")
    from . import _kernels

    if backend == "numba" and not _kernels.HAVE_NUMBA:
        raise ValueError("backend: 'numba' needs the numba package (pip install numba)")
    use_numba = backend == "numba" or (backend == "auto" and _kernels.HAVE_NUMBA)
    if background is None:
        background = torch.zeros(3, dtype=dtype, device=dev)
    sub = SUBTILE
    npx = sub * sub
    gsx, gsy = (width + sub - 1) // sub, (height + sub - 1) // sub
    nsub = gsx * gsy
    splat, key = _pairs(means2d, conics, opacities, depths, radii, width, height, sub)
    if use_numba:
        return _rasterize_numba(splat, key, means2d, conics, opacities, colors, depths, width, height,
                                background, nsub, gsx, gsy)
    weights = torch.zeros(n, dtype=torch.float64, device=dev)
    pairs_per_sub = torch.bincount(key, minlength=nsub)
    sub_end = torch.cumsum(pairs_per_sub, 0)
    lxc = (torch.arange(npx, device=dev) % sub).to(dtype) + 0.5
    lyc = (torch.arange(npx, device=dev) // sub).to(dtype) + 0.5
    ragged = width % sub != 0 or height % sub != 0
    feats_all = torch.cat([colors, torch.ones_like(depths)[:, None], depths[:, None]], dim=1)  # [N, 5]
    outs = []
    max_pairs = max(1, chunk_elements // npx)
    s0 = 0
    sub_end_l = sub_end.tolist()
    while s0 < nsub:
        p0 = sub_end_l[s0 - 1] if s0 else 0
        # largest s1 with pairs in [s0, s1) <= max_pairs (at least one sub-tile)
        s1 = int(torch.searchsorted(sub_end, p0 + max_pairs, right=True))
        s1 = min(max(s1, s0 + 1), nsub)
        p1 = sub_end_l[s1 - 1]
        out = torch.zeros(s1 - s0, npx, 5, dtype=dtype, device=dev)
        if p1 > p0:
            sid = splat[p0:p1]
            k = key[p0:p1]
            seg = k - s0
            tx, ty = k % gsx, k // gsx
            xc = (tx * sub).to(dtype)[:, None] + lxc  # [P, 64] pixel-centre coordinates
            yc = (ty * sub).to(dtype)[:, None] + lyc
            m = means2d[sid]
            dx = m[:, 0:1] - xc
            dy = m[:, 1:2] - yc
            con = conics[sid]
            power = (-0.5 * (con[:, 0:1] * dx * dx + con[:, 2:3] * dy * dy)
                     - con[:, 1:2] * dx * dy)
            alpha = torch.clamp_max(opacities[sid][:, None] * torch.exp(power), ALPHA_MAX)
            ok = (power <= 0) & (alpha >= ALPHA_MIN)
            if ragged:  # edge sub-tiles reach past the image
                ok &= (xc < width) & (yc < height)
            alpha = alpha * ok
            log1m = torch.log1p(-alpha).to(torch.float64)
            incl = torch.cumsum(log1m, dim=0)
            # first row of each segment (seg is sorted); empty segments are never looked up
            first = torch.searchsorted(seg, torch.arange(s1 - s0, device=dev)).clamp_max(seg.numel() - 1)
            base = (incl[first] - log1m[first])[seg]  # log T before the segment's first pair
            log_t_after = incl - base
            # T_before = T_after / (1 - alpha); differences are small, so float32 is enough from here
            t_before = torch.exp((log_t_after - log1m).to(dtype))
            w = alpha * t_before * (log_t_after >= LOG_T_MIN)
            out = out.index_add(0, seg, w[:, :, None] * feats_all[sid][:, None, :])
            weights.index_add_(0, sid, w.detach().to(torch.float64).sum(1))
        outs.append(out)
        s0 = s1
    grid = torch.cat(outs, 0).reshape(gsy, gsx, sub, sub, 5).permute(0, 2, 1, 3, 4)
    grid = grid.reshape(gsy * sub, gsx * sub, 5)[:height, :width]
    alpha_img = grid[..., 3]
    image = grid[..., :3] + (1.0 - alpha_img)[..., None] * background.to(dtype)
    return Raster(image=image, alpha=alpha_img, depth=grid[..., 4], weights=weights,
                  num_pairs=int(splat.numel()))



class _NumbaComposite(torch.autograd.Function):
    """Compositing by the numba kernels, with the analytic backward of the reference rasteriser."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, sub_start, pair_splat, width, height, gsx):
        from ._kernels import composite_forward

        f64 = lambda t: t.detach().cpu().to(torch.float64).numpy()  # noqa: E731
        arrays = (f64(means2d), f64(conics), f64(opacities), f64(feats))
        out, pair_w = composite_forward(sub_start, pair_splat, *arrays, width, height, SUBTILE, gsx,
                                        ALPHA_MIN, ALPHA_MAX, T_MIN)
        ctx.arrays = arrays
        ctx.meta = (sub_start, pair_splat, width, height, gsx)
        out_t = torch.from_numpy(out).to(dtype=means2d.dtype, device=means2d.device)
        pw = torch.from_numpy(pair_w)
        ctx.mark_non_differentiable(pw)
        return out_t, pw

    @staticmethod
    def backward(ctx, grad_out, _grad_pw):
        from ._kernels import composite_backward

        sub_start, pair_splat, width, height, gsx = ctx.meta
        means2d, conics, opac, feats = ctx.arrays
        g = composite_backward(sub_start, pair_splat, means2d, conics, opac, feats, width, height, SUBTILE, gsx,
                               ALPHA_MIN, ALPHA_MAX, T_MIN, grad_out.detach().cpu().to(torch.float64).numpy())
        idx = torch.from_numpy(pair_splat)
        dtype, dev = grad_out.dtype, grad_out.device
        outs = []
        for per_pair, n_cols in zip(g, (2, 3, None, feats.shape[1])):
            shape = (means2d.shape[0],) if n_cols is None else (means2d.shape[0], n_cols)
            acc = torch.zeros(shape, dtype=torch.float64).index_add_(0, idx, torch.from_numpy(per_pair))
            outs.append(acc.to(dtype=dtype, device=dev))
        return (*outs, None, None, None, None, None)


def _rasterize_numba(splat, key, means2d, conics, opacities, colors, depths, width, height, background,
                     nsub, gsx, gsy) -> Raster:
    """Compositing with the numba kernels (float64 inside, output in the input dtype)."""
    dtype, dev = means2d.dtype, means2d.device
    sub = SUBTILE
    n = means2d.shape[0]
    counts = torch.bincount(key, minlength=nsub)
    sub_start = torch.cat([torch.zeros(1, dtype=torch.int64), torch.cumsum(counts, 0)]).numpy()
    pair_splat = splat.cpu().numpy()
    feats = torch.cat([colors, torch.ones_like(depths)[:, None], depths[:, None]], 1)
    out, pair_w = _NumbaComposite.apply(means2d, conics, opacities, feats, sub_start, pair_splat,
                                        width, height, gsx)
    weights = torch.from_numpy(np.bincount(pair_splat, weights=pair_w.numpy(), minlength=n)).to(dev)
    grid = out.reshape(gsy, gsx, sub, sub, 5).permute(0, 2, 1, 3, 4)
    grid = grid.reshape(gsy * sub, gsx * sub, 5)[:height, :width]
    alpha_img = grid[..., 3]
    image = grid[..., :3] + (1.0 - alpha_img)[..., None] * background.to(dtype)
    return Raster(image=image, alpha=alpha_img, depth=grid[..., 4], weights=weights,
                  num_pairs=int(splat.numel()))
