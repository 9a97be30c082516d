"""``solve``: one entry point for every method, as the CLI's ``solve`` uses it."""

from __future__ import annotations

from typing import Any, Callable, Mapping

from .errors import SolveError
from .instance import Instance
from .solution import Solution

__all__ = ["METHODS", "solve"]


def _ilp(instance: Instance, **kw: Any) -> Solution:
    from l3gs_opt.models import solve_ilp

    return solve_ilp(instance, **kw)


def _lp(instance: Instance, **kw: Any) -> Solution:
    from l3gs_opt.models import solve_ilp

    return solve_ilp(instance, relax=True, **kw)


def _brute(instance: Instance, *, slot: int | None = None, **_model_options: Any) -> Solution:
    # Enumeration needs no backend, form or presolve: those options do not apply and are ignored.
    from l3gs_opt.solvers import solve_brute_force

    return solve_brute_force(instance, slot=slot)


#: Method name -> function(instance, **options) -> Solution.
METHODS: dict[str, Callable[..., Solution]] = {"ilp": _ilp, "lp": _lp, "brute": _brute}


def solve(instance: Instance, method: str = "ilp", *, backend: str = "highs", form: str = "standard",
          slot: int | None = None, time_limit_s: float | None = None, presolve: bool = True,
          options: Mapping[str, Any] | None = None) -> Solution:
    """Solve ``instance`` with ``method``.

    Parameters
    ----------
    instance : Instance
    method : {"ilp", "lp", "brute"}
        ``ilp``: exact model on ``backend``; ``lp``: its LP relaxation (a bound);
        ``brute``: enumeration (tiny instances only).
    backend : {"cbc", "highs", "cpsat", "scip"}
    form : {"standard", "gap"}
        ``gap``: Problem A, the GAP form (layered only).
    slot : int, optional
        Solve the single-slot MCKP of this slot given ``instance.held``.
    time_limit_s : float, optional
        Seconds; a run that hits it says ``time_limit`` and carries a valid bound.
    presolve : bool
    options : mapping, optional
        Backend-specific options (unknown ones warn).

    Raises
    ------
    SolveError
        Unknown method, form or backend; a slot out of range; an option that does not apply.
    """
    if method not in METHODS:
        raise SolveError(f"method {method!r} is not one of {', '.join(METHODS)}")
    return METHODS[method](instance, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                           presolve=presolve, options=options)
