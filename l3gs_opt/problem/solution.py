"""One :class:`Solution` type for every model, solver and heuristic.

:func:`finish_solution` is the single exit every method goes through: it re-checks the schedule
in exact integer bytes (repairing it, and downgrading the status, if a backend's tolerance let
it exceed a budget), re-evaluates the objective in float64 from the instance, and derives the
gap from the bound.
"""

from __future__ import annotations

import enum
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Iterable, Mapping

import numpy as np

from l3gs_opt.problem.evaluate import Arrival, evaluate_objective, feasibility_violations, normalize_arrivals, repair_schedule
from l3gs_opt.problem.instance import Instance

__all__ = ["Status", "ModelSize", "Solution", "GAP_TOL", "relative_gap", "utility_scale", "finish_solution"]

#: Relative gap under which an answer counts as proven optimal. Backends are run with a zero
#: gap tolerance; this only absorbs float round-off between a backend's bound and our
#: re-evaluated objective (and CP-SAT's scaling error, see models/backends/cpsat.py).
GAP_TOL = 1e-9


class Status(str, enum.Enum):
    """How a method ended. Only ``OPTIMAL`` is a proof of optimality."""

    OPTIMAL = "optimal"          #: proven optimal (gap <= GAP_TOL)
    FEASIBLE = "feasible"        #: a feasible schedule, no proof (heuristic, or repaired)
    TIME_LIMIT = "time_limit"    #: stopped by the time limit (or a stop request, said in the message); the schedule is feasible, maybe empty
    INFEASIBLE = "infeasible"    #: the backend claims no schedule exists
    ERROR = "error"              #: the backend failed; the schedule is the empty one

    def __str__(self) -> str:
        return self.value


@dataclass(frozen=True)
class ModelSize:
    """Size of a built model: variables, constraints (rows) and non-zeros."""

    variables: int
    constraints: int
    nonzeros: int


def relative_gap(objective: float, bound: float | None, scale: float | None = None) -> float | None:
    """``(bound - objective) / max(|bound|, scale)``, 0 when both are equal, None without a bound.

    Objectives of non-negative utilities: ``scale`` None, the gap lies in [0, 1] when the bound is
    valid. Signed layer utilities (``dU < 0``): the optimum can be 0 (or near it) while its terms are
    not, and a bound off by round-off would read as a gap of 1; ``scale`` (:func:`utility_scale`,
    the sum of the utilities' magnitudes) measures the gap against the size of the terms instead.
    """
    if bound is None or not math.isfinite(bound):
        return None
    if bound == objective:
        return 0.0
    denom = max(abs(bound), scale or 0.0)
    return (bound - objective) / denom if denom != 0 else math.inf


def utility_scale(instance: Any) -> float | None:
    """The sum of the magnitudes of ``instance``'s utilities when some are negative, else None
    (the scale of :func:`relative_gap`)."""
    u = getattr(instance, "utility", None)
    if u is None:
        return None
    u = np.asarray(u, dtype=np.float64)
    if u.size == 0 or u.min() >= 0:
        return None
    return math.fsum(np.abs(u).ravel().tolist())


