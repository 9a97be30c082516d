"""The heuristics ``exact`` starts from, for both searches (Problems I/III and II/IV).

Run directly, without their LP bound, not through the method table: the table names ``exact``
itself.
"""

from __future__ import annotations

import time
from typing import Iterable, Iterator

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import Solution

from .lagrange import GapData, assignment_feasible, assignment_value

__all__ = ["START_NAMES", "check_starts", "run_start", "run_starts", "best_start"]

#: Every start heuristic ``exact``'s ``heuristics`` option may name.
START_NAMES = ("rolling-future:bb", "slope", "rolling:bb", "static", "progressive", "mpc:3")


def check_starts(names: Iterable[str]) -> None:
    """Refuse a name not in :data:`START_NAMES` (one :class:`SolveError` naming it)."""
    for name in names:
        if name not in START_NAMES:
            raise SolveError(f"method 'exact': start heuristic {name!r} is not one of {', '.join(START_NAMES)}")


def run_start(name: str, instance: Instance, left: float | None) -> Solution:
    """Run start heuristic ``name`` on ``instance`` with ``left`` seconds (None: no limit)."""
    from .. import heuristics, rolling

    check_starts([name])
    if name in ("slope", "static", "progressive"):
        fn = {"slope": heuristics.solve_slope, "static": heuristics.solve_static,
              "progressive": heuristics.solve_progressive}[name]
        return fn(instance, time_limit_s=left, with_bound=False)
    if name in ("rolling:bb", "rolling-future:bb"):
        return rolling.solve_rolling(instance, "bb", future=name.startswith("rolling-future"), time_limit_s=left,
                                     with_bound=False)
    return rolling.solve_mpc(instance, 3, time_limit_s=left, with_bound=False)


def run_starts(names: Iterable[str], instance: Instance, deadline: float | None) -> Iterator[tuple[str, Solution]]:
    """Each start heuristic's ``(name, solution)`` in turn, each given the time left to ``deadline``
    (``time.perf_counter()`` seconds; None: no limit); none once it has passed. Every name is
    checked before the first runs."""
    names = tuple(names)
    check_starts(names)
    for name in names:
        left = None if deadline is None else deadline - time.perf_counter()
        if left is not None and left <= 0:
            return
        yield name, run_start(name, instance, left)


def best_start(instance: Instance, data: GapData, names: Iterable[str], deadline: float | None
               ) -> tuple[np.ndarray, str, dict[str, float]]:
    """The best feasible assignment of the start heuristics ``names`` (see :func:`run_starts`):
    ``(assignment, its heuristic's name or "empty", every heuristic's value)``."""
    best, best_name, values = np.full(data.n, -1, dtype=np.int64), "empty", {}
    best_val = assignment_value(data, best)
    for name, sol in run_starts(names, instance, deadline):
        assign = data.assignment(sol.arrivals)
        if not assignment_feasible(data, assign):   # never expected: heuristics are feasible
            continue
        value = assignment_value(data, assign)
        values[name] = value
        if value > best_val:
            best, best_name, best_val = assign, name, value
    return best, best_name, values
