"""Optional numba kernels for compositing (forward, and the analytic backward) and the per-splat
screen maths that every numba kernel here and in the utility pipeline shares.

Same rules as the vectorised torch path in :mod:`l3gs_opt.renderer.rasterize` and the same
(splat, sub-tile) pair list, but each pixel walks its sorted pairs sequentially, stopping at the
transmittance threshold as the reference CUDA kernel does, so the work is proportional to what
is actually blended.  The backward walks the blended pairs back to front, recovering
``T_i = T_{i+1} / (1 - alpha_i)`` and the suffix sums, as the reference ``renderCUDA`` backward
does; gradients are accumulated per (splat, sub-tile) pair (one thread per sub-tile, so no
races) and summed per splat in torch.  Arithmetic is float64 throughout.  Used automatically
(``backend="auto"``) when numba is installed; the pure torch path remains the fallback and the
independent check (tests compare both against the per-pixel reference and each other).
"""

from __future__ import annotations

import numpy as np

from .projection import COV2D_DILATION

try:  # numba is optional
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised when numba is absent
    numba = None
    HAVE_NUMBA = False

__all__ = ["HAVE_NUMBA", "composite_forward"]

#: Candidate (splat, sub-tile) cells up to which the pair listing culls in one pass over a buffer of
#: all of them (8 bytes each: 128 MB); above, it counts first and stores the survivors only.
SINGLE_PASS_CELLS = 1 << 24

if HAVE_NUMBA:
    @numba.njit(inline="always")
    def _falloff(means2d, conics, i, cx, cy):
        """Offset from splat ``i``'s centre to the pixel centre and the Gaussian exponent there."""
        dx = means2d[i, 0] - cx
        dy = means2d[i, 1] - cy
        return dx, dy, -0.5 * (conics[i, 0] * dx * dx + conics[i, 2] * dy * dy) - conics[i, 1] * dx * dy

    @numba.njit(inline="always")
    def _screen_cov(rot, cov6, i, x, y, z, fx, fy, lim_x, lim_y):
        """Splat ``i``'s 2-D covariance in pixels (EWA: ``J R Sigma R^T J^T``, ``J`` at the centre
        clamped to the view as the reference does, plus :data:`COV2D_DILATION` on the diagonal) from
        its camera-space centre ``(x, y, z)``: ``(a, b, b10, c)`` with ``b10`` the lower-left entry
        formed as torch forms it (``b`` up to rounding). Float64, in the torch path's order."""
        tx = min(max(x / z, -lim_x), lim_x) * z
        ty = min(max(y / z, -lim_y), lim_y) * z
        j00 = fx / z
        j02 = -fx * tx / (z * z)
        j11 = fy / z
        j12 = -fy * ty / (z * z)
        # T = J R (J's zero entries add nothing), then T Sigma T^T as (T Sigma) T^T.
        t00 = j00 * rot[0, 0] + j02 * rot[2, 0]
        t01 = j00 * rot[0, 1] + j02 * rot[2, 1]
        t02 = j00 * rot[0, 2] + j02 * rot[2, 2]
        t10 = j11 * rot[1, 0] + j12 * rot[2, 0]
        t11 = j11 * rot[1, 1] + j12 * rot[2, 1]
        t12 = j11 * rot[1, 2] + j12 * rot[2, 2]
        sxx, sxy, sxz, syy, syz, szz = cov6[i, 0], cov6[i, 1], cov6[i, 2], cov6[i, 3], cov6[i, 4], cov6[i, 5]
        u0 = t00 * sxx + t01 * sxy + t02 * sxz
        u1 = t00 * sxy + t01 * syy + t02 * syz
        u2 = t00 * sxz + t01 * syz + t02 * szz
        v0 = t10 * sxx + t11 * sxy + t12 * sxz
        v1 = t10 * sxy + t11 * syy + t12 * syz
        v2 = t10 * sxz + t11 * syz + t12 * szz
        a = u0 * t00 + u1 * t01 + u2 * t02 + COV2D_DILATION
        b = u0 * t10 + u1 * t11 + u2 * t12
        b10 = v0 * t00 + v1 * t01 + v2 * t02
        c = v0 * t10 + v1 * t11 + v2 * t12 + COV2D_DILATION
        return a, b, b10, c

    @numba.njit(inline="always")
    def _screen_radius(a, c, det):
        """The splat's pixel radius: 3 sigma of the larger eigenvalue, rounded up (the reference's
        ``ceil(3 sqrt(lambda_1))``, with its 0.1 floor under the discriminant)."""
        mid = 0.5 * (a + c)
        lam1 = mid + np.sqrt(max(mid * mid - det, 0.1))
        return np.ceil(3.0 * np.sqrt(max(lam1, 0.0)))

