"""The clock every exact search keeps: seconds since it started and left to its deadline (which a
stop request, :mod:`l3gs_opt.stop`, brings forward to now)."""

from __future__ import annotations

import time

from l3gs_opt import stop

__all__ = ["Clock"]


class Clock:
    """Mixin over ``started`` and ``deadline`` (``time.perf_counter()`` seconds; ``deadline``
    None: no limit)."""

    started: float
    deadline: float | None

    def now(self) -> float:
        """Seconds since the start."""
        return time.perf_counter() - self.started

    def left(self) -> float | None:
        """Seconds to the deadline (None without a limit); 0 once a stop is requested
        (:mod:`l3gs_opt.stop`), so every phase started after it gets no time."""
        if stop.requested():
            return 0.0
        return None if self.deadline is None else self.deadline - time.perf_counter()

    def out_of_time(self) -> bool:
        """The deadline passed, or a stop was requested."""
        return stop.expired(self.deadline)
