"""Exact 0-1 knapsack in integers: a bounded Pareto-state DP whose states are fathomed by a
relaxed-weight DP bound.

Used by ``bb`` (:func:`l3gs_opt.solvers._mckp.branch_and_bound`) when every row of the option table
has one option and every value is an integer: the 0-1 knapsack, e.g. Pisinger's and Jooken et al.'s
public sets, where capacities reach 1e10 and the LP bound is too weak (Jooken's items come in groups
whose weights sit just above ``capacity / k``: the LP fills the knapsack, no integer solution does).

Algorithm (in the spirit of Pisinger's Minknap and Combo, with a different bound):

1. **Relaxed DP bound.** Weights are scaled by ``lambda = num / den`` and rounded down
   (``floor(lambda w)`` units), profits kept exact. ``U_s[r]``, the best profit of items
   ``s..n-1`` whose units sum to at most ``r``, is an upper bound on what those items add to any
   state with ``R`` bytes left, at ``r = floor(lambda R)``: a set of items that fits in ``R`` bytes
   has ``sum floor(lambda w) <= floor(lambda sum w) <= floor(lambda R)`` (a Chvatal-Gomory rounding
   of the capacity row). Unlike the LP bound it knows items are indivisible (two items of
   ``capacity / 2 + 1`` bytes do not fit). The scale is ``lambda = units / (capacity + 1)``: the
   capacity becomes ``units - 1`` units and an item a little heavier than ``capacity / k`` keeps
   its full ``units / k`` (Jooken's groups sit just above ``capacity / 2^i``: the knapsack cannot be
   filled to the last unit, and the bound knows it). The usual ``1 / ceil(capacity / units)``
   rounds those items down a unit and loses exactly that: on Jooken's ``eps = 0`` files its root
   bound is ``capacity / 512`` above the optimum, this one's is the optimum. ``units`` is the
   largest table allowed, a power of two below it, or one of the three sizes in ``[units / 4,
   units]`` that lose the fewest bytes per item to rounding (a power of two loses ``frac(eps K)`` of
   a unit on every item of ``(1/2^i + eps) capacity``), whichever gives the smallest root bound
   (:func:`_pick_scale`). When ``units * (capacity + 1)`` would not fit in int64 the scale falls
   back to ``1 / ceil(capacity / units)``; with ``capacity <= units`` it is 1 (exact). The same
   DP with weights rounded *up* gives a feasible start (:func:`_dp_solution`). The tables are
   kept every ``B`` stages and recomputed block by block (memory O((n / B + B) * units), work
   2 n units; choosing the scale and the two start solutions cost about 7 n units more).
2. **Forward DP over Pareto states** ``(bytes, profit)``: per item, merge "without" and "with",
   drop dominated states (more bytes, no more profit) and states whose ``profit + U`` cannot beat
   the incumbent. Every state is a feasible solution, so the incumbent rises as the DP goes.
3. **Solution.** Each state carries a 64-bit mask of the last block's decisions and the index of its
   ancestor at the previous block's end; the chosen items are read back through those.

Everything is int64: bytes up to 2**53, profits summing below 2**62 (checked by the caller), so no
value and no bound is ever rounded, and ``optimal`` means exactly optimal.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from l3gs_opt.errors import SolveError

__all__ = ["Kp01Result", "solve_kp01", "fits_kp01", "MAX_PROFIT_TOTAL"]

#: Profits must sum below this (int64 sums and bounds never overflow).
MAX_PROFIT_TOTAL = 2**62

#: Relaxed-DP resolution: capacity units of the bound tables (8 bytes a unit a table; about
#: 2 sqrt(n) tables are kept: 150 MB at n = 1200).
_UNITS = 1 << 18

#: Cells (items x units) the bound tables may cost.
_WORK_CELLS = 300_000_000

#: Table sizes picked by least rounding loss, tried beside the powers of two (:func:`_pick_scale`).
_LOSS_SCALES = 3

#: Items the rounding loss is scored on (an evenly spaced sample of the weight order).
_LOSS_SAMPLE = 256

#: Decisions per mask (one uint64 per state).
_BLOCK = 64

#: States of one stage after which the search stops (memory: about 28 bytes a state).
MAX_STATES = 30_000_000
#: Shares of a time limit the set-up may take (a 2,000-item set took 2 s of set-up under a 1 s
#: limit): the scale search stops trying candidates past the first share, keeping the tightest so
#: far (any scale gives a valid bound), and each start DP runs only before the second. The bound
#: table always runs, as the answer's bound needs it: n x units cells (at most _WORK_CELLS), 0.2-0.8 s
#: at n=2,000 here, which a limit under a second can be overrun by.
SCALE_SHARE, START_DP_SHARE = 0.25, 0.5


@dataclass(frozen=True, eq=False)
class Kp01Result:
    """``take`` (bool [n]) of the best solution found, its exact ``value``, an exact upper
    ``bound`` on the optimum, and whether the search finished (``optimal``: value == optimum)."""

    take: np.ndarray
    value: int
    bound: int
    optimal: bool
    stats: dict = field(default_factory=dict)


def fits_kp01(weight: np.ndarray, profit: np.ndarray) -> bool:
    """Whether the integer solver applies: profits integral, non-negative and summing below
    :data:`MAX_PROFIT_TOTAL`, weights positive below 2**53."""
    profit = np.asarray(profit, dtype=np.float64)
    if profit.size == 0:
        return True
    if not np.all(np.isfinite(profit)) or (profit < 0).any() or (profit != np.floor(profit)).any():
        return False
    if math.fsum(profit.tolist()) >= MAX_PROFIT_TOTAL / 2:
        return False
    weight = np.asarray(weight)
    return bool((weight > 0).all() and (weight <= 2**53).all())


def _kernels():
    from . import _kp01_kernels

    return _kp01_kernels


def _greedy(w: np.ndarray, p: np.ndarray, c: int) -> np.ndarray:
    """Items by profit per byte (exact order by cross products is not needed: any order is feasible),
    each taken when it fits; then the most profitable item alone if that is better."""
    order = np.argsort(-(p / w), kind="stable")
    take = np.zeros(len(w), dtype=bool)
    room = c
    for i in order.tolist():
        if w[i] <= room:
            take[i] = True
            room -= int(w[i])
    best = int(np.argmax(p))
    if int(p[best]) > int(p[take].sum()):
        take[:] = False
        take[best] = True
    return take


def _dp_value(wu: np.ndarray, p: np.ndarray, m: int) -> int:
    """The best profit of items whose units ``wu`` sum to at most ``m``."""
    u = np.zeros(m + 1, dtype=np.int64)
    for k, pk in zip(wu.tolist(), p.tolist()):
        if k <= m:
            np.maximum(u[k:], u[:m + 1 - k] + pk, out=u[k:])
    return int(u[m])


def _dp_solution(wu: np.ndarray, p: np.ndarray, m: int) -> np.ndarray:
    """The best items (bool [n]) whose units ``wu`` sum to at most ``m``. With weights rounded *up*
    (``ceil(lambda w)``) a feasible solution of the knapsack (``sum ceil(lambda w) <= floor(lambda
    c)`` implies ``sum w <= c``); with them rounded down, the relaxation's optimum (feasible or not:
    the caller checks the bytes)."""
    n = len(wu)
    u = np.zeros(m + 1, dtype=np.int64)
    took = np.zeros((n, (m + 8) // 8), dtype=np.uint8)    # bit r of row i: item i taken at r units
    row = np.zeros(m + 1, dtype=bool)
    for i in range(n):
        k = int(wu[i])
        if k > m:
            continue
        cand = u[:m + 1 - k] + int(p[i])
        better = cand > u[k:]
        u[k:] = np.where(better, cand, u[k:])
        row[:k] = False
        row[k:] = better
        took[i] = np.packbits(row)
    take = np.zeros(n, dtype=bool)
    r = m
    for i in range(n - 1, -1, -1):
        if took[i, r >> 3] >> (7 - (r & 7)) & 1:
            take[i] = True
            r -= int(wu[i])
    return take


class _Bounds:
    """``U_s`` for s = 0..n (items in DP order), kept every ``block`` stages, recomputed per block."""

    def __init__(self, wu: np.ndarray, p: np.ndarray, units: int):
        self.wu, self.p, self.units = wu, p, units
        n = len(wu)
        self.block = max(1, int(math.isqrt(n)))
        self.kept: dict[int, np.ndarray] = {}
        u = np.zeros(units + 1, dtype=np.int64)
        self.kept[n] = u
        for s in range(n - 1, -1, -1):
            u = self._step(u, s)
            if s % self.block == 0:
                self.kept[s] = u
        self.cache: dict[int, np.ndarray] = {}
        self.cache_block = -1

    def _step(self, u: np.ndarray, s: int) -> np.ndarray:
        k = int(self.wu[s])
        if k > self.units:
            return u
        out = u.copy()
        np.maximum(out[k:], u[:len(u) - k] + int(self.p[s]), out=out[k:])
        return out

    def at(self, s: int) -> np.ndarray:
        if s in self.kept:
            return self.kept[s]
        b = s // self.block
        if b != self.cache_block:
            top = min((b + 1) * self.block, len(self.wu))
            u = self.kept[top]
            self.cache = {}
            for t in range(top - 1, b * self.block, -1):
                u = self._step(u, t)
                self.cache[t] = u
            self.cache_block = b
        return self.cache[s]


def _pick_scale(w: np.ndarray, p: np.ndarray, capacity: int, units: int,
                deadline: float | None = None) -> tuple[int, int, int]:
    """The relaxed DP's ``lambda = num / den`` (module docstring): 1 for small capacities; else
    ``K / (capacity + 1)`` for the ``K`` among ``units``, the powers of two below it and the sizes
    of least rounding loss (:func:`_least_loss_scales`) whose root bound is smallest (the finest on
    a tie: a finer scale is not always tighter, as the rounding loss depends on how the weights sit
    against ``capacity / K``; the candidates cost about five tables); ``1 / ceil(capacity / units)``
    when ``units * (capacity + 1)`` would overflow int64. Past ``deadline`` (``time.perf_counter()``
    seconds) no further candidate is tried. Returns ``(num, den, candidates tried)``."""
    if capacity <= units:
        return 1, 1, 0
    if units * (capacity + 1) >= 2**62:
        return 1, -(-capacity // units), 0
    den = capacity + 1
    powers = [1 << j for j in range(units.bit_length() - 1, 5, -1)]
    candidates = sorted({units, *powers, *_least_loss_scales(w, den, units)}, reverse=True)
    best, tried = None, 0
    for K in candidates:
        if best is not None and deadline is not None and time.perf_counter() > deadline:
            break
        b = _dp_value(K * w // den, p, K * capacity // den)
        tried += 1
        if best is None or b < best[0]:
            best = (b, K)
    return best[1], den, tried


def _least_loss_scales(w: np.ndarray, den: int, units: int, count: int = _LOSS_SCALES) -> list[int]:
    """The ``count`` table sizes ``K`` in ``[units / 4, units]`` at which rounding ``K w / den`` down
    loses the fewest bytes per item on average (``frac(K w / den) * den / K``; the largest ``K`` on a
    tie). Every item the relaxation takes may be up to its loss lighter than it is, so the root
    bound tends to follow this loss; a power of two can sit badly against weights like
    ``(1/2^i + eps) capacity`` (each loses ``frac(eps K)`` of a unit) where a nearby ``K`` loses
    almost nothing. Scored in float64 on at most :data:`_LOSS_SAMPLE` items spread over the weight
    order (a ranking only: the bound itself is exact whatever ``K``)."""
    lo = max(1, units // 4)
    sample = np.sort(w)[np.linspace(0, len(w) - 1, min(len(w), _LOSS_SAMPLE)).astype(np.int64)]
    loss = _kernels().rounding_loss(sample.astype(np.float64) / den, lo, units)   # [K - lo]
    best = np.lexsort((-np.arange(len(loss)), loss))[:count]
    return [lo + int(i) for i in best]


def solve_kp01(weight: np.ndarray, profit: np.ndarray, capacity: int, *, time_limit_s: float | None = None,
               incumbent: np.ndarray | None = None, units: int = _UNITS,
               max_states: int = MAX_STATES) -> Kp01Result:
    """Exact 0-1 knapsack: ``max p.x`` subject to ``w.x <= capacity``, x in {0, 1}^n.

    Parameters
    ----------
    weight : int array [n]
        Bytes of each item (> 0; items heavier than the capacity are never taken).
    profit : int-valued array [n]
        Profits (>= 0, see :func:`fits_kp01`).
    capacity : int
        Bytes available (>= 0).
    time_limit_s : float, optional
        Stop after this many seconds with the best solution and an exact upper bound.
    incumbent : bool array [n], optional
        A feasible solution to start from (e.g. the caller's greedy).
    units : int
        Resolution of the relaxed DP bound (capacity units).
    """
    started = time.perf_counter()
    w_all = np.asarray(weight, dtype=np.int64)
    p_all = np.asarray(profit, dtype=np.float64).astype(np.int64)
    c = int(capacity)
    n_all = len(w_all)
    keep = np.nonzero((w_all <= c) & (p_all > 0))[0]
    stats: dict = {"kp01": True, "items": int(len(keep))}
    take = np.zeros(n_all, dtype=bool)
    if len(keep) == 0:
        return Kp01Result(take, 0, 0, True, stats)
    w, p = w_all[keep], p_all[keep]
    n = len(w)
    if int(w.sum()) <= c:
        take[keep] = True
        v = int(p.sum())
        return Kp01Result(take, v, v, True, stats)
    # Incumbent: the greedy, or the caller's solution when better.
    best_take = _greedy(w, p, c)
    z = int(p[best_take].sum())
    if incumbent is not None:
        inc = np.asarray(incumbent, dtype=bool)[keep]
        if int(w[inc].sum()) <= c and int(p[inc].sum()) > z:
            best_take, z = inc.copy(), int(p[inc].sum())
    stats["greedy"] = z
    # DP order: by profit per byte, best first (the states then rise in profit early: good incumbents).
    order = np.lexsort((-w, -(p / w)))
    wo, po = w[order], p[order]
    # Bound tables cost n x units work twice (and the scale and start solutions about 7 times):
    # keep that near 3e8 cells on large n.
    units = max(1024, min(units, _WORK_CELLS // n))
    def by(share: float) -> float | None:
        return None if time_limit_s is None else started + share * float(time_limit_s)

    num, den, stats["scales_tried"] = _pick_scale(wo, po, c, units, by(SCALE_SHARE))
    m = num * c // den
    wu = num * wo // den
    # Two DP solutions at that scale: weights rounded up (always feasible) and rounded down (the
    # relaxation's own optimum: feasible more often than not, and then optimal).
    # At scale 1 (small capacities) the two are the same exact DP: run it once.
    roundings = [("rounded_up", -(-num * wo // den))] + ([("rounded_down", wu)] if num != den else [])
    for name, rounded in roundings:
        if time_limit_s is not None and time.perf_counter() > by(START_DP_SHARE):
            stats.setdefault("skipped", []).append(name)
            continue
        sol = _dp_solution(rounded, po, m)
        value = int(po[sol].sum())
        stats[name] = value if int(wo[sol].sum()) <= c else None
        if stats[name] is not None and value > z:
            best_take = np.zeros(n, dtype=bool)
            best_take[order[sol]] = True
            z = value
    bounds = _Bounds(wu, po, m)
    stats["scale"] = f"{num}/{den}"
    root = int(bounds.at(0)[m])
    stats["root_bound"] = root
    if root <= z:
        out = np.zeros(n_all, dtype=bool)
        out[keep[best_take]] = True
        return Kp01Result(out, z, z, True, {**stats, "stages": 0})
    kern = _kernels()
    cwf = np.concatenate([[0.0], np.cumsum(wo.astype(np.float64))])
    cpf = np.concatenate([[0.0], np.cumsum(po.astype(np.float64))])
    eff = po.astype(np.float64) / wo.astype(np.float64)
    W = np.zeros(1, dtype=np.int64)
    P = np.zeros(1, dtype=np.int64)
    M = np.zeros(1, dtype=np.uint64)
    A = np.zeros(1, dtype=np.int32)
    saved: list[tuple[np.ndarray, np.ndarray]] = []
    best_dp: tuple[int, np.ndarray] | None = None   # (value, items in DP order)
    peak, stopped = 1, None
    s_done = 0
    for s in range(n):
        if time_limit_s is not None and time.perf_counter() - started > time_limit_s:
            stopped = "time limit"
            break
        u_next = bounds.at(s + 1)
        bit = np.uint64(1) << np.uint64(s % _BLOCK)
        W, P, M, A = kern.stage(W, P, M, A, int(wo[s]), int(po[s]), bit, c, u_next, num, den, z, cwf, cpf, eff,
                                s + 1)
        s_done = s + 1
        k = len(W)
        if k == 0:
            break
        peak = max(peak, k)
        if int(P[k - 1]) > z:
            z = int(P[k - 1])
            best_dp = (z, _read_back(M, A, k - 1, saved, s))
        if (s + 1) % _BLOCK == 0:
            saved.append((M, A))
            M = np.zeros(k, dtype=np.uint64)
            A = np.arange(k, dtype=np.int32)
        if k > max_states:
            stopped = f"more than {max_states} states"
            break
    stats.update(stages=s_done, peak_states=int(peak))
    if stopped is None:
        bound = z
        optimal = True
    else:
        stats["stopped"] = stopped
        u_next = bounds.at(s_done)
        live = int((P + u_next[num * (c - W) // den]).max()) if len(W) else z
        bound = max(z, live)
        optimal = bound <= z
    out = np.zeros(n_all, dtype=bool)
    if best_dp is not None:
        items = order[best_dp[1]]
        sel = np.zeros(n, dtype=bool)
        sel[items] = True
    else:
        sel = best_take
    out[keep[sel]] = True
    value = int(p_all[out].sum())
    if int(w_all[out].sum()) > c or value != z:
        raise SolveError(f"kp01: read-back solution ({value}, {int(w_all[out].sum())} bytes) "
                             f"disagrees with the incumbent {z}")   # an internal invariant, not user input
    return Kp01Result(out, value, bound, optimal, stats)


def _read_back(M: np.ndarray, A: np.ndarray, k: int, saved: list[tuple[np.ndarray, np.ndarray]],
               s: int) -> np.ndarray:
    """Stages (DP positions) whose item state ``k`` of stage ``s`` takes."""
    items: list[int] = []
    b = s // _BLOCK
    mask, anc = int(M[k]), int(A[k])
    while True:
        items.extend(b * _BLOCK + j for j in range(_BLOCK) if mask >> j & 1)
        b -= 1
        if b < 0:
            break
        mask, anc = int(saved[b][0][anc]), int(saved[b][1][anc])
    return np.array(sorted(items), dtype=np.int64)
