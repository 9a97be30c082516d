"""A backend-neutral mixed-integer linear model (maximisation), built row by row.

Formulations (one module per problem) fill a :class:`ModelBuilder`; backends translate the
resulting :class:`LinearModel`. The model also carries how to read a schedule back from a
variable vector (``decode``), so backends never learn what a variable means.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.sparse as sp

from l3gs_opt.problem.solution import ModelSize

__all__ = ["LinearModel", "ModelBuilder", "BYTE_SPLIT_ABOVE", "BYTE_DIGIT"]

#: A byte row whose budget or largest cost exceeds this many bytes is written in base
#: :data:`BYTE_DIGIT` (see :meth:`ModelBuilder.byte_row`). Float backends compare row activities
#: against tolerances relative to the row's largest coefficient (CBC ~1e-7, HiGHS 1e-9 after its
#: own scaling): at 10^12 bytes a 1-byte overflow passes as feasible and a 1-byte chunk as free
#: (CBC then called such instances infeasible, HiGHS returned no answer at 2^53). Below 2^31 the
#: digits would only grow the model; the exact-bytes check after every solve catches the rest.
BYTE_SPLIT_ABOVE = 2**31
#: Base of the digit rows: every coefficient of a split row is at most 2**10, so a tolerance of
#: 1e-6 on a carry or relative to a coefficient is a thousandth of a byte.
BYTE_DIGIT = 2**10
#: Largest distance from 0 or 1 of an arrival variable read as a schedule. The backends accept
#: integers within at most 1e-6 (CBC's integerTolerance 1e-7; HiGHS's mip_feasibility_tolerance,
#: which its adapter sets to 1e-9; SCIP's feastol 1e-6; CP-SAT has no tolerance); a value further
#: off is a relaxation's, not an incumbent (CBC writes its LP values when it stops without one).
INTEGRALITY_TOL = 1e-5


@dataclass(frozen=True, eq=False)
class LinearModel:
    """``max c.x + constant  s.t.  row_lb <= A x <= row_ub,  lb <= x <= ub,  x_i integer where marked``.

    Attributes
    ----------
    problem : str
        "I".."IV", "A" or "MCKP".
    var_names, row_names : list of str
        Names with indices, e.g. ``x[j,l,t]`` (``x[l,t]`` for a single object).
    objective : float array [n]
    constant : float
        Added to ``objective @ x`` (utility of held chunks).
    matrix : scipy.sparse.csr_matrix [m, n]
    decode : list of (variable index, tuple of (j, l, t))
        A variable at value 1 means these chunks arrive.
    integral_ok : bool array [n]
        Continuous variables that some optimum has integral anyway (shown-version ``w``): a
        backend that needs integers (CP-SAT) may declare them so.
    slot : int or None
        The slot of a single-slot model.
    byte_digits : bool
        Some byte row is written in base-:data:`BYTE_DIGIT` digits (:meth:`ModelBuilder.byte_row`).
    """

    problem: str
    var_names: list[str]
    lb: np.ndarray
    ub: np.ndarray
    integer: np.ndarray
    objective: np.ndarray
    constant: float
    matrix: sp.csr_matrix
    row_lb: np.ndarray
    row_ub: np.ndarray
    row_names: list[str]
    decode: list[tuple[int, tuple[tuple[int, int, int], ...]]]
    integral_ok: np.ndarray | None = None
    slot: int | None = None
    stats: dict = field(default_factory=dict)
    byte_digits: bool = False

    @property
    def size(self) -> ModelSize:
        return ModelSize(variables=len(self.var_names), constraints=len(self.row_names),
                         nonzeros=int(self.matrix.nnz))

    def fractional(self, values: np.ndarray) -> tuple[int, float]:
        """How many arrival variables lie more than :data:`INTEGRALITY_TOL` from 0 and 1, and the
        largest such distance (0.0 when none does)."""
        index = np.fromiter((i for i, _ in self.decode), dtype=np.int64, count=len(self.decode))
        off = np.abs(values[index] - np.round(values[index])) if len(index) else np.zeros(0)
        bad = off > INTEGRALITY_TOL
        return int(bad.sum()), float(off[bad].max()) if bad.any() else 0.0

    def schedule(self, values: np.ndarray) -> list[tuple[int, int, int]]:
        """Arrivals of an integral variable vector (within :data:`INTEGRALITY_TOL`; see
        :meth:`fractional`): values above 0.5 count as 1."""
        out: list[tuple[int, int, int]] = []
        for index, chunks in self.decode:
            if values[index] > 0.5:
                out.extend(chunks)
        return out


class ModelBuilder:
    """Collects variables and rows; ``build()`` returns the immutable :class:`LinearModel`."""

    def __init__(self, problem: str, *, slot: int | None = None) -> None:
        self.problem = problem
        self.slot = slot
        self._names: list[str] = []
        self._lb: list[float] = []
        self._ub: list[float] = []
        self._int: list[bool] = []
        self._integral_ok: list[bool] = []
        self._obj: list[float] = []
        self._rows: list[int] = []
        self._cols: list[int] = []
        self._vals: list[float] = []
        self._row_lb: list[float] = []
        self._row_ub: list[float] = []
        self._row_names: list[str] = []
        self.decode: list[tuple[int, tuple[tuple[int, int, int], ...]]] = []
        self.constant = 0.0
        self.byte_digits = False

    def var(self, name: str, *, obj: float = 0.0, lb: float = 0.0, ub: float = 1.0, integer: bool = True,
            integral_ok: bool = False) -> int:
        self._names.append(name)
        self._integral_ok.append(integer or integral_ok)
        self._lb.append(lb)
        self._ub.append(ub)
        self._int.append(integer)
        self._obj.append(float(obj))
        return len(self._names) - 1

    def row(self, name: str, cols: Sequence[int], vals: Sequence[float], *, lb: float = -np.inf,
            ub: float = np.inf) -> int:
        index = len(self._row_names)
        self._rows.extend([index] * len(cols))
        self._cols.extend(cols)
        self._vals.extend(vals)
        self._row_lb.append(lb)
        self._row_ub.append(ub)
        self._row_names.append(name)
        return index

    def byte_row(self, name: str, cols: Sequence[int], costs: Sequence[int], budget: int) -> None:
        """``sum costs[i] * x[cols[i]] <= budget`` in exact integer bytes, over binary columns.

        Up to :data:`BYTE_SPLIT_ABOVE` bytes this is one row. Above it, the row is written in base
        ``M`` = :data:`BYTE_DIGIT` with an integer slack ``s = budget - sum c x >= 0`` held as
        digits ``s_d`` in ``0..M-1`` and integer carries ``k_d``: digit ``d`` of the sum plus
        ``s_d`` plus the carry in equals digit ``d`` of the budget plus ``M`` times the carry out,
        and the top digit carries nothing out. Every feasible ``x`` has exactly one such
        completion (the digits of its slack) and every completion gives ``sum c x + s = budget``
        with ``s >= 0``, so the model is unchanged, while no coefficient exceeds ``M``.
        """
        costs = [int(c) for c in costs]
        budget = int(budget)
        if max([budget, *costs]) <= BYTE_SPLIT_ABOVE:
            self.row(name, cols, [float(c) for c in costs], ub=float(budget))
            return
        self.byte_digits = True
        M = BYTE_DIGIT
        digits = 1
        while M ** digits <= max(budget, sum(costs)):
            digits += 1
        carry, carry_max = None, 0
        for d in range(digits):
            part = [(c // M ** d) % M for c in costs]
            keep = [(col, float(v)) for col, v in zip(cols, part) if v]
            s_d = self.var(f"{name}.s{d}", ub=float(M - 1))
            row_cols = [col for col, _ in keep] + [s_d]
            row_vals = [v for _, v in keep] + [1.0]
            if carry is not None:
                row_cols.append(carry)
                row_vals.append(1.0)
            b_d = (budget // M ** d) % M
            if d < digits - 1:
                # Largest carry out: (largest digit sum + M - 1 + largest carry in - b_d) / M.
                carry_max = (sum(part) + M - 1 + carry_max - b_d) // M
                out = self.var(f"{name}.k{d + 1}", ub=float(max(carry_max, 0)))
                row_cols.append(out)
                row_vals.append(-float(M))
                carry = out
            self.row(f"{name}.d{d}", row_cols, row_vals, lb=float(b_d), ub=float(b_d))

    def build(self, **stats: object) -> LinearModel:
        n, m = len(self._names), len(self._row_names)
        matrix = sp.csr_matrix((np.asarray(self._vals, dtype=np.float64),
                                (np.asarray(self._rows, dtype=np.int64), np.asarray(self._cols, dtype=np.int64))),
                               shape=(m, n))
        matrix.sum_duplicates()
        return LinearModel(problem=self.problem, var_names=self._names, lb=np.asarray(self._lb, dtype=np.float64),
                           ub=np.asarray(self._ub, dtype=np.float64), integer=np.asarray(self._int, dtype=bool),
                           objective=np.asarray(self._obj, dtype=np.float64), constant=float(self.constant),
                           matrix=matrix, row_lb=np.asarray(self._row_lb, dtype=np.float64),
                           row_ub=np.asarray(self._row_ub, dtype=np.float64), row_names=self._row_names,
                           decode=self.decode, integral_ok=np.asarray(self._integral_ok, dtype=bool),
                           slot=self.slot, stats=dict(stats), byte_digits=self.byte_digits)


def index_name(letter: str, j: int, l: int, t: int | None, *, one_object: bool) -> str:
    """``x[j,l,t]``, or ``x[l,t]`` when the scene has one object (no object axis)."""
    parts = ([] if one_object else [j]) + [l] + ([] if t is None else [t])
    return f"{letter}[{','.join(str(p) for p in parts)}]"
