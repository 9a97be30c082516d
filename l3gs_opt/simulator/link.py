"""One sequential link driven by a bandwidth trace: pure byte accounting (no scenes, no torch).

Each slot ``t`` the link can move ``capacity[t] = bandwidth[t] (+ bank)`` bytes. It sends, in
order, first what was cut off at the end of the previous slot (*in flight*: it carries over),
then the slot's requests, each from its first byte to its last. A request that gets some but not
all of its bytes is in flight and continues first next slot. What the cut does to a request that
got no byte is the ``carry`` rule: ``"started"`` (default) drops every such request (the client
asks again next slot if it still wants it: the requester re-plans every slot); ``"head"`` keeps
the first of them in flight when no started transfer is cut off (the request on the wire at the
cut: an HTTP client has sent it and waits for its first byte), so that whether a cut falls a few
bytes before or after a chunk's first byte no longer decides what goes first next slot. When the queue runs dry, the rest of the slot's bytes are idle:
lost (``budget="per_slot"``, the paper's per-slot budget) or banked for the next slot
(``budget="cumulative"``: the bytes up to slot t are bounded by the bandwidth up to slot t,
the instance option of the same name).

Byte counts are Python ints (exact), at most 2^53 each (:data:`l3gs_opt.traces.bandwidth.MAX_SLOT_BYTES`, as
in instances); a slot never delivers more than its capacity, and ``delivered + idle == capacity``
holds in every slot.

Example
-------
>>> link = Link([10, 10])
>>> d = link.step([("a", 15)])
>>> d.delivered, d.in_flight
({'a': 10}, (('a', 5),))
>>> link.step([("b", 3)]).delivered      # "a" finishes first, then "b"
{'a': 5, 'b': 3}
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Hashable, Mapping, Sequence

import numpy as np

from l3gs_opt.errors import L3gsError
from l3gs_opt.traces.bandwidth import MAX_SLOT_BYTES

__all__ = ["LinkError", "Transfer", "SlotDelivery", "Link", "BUDGETS", "CARRIES", "max_min_shares", "split_bytes"]

BUDGETS = ("per_slot", "cumulative")
#: What a slot's cut keeps in flight (``Link.carry``; see the module docstring).
CARRIES = ("started", "head")


class LinkError(L3gsError, ValueError):
    """Bad link input: a negative or fractional byte count, a duplicate request, a slot past the trace."""


@dataclass
class Transfer:
    """One chunk on the link: ``size`` bytes, ``delivered`` of them so far."""

    key: Hashable
    size: int
    delivered: int = 0

    @property
    def remaining(self) -> int:
        return self.size - self.delivered


@dataclass(frozen=True)
class SlotDelivery:
    """What the link did in one slot.

    Attributes
    ----------
    slot : int
    capacity : int
        Bytes the link could move in this slot: the trace's bytes, plus the bank (cumulative).
    delivered : dict
        Bytes delivered in this slot per key, in the order they were sent.
    started : tuple
        Keys whose first byte arrived in this slot.
    completed : tuple
        Keys whose last byte arrived in this slot.
    dropped : tuple
        Requests that got no byte (they are forgotten).
    in_flight : tuple of (key, remaining bytes)
        Cut off at the end of the slot: they continue first next slot (with ``carry="head"``, a
        request with no byte yet may be among them: its remaining bytes are its size).
    idle : int
        Bytes of ``capacity`` not used (``sum(delivered) + idle == capacity``).
    banked : int
        Idle bytes kept for the next slot (cumulative budget; 0 per slot).
    """

    slot: int
    capacity: int
    delivered: dict
    started: tuple
    completed: tuple
    dropped: tuple
    in_flight: tuple
    idle: int
    banked: int

    @property
    def bytes(self) -> int:
        """Bytes delivered in this slot."""
        return sum(self.delivered.values())


def _byte_count(value, name: str, index: int | None = None, *, positive: bool = False) -> int:
    where = name if index is None else f"{name}[{index}]"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer, float, np.floating)):
        raise LinkError(f"{where} = {value!r}: must be an integer number of bytes")
    if isinstance(value, (float, np.floating)) and not (np.isfinite(value) and float(value).is_integer()):
        raise LinkError(f"{where} = {value!r}: must be an integer number of bytes")
    v = int(value)
    if v < (1 if positive else 0):
        raise LinkError(f"{where} = {v}: must be {'> 0' if positive else '>= 0'} bytes")
    if v > MAX_SLOT_BYTES:
        raise LinkError(f"{where} = {v}: more than 2^53 bytes (MAX_SLOT_BYTES)")
    return v


def _items(values, name: str, what: str) -> list:
    """``values`` as a list if it is a sequence (list, tuple, 1-D array, any iterable); a number, a
    string or a mapping is refused by name (iterating a dict would take its keys as the items)."""
    if isinstance(values, (str, bytes, Mapping)) or (isinstance(values, np.ndarray) and values.ndim != 1):
        items = None
    else:
        try:
            items = list(values)
        except TypeError:   # not iterable: 5, None
            items = None
    if items is None:
        shown = repr(values)
        shown = shown if len(shown) <= 60 else f"{type(values).__name__} of shape {np.shape(values)}"
        raise LinkError(f"{name} = {shown}: must be a sequence of {what}")
    return items


def _byte_counts(values, name: str) -> list[int]:
    """``values`` (a sequence or 1-D array) as a list of byte counts, each checked by :func:`_byte_count`."""
    return [_byte_count(v, name, i) for i, v in enumerate(_items(values, name, "integer byte counts"))]


def _requests(requests, busy=frozenset()) -> list[tuple[Hashable, int]]:
    """``requests`` as ``(key, size)`` pairs after the checks :meth:`Link.step` and :meth:`Link.demand`
    share: pairs, hashable keys (a dict of transfers holds them), sizes positive whole bytes, and no
    key twice or among ``busy`` (the keys in flight), naming the request's index."""
    seen = set(busy)
    out = []
    for i, req in enumerate(_items(requests, "requests", "(key, bytes) pairs")):
        try:
            key, size = req
        except (TypeError, ValueError):
            raise LinkError(f"requests[{i}] = {req!r}: must be a (key, bytes) pair") from None
        try:
            hash(key)
        except TypeError:
            raise LinkError(f"requests[{i}]: key {key!r} must be hashable (a str, int or tuple)") from None
        size = _byte_count(size, "requests", i, positive=True)
        if key in seen:
            raise LinkError(f"requests[{i}]: key {key!r} is requested twice or already in flight")
        seen.add(key)
        out.append((key, size))
    return out


