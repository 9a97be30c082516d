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

from l3gs_opt.solution import ModelSize

__all__ = ["LinearModel", "ModelBuilder"]


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
        Continuous variables that some optimum has integral anyway (shown-version ``w``,
        unspent-bytes carry ``r``): a backend that needs integers (CP-SAT) may declare them so.
    slot : int or None
        The slot of a single-slot model.
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

    @property
    def size(self) -> ModelSize:
        return ModelSize(variables=len(self.var_names), constraints=len(self.row_names),
                         nonzeros=int(self.matrix.nnz))

    def schedule(self, values: np.ndarray) -> list[tuple[int, int, int]]:
        """Arrivals of a (near-)integral variable vector; values above 0.5 count as 1."""
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
                           slot=self.slot, stats=dict(stats))


def index_name(letter: str, j: int, l: int, t: int | None, *, one_object: bool) -> str:
    """``x[j,l,t]``, or ``x[l,t]`` when the scene has one object (no object axis)."""
    parts = ([] if one_object else [j]) + [l] + ([] if t is None else [t])
    return f"{letter}[{','.join(str(p) for p in parts)}]"
