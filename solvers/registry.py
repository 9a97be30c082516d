"""Method names of the solvers package, resolved to functions.

``resolve(name)`` returns ``function(instance, *, slot, time_limit_s, **options) -> Solution``
for a method name such as ``"brute"``; parametrised names (``"fptas:0.01"``,
``"rolling:bb"``) are parsed here. :func:`l3gs_opt.solve` asks this registry for every method
that is not an ILP.
"""

from __future__ import annotations

from typing import Any, Callable

from l3gs_opt.errors import SolveError
from l3gs_opt.instance import Instance
from l3gs_opt.solution import Solution

from .brute_force import solve_brute_force

__all__ = ["names", "resolve"]

SolverFn = Callable[..., Solution]


def _brute(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
           **_model_options: Any) -> Solution:
    # Enumeration needs no backend, form or presolve: those options do not apply and are ignored.
    return solve_brute_force(instance, slot=slot)


_FIXED: dict[str, SolverFn] = {"brute": _brute}


def names() -> list[str]:
    """Method names (parametrised ones shown with their parameter, e.g. ``fptas:EPS``)."""
    return sorted(_FIXED)


def resolve(name: str) -> SolverFn:
    """The function behind a method name; unknown names are a :class:`SolveError`."""
    if name in _FIXED:
        return _FIXED[name]
    raise SolveError(f"method {name!r} is not one of ilp, lp, {', '.join(names())}")
