"""``solve``: one entry point for every method, as the CLI's ``solve`` uses it."""

from __future__ import annotations

import dataclasses
import math
from types import MappingProxyType
from typing import Any, Callable, Mapping

import numpy as np

from l3gs_opt import stop
from l3gs_opt.errors import SolveError
from l3gs_opt.models.backends import used_up
from l3gs_opt.problem.arguments import check_instance, check_options, check_slot, check_time_limit
from l3gs_opt.problem.instance import Instance, scale_exponent
from l3gs_opt.problem.items import ItemInstance
from l3gs_opt.problem.solution import Solution, Status, finish_solution
from l3gs_opt.solvers.registry import MODEL_OPTIONS, TABLE, MethodEntry, entry, names, resolve

__all__ = ["METHODS", "method_names", "resolve_method", "solve", "check_time_limit", "check_slot"]


#: Every method family (the name before any ``:``) -> its :class:`~l3gs_opt.solvers.registry.MethodEntry`:
#: the one method table, for both instance forms (it lives in :mod:`l3gs_opt.solvers.registry`).
METHODS: Mapping[str, MethodEntry] = MappingProxyType(TABLE)


def method_names(*, items: bool = False) -> list[str]:
    """Every method name ``solve`` accepts for the ``Instance`` form (or the item form), parametrised
    ones as ``name:PARAM``."""
    return names(items=items)


def resolve_method(name: str, *, items: bool = False) -> Callable[..., Solution]:
    """The function behind a method name (of the ``Instance`` form, or the item form).

    Raises
    ------
    SolveError
        Unknown or malformed name, or a method that does not take that instance form.
    """
    return resolve(name, items=items)


def solve(instance: Instance | ItemInstance, method: str = "ilp", *, backend: str = "highs", form: str = "standard",
          slot: int | None = None, time_limit_s: float | None = None, presolve: bool = True,
          options: Mapping[str, Any] | None = None) -> Solution:
    """Solve ``instance`` with ``method``.

    Parameters
    ----------
    instance : Instance or ItemInstance
        Either form; the method table (:mod:`l3gs_opt.solvers.registry`) says which methods take
        an item instance (``l3gs-opt/items@1``): ``method_names(items=True)``.
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
        or ``inf``: no limit. Checked (:func:`check_time_limit`) before anything else. A stop
        request (:mod:`l3gs_opt.stop`: the first Ctrl-C of ``l3gs-opt solve``) ends ``exact`` and
        the HiGHS and CP-SAT backends the same way, now, and says so in the message.
    presolve : bool
        Drop chunks that cannot matter before modelling (see :mod:`l3gs_opt.problem.presolve`). The
        optimum is unchanged, but the ``lp`` bound is that of the presolved model: dropping
        dominated options can make it tighter than the textbook LP (``presolve=False``).
    options : mapping, optional
        Backend-specific options, keyed by option name (``str``); unknown ones warn, a value the
        backend refuses is an error.

    Raises
    ------
    SolveError
        Unknown method, form or backend; a time limit that is not > 0 seconds; a slot out of
        range; an option that does not apply; ``instance`` not an ``Instance`` or
        ``ItemInstance``; ``options`` not a mapping with string keys.
    """
    time_limit_s = check_time_limit(time_limit_s)
    check_instance(instance, Instance, ItemInstance)
    slot = check_slot(slot, instance.T)
    options = check_options(options)
    _check_model_options(method, backend, form, presolve)
    exponent = scale_exponent(instance.utility, UTILITY_TOP)
    if not -UTILITY_BAND <= exponent <= UTILITY_BAND:
        return _noting_stop(_solve_scaled(instance, exponent, method, backend=backend, form=form, slot=slot,
                                          time_limit_s=time_limit_s, presolve=presolve, options=options),
                            time_limit_s)
    return _noting_stop(_dispatch(instance, method, backend=backend, form=form, slot=slot,
                                  time_limit_s=time_limit_s, presolve=presolve, options=options), time_limit_s)


def _noting_stop(solution: Solution, time_limit_s: float | None) -> Solution:
    """A run that a stop request (:mod:`l3gs_opt.stop`) ended says so in its message; its status
    stays ``time_limit`` (stopped before a proof, with a feasible schedule and a valid bound). A
    run that went on to its time limit all the same (CBC, which PuLP runs as a child process, does
    not see the request) is not said to be stopped by it."""
    if not stop.requested() or solution.status is not Status.TIME_LIMIT:
        return solution
    if used_up(solution.runtime_s, time_limit_s):
        return solution
    return dataclasses.replace(solution, message="; ".join(m for m in (solution.message, stop.STOPPED_NOTE) if m))


_DEFAULTS = {"backend": "highs", "form": "standard", "presolve": True}


def _check_model_options(method: Any, backend: Any, form: Any, presolve: Any) -> None:
    """``backend`` and ``form`` must be known names whatever the method; an option given to a
    method that does not use it (its table entry's ``uses``) is a warning: it would be dropped
    silently otherwise."""
    import warnings

    from l3gs_opt.models import FORMS, Backend

    given = {"backend": str(Backend.parse(backend)), "form": form, "presolve": presolve}
    if form not in FORMS:
        raise SolveError(f"form {form!r} is not one of {', '.join(FORMS)}")
    if not isinstance(presolve, (bool, np.bool_)):
        raise SolveError(f"presolve = {presolve!r}: must be true or false")
    uses = entry(method).uses
    ignored = [k for k in MODEL_OPTIONS if given[k] != _DEFAULTS[k] and k not in uses]
    if ignored:
        warnings.warn(f"method {method!r} does not use {', '.join(ignored)}: ignored", UserWarning, stacklevel=3)


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
    fn = resolve(method, items=isinstance(instance, ItemInstance))
    return fn(instance, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s, presolve=presolve,
              options=options)
