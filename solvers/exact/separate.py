"""``exact`` for Problems II/IV (separate versions): branch-and-price over per-object paths.

An object's part of a schedule is a path (which of its versions arrive, and when; see
:mod:`.separate_data`); the objects share only the byte budgets. So:

1. **Primal start**: the best of the heuristics that take separate instances (``rolling-future:bb``,
   ``slope``, ``rolling:bb``, ``static``, ``progressive``, and ``mpc:3`` on small scenes), then
   local search: each object's path re-optimised exactly against the bytes the others leave
   (the path DP with the slot's spare bytes as the capacity), until no object improves.
2. **Bound**: Dantzig-Wolfe column generation over paths (:mod:`.separate_master`) with the
   budget rows linking the objects; pricing is one longest path per object (exact DP over
   (slot, versions held)). Every pricing round is a Lagrangian bound, valid whatever the LP did.
3. **Primal from the root**: the master solution rounded greedily, and the restricted master
   solved as a MIP over the paths generated (HiGHS, ``MIP_SHARE`` of the time left), each
   checked in exact integer bytes and improved by the local search.
4. **Closing the gap** (``branching``): ``mip`` - arrivals the root's Lagrangian certificate
   rules out at the incumbent are fixed out (:mod:`.separate_mip`: a forward-backward pass of the
   path DP gives the best path through every (version, slot) arrival), and HiGHS solves the
   standard model over the rest, cut off at the incumbent; ``price`` - best-first
   branch-and-price on "version l of object j has arrived by slot t" (children: by t, which also
   forces it in; or not before t + 1, which may leave it out), chosen where the master is
   fractional, weighted by what arriving one slot later loses, with column generation at every
   node started from the parent's multipliers (an integral master is a schedule);
   ``both`` (default) - the two at once, HiGHS in a second thread; the answer carries the smaller
   of their bounds. On the paper's scenes the path bound equals the LP bound (the per-object
   problem is nearly integral; the gap is in the per-slot knapsacks), so the knapsack cuts of
   HiGHS's branch-and-cut close most of it, and branch-and-price alone closes small instances.

A time limit (or ``max_nodes``) returns the best schedule with a valid bound (the largest bound of
the open nodes), status ``time_limit``; ``optimal`` only when the gap is at most ``GAP_TOL``
(through :func:`~l3gs_opt.problem.solution.finish_solution`). Options: either availability, either
budget (``cumulative``: row t is the bytes by slot t, priced as ``sum_{t' >= t} pi[t']`` per
byte), held versions (any set: the best held one is the base). ``slot`` is refused (use ``bb``),
as is an object with more than :data:`.separate_data.MAX_VERSIONS` versions worth fetching.
"""

from __future__ import annotations

import heapq
import itertools
import math
import threading
import time
from typing import Any

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import GAP_TOL, Solution, Status, finish_solution, relative_gap

from .clock import Clock
from .separate_data import (Path, lagrangian_bound, path_bytes, path_value, price_paths, schedule_feasible,
                            separate_data)
from .separate_master import PathPool, path_generation
from .separate_mip import fixed_mask, reduced_mip
from .sides import run_sides
from .starts import check_starts, run_starts

__all__ = ["solve_separate", "START_HEURISTICS"]

