"""``exact``: Problems I/III on Problem A (the GAP form) by decomposition, with certified gaps.

Length (~800 lines): the primal moves (local search, rounding), the branching rules and the
search itself (:class:`_Search`, one method per phase) share the node masks and the incumbent's
representation; the bounds, columns, LNS and repair live in their own modules beside it.

1. **Primal start**: the best of the heuristics (``rolling-future:bb``, ``slope``, ``rolling:bb``,
   and ``mpc:3`` on small scenes), then local search (move a chunk to an earlier slot, insert,
   swap two chunks between slots or out of the schedule), always feasible in integer bytes; then,
   on instances small enough for column generation (``ROOT_PRIMAL``), simulated annealing over
   chunk orders decoded first-fit (:mod:`.anneal`; every optimum is such a decoding).
2. **Bounds**: the LP relaxation of Problem A (HiGHS) gives the first multipliers (and the
   Lagrangian bound at them); then, when Problem A has at most ``COLGEN_MAX_PAIRS`` (chunk, slot)
   pairs, Dantzig-Wolfe column generation over per-slot fillings (:mod:`.colgen`), seeded with
   the knapsack fillings at the LP duals, priced by the exact single-slot knapsack solver and
   stabilised around the best multipliers. Every pricing round is a Lagrangian bound with the
   linking rows (at most once, precedence) dualised (:mod:`.lagrange`), valid whatever the LP
   did; the answer carries the best of them. Once it converges, rounds of cover cuts of the
   arrived-by knapsacks (:mod:`.covers`) enter the master within the same time share.
3. **Lagrangian-guided repair**: the LP solution, the master solution and the knapsack fillings
   are rounded into schedules; relaxation-induced neighbourhoods (chunks the LP / master holds
   wholly in one slot stay there or leave, the rest move freely: a small MIP,
   :func:`.lns.lp_neighbourhood`); when column generation is skipped (large instances) a second
   LP neighbourhood in which those chunks may also shift by up to ``BAND_WIDTH`` slots; local
   search and a window LNS (:mod:`.lns`: a few slots re-solved exactly as a small MIP, the rest
   fixed), with, on instances small enough for column generation, a level-keeping repair before
   and after it (:mod:`.repair`: CP-SAT repacks the schedule so that one chunk gains and none
   loses). The repair and window LNS run only where the annealing did not (``ROOT_PRIMAL``).
4. **Closing the gap**: reduced-cost fixing with every Lagrangian certificate met (the LP duals'
   and the column generation's: a chunk whose forced arrival in slot t cannot beat the incumbent
   under the knapsack's LP bound is removed from t), then branching: ``branching="mip"`` -
   HiGHS branch-and-cut on Problem A reduced by that fixing (layer order through cumulative
   columns: two non-zeros a row), started from the incumbent and cut off at it, and stopped and
   restarted on a smaller model whenever it finds a schedule at which the fixing, redone, drops
   at least ``1 - RESTART_SHRINK`` of its pairs; each run is kept ``MIP_MARGIN_S`` (plus a little
   per pair) short of the deadline because HiGHS overruns its limit; ``branching="price"`` - our
   own best-first branch-and-price with column generation (Lagrangian bounds) and fixing at every
   node, branching on "chunk i has arrived by slot t" where the profit drops most (children: by
   t, or after t; either may leave i out), then on ``x[i,t]``; ``branching="both"`` (default) -
   the two at once, HiGHS in a second thread; the answer carries the smaller of their bounds.
   Where HiGHS runs alone (``mip``, large instances, and the LP neighbourhoods) it runs once per
   core with different seeds, sharing schedules (:mod:`l3gs_opt.models.backends.highs_race`).

A time limit returns the best schedule with a valid bound, status ``time_limit``; ``optimal``
only when the certified gap is at most ``GAP_TOL``. ``details["bound_kind"]`` says which bound
the answer carries. Supported: layered instances (Problems I, III) with per-slot budgets, either
availability, same-slot or strict layers. Separate instances (Problems II/IV) go to
:mod:`.separate` (per-object paths: path pricing, branch-and-price beside a reduced HiGHS model).
Layered instances with the ``cumulative`` budget go to :mod:`.cumulative` (the arrived-by form:
per-slot knapsacks again, fixing, HiGHS on what is left).

Signed layer utilities (``dU < 0``) need nothing special: Problem A's profits ``P[i,t]`` are then
signed too, the Lagrangian bound holds for any sign (each slot's knapsack takes only positive
reduced profits, and a lower layer's is raised by its upper layer's precedence multiplier), every
primal move is accepted only when it raises the exactly summed value, and presolve keeps a
negative layer exactly when a run of layers above it may recover it.
"""

from __future__ import annotations

import heapq
import itertools
import math
import threading
import time
from typing import Any, Mapping

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.models.backends.highs_race import mip_seeds
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import GAP_TOL, Solution, Status, finish_solution, relative_gap, utility_scale
from l3gs_opt.stop import expired, requested

from . import kernels
from .clock import Clock
from .colgen import ColumnPool, Master, column_generation
from .covers import separate_covers
from .sides import run_sides
from .starts import best_start
from .anneal import anneal_race
from .warm import warm_up
from . import lagrange
from .lns import lp_neighbourhood, reduced_mip, window_sweep
from .repair import level_repair
from .lagrange import GapData, LagrangeValue, assignment_feasible, assignment_value, gap_data, knapsack

__all__ = ["solve_exact", "local_search", "round_schedule", "reduced_cost_fixing"]

