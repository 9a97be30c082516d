"""Level-keeping repair for Problem A: raise one chunk's profit while no other chunk's drops (CP-SAT).

A chunk's profit ``P[i,t]`` is flat over every slot in which its object is out of view, so most
of a schedule can be repacked at no cost, and a better schedule often differs from the incumbent
by such moves plus one chunk arriving earlier. T60-J20-s0: the 60 s schedule (178,641.66) and the
optimum (178,657.52) differ in 42 of 80 chunks, 41 of them at equal profit. Neither HiGHS nor
CP-SAT finds that repacking in 30 s on the neighbourhood "no chunk loses profit" (738 pairs);
forcing the one chunk to gain makes it a feasibility problem that CP-SAT's propagation settles in
about a second, and proves infeasible in hundredths of one for the chunks that cannot gain.

:func:`level_repair` tries that for every chunk that could gain (largest possible gain first),
adopts the first repacking found, and starts again from it, until a pass finds none or time runs
out. Budgets are checked in integer bytes by CP-SAT and again by
:func:`~.lagrange.assignment_feasible`; profits only choose the slots each chunk may use.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .lagrange import GapData, assignment_feasible, assignment_value, chunk_profits

__all__ = ["level_repair", "RepairResult", "REPAIR_WORKERS"]

#: CP-SAT workers per repair: its portfolio's diversity finds the repacking sooner even on 2 cores
#: (T60-J20-s0, 4 seeds: 0.7-1.4 s with 4 workers and the incumbent as hint, 1.1-2.0 s with 8,
#: 2.9-9.9 s with 16; one worker took 9 s).
REPAIR_WORKERS = 4
#: A chunk is a target only when some slot raises its profit by more than this share of the
#: largest profit (smaller gains are float noise of the profit sums).
GAIN_TOL = 1e-12


@dataclass(frozen=True, eq=False)
class RepairResult:
    """Outcome of :func:`level_repair`."""

    assign: np.ndarray      #: best schedule reached (the start when no repair was found)
    repairs: int            #: repackings adopted
    tried: int              #: CP-SAT runs
    undecided: int          #: runs that ended at their time limit with neither a schedule nor a proof
    ruled_out: int          #: targets the byte count ruled out before CP-SAT (:func:`_room_for`)
    seconds: float


def _must_arrive(cur: np.ndarray, target: int) -> np.ndarray:
    """Chunks a level-keeping repair of ``target`` must schedule: leaving earns 0, so every chunk
    earning more now, and the target unless it gains by leaving (its profit now is negative)."""
    must = cur > 0
    must[target] = cur[target] >= 0
    return must


def _keep_mask(allowed: np.ndarray, profit: np.ndarray, cur: np.ndarray, assign: np.ndarray) -> np.ndarray:
    """Pairs where a chunk earns at least ``cur`` (and each chunk's slot in ``assign``)."""
    keep = allowed & (profit >= cur[:, None])
    on = np.nonzero(assign >= 0)[0]
    keep[on, assign[on]] = True
    return keep


def _room_for(data: GapData, keep: np.ndarray, cur: np.ndarray, target: int, target_better: np.ndarray) -> bool:
    """False when bytes alone rule the repair of ``target`` out: some slot t by which the chunks
    that must arrive (those earning more than 0 now, the target, and the layers under them, each by
    its last allowed slot, a lower layer by its upper's less d) need more than the budgets of slots
    0..t. A necessary condition: True does not mean CP-SAT will find a schedule. Cheap (O(n + T));
    on the J=20 schedules it ruled out 6 of 6 to 45 of 49 targets, 33 of 53 on T60-J20-s4."""
    d = 1 if data.strict else 0
    rows = keep.copy()
    rows[target] = target_better
    has = rows.any(axis=1)
    last = np.where(has, data.T - 1 - np.argmax(rows[:, ::-1], axis=1), -1)
    must = _must_arrive(cur, target)
    for u in np.argsort(-data.item_l, kind="stable").tolist():   # upper layers first
        lo = int(data.lower[u])
        if must[u] and lo >= 0:
            must[lo] = True
            last[lo] = min(last[lo], last[u] - d)
    if (must & (last < 0)).any():
        return False
    need = np.zeros(data.T, dtype=np.int64)
    np.add.at(need, last[must], data.cost[must])
    return bool((np.cumsum(need) <= np.cumsum(data.budget)).all())


def level_repair(data: GapData, assign: np.ndarray, allowed: np.ndarray, *, deadline: float | None,
                 per_target_s: float = 2.0, workers: int = REPAIR_WORKERS, seed: int = 0) -> RepairResult:
    """Level-keeping repairs (module doc) from ``assign`` (feasible), each a CP-SAT run of at most
    ``per_target_s`` seconds (doubled for each retry of the targets CP-SAT left undecided), until a
    pass over the targets finds none and decides all, or ``deadline`` (``time.perf_counter()``
    seconds) passes."""
    started = time.perf_counter()
    best = np.asarray(assign, dtype=np.int64).copy()
    value = assignment_value(data, best)
    scale = float(np.abs(data.profit).max(initial=0.0))
    repairs = tried = undecided = ruled_out = 0

    def result() -> RepairResult:
        return RepairResult(best, repairs, tried, undecided, ruled_out, time.perf_counter() - started)

    limit, pending, levels = per_target_s, None, None
    while True:
        cur = chunk_profits(data, best)
        better = allowed & (data.profit > cur[:, None] + GAIN_TOL * scale)
        gain = np.where(better, data.profit - cur[:, None], 0.0).max(axis=1, initial=0.0)
        targets = np.nonzero(gain > 0)[0]
        targets = targets[np.argsort(-gain[targets], kind="stable")].tolist()
        if pending is not None:
            targets = [i for i in targets if i in pending]
        keep = _keep_mask(allowed, data.profit, cur, best)
        if targets and levels is None:
            if deadline is not None and deadline - time.perf_counter() <= 0.01:
                return result()   # (building CP-SAT's model is not free either)
            levels = _LevelModel(data, best, cur, keep)
        improved, unknown = False, []
        for target in targets:
            left = None if deadline is None else deadline - time.perf_counter()
            if left is not None and left <= 0.01:
                return result()
            if not _room_for(data, keep, cur, target, better[target]):
                ruled_out += 1
                continue
            tried += 1
            status, cand = levels.repack(target, better[target], limit if left is None else min(limit, left),
                                         workers, seed)
            if status == "unknown":
                undecided += 1
                unknown.append(target)
            if cand is None or not assignment_feasible(data, cand, allowed):
                continue
            cand_value = assignment_value(data, cand)
            if cand_value > value:
                best, value, improved = cand, cand_value, True
                repairs += 1
                break
        if improved:
            limit, pending, levels = per_target_s, None, None
        elif unknown:
            # Undecided targets again, with twice the time (the repacking of T60-J20-s0 took 0.7-2.6 s).
            limit, pending = 2 * limit, set(unknown)
        else:
            return result()


class _LevelModel:
    """CP-SAT model of "every chunk earns at least ``cur``" around ``assign`` (built once per
    incumbent, cloned per target): ``x[i,t]`` for the pairs in ``keep`` (:func:`_keep_mask`), slot
    budgets in bytes, layer order, at most once, and exactly once where leaving (0) would earn
    less."""

    def __init__(self, data: GapData, assign: np.ndarray, cur: np.ndarray, keep: np.ndarray) -> None:
        from ortools.sat.python import cp_model

        n, T = data.n, data.T
        d = 1 if data.strict else 0
        self.n, self.cur = n, cur
        model = self.model = cp_model.CpModel()
        ii, tt = np.nonzero(keep)
        self.pairs = list(zip(ii.tolist(), tt.tolist()))
        lits = [model.new_bool_var(f"x_{i}_{t}") for i, t in self.pairs]
        self.index = [v.index for v in lits]
        self.slots: list[list[tuple[int, int]]] = [[] for _ in range(n)]   # (slot, variable index) per item
        by_slot: list[list[int]] = [[] for _ in range(T)]
        for k, (i, t) in enumerate(self.pairs):
            self.slots[i].append((t, k))
            by_slot[t].append(k)
        for i in range(n):
            item_lits = [lits[k] for _, k in self.slots[i]]
            if cur[i] > 0:                            # (_must_arrive without a target)
                model.add_exactly_one(item_lits)     # (empty: no schedule keeps i's level; never expected)
            elif len(item_lits) > 1:
                model.add_at_most_one(item_lits)
        for t in range(T):
            ks = by_slot[t]
            costs = [int(data.cost[self.pairs[k][0]]) for k in ks]
            if sum(costs) > int(data.budget[t]):
                model.add(cp_model.LinearExpr.weighted_sum([lits[k] for k in ks], costs) <= int(data.budget[t]))
        # Layer order: arrived(u, by t) <= arrived(lower, by t - d) at each slot u may use.
        for u in np.nonzero(data.lower >= 0)[0].tolist():
            lo_slots = self.slots[int(data.lower[u])]
            arrived_u: list = []
            for t, k in self.slots[u]:            # (slots ascending: pairs come from np.nonzero)
                arrived_u.append(lits[k])
                arrived_lo = [lits[kl] for s, kl in lo_slots if s <= t - d]
                model.add(cp_model.LinearExpr.sum(arrived_u) <= cp_model.LinearExpr.sum(arrived_lo))
        for k, (i, t) in enumerate(self.pairs):
            model.add_hint(lits[k], bool(assign[i] == t))

    def repack(self, target: int, target_better: np.ndarray, time_limit_s: float, workers: int, seed: int
               ) -> tuple[str, np.ndarray | None]:
        """A schedule of the model in which ``target`` gains: it arrives where its profit beats
        ``cur[target]`` (or, when that is negative, it may leave), with CP-SAT's verdict:
        ("found", schedule), ("none", None) when there is none, ("unknown", None) at the time limit."""
        from ortools.sat.python import cp_model

        from l3gs_opt.models.backends.cpsat import run_stoppable

        model = self.model.clone()
        var = model.get_bool_var_from_proto_index
        gaining = [var(self.index[k]) for t, k in self.slots[target] if target_better[t]]
        model.add(cp_model.LinearExpr.sum([var(self.index[k]) for t, k in self.slots[target]
                                           if not target_better[t]]) == 0)
        if _must_arrive(self.cur, target)[target]:
            if not gaining:
                return "none", None
            model.add_exactly_one(gaining)
        solver = cp_model.CpSolver()
        solver.parameters.max_time_in_seconds = max(float(time_limit_s), 0.01)
        solver.parameters.num_workers = int(workers)
        solver.parameters.random_seed = int(seed)
        status = run_stoppable(solver, model)
        if status == cp_model.INFEASIBLE:
            return "none", None
        if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
            return "unknown", None
        out = np.full(self.n, -1, dtype=np.int64)
        for k, (i, t) in enumerate(self.pairs):
            if solver.boolean_value(var(self.index[k])):
                out[i] = t
        return "found", out
