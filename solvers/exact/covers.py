"""Cover cuts of the arrived-by knapsacks of Problem A (per-slot budgets).

The chunks that have arrived by slot t fit the bytes of slots ``0..t``: ``sum_i c[i] y[i,t] <=
C[t]`` with ``y[i,t] = sum_{s<=t} x[i,s]`` and ``C[t] = sum_{s<=t} B[s]``. No single slot's
knapsack sees that row, so the Dantzig-Wolfe master over per-slot fillings can break it; a set S
of chunks with ``c(S) > C[t]`` gives the valid row ``sum_{i in S} y[i,t] <= |S| - 1`` (a
:class:`~.lagrange.Cover`). In the master a filling of slot s <= t has coefficient ``|filling &
S|`` in it, and its multiplier only lowers the reduced profits of S's chunks in slots ``0..t``, so
the pricing stays one knapsack per slot (see :meth:`~.lagrange.Multipliers.cover_charge`).

``exact`` runs rounds of them when ``search.COVER_CUTS`` asks; it is off by default: on nine J=20
development instances they lowered the root bound on six but did not shorten the proofs
(``benchmarks/results/cover_cuts_exact_ab.txt``).
"""

from __future__ import annotations

import numpy as np

from .lagrange import Cover, GapData, knapsack

__all__ = ["separate_covers", "COVER_TOL"]

#: A cover counts as violated when its row's left side exceeds ``|S| - 1`` by more than this
#: (master values are LP solutions, exact to ~1e-9).
COVER_TOL = 1e-6


def _most_violated(cost: np.ndarray, gap: np.ndarray, capacity: int) -> np.ndarray | None:
    """Positions of a cover of ``capacity`` (bytes ``cost``) of least slack ``sum gap`` (``gap =
    1 - y >= 0``), made minimal, or None when the items fit.

    The most violated cover is the complement of a 0-1 knapsack: keep out of S the set R of most
    slack with ``c(R) <= c(all) - capacity - 1``."""
    total = int(cost.sum())
    if total <= capacity:
        return None
    out, _, _ = knapsack(cost, gap, total - capacity - 1)
    inside = np.ones(len(cost), dtype=bool)
    inside[out] = False
    # Minimal: dropping a chunk lowers the left side by y and the right side by 1, so each drop
    # that keeps a cover makes the row more violated; most slack first.
    spent = int(cost[inside].sum())
    for k in np.argsort(-gap, kind="stable"):
        if inside[k] and spent - int(cost[k]) > capacity:
            inside[k] = False
            spent -= int(cost[k])
    return np.nonzero(inside)[0]


def separate_covers(data: GapData, x: np.ndarray, known: set[tuple[int, bytes]] | None = None,
                    tol: float = COVER_TOL) -> list[Cover]:
    """For each slot t, the most violated minimal cover of the arrived-by knapsack at the
    (fractional) arrivals ``x`` [n, T], when it is violated by more than ``tol`` and not in
    ``known`` (keys ``(t, items.tobytes())``).

    Only chunks that may arrive by t (``data.allowed``) are candidates: the others have ``y = 0``
    at every schedule.
    """
    known = known or set()
    y = np.clip(np.cumsum(x, axis=1), 0.0, 1.0)
    reach = np.cumsum(data.allowed, axis=1) > 0
    capacity = np.cumsum(data.budget.astype(object))   # Python ints: exact bytes
    out = []
    for t in range(data.T):
        cand = np.nonzero(reach[:, t])[0]
        if len(cand) == 0 or int(data.cost[cand].sum()) <= int(capacity[t]):
            continue
        pos = _most_violated(data.cost[cand], 1.0 - y[cand, t], int(capacity[t]))
        if pos is None:
            continue
        items = cand[pos].astype(np.int64)
        if float((1.0 - y[items, t]).sum()) >= 1.0 - tol or (t, items.tobytes()) in known:
            continue
        out.append(Cover(items, t))
    return out