#: Heuristics the primal side starts from (``mpc:3`` is added when J * L <= MPC_MAX_CHUNKS).
START_HEURISTICS = ("rolling-future:bb", "slope", "rolling:bb")
MPC_MAX_CHUNKS = 100
#: Root column generation runs only when Problem A has at most this many (chunk, slot) pairs:
#: above it the 60 s goes to the primal side (the LP and band neighbourhoods, the window LNS) and
#: HiGHS instead, and the bound is the Lagrangian at the LP duals and HiGHS's. J=20 (T=60: 4,800
#: pairs) keeps it: without it seeds 0-9 proved 3 of 10 in 60 s against 7 of 10. At J=50 (12,000) the root
#: did not converge in its share on 4 of 5 seeds, its bound stayed at the LP duals' certificate,
#: and HiGHS's bound ended below the Dantzig-Wolfe one; without it (A/B, J=50 seeds 0-9, 60 s)
#: the final gap was smaller on 8 of 10 seeds, s3 proven (benchmarks/results/exact_colgen_max_pairs_ab.md).
#: At J=200 (48,000) one master round takes seconds. Sizes between were not measured.
COLGEN_MAX_PAIRS = 10_000
#: Shares of the time left that each root phase may use (the rest goes to the branching):
#: column generation, window LNS, and one local-search call (its exchange step is O(n^2)).
COLGEN_SHARE, LNS_SHARE, LOCAL_SEARCH_SHARE = 0.4, 0.2, 0.02
#: Time share of each relaxation-induced neighbourhood MIP (chunks the LP or the master schedules
#: wholly stay there or leave, the others move freely; :func:`.lns.lp_neighbourhood`).
NEIGHBOURHOOD_SHARE = 0.1
#: When column generation is skipped (large instances), a second LP neighbourhood in which the
#: chunks the LP holds wholly in slot s may also shift to s +- BAND_WIDTH, with this time share:
#: at J=200 it reached schedules the plain neighbourhood and the window LNS did not.
BAND_WIDTH, BAND_SHARE = 2, 0.25
#: While the root column generation runs (one core: the master LP is serial and the pricing takes
#: 0.2 % of its time at J=50), HiGHS searches Problem A, fixed at the LP duals' certificate and
#: cut off at the incumbent, on the other core; it stops when column generation does (or closes
#: the gap itself). Not with ``branching="price"``.
ROOT_MIP = True
#: The reduced MIP is stopped and restarted on a smaller model when HiGHS finds a schedule at
#: which reduced-cost fixing keeps at most this share of the pairs it was given.
RESTART_SHRINK = 0.9
#: Time share (of the time left) of each level-keeping repair, before and after the window LNS
#: (:mod:`.repair`), on instances small enough for column generation: at J=200 (T60-J200-s1) 29 of
#: its 30 CP-SAT runs ended undecided in 60 s.
REPAIR_SHARE = 0.15
#: Time share (of the time left) for the exact-knapsack fixing test before each reduced MIP.
EXACT_FIXING_SHARE = 0.05
#: Seconds (plus per allowed pair) kept back from each HiGHS MIP: HiGHS 1.14 runs past its time
#: limit and interrupt (model set-up and clean-up call no callback): 0.4-2.3 s measured on the
#: 43,715-pair J=200 model at load 3-4, 5.7 s once at load 3 in the recorded benchmark.
MIP_MARGIN_S, MIP_MARGIN_PER_PAIR_S = 1.0, 5e-5
#: How the gap is closed after the root: ``mip`` - HiGHS branch-and-cut on the model reduced by
#: Lagrangian fixing, cut off at the incumbent; ``price`` - our own best-first branch-and-price
#: (column generation and fixing at every node); ``both`` (default) - the two at once, HiGHS in a
#: second thread (it releases the GIL), sharing schedules and stopping when either closes: at
#: J=20 the MIP proves s1-s3 and branch-and-price s4. Large instances (column generation skipped
#: at the root), and instances whose root column generation did not converge in its share, run
#: ``mip`` only.
BRANCHING = ("both", "mip", "price")
#: Cover cuts of the arrived-by knapsacks (:mod:`.covers`): ``"off"``; ``"root"`` - rounds of
#: them in the master once the root column generation converges, within its time share (the rows
#: stay in the master at every node and go into HiGHS's reduced model); ``"nodes"`` - rounds at
#: every branch-and-price node too. Off: on nine J=20 development instances ``"root"`` lowered the
#: root bound on six (s4: 307,654.27 to 307,553.94, optimum 307,421.67) but did not shorten the
#: proofs: 12 of 16 runs proved within 60 s with it and 12 of 16 without, s3 took 27.5-28.0 s
#: against 18.8-19.0 s in both runs, and run-to-run noise (without covers s0 and s11 proved in
#: one run and not in the other) was larger than any gain; ``"nodes"`` took 48.5 s on s4 against 37.7 s
#: (benchmarks/results/cover_cuts_exact_ab.txt).
COVER_CUTS = "off"
#: The primal search at the root, on instances small enough for column generation (larger ones keep
#: ``"lns"``): ``"anneal"`` - rounds of simulated annealing over chunk orders (:mod:`.anneal`) right
#: after the start heuristics (without ``mpc:3``), for ANNEAL_SHARE of the time limit (ANNEAL_ROUNDS
#: rounds without a limit); no LP neighbourhood MIPs on small instances (LEAN_ROOT_MAX_PAIRS), and
#: after the root only the fixing; ``"lns"`` -
#: ``mpc:3`` among the starts, the LP neighbourhoods after the LP and the root, then the level-keeping
#: repair, the window LNS and the repair again (:meth:`_Search.improve_at_root`). ``"anneal"``: on J=20
#: the annealing reaches within 0.05 % of the optimum in 4 s (the optimum on s2, s3, s5, s12), where the
#: root's repair and LNS took 10-20 s to end further from it; seeds 0-9 proven 6 of 10 in 60 s against
#: 5 of 10 (benchmarks/results/exact_anneal_ab.md). After it the two neighbourhoods gained on 2 of 28
#: calls (J=20 seeds 0-13) and took about 5 s on most seeds; without them and ``mpc:3`` (with the
#: patience and the fixing below) the nine J=20 seeds both arms proved took 4.5-13.0 s less each, s11
#: lost its proof (26.8 s before), and seeds 0-9 proved 7 of 10 in a median of 19.9 s against 27.6 s
#: (benchmarks/results/exact_lean_root_ab.md).
ROOT_PRIMAL = "anneal"
ANNEAL_SHARE, ANNEAL_ROUNDS = 0.07, 12
#: The annealing stops early when this many rounds in a row find nothing better (most J=20 seeds
#: reach their best in the first two rounds of about 0.35 s, from the fourteen runs of 4.2 s each).
ANNEAL_PATIENCE = 4
#: Seeds of the annealing chains, raced one per core (:func:`.anneal.anneal_race`); None: one per
#: core this process may use, as for HiGHS's races (``mip_seeds``: (0, 1) on our 2-core box, whose
#: second core is idle until the root LP). J=20 seeds 0-9, two runs each: 8 of 10 proven in 60 s in
#: both, median 16.9 / 17.4 s; with seed 0 alone 7 of 10, median 31.1 / 31.4 s (s0 never: its chain
#: ends 1.1 below the optimum, seed 1's at it) (benchmarks/results/exact_anneal_race_ab.md).
ANNEAL_SEEDS: tuple[int, ...] | None = None
#: Seconds the annealing waits at least for its kernel (:mod:`.kernels`): loading
#: it from numba's disk cache, with numba's import, takes ~0.25 s on our 2-core box.
KERNEL_LOAD_S = 1.0
#: The LP neighbourhoods are left out after the annealing only where n * T is at most this (J=20:
#: 4,800): at J=50 (12,000; the root column generation does not converge in its share and the gap
#: is mostly the schedule) the run with them ended higher than two runs without on 6 of the 8
#: pairs of the four open seeds (equal on 1; benchmarks/results/exact_lean_root_ab.md). (J=50 has
#: since left the annealing's sizes: :data:`COLGEN_MAX_PAIRS`.)
LEAN_ROOT_MAX_PAIRS = 8_000
#: Branch-and-price is best-first over bands of this relative width (of the root bound): of the
#: open nodes whose bounds fall in one band, the newest comes first (a dive). On T60-J20-s13 and
#: s15 whole subtrees had one bound (fractional node masters worth the optimum); plain best-first
#: went across them breadth-first and rounded none into the optimum (development seeds 10-15:
#: exact.md, fifteenth session).
BOUND_BAND = 1e-5
#: A branch-and-price node's master starts from its parent's last basis (one branching decision
#: away) rather than from the last node solved (anywhere in the tree, best-first): a node's first
#: master solve took 2,300 dual simplex iterations and 0.33 s on average from the last node's
#: basis (J=20 s0, 27 nodes), a cold one at the root 644 iterations.
PARENT_BASIS = True
#: A node is closed when its bound is within this relative distance of the incumbent: below
#: GAP_TOL so that a closed tree certifies an optimal gap.
CLOSE_TOL = 0.1 * GAP_TOL
#: A master value x (or a cumulative "arrived by t" share) below this, or above 1 minus it, counts
#: as integral when choosing where to branch: the master LP's own round-off is ~1e-9.
FRACTIONAL_TOL = 1e-6


