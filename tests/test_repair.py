"""Level-keeping repair (``solvers/repair.py``) against brute force on tiny instances."""

from __future__ import annotations

import itertools as it
import math
import time

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core_helpers import PER_SLOT_OPTIONS, random_instance
from l3gs_opt.solvers.exact.search import round_schedule
from l3gs_opt.solvers.exact.lagrange import assignment_feasible, assignment_value, chunk_profits, gap_data
from l3gs_opt.solvers.exact.repair import GAIN_TOL, _keep_mask, _room_for, level_repair

ACCEPTED = PER_SLOT_OPTIONS


def _profits(data, schedules: np.ndarray) -> np.ndarray:
    """Profit of each chunk in each schedule (0 when it does not arrive)."""
    return np.array([chunk_profits(data, a) for a in schedules]).reshape(len(schedules), data.n)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), tight=st.sampled_from([0.3, 0.8]))
def test_repair_ends_where_no_schedule_dominates_it_chunk_by_chunk(seed: int, opt: int, tight: float) -> None:
    """From a random feasible start, the result is feasible, no worse, and (every target decided)
    no feasible schedule, enumerated, gives every chunk at least its profit and one chunk more."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=4, J=2, L=3, options=ACCEPTED[opt], tight=tight, zero_p=0.4)
    data = gap_data(inst)
    start = round_schedule(data, rng.random((data.n, data.T)), data.allowed)
    assert assignment_feasible(data, start)
    rep = level_repair(data, start, data.allowed, deadline=None)
    assert assignment_feasible(data, rep.assign)
    assert assignment_value(data, rep.assign) >= assignment_value(data, start)
    assert rep.undecided == 0 and rep.tried >= rep.repairs
    assert math.isclose(math.fsum(chunk_profits(data, rep.assign)) + data.constant,
                        assignment_value(data, rep.assign), rel_tol=1e-12, abs_tol=1e-12)
    if data.n == 0:   # (presolve dropped every chunk)
        return
    schedules = np.array([a for a in it.product(range(-1, data.T), repeat=data.n)
                          if assignment_feasible(data, np.asarray(a, dtype=np.int64))])
    mine = _profits(data, rep.assign[None, :])
    theirs = _profits(data, schedules)
    tol = GAIN_TOL * float(np.abs(data.profit).max(initial=0.0))
    dominating = (theirs >= mine).all(axis=1) & (theirs > mine + tol).any(axis=1)
    assert not dominating.any(), schedules[dominating][0]


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), opt=st.integers(0, 3), tight=st.sampled_from([0.3, 0.8]))
def test_byte_count_rules_out_only_impossible_repairs(seed: int, opt: int, tight: float) -> None:
    """Whenever the byte count says a target cannot gain, no feasible schedule (enumerated) gives
    it more and every other chunk at least its profit."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=4, J=2, L=3, options=ACCEPTED[opt], tight=tight, zero_p=0.4)
    data = gap_data(inst)
    if data.n == 0:
        return
    start = round_schedule(data, rng.random((data.n, data.T)), data.allowed)
    cur = chunk_profits(data, start)
    keep = _keep_mask(data.allowed, data.profit, cur, start)
    better = data.allowed & (data.profit > cur[:, None])
    schedules = np.array([a for a in it.product(range(-1, data.T), repeat=data.n)
                          if assignment_feasible(data, np.asarray(a, dtype=np.int64))])
    theirs = _profits(data, schedules)
    keeps_level = theirs >= cur[None, :]
    for target in np.nonzero(better.any(axis=1))[0]:
        if not _room_for(data, keep, cur, int(target), better[target]):
            others = np.delete(keeps_level, target, axis=1).all(axis=1)
            assert not (others & (theirs[:, target] > cur[target])).any(), (target, start)


def test_repair_finds_a_repacking_local_search_cannot() -> None:
    """Two slots of 4 bytes; chunk a (3 bytes, wanted early) waits in slot 1 because slot 0 holds
    two 2-byte chunks whose profit is the same in either slot. Moving a into slot 0 needs both of
    them out first: no single move or exchange does it, the repair does."""
    from l3gs_opt import Instance

    # Objects: a (3 bytes, worth 10 in slot 0 and 1 in slot 1), b and c (2 bytes each, shown in
    # slot 1 only). (a worth nothing in slot 1 would not be allowed there: presolve.)
    utility = np.zeros((2, 3, 1))
    utility[0, 0, 0] = 10.0
    utility[1, 0, 0] = 1.0
    utility[1, 1, 0] = utility[1, 2, 0] = 1.0
    inst = Instance("layered", bandwidth=np.array([4, 4]), cost=np.array([[3], [2], [2]]), utility=utility)
    data = gap_data(inst)
    slot_of = {int(j): k for k, j in enumerate(data.item_j)}
    start = np.full(data.n, -1, dtype=np.int64)
    start[slot_of[0]], start[slot_of[1]], start[slot_of[2]] = 1, 0, 0
    assert assignment_feasible(data, start)
    rep = level_repair(data, start, data.allowed, deadline=time.perf_counter() + 30)
    assert rep.repairs >= 1
    assert rep.assign[slot_of[0]] == 0
    assert assignment_value(data, rep.assign) > assignment_value(data, start)


def test_repair_stops_at_its_deadline_with_the_start() -> None:
    rng = np.random.default_rng(3)
    inst = random_instance(rng, T=4, J=2, L=3, tight=0.5)
    data = gap_data(inst)
    start = round_schedule(data, rng.random((data.n, data.T)), data.allowed)
    rep = level_repair(data, start, data.allowed, deadline=time.perf_counter() - 1.0)
    assert rep.tried == 0 and (rep.assign == start).all()
