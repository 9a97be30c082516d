"""Dantzig-Wolfe column generation for Problem A: per-slot fillings priced by the knapsack solver.

Master LP (restricted to a pool of columns; a column is one slot's set of arriving chunks)::

    max  sum_c P_c lam_c
    s.t. sum_{c in slot t} lam_c <= 1             (convexity; = 1 at a node that forces items into t)
         sum_c a_ic lam_c <= 1                    (at most once, dual mu[i])
         precedence rows (u, t) of Problem A      (dual pi[u,t]; added lazily when violated)
         cover rows of the arrived-by knapsacks   (dual d[k]; added by the caller, :mod:`.covers`)
         lam >= 0

Every master solve yields multipliers ``(mu, pi)``; :func:`~.lagrange.lagrangian_value` at them
prices new columns (one knapsack per slot) and *is* a valid upper bound (the Lasdon bound), so
the bound never depends on the LP having converged. At convergence the master value equals the
Lagrangian dual (the DW bound), at least as tight as the LP relaxation. Artificial columns
(cost ``big_m``) keep the master feasible when branching forces chunks.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from l3gs_opt.stop import expired

from .lagrange import Cover, GapData, LagrangeValue, Multipliers, lagrangian_value, reduced_profits

__all__ = ["ColumnPool", "Master", "Basis", "CgResult", "column_generation"]

#: A column enters the master when its reduced profit exceeds this fraction of the bound
#: (smaller improvements are float noise of the LP's dual values).
ENTER_TOL = 1e-9
#: Precedence row violations below this (in LP units, rows have coefficients +-1) are LP noise.
ROW_TOL = 1e-7
#: HiGHS simplex strategies for a master re-solve: after only new columns the last basis is still
#: primal feasible, so primal simplex continues from it; after new rows or a node's bound changes
#: it is dual feasible instead, and dual simplex (HiGHS's default) continues. Root column
#: generation, one run each, one core: J=20 s0 3.0 s against 6.5 s with dual simplex throughout,
#: s3 2.6 against 8.1, s4 and s9 unchanged (primal simplex throughout: 4.4 s on both; after new
#: rows too it took 540 ms a solve at J=50 s0 against dual's 76 ms).
PRIMAL_SIMPLEX, DUAL_SIMPLEX = 4, 1


class ColumnPool:
    """Every column generated so far (shared by all nodes): slot, membership, profit."""

    def __init__(self, data: GapData) -> None:
        self.data = data
        self.slot: list[int] = []
        self.items: list[np.ndarray] = []
        self.profit: list[float] = []
        self._seen: set[tuple[int, bytes]] = set()

    def __len__(self) -> int:
        return len(self.slot)

    def add(self, t: int, items: np.ndarray) -> int | None:
        """Add slot t's filling ``items`` (over budget or duplicate: ignored); its index or None."""
        items = np.unique(np.asarray(items, dtype=np.int64))
        key = (int(t), items.tobytes())
        if key in self._seen or int(self.data.cost[items].sum()) > int(self.data.budget[t]):
            return None
        if len(items) and not self.data.allowed[items, t].all():
            return None
        self._seen.add(key)
        self.slot.append(int(t))
        self.items.append(items)
        self.profit.append(math.fsum(self.data.profit[items, t].tolist()))
        return len(self.slot) - 1

    def add_assignment(self, assign: np.ndarray) -> None:
        for t in range(self.data.T):
            self.add(t, np.nonzero(assign == t)[0])


@dataclass(frozen=True, eq=False)
class Basis:
    """A master basis: HiGHS's status of each column and row (in the master's order) at one solve."""

    cols: tuple
    rows: tuple


