"""Array core of the single-slot multiple-choice knapsack (MCKP): options, LP hull, bb, dp, fptas.

Length (~1,000 lines, one module on purpose): the option table's padded layout, the LP hull, the
pruning tolerance and the compiled kernels' argument packing are shared by every algorithm here
(bb, dp, fptas, greedy, the rolling schedulers' per-slot calls); split, each piece would import
the others' privates.

Everything here works on a padded option table (:class:`OptionTable`) rather than on an
:class:`~l3gs_opt.problem.instance.Instance`, so that the rolling schedulers can call it each slot
with their own valuation (e.g. future utility). :mod:`l3gs_opt.solvers.mckp` wraps it for
instances and returns :class:`~l3gs_opt.problem.solution.Solution` objects.

Problem, per row ``i`` (an object with something left to gain) and option ``o``::

    max  sum_i value[i, o_i]     s.t.  sum_i cost[i, o_i] <= budget,

where each row takes at most one option (``o_i`` may be "none", cost 0, value 0). Costs are
exact integer bytes (int64), values float64.

Conventions: rows hold their options sorted by cost, Pareto-filtered (value strictly increasing
with cost) and left-packed; ``valid[i, k]`` marks real entries. ``level[i, k]`` says what the
option means for the caller (layered: the top layer reached; separate: the version).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from types import ModuleType

import numpy as np

from l3gs_opt.errors import SolveError

from . import _kp01

__all__ = [
    "BOUND_SLACK",
    "MAX_DP_CELLS",
    "MAX_BB_STATES",
    "OptionTable",
    "LpRelaxation",
    "MckpResult",
    "build_table",
    "hull_increments",
    "lp_relaxation",
    "greedy",
    "branch_and_bound",
    "dynamic_programme",
    "fptas",
    "compiled_kernels",
]

#: Relative slack added to LP and Lagrangian bounds, and used as the pruning tolerance of the
#: branch-and-bound. Why: the upper hull is computed with float64 cross products and values are
#: float64 sums, so a bound can come out low by a few ulps times the number of rows (<= 1e5 rows
#: times 2.2e-16 is about 2e-11 at worst, in practice far less). 1e-11 keeps every reported
#: bound valid and stays two orders of magnitude under ``GAP_TOL`` (1e-9), the gap that counts
#: as proven optimal.
BOUND_SLACK = 1e-11

#: Largest DP table (rows x (capacity + 1) cells, one byte each for the choice) ``dp`` and
#: ``fptas`` accept: 50 M cells is 50 MB for the choices plus two float64 rows.
MAX_DP_CELLS = 50_000_000

#: Largest number of live states the branch-and-bound keeps in one stage before giving up
#: the exact search (it then returns its best answer with a valid bound, status time_limit).
MAX_BB_STATES = 4_000_000

_INT_INF = np.iinfo(np.int64).max

#: Below this many (state, option, multiplier) triples a stage bounds its candidates with every
#: multiplier directly; above it, by binary search in the lower envelope (same value, less work).
_DIRECT_BOUND_CELLS = 60_000

#: The branch-and-bound switches to the compiled stage kernel once its numpy stages have looked at
#: this many candidates (state x option pairs), about 0.3 s of work: importing numba and loading
#: the cached kernels (about 0.5 s, once per process) is then paid only by the DPs that gain from
#: it. The decision depends on the instance only, never on what ran before in the process.
_COMPILED_AFTER = 10_000_000

#: The one-switch completion (:func:`_switch_completion`) runs after stages 1, 2, 4, 8, ... when a
#: stage has at least this many states: small DPs finish before it would pay for itself.
_SWITCH_MIN_STATES = 1000


@dataclass(frozen=True, eq=False)
class OptionTable:
    """The MCKP of one slot as padded arrays.

    Attributes
    ----------
    rows : int array [n]
        The object (j) of each row.
    cost : int64 array [n, K]
        Extra bytes of each option (0 where not valid).
    value : float64 array [n, K]
        Extra utility of each option (0 where not valid).
    valid : bool array [n, K]
        Real options; left-packed, sorted by cost, values strictly increasing.
    level : int array [n, K]
        Layered: the top layer the option reaches (layers ``held_levels[j]..level`` arrive).
        Separate: the version that arrives.
    budget : int
        Bytes available.
    """

    rows: np.ndarray
    cost: np.ndarray
    value: np.ndarray
    valid: np.ndarray
    level: np.ndarray
    budget: int

    @property
    def n(self) -> int:
        return int(self.rows.shape[0])

    @property
    def counts(self) -> np.ndarray:
        return self.valid.sum(axis=1)


def build_table(*, layered: bool, cost: np.ndarray, gain: np.ndarray, held: np.ndarray, budget: int,
                same_slot_layers: bool = True, pareto: bool = True) -> OptionTable:
    """The option table of one slot (vectorised :func:`l3gs_opt.problem.presolve.mckp_options`).

    Parameters
    ----------
    layered : bool
    cost : int array [J, L]
        Bytes per layer (layered) or per whole version (separate).
    gain : float array [J, L]
        Value of showing each chunk: per-layer value (layered, 0 for held layers) or the
        version's value above the best held version, clipped at 0 (separate, 0 for held).
    held : bool array [J, L]
    budget : int
        Bytes available in the slot.
    same_slot_layers : bool
        Layered only: False allows one layer per object (the next one).
    pareto : bool
        Drop options over the budget, worth nothing, or dominated (as the core presolve does).
        Must stay True for :func:`lp_relaxation` and the solvers.
    """
    cost = np.asarray(cost, dtype=np.int64)
    gain = np.asarray(gain, dtype=np.float64)
    held = np.asarray(held, dtype=bool)
    J, L = cost.shape
    if layered:
        h = held.sum(axis=1)
        cc = np.cumsum(cost, axis=1)
        base = np.where(h > 0, cc[np.arange(J), np.maximum(h - 1, 0)], 0) if L else np.zeros(J, np.int64)
        ocost = cc - base[:, None]
        # Held layers have gain 0, so the cumulative sum from layer 0 adds the same terms in the
        # same order as a sum from layer h (exact zeros first): values agree bit for bit.
        ovalue = np.cumsum(np.where(held, 0.0, gain), axis=1)
        lev = np.broadcast_to(np.arange(L), (J, L))
        ok = lev >= h[:, None]
        if not same_slot_layers:
            ok &= lev == h[:, None]
    else:
        ocost = cost.copy()
        ovalue = np.where(held, 0.0, gain)
        lev = np.broadcast_to(np.arange(L), (J, L))
        ok = ~held
    if pareto:
        ok &= (ocost <= budget) & (ovalue > 0)
    key_cost = np.where(ok, ocost, _INT_INF)
    if not layered:
        # Sort each row by (cost ascending, value descending).
        o1 = np.argsort(-np.where(ok, ovalue, -np.inf), axis=1, kind="stable")
        o2 = np.argsort(np.take_along_axis(key_cost, o1, axis=1), axis=1, kind="stable")
        order = np.take_along_axis(o1, o2, axis=1)
        ocost, ovalue, ok, lev = (np.take_along_axis(a, order, axis=1) for a in (ocost, ovalue, ok, np.asarray(lev)))
    if pareto and L > 1:
        vals = np.where(ok, ovalue, -np.inf)
        prev = np.maximum.accumulate(vals, axis=1)
        prev = np.concatenate([np.full((J, 1), -np.inf), prev[:, :-1]], axis=1)
        ok &= ovalue > prev
    # Left-pack the valid entries (unless they already are) and drop rows with none.
    if L > 1 and (ok[:, 1:] & ~ok[:, :-1]).any():
        pack = np.argsort(~ok, axis=1, kind="stable")
        ocost, ovalue, ok, lev = (np.take_along_axis(np.asarray(a), pack, axis=1) for a in (ocost, ovalue, ok, lev))
    lev = np.asarray(lev)
    counts = ok.sum(axis=1)
    K = int(counts.max()) if J else 0
    rows = np.nonzero(counts > 0)[0]
    ok = ok[rows, :K]
    return OptionTable(rows=rows, cost=np.where(ok, ocost[rows, :K], 0), value=np.where(ok, ovalue[rows, :K], 0.0),
                       valid=ok, level=lev[rows, :K].astype(np.int64), budget=int(budget))


# -- LP relaxation ------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class LpRelaxation:
    """The LP relaxation of an :class:`OptionTable` and its greedy rounding.

    Attributes
    ----------
    value : float
        LP optimum (``BOUND_SLACK`` not included).
    slope : float
        Slope (value per byte) of the break increment (0 when everything fits).
    choice : int array [n]
        Option index of each row in the integral part of the LP (-1: none).
    slopes : float array [m]
        Every hull increment's slope, sorted descending (for Lagrangian multipliers).
    break_index : int
        Position of the break increment in ``slopes`` (m when everything fits).
    break_row, break_option : int
        Row and hull option the break increment leads to (-1 when none).
    """

    value: float
    slope: float
    choice: np.ndarray
    slopes: np.ndarray
    break_index: int
    break_row: int
    break_option: int
    inc_cost: np.ndarray | None = None
    inc_value: np.ndarray | None = None


def _hull(table: OptionTable) -> np.ndarray:
    """Bool [n, K]: options on the upper convex hull of {(0, 0)} and the row's options."""
    n, K = table.cost.shape
    c = np.concatenate([np.zeros((n, 1)), table.cost.astype(np.float64)], axis=1)
    v = np.concatenate([np.zeros((n, 1)), table.value], axis=1)
    keep = np.concatenate([np.ones((n, 1), bool), table.valid], axis=1)
    idx = np.broadcast_to(np.arange(K + 1), (n, K + 1))
    while True:
        prev = np.maximum.accumulate(np.where(keep, idx, -1), axis=1)
        prev = np.concatenate([np.full((n, 1), -1), prev[:, :-1]], axis=1)
        nxt = np.flip(np.minimum.accumulate(np.flip(np.where(keep, idx, K + 1), axis=1), axis=1), axis=1)
        nxt = np.concatenate([nxt[:, 1:], np.full((n, 1), K + 1)], axis=1)
        inner = keep & (prev >= 0) & (nxt <= K)
        p = np.clip(prev, 0, K)
        q = np.clip(nxt, 0, K)
        cp, vp = np.take_along_axis(c, p, 1), np.take_along_axis(v, p, 1)
        cq, vq = np.take_along_axis(c, q, 1), np.take_along_axis(v, q, 1)
        # Point i is not a hull vertex when slope(prev, i) <= slope(i, next).
        drop = inner & ((v - vp) * (cq - c) <= (vq - v) * (c - cp))
        if not drop.any():
            return keep[:, 1:]
        keep = keep & ~drop


