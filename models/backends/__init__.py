"""Backends: one module each, imported only when chosen; one result type and status table.

Common parameters first (time limit, LP relaxation), backend-specific ones in ``options``
(an unknown option warns rather than fails). Every backend runs with zero MIP gap tolerance so
that "optimal" means proven optimal up to round-off.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import importlib
import importlib.util
import time
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from l3gs_opt.errors import BackendUnavailableError, SolveError
from l3gs_opt.problem.arguments import check_options
from l3gs_opt.problem.instance import scale_exponent
from l3gs_opt.problem.solution import Status

from ..linear import LinearModel

__all__ = ["Backend", "BackendResult", "is_installed", "installed_backends", "solve_model", "time_left", "MIN_SOLVE_S"]


class Backend(str, enum.Enum):
    """The ILP backends. Values are the CLI names."""

    CBC = "cbc"            #: COIN-OR CBC through PuLP
    HIGHS = "highs"        #: HiGHS through highspy
    CPSAT = "cpsat"        #: OR-Tools CP-SAT (integer objective: scaled, error bound reported)
    SCIP = "scip"          #: SCIP through OR-Tools' linear solver wrapper

    def __str__(self) -> str:
        return self.value

    @classmethod
    def parse(cls, name: "str | Backend") -> "Backend":
        try:
            return cls(name)
        except ValueError:
            raise SolveError(f"backend {name!r} is not one of {', '.join(b.value for b in cls)}") from None


#: Seconds a backend's solver is given at least, when building its model used up the time limit
#: (so a model built past the limit still ends as a time limit, not an error).
MIN_SOLVE_S = 0.01


def time_left(time_limit_s: float | None, started: float) -> float | None:
    """What is left of ``time_limit_s`` (seconds) since ``started`` (a ``time.perf_counter()``
    reading), at least :data:`MIN_SOLVE_S`; None for no limit. An adapter that builds its solver's
    model in Python gives the solver this, so the limit covers that build too."""
    if time_limit_s is None:
        return None
    return max(MIN_SOLVE_S, time_limit_s - (time.perf_counter() - started))


_OBJECTIVE_TOP = 20  # log2 of the largest objective coefficient a backend sees
_MODULE = {Backend.CBC: "cbc", Backend.HIGHS: "highs", Backend.CPSAT: "cpsat", Backend.SCIP: "scip"}
_PACKAGE = {Backend.CBC: "pulp", Backend.HIGHS: "highspy", Backend.CPSAT: "ortools", Backend.SCIP: "ortools"}


@dataclass(frozen=True)
class BackendResult:
    """What a backend returns, in model units (``constant`` excluded from ``bound``).

    ``values`` is None when the backend has no solution; ``bound`` is an upper bound on
    ``objective @ x`` (None when unknown).
    """

    status: Status
    values: np.ndarray | None
    bound: float | None
    version: str
    message: str = ""
    details: Mapping[str, Any] = field(default_factory=dict)


def is_installed(backend: "str | Backend") -> bool:
    """Whether the backend's library can be imported (answered without importing it)."""
    return importlib.util.find_spec(_PACKAGE[Backend.parse(backend)]) is not None


def installed_backends() -> list[Backend]:
    return [b for b in Backend if is_installed(b)]


def solve_model(model: LinearModel, backend: "str | Backend", *, time_limit_s: float | None = None,
                relax: bool = False, options: Mapping[str, Any] | None = None) -> BackendResult:
    """Solve ``model`` with ``backend``; ``relax`` drops integrality (an LP bound).

    ``options`` is checked here too (a mapping with ``str`` keys, :func:`check_options`): models
    are solved directly, not only through :func:`l3gs_opt.methods.solve`."""
    backend = Backend.parse(backend)
    options = check_options(options)
    if time_limit_s is not None and not time_limit_s > 0:
        raise SolveError(f"time_limit_s = {time_limit_s!r}: must be > 0 seconds")
    if not is_installed(backend):
        raise BackendUnavailableError(f"backend {backend.value!r} needs the package {_PACKAGE[backend]!r}")
    module = importlib.import_module(f"{__name__}.{_MODULE[backend]}")
    if model.size.variables == 0:
        return BackendResult(status=Status.OPTIMAL, values=np.zeros(0), bound=0.0, version=module.version(),
                             message="empty model after presolve: nothing to solve")
    # Backends compare objective terms against absolute tolerances (CBC drops a lone 1e-9 utility as
    # zero; HiGHS's 1e-7 dual tolerance lets a 1e-8 relative loss pass as optimal when the largest
    # coefficient is ~1). Scaling by a power of two (exact in float64) so the largest coefficient is
    # about 2**20 keeps every instance, whatever its utility units, at a relative accuracy of ~1e-13.
    # The factor is applied as an exponent (ldexp): 2**k itself overflows for subnormal utilities
    # (5e-324 needs k = 1094) and underflows for utilities near 1e308.
    exponent = scale_exponent(model.objective, _OBJECTIVE_TOP)
    scaled = dataclasses.replace(model, objective=np.ldexp(model.objective, exponent))
    result = module.solve(scaled, time_limit_s=time_limit_s, relax=relax, options=options)
    if exponent == 0:
        return result
    bound = None if result.bound is None else math.ldexp(result.bound, -exponent)
    return dataclasses.replace(result, bound=bound,
                               details={**result.details, "objective_prescale_log2": exponent})


#: A status table maps a backend's own code to a :class:`Status`, or to a pair
#: ``(status when the time limit was used up, status otherwise)`` for a stop without proof.
StatusTable = Mapping[Any, "Status | tuple[Status, Status]"]


def mapped_status(table: StatusTable, code: Any, *, limit_hit: bool) -> Status:
    """The :class:`Status` of a backend's ``code`` through its one ``table`` (unknown codes: ``ERROR``)."""
    entry = table.get(code, Status.ERROR)
    if isinstance(entry, tuple):
        return entry[0] if limit_hit else entry[1]
    return entry


#: A run that stopped without proof at or past this share of its time limit used the limit up.
LIMIT_SLACK = 0.95


def used_up(seconds: float, time_limit_s: float | None) -> bool:
    """Whether a run of ``seconds`` that stopped without proof used up its time limit (with
    :data:`LIMIT_SLACK`); anything sooner stopped it (an error, a stop request)."""
    return time_limit_s is not None and seconds >= LIMIT_SLACK * time_limit_s


def timed_out(start: float, time_limit_s: float | None) -> bool:
    """:func:`used_up` for a run started at ``start`` (``time.perf_counter()``) and ending now."""
    return used_up(time.perf_counter() - start, time_limit_s)
