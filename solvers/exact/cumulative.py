"""``exact`` for Problems I/III under the ``cumulative`` budget (one sequential link).

The per-slot decomposition of :mod:`.search` needs per-slot budgets; under the cumulative budget
the slots are coupled, but in the arrived-by form (:mod:`.cumulative_data`) each budget row
holds one slot's variables again, so the same recipe applies:

1. **Primal start**: the best of the start heuristics (``rolling-future:bb``, ``slope``,
   ``rolling:bb``), and the LP's order (chunks the LP holds at the horizon, sent in the order of
   their LP arrival, each in the first slot the link's bytes allow); both improved by a local
   search over send orders (:mod:`.cumulative_order`: insert, remove, move a chunk) for
   ``ORDER_SHARE`` of the time left.
2. **Bound**: the LP relaxation of the arrived-by model (HiGHS); its duals on the linking rows
   are the multipliers of the Lagrangian bound with one exact 0-1 knapsack per slot (capacity:
   the bytes up to that slot), improved by subgradient steps for ``SUBGRADIENT_SHARE`` of the
   time left.
3. **Reduced-cost fixing**: every Lagrangian value met narrows each chunk's arrival window
   (:func:`.cumulative_data.fix_windows`); an empty window proves the incumbent optimal.
4. **Branch-and-cut**: HiGHS on the arrived-by model over those windows, cut off at the
   incumbent and started from it; its schedules are checked in exact integer bytes. When it finds
   a schedule at which the fixing, redone, would drop at least ``1 - RESTART_SHRINK`` of the
   variables, it is stopped and restarted on the smaller model. One HiGHS run per core (different
   seeds, schedules shared; :func:`~l3gs_opt.models.backends.highs_race.race_mip`): nothing else
   runs then, and HiGHS's time on one model varies with the seed.

A time limit returns the best schedule with the smaller of the Lagrangian bound and HiGHS's dual
bound, status ``time_limit``; ``optimal`` only when the certified gap is at most ``GAP_TOL``.
Any sign of layer utility: every value is summed exactly from the instance, the bound holds for
any sign, and the LP order is only one more candidate schedule.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import GAP_TOL, Solution, Status, finish_solution, relative_gap, utility_scale

from .clock import Clock
from .cumulative_data import (LinkData, LinkMultipliers, Windows, fix_windows, link_data, link_lagrangian,
                              link_subgradient, schedule_feasible, windows_on_events)
from .cumulative_order import improve_order
from .lagrange import assignment_value, into_presolve_slots
from .lns import MIP_BOUND_SLACK
from .starts import run_starts

__all__ = ["solve_cumulative", "START_HEURISTICS", "arrived_by_model"]

START_HEURISTICS = ("rolling-future:bb", "slope", "rolling:bb")
#: Share of the time left after the LP that subgradient steps may take (and at most this many
#: seconds): on the bench's T=60 instances they lowered the bound at the LP duals by 1e-5 to 3e-4
#: of it, and at 3 s a run the proofs took longer (J=50 s0 5.1 s, at 0.5 s 2.3 s).
SUBGRADIENT_SHARE, SUBGRADIENT_MAX_S = 0.05, 0.5
#: Share of the time left (and at most this many seconds) for the order search after the LP: it
#: finds in 0.3 s a schedule HiGHS needed 56 s for (J=50 s1), which shows under short limits;
#: the 60 s proofs are the same with or without it.
ORDER_SHARE, ORDER_MAX_S = 0.1, 5.0
#: HiGHS is stopped and restarted when fixing at its new schedule keeps at most this share.
RESTART_SHRINK = 0.9
#: Seconds kept back from HiGHS's limit (it overruns it a little).
MIP_MARGIN_S = 0.5
#: Seconds between trace points taken inside HiGHS (gap-against-time plots).
TRACE_EVERY_S = 1.0


def arrived_by_model(data: LinkData, windows: Windows, *, relax: bool, events: np.ndarray | None = None):
    """The arrived-by model over the windows as a ``highspy.HighsLp`` (minimising minus the value):
    ``(lp, var, rows)`` with ``var`` [n, T] the column of ``z[i,t]`` (-1: none, z = 0) and ``rows``
    the first row of each family (``"budget"``, ``"stay"``, ``"order"``) plus the (chunk, slot) of
    every linking row.

    With ``events`` [n, T] (``data.allowed``: presolve's event slots, where holding the chunk is
    worth something or the layer above needs it) chunk i may arrive only in those slots: one column
    per event slot in its window, shared by the slots up to its next one (``var`` maps them all), so
    the stay rows link consecutive event slots and the rows' (chunk, slot) are those of the first
    column. A fifth of the columns on the bench instances, the same optimum and LP value. Without
    ``events`` every slot of the window has its column: the root LP is solved so, because its duals
    become the Lagrangian's multipliers, one per slot."""
    from scipy import sparse

    from l3gs_opt.models.backends.highs import sparse_lp

    n, T, d = data.n, data.T, data.d
    first, by = windows.first, windows.by
    tt = np.arange(T)
    has_var = tt[None, :] >= first[:, None]
    own = has_var if events is None else has_var & events   # the slots with a column of their own
    ci, ct = np.nonzero(own)                                  # row-major: by chunk, then slot
    nv = len(ci)
    col_at = -np.ones((n, T), dtype=np.int64)
    col_at[ci, ct] = np.arange(nv)
    latest = np.maximum.accumulate(np.where(own, tt[None, :], -1), axis=1)
    var = np.where(latest >= 0, col_at[np.arange(n)[:, None], np.maximum(latest, 0)], -1)
    ii, ts = np.nonzero(var >= 0)
    r_i, c_i, v_i, lo_b, up_b = [], [], [], [], []
    r = 0
    # Budget rows scaled by their right-hand side (bytes up to 1e12: coefficients <= 1).
    cap = data.capacity.astype(np.float64)
    scale = np.where(cap > 0, cap, 1.0)
    r_i.append(r + ts)
    c_i.append(var[ii, ts])
    v_i.append(data.cost[ii] / scale[ts])
    lo_b.append(np.full(T, -np.inf))
    up_b.append(cap / scale)
    r += T
    # Arrived stays arrived: z[i,t] - z[i,t'] <= 0 for consecutive columns t < t' of chunk i.
    nxt = np.nonzero(ci[1:] == ci[:-1])[0]
    stay_i, stay_t = ci[nxt], ct[nxt]
    r_stay = r
    rows = r + np.arange(len(nxt))
    r_i += [rows, rows]
    c_i += [nxt, nxt + 1]
    v_i += [np.ones(len(rows)), -np.ones(len(rows))]
    lo_b.append(np.full(len(rows), -np.inf))
    up_b.append(np.zeros(len(rows)))
    r += len(rows)
    # Layer order: z[u,t] - z[lo,t-d] <= 0 (no column for z[lo,t-d]: z[u,t] <= 0), once per pair of columns.
    has_lo = (data.lower >= 0)[:, None] & (var >= 0)
    ord_i, ord_t = np.nonzero(has_lo)
    u_col = var[ord_i, ord_t]
    lo_col = np.where(ord_t - d >= 0, var[data.lower[ord_i], np.maximum(ord_t - d, 0)], -1)
    _, keep = np.unique(np.stack([u_col, lo_col]), axis=1, return_index=True)
    keep.sort()
    ord_i, ord_t, u_col, lo_col = ord_i[keep], ord_t[keep], u_col[keep], lo_col[keep]
    r_order = r
    rows = r + np.arange(len(ord_i))
    r_i.append(rows)
    c_i.append(u_col)
    v_i.append(np.ones(len(rows)))
    ok = lo_col >= 0
    r_i.append(rows[ok])
    c_i.append(lo_col[ok])
    v_i.append(-np.ones(int(ok.sum())))
    lo_b.append(np.full(len(rows), -np.inf))
    up_b.append(np.zeros(len(rows)))
    r += len(rows)
    A = sparse.csc_matrix((np.concatenate(v_i), (np.concatenate(r_i), np.concatenate(c_i))), shape=(r, nv))
    value = np.zeros(nv)
    np.add.at(value, var[ii, ts], data.shown[ii, ts])
    forced = np.zeros(nv)
    late = ts >= by[ii]
    forced[var[ii[late], ts[late]]] = 1.0
    lp = sparse_lp(A, col_cost=-value, col_lower=forced,
                   col_upper=np.ones(nv), row_lower=np.concatenate(lo_b), row_upper=np.concatenate(up_b),
                   integer=not relax)
    families = {"budget": 0, "stay": r_stay, "order": r_order, "stay_rows": (stay_i, stay_t),
                "order_rows": (ord_i, ord_t), "end": r}
    return lp, var, families


