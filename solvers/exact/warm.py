"""``warm_up``: compile (or load) every kernel of ``exact`` now (:mod:`.kernels`)."""

from __future__ import annotations

import time

from . import anneal, pricing  # noqa: F401 - importing them registers their kernels
from .kernels import KERNELS, ready

__all__ = ["warm_up"]


def warm_up(names: tuple[str, ...] | None = None) -> dict[str, float]:
    """Compile (or load from numba's disk cache) the named kernels (default: all), now; the
    seconds each took. ~9 s on a machine's first call here, ~0.3 s after."""
    took = {}
    for name in names or tuple(KERNELS):
        began = time.perf_counter()
        ready(name, None)
        took[name] = time.perf_counter() - began
    return took
