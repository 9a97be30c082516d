"""Reading and writing item instances: JSON (small) and NPZ (large), schema ``l3gs-opt/items@1``.

As for :mod:`l3gs_opt.problem.instance_io`, the JSON parser walks nested lists itself so that a fault
names its exact index (``utility[3]: expected 7 entries (items), got 6``).

JSON keys: ``schema`` (``"l3gs-opt/items@1"``), ``bandwidth`` [T], ``object`` [N], ``cost`` [N],
``utility`` [T][N], and optionally ``group`` [N], ``requires`` [[parent, child], ...], ``held``
[N] (0/1), ``slot_s``, ``options``, ``names`` [N], ``meta``. An unknown key is an error. NPZ files
hold the arrays under the same names and the other keys as JSON text in 0-d string arrays.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from l3gs_opt.input_files import npz_text, parse_json
from l3gs_opt.problem.instance_io import (check_head, instance_from_raw, nested_array, npz_fields, read_raw_problem,
                          write_problem_file)
from l3gs_opt.problem.items import ITEMS_SCHEMA, ItemInstance, ItemInstanceError

__all__ = ["items_from_dict", "items_from_raw", "load_items", "load_problem", "save_items"]

_KEYS = ("schema", "bandwidth", "slot_s", "object", "cost", "utility", "group", "requires", "held", "options",
         "names", "meta")
_REQUIRED = ("schema", "bandwidth", "object", "cost", "utility")
_DIMS = {"bandwidth": ("slots",), "object": ("items",), "cost": ("items",), "utility": ("slots", "items"),
         "group": ("items",), "held": ("items",), "requires": ("edges", "ends")}


def _nested(value: Any, name: str, *, integer: bool) -> np.ndarray:
    return nested_array(value, name, _DIMS[name], integer=integer, error=ItemInstanceError,
                        pairs=name == "requires")


def _check_head(data: Mapping[str, Any]) -> None:
    check_head(data, _KEYS, _REQUIRED, ITEMS_SCHEMA, error=ItemInstanceError)


def _build(data: Mapping[str, Any]) -> ItemInstance:
    return ItemInstance(bandwidth=data["bandwidth"], object=data["object"], cost=data["cost"],
                        utility=data["utility"], group=data.get("group"), requires=data.get("requires"),
                        held=data.get("held"), slot_s=data.get("slot_s", 1.0), options=data.get("options"),
                        names=data.get("names"), meta=data.get("meta"))


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


def items_from_raw(is_npz: bool, raw: Any) -> ItemInstance:
    """The item instance from :func:`l3gs_opt.problem.instance_io.read_raw_problem`'s answer."""
    if not is_npz:
        return items_from_dict(raw)
    fields = npz_fields(raw, _KEYS, _DIMS, error=ItemInstanceError)
    _check_head(fields)
    return _build(fields)


def load_items(path: str | os.PathLike[str]) -> ItemInstance:
    """Load an item instance from ``.json`` or ``.npz`` (within the limits of
    :func:`l3gs_opt.problem.instance_io.read_raw_problem`); every fault is an :class:`ItemInstanceError`."""
    return items_from_raw(*read_raw_problem(path, error=ItemInstanceError))


def save_items(instance: ItemInstance, path: str | os.PathLike[str]) -> Path:
    """Write ``.json`` (small) or ``.npz`` (large), chosen by the suffix (see
    :func:`l3gs_opt.problem.instance_io.write_problem_file`)."""
    data = instance.to_dict()
    return write_problem_file(path, data, {key: getattr(instance, key) for key in _DIMS if key in data},
                              error=ItemInstanceError)


def _schema_of(is_npz: bool, raw: Any) -> Any:
    """The ``schema`` a read file states, or None when it states none readable (the loader then says why)."""
    if not is_npz:
        return raw.get("schema") if isinstance(raw, Mapping) else None
    arr = raw.get("schema")
    if arr is None or arr.ndim != 0 or arr.dtype.kind != "U":
        return None
    try:
        return parse_json(npz_text(arr, ItemInstanceError, field="schema"), ItemInstanceError, field="schema")
    except ItemInstanceError:
        return None


def load_problem(path: str | os.PathLike[str]) -> Any:
    """Load either instance form by its ``schema``, reading the file once: ``l3gs-opt/items@1``
    gives an :class:`ItemInstance`, anything else goes to the instance loader (which names a wrong
    or missing schema). A file that cannot be read is an :class:`~l3gs_opt.errors.InstanceError`."""
    is_npz, raw = read_raw_problem(path)
    if _schema_of(is_npz, raw) == ITEMS_SCHEMA:
        return items_from_raw(is_npz, raw)
    return instance_from_raw(is_npz, raw)