#: Heuristics the primal side starts from (``mpc:3`` is added when J * L <= MPC_MAX_CHUNKS).
START_HEURISTICS = ("rolling-future:bb", "slope", "rolling:bb", "static", "progressive")
MPC_MAX_CHUNKS = 100
#: Share of the time limit the start heuristics may use, and of the time left for the root column
#: generation and for the restricted-master MIP.
START_SHARE, ROOT_SHARE, MIP_SHARE = 0.2, 0.5, 0.15
#: Column-generation rounds without progress before a node is branched (the root: ROOT_STALL).
NODE_STALL, ROOT_STALL = 10, 40
#: A node is closed when its bound is within this relative distance of the incumbent: below
#: GAP_TOL so that a closed tree certifies an optimal gap.
CLOSE_TOL = 0.1 * GAP_TOL
#: A master share below this, or above 1 minus it, counts as integral when choosing a branch.
FRACTIONAL_TOL = 1e-6
#: Nodes between two local searches of the rounded master (each is K exact path DPs).
LOCAL_SEARCH_EVERY = 8
#: How the gap is closed after the root (``exact``'s ``branching`` option): ``mip`` - HiGHS on the
#: model reduced by Lagrangian fixing, cut off at the incumbent; ``price`` - branch-and-price over
#: paths; ``both`` (default) - the two at once, HiGHS in a second thread.
BRANCHING = ("both", "mip", "price")
#: Seconds kept back from the HiGHS MIP (it overruns its limit a little).
MIP_MARGIN_S = 1.0


def solve_separate(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
                   heuristics: tuple[str, ...] | None = None, max_nodes: int | None = None,
                   branching: str = "both", **_ignored: Any) -> Solution:
    """Solve Problem II/IV exactly (see the module doc) or stop at ``time_limit_s`` seconds.

    Parameters
    ----------
    instance : Instance
        A separate instance (any availability and budget, any held versions).
    time_limit_s : float, optional
        Wall-clock seconds; the answer then carries the best schedule and a valid bound.
    heuristics : tuple of str, optional
        Start heuristics (names of :data:`.starts.START_NAMES`; default :data:`START_HEURISTICS`, plus
        ``mpc:3`` on scenes of at most ``MPC_MAX_CHUNKS`` versions).
    max_nodes : int, optional
        Stop branching after this many nodes (status ``time_limit`` unless proven).
    branching : {"both", "mip", "price"}
        How the gap is closed after the root (see :data:`BRANCHING`).

    Returns
    -------
    Solution
        ``bound`` is the best certified bound (``details["bound_kind"]``); ``details`` holds the
        root bound, nodes, paths generated and a ``trace`` of (seconds, incumbent, bound).

    Raises
    ------
    SolveError
        ``slot`` given, an unknown start heuristic or branching, a layered instance, an object with
        too many versions for the path DP.
    """
    started = time.perf_counter()
    if slot is not None:
        raise SolveError("method 'exact' schedules the whole horizon: slot does not apply (use 'bb' for one slot)")
    if branching not in BRANCHING:
        raise SolveError(f"branching = {branching!r} is not one of {', '.join(BRANCHING)}")
    if instance.layered:
        raise SolveError("solve_separate: separate instances only (Problems II and IV)")
    if heuristics is not None:
        check_starts(heuristics)
    search = _PathSearch(instance, started=started, time_limit_s=time_limit_s, max_nodes=max_nodes,
                         branching=branching)
    search.start(heuristics)
    if search.data.K == 0:
        search.bound, search.bound_kind = search.z, "no version can add anything"
    else:
        search.root()
        search.branch()
    return search.finish()


