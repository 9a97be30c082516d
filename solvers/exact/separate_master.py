"""Column generation for Problems II/IV: the path master of :mod:`.separate_data` (HiGHS).

Restricted master LP over a pool of paths (one column per (object, path))::

    max  sum v[k,p] lam[k,p]
    s.t. sum_p lam[k,p] <= 1          (= 1 at a node whose object k must fetch some version)
         sum a[k,p,t] lam[k,p] <= R[t] (budget rows, scaled by 1/R[t])
         lam >= 0

Every master solve gives budget duals ``pi``; :func:`.separate_data.lagrangian_bound` at them
prices new paths (one longest path per object) and *is* a valid upper bound, so the bound never
depends on the LP having converged. Pricing uses Wentges smoothing around the best duals so far
(any point is a valid bound; a point that prices out nothing falls back to the master's duals).
Artificial columns (cost ``big_m``) keep a node's master feasible when branching forces a
version in.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from l3gs_opt import stop

from .separate_data import Path, PriceResult, SeparateData, lagrangian_bound, path_bytes, path_value
from .colgen import DUAL_SIMPLEX, PRIMAL_SIMPLEX

__all__ = ["PathPool", "PathMaster", "NodeResult", "path_generation"]

#: A path enters the master when its reduced value exceeds this share of the largest object value
#: (master coefficients are scaled to that value; smaller improvements are the LP's dual noise).
ENTER_TOL = 1e-9


class PathPool:
    """Every path generated so far (shared by all nodes): object, slots per version, value, bytes."""

    def __init__(self, data: SeparateData) -> None:
        self.data = data
        self.obj: list[int] = []
        self.path: list[Path] = []
        self.value: list[float] = []
        self.bytes: list[dict[int, int]] = []
        self.bits: list[int] = []                    # version set of the path
        self._seen: dict[tuple[int, Path], int] = {}

    def __len__(self) -> int:
        return len(self.obj)

    def add(self, k: int, path: Path) -> int | None:
        """Add object k's path (duplicate or the empty path: ignored); its index or None."""
        key = (int(k), tuple(int(s) for s in path))
        if key in self._seen or all(s < 0 for s in path):
            return None
        self._seen[key] = len(self.obj)
        self.obj.append(key[0])
        self.path.append(key[1])
        self.value.append(path_value(self.data, key[0], key[1]))
        self.bytes.append(path_bytes(self.data, key[0], key[1]))
        self.bits.append(sum(1 << b for b, s in enumerate(key[1]) if s >= 0))
        return len(self.obj) - 1

    def add_schedule(self, paths: dict[int, Path]) -> None:
        for k, path in paths.items():
            self.add(k, path)

    def index(self, k: int, path: Path) -> int | None:
        return self._seen.get((int(k), tuple(int(s) for s in path)))

    def compatible(self, c: int, allowed: np.ndarray, must: np.ndarray) -> bool:
        k, path = self.obj[c], self.path[c]
        if (self.bits[c] & int(must[k])) != int(must[k]):
            return False
        return all(s < 0 or (int(allowed[k, s]) >> b) & 1 for b, s in enumerate(path))


@dataclass(eq=False)
class NodeResult:
    """Column generation at one node."""

    bound: float               #: best valid Lagrangian bound seen (held constant included)
    pi: np.ndarray | None      #: its budget multipliers
    master: float              #: last master LP value (held constant included)
    lam: dict[int, float]      #: pool index -> master value, for the master's positive columns
    converged: bool            #: no path prices out at the master's duals
    iterations: int
    infeasible: bool = False   #: the node's restrictions leave some object no path


