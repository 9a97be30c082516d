"""SCIP adapter through OR-Tools' linear solver wrapper (pywraplp)."""

from __future__ import annotations

import time
import warnings
from typing import Any

import numpy as np
from ortools.linear_solver import pywraplp

from l3gs_opt.problem.solution import Status

from ..linear import LinearModel
from . import BackendResult, mapped_status, timed_out, time_left

_KNOWN = {"threads"}
#: pywraplp's result codes (NOT_SOLVED before the time limit: an error, not a stop).
_STATUS = {pywraplp.Solver.OPTIMAL: Status.OPTIMAL, pywraplp.Solver.INFEASIBLE: Status.INFEASIBLE,
           pywraplp.Solver.FEASIBLE: (Status.TIME_LIMIT, Status.FEASIBLE),
           pywraplp.Solver.NOT_SOLVED: (Status.TIME_LIMIT, Status.ERROR)}


#: SCIP's default value of infinity (its parameter numerics/infinity): BestBound() answers it when
#: there is no bound yet.
SCIP_INFINITY = 1e20


def version() -> str:
    import ortools

    return f"ortools {ortools.__version__} (SCIP)"


def solve(model: LinearModel, *, time_limit_s: float | None, relax: bool, options: dict[str, Any]) -> BackendResult:
    start = time.perf_counter()
    solver = pywraplp.Solver.CreateSolver("GLOP" if relax else "SCIP")
    if solver is None:
        return BackendResult(status=Status.ERROR, values=None, bound=None, version=version(),
                             message="OR-Tools was built without SCIP")
    inf = solver.infinity()
    xs = []
    for i in range(model.size.variables):
        lb = model.lb[i] if np.isfinite(model.lb[i]) else -inf
        ub = model.ub[i] if np.isfinite(model.ub[i]) else inf
        xs.append(solver.IntVar(lb, ub, "") if (model.integer[i] and not relax) else solver.NumVar(lb, ub, ""))
    csr = model.matrix
    for r in range(model.size.constraints):
        lb = model.row_lb[r] if np.isfinite(model.row_lb[r]) else -inf
        ub = model.row_ub[r] if np.isfinite(model.row_ub[r]) else inf
        ct = solver.Constraint(lb, ub)
        for k in range(csr.indptr[r], csr.indptr[r + 1]):
            ct.SetCoefficient(xs[csr.indices[k]], float(csr.data[k]))
    objective = solver.Objective()
    for i in np.nonzero(model.objective)[0]:
        objective.SetCoefficient(xs[i], float(model.objective[i]))
    objective.SetMaximization()
    if time_limit_s is not None:
        solver.SetTimeLimit(max(1, int(time_left(time_limit_s, start) * 1000)))
    for key, value in options.items():
        if key == "threads":
            solver.SetNumThreads(int(value))
        else:
            warnings.warn(f"scip: unknown option {key!r} ignored", stacklevel=3)
    params = pywraplp.MPSolverParameters()
    if not relax:
        params.SetDoubleParam(params.RELATIVE_MIP_GAP, 0.0)
    code = solver.Solve(params)
    has_solution = code in (pywraplp.Solver.OPTIMAL, pywraplp.Solver.FEASIBLE)
    # With a solution and no proof (FEASIBLE), only the time limit can have stopped SCIP here (no
    # other limit is set and no stop request reaches it); its own clock may end it a little before
    # 95 % of ours (seen once in CI: FEASIBLE at a 1.5 s limit, reported as feasible).
    limit_hit = time_limit_s is not None and (code == pywraplp.Solver.FEASIBLE or timed_out(start, time_limit_s))
    status = mapped_status(_STATUS, code, limit_hit=limit_hit)
    values = np.array([v.solution_value() for v in xs]) if has_solution else None
    bound = None
    if relax:
        bound = objective.Value() if status is Status.OPTIMAL else None
    elif has_solution:
        # Only with a solution: a run stopped before SCIP solved anything (result code NOT_SOLVED,
        # e.g. a 1 ms limit on a loaded machine) answers BestBound() with 0, which is no bound.
        b = objective.BestBound()
        # SCIP's "no bound" is its infinity (1e20), which the caller would divide by the
        # objective prescale into a plausible-looking number (3.8e14 on a 2x2 instance). OR-Tools'
        # solver.infinity() is float inf since 9.15, so SCIP's own value is what to compare with.
        bound = float(b) if np.isfinite(b) and abs(b) < min(inf, SCIP_INFINITY) else None
    return BackendResult(status=status, values=values, bound=bound, version=version() + f" {solver.SolverVersion()}",
                         message=f"SCIP result code {code}",
                         details={"nodes": int(solver.nodes()) if not relax else 0})