@dataclass
class Link:
    """A sequential link over ``len(bandwidth)`` slots (see the module docstring).

    Parameters
    ----------
    bandwidth : sequence of int, shape [T]
        Bytes the trace allows in each slot (bytes per slot, >= 0).
    budget : {"per_slot", "cumulative"}
        Whether idle bytes are lost or banked for the next slot.
    carry : {"started", "head"}
        Whether the cut keeps only started transfers in flight, or also the first request with
        no byte yet when nothing started is cut off.

    Raises
    ------
    LinkError
        A ``bandwidth`` that is not a sequence, a negative or fractional byte count (naming the
        index), an unknown budget or carry rule.
    """

    bandwidth: Sequence[int]
    budget: str = "per_slot"
    carry: str = "started"
    slot: int = field(default=0, init=False)
    bank: int = field(default=0, init=False)
    in_flight: list = field(default_factory=list, init=False)

    def __post_init__(self) -> None:
        if self.budget not in BUDGETS:
            raise LinkError(f"budget = {self.budget!r}: must be one of {', '.join(BUDGETS)}")
        if self.carry not in CARRIES:
            raise LinkError(f"carry = {self.carry!r}: must be one of {', '.join(CARRIES)}")
        self.bandwidth = _byte_counts(self.bandwidth, "bandwidth")

    @property
    def slots(self) -> int:
        return len(self.bandwidth)

    @property
    def in_flight_bytes(self) -> int:
        """Bytes still to come of the transfers cut off at the end of the last slot."""
        return sum(tr.remaining for tr in self.in_flight)

    def demand(self, requests: Sequence[tuple[Hashable, int]] = ()) -> int:
        """Bytes the link would move next slot with ``requests`` if nothing limited it, beyond
        its bank: what it asks of a shared bottleneck.

        Raises
        ------
        LinkError
            On a request :meth:`step` would refuse (naming its index).
        """
        sizes = [size for _, size in _requests(requests, {tr.key for tr in self.in_flight})]
        return max(0, self.in_flight_bytes + sum(sizes) - self.bank)

    def step(self, requests: Sequence[tuple[Hashable, int]] = (), *, bandwidth: int | None = None,
             head_bytes: int = 0) -> SlotDelivery:
        """Run the next slot with ``requests`` (``(key, size in bytes)``, in sending order).

        ``bandwidth`` (bytes) replaces the slot's entry of the trace first: a link whose share
        of a bottleneck is decided as the slot runs (see :func:`max_min_shares`).
        ``head_bytes``: the slot's first bytes go out before ``requests`` are made (the client is
        still planning): only the transfers in flight may use them, and what they cannot use is
        idle (lost, never banked: the link time has passed).

        Raises
        ------
        LinkError
            Past the last slot; ``requests`` that is not a sequence of pairs; a size that is not a
            positive integer; a key that is not hashable, requested twice or already in flight
            (naming the request's index).
        """
        if self.slot >= self.slots:
            raise LinkError(f"slot {self.slot}: the trace has only {self.slots} slots")
        if bandwidth is not None:
            self.bandwidth[self.slot] = _byte_count(bandwidth, "bandwidth", self.slot)
        queue = list(self.in_flight)
        queue += [Transfer(key, size) for key, size in _requests(requests, {tr.key for tr in self.in_flight})]
        capacity = self.bandwidth[self.slot] + self.bank
        head = min(_byte_count(head_bytes, "head_bytes"), capacity)
        lost = max(0, head - sum(tr.remaining for tr in self.in_flight))
        left = capacity - lost
        delivered: dict = {}
        started, completed, carried, dropped = [], [], [], []
        for tr in queue:
            if left <= 0:
                keep = tr.delivered > 0 or (self.carry == "head" and not carried)
                (carried if keep else dropped).append(tr)
                continue
            if tr.delivered == 0:
                started.append(tr.key)
            take = min(left, tr.remaining)
            tr.delivered += take
            left -= take
            delivered[tr.key] = take
            if tr.remaining == 0:
                completed.append(tr.key)
            else:
                carried.append(tr)
        self.in_flight = carried
        self.bank = left if self.budget == "cumulative" else 0
        out = SlotDelivery(slot=self.slot, capacity=capacity, delivered=delivered, started=tuple(started),
                           completed=tuple(completed), dropped=tuple(tr.key for tr in dropped),
                           in_flight=tuple((tr.key, tr.remaining) for tr in carried), idle=left + lost,
                           banked=self.bank)
        self.slot += 1
        return out


