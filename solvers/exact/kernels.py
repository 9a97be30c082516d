"""``exact``'s compiled (numba) kernels: compiled once per machine, and never on a solve's clock.

numba caches a compiled kernel on disk, so only a machine's first use compiles it. That first use
is slow: on our 2-core box the pricing knapsack took 2.7 s and the annealing kernels 6.1 s, and a
fresh install's first ``exact`` under a 5 s limit ran 8.8 s and returned its start schedule with a
bound four times the optimum. So a solve under a time limit does not wait for a compile:

- :func:`prepare` starts compiling kernels in a background thread (loading them from numba's disk
  cache, ~0.2 s, when they are there);
- :func:`ready` says whether a kernel can be called now, or waits for it up to ``wait_s``; until
  it is ready the callers take their uncompiled path (the pricing knapsack falls back to ``bb``,
  the annealing waits within its own deadline and otherwise leaves the schedule as it is);
- :func:`.warm.warm_up` compiles every kernel now (``scripts/setup.sh`` and the bench and
  experiment runners call it before any timed solve).

A fork while a compile runs would leave the child with numba's compiler lock held and no thread
to release it: the fork waits for the compile to end (:func:`os.register_at_fork`). So does the
end of the process, so that a compile started by a short solve reaches the disk cache.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import threading
from typing import Callable

__all__ = ["KERNELS", "register", "prepare", "ready"]


#: Name -> a call that compiles (or loads) that kernel on a tiny input; each module that owns a
#: kernel registers it (:func:`register`), so this one imports none of them.
KERNELS: dict[str, Callable[[], None]] = {}


def register(name: str, warm: Callable[[], None]) -> None:
    """``warm()`` compiles kernel ``name`` (called once, in the compile thread)."""
    KERNELS[name] = warm


_lock = threading.Lock()
_done: dict[str, threading.Event] = {}
_running: list[threading.Thread] = []


def _compile(names: tuple[str, ...], events: list[threading.Event]) -> None:
    for name, event in zip(names, events):
        # A kernel that fails to compile fails again at its real call, where the caller sees it;
        # here it must not leave the later kernels' events unset (their waiters would hang).
        try:
            with contextlib.suppress(Exception):
                KERNELS[name]()
        finally:
            event.set()


def prepare(*names: str) -> None:
    """Start compiling (or loading) the named kernels, one after another in a daemon thread;
    those already started are left alone."""
    with _lock:
        todo = tuple(n for n in names if n not in _done)
        if not todo:
            return
        events = [threading.Event() for _ in todo]
        _done.update(zip(todo, events))
        thread = threading.Thread(target=_compile, args=(todo, events), name="l3gs-kernels", daemon=True)
        _running.append(thread)
        thread.start()


def ready(name: str, wait_s: float | None = 0.0) -> bool:
    """Whether kernel ``name`` can be called without compiling: started by :func:`prepare` if it
    was not, then waited for up to ``wait_s`` seconds (None: until it is)."""
    prepare(name)
    return _done[name].wait(None if wait_s is None else max(0.0, wait_s))


def _finish_compiles() -> None:
    for thread in list(_running):
        thread.join()
    _running.clear()


os.register_at_fork(before=_finish_compiles)
# A compile cut off by the end of the process is lost, and the next process starts it again: a
# machine's first short solve so waits for it at exit (once; seconds), and later ones load it.
atexit.register(_finish_compiles)