def _closed(bound: float, z: float) -> bool:
    # (An infinite bound, i.e. none yet, closes nothing: the relative tolerance would make it.)
    return bound < math.inf and bound <= z + CLOSE_TOL * max(abs(bound), 1e-300)


# -- primal side -----------------------------------------------------------------------------

def _spare(data: GapData, assign: np.ndarray) -> np.ndarray:
    spent = np.zeros(data.T, dtype=np.int64)
    on = assign >= 0
    np.add.at(spent, assign[on], data.cost[on])
    return data.budget - spent


def local_search(data: GapData, assign: np.ndarray, allowed: np.ndarray, *, forced: Mapping[int, int] | None = None,
                 deadline: float | None = None, max_swaps: int = 2000) -> np.ndarray:
    """Improve a feasible assignment (slot per item, -1 never) without breaking it.

    Moves: a chunk to an earlier slot that fits (the one of largest ``P[i,t]``, earliest on ties:
    with ``dU >= 0``, ``P[i,t]`` never grows with t, so that is the earliest; with signed layer
    utilities a later one may be worth more), an unscheduled chunk in; then the best exchange of
    two chunks (one moving earlier into the other's slot, the other later or out), repeated.
    Every move raises the value. Forced chunks stay put.
    """
    assign = assign.copy()
    forced = forced or {}
    n, T = data.n, data.T
    d = 1 if data.strict else 0
    frozen = np.zeros(n, dtype=bool)
    frozen[list(forced)] = True
    spare = _spare(data, assign)
    profit_ext = np.concatenate([data.profit, np.zeros((n, 1))], axis=1)   # slot T = never
    allowed_ext = np.concatenate([allowed, np.ones((n, 1), bool)], axis=1)
    cost = data.cost
    lower, upper = data.lower, data.upper
    order = np.argsort(-data.profit.max(axis=1, initial=0.0), kind="stable")
    if n == 0:
        return assign
    for _ in range(max_swaps):
        if expired(deadline):
            break
        # 1. earliest-slot moves and insertions, until none applies.
        moved = True
        while moved:
            moved = False
            for i in order:
                if frozen[i]:
                    continue
                lo = lower[i]
                if lo >= 0 and assign[lo] < 0:
                    continue
                first = assign[lo] + d if lo >= 0 else 0
                cur = assign[i] if assign[i] >= 0 else T
                if cur <= first:
                    continue
                up = upper[i]
                last = cur if (up < 0 or assign[up] < 0) else min(cur, assign[up] - d + 1)
                ok = allowed[i, first:last] & (spare[first:last] >= cost[i])
                if not ok.any():
                    continue
                t = first + int(np.argmax(np.where(ok, profit_ext[i, first:last], -np.inf)))
                if profit_ext[i, t] <= profit_ext[i, cur]:
                    continue
                if assign[i] >= 0:
                    spare[assign[i]] += cost[i]
                spare[t] -= cost[i]
                assign[i] = t
                moved = True
        # 2. best exchange: k moves into i's slot a, i moves to k's slot b > a (or out: b = T).
        slot = np.where(assign >= 0, assign, T)
        a = slot[:, None]                       # i's slot (rows)
        b = slot[None, :]                       # k's slot (columns)
        ar = np.arange(n)
        aa, bb = np.broadcast_to(a, (n, n)), np.broadcast_to(b, (n, n))
        kk, ii = ar[None, :], ar[:, None]
        delta = profit_ext[kk, aa] + profit_ext[ii, bb] - profit_ext[ii, aa] - profit_ext[kk, bb]
        spare_ext = np.concatenate([spare, [np.iinfo(np.int64).max // 4]])   # slot T (never): no budget
        ok = (a < b) & (a < T)
        ok &= spare_ext[aa] + cost[:, None] - cost[None, :] >= 0
        ok &= spare_ext[bb] + cost[None, :] - cost[:, None] >= 0
        ok &= allowed_ext[kk, aa] & allowed_ext[ii, bb]
        ok &= ~frozen[:, None] & ~frozen[None, :]
        ok &= data.item_j[:, None] != data.item_j[None, :]
        # k into a: its lower layer there by a - d, its upper layer (if scheduled) from a + d.
        lo_k = np.where(lower >= 0, slot[np.maximum(lower, 0)], -T - 1)
        ok &= (lower[None, :] < 0) | (lo_k[None, :] <= a - d)
        up_k = np.where(upper >= 0, slot[np.maximum(upper, 0)], T + 1)
        ok &= (up_k[None, :] >= a + d) | (up_k[None, :] >= T)
        # i into b: its upper layer not before b + d (never, when i leaves the schedule).
        up_i = np.where(upper >= 0, slot[np.maximum(upper, 0)], T + 1)
        ok &= np.where(b >= T, up_i[:, None] >= T, up_i[:, None] >= b + d)
        delta = np.where(ok, delta, 0.0)
        best = int(np.argmax(delta))
        i, k = divmod(best, n)
        if delta[i, k] <= 1e-12 * max(1.0, float(np.abs(data.profit).max(initial=0.0))):
            break
        ai, bk = int(slot[i]), int(slot[k])
        spare[ai] += cost[i] - cost[k]
        if bk < T:
            spare[bk] += cost[k] - cost[i]
        assign[k] = ai
        assign[i] = bk if bk < T else -1
    return assign


def round_schedule(data: GapData, score: np.ndarray, allowed: np.ndarray, *,
                   forced: Mapping[int, int] | None = None) -> np.ndarray:
    """Greedy schedule from per-(item, slot) scores (e.g. the master solution): take the pairs
    in descending score (ties: more profit first) when they fit and keep layer order."""
    n = data.n
    d = 1 if data.strict else 0
    assign = np.full(n, -1, dtype=np.int64)
    spare = data.budget.copy()
    for i, t in (forced or {}).items():
        assign[i] = t
        spare[t] -= data.cost[i]
    ii, tt = np.nonzero((score > 0) & allowed)
    order = np.lexsort((-data.profit[ii, tt], -score[ii, tt]))
    pending = list(zip(ii[order].tolist(), tt[order].tolist()))
    for _ in range(data.item_l.max(initial=0) + 2):   # lower layers may come later in the order
        rest = []
        for i, t in pending:
            if assign[i] >= 0:
                continue
            lo, up = data.lower[i], data.upper[i]
            if (lo >= 0 and (assign[lo] < 0 or assign[lo] > t - d)) or spare[t] < data.cost[i] or \
                    (up >= 0 and 0 <= assign[up] < t + d):
                rest.append((i, t))
                continue
            assign[i] = t
            spare[t] -= data.cost[i]
        if len(rest) == len(pending):
            break
        pending = rest
    return assign


# -- reduced-cost fixing -----------------------------------------------------------------------

def reduced_cost_fixing(data: GapData, lv: LagrangeValue, bound: float, incumbent: float,
                        allowed: np.ndarray, *, exact_knapsack: bool = False,
                        deadline: float | None = None) -> np.ndarray:
    """``allowed`` minus the pairs (i, t) whose forced arrival cannot beat ``incumbent``.

    Forcing i into slot t changes the Lagrangian bound to at most ``bound - K_t + p~[i,t] +
    LPK_t(B_t - c_i)``, with ``LPK_t`` the LP (Dantzig) bound of slot t's knapsack (an upper
    bound on the knapsack left after i). ``bound`` must be ``lv``'s bound. With
    ``exact_knapsack``, each pair this keeps (and the knapsack at ``lv`` did not choose) is tested
    again with the knapsack without i at capacity ``B_t - c_i`` solved exactly (its solver's
    upper bound): one knapsack per pair, so only for small instances; at J=20 it dropped a tenth
    more of the pairs. ``deadline`` (``time.perf_counter()`` seconds) stops those tests early
    (keeping a pair is always valid).
    """
    out = allowed.copy()
    red = lv.reduced
    for t in range(data.T):
        cand = np.nonzero(allowed[:, t])[0]
        if len(cand) == 0:
            continue
        col = red[:, t]
        pos = np.nonzero((col > 0) & allowed[:, t])[0]
        ratio = col[pos] / data.cost[pos]
        o = pos[np.argsort(-ratio, kind="stable")]
        cum_c = np.r_[0.0, np.cumsum(data.cost[o].astype(np.float64))]
        cum_v = np.r_[0.0, np.cumsum(col[o])]
        cap = (data.budget[t] - data.cost[cand]).astype(np.float64)
        lpk = np.interp(np.maximum(cap, 0.0), cum_c, cum_v)
        forced_bound = bound - lv.slot_bound[t] + col[cand] + lpk
        # Margin for the float error of this estimate (cum sums of at most n terms).
        margin = 8 * (data.n + data.T) * np.finfo(float).eps * (abs(bound) + float(np.abs(cum_v).max(initial=0)))
        drop = (forced_bound + margin < incumbent) | (cap < 0)
        out[cand[drop], t] = False
        if not exact_knapsack:
            continue
        rest = np.where(allowed[:, t], col, -np.inf)
        for k in np.nonzero(~drop & ~lv.x[cand, t])[0]:
            if expired(deadline):
                exact_knapsack = False   # out of time: the Dantzig test only, for the other slots
                break
            i = cand[k]
            without = rest.copy()
            without[i] = -np.inf
            _, value, _ = knapsack(data.cost, without, int(cap[k]))
            if bound - lv.slot_bound[t] + col[i] + value + margin < incumbent:
                out[i, t] = False
    return out


def _propagate(data: GapData, allowed: np.ndarray, forced: Mapping[int, int]) -> np.ndarray | None:
    """A node's arrival mask: forced items only in their slot, their lower layers no later, their
    upper layers no earlier. None when that leaves a forced item nowhere to go."""
    allowed = allowed.copy()
    d = 1 if data.strict else 0
    for i, t in forced.items():
        if not allowed[i, t]:
            return None
        allowed[i, :] = False
        allowed[i, t] = True
        lo, cap = data.lower[i], t - d
        while lo >= 0:
            allowed[lo, max(cap + 1, 0):] = False
            if not allowed[lo].any():
                return None
            cap = int(np.nonzero(allowed[lo])[0].max()) - d
            lo = data.lower[lo]
        _exclude_upper_before(data, allowed, i, t + d)
    if any(not allowed[i, t] for i, t in forced.items()):
        return None
    return allowed


def _exclude_upper_before(data: GapData, allowed: np.ndarray, i: int, floor: int) -> None:
    """In place: the layer above i cannot arrive before slot ``floor``, the one above that not
    before its own earliest allowed slot (+ d), and so on up the object."""
    d = 1 if data.strict else 0
    up = int(data.upper[i])
    while up >= 0:
        allowed[up, :min(floor, data.T)] = False
        rows = np.nonzero(allowed[up])[0]
        if len(rows) == 0:
            break
        floor = int(rows.min()) + d
        up = int(data.upper[up])


def _cumulative_split(data: GapData, x: np.ndarray) -> tuple[int, int] | None:
    """The (item, slot) whose "arrived by slot t" is most fractional in the master solution ``x``
    (mass both at or before t and after t), weighted by how much the profit drops from t to t + 1;
    among splits at no drop (most of them: an object out of view earns nothing, so its chunk's
    profit is flat over those slots) by profit. None when there is none.

    Branching where the profit is flat only moves the master's mass to an equally good slot, so
    the bound does not move (T60-J20-s4: stuck at 307,472.8 after 1,306 nodes started from the
    optimum; weighted by the drop, proven optimal in 35 nodes).
    """
    cum = np.cumsum(x, axis=1)
    split = np.minimum(cum, cum[:, -1:] - cum)
    split[split < FRACTIONAL_TOL] = 0.0
    if split.max(initial=0.0) <= 0:
        return None
    drop = np.zeros_like(data.profit)
    drop[:, :-1] = np.abs(data.profit[:, :-1] - data.profit[:, 1:])
    score = split * drop
    if score.max() <= 0:
        score = split * (1.0 + data.profit / (data.profit.max() + 1e-300))
    i, t = np.unravel_index(int(np.argmax(score)), score.shape)
    return int(i), int(t)


def _split_masks(data: GapData, mask: np.ndarray, i: int, t: int) -> tuple[np.ndarray, np.ndarray]:
    """Children of a cumulative branch: item i arrives in slots <= t (or never), or after t (or
    never); in the second, its upper layers cannot arrive before t + 1 + d either."""
    by, after = mask.copy(), mask.copy()
    by[i, t + 1:] = False
    after[i, :t + 1] = False
    _exclude_upper_before(data, after, i, t + 1 + (1 if data.strict else 0))
    return by, after


# -- the solver ---------------------------------------------------------------------------------

def solve_exact(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
                heuristics: tuple[str, ...] | None = None, max_nodes: int | None = None, lns_width: int = 8,
                branching: str = "both",
                **_ignored: Any) -> Solution:
    """Solve Problem I/III exactly (see the module doc) or stop at ``time_limit_s`` seconds.

    Returns
    -------
    Solution
        ``bound`` is the best certified bound (``details["bound_kind"]`` says which: the
        column-generation Lagrangian bound, or the closed branch-and-bound tree); ``details``
        holds the root bound, nodes, columns, fixings and a ``trace`` of (seconds, incumbent,
        bound) for gap-against-time plots.

    Raises
    ------
    SolveError
        ``slot`` given. Separate instances (Problems II/IV) go to :func:`.separate.solve_separate`,
        layered ones with the cumulative budget to :func:`.cumulative.solve_cumulative`.
    """
    started = time.perf_counter()
    # Compiled (or loaded from numba's disk cache) beside the solve; a solve without a time limit
    # may wait for them (.kernels). The pricing knapsack is needed first.
    if time_limit_s is None:
        warm_up()
    else:
        kernels.prepare(*kernels.KERNELS)
    if not instance.layered:
        # Problems II/IV: branch-and-price over per-object paths (solvers/exact/separate.py).
        from .separate import solve_separate

        return solve_separate(instance, slot=slot, time_limit_s=time_limit_s, heuristics=heuristics,
                              max_nodes=max_nodes, branching=branching)
    if slot is not None:
        raise SolveError("method 'exact' schedules the whole horizon: slot does not apply (use 'bb' for one slot)")
    if branching not in BRANCHING:
        raise SolveError(f"branching = {branching!r} is not one of {', '.join(BRANCHING)}")
    if instance.options.budget == "cumulative":
        # One sequential link: the arrived-by form (solvers/exact/cumulative.py; HiGHS is its
        # only branching, so ``branching`` and ``max_nodes`` do not apply).
        from .cumulative import solve_cumulative

        return solve_cumulative(instance, time_limit_s=time_limit_s, heuristics=heuristics)
    search = _Search(instance, started=started, time_limit_s=time_limit_s, max_nodes=max_nodes, lns_width=lns_width,
                     branching=branching)
    search.start(heuristics)
    if search.data.n == 0:
        search.bound, search.bound_kind = search.z, "no chunk can arrive"
    else:
        search.root()
        search.improve_at_root()
        search.branch()
    return search.finish()


class _Search(Clock):
    """One run of ``exact``: the incumbent ``assign`` (value ``z``), the best bound and its kind,
    the column pool and the Lagrangian certificates met, and one method per phase (start, root,
    repair and LNS at the root, the MIP side, the price side, finish). Only the MIP side may run
    in a second thread; it reads the incumbent and bound for the trace and hands its schedules over
    through ``found`` (see :meth:`branch`)."""

    def __init__(self, instance: Instance, *, started: float, time_limit_s: float | None, max_nodes: int | None,
                 lns_width: int, branching: str) -> None:
        self.instance, self.started, self.time_limit_s = instance, started, time_limit_s
        self.max_nodes, self.lns_width, self.branching = max_nodes, lns_width, branching
        self.deadline = None if time_limit_s is None else started + float(time_limit_s)
        self.data = data = gap_data(instance)
        self.allowed0 = data.allowed
        self.trace: list[tuple[float, float, float]] = []
        self.hit_limit = False
        self.anneal_skipped = False
        self.details: dict[str, Any] = {"items": data.n, "slots": data.T, "presolve": dict(data.stats)}
        self.pool = ColumnPool(data)
        self.rows: list[tuple[int, int]] = []
        self.bound = math.inf
        self.bound_kind = "none"
        self.nodes = 0
        self.certificates: list[LagrangeValue] = []
        self.assign = np.full(data.n, -1, dtype=np.int64)
        self.z = assignment_value(data, self.assign)

    def ls_deadline(self) -> float | None:
        if self.deadline is None:
            return None
        return min(self.deadline, time.perf_counter() + LOCAL_SEARCH_SHARE * float(self.time_limit_s) + 0.05)

    # -- the incumbent ---------------------------------------------------------------------------
    def try_incumbent(self, cand: np.ndarray, allowed: np.ndarray, forced: Mapping[int, int]) -> None:
        cand = local_search(self.data, cand, allowed, forced=forced, deadline=self.ls_deadline(), max_swaps=50)
        if not assignment_feasible(self.data, cand):
            return
        value = assignment_value(self.data, cand)
        if value > self.z:
            self.assign, self.z = cand, value
            self.pool.add_assignment(cand)

    def neighbourhood(self, x: np.ndarray, band: int = 0, share: float = NEIGHBOURHOOD_SHARE) -> None:
        """The LP neighbourhood MIP around ``x`` (not on small instances after the annealing: :attr:`lean`)."""
        left = self.left()
        if (left is not None and left <= 0) or _closed(self.bound, self.z) or self.lean:
            return
        cand = lp_neighbourhood(self.data, x, self.allowed0, self.z, time_limit_s=None if left is None else share * left,
                                start=self.assign, band=band, seeds=mip_seeds())
        if cand is not None:
            self.try_incumbent(cand, self.allowed0, {})

    def fixed_at(self, value: float, mask: np.ndarray, exact: bool = False) -> np.ndarray:
        """``mask`` minus the pairs that no schedule better than ``value`` uses, by every
        Lagrangian certificate met so far (``exact``: the knapsack test too, on small instances,
        for at most EXACT_FIXING_SHARE of the time left)."""
        exact = exact and self.data.n * self.data.T <= COLGEN_MAX_PAIRS
        fix_deadline = None if self.deadline is None else \
            time.perf_counter() + EXACT_FIXING_SHARE * max(self.deadline - time.perf_counter(), 0.0)
        # The knapsack test only with the tightest certificate, after every certificate's cheap test:
        # run first on the LP duals' one, it spent the whole share on pairs the root's would drop
        # anyway (J=20 s3, s9: 2.5 s for one pair) and never reached the root's.
        for lv in self.certificates:
            mask = reduced_cost_fixing(self.data, lv, lv.bound, value, mask)
        if exact and self.certificates:
            lv = min(self.certificates, key=lambda c: c.bound)
            mask = reduced_cost_fixing(self.data, lv, lv.bound, value, mask, exact_knapsack=True,
                                       deadline=fix_deadline)
        return mask

    # -- phases ----------------------------------------------------------------------------------
    def start(self, heuristics: tuple[str, ...] | None) -> None:
        """The best start heuristic (at most a fifth of the time limit), then local search."""
        data, instance = self.data, self.instance
        if heuristics is None:   # (not ``mpc:3`` before the annealing: it needs no slow start)
            mpc = instance.J * instance.L <= MPC_MAX_CHUNKS and not self.anneals
            heuristics = START_HEURISTICS + (("mpc:3",) if mpc else ())
        h_deadline = None if self.deadline is None else self.started + 0.2 * float(self.time_limit_s)
        assign, start_name, start_values = (best_start(instance, data, heuristics, h_deadline) if data.n else
                                            (np.full(0, -1, np.int64), "empty", {}))
        self.details["start"] = {"best": start_name, "values": start_values}
        self.assign = local_search(data, assign, self.allowed0, deadline=self.ls_deadline())
        self.z = assignment_value(data, self.assign)
        self.details["after_local_search"] = self.z
        if self.anneals and data.n:
            share = None if self.deadline is None else ANNEAL_SHARE * float(self.time_limit_s)
            # Its kernel loads from numba's cache beside the start heuristics; a machine's first
            # solve may still be compiling it: waited for within the share (at least
            # KERNEL_LOAD_S), then the root's repair and LNS run instead.
            wait = None if share is None else min(max(share, KERNEL_LOAD_S), self.deadline - time.perf_counter())
            if kernels.ready("anneal", wait):
                deadline = None if share is None else min(self.deadline, time.perf_counter() + share)
                cand = anneal_race(data, self.assign, seeds=ANNEAL_SEEDS or mip_seeds(), deadline=deadline,
                                   rounds=ANNEAL_ROUNDS if deadline is None else None, patience=ANNEAL_PATIENCE,
                                   stop=requested)
                self.try_incumbent(cand, self.allowed0, {})
                self.details["after_anneal"] = self.z
            else:
                self.anneal_skipped = True
                self.details["kernels"] = ("no annealing: its compiled kernel was not ready within its share "
                                           "(a machine's first solve; l3gs_opt.warm_up() compiles it)")
        self.pool.add_assignment(self.assign)

    def root(self) -> None:
        """Root LP (its duals: the first multipliers and column generation's stability centre; its
        solution rounded into a schedule), then column generation, a Lagrangian bound every round."""
        data, allowed0, T = self.data, self.allowed0, self.data.T
        lp_value, lp_mult, lp_x = lagrange.lp_multipliers(data, time_limit_s=self.left())
        start_point = None
        self.details["lp"] = {"value": lp_value, "seconds": self.now()}
        # Every Lagrangian value met is a valid fixing certificate: keep the LP duals' one too.
        if lp_mult is not None:
            lv0 = lagrange.lagrangian_value(data, lp_mult, deadline=self.deadline)
            start_point = (lp_mult, lv0)
            self.certificates.append(lv0)
            self.details["lp"]["lagrangian_at_lp_duals"] = lv0.bound
            for t in range(T):   # the knapsacks at the LP duals: first columns near the optimal duals
                self.pool.add(t, np.nonzero(lv0.x[:, t])[0])
            self.try_incumbent(round_schedule(data, lp_x, allowed0), allowed0, {})
            self.neighbourhood(lp_x)
            self.trace.append((self.now(), self.z, max(self.z, lv0.bound)))
        left = self.left()
        self.big = big = data.n * T > COLGEN_MAX_PAIRS and start_point is not None
        # A share of the time left: the primal side and the branching need the rest.
        # The master LP runs on one core: HiGHS on Problem A, fixed at the LP duals' certificate,
        # searches for schedules on the other (ROOT_MIP).
        self.new_mip_side(seeds=(0,))
        beside = None
        if start_point is not None:   # (the MIP side's trace points need a bound: without one it does not run)
            self.bound = max(start_point[1].bound, self.z)
        if (ROOT_MIP and not big and self.branching != "price" and start_point is not None
                and not _closed(self.bound, self.z)):
            self.allowed_root = self.fixed_at(self.z, allowed0)
            z0, start0 = self.z, self.assign.copy()
            beside = lambda: self.mip_side(z0, start0)   # noqa: E731
        box: dict[str, Any] = {}

        # One master LP for the root and every node (moved between them by bound changes).
        self.master = Master(data, self.pool, self.rows, allowed=allowed0, forced={})

        until = None if left is None else time.perf_counter() + (0.0 if big else COLGEN_SHARE * left)

        def price() -> None:
            cg = column_generation(
                data, self.pool, self.rows, allowed=allowed0, forced={}, incumbent=self.z,
                time_limit_s=None if left is None else (0.0 if big else COLGEN_SHARE * left),
                max_iterations=1 if big else 100_000, stall_iterations=100_000, start=start_point,
                stop=self.stop.is_set, master=self.master)
            box["converged"] = cg.converged
            box["cg"] = self.cover_rounds(cg, until) if COVER_CUTS != "off" and cg.converged else cg

        run_sides(price, beside, self.stop, name="exact-root-mip")
        self.root_cg = root = box["cg"]
        self.root_converged = bool(box["converged"])
        if root.value is not (start_point[1] if start_point else None):
            self.certificates.append(root.value)
        self.bound = max(root.bound, self.z) if math.isfinite(root.bound) else self.z
        self.bound_kind = ("Lagrangian at the LP duals (per-slot knapsacks solved exactly; column generation skipped)"
                           if big else "Lagrangian (column-generation duals; per-slot knapsacks solved exactly)")
        self.details["root"] = {"bound": root.bound, "master_lp": root.master, "iterations": root.iterations,
                                "converged": self.root_converged, "seconds": self.now(), "columns": len(self.pool),
                                "precedence_rows": len(self.rows), "colgen_skipped": bool(big)}
        if beside is not None:
            self.take_mip("root_mip")
            self.details["root_mip"].update(incumbent_before=z0, incumbent_after=self.z)
        if root.xbar.any():   # (empty when column generation was skipped)
            self.try_incumbent(round_schedule(data, root.xbar, allowed0), allowed0, {})
            self.neighbourhood(root.xbar)
        elif big and lp_x is not None and not _closed(self.bound, self.z):
            self.neighbourhood(lp_x, band=BAND_WIDTH, share=BAND_SHARE)
        self.try_incumbent(round_schedule(data, root.value.x.astype(float) + root.xbar, allowed0), allowed0, {})
        self.trace.append((self.now(), self.z, self.bound))
        self.details["root"]["repair"] = []

    def cover_rounds(self, cg: Any, until: float | None, allowed: np.ndarray | None = None,
                     forced: Mapping[int, int] | None = None, record: dict | None = None) -> Any:
        """Rounds of cover cuts (:mod:`.covers`) once column generation has converged at the root
        (or at a node: ``allowed``, ``forced``; its counts go to ``record``): the most violated
        cover of each slot's arrived-by knapsack at the master solution, then column generation
        again from the last multipliers, until no cover is violated, the gap is closed, or
        ``until`` (``time.perf_counter()`` seconds). Returns the last round's result (its bound is
        the best met: each round starts from the last one's)."""
        allowed = self.allowed0 if allowed is None else allowed
        forced = {} if forced is None else dict(forced)
        root = record is None
        if root:
            record = self.details["covers"] = {"bound_before": cg.bound, "rounds": 0, "covers": 0, "converged": True}
        while not (self.stop.is_set() or expired(until) or _closed(cg.bound, self.z)):
            cuts = separate_covers(self.data, cg.xbar, self.master.cover_keys)
            if not cuts:
                break
            self.master.add_covers(cuts)
            nxt = column_generation(
                self.data, self.pool, self.rows, allowed=allowed, forced=forced, incumbent=self.z,
                time_limit_s=None if until is None else max(until - time.perf_counter(), 0.0),
                max_iterations=100_000, stall_iterations=100_000, start_bound=cg.bound, start=(cg.mult, cg.value),
                stop=self.stop.is_set, master=self.master)
            record["rounds"] += 1
            record["covers"] = len(self.master.covers)
            record["converged"] = bool(nxt.converged)
            cg = nxt
            if not nxt.converged:
                break
        if root:
            record.update(bound_after=cg.bound, seconds=self.now())
        return cg

    def repair(self) -> None:
        """Level-keeping repair (:mod:`.repair`): a chunk gains, nobody loses; REPAIR_SHARE of the time left."""
        # By size (``big`` also needs the LP's duals back: at J=200 CP-SAT's model alone took 1.5 s)
        if _closed(self.bound, self.z) or self.data.n * self.data.T > COLGEN_MAX_PAIRS:
            return
        left = self.left()
        rep = level_repair(self.data, self.assign, self.allowed0,
                           deadline=None if left is None else time.perf_counter() + REPAIR_SHARE * left)
        self.try_incumbent(rep.assign, self.allowed0, {})
        self.details["root"]["repair"].append({"incumbent": self.z, "repairs": rep.repairs, "tried": rep.tried,
                                               "undecided": rep.undecided, "ruled_out": rep.ruled_out,
                                               "seconds": rep.seconds})
        self.trace.append((self.now(), self.z, self.bound))

    @property
    def anneals(self) -> bool:
        """The root's primal search is the annealing (:data:`ROOT_PRIMAL`), not the repair and LNS."""
        return ROOT_PRIMAL == "anneal" and self.data.n * self.data.T <= COLGEN_MAX_PAIRS and not self.anneal_skipped

    @property
    def lean(self) -> bool:
        """No LP neighbourhood MIPs at the root: the annealing runs and the instance is small
        (:data:`LEAN_ROOT_MAX_PAIRS`)."""
        return self.anneals and self.data.n * self.data.T <= LEAN_ROOT_MAX_PAIRS

    def improve_at_root(self) -> None:
        """Repair, window LNS from the repaired schedule (LNS_SHARE of the time left), repair again
        (not when the annealing ran at the start: :data:`ROOT_PRIMAL`); then fix at the incumbent
        the pairs no better schedule uses."""
        if not self.anneals:
            self._repair_and_lns()
        self.allowed_root = self.fixed_at(self.z, self.allowed0, exact=True)
        self.details["root"]["fixed_pairs"] = int(self.allowed0.sum() - self.allowed_root.sum())
        self.details["root"]["incumbent"] = self.z

    def _repair_and_lns(self) -> None:
        self.repair()
        if not _closed(self.bound, self.z):
            left = self.left()
            lns_deadline = None if left is None else time.perf_counter() + LNS_SHARE * left
            cand = window_sweep(self.data, self.assign, self.allowed0, width=self.lns_width, deadline=lns_deadline)
            self.try_incumbent(cand, self.allowed0, {})
            self.details["root"]["after_lns"] = self.z
            self.trace.append((self.now(), self.z, self.bound))
        self.repair()

    def branch(self) -> None:
        """The MIP side and the price side: together (the MIP side in a second thread: highspy
        releases the GIL), or one alone; whichever closes the gap first stops the other."""
        branching = self.branching
        use_mip = branching in ("both", "mip") and not _closed(self.bound, self.z) and not self.out_of_time()
        # Column generation at every node is too slow where it is skipped at the root (large instances)
        # or did not converge there in its share (J=50: 2-3 real nodes in the 30 s after the root); the
        # second core then runs another HiGHS instead.
        use_price = branching == "price" or (branching == "both" and not self.big and self.root_converged)
        # Alone, the MIP side races HiGHS runs on the cores; beside the price side it has one.
        self.new_mip_side(seeds=(0,) if use_price else mip_seeds())
        run_sides(self.price_side if use_price else None,
                  (lambda: self.mip_side(self.z, self.assign.copy())) if use_mip else None, self.stop, name="exact-mip")
        self.take_mip("reduced_mip" if use_mip else None)
        if use_mip:
            self.hit_limit = self.mip["hit_limit"]
        self.bound = max(self.bound, self.z)
        self.trace.append((self.now(), self.z, self.bound))

    def new_mip_side(self, seeds: tuple[int, ...]) -> None:
        """Fresh state for one run of :meth:`mip_side` (HiGHS runs raced over ``seeds``)."""
        self.found: list[np.ndarray] = []     # schedules the MIP side found, handed to the main thread
        self.stop = threading.Event()          # set when one side has closed the gap (or at the end)
        self.mip: dict[str, Any] = {"bound": math.inf, "kind": "", "hit_limit": False, "runs": []}
        self.mip_seeds = seeds

    def take_mip(self, key: str | None) -> None:
        """After the MIP side has returned: raise its error, take its schedules, and (``key``: it
        ran) record its runs under ``details[key]`` and take its bound when smaller."""
        mip = self.mip
        if "error" in mip:
            raise mip["error"]
        self.take_found()
        if key is None:
            return
        self.details[key] = ({**mip["runs"][-1], "variables": mip["runs"][0]["variables"],
                              "runs": mip["runs"]} if mip["runs"] else {})
        if max(self.z, mip["bound"]) < self.bound:
            self.bound, self.bound_kind = max(self.z, mip["bound"]), mip["kind"]

    def take_found(self) -> None:
        while self.found:
            self.try_incumbent(self.found.pop(), self.allowed0, {})

    def mip_side(self, zh: float, start: np.ndarray) -> None:
        """HiGHS on the model reduced by Lagrangian fixing, cut off at ``zh``; each time it finds
        a schedule at which fixing would drop enough pairs, it is stopped, the fixing redone at
        the new incumbent and HiGHS restarted from it on the smaller model. Touches no shared
        state but ``found`` and ``mip`` (it may run in its own thread, next to the pricing);
        an exception is kept in ``mip["error"]`` and raised again by the caller."""
        try:
            self._mip_runs(zh, start)
        except BaseException as exc:
            self.mip["error"] = exc
            self.stop.set()

    def _mip_runs(self, zh: float, start: np.ndarray) -> None:
        data, mip, stop = self.data, self.mip, self.stop
        mask = self.allowed_root
        may_restart = True
        while not stop.is_set():
            left = self.left()
            if left is not None:
                left -= MIP_MARGIN_S + MIP_MARGIN_PER_PAIR_S * float(mask.sum())
                if left <= 0:
                    mip["hit_limit"] = True
                    break
            size = int(mask.sum())

            def restart_if(value: float, mask: np.ndarray = mask, size: int = size) -> bool:
                return value > zh and int(self.fixed_at(value, mask).sum()) <= RESTART_SHRINK * size

            z_before = zh
            outcome, cand, mip_bound = reduced_mip(data, mask, zh, time_limit_s=left, start=start,
                                                   restart_if=restart_if if may_restart else None,
                                                   stop=stop.is_set, seeds=self.mip_seeds,
                                                   covers=tuple(self.master.covers))
            if cand is not None:   # (feasible in exact bytes and better than zh: reduced_mip checks)
                self.found.append(cand)
                zh, start = assignment_value(data, cand), cand
            mip["runs"].append({"outcome": outcome, "bound": mip_bound, "variables": size, "seconds": self.now()})
            if outcome == "optimal":
                # Nothing in the mask beats max(z_before, what HiGHS returned), and every
                # schedule better than z_before lies in the mask.
                mip["bound"] = zh
                mip["kind"] = ("Lagrangian reduced-cost fixing, then HiGHS branch-and-cut on the reduced model "
                               "(cut off at the incumbent): closed")
                stop.set()
            elif max(z_before, mip_bound) < mip["bound"]:
                mip["bound"] = max(z_before, mip_bound)
                mip["kind"] = "HiGHS dual bound on the model reduced by Lagrangian fixing"
            self.trace.append((self.now(), max(self.z, zh), min(self.bound, mip["bound"])))
            if outcome != "restart":
                mip["hit_limit"] = outcome == "time_limit"
                break
            # (HiGHS's schedule failing the exact check would restart forever: run on instead.)
            may_restart = zh > z_before
            mask = self.fixed_at(zh, mask, exact=True)

    def price_side(self) -> None:
        """Best-first branch-and-price (over bands of BOUND_BAND, newest first within one). Heap
        entries: (band key, tie, bound, forced, allowed mask, root result, the parent's master basis)."""
        data, stop, max_nodes = self.data, self.stop, self.max_nodes
        counter = itertools.count()
        unresolved = -math.inf
        heap: list = []
        band = BOUND_BAND * abs(self.bound) if math.isfinite(self.bound) else 0.0

        def key(b: float) -> float:
            return -b if band == 0 else -math.floor(b / band)

        node_covers = ({"rounds": 0, "covers": 0, "converged": True} if COVER_CUTS == "nodes" else None)
        if node_covers is not None:
            self.details["node_covers"] = node_covers
        if not _closed(self.bound, self.z):
            heap.append((key(self.bound), 0, self.bound, {}, self.allowed_root, self.root_cg, None))
        while heap and not stop.is_set() and not self.out_of_time() and (max_nodes is None or self.nodes < max_nodes):
            self.take_found()
            _, _, node_bound, forced, allowed, pre, basis = heapq.heappop(heap)
            if _closed(node_bound, self.z):
                continue
            self.nodes += 1
            if pre is None:
                mask = _propagate(data, allowed, forced)
                if mask is None:
                    continue
                cg = column_generation(data, self.pool, self.rows, allowed=mask, forced=forced, incumbent=self.z,
                                       time_limit_s=self.left(), start_bound=node_bound, stall_iterations=8,
                                       master=self.master, basis=basis)
                if cg.infeasible:
                    continue
                if COVER_CUTS == "nodes" and cg.converged:
                    cg = self.cover_rounds(cg, self.deadline, mask, forced, record=node_covers)
                node_bound = min(node_bound, cg.bound)
                self.try_incumbent(round_schedule(data, cg.xbar, mask, forced=forced), mask, forced)
                if (self.out_of_time() or stop.is_set()) and not _closed(node_bound, self.z):
                    heapq.heappush(heap, (key(node_bound), -next(counter), node_bound, forced, allowed, None, basis))
                    break
            else:
                mask, cg = allowed, pre
            if _closed(node_bound, self.z):
                continue
            mask = reduced_cost_fixing(data, cg.value, cg.value.bound, self.z, mask) \
                if cg.value.bound <= node_bound else mask
            children = _children(data, cg, mask, forced)
            if children is None:
                # Nothing left to branch on: keep the node's bound in the answer's bound.
                unresolved = max(unresolved, node_bound)
                continue
            # The children start their master from this node's last basis (PARENT_BASIS).
            basis = self.master.snapshot() if PARENT_BASIS else None
            for child_forced, child_mask in children:
                heapq.heappush(heap, (key(node_bound), -next(counter), node_bound, child_forced, child_mask, None, basis))
            self.trace.append((self.now(), self.z,
                               min(self.mip["bound"], max(self.z, max((h[2] for h in heap), default=self.z)))))
        open_bound = max([h[2] for h in heap if not _closed(h[2], self.z)] + [unresolved], default=-math.inf)
        price_bound = min(max(self.z, open_bound), max(self.root_cg.bound, self.z))
        if open_bound == -math.inf:
            stop.set()   # the tree is closed: the MIP side may stop
        if price_bound < self.bound:
            self.bound = price_bound
            self.bound_kind = ("branch-and-price tree closed (every node's Lagrangian bound <= incumbent)"
                               if open_bound == -math.inf else
                               "branch-and-price: the largest Lagrangian bound of the open nodes")

    def finish(self) -> Solution:
        """Status and gap, decided once (through :func:`relative_gap`), and the checked solution."""
        stopped = self.hit_limit or self.out_of_time() or (self.max_nodes is not None and self.nodes >= self.max_nodes)
        gap = relative_gap(self.z, self.bound, utility_scale(self.instance))
        if gap is not None and gap <= GAP_TOL:
            status, message = Status.OPTIMAL, ""
        elif stopped:
            status = Status.TIME_LIMIT
            message = f"stopped after {self.nodes} node(s): best schedule and a valid bound ({self.bound_kind})"
        else:
            status, message = Status.FEASIBLE, f"search ended without proof ({self.bound_kind})"
        self.details.update({"bound_kind": self.bound_kind, "nodes": self.nodes, "columns": len(self.pool),
                             "precedence_rows": len(self.rows), "trace": self.trace})
        return finish_solution(self.instance, self.data.arrivals(self.assign), problem=self.instance.problem,
                               method="exact", status=status, bound=self.bound,
                               runtime_s=time.perf_counter() - self.started, message=message, details=self.details)


def _children(data: GapData, cg: Any, mask: np.ndarray, forced: Mapping[int, int]
              ) -> list[tuple[dict[int, int], np.ndarray]] | None:
    """The two children of a node, or None when there is nothing left to branch on.

    Branch on the most fractional "arrived by slot t" weighted by the profit drop there (see
    :func:`_cumulative_split`); when that is integral, on the most fractional ``x[i,t]`` (ties:
    larger profit), then on a pair the knapsacks chose that the master did not.
    """
    x = cg.xbar
    split = _cumulative_split(data, x)
    if split is not None:
        by, after = _split_masks(data, mask, *split)
        return [(dict(forced), by), (dict(forced), after)]
    frac = np.minimum(x, 1.0 - x) * (mask & (x > FRACTIONAL_TOL) & (x < 1 - FRACTIONAL_TOL))
    if frac.max(initial=0.0) > 0:
        # Profits may be negative (signed layer utilities): weight by their size, in [0, 2].
        score = frac * (1.0 + data.profit / (np.abs(data.profit).max() + 1e-300))
        i, t = np.unravel_index(int(np.argmax(score)), score.shape)
    else:
        diff = cg.value.x & (x < 0.5) & mask
        for i_f in forced:
            diff[i_f, :] = False
        if not diff.any():
            diff = (x > 0.5) & mask
            for i_f in forced:
                diff[i_f, :] = False
        if not diff.any():
            return None
        # Among the candidates only (a negative profit must not lose to a non-candidate's 0).
        i, t = np.unravel_index(int(np.argmax(np.where(diff, data.profit, -np.inf))), diff.shape)
    i, t = int(i), int(t)
    mask_zero = mask.copy()
    mask_zero[i, t] = False
    return [({**forced, i: t}, mask), (dict(forced), mask_zero)]