@dataclass(eq=False)
class CgResult:
    """Outcome of column generation at one node."""

    bound: float                 #: best valid Lagrangian bound seen
    mult: Multipliers            #: multipliers of that bound
    value: LagrangeValue         #: the Lagrangian value there (knapsack solutions, reduced profits)
    master: float                #: last master LP value
    xbar: np.ndarray             #: [n, T] master solution in x terms
    converged: bool              #: no column prices out and no precedence row is violated
    iterations: int
    infeasible: bool = False     #: the node's forcings admit no schedule


def master_big_m(data: GapData) -> float:
    """Cost of the master's artificial columns: more than any schedule is worth."""
    return 10.0 * (float(data.profit.max(axis=1).sum()) + 1.0)


class Master:
    """The restricted master LP (HiGHS), kept across the nodes of a search.

    It holds every pool column and every precedence row met so far; :meth:`focus` moves it to a
    node: the columns the node rules out get upper bound 0, a slot with forced items gets its
    convexity row's lower bound 1 and its artificial column (cost ``big_m``), a precedence row of
    a forced item its artificial slack. HiGHS keeps its basis across those bound changes, so a
    node's first solve starts from the last node's optimum (from scratch it took 5 times the
    iterations of a later solve at J=20: a median 1,456 against 302), or from a basis given to
    :meth:`focus` (the parent's: :meth:`snapshot`). Each re-solve picks its simplex by what changed
    since the last (:data:`PRIMAL_SIMPLEX`).
    """

    def __init__(self, data: GapData, pool: ColumnPool, rows: list[tuple[int, int]], *, allowed: np.ndarray,
                 forced: dict[int, int], big_m: float | None = None, time_limit_s: float | None = None) -> None:
        import highspy

        from l3gs_opt.models.backends.highs import WallClock, new_highs

        self.data, self.pool = data, pool
        self.big_m = master_big_m(data) if big_m is None else big_m
        self.h = new_highs()
        # HiGHS's own limit is checked only between some phases: the wall-clock interrupt stops
        # it inside the simplex (without it one master solve at J=50 ran 19 s past a 35 s limit).
        self.clock = WallClock(self.h)
        self.inf = highspy.kHighsInf
        n, T = data.n, data.T
        # Rows: once [0, n), convexity [n, n + T), precedence and cover rows after.
        self.h.addRows(n + T, np.full(n + T, -self.inf), np.ones(n + T), 0, np.zeros(n + T, np.int32),
                       np.zeros(0, np.int32), np.zeros(0))
        self.rows: list[tuple[int, int]] = []
        self.row_index: dict[tuple[int, int], int] = {}
        self._rows_of: dict[int, list] = {}   # item -> its precedence rows ((u, t), row index)
        # (number of real columns, then their slots and (column, item) entries): see _compatible_all
        self._entries_of: tuple[int, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.cols: list[int] = []          # pool index of each master column (-1: artificial)
        self.changes: set[str] = set()     # "columns", "rows", "bounds" since the last solve
        self.held: set[int] = set()        # pool indices in the master
        # Artificial column of each convexity row (keeps the LP feasible when a slot is forced) and
        # of each precedence row (when an upper layer is forced); bound 0 unless so.
        self.slot_art = np.arange(T)
        for t in range(T):
            self._add_raw(-1, [n + t], [1.0], self.big_m)
        self.row_art: list[int] = []
        # Cover rows (globally valid: kept at every node, no artificial column needed since the
        # artificial columns alone satisfy them): their covers, row indices, and membership [k, n].
        self.covers: list[Cover] = []
        self.cover_rows: list[int] = []
        self.cover_keys: set[tuple[int, bytes]] = set()    # (slot, items.tobytes()) of each
        self._cover_member = np.zeros((0, data.n), dtype=np.int64)
        self._cover_slot = np.zeros(0, dtype=np.int64)
        self.allowed, self.forced, self.forced_by_slot = allowed, forced, {}
        self.add_rows(rows)
        self.focus(allowed, forced, time_limit_s)

    def focus(self, allowed: np.ndarray, forced: dict[int, int], time_limit_s: float | None = None,
              basis: "Basis | None" = None) -> None:
        """Move the master to a node: its arrival mask, its forced items and its time limit
        (seconds from now); ``basis`` (:meth:`snapshot`, e.g. the parent's last) starts the next
        solve, else the last solve's basis (another node's, in a best-first search) does."""
        self.allowed, self.forced = allowed, forced
        self.forced_by_slot = {}
        for i, t in forced.items():
            self.forced_by_slot.setdefault(t, set()).add(i)
        self.add_columns([c for c in range(len(self.pool)) if c not in self.held])
        n, T = self.data.n, self.data.T
        pos = np.nonzero(np.asarray(self.cols) >= 0)[0].astype(np.int32)
        upper = np.where(self._compatible_all(pos), self.inf, 0.0)
        upper_art = [self.inf if t in self.forced_by_slot else 0.0 for t in range(T)]
        upper_art += [self.inf if u in forced else 0.0 for (u, _) in self.rows]
        art = np.r_[self.slot_art, np.asarray(self.row_art, dtype=np.int64)].astype(np.int32)
        idx = np.r_[pos, art].astype(np.int32)
        up = np.r_[upper, np.asarray(upper_art, dtype=np.float64)]
        if len(idx):
            self.h.changeColsBounds(len(idx), idx, np.zeros(len(idx)), up)
        lower = np.asarray([1.0 if t in self.forced_by_slot else -self.inf for t in range(T)])
        self.h.changeRowsBounds(T, np.arange(n, n + T, dtype=np.int32), lower, np.ones(T))
        self.changes.add("bounds")
        self.clock.limit(None if time_limit_s is None else max(float(time_limit_s), 0.01))
        if basis is not None:
            self.restore(basis)

    def snapshot(self) -> "Basis":
        """The last solve's basis (column and row statuses), to start a child node from."""
        b = self.h.getBasis()
        return Basis(tuple(b.col_status), tuple(b.row_status)) if b.valid else Basis((), ())

    def restore(self, basis: "Basis") -> None:
        """Start the next solve from ``basis``: the columns added since are nonbasic at 0, the rows
        added since basic. A nonbasic column sits at its lower bound (0: its upper one may be gone
        at this node) and a nonbasic row at its upper one (its lower one may be)."""
        import highspy

        if not basis.cols:
            return
        st = highspy.HighsBasisStatus
        cols = [st.kLower if c == st.kUpper else c for c in basis.cols]
        rows = [st.kUpper if r == st.kLower else r for r in basis.rows]
        b = highspy.HighsBasis()
        b.col_status = cols + [st.kLower] * (self.h.getNumCol() - len(cols))
        b.row_status = rows + [st.kBasic] * (self.h.getNumRow() - len(rows))
        b.valid = True
        self.h.setBasis(b)

    def _compatible_all(self, pos: np.ndarray) -> np.ndarray:
        """:meth:`compatible` of the pool columns at master positions ``pos``, in one pass over
        their (column, item) entries (a node's master holds thousands of columns)."""
        cache = self._entries_of
        if cache is None or cache[0] != pos.size:   # (columns are only ever appended)
            cols = np.asarray(self.cols, dtype=np.int64)[pos]
            slot = np.asarray(self.pool.slot, dtype=np.int64)[cols] if len(cols) else np.zeros(0, np.int64)
            sizes = np.asarray([len(self.pool.items[c]) for c in cols.tolist()], dtype=np.int64)
            owner = np.repeat(np.arange(len(cols)), sizes)
            items = (np.concatenate([self.pool.items[c] for c in cols.tolist()]) if sizes.sum()
                     else np.zeros(0, np.int64))
            self._entries_of = (pos.size, slot, owner, items)
        _, slot, owner, items = self._entries_of
        return self._fits(slot, owner, items)

    def compatible(self, c: int) -> bool:
        """Whether the node allows pool column ``c``: every item may arrive in its slot, and it
        holds every item forced into that slot."""
        items = np.asarray(self.pool.items[c], dtype=np.int64)
        slot = np.asarray([self.pool.slot[c]], dtype=np.int64)
        return bool(self._fits(slot, np.zeros(len(items), dtype=np.int64), items)[0])

    def _fits(self, slot: np.ndarray, owner: np.ndarray, items: np.ndarray) -> np.ndarray:
        """The rule of :meth:`compatible` for columns given by their slots ``slot`` [m] and
        (column ``owner[k]`` holds item ``items[k]``) entries."""
        ok = np.ones(len(slot), dtype=bool)
        ok[owner[~self.allowed[items, slot[owner]]]] = False
        if self.forced:
            forced_slot = np.full(self.data.n, -1, dtype=np.int64)
            need = np.zeros(self.data.T, dtype=np.int64)
            for i, t in self.forced.items():
                forced_slot[i] = t
                need[t] += 1
            hits = np.bincount(owner[forced_slot[items] == slot[owner]], minlength=len(slot))
            ok &= hits == need[slot]
        return ok

    # -- building --------------------------------------------------------------------------
    def _add_raw(self, pool_index: int, idx: list[int], val: list[float], cost: float) -> None:
        self.h.addCol(float(cost), 0.0, self.inf, len(idx), np.asarray(idx, np.int32), np.asarray(val, np.float64))
        self.cols.append(pool_index)

    def _entries(self, c: int) -> tuple[list[int], list[float]]:
        data, t, items = self.data, self.pool.slot[c], self.pool.items[c]
        n = data.n
        coef: dict[int, float] = {int(i): 1.0 for i in items}
        coef[n + t] = 1.0
        d = 1 if data.strict else 0
        for i in items.tolist():
            for (u, tt), r in self._rows_of.get(i, ()):
                if tt >= t:
                    coef[r] = coef.get(r, 0.0) + 1.0
            up = int(data.upper[i])
            if up >= 0:
                for (u, tt), r in self._rows_of.get(up, ()):
                    if tt >= t + d:
                        coef[r] = coef.get(r, 0.0) - 1.0
        if self.covers:
            hits = self._cover_member[:, items].sum(axis=1) * (self._cover_slot >= t)
            for k in np.nonzero(hits)[0].tolist():
                coef[self.cover_rows[k]] = float(hits[k])
        keys = [k for k, v in coef.items() if v != 0.0]
        return keys, [coef[k] for k in keys]

    def add_columns(self, pool_indices: list[int]) -> None:
        if not pool_indices:
            return
        starts, idx, val, costs = [], [], [], []
        for c in pool_indices:
            keys, vals = self._entries(c)
            starts.append(len(idx))
            idx.extend(keys)
            val.extend(vals)
            costs.append(-self.pool.profit[c])   # HiGHS minimises: cost = -profit
            self.cols.append(c)
            self.held.add(c)
        m = len(pool_indices)
        self.changes.add("columns")
        self.h.addCols(m, np.asarray(costs), np.zeros(m), np.full(m, self.inf), len(idx),
                       np.asarray(starts, np.int32), np.asarray(idx, np.int32), np.asarray(val, np.float64))

    def add_rows(self, rows: list[tuple[int, int]]) -> None:
        rows = [r for r in rows if r not in self.row_index]
        if not rows:
            return
        data = self.data
        d = 1 if data.strict else 0
        # Row (u, t) over the master's columns: +1 where the column's slot is <= t and holds u,
        # -1 where its slot is <= t - d and holds lo(u) (artificial columns: never).
        slots, member = self._column_members()
        uu = np.asarray([u for u, _ in rows], dtype=np.int64)
        tt = np.asarray([t for _, t in rows], dtype=np.int64)
        lo = data.lower[uu]
        if (lo < 0).any():
            raise ValueError(f"precedence row for item {int(uu[lo < 0][0])}, which has no lower layer")
        starts, idx, val = [], [], []
        for block in range(0, len(rows), 256):   # (rows x columns) at a time: bounded memory
            b = slice(block, block + 256)
            coef = (member[:, uu[b]].T * (slots[None, :] <= tt[b, None])
                    - member[:, lo[b]].T * (slots[None, :] <= tt[b, None] - d))
            r, c = np.nonzero(coef)
            starts.extend((len(idx) + np.searchsorted(r, np.arange(len(coef)))).tolist())
            idx.extend(c.tolist())
            val.extend(coef[r, c].astype(np.float64).tolist())
        base = self.h.getNumRow()
        for k, (u, t) in enumerate(rows):
            self.row_index[(u, t)] = base + k
            self._rows_of.setdefault(u, []).append(((u, t), base + k))
            self.rows.append((u, t))
        m = len(rows)
        self.changes.add("rows")
        self.h.addRows(m, np.full(m, -self.inf), np.zeros(m), len(idx), np.asarray(starts, np.int32),
                       np.asarray(idx, np.int32), np.asarray(val, np.float64))
        # Artificial slack per row (big-M), so forcing an upper layer never makes the LP infeasible
        # (bound 0 at nodes that do not force it).
        for (u, t) in rows:
            self.row_art.append(len(self.cols))
            self._add_raw(-1, [self.row_index[(u, t)]], [-1.0], self.big_m)
            if u not in self.forced:
                self.h.changeColBounds(self.row_art[-1], 0.0, 0.0)

    def _column_members(self) -> tuple[np.ndarray, np.ndarray]:
        """Slot [m] and item membership [m, n] (int8) of the master's m columns; an artificial
        column has slot T + 1 (after every row's slot) and no items."""
        data = self.data
        cols = np.asarray(self.cols, dtype=np.int64)
        real = np.nonzero(cols >= 0)[0]
        slots = np.full(len(cols), data.T + 1, dtype=np.int64)
        slots[real] = np.asarray(self.pool.slot, dtype=np.int64)[cols[real]]
        member = np.zeros((len(cols), data.n), dtype=np.int8)
        if len(real):
            sizes = [len(self.pool.items[c]) for c in cols[real]]
            member[np.repeat(real, sizes), np.concatenate([self.pool.items[c] for c in cols[real]])] = 1
        return slots, member

    def add_covers(self, covers: list[Cover]) -> None:
        """Cover rows ``sum_{i in S} y[i,t] <= |S| - 1`` over the master's columns (a column of
        slot s <= t has coefficient ``|its items & S|``); covers already held are skipped."""
        new = []
        for cov in covers:
            key = (int(cov.slot), np.asarray(cov.items, dtype=np.int64).tobytes())
            if key not in self.cover_keys:
                self.cover_keys.add(key)
                new.append(cov)
        if not new:
            return
        n = self.data.n
        member = np.zeros((len(new), n), dtype=np.int64)
        for k, cov in enumerate(new):
            member[k, cov.items] = 1
        slot = np.asarray([cov.slot for cov in new], dtype=np.int64)
        col_slots, col_member = self._column_members()
        # [covers, columns]: chunks of S a column holds, where its slot is <= the cover's.
        coef = (member @ col_member.T.astype(np.int64)) * (col_slots[None, :] <= slot[:, None])
        r, c = np.nonzero(coef)
        starts = np.searchsorted(r, np.arange(len(new)))
        idx, val = c, coef[r, c].astype(np.float64)
        base = self.h.getNumRow()
        m = len(new)
        self.changes.add("rows")
        self.h.addRows(m, np.full(m, -self.inf), np.asarray([len(cov.items) - 1.0 for cov in new]), len(idx),
                       np.asarray(starts, np.int32), np.asarray(idx, np.int32), np.asarray(val, np.float64))
        self.covers.extend(new)
        self.cover_rows.extend(range(base, base + m))
        self._cover_member = np.vstack([self._cover_member, member])
        self._cover_slot = np.r_[self._cover_slot, slot]

    # -- solving ---------------------------------------------------------------------------
    def solve(self) -> tuple[float, Multipliers, np.ndarray] | None:
        """Solve; (master value with the held constant, multipliers >= 0, lam per master column),
        or None when HiGHS stops short of an optimum (time limit; or twice in a row, the second time
        from scratch, an undecided status): its duals then price validly but its value is no master
        optimum, and convergence is judged on that value."""
        import highspy

        strategy = PRIMAL_SIMPLEX if self.changes == {"columns"} else DUAL_SIMPLEX
        self.h.setOptionValue("simplex_strategy", strategy)
        self.changes = set()
        for attempt in range(2):
            self.h.run()
            status = self.h.getModelStatus()
            if status in (highspy.HighsModelStatus.kOptimal, highspy.HighsModelStatus.kModelEmpty):
                break   # (empty: no column yet, every dual 0)
            if status in (highspy.HighsModelStatus.kTimeLimit, highspy.HighsModelStatus.kInterrupt) or attempt:
                return None
            self.h.clearSolver()
        sol = self.h.getSolution()
        data = self.data
        dual = -np.asarray(sol.row_dual)          # max-form multipliers
        lam = np.asarray(sol.col_value)
        mu = np.maximum(0.0, dual[:data.n])
        pi = np.zeros((data.n, data.T))
        for (u, t), r in self.row_index.items():
            pi[u, t] = max(0.0, dual[r])
        cover = np.maximum(0.0, dual[np.asarray(self.cover_rows, dtype=np.int64)])
        value = self.data.constant - float(self.h.getInfo().objective_function_value)
        self.rho = dual[data.n:data.n + data.T]      # convexity duals (for reduced costs)
        return value, Multipliers(mu, pi, cover, tuple(self.covers)), lam

    def xbar(self, lam: np.ndarray) -> np.ndarray:
        """``[n, T]``: the master solution in arrival terms (artificials contribute nothing)."""
        x = np.zeros((self.data.n, self.data.T))
        for pos in np.nonzero(lam > 1e-12)[0]:
            c = self.cols[pos]
            if c >= 0:
                x[self.pool.items[c], self.pool.slot[c]] += lam[pos]
        return x

    def violated_rows(self, x: np.ndarray) -> list[tuple[int, int]]:
        data = self.data
        has = np.nonzero(data.lower >= 0)[0]
        if len(has) == 0:
            return []
        cum = np.cumsum(x, axis=1)
        lo = cum[data.lower[has]]
        if data.strict:
            lo = np.concatenate([np.zeros((len(has), 1)), lo[:, :-1]], axis=1)
        viol = cum[has] - lo > ROW_TOL
        uu, tt = np.nonzero(viol)
        return [(int(has[a]), int(b)) for a, b in zip(uu, tt) if (int(has[a]), int(b)) not in self.row_index]


def column_generation(data: GapData, pool: ColumnPool, rows: list[tuple[int, int]], *, allowed: np.ndarray,
                      forced: dict[int, int], incumbent: float, time_limit_s: float | None = None,
                      max_iterations: int = 500, stall_iterations: int = 12, start_bound: float = math.inf,
                      trace: list | None = None, clock0: float | None = None, smoothing: float = 0.5,
                      start: tuple[Multipliers, LagrangeValue] | None = None,
                      stop: Callable[[], bool] | None = None, master: "Master | None" = None,
                      basis: Basis | None = None) -> CgResult:
    """Column generation at a node until converged, stalled, pruned (bound <= incumbent), out of
    time, or ``stop()`` returns true (polled before each master solve once a bound is known: e.g.
    another thread closed the gap).

    ``rows`` (precedence rows (u, t) known so far) is extended in place with the rows found
    violated, so later nodes start with them. ``trace`` gets ``(seconds since clock0, bound)``.
    ``start`` (multipliers and their Lagrangian value) is the first smoothing centre and bound.
    ``master``: a :class:`Master` kept across nodes (moved to this node first), else a new one.
    """
    started = time.perf_counter()
    clock0 = started if clock0 is None else clock0
    # The pricing knapsacks stop here too (their upper bound keeps the value a valid bound): on a
    # hard 600-item slot an unbounded one took 60 s under a 10 s limit.
    deadline = None if time_limit_s is None else started + time_limit_s
    if master is None:
        master = Master(data, pool, rows, allowed=allowed, forced=forced, time_limit_s=time_limit_s)
    else:
        master.add_rows(rows)
        master.focus(allowed, forced, time_limit_s, basis)
    best, best_mult, best_val = start_bound, None, None
    if start is not None:   # e.g. the LP duals: the first stability centre
        best_mult, best_val = start
        best = min(best, best_val.bound)
    history: list[float] = []
    value, xbar, converged, it = -math.inf, np.zeros((data.n, data.T)), False, 0
    master_stopped = False   # a master solve stopped short of its optimum (time limit, undecided)
    for it in range(1, max_iterations + 1):
        if best_val is not None and (expired(deadline)
                                     or (stop is not None and stop())):
            break
        solved = master.solve()
        if solved is None:
            master_stopped = True
            break
        value, mult, lam = solved
        xbar = master.xbar(lam)
        new_rows = master.violated_rows(xbar)
        if new_rows:
            master.add_rows(new_rows)
            rows.extend(new_rows)
            continue
        # Wentges smoothing: price at a point between the best multipliers so far and the
        # master's; any point gives a valid bound. A mis-price (no column improves the master)
        # falls back to the master's duals.
        red_master = reduced_profits(data, mult)
        if allowed is not None:
            red_master = np.where(allowed, red_master, -np.inf)
        points = [mult]
        if best_mult is not None and smoothing > 0:
            points.insert(0, best_mult.blend(mult, smoothing))
        added = []
        for point in points:
            lv = lagrangian_value(data, point, allowed=allowed, forced=forced, deadline=deadline)
            if lv.bound == -math.inf:
                return CgResult(-math.inf, point, lv, value, xbar, True, it, infeasible=True)
            if lv.bound < best or best_val is None:
                if lv.bound < best:
                    best = lv.bound
                best_mult, best_val = point, lv
            scale = ENTER_TOL * max(abs(best), 1.0)
            for t in range(data.T):
                items = np.nonzero(lv.x[:, t])[0]
                rc = float(red_master[items, t].sum()) - float(master.rho[t]) if len(items) else -float(master.rho[t])
                if rc > scale:
                    c = pool.add(t, items)
                    if c is not None:
                        added.append(c)
            if added:
                break
        if trace is not None:
            trace.append((time.perf_counter() - clock0, best))
        added = [c for c in added if master.compatible(c)]
        gap = best - value
        if best <= incumbent or gap <= ENTER_TOL * max(abs(best), 1.0) or not added:
            converged = gap <= ENTER_TOL * max(abs(best), 1.0) or not added
            break
        history.append(best)
        if len(history) > stall_iterations and history[-stall_iterations - 1] - best <= 1e-6 * abs(best):
            break
        if expired(deadline):
            break
        master.add_columns(added)
    if best_val is None:   # stopped before pricing once: price at the last duals
        solved = None if master_stopped else master.solve()
        if solved is not None:
            value, mult, lam = solved
            xbar = master.xbar(lam)
        else:
            # No master optimum in time: the Lagrangian at zero multipliers is still a valid bound.
            mult = Multipliers.zeros(data)
        best_val = lagrangian_value(data, mult, allowed=allowed, forced=forced, deadline=deadline)
        best_mult = mult
        best = min(best, best_val.bound)
    return CgResult(best, best_mult, best_val, value, xbar, converged, it)
