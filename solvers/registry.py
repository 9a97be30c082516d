"""Method names of the solvers package, resolved to functions.

``resolve(name)`` returns ``function(instance, *, slot, time_limit_s, **options) -> Solution``
for a method name such as ``"bb"``; parametrised names (``"fptas:0.01"``, ``"rolling:bb"``,
``"rolling-future:fptas:0.1"``, ``"mpc:5"``) are parsed here. :func:`l3gs_opt.solve` asks this
registry for every method that is not an ILP. Options a method does not use (``backend``,
``form``, ``presolve``, ``options``) are accepted and ignored; the ILP-based ones
(``rolling:ilp``, ``mpc:H``) use ``backend``.

Single-slot methods (``bb``, ``dp``, ``fptas:EPS``, ``greedy``) need ``slot`` unless the
instance has one slot; multi-slot methods (``rolling:*``, ``rolling-future:*``, ``mpc:H``,
``progressive``, ``slope``, ``static``) refuse a ``slot``.
"""

from __future__ import annotations

import functools
from typing import Any, Callable

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import Solution

from .brute_force import solve_brute_force

__all__ = ["names", "resolve"]

SolverFn = Callable[..., Solution]


def _brute(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
           **_model_options: Any) -> Solution:
    # Enumeration needs no backend, form or presolve: those options do not apply and are ignored.
    return solve_brute_force(instance, slot=slot)


def _with_bound(options: Any) -> bool:
    """``options={"bound": False}`` skips the LP bound of the multi-slot heuristics."""
    if options and "bound" in options:
        return bool(options["bound"])
    return True


def _single(name: str) -> SolverFn:
    from . import mckp

    fn = {"bb": mckp.solve_bb, "dp": mckp.solve_dp, "greedy": mckp.solve_greedy}[name]

    def run(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
            **_model_options: Any) -> Solution:
        return fn(instance, slot=slot, time_limit_s=time_limit_s)

    run.__name__ = f"solve_{name}"
    return run


def _fptas(eps: float) -> SolverFn:
    from . import mckp

    def run(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
            **_model_options: Any) -> Solution:
        return mckp.solve_fptas(instance, eps, slot=slot, time_limit_s=time_limit_s)

    return run


def _multi(kind: str) -> SolverFn:
    from . import heuristics

    fn = {"progressive": heuristics.solve_progressive, "slope": heuristics.solve_slope,
          "static": heuristics.solve_static}[kind]

    def run(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
            options: Any = None, **_model_options: Any) -> Solution:
        return fn(instance, slot=slot, time_limit_s=time_limit_s, with_bound=_with_bound(options))

    return run


def _rolling(solver: str, future: bool) -> SolverFn:
    from . import rolling

    rolling.slot_picker(solver)   # validate the per-slot solver name now

    def run(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
            backend: str = "highs", options: Any = None, **_model_options: Any) -> Solution:
        return rolling.solve_rolling(instance, solver, future=future, slot=slot, time_limit_s=time_limit_s,
                                     backend=backend, with_bound=_with_bound(options))

    return run


def _mpc(horizon: int) -> SolverFn:
    from . import rolling

    def run(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
            backend: str = "highs", options: Any = None, **_model_options: Any) -> Solution:
        return rolling.solve_mpc(instance, horizon, slot=slot, time_limit_s=time_limit_s, backend=backend,
                                 with_bound=_with_bound(options))

    return run


def _link_dp(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
             **_model_options: Any) -> Solution:
    from .link_dp import solve_link_dp

    if slot is not None:
        raise SolveError("method 'link-dp' schedules every slot; it takes no slot")
    return solve_link_dp(instance, time_limit_s=time_limit_s)


_FIXED: dict[str, SolverFn] = {"brute": _brute, "link-dp": _link_dp}
_SINGLE = ("bb", "dp", "greedy")
_MULTI = ("progressive", "slope", "static")
_PARAMETRISED = ("fptas:EPS", "mpc:H", "rolling:SOLVER", "rolling-future:SOLVER")


def names() -> list[str]:
    """Method names (parametrised ones shown with their parameter, e.g. ``fptas:EPS``)."""
    return sorted([*_FIXED, *_SINGLE, *_MULTI, *_PARAMETRISED])


@functools.lru_cache(maxsize=64)
def resolve(name: str) -> SolverFn:
    """The function behind a method name; unknown or malformed names are a :class:`SolveError`."""
    from .rolling import parse_eps

    if not isinstance(name, str):
        raise SolveError(f"method {name!r} must be a string")
    if name in _FIXED:
        return _FIXED[name]
    if name in _SINGLE:
        return _single(name)
    if name in _MULTI:
        return _multi(name)
    if name.startswith("fptas:"):
        return _fptas(parse_eps(name))
    for prefix, future in (("rolling-future:", True), ("rolling:", False)):
        if name.startswith(prefix):
            solver = name[len(prefix):]
            if not solver:
                raise SolveError(f"method {name!r}: give the per-slot solver, e.g. {prefix}bb")
            return _rolling(solver, future)
    if name.startswith("mpc:"):
        text = name[4:]
        try:
            horizon = int(text)
        except ValueError:
            raise SolveError(f"method {name!r}: H = {text!r} must be a positive integer (slots)") from None
        if horizon < 1:
            raise SolveError(f"method {name!r}: H = {horizon} must be a positive integer (slots)")
        return _mpc(horizon)
    raise SolveError(f"method {name!r} is not one of ilp, lp, {', '.join(names())}")