def hull_increments(table: OptionTable) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every row's upper-hull increments: ``(row, option, bytes, value, slope)``, slopes forced
    non-increasing within a row (a running minimum guards against float ties), unsorted."""
    n, K = table.cost.shape
    hull = _hull(table)
    # Increments between consecutive hull vertices (the origin first).
    hc = np.where(hull, table.cost, 0)
    hv = np.where(hull, table.value, 0.0)
    prev_c = np.maximum.accumulate(hc, axis=1)
    prev_v = np.maximum.accumulate(hv, axis=1)
    prev_c = np.concatenate([np.zeros((n, 1), np.int64), prev_c[:, :-1]], axis=1)
    prev_v = np.concatenate([np.zeros((n, 1)), prev_v[:, :-1]], axis=1)
    rr, kk = np.nonzero(hull)
    dc = (table.cost - prev_c)[rr, kk]
    dv = (table.value - prev_v)[rr, kk]
    slope = dv / dc
    # Within a row slopes decrease; force it in float (a running minimum per row) so that a
    # row's increments are always taken as a prefix.
    # (np.nonzero lists the increments by row, then option: already in row order.)
    starts = np.r_[True, rr[1:] != rr[:-1]]
    for _ in range(K - 1):  # K (levels per row) is small
        slope = np.where(starts, slope, np.minimum(slope, np.r_[np.inf, slope[:-1]]))
    return rr, kk, dc, dv, slope


def lp_relaxation(table: OptionTable) -> LpRelaxation:
    """Solve the LP relaxation by the upper hulls: increments sorted by slope, filled greedily."""
    n, K = table.cost.shape
    if n == 0:
        return LpRelaxation(0.0, 0.0, np.zeros(0, np.int64), np.zeros(0), 0, -1, -1)
    rr, kk, dc, dv, slope = hull_increments(table)
    # Increments come in (row, option) order, so a stable sort keeps a row's ties in order; the
    # (much faster) default sort is used when no two slopes are equal.
    order = np.argsort(-slope)
    if len(order) > 1 and (np.diff(slope[order]) == 0).any():
        order = np.argsort(-slope, kind="stable")
    cum = np.cumsum(dc[order])
    b = int(np.searchsorted(cum, table.budget, side="right"))  # first increment that does not fit
    m = len(order)
    taken = order[:b]
    # A row's taken increments are a prefix of its increments (listed by row, then option):
    # the choice is the option of the last one taken.
    mark = np.zeros(len(rr), dtype=bool)
    mark[taken] = True
    last = mark & ~np.r_[mark[1:] & (rr[1:] == rr[:-1]), False]
    choice = np.full(n, -1, dtype=np.int64)
    choice[rr[last]] = kk[last]
    value = float(dv[taken].sum())
    used = int(cum[b - 1]) if b > 0 else 0
    if b < m:
        k = order[b]
        value += (table.budget - used) / dc[k] * dv[k]
        lam = float(slope[k])
        brow, bopt = int(rr[k]), int(kk[k])
    else:
        lam, brow, bopt = 0.0, -1, -1
    return LpRelaxation(value=value, slope=lam, choice=choice, slopes=slope[order], break_index=b,
                        inc_cost=dc[order], inc_value=dv[order],
                        break_row=brow, break_option=bopt)


# -- results --------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class MckpResult:
    """Chosen option per row (-1: none), the value of that choice, a valid upper bound, and
    whether the answer is proven optimal."""

    choice: np.ndarray
    value: float
    bound: float
    optimal: bool
    stats: dict


def _pick(table: OptionTable, choice: np.ndarray) -> tuple[int, float]:
    sel = choice >= 0
    r = np.nonzero(sel)[0]
    return int(table.cost[r, choice[r]].sum()), math.fsum(table.value[r, choice[r]].tolist())


def _improve(table: OptionTable, choice: np.ndarray, rounds: int = 64) -> np.ndarray:
    """Greedy fill: repeatedly apply the single most valuable upgrade that fits the spare bytes."""
    choice = choice.copy()
    n = table.n
    if n == 0:
        return choice
    ar = np.arange(n)
    has = choice >= 0
    cur_c = np.where(has, table.cost[ar, np.maximum(choice, 0)], 0)
    cur_v = np.where(has, table.value[ar, np.maximum(choice, 0)], 0.0)
    spare = table.budget - int(cur_c.sum())
    K = table.cost.shape[1]
    for _ in range(rounds):
        gain = np.where(table.valid & (table.cost - cur_c[:, None] <= spare), table.value - cur_v[:, None], -np.inf)
        flat = int(np.argmax(gain))
        i, k = divmod(flat, K)
        if not gain[i, k] > 0:
            break
        spare -= int(table.cost[i, k] - cur_c[i])
        cur_c[i], cur_v[i], choice[i] = table.cost[i, k], table.value[i, k], k
    return choice


def _swap(table: OptionTable, choice: np.ndarray, lam: float, rounds: int = 8, width: int = 256) -> np.ndarray:
    """Pair moves: change one row's option to a cheaper one and another's to a dearer one when
    together they fit the spare bytes and gain value. Candidates are the ``width`` moves of
    each kind with the best reduced gain ``dv - lam * dc``."""
    choice = choice.copy()
    n, K = table.cost.shape
    ar = np.arange(n)
    for _ in range(rounds):
        used, _ = _pick(table, choice)
        spare = table.budget - used
        cur_c = np.where(choice >= 0, table.cost[ar, np.maximum(choice, 0)], 0)
        cur_v = np.where(choice >= 0, table.value[ar, np.maximum(choice, 0)], 0.0)
        # Moves to every option and to "none" (column K).
        dc = np.concatenate([table.cost, np.zeros((n, 1), np.int64)], axis=1) - cur_c[:, None]
        dv = np.concatenate([table.value, np.zeros((n, 1))], axis=1) - cur_v[:, None]
        ok = np.concatenate([table.valid, np.ones((n, 1), bool)], axis=1)
        red = dv - lam * dc
        up = ok & (dc > 0) & (dc <= spare + table.budget)
        down = ok & (dc < 0)
        if not up.any() or not down.any():
            break
        def top(mask: np.ndarray) -> np.ndarray:
            flat = np.nonzero(mask.ravel())[0]
            if len(flat) > width:
                flat = flat[np.argpartition(-red.ravel()[flat], width)[:width]]
            return flat
        u, d = top(up), top(down)
        ur, dr = u // (K + 1), d // (K + 1)
        tot_c = dc.ravel()[u][:, None] + dc.ravel()[d][None, :]
        tot_v = dv.ravel()[u][:, None] + dv.ravel()[d][None, :]
        good = (tot_c <= spare) & (ur[:, None] != dr[None, :]) & (tot_v > 0)
        if not good.any():
            break
        x, y = np.unravel_index(int(np.argmax(np.where(good, tot_v, -np.inf))), good.shape)
        for flat in (u[x], d[y]):
            i, o = divmod(int(flat), K + 1)
            choice[i] = o if o < K else -1
        choice = _improve(table, choice, rounds=4)
    return choice


def greedy(table: OptionTable, lp: LpRelaxation | None = None) -> MckpResult:
    """LP-greedy: the integral part of the LP, then the best upgrades that still fit; also tries
    the break option alone, so the answer is at least half the LP value."""
    lp = lp_relaxation(table) if lp is None else lp
    choice = _improve(table, lp.choice)
    if lp.break_row >= 0:
        choice = _swap(table, choice, lp.slope)
    _, value = _pick(table, choice)
    if lp.break_row >= 0:
        alone = np.full(table.n, -1, dtype=np.int64)
        alone[lp.break_row] = lp.break_option
        alone = _improve(table, alone)
        _, v2 = _pick(table, alone)
        if v2 > value:
            choice, value = alone, v2
    bound = max(lp.value * (1 + BOUND_SLACK), value)
    return MckpResult(choice=choice, value=value, bound=bound, optimal=False, stats={"lp": lp.value})


# -- branch and bound ------------------------------------------------------------------------------

def _multipliers(lp: LpRelaxation) -> np.ndarray:
    """Lagrange multipliers to bound with, ascending: the break slope and the slopes of
    increments at geometrically growing distances from it (ratio 1.25, either side), so that
    the bound stays tight while the core grows away from the break."""
    m = len(lp.slopes)
    if m == 0 or lp.break_index >= m:
        return np.array([lp.slope])
    steps = np.unique(np.round(1.25 ** np.arange(int(np.log(m) / np.log(1.25)) + 2)).astype(np.int64))
    pos = lp.break_index + np.concatenate([[0], steps, -steps])
    pos = np.clip(pos, 0, m - 1)
    lams = np.unique(np.concatenate([[lp.slope], lp.slopes[pos], [0.0]]))
    return lams[lams >= 0]


def _envelope(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lower envelope of the lines ``a_k + b_k x`` on ``x >= 0``: (intercepts, slopes, start x)
    of the pieces, by increasing x. ``b`` must be ascending (as :func:`_multipliers` gives)."""
    ha: list[float] = []
    hb: list[float] = []
    hs: list[float] = []
    for k in range(len(b) - 1, -1, -1):          # slopes descending
        ak, bk = float(a[k]), float(b[k])
        if hb and hb[-1] == bk:
            if ak >= ha[-1]:
                continue
            ha.pop(), hb.pop(), hs.pop()
        x = 0.0
        while hb:
            x = (ak - ha[-1]) / (hb[-1] - bk)      # the new line is lower for x > this
            if x <= 0.0 or (len(hb) > 1 and x <= hs[-1]):
                ha.pop(), hb.pop(), hs.pop()
                x = 0.0
                continue
            break
        ha.append(ak)
        hb.append(bk)
        hs.append(x if len(hb) > 1 else 0.0)
    return np.asarray(ha), np.asarray(hb), np.asarray(hs)


