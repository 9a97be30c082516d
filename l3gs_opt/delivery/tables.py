"""Utility tables beside a stream export: what a server offers a client that holds no splats yet.

A client that values chunks by a splat utility needs the splats' geometry: the simulator's client
knows the whole bundle from the start. A real client knows only the index; so, as the paper does,
the utilities are precomputed on a grid of viewpoints (:func:`l3gs_opt.pipeline.utilities.tabulate`)
and served as files. :func:`export_tables` writes one table per (utility, view) next to
``index.json`` and lists them in ``tables.json``::

    {"schema": "l3gs-opt/utility-tables/1",
     "index_sha256": "...the index.json the tables were made from...",
     "tables": [{"file": "utility-eq1-object.npz", "utility": "eq1", "view": "object",
                 "bytes": 20934, "sha256": "...", "grid": {...how the grid was chosen...}}]}

Tables of other utilities or views already listed are kept (a table of the same utility and view
is replaced), unless they were made from another ``index.json`` (an export written again): then
the manifest starts over. A reader refuses tables made from another index (stale utilities).

The server serves ``tables.json`` and the files it lists (:mod:`l3gs_opt.delivery.server`);
``l3gs-opt fetch --catalogue tables`` reads them (:func:`load_table`).

The grid: positions on a lattice over the box of the scene's splat centres (the 1st to 99th
percentile per axis, so that a few far splats do not stretch it), widened by ``margin`` times its
extent on each side (viewers stand outside the objects), ``counts`` positions per axis; at each,
``yaw_steps`` yaws times ``pitches_deg`` about the ``up`` axis; cameras of the client's image size
and field of view (a table answers in its own pixels).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.input_files import read_json
from l3gs_opt.output_files import write_atomic
from l3gs_opt.scene.stream_index import INDEX_NAME

__all__ = ["TablesError", "TABLES_NAME", "TABLES_SCHEMA", "export_tables", "read_tables", "load_table"]

TABLES_NAME = "tables.json"
TABLES_SCHEMA = "l3gs-opt/utility-tables/1"
_VIEWS = ("object", "scene")


class TablesError(L3gsError, ValueError):
    """A bad tables manifest or option; names the field and the entry."""

    def __init__(self, field: str, message: str, index: Optional[int] = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


def _grid_box(means: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.percentile(means, 1, axis=0), np.percentile(means, 99, axis=0)
    pad = margin * np.maximum(hi - lo, 1e-6)
    return lo - pad, hi + pad


def export_tables(export_dir, *, utility: str = "eq1", views: Sequence[str] = ("object",),
                  counts: Sequence[int] = (5, 5, 2), margin: float = 0.5, yaw_steps: int = 12,
                  pitches_deg: Sequence[float] = (-20.0, 0.0, 20.0), up: str = "z", width: int = 160,
                  height: int = 120, fov_deg: float = 70.0, progress: bool = False) -> Path:
    """Tabulate ``utility`` for each of ``views`` over the export's bundle; returns ``tables.json``'s path.

    Parameters
    ----------
    export_dir : path
        A stream export (``index.json`` and its data files).
    utility : str
        A held-free splat utility (``eq1``, ``visibility``, ...).
    views : sequence of {"object", "scene"}
        Unit views to tabulate: ``object`` for per-object methods (``l3gs``, solver methods),
        ``scene`` for whole-scene layers (``l3gs-noseg``).
    counts, margin, yaw_steps, pitches_deg, up, width, height, fov_deg
        The grid (see the module docstring); ``width``/``height``/``fov_deg`` are the client's
        (pixels, degrees).

    Raises
    ------
    TablesError
        A bad view, margin or up axis; :class:`~l3gs_opt.pipeline.utilities.UtilityNameError` for a
        held-aware or unknown utility, :class:`~l3gs_opt.scene.stream_index.StreamError` for a bad export.
    """
    import dataclasses

    from l3gs_opt.pipeline.splat_utility import grid_positions
    from l3gs_opt.pipeline.table_files import utility_table_bytes
    from l3gs_opt.pipeline.utilities import get_utility, tabulate
    from l3gs_opt.scene.stream_index import read_stream, stream_bundle
    from l3gs_opt.simulator.catalog import _base_scene, build_catalog

    for i, v in enumerate(views):
        if v not in _VIEWS:
            raise TablesError("views", f"{v!r} is not one of {', '.join(_VIEWS)}", i)
    if not (isinstance(margin, (int, float)) and 0 <= margin < 100):
        raise TablesError("margin", f"{margin!r}: must be a number in [0, 100)")
    if up not in ("x", "y", "z"):
        raise TablesError("up", f"{up!r}: must be x, y or z")
    name = get_utility(utility).name   # an unknown name fails here, before any work
    folder = Path(export_dir)
    index_sha = hashlib.sha256((folder / INDEX_NAME).read_bytes()).hexdigest() \
        if (folder / INDEX_NAME).is_file() else None
    bundle = stream_bundle(read_stream(folder))
    base = _base_scene(bundle)
    lo, hi = _grid_box(base[0].means, float(margin))
    positions = grid_positions(lo, hi, counts)
    grid = {"lo": lo.tolist(), "hi": hi.tolist(), "counts": [int(c) for c in counts], "margin": margin,
            "yaw_steps": yaw_steps, "pitches_deg": [float(x) for x in pitches_deg], "up": up, "width": width,
            "height": height, "fov_deg": fov_deg}
    entries = []
    if (folder / TABLES_NAME).is_file():
        try:
            entries = read_tables(folder)
        except TablesError:
            entries = []   # another index's (or a broken) manifest: start over
    for view in views:
        cat = build_catalog(bundle, view, base=base)
        J, L = cat.shape
        labelled = dataclasses.replace(base[0], object_ids=(cat.unit_of_row // L).astype(np.int32),
                                       layers=(cat.unit_of_row % L).astype(np.int32))
        table = tabulate(name, labelled, positions, yaw_steps=yaw_steps, pitches_deg=tuple(pitches_deg),
                         up_axis="xyz".index(up), width=width, height=height, fov_deg=fov_deg, progress=progress)
        data = utility_table_bytes(table, utility=name, view=view)
        file = f"utility-{name}-{view}.npz"
        write_atomic(folder / file, data)
        entries = [e for e in entries if (e["utility"], e["view"]) != (name, view)]
        entries.append({"file": file, "utility": name, "view": view, "bytes": len(data),
                        "sha256": hashlib.sha256(data).hexdigest(), "grid": grid})
    manifest = {"schema": TABLES_SCHEMA, "index_sha256": index_sha, "tables": entries}
    return write_atomic(folder / TABLES_NAME, json.dumps(manifest, indent=1) + "\n")


def read_tables(source, *, index_bytes: Optional[bytes] = None) -> list[dict]:
    """The checked entries of a ``tables.json`` (a path, a folder holding it, or its bytes).

    ``index_bytes``: the ``index.json`` the tables must have been made from (default, for a path:
    the one beside the manifest; for bytes: not checked).

    Raises
    ------
    TablesError
        Not the schema; tables made from another index; an entry without a safe relative file
        name, a utility, a view of ``object``/``scene``, a byte count or a SHA-256.
    """
    if isinstance(source, (bytes, bytearray)):
        try:
            m = json.loads(bytes(source).decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise TablesError("tables", f"not JSON: {exc}") from None
    else:
        p = Path(source)
        if p.is_dir():
            p = p / TABLES_NAME
        m = read_json(p, lambda f, msg: TablesError(f, msg), field="tables")
        if index_bytes is None and (p.parent / INDEX_NAME).is_file():
            index_bytes = (p.parent / INDEX_NAME).read_bytes()
    if not isinstance(m, dict) or m.get("schema") != TABLES_SCHEMA:
        raise TablesError("schema", f"must be {TABLES_SCHEMA!r}")
    if index_bytes is not None and m.get("index_sha256") != hashlib.sha256(index_bytes).hexdigest():
        raise TablesError("index_sha256", "the tables were made from another index.json (the export was written "
                                          "again): run 'l3gs-opt bundle tables' again")
    entries = m.get("tables")
    if not isinstance(entries, list):
        raise TablesError("tables", "must be a list")
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise TablesError("tables", "must be an object", i)
        f = e.get("file")
        if not (isinstance(f, str) and f and "/" not in f and "\\" not in f and f not in (".", "..")
                and "\0" not in f):
            raise TablesError("tables", f"file {f!r} must be a plain file name in the export's folder", i)
        if not isinstance(e.get("utility"), str) or e.get("view") not in _VIEWS:
            raise TablesError("tables", f"needs a utility name and a view of {', '.join(_VIEWS)}", i)
        if not (isinstance(e.get("bytes"), int) and e["bytes"] >= 0):
            raise TablesError("tables", "bytes must be a whole number >= 0", i)
        sha = e.get("sha256")
        if not (isinstance(sha, str) and len(sha) == 64 and all(c in "0123456789abcdef" for c in sha)):
            raise TablesError("tables", "sha256 must be 64 hex digits", i)
    return entries


def load_table(entry: dict, data: bytes):
    """The :class:`~l3gs_opt.pipeline.splat_utility.UtilityTable` of a manifest entry from its file's
    bytes, checked against the entry's size, hash, utility and view.

    Raises
    ------
    TablesError
        Bytes that are not the entry's; a file that says another utility or view.
    """
    from l3gs_opt.pipeline.table_files import read_utility_table

    if len(data) != entry["bytes"] or hashlib.sha256(data).hexdigest() != entry["sha256"]:
        raise TablesError("tables", f"{entry['file']}: {len(data)} bytes that are not the manifest's (size or sha256)")
    table, meta = read_utility_table(data)
    if (meta["utility"], meta["view"]) != (entry["utility"], entry["view"]):
        raise TablesError("tables", f"{entry['file']} holds {meta['utility']}/{meta['view']}, the manifest says "
                                    f"{entry['utility']}/{entry['view']}")
    return table
