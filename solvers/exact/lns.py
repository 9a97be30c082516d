"""Window large-neighbourhood search for Problem A: re-optimise a few slots exactly, the rest fixed.

Given a feasible assignment (slot per chunk, -1 never), a window ``W = [start, end)`` of slots is
re-solved as a small MIP (HiGHS): chunks arriving before ``W`` stay; a chunk arriving in ``W``
may move to any slot of ``W`` or leave the schedule; a chunk arriving after ``W`` (or never) may
move into ``W`` or keep its slot. Budgets of the window's slots, layer order inside the window and
against the chunks outside it are kept exactly, so the result is feasible whenever the MIP's
is; it is re-checked in integer bytes (:func:`~.lagrange.assignment_feasible`) before use.
Sweeping windows over the horizon is the primal workhorse of ``exact`` at the paper's scale.
"""

from __future__ import annotations

import math
import time
from typing import Callable, Sequence

import numpy as np

from l3gs_opt.models.backends.highs import new_highs
from l3gs_opt.models.backends.highs_race import race_mip

from .lagrange import Cover, GapData, assignment_feasible, assignment_value, chunk_profits

__all__ = ["MIP_BOUND_SLACK", "improve_window", "window_sweep", "reduced_mip", "lp_neighbourhood"]

#: Relative slack on HiGHS's MIP dual bound: its LPs are solved to 1e-7 dual feasibility, as
#: for :data:`l3gs_opt.solvers.bounds.LP_BOUND_SLACK`.
MIP_BOUND_SLACK = 1e-7


def improve_window(data: GapData, assign: np.ndarray, allowed: np.ndarray, start: int, end: int, *,
                   time_limit_s: float = 5.0) -> np.ndarray | None:
    """Best assignment that differs from ``assign`` only as described in the module doc, or None
    when the MIP finds nothing better (or fails)."""
    import highspy

    n = data.n
    d = 1 if data.strict else 0
    in_w = (assign >= start) & (assign < end)
    later = (assign >= end) | (assign < 0)
    out_val = np.where(later, chunk_profits(data, assign), 0.0)
    # Which (i, t in W) pairs get a variable.
    ok = allowed[:, start:end].copy()
    ok[~(in_w | later)] = False
    for i in range(n):          # lower-layer constraints against fixed or immovable chunks
        lo = data.lower[i]
        if lo < 0 or not ok[i].any():
            continue
        if 0 <= assign[lo] < start:
            ok[i, :max(0, assign[lo] + d - start)] = False
        elif not ok[lo].any():
            ok[i] = False       # its lower layer cannot be in the window: it cannot be either
    elig = np.nonzero(ok.any(axis=1) | in_w)[0]
    if len(elig) == 0:
        return None
    var: dict[tuple[int, int], int] = {}
    costs: list[float] = []
    for i in elig:
        for k in np.nonzero(ok[i])[0]:
            var[(int(i), int(k))] = len(costs)
            costs.append(float(data.profit[i, start + k] - out_val[i]))
    if not var:
        return None
    by_item: dict[int, list[tuple[int, int]]] = {}
    for (i, k), v in var.items():
        by_item.setdefault(i, []).append((k, v))
    rows: list[tuple[float, float, list[int], list[float]]] = []
    for i, lst in by_item.items():
        rows.append((-np.inf, 1.0, [v for _, v in lst], [1.0] * len(lst)))
    # Budgets: every chunk in a window slot is a variable, so each slot's whole budget is free.
    for k in range(end - start):
        items_k = [(i, v) for (i, kk), v in var.items() if kk == k]
        if items_k:
            rows.append((-np.inf, float(data.budget[start + k]), [v for _, v in items_k],
                         [float(data.cost[i]) for i, _ in items_k]))
    items_in = set(by_item)
    for i in elig.tolist():
        lo, up = int(data.lower[i]), int(data.upper[i])
        # A chunk that was in the window must stay in it when its upper layer keeps a later slot
        # outside the window (dropping it would orphan that layer).
        if in_w[i] and up >= 0 and (up not in items_in) and assign[up] >= end:
            lst = by_item.get(i, [])
            rows.append((1.0, 1.0, [v for _, v in lst], [1.0] * len(lst)))
        if i not in items_in or lo < 0 or lo not in items_in:
            continue
        ui, li = by_item[i], by_item[lo]
        for k in range(end - start):
            cu = [v for kk, v in ui if kk <= k]
            cl = [v for kk, v in li if kk <= k - d]
            if cu:
                rows.append((-np.inf, 0.0, cu + cl, [1.0] * len(cu) + [-1.0] * len(cl)))
        if in_w[lo] and assign[i] >= end:
            # u out keeps its later slot, lo out leaves: forbid (1 - sum x_u <= sum x_lo).
            rows.append((1.0, np.inf, [v for _, v in ui] + [v for _, v in li], [1.0] * (len(ui) + len(li))))
    nv = len(costs)
    h = new_highs(time_limit_s=max(time_limit_s, 0.01), mip=True, proof=False)
    inf = highspy.kHighsInf
    h.addCols(nv, -np.asarray(costs), np.zeros(nv), np.ones(nv), 0, np.zeros(nv, np.int32),
              np.zeros(0, np.int32), np.zeros(0))
    h.changeColsIntegrality(nv, np.arange(nv, dtype=np.int32),
                            np.full(nv, highspy.HighsVarType.kInteger))
    for lo_b, up_b, cols, vals in rows:
        h.addRow(-inf if lo_b == -np.inf else lo_b, inf if up_b == np.inf else up_b, len(cols),
                 np.asarray(cols, np.int32), np.asarray(vals, np.float64))
    # Start from the current assignment (feasible for the window MIP).
    start_x = np.zeros(nv)
    for i in elig.tolist():
        if in_w[i] and (i, int(assign[i]) - start) in var:
            start_x[var[(i, int(assign[i]) - start)]] = 1.0
    h.setSolution(_solution(start_x))
    h.run()
    if h.getInfo().primal_solution_status != 2:   # no feasible point
        return None
    x = np.asarray(h.getSolution().col_value)
    out = assign.copy()
    for i in elig.tolist():
        if in_w[i]:
            out[i] = -1
    for (i, k), v in var.items():
        if x[v] > 0.5:
            out[i] = start + k
    if not assignment_feasible(data, out, allowed):
        return None
    return out


