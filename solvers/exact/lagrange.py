"""Problem A (the GAP form) as arrays, and its Lagrangian relaxation with per-slot knapsacks.

Problem A, for layered instances (Problems I and III)::

    max  sum_{i,t} P[i,t] x[i,t]
    s.t. sum_i c[i] x[i,t] <= B[t]                              (budget of slot t)
         sum_t x[i,t] <= 1                                       (at most once; multiplier mu[i])
         sum_{s<=t} x[u,s] - sum_{s<=t-d} x[lo(u),s] <= 0          (precedence; multiplier pi[u,t])

where ``i`` runs over the chunks (j, l) presolve keeps, ``P[i,t]`` is the utility chunk i earns
from arriving in slot t to the horizon (``dU~`` of docs/design.md), ``lo(u)`` is the layer under u
(when it is not held) and ``d`` is 0 (same-slot layers) or 1 (strict). Dualising the two
linking families leaves one 0-1 knapsack per slot with reduced profits

    p~[i,t] = P[i,t] - mu[i] - sum_{t'>=t} pi[i,t'] + sum_{t'>=t+d} pi[up(i),t'],

solved exactly by the single-slot branch-and-bound (:func:`l3gs_opt.solvers._mckp.branch_and_bound`,
one option per row). ``L(mu, pi) = sum_t max(0, K_t(p~)) + sum_i mu[i]`` is an upper bound on the
optimum for every ``mu, pi >= 0`` (plus the held chunks' constant utility); because each
knapsack is solved in integers it is at least as tight as the LP relaxation at its optimal
multipliers. Cover rows of the arrived-by knapsacks (:class:`Cover`, ``sum_{i in S} sum_{s<=t}
x[i,s] <= |S| - 1``) may be dualised too (multiplier ``d``): each lowers ``p~[i,s]`` by ``d`` for
the chunks of S in slots ``s <= t`` and adds ``(|S| - 1) d`` to ``L``, so the bound stays one
knapsack per slot (:mod:`.covers`).

Options: ``availability="next_slot"`` shifts ``P`` by one slot, ``same_slot_layers=False`` sets
``d = 1``. The ``cumulative`` budget couples the slots, so Problem A has no per-slot knapsack:
``gap_data`` rejects it (:mod:`.cumulative_data` writes such instances over "arrived by slot t",
where it has). The separate representation
(Problems II/IV, whose objective is a max over versions) is not Problem A: ``exact`` solves it
over per-object paths (:mod:`.separate`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from l3gs_opt import stop
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import presolve

from .. import _mckp
from . import kernels
from . import pricing

__all__ = ["ChunkItems", "GapData", "gap_data", "chunk_arrays", "Cover", "Multipliers", "LagrangeValue", "knapsack", "reduced_profits",
           "lagrangian_value", "PolyakStep", "subgradient", "lp_multipliers", "assignment_value", "assignment_feasible",
           "chunk_profits", "into_presolve_slots"]

_EPS = np.finfo(np.float64).eps


class ChunkItems:
    """Chunks as items ``i`` (object ``item_j[i]``, layer ``item_l[i]``, ``cost[i]`` bytes): the
    assignment form of a schedule (slot per item, -1 = never) and back."""

    item_j: np.ndarray
    item_l: np.ndarray
    cost: np.ndarray

    @property
    def n(self) -> int:
        return int(self.cost.shape[0])

    def arrivals(self, assign: np.ndarray) -> list[tuple[int, int, int]]:
        """Arrivals ``(j, l, t)`` of an assignment."""
        return [(int(self.item_j[i]), int(self.item_l[i]), int(assign[i])) for i in np.nonzero(assign >= 0)[0]]

    def assignment(self, arrivals) -> np.ndarray:
        """The assignment of a schedule; chunks presolve dropped are ignored (they add nothing and
        need no bytes in any optimal schedule)."""
        index = {(int(j), int(l)): i for i, (j, l) in enumerate(zip(self.item_j, self.item_l))}
        out = np.full(self.n, -1, dtype=np.int64)
        for j, l, t in arrivals:
            i = index.get((int(j), int(l)))
            if i is not None:
                out[i] = int(t)
        return out


def into_presolve_slots(data, assign: np.ndarray, *, wait: bool) -> np.ndarray:
    """A feasible schedule ``assign`` moved inside ``data.allowed`` [n, T] (presolve's slots) at the
    same value: an arrival outside them waits for the chunk's next allowed slot (``wait``: the
    cumulative budget, where a chunk only arrives in its event slots and waiting loosens every row
    in between) or is dropped (per-slot budgets, where the slots left out are those after the
    chunk's last event slot: it is worth nothing there). Layers above go first; presolve's closure
    (a layer's event slots include those the layer above needs it by) keeps the layer order."""
    out = assign.copy()
    for i in np.argsort(-data.item_l, kind="stable"):
        t = int(out[i])
        if t < 0 or data.allowed[i, t]:
            continue
        later = np.nonzero(data.allowed[i, t:])[0] if wait else ()
        out[i] = t + int(later[0]) if len(later) else -1
    return out


@dataclass(frozen=True, eq=False)
class GapData(ChunkItems):
    """Problem A of a layered instance over the chunks presolve keeps.

    Attributes
    ----------
    item_j, item_l : int arrays [n]
        Object and layer of each chunk (items listed by object, then layer).
    cost : int64 array [n]
        Bytes of each chunk.
    profit : float64 array [n, T]
        ``P[i,t]``: utility earned by arriving in slot t (summed from the first slot it is shown
        to the horizon); 0 where the chunk cannot arrive.
    allowed : bool array [n, T]
        Chunk i may arrive in slot t (presolve: it fits, its lower layer can be there by then).
    lower, upper : int arrays [n]
        The item of the layer below / above (-1: none, or the layer below is held).
    strict : bool
        Layer l must arrive strictly after layer l-1 (``same_slot_layers=False``).
    budget : int64 array [T]
        Bytes per slot.
    constant : float
        Utility of the held chunks over the horizon.
    """

    T: int
    item_j: np.ndarray
    item_l: np.ndarray
    cost: np.ndarray
    profit: np.ndarray
    allowed: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    strict: bool
    budget: np.ndarray
    constant: float
    stats: dict = field(default_factory=dict)

    def assignment(self, arrivals) -> np.ndarray:
        """The assignment of a schedule (chunks presolve dropped are ignored), inside presolve's
        slots (:func:`into_presolve_slots`: a heuristic may send a chunk where it is worth nothing)."""
        return into_presolve_slots(self, ChunkItems.assignment(self, arrivals), wait=False)


def check_supported(instance: Instance, method: str = "exact") -> None:
    """Raise :class:`SolveError` for what the per-slot decomposition cannot express."""
    if not instance.layered:
        raise SolveError(f"method {method!r}: Problem A is the layered form; the separate representation (Problem "
                         f"{instance.problem}) is solved over per-object paths (solvers/exact/separate.py)")
    if instance.options.budget == "cumulative":
        raise SolveError(f"method {method!r}: budget 'cumulative' couples all slots, so Problem A does not split "
                         "into per-slot knapsacks; its arrived-by form does (solvers/exact/cumulative.py)")


def chunk_arrays(instance: Instance) -> tuple:
    """The chunks presolve keeps of a layered instance, for either budget.

    Returns ``(reduction, item_j, item_l, lower, upper, allowed, shown, future)``: ``allowed``
    [n, T] the slots a chunk may arrive in, ``shown`` [n, T] the value of "arrived by t" (presolve's
    gain shifted by the availability option), ``future`` [n, T] its suffix sums (the value of
    arriving in slot t).
    """
    inst = instance
    red = presolve(inst)
    T = inst.T
    shift = 1 if inst.options.availability == "next_slot" else 0
    gain = np.moveaxis(red.gain, 0, -1)                    # [J, L, T]: value of "shown at t"
    shown = np.zeros_like(gain)
    shown[:, :, :T - shift] = gain[:, :, shift:]          # value of "arrived by t"
    jj, ll = np.nonzero(red.active)
    n = len(jj)
    index = -np.ones((inst.J, inst.L), dtype=np.int64)
    index[jj, ll] = np.arange(n)
    lower = np.where(ll > 0, index[jj, np.maximum(ll - 1, 0)], -1)
    upper = -np.ones(n, dtype=np.int64)
    upper[lower[lower >= 0]] = np.nonzero(lower >= 0)[0]
    allowed = red.arrive[jj, ll, :].copy()
    # Presolve keeps the lower layer of every active layer active (or held); a chunk whose
    # lower layer is neither is never deliverable.
    orphan = (ll > 0) & (lower < 0) & ~inst.held[jj, np.maximum(ll - 1, 0)]
    allowed[orphan] = False
    shown = shown[jj, ll, :]
    future = np.flip(np.cumsum(np.flip(shown, axis=1), axis=1), axis=1)
    return red, jj.astype(np.int64), ll.astype(np.int64), lower.astype(np.int64), upper, allowed, shown, future


def gap_data(instance: Instance) -> GapData:
    """Problem A of a layered, per-slot-budget instance (see the module doc).

    Raises
    ------
    SolveError
        Separate representation or cumulative budget (see :func:`check_supported`).
    """
    check_supported(instance)
    inst = instance
    red, jj, ll, lower, upper, allowed, _, future = chunk_arrays(inst)
    profit = np.where(allowed, future, 0.0)
    return GapData(T=inst.T, item_j=jj, item_l=ll, cost=inst.cost[jj, ll].astype(np.int64),
                   profit=profit, allowed=allowed, lower=lower, upper=upper,
                   strict=not inst.options.same_slot_layers, budget=inst.bandwidth.astype(np.int64),
                   constant=red.constant, stats=dict(red.stats))


# -- schedules in item form ---------------------------------------------------------------------

def chunk_profits(data: GapData, assign: np.ndarray) -> np.ndarray:
    """``P[i, assign[i]]`` per chunk (0 for a chunk that does not arrive)."""
    on = assign >= 0
    out = np.zeros(data.n)
    out[on] = data.profit[np.nonzero(on)[0], assign[on]]
    return out


def assignment_value(data: GapData, assign: np.ndarray) -> float:
    """Objective of an assignment (held constant included), as an exactly rounded sum; any data
    with ``profit`` [n, T] (value of arriving in slot t) and ``constant`` (also the cumulative
    budget's :class:`.cumulative_data.LinkData`)."""
    on = np.nonzero(assign >= 0)[0]
    return math.fsum([data.constant, *data.profit[on, assign[on]].tolist()])


def assignment_feasible(data: GapData, assign: np.ndarray, allowed: np.ndarray | None = None) -> bool:
    """Budgets (integer bytes), precedence and the allowed mask hold."""
    allowed = data.allowed if allowed is None else allowed
    on = assign >= 0
    if (on & ~allowed[np.arange(data.n), np.maximum(assign, 0)]).any():
        return False
    spent = [0] * data.T   # Python ints: exact bytes
    for i in np.nonzero(on)[0]:
        spent[assign[i]] += int(data.cost[i])
    if any(spent[t] > int(data.budget[t]) for t in range(data.T)):
        return False
    has = data.lower >= 0
    u = np.nonzero(has & on)[0]
    lo = data.lower[u]
    if (assign[lo] < 0).any():
        return False
    gap = assign[u] - assign[lo]
    return bool((gap >= (1 if data.strict else 0)).all())


# -- the Lagrangian ---------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Cover:
    """A cover of the arrived-by knapsack of slot ``slot``: chunks ``items`` whose bytes exceed
    those of slots ``0..slot`` together, so at most ``len(items) - 1`` of them arrive by then
    (``sum_{i in items} sum_{s <= slot} x[i,s] <= len(items) - 1``; valid under per-slot budgets)."""

    items: np.ndarray
    slot: int

    def __post_init__(self) -> None:
        # Sorted, distinct and read-only: covers are told apart by (slot, items.tobytes()).
        items = np.unique(np.asarray(self.items, dtype=np.int64))
        if items.ndim != 1 or len(items) == 0 or items[0] < 0 or int(self.slot) < 0:
            raise ValueError(f"Cover: items must be distinct chunk indices >= 0 and slot >= 0, got {self.items!r}, "
                             f"{self.slot!r}")
        items.setflags(write=False)
        object.__setattr__(self, "items", items)
        object.__setattr__(self, "slot", int(self.slot))


@dataclass(eq=False)
class Multipliers:
    """``mu`` [n] for at-most-once rows, ``pi`` [n, T] for precedence rows (row (u, t); 0 for
    items without a lower layer), ``cover`` [k] for the cover rows ``covers`` (none by default).
    All >= 0."""

    mu: np.ndarray
    pi: np.ndarray
    cover: np.ndarray = field(default_factory=lambda: np.zeros(0))
    covers: tuple[Cover, ...] = ()

    @classmethod
    def zeros(cls, data: GapData) -> "Multipliers":
        return cls(np.zeros(data.n), np.zeros((data.n, data.T)))

    def copy(self) -> "Multipliers":
        return Multipliers(self.mu.copy(), self.pi.copy(), self.cover.copy(), self.covers)

    def blend(self, other: "Multipliers", weight: float) -> "Multipliers":
        """``weight * self + (1 - weight) * other``. Cover rows are only ever appended, so one
        list of covers is the start of the other; a row missing from one has multiplier 0 there."""
        covers = self.covers if len(self.covers) >= len(other.covers) else other.covers
        k = len(covers)
        mine, theirs = np.zeros(k), np.zeros(k)
        mine[:len(self.cover)] = self.cover
        theirs[:len(other.cover)] = other.cover
        return Multipliers(weight * self.mu + (1 - weight) * other.mu, weight * self.pi + (1 - weight) * other.pi,
                           weight * mine + (1 - weight) * theirs, covers)

    def cover_charge(self, data: GapData) -> np.ndarray:
        """``[n, T]``: what the cover rows take from chunk i's reduced profit in slot s, the sum
        of the multipliers of the covers that hold i and whose slot is s or later."""
        per_slot = np.zeros((data.n, data.T))
        for d, cov in zip(self.cover.tolist(), self.covers):
            if d > 0:
                per_slot[cov.items, cov.slot] += d
        return np.flip(np.cumsum(np.flip(per_slot, axis=1), axis=1), axis=1)

    def cover_constant(self) -> list[float]:
        """The cover rows' right-hand sides times their multipliers (terms of the Lagrangian)."""
        return [(len(cov.items) - 1) * d for d, cov in zip(self.cover.tolist(), self.covers) if d > 0]


@dataclass(eq=False)
class LagrangeValue:
    """``L(mu, pi)`` and the knapsack solutions behind it.

    ``bound`` is valid (float round-off included); ``x`` [n, T] the per-slot knapsack choices;
    ``slot_bound`` [T] each slot's knapsack bound (>= 0); ``exact`` whether every knapsack was
    solved to optimality (else ``slot_bound`` is the solver's bound).
    """

    bound: float
    x: np.ndarray
    slot_bound: np.ndarray
    reduced: np.ndarray
    exact: bool


def reduced_profits(data: GapData, mult: Multipliers) -> np.ndarray:
    """``p~[i,t]`` (see the module doc), ``[n, T]``; ``-inf`` where the item may not arrive."""
    # Only items with a lower layer have precedence rows: other entries of pi are ignored.
    pi = np.where((data.lower >= 0)[:, None], mult.pi, 0.0)
    suffix = np.flip(np.cumsum(np.flip(pi, axis=1), axis=1), axis=1)   # sum_{t'>=t} pi[i,t']
    red = data.profit - mult.mu[:, None] - suffix
    has_up = data.upper >= 0
    if has_up.any():
        up = suffix[data.upper[has_up]]
        if data.strict:
            up = np.concatenate([up[:, 1:], np.zeros((up.shape[0], 1))], axis=1)
        red[has_up] += up
    if mult.covers:
        red -= mult.cover_charge(data)
    return np.where(data.allowed, red, -np.inf)


#: Largest pricing knapsack the compiled depth-first search takes first (items with a positive
#: reduced profit that fit): beyond it, node counts can grow past its limit.
PRICING_MAX_ITEMS = 400


def knapsack(cost: np.ndarray, value: np.ndarray, capacity: int, *,
             time_limit_s: float | None = None) -> tuple[np.ndarray, float, bool]:
    """0-1 knapsack: (chosen positions, upper bound, optimal).

    Up to :data:`PRICING_MAX_ITEMS` items, the compiled depth-first search of :mod:`.pricing`
    (its optimum; the callers add the round-off slack); when it is absent, not compiled yet
    (:mod:`.kernels`) or gives up, the
    single-slot branch-and-bound (its bound: the optimum plus its relative slack when optimal).
    Items with value <= 0 or cost > capacity are never chosen.
    """
    take = np.nonzero((value > 0) & (cost <= capacity))[0]
    if len(take) == 0 or capacity <= 0:
        return np.zeros(0, dtype=np.int64), 0.0, True
    if int(cost[take].sum()) <= capacity:
        return take, math.fsum(value[take].tolist()), True
    # (while the compiled search is still compiling, on a machine's first solve, bb takes its turn)
    if pricing.available() and len(take) <= PRICING_MAX_ITEMS and kernels.ready("pricing"):
        chosen, best, done = pricing.solve_kp01_float(cost[take], value[take], int(capacity))
        if done:   # exact up to float round-off, which the callers' slack covers
            return take[chosen], best, True
    table = _mckp.build_table(layered=False, cost=cost[take, None], gain=value[take, None],
                              held=np.zeros((len(take), 1), bool), budget=int(capacity))
    res = _mckp.branch_and_bound(table, time_limit_s=time_limit_s)
    rows = table.rows[res.choice >= 0]
    return take[rows], float(res.bound), bool(res.optimal)


def lagrangian_value(data: GapData, mult: Multipliers, *, allowed: np.ndarray | None = None,
                     forced: dict[int, int] | None = None, deadline: float | None = None) -> LagrangeValue:
    """``L(mu, pi)`` with per-slot knapsacks solved exactly, or until ``deadline``
    (``time.perf_counter()`` seconds): a knapsack stopped there contributes its branch-and-bound
    upper bound, so the value stays a valid bound (``exact`` false).

    ``allowed`` narrows the arrivals (a branch-and-bound node); ``forced`` maps item -> slot
    for items fixed to arrive there (their reduced profit is earned and their bytes reserved).
    Returns ``bound = -inf`` when the forced items of a slot exceed its budget.
    """
    red = reduced_profits(data, mult)
    if allowed is not None:
        red = np.where(allowed, red, -np.inf)
    forced = forced or {}
    T = data.T
    x = np.zeros((data.n, T), dtype=bool)
    slot_bound = np.zeros(T)
    exact = True
    covers = mult.cover_constant()
    magnitude = float(mult.mu.sum()) + math.fsum(covers) + float(mult.cover.sum())
    by_slot: dict[int, list[int]] = {}
    for i, t in forced.items():
        by_slot.setdefault(t, []).append(i)
    for t in range(T):
        fixed = by_slot.get(t, [])
        cap = int(data.budget[t]) - sum(int(data.cost[i]) for i in fixed)
        if cap < 0:
            return LagrangeValue(-math.inf, x, slot_bound, red, True)
        col = red[:, t].copy()
        base = math.fsum(col[fixed].tolist()) if fixed else 0.0
        col[fixed] = -np.inf
        left = None if deadline is None else max(deadline - time.perf_counter(), 0.01)
        chosen, value, optimal = knapsack(data.cost, col, cap, time_limit_s=left)
        exact &= optimal
        x[chosen, t] = True
        x[fixed, t] = True
        # Without forced items an empty slot is always possible: the slot's value is >= 0.
        slot_bound[t] = base + value if fixed else max(0.0, value)
        magnitude += float(np.abs(col[chosen]).sum()) + abs(base)
    # Round-off: each p~ is a sum of at most T + 3 terms and a cover charge (a sum over the
    # covers), each slot a sum of at most n terms.
    slack = 4 * (data.T + data.n + len(mult.covers) + 4) * _EPS * (magnitude + float(np.abs(data.profit).max(initial=0.0)))
    bound = math.fsum([data.constant, *slot_bound.tolist(), *mult.mu.tolist(), *covers]) + slack
    return LagrangeValue(bound, x, slot_bound, red, exact)


def _subgradient(data: GapData, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row activities of the dualised rows at the knapsack solution: (once - 1, precedence)."""
    g_mu = x.sum(axis=1) - 1.0
    cum = np.cumsum(x, axis=1).astype(np.float64)
    g_pi = np.zeros_like(cum)
    has = data.lower >= 0
    lo = cum[data.lower[has]]
    if data.strict:
        lo = np.concatenate([np.zeros((lo.shape[0], 1)), lo[:, :-1]], axis=1)
    g_pi[has] = cum[has] - lo
    return g_mu, g_pi


class PolyakStep:
    """The subgradient step of both Lagrangians (this one and :mod:`.cumulative_data`'s): Polyak's
    ``theta (L - target) / |g|^2``, ``theta`` halved after ``STALL`` iterations without a better
    bound, spent once it falls below ``THETA_MIN``."""

    STALL, THETA_MIN = 5, 1e-4

    def __init__(self) -> None:
        self.theta, self.stall = 1.0, 0

    def size(self, value: float, target: float, norm: float) -> float:
        return self.theta * (value - target) / norm

    def record(self, better: bool) -> bool:
        """One iteration (``better``: it lowered the best bound); False once the step is spent."""
        if better:
            self.stall = 0
            return True
        self.stall += 1
        if self.stall >= self.STALL:
            self.theta, self.stall = self.theta / 2, 0
        return self.theta >= self.THETA_MIN


def subgradient(data: GapData, *, target: float, start: Multipliers | None = None, iterations: int = 200,
                time_limit_s: float | None = None, allowed: np.ndarray | None = None,
                forced: dict[int, int] | None = None,
                trace: list | None = None) -> tuple[float, Multipliers, LagrangeValue]:
    """Minimise ``L(mu, pi)`` by the subgradient method with Polyak steps towards ``target``
    (a lower bound on the optimum, e.g. the incumbent's value).

    Returns the best bound, its multipliers and the value at them. ``trace`` (if given) gets
    ``(seconds, bound)`` after every iteration.
    """
    started = time.perf_counter()
    mult = start.copy() if start is not None else Multipliers(np.zeros(data.n), np.zeros((data.n, data.T)))
    best_val = lagrangian_value(data, mult, allowed=allowed, forced=forced)
    best, best_mult = best_val.bound, mult.copy()
    val = best_val
    schedule = PolyakStep()
    has = (data.lower >= 0)[:, None]
    for _ in range(iterations):
        if stop.expired(None if time_limit_s is None else started + time_limit_s):
            break
        g_mu, g_pi = _subgradient(data, val.x)
        # Only the directions that can move count (a multiplier at 0 with a negative row activity stays).
        g_mu = np.where((mult.mu <= 0) & (g_mu < 0), 0.0, g_mu)
        g_pi = np.where(has & ~((mult.pi <= 0) & (g_pi < 0)), g_pi, 0.0)
        norm = float((g_mu ** 2).sum() + (g_pi ** 2).sum())
        if norm == 0 or val.bound <= target:
            break
        step = schedule.size(val.bound, target, norm)
        mult = Multipliers(np.maximum(0.0, mult.mu + step * g_mu), np.maximum(0.0, mult.pi + step * g_pi))
        val = lagrangian_value(data, mult, allowed=allowed, forced=forced)
        better = val.bound < best - 1e-12 * abs(best)
        if better:
            best, best_mult, best_val = val.bound, mult.copy(), val
        if not schedule.record(better):
            break
        if trace is not None:
            trace.append((time.perf_counter() - started, best))
    return best, best_mult, best_val


def lp_multipliers(data: GapData, *, time_limit_s: float | None = None
                   ) -> tuple[float | None, Multipliers | None, np.ndarray | None]:
    """LP relaxation of Problem A (HiGHS): its value, its row duals as Lagrangian multipliers, and
    its solution ``x`` [n, T].

    The LP is written with cumulative variables ``Y[i,t] = Y[i,t-1] + x[i,t]`` so that a
    precedence row is ``Y[u,t] - Y[lo,t-d] <= 0`` (two non-zeros) and at most once is
    ``Y[i,T-1] <= 1``; substituting Y gives Problem A's rows, so their duals are ``pi`` and
    ``mu``. ``L(mu, pi)`` at these duals is at most the LP value (each knapsack is solved in
    integers) and, unlike the LP value, a bound that does not depend on the LP's tolerances.
    Returns ``(None, None, None)`` when HiGHS gives no optimal LP.
    """
    from scipy import sparse

    n, T = data.n, data.T
    if n == 0:
        return data.constant, Multipliers.zeros(data), np.zeros((0, T))
    d = 1 if data.strict else 0
    nx = n * T
    X = np.arange(nx).reshape(n, T)            # x[i,t]
    Y = nx + np.arange(nx).reshape(n, T)       # Y[i,t]
    rows_i, cols_i, vals = [], [], []
    lo_b, up_b = [], []
    r = 0
    # Definitions: Y[i,t] - Y[i,t-1] - x[i,t] = 0.
    ii, tt = np.meshgrid(np.arange(n), np.arange(T), indexing="ij")
    defn = r + (ii * T + tt)
    rows_i += [defn.ravel(), defn.ravel(), defn[:, 1:].ravel()]
    cols_i += [Y.ravel(), X.ravel(), Y[:, :-1].ravel()]
    vals += [np.ones(nx), -np.ones(nx), -np.ones(n * (T - 1))]
    lo_b.append(np.zeros(nx))
    up_b.append(np.zeros(nx))
    r += nx
    # Budgets.
    rows_i.append(r + tt.ravel())
    cols_i.append(X.ravel())
    vals.append(np.repeat(data.cost.astype(np.float64), T))
    lo_b.append(np.full(T, -np.inf))
    up_b.append(data.budget.astype(np.float64))
    r_budget = r
    r += T
    # At most once.
    r_once = r
    rows_i.append(r + np.arange(n))
    cols_i.append(Y[:, -1])
    vals.append(np.ones(n))
    lo_b.append(np.full(n, -np.inf))
    up_b.append(np.ones(n))
    r += n
    # Precedence rows (u, t).
    uu = np.nonzero(data.lower >= 0)[0]
    r_prec = r
    if len(uu):
        pu, pt = np.meshgrid(uu, np.arange(T), indexing="ij")
        prow = r + np.arange(pu.size).reshape(pu.shape)
        rows_i += [prow.ravel()]
        cols_i += [Y[pu, pt].ravel()]
        vals += [np.ones(pu.size)]
        has_lo = pt - d >= 0
        rows_i.append(prow[has_lo])
        cols_i.append(Y[data.lower[pu[has_lo]], pt[has_lo] - d])
        vals.append(-np.ones(int(has_lo.sum())))
        lo_b.append(np.full(pu.size, -np.inf))
        up_b.append(np.zeros(pu.size))
        r += pu.size
    A = sparse.csc_matrix((np.concatenate(vals), (np.concatenate(rows_i), np.concatenate(cols_i))), shape=(r, 2 * nx))
    from l3gs_opt.models.backends.highs import solve_lp, sparse_lp

    # Y is free: its bounds are implied by the rows, and a bound must not take over a row's dual.
    lp = sparse_lp(A, col_cost=np.concatenate([-data.profit.ravel(), np.zeros(nx)]),
                   col_lower=np.concatenate([np.zeros(nx), np.full(nx, -np.inf)]),
                   col_upper=np.concatenate([np.where(data.allowed.ravel(), 1.0, 0.0), np.full(nx, np.inf)]),
                   row_lower=np.concatenate(lo_b), row_upper=np.concatenate(up_b))
    h = solve_lp(lp, time_limit_s=time_limit_s)
    if h is None:
        return None, None, None
    sol = h.getSolution()
    dual = -np.asarray(sol.row_dual)
    mu = np.maximum(0.0, dual[r_once:r_once + n])
    pi = np.zeros((n, T))
    if len(uu):
        pi[uu] = np.maximum(0.0, dual[r_prec:r]).reshape(len(uu), T)
    x = np.asarray(sol.col_value)[:nx].reshape(n, T)
    value = data.constant - float(h.getInfo().objective_function_value)
    del r_budget
    return value, Multipliers(mu, pi), x
