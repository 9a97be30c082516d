"""Plain-text comparison tables of solutions (for the CLI, the demo and reports)."""

from __future__ import annotations

from typing import Sequence

from l3gs_opt.problem.solution import Solution

__all__ = ["comparison_table"]


def _num(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def comparison_table(rows: Sequence[tuple[str, Solution]]) -> str:
    """A fixed-width table: label, problem, status, objective, bound, gap, run time, model sizes."""
    header = ("method", "problem", "status", "objective", "bound", "gap", "time_s", "vars/rows/nnz before",
              "after presolve")
    lines = [header]
    for label, s in rows:
        def size(ms):  # noqa: ANN001 - tiny local formatter
            return "-" if ms is None else f"{ms.variables}/{ms.constraints}/{ms.nonzeros}"

        lines.append((label, s.problem, s.status.value, _num(s.objective, ".6g"), _num(s.bound, ".6g"),
                      _num(s.gap, ".2e"), f"{s.runtime_s:.3f}", size(s.size_before), size(s.size_after)))
    widths = [max(len(str(row[i])) for row in lines) for i in range(len(header))]
    out = ["  ".join(str(v).ljust(w) for v, w in zip(row, widths)).rstrip() for row in lines]
    out.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(out)
