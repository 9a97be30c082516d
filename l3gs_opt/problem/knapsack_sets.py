"""Public 0-1 knapsack instances with known optima, read as single-slot instances.

A 0-1 knapsack is the single-slot MCKP in which every object has one layer: weight = chunk cost
(bytes), profit = utility, capacity = the slot's bandwidth (bytes). Two published formats:

* **Pisinger** (``knapPI_{class}_{n}_{R}_{k}.txt``): ``n c`` on the first line, then ``p w`` per
  item; an optional last line is an optimal 0/1 vector. The optimum is read from ``NAME.opt``
  beside the file when it is there.
* **Jooken** (``*.in``, Jooken, Leyman and De Causmaecker, EJOR 2022): ``n``, then ``i p w`` per
  item, then the capacity. The optimum is read from ``optima.csv`` (``name,optimum``) in the
  same folder when it lists the file.

The format is told by the file's first line (two numbers: Pisinger; one: Jooken). Every fault is
one :class:`~l3gs_opt.errors.InstanceError` naming the file's line.
"""

from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from l3gs_opt.errors import InstanceError
from l3gs_opt.input_files import read_text
from l3gs_opt.problem.instance import MAX_BYTES, Instance

__all__ = ["KnapsackSet", "load_knapsack"]


@dataclass(frozen=True)
class KnapsackSet:
    """One 0-1 knapsack instance: ``instance`` (layered, T = 1, L = 1) and its published optimum
    (``None`` when none was found beside the file)."""

    name: str
    format: str
    instance: Instance
    optimum: int | None


def _error(field: str, message: str) -> InstanceError:
    return InstanceError(field, message)


def _integers(line: str, lineno: int, count: int) -> list[int]:
    parts = line.split()
    if len(parts) != count:
        raise InstanceError("file", f"line {lineno}: expected {count} integers, found {len(parts)}")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise InstanceError("file", f"line {lineno}: {line.strip()[:40]!r} is not {count} integers") from None
    for v in values:
        if not 0 <= v <= MAX_BYTES:
            raise InstanceError("file", f"line {lineno}: {v} is outside 0..2**53")
    return values


def load_knapsack(path: str | os.PathLike[str]) -> KnapsackSet:
    """Read a Pisinger or Jooken 0-1 knapsack file and its known optimum.

    Raises
    ------
    InstanceError
        Not a regular readable file, a malformed line (named by number), a count that disagrees
        with the lines, a weight of 0 or a value outside ``0..2**53``.
    """
    path = Path(path)
    lines = [ln for ln in read_text(path, _error).splitlines() if ln.strip()]
    if not lines:
        raise InstanceError("file", f"{path}: empty")
    head = lines[0].split()
    if len(head) == 2:
        fmt = "pisinger"
        n, capacity = _integers(lines[0], 1, 2)
        if len(lines) not in (n + 1, n + 2):
            raise InstanceError("file", f"{path}: line 1 says {n} items, the file has {len(lines) - 1} more lines")
        rows = [_integers(lines[k], k + 1, 2) for k in range(1, n + 1)]
        profit = np.array([r[0] for r in rows], dtype=np.int64)
        weight = np.array([r[1] for r in rows], dtype=np.int64)
        optimum = _sidecar_opt(path.with_suffix(".opt"))
    elif len(head) == 1:
        fmt = "jooken"
        (n,) = _integers(lines[0], 1, 1)
        if len(lines) != n + 2:
            raise InstanceError("file", f"{path}: line 1 says {n} items, expected {n + 2} lines, found {len(lines)}")
        rows = [_integers(lines[k], k + 1, 3) for k in range(1, n + 1)]
        for k, row in enumerate(rows):
            if row[0] != k:
                raise InstanceError("file", f"line {k + 2}: item number {row[0]}, expected {k}")
        profit = np.array([r[1] for r in rows], dtype=np.int64)
        weight = np.array([r[2] for r in rows], dtype=np.int64)
        (capacity,) = _integers(lines[n + 1], n + 2, 1)
        optimum = _optima_csv(path)
    else:
        raise InstanceError("file", f"{path}: line 1 has {len(head)} fields: neither Pisinger's 'n c' nor Jooken's 'n'")
    if n == 0:
        raise InstanceError("file", f"{path}: no items")
    zero = np.flatnonzero(weight == 0)
    if zero.size:
        raise InstanceError("file", f"item {int(zero[0])}: weight 0 (a chunk costs at least one byte)")
    inst = Instance("layered", bandwidth=[capacity], cost=weight[:, None], utility=profit[None, :, None].astype(float),
                    meta={"knapsack": path.stem, "format": fmt})
    return KnapsackSet(name=path.stem, format=fmt, instance=inst, optimum=optimum)


def _sidecar_opt(path: Path) -> int | None:
    if not path.exists():
        return None
    text = read_text(path, _error, field="optimum", max_bytes=1024).strip()
    try:
        return int(text)
    except ValueError:
        raise InstanceError("optimum", f"{path}: {text[:40]!r} is not an integer") from None


def _optima_csv(path: Path) -> int | None:
    table = path.parent / "optima.csv"
    if not table.exists():
        return None
    for k, row in enumerate(csv.reader(io.StringIO(read_text(table, _error, field="optimum")))):
        if k == 0 or not row:
            continue
        if len(row) != 2:
            raise InstanceError("optimum", f"{table}: line {k + 1}: expected name,optimum")
        if row[0] == path.stem:
            try:
                return int(row[1])
            except ValueError:
                raise InstanceError("optimum", f"{table}: line {k + 1}: {row[1][:40]!r} is not an integer") from None
    return None
