"""Compiled (numba) stage of :mod:`.anneal`: the first-fit decoder and the annealing loop.

Imported on first need (numba costs a few tenths of a second to import); compiled once per machine
and cached on disk. :func:`.anneal.first_fit` is the plain-Python reference of :func:`decode`.

State of a decoded order (arrays the caller owns, ``n`` chunks, ``T`` slots, ``K`` checkpoints):
``assign`` [n] the slot of each chunk (-1: left out), ``pos`` [n] the order position whose
decoding placed it, ``ck_load`` [K, T] the bytes per slot and ``ck_val`` [K] the value before
position ``c * CHECK``, ``ck_hash`` [K] a Zobrist hash of the placements made by then. A move
re-decodes from the checkpoint before its first changed position and stops at the first
checkpoint after its last one whose hash matches the stored one: the placements from there on
are the same as before, so their value is carried over.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["CHECK", "decode", "anneal"]

#: Order positions between two checkpoints of the decoder's state.
CHECK = 8
_UNDECIDED = -2


@numba.njit(cache=True, nogil=True)
def decode(q0, hi, order, cost, profit, allowed, lower, upper, strict, budget, zob, assign, pos,
           ck_load, ck_val, ck_hash, total_old, old_assign, old_pos):  # pragma: no cover
    """Decode ``order`` from position ``q0`` (a multiple of :data:`CHECK`) and return the value.

    Each chunk in turn (its undecided lower layers first) goes to the first slot from its lower
    layer's (the one after it with strict layers) where it is allowed and its bytes fit; it is left
    out when its lower layer is, when nothing fits, or when it earns less than 0 there and no layer
    depends on it. ``hi``: the last position a move changed; at a checkpoint after it whose hash is
    the stored one, decoding stops, and the chunks not decoded again take their slots from
    ``old_assign`` / ``old_pos`` (the state before the move), their value from ``total_old``.
    """
    n, T = profit.shape
    c = q0 // CHECK
    load = ck_load[c].copy()
    val = ck_val[c]
    h = ck_hash[c]
    for i in range(n):
        if pos[i] >= q0:
            assign[i] = _UNDECIDED
            pos[i] = n + 1
    stack = np.empty(n + 1, np.int64)
    for q in range(q0, n):
        if q % CHECK == 0 and q > q0:
            cc = q // CHECK
            if q > hi and ck_hash[cc] == h:
                for j in range(n):
                    if pos[j] == n + 1:
                        assign[j] = old_assign[j]
                        pos[j] = old_pos[j]
                return val + (total_old - ck_val[cc])
            ck_load[cc, :] = load
            ck_val[cc] = val
            ck_hash[cc] = h
        m = 0
        k = order[q]
        while k >= 0 and assign[k] == _UNDECIDED:
            stack[m] = k
            m += 1
            k = lower[k]
        for r in range(m - 1, -1, -1):
            k = stack[r]
            pos[k] = q
            lo = lower[k]
            placed = -1
            start = 0
            free = True
            if lo >= 0:
                if assign[lo] < 0:
                    free = False
                else:
                    start = assign[lo] + (1 if strict else 0)
            if free:
                for t in range(start, T):
                    if allowed[k, t] and load[t] + cost[k] <= budget[t]:
                        if profit[k, t] >= 0 or upper[k] >= 0:
                            placed = t
                        break
            assign[k] = placed
            h ^= zob[k, placed + 1]
            if placed >= 0:
                load[placed] += cost[k]
                val += profit[k, placed]
    return val


@numba.njit(cache=True, nogil=True)
def _move(order, a, b, kind):  # pragma: no cover
    """Swap positions ``a`` and ``b`` (kind 0) or move the chunk at ``a`` to ``b`` (kind 1)."""
    if kind == 0:
        x = order[a]
        order[a] = order[b]
        order[b] = x
    else:
        x = order[a]
        if a < b:
            for q in range(a, b):
                order[q] = order[q + 1]
        else:
            for q in range(a, b, -1):
                order[q] = order[q - 1]
        order[b] = x


@numba.njit(cache=True, nogil=True)
def anneal(order0, cost, profit, allowed, lower, upper, strict, budget, iters, temp0, temp1, window,
           seed):  # pragma: no cover
    """Simulated annealing over chunk orders; returns ``(best order, its value, its assignment)``.

    Moves: swap two positions, or move one chunk to another position; with probability 0.7 the
    second position is within ``window`` of the first. Temperature falls geometrically from
    ``temp0`` to ``temp1`` over ``iters`` moves (Metropolis acceptance, in the profits' units).
    The value returned is that of a full decoding of the best order.
    """
    np.random.seed(seed)
    n, T = profit.shape
    order = order0.copy()
    zob = np.empty((n, T + 1), np.int64)
    for i in range(n):
        for t in range(T + 1):
            zob[i, t] = np.random.randint(1, 2 ** 62) * 2 + np.random.randint(0, 2)
    nck = n // CHECK + 2
    assign = np.full(n, _UNDECIDED, np.int64)
    pos = np.full(n, n + 1, np.int64)
    ck_load = np.zeros((nck, T), np.int64)
    ck_val = np.zeros(nck)
    ck_hash = np.zeros(nck, np.int64)
    val = decode(0, n, order, cost, profit, allowed, lower, upper, strict, budget, zob, assign, pos, ck_load,
                 ck_val, ck_hash, 0.0, assign, pos)
    b_assign = assign.copy()
    b_pos = pos.copy()
    b_load = ck_load.copy()
    b_val = ck_val.copy()
    b_hash = ck_hash.copy()
    best = order.copy()
    best_val = val
    rate = math.log(temp1 / temp0)
    for it in range(iters):
        temp = temp0 * math.exp(rate * it / iters)
        a = np.random.randint(n)
        if np.random.random() < 0.7:
            b = a + np.random.randint(-window, window + 1)
            if b < 0 or b >= n:
                continue
        else:
            b = np.random.randint(n)
        if a == b:
            continue
        kind = np.random.randint(2)
        q0 = (min(a, b) // CHECK) * CHECK
        c0 = q0 // CHECK
        b_assign[:] = assign
        b_pos[:] = pos
        b_load[c0:] = ck_load[c0:]
        b_val[c0:] = ck_val[c0:]
        b_hash[c0:] = ck_hash[c0:]
        _move(order, a, b, kind)
        v = decode(q0, max(a, b), order, cost, profit, allowed, lower, upper, strict, budget, zob, assign, pos,
                   ck_load, ck_val, ck_hash, val, b_assign, b_pos)
        d = v - val
        if d >= 0 or np.random.random() < math.exp(d / temp):
            val = v
            if v > best_val:
                best_val = v
                best[:] = order
        else:
            if kind == 0:
                _move(order, a, b, 0)
            else:
                _move(order, b, a, 1)
            assign[:] = b_assign
            pos[:] = b_pos
            ck_load[c0:] = b_load[c0:]
            ck_val[c0:] = b_val[c0:]
            ck_hash[c0:] = b_hash[c0:]
    assign[:] = _UNDECIDED
    pos[:] = n + 1
    ck_hash[:] = 0
    ck_val[:] = 0.0
    ck_load[:] = 0
    best_val = decode(0, n, best, cost, profit, allowed, lower, upper, strict, budget, zob, assign, pos, ck_load,
                      ck_val, ck_hash, 0.0, assign, pos)
    return best, best_val, assign
