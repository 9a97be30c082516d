"""Reading and writing instances: JSON (small) and NPZ (large), schema ``l3gs-opt/instance@1``.

The parser walks nested lists itself so that a fault names its exact index
(``utility[3][2]: expected 4 entries (layers), got 3``) instead of surfacing a numpy error.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .errors import InstanceError
from .instance import SCHEMA, Instance, Options

__all__ = ["instance_from_dict", "load_instance", "save_instance", "nested_array", "npz_fields",
           "read_problem_file"]

_KEYS = ("schema", "representation", "bandwidth", "slot_s", "cost", "utility", "held", "options", "names",
         "meta")
_REQUIRED = ("schema", "representation", "bandwidth", "cost", "utility")
_DIMS = {"bandwidth": ("slots",), "cost": ("objects", "layers"), "utility": ("slots", "objects", "layers"),
         "held": ("objects", "layers")}


def _brief(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 24 else text[:21] + "..."


def nested_array(value: Any, name: str, dims: tuple[str, ...], *, integer: bool,
                 error: type[InstanceError] = InstanceError, pairs: bool = False) -> np.ndarray:
    """Nested JSON lists -> array, checking every entry's type and every list's length.

    ``dims`` names the axes (for messages); ``pairs``: the second axis holds exactly two entries
    (edge lists). Integers stay int64 unless a float appears (the caller then names a fractional
    value). Errors are ``error(name, message, index)``, so both instance forms share one parser.
    """
    shape: list[int | None] = [None] * len(dims)
    flat: list[float | int] = []

    def walk(v: Any, depth: int, idx: tuple[int, ...]) -> None:
        if depth == len(dims):
            if type(v) is bool or not isinstance(v, (int, float)):
                raise error(name, f"= {_brief(v)}: must be a number", idx)
            if integer and abs(v) > 2**63 - 1 and (isinstance(v, int) or math.isfinite(v)):
                raise error(name, f"= {_brief(v)}: out of range", idx)
            if not integer and isinstance(v, int) and abs(v) > 1e308:
                raise error(name, f"= {_brief(v)}: must be finite", idx)
            flat.append(v)
            return
        if not isinstance(v, list):
            raise error(name, f"must be a list over {dims[depth]}, got {type(v).__name__}", idx)
        if pairs and depth == 1 and len(v) != 2:
            raise error(name, f"must be a [parent, child] pair, got {len(v)} entries", idx)
        if shape[depth] is None:
            shape[depth] = len(v)
        elif len(v) != shape[depth]:
            raise error(name, f"expected {shape[depth]} entries ({dims[depth]}), got {len(v)}", idx)
        for i, item in enumerate(v):
            walk(item, depth + 1, idx + (i,))

    walk(value, 0, ())
    full = tuple(0 if s is None else s for s in shape)
    if integer and not any(isinstance(v, float) for v in flat):
        arr = np.array(flat, dtype=np.int64)
    else:
        arr = np.array(flat, dtype=np.float64)
    return arr.reshape(full)


def _nested(value: Any, name: str, *, integer: bool) -> np.ndarray:
    return nested_array(value, name, _DIMS[name], integer=integer)


def check_head(data: Mapping[str, Any], keys: tuple[str, ...], required: tuple[str, ...], schema: str, *,
               error: type[InstanceError] = InstanceError) -> None:
    """No unknown key (a typo must not drop data), every required key, the expected ``schema``."""
    for key in data:
        if key not in keys:
            raise error(str(key), f"unknown key (known: {', '.join(keys)})")
    for key in required:
        if key not in data:
            raise error(key, "missing")
    if data["schema"] != schema:
        raise error("schema", f"{_brief(data['schema'])}: expected {schema!r}")


def instance_from_dict(data: Any) -> Instance:
    """Validate a decoded ``l3gs-opt/instance@1`` JSON object and build the instance.

    Raises
    ------
    InstanceError
        Unknown or missing keys, a wrong schema, wrong shapes, NaN/inf, negative numbers,
        fractional bytes, a held set that is not a prefix (layered).
    """
    if not isinstance(data, Mapping):
        raise InstanceError("instance", "must be a JSON object")
    check_head(data, _KEYS, _REQUIRED, SCHEMA)
    if not isinstance(data["representation"], str):
        raise InstanceError("representation", "must be a string")
    held = data.get("held")
    if held is not None:
        held = _nested(held, "held", integer=True)
    slot_s = data.get("slot_s", 1.0)
    return Instance(
        representation=data["representation"],
        bandwidth=_nested(data["bandwidth"], "bandwidth", integer=True),
        cost=_nested(data["cost"], "cost", integer=True),
        utility=_nested(data["utility"], "utility", integer=False),
        held=held,
        slot_s=slot_s,
        options=Options.from_dict(data.get("options")),
        names=data.get("names"),
        meta=data.get("meta") or {},
    )


def npz_fields(npz: Mapping[str, np.ndarray], keys: tuple[str, ...], dims: Mapping[str, Any], *,
               error: type[InstanceError] = InstanceError) -> dict[str, Any]:
    """NPZ entries carry the JSON names: arrays for the keys in ``dims`` (numeric), the rest as
    JSON text in 0-d string arrays. Unknown keys are an error."""
    out: dict[str, Any] = {}
    for key in npz:
        if key not in keys:
            raise error(key, f"unknown key (known: {', '.join(keys)})")
        arr = npz[key]
        if key in dims:
            if arr.size and arr.dtype.kind not in "biuf":
                raise error(key, f"must be numeric, got dtype {arr.dtype}")
            out[key] = arr
        else:
            if arr.ndim != 0 or arr.dtype.kind != "U":
                raise error(key, "must be stored as JSON text in a 0-d string array")
            try:
                out[key] = json.loads(str(arr))
            except json.JSONDecodeError as exc:
                raise error(key, f"not valid JSON: {exc}") from None
    return out


def read_problem_file(path: str | os.PathLike[str], keys: tuple[str, ...], dims: Mapping[str, Any], *,
                      error: type[InstanceError] = InstanceError,
                      what: str = "instance") -> tuple[bool, Any]:
    """Read a ``.json`` or ``.npz`` problem file: ``(True, fields)`` for NPZ, ``(False, decoded
    JSON)`` otherwise. A missing, unreadable or malformed file is ``error("file", ...)``."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".npz":
            try:
                with np.load(path, allow_pickle=False) as npz:
                    return True, npz_fields({k: npz[k] for k in npz.files}, keys, dims, error=error)
            except (zipfile.BadZipFile, ValueError, EOFError, OSError) as exc:
                if isinstance(exc, InstanceError):
                    raise
                raise error("file", f"{path}: not a readable NPZ {what} ({exc})") from None
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error("file", f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error("file", f"{path}: cannot be read ({exc})") from None
    try:
        return False, json.loads(text)
    except json.JSONDecodeError as exc:
        raise error("file", f"{path}: not valid JSON ({exc})") from None


def load_instance(path: str | os.PathLike[str]) -> Instance:
    """Load an instance from ``.json`` or ``.npz``; every fault is an :class:`InstanceError`."""
    is_npz, data = read_problem_file(path, _KEYS, _DIMS)
    if not is_npz:
        return instance_from_dict(data)
    check_head(data, _KEYS, _REQUIRED, SCHEMA)
    return Instance(representation=data["representation"], bandwidth=data["bandwidth"],
                    cost=data["cost"], utility=data["utility"], held=data.get("held"),
                    slot_s=data.get("slot_s", 1.0), options=Options.from_dict(data.get("options")),
                    names=data.get("names"), meta=data.get("meta") or {})


def save_instance(instance: Instance, path: str | os.PathLike[str]) -> Path:
    """Write ``.json`` (small instances) or ``.npz`` (large), chosen by the suffix."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = instance.to_dict()
    if path.suffix.lower() == ".npz":
        arrays: dict[str, np.ndarray] = {}
        for key, value in data.items():
            if key in _DIMS:
                arrays[key] = np.asarray(getattr(instance, key))
            else:
                arrays[key] = np.array(json.dumps(value))
        np.savez_compressed(path, **arrays)
    else:
        path.write_text(json.dumps(data, allow_nan=False) + "\n", encoding="utf-8")
    return path
