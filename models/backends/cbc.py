"""CBC adapter through PuLP.

PuLP reports ``Optimal`` for some CBC runs stopped by a time limit (coin-or/pulp issues 649 and
711; seen here with PuLP 3.3 and CBC 2.10.3). So the status and the bound are read from CBC's own
log (``Result - ...``, ``Upper bound:``), never from PuLP's status.

CBC's own "Optimal" is a claim, not a certificate: on T60-J20-s6 and s8 under the cumulative
budget, written then with a continuous byte carry per slot, CBC 2.10.3 reported "Optimal solution
found" below schedules other methods found (s6: 297,116.33 against 297,194.76), also with presolve,
preprocessing, cuts and heuristics off. On the prefix rows the models use now it closes at the
right optimum (models/_common.py ``add_budget``); the benchmark reports count an optimum claimed
below a known schedule as wrong.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import tempfile
import threading
import time
import warnings
from importlib.metadata import version as _pkg_version
from typing import Any

import numpy as np
import pulp

from l3gs_opt import stop
from l3gs_opt.problem.solution import Status

from ..linear import LinearModel
from . import BackendResult, mapped_status, time_left

_KNOWN = {"threads", "presolve", "cuts", "strong", "maxNodes"}
#: Objective range (largest over smallest nonzero coefficient) above which CBC runs with Clp's
#: scaling off. Clp's own scaling rescales the objective and undoes the power-of-two prescale of
#: :func:`~l3gs_opt.models.backends.solve_model` (largest coefficient ~2**20 against an absolute
#: 1e-7 tolerance): a Problem III model with coefficients 5.2e5 and 5.1e-7 (utilities 1024 and
#: 1e-9, the 1024 out of reach, a range of 1e12) came back "optimal" at 0 with bound 0, the
#: optimum being 1e-9 (tests/test_stiff.py; HiGHS and CP-SAT found it). Without Clp's scaling it
#: does too. But scaling off costs the root LP at scale: at J=200, T=60 (objective range 4.0e4)
#: 12.5 s against 2.8 s (benchmarks/results/cbc_scaling.md). Up to 1e6 the smallest coefficient
#: is at least a millionth of the largest whatever Clp's scaling does, above its 1e-7 tolerances;
#: tests/test_stiff.py pins a case on each side and checks CBC against brute force below it.
STIFF_OBJECTIVE_RANGE = 1e6
#: CBC command-line settings of a model whose objective range exceeds STIFF_OBJECTIVE_RANGE.
STIFF_ARGS = ("scaling off",)
#: Seconds between the SIGINTs a stop request sends CBC: CBC acts on one only in its tree search
#: (one sent while it reads its file or solves the root LP is lost), so it is sent again until
#: CBC ends.
CBC_RESEND_S = 0.25
#: Seconds CBC's process must have existed before the first SIGINT: CBC installs its handler
#: only after it starts, and a SIGINT before that kills it (seen at once, not at 0.05 s).
CBC_HANDLER_S = 0.2
_RESULT = re.compile(r"^Result - (.*)$", re.M)
_UPPER = re.compile(r"^Upper bound:\s+(\S+)", re.M)
_VERSION = re.compile(r"^Version:\s+(\S+)", re.M)


#: CBC's result line, classified by :func:`_result_kind`.
#: A Ctrl-C in a terminal reaches CBC too (PuLP's child shares the terminal's process group): it
#: stops like a time limit, with its best schedule and bound, and ``methods`` says it was a request.
_STATUS = {"optimal": Status.OPTIMAL, "stopped on time": Status.TIME_LIMIT, "stopped on request": Status.TIME_LIMIT,
           "infeasible": Status.INFEASIBLE}


def _result_kind(result: str, relax: bool, pulp_status: str) -> str:
    if result.startswith("Optimal"):
        return "optimal"
    if result.startswith("Stopped on time"):
        return "stopped on time"
    if result.lower().startswith("user ctrl-c"):
        return "stopped on request"
    if "infeasible" in result.lower():
        return "infeasible"
    if relax and pulp_status == "Optimal":   # CBC's LP path prints no "Result -" line
        return "optimal"
    return result


def _interrupt_until(done: threading.Event) -> None:
    """Send this process's CBC children SIGINT every :data:`CBC_RESEND_S` until ``done``, each
    first :data:`CBC_HANDLER_S` after it is seen (in a thread: :func:`l3gs_opt.stop.stoppable`
    waits on the solve, not on this)."""

    def send() -> None:
        seen: dict[int, float] = {}
        while not done.is_set():
            now = time.perf_counter()
            for pid in stop.child_processes("cbc"):
                if now - seen.setdefault(pid, now) >= CBC_HANDLER_S:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGINT)
            done.wait(CBC_RESEND_S)

    threading.Thread(target=send, name="l3gs-cbc-stop", daemon=True).start()


def objective_range(model: LinearModel) -> float:
    """Largest over smallest absolute nonzero objective coefficient (1.0 when at most one)."""
    nonzero = np.abs(model.objective[model.objective != 0])
    return float(nonzero.max() / nonzero.min()) if nonzero.size else 1.0


def cbc_args(model: LinearModel) -> tuple[str, ...]:
    """CBC's settings for ``model``: Clp's scaling off only for a stiff objective (see
    :data:`STIFF_OBJECTIVE_RANGE`)."""
    return STIFF_ARGS if objective_range(model) > STIFF_OBJECTIVE_RANGE else ()


def version(log: str = "") -> str:
    found = _VERSION.search(log)
    return f"pulp {_pkg_version('pulp')}" + (f" (CBC {found.group(1)})" if found else " (CBC)")


def solve(model: LinearModel, *, time_limit_s: float | None, relax: bool, options: dict[str, Any]) -> BackendResult:
    started = time.perf_counter()
    problem = pulp.LpProblem("l3gs", pulp.LpMaximize)
    # PuLP 3.3 deprecates free-standing LpVariable in favour of LpProblem.add_variable.
    new_var = getattr(problem, "add_variable", pulp.LpVariable)
    xs = []
    for i in range(model.size.variables):
        lb = model.lb[i] if np.isfinite(model.lb[i]) else None
        ub = model.ub[i] if np.isfinite(model.ub[i]) else None
        cat = pulp.LpInteger if (model.integer[i] and not relax) else pulp.LpContinuous
        xs.append(new_var(f"v{i}", lowBound=lb, upBound=ub, cat=cat))
    nz = np.nonzero(model.objective)[0]
    problem += pulp.LpAffineExpression([(xs[i], float(model.objective[i])) for i in nz])
    csr = model.matrix
    for r in range(model.size.constraints):
        expr = [(xs[csr.indices[k]], float(csr.data[k])) for k in range(csr.indptr[r], csr.indptr[r + 1])]
        lo, hi = model.row_lb[r], model.row_ub[r]
        if lo == hi:
            problem += pulp.LpConstraint(pulp.LpAffineExpression(expr), pulp.LpConstraintEQ, f"r{r}", float(hi))
            continue
        if np.isfinite(hi):
            problem += pulp.LpConstraint(pulp.LpAffineExpression(expr), pulp.LpConstraintLE, f"r{r}u", float(hi))
        if np.isfinite(lo):
            problem += pulp.LpConstraint(pulp.LpAffineExpression(expr), pulp.LpConstraintGE, f"r{r}l", float(lo))
    kwargs = {k: v for k, v in options.items() if k in _KNOWN}
    for key in options:
        if key not in _KNOWN:
            warnings.warn(f"cbc: unknown option {key!r} ignored", stacklevel=3)
    args = cbc_args(model)
    fd, log_path = tempfile.mkstemp(suffix=".log", prefix="l3gs-cbc-")
    os.close(fd)
    try:
        with warnings.catch_warnings():
            # PuLP 3.3 announces PULP_CBC_CMD's removal in 4.0 (pyproject pins pulp<4): the bundled
            # CBC binary is what makes the backend work on a fresh machine.
            warnings.simplefilter("ignore", DeprecationWarning)
            cmd = pulp.PULP_CBC_CMD(msg=False, mip=not relax, timeLimit=time_left(time_limit_s, started),
                                    gapRel=0.0, gapAbs=0.0, logPath=log_path, options=list(args), **kwargs)
        done = threading.Event()

        def run() -> None:
            try:
                problem.solve(cmd)
            finally:
                done.set()

        try:
            stop.stoppable(run, lambda: _interrupt_until(done))
        except pulp.PulpSolverError as exc:
            # CBC killed before its handler was in place (a terminal's Ctrl-C at its start): no
            # answer, and not an error when a stop was asked for.
            status = Status.TIME_LIMIT if stop.requested() else Status.ERROR
            return BackendResult(status=status, values=None, bound=None, version=version(),
                                 message=f"CBC ended without an answer ({exc})", details={"cbc_args": list(args)})
        with open(log_path, encoding="utf-8", errors="replace") as fh:
            log = fh.read()
    finally:
        os.unlink(log_path)
    raw = [v.varValue for v in xs]
    # PuLP leaves out (value None) a variable in no row and not in the objective: any value in its
    # bounds is optimal, so it gets the one nearest 0. Only a missing used variable means "no solution".
    used = np.zeros(len(xs), dtype=bool)
    used[nz] = True
    used[csr.indices] = True
    # A MIP stopped before CBC found an integer schedule still writes a solution file, holding the
    # LP relaxation's fractional values ("no integer solution - continuous used"; PuLP: sol_status
    # NoSolutionFound). Rounded and repaired, they would pass for an incumbent CBC never had.
    integral = relax or problem.sol_status in (pulp.LpSolutionOptimal, pulp.LpSolutionIntegerFeasible)
    has_solution = integral and bool(xs) and all(v is not None for v, u in zip(raw, used) if u)
    values = None
    if has_solution:
        values = np.array([v if v is not None else min(max(0.0, model.lb[i]), model.ub[i])
                           for i, v in enumerate(raw)], dtype=np.float64)
    found = _RESULT.search(log)
    result = found.group(1).strip() if found else ""
    objective = float(values @ model.objective) if values is not None else None
    status = mapped_status(_STATUS, _result_kind(result, relax, pulp.LpStatus[problem.status]), limit_hit=True)
    bound = None
    if status is Status.OPTIMAL:
        bound = objective
    elif status is Status.TIME_LIMIT:
        upper = _UPPER.search(log)
        if upper:
            bound = float(upper.group(1))
    return BackendResult(status=status, values=values, bound=bound, version=version(log),
                         message=f"CBC: {result or 'no result line'} (PuLP said {pulp.LpStatus[problem.status]})",
                         details={"cbc_args": list(args)})
