"""The clock every exact search keeps: seconds since it started and left to its deadline."""

from __future__ import annotations

import time

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
        """Seconds to the deadline (None without a limit)."""
        return None if self.deadline is None else self.deadline - time.perf_counter()

    def out_of_time(self) -> bool:
        return self.deadline is not None and time.perf_counter() >= self.deadline
