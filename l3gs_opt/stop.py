"""A stop request: the first Ctrl-C of a long solve ends it with the best answer found so far.

A solver that runs for minutes (``exact`` with a long time limit, a MILP backend) has a schedule
and a valid bound long before it ends. Inside :func:`on_interrupt` the first SIGINT does not raise
:class:`KeyboardInterrupt`; it sets a process-wide flag that every time limit also obeys: the exact
searches' clocks (:mod:`l3gs_opt.solvers.exact.clock`) read as out of time, HiGHS stops inside its
loops (the wall-clock callback of :mod:`l3gs_opt.models.backends.highs`) and CP-SAT through its
``stop_search`` (:func:`stoppable`). The method then finishes as it does at its time limit: status
``time_limit``, its best schedule and a valid bound, and a message that says it was stopped on
request. A second Ctrl-C raises :class:`KeyboardInterrupt` as usual.

CBC, which PuLP runs as a child process, does not see a request made in Python: its adapter sends
it SIGINT (:func:`child_processes`, Linux only), again every ``CBC_RESEND_S``
(``models/backends/cbc.py``) until it ends, since CBC acts on one only in its tree search. It then
stops as at its time limit: its best integer schedule, if it found one, and its bound. In a
terminal the Ctrl-C also reaches it directly. SCIP (an optional backend) is not watched. The compiled knapsack searches end at their own (short) limits.

A process that forks in a loop (the local executor) would lose some Ctrl-Cs: Python drops an
exception raised inside a fork hook (:func:`os.register_at_fork`; :mod:`logging` registers some),
so a SIGINT that lands during a fork raises its KeyboardInterrupt where nobody sees it.
:func:`noted_interrupts` keeps a note of it for the loop to raise again.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator, TypeVar

__all__ = ["child_processes", "requested", "request", "clear", "expired", "on_interrupt", "noted_interrupts",
           "stoppable", "STOPPED_NOTE"]

#: What a method stopped on request says (appended to its message).
STOPPED_NOTE = "stopped on request (Ctrl-C) before its time limit: the best schedule so far and a valid bound"

_flag = threading.Event()
T = TypeVar("T")


def requested() -> bool:
    """Whether a stop was requested (inside :func:`on_interrupt`)."""
    return _flag.is_set()


def request() -> None:
    """Ask every running solve to stop at its next check (what the first Ctrl-C does; e.g. from
    another thread). The request holds, for later solves too, until :func:`clear`."""
    _flag.set()


def expired(deadline: float | None) -> bool:
    """Whether ``deadline`` (``time.perf_counter()`` seconds; None: none) has passed, or a stop
    was requested: the test of every loop that runs to a deadline."""
    return _flag.is_set() or (deadline is not None and time.perf_counter() > deadline)


def clear() -> None:
    """Withdraw a stop request (:func:`on_interrupt` does on entry and on exit)."""
    _flag.clear()


@contextmanager
def on_interrupt(notice: str | None = None) -> Iterator[None]:
    """Within the block, the first SIGINT requests a stop (printing ``notice`` on stderr); the
    second raises :class:`KeyboardInterrupt`. The flag is cleared on entry and on exit, and the
    previous handler restored. Outside the main thread (where Python allows no signal handler)
    the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        if _flag.is_set():
            raise KeyboardInterrupt
        _flag.set()
        if notice:
            print(notice, file=sys.stderr, flush=True)

    _flag.clear()
    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _flag.clear()


@contextmanager
def noted_interrupts() -> Iterator[Callable[[], None]]:
    """Within the block, SIGINT is handled as before, and a KeyboardInterrupt its handler raises is
    also noted; the block gets a ``check()`` that raises KeyboardInterrupt again if one was noted
    (once). A loop that forks calls it after each fork, where Python may have dropped the first
    (see the module doc). A handler that does not raise (:func:`on_interrupt`'s first Ctrl-C) is
    left alone. Outside the main thread, or with SIGINT ignored or left to the system, ``check``
    does nothing."""
    noted = threading.Event()

    def check() -> None:
        if noted.is_set():
            noted.clear()
            raise KeyboardInterrupt

    previous = signal.getsignal(signal.SIGINT) if threading.current_thread() is threading.main_thread() else None
    if not callable(previous):
        yield check
        return

    def handler(signum: int, frame: object) -> None:
        try:
            previous(signum, frame)
        except KeyboardInterrupt:
            noted.set()
            raise

    signal.signal(signal.SIGINT, handler)
    try:
        yield check
    finally:
        signal.signal(signal.SIGINT, previous)


def stoppable(run: Callable[[], T], halt: Callable[[], None], poll_s: float = 0.05) -> T:
    """``run()``, in a worker thread while this one waits, calling ``halt()`` once if a stop is
    requested meanwhile (e.g. CP-SAT's ``stop_search``). A call into C that runs no Python code
    would otherwise hold off the very signal handler that makes the request until it returns:
    Python runs handlers in the main thread only, between its own instructions. ``run``'s
    exception, if any, is raised here; a second Ctrl-C raises here too."""
    out: dict[str, object] = {}

    def work() -> None:
        try:
            out["value"] = run()
        except BaseException as exc:   # handed to the waiting thread
            out["error"] = exc

    thread = threading.Thread(target=work, name="l3gs-stoppable", daemon=True)
    thread.start()
    halted = False
    while thread.is_alive():
        thread.join(poll_s)
        if not halted and _flag.is_set():
            halt()
            halted = True
    if "error" in out:
        raise out["error"]  # type: ignore[misc]
    return out["value"]  # type: ignore[return-value]


def child_processes(name: str) -> list[int]:
    """Process ids of this process's children whose command name is ``name`` (Linux ``/proc``;
    an empty list where there is none)."""
    me = os.getpid()
    pids: list[int] = []
    try:
        for task in os.listdir(f"/proc/{me}/task"):
            with open(f"/proc/{me}/task/{task}/children", encoding="ascii") as fh:
                pids += [int(p) for p in fh.read().split()]
    except OSError:
        return []
    out = []
    for pid in pids:
        try:
            with open(f"/proc/{pid}/comm", encoding="utf-8") as fh:
                if fh.read().strip() == name:
                    out.append(pid)
        except OSError:
            continue
    return out
