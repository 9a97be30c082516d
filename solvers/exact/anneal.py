"""Schedules of Problem A from chunk orders: a first-fit decoder and simulated annealing over orders.

**Decoder.** Given an order of the chunks, each in turn goes to the first slot where it is allowed,
its bytes fit and its lower layer has arrived (strictly before, with strict layers); its undecided
lower layers are decoded first. A chunk is left out when its lower layer is, when it fits nowhere,
or when it would earn less than 0 and no layer depends on it.

**Why orders suffice** (non-negative profits, which is every instance without signed layer
utilities): decode the chunks of any feasible schedule S by slot, lower layers first within a
slot, then the chunks S leaves out. By induction each chunk of S lands in its slot in S or earlier:
when it is decoded, the chunks placed in its S slot are some of those S puts there, so it fits.
Profits ``P[i, t]`` never rise with t, so the decoded schedule is worth at least S
(:func:`slot_order` builds that order; the tests check it against brute force). Every optimum is
therefore the decoding of some order, and a search over orders loses nothing.

**Search.** :func:`anneal_schedule` runs rounds of simulated annealing over orders (swap two
positions or move one, mostly nearby; :mod:`._anneal_kernels`), each round from the best order so
far, until its deadline; :func:`anneal_race` runs chains of other seeds beside it, one per core.
Moves re-decode only from the checkpoint before the first changed position until the decoder's
state meets the old one again. It is a heuristic: its schedule is checked in exact bytes and valued
in float64 from the data, and nothing here claims a bound.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.evaluate import trim_losing_layers
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import Solution, Status, finish_solution

from . import kernels
from .lagrange import GapData, assignment_feasible, assignment_value, gap_data

__all__ = ["first_fit", "slot_order", "anneal_schedule", "anneal_race", "solve_anneal", "TEMP0_SHARE", "TEMP_FALL",
           "MOVES_PER_CHUNK", "MAX_MOVES", "ROUNDS"]

#: Starting temperature of a round, as a share of the mean most a chunk can earn (``max_t |P|``):
#: about 300 utility units on the paper-scale instances, where a slot's utilities run to thousands.
TEMP0_SHARE = 0.08
#: Final temperature of a round = starting temperature / TEMP_FALL.
TEMP_FALL = 300.0
#: Moves of one round per chunk (a round of 80 chunks takes about a third of a second here), at most
#: MAX_MOVES (a round of 800 chunks: about 6 s).
MOVES_PER_CHUNK, MAX_MOVES = 4000, 1_000_000
#: Moves of the first round when a deadline is set (it measures the speed the later rounds are sized
#: by, so that none runs past the deadline).
CALIBRATION_MOVES = 20_000
#: Rounds of the ``anneal`` method when its time limit does not stop it first (reproducible).
ROUNDS = 8
#: With probability 0.7 a move's second position is at most this far from its first.
WINDOW = 5


def first_fit(data: GapData, order: np.ndarray) -> np.ndarray:
    """The assignment [n] (slot or -1) the decoder makes of ``order`` (a permutation of the chunks).

    Plain Python; the reference for the compiled decoder of :mod:`._anneal_kernels`.
    """
    n, T = data.n, data.T
    assign = np.full(n, -2, dtype=np.int64)
    load = [0] * T   # Python ints: exact bytes
    for k0 in order:
        chain, k = [], int(k0)
        while k >= 0 and assign[k] == -2:
            chain.append(k)
            k = int(data.lower[k])
        for k in reversed(chain):
            lo = int(data.lower[k])
            placed = -1
            if lo < 0 or assign[lo] >= 0:
                start = 0 if lo < 0 else int(assign[lo]) + (1 if data.strict else 0)
                for t in range(start, T):
                    if data.allowed[k, t] and load[t] + int(data.cost[k]) <= int(data.budget[t]):
                        if data.profit[k, t] >= 0 or data.upper[k] >= 0:
                            placed = t
                        break
            assign[k] = placed
            if placed >= 0:
                load[placed] += int(data.cost[k])
    return assign


def slot_order(data: GapData, assign: np.ndarray) -> np.ndarray:
    """An order whose decoding puts every chunk of ``assign`` in its slot or earlier (so it is worth
    at least as much when profits are non-negative): by slot, lower layers first, the chunks left
    out last."""
    slot = np.where(assign >= 0, assign, data.T)
    return np.lexsort((data.item_l, slot)).astype(np.int64)


def _kernels():
    from . import _anneal_kernels

    return _anneal_kernels


def _warm() -> None:
    # The arrays of a real (tiny) Problem A, passed as every call passes them (call_kernel), so
    # the kernel compiles for their types: a round of no moves, like the calibration call.
    data = gap_data(Instance(representation="layered", bandwidth=np.array([5, 5]), cost=np.array([[3, 4]]),
                             utility=np.ones((2, 1, 2))))
    call_kernel(_kernels(), np.arange(data.n, dtype=np.int64), data, 0, 1.0, 0.1, 0)


kernels.register("anneal", _warm)


def call_kernel(k, order: np.ndarray, data: GapData, moves: int, temp0: float, temp1: float, seed: int):
    """One round of the compiled annealing (``k.anneal``) from ``order``: (order, value, assignment).
    The one place its arguments are built, so :func:`_warm` compiles it for the types every call
    passes."""
    return k.anneal(order, data.cost, data.profit, data.allowed, data.lower, data.upper, bool(data.strict),
                    data.budget.astype(np.int64), moves, temp0, temp1, WINDOW, seed)


def anneal_schedule(data: GapData, start: np.ndarray | None, *, deadline: float | None = None,
                    rounds: int | None = None, seed: int = 0, moves: int | None = None,
                    patience: int | None = None, stop: Callable[[], bool] | None = None) -> np.ndarray:
    """The best schedule rounds of simulated annealing over chunk orders find, each round from the
    best order so far: ``rounds`` rounds, or fewer when ``deadline`` (``time.perf_counter()``
    seconds) passes first. Under a deadline the first round is short (:data:`CALIBRATION_MOVES`) and
    each later one is cut to the moves that fit the time left at the speed measured so far.

    Parameters
    ----------
    data : GapData
        Problem A (per-slot budgets, bytes; profits in utility units).
    start : int array [n] or None
        A feasible assignment to start from (its :func:`slot_order`); None: chunks by profit per
        byte in slot 0.
    deadline, rounds : float or None, int or None
        When to stop (at least one of them; None: no such limit). A deadline already passed runs
        nothing.
    seed : int
        Seed of the moves (round r uses ``seed * 1000 + r``).
    moves : int or None
        Moves per round (default :data:`MOVES_PER_CHUNK` per chunk, at most :data:`MAX_MOVES`); under
        a deadline, fewer when they would not fit.
    patience : int or None
        Stop once this many full rounds in a row have found nothing better (None: never).
    stop : callable or None
        Polled before each round: true ends the search there (a stop request; a raced chain's
        sibling failed). A round itself is not interrupted (about 0.35 s at 80 chunks).

    Returns
    -------
    int array [n]
        A feasible assignment, never worth less than ``start`` (``start`` itself when no round
        beats it).
    """
    if deadline is None and rounds is None:
        raise SolveError("anneal_schedule: give a deadline or a number of rounds")
    n = data.n
    fallback = np.full(n, -1, dtype=np.int64) if start is None else np.asarray(start, dtype=np.int64)
    if n == 0:
        return fallback
    # The compile of a machine's first call counts against the deadline (it is never waited past).
    if not kernels.ready("anneal", None if deadline is None else deadline - time.perf_counter()):
        return fallback
    k = _kernels()
    if start is None:
        order = np.argsort(-(data.profit[:, 0] / data.cost), kind="stable").astype(np.int64)
    else:
        order = slot_order(data, fallback)
    scale = float(np.abs(data.profit).max(axis=1).mean())
    temp0 = max(TEMP0_SHARE * scale, 1e-300)
    temp1 = temp0 / TEMP_FALL
    moves = min(MOVES_PER_CHUNK * n, MAX_MOVES) if moves is None else int(moves)
    best, best_val = fallback, assignment_value(data, fallback)
    rate = None   # moves per second, measured by the rounds so far
    if deadline is not None:   # a round of no moves: the compiled code is loaded before the speed is measured
        call_kernel(k, order, data, 0, temp0, temp1, 0)
    r = stale = 0
    while (rounds is None or r < rounds) and (patience is None or stale < patience):
        if stop is not None and stop():
            break
        size = moves
        if deadline is not None:
            left = deadline - time.perf_counter()
            # A round fits the time left: the first one is short and measures the speed.
            size = min(size, CALIBRATION_MOVES) if rate is None else min(size, int(rate * left))
            if left <= 0 or size < CALIBRATION_MOVES // 10:
                break
        began = time.perf_counter()
        order, _, assign = call_kernel(k, order, data, size, temp0, temp1, seed * 1000 + r)
        rate = size / max(time.perf_counter() - began, 1e-9)
        r += 1
        # Valued again exactly from the data: the kernel's running sum is only its guide.
        better = False
        if assignment_feasible(data, assign):
            value = assignment_value(data, assign)
            if value > best_val:
                best, best_val, better = assign.copy(), value, True
        # (the short first round under a deadline does not count against the patience)
        stale = 0 if better else stale + (size >= moves)
    return best


def anneal_race(data: GapData, start: np.ndarray | None, *, seeds: Sequence[int],
                stop: Callable[[], bool] | None = None, **kw) -> np.ndarray:
    """The best of :func:`anneal_schedule` chains, one per seed, run at once in threads (the kernel
    releases the GIL, so each gets a core); ``stop`` and ``kw`` go to every chain (the same
    deadline). An exception in the caller's wait (a second Ctrl-C) or in a chain ends the others
    after their round, then propagates.

    Ties go to the earlier seed, so without a deadline the answer does not depend on which chain
    ends first. Why: from the same start the chains end on different plateaus (T60-J20-s0, eight seeds
    of 4.2 s each: seed 1 at the optimum, seed 0 1.1 below it, the others up to 6.2 below; s9: seed 7
    at it, the others 26-35 below; benchmarks/results/exact_anneal_race_ab.md).
    """
    seeds = list(seeds)
    if not seeds:
        raise SolveError("anneal_race: give at least one seed")
    if len(seeds) == 1:
        return anneal_schedule(data, start, seed=seeds[0], stop=stop, **kw)
    abort = threading.Event()

    def stopped() -> bool:
        return abort.is_set() or (stop is not None and stop())

    with ThreadPoolExecutor(max_workers=len(seeds), thread_name_prefix="l3gs-anneal") as pool:
        futures = [pool.submit(anneal_schedule, data, start, seed=s, stop=stopped, **kw) for s in seeds]
        try:
            done, _ = wait(futures, return_when=FIRST_EXCEPTION)
            failed = [f.exception() for f in done if f.exception() is not None]
            if failed:
                raise failed[0]
        except BaseException:
            abort.set()   # (before the pool's exit waits for the chains)
            raise
        outs = [f.result() for f in futures]
    values = [assignment_value(data, out) for out in outs]
    return outs[max(range(len(outs)), key=lambda k: (values[k], -k))]


def solve_anneal(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
                 with_bound: bool = True, rounds: int = ROUNDS, seed: int = 0) -> Solution:
    """The ``anneal`` method: Problems I/III with per-slot budgets, from the better of
    ``rolling-future:bb`` and ``static``, by :func:`anneal_schedule` (``rounds`` rounds, or fewer
    when ``time_limit_s`` seconds pass first). Status ``feasible``; the bound is the LP relaxation
    (``with_bound=False``: none).

    Raises
    ------
    SolveError
        ``slot`` given, the separate representation or the cumulative budget.
    """
    from ..rolling import _bound, bound_phrase
    from .starts import best_start

    started = time.perf_counter()
    if slot is not None:
        raise SolveError("method 'anneal' schedules the whole horizon: slot does not apply (use 'bb' for one slot)")
    if not instance.layered:
        raise SolveError(f"method 'anneal' orders layered chunks; the separate representation (Problem "
                         f"{instance.problem}) is not supported (use 'exact' or a heuristic)")
    if instance.options.budget == "cumulative":
        raise SolveError("method 'anneal' packs per-slot budgets; budget 'cumulative' is not supported (use 'exact' "
                         "or 'link-dp')")
    data = gap_data(instance)
    deadline = None if time_limit_s is None else started + float(time_limit_s)
    start, start_name, _ = best_start(instance, data, ("rolling-future:bb", "static"), deadline)
    assign = anneal_schedule(data, start, deadline=deadline, rounds=rounds, seed=seed)
    # A negative top layer the decoder placed as a step that no layer above repaid is cut off.
    arrivals = trim_losing_layers(instance, data.arrivals(assign))
    schedule_s = time.perf_counter() - started
    bound, bound_s = _bound(instance, with_bound, started, time_limit_s)
    return finish_solution(instance, arrivals, problem=instance.problem, method="anneal",
                           status=Status.FEASIBLE, bound=bound, runtime_s=time.perf_counter() - started,
                           message=f"anneal: simulated annealing over chunk orders (a heuristic); {bound_phrase(bound)}",
                           details={"start": start_name, "start_value": assignment_value(data, start), "schedule_s": schedule_s,
                                    "bound_s": bound_s})