class _PathSearch(Clock):
    """One run: the incumbent (one path per object, value ``z``), the best bound and its kind, the
    path pool, and one method per phase."""

    def __init__(self, instance: Instance, *, started: float, time_limit_s: float | None,
                 max_nodes: int | None, branching: str) -> None:
        self.instance, self.started, self.time_limit_s, self.max_nodes = instance, started, time_limit_s, max_nodes
        self.branching = branching
        self.deadline = None if time_limit_s is None else started + float(time_limit_s)
        self.data = data = separate_data(instance)
        self.pool = PathPool(data)
        self.paths: dict[int, Path] = {}
        self.z = data.constant
        self.bound, self.bound_kind = math.inf, "none"
        self.nodes, self.stopped = 0, False
        self.trace: list[tuple[float, float, float]] = []
        self.details: dict[str, Any] = {"objects": data.K, "versions_per_object": data.V, "slots": data.T,
                                        "presolve": dict(data.stats)}
        self.must0 = np.zeros(data.K, dtype=np.int64)
        # A tiny price per byte breaks the local search's ties towards paths that spend less.
        self.tie_price = 1e-12 * (float(data.show[:, :, -1].sum(axis=0).max(initial=0.0)) /
                                  max(float(data.rhs.max(initial=1)), 1.0)) if data.K else 0.0

    # -- clocks: Clock; and the closing test
    def closed(self, bound: float) -> bool:
        return bound <= self.z + CLOSE_TOL * max(abs(bound), 1e-300)

    def note(self) -> None:
        self.trace.append((self.now(), self.z, max(self.bound, self.z)))

    # -- the incumbent -------------------------------------------------------------------------
    def value(self, paths: dict[int, Path]) -> float:
        return math.fsum([self.data.constant, *(path_value(self.data, k, p) for k, p in paths.items())])

    def repaired(self, paths: dict[int, Path]) -> dict[int, Path]:
        """Drop whole paths (least value per byte first) until the budgets hold in exact bytes."""
        data, paths = self.data, dict(paths)
        while paths and not schedule_feasible(data, paths):
            def worth(k: int) -> float:
                spent = sum(int(data.cost[k, b]) for b, s in enumerate(paths[k]) if s >= 0)
                return path_value(data, k, paths[k]) / max(spent, 1)
            del paths[min(paths, key=worth)]
        return paths

    def try_incumbent(self, paths: dict[int, Path], *, improve: bool = True) -> None:
        paths = self.repaired({k: p for k, p in paths.items() if any(s >= 0 for s in p)})
        if improve:
            paths = self.local_search(paths)
        value = self.value(paths)
        if value > self.z:
            self.paths, self.z = paths, value
            self.pool.add_schedule(paths)

    def local_search(self, paths: dict[int, Path]) -> dict[int, Path]:
        """Re-optimise one object's path at a time against the bytes the others leave (exact for
        that object under per-slot budgets; under the cumulative budget the slot's spare bytes
        are a per-arrival cap and the result is checked), until no object improves."""
        data, paths = self.data, dict(paths)
        T = data.T
        spent = np.zeros((data.K, T), dtype=object)      # Python ints: exact bytes
        for k, p in paths.items():
            for t, b in path_bytes(data, k, p).items():
                spent[k, t] += b
        total = spent.sum(axis=0)
        rho = np.full(T, self.tie_price)
        improved = True
        while improved and not self.out_of_time():
            improved = False
            for k in range(data.K):
                others = total - spent[k]
                if data.cumulative:
                    room = data.rhs.astype(object) - np.cumsum(others)
                    cap = np.minimum.accumulate(room[::-1])[::-1]
                else:
                    room = data.rhs.astype(object) - others
                    cap = room
                cap = np.asarray([max(int(c), -1) for c in cap], dtype=np.int64)
                res = price_paths(data, rho, cap=cap[None, :], objects=np.asarray([k]))
                new = res.paths[0]
                if new is None:
                    continue
                old = paths.get(k)
                old_value = path_value(data, k, old) if old is not None else 0.0
                if path_value(data, k, new) <= old_value:
                    continue
                trial = dict(paths)
                trial[k] = new
                if not schedule_feasible(data, trial):
                    continue
                paths = trial
                total = total - spent[k]
                spent[k] = 0
                for t, b in path_bytes(data, k, new).items():
                    spent[k, t] += b
                total = total + spent[k]
                improved = True
        return {k: p for k, p in paths.items() if any(s >= 0 for s in p)}

    def round_master(self, lam: dict[int, float], allowed: np.ndarray, must: np.ndarray) -> dict[int, Path]:
        """Greedy: the master's paths by descending share (then value), each taken when its object
        has none yet and the budgets still hold in exact bytes."""
        pool, data = self.pool, self.data
        order = sorted(lam, key=lambda c: (-lam[c], -pool.value[c]))
        paths: dict[int, Path] = {}
        for c in order:
            k = pool.obj[c]
            if k in paths:
                continue
            trial = dict(paths)
            trial[k] = pool.path[c]
            if schedule_feasible(data, trial, allowed=allowed):
                paths = trial
        return paths

    def restricted_mip(self, time_limit_s: float) -> None:
        """The master over every path generated, solved as a MIP (HiGHS; a heuristic: its schedule
        is checked in exact bytes and improved by the local search)."""
        import highspy

        from .separate_master import PathMaster

        if time_limit_s <= 0.05 or len(self.pool) == 0:
            return
        master = PathMaster(self.data, self.pool, allowed=self.data.allowed, must=self.must0)
        h = master.h
        n = h.getNumCol()
        h.changeColsIntegrality(n, np.arange(n, dtype=np.int32), np.full(n, highspy.HighsVarType.kInteger))
        h.setOptionValue("time_limit", float(time_limit_s))
        h.setOptionValue("mip_rel_gap", 0.0)
        h.run()
        sol = h.getSolution()
        if not sol.value_valid:
            return
        lam = np.asarray(sol.col_value)
        paths = {}
        for i in np.nonzero(lam > 0.5)[0]:
            c = master.cols[i]
            if c >= 0:
                paths[self.pool.obj[c]] = self.pool.path[c]
        self.try_incumbent(paths)

    # -- phases --------------------------------------------------------------------------------
    def start(self, heuristics: tuple[str, ...] | None) -> None:
        inst, data = self.instance, self.data
        if heuristics is None:
            heuristics = START_HEURISTICS + (("mpc:3",) if inst.J * inst.L <= MPC_MAX_CHUNKS else ())
        values: dict[str, float] = {}
        best, best_name = {}, "empty"
        h_deadline = None if self.deadline is None else self.started + START_SHARE * float(self.time_limit_s)
        for name, sol in run_starts(heuristics if data.K else (), inst, h_deadline):
            paths = data.paths_of(sol.arrivals)
            if not schedule_feasible(data, paths):    # never expected: heuristics are feasible
                continue
            values[name] = self.value(paths)
            self.pool.add_schedule(paths)
            if values[name] > self.value(best):
                best, best_name = paths, name
        self.details["start"] = {"best": best_name, "values": values}
        self.try_incumbent(best)
        self.details["after_local_search"] = self.z
        self.note()

    def root(self) -> None:
        data = self.data
        left = self.left()
        deadline = None if left is None else time.perf_counter() + ROOT_SHARE * left
        res = path_generation(data, self.pool, allowed=data.allowed, must=self.must0, incumbent=self.z,
                              deadline=deadline, stall_iterations=ROOT_STALL)
        self.root_result = res
        self.bound = max(res.bound, self.z)
        self.bound_kind = "Lagrangian over the budget rows (path pricing exact; column-generation duals)"
        self.details["root"] = {"bound": res.bound, "master_lp": res.master, "iterations": res.iterations,
                                "converged": res.converged, "seconds": self.now(), "paths": len(self.pool)}
        self.note()
        if self.closed(self.bound):
            return
        self.try_incumbent(self.round_master(res.lam, data.allowed, self.must0))
        left = self.left()
        self.restricted_mip(MIP_SHARE * left if left is not None else 30.0)
        self.details["root"]["incumbent"] = self.z
        self.note()

    def branch(self) -> None:
        """The MIP side (HiGHS on the model reduced by Lagrangian fixing, in a second thread:
        highspy releases the GIL) and branch-and-price, together or one alone; whichever closes the
        gap first stops the other. The answer carries the smaller of their bounds."""
        use_mip = self.branching in ("both", "mip") and not self.closed(self.bound) and not self.out_of_time()
        use_price = self.branching in ("both", "price")
        self.found: list[dict[int, Path]] = []
        self.stop = threading.Event()
        self.mip: dict[str, Any] = {"bound": math.inf, "outcome": None}
        mip = None
        if use_mip:
            mask = self.fixed_root()
            mip = lambda: self.mip_side(mask, self.z, dict(self.paths))  # noqa: E731
        run_sides(self.price_side if use_price else None, mip, self.stop, name="exact-separate-mip")
        if "error" in self.mip:
            raise self.mip["error"]
        self.take_found()
        if use_mip:
            self.details["reduced_mip"] = {k: v for k, v in self.mip.items() if k != "error"}
            if max(self.z, self.mip["bound"]) < self.bound:
                self.bound = max(self.z, self.mip["bound"])
                self.bound_kind = self.mip["kind"]
            if self.mip["outcome"] == "time_limit":
                self.stopped = True
        self.bound = max(self.bound, self.z)
        self.note()

    def fixed_root(self) -> np.ndarray:
        """Presolve's arrivals minus those the root certificate rules out at the incumbent."""
        root = self.root_result
        if root.pi is None:
            return self.data.allowed
        bound, res = lagrangian_bound(self.data, root.pi)
        mask = fixed_mask(self.data, root.pi, bound, res.value, self.z, self.data.allowed)
        kept = int(sum(bin(int(v)).count("1") for v in mask.ravel()))
        total = int(sum(bin(int(v)).count("1") for v in self.data.allowed.ravel()))
        self.details["root"]["fixed_arrivals"] = total - kept
        return mask

    def take_found(self) -> None:
        while self.found:
            self.try_incumbent(self.found.pop(), improve=False)

    def mip_side(self, mask: np.ndarray, zh: float, start: dict[int, Path]) -> None:
        """HiGHS on the reduced model; touches no shared state but ``found``, ``mip`` and ``stop``
        (it may run in its own thread); an exception is kept in ``mip["error"]``."""
        try:
            left = self.left()
            if left is not None:
                left -= MIP_MARGIN_S
                if left <= 0:
                    self.mip["outcome"] = "time_limit"
                    return
            outcome, paths, bound = reduced_mip(self.data, mask, zh, time_limit_s=left, start=start,
                                                stop=self.stop.is_set)
            if paths is not None:
                self.found.append(paths)
                zh = max(zh, self.value(paths))
            self.mip["outcome"] = outcome
            if outcome == "optimal":
                # Nothing in the mask beats zh, and every schedule better than the incumbent the
                # mask was fixed at lies in the mask.
                self.mip["bound"] = zh
                self.mip["kind"] = ("Lagrangian reduced-cost fixing over paths, then HiGHS branch-and-cut on the "
                                    "reduced model (cut off at the incumbent): closed")
                self.stop.set()
            else:
                self.mip["bound"] = max(zh, bound)
                self.mip["kind"] = "HiGHS dual bound on the model reduced by Lagrangian fixing"
            self.mip["seconds"] = self.now()
        except BaseException as exc:   # handed to the caller's thread
            self.mip["error"] = exc
            self.stop.set()

    def price_side(self) -> None:
        """Best-first branch-and-price. Heap entries: (-bound, tie, allowed, must, parent pi, result)."""
        data = self.data
        counter = itertools.count()
        heap: list = []
        unresolved = -math.inf
        root = self.root_result
        if not self.closed(self.bound):
            heap.append((-self.bound, next(counter), data.allowed, self.must0, root.pi, root))
        while heap and not self.stop.is_set():
            self.take_found()
            if self.out_of_time() or (self.max_nodes is not None and self.nodes >= self.max_nodes):
                self.stopped = True
                break
            neg, _, allowed, must, parent_pi, res = heapq.heappop(heap)
            node_bound = -neg
            if self.closed(node_bound):
                continue
            self.nodes += 1
            if res is None:
                res = path_generation(data, self.pool, allowed=allowed, must=must, incumbent=self.z,
                                      start_bound=node_bound, start_pi=parent_pi, deadline=self.deadline,
                                      stall_iterations=NODE_STALL, close=CLOSE_TOL * max(abs(node_bound), 1e-300))
                if res.infeasible:
                    continue
                node_bound = min(node_bound, res.bound)
                cand = self.round_master(res.lam, allowed, must)
                self.try_incumbent(cand, improve=self.nodes % LOCAL_SEARCH_EVERY == 0)
                if (self.out_of_time() or self.stop.is_set()) and not self.closed(node_bound):
                    heapq.heappush(heap, (-node_bound, next(counter), allowed, must, parent_pi, None))
                    self.stopped = self.out_of_time()
                    break
            if self.closed(node_bound):
                continue
            split = self.split(res.lam)
            if split is None:
                # An integral master: its schedule was tried above; unless that closed the node
                # (column generation stalled before converging), keep its bound in the answer.
                unresolved = max(unresolved, node_bound)
                continue
            k, b, t = split
            by, after = allowed.copy(), allowed.copy()
            by[k, t + 1:] &= ~(1 << b)
            after[k, :t + 1] &= ~(1 << b)
            must_by = must.copy()
            must_by[k] |= 1 << b
            for child_allowed, child_must in ((by, must_by), (after, must)):
                heapq.heappush(heap, (-node_bound, next(counter), child_allowed, child_must, res.pi, None))
            self.trace.append((self.now(), self.z, min(self.mip["bound"], max(self.z, -heap[0][0], unresolved))))
        open_bound = max([-h[0] for h in heap if not self.closed(-h[0])] + [unresolved], default=-math.inf)
        if open_bound == -math.inf:
            self.stop.set()   # the tree is closed (the bound is the incumbent): the MIP side may stop
        tree_bound = max(self.z, open_bound)
        if tree_bound < self.bound:
            self.bound = tree_bound
            self.bound_kind = ("branch-and-price tree closed (every node's Lagrangian bound <= incumbent)"
                               if open_bound == -math.inf else
                               "branch-and-price: the largest Lagrangian bound of the open nodes")

    def split(self, lam: dict[int, float]) -> tuple[int, int, int] | None:
        """The (object, version bit, slot) whose "arrived by slot t" share is most fractional,
        weighted by the utility lost by arriving one slot later (flat stretches do not move the
        bound); None when the master is integral."""
        data, pool = self.data, self.pool
        y = np.zeros((data.K, data.V, data.T))
        for c, share in lam.items():
            k = pool.obj[c]
            for b, s in enumerate(pool.path[c]):
                if s >= 0:
                    y[k, b, s:] += share
        frac = np.minimum(y, 1.0 - y)
        frac[frac < FRACTIONAL_TOL] = 0.0
        if frac.max(initial=0.0) <= 0:
            return None
        loss = np.zeros_like(y)
        shown = np.arange(data.T) + data.shift
        ok = shown < data.T
        loss[:, :, ok] = np.moveaxis(data.gain[shown[ok]], 0, -1)
        score = frac * loss
        if score.max() <= 0:
            score = frac
        k, b, t = np.unravel_index(int(np.argmax(score)), score.shape)
        return int(k), int(b), int(t)

    def finish(self) -> Solution:
        gap = relative_gap(self.z, self.bound)
        if gap is not None and gap <= GAP_TOL:
            status, message = Status.OPTIMAL, ""
        elif self.stopped or self.out_of_time():
            status = Status.TIME_LIMIT
            message = f"stopped after {self.nodes} node(s): best schedule and a valid bound ({self.bound_kind})"
        else:
            status, message = Status.FEASIBLE, f"search ended without proof ({self.bound_kind})"
        self.details.update({"bound_kind": self.bound_kind, "nodes": self.nodes, "paths": len(self.pool),
                             "trace": self.trace})
        return finish_solution(self.instance, self.data.arrivals(self.paths), problem=self.instance.problem,
                               method="exact", status=status, bound=self.bound,
                               runtime_s=time.perf_counter() - self.started, message=message, details=self.details)

