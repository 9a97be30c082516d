"""Pacing response bytes to a bandwidth trace: a token bucket per client session.

A session's bucket fills at the rate of the trace slot the session is in (slot ``i`` of the
trace covers ``[i * slot_s, (i + 1) * slot_s)`` seconds after the session's first request, at
``bytes_per_slot[i] / slot_s`` bytes per second; past the end the trace repeats, as mahimahi
replays its traces) and holds at most ``burst_bytes``. A writer reserves the bytes of a piece
before sending it and sleeps until the bucket is no longer in debt, so concurrent responses of one
session share its throughput and an idle session cannot save more than one burst.

Why a small burst: a client counts the bytes that arrive in each slot; whatever the bucket holds
at a slot boundary is sent at once and lands in the slot it was earned in, so the error per slot
is at most one burst. The default burst, 10 ms of the trace's fastest slot (1 % of a 1 s slot at
that rate) but at least 2 KiB, keeps that error small and the writes at most 100 per second (or
rate / 2 KiB below 200 kB/s).

Why pieces sized to the current slot: a piece is reserved whole and sent when the trace has
earned it, so the bytes sent by time t run up to one piece ahead of the trace, and a slot's count
is off by up to a piece. A burst-sized piece in a slot five times slower than the fastest is 5 %
of that slot's bytes; :meth:`SessionBucket.piece_bytes` (10 ms of the current slot's rate, between
:data:`MIN_PIECE_BYTES` and the burst) keeps it near 1 % at any rate, at up to 100 writes a second.

Nothing here touches host networking: pacing is done by the server delaying its writes.

Example
-------
>>> shaper = TraceShaper([1000, 0, 500], slot_s=1.0, burst_bytes=100)
>>> shaper.cumulative_bytes(1.5), shaper.cumulative_bytes(2.5)
(1000.0, 1250.0)
>>> shaper.time_for_bytes(1100.0)
2.2
"""

from __future__ import annotations

import asyncio
import bisect
import collections
import math
import os
import time
from typing import Callable, Hashable, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.traces.bandwidth import MAX_SLOT_BYTES

__all__ = ["ShapingError", "TraceShaper", "SessionBucket", "MIN_BURST_BYTES", "MIN_PIECE_BYTES", "BURST_S",
           "MAX_SESSIONS", "MAX_AGE_S",
           "trace_shaper"]

#: Smallest burst (bytes): two Ethernet frames' payload, so slow traces do not pay a write per few bytes.
MIN_BURST_BYTES = 2048
#: Smallest piece a paced response is written in (bytes): below 25.6 kB/s fewer than 100 writes a second.
MIN_PIECE_BYTES = 256
#: Default burst as time at the trace's fastest rate (seconds): 1 % of a 1 s slot.
BURST_S = 0.01
#: Largest session age a client may claim (seconds): its first request cannot come later than this
#: after its clock started.
MAX_AGE_S = 10.0
#: Sessions remembered at once; the least recently used is forgotten first (it restarts the trace).
MAX_SESSIONS = 4096


