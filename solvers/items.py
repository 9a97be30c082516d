"""Fast solvers for item instances (``l3gs-opt/items@1``): per-slot MCKP, rolling schedulers, brute force.

**Per-slot MCKP.** Given what is held, an object can move to any *precedence-closed* item set:
a set S of unheld items whose every parent is held or (same-slot precedence) in S itself; under
strict precedence every parent must be held before the slot. Each object is one MCKP row, each
closed set one option: its cost the bytes of S, its value what S adds at the slot, summed over
the object's groups (``max(0, max_{i in S, g} gain[i])`` per group, the gain over the group's held
items). Two items of one group that no item requires are never both worth sending in one slot
(drop the one worth less at the slot: the set stays closed, loses nothing and costs less), so
sets hold at most one such "leaf" per group; for Problem II this leaves the L versions, for
Problem I the L - h layer prefixes. The sets are enumerated per object (cached per held state;
more than :data:`MAX_CLOSED_SETS` is a :class:`~l3gs_opt.errors.SolveError`) and the table is
handed to the single-slot core (:mod:`._mckp`: ``bb``, ``dp``, ``greedy``, ``fptas:EPS``).

**Rolling.** ``rolling:SOLVER`` / ``rolling-future:SOLVER`` commit each slot's MCKP answer as
:mod:`.rolling` does for Problems I/II (next-slot availability, strict precedence, cumulative
budgets with in-flight downloads, future valuation summed over the rest of the horizon);
``mpc:H`` solves the item ILP over the next H slots and commits the first. Their bound is the LP
relaxation of the item ILP (HiGHS).

**Brute force** (:func:`solve_items_brute_force`) enumerates every schedule of a tiny instance,
with the rules and the objective written out again; it shares no code with the models, with
:mod:`l3gs_opt.problem.items_eval` or with the enumeration here.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.items import ItemInstance, item_gain
from l3gs_opt.problem.solution import Solution, Status, finish_solution

from . import _mckp
from ._mckp import MckpResult, OptionTable
from .mckp import resolve_slot
from .brute_force import MAX_SCHEDULES

__all__ = ["MAX_CLOSED_SETS", "closed_sets", "item_slot_table", "solve_items_slot", "solve_items_rolling",
           "solve_items_mpc", "solve_items_brute_force"]

#: Most precedence-closed item sets enumerated for one object in one state. An object whose items
#: are independent has 2^n of them (a ``distill`` object with L layers about 2^(L+1)); past this
#: limit the per-slot MCKP is refused rather than left to exhaust memory: use the ILP.
MAX_CLOSED_SETS = 1 << 16

Picker = Callable[[OptionTable, "float | None"], MckpResult]


# -- closed sets -------------------------------------------------------------------------------------

@dataclass
class _Structure:
    """Per object: its items (topological order), and the enumeration cache."""

    objects: list[int]
    items: list[list[int]]
    leaf: np.ndarray
    cache: dict


def _structure(inst: ItemInstance) -> _Structure:
    by_object: dict[int, list[int]] = {}
    for i in inst.order.tolist():
        by_object.setdefault(int(inst.object[i]), []).append(i)
    objects = sorted(by_object)
    leaf = np.array([not inst.children[i] for i in range(inst.N)], dtype=bool)
    return _Structure(objects=objects, items=[by_object[j] for j in objects], leaf=leaf, cache={})


def closed_sets(instance: ItemInstance, items: list[int], held: np.ndarray, parent_ok: np.ndarray, *,
                leaf: np.ndarray | None = None, limit: int = MAX_CLOSED_SETS) -> list[tuple[int, ...]]:
    """Non-empty sets S of unheld ``items`` (one object's, in topological order) that can arrive in one
    slot: every parent of an item of S is in ``parent_ok`` (held before the slot) or, with same-slot
    precedence, in S; at most one leaf (an item nothing requires) per group.

    Raises
    ------
    SolveError
        More than ``limit`` sets.
    """
    inst = instance
    strict = not inst.options.same_slot_layers
    leaf = np.array([not inst.children[i] for i in range(inst.N)], dtype=bool) if leaf is None else leaf
    gi = inst.group_index
    # Items that can be in some set: each parent already allowed, or itself such a candidate.
    cand: list[int] = []
    possible: set[int] = set()
    for i in items:
        if held[i]:
            continue
        if all(parent_ok[p] or (not strict and p in possible) for p in inst.parents[i]):
            cand.append(i)
            possible.add(i)
    out: list[tuple[int, ...]] = []
    chosen: list[int] = []
    chosen_set: set[int] = set()
    leaf_groups: set[int] = set()
    # Depth-first over the candidates in topological order, each in or out (an explicit stack:
    # objects with many items must not hit Python's recursion limit).
    stack: list[tuple[int, int]] = [(0, 0)]   # (candidate position, 0 = first visit / 1 = after "in")
    while stack:
        k, phase = stack.pop()
        if k == len(cand):
            if chosen:
                out.append(tuple(sorted(chosen)))
                if len(out) > limit:
                    raise SolveError(f"object {int(inst.object[cand[0]])}: more than {limit} precedence-closed "
                                     f"item sets can arrive in one slot (from {len(cand)} candidate items); the "
                                     "per-slot MCKP enumerates them: use method 'ilp' for this instance")
            continue
        i = cand[k]
        if phase == 1:  # undo "in", then explore "out"
            chosen.pop()
            chosen_set.discard(i)
            if leaf[i]:
                leaf_groups.discard(int(gi[i]))
            stack.append((k + 1, 0))
            continue
        ok = all(parent_ok[p] or (not strict and p in chosen_set) for p in inst.parents[i])
        if ok and not (leaf[i] and int(gi[i]) in leaf_groups):
            chosen.append(i)
            chosen_set.add(i)
            if leaf[i]:
                leaf_groups.add(int(gi[i]))
            stack.append((k, 1))
            stack.append((k + 1, 0))
        else:
            stack.append((k + 1, 0))
    return out


def _object_sets(st: _Structure, inst: ItemInstance, o: int, held: np.ndarray,
                 parent_ok: np.ndarray) -> tuple[list[tuple[int, ...]], np.ndarray, np.ndarray, np.ndarray]:
    """Cached: the object's closed sets, their membership matrix [S, n], the object's items [n],
    and each set's bytes [S] (int64, exact)."""
    items = st.items[o]
    key = (o, tuple(bool(held[i]) for i in items), tuple(bool(parent_ok[i]) for i in items))
    got = st.cache.get(key)
    if got is None:
        sets = closed_sets(inst, items, held, parent_ok, leaf=st.leaf)
        local = {i: k for k, i in enumerate(items)}
        member = np.zeros((len(sets), len(items)), dtype=bool)
        for s, S in enumerate(sets):
            member[s, [local[i] for i in S]] = True
        costs = [int(c) for c in inst.cost[items]]
        if sum(costs) < 2**62:
            nbytes = member.astype(np.int64) @ np.asarray(costs, dtype=np.int64)
        else:  # sums of 2**53-byte items could overflow int64: exact Python ints, capped
            nbytes = np.array([min(sum(costs[local[i]] for i in S), 2**62) for S in sets], dtype=np.int64)
        got = (sets, member, np.asarray(items, dtype=np.int64), nbytes)
        st.cache[key] = got
    return got


def _set_values(inst: ItemInstance, member: np.ndarray, items: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Value of each set [S]: ``sum_t sum_g max(0, max_{i in S, g} gain[t, i])`` over the rows of
    ``gain`` [T', N] (one row: a slot; several: the rest of the horizon)."""
    g_local = gain[:, items]                      # [T', n]
    gi = inst.group_index[items]
    values = np.zeros(member.shape[0])
    labels, counts = np.unique(gi, return_counts=True)
    singles = np.isin(gi, labels[counts == 1])
    if singles.any():
        values += member[:, singles].astype(np.float64) @ g_local[:, singles].sum(axis=0)
    for g in labels[counts > 1]:
        cols = np.flatnonzero(gi == g)
        # [S, T', m]: a member's gain per slot, max over the group's members, summed over slots.
        values += (member[:, None, cols] * g_local[None, :, cols]).max(axis=2).sum(axis=1)
    return values


def item_slot_table(instance: ItemInstance, gain: np.ndarray, held: np.ndarray, parent_ok: np.ndarray,
                    budget: int, *, structure: _Structure | None = None
                    ) -> tuple[OptionTable, list[list[tuple[int, ...]]]]:
    """The option table of one slot (one row per object with something worth sending) and, per
    table row, its closed sets (``table.level[r, k]`` indexes them).

    Parameters
    ----------
    gain : float array [T', N]
        What showing each item adds over its group's held items, per valued slot
        (:func:`l3gs_opt.problem.items.item_gain` given ``held``).
    held, parent_ok : bool arrays [N]
        Held items; items that may serve as parents this slot (held before it).
    budget : int
        Bytes available.
    """
    inst = instance
    st = structure or _structure(inst)
    all_sets, costs, values = [], [], []
    for o in range(len(st.objects)):
        sets, member, items, nbytes = _object_sets(st, inst, o, held, parent_ok)
        all_sets.append(sets)
        costs.append(nbytes)
        values.append(_set_values(inst, member, items, gain) if sets else np.zeros(0))
    n = len(all_sets)
    K = max((len(s) for s in all_sets), default=0)
    cost = np.ones((n, max(K, 1)), dtype=np.int64)
    value = np.zeros((n, max(K, 1)))
    pad = np.ones((n, max(K, 1)), dtype=bool)     # padding is passed as "held": never an option
    for o in range(n):
        k = len(all_sets[o])
        cost[o, :k] = np.maximum(costs[o], 1)
        value[o, :k] = values[o]
        pad[o, :k] = False
    # The separate-representation table: each column one whole option, sorted, Pareto-filtered,
    # left-packed; ``level`` keeps the column, i.e. the index of the closed set.
    table = _mckp.build_table(layered=False, cost=cost, gain=value, held=pad, budget=int(budget))
    return table, [all_sets[int(r)] for r in table.rows]


def _chosen(table: OptionTable, sets: list[list[tuple[int, ...]]], choice: np.ndarray) -> list[int]:
    out: list[int] = []
    for r in np.nonzero(choice >= 0)[0]:
        out.extend(sets[int(r)][int(table.level[r, choice[r]])])
    return out


# -- single slot ------------------------------------------------------------------------------------

def _picker(name: str, backend: str) -> Picker:
    from .rolling import slot_picker

    return slot_picker(name, backend=backend)


def solve_items_slot(instance: ItemInstance, solver: str, *, slot: int | None = None,
                     time_limit_s: float | None = None, backend: str = "highs") -> Solution:
    """The single-slot MCKP of an item instance at ``slot`` given ``held``, by ``solver`` (``bb``,
    ``dp``, ``greedy``, ``fptas:EPS``); ``problem = "MCKP"``, objective the utility shown at the slot."""
    started = time.perf_counter()
    slot = resolve_slot(instance, slot, solver)
    pick = _picker(solver, backend)
    inst = instance
    gain, base = item_gain(inst, inst.utility[slot:slot + 1])
    table, sets = item_slot_table(inst, gain, inst.held, inst.held, int(inst.bandwidth[slot]))
    result = pick(table, time_limit_s)
    constant = math.fsum(base.ravel().tolist())
    arrivals = [(int(inst.object[i]), i, slot) for i in _chosen(table, sets, result.choice)]
    if solver in ("bb", "dp"):
        status = Status.OPTIMAL if result.optimal else Status.TIME_LIMIT
        message = "" if result.optimal else f"stopped ({result.stats.get('stopped')}): best answer and a valid bound"
    else:
        status = Status.FEASIBLE
        message = "LP-greedy; bound is the LP relaxation" if solver == "greedy" else f"{solver}: approximation"
    return finish_solution(inst, arrivals, problem="MCKP", method=solver, status=status,
                                 bound=result.bound + constant, runtime_s=time.perf_counter() - started, slot=slot,
                                 message=message, details={**result.stats, "rows": table.n,
                                                           "options": int(table.valid.sum())})


# -- the LP bound -----------------------------------------------------------------------------------

# -- rolling schedulers -------------------------------------------------------------------------------

def _gain_rows(inst: ItemInstance, slot: int, held: np.ndarray, future: bool) -> np.ndarray:
    """[T', N] gains that value an arrival in ``slot``: its first shown slot, or through the horizon."""
    first = slot + (1 if inst.options.availability == "next_slot" else 0)
    if first >= inst.T:
        return np.zeros((1, inst.N))
    rows = inst.utility[first:] if future else inst.utility[first:first + 1]
    return item_gain(inst, rows, held)[0]


def solve_items_rolling(instance: ItemInstance, solver: str, *, future: bool = False, slot: int | None = None,
                        time_limit_s: float | None = None, backend: str = "highs",
                        with_bound: bool = True) -> Solution:
    """``rolling:SOLVER`` / ``rolling-future:SOLVER`` on an item instance (see the module docstring).

    Under a cumulative budget unspent bytes carry over; when bytes are left after a slot's MCKP,
    the most efficient option (value per byte) that does not fit them but fits the bytes still to
    come starts downloading and arrives in the first slot whose bytes cover it, as in
    :func:`l3gs_opt.solvers.rolling.run_rolling`.
    """
    name = f"{'rolling-future' if future else 'rolling'}:{solver}"
    if slot is not None:
        raise SolveError(f"method {name!r} schedules the whole horizon: slot does not apply "
                         f"(use method {solver!r} for one slot)")
    from .rolling import RollingForm, run_rolling

    inst = instance
    st = _structure(inst)
    strict = not inst.options.same_slot_layers

    def table(t: int, held: np.ndarray, fresh: np.ndarray, budget: int):
        # Under strict precedence an item that arrived this slot is no parent yet.
        parent_ok = held & ~fresh if strict else held.copy()
        tab, sets = item_slot_table(inst, _gain_rows(inst, t, held, future), held, parent_ok, budget, structure=st)
        return tab, lambda row, option: list(sets[row][int(tab.level[row, option])])

    def finish(arrivals, **kw) -> Solution:
        return finish_solution(inst, arrivals, problem="items", **kw)

    form = RollingForm(held=inst.held.copy(), table=table, arrival=lambda i, t: (int(inst.object[i]), int(i), t),
                       finish=finish, held_value=math.fsum(item_gain(inst)[1].ravel().tolist()),
                       bound_label="LP relaxation of the item ILP",
                       details=lambda: {"closed_set_states": len(st.cache)})
    return run_rolling(inst, _picker(solver, backend), method=name, future=future, time_limit_s=time_limit_s,
                       with_bound=with_bound, form=form)


def solve_items_mpc(instance: ItemInstance, horizon: int, *, slot: int | None = None,
                    time_limit_s: float | None = None, backend: str = "highs", with_bound: bool = True) -> Solution:
    """``mpc:H`` on the item form: :func:`l3gs_opt.solvers.rolling.solve_mpc` (one loop, both forms)."""
    from .rolling import solve_mpc

    return solve_mpc(instance, horizon, slot=slot, time_limit_s=time_limit_s, backend=backend,
                     with_bound=with_bound)


# -- brute force ------------------------------------------------------------------------------------

def solve_items_brute_force(instance: ItemInstance, *, slot: int | None = None) -> Solution:
    """Every schedule of a tiny item instance (each unheld item: never, or one slot), the best kept.

    Raises
    ------
    SolveError
        More than ``MAX_SCHEDULES`` candidate schedules.
    """
    inst = instance
    started = time.perf_counter()
    T, N = inst.T, inst.N
    unheld = [i for i in range(N) if not inst.held[i]]
    choices = [None, slot] if slot is not None else [None, *range(T)]
    count = len(choices) ** len(unheld)
    if count > MAX_SCHEDULES:
        raise SolveError(f"brute force: {count} candidate schedules exceed the limit of {MAX_SCHEDULES}")
    groups: dict[int, list[int]] = {}
    for i in range(N):
        groups.setdefault(int(inst.group[i]), []).append(i)
    edges = [(int(p), int(c)) for p, c in inst.requires.tolist()]
    held = [bool(h) for h in inst.held]
    cost = [int(c) for c in inst.cost]
    bandwidth = [int(b) for b in inst.bandwidth]
    strict = not inst.options.same_slot_layers
    same_slot = inst.options.availability == "same_slot"
    per_slot = inst.options.budget == "per_slot" or slot is not None
    slots = [slot] if slot is not None else list(range(T))
    best_value, best = -1.0, {}
    for pick in itertools.product(choices, repeat=len(unheld)):
        when = {i: t for i, t in zip(unheld, pick) if t is not None}
        spent = [0] * T
        for i, t in when.items():
            spent[t] += cost[i]
        if per_slot:
            if any(spent[t] > bandwidth[t] for t in range(T)):
                continue
        else:
            total_s = total_b = 0
            over = False
            for t in range(T):
                total_s += spent[t]
                total_b += bandwidth[t]
                over |= total_s > total_b
            if over:
                continue
        ok = True
        for p, c in edges:
            if c in when and not held[p]:
                if p not in when or when[p] > when[c] or (strict and when[p] == when[c]):
                    ok = False
                    break
        if not ok:
            continue
        value = 0.0
        for t in slots:
            for items in groups.values():
                shown = [float(inst.utility[t][i]) for i in items if held[i] or (
                    i in when and (slot is not None or when[i] < t or (same_slot and when[i] == t)))]
                value += max(shown, default=0.0)
        if value > best_value:
            best_value, best = value, when
    arrivals = [(int(inst.object[i]), i, t) for i, t in best.items()]
    return finish_solution(inst, arrivals, problem="MCKP" if slot is not None else "items", method="brute",
                                 status=Status.OPTIMAL, bound=best_value, runtime_s=time.perf_counter() - started,
                                 slot=slot, message=f"enumerated {count} schedules")


# -- dispatch -----------------------------------------------------------------------------------------
