"""Objective and feasibility of an item schedule, from the :class:`~l3gs_opt.problem.items.ItemInstance` alone.

A schedule is a collection of arrivals ``(object, item, t)``: item ``i`` (its global index)
arrives in slot t. The object is redundant (it is ``instance.object[item]``) and checked; it
keeps arrivals triples like the ``(j, l, t)`` of Problems I/II, so one
:class:`~l3gs_opt.problem.solution.Solution` type serves both.

As in :mod:`l3gs_opt.problem.evaluate`: the objective is re-evaluated in float64 with ``math.fsum``;
feasibility is checked in exact integer bytes (Python ints); malformed arrivals are refused
(:func:`~l3gs_opt.problem.evaluate.checked_arrivals`), never truncated or wrapped. Every item method leaves through
:func:`l3gs_opt.problem.solution.finish_solution`, which calls these for an item instance.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Iterable, Sequence

import numpy as np

from l3gs_opt.errors import InstanceError
from l3gs_opt.problem.arguments import check_instance, check_slot
from l3gs_opt.problem.evaluate import budget_violations, checked_arrivals, first_breach
from l3gs_opt.problem.items import ItemInstance

__all__ = ["ItemArrival", "normalize_item_arrivals", "evaluate_items", "item_violations", "items_feasible",
           "repair_items"]

ItemArrival = tuple[int, int, int]


def normalize_item_arrivals(arrivals: Iterable[Sequence[int]]) -> tuple[ItemArrival, ...]:
    """Sorted tuple of ``(object, item, t)`` int triples (by slot, then item)."""
    out = [(int(a[0]), int(a[1]), int(a[2])) for a in arrivals]
    return tuple(sorted(out, key=lambda a: (a[2], a[1], a[0])))


def _item_arrivals(instance: ItemInstance, arrivals: Iterable[Sequence[int]]) -> list[ItemArrival]:
    """The arrivals as int triples; the object is a label (any integer), checked against the item
    by the callers: :func:`item_violations` reports a mismatch, :func:`evaluate_items` refuses it."""
    return checked_arrivals(arrivals, [("object", None), ("item", instance.N), ("slot", instance.T)])


def _arrival_slots(instance: ItemInstance, arrivals: Iterable[Sequence[int]]) -> np.ndarray:
    """``[N]``: the slot each item arrives in, or -1. An item given twice, or under another
    object, is refused: its value would depend on the order of the arrivals or on a guess."""
    slots = np.full(instance.N, -1, dtype=np.int64)
    first: dict[int, int] = {}
    for k, (j, i, t) in enumerate(_item_arrivals(instance, arrivals)):
        if j != int(instance.object[i]):
            raise InstanceError("arrivals", f"= {(j, i, t)}: item {i} is of object {int(instance.object[i])}, "
                                            f"not {j}", (k,))
        if i in first:
            raise InstanceError("arrivals", f"= {(j, i, t)}: item {i} is given twice (also as arrivals[{first[i]}]); "
                                            "an item arrives at most once", (k,))
        first[i] = k
        slots[i] = t
    return slots


def evaluate_items(instance: ItemInstance, arrivals: Iterable[Sequence[int]], *, slot: int | None = None) -> float:
    """Total utility of a (valid) schedule, held items included.

    ``sum_t sum_g max(0, max {U[t, i] : i in g shown at t})``; an item is shown at t when held or
    arrived in a slot ``<= t`` (``< t`` under next-slot availability). With ``slot=s`` only slot s
    counts and an item arriving in s is shown at s (one arriving in another slot is not).

    Each item counts from its arrival as written: budgets, precedence and items already held are
    not checked here (:func:`item_violations` does that), so an infeasible schedule gets the value
    of the formula above.

    Raises
    ------
    InstanceError
        A malformed schedule (wrong type or length, an index out of range, a non-integer), an
        item given twice, or an arrival whose object is not its item's.
    SolveError
        ``instance`` is not an :class:`ItemInstance`; ``slot`` is not an integer in ``0..T-1``.
    """
    inst = instance
    check_instance(inst, ItemInstance)
    slot = check_slot(slot, inst.T)
    slots = _arrival_slots(inst, arrivals)
    if slot is not None:
        shown = (inst.held | (slots == slot))[None]
        utility = inst.utility[slot:slot + 1]
    else:
        t = np.arange(inst.T)[:, None]
        arrived = slots[None] >= 0
        on = slots[None] <= t if inst.options.availability == "same_slot" else slots[None] < t
        shown = (arrived & on) | inst.held[None]
        utility = inst.utility
    values = np.where(shown, utility, 0.0)
    best = np.zeros((values.shape[0], inst.G))
    if inst.N:
        np.maximum.at(best, (slice(None), inst.group_index), values)
    return math.fsum(best.ravel().tolist())


def item_violations(instance: ItemInstance, arrivals: Iterable[Sequence[int]], *,
                    slot: int | None = None) -> list[str]:
    """Every rule the schedule breaks, as readable strings (empty list: feasible).

    Checked exactly: the object matching the item, each item at most once and not already held,
    in slot ``slot`` when given, per-slot or cumulative byte budgets in integer bytes (per slot
    when ``slot`` is given), and precedence: each parent held, or arrived in the same or an
    earlier slot (strictly earlier when ``options.same_slot_layers`` is false).

    Raises
    ------
    InstanceError
        A malformed schedule, which is not a schedule to report on (wrong type or length, an item
        or slot out of range, a non-integer).
    SolveError
        ``instance`` is not an :class:`ItemInstance`; ``slot`` is not an integer in ``0..T-1``.
    """
    inst = instance
    check_instance(inst, ItemInstance)
    slot = check_slot(slot, inst.T)
    problems: list[str] = []
    seen: dict[int, int] = {}
    spent: dict[int, int] = defaultdict(int)
    for j, i, t in _item_arrivals(inst, arrivals):
        if j != int(inst.object[i]):
            problems.append(f"arrival {(j, i, t)}: item {i} is of object {int(inst.object[i])}")
        if slot is not None and t != slot:
            problems.append(f"arrival {(j, i, t)} is not in slot {slot}")
        if i in seen:
            problems.append(f"item {i} arrives twice (slots {seen[i]} and {t})")
            continue
        if inst.held[i]:
            problems.append(f"item {i} is already held")
        seen[i] = t
        spent[t] += int(inst.cost[i])
    problems += budget_violations(spent, inst.bandwidth, cumulative=inst.options.budget == "cumulative" and slot is None)
    strict = not inst.options.same_slot_layers
    for i, t in seen.items():
        for p in inst.parents[i]:
            if inst.held[p]:
                continue
            tp = seen.get(p)
            if tp is None or tp > t or (strict and tp == t):
                rule = "a strictly earlier slot" if strict else "the same or an earlier slot"
                problems.append(f"item {i} arrives in slot {t} but item {p} it requires is not held and does not "
                                f"arrive in {rule}")
    return problems


def items_feasible(instance: ItemInstance, arrivals: Iterable[Sequence[int]], *, slot: int | None = None) -> bool:
    """Whether :func:`item_violations` finds nothing; malformed input raises as it does there."""
    return not item_violations(instance, arrivals, slot=slot)


def repair_items(instance: ItemInstance, arrivals: Iterable[Sequence[int]], *,
                 slot: int | None = None) -> tuple[tuple[ItemArrival, ...], int]:
    """Drop items until the schedule is feasible; return it and how many were dropped.

    For a schedule a backend's tolerance let exceed a budget by a few bytes. Items out of range,
    held or repeated go first; then an item whose parent is missing (with everything that
    requires it); then, per over-full slot, the item of least utility per byte (with its
    descendants). The result is feasible but no longer proven optimal.
    """
    inst = instance
    current: dict[int, int] = {}
    for _, i, t in normalize_item_arrivals(arrivals):
        if 0 <= i < inst.N and 0 <= t < inst.T and not inst.held[i] and i not in current \
                and (slot is None or t == slot):
            current[i] = t
    start = len(current)
    value = inst.utility.sum(axis=0)
    strict = not inst.options.same_slot_layers

    def drop(i: int) -> None:
        stack = [i]
        while stack:
            k = stack.pop()
            if current.pop(k, None) is not None:
                stack.extend(inst.children[k])

    while True:
        schedule = [(int(inst.object[i]), i, t) for i, t in current.items()]
        if items_feasible(inst, schedule, slot=slot):
            return normalize_item_arrivals(schedule), start - len(current)
        orphan = next((i for i, t in current.items() for p in inst.parents[i]
                       if not inst.held[p] and (p not in current or current[p] > t or (strict and current[p] == t))),
                      None)
        if orphan is not None:
            drop(orphan)
            continue
        spent: dict[int, int] = defaultdict(int)
        for i, t in current.items():
            spent[t] += int(inst.cost[i])
        cumulative = inst.options.budget == "cumulative" and slot is None
        bad_t = first_breach(spent, inst.bandwidth, cumulative=cumulative)
        pool = [i for i, t in current.items() if (t <= bad_t if cumulative else t == bad_t)]
        drop(min(pool, key=lambda i: (value[i] / inst.cost[i], -i)))
