"""One strict JSON serialiser for everything l3gs-opt prints or records as JSON.

Every ``--json`` output (``solve``, ``predict``, ``simulate``) and every record line (``bench``,
``compare``, ``simulate``, ``experiments``, the demo) goes through :func:`dumps`, so that what a
command prints is always JSON that any parser reads back:

* numpy scalars become Python ones (``np.bool_`` -> ``bool``, ``np.int64`` -> ``int``, ``np.float32``
  -> ``float``), numpy arrays and tuples become lists, an ``Enum`` its value, a path its text;
* mapping keys must be strings or integers (integers are written as their text, as :mod:`json` does);
* any other type (a set, an object) is refused with :class:`JsonOutputError` naming where it sits
  (``details.cuts[2]``) -- unless the caller passes ``other`` (e.g. ``str``) to convert it;
* the text is written with ``allow_nan=False``: ``NaN``, ``Infinity`` and ``-Infinity`` never appear.

**Non-finite numbers are written as** ``null``. ``null`` where a number is expected means *there is
no finite value*: undefined (NaN, e.g. a mean over no samples) or unbounded (an infinite bound or
error). Readers that need to tell these apart must not rely on the JSON text; with
``nonfinite="error"`` the serialiser raises :class:`JsonOutputError` instead, naming the value's
place (``result.mae_mbps = nan``).

Example
-------
>>> import numpy as np
>>> dumps({"ok": np.bool_(True), "n": np.int64(3), "x": np.array([1.5, np.inf])})
'{"ok": true, "n": 3, "x": [1.5, null]}'
"""

from __future__ import annotations

import enum
import json
import math
import os
from collections.abc import Mapping
from typing import Any, Callable

import numpy as np

from l3gs_opt.errors import L3gsError

__all__ = ["OutputError", "JsonOutputError", "to_jsonable", "dumps"]


class OutputError(L3gsError, ValueError):
    """An output or record file cannot be written or read back as promised.

    Attributes
    ----------
    field : str
        What is at fault: a value's place in the output (``details.x[2]``), a file, or an option.
    index : int or None
        The entry inside it (a line number of a record file, 1-based), when one is at fault.
    """

    def __init__(self, field: str, message: str, index: int | None = None):
        self.field = field
        self.index = index
        sep = " " if message.startswith("= ") else ": "   # "--seeds = -1: ...", as InstanceError
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}{sep}{message}")


class JsonOutputError(OutputError):
    """A value has no strict JSON form (an unsupported type, or a non-finite number with
    ``nonfinite="error"``)."""


def _path(parent: str, key: Any) -> str:
    return f"{parent}[{key}]" if isinstance(key, int) else (f"{parent}.{key}" if parent else str(key))


def to_jsonable(value: Any, *, nonfinite: str = "null", other: Callable[[Any], Any] | None = None,
                where: str = "value") -> Any:
    """``value`` as plain JSON data (dict, list, str, int, float, bool, None), following the rules
    of this module.

    Parameters
    ----------
    value : any
        Nested mappings, lists, tuples, numpy arrays and scalars, Python scalars, enums, paths.
    nonfinite : {"null", "error"}
        What a NaN or infinite float becomes: ``None`` (see the module docstring for its meaning),
        or :class:`JsonOutputError`.
    other : callable, optional
        Converts a value of any other type (e.g. ``str``); by default such a value is an error.
    where : str
        The name of ``value`` in error messages.

    Raises
    ------
    JsonOutputError
        An unsupported type or mapping key, or a non-finite number with ``nonfinite="error"``.
    """
    if nonfinite not in ("null", "error"):
        raise ValueError(f"nonfinite = {nonfinite!r}: must be 'null' or 'error'")
    return _convert(value, nonfinite, other, where)


def _convert(value: Any, nonfinite: str, other: Callable[[Any], Any] | None, where: str) -> Any:
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if math.isfinite(value):
            return float(value)
        if nonfinite == "error":
            raise JsonOutputError(where, f"= {float(value)}: not a finite number, which JSON cannot hold")
        return None
    if isinstance(value, enum.Enum):
        return _convert(value.value, nonfinite, other, where)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, Mapping):
        out = {}
        for key, item in value.items():
            if isinstance(key, (bool, np.bool_)) or not isinstance(key, (str, int, np.integer)):
                raise JsonOutputError(where, f"key {key!r} of type {type(key).__name__}: keys must be text "
                                             "or integers")
            key = key if isinstance(key, str) else str(int(key))
            out[key] = _convert(item, nonfinite, other, _path(where, key))
        return out
    if isinstance(value, np.ndarray):
        value = value.tolist() if value.ndim else value.item()
        return _convert(value, nonfinite, other, where)
    if isinstance(value, (list, tuple)):
        return [_convert(item, nonfinite, other, _path(where, i)) for i, item in enumerate(value)]
    if isinstance(value, np.generic):   # np.str_ and the like
        return _convert(value.item(), nonfinite, other, where)
    if other is not None:
        return _convert(other(value), nonfinite, None, where)
    raise JsonOutputError(where, f"a value of type {type(value).__name__} has no JSON form")


def dumps(value: Any, *, nonfinite: str = "null", other: Callable[[Any], Any] | None = None,
          where: str = "value", indent: int | None = None, sort_keys: bool = False) -> str:
    """``value`` as strict JSON text (one line unless ``indent``); see :func:`to_jsonable`.

    Raises
    ------
    JsonOutputError
        A value without a JSON form (see :func:`to_jsonable`).
    """
    data = to_jsonable(value, nonfinite=nonfinite, other=other, where=where)
    return json.dumps(data, allow_nan=False, indent=indent, sort_keys=sort_keys)
