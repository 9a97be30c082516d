"""The byte-level link: checked against a byte-by-byte reference and on identities (trace bytes, capacity)."""

from __future__ import annotations

import numpy as np
import pytest

from l3gs_opt.errors import L3gsError
from l3gs_opt.simulator.link import Link, LinkError, max_min_shares, split_bytes


def _reference(bandwidth, budget, request_lists, carry="started"):
    """One byte at a time: the slow, obvious model of the link (what the fast one must match)."""
    return _reference_with_head(bandwidth, budget, request_lists, [0] * len(request_lists), carry)


@pytest.mark.parametrize("carry", ["started", "head"])
@pytest.mark.parametrize("budget", ["per_slot", "cumulative"])
@pytest.mark.parametrize("seed", range(6))
def test_matches_byte_by_byte_reference(budget, seed, carry):
    rng = np.random.default_rng(seed)
    T = 6
    bandwidth = rng.integers(0, 40, T).tolist()
    key = 0
    lists = []
    fast = Link(bandwidth, budget=budget, carry=carry)
    got = []
    for t in range(T):
        reqs = []
        for _ in range(int(rng.integers(0, 4))):
            reqs.append((key, int(rng.integers(1, 30))))
            key += 1
        lists.append(reqs)
        d = fast.step(reqs)
        got.append((d.delivered, list(d.in_flight), d.idle, d.banked))
    assert got == _reference(bandwidth, budget, lists, carry)


@pytest.mark.parametrize("budget", ["per_slot", "cumulative"])
def test_delivers_exactly_the_trace_when_demand_exceeds_it(budget):
    bandwidth = [7, 0, 13, 1, 30, 5]
    link = Link(bandwidth, budget=budget)
    total = 0
    for t, b in enumerate(bandwidth):
        d = link.step([(f"c{t}", 1000)])   # far more than a slot: always something to send
        assert d.bytes == b and d.idle == 0 and d.capacity == b
        total += d.bytes
    assert total == sum(bandwidth)


def test_capacity_identity_and_bank():
    link = Link([10, 10, 10], budget="cumulative")
    d0 = link.step([("a", 4)])
    assert (d0.bytes, d0.idle, d0.banked) == (4, 6, 6)
    d1 = link.step([("b", 25)])                  # 10 + 6 banked
    assert (d1.capacity, d1.bytes, d1.banked) == (16, 16, 0)
    d2 = link.step()
    assert d2.delivered == {"b": 9} and d2.completed == ("b",) and d2.idle == 1
    per = Link([10, 10], budget="per_slot")
    per.step([("a", 4)])
    assert per.bank == 0 and per.step([("b", 25)]).capacity == 10


def test_cut_off_chunk_carries_over_and_unstarted_requests_drop():
    link = Link([10, 10, 10])
    d = link.step([("a", 15), ("b", 3)])
    assert d.delivered == {"a": 10} and d.started == ("a",) and d.dropped == ("b",) and d.in_flight == (("a", 5),)
    assert link.in_flight_bytes == 5
    d = link.step([("c", 2)])
    assert d.delivered == {"a": 5, "c": 2} and d.completed == ("a", "c") and d.started == ("c",)


def test_zero_bandwidth_delivers_nothing():
    link = Link([0, 0, 0])
    for _ in range(3):
        d = link.step([("a", 5), ("b", 1)])
        assert d.bytes == 0 and d.dropped == ("a", "b") and d.in_flight == ()


@pytest.mark.parametrize("bandwidth, match", [([3, -1], r"bandwidth\[1\] = -1"), ([1.5], r"bandwidth\[0\] = 1.5"),
                                              ([True], r"bandwidth\[0\]")])
def test_bad_bandwidth(bandwidth, match):
    with pytest.raises(LinkError, match=match):
        Link(bandwidth)


def test_bad_requests_and_slots():
    assert issubclass(LinkError, L3gsError)
    with pytest.raises(LinkError, match="budget"):
        Link([1], budget="banked")
    link = Link([5, 5])
    with pytest.raises(LinkError, match=r"requests\[1\]: key 'a' is requested twice"):
        link.step([("a", 1), ("a", 2)])
    with pytest.raises(LinkError, match=r"requests\[0\] = 0: must be > 0"):
        link.step([("a", 0)])
    link.step([("a", 9)])
    with pytest.raises(LinkError, match="already in flight"):
        link.step([("a", 9)])
    link.step()
    with pytest.raises(LinkError, match="slot 2: the trace has only 2 slots"):
        link.step()


def _round_robin(total, demands):
    """One byte at a time, in index order: first to clients short of their demand, then to all."""
    got = [0] * len(demands)
    left = total
    while left and any(g < d for g, d in zip(got, demands)):
        for i, d in enumerate(demands):
            if left and got[i] < d:
                got[i] += 1
                left -= 1
    while left:
        for i in range(len(demands)):
            if left:
                got[i] += 1
                left -= 1
    return got


@pytest.mark.parametrize("seed", range(40))
def test_max_min_shares_match_byte_round_robin(seed):
    rng = np.random.default_rng(seed)
    K = int(rng.integers(1, 6))
    demands = rng.integers(0, 30, K).tolist()
    total = int(rng.integers(0, 120))
    shares = max_min_shares(total, demands)
    assert shares == _round_robin(total, demands)
    assert sum(shares) == total
    # Max-min fair: a client short of its demand gets at least as much as any other client.
    for i, (s, d) in enumerate(zip(shares, demands)):
        if s < d:
            assert all(s >= other - 1 for other in shares)


