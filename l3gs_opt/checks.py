"""Checks of single arguments that every layer shares: counts, seeds, finite numbers, file paths and
arrays of real numbers, each raising the caller's own error class with one wording.

A layer-0 module (it imports only :mod:`l3gs_opt.errors`), so that the traces, the scene, the
pipeline and the simulator call the same checks: the traces could not import the pipeline's count
check or the scene's seed check, and grew twins of them.

An ``error`` argument is a callable ``(field, message) -> Exception``: an error class with that
signature (``InstanceError``, ``SceneError``, ``SimulationError``), or :func:`field_error` of a class
that takes one message (``TraceError``). A message that starts with ``"= "`` reads
``field = value: ...``, any other ``field: ...``.
"""

from __future__ import annotations

import math
import os
import reprlib
from pathlib import Path
from typing import Callable

import numpy as np

from l3gs_opt.errors import L3gsError

__all__ = ["ArgumentError", "ErrorFactory", "field_error", "shown", "brief", "is_real", "as_float", "check_count", "check_seed",
           "check_number", "check_path", "real_array"]

#: ``(field, message) -> Exception``: how a check raises the caller's error.
ErrorFactory = Callable[[str, str], Exception]


class ArgumentError(L3gsError, ValueError):
    """An argument out of its range, when the caller names no error class of its own."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(_joined(field, message))


def _joined(field: str, message: str) -> str:
    return f"{field} {message}" if message.startswith("= ") else f"{field}: {message}"


def field_error(cls: Callable[[str], Exception]) -> ErrorFactory:
    """The ``error`` argument for an error class that takes one message."""
    return lambda field, message: cls(_joined(field, message))


def shown(value: object) -> str:
    """``repr(value)`` on one line, cut to 60 characters (a huge list or int in a message helps no one)."""
    try:
        text = " ".join(repr(value).split())   # an array's repr spans lines
    except ValueError:   # an int of more than 4300 digits
        text = f"<{type(value).__name__} too long to show>"
    return text if len(text) <= 60 else text[:57] + "..."


#: A container's repr for messages: a few levels and entries, never the whole (a list nested
#: 100,000 deep would exhaust ``repr``'s recursion, a list of 10^6 numbers fill the message).
_SHORT_REPR = reprlib.Repr()
_SHORT_REPR.maxlevel, _SHORT_REPR.maxlist, _SHORT_REPR.maxtuple, _SHORT_REPR.maxdict = 3, 4, 4, 2


def brief(value: object) -> str:
    """Any value, as given, for a message: at most 24 characters and never an exception
    (:data:`_SHORT_REPR` for containers; :func:`shown` for an int of 5,000 digits)."""
    if isinstance(value, (list, tuple, dict, set, frozenset)):
        try:
            text = _SHORT_REPR.repr(value)
        except ValueError:   # an int of more than 4300 digits inside
            text = f"<{type(value).__name__}>"
    else:
        text = shown(value)
    return text if len(text) <= 24 else text[:21] + "..."


def as_float(value: object) -> float:
    """A real number as a float; an int beyond float's range (``10**400``) as ``inf`` or ``-inf``,
    where ``float()`` raises OverflowError (``float("1e400")`` is inf too)."""
    try:
        return float(value)
    except OverflowError:
        return math.inf if value > 0 else -math.inf


def is_real(value: object) -> bool:
    """A real number type: Python or numpy int or float, never a bool (True is not 1 Mbit/s)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def check_count(field: str, value: object, *, high: int, low: int = 1,
                error: ErrorFactory = ArgumentError) -> int:
    """``value`` as an int if it is an integer (not a bool) in ``[low, high]``, else
    ``error(field, "0: must be an integer in [1, 1000]")``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not low <= value <= high:
        raise error(field, f"{shown(value)}: must be an integer in [{low}, {high}]")
    return int(value)


def check_seed(seed: object, *, field: str = "seed", error: ErrorFactory = ArgumentError) -> int:
    """``seed`` as an int if it is a whole number >= 0 (what :func:`numpy.random.default_rng`
    takes), else ``error(field, "= -1: must be an integer >= 0")``: refused by name rather than deep
    inside numpy."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise error(field, f"= {shown(seed)}: must be an integer >= 0")
    return int(seed)


def check_number(field: str, value: object, ok: Callable[[float], bool], want: str,
                 error: ErrorFactory = ArgumentError) -> float:
    """``value`` as a float if it is a finite real number (not a bool or a string) and ``ok(value)``,
    else ``error(field, "= value: must be WANT")``."""
    number = as_float(value) if is_real(value) else math.nan
    if not (math.isfinite(number) and ok(number)):
        raise error(field, f"= {shown(value)}: must be {want}")
    return number


def check_path(path: object, *, field: str = "path", error: ErrorFactory = ArgumentError) -> Path:
    """``Path(path)`` if ``path`` is a str or an ``os.PathLike`` of one (not pathlib's TypeError)."""
    if isinstance(path, str) or (isinstance(path, os.PathLike) and isinstance(os.fspath(path), str)):
        return Path(path)
    raise error(field, f"= {shown(path)}: must be a file path (str or os.PathLike), got {type(path).__name__}")


def real_array(field: str, value: object, error: ErrorFactory = ArgumentError) -> np.ndarray:
    """``value`` as an array of real numbers: a float array as it is, anything else converted to
    float64. Bools, strings, complex numbers, objects and ragged lists are refused by name (numpy
    would parse ``'5'``, take True as 1, or fail with its own TypeError or ValueError)."""
    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
        return value
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):   # ragged nesting
        raise error(field, f"= {shown(value)}: must be an array of numbers (rows of equal length)") from None
    if array.dtype.kind not in "iuf":
        kinds = {"b": "bools", "U": "strings", "S": "bytes", "c": "complex numbers"}
        got = kinds.get(array.dtype.kind, type(value).__name__ if array.ndim == 0 else f"dtype {array.dtype}")
        raise error(field, f"= {shown(value)}: must be an array of numbers, got {got}")
    return array.astype(np.float64)