class PathMaster:
    """The restricted master LP of one node, built from the pool's compatible paths."""

    def __init__(self, data: SeparateData, pool: PathPool, *, allowed: np.ndarray, must: np.ndarray,
                 time_limit_s: float | None = None) -> None:
        import highspy

        from l3gs_opt.models.backends.highs import new_highs

        self.data, self.pool, self.allowed, self.must = data, pool, allowed, must
        # The node's deadline, as for Problem I's master (colgen.Master).
        self.h = new_highs(time_limit_s=None if time_limit_s is None else max(time_limit_s, 0.01))
        self.inf = highspy.kHighsInf
        K, T = data.K, data.T
        # Objective and rows scaled so that coefficients are at most ~1 (values 1e-6..1e6 and
        # bytes up to 2^53 in one instance).
        self.vscale = max(float(data.show[:, :, -1].sum(axis=0).max(initial=0.0)) if K else 0.0, 1e-300)
        self.rows = np.nonzero(data.rhs > 0)[0]          # budget rows with room (others admit nothing)
        self.row_of = np.full(T, -1, dtype=np.int64)
        self.row_of[self.rows] = K + np.arange(len(self.rows))
        self.rscale = data.rhs[self.rows].astype(np.float64)
        lower = np.full(K + len(self.rows), -self.inf)
        lower[:K] = np.where(must != 0, 1.0, -self.inf)
        upper = np.concatenate([np.ones(K), np.ones(len(self.rows))])
        self.h.addRows(K + len(self.rows), lower, upper, 0, np.zeros(K + len(self.rows), np.int32),
                       np.zeros(0, np.int32), np.zeros(0))
        self.cols: list[int] = []          # pool index per master column (-1: artificial)
        self.members: set[int] = set()
        self.solved = False                # (solves after the first: primal simplex)
        big_m = 10.0 * (K + 1)
        for k in np.nonzero(must != 0)[0]:
            self.h.addCol(big_m, 0.0, self.inf, 1, np.asarray([k], np.int32), np.asarray([1.0]))
            self.cols.append(-1)
        self.add_columns([c for c in range(len(pool)) if pool.compatible(c, allowed, must)])

    def _entries(self, c: int) -> tuple[list[int], list[float]]:
        data, spent = self.data, self.pool.bytes[c]
        idx, val = [self.pool.obj[c]], [1.0]
        if data.cumulative:
            total, first = 0, min(spent)
            for t in range(first, data.T):
                total += spent.get(t, 0)
                r = int(self.row_of[t])
                if r >= 0:
                    idx.append(r)
                    val.append(total / float(data.rhs[t]))
        else:
            for t, b in sorted(spent.items()):
                r = int(self.row_of[t])
                if r >= 0:
                    idx.append(r)
                    val.append(b / float(data.rhs[t]))
        return idx, val

    def add_columns(self, pool_indices: list[int]) -> None:
        if not pool_indices:
            return
        starts, idx, val, costs = [], [], [], []
        for c in pool_indices:
            i, v = self._entries(c)
            starts.append(len(idx))
            idx.extend(i)
            val.extend(v)
            costs.append(-self.pool.value[c] / self.vscale)   # HiGHS minimises
            self.cols.append(c)
            self.members.add(c)
        m = len(pool_indices)
        self.h.addCols(m, np.asarray(costs), np.zeros(m), np.full(m, self.inf), len(idx),
                       np.asarray(starts, np.int32), np.asarray(idx, np.int32), np.asarray(val, np.float64))

    def solve(self) -> tuple[float, np.ndarray, np.ndarray, np.ndarray] | None:
        """Solve; (master value with the held constant, pi [T] >= 0 in utility per byte, mu [K] in
        utility, lam per master column), or None when HiGHS did not reach an optimum."""
        import highspy

        # A path master only ever gains columns after its first solve: its last basis is still
        # primal feasible, so primal simplex goes on from it (as Problem I's master does after new
        # columns: colgen.PRIMAL_SIMPLEX).
        self.h.setOptionValue("simplex_strategy", PRIMAL_SIMPLEX if self.solved else DUAL_SIMPLEX)
        self.solved = True
        self.h.run()
        if self.h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
            return None
        sol = self.h.getSolution()
        dual = -np.asarray(sol.row_dual)           # max-form multipliers (scaled)
        K, T = self.data.K, self.data.T
        pi = np.zeros(T)
        pi[self.rows] = np.maximum(dual[K:], 0.0) * self.vscale / self.rscale
        mu = dual[:K] * self.vscale
        value = self.data.constant - float(self.h.getInfo().objective_function_value) * self.vscale
        return value, pi, mu, np.asarray(sol.col_value)

    def positive(self, lam: np.ndarray) -> dict[int, float]:
        return {self.cols[i]: float(lam[i]) for i in np.nonzero(lam > 1e-12)[0] if self.cols[i] >= 0}


