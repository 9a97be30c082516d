"""Reading and writing instances: JSON (small) and NPZ (large), schema ``l3gs-opt/instance@1``.

The parser walks nested lists itself so that a fault names its exact index
(``utility[3][2]: expected 4 entries (layers), got 3``) instead of surfacing a numpy error.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from l3gs_opt.checks import brief as _brief
from l3gs_opt.checks import is_real
from l3gs_opt.errors import InstanceError, os_error_reason
from l3gs_opt.input_files import key_name, load_npz, npz_text, parse_json, read_json
from l3gs_opt.problem.instance import SCHEMA, Instance, Options

__all__ = ["MAX_JSON_BYTES", "MAX_NPZ_BYTES", "instance_from_dict", "instance_from_raw", "load_instance",
           "save_instance", "nested_array", "npz_fields", "read_raw_problem", "read_problem_file",
           "write_problem_file"]

#: Largest JSON instance file read or written (bytes), either form. Decoding JSON takes ~5-12x the
#: file in Python objects; larger instances belong in NPZ.
MAX_JSON_BYTES = 64 * 2**20
#: Largest total of an NPZ instance's arrays (bytes, uncompressed), checked against the zip directory
#: and the ``.npy`` headers before anything is decompressed: 2^27 float64 utilities, far above
#: what any solver here handles.
MAX_NPZ_BYTES = 2**30

_KEYS = ("schema", "representation", "bandwidth", "slot_s", "cost", "utility", "held", "options", "names",
         "meta")
_REQUIRED = ("schema", "representation", "bandwidth", "cost", "utility")
#: Floats at or above this magnitude are refused where an integer is expected (see nested_array).
_MAX_EXACT_FLOAT = 2.0**53
_DIMS = {"bandwidth": ("slots",), "cost": ("objects", "layers"), "utility": ("slots", "objects", "layers"),
         "held": ("objects", "layers")}


def nested_array(value: Any, name: str, dims: tuple[str, ...], *, integer: bool,
                 error: type[InstanceError] = InstanceError, pairs: bool = False) -> np.ndarray:
    """Nested JSON lists -> array, checking every entry's type and every list's length.

    ``dims`` names the axes (for messages); ``pairs``: the second axis holds exactly two entries
    (edge lists). Errors are ``error(name, message, index)``, so both instance forms share one parser.

    ``integer``: the array is int64 and exact. A float entry is accepted when it is a whole number
    below 2**53 in magnitude (above it a float may stand for a rounded integer: 2**53 + 1 written
    ``9007199254740993.0`` reads as 2**53); integers up to 2**63 - 1 are kept exact whatever else
    the list holds. A fractional or non-finite float makes the array float64, so that the caller
    names it with its own rule (fractional bytes, 0/1, an item index). Otherwise the array is
    float64 and an integer beyond 1e308 is refused.

    A numpy int or float scalar counts as the number it holds (a dict built from numpy arrays
    holds them; JSON never does), a numpy bool does not; a numpy array anywhere in the nesting
    counts as the lists it holds (``arr.tolist()``), checked entry by entry as they are. A list
    where a number belongs is refused at once: the lists nest exactly ``len(dims)`` deep.

    The lists are walked once to check them; the array is then built by numpy from the lists
    themselves (no flat copy of the entries).
    """
    shape: list[int | None] = [None] * len(dims)
    first_at: list[tuple[int, ...]] = [()] * len(dims)   # the list that set each length
    last = len(dims) - 1
    found = {"float": False, "fraction": False}

    def check_list(v: Any, depth: int, idx: tuple[int, ...]) -> None:
        if not isinstance(v, list):
            raise error(name, f"must be a list over {dims[depth]}, got {type(v).__name__}", idx)
        if pairs and depth == 1 and len(v) != 2:
            raise error(name, f"must be a [parent, child] pair, got {len(v)} entries", idx)
        if shape[depth] is None:
            shape[depth], first_at[depth] = len(v), idx
        elif len(v) != shape[depth]:
            # The first list of a level sets its length; naming it shows which of the two is short
            # when that first one is the odd one out.
            where = "".join(f"[{i}]" for i in first_at[depth])
            raise error(name, f"expected {shape[depth]} entries ({dims[depth]}), got {len(v)} "
                              f"({name}{where} has {shape[depth]})", idx)

    def leaf(v: Any, idx: tuple[int, ...]) -> None:
        if isinstance(v, list):
            raise error(name, f"= {_brief(v)}: must be a number, not a list ({name} nests {len(dims)} "
                              f"level{'s' if len(dims) > 1 else ''} of lists: {', '.join(dims)})", idx)
        if is_real(v) and isinstance(v, np.generic):
            v = v.item()   # np.int64(3) -> 3; an np.longdouble stays one and is refused below
        if type(v) is bool or not isinstance(v, (int, float)):
            raise error(name, f"= {_brief(v)}: must be a number", idx)
        if isinstance(v, int):
            if integer and abs(v) > 2**63 - 1:
                raise error(name, f"= {_brief(v)}: out of range", idx)
            if not integer and abs(v) > 1e308:
                raise error(name, f"= {_brief(v)}: must be finite", idx)
        elif integer:
            found["float"] = True
            if not (math.isfinite(v) and v.is_integer()):
                found["fraction"] = True
            elif abs(v) >= _MAX_EXACT_FLOAT:
                raise error(name, f"= {_brief(v)}: a whole number written as a float must be below 2**53 "
                                  "(above it the float may be rounded); write it as an integer", idx)

    def walk(v: Any, depth: int, idx: tuple[int, ...]) -> None:
        if isinstance(v, np.ndarray):
            v = v.tolist()   # a 0-d array becomes its scalar, refused below as "not a list"
        check_list(v, depth, idx)
        if depth < last:
            for i, item in enumerate(v):
                walk(item, depth + 1, idx + (i,))
            return
        for i, item in enumerate(v):
            if type(item) is not float or integer:   # a plain float needs no check for a float array
                leaf(item, idx + (i,))

    if isinstance(value, np.ndarray):
        value = value.tolist()   # the array is then built from these lists, as from JSON's
    walk(value, 0, ())
    full = tuple(0 if s is None else s for s in shape)
    dtype = np.int64 if integer and not found["fraction"] else np.float64
    return np.array(value, dtype=dtype).reshape(full)


def _nested(value: Any, name: str, *, integer: bool) -> np.ndarray:
    return nested_array(value, name, _DIMS[name], integer=integer)


def check_head(data: Mapping[str, Any], keys: tuple[str, ...], required: tuple[str, ...], schema: str, *,
               error: type[InstanceError] = InstanceError) -> None:
    """No unknown key (a typo must not drop data), every required key, the expected ``schema``, and no
    ``null``: an optional key is either left out (its default) or given a value of its type."""
    for key in data:
        if key not in keys:
            raise error(key_name(key), f"unknown key (known: {', '.join(keys)})")
    for key in required:
        if key not in data:
            raise error(key, "missing")
    if data["schema"] != schema:
        raise error("schema", f"{_brief(data['schema'])}: expected {schema!r}")
    for key, value in data.items():
        if value is None:
            raise error(key, "is null: leave the key out for its default")


def instance_from_dict(data: Any) -> Instance:
    """Validate a decoded ``l3gs-opt/instance@1`` JSON object and build the instance.

    Raises
    ------
    InstanceError
        Unknown or missing keys, a wrong schema, wrong shapes, NaN/inf, negative numbers,
        fractional bytes, a held set that is not a prefix (layered), ``null`` for an optional key,
        a ``meta`` that is not an object.
    """
    if not isinstance(data, Mapping):
        raise InstanceError("instance", "must be a JSON object")
    check_head(data, _KEYS, _REQUIRED, SCHEMA)
    if not isinstance(data["representation"], str):
        raise InstanceError("representation", "must be a string")
    arrays = {key: _nested(data[key], key, integer=key != "utility") for key in _DIMS if key in data}
    return _build({**data, **arrays})


def _build(fields: Mapping[str, Any]) -> Instance:
    """The instance from checked fields (arrays for the keys of ``_DIMS``); absent keys take their
    defaults, present ones are validated by :class:`Instance` (``meta: false`` is not ``{}``)."""
    return Instance(representation=fields["representation"], bandwidth=fields["bandwidth"], cost=fields["cost"],
                    utility=fields["utility"], held=fields.get("held"), slot_s=fields.get("slot_s", 1.0),
                    options=Options.from_dict(fields.get("options")), names=fields.get("names"),
                    meta=fields.get("meta"))


def npz_fields(npz: Mapping[str, np.ndarray], keys: tuple[str, ...], dims: Mapping[str, Any], *,
               error: type[InstanceError] = InstanceError) -> dict[str, Any]:
    """NPZ entries carry the JSON names: arrays for the keys in ``dims`` (numeric), the rest as
    JSON text in 0-d string arrays, decoded as strictly as a JSON file. Unknown keys are an error."""
    out: dict[str, Any] = {}
    for key in npz:
        if key not in keys:
            raise error(key_name(key), f"unknown key (known: {', '.join(keys)})")
        arr = npz[key]
        if key in dims:
            if arr.size and arr.dtype.kind not in "biuf":
                raise error(key, f"must be numeric, got dtype {arr.dtype}")
            out[key] = arr
        else:
            if arr.ndim != 0 or arr.dtype.kind != "U":
                raise error(key, "must be stored as JSON text in a 0-d string array")
            out[key] = parse_json(npz_text(arr, error, field=key), error, field=key)
    return out


def read_raw_problem(path: str | os.PathLike[str], *,
                     error: type[InstanceError] = InstanceError) -> tuple[bool, Any]:
    """A ``.json`` or ``.npz`` problem file as read, within limits: ``(True, {name: array})`` for
    NPZ, ``(False, decoded JSON)`` otherwise.

    Only a regular file is opened (a FIFO or a device is refused before it can block); a JSON file
    may hold at most :data:`MAX_JSON_BYTES` bytes and is decoded strictly (no duplicate keys, no
    NaN/Infinity, nesting at most 64 deep); the members of an NPZ file may claim at most
    :data:`MAX_NPZ_BYTES` bytes uncompressed, checked before anything is decompressed. Every fault
    is ``error("file", ...)`` (a duplicate key names the key).
    """
    path = Path(path)
    if path.suffix.lower() == ".npz":
        return True, load_npz(path, error, max_bytes=MAX_NPZ_BYTES)
    return False, read_json(path, error, max_bytes=MAX_JSON_BYTES)


def read_problem_file(path: str | os.PathLike[str], keys: tuple[str, ...], dims: Mapping[str, Any], *,
                      error: type[InstanceError] = InstanceError) -> tuple[bool, Any]:
    """Read a ``.json`` or ``.npz`` problem file (:func:`read_raw_problem`): ``(True, fields)`` for
    NPZ (:func:`npz_fields`), ``(False, decoded JSON)`` otherwise."""
    is_npz, raw = read_raw_problem(path, error=error)
    return is_npz, (npz_fields(raw, keys, dims, error=error) if is_npz else raw)


def instance_from_raw(is_npz: bool, raw: Any) -> Instance:
    """The instance from :func:`read_raw_problem`'s answer."""
    if not is_npz:
        return instance_from_dict(raw)
    fields = npz_fields(raw, _KEYS, _DIMS)
    check_head(fields, _KEYS, _REQUIRED, SCHEMA)
    return _build(fields)


