"""The two sides of an exact search, run together: a MIP side (HiGHS in a second thread) beside a
price side (branch-and-price in this one), or either alone; whichever closes the gap first sets
``stop`` and the other returns."""

from __future__ import annotations

import sys
import threading
from typing import Callable, Optional

__all__ = ["SWITCH_INTERVAL_S", "run_sides"]

#: GIL switch interval (s) while both sides run: HiGHS's interrupt callbacks need the GIL, and at
#: Python's default 5 ms a busy pricing thread slowed a HiGHS MIP ten-fold (2,755 nodes in 1.7 s
#: alone, 257 in 6 s); at 0.1 ms it took 2.7 s.
SWITCH_INTERVAL_S = 1e-4


def run_sides(price: Optional[Callable[[], None]], mip: Optional[Callable[[], None]], stop: threading.Event, *,
              name: str) -> None:
    """Run ``mip`` in a thread named ``name`` beside ``price`` when both are given (highspy releases
    the GIL), else the one given. ``stop`` is set when the price side returns, so the MIP thread
    never outlives the call; the switch interval is restored."""
    if price is not None and mip is not None:
        old = sys.getswitchinterval()
        worker = threading.Thread(target=mip, name=name, daemon=True)
        sys.setswitchinterval(min(old, SWITCH_INTERVAL_S))
        worker.start()
        try:
            price()
        finally:
            stop.set()
            worker.join()
            sys.setswitchinterval(old)
    elif mip is not None:
        mip()
    elif price is not None:
        price()
