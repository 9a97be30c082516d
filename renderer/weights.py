"""Each splat's share of the picture: its alpha-compositing weight summed over the pixels.

For splat i at pixel p the renderer blends ``w_ip = alpha_ip T_ip`` of its colour, with ``T_ip``
the transmittance left by the splats in front (see :mod:`l3gs_opt.renderer.rasterize` for the
rules). Summed over the pixels, ``W_i = sum_p w_ip`` is the part of the picture splat i paints, in
pixels: occlusion and opacity included, and ``sum_i w_ip + T_final(p) = 1`` at every pixel.
:attr:`RenderOutput.weights` already returns it; :func:`splat_weights` computes only it (no
colours, no gradient) and adds two options the renderer has no use for:

* ``held``: the weights a splat would have *if it were added alone to the held splats*: the
  transmittance in front of every splat counts the held splats only (``T_ip = prod over held k in
  front of i of (1 - alpha_kp)``), and the early stop follows the held splats alone. With every
  splat held this is the renderer's weight exactly (same pairs, same order, same arithmetic);
* ``pixel_weight``: a per-pixel factor ``f_p`` (``W_i = sum_p f_p w_ip``), e.g. how far the held
  picture is from the full one at p.

Both run in one compiled pass over the renderer's sorted (splat, sub-tile) pairs when numba is
installed, else in a per-pixel NumPy loop (slow; small scenes and tests only).

For many viewpoints of one scene, prepare it once (:class:`WeightScene`: world covariances and
opacities in float64, camera-independent) and call :func:`scene_weights`: with numba, the
projection too is one compiled pass (the rules of :func:`~l3gs_opt.renderer.projection.project_gaussians`
in float64), then the same pair listing and walk; the tests hold it to the float64 torch renderer.
"""

from __future__ import annotations

import numpy as np
import torch

from dataclasses import dataclass

from ._kernels import HAVE_NUMBA
from .projection import (JACOBIAN_CLAMP, NEAR_PLANE, TILE_SIZE, Projection,
                         covariances_from_params, project_gaussians)
from .rasterize import ALPHA_MAX, ALPHA_MIN, SUBTILE, T_MIN, _pairs

if HAVE_NUMBA:
    import numba

__all__ = ["splat_weights", "projection_weights", "WeightScene", "scene_weights"]


