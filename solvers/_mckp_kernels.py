"""Compiled (numba) kernels of the MCKP branch-and-bound: one DP stage in one call.

Imported only by :func:`l3gs_opt.solvers._mckp.compiled_kernels`, on first need, because
importing numba costs a few tenths of a second that small instances should not pay; compiled
once per machine and cached on disk (``cache=True``). Each kernel mirrors a numpy function of
:mod:`l3gs_opt.solvers._mckp` operation for operation (same float64 expressions in the same
order), so both give the same states bit for bit; the numpy versions stay as the fallback when
numba is missing and as the reference the tests compare against.

Why a kernel: on Pisinger's strongly correlated instances the DP looks at up to 7e8 (state,
option) pairs; the numpy stage spends 20-40 ns on each (about twenty array passes and a sort),
this one 4-8 ns (one bounding pass and a merge, no sort).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["envelope", "stage"]


@numba.njit(cache=True, nogil=True)
def envelope(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Lower envelope of the lines ``a_k + b_k x`` on ``x >= 0``: (intercepts, slopes, start x)
    of the pieces by increasing x; ``b`` ascending. Mirrors ``_mckp._envelope``."""
    q = b.shape[0]
    ha = np.empty(q)
    hb = np.empty(q)
    hs = np.empty(q)
    n = 0
    for k in range(q - 1, -1, -1):          # slopes descending
        ak = a[k]
        bk = b[k]
        if n > 0 and hb[n - 1] == bk:
            if ak >= ha[n - 1]:
                continue
            n -= 1
        x = 0.0
        while n > 0:
            x = (ak - ha[n - 1]) / (hb[n - 1] - bk)      # the new line is lower for x > this
            if x <= 0.0 or (n > 1 and x <= hs[n - 1]):
                n -= 1
                x = 0.0
                continue
            break
        ha[n] = ak
        hb[n] = bk
        hs[n] = x if n > 0 else 0.0
        n += 1
    return ha[:n].copy(), hb[:n].copy(), hs[:n].copy()


@numba.njit(cache=True, nogil=True)
def stage(W: np.ndarray, P: np.ndarray, c: np.ndarray, v: np.ndarray, budget: int, cap: int, F: np.ndarray,
          lams: np.ndarray, thr: float, opt_ids: np.ndarray):  # pragma: no cover
    """One DP stage, as ``_mckp._stage_numpy`` (see its docstring for the arguments).

    Every state (``W`` ascending, ``P``) times every option (``c``, ``v``), kept when
    ``W + c <= cap`` and its bound ``P + v + min_k (F_k + lams_k * (budget - W - c))`` exceeds
    ``thr``, then Pareto-filtered. Returns ``(W, P, parent state (int32), option id
    (``opt_ids[position]``, in its dtype), largest bound of a feasible candidate cut by the bound
    or -inf)``.

    Phase 1 bounds each option's candidates in one pass (the envelope piece only moves down,
    since bytes left fall as the states' bytes rise) and keeps the live ones as a run sorted by
    bytes; phase 2 merges the runs one after another, dropping dominated states as it goes.
    Ties in bytes are resolved as the numpy stage's stable sort does: the earlier option first,
    and a later, strictly more valuable state replaces it.
    """
    ea, eb, es = envelope(F, lams)
    ne = es.shape[0]
    m = W.shape[0]
    k = c.shape[0]
    big = np.iinfo(np.int64).max
    # Phase 1. Each run is followed by a sentinel (bytes = big) so the merge needs no bounds test.
    hi = np.empty(k, np.int64)        # states 0..hi[o]-1 fit with option o
    total = 0
    for o in range(k):
        hi[o] = np.searchsorted(W, cap - c[o], side="right")
        total += hi[o]
    cw = np.empty(total + k, np.int64)
    cp = np.empty(total + k)
    ci = np.empty(total + k, np.int64)                  # flat source o * m + j
    start = np.zeros(k + 1, np.int64)
    n = 0
    dead = -np.inf
    for o in range(k):
        start[o] = n
        co = c[o]
        vo = v[o]
        bc = float(budget - co)
        kp = ne - 1
        for j in range(hi[o]):
            w = W[j]
            # Envelope piece at bytes left d = budget - w - co: the last piece whose start is
            # <= d, tested as the numpy path does (w <= (budget - co) - start, in float64).
            while kp > 0 and not (float(w) <= bc - es[kp]):
                kp -= 1
            wm = w + co
            d = float(budget - wm)
            pm = P[j] + vo
            ub = pm + ea[kp] + eb[kp] * d
            if ub > thr:
                cw[n] = wm
                cp[n] = pm
                ci[n] = o * m + j
                n += 1
            elif ub > dead:
                dead = ub
        cw[n] = big
        n += 1
    start[k] = n
    if k == 0:               # no option left: every state dies
        return (np.empty(0, np.int64), np.empty(0), np.empty(0, np.int32), np.empty(0, opt_ids.dtype), dead)
    # Phase 2.
    rw = np.empty(n + 1, np.int64)
    rp = np.empty(n + 1)
    ri = np.empty(n + 1, np.int64)
    ow = np.empty(n + 1, np.int64)
    op = np.empty(n + 1)
    oi = np.empty(n + 1, np.int64)
    nr = start[1] - 1
    rw[:nr] = cw[:nr]
    rp[:nr] = cp[:nr]
    ri[:nr] = ci[:nr]
    for o in range(1, k):
        s0 = start[o]
        nb = start[o + 1] - s0 - 1
        if nb == 0:
            continue
        rw[nr] = big
        i = 0
        j = s0
        no = 0
        last_p = -np.inf
        for _ in range(nr + nb):
            a = rw[i]
            b = cw[j]
            if a <= b:
                w = a
                p = rp[i]
                x = ri[i]
                i += 1
            else:
                w = b
                p = cp[j]
                x = ci[j]
                j += 1
            # Undominated: more value than every state kept so far (they all cost no more).
            if p > last_p:
                if no > 0 and ow[no - 1] == w:
                    no -= 1
                ow[no] = w
                op[no] = p
                oi[no] = x
                no += 1
                last_p = p
        rw, ow = ow, rw
        rp, op = op, rp
        ri, oi = oi, ri
        nr = no
    parent = np.empty(nr, np.int32)
    pick = np.empty(nr, opt_ids.dtype)
    mm = max(m, 1)
    for t in range(nr):
        o = ri[t] // mm
        parent[t] = ri[t] - o * mm
        pick[t] = opt_ids[o]
    return rw[:nr].copy(), rp[:nr].copy(), parent, pick, dead