def _integral_values(table: OptionTable, tol: float) -> bool:
    """True when every option value is an integer and every sum of them is exact in float64.

    Then every solution's value is an integer, so a better one than ``z`` is worth at least
    ``z + 1``: a bound below that (less ``2 tol`` for the bound's own round-off) cuts.
    """
    vals = table.value[table.valid]
    if vals.size == 0 or tol >= 0.25:
        return False
    if not bool((vals == np.floor(vals)).all()):
        return False
    return float(table.value.max(axis=1).sum()) < 2.0 ** 52


def _cut_level(z: float, tol: float, integral: bool) -> float:
    """A bound must exceed this for its solutions to possibly beat ``z`` (see ``BOUND_SLACK``):
    ``z + tol``, or with integral values ``z + 1 - 2 tol`` (bounds can come out ``tol`` low)."""
    return z + max(tol, 1.0 - 2.0 * tol) if integral else z + tol


def _cut_bound(ub: float, z: float, integral: bool) -> float:
    """What a part cut at bound ``ub`` (no more than the cut level of ``z``) contributes to the
    reported bound: ``ub``, or with integral values at most ``z`` (its solutions are integers
    below ``z + 1``)."""
    return min(ub, z) if integral else ub


@dataclass(frozen=True, eq=False)
class _Reduced:
    lams: np.ndarray          # [q] multipliers, ascending
    root: np.ndarray          # [q] Lagrangian bound per multiplier
    fixed_bound: np.ndarray   # [n, K+1] bound with row i at option o (column K: none)
    allowed: np.ndarray       # [n, K+1] options that may still beat z
    discarded: float          # largest bound of a removed option (-inf: none)
    costs_ext: np.ndarray     # [n, K+1]
    vals_ext: np.ndarray      # [n, K+1]