def _reduced(data: SeparateData, pool: PathPool, c: int, pi: np.ndarray, mu: np.ndarray) -> float:
    """Reduced value of pool path c at master duals (pi, mu), utility units."""
    rho = np.flip(np.cumsum(np.flip(pi))) if data.cumulative else pi
    priced = sum(rho[t] * b for t, b in pool.bytes[c].items())
    return pool.value[c] - priced - float(mu[pool.obj[c]])


def path_generation(data: SeparateData, pool: PathPool, *, allowed: np.ndarray, must: np.ndarray, incumbent: float,
                    start_bound: float = math.inf, start_pi: np.ndarray | None = None,
                    deadline: float | None = None, max_iterations: int = 10_000, stall_iterations: int = 30,
                    smoothing: float = 0.5, close: float = 0.0) -> NodeResult:
    """Column generation at a node until converged, closed (bound <= incumbent + ``close``),
    stalled or out of time (``deadline``: ``time.perf_counter()`` seconds)."""
    master = PathMaster(data, pool, allowed=allowed, must=must,
                        time_limit_s=None if deadline is None else deadline - time.perf_counter())
    best, best_pi = start_bound, start_pi
    value, lam, converged, it = -math.inf, {}, False, 0
    history: list[float] = []
    tol = ENTER_TOL * master.vscale
    for it in range(1, max_iterations + 1):
        solved = master.solve()
        if solved is None:
            break
        value, pi, mu, raw = solved
        lam = master.positive(raw)
        points = [pi]
        if best_pi is not None and smoothing > 0:
            points.insert(0, smoothing * best_pi + (1 - smoothing) * pi)
        added: list[int] = []
        for point in points:
            bound, res = lagrangian_bound(data, point, allowed=allowed, must=must)
            if bound == -math.inf:
                return NodeResult(-math.inf, None, value, lam, True, it, infeasible=True)
            if bound < best or best_pi is None:
                best, best_pi = min(best, bound), point
            added = _new_columns(data, pool, master, res, pi, mu, tol)
            if added:
                break
        if best <= incumbent + close or best - value <= tol or not added:
            converged = best - value <= tol or not added
            break
        history.append(best)
        if len(history) > stall_iterations and history[-stall_iterations - 1] - best <= 1e-7 * abs(best):
            break
        if stop.expired(deadline):
            break
        master.add_columns(added)
    if best_pi is None:
        return NodeResult(best, None, value, lam, False, it)
    return NodeResult(best, best_pi, value, lam, converged, it)


def _new_columns(data: SeparateData, pool: PathPool, master: PathMaster, res: PriceResult, pi: np.ndarray,
                 mu: np.ndarray, tol: float) -> list[int]:
    """Pool indices of the priced paths not yet in the master whose reduced value at the master's
    duals exceeds ``tol`` (a path already there prices out only by the LP's round-off)."""
    added = []
    for k, path in enumerate(res.paths):
        if path is None:
            continue
        c = pool.add(k, path)
        c = pool.index(k, path) if c is None else c
        if c is None or c in master.members:
            continue
        if _reduced(data, pool, c, pi, mu) > tol:
            added.append(c)
    return added
