"""The per-slot pricing knapsack of ``exact``: a compiled depth-first branch-and-bound.

Column generation and the Lagrangian bound solve one 0-1 knapsack per slot per iteration (at
J=20, T=60: some 9,000 of them, each of ~80 items with float reduced profits). The general
single-slot solver (``bb``) pays ~1.5 ms of Python per call there; this is the Horowitz-Sahni
depth-first search (Martello and Toth, *Knapsack Problems*, 1990, section 2.5.2) with Dantzig's
bound, compiled: tens of microseconds. Why not ``bb``'s 0-1 search (``solvers/_kp01.py``): that one
is exact in integer arithmetic for capacities up to 1e10 and integer profits; these profits are
float reduced costs and the callers add a round-off slack to the bound anyway.

A search that exceeds ``max_nodes`` stops and says so; the caller then falls back to ``bb``.
"""

from __future__ import annotations

import numpy as np

from . import kernels

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is a dependency; the caller falls back to bb
    njit = None

__all__ = ["solve_kp01_float", "MAX_NODES", "available"]

#: Nodes the compiled search may visit before it gives up (the caller falls back to ``bb``).
MAX_NODES = 2_000_000


def available() -> bool:
    """Whether the compiled search exists (numba installed)."""
    return njit is not None


if njit is not None:
    @njit(cache=True, nogil=True)   # (like the other solver kernels: the HiGHS thread runs meanwhile)
    def _search(w, p, cap, max_nodes):  # pragma: no cover - compiled
        """Items sorted by p/w descending, every w <= cap, every p > 0. Returns (best value,
        taken mask, finished)."""
        n = w.shape[0]
        x = np.zeros(n, np.bool_)
        best_x = np.zeros(n, np.bool_)
        best = 0.0
        room = cap          # bytes left
        val = 0.0           # value taken
        j = 0
        nodes = 0
        while True:
            # Step 2: Dantzig's bound from item j with `room` bytes left.
            nodes += 1
            if nodes > max_nodes:
                return best, best_x, False
            r, used, gain = j, 0, 0.0
            while r < n and used + w[r] <= room:
                used += w[r]
                gain += p[r]
                r += 1
            bound = val + gain
            if r < n:
                bound += p[r] * (room - used) / w[r]
            if bound > best:
                # Step 3: forward -- take items j..r-1 (they fit), skip item r, go on.
                for i in range(j, r):
                    x[i] = True
                room -= used
                val += gain
                j = r
                if j < n:
                    x[j] = False
                    j += 1
                    if j < n:
                        continue
                # Step 4: a leaf (every item decided).
                if val > best:
                    best = val
                    best_x[:] = x
            # Step 5: backtrack to the last taken item before j and drop it.
            i = j - 1
            while i >= 0 and not x[i]:
                i -= 1
            if i < 0:
                return best, best_x, True
            x[i] = False
            room += w[i]
            val -= p[i]
            for k in range(i + 1, n):
                x[k] = False
            j = i + 1


def _warm() -> None:
    if available():
        solve_kp01_float(np.array([3, 4, 5], np.int64), np.array([1.0, 2.0, 3.0]), 7)


kernels.register("pricing", _warm)


def solve_kp01_float(cost: np.ndarray, value: np.ndarray, capacity: int, *, max_nodes: int = MAX_NODES
                     ) -> tuple[np.ndarray, float, bool]:
    """Maximise ``sum value[S]`` with ``sum cost[S] <= capacity`` over items with value > 0 and
    cost <= capacity: (chosen positions, best value, finished). ``finished`` False: the search
    stopped at ``max_nodes`` (the positions are then a feasible choice, not a proven optimum)."""
    cost = np.asarray(cost, np.int64)
    value = np.asarray(value, np.float64)
    take = np.flatnonzero((value > 0) & (cost <= capacity))
    if take.size == 0 or capacity <= 0:
        return np.zeros(0, np.int64), 0.0, True
    ratio = value[take] / cost[take]
    order = take[np.argsort(-ratio, kind="stable")]
    best, mask, done = _search(cost[order], value[order], np.int64(capacity), np.int64(max_nodes))
    chosen = np.sort(order[mask])
    return chosen, float(best), bool(done)
