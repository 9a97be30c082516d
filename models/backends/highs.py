"""HiGHS adapter (highspy): builds a column-wise ``HighsLp`` and maps HiGHS's model status.

HiGHS 1.14.0's MIP presolve returns a sub-optimal point as ``kOptimal`` on some models with
continuous columns (singleton-column stuffing; ERGO-Code/HiGHS issues 2957, 3043, 3073, 3094,
fixed in 1.15.0, which cannot share a process with OR-Tools 9.15). We saw it here on a 9-column
Problem II model (tests/test_backends.py pins it). Work-around on 1.14: columns the formulation
marks ``integral_ok`` are declared integer (their optimum is integral anyway), and a MIP that
still has continuous columns is solved with presolve off.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from importlib.metadata import version as _pkg_version
from typing import Any

import highspy
import numpy as np

from l3gs_opt import stop
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.solution import Status

from ..linear import LinearModel
from . import BackendResult

_PRESOLVE_BUG = _pkg_version("highspy").startswith("1.14.")
_KNOWN = {"threads", "presolve", "presolve_rule_off", "random_seed", "mip_feasibility_tolerance",
          "primal_feasibility_tolerance", "mip_heuristic_run_root_reduced_cost"}
#: ``presolve_rule_off`` bit of HiGHS's rule 13, "parallel rows and columns". Its parallel-column
#: dominance test compares two columns' costs per unit of the other column against an *absolute*
#: 1e-7 (the dual feasibility tolerance), so on a knapsack row whose weights are nearly
#: proportional it fixes a column that the optimum uses and still reports ``kOptimal``: Jooken's
#: n_1200_c_1000000_g_14_f_0.3_eps_0.01_s_100 gave 1,011,933 with bound 1,011,933.0000000002 where
#: the optimum is 1,011,934 (tests/test_known_answers.py). Switching the rule off alone fixes it;
#: benchmarks/results/highs_presolve.md measures what it costs.
PARALLEL_RULE_OFF = 1 << 13
#: A model with base-2**10 digit rows for a huge byte budget (models/linear.py) runs with presolve
#: off: HiGHS 1.14's aggregator (rule 12) substitutes the digit equalities into each other,
#: multiplying the digit weights back together, and called a model whose empty schedule is
#: feasible "infeasible"; with it off, rules 14-16 still returned a schedule 1e-3 below the optimum
#: as optimal on the stiff suite's bytes_1e12-T5 GAP form. Without presolve all of them were right.


def _fresh_pool_in_child() -> None:
    """HiGHS's thread pool is one per process, made by its first solve; a forked child inherits
    it without its threads, and its first solve that hands work to them waits for ever (seen
    here: a parent that solved with ``threads=2``, as 1.14 does by default on 4 or more cores
    and 1.16 on 2, then forked; the child's MIP never returned). Dropping the inherited pool
    (without waiting for threads that are not there) makes the child's first solve build its own."""
    highspy.Highs.resetGlobalScheduler(False)


os.register_at_fork(after_in_child=_fresh_pool_in_child)


class WallClock:
    """A wall-clock deadline that stops HiGHS from inside its simplex, IPM and MIP loops, movable
    between solves (:meth:`limit`).

    HiGHS 1.14 checks ``time_limit`` only between some phases: on a 100,000-column MCKP it ran to
    113-186 s under a 60 s limit. The interrupt callbacks run inside those loops; an interrupted
    run ends with ``kInterrupt``, reported as ``time_limit``. With them the same run took 89 s:
    HiGHS's set-up before the root node (~25 s there) calls no callback and cannot be cut short.
    A stop request (:mod:`l3gs_opt.stop`, the first Ctrl-C of ``l3gs-opt solve``) stops it the same way.
    """

    def __init__(self, h: highspy.Highs, time_limit_s: float | None = None) -> None:
        self.h = h
        self.limit(time_limit_s)
        self.rearmed = False   # (a new object has no interrupt to clear)
        for hook in (h.cbSimplexInterrupt, h.cbIpmInterrupt, h.cbMipInterrupt):
            hook.subscribe(self._check)

    def limit(self, time_limit_s: float | None) -> None:
        """The next solves stop ``time_limit_s`` seconds from now (None: never); HiGHS's own
        ``time_limit`` counts every solve of the object, so it is set past its run time so far."""
        if time_limit_s is None:
            self.deadline = math.inf
            self.h.setOptionValue("time_limit", highspy.kHighsInf)
        else:
            self.deadline = time.perf_counter() + float(time_limit_s)
            self.h.setOptionValue("time_limit", self.h.getRunTime() + float(time_limit_s))
        # HiGHS keeps an interrupted run's interrupt flag: without clearing it at the next run's
        # first callback, every later run of the object stops there (exact's kept master at J=50:
        # after the root's last solve was stopped, all 899 node solves returned nothing).
        self.rearmed = True

    def _check(self, event: Any) -> None:
        if stop.expired(self.deadline):
            event.interrupt()
        elif self.rearmed:
            event.interrupt(False)
            self.rearmed = False


#: HiGHS's MIP feasibility tolerance wherever a MIP's answer counts. With the default 1e-6, HiGHS
#: 1.14 let an integer carry of a digit row sit 1e-6 off an integer (a byte off at 2**20) and
#: pruned the optimum of prescaled strongly correlated MCKPs (tests/test_backends.py); our rows have
#: integer data, so the tighter tolerance costs no feasible point.
MIP_FEASIBILITY_TOL = 1e-9


def new_highs(*, time_limit_s: float | None = None, mip: bool = False, proof: bool = True) -> highspy.Highs:
    """A quiet HiGHS, set up as every caller here needs it (this adapter, exact's LPs and MIPs).

    ``time_limit_s`` (seconds) is HiGHS's own limit and a wall-clock interrupt
    (:class:`WallClock`). ``mip``: zero relative and absolute gaps (``kOptimal`` then means
    proven) and :data:`MIP_FEASIBILITY_TOL`; with ``proof`` (a MIP whose optimum or bound is
    reported) also presolve rule 13 off (:data:`PARALLEL_RULE_OFF`). A heuristic's MIP
    (``proof=False``: exact's window LNS, whose schedules are checked and valued anyway) keeps the
    rule: without it the 2 s window MIPs found worse schedules and T60-J20-s0 lost its proof
    (time_limit at 60 s instead of optimal in 28.5 s).
    """
    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    if time_limit_s is not None:
        WallClock(h, time_limit_s)
    if mip:
        h.setOptionValue("mip_rel_gap", 0.0)
        h.setOptionValue("mip_abs_gap", 0.0)
        h.setOptionValue("mip_feasibility_tolerance", MIP_FEASIBILITY_TOL)
        if proof:
            h.setOptionValue("presolve_rule_off", PARALLEL_RULE_OFF)
    return h


def sparse_lp(matrix: Any, *, col_cost: np.ndarray, col_lower: np.ndarray, col_upper: np.ndarray,
              row_lower: np.ndarray, row_upper: np.ndarray, integer: bool = False) -> highspy.HighsLp:
    """A ``HighsLp`` (minimise) from a scipy sparse matrix and bound arrays; infinite bounds
    (numpy's) become HiGHS's; ``integer`` makes every column integer."""
    A = matrix.tocsc()
    inf = highspy.kHighsInf
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = int(A.shape[1]), int(A.shape[0])
    lp.col_cost_ = np.asarray(col_cost, dtype=np.float64)
    lp.col_lower_ = np.where(np.isfinite(col_lower), col_lower, -inf)
    lp.col_upper_ = np.where(np.isfinite(col_upper), col_upper, inf)
    lp.row_lower_ = np.where(np.isfinite(row_lower), row_lower, -inf)
    lp.row_upper_ = np.where(np.isfinite(row_upper), row_upper, inf)
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = A.indptr.astype(np.int32)
    lp.a_matrix_.index_ = A.indices.astype(np.int32)
    lp.a_matrix_.value_ = A.data
    if integer:
        lp.integrality_ = [highspy.HighsVarType.kInteger] * lp.num_col_
    return lp


def solve_lp(lp: highspy.HighsLp, *, time_limit_s: float | None = None) -> highspy.Highs | None:
    """HiGHS on ``lp`` (at least 0.01 s when limited): the solver holding its solution when the LP
    is optimal, else None."""
    h = new_highs(time_limit_s=None if time_limit_s is None else max(time_limit_s, 0.01))
    h.passModel(lp)
    h.run()
    return h if h.getModelStatus() == highspy.HighsModelStatus.kOptimal else None


def set_option(h: highspy.Highs, key: str, value: Any) -> None:
    """Set a user's HiGHS option. A name outside :data:`_KNOWN` warns (passed through when HiGHS
    knows it, ignored when it does not); a value HiGHS refuses is a :class:`SolveError`:
    ``setOptionValue`` only returns ``kError`` and keeps its old value, so the run would go on
    without what the user asked for and say nothing."""
    exists = h.getOptionType(key)[0] == highspy.HighsStatus.kOk
    if key not in _KNOWN:
        what = " passed through to HiGHS" if exists else ": HiGHS has no such option either; ignored"
        warnings.warn(f"highs: unknown option {key!r}{what}", stacklevel=4)
    if not exists:
        return
    try:
        status = h.setOptionValue(key, value)
    except TypeError:   # not a bool, int, float or str: highspy's binding has no overload for it
        status = highspy.HighsStatus.kError
    if status == highspy.HighsStatus.kError:
        text = repr(value.item() if isinstance(value, np.generic) else value)
        kind = str(h.getOptionType(key)[1]).rsplit(".k", 1)[-1].lower()
        raise SolveError(f"options[{key!r}] = {text if len(text) <= 40 else text[:37] + '...'}: HiGHS refuses "
                         f"this value for its {kind} option {key!r}")


def _run(h: highspy.Highs, *, threads_asked: bool) -> None:
    """``h.run()``, and once more after restarting HiGHS's thread pool when the user's ``threads``
    option is what stopped it.

    HiGHS keeps one thread pool per process, made by its first solve with that solve's
    ``threads`` (0, the default, takes whatever pool exists). A later solve asking for another
    count returns ``kError`` at once with the model status unset: the user saw "error" and no
    schedule. Restarting the pool (``resetGlobalScheduler``) lets it run with the count asked
    for; later solves with the default use that pool. It must not happen while another HiGHS
    solve of this process runs (nothing here sets ``threads``: only a user can).
    """
    status = h.run()
    if (threads_asked and status == highspy.HighsStatus.kError
            and h.getModelStatus() == highspy.HighsModelStatus.kNotset):
        highspy.Highs.resetGlobalScheduler(True)
        h.run()


def version() -> str:
    return f"highspy {_pkg_version('highspy')}"


def solve(model: LinearModel, *, time_limit_s: float | None, relax: bool, options: dict[str, Any]) -> BackendResult:
    ms = highspy.HighsModelStatus
    status_map = {ms.kOptimal: Status.OPTIMAL, ms.kTimeLimit: Status.TIME_LIMIT, ms.kInfeasible: Status.INFEASIBLE,
                  ms.kIterationLimit: Status.TIME_LIMIT, ms.kSolutionLimit: Status.FEASIBLE,
                  ms.kInterrupt: Status.TIME_LIMIT}
    mip = not relax and bool(model.integer.any())
    h = new_highs(time_limit_s=time_limit_s, mip=mip)
    inf = highspy.kHighsInf
    lp = highspy.HighsLp()
    n, m = model.size.variables, model.size.constraints
    lp.num_col_, lp.num_row_ = n, m
    lp.sense_ = highspy.ObjSense.kMaximize
    lp.offset_ = 0.0
    lp.col_cost_ = model.objective
    lp.col_lower_ = np.where(np.isfinite(model.lb), model.lb, -inf)
    lp.col_upper_ = np.where(np.isfinite(model.ub), model.ub, inf)
    lp.row_lower_ = np.where(np.isfinite(model.row_lb), model.row_lb, -inf)
    lp.row_upper_ = np.where(np.isfinite(model.row_ub), model.row_ub, inf)
    csc = model.matrix.tocsc()
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = csc.indptr.astype(np.int32)
    lp.a_matrix_.index_ = csc.indices.astype(np.int32)
    lp.a_matrix_.value_ = csc.data
    presolve_off = False
    if not relax and model.integer.any():
        integer = model.integer
        if _PRESOLVE_BUG:
            integer = model.integer | model.integral_ok
            presolve_off = not integer.all()
        kinds = [highspy.HighsVarType.kInteger if i else highspy.HighsVarType.kContinuous for i in integer]
        lp.integrality_ = kinds
    h.passModel(lp)
    if presolve_off:
        h.setOptionValue("presolve", "off")
    if mip and model.byte_digits:
        options = {"presolve": "off", **options}
    for key, value in options.items():
        set_option(h, key, value)
    _run(h, threads_asked="threads" in options)
    model_status = h.getModelStatus()
    info = h.getInfo()
    status = status_map.get(model_status, Status.ERROR)
    has_solution = info.primal_solution_status == 2  # kSolutionStatusFeasible
    values = np.asarray(h.getSolution().col_value, dtype=np.float64) if has_solution else None
    if relax or not model.integer.any():
        bound = float(info.objective_function_value) if status is Status.OPTIMAL else None
    elif status in (Status.OPTIMAL, Status.TIME_LIMIT, Status.FEASIBLE):
        bound = float(info.mip_dual_bound) if np.isfinite(info.mip_dual_bound) else None
    else:
        bound = None   # an unset status leaves mip_dual_bound at 0: no bound, not a proof of 0
    return BackendResult(status=status, values=values, bound=bound, version=version(),
                         message=f"HiGHS: {h.modelStatusToString(model_status)}",
                         details={"mip_node_count": int(getattr(info, "mip_node_count", 0)),
                                  "presolve_off_workaround": presolve_off})
