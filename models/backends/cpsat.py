"""OR-Tools CP-SAT adapter.

CP-SAT needs integers. Constraint coefficients here are bytes and 0/1 (already integers); the
utility objective is scaled by a power of two ``scale`` so that ``sum |c_i| ub_i * scale <= 2**53``
and rounded. Rounding moves each coefficient by ``|e_i| <= 0.5 / scale``, so for every
schedule ``|true(x) - scaled(x) / scale| <= E = sum_i |e_i| ub_i``: the reported bound is
``bound_scaled / scale + E`` (valid for the true objective) and a CP-SAT optimum is within
``2 E`` of the true optimum. ``scale`` and ``E`` go into the result's details.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Any

import numpy as np
from ortools.sat.python import cp_model

from l3gs_opt import stop
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.solution import Status

from ..linear import LinearModel
from . import BackendResult, mapped_status, time_left

_TARGET = 2.0**53
_KNOWN = {"num_workers", "random_seed", "log_search_progress"}
_STATUS = {cp_model.OPTIMAL: Status.OPTIMAL, cp_model.INFEASIBLE: Status.INFEASIBLE,
           cp_model.FEASIBLE: (Status.TIME_LIMIT, Status.FEASIBLE), cp_model.UNKNOWN: (Status.TIME_LIMIT, Status.FEASIBLE)}


def run_stoppable(solver: Any, model: Any) -> Any:
    """``solver.solve(model)`` (a ``cp_model.CpSolver`` and ``CpModel``) that a stop request
    (:mod:`l3gs_opt.stop`) ends through ``stop_search``. Ctrl-C is ``l3gs_opt.stop``'s, not CP-SAT's
    own (which would stop it without the request that makes every other solver stop and say so)."""
    solver.parameters.catch_sigint_signal = False
    return stop.stoppable(lambda: solver.solve(model), solver.stop_search)


def version() -> str:
    import ortools

    return f"ortools {ortools.__version__} (CP-SAT)"


def _integral(values: np.ndarray) -> bool:
    finite = values[np.isfinite(values)]
    return bool(np.all(finite == np.round(finite)))


def solve(model: LinearModel, *, time_limit_s: float | None, relax: bool, options: dict[str, Any]) -> BackendResult:
    if relax:
        raise SolveError("backend 'cpsat' cannot solve an LP relaxation; use highs, cbc or scip")
    if not (model.integral_ok.all() and _integral(model.matrix.data) and _integral(model.row_lb)
            and _integral(model.row_ub) and _integral(model.lb) and _integral(model.ub)):
        raise SolveError("backend 'cpsat' needs integer variables and coefficients; this model has others")
    unbounded = np.nonzero(~np.isfinite(model.ub) | ~np.isfinite(model.lb))[0]
    if len(unbounded):
        # (The cumulative budget's byte carry was the one such column; its rows are prefix rows now.)
        raise SolveError(f"backend 'cpsat' needs finite variable bounds; variable "
                         f"{model.var_names[int(unbounded[0])]!r} is unbounded")
    started = time.perf_counter()
    weight = float(np.sum(np.abs(model.objective) * np.maximum(np.abs(model.ub), np.abs(model.lb))))
    scale = 2.0 ** math.floor(math.log2(_TARGET / weight)) if weight > 0 else 1.0
    scaled = np.round(model.objective * scale)
    error = float(np.sum(np.abs(model.objective - scaled / scale) * np.maximum(np.abs(model.ub), np.abs(model.lb))))
    m = cp_model.CpModel()
    xs = [m.new_int_var(int(model.lb[i]), int(model.ub[i]), f"v{i}") for i in range(model.size.variables)]
    csr = model.matrix
    for r in range(model.size.constraints):
        cols = csr.indices[csr.indptr[r]:csr.indptr[r + 1]]
        vals = csr.data[csr.indptr[r]:csr.indptr[r + 1]]
        expr = cp_model.LinearExpr.weighted_sum([xs[c] for c in cols], [int(v) for v in vals])
        lo, hi = model.row_lb[r], model.row_ub[r]
        if np.isfinite(lo) and np.isfinite(hi):
            m.add_linear_constraint(expr, int(lo), int(hi))
        elif np.isfinite(hi):
            m.add(expr <= int(hi))
        elif np.isfinite(lo):
            m.add(expr >= int(lo))
    nz = np.nonzero(scaled)[0]
    m.maximize(cp_model.LinearExpr.weighted_sum([xs[i] for i in nz], [int(scaled[i]) for i in nz]))
    solver = cp_model.CpSolver()
    if time_limit_s is not None:
        solver.parameters.max_time_in_seconds = time_left(time_limit_s, started)
    for key, value in options.items():
        if key not in _KNOWN:
            warnings.warn(f"cpsat: unknown option {key!r} passed through to CP-SAT", stacklevel=3)
        setattr(solver.parameters, key, value)
    code = run_stoppable(solver, m)
    has_solution = code in (cp_model.OPTIMAL, cp_model.FEASIBLE)
    # CP-SAT stops short of a proof only at a limit; its clock includes presolve, ours the build.
    status = mapped_status(_STATUS, code, limit_hit=time_limit_s is not None or stop.requested())
    values = np.array([solver.value(x) for x in xs], dtype=np.float64) if has_solution else None
    bound = None
    if has_solution:
        # Without a solution (status UNKNOWN) CP-SAT's objective bound is not trustworthy: the
        # benchmark caught one below the true optimum (Pisinger uncorrelated J=1000, 5 s limit).
        bound = float(solver.best_objective_bound) / scale + error
        if not math.isfinite(bound):
            bound = None
    return BackendResult(status=status, values=values, bound=bound, version=version(),
                         message=f"CP-SAT: {solver.status_name(code)}",
                         details={"objective_scale": scale, "scaling_error_bound": error,
                                  "optimality_error_bound": 2 * error})
