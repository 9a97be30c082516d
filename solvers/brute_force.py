"""Brute force: every schedule of a tiny instance, checked and valued straight from the definitions.

The reference the tests hold every model and solver to. It shares no code with the models or
with :mod:`l3gs_opt.problem.evaluate`: rules and objective are written out again here, plainly.
Layered utilities may be negative: every layer held counts, whatever its sign, and nothing
is pruned on a sign (every schedule is valued).
"""

from __future__ import annotations

import itertools
import math
import time

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import Solution, Status, finish_solution

__all__ = ["solve_brute_force", "MAX_SCHEDULES"]

#: Refuse instances with more candidate schedules than this (each is checked in Python).
MAX_SCHEDULES = 300_000


def _feasible(inst: Instance, when: dict[tuple[int, int], int], slot: int | None) -> bool:
    spent = [0] * inst.T
    for (j, l), t in when.items():
        spent[t] += int(inst.cost[j, l])
    if inst.options.budget == "per_slot" or slot is not None:
        if any(spent[t] > int(inst.bandwidth[t]) for t in range(inst.T)):
            return False
    else:
        total_spent = total_budget = 0
        for t in range(inst.T):
            total_spent += spent[t]
            total_budget += int(inst.bandwidth[t])
            if total_spent > total_budget:
                return False
    if inst.layered:
        for (j, l), t in when.items():
            if l == 0 or inst.held[j][l - 1]:
                continue
            if (j, l - 1) not in when:
                return False
            t_below = when[(j, l - 1)]
            if t_below > t or (not inst.options.same_slot_layers and t_below == t):
                return False
    return True


def _value(inst: Instance, when: dict[tuple[int, int], int], slot: int | None) -> float:
    slots = [slot] if slot is not None else list(range(inst.T))
    total = 0.0
    for t in slots:
        for j in range(inst.J):
            shown = []
            for l in range(inst.L):
                if inst.held[j][l]:
                    shown.append(l)
                elif (j, l) in when:
                    a = when[(j, l)]
                    if slot is not None or a < t or (a == t and inst.options.availability == "same_slot"):
                        shown.append(l)
            if inst.layered:
                total += sum(float(inst.utility[t][j][l]) for l in shown)
            else:
                total += max([float(inst.utility[t][j][l]) for l in shown], default=0.0)
    return total


def solve_brute_force(instance: Instance, *, slot: int | None = None) -> Solution:
    """Enumerate all schedules (each unheld chunk: never, or one slot) and keep the best.

    Raises
    ------
    SolveError
        When the instance has more than ``MAX_SCHEDULES`` candidate schedules.
    """
    inst = instance
    started = time.perf_counter()
    chunks = [(j, l) for j in range(inst.J) for l in range(inst.L) if not inst.held[j][l]]
    choices = [None, slot] if slot is not None else [None, *range(inst.T)]
    count = len(choices) ** len(chunks)
    if count > MAX_SCHEDULES:
        raise SolveError(f"brute force: {count} candidate schedules exceed the limit of {MAX_SCHEDULES}")
    # Below any schedule's value: with signed layer utilities every schedule, the empty one
    # included, can be worth less than 0 (a negative layer already held).
    best_value, best = -math.inf, {}
    for pick in itertools.product(choices, repeat=len(chunks)):
        when = {c: t for c, t in zip(chunks, pick) if t is not None}
        if not _feasible(inst, when, slot):
            continue
        value = _value(inst, when, slot)
        if value > best_value:
            best_value, best = value, when
    arrivals = [(j, l, t) for (j, l), t in best.items()]
    problem = "MCKP" if slot is not None else inst.problem
    return finish_solution(inst, arrivals, problem=problem, method="brute", status=Status.OPTIMAL,
                           bound=best_value, runtime_s=time.perf_counter() - started, slot=slot,
                           message=f"enumerated {count} schedules")