def _reduce(table: OptionTable, lp: LpRelaxation, z: float, tol: float, *, integral: bool = False) -> _Reduced:
    """Lagrangian reduction: drop every option no solution better than ``z`` can use (bound not
    above :func:`_cut_level`).

    For any multiplier ``lam >= 0``, ``sum_i max_o (v - lam c) + lam * budget`` bounds every
    solution; fixing row i to option o lowers that by the option's reduced-profit shortfall.
    """
    n, K = table.cost.shape
    B = table.budget
    cut = _cut_level(z, tol, integral)
    lams = _multipliers(lp)                                      # [q], ascending
    q = len(lams)
    costs_ext = np.concatenate([table.cost, np.zeros((n, 1), np.int64)], axis=1)   # column K: none
    vals_ext = np.concatenate([table.value, np.zeros((n, 1))], axis=1)
    valid_ext = np.concatenate([table.valid, np.ones((n, 1), bool)], axis=1)
    # F(lam) = sum_i max(0, max_o v - lam c) = sum of (dv - lam dc) over the hull increments
    # steeper than lam (each row's hull is concave), from prefix sums of the sorted increments.
    pos = np.searchsorted(-lp.slopes, -lams, side="left")
    cum_c = np.r_[0.0, np.cumsum(lp.inc_cost.astype(np.float64))]
    cum_v = np.r_[0.0, np.cumsum(lp.inc_value)]
    F = cum_v[pos] - lams * cum_c[pos]
    root = F + lams * B
    # Reduction, first with the best multiplier alone on every row (cheap), then with all
    # multipliers on the rows that test leaves open. fixed_bound[i, o] is a valid bound on every
    # solution with row i at option o (column K: none).
    kb = int(np.argmin(root))
    red0 = np.where(valid_ext, vals_ext - costs_ext * lams[kb], -np.inf)
    fixed_bound = root[kb] - red0.max(axis=1, keepdims=True) + red0
    open_rows = np.nonzero((valid_ext & (fixed_bound > cut)).sum(axis=1) > 1)[0]
    chunk = max(1, 2_000_000 // ((K + 1) * q))
    for lo in range(0, len(open_rows), chunk):
        rows = open_rows[lo:lo + chunk]
        red = np.where(valid_ext[rows][:, :, None],
                       vals_ext[rows][:, :, None] - costs_ext[rows][:, :, None].astype(np.float64) * lams, -np.inf)
        f_rows = red.max(axis=1)
        fixed_bound[rows] = np.minimum(fixed_bound[rows],
                                       (root[None, None, :] - f_rows[:, None, :] + red).min(axis=2))
    allowed = valid_ext & (fixed_bound > cut)
    removed = valid_ext & ~allowed
    discarded = _cut_bound(float(fixed_bound[removed].max()), z, integral) if removed.any() else -np.inf
    return _Reduced(lams=lams, root=root, fixed_bound=fixed_bound, allowed=allowed, discarded=discarded,
                    costs_ext=costs_ext, vals_ext=vals_ext)


def _stage_numpy(W: np.ndarray, P: np.ndarray, c_o: np.ndarray, v_o: np.ndarray, budget: int, cap: int,
                 F_rest: np.ndarray, lams: np.ndarray, cut: float, opt_ids: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """One DP stage in numpy: every state times every option, bounded, Pareto-filtered.

    Parameters
    ----------
    W : int64 array [m]
        Bytes of each state, strictly ascending.
    P : float64 array [m]
        Value of each state, strictly ascending.
    c_o, v_o : int64 / float64 arrays [k]
        Bytes and value of the row's options still allowed (any order; equal bytes go to the
        earlier option unless a later one is worth strictly more).
    budget, cap : int
        Bytes available; a candidate is feasible when its bytes are at most ``cap`` (the budget
        less the least the rows not yet added must use).
    F_rest, lams : float64 arrays [q]
        Lagrangian contribution of the rows not yet added at each multiplier (ascending): a
        candidate's bound is ``P + v + min_k (F_rest[k] + lams[k] * (budget - W - c))``.
    cut : float
        Candidates whose bound is not above this are dropped (:func:`_cut_level`).
    opt_ids : int array [k]
        What to record for each option (its column in the option table), in the dtype to keep.

    Returns
    -------
    (W, P, parent, pick, dead) : the new states (bytes ascending), each one's parent state
    (int32) and option id (from ``opt_ids``), and the largest bound of a feasible candidate the
    bound cut (-inf if none).
    """
    m = len(W)
    k_opts = len(c_o)
    # All candidates at once, option-major ([options, states]): each option's row is sorted
    # by bytes because the states are. Bounds: every multiplier directly while that is
    # cheap, else a binary search in the lower envelope of F_rest[k] + lam[k] * (bytes left).
    Wm = W[None, :] + c_o[:, None]
    Pm = P[None, :] + v_o[:, None]
    feas = Wm <= cap
    d = (budget - Wm).astype(np.float64)
    if m * k_opts * len(lams) <= _DIRECT_BOUND_CELLS:
        ub = Pm + (F_rest[None, None, :] + d[:, :, None] * lams[None, None, :]).min(axis=2)
    else:
        env_a, env_b, env_s = _envelope(F_rest, lams)
        # Piece index k[t, s] = #{pieces whose start <= bytes left} - 1, found from the
        # thresholds in byte space (W sorted): cheaper than a search per candidate.
        ne = len(env_s)
        pos = np.searchsorted(W, (budget - c_o[:, None] - env_s[None, :]).ravel(), side="right").reshape(k_opts, ne)
        steps = np.zeros((k_opts, m + 1), dtype=np.int64)
        steps[:, 0] = ne
        np.add.at(steps, (np.repeat(np.arange(k_opts), ne), pos.ravel()), -1)
        k = np.cumsum(steps, axis=1)[:, :m] - 1
        ub = Pm + env_a[k] + env_b[k] * d
    live = feas & (ub > cut)
    dead_mask = feas & ~live
    dead = float(ub[dead_mask].max()) if dead_mask.any() else -np.inf
    sel = np.flatnonzero(live)
    nW, nP, nI = Wm.ravel()[sel], Pm.ravel()[sel], sel
    if k_opts > 1 and len(nW) > 1:
        srt = np.argsort(nW, kind="stable")   # merges the sorted rows (runs)
        nW, nP, nI = nW[srt], nP[srt], nI[srt]
    if len(nP) > 1:
        # Undominated: value strictly above every cheaper-or-equal state kept before; of
        # equal-byte states only the last kept (the most valuable) survives.
        run = np.maximum.accumulate(nP)
        keep = np.empty(len(nP), bool)
        keep[0] = True
        np.greater(nP[1:], run[:-1], out=keep[1:])
        nW, nP, nI = nW[keep], nP[keep], nI[keep]
        last = np.empty(len(nW), bool)
        last[-1] = True
        np.not_equal(nW[1:], nW[:-1], out=last[:-1])
        if not last.all():
            nW, nP, nI = nW[last], nP[last], nI[last]
    pick, parent = np.divmod(nI, max(m, 1))
    return nW, nP, parent.astype(np.int32), opt_ids[pick], dead


def _switch_completion(W: np.ndarray, P: np.ndarray, rest: np.ndarray, allowed: np.ndarray, costs_ext: np.ndarray,
                       vals_ext: np.ndarray, a_idx: np.ndarray, a_cost: np.ndarray, a_val: np.ndarray, spare0: int,
                       comp_v: float) -> tuple[float, int, int, int] | None:
    """Best completion of the states by the LP choices of the rows ``rest`` with one of them
    moved to another allowed option (columns of ``costs_ext``; K: none).

    A state (``W``, ``P``) completed by the LP choices has ``spare0 - W`` bytes left; a move of
    ``dc`` bytes and ``dv`` value fits when ``dc <= spare0 - W``. Returns (value, state, row,
    option) of the best, or None when no move fits any state.
    """
    n_rest = len(rest)
    moves = allowed[rest].copy()
    moves[np.arange(n_rest), a_idx[rest]] = False
    rr, oo = np.nonzero(moves)
    if len(rr) == 0 or len(W) == 0:
        return None
    rows = rest[rr]
    dc = costs_ext[rows, oo] - a_cost[rows]
    dv = vals_ext[rows, oo] - a_val[rows]
    order = np.argsort(dc, kind="stable")
    dc, dv = dc[order], dv[order]
    # best[t]: the most valuable of the moves 0..t (the ones costing at most dc[t]).
    run = np.maximum.accumulate(dv)
    best = np.maximum.accumulate(np.where(dv == run, np.arange(len(dv)), 0))
    pos = np.searchsorted(dc, spare0 - W, side="right") - 1
    fits = pos >= 0
    if not fits.any():
        return None
    value = np.where(fits, P + comp_v + dv[best[np.maximum(pos, 0)]], -np.inf)
    k = int(np.argmax(value))
    t = order[best[pos[k]]]
    return float(value[k]), k, int(rows[t]), int(oo[t])


_KERNELS: object = None    # the compiled kernels module, False when numba is missing, None: not tried


def compiled_kernels() -> ModuleType | None:
    """The numba stage kernels (:mod:`l3gs_opt.solvers._mckp_kernels`), or None without numba.

    Imported on first call: numba costs a few tenths of a second to import, and the kernels
    are compiled once per machine (cached on disk) on first use.
    """
    global _KERNELS
    if _KERNELS is None:
        try:
            from . import _mckp_kernels
        except ImportError:
            _KERNELS = False
        else:
            _KERNELS = _mckp_kernels
    return _KERNELS or None


def branch_and_bound(table: OptionTable, *, time_limit_s: float | None = None,
                     max_states: int = MAX_BB_STATES, compiled: bool | None = None) -> MckpResult:
    """Exact MCKP: LP bound, Lagrangian reduction, then a bounded dynamic programme over the
    rows that are not fixed (an expanding core in the spirit of Pisinger's minimal algorithm).

    1. LP relaxation from the upper hulls; the greedy rounding gives an incumbent ``z``.
    2. For multipliers ``lam`` (the break slope and slopes at growing distances from it) the
       Lagrangian bound ``sum_i max_o (v - lam c) + lam * budget`` holds for every solution;
       fixing row i to option o lowers it by that option's reduced-profit shortfall. Options
       whose bound is no better than ``z`` (within ``BOUND_SLACK``) are removed; rows left
       with one option are fixed.
    3. The remaining rows are added one at a time (closest to the break first) to a list of
       undominated partial solutions (bytes, value) - Nemhauser-Ullmann states, exact in
       integer bytes. Each state is bounded by ``value + min_lam (F_rest(lam) + lam *
       (budget - bytes))`` (the lower envelope of those lines) and pruned when that is no
       better than ``z``; completing a state with the LP choices of the rows not yet added may
       improve ``z``, and each row's options are checked against the current ``z`` again
       before it is added.

    When every value is an integer (and their sums are exact in float64), every solution is an
    integer, so "better than ``z``" means at least ``z + 1``: bounds below that cut (Pisinger's
    codes do the same with integer profits). On Pisinger's strongly correlated class (LP gap of
    2-7 units on values near 2.6e7) that removes 30-75 % of the DP's candidates.

    Besides the LP choices, the states are completed (after stages 1, 2, 4, ... of large DPs)
    with one row of the rest moved to another option (:func:`_switch_completion`): on weakly
    correlated instances, whose LP bound is often attained, that finds the optimum within a few
    stages, and the cut then ends the DP.

    A stage (:func:`_stage_numpy`) merges the options' runs of states, each sorted by bytes. Large
    DPs run their stages in a compiled kernel (:func:`l3gs_opt.solvers._mckp_kernels.stage`,
    numba) that gives the same states with the same float64 arithmetic, 3-5x faster. ``compiled``:
    None (default) switches to it once the numpy stages have looked at ``_COMPILED_AFTER``
    candidates (numba's import is not worth it for small DPs), True uses it for every stage with
    more than one option, False never; without numba the numpy path runs in every case.

    A 0-1 knapsack (one option per row) with integer values goes first to the exact integer search of
    :func:`l3gs_opt.solvers._kp01.solve_kp01` (relaxed-DP and LP bounds on Pareto states) for half
    the time left after a short first try of the search above (``_KP01_QUICK_S``), then, if
    unproven, to the search above again on the rest; the better answer and the lower of the
    (valid) bounds are returned.

    The reported bound is the largest bound of anything pruned (or, when stopped early, of any
    live state), never below ``z``: a valid upper bound in every case.
    """
    started = time.perf_counter()
    n, K = table.cost.shape
    stats: dict = {"rows": n}
    if n == 0:
        return MckpResult(np.zeros(0, np.int64), 0.0, 0.0, True, stats)
    if K == 1 and _kp01.fits_kp01(table.cost[:, 0], table.value[:, 0]):
        return _branch_and_bound_01(table, time_limit_s=time_limit_s, max_states=max_states, compiled=compiled)
    return _branch_and_bound_mckp(table, time_limit_s=time_limit_s, max_states=max_states, compiled=compiled,
                                  started=started)


#: Share of ``bb``'s time limit the integer 0-1 search (:mod:`l3gs_opt.solvers._kp01`) gets before
#: the Lagrangian state DP takes over on what remains: each proves instances the other does not
#: (Jooken et al.'s set: the relaxed-DP bound sees that items are indivisible, the Lagrangian
#: envelope orders and cuts the core better on others).
_KP01_SHARE = 0.5

#: Seconds (at most a tenth of the time limit) the MCKP search gets on a 0-1 table before the
#: integer search starts.
_KP01_QUICK_S = 1.0


def _float_up(x: int) -> float:
    """The least float64 >= the integer ``x`` (an exact bound stays a bound above 2**53)."""
    f = float(x)
    return math.nextafter(f, math.inf) if f < x else f


def _branch_and_bound_01(table: OptionTable, *, time_limit_s: float | None, max_states: int,
                         compiled: bool | None) -> MckpResult:
    """0-1 knapsack with integer values: the exact integer search first, then (if it has not
    proven its answer) the MCKP state DP on the time left; the better answer, the lower bound."""
    started = time.perf_counter()
    # A short try of the MCKP search first: it proves most 0-1 instances (Pisinger's) in
    # milliseconds, before the integer search builds its bound tables (tenths of a second).
    quick = _KP01_QUICK_S if time_limit_s is None else min(_KP01_QUICK_S, 0.1 * time_limit_s)
    early = _branch_and_bound_mckp(table, time_limit_s=quick, max_states=max_states, compiled=compiled,
                                   started=started)
    left = None if time_limit_s is None else max(0.0, time_limit_s - (time.perf_counter() - started))
    if early.optimal or compiled_kernels() is None:   # the integer search's stage needs numba
        if early.optimal or left == 0.0:
            return early
        return _branch_and_bound_mckp(table, time_limit_s=left, max_states=max_states, compiled=compiled,
                                      started=time.perf_counter())
    first = None if left is None else left * _KP01_SHARE
    kp = _kp01.solve_kp01(table.cost[:, 0], table.value[:, 0], table.budget, time_limit_s=first,
                          incumbent=early.choice >= 0)
    choice = np.where(kp.take, 0, -1).astype(np.int64)
    value = _pick(table, choice)[1]
    stats = {"rows": table.n, **{f"kp01_{k}": v for k, v in kp.stats.items()}}
    if kp.optimal:
        return MckpResult(choice, value, max(value, _float_up(kp.bound)), True, stats)
    left = None if time_limit_s is None else max(0.0, time_limit_s - (time.perf_counter() - started))
    other = _branch_and_bound_mckp(table, time_limit_s=left, max_states=max_states, compiled=compiled,
                                   started=time.perf_counter())
    stats.update(other.stats)
    bound = min(_float_up(kp.bound), other.bound)
    if other.value > value:
        choice, value = other.choice, other.value
    optimal = other.optimal or bound <= value
    return MckpResult(choice, value, max(bound, value), optimal, stats)


def _branch_and_bound_mckp(table: OptionTable, *, time_limit_s: float | None, max_states: int,
                           compiled: bool | None, started: float) -> MckpResult:
    """The MCKP search of :func:`branch_and_bound` (any table)."""
    n, K = table.cost.shape
    stats: dict = {"rows": n}
    lp = lp_relaxation(table)
    inc = greedy(table, lp)
    z, best_choice = inc.value, inc.choice
    stats["lp"] = float(lp.value)
    stats["greedy"] = z
    tol = BOUND_SLACK * max(abs(lp.value), 1e-300)
    integral = _integral_values(table, tol)
    stats["integral"] = integral
    if lp.break_index >= len(lp.slopes) or lp.value <= _cut_level(z, tol, integral):
        bound = _cut_bound(lp.value + tol, z, integral) if lp.break_index < len(lp.slopes) else lp.value + tol
        return MckpResult(best_choice, z, max(z, bound), True, {**stats, "core": 0})
    B = table.budget
    red_ = _reduce(table, lp, z, tol, integral=integral)
    lams, root, fixed_bound, allowed, discarded = red_.lams, red_.root, red_.fixed_bound, red_.allowed, red_.discarded
    costs_ext, vals_ext = red_.costs_ext, red_.vals_ext
    q = len(lams)
    stats["multipliers"] = q
    ub_root = float(root.min())
    chunk = max(1, 2_000_000 // ((K + 1) * q))
    cnt = allowed.sum(axis=1)
    if (cnt == 0).any():   # some row has no option left: nothing beats z
        return MckpResult(best_choice, z, max(z, discarded), True, {**stats, "core": 0})
    a = lp.choice                                                 # LP integral choice (-1: none)
    ar = np.arange(n)
    a_cost = np.where(a >= 0, table.cost[ar, np.maximum(a, 0)], 0)
    a_val = np.where(a >= 0, table.value[ar, np.maximum(a, 0)], 0.0)
    a_idx = np.where(a >= 0, a, K)
    fixed = cnt == 1
    fix_idx = np.argmax(allowed, axis=1)
    fr = np.nonzero(fixed)[0]
    W0 = int(costs_ext[fr, fix_idx[fr]].sum())
    P0 = math.fsum(vals_ext[fr, fix_idx[fr]].tolist())
    free = np.nonzero(~fixed)[0]
    # Order: rows whose best alternative to the LP choice loses least in the bound first.
    alt = np.where(allowed[free], fixed_bound[free], -np.inf)
    alt[np.arange(len(free)), a_idx[free]] = -np.inf
    order = np.argsort(-alt.max(axis=1), kind="stable")
    free = free[order]
    # Bound contributions of the free rows restricted to their allowed options.
    f_free = np.empty((len(free), q))
    for lo in range(0, len(free), chunk):
        rows = free[lo:lo + chunk]
        red = np.where(allowed[rows][:, :, None],
                       vals_ext[rows][:, :, None] - costs_ext[rows][:, :, None].astype(np.float64) * lams, -np.inf)
        f_free[lo:lo + chunk] = red.max(axis=1)
    stats["core"] = int(len(free))
    stats["fixed"] = int(len(fr))
    F_rest = f_free.sum(axis=0)   # bound contribution of free rows not yet added
    min_cost_free = np.where(allowed[free], costs_ext[free], _INT_INF).min(axis=1)
    min_rest = int(min_cost_free.sum())
    comp_c_rest = int(a_cost[free].sum())
    comp_v_rest = float(a_val[free].sum())
    W = np.array([W0], dtype=np.int64)
    P = np.array([P0])
    parents: list[np.ndarray] = []
    picks: list[np.ndarray] = []
    best_at: tuple[int, int, int, int] | None = None  # (stage, state, switched row, its option) of the incumbent
    next_switch = 1         # stage count at which the one-switch completion runs next (doubles)
    switch_found = 0
    z_root = z
    cut = _cut_level(z, tol, integral)
    stopped = None
    peak = 1
    kernels = compiled_kernels() if compiled else None
    compiled_stages = 0
    candidates = 0          # (state, option) pairs the stages have looked at
    pick_dtype = _choice_dtype(K + 1)

    def bound_of(P_: np.ndarray, W_: np.ndarray, F_: np.ndarray) -> np.ndarray:
        ea, eb, es = _envelope(F_, lams)
        d = (B - W_).astype(np.float64)
        k = np.searchsorted(es, d, side="right") - 1
        return P_ + ea[k] + eb[k] * d

    for s, i in enumerate(free):
        if time_limit_s is not None and time.perf_counter() - started > time_limit_s:
            stopped = "time limit"
            break
        # Options of this row that may still beat the incumbent (z only grows).
        if z > z_root:
            still = allowed[i] & (fixed_bound[i] > cut)
            gone = allowed[i] & ~still
            if gone.any():
                discarded = max(discarded, _cut_bound(float(fixed_bound[i][gone].max()), z, integral))
            opts = np.nonzero(still)[0]
        else:
            opts = np.nonzero(allowed[i])[0]
        c_o, v_o = costs_ext[i, opts], vals_ext[i, opts]
        F_rest = F_rest - f_free[s]
        min_rest -= int(min_cost_free[s])
        comp_c_rest -= int(a_cost[i])
        comp_v_rest -= float(a_val[i])
        m = len(W)
        if len(opts) == 1 and m:
            # The incumbent has fixed this row: shift every state by its one option.
            c1, v1 = int(c_o[0]), float(v_o[0])
            keep_idx = np.nonzero(W + c1 <= B - min_rest)[0]
            W, P = W[keep_idx] + c1, P[keep_idx] + v1
            parents.append(keep_idx.astype(np.uint16 if m <= 65536 else np.int32))
            picks.append(np.full(len(W), opts[0], dtype=pick_dtype))
            if len(W) == 0:
                break
            continue
        if kernels is None and compiled is None and candidates >= _COMPILED_AFTER:
            kernels = compiled_kernels()
        candidates += m * len(opts)
        opt_ids = opts.astype(pick_dtype)
        if kernels is not None:
            W, P, parent, pick, dead = kernels.stage(W, P, c_o, v_o, B, B - min_rest, F_rest, lams, cut, opt_ids)
            compiled_stages += 1
        else:
            W, P, parent, pick, dead = _stage_numpy(W, P, c_o, v_o, B, B - min_rest, F_rest, lams, cut, opt_ids)
        if dead > -np.inf:
            discarded = max(discarded, _cut_bound(dead, z, integral))
        # Back-pointers in compact types (they are kept for every stage): 3 bytes a state while
        # the previous stage has at most 65,536 states.
        parents.append(parent.astype(np.uint16) if m <= 65536 else parent)
        picks.append(pick)
        peak = max(peak, len(W))
        if len(W) == 0:
            break
        # Complete with the LP choices of the rows not yet added. The states' values rise with
        # their bytes, so the best completion is the last state that fits.
        k = int(np.searchsorted(W, B - comp_c_rest, side="right")) - 1
        if k >= 0 and P[k] + comp_v_rest > z:
            z, best_at = float(P[k] + comp_v_rest), (s, k, -1, -1)
            cut = _cut_level(z, tol, integral)
        if len(W) >= _SWITCH_MIN_STATES and s + 1 >= next_switch and s + 1 < len(free):
            # Also complete with one row of the rest moved off its LP choice, which fills the bytes
            # the LP choices leave (or frees those they overrun): it finds solutions worth the LP
            # bound long before the DP reaches the rows that make them (weakly correlated ties).
            next_switch = 2 * (s + 1)
            found = _switch_completion(W, P, free[s + 1:], allowed, costs_ext, vals_ext, a_idx, a_cost, a_val,
                                       B - comp_c_rest, comp_v_rest)
            if found is not None and found[0] > z:
                z, best_at = found[0], (s, *found[1:])
                cut = _cut_level(z, tol, integral)
                switch_found += 1
        if len(W) > max_states:
            stopped = f"more than {max_states} states"
            break
    stats["stages"] = len(parents)
    stats["peak_states"] = int(peak)
    stats["compiled_stages"] = compiled_stages
    stats["candidates"] = candidates
    if stopped is None:
        bound = max(z, discarded)
        optimal = True
    else:
        live_ub = ub_root
        if parents and len(W):
            live_ub = float(bound_of(P, W, F_rest).max())
        bound = max(z, discarded, live_ub)
        optimal = False
        stats["stopped"] = stopped
    stats["switch_incumbents"] = switch_found
    if best_at is not None:
        s, k, row, opt = best_at
        stats["incumbent_stage"] = s
        choice = np.where(a >= 0, a, -1)
        choice[fr] = np.where(fix_idx[fr] < K, fix_idx[fr], -1)
        for stage in range(s, -1, -1):
            o = int(picks[stage][k])
            choice[free[stage]] = o if o < K else -1
            k = int(parents[stage][k])
        if row >= 0:
            choice[row] = opt if opt < K else -1
        best_choice = choice
        # The incumbent value is recomputed from the choice (float sums in one order).
        z = _pick(table, best_choice)[1]
    return MckpResult(best_choice, z, max(bound, z), optimal, stats)


# -- dynamic programmes ----------------------------------------------------------------------------

def _choice_dtype(K: int) -> type:
    return np.uint8 if K < 255 else np.uint16


def dynamic_programme(table: OptionTable, *, max_cells: int = MAX_DP_CELLS) -> MckpResult:
    """Exact DP over bytes divided by the greatest common divisor of every option cost.

    ``best[w]`` is the largest value with at most ``w`` units; one pass per row, one numpy
    operation per option. Memory: one byte per (row, unit) for the choices.

    Raises
    ------
    SolveError
        When rows x (capacity + 1) exceeds ``max_cells``.
    """
    n, K = table.cost.shape
    if n == 0:
        return MckpResult(np.zeros(0, np.int64), 0.0, 0.0, True, {"rows": 0})
    g = int(np.gcd.reduce(table.cost[table.valid]))
    cap = table.budget // g
    cells = n * (cap + 1)
    if cells > max_cells:
        raise SolveError(f"dp: the table would have {n} rows x {cap + 1} byte units (gcd {g} bytes) = {cells} "
                         f"cells, more than the limit of {max_cells}; use bb or fptas:EPS")
    units = table.cost // g
    best = np.zeros(cap + 1)
    choice = np.zeros((n, cap + 1), dtype=_choice_dtype(K))
    for i in range(n):
        new = best.copy()
        row = choice[i]
        for k in range(int(table.valid[i].sum())):
            c = int(units[i, k])
            cand = best[:cap + 1 - c] + table.value[i, k]
            tgt = new[c:]
            better = cand > tgt
            tgt[better] = cand[better]
            row[c:][better] = k + 1
        best = new
    out = np.full(n, -1, dtype=np.int64)
    w = cap
    for i in range(n - 1, -1, -1):
        k = int(choice[i, w])
        if k:
            out[i] = k - 1
            w -= int(units[i, k - 1])
    value = _pick(table, out)[1]
    return MckpResult(out, value, max(value, float(best[cap])), True,
                      {"rows": n, "gcd": g, "capacity_units": cap, "cells": cells})


def fptas(table: OptionTable, eps: float, *, max_cells: int = MAX_DP_CELLS) -> MckpResult:
    """(1 - eps)-approximation by profit scaling, on the rows the Lagrangian reduction leaves open.

    With a feasible value ``z0 >= LP/2`` (the greedy), the reduction of :func:`branch_and_bound`
    removes options no solution better than ``z0`` can use; rows left with one option are
    fixed. On the ``n`` open rows, values are scaled by ``k = eps * z0 / n`` to ``floor(v / k)``
    and a DP over scaled profit finds the least bytes for each profit. For the optimum S*
    (which, if better than ``z0``, uses only options kept): ``OPT <= P_fixed + k * (best scaled
    profit) + n k <= value + eps z0``, so ``value >= (1 - eps) OPT``, and ``P_fixed + k * best +
    n k`` is a valid bound. Run time O(options * n / eps).

    Raises
    ------
    SolveError
        For eps outside (0, 1), or when open rows x scaled-profit range exceeds ``max_cells``.
    """
    if not (0 < eps < 1):
        raise SolveError(f"fptas: eps = {eps!r}: must be in (0, 1)")
    n_all, K = table.cost.shape
    if n_all == 0:
        return MckpResult(np.zeros(0, np.int64), 0.0, 0.0, True, {"rows": 0})
    lp = lp_relaxation(table)
    inc = greedy(table, lp)
    z0 = inc.value
    tol = BOUND_SLACK * max(abs(lp.value), 1e-300)
    lp_bound = lp.value * (1 + BOUND_SLACK)
    if not z0 > 0 or lp.break_index >= len(lp.slopes) or lp.value - z0 <= tol:
        return MckpResult(inc.choice, z0, max(z0, lp_bound), False, {"rows": n_all, "open_rows": 0})
    red = _reduce(table, lp, z0, tol)
    cnt = red.allowed.sum(axis=1)
    if (cnt == 0).any():      # nothing beats the greedy
        return MckpResult(inc.choice, z0, max(z0, red.discarded), False, {"rows": n_all, "open_rows": 0})
    fixed = cnt == 1
    fix_idx = np.argmax(red.allowed, axis=1)
    fr = np.nonzero(fixed)[0]
    W0 = int(red.costs_ext[fr, fix_idx[fr]].sum())
    P0 = math.fsum(red.vals_ext[fr, fix_idx[fr]].tolist())
    rows = np.nonzero(~fixed)[0]
    n = len(rows)
    budget = table.budget - W0
    out = np.where(fixed & (fix_idx < K), fix_idx, -1).astype(np.int64)
    if n == 0 or budget < 0:
        value = _pick(table, out)[1] if budget >= 0 else -math.inf
        if value < z0:
            out, value = inc.choice, z0
        bound = min(lp_bound, max(z0 + tol, red.discarded, P0 if budget >= 0 else -math.inf))
        return MckpResult(out, value, max(bound, value), False, {"rows": n_all, "open_rows": 0})
    ok = red.allowed[rows, :K]
    k = eps * z0 / n
    # Sized in floats, and cast only once the table is known to fit: a tiny eps makes the scaled
    # profits overflow int64 (the cast would give garbage, not an error).
    scaled = np.where(ok, np.floor(table.value[rows] / k), 0.0)
    top_f = float(min(np.floor(max(lp.value - P0, 0.0) * (1 + BOUND_SLACK) / k) + 1.0, scaled.max(axis=1).sum()))
    if not n * (top_f + 1.0) <= max_cells:
        raise SolveError(f"fptas: the table would have {n} rows x {top_f + 1:.6g} profit units = "
                         f"{n * (top_f + 1):.6g} cells, more than the limit of {max_cells}; use a larger eps or bb")
    profit = scaled.astype(np.int64)
    top = int(top_f)
    cells = n * (top + 1)
    sentinel = budget + 1
    least = np.full(top + 1, sentinel, dtype=np.int64)
    least[0] = 0
    choice = np.zeros((n, top + 1), dtype=_choice_dtype(K))
    for r, i in enumerate(rows):
        new = least.copy()
        row = choice[r]
        for kk in np.nonzero(ok[r])[0]:
            p = int(profit[r, kk])
            if p <= 0 or p > top:
                continue
            cand = np.minimum(least[:top + 1 - p] + table.cost[i, kk], sentinel)
            tgt = new[p:]
            better = cand < tgt
            tgt[better] = cand[better]
            row[p:][better] = kk + 1
        least = new
    reach = np.nonzero(least <= budget)[0]
    p = int(reach.max()) if len(reach) else 0
    best_p = p
    for r in range(n - 1, -1, -1):
        kk = int(choice[r, p])
        if kk:
            out[rows[r]] = kk - 1
            p -= int(profit[r, kk - 1])
    value = _pick(table, out)[1]
    if value < z0:   # never return less than the greedy (the guarantee holds for both)
        out, value = inc.choice, z0
    bound = min(lp_bound, max(z0 + tol, red.discarded, P0 + k * best_p + n * k))
    return MckpResult(out, value, max(bound, value), False,
                      {"rows": n_all, "open_rows": n, "eps": eps, "scale": k, "profit_units": top, "cells": cells,
                       "lp": float(lp.value)})