def split_bytes(total: int, parts: int) -> list[int]:
    """``total`` bytes in ``parts`` near-equal integer parts, the larger ones first (they sum to ``total``).

    ``parts`` is 1..:data:`~l3gs_opt.pipeline.counts.MAX_SUBSTEPS`, the parts of a slot
    (``SimConfig.substeps``): the list is built in Python, so ``parts=10**10`` would hang.

    Raises
    ------
    LinkError
        On a byte count :func:`max_min_shares` would refuse, or ``parts`` out of range.
    """
    from l3gs_opt.pipeline.counts import MAX_SUBSTEPS

    total = _byte_count(total, "total")
    if isinstance(parts, (bool, np.bool_)) or not isinstance(parts, (int, np.integer)) or not 1 <= parts <= MAX_SUBSTEPS:
        raise LinkError(f"parts = {parts!r}: must be an integer in [1, {MAX_SUBSTEPS}] (MAX_SUBSTEPS)")
    q, r = divmod(total, int(parts))
    return [q + (1 if i < r else 0) for i in range(int(parts))]


def max_min_shares(total: int, demands: Sequence[int]) -> list[int]:
    """Split ``total`` bytes of a bottleneck max-min fairly among clients with ``demands`` (bytes).

    Water-filling in whole bytes: every client gets ``min(demand, level)`` for the largest
    level the bytes allow, the bytes left below the next level go one each to the unsatisfied
    clients in index order; when every demand is met, the bytes nobody can use are split
    equally (lower indices first) so that the shares always sum to ``total``. The same as
    handing out single bytes round-robin in index order, first to clients still short of
    their demand, then to all.

    Raises
    ------
    LinkError
        ``demands`` that is not a sequence (a number, a string, a mapping); a negative or
        fractional byte count, naming the index.

    Example
    -------
    >>> max_min_shares(10, [2, 100, 100])
    [2, 4, 4]
    >>> max_min_shares(10, [1, 1])
    [5, 5]
    """
    total = _byte_count(total, "total")
    d = _byte_counts(demands, "demands")
    K = len(d)
    if K == 0:
        raise LinkError("demands: at least one client is needed")
    if sum(d) <= total:
        q, r = divmod(total - sum(d), K)
        return [d[i] + q + (1 if i < r else 0) for i in range(K)]
    # The largest level m with sum(min(d, m)) <= total (0 <= m < max(d)), by bisection.
    lo, hi = 0, max(d)
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if sum(min(v, mid) for v in d) <= total:
            lo = mid
        else:
            hi = mid
    out = [min(v, lo) for v in d]
    left = total - sum(out)
    for i in range(K):
        if left == 0:
            break
        if d[i] > lo:
            out[i] += 1
            left -= 1
    return out
