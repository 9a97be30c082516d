"""The arguments every solve takes, checked one way for every method and both instance forms.

``check_time_limit`` and ``check_slot`` sit at the bottom layer so that the solvers, the models and
:func:`l3gs_opt.methods.solve` all call the same check (the slot was once checked four ways that
disagreed on numpy integers).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from l3gs_opt.errors import SolveError

__all__ = ["check_time_limit", "check_slot"]


def check_time_limit(value: Any, *, name: str = "time_limit_s") -> float | None:
    """``time_limit_s`` as every method takes it: ``None`` (no limit) or a float > 0 seconds.

    ``inf`` (``--time-limit inf``) means "no limit" and is returned as ``None``, so that every
    method and backend runs exactly as it does without a limit. ``name`` is the argument named in
    the message (the CLI says ``--time-limit``).

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
    seconds = float(value)
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