def _solution(x: np.ndarray):
    import highspy

    sol = highspy.HighsSolution()
    sol.col_value = x.tolist()
    sol.value_valid = True
    return sol


def window_sweep(data: GapData, assign: np.ndarray, allowed: np.ndarray, *, width: int, deadline: float | None,
                 per_window_s: float = 2.0, rounds: int = 3) -> np.ndarray:
    """Sweep windows of ``width`` slots (half-overlapping) over the horizon, keeping every
    improvement, for up to ``rounds`` passes or until a pass improves nothing."""
    best = assign.copy()
    value = assignment_value(data, best)
    T = data.T
    step = max(1, width // 2)
    for _ in range(rounds):
        improved = False
        for start in range(0, T, step):
            left = None if deadline is None else deadline - time.perf_counter()
            if left is not None and left <= 0:
                return best
            cand = improve_window(data, best, allowed, start, min(T, start + width),
                                  time_limit_s=per_window_s if left is None else min(per_window_s, left))
            if cand is None:
                continue
            v = assignment_value(data, cand)
            if v > value * (1 + 1e-12) + 1e-300:
                best, value, improved = cand, v, True
        if not improved:
            break
    return best


def _add_problem_a(h, data: GapData, var: np.ndarray, ii: np.ndarray, tt: np.ndarray, *,
                   sparse: bool, covers: Sequence[Cover] = ()) -> np.ndarray | None:
    """Columns ``x`` (binary, one per allowed pair; ``var[i,t]`` its index or -1) and Problem A's
    rows into HiGHS model ``h``.

    ``sparse``: layer order through cumulative columns ``Y[i,k] = Y[i,k-1] + x[i,s_k]`` over item
    i's allowed slots ``s_k`` (continuous, in [0, 1], so they also say "at most once"), one row
    ``Y[u,s] <= Y[lo, last allowed slot <= s - d]`` per allowed pair (u, s): 2 non-zeros instead of
    the O(T) of ``sum_{s'<=s} x[u,s'] - sum_{s'<=s-d} x[lo,s'] <= 0``. Same feasible x (the
    substitution is exact); HiGHS's simplex runs on about a tenth of the non-zeros.
    ``covers``: their rows ``sum_{i in S} sum_{s <= t} x[i,s] <= |S| - 1`` too (valid for every
    schedule; :mod:`.covers`).
    """
    import highspy

    n, T = data.n, data.T
    d = 1 if data.strict else 0
    nv = len(ii)
    inf = highspy.kHighsInf
    h.addCols(nv, -data.profit[ii, tt], np.zeros(nv), np.ones(nv), 0, np.zeros(nv, np.int32),
              np.zeros(0, np.int32), np.zeros(0))
    h.changeColsIntegrality(nv, np.arange(nv, dtype=np.int32), np.full(nv, highspy.HighsVarType.kInteger))
    for t in range(T):
        cols = var[:, t][var[:, t] >= 0]
        if len(cols) and int(data.cost[ii[cols]].sum()) > int(data.budget[t]):
            h.addRow(-inf, float(data.budget[t]), len(cols), cols.astype(np.int32), data.cost[ii[cols]].astype(float))
    for cov in covers:
        cols = var[cov.items, :cov.slot + 1]
        cols = cols[cols >= 0]
        if len(cols) > len(cov.items) - 1:
            h.addRow(-inf, float(len(cov.items) - 1), len(cols), cols.astype(np.int32), np.ones(len(cols)))
    if not sparse:
        for i in range(n):
            cols = var[i][var[i] >= 0]
            if len(cols) > 1:
                h.addRow(-inf, 1.0, len(cols), cols.astype(np.int32), np.ones(len(cols)))
        for u in np.nonzero(data.lower >= 0)[0]:
            lo = int(data.lower[u])
            for t in np.nonzero(var[u] >= 0)[0]:
                cu = var[u][:t + 1][var[u][:t + 1] >= 0]
                cl_slots = var[lo][:max(t + 1 - d, 0)]
                cl = cl_slots[cl_slots >= 0]
                h.addRow(-inf, 0.0, len(cu) + len(cl), np.r_[cu, cl].astype(np.int32),
                         np.r_[np.ones(len(cu)), -np.ones(len(cl))])
        return None
    # Cumulative columns for items that have a lower or an upper layer with pairs left.
    linked = np.zeros(n, dtype=bool)
    has_lo = data.lower >= 0
    linked[has_lo] = True
    linked[data.lower[has_lo]] = True
    ycol = -np.ones((n, T), dtype=np.int64)     # Y column of item i at its allowed slot t
    count = nv
    for i in np.nonzero(linked)[0]:
        cols = var[i][var[i] >= 0]
        if len(cols) == 0:
            continue
        k = len(cols)
        h.addCols(k, np.zeros(k), np.zeros(k), np.ones(k), 0, np.zeros(k, np.int32), np.zeros(0, np.int32),
                  np.zeros(0))
        slots = np.nonzero(var[i] >= 0)[0]
        ycol[i, slots] = count + np.arange(k)
        for a in range(k):   # Y[i,k] - Y[i,k-1] - x[i,s_k] = 0
            idx = [count + a, int(cols[a])] + ([count + a - 1] if a else [])
            h.addRow(0.0, 0.0, len(idx), np.asarray(idx, np.int32), np.asarray([1.0, -1.0, -1.0][:len(idx)]))
        count += k
    for i in np.nonzero(~linked)[0]:
        cols = var[i][var[i] >= 0]
        if len(cols) > 1:
            h.addRow(-inf, 1.0, len(cols), cols.astype(np.int32), np.ones(len(cols)))
    for u in np.nonzero(has_lo)[0]:
        lo = int(data.lower[u])
        lo_slots = np.nonzero(ycol[lo] >= 0)[0]
        for s in np.nonzero(ycol[u] >= 0)[0]:
            k = int(np.searchsorted(lo_slots, s - d, side="right")) - 1   # last allowed slot of lo <= s - d
            if k < 0:
                h.changeColBounds(int(var[u, s]), 0.0, 0.0)   # never reachable: already excluded by the mask
                h.addRow(-inf, 0.0, 1, np.asarray([ycol[u, s]], np.int32), np.ones(1))
            else:
                h.addRow(-inf, 0.0, 2, np.asarray([ycol[u, s], ycol[lo, lo_slots[k]]], np.int32),
                         np.asarray([1.0, -1.0]))
    return ycol


def reduced_mip(data: GapData, mask: np.ndarray, incumbent: float, *, time_limit_s: float | None,
                start: np.ndarray | None = None, sparse: bool = True, highs_options: dict | None = None,
                restart_if: Callable[[float], bool] | None = None,
                stop: Callable[[], bool] | None = None, proof: bool = True,
                seeds: Sequence[int] = (0,), covers: Sequence[Cover] = ()) -> tuple[str, np.ndarray | None, float]:
    """Problem A restricted to the pairs in ``mask`` (after reduced-cost fixing), solved by HiGHS
    with the objective cut off at ``incumbent``: only strictly better schedules are searched.

    Returns ``(outcome, assignment or None, bound)``: outcome ``"optimal"`` (the assignment is the
    optimum of the restricted problem, or None when no schedule beats ``incumbent``: then the
    bound is ``incumbent``), ``"time_limit"`` with HiGHS's dual bound (held constant included;
    ``inf`` when it has none), or ``"restart"``: HiGHS found a schedule of value v (objective,
    held constant included) with ``restart_if(v)`` true and was stopped there, so that the caller
    can fix more pairs at the better incumbent and start again (the bound is then HiGHS's dual
    bound so far, as for ``"time_limit"``). ``sparse`` picks the layer-order rows (see
    :func:`_add_problem_a`); ``highs_options`` are passed to HiGHS as they are. ``stop()``
    returning true (polled in HiGHS's loops, e.g. set by another thread) ends the run as
    ``"time_limit"``. ``proof=False`` (a heuristic call, whose schedule is checked and valued
    anyway) lets HiGHS use presolve rule 13, which :func:`new_highs` otherwise switches off.
    ``seeds``: one HiGHS run per seed, raced in threads (:func:`~l3gs_opt.models.backends.highs_race.race_mip`:
    they share schedules, the first to close ends all; the bound is the best of theirs).
    ``covers``: cover rows of the arrived-by knapsacks added to the model (:func:`_add_problem_a`).
    """
    import highspy

    n, T = data.n, data.T
    ii, tt = np.nonzero(mask)
    nv = len(ii)
    if nv == 0:
        return "optimal", None, incumbent
    var = -np.ones((n, T), dtype=np.int64)
    var[ii, tt] = np.arange(nv)
    # With ``proof`` its "optimal" closes exact's search: HiGHS's presolve rule that returned wrong
    # optima is switched off (models/backends/highs.py); a heuristic call keeps it (faster).
    def fresh() -> highspy.Highs:
        h = new_highs(time_limit_s=None if time_limit_s is None else max(time_limit_s, 0.01), mip=True, proof=proof)
        for key, value in (highs_options or {}).items():
            h.setOptionValue(key, value)
        # Only schedules strictly better than the incumbent (HiGHS minimises -profit).
        h.setOptionValue("objective_bound", float(-(incumbent - data.constant)))
        return h

    first = fresh()
    ycol = _add_problem_a(first, data, var, ii, tt, sparse=sparse, covers=covers)
    x0 = None
    if start is not None and (start < 0).sum() < n:
        on = np.nonzero(start >= 0)[0]
        if (var[on, start[on]] >= 0).all():
            x0 = np.zeros(nv)
            x0[var[on, start[on]]] = 1.0
            if ycol is not None:   # the cumulative columns follow from x
                full = np.zeros(first.getNumCol())
                full[:nv] = x0
                xs = np.zeros((n, T))
                xs[ii, tt] = x0
                cum = np.cumsum(xs, axis=1)
                has = ycol >= 0
                full[ycol[has]] = cum[has]
                x0 = full
    seeds = tuple(seeds)
    model = first.getModel() if len(seeds) > 1 else None
    restart = [False]

    def improving(event) -> None:
        # HiGHS minimises -(profit): its objective is minus ours without the held constant.
        if restart_if(data.constant - float(event.data_out.objective_function_value)):
            restart[0] = True

    def interrupt(event) -> None:
        if restart[0]:
            event.interrupt()

    def build(seed: int) -> highspy.Highs:
        if seed == seeds[0]:
            h = first
        else:
            h = fresh()
            h.passModel(model)
        if restart_if is not None:
            h.cbMipImprovingSolution.subscribe(improving)
            for hook in (h.cbSimplexInterrupt, h.cbMipInterrupt):
                hook.subscribe(interrupt)
        if x0 is not None:
            h.setSolution(_solution(x0))
        return h

    race = race_mip(build, seeds, stop=stop)

    def decode(col: np.ndarray) -> np.ndarray:
        cand = np.full(n, -1, dtype=np.int64)
        on = col[:nv] > 0.5
        cand[ii[on]] = tt[on]
        return cand

    # (A point no better than the cut-off is not an answer.)
    assign, exact_ok = race.pick(decode, lambda a: assignment_feasible(data, a, mask),
                                 lambda a: assignment_value(data, a), incumbent)
    if exact_ok and race.winner is not None:
        # Closed: nothing in the mask beats max(incumbent, what HiGHS returned).
        return "optimal", assign, (incumbent if assign is None else assignment_value(data, assign))
    dual = -race.dual + data.constant if math.isfinite(race.dual) else math.inf
    # HiGHS's dual bound carries its LP tolerances (as lp_bound's LP value does).
    return ("restart" if restart[0] else "time_limit"), assign, dual + MIP_BOUND_SLACK * abs(dual)


def lp_neighbourhood(data: GapData, x: np.ndarray, allowed: np.ndarray, incumbent: float, *,
                     time_limit_s: float | None, start: np.ndarray | None = None, support: bool = False,
                     band: int = 0, integral_tol: float = 1e-6, seeds: Sequence[int] = (0,)) -> np.ndarray | None:
    """Best schedule in the neighbourhood of an LP (or master) solution ``x`` [n, T]: a chunk the LP
    schedules wholly in slot s may arrive in slots ``s - band .. s + band`` or not at all, every
    other chunk anywhere it is allowed (``band = 0``: a relaxation-induced neighbourhood; a band
    of 2 lets whole chunks shift to make room, which found better schedules at J=200); with
    ``support``, every chunk only where ``x`` is positive (for a column-generation master: its
    restricted master as an integer programme, in arrival terms). Solved by :func:`reduced_mip`
    with the cut-off at ``incumbent`` (one HiGHS run per seed, raced); None when it finds nothing better."""
    if support:
        mask = allowed & (x > integral_tol)
    else:
        whole = (x >= 1.0 - integral_tol) & allowed
        mask = allowed.copy()
        rows = np.nonzero(whole.any(axis=1))[0]
        slot = whole[rows].argmax(axis=1)
        near = np.abs(np.arange(data.T)[None, :] - slot[:, None]) <= band
        mask[rows] = allowed[rows] & near
    if start is not None:   # keep the start inside the neighbourhood, so HiGHS begins from it
        on = np.nonzero(start >= 0)[0]
        mask[on, start[on]] = True
    _, cand, _ = reduced_mip(data, mask, incumbent, time_limit_s=time_limit_s, start=start, proof=False,
                             seeds=seeds)
    return cand
