"""``solve``: one entry point for every method, as the CLI's ``solve`` uses it."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

import numpy as np

from .errors import SolveError
from .instance import Instance, scale_exponent
from .items import ItemInstance
from .solution import Solution, finish_solution

__all__ = ["METHODS", "method_names", "solve", "check_time_limit", "check_slot"]


def check_time_limit(value: Any, *, name: str = "time_limit_s") -> float | None:
    """``time_limit_s`` as every method takes it: ``None`` (no limit) or a float > 0 seconds.

    ``inf`` (``--time-limit inf``) means "no limit" and is returned as ``None``, so that every
    method and backend runs exactly as it does without a limit. ``name`` is the argument named in
    the message (the CLI says ``--time-limit``).

    Raises
    ------
    SolveError
        Not a number (a bool or a string included), NaN, zero or negative.
    """
    if value is None:
        return None
    shown = value.item() if isinstance(value, np.generic) else value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise SolveError(f"{name} = {shown!r}: must be a number of seconds > 0 (or inf for no limit)")
    seconds = float(value)
    if math.isnan(seconds) or seconds <= 0:
        raise SolveError(f"{name} = {shown!r}: must be > 0 seconds (or inf for no limit)")
    return None if math.isinf(seconds) else seconds


def check_slot(value: Any, T: int, *, name: str = "slot") -> int | None:
    """``slot`` as every method takes it: ``None`` or a Python ``int`` in ``0..T-1``; a numpy
    integer is accepted and converted, a bool or a float (even ``1.0``) is not.

    Raises
    ------
    SolveError
        Not an integer, or out of range.
    """
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 0 <= value < T:
        shown = value.item() if isinstance(value, np.generic) else value
        raise SolveError(f"{name} = {shown!r}: must be an integer in 0..{T - 1}")
    return int(value)


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
        Solve the single-slot MCKP of this slot given ``instance.held`` (0-based; a numpy
        integer is accepted; checked by :func:`check_slot`).
    time_limit_s : float, optional
        Seconds, > 0; a run that hits it says ``time_limit`` and carries a valid bound. ``None``
        or ``inf``: no limit. Checked (:func:`check_time_limit`) before anything else.
    presolve : bool
        Drop chunks that cannot matter before modelling (see :mod:`l3gs_opt.presolve`). The
        optimum is unchanged, but the ``lp`` bound is that of the presolved model: dropping
        dominated options can make it tighter than the textbook LP (``presolve=False``).
    options : mapping, optional
        Backend-specific options (unknown ones warn).

    Raises
    ------
    SolveError
        Unknown method, form or backend; a time limit that is not > 0 seconds; a slot out of
        range; an option that does not apply.
    """
    time_limit_s = check_time_limit(time_limit_s)
    slot = check_slot(slot, instance.T) if isinstance(instance, (Instance, ItemInstance)) else slot
    if isinstance(instance, (Instance, ItemInstance)):
        exponent = scale_exponent(instance.utility, UTILITY_TOP)
        if not -UTILITY_BAND <= exponent <= UTILITY_BAND:
            return _solve_scaled(instance, exponent, method, backend=backend, form=form, slot=slot,
                                 time_limit_s=time_limit_s, presolve=presolve, options=options)
    return _dispatch(instance, method, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                     presolve=presolve, options=options)


#: Utilities are solved as they are while the largest lies within 2**(UTILITY_TOP +- UTILITY_BAND)
#: (about 1e-6 .. 1e18); beyond, on a copy scaled by a power of two (see :func:`_solve_scaled`).
UTILITY_TOP = 20
UTILITY_BAND = 40


def _solve_scaled(instance: Instance | ItemInstance, exponent: int, method: str, **kw: Any) -> Solution:
    """Solve ``instance`` with its utilities times ``2**exponent``, then check and value the schedule
    on the original. Solvers' tolerances and bound slacks are partly absolute (HiGHS treats a cost
    of 1e20 as infinite; ``bb``'s pruning floor is 1e-300): near 1e300 or among subnormal utilities
    they misjudge. Scaling by a power of two is exact while values stay normal, so the scaled
    optimum is the original one; the bound is scaled back with ``ldexp``."""
    scaled = _dispatch(instance.replace(utility=np.ldexp(instance.utility, exponent)), method, **kw)
    bound = None if scaled.bound is None else math.ldexp(scaled.bound, -exponent)
    return finish_solution(instance, scaled.arrivals, problem=scaled.problem, method=scaled.method,
                           status=scaled.status, bound=bound, runtime_s=scaled.runtime_s, slot=scaled.slot,
                           backend=scaled.backend, backend_version=scaled.backend_version,
                           size_before=scaled.size_before, size_after=scaled.size_after, message=scaled.message,
                           details={**scaled.details, "utility_prescale_log2": exponent})


def _dispatch(instance: Instance | ItemInstance, method: str, *, backend: str, form: str, slot: int | None,
              time_limit_s: float | None, presolve: bool, options: Mapping[str, Any] | None) -> Solution:
    if isinstance(instance, ItemInstance):
        from l3gs_opt.solvers.items import solve_items

        return solve_items(instance, method, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                           presolve=presolve, options=options)
    if method in METHODS:
        fn = METHODS[method]
    else:
        from l3gs_opt.solvers.registry import resolve

        fn = resolve(method)
    return fn(instance, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s, presolve=presolve,
              options=options)