if HAVE_NUMBA:
    @numba.njit(parallel=True, cache=True, fastmath=False)
    def _composite(sub_start, pair_splat, means2d, conics, opac, feats, width, height, sub, gsx,
                   alpha_min, alpha_max, t_min, out, pair_w):
        nsub = sub_start.shape[0] - 1
        nf = feats.shape[1]
        for s in numba.prange(nsub):
            p0, p1 = sub_start[s], sub_start[s + 1]
            if p1 == p0:
                continue
            x0 = (s % gsx) * sub
            y0 = (s // gsx) * sub
            acc = np.zeros(nf)
            for ly in range(sub):
                py = y0 + ly
                if py >= height:
                    break
                for lx in range(sub):
                    px = x0 + lx
                    if px >= width:
                        break
                    T = 1.0
                    acc[:] = 0.0
                    cx = px + 0.5
                    cy = py + 0.5
                    for p in range(p0, p1):
                        i = pair_splat[p]
                        dx, dy, power = _falloff(means2d, conics, i, cx, cy)
                        if power > 0.0:
                            continue
                        a = opac[i] * np.exp(power)
                        if a > alpha_max:
                            a = alpha_max
                        if a < alpha_min:
                            continue
                        test_t = T * (1.0 - a)
                        if test_t < t_min:
                            break
                        w = a * T
                        for f in range(nf):
                            acc[f] += w * feats[i, f]
                        pair_w[p] += w
                        T = test_t
                    q = ly * sub + lx
                    for f in range(nf):
                        out[s, q, f] = acc[f]


def composite_forward(sub_start, pair_splat, means2d, conics, opac, feats, width, height, sub, gsx,
                      alpha_min, alpha_max, t_min):
    """Run the kernel.  Arrays are NumPy (float64 for the splat data, int64 for indices).

    Returns
    -------
    out : ndarray, shape [num_subtiles, sub * sub, F]
        Per sub-tile pixel sums of ``w * feats`` (F features, e.g. r, g, b, 1, z).
    pair_w : ndarray, shape [P]
        Blending weight summed over the sub-tile's pixels, per pair.
    """
    nsub = sub_start.shape[0] - 1
    out = np.zeros((nsub, sub * sub, feats.shape[1]))
    pair_w = np.zeros(pair_splat.shape[0])
    _composite(sub_start, pair_splat, means2d, conics, opac, feats, width, height, sub, gsx,
               alpha_min, alpha_max, t_min, out, pair_w)
    return out, pair_w


if HAVE_NUMBA:
    @numba.njit(parallel=True, cache=True, fastmath=False)
    def _composite_backward(sub_start, pair_splat, means2d, conics, opac, feats, width, height, sub, gsx,
                            alpha_min, alpha_max, t_min, grad_out, g_mean, g_conic, g_opac, g_feat):
        """Per-pair gradients of ``L = sum_pixels sum_f grad_out[s, q, f] * O[s, q, f]``.

        Walks each pixel's blended pairs front to back to find the last one and ``T_final``,
        then back to front with ``T_i = T_{i+1} / (1 - alpha_i)`` (as the reference backward).
        """
        nsub = sub_start.shape[0] - 1
        nf = feats.shape[1]
        for s in numba.prange(nsub):
            p0, p1 = sub_start[s], sub_start[s + 1]
            if p1 == p0:
                continue
            x0 = (s % gsx) * sub
            y0 = (s // gsx) * sub
            acc = np.zeros(nf)
            for ly in range(sub):
                py = y0 + ly
                if py >= height:
                    break
                for lx in range(sub):
                    px = x0 + lx
                    if px >= width:
                        break
                    q = ly * sub + lx
                    cx = px + 0.5
                    cy = py + 0.5
                    # forward: last blended pair and final transmittance
                    T = 1.0
                    last = p0 - 1
                    for p in range(p0, p1):
                        i = pair_splat[p]
                        dx, dy, power = _falloff(means2d, conics, i, cx, cy)
                        if power > 0.0:
                            continue
                        a = min(alpha_max, opac[i] * np.exp(power))
                        if a < alpha_min:
                            continue
                        test_t = T * (1.0 - a)
                        if test_t < t_min:
                            break
                        T = test_t
                        last = p
                    # backward
                    acc[:] = 0.0  # sum_{k > i} alpha_k T_k f_k
                    for p in range(last, p0 - 1, -1):
                        i = pair_splat[p]
                        dx, dy, power = _falloff(means2d, conics, i, cx, cy)
                        if power > 0.0:
                            continue
                        g = np.exp(power)
                        raw = opac[i] * g
                        a = min(alpha_max, raw)
                        if a < alpha_min:
                            continue
                        T = T / (1.0 - a)  # transmittance before this pair
                        w = a * T
                        gf = 0.0
                        gs = 0.0
                        for f in range(nf):
                            go = grad_out[s, q, f]
                            g_feat[p, f] += w * go
                            gf += go * feats[i, f]
                            gs += go * acc[f]
                        d_alpha = T * gf - gs / (1.0 - a)
                        for f in range(nf):
                            acc[f] += w * feats[i, f]
                        if raw > alpha_max:
                            continue  # clamped: no gradient to opacity or shape
                        g_opac[p] += d_alpha * g
                        d_power = d_alpha * a
                        g_mean[p, 0] += -d_power * (conics[i, 0] * dx + conics[i, 1] * dy)
                        g_mean[p, 1] += -d_power * (conics[i, 2] * dy + conics[i, 1] * dx)
                        g_conic[p, 0] += -0.5 * d_power * dx * dx
                        g_conic[p, 1] += -d_power * dx * dy
                        g_conic[p, 2] += -0.5 * d_power * dy * dy


def composite_backward(sub_start, pair_splat, means2d, conics, opac, feats, width, height, sub, gsx,
                       alpha_min, alpha_max, t_min, grad_out):
    """Per-pair gradients (mean2d [P, 2], conic [P, 3], opacity [P], features [P, F]) for the
    output gradient ``grad_out`` [num_subtiles, sub * sub, F] (see :func:`composite_forward`)."""
    npairs = pair_splat.shape[0]
    nf = feats.shape[1]
    g_mean = np.zeros((npairs, 2))
    g_conic = np.zeros((npairs, 3))
    g_opac = np.zeros(npairs)
    g_feat = np.zeros((npairs, nf))
    _composite_backward(sub_start, pair_splat, means2d, conics, opac, feats, width, height, sub, gsx,
                        alpha_min, alpha_max, t_min, np.ascontiguousarray(grad_out), g_mean, g_conic, g_opac, g_feat)
    return g_mean, g_conic, g_opac, g_feat


if HAVE_NUMBA:
    @numba.njit(inline="always")
    def _cells(i, j, means2d, conics, opac, sx0, sx1, sy0, sy1, width, height, sub, gsx, alpha_cut, keys, start):
        """Sub-tiles of splat ``i`` (at position ``j`` of the depth order) whose best alpha reaches
        ``alpha_cut``; their ids go to ``keys[start:]`` unless ``start < 0``. Returns their count.

        The cull ``o exp(-lam d^2 / 2) >= cut`` is first decided on ``d^2`` against
        ``2 log(o / cut) / lam`` without the exp; only within a relative 1e-6 of that radius is the
        exp evaluated, so the survivors are exactly those of the plain test."""
        mx, my = means2d[i, 0], means2d[i, 1]
        a, b, c = conics[i, 0], conics[i, 1], conics[i, 2]
        half_tr = 0.5 * (a + c)
        det = a * c - b * b
        lam = det / (half_tr + np.sqrt(max(half_tr * half_tr - det, 0.0)))
        lam = max(lam, 0.0) * (1.0 - 1e-6)
        o = opac[i]
        if not o >= alpha_cut:
            return 0
        d2max = 2.0 * np.log(o / alpha_cut) / lam if lam > 0.0 else np.inf
        n = 0
        for ty in range(sy0[j], sy1[j]):
            y_lo = ty * sub + 0.5
            y_hi = min(ty * sub + sub, height) - 0.5
            dy = max(y_lo - my, my - y_hi, 0.0)
            for tx in range(sx0[j], sx1[j]):
                x_lo = tx * sub + 0.5
                x_hi = min(tx * sub + sub, width) - 0.5
                dx = max(x_lo - mx, mx - x_hi, 0.0)
                d2 = dx * dx + dy * dy
                if d2 > d2max * (1.0 + 1e-6):
                    continue
                if d2 >= d2max * (1.0 - 1e-6) and o * np.exp(-0.5 * lam * d2) < alpha_cut:
                    continue
                if start >= 0:
                    keys[start + n] = ty * gsx + tx
                n += 1
        return n

    @numba.njit(cache=True, parallel=True)
    def _pairs_kernel(order, means2d, conics, opac, sx0, sx1, sy0, sy1, width, height, sub, gsx, nsub,
                      alpha_cut):
        """(splat, sub-tile) pairs surviving the exact alpha cull, stably bucketed by sub-tile: the
        cull in parallel over splats, the bucketing sequential in depth order. When the candidate
        sub-tiles fit in ``SINGLE_PASS_CELLS`` the cull writes each splat's survivors into its
        slice of a buffer of all candidates (one pass); else it counts first and writes at the
        counts' offsets (two passes, memory of the survivors only)."""
        n = order.shape[0]
        cap = np.zeros(n + 1, np.int64)
        for j in range(n):
            cap[j + 1] = cap[j] + max(sx1[j] - sx0[j], 0) * max(sy1[j] - sy0[j], 0)
        count = np.zeros(n + 1, np.int64)   # count[j + 1]: survivors of splat j, then prefix sums
        if cap[n] <= SINGLE_PASS_CELLS:
            cell = np.empty(cap[n], np.int64)
            for j in numba.prange(n):
                count[j + 1] = _cells(order[j], j, means2d, conics, opac, sx0, sx1, sy0, sy1, width, height, sub,
                                      gsx, alpha_cut, cell, cap[j])
            start = cap
        else:
            none = np.zeros(0, np.int64)
            for j in numba.prange(n):
                count[j + 1] = _cells(order[j], j, means2d, conics, opac, sx0, sx1, sy0, sy1, width, height, sub,
                                      gsx, alpha_cut, none, -1)
            start = np.zeros(n + 1, np.int64)
            for j in range(n):
                start[j + 1] = start[j] + count[j + 1]
            cell = np.empty(start[n], np.int64)
            for j in numba.prange(n):
                if count[j + 1] > 0:
                    _cells(order[j], j, means2d, conics, opac, sx0, sx1, sy0, sy1, width, height, sub, gsx,
                           alpha_cut, cell, start[j])
        bucket = np.zeros(nsub + 1, np.int64)
        for j in range(n):
            for p in range(start[j], start[j] + count[j + 1]):
                bucket[cell[p] + 1] += 1
        for s in range(nsub):
            bucket[s + 1] += bucket[s]
        total = bucket[nsub]
        out_splat = np.empty(total, np.int64)
        out_key = np.empty(total, np.int64)
        fill = bucket[:nsub].copy()
        for j in range(n):
            i = order[j]
            for p in range(start[j], start[j] + count[j + 1]):
                s = cell[p]
                out_splat[fill[s]] = i
                out_key[fill[s]] = s
                fill[s] += 1
        return out_splat, out_key


def list_pairs(order, means2d, conics, opac, sx0, sx1, sy0, sy1, width, height, sub, gsx, nsub, alpha_cut):
    """NumPy wrapper of the pair-listing kernel; returns (splat index [P], sub-tile id [P]) sorted by
    (sub-tile, position in ``order``)."""
    return _pairs_kernel(order, means2d, conics, opac, sx0, sx1, sy0, sy1, width, height, sub, gsx, nsub,
                         alpha_cut)