def test_max_min_shares_examples_and_errors():
    assert max_min_shares(10, [2, 100, 100]) == [2, 4, 4]
    assert max_min_shares(10, [0, 0]) == [5, 5]            # nobody can use them: split anyway
    assert max_min_shares(7, [100]) == [7]                 # one client gets the whole link
    assert max_min_shares(0, [5, 5]) == [0, 0]
    with pytest.raises(LinkError, match=r"demands\[1\] = -1"):
        max_min_shares(10, [1, -1])
    with pytest.raises(LinkError, match="at least one client"):
        max_min_shares(10, [])


def test_split_bytes_and_per_step_bandwidth():
    assert split_bytes(10, 4) == [3, 3, 2, 2] and split_bytes(0, 3) == [0, 0, 0]
    with pytest.raises(LinkError, match="parts = 0"):
        split_bytes(10, 0)
    # A link whose capacity is set as it runs moves the same bytes as one given the trace up front.
    bandwidth = [7, 0, 13, 1]
    lists = [[("a", 9), ("b", 4)], [("c", 2)], [("d", 20)], []]
    fixed = Link(bandwidth)
    live = Link([0] * 4)
    for reqs, b in zip(lists, bandwidth):
        assert fixed.step(reqs) == live.step(reqs, bandwidth=b)
    link = Link([0, 0])
    link.step([("x", 10)], bandwidth=4)
    assert link.demand([("y", 3)]) == 9            # 6 in flight + 3 requested
    with pytest.raises(LinkError, match=r"bandwidth\[1\] = -2"):
        link.step(bandwidth=-2)


def _reference_with_head(bandwidth, budget, request_lists, heads, carry="started"):
    """One byte at a time with a planning head: the slot's first ``heads[t]`` bytes may go only to
    transfers carried over; those they cannot use are lost (idle, never banked). At the cut the
    started, unfinished transfers stay in flight, or (``carry="head"``, none started) the first
    unfinished one."""
    flight: list[list] = []
    bank = 0
    out = []
    for t, requests in enumerate(request_lists):
        carried = list(flight)
        queue = flight + [[k, s, 0] for k, s in requests]
        cap = bandwidth[t] + bank
        delivered: dict = {}
        used = lost = 0
        for i in range(cap):
            pool = carried if i < heads[t] else queue
            head = next((q for q in pool if q[2] < q[1]), None)
            if head is None:
                if i < heads[t]:
                    lost += 1
                    continue
                break
            head[2] += 1
            used += 1
            delivered[head[0]] = delivered.get(head[0], 0) + 1
        unfinished = [q for q in queue if q[2] < q[1]]
        flight = [q for q in unfinished if q[2] > 0] or (unfinished[:1] if carry == "head" else [])
        idle = cap - used
        bank = (idle - lost) if budget == "cumulative" else 0
        out.append((delivered, [(q[0], q[1] - q[2]) for q in flight], idle, bank))
    return out


@pytest.mark.parametrize("carry", ["started", "head"])
@pytest.mark.parametrize("budget", ["per_slot", "cumulative"])
@pytest.mark.parametrize("seed", range(8))
def test_planning_head_matches_byte_by_byte_reference(budget, seed, carry):
    rng = np.random.default_rng(seed)
    T = 6
    bandwidth = [int(x) for x in rng.integers(0, 40, size=T)]
    heads = [int(x) for x in rng.integers(0, 25, size=T)]
    reqs = [[(f"{t}-{i}", int(rng.integers(1, 30))) for i in range(int(rng.integers(0, 4)))] for t in range(T)]
    link = Link(bandwidth, budget=budget, carry=carry)
    for (delivered, flight, idle, bank), requests, h in zip(_reference_with_head(bandwidth, budget, reqs, heads, carry),
                                                          reqs, heads):
        d = link.step(requests, head_bytes=h)
        assert (d.delivered, list(d.in_flight), d.idle, d.banked) == (delivered, flight, idle, bank)


def test_planning_head_hand_computed():
    link = Link([100, 100])
    d = link.step([("a", 130)])
    assert d.in_flight == (("a", 30),)
    d = link.step([("b", 200)], head_bytes=50)     # 'a' uses 30 of the 50, 20 are lost, 'b' gets 50
    assert d.delivered == {"a": 30, "b": 50} and d.idle == 20


def test_carry_head_keeps_the_request_on_the_wire():
    """A cut just before or just after a chunk's first byte leaves the same chunk first next slot."""
    for cap, flight in ((10, ("b", 10)), (11, ("b", 9))):
        link = Link([cap, 100], carry="head")
        d = link.step([("a", 10), ("b", 10), ("c", 10)])
        assert d.in_flight == (flight,) and d.dropped == ("c",)
        assert list(link.step([("d", 5)]).delivered) == ["b", "d"]
    started = Link([10, 100])
    d = started.step([("a", 10), ("b", 10)])
    assert d.in_flight == () and d.dropped == ("b",)
    # No capacity at all: the first request still waits on the wire, the others drop.
    d = Link([0], carry="head").step([("a", 3), ("b", 4)])
    assert d.in_flight == (("a", 3),) and d.dropped == ("b",) and d.started == ()
    with pytest.raises(LinkError, match="carry = 'tail'"):
        Link([1], carry="tail")
