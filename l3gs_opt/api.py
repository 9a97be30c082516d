"""``solve``: one entry point for every method, as the CLI's ``solve`` uses it."""

from __future__ import annotations

from typing import Any, Callable, Mapping

from .instance import Instance
from .items import ItemInstance
from .solution import Solution

__all__ = ["METHODS", "method_names", "solve"]


def _ilp(instance: Instance, **kw: Any) -> Solution:
    from l3gs_opt.models import solve_ilp

    return solve_ilp(instance, **kw)


def _lp(instance: Instance, **kw: Any) -> Solution:
    from l3gs_opt.models import solve_ilp

    return solve_ilp(instance, relax=True, **kw)


#: Methods built on the exact models; every other name is resolved by l3gs_opt.solvers.registry.
METHODS: dict[str, Callable[..., Solution]] = {"ilp": _ilp, "lp": _lp}


def method_names() -> list[str]:
    """Every method name ``solve`` accepts (parametrised ones as ``name:PARAM``)."""
    from l3gs_opt.solvers.registry import names

    return [*METHODS, *names()]


def solve(instance: Instance | ItemInstance, method: str = "ilp", *, backend: str = "highs", form: str = "standard",
          slot: int | None = None, time_limit_s: float | None = None, presolve: bool = True,
          options: Mapping[str, Any] | None = None) -> Solution:
    """Solve ``instance`` with ``method``.

    Parameters
    ----------
    instance : Instance or ItemInstance
        An item instance (``l3gs-opt/items@1``) goes to :func:`l3gs_opt.solvers.items.solve_items`,
        which takes ``ilp``, ``lp``, ``brute``, ``bb``/``dp``/``greedy``/``fptas:EPS``,
        ``rolling:*``, ``rolling-future:*`` and ``mpc:H``.
    method : str
        ``ilp``: exact model on ``backend``; ``lp``: its LP relaxation (a bound); any name of
        :func:`method_names`, e.g. ``brute`` (enumeration, tiny instances only).
    backend : {"cbc", "highs", "cpsat", "scip"}
    form : {"standard", "gap"}
        ``gap``: Problem A, the GAP form (layered only).
    slot : int, optional
        Solve the single-slot MCKP of this slot given ``instance.held``.
    time_limit_s : float, optional
        Seconds; a run that hits it says ``time_limit`` and carries a valid bound.
    presolve : bool
        Drop chunks that cannot matter before modelling (see :mod:`l3gs_opt.presolve`). The
        optimum is unchanged, but the ``lp`` bound is that of the presolved model: dropping
        dominated options can make it tighter than the textbook LP (``presolve=False``).
    options : mapping, optional
        Backend-specific options (unknown ones warn).

    Raises
    ------
    SolveError
        Unknown method, form or backend; a slot out of range; an option that does not apply.
    """
    if isinstance(instance, ItemInstance):
        from l3gs_opt.solvers.items import solve_items

        return solve_items(instance, method, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                           presolve=presolve, options=options)
    if method in METHODS:
        fn = METHODS[method]
    else:
        from l3gs_opt.solvers.registry import resolve

        fn = resolve(method)
    return fn(instance, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                           presolve=presolve, options=options)
