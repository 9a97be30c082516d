"""``solve``: one entry point for every method, as the CLI's ``solve`` uses it."""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.arguments import check_slot, check_time_limit
from l3gs_opt.problem.instance import Instance, scale_exponent
from l3gs_opt.problem.items import ItemInstance
from l3gs_opt.problem.solution import Solution, finish_solution

__all__ = ["METHODS", "method_names", "resolve_method", "solve", "check_time_limit", "check_slot"]


def _ilp(instance: Instance, **kw: Any) -> Solution:
    from l3gs_opt.models import solve_ilp

    return solve_ilp(instance, **kw)


def _lp(instance: Instance, **kw: Any) -> Solution:
    from l3gs_opt.models import solve_ilp

    return solve_ilp(instance, relax=True, **kw)


def _exact(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
           options: Any = None, **_model_options: Any) -> Solution:
    # Here rather than in solvers/registry.py: exact starts from the registry's heuristics, so the
    # registry naming it too would be an import cycle.
    import warnings

    from l3gs_opt.solvers.exact.search import solve_exact

    known = ("branching", "lns_width", "heuristics", "max_nodes")
    opts = dict(options or {})
    for key in [k for k in opts if k not in known]:
        warnings.warn(f"method 'exact': option {key!r} is unknown (known: {', '.join(known)}); ignored",
                      stacklevel=3)
        opts.pop(key)
    return solve_exact(instance, slot=slot, time_limit_s=time_limit_s, **opts)


#: Methods built on the exact models and the decomposition; every other name is resolved by
#: :mod:`l3gs_opt.solvers.registry`. :func:`resolve_method` looks in both: the one method table.
METHODS: dict[str, Callable[..., Solution]] = {"ilp": _ilp, "lp": _lp, "exact": _exact}


def method_names() -> list[str]:
    """Every method name ``solve`` accepts (parametrised ones as ``name:PARAM``)."""
    from l3gs_opt.solvers.registry import names

    return [*METHODS, *names()]


def resolve_method(name: str) -> Callable[..., Solution]:
    """The function behind a method name of the ``Instance`` form (the one table every caller
    asks: ``solve``, the simulator's and the bench's name checks).

    Raises
    ------
    SolveError
        Unknown or malformed name.
    """
    if name in METHODS:
        return METHODS[name]
    from l3gs_opt.solvers.registry import resolve

    return resolve(name)


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
        Drop chunks that cannot matter before modelling (see :mod:`l3gs_opt.problem.presolve`). The
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
    _check_model_options(method, backend, form, presolve)
    if isinstance(instance, (Instance, ItemInstance)):
        exponent = scale_exponent(instance.utility, UTILITY_TOP)
        if not -UTILITY_BAND <= exponent <= UTILITY_BAND:
            return _solve_scaled(instance, exponent, method, backend=backend, form=form, slot=slot,
                                 time_limit_s=time_limit_s, presolve=presolve, options=options)
    return _dispatch(instance, method, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                     presolve=presolve, options=options)


#: The options of ``solve`` each method family uses; a method given another one (not at its
#: default) warns that it ignores it, e.g. ``exact`` with ``backend="scip"``.
_USES = {"ilp": ("backend", "form", "presolve"), "lp": ("backend", "form", "presolve"),
         "rolling": ("backend",), "rolling-future": ("backend",), "mpc": ("backend",)}
_DEFAULTS = {"backend": "highs", "form": "standard", "presolve": True}


def _check_model_options(method: Any, backend: Any, form: Any, presolve: Any) -> None:
    """``backend`` and ``form`` must be known names whatever the method; an option given to a
    method that does not use it is a warning (it would be dropped silently otherwise)."""
    import warnings

    from l3gs_opt.models import FORMS, Backend

    Backend.parse(backend)
    if form not in FORMS:
        raise SolveError(f"form {form!r} is not one of {', '.join(FORMS)}")
    if not isinstance(presolve, (bool, np.bool_)):
        raise SolveError(f"presolve = {presolve!r}: must be true or false")
    family = method.split(":", 1)[0] if isinstance(method, str) else method
    given = {"backend": str(Backend.parse(backend)), "form": form, "presolve": bool(presolve)}
    ignored = [k for k, v in given.items() if v != _DEFAULTS[k] and k not in _USES.get(family, ())]
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
    if isinstance(instance, ItemInstance):
        from l3gs_opt.solvers.items import solve_items

        return solve_items(instance, method, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s,
                           presolve=presolve, options=options)
    return resolve_method(method)(instance, backend=backend, form=form, slot=slot, time_limit_s=time_limit_s, presolve=presolve,
              options=options)
