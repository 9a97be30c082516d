"""The arguments every solve takes, checked one way for every method and both instance forms.

``check_time_limit``, ``check_slot``, ``check_options`` and ``check_instance`` sit at the bottom
layer so that the solvers, the models, the evaluators and :func:`l3gs_opt.methods.solve` all call
the same check (the slot was once checked four ways that disagreed on numpy integers).
"""

from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from l3gs_opt.checks import as_float, brief
from l3gs_opt.errors import SolveError

__all__ = ["check_time_limit", "check_slot", "check_options", "check_instance"]


def check_time_limit(value: Any, *, name: str = "time_limit_s") -> float | None:
    """``time_limit_s`` as every method takes it: ``None`` (no limit) or a float > 0 seconds.

    ``inf`` (``--time-limit inf``) means "no limit" and is returned as ``None``, so that every
    method and backend runs exactly as it does without a limit. So is an integer beyond float's
    range (``10**400``): it rounds to ``inf`` as ``float("1e400")`` does, and no run can reach it.
    ``name`` is the argument named in the message (the CLI says ``--time-limit``).

    Raises
    ------
    SolveError
        Not a number (a bool or a string included), NaN, zero or negative.
    """
    if value is None:
        return None
    shown = value.item() if isinstance(value, np.generic) else value
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise SolveError(f"{name} = {shown!r}: must be a number of seconds > 0 (or inf for no limit)")
    seconds = as_float(value)   # an int beyond 1.8e308 s is inf: longer than any run
    if math.isnan(seconds) or seconds <= 0:
        raise SolveError(f"{name} = {shown!r}: must be > 0 seconds (or inf for no limit)")
    return None if math.isinf(seconds) else seconds


def check_slot(value: Any, T: int, *, name: str = "slot") -> int | None:
    """``slot`` as every method takes it: ``None`` or a Python ``int`` in ``0..T-1``; a numpy
    integer is accepted and converted, a bool or a float (even ``1.0``) is not.

    Raises
    ------
    SolveError
        Not an integer, or out of range.
    """
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 0 <= value < T:
        shown = value.item() if isinstance(value, np.generic) else value
        raise SolveError(f"{name} = {shown!r}: must be an integer in 0..{T - 1}")
    return int(value)


def check_options(value: Any, *, name: str = "options") -> dict[str, Any]:
    """``options`` (backend-specific settings) as every method takes it: ``None`` (none) or a
    mapping from option names (``str``) to values, returned as a new ``dict``. Whether a backend
    knows a name, and takes its value, is the backend's to say.

    Raises
    ------
    SolveError
        Not a mapping (a list of pairs or a string included), or a key that is not a string.
    """
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise SolveError(f"{name} = {brief(value)}: must be a mapping of option names (str) to values, "
                         f"got {type(value).__name__}")
    for key in value:
        if not isinstance(key, str):
            raise SolveError(f"{name}: key {brief(key)} must be an option name (str), got {type(key).__name__}")
    return dict(value)


def check_instance(value: Any, *kinds: type, name: str = "instance") -> None:
    """``value`` must be one of the instance classes ``kinds`` (passed in, so that this module
    imports no instance form); anything else would fail later as a raw ``AttributeError``.

    Raises
    ------
    SolveError
        Naming the type given and the types accepted.
    """
    if not isinstance(value, kinds):
        accepted = " or ".join(k.__name__ for k in kinds)
        raise SolveError(f"{name} must be an {accepted}, got {type(value).__name__}")
