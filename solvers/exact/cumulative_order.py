"""Local search over send orders for the ``cumulative`` budget (one sequential link).

With one link and same-slot layers a schedule is an order of chunks: each arrives in the first
slot whose bytes up to it cover it and everything sent before it (never before its earliest slot;
see :mod:`l3gs_opt.solvers.link_dp`). Every order is feasible: the bytes arriving by slot t are
at most the bytes of a prefix that fits by t. The search improves an order by the best of three
moves, each valued for every position at once (an insertion shifts every later chunk by the same
bytes, so its effect is one suffix sum):

* **insert** a chunk not sent (after its lower layer);
* **remove** a chunk and the layers above it that are sent (the later chunks move earlier);
* **move** a chunk elsewhere (after its lower layer, before its upper layer).

Values are ``profit[i, slot]`` (any sign); the caller checks and values the result exactly.
Strict layers (a layer strictly after the one below) are not orders of this kind: the search
leaves such instances alone.
"""

from __future__ import annotations

import numpy as np

from l3gs_opt import stop

from .cumulative_data import LinkData

__all__ = ["order_of", "order_slots", "improve_order"]


def order_of(data: LinkData, assign: np.ndarray) -> np.ndarray:
    """The send order of an assignment: by slot, a lower layer before its upper layer."""
    on = np.nonzero(assign >= 0)[0]
    return on[np.lexsort((data.item_l[on], assign[on]))]


def order_slots(data: LinkData, order: np.ndarray, before: int = 0) -> np.ndarray:
    """Each chunk's slot when ``order`` is sent after ``before`` bytes (T: it does not arrive)."""
    prefix = before + np.cumsum(data.cost[order])
    return np.maximum(np.searchsorted(data.capacity, prefix, side="left"), data.first[order])


def _insert_gains(data: LinkData, fut: np.ndarray, order: np.ndarray, values: np.ndarray, c: int) -> np.ndarray:
    """Value change of inserting chunk ``c`` before each position ``p`` of ``order`` (``p = len``:
    at the end); ``values`` are the order's chunks' current values. -inf where a chunk would no
    longer arrive."""
    T = data.T
    cc = int(data.cost[c])
    prefix = np.cumsum(data.cost[order])
    later = np.maximum(np.searchsorted(data.capacity, prefix + cc, side="left"), data.first[order])
    delta = np.where(later < T, fut[order, np.minimum(later, T)], -np.inf) - values
    suffix = np.concatenate([np.cumsum(delta[::-1])[::-1], [0.0]])
    sent = np.concatenate([[0], prefix])
    own = np.maximum(np.searchsorted(data.capacity, sent + cc, side="left"), data.first[c])
    return np.where(own < T, fut[c, np.minimum(own, T)], -np.inf) + suffix


def improve_order(data: LinkData, assign: np.ndarray, *, deadline: float | None = None,
                  max_rounds: int = 1000) -> np.ndarray:
    """Best-improvement search from ``assign`` until no move gains, ``max_rounds`` moves, or
    ``deadline`` (``time.perf_counter()`` seconds). Returns the assignment of the final order."""
    if data.strict or data.n == 0:
        return assign
    T = data.T
    fut = np.concatenate([data.profit, np.zeros((data.n, 1))], axis=1)   # column T: not arriving
    order = order_of(data, assign)
    for _ in range(max_rounds):
        if stop.expired(deadline):
            break
        slots = order_slots(data, order)
        if (slots >= T).any():      # (only from a start that is not an order of this kind)
            order = order[slots < T]
            continue
        values = fut[order, slots]
        total = float(values.sum())
        pos = -np.ones(data.n, dtype=np.int64)
        pos[order] = np.arange(len(order))
        best_gain, best = 1e-12 * max(1.0, abs(total)), None
        for c in np.nonzero(pos < 0)[0]:                                    # insert
            lo = data.lower[c]
            if lo >= 0 and pos[lo] < 0:
                continue
            gain = _insert_gains(data, fut, order, values, c)
            start = 0 if lo < 0 else pos[lo] + 1
            p = start + int(np.argmax(gain[start:]))
            if gain[p] > best_gain:
                best_gain, best = gain[p], ("insert", c, p)
        for k, c in enumerate(order):                                       # remove, move
            chain = [c]
            while data.upper[chain[-1]] >= 0 and pos[data.upper[chain[-1]]] >= 0:
                chain.append(data.upper[chain[-1]])
            rest = np.delete(order, pos[chain])
            s_rest = order_slots(data, rest)
            gain = float(fut[rest, s_rest].sum()) - total
            if gain > best_gain:
                best_gain, best = gain, ("remove", pos[chain])
            if len(chain) > 1 and data.upper[c] >= 0:
                up_at = int(pos[data.upper[c]]) - 1        # its upper layer's position once c is out
            else:
                up_at = len(order) - 1
            rest = np.delete(order, k)
            s_rest = order_slots(data, rest)
            v_rest = fut[rest, s_rest]
            gain = _insert_gains(data, fut, rest, v_rest, c) + float(v_rest.sum()) - total
            lo = data.lower[c]
            start = 0 if lo < 0 else int(pos[lo]) + 1
            if start <= up_at:
                p = start + int(np.argmax(gain[start:up_at + 1]))
                if gain[p] > best_gain:
                    best_gain, best = gain[p], ("move", k, p)
        if best is None:
            break
        if best[0] == "insert":
            order = np.insert(order, best[2], best[1])
        elif best[0] == "remove":
            order = np.delete(order, best[1])
        else:
            c = order[best[1]]
            order = np.insert(np.delete(order, best[1]), best[2], c)
    slots = order_slots(data, order)
    out = np.full(data.n, -1, dtype=np.int64)
    ok = slots < T
    out[order[ok]] = slots[ok]
    return out
