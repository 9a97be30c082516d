"""Utility tables as files: what a server hands a client so that it can value chunks it does not hold.

A :class:`~l3gs_opt.pipeline.splat_utility.UtilityTable` holds per-(object, layer) utilities on a
grid of viewpoints (the paper precomputes one over 1,000 positions x 1,728 orientations because
valuing every splat for one viewport took it 10.29 s). Written as one ``.npz`` (no pickles): the grid
(``positions``, ``yaw_steps``, ``pitches_deg``, ``up_axis``, ``intrinsics``), the sparse values
(CSR ``data``/``indices``/``indptr``, ``shape``, ``shape_jl``) and what it tabulates (``utility``,
``view``). Reading checks every array's type, shape and range and names the field at fault.

Example
-------
>>> from l3gs_opt.pipeline.table_files import read_utility_table, write_utility_table  # doctest: +SKIP
>>> write_utility_table("t.npz", table, utility="eq1", view="object")               # doctest: +SKIP
>>> table, meta = read_utility_table("t.npz")                                       # doctest: +SKIP
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.output_files import write_atomic

__all__ = ["TableFileError", "write_utility_table", "read_utility_table", "utility_table_bytes", "MAX_TABLE_BYTES"]

#: Largest table file read (bytes): a 1,000 x 1,728 grid of 100 x 4 cells, fully dense, is ~5.5 GB;
#: real tables are sparse (most objects are out of view from most viewpoints).
MAX_TABLE_BYTES = 2 << 30
_KEYS = ("positions", "yaw_steps", "pitches_deg", "up_axis", "intrinsics", "data", "indices", "indptr", "shape",
         "shape_jl", "utility", "view")


class TableFileError(L3gsError, ValueError):
    """A utility table file that cannot be read; names the field."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"{field}: {message}")


def utility_table_bytes(table, *, utility: str, view: str) -> bytes:
    """The ``.npz`` bytes of ``table`` (see the module docstring)."""
    v = table.values.tocsr()
    buf = io.BytesIO()
    np.savez_compressed(
        buf, positions=np.asarray(table.positions, np.float64), yaw_steps=np.int64(table.yaw_steps),
        pitches_deg=np.asarray(table.pitches_deg, np.float64), up_axis=np.int64(table.up_axis),
        intrinsics=np.asarray(table.intrinsics, np.float64), data=v.data.astype(np.float64),
        indices=v.indices.astype(np.int64), indptr=v.indptr.astype(np.int64), shape=np.asarray(v.shape, np.int64),
        shape_jl=np.asarray(table.shape_jl, np.int64), utility=np.str_(utility), view=np.str_(view))
    return buf.getvalue()


def write_utility_table(path, table, *, utility: str, view: str) -> Path:
    """Write ``table`` to ``path`` (atomically: a reader never sees half a file); returns the path."""
    return write_atomic(path, utility_table_bytes(table, utility=utility, view=view))


def _array(z, key: str, dtype_kind: str, ndim: int) -> np.ndarray:
    a = z[key]
    if a.dtype.kind not in dtype_kind or a.ndim != ndim:
        raise TableFileError(key, f"a {a.ndim}-d array of dtype {a.dtype}: expected {ndim}-d of kind {dtype_kind!r}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise TableFileError(key, "holds a value that is not finite")
    return a


def read_utility_table(source) -> tuple["object", dict]:
    """Read a table written by :func:`write_utility_table`: a path or the file's bytes.

    Returns
    -------
    (UtilityTable, {"utility": str, "view": str})

    Raises
    ------
    TableFileError
        Not a table file; a missing key; an array of the wrong type or shape; indices out of
        range; a value that is negative or not finite.
    """
    import scipy.sparse as sp

    from l3gs_opt.pipeline.splat_utility import UtilityTable

    if isinstance(source, (bytes, bytearray, memoryview)):
        data = bytes(source)
    else:
        p = Path(source)
        try:
            size = p.stat().st_size
        except OSError as exc:
            raise TableFileError("file", f"{p}: {exc.strerror or exc}") from None
        if size > MAX_TABLE_BYTES:
            raise TableFileError("file", f"{p}: {size} bytes is more than {MAX_TABLE_BYTES}")
        data = p.read_bytes()
    try:
        z = np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise TableFileError("file", f"not a utility table (.npz): {exc}") from None
    with z:
        missing = [k for k in _KEYS if k not in z.files]
        if missing:
            raise TableFileError(missing[0], "missing from the table file")
        try:
            positions = _array(z, "positions", "f", 2)
            pitches = _array(z, "pitches_deg", "f", 1)
            intr = _array(z, "intrinsics", "f", 1)
            vals = _array(z, "data", "f", 1)
            indices = _array(z, "indices", "iu", 1)
            indptr = _array(z, "indptr", "iu", 1)
            shape = _array(z, "shape", "iu", 1)
            shape_jl = _array(z, "shape_jl", "iu", 1)
            yaw_steps, up_axis = int(_array(z, "yaw_steps", "iu", 0)), int(_array(z, "up_axis", "iu", 0))
            utility, view = str(_array(z, "utility", "U", 0)), str(_array(z, "view", "U", 0))
        except (ValueError, zipfile.BadZipFile, OSError) as exc:   # a damaged member
            raise TableFileError("file", f"a damaged member: {exc}") from None
    if positions.shape[1:] != (3,) or positions.shape[0] < 1:
        raise TableFileError("positions", f"shape {positions.shape}: expected [P >= 1, 3]")
    if yaw_steps < 1 or pitches.size < 1 or not (np.all(np.diff(pitches) > 0) and np.all(np.abs(pitches) < 90)):
        raise TableFileError("pitches_deg", "needs yaw_steps >= 1 and increasing pitches in (-90, 90)")
    if up_axis not in (0, 1, 2):
        raise TableFileError("up_axis", f"{up_axis}: must be 0, 1 or 2")
    if intr.shape != (6,) or intr[0] < 1 or intr[1] < 1 or intr[2] <= 0 or intr[3] <= 0:
        raise TableFileError("intrinsics", "expected (width, height, fx, fy, cx, cy) with positive sizes")
    if shape_jl.shape != (2,) or shape_jl.min() < 1:
        raise TableFileError("shape_jl", f"{shape_jl.tolist()}: expected (J >= 1, L >= 1)")
    rows = positions.shape[0] * yaw_steps * pitches.size
    cols = int(shape_jl[0] * shape_jl[1])
    if shape.tolist() != [rows, cols]:
        raise TableFileError("shape", f"{shape.tolist()}: the grid and cells make [{rows}, {cols}]")
    if indptr.shape != (rows + 1,) or indptr[0] != 0 or np.any(np.diff(indptr) < 0) or indptr[-1] != vals.size:
        raise TableFileError("indptr", f"not a CSR row pointer for {rows} rows and {vals.size} values")
    if indices.shape != vals.shape or (indices.size and (indices.min() < 0 or indices.max() >= cols)):
        raise TableFileError("indices", f"column indices must be in [0, {cols}) and one per value")
    if vals.size and vals.min() < 0:
        raise TableFileError("data", "holds a negative utility")
    values = sp.csr_matrix((vals, indices, indptr), shape=(rows, cols))
    w, h = int(intr[0]), int(intr[1])
    table = UtilityTable(positions, yaw_steps, pitches, values, (int(shape_jl[0]), int(shape_jl[1])), up_axis,
                         (w, h, float(intr[2]), float(intr[3]), float(intr[4]), float(intr[5])))
    return table, {"utility": utility, "view": view}