def load_instance(path: str | os.PathLike[str]) -> Instance:
    """Load an instance from ``.json`` or ``.npz``; every fault is an :class:`InstanceError`."""
    return instance_from_raw(*read_raw_problem(path))


def write_problem_file(path: str | os.PathLike[str], data: Mapping[str, Any], arrays: Mapping[str, Any], *,
                       error: type[InstanceError] = InstanceError) -> Path:
    """Write a problem as ``.json`` (``data``, the JSON object) or ``.npz`` (``arrays`` for its
    array keys, the other keys of ``data`` as JSON text), chosen by the suffix.

    A file the readers would refuse (over :data:`MAX_JSON_BYTES` / :data:`MAX_NPZ_BYTES`) is not
    written; a folder or an unwritable place is ``error("file", ...)``.
    """
    path = Path(path)
    if path.is_dir():
        raise error("file", f"{path}: is a folder, expected a file name (.json or .npz)")
    try:
        if path.suffix.lower() == ".npz":
            out = {key: np.asarray(arrays[key]) if key in arrays else np.array(json.dumps(value))
                   for key, value in data.items()}
            size = sum(arr.nbytes for arr in out.values())
            if size > MAX_NPZ_BYTES:
                raise error("file", f"{path}: {size:,} bytes of arrays, more than the readers' limit of "
                                    f"{MAX_NPZ_BYTES:,}")
            path.parent.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(path, **out)
        else:
            text = json.dumps(data, allow_nan=False) + "\n"
            if len(text) > MAX_JSON_BYTES:
                raise error("file", f"{path}: {len(text):,} bytes of JSON, more than the readers' limit of "
                                    f"{MAX_JSON_BYTES:,}: write .npz")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise error("file", f"{path}: cannot be written ({os_error_reason(exc)})") from None
    return path


def save_instance(instance: Instance, path: str | os.PathLike[str]) -> Path:
    """Write ``.json`` (small instances) or ``.npz`` (large), chosen by the suffix (see
    :func:`write_problem_file`)."""
    data = instance.to_dict()
    return write_problem_file(path, data, {key: getattr(instance, key) for key in _DIMS if key in data})