def _lp_duals(data: LinkData, windows: Windows, time_limit_s: float | None
              ) -> tuple[float | None, LinkMultipliers | None, np.ndarray | None]:
    """LP value, its duals on the linking rows as multipliers, and ``z`` [n, T] (None: no optimal LP)."""
    from l3gs_opt.models.backends.highs import solve_lp

    lp, var, rows = arrived_by_model(data, windows, relax=True)
    if lp.num_col_ == 0:
        return data.constant, LinkMultipliers.zeros(data), np.zeros((data.n, data.T))
    h = solve_lp(lp, time_limit_s=time_limit_s)
    if h is None:
        return None, None, None
    sol = h.getSolution()
    dual = np.maximum(0.0, -np.asarray(sol.row_dual))
    mult = LinkMultipliers.zeros(data)
    si, st = rows["stay_rows"]
    mult.alpha[si, st] = dual[rows["stay"]:rows["stay"] + len(si)]
    oi, ot = rows["order_rows"]
    mult.beta[oi, ot] = dual[rows["order"]:rows["end"]]
    col = np.asarray(sol.col_value)
    z = np.zeros((data.n, data.T))
    on = var >= 0
    z[on] = col[var[on]]
    return data.constant - float(h.getInfo().objective_function_value), mult, z


def lp_order(data: LinkData, z: np.ndarray) -> np.ndarray:
    """A schedule from LP values ``z`` [n, T]: the chunks held at the horizon (``z >= 1/2``), sent
    in the order of their LP arrival (``sum_t (1 - z[i,t])``; a layer after the one below it), each
    in the first slot whose bytes cover it and everything sent before it."""
    n, T = data.n, data.T
    assign = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return assign
    late = (1.0 - np.clip(z, 0.0, 1.0)).sum(axis=1)
    take = z[:, -1] >= 0.5
    sent = 0
    for i in np.lexsort((data.item_l, late)):
        if not take[i]:
            continue
        lo = data.lower[i]
        if lo >= 0 and assign[lo] < 0:
            continue
        c = int(data.cost[i])
        t = max(int(np.searchsorted(data.capacity, sent + c, side="left")), int(data.first[i]))
        if lo >= 0:
            t = max(t, int(assign[lo]) + data.d)
        if t >= T:
            continue
        assign[i] = t
        sent += c
    return assign