@dataclass(frozen=True)
class Solution:
    """A schedule and everything needed to trust it.

    Attributes
    ----------
    problem : str
        "I", "II", "III", "IV", "A" (GAP form) or "MCKP" (single slot).
    method : str
        The method asked for, e.g. "ilp" or "brute".
    status : Status
    arrivals : tuple of (j, l, t)
        Chunks that arrive and the slot they arrive in (0-based), sorted by slot.
    objective : float
        Total utility of the schedule including held chunks, re-evaluated from the instance in
        float64 (for ``slot`` answers: the utility shown at that slot).
    bound : float or None
        Best known upper bound on the optimum (same units as ``objective``); None when the
        method has none.
    gap : float or None
        ``(bound - objective) / |bound|``; None without a bound.
    runtime_s : float
        Wall-clock seconds, building the model included.
    backend, backend_version : str or None
        The library that solved it (None for pure-Python methods).
    size_before, size_after : ModelSize or None
        Model size without and with presolve (None for methods that build no model).
    slot : int or None
        The slot of a single-slot answer.
    message : str
        Human-readable notes (time limit hit, schedule repaired, ...).
    details : mapping
        Method-specific facts (e.g. CP-SAT's objective scale and its error bound).
    """

    problem: str
    method: str
    status: Status
    arrivals: tuple[Arrival, ...]
    objective: float
    bound: float | None
    gap: float | None
    runtime_s: float
    backend: str | None = None
    backend_version: str | None = None
    size_before: ModelSize | None = None
    size_after: ModelSize | None = None
    slot: int | None = None
    message: str = ""
    details: Mapping[str, Any] = field(default_factory=dict)

    @property
    def proven_optimal(self) -> bool:
        return self.status is Status.OPTIMAL

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (``arrivals`` as lists, ``model_size`` with before/after)."""
        return {
            "problem": self.problem,
            "method": self.method,
            "backend": self.backend,
            "backend_version": self.backend_version,
            "status": self.status.value,
            "objective": self.objective,
            "bound": self.bound,
            "gap": self.gap,
            "runtime_s": self.runtime_s,
            "slot": self.slot,
            "arrivals": [list(a) for a in self.arrivals],
            "model_size": {
                "before_presolve": asdict(self.size_before) if self.size_before else None,
                "after_presolve": asdict(self.size_after) if self.size_after else None,
            },
            "message": self.message,
            "details": dict(self.details),
        }


def _schedule_rules(instance: Any) -> tuple:
    """(normalise, violations, repair, evaluate, unit) of the instance's form: ``Instance`` chunks
    or ``ItemInstance`` items (imported here: the item form builds on this module)."""
    from l3gs_opt.problem.items import ItemInstance

    if isinstance(instance, ItemInstance):
        from l3gs_opt.problem.items_eval import evaluate_items, item_violations, normalize_item_arrivals, repair_items

        return normalize_item_arrivals, item_violations, repair_items, evaluate_items, "item"
    return normalize_arrivals, feasibility_violations, repair_schedule, evaluate_objective, "chunk"


def finish_solution(
    instance: Instance,
    arrivals: Iterable[Arrival],
    *,
    problem: str,
    method: str,
    status: Status,
    bound: float | None,
    runtime_s: float,
    slot: int | None = None,
    backend: str | None = None,
    backend_version: str | None = None,
    size_before: ModelSize | None = None,
    size_after: ModelSize | None = None,
    message: str = "",
    details: Mapping[str, Any] | None = None,
) -> Solution:
    """Check, repair if needed, re-evaluate and package a schedule (of an ``Instance`` or an
    ``ItemInstance``).

    ``status`` is the method's own claim. It is downgraded when the schedule had to be
    repaired (to ``FEASIBLE``) or when a claimed optimum is further than ``GAP_TOL`` from the
    bound (to ``FEASIBLE``). A bound below the re-evaluated objective by at most ``GAP_TOL``
    (backend round-off) is raised to it; one further below is wrong and dropped (``None``, so an
    optimum claimed on it is reported ``FEASIBLE``); an infinite bound is no bound.
    """
    normalize, violations_of, repair, evaluate, unit = _schedule_rules(instance)
    notes = [message] if message else []
    schedule = normalize(arrivals)
    violations = violations_of(instance, schedule, slot=slot)
    if violations:
        schedule, dropped = repair(instance, schedule, slot=slot)
        notes.append(f"repaired: the schedule broke {len(violations)} rule(s) ({violations[0]}); "
                     f"dropped {dropped} {unit}(s)")
        if status is Status.OPTIMAL:
            status = Status.FEASIBLE
    objective = evaluate(instance, schedule, slot=slot)
    if bound is not None and not math.isfinite(bound):
        bound = None
    if bound is not None and bound < objective - GAP_TOL * max(1.0, abs(objective)):
        # Not round-off: the method's bound is wrong, and nothing it proved can be trusted.
        notes.append(f"the reported bound {bound!r} is below this schedule's value {objective!r}: dropped")
        bound = None
    elif bound is not None and bound < objective:
        bound = objective
    gap = relative_gap(objective, bound, utility_scale(instance))
    if status is Status.OPTIMAL and (gap is None or gap > GAP_TOL):
        notes.append(f"claimed optimal but gap to bound is {gap}; reported as feasible")
        status = Status.FEASIBLE
    return Solution(problem=problem, method=method, status=status, arrivals=schedule, objective=objective,
                    bound=bound, gap=gap, runtime_s=float(runtime_s), backend=backend,
                    backend_version=backend_version, size_before=size_before, size_after=size_after,
                    slot=slot, message="; ".join(notes), details=dict(details or {}))
