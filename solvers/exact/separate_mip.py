"""Problems II/IV: Lagrangian reduced-cost fixing over paths, and HiGHS on the model it leaves.

**Fixing.** At budget multipliers ``pi >= 0`` the Lagrangian bound is ``L(pi) = C + sum_k best_k``
(:mod:`.separate_data`). Forcing version b of object k to arrive in slot t replaces ``best_k``
by the best path through that arrival, so no schedule better than an incumbent ``z`` uses the
arrival when ``L(pi) - best_k + forced[k,b,t] < z``. ``forced`` comes from one forward and one
backward pass of the path DP (the forward values before slot t's arrivals, the backward values
from the set held after them), for every (k, b, t) at once.

**Reduced MIP.** The standard model of Problem II (``x[k,b,t]`` arrivals, ``w[k,b,t]`` the
version shown, budget rows scaled by their right-hand side) over the arrivals fixing keeps,
cut off at the incumbent (HiGHS only looks for better schedules) and started from it. Its
schedules are checked in exact integer bytes; "optimal" or "infeasible" (nothing beats the
incumbent) closes the search only when the schedule it returns passes that check.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from .separate_data import Path, SeparateData, path_value, schedule_feasible

__all__ = ["forced_values", "fixed_mask", "reduced_mip", "MIP_BOUND_SLACK"]

#: Relative slack on HiGHS's dual bound (its LP tolerances; as exact's layered MIP side).
MIP_BOUND_SLACK = 1e-9


def _rho(data: SeparateData, pi: np.ndarray) -> np.ndarray:
    pi = np.maximum(pi, 0.0)
    return np.flip(np.cumsum(np.flip(pi))) if data.cumulative else pi


def forced_values(data: SeparateData, rho: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """``[K, V, T]``: the best reduced path value of object k with version b arriving in slot t
    (-inf where that arrival is not allowed), at arrival prices ``rho`` (utility per byte)."""
    K, T, V, S = data.K, data.T, data.V, data.states
    pf, pa, pt = data.pair_from, data.pair_add, data.pair_to
    pcost, cap = data.pair_cost, data.rhs
    pcost_f = pcost.astype(np.float64)
    show, shift = data.show, data.shift
    kk = np.arange(K)[:, None]
    oks = [((pa[None, :] & ~allowed[:, t][:, None]) == 0) & (pcost <= cap[t]) for t in range(T)]
    # Forward: value before slot t's arrivals (next_slot: slot t already earned).
    before = np.empty((T, K, S))
    value = np.full((K, S), -np.inf)
    value[:, 0] = 0.0
    for t in range(T):
        if shift:
            value = value + show[t]
        before[t] = value
        cand = np.where(oks[t], value[:, pf] - rho[t] * pcost_f, -np.inf)
        after = value.copy()
        if len(pa):
            np.maximum.at(after, (kk, pt[None, :]), cand)
        value = after if shift else after + show[t]
    # Backward: rest[t][S] = best from holding S right after slot t's arrivals (its earnings on).
    out = np.full((K, V, T), -np.inf)
    nxt = np.zeros((K, S))          # Q_{t+1}: from state S before slot t+1's arrivals
    for t in range(T - 1, -1, -1):
        rest = nxt.copy()
        if not shift:
            rest = rest + show[t]
        elif t + 1 < T:
            rest = rest + show[t + 1]
        val = np.where(oks[t], before[t][:, pf] - rho[t] * pcost_f + rest[:, pt], -np.inf)
        for b in range(V):
            has = ((pa >> b) & 1) == 1
            if has.any():
                out[:, b, t] = val[:, has].max(axis=1)
        q = rest.copy()
        if len(pa):
            np.maximum.at(q, (kk, pf[None, :]), np.where(oks[t], rest[:, pt] - rho[t] * pcost_f, -np.inf))
        nxt = q
    return out


def fixed_mask(data: SeparateData, pi: np.ndarray, bound: float, best: np.ndarray, incumbent: float,
               allowed: np.ndarray) -> np.ndarray:
    """``allowed`` (bit masks [K, T]) minus the arrivals no schedule better than ``incumbent`` uses,
    by the Lagrangian certificate at ``pi`` (``bound`` = L(pi), ``best`` [K] its per-object path
    values)."""
    forced = forced_values(data, _rho(data, pi), allowed)
    # Float error of the sums compared: a few ulps of the terms, T + K of them.
    scale = abs(bound) + float(np.abs(best).sum()) + abs(incumbent)
    margin = 64 * (data.T * data.V + data.K) * np.finfo(np.float64).eps * scale
    drop = bound - best[:, None, None] + forced + margin < incumbent        # [K, V, T]
    out = allowed.copy()
    for b in range(data.V):
        out &= ~(drop[:, b, :].astype(np.int64) << b)
    return out


def reduced_mip(data: SeparateData, allowed: np.ndarray, incumbent: float, *, time_limit_s: float | None,
                start: dict[int, Path] | None = None, stop: Callable[[], bool] | None = None
                ) -> tuple[str, dict[int, Path] | None, float]:
    """HiGHS on Problem II over the arrivals ``allowed`` keeps, cut off at ``incumbent`` (held
    constant included).

    Returns
    -------
    (outcome, paths, bound)
        ``outcome`` "optimal" (nothing in the mask beats ``max(incumbent, value of paths)``) or
        "time_limit" (stopped: ``bound`` is HiGHS's dual bound plus its slack); ``paths`` a better
        schedule, feasible in exact bytes, or None.
    """
    import highspy

    from l3gs_opt.models.backends.highs import new_highs

    K, T, V = data.K, data.T, data.V
    shift = data.shift
    h = new_highs(time_limit_s=None if time_limit_s is None else max(time_limit_s, 0.01), mip=True)
    if stop is not None:
        def interrupt(event) -> None:
            if stop():
                event.interrupt()

        for hook in (h.cbSimplexInterrupt, h.cbMipInterrupt):
            hook.subscribe(interrupt)
    inf = highspy.kHighsInf
    xs = [(k, b, t) for k in range(K) for b in range(V) for t in range(T) if (int(allowed[k, t]) >> b) & 1]
    if not xs:
        return "optimal", None, incumbent
    xindex = {key: i for i, key in enumerate(xs)}
    nx = len(xs)
    # Columns: x then w; w[k,b,t] only where the version can be held and is worth something.
    ws = []
    first = {}
    for k, b, t in xs:
        first[(k, b)] = min(first.get((k, b), T), t)
    for (k, b), f in first.items():
        for t in range(f + shift, T):
            if data.gain[t, k, b] > 0:
                ws.append((k, b, t))
    nw = len(ws)
    vscale = max(float(data.gain.max(initial=0.0)), 1e-300)
    cost = np.concatenate([np.zeros(nx), -data.gain[[t for _, _, t in ws], [k for k, _, _ in ws],
                                                    [b for _, b, _ in ws]] / vscale if nw else np.zeros(0)])
    h.addVars(nx + nw, np.zeros(nx + nw), np.ones(nx + nw))
    h.changeColsCost(nx + nw, np.arange(nx + nw, dtype=np.int32), cost)
    h.changeColsIntegrality(nx, np.arange(nx, dtype=np.int32), np.full(nx, highspy.HighsVarType.kInteger))

    def row(idx: list[int], val: list[float], lo: float, hi: float) -> None:
        h.addRow(lo, hi, len(idx), np.asarray(idx, np.int32), np.asarray(val, np.float64))

    by_kb: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for (k, b, t), i in xindex.items():
        by_kb.setdefault((k, b), []).append((t, i))
    for items in by_kb.values():
        if len(items) > 1:
            row([i for _, i in items], [1.0] * len(items), -inf, 1.0)
    by_kt: dict[tuple[int, int], list[int]] = {}
    for n_w, (k, b, t) in enumerate(ws):
        src = [i for s, i in by_kb[(k, b)] if s + shift <= t]
        row([nx + n_w] + src, [1.0] + [-1.0] * len(src), -inf, 0.0)
        by_kt.setdefault((k, t), []).append(nx + n_w)
    for cols in by_kt.values():
        if len(cols) > 1:
            row(cols, [1.0] * len(cols), -inf, 1.0)
    for t in range(T):
        if data.rhs[t] <= 0:
            continue
        idx = [i for i, (k, b, s) in enumerate(xs) if (s <= t if data.cumulative else s == t)]
        if idx:
            row(idx, [int(data.cost[xs[i][0], xs[i][1]]) / float(data.rhs[t]) for i in idx], -inf, 1.0)
    # Only schedules strictly better than the incumbent (HiGHS minimises -(utility) / vscale).
    h.setOptionValue("objective_bound", float(-(incumbent - data.constant) / vscale))
    if start:
        x0 = np.zeros(nx + nw)
        ok = True
        for k, path in start.items():
            for b, t in enumerate(path):
                if t >= 0:
                    if (k, b, t) not in xindex:
                        ok = False
                    else:
                        x0[xindex[(k, b, t)]] = 1.0
        if ok:
            sol = highspy.HighsSolution()
            sol.col_value = list(x0)
            sol.value_valid = True
            h.setSolution(sol)
    h.run()
    status = h.getModelStatus()
    info = h.getInfo()
    ms = highspy.HighsModelStatus
    paths = None
    exact_ok = True
    if info.primal_solution_status == 2:
        x = np.asarray(h.getSolution().col_value)[:nx]
        found: dict[int, list[int]] = {}
        for i in np.nonzero(x > 0.5)[0]:
            k, b, t = xs[i]
            found.setdefault(k, [-1] * V)[b] = t
        paths = {k: tuple(p) for k, p in found.items()}
        if not schedule_feasible(data, paths, allowed=allowed):
            paths, exact_ok = None, False     # over a budget by HiGHS's tolerance: no proof from it
    if paths is not None:
        value = math.fsum([data.constant, *(path_value(data, k, p) for k, p in paths.items())])
        if value <= incumbent:
            paths = None
    if exact_ok and status in (ms.kOptimal, ms.kInfeasible, ms.kObjectiveBound):
        return "optimal", paths, incumbent
    raw = float(info.mip_dual_bound)
    dual = data.constant - raw * vscale if math.isfinite(raw) else math.inf
    return "time_limit", paths, dual + MIP_BOUND_SLACK * abs(dual)