def solve_cumulative(instance: Instance, *, time_limit_s: float | None = None,
                     heuristics: tuple[str, ...] | None = None, **_ignored: Any) -> Solution:
    """Solve a layered, cumulative-budget instance exactly (see the module doc), or stop at
    ``time_limit_s`` seconds with the best schedule and a valid bound."""
    run = _Run(instance, time_limit_s)
    run.start(START_HEURISTICS if heuristics is None else tuple(heuristics))
    if run.data.n and not run.proven():
        run.root()
        if not run.proven() and not run.out_of_time():
            run.mip()
    return run.finish()


class _Run(Clock):
    """One run: the incumbent ``assign`` (value ``z``), the bound and its kind, the windows."""

    def __init__(self, instance: Instance, time_limit_s: float | None) -> None:
        self.instance = instance
        self.started = time.perf_counter()
        self.deadline = None if time_limit_s is None else self.started + float(time_limit_s)
        self.data = data = link_data(instance)
        self.assign = np.full(data.n, -1, dtype=np.int64)
        self.z = assignment_value(data, self.assign)
        self.bound, self.bound_kind = (self.z, "no chunk can arrive") if data.n == 0 else (math.inf, "none")
        self.windows = Windows(data.first.copy(), np.full(data.n, data.T, dtype=np.int64), closed=False)
        self.lv = None
        self.trace: list[tuple[float, float, float]] = []
        self.hit_limit = False
        self.details: dict[str, Any] = {"items": data.n, "slots": data.T, "presolve": dict(data.stats),
                                        "form": "arrived-by (cumulative budget)"}

    def proven(self) -> bool:
        # A tenth of GAP_TOL (as the layered search's CLOSE_TOL): finish_solution re-sums the
        # objective from the instance, and its last bit may differ from ours.
        gap = relative_gap(self.z, self.bound, utility_scale(self.instance))
        return gap is not None and gap <= 0.1 * GAP_TOL

    def offer(self, assign: np.ndarray, source: str) -> None:
        if schedule_feasible(self.data, assign):
            value = assignment_value(self.data, assign)
            if value > self.z:
                self.assign, self.z = assign, value
                self.details["incumbent_from"] = source

    def set_bound(self, value: float, kind: str) -> None:
        if value < self.bound:
            self.bound, self.bound_kind = max(value, self.z), kind
        self.trace.append((self.now(), self.z, self.bound))

    def start(self, heuristics: tuple[str, ...]) -> None:
        values = {}
        for name, sol in run_starts(heuristics, self.instance, self.deadline):
            assign = self.data.assignment(sol.arrivals)
            values[name] = assignment_value(self.data, assign)
            self.offer(assign, name)
        self.details["start_values"] = values
        self.trace.append((self.now(), self.z, self.bound))

    def fix(self, lv) -> None:
        self.windows = fix_windows(self.data, lv, self.z, self.windows.first, self.windows.by)
        if self.windows.closed:
            self.set_bound(self.z, "Lagrangian reduced-cost fixing: no arrival window left")

    def root(self) -> None:
        data = self.data
        lp_value, mult, zlp = _lp_duals(data, self.windows, self.left())
        if mult is None:
            self.hit_limit = self.out_of_time()
            return
        self.details["lp_bound"] = lp_value
        by_lp = lp_order(data, zlp)
        self.offer(by_lp, "lp order")
        left = self.left()
        deadline = None if left is None else time.perf_counter() + min(ORDER_MAX_S, ORDER_SHARE * left)
        for name, assign in (("lp order", by_lp), ("start", self.assign)):
            self.offer(improve_order(data, assign, deadline=deadline), f"order search from the {name}")
        self.trace.append((self.now(), self.z, self.bound))
        lv = link_lagrangian(data, mult, first=self.windows.first, deadline=self.deadline)
        self.details["lagrangian_at_lp_duals"] = lv.bound
        self.set_bound(lv.bound, "Lagrangian (per-slot knapsacks at the LP duals)")
        self.fix(lv)
        if self.proven() or self.windows.closed:
            return
        left = self.left()
        budget = SUBGRADIENT_MAX_S if left is None else min(SUBGRADIENT_MAX_S, SUBGRADIENT_SHARE * left)
        best, _ = link_subgradient(data, mult, target=self.z, time_limit_s=budget, first=self.windows.first)
        self.details["lagrangian_subgradient"] = best.bound
        self.set_bound(best.bound, "Lagrangian (per-slot knapsacks, subgradient from the LP duals)")
        self.lv = best
        self.fix(best)
        self.details["windows_after_root"] = self.variables()

    def variables(self) -> int:
        return int(np.maximum(self.data.T - self.windows.first, 0).sum())

    def mip(self) -> None:
        runs = self.details.setdefault("mip_runs", [])
        while not self.proven() and not self.windows.closed:
            left = self.left()
            if left is not None:
                left -= MIP_MARGIN_S
                if left <= 0:
                    self.hit_limit = True
                    return
            size = self.variables()
            z_before = self.z
            outcome, assign, dual = self._mip_once(left, size)
            runs.append({"outcome": outcome, "variables": size, "bound": dual, "seconds": self.now()})
            if assign is not None:
                self.offer(assign, "highs")
            if outcome == "optimal":
                self.set_bound(self.z, "Lagrangian fixing, then HiGHS on the arrived-by model (cut off at the "
                                       "incumbent): closed")
                return
            self.set_bound(max(z_before, dual), "HiGHS dual bound on the arrived-by model after fixing")
            if outcome != "restart":
                self.hit_limit = True
                return
            if self.lv is not None:
                self.fix(self.lv)

    def _mip_once(self, time_limit_s: float | None, size: int) -> tuple[str, np.ndarray | None, float]:
        """HiGHS on the model over the windows, cut off at the incumbent: ``(outcome, schedule or
        None, dual bound)``; outcome ``optimal`` (nothing in the windows beats the incumbent or
        the schedule returned), ``time_limit`` or ``restart``."""
        import highspy

        from l3gs_opt.models.backends.highs import new_highs
        from l3gs_opt.models.backends.highs_race import mip_seeds, race_mip

        data = self.data
        windows = windows_on_events(self.windows, data.allowed)
        if windows.closed:   # a chunk every better schedule needs has no slot left where it matters
            return "optimal", None, self.z
        lp, var, _ = arrived_by_model(data, windows, relax=False, events=data.allowed)
        self.details.setdefault("mip_columns", []).append(int(lp.num_col_))
        restart = [False]
        z_before, best = self.z, [self.z]
        last = [time.perf_counter()]
        traced = [self.bound]

        def note(out) -> None:
            # A trace point: the best schedule and HiGHS's dual bound (valid above z_before: every
            # better schedule lies in the windows), at most one a TRACE_EVERY_S. The raced runs
            # report their own dual bounds: the trace keeps the smallest so far, so it never rises.
            raw = float(out.mip_dual_bound)
            dual = data.constant - raw if math.isfinite(raw) else math.inf
            traced[0] = min(traced[0], max(z_before, dual + MIP_BOUND_SLACK * abs(dual)))
            self.trace.append((self.now(), best[0], max(traced[0], best[0])))
            last[0] = time.perf_counter()

        cols = var >= 0

        def schedule_of(col: np.ndarray) -> np.ndarray:
            zz = np.zeros((data.n, data.T), dtype=bool)
            zz[cols] = col[var[cols]] > 0.5
            return np.where(zz.any(axis=1), np.argmax(zz, axis=1), -1).astype(np.int64)

        def improving(event) -> None:
            cand = schedule_of(np.asarray(event.data_out.mip_solution))
            if not schedule_feasible(data, cand, self.windows.first):
                return   # (over a budget within HiGHS's tolerance: not a schedule)
            value = assignment_value(data, cand)
            if value > best[0]:
                best[0] = value
                note(event.data_out)
            if self.lv is not None and value > self.z:
                w = fix_windows(data, self.lv, value, self.windows.first, self.windows.by)
                if w.closed or int(np.maximum(data.T - w.first, 0).sum()) <= RESTART_SHRINK * size:
                    restart[0] = True

        def interrupt(event) -> None:
            if restart[0]:
                event.interrupt()
            elif time.perf_counter() - last[0] >= TRACE_EVERY_S:
                note(event.data_out)

        # The incumbent as a start, its arrivals moved to event slots (same value), if it lies in the windows.
        x0 = data.arrived(into_presolve_slots(data, self.assign, wait=True))
        start = None
        if not (x0 & ~cols).any() and (x0 | (np.arange(data.T)[None, :] < windows.by[:, None]))[cols].all():
            col_value = np.zeros(lp.num_col_)
            col_value[var[cols]] = x0[cols]
            start = highspy.HighsSolution()
            start.col_value = col_value.tolist()
            start.value_valid = True

        def build(seed: int) -> highspy.Highs:
            h = new_highs(time_limit_s=time_limit_s, mip=True)
            h.passModel(lp)
            h.setOptionValue("objective_bound", float(-(self.z - data.constant)))
            h.cbMipImprovingSolution.subscribe(improving)
            h.cbMipInterrupt.subscribe(interrupt)
            if start is not None:
                h.setSolution(start)
            return h

        race = race_mip(build, mip_seeds())
        assign, exact_ok = race.pick(schedule_of, lambda a: schedule_feasible(data, a, self.windows.first),
                                     lambda a: assignment_value(data, a), self.z)
        if exact_ok and race.winner is not None:
            return "optimal", assign, self.z if assign is None else assignment_value(data, assign)
        dual = data.constant - race.dual if math.isfinite(race.dual) else math.inf
        return ("restart" if restart[0] else "time_limit"), assign, dual + MIP_BOUND_SLACK * abs(dual)

    def finish(self) -> Solution:
        gap = relative_gap(self.z, self.bound, utility_scale(self.instance))
        if gap is not None and gap <= GAP_TOL:
            status, message = Status.OPTIMAL, ""
        elif self.hit_limit or self.out_of_time():
            status, message = Status.TIME_LIMIT, f"stopped: best schedule and a valid bound ({self.bound_kind})"
        else:
            status, message = Status.FEASIBLE, f"search ended without proof ({self.bound_kind})"
        self.details.update({"bound_kind": self.bound_kind, "trace": self.trace})
        return finish_solution(self.instance, self.data.arrivals(self.assign), problem=self.instance.problem,
                               method="exact", status=status, bound=self.bound,
                               runtime_s=time.perf_counter() - self.started, message=message, details=self.details)
