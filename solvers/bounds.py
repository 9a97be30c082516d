"""The certificate every multi-slot heuristic reports: the LP relaxation of Problem I/II.

Built once by the core's model code (:func:`l3gs_opt.models.build_model`, with presolve) and
solved as an LP by HiGHS. Its value (plus the held constant) is an upper bound on the optimum,
so ``(bound - objective) / bound`` is a certified gap. With signed layer utilities the
relaxation is the same (every held layer counts with its sign); only its slack grows with the
negative terms.
"""

from __future__ import annotations

import time

from l3gs_opt.errors import BackendUnavailableError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.items import ItemInstance

__all__ = ["LP_BOUND_SLACK", "lp_bound"]

#: Relative slack added to the LP value. HiGHS solves the LP to a dual feasibility tolerance
#: of 1e-7, so its optimum may sit a little under the true LP optimum; 1e-7 relative keeps the
#: bound valid for the utilities we meet (a gap below it is not meaningful anyway).
LP_BOUND_SLACK = 1e-7


def lp_bound(instance: "Instance | ItemInstance", *, slot: int | None = None,
             time_limit_s: float | None = None) -> tuple[float | None, float]:
    """Upper bound on Problem I/II or an item instance (or the single-slot MCKP at ``slot``) and the
    seconds it took; within ``time_limit_s`` seconds when given (building the model included: the
    LP gets what is left, and a model built past the limit is not solved).

    Returns ``(None, seconds)`` when HiGHS is not installed or reports no bound, or when the LP did
    not finish within the limit (only an optimal LP is a bound).
    """
    from l3gs_opt.models import build_items_model, build_model, solve_model

    started = time.perf_counter()
    if time_limit_s is not None and time_limit_s <= 0:   # spent already: not even the model is built
        return None, 0.0
    try:
        if isinstance(instance, ItemInstance):   # the item form's ILP, same relaxation
            model = build_items_model(instance, slot=slot)
        else:
            model = build_model(instance, slot=slot)
        left = None if time_limit_s is None else time_limit_s - (time.perf_counter() - started)
        if left is not None and left <= 0:
            return None, time.perf_counter() - started
        result = solve_model(model, "highs", relax=True, time_limit_s=left)
    except BackendUnavailableError:
        return None, time.perf_counter() - started
    if result.bound is None:
        return None, time.perf_counter() - started
    value = result.bound + model.constant
    # The LP's error is relative to the terms it adds, not to their sum: with signed layer
    # utilities (negative coefficients, a negative held constant) the value can be near 0 while
    # the terms are not. Without negative terms this is ``abs(value)``, as before.
    negative = float(-model.objective[model.objective < 0].sum()) + max(0.0, -model.constant)
    return value + LP_BOUND_SLACK * (abs(value) + 2.0 * negative), time.perf_counter() - started
