"""Problems I/III under the ``cumulative`` budget in "arrived-by" form, and its Lagrangian bound.

With one sequential link the bytes that have arrived by slot t are at most ``C[t] = sum_{s<=t}
B[s]``. Written over ``z[i,t]`` = "chunk i has arrived by slot t" (an arrival in slot t is
``z[i,t] - z[i,t-1]``), the budget of slot t involves that slot's ``z`` only::

    max  C0 + sum_{i,t} s[i,t] z[i,t]
    s.t. sum_i c[i] z[i,t] <= C[t]                              (cumulative budget of slot t)
         z[i,t] - z[i,t+1] <= 0                                  (arrived stays arrived; alpha[i,t])
         z[u,t] - z[lo(u),t-d] <= 0                              (layer order; beta[u,t])
         z[i,t] = 0 for t < first[i],  z in {0, 1}

with ``s[i,t]`` the value of chunk i being there at slot t (presolve's gain, shifted one slot
under ``next_slot`` availability: any sign) and ``d`` = 0 (same-slot layers) or 1 (strict).
Dualising the two linking families with ``alpha, beta >= 0`` leaves one 0-1 knapsack per slot,
capacity ``C[t]``, with reduced profits

    r[i,t] = s[i,t] - alpha[i,t] + alpha[i,t-1] - beta[i,t] + beta[up(i),t+d],

and ``L(alpha, beta) = C0 + sum_t max(0, K_t(r))`` bounds the optimum from above for all
multipliers >= 0 (the dualised rows have right-hand side 0; each knapsack is solved in integers,
so at the LP's duals the bound is at most the LP value). ``first[i]`` is the earliest slot
presolve lets chunk i arrive in; presolve's other exclusions under this budget (slots with zero
bandwidth) are dominance rules, which the model does not need.

Reduced-cost fixing narrows each chunk to an arrival window: :func:`fix_windows` (a chunk whose
arrival by slot t cannot beat the incumbent arrives after t; one whose absence at t cannot, by t).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from l3gs_opt import stop
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance

from .lagrange import ChunkItems, PolyakStep, chunk_arrays, knapsack

__all__ = ["LinkData", "link_data", "schedule_feasible", "LinkMultipliers", "LinkLagrange",
           "link_lagrangian", "link_subgradient", "fix_windows", "Windows", "windows_on_events"]

_EPS = np.finfo(np.float64).eps


@dataclass(frozen=True, eq=False)
class LinkData(ChunkItems):
    """A layered, cumulative-budget instance over the chunks presolve keeps.

    Attributes
    ----------
    item_j, item_l : int arrays [n]
        Object and layer of each chunk.
    cost : int64 array [n]
        Bytes of each chunk.
    shown : float64 array [n, T]
        ``s[i,t]``: the value of chunk i having arrived by slot t (any sign).
    profit : float64 array [n, T]
        ``sum_{t'>=t} s[i,t']``: the value of arriving in slot t (Problem A's ``P``, for every
        slot; :func:`.lagrange.assignment_value` sums it for a schedule).
    first : int64 array [n]
        Earliest slot chunk i may arrive in (T: never).
    allowed : bool array [n, T]
        The slots chunk i may arrive in (presolve's event slots: where having it is worth
        something, or where the layer above needs it).
    lower, upper : int arrays [n]
        The chunk of the layer below / above (-1: none, or the layer below is held).
    strict : bool
        Layer l arrives strictly after layer l-1.
    capacity : int64 array [T]
        ``C[t]``: bytes by slot t.
    constant : float
        Utility of the held chunks.
    """

    T: int
    item_j: np.ndarray
    item_l: np.ndarray
    cost: np.ndarray
    shown: np.ndarray
    profit: np.ndarray
    first: np.ndarray
    allowed: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    strict: bool
    capacity: np.ndarray
    constant: float
    stats: dict = field(default_factory=dict)

    @property
    def d(self) -> int:
        return 1 if self.strict else 0

    def arrived(self, assign: np.ndarray) -> np.ndarray:
        """``z`` [n, T] (bool) of an assignment."""
        t = np.arange(self.T)
        return (assign[:, None] >= 0) & (t[None, :] >= assign[:, None])


def link_data(instance: Instance) -> LinkData:
    """The arrived-by form of a layered instance with the ``cumulative`` budget."""
    if not instance.layered or instance.options.budget != "cumulative":
        raise SolveError("the arrived-by form is for layered instances with the cumulative budget")
    red, jj, ll, lower, upper, allowed, shown, future = chunk_arrays(instance)
    T = instance.T
    first = np.where(allowed.any(axis=1), np.argmax(allowed, axis=1), T).astype(np.int64)
    return LinkData(T=T, item_j=jj, item_l=ll, cost=instance.cost[jj, ll].astype(np.int64), shown=shown,
                    profit=future, first=first, allowed=allowed, lower=lower, upper=upper,
                    strict=not instance.options.same_slot_layers,
                    capacity=np.cumsum(instance.bandwidth.astype(np.int64)), constant=red.constant,
                    stats=dict(red.stats))


def schedule_feasible(data: LinkData, assign: np.ndarray, first: np.ndarray | None = None) -> bool:
    """Cumulative budgets in exact integer bytes, earliest slots and layer order."""
    first = data.first if first is None else first
    on = assign >= 0
    if (assign >= data.T).any() or (on & (assign < first)).any():
        return False
    spent = np.zeros(data.T, dtype=np.int64)
    np.add.at(spent, assign[on], data.cost[on])
    if (np.cumsum(spent) > data.capacity).any():
        return False
    has = on & (data.lower >= 0)
    lo = assign[data.lower[has]]
    return bool(((lo >= 0) & (lo <= assign[has] - data.d)).all())


# -- arrivals only where they can matter ---------------------------------------------------------

def windows_on_events(windows: "Windows", events: np.ndarray) -> "Windows":
    """``windows`` narrowed to the slots ``events`` [n, T] allows (presolve's event slots): ``first``
    up to the next one, ``by`` down to the last one (closed when a chunk that must arrive has none
    in between)."""
    n, T = events.shape
    tt = np.arange(T)
    in_window = events & (tt[None, :] >= windows.first[:, None])
    first = np.where(in_window.any(axis=1), np.argmax(in_window, axis=1), T).astype(np.int64)
    by = windows.by.copy()
    need = by < T
    if need.any():
        upto = events[need] & (tt[None, :] <= by[need, None])
        last = np.where(upto.any(axis=1), T - 1 - np.argmax(upto[:, ::-1], axis=1), -1)
        by[need] = last
    closed = windows.closed or bool((need & ((by < 0) | (first > by))).any())
    return Windows(first, np.where(by < 0, 0, by), closed)


# -- the Lagrangian bound ------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class LinkMultipliers:
    """``alpha`` [n, T] on "arrived stays arrived" (column T-1 unused), ``beta`` [n, T] on layer
    order (rows of chunks without a lower layer unused); both >= 0."""

    alpha: np.ndarray
    beta: np.ndarray

    @classmethod
    def zeros(cls, data: LinkData) -> "LinkMultipliers":
        return cls(np.zeros((data.n, data.T)), np.zeros((data.n, data.T)))


@dataclass(frozen=True, eq=False)
class LinkLagrange:
    """``L(alpha, beta)``: the valid ``bound``, the knapsack choices ``z`` [n, T], each slot's
    value ``slot`` [T] (>= 0), the reduced profits ``reduced`` [n, T] (-inf where z is fixed at 0)
    and whether every knapsack was solved to optimality."""

    bound: float
    z: np.ndarray
    slot: np.ndarray
    reduced: np.ndarray
    exact: bool


def _reduced(data: LinkData, mult: LinkMultipliers, first: np.ndarray) -> np.ndarray:
    T, d = data.T, data.d
    alpha = mult.alpha.copy()
    alpha[:, T - 1] = 0.0
    beta = np.where((data.lower >= 0)[:, None], mult.beta, 0.0)
    red = data.shown - alpha - beta
    red[:, 1:] += alpha[:, :-1]
    has_up = data.upper >= 0
    if has_up.any():
        up = beta[data.upper[has_up]]
        red[has_up, :T - d] += up[:, d:]
    open_ = np.arange(T)[None, :] >= first[:, None]
    return np.where(open_, red, -np.inf)


def link_lagrangian(data: LinkData, mult: LinkMultipliers, *, first: np.ndarray | None = None,
                    deadline: float | None = None) -> LinkLagrange:
    """``L(alpha, beta)`` with each slot's knapsack solved exactly, or to its solver's upper bound
    when ``deadline`` (``time.perf_counter()`` seconds) stops it (``exact`` false; still valid).
    ``first`` narrows the earliest slots (reduced-cost fixing)."""
    first = data.first if first is None else first
    red = _reduced(data, mult, first)
    T = data.T
    z = np.zeros((data.n, T), dtype=bool)
    slot = np.zeros(T)
    exact = True
    magnitude = 0.0
    for t in range(T):
        left = None if deadline is None else max(deadline - time.perf_counter(), 0.01)
        chosen, value, optimal = knapsack(data.cost, red[:, t], int(data.capacity[t]), time_limit_s=left)
        exact &= optimal
        z[chosen, t] = True
        slot[t] = max(0.0, value)
        magnitude += float(np.abs(red[chosen, t]).sum())
    # Round-off: each r is a sum of at most 5 terms (each at most ``term``), each slot a sum of
    # at most n of them.
    term = float(np.abs(data.shown).max(initial=0.0)) + 2 * float(mult.alpha.max(initial=0.0)) \
        + 2 * float(mult.beta.max(initial=0.0))
    slack = 8 * _EPS * ((data.n + data.T + 4) * magnitude + data.n * T * term)
    bound = math.fsum([data.constant, *slot.tolist()]) + slack
    return LinkLagrange(bound, z, slot, red, exact)


def link_subgradient(data: LinkData, start: LinkMultipliers, *, target: float, time_limit_s: float,
                     first: np.ndarray | None = None, trace: list | None = None
                     ) -> tuple[LinkLagrange, LinkMultipliers]:
    """Polyak subgradient steps towards ``target`` (the incumbent's value) from ``start`` for at
    most ``time_limit_s`` seconds: the best value met and its multipliers."""
    started = time.perf_counter()
    deadline = started + time_limit_s
    d, T = data.d, data.T
    has = (data.lower >= 0)
    mult = start
    val = link_lagrangian(data, mult, first=first, deadline=deadline)
    best, best_mult = val, mult
    schedule = PolyakStep()
    while not stop.expired(deadline) and val.bound > target:
        z = val.z.astype(np.float64)
        g_a = np.zeros_like(z)
        g_a[:, :-1] = z[:, :-1] - z[:, 1:]
        g_b = np.zeros_like(z)
        if has.any():
            lo = np.zeros((int(has.sum()), T))
            lo[:, d:] = z[data.lower[has], :T - d]
            g_b[has] = z[has] - lo
        g_a = np.where((mult.alpha <= 0) & (g_a < 0), 0.0, g_a)
        g_b = np.where((mult.beta <= 0) & (g_b < 0), 0.0, g_b)
        norm = float((g_a ** 2).sum() + (g_b ** 2).sum())
        if norm == 0:
            break
        step = schedule.size(val.bound, target, norm)
        mult = LinkMultipliers(np.maximum(0.0, mult.alpha + step * g_a), np.maximum(0.0, mult.beta + step * g_b))
        val = link_lagrangian(data, mult, first=first, deadline=deadline)
        better = val.bound < best.bound - 1e-12 * abs(best.bound)
        if better:
            best, best_mult = val, mult
        if not schedule.record(better):
            break
        if trace is not None:
            trace.append((time.perf_counter() - started, best.bound))
    return best, best_mult


# -- reduced-cost fixing -------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Windows:
    """Per chunk: ``first`` (earliest arrival slot, T = never) and ``by`` (it must have arrived by
    this slot in any better schedule; T = not forced). ``closed``: no schedule beats the incumbent."""

    first: np.ndarray
    by: np.ndarray
    closed: bool


def _propagate(data: LinkData, first: np.ndarray, by: np.ndarray) -> None:
    """Layer order in both directions until nothing changes (in place)."""
    d = data.d
    has = np.nonzero(data.lower >= 0)[0]
    if len(has) == 0:
        return
    lo = data.lower[has]
    # Chunks listed by object, then layer: one pass up and one down per layer.
    for _ in range(int(data.item_l.max(initial=0)) + 1):
        changed = False
        new_first = np.maximum(first[has], np.minimum(first[lo] + d, data.T))
        if (new_first != first[has]).any():
            first[has] = new_first
            changed = True
        need = by[has] < data.T
        new_by = np.where(need, np.minimum(by[lo], by[has] - d), by[lo])
        if (new_by != by[lo]).any():
            np.minimum.at(by, lo, new_by)
            changed = True
        if not changed:
            break


def fix_windows(data: LinkData, lv: LinkLagrange, incumbent: float, first: np.ndarray | None = None,
                by: np.ndarray | None = None) -> Windows:
    """Narrow each chunk's arrival window with one Lagrangian value ``lv`` (reduced-cost fixing).

    Forcing ``z[i,t] = 1`` changes slot t's part of the bound to at most ``r[i,t] + D_t(C[t] -
    c[i])``, with ``D_t`` the LP (Dantzig) bound of slot t's knapsack; if the bound then falls
    below ``incumbent``, every better schedule has ``z[i,t] = 0``, hence ``z[i,s] = 0`` for
    ``s <= t``. Forcing ``z[i,t] = 0`` where the exact knapsack took i changes it to at most
    ``max(0, D_t(C[t] + c[i]) - r[i,t])`` (take the LP optimum without i and add i); if that
    falls below, every better schedule has i by slot t. Layer order then carries both along.
    """
    first = (data.first if first is None else first).copy()
    by = np.full(data.n, data.T, dtype=np.int64) if by is None else by.copy()
    red = lv.reduced
    margin = 16 * (data.n + data.T) * _EPS * (abs(lv.bound) + float(np.abs(np.where(np.isfinite(red), red, 0)).sum()))
    for t in range(data.T):
        col = red[:, t]
        open_ = np.isfinite(col)
        cand = np.nonzero(open_)[0]
        if len(cand) == 0:
            continue
        pos = np.nonzero(open_ & (col > 0))[0]
        o = pos[np.argsort(-col[pos] / data.cost[pos], kind="stable")]
        cum_c = np.r_[0.0, np.cumsum(data.cost[o].astype(np.float64))]
        cum_v = np.r_[0.0, np.cumsum(col[o])]
        cap = float(data.capacity[t])
        rest = lv.bound - lv.slot[t]
        room = cap - data.cost[cand]
        with_i = rest + col[cand] + np.interp(np.maximum(room, 0.0), cum_c, cum_v)
        drop = (room < 0) | (with_i + margin < incumbent)
        if drop.any():
            first[cand[drop]] = np.maximum(first[cand[drop]], t + 1)
        if lv.exact:
            took = cand[lv.z[cand, t]]
            without = rest + np.maximum(0.0, np.interp(cap + data.cost[took], cum_c, cum_v) - col[took])
            need = took[without + margin < incumbent]
            by[need] = np.minimum(by[need], t)
    _propagate(data, first, by)
    return Windows(first, by, closed=bool((first > by).any()))
