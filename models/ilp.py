"""The ``ilp`` method: build the model (with presolve), solve it with a backend, check the answer."""

from __future__ import annotations

import time
from typing import Any, Callable, Mapping

from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import Solution, Status, finish_solution

from .backends import MIN_SOLVE_S, Backend, solve_model, time_left
from .build import build_model
from .linear import LinearModel

__all__ = ["solve_ilp", "solve_built", "MIN_SOLVE_S", "NAIVE_BUILD_FACTOR"]

#: The naive model's build time, in units of the presolved one's (an estimate; at J=200, T=60 the
#: naive one took 0.70 s against 0.67 s): above what the limit leaves,
#: its size is not reported.
NAIVE_BUILD_FACTOR = 1.5


def solve_ilp(instance: Instance, *, backend: "str | Backend" = Backend.HIGHS, form: str = "standard",
              slot: int | None = None, time_limit_s: float | None = None, presolve: bool = True,
              relax: bool = False, options: Mapping[str, Any] | None = None) -> Solution:
    """Solve Problem I-IV, A or the single-slot MCKP exactly with an ILP backend.

    The size of the naive model (no presolve) is reported next to the one solved. ``relax``
    solves the LP relaxation instead: its value is a bound, its schedule is the empty one
    (status ``feasible``), which keeps the answer honest.

    Returns
    -------
    Solution
        ``status`` comes from the backend's own termination, downgraded by the exact checks.
    """
    return solve_built(instance, lambda enabled: build_model(instance, form=form, slot=slot, presolve_enabled=enabled),
                       backend=backend, slot=slot, time_limit_s=time_limit_s, presolve=presolve, relax=relax,
                       options=options)


def solve_built(instance: Any, build: Callable[[bool], LinearModel], *, backend: "str | Backend",
                slot: int | None, time_limit_s: float | None, presolve: bool, relax: bool,
                options: Mapping[str, Any] | None) -> Solution:
    """Build with ``build(presolve_enabled)``, solve on ``backend`` and check the answer: the one
    path every exact model takes (either instance form). The naive model's size (no presolve) is
    reported next to the one solved when the time limit leaves room to build it; ``relax`` gives
    a bound with the empty schedule."""
    backend = Backend.parse(backend)
    started = time.perf_counter()
    model = build(presolve)
    built_s = time.perf_counter() - started
    # The time limit covers building the model too: the backend gets what is left (at least
    # MIN_SOLVE_S, so a model built past the limit still ends as a time limit, not an error).
    left = time_left(time_limit_s, started)
    result = solve_model(model, backend, time_limit_s=left, relax=relax, options=options)
    runtime = time.perf_counter() - started
    # The naive model is built for its size only, after the solve and only when the limit leaves
    # room for it (it is larger than the presolved one: NAIVE_BUILD_FACTOR times its build time).
    fits = time_limit_s is None or runtime + NAIVE_BUILD_FACTOR * built_s <= time_limit_s
    naive = model.size if not presolve else (build(False).size if fits else None)
    bound = None if result.bound is None else result.bound + model.constant
    details: dict[str, Any] = {"presolve": dict(model.stats), **dict(result.details)}
    message = result.message
    if relax:
        arrivals: list = []
        status = Status.FEASIBLE if result.status is Status.OPTIMAL else result.status
        message = f"LP relaxation: bound only, empty schedule; {message}"
    else:
        values, status = result.values, result.status
        if status is Status.ERROR and values is not None:
            values = None
            message = f"the backend failed: its values are not read, the empty schedule is returned; {message}"
        if values is not None:
            count, worst = model.fractional(values)
            if count:
                # Not an incumbent: rounded and repaired, a relaxation would pass for one.
                values = None
                if status is Status.OPTIMAL:
                    status = Status.ERROR
                message = (f"no incumbent: the backend's values are fractional ({count} arrival variable(s), "
                           f"up to {worst:.3g} from an integer), so the empty schedule is returned; {message}")
        if status is Status.ERROR:
            bound = None      # a failed run (or a fractional "optimum") certifies nothing
        arrivals = model.schedule(values) if values is not None else []
        if result.values is None and status in (Status.TIME_LIMIT, Status.FEASIBLE):
            message = f"no incumbent found: the empty schedule is returned; {message}"
    return finish_solution(instance, arrivals, problem=model.problem, method="lp" if relax else "ilp",
                           status=status, bound=bound, runtime_s=runtime, slot=slot,
                           backend=backend.value, backend_version=result.version, size_before=naive,
                           size_after=model.size, message=message, details=details)
