"""Single-slot methods: ``bb``, ``dp``, ``fptas:EPS`` and ``greedy`` on an instance's slot.

Each solves the single-slot MCKP of docs/design.md (the paper's Lemma 3) at ``slot`` given
``instance.held`` and returns a :class:`~l3gs_opt.problem.solution.Solution` with ``problem="MCKP"``,
whose objective is the utility shown at the slot, held chunks included.

* ``bb`` - exact: LP bound from upper hulls, Lagrangian reduction, bounded state DP
  (:func:`l3gs_opt.solvers._mckp.branch_and_bound`; integer utilities cut bounds below the
  incumbent + 1, and large DPs run their stages compiled with numba). Proves optimality, or
  under a time limit returns its best answer with a valid bound.
* ``dp`` - exact: DP over bytes divided by the gcd of the option costs; a
  :class:`~l3gs_opt.errors.SolveError` when the table would exceed ``MAX_DP_CELLS``.
* ``fptas:EPS`` - value at least ``(1 - EPS)`` times the optimum (profit scaling); its
  bound is certified.
* ``greedy`` - LP-greedy rounded; its bound is the LP value.

Example
-------
>>> from l3gs_opt.solvers.mckp import solve_bb
>>> solution = solve_bb(instance, slot=0)          # doctest: +SKIP
>>> solution.status, solution.objective, solution.gap   # doctest: +SKIP
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.arguments import check_slot
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import shown_value
from l3gs_opt.problem.solution import Solution, Status, finish_solution

from . import _mckp
from ._mckp import OptionTable

__all__ = ["slot_table", "table_arrivals", "resolve_slot", "solve_bb", "solve_dp", "solve_fptas", "solve_greedy"]


def resolve_slot(instance: Any, slot: int | None, method: str) -> int:
    """The slot a single-slot method solves (either instance form): ``slot``, or 0 for a one-slot instance.

    Raises
    ------
    SolveError
        ``slot`` missing on a multi-slot instance, or out of range.
    """
    if slot is None:
        if instance.T == 1:
            return 0
        raise SolveError(f"method {method!r} solves one slot's MCKP: pass slot (0..{instance.T - 1}) for an "
                         f"instance with T = {instance.T} slots, or use rolling:{method} for the whole horizon")
    return check_slot(slot, instance.T)


def slot_table(instance: Instance, slot: int, *, budget: int | None = None) -> tuple[OptionTable, float]:
    """The option table of ``slot`` (utility at that slot) and the held constant."""
    gain, constant = shown_value(instance, instance.utility[slot:slot + 1])
    table = _mckp.build_table(layered=instance.layered, cost=instance.cost, gain=gain[0], held=instance.held,
                              budget=int(instance.bandwidth[slot]) if budget is None else int(budget),
                              same_slot_layers=instance.options.same_slot_layers)
    return table, constant


def table_arrivals(table: OptionTable, choice: np.ndarray, held_levels: np.ndarray | None, slot: int,
                   *, layered: bool) -> list[tuple[int, int, int]]:
    """Arrivals ``(j, l, slot)`` of a choice (-1 = none) over the table's rows."""
    out: list[tuple[int, int, int]] = []
    for i in np.nonzero(choice >= 0)[0]:
        j = int(table.rows[i])
        top = int(table.level[i, choice[i]])
        if layered:
            out.extend((j, l, slot) for l in range(int(held_levels[j]), top + 1))
        else:
            out.append((j, top, slot))
    return out


def _finish(instance: Instance, slot: int, table: OptionTable, constant: float, result: _mckp.MckpResult, *,
            method: str, started: float, status: Status, message: str = "") -> Solution:
    arrivals = table_arrivals(table, result.choice, instance.held_levels, slot, layered=instance.layered)
    runtime = time.perf_counter() - started
    return finish_solution(instance, arrivals, problem="MCKP", method=method, status=status,
                           bound=result.bound + constant, runtime_s=runtime, slot=slot, message=message,
                           details={**result.stats, "rows": table.n, "options": int(table.valid.sum())})


def solve_bb(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
             **_ignored: Any) -> Solution:
    """Exact MCKP of one slot by branch-and-bound (see :func:`l3gs_opt.solvers._mckp.branch_and_bound`)."""
    started = time.perf_counter()
    slot = resolve_slot(instance, slot, "bb")
    table, constant = slot_table(instance, slot)
    result = _mckp.branch_and_bound(table, time_limit_s=time_limit_s)
    status = Status.OPTIMAL if result.optimal else Status.TIME_LIMIT
    message = "" if result.optimal else f"stopped ({result.stats.get('stopped')}): best answer and a valid bound"
    return _finish(instance, slot, table, constant, result, method="bb", started=started, status=status,
                   message=message)


def solve_dp(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
             **_ignored: Any) -> Solution:
    """Exact MCKP of one slot by DP over gcd-scaled bytes."""
    started = time.perf_counter()
    slot = resolve_slot(instance, slot, "dp")
    table, constant = slot_table(instance, slot)
    result = _mckp.dynamic_programme(table)
    return _finish(instance, slot, table, constant, result, method="dp", started=started, status=Status.OPTIMAL)


def solve_fptas(instance: Instance, eps: float, *, slot: int | None = None, time_limit_s: float | None = None,
                **_ignored: Any) -> Solution:
    """(1 - eps)-approximate MCKP of one slot; ``bound`` is certified (``value + eps * z0``)."""
    started = time.perf_counter()
    slot = resolve_slot(instance, slot, f"fptas:{eps}")
    table, constant = slot_table(instance, slot)
    result = _mckp.fptas(table, eps)
    return _finish(instance, slot, table, constant, result, method=f"fptas:{eps}", started=started,
                   status=Status.FEASIBLE, message=f"(1 - {eps})-approximation")


def solve_greedy(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
                 **_ignored: Any) -> Solution:
    """LP-greedy MCKP of one slot; ``bound`` is the LP value."""
    started = time.perf_counter()
    slot = resolve_slot(instance, slot, "greedy")
    table, constant = slot_table(instance, slot)
    result = _mckp.greedy(table)
    return _finish(instance, slot, table, constant, result, method="greedy", started=started,
                   status=Status.FEASIBLE, message="LP-greedy; bound is the LP relaxation")
