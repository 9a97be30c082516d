"""Compiled (numba) stage of the 0-1 knapsack DP (:mod:`l3gs_opt.solvers._kp01`): one merge per item.

Imported on first need (numba costs a few tenths of a second to import); compiled once per
machine and cached on disk.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["stage", "rounding_loss"]


@numba.njit(cache=True, nogil=True)
def stage(W: np.ndarray, P: np.ndarray, M: np.ndarray, A: np.ndarray, w: int, p: int, bit: np.uint64, cap: int,
          U: np.ndarray, num: int, den: int, z: int, cw: np.ndarray, cp: np.ndarray, eff: np.ndarray,
          nxt: int):  # pragma: no cover
    """Merge the states without the item (``W`` ascending, ``P`` strictly rising) and with it.

    A candidate is dropped when an earlier one (no more bytes) has at least its profit, or when
    ``profit + U[num * (cap - bytes) // den] <= z`` (the relaxed DP bound at the scale
    ``num / den``; ``num * cap`` fits in int64) or its LP bound is (it cannot beat the incumbent ``z``).

    The LP (Dantzig) bound of the items ``nxt..`` (by profit per byte, best first) within ``r``
    bytes: ``cw``/``cp`` are their float64 running sums of bytes and profit, ``eff`` each one's
    profit per byte. The LP value is concave in ``r``, so evaluating it on any one of its linear
    pieces (a break position off by one through round-off) still gives at least the LP value; the
    float sums' own round-off (< 1e-12 relative for 1e4 items) is covered by adding 1e-12 of it
    and 2 before rounding down: the result stays an upper bound.
    """
    n = W.shape[0]
    jend = 0
    while jend < n and W[jend] + w <= cap:
        jend += 1
    size = n + jend
    oW = np.empty(size, dtype=np.int64)
    oP = np.empty(size, dtype=np.int64)
    oM = np.empty(size, dtype=np.uint64)
    oA = np.empty(size, dtype=np.int32)
    i = 0
    j = 0
    k = 0
    last = np.int64(-1)
    m_items = eff.shape[0]
    # With more bytes left than the rest weighs, the LP bound is their whole profit: skip it.
    last_r_ok = cw[m_items] - cw[nxt]
    while i < n or j < jend:
        if j >= jend:
            take_i = True
        elif i >= n:
            take_i = False
        else:
            wj = W[j] + w
            take_i = W[i] < wj or (W[i] == wj and P[i] >= P[j] + p)
        if take_i:
            cw_ = W[i]
            cp_ = P[i]
            cm = M[i]
            ca = A[i]
            i += 1
        else:
            cw_ = W[j] + w
            cp_ = P[j] + p
            cm = M[j] | bit
            ca = A[j]
            j += 1
        if cp_ <= last:
            continue
        last = cp_
        if cp_ + U[num * (cap - cw_) // den] <= z:
            continue
        r = cap - cw_
        if r < last_r_ok:
            # LP bound of the rest within r bytes.
            target = cw[nxt] + r
            t = np.searchsorted(cw, target, side="right") - 1
            if t < nxt:
                t = nxt
            lp = cp[t] - cp[nxt]
            if t < m_items:
                lp += (target - cw[t]) * eff[t]
            lp = lp + abs(lp) * 1e-12 + 2.0
            if cp_ + np.int64(lp) <= z:
                continue
        oW[k] = cw_
        oP[k] = cp_
        oM[k] = cm
        oA[k] = ca
        k += 1
    return oW[:k].copy(), oP[:k].copy(), oM[:k].copy(), oA[:k].copy()


@numba.njit(cache=True, nogil=True)
def rounding_loss(q: np.ndarray, lo: int, hi: int) -> np.ndarray:  # pragma: no cover
    """``out[K - lo] = sum_i frac(K q_i) / K`` for ``K = lo..hi`` with ``q = w / (capacity + 1)``:
    the bytes that rounding ``K q_i`` down loses, summed over the items, over ``capacity + 1``
    (float64, a ranking only: :func:`l3gs_opt.solvers._kp01._least_loss_scales`)."""
    out = np.empty(hi - lo + 1)
    for K in range(lo, hi + 1):
        s = 0.0
        for qi in q:
            x = K * qi
            s += x - np.floor(x)
        out[K - lo] = s / K
    return out
