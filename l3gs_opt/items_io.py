"""Reading and writing item instances: JSON (small) and NPZ (large), schema ``l3gs-opt/items@1``.

As for :mod:`l3gs_opt.instance_io`, the JSON parser walks nested lists itself so that a fault
names its exact index (``utility[3]: expected 7 entries (items), got 6``).

JSON keys: ``schema`` (``"l3gs-opt/items@1"``), ``bandwidth`` [T], ``object`` [N], ``cost`` [N],
``utility`` [T][N], and optionally ``group`` [N], ``requires`` [[parent, child], ...], ``held``
[N] (0/1), ``slot_s``, ``options``, ``names`` [N], ``meta``. An unknown key is an error. NPZ files
hold the arrays under the same names and the other keys as JSON text in 0-d string arrays.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .instance_io import check_head, nested_array, read_problem_file
from .items import ITEMS_SCHEMA, ItemInstance, ItemInstanceError

__all__ = ["items_from_dict", "load_items", "load_problem", "save_items"]

_KEYS = ("schema", "bandwidth", "slot_s", "object", "cost", "utility", "group", "requires", "held", "options",
         "names", "meta")
_REQUIRED = ("schema", "bandwidth", "object", "cost", "utility")
_DIMS = {"bandwidth": ("slots",), "object": ("items",), "cost": ("items",), "utility": ("slots", "items"),
         "group": ("items",), "held": ("items",), "requires": ("edges", "ends")}


def _brief(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 24 else text[:21] + "..."


def _nested(value: Any, name: str, *, integer: bool) -> np.ndarray:
    return nested_array(value, name, _DIMS[name], integer=integer, error=ItemInstanceError,
                        pairs=name == "requires")


def _check_head(data: Mapping[str, Any]) -> None:
    check_head(data, _KEYS, _REQUIRED, ITEMS_SCHEMA, error=ItemInstanceError)


def _build(data: Mapping[str, Any]) -> ItemInstance:
    return ItemInstance(bandwidth=data["bandwidth"], object=data["object"], cost=data["cost"],
                        utility=data["utility"], group=data.get("group"), requires=data.get("requires"),
                        held=data.get("held"), slot_s=data.get("slot_s", 1.0), options=data.get("options"),
                        names=data.get("names"), meta=data.get("meta") or {})


def items_from_dict(data: Any) -> ItemInstance:
    """Validate a decoded ``l3gs-opt/items@1`` JSON object and build the item instance.

    Raises
    ------
    ItemInstanceError
        Unknown or missing keys, a wrong schema, wrong shapes, NaN/inf, negative numbers,
        fractional bytes, bad or cyclic edges, a held set not closed under precedence.
    """
    if not isinstance(data, Mapping):
        raise ItemInstanceError("instance", "must be a JSON object")
    _check_head(data)
    out = dict(data)
    for key in ("bandwidth", "object", "cost", "group", "held", "requires"):
        if out.get(key) is not None:
            out[key] = _nested(out[key], key, integer=True)
    out["utility"] = _nested(out["utility"], "utility", integer=False)
    if out.get("requires") is not None and out["requires"].size == 0:
        out["requires"] = np.zeros((0, 2), np.int64)
    return _build(out)


def load_items(path: str | os.PathLike[str]) -> ItemInstance:
    """Load an item instance from ``.json`` or ``.npz``; every fault is an :class:`ItemInstanceError`."""
    is_npz, data = read_problem_file(path, _KEYS, _DIMS, error=ItemInstanceError, what="item instance")
    if not is_npz:
        return items_from_dict(data)
    _check_head(data)
    return _build(data)


def save_items(instance: ItemInstance, path: str | os.PathLike[str]) -> Path:
    """Write ``.json`` (small) or ``.npz`` (large), chosen by the suffix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = instance.to_dict()
    if path.suffix.lower() == ".npz":
        arrays: dict[str, np.ndarray] = {}
        for key, value in data.items():
            arrays[key] = np.asarray(getattr(instance, key)) if key in _DIMS else np.array(json.dumps(value))
        np.savez_compressed(path, **arrays)
    else:
        path.write_text(json.dumps(data, allow_nan=False) + "\n", encoding="utf-8")
    return path


def _schema_of(path: Path) -> str | None:
    """The file's ``schema`` string, or None when it cannot be read cheaply (the loader then says why)."""
    try:
        if path.suffix.lower() == ".npz":
            with np.load(path, allow_pickle=False) as npz:
                return str(npz["schema"]) if "schema" in npz.files else None
        data = json.loads(path.read_text(encoding="utf-8"))
        return data.get("schema") if isinstance(data, Mapping) else None
    except Exception:  # noqa: BLE001 - any fault here is reported by the real loader
        return None


def load_problem(path: str | os.PathLike[str]) -> Any:
    """Load either instance form by its ``schema``: ``l3gs-opt/items@1`` gives an
    :class:`ItemInstance`, anything else goes to :func:`l3gs_opt.instance_io.load_instance` (which
    names a wrong or missing schema)."""
    from .instance_io import load_instance

    path = Path(path)
    return load_items(path) if _schema_of(path) == ITEMS_SCHEMA else load_instance(path)