def power_cut(opacity: np.ndarray) -> np.ndarray:
    """Per splat, the Gaussian exponent below which it is skipped at a pixel: ``o exp(power) <
    ALPHA_MIN`` iff ``power < log(ALPHA_MIN / o)``, less a margin of 1e-9 so that the test without
    the exp skips only pixels the exact test skips too (-inf for ``o = 0``: the exact test decides)."""
    o = np.asarray(opacity, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(o > 0.0, np.log(ALPHA_MIN / np.where(o > 0.0, o, 1.0)) - 1e-9, -np.inf)


def _walk_python(sub_start, pair_splat, means2d, conics, opac, held, pix_w, width, height, sub, gsx, out):
    """The kernel's rules, one pixel at a time (the fallback without numba)."""
    for s in range(sub_start.shape[0] - 1):
        p0, p1 = sub_start[s], sub_start[s + 1]
        x0, y0 = (s % gsx) * sub, (s // gsx) * sub
        for py in range(y0, min(y0 + sub, height)):
            for px in range(x0, min(x0 + sub, width)):
                T = 1.0
                f = pix_w[py, px]
                for p in range(p0, p1):
                    i = pair_splat[p]
                    dx, dy = means2d[i, 0] - (px + 0.5), means2d[i, 1] - (py + 0.5)
                    power = -0.5 * (conics[i, 0] * dx * dx + conics[i, 2] * dy * dy) - conics[i, 1] * dx * dy
                    if power > 0.0:
                        continue
                    a = min(ALPHA_MAX, opac[i] * np.exp(power))
                    if a < ALPHA_MIN:
                        continue
                    test_t = T * (1.0 - a)
                    if held[i]:
                        if test_t < T_MIN:
                            break
                        out[i] += f * a * T
                        T = test_t
                    else:
                        out[i] += f * a * T


if HAVE_NUMBA:
    from ._kernels import _falloff, _screen_cov, _screen_radius

    @numba.njit(inline="always")
    def _alpha(means2d, conics, opac, pcut, i, cx, cy):
        """Splat ``i``'s alpha at the pixel centre ``(cx, cy)`` by the renderer's rules, or 0 where the
        renderer skips it (the opacity cut ``pcut`` tried first, without the exp)."""
        _, _, power = _falloff(means2d, conics, i, cx, cy)
        if power > 0.0 or power < pcut[i]:
            return 0.0
        a = opac[i] * np.exp(power)
        if a > ALPHA_MAX:
            a = ALPHA_MAX
        return a if a >= ALPHA_MIN else 0.0


if HAVE_NUMBA:
    @numba.njit(parallel=True, cache=True, fastmath=False)
    def _walk(sub_start, pair_splat, means2d, conics, opac, pcut, held, pix_w, width, height, sub, gsx, pair_w):
        nsub = sub_start.shape[0] - 1
        for s in numba.prange(nsub):
            p0, p1 = sub_start[s], sub_start[s + 1]
            if p1 == p0:
                continue
            x0 = (s % gsx) * sub
            y0 = (s // gsx) * sub
            for ly in range(sub):
                py = y0 + ly
                if py >= height:
                    break
                for lx in range(sub):
                    px = x0 + lx
                    if px >= width:
                        break
                    T = 1.0
                    f = pix_w[py, px]
                    cx = px + 0.5
                    cy = py + 0.5
                    for p in range(p0, p1):
                        i = pair_splat[p]
                        a = _alpha(means2d, conics, opac, pcut, i, cx, cy)
                        if a == 0.0:
                            continue
                        test_t = T * (1.0 - a)
                        if held[i]:
                            if test_t < T_MIN:
                                break
                            pair_w[p] += f * a * T
                            T = test_t
                        else:
                            pair_w[p] += f * a * T


def projection_weights(proj: Projection, opacities: torch.Tensor, width: int, height: int, *,
                       held: np.ndarray | None = None, pixel_weight: np.ndarray | None = None,
                       compiled: bool | None = None) -> np.ndarray:
    """:func:`splat_weights` from a projection already made (float64 [N], pixels).

    ``compiled``: the numba kernel (default when numba is installed) or the Python loop.
    """
    n = proj.means2d.shape[0]
    held_a = np.ones(n, dtype=np.bool_) if held is None else np.asarray(held, dtype=np.bool_)
    if held_a.shape != (n,):
        raise ValueError(f"held: shape {held_a.shape}, expected ({n},)")
    pix = np.ones((height, width)) if pixel_weight is None else np.ascontiguousarray(pixel_weight, np.float64)
    if pix.shape != (height, width):
        raise ValueError(f"pixel_weight: shape {pix.shape}, expected ({height}, {width})")
    splat, key = _pairs(proj.means2d, proj.conics, opacities, proj.depths, proj.radii, width, height, SUBTILE)
    sub = SUBTILE
    gsx, gsy = (width + sub - 1) // sub, (height + sub - 1) // sub
    counts = np.bincount(key.numpy(), minlength=gsx * gsy)
    sub_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    pair_splat = splat.numpy().astype(np.int64)
    f64 = lambda t: np.ascontiguousarray(t.detach().cpu().to(torch.float64).numpy())  # noqa: E731
    args = (f64(proj.means2d), f64(proj.conics), f64(opacities), held_a, pix, width, height, sub, gsx)
    if compiled is None:
        compiled = HAVE_NUMBA
    if compiled:
        if not HAVE_NUMBA:
            raise ValueError("compiled: needs the numba package")
        pair_w = np.zeros(pair_splat.shape[0])
        _walk(sub_start, pair_splat, *args[:3], power_cut(args[2]), *args[3:], pair_w)
        return np.bincount(pair_splat, weights=pair_w, minlength=n)
    out = np.zeros(n)
    _walk_python(sub_start, pair_splat, *args, out)
    return out


def splat_weights(scene, camera, *, held: np.ndarray | None = None, pixel_weight: np.ndarray | None = None,
                  compiled: bool | None = None) -> np.ndarray:
    """Each splat's blending weight summed over the pixels of ``camera``'s picture (float64 [N],
    pixels; 0 when culled).

    Parameters
    ----------
    scene : SplatScene
    camera : Camera
        Its width and height set the picture the weights are counted on.
    held : bool array [N], optional
        Splats the viewer holds; the others are valued as if each were added alone (see the
        module doc). Default: all held (the renderer's weights).
    pixel_weight : float array [H, W], optional
        Per-pixel factor (default 1).
    """
    with torch.no_grad():
        means = torch.tensor(np.asarray(scene.means), dtype=torch.float32)
        covars = covariances_from_params(torch.tensor(np.asarray(scene.log_scales), dtype=torch.float32),
                                         torch.tensor(np.asarray(scene.quats), dtype=torch.float32))
        proj = project_gaussians(means, covars, camera)
        opac = torch.sigmoid(torch.tensor(np.asarray(scene.opacity_logits), dtype=torch.float32))
    return projection_weights(proj, opac, camera.width, camera.height, held=held, pixel_weight=pixel_weight,
                              compiled=compiled)


@dataclass(frozen=True)
class WeightScene:
    """A scene prepared for :func:`scene_weights` (camera-independent, float64).

    ``means [N, 3]`` (world units), ``cov6 [N, 6]`` world covariances ``(xx, xy, xz, yy, yz, zz)``
    (world units squared, from :func:`covariances_from_params` in float64), ``opacity [N]``
    (activated), ``power_cut [N]`` (:func:`power_cut`).
    """

    means: np.ndarray
    cov6: np.ndarray
    opacity: np.ndarray
    power_cut: np.ndarray

    @classmethod
    def from_scene(cls, scene) -> "WeightScene":
        with torch.no_grad():
            cov = covariances_from_params(torch.tensor(np.asarray(scene.log_scales), dtype=torch.float64),
                                          torch.tensor(np.asarray(scene.quats), dtype=torch.float64))
            opac = torch.sigmoid(torch.tensor(np.asarray(scene.opacity_logits), dtype=torch.float64))
        cov6 = np.ascontiguousarray(cov.reshape(-1, 9)[:, [0, 1, 2, 4, 5, 8]].numpy())
        opacity = opac.numpy()
        return cls(np.ascontiguousarray(np.asarray(scene.means, dtype=np.float64)), cov6, opacity, power_cut(opacity))

    @property
    def num_splats(self) -> int:
        return int(self.means.shape[0])


if HAVE_NUMBA:
    @numba.njit(parallel=True, cache=True, fastmath=False)
    def _project(means, cov6, rot, trans, fx, fy, cx, cy, lim_x, lim_y, width, height, sub,
                 means2d, conics, depths, rect):
        """project_gaussians + tile_rects in float64; ``rect[:, i]`` = sub-tile range (x0, x1, y0, y1),
        empty (all 0) when culled (``means2d`` and ``conics`` are then not written)."""
        gx = (width + TILE_SIZE - 1) // TILE_SIZE
        gy = (height + TILE_SIZE - 1) // TILE_SIZE
        gsx = (width + sub - 1) // sub
        gsy = (height + sub - 1) // sub
        f = TILE_SIZE // sub
        for i in numba.prange(means.shape[0]):
            mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
            x = rot[0, 0] * mx + rot[0, 1] * my + rot[0, 2] * mz + trans[0]
            y = rot[1, 0] * mx + rot[1, 1] * my + rot[1, 2] * mz + trans[1]
            z = rot[2, 0] * mx + rot[2, 1] * my + rot[2, 2] * mz + trans[2]
            depths[i] = z
            rect[0, i] = 0
            rect[1, i] = 0
            rect[2, i] = 0
            rect[3, i] = 0
            if not z >= NEAR_PLANE:
                continue
            a, b, _, c = _screen_cov(rot, cov6, i, x, y, z, fx, fy, lim_x, lim_y)
            det = a * c - b * b
            if not det > 0.0:
                continue
            px = fx * x / z + cx
            py = fy * y / z + cy
            means2d[i, 0] = px
            means2d[i, 1] = py
            conics[i, 0] = c / det
            conics[i, 1] = -b / det
            conics[i, 2] = a / det
            r = _screen_radius(a, c, det)
            if not (r > 0.0 and r < np.inf):
                continue
            p0 = px - 0.5
            p1 = py - 0.5
            x0 = min(max(np.floor((p0 - r) / TILE_SIZE), 0.0), gx)
            x1 = min(max(np.floor((p0 + r + TILE_SIZE - 1) / TILE_SIZE), 0.0), gx)
            y0 = min(max(np.floor((p1 - r) / TILE_SIZE), 0.0), gy)
            y1 = min(max(np.floor((p1 + r + TILE_SIZE - 1) / TILE_SIZE), 0.0), gy)
            if x1 > x0 and y1 > y0:
                rect[0, i] = min(int(x0) * f, gsx)
                rect[1, i] = min(int(x1) * f, gsx)
                rect[2, i] = min(int(y0) * f, gsy)
                rect[3, i] = min(int(y1) * f, gsy)


if HAVE_NUMBA:
    @numba.njit(parallel=True, cache=True)
    def _depth_sort_buckets(sub_start, pair_splat, depths):
        """Sort each sub-tile's pairs by depth, stably (in place)."""
        for s in numba.prange(sub_start.shape[0] - 1):
            p0, p1 = sub_start[s], sub_start[s + 1]
            if p1 - p0 < 2:
                continue
            seg = pair_splat[p0:p1].copy()
            perm = np.argsort(depths[seg], kind="mergesort")
            for q in range(p1 - p0):
                pair_splat[p0 + q] = seg[perm[q]]


if HAVE_NUMBA:
    @numba.njit(parallel=True, cache=True, fastmath=False)
    def _walk_prefix(sub_start, pair_splat, means2d, conics, opac, pcut, obj, lay, J, L, width, height, sub, gsx,
                     pair_w):
        """Weights in the picture of "every other object whole, this object up to this splat's layer":
        splat i (object j, layer l) is dimmed by every splat in front except those of object j with a
        layer above l. Log-transmittances: the full product, and per (object, layer)."""
        nsub = sub_start.shape[0] - 1
        log_t_min = np.log(T_MIN)
        for s in numba.prange(nsub):
            p0, p1 = sub_start[s], sub_start[s + 1]
            if p1 == p0:
                continue
            x0 = (s % gsx) * sub
            y0 = (s // gsx) * sub
            logq = np.zeros((J, L))
            for ly in range(sub):
                py = y0 + ly
                if py >= height:
                    break
                for lx in range(sub):
                    px = x0 + lx
                    if px >= width:
                        break
                    logq[:, :] = 0.0
                    log_all = 0.0
                    cx = px + 0.5
                    cy = py + 0.5
                    for p in range(p0, p1):
                        i = pair_splat[p]
                        a = _alpha(means2d, conics, opac, pcut, i, cx, cy)
                        if a == 0.0:
                            continue
                        j = obj[i]
                        li = lay[i]
                        above = 0.0
                        for m in range(li + 1, L):
                            above += logq[j, m]
                        la = np.log1p(-a)
                        # blended in its picture iff the light it leaves stays >= T_MIN (the
                        # renderer's early stop; light only decreases along a picture's splats)
                        if log_all - above + la >= log_t_min:
                            pair_w[p] += a * np.exp(log_all - above)
                        log_all += la
                        logq[j, li] += la
                        if log_all < log_t_min:
                            # stop once no later splat can be seen: even with its object's layers
                            # above 0 taken away, the light left is below T_MIN
                            most = 0.0
                            for jj in range(J):
                                r = 0.0
                                for m in range(1, L):
                                    r += logq[jj, m]
                                if r < most:
                                    most = r
                            if log_all - most < log_t_min:
                                break


def scene_weights(prep: WeightScene, camera, *, held: np.ndarray | None = None,
                  pixel_weight: np.ndarray | None = None, prefix: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> np.ndarray:
    """:func:`splat_weights` of a prepared scene (float64 [N], pixels). With numba: compiled
    projection, pair listing and walk, all float64; without it, the torch projection in float64
    and the Python walk.

    ``prefix=(object, layer)`` (int arrays [N], objects numbered 0..J-1; needs numba; not with
    ``held`` or ``pixel_weight``): each splat's weight in the picture of every other object whole
    and its own object up to its layer (its object's higher layers in front do not dim it)."""
    n, width, height = prep.num_splats, int(camera.width), int(camera.height)
    held_a = np.ones(n, dtype=np.bool_) if held is None else np.asarray(held, dtype=np.bool_)
    if held_a.shape != (n,):
        raise ValueError(f"held: shape {held_a.shape}, expected ({n},)")
    if prefix is not None and (held is not None or pixel_weight is not None or not HAVE_NUMBA):
        raise ValueError("prefix: needs numba, and not with held or pixel_weight")
    if not HAVE_NUMBA:
        with torch.no_grad():
            c = torch.from_numpy(prep.cov6)
            covars = torch.stack([c[:, 0], c[:, 1], c[:, 2], c[:, 1], c[:, 3], c[:, 4], c[:, 2], c[:, 4], c[:, 5]],
                                 dim=-1).reshape(-1, 3, 3)
            proj = project_gaussians(torch.from_numpy(prep.means), covars, camera)
        return projection_weights(proj, torch.from_numpy(prep.opacity), width, height, held=held_a,
                                  pixel_weight=pixel_weight, compiled=False)
    from ._kernels import list_pairs

    pix = np.ones((height, width)) if pixel_weight is None else np.ascontiguousarray(pixel_weight, np.float64)
    if pix.shape != (height, width):
        raise ValueError(f"pixel_weight: shape {pix.shape}, expected ({height}, {width})")
    w2c = np.asarray(camera.world_to_camera, dtype=np.float64)
    tan_x, tan_y = camera.tan_half_fov
    sub = SUBTILE
    gsx, gsy = (width + sub - 1) // sub, (height + sub - 1) // sub
    means2d, conics = np.empty((n, 2)), np.empty((n, 3))
    depths, rect = np.empty(n), np.empty((4, n), np.int64)
    _project(prep.means, prep.cov6, np.ascontiguousarray(w2c[:3, :3]), np.ascontiguousarray(w2c[:3, 3]),
             float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy), JACOBIAN_CLAMP * tan_x,
             JACOBIAN_CLAMP * tan_y, width, height, sub, means2d, conics, depths, rect)
    vis = np.flatnonzero((rect[1] > rect[0]) & (rect[3] > rect[2]))
    r = rect[:, vis]
    # Pairs listed in index order, then sorted by depth inside each sub-tile (stable: ties keep the
    # index order), which is the renderer's global stable depth order restricted to the sub-tile,
    # at the cost of many small sorts in parallel instead of one large one.
    pair_splat, key = list_pairs(vis, means2d, conics, prep.opacity, r[0], r[1], r[2], r[3], width, height, sub,
                                 gsx, gsx * gsy, ALPHA_MIN * (1.0 - 1e-4))
    sub_start = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=gsx * gsy))]).astype(np.int64)
    _depth_sort_buckets(sub_start, pair_splat, depths)
    pair_w = np.zeros(pair_splat.shape[0])
    if prefix is not None:
        obj, lay = (np.ascontiguousarray(a, dtype=np.int64) for a in prefix)
        _walk_prefix(sub_start, pair_splat, means2d, conics, prep.opacity, prep.power_cut, obj, lay,
                     int(obj.max()) + 1 if n else 1, int(lay.max()) + 1 if n else 1, width, height, sub, gsx, pair_w)
        return np.bincount(pair_splat, weights=pair_w, minlength=n)
    _walk(sub_start, pair_splat, means2d, conics, prep.opacity, prep.power_cut, held_a, pix, width, height, sub, gsx,
          pair_w)
    return np.bincount(pair_splat, weights=pair_w, minlength=n)