class ShapingError(L3gsError, ValueError):
    """A bad trace or option for shaping; names the field and the index."""

    def __init__(self, field: str, message: str, index: int | None = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


class TraceShaper:
    """Bytes per slot of a trace, and a :class:`SessionBucket` per client session.

    Parameters
    ----------
    bytes_per_slot : sequence of int, shape [T]
        Bytes the trace allows in each slot (>= 0, at least one > 0).
    slot_s : float
        Slot length, seconds.
    burst_bytes : int, optional
        Bucket size, bytes (default: ``max(MIN_BURST_BYTES, BURST_S x fastest rate)``).
    clock : callable, optional
        Monotonic seconds (default :func:`time.monotonic`; tests pass a fake one).

    Raises
    ------
    ShapingError
        A negative, fractional or too large byte count (naming the slot), an all-zero trace, a
        non-positive slot length or burst.
    """

    def __init__(self, bytes_per_slot: Sequence[int], *, slot_s: float = 1.0, burst_bytes: int | None = None,
                 clock: Callable[[], float] = time.monotonic):
        values = []
        for i, b in enumerate(bytes_per_slot):
            if isinstance(b, (bool, np.bool_)) or not isinstance(b, (int, np.integer, float, np.floating)) \
                    or not math.isfinite(b) or float(b) != int(b) or not 0 <= int(b) <= MAX_SLOT_BYTES:
                raise ShapingError("bytes_per_slot", f"{b!r}: must be a whole number of bytes in [0, 2^53]", i)
            values.append(int(b))
        if not values or max(values) == 0:
            raise ShapingError("bytes_per_slot", "needs at least one slot with bytes > 0 (else nothing is ever sent)")
        if isinstance(slot_s, bool) or not isinstance(slot_s, (int, float)) or not (math.isfinite(slot_s) and slot_s > 0):
            raise ShapingError("slot_s", f"{slot_s!r}: must be a positive number of seconds")
        self.bytes_per_slot = tuple(values)
        self.slot_s = float(slot_s)
        fastest = max(values) / self.slot_s
        if burst_bytes is None:
            burst_bytes = max(MIN_BURST_BYTES, int(BURST_S * fastest))
        if isinstance(burst_bytes, bool) or not isinstance(burst_bytes, (int, np.integer)) or burst_bytes < 1:
            raise ShapingError("burst_bytes", f"{burst_bytes!r}: must be a positive whole number of bytes")
        self.burst_bytes = int(burst_bytes)
        self.clock = clock
        self._cum = [0] + list(np.cumsum(values, dtype=object))   # exact ints: bytes before slot i
        self._sessions: collections.OrderedDict[Hashable, SessionBucket] = collections.OrderedDict()

    @property
    def period_bytes(self) -> int:
        """Bytes of one pass over the trace."""
        return self._cum[-1]

    def cumulative_bytes(self, t: float) -> float:
        """Bytes the trace allows in its first ``t`` seconds (the trace repeating), ``A(t)``."""
        if t <= 0:
            return 0.0
        T = len(self.bytes_per_slot)
        laps, rest = divmod(t / self.slot_s, T)
        i = min(int(rest), T - 1)
        frac = rest - i
        return float(laps * self.period_bytes + self._cum[i] + frac * self.bytes_per_slot[i])

    def time_for_bytes(self, amount: float) -> float:
        """The first time ``t`` (seconds) with ``A(t) >= amount``: the inverse of :meth:`cumulative_bytes`."""
        if amount <= 0:
            return 0.0
        T = len(self.bytes_per_slot)
        laps, rest = divmod(amount, self.period_bytes)
        if rest == 0:   # ends exactly on a lap: the first slot with bytes of that lap's end
            laps, rest = laps - 1, self.period_bytes
        # The slot in which the cumulative curve reaches `rest` (zero-byte slots are skipped).
        i = bisect.bisect_left(self._cum, rest) - 1
        i = max(0, min(i, T - 1))
        frac = (rest - self._cum[i]) / self.bytes_per_slot[i]
        return (laps * T + i + frac) * self.slot_s

    def session(self, key: Hashable, *, start_slot: int = 0, age_s: float = 0.0) -> "SessionBucket":
        """The bucket of session ``key``, created on first use: its trace clock at slot
        ``start_slot``, started ``age_s`` seconds ago (the client's clock started before its first
        request arrived: 0 <= ``age_s`` <= :data:`MAX_AGE_S`)."""
        bucket = self._sessions.get(key)
        if bucket is None:
            bucket = SessionBucket(self, start_slot=start_slot, age_s=age_s)
            self._sessions[key] = bucket
            while len(self._sessions) > MAX_SESSIONS:
                self._sessions.popitem(last=False)
        else:
            self._sessions.move_to_end(key)
        return bucket


class SessionBucket:
    """The token bucket of one session (see the module docstring).

    The bucket starts empty; its clock starts at its creation (less ``age_s``: when the client's
    own clock started), at the start of slot ``start_slot`` of the trace (a client resuming at slot
    t asks for it, so server and client agree on which slot is which).
    """

    def __init__(self, shaper: TraceShaper, *, start_slot: int = 0, age_s: float = 0.0):
        if isinstance(start_slot, bool) or not isinstance(start_slot, (int, np.integer)) or start_slot < 0:
            raise ShapingError("start_slot", f"{start_slot!r}: must be a whole number >= 0")
        if isinstance(age_s, bool) or not isinstance(age_s, (int, float)) or not 0.0 <= age_s <= MAX_AGE_S:
            raise ShapingError("age_s", f"{age_s!r}: must be seconds in [0, {MAX_AGE_S}]")
        self.shaper = shaper
        # The trace's time began when the client's did: the link time before the first request
        # arrived is gone (the bucket starts empty), and later slots line up with the client's.
        self.start = shaper.clock() - float(age_s)
        self.offset_s = int(start_slot) * shaper.slot_s
        self._offset_bytes = shaper.cumulative_bytes(self.offset_s)
        self._at = 0.0             # session seconds of the last update
        # Empty at the start, so the session's first slot gets the trace's bytes and not a burst more.
        self._tokens = 0.0
        self.sent = 0              # bytes reserved so far

    def _allowed(self, s: float) -> float:
        """Bytes the trace allows in the session's first ``s`` seconds."""
        return self.shaper.cumulative_bytes(self.offset_s + s) - self._offset_bytes

    def piece_bytes(self) -> int:
        """Bytes to write at once now: :data:`BURST_S` of the current slot's rate, at least
        :data:`MIN_PIECE_BYTES`, at most the burst (see the module docstring)."""
        sh = self.shaper
        T = len(sh.bytes_per_slot)
        slot = int((self.offset_s + max(0.0, sh.clock() - self.start)) / sh.slot_s) % T
        rate = sh.bytes_per_slot[slot] / sh.slot_s
        return int(min(sh.burst_bytes, max(MIN_PIECE_BYTES, BURST_S * rate)))

    def reserve(self, n: int) -> float:
        """Take ``n`` bytes now; returns the seconds to wait before sending them (0: at once).

        The bucket may go into debt: a second writer reserving after the first waits for both.
        """
        sh = self.shaper
        now = sh.clock() - self.start
        if now > self._at:
            self._tokens = min(float(sh.burst_bytes), self._tokens + self._allowed(now) - self._allowed(self._at))
            self._at = now
        self._tokens -= n
        self.sent += n
        if self._tokens >= 0:
            return 0.0
        # Wait until the refill since `_at` repays the debt.
        target = self._allowed(self._at) + self._offset_bytes - self._tokens
        ready = sh.time_for_bytes(target) - self.offset_s
        return max(0.0, ready - now)

    async def acquire(self, n: int) -> None:
        """Reserve ``n`` bytes and sleep until they may be sent."""
        wait = self.reserve(n)
        if wait > 0:
            await asyncio.sleep(wait)


def trace_shaper(trace, *, mbps: float | None = None, slot_s: float = 1.0, burst_bytes: int | None = None,
                 format: str = "auto") -> TraceShaper:
    """A :class:`TraceShaper` from a trace file or bundled trace name (Mbit/s per second, scaled to a
    mean of ``mbps`` first), a sequence of bytes per slot, or a shaper (returned as it is)."""
    if isinstance(trace, TraceShaper):
        return trace
    if isinstance(trace, (str, os.PathLike)):
        from l3gs_opt.traces.bandwidth import mbps_to_bytes, read_bandwidth_trace

        raw = read_bandwidth_trace(trace, format=format)
        scaled = raw.scaled(mbps)[0] if mbps is not None else raw
        return TraceShaper(mbps_to_bytes(scaled.mbps, slot_s).tolist(), slot_s=slot_s, burst_bytes=burst_bytes)
    return TraceShaper(list(trace), slot_s=slot_s, burst_bytes=burst_bytes)
