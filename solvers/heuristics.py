"""Order-based multi-slot heuristics: ``progressive``, ``static`` and the paper's ``slope`` greedy.

* ``progressive`` - progressive loading: every object's base layer first (best time-averaged
  utility per byte first), then every second layer, and so on.
* ``static`` - one fixed order of all chunks by time-averaged utility per byte (a layer's lower
  layers are pulled in just before it).
* ``slope`` - the paper's greedy: each slot, repeatedly send the option of best incremental
  slope ``(U[z] - U[h]) / (C[z] - C[h])`` (utility at that slot) that still fits, via the
  rolling engine (so every instance option is respected as in :mod:`.rolling`). With divisible
  layers this greedy is optimal when bandwidth and utilities are static: its value is then the
  LP optimum, which :func:`slope_fractional_value` computes.

The fixed orders are packed slot by slot: per-slot budget - first fit in order, a chunk waits
until its lower layer is held (arrived in an earlier slot when same-slot layers are off);
cumulative budget - one sequential link downloads the chunks in order and each arrives in the
first slot whose cumulative bytes cover everything before it. Separate representation: a
version is sent only if its time-averaged utility beats the best version held (or sent).
Every answer carries the LP relaxation of Problem I/II as its bound.

Signed layer utilities (layered ``dU < 0``): a fixed order skips the layers presolve drops (no
run of layers from them up can add anything), and every answer is cut back, per object, to its
delivered prefix of best value (:func:`~l3gs_opt.problem.evaluate.trim_losing_layers`), so a
negative layer is kept only when the layers above it make it worth it. ``slope`` values whole
levels by their cumulative utility (a level no better than a lower one is never an option).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.evaluate import trim_losing_layers
from l3gs_opt.problem.presolve import presolve, shown_value
from l3gs_opt.problem.solution import Solution, Status, finish_solution

from . import _mckp
from ._mckp import MckpResult, OptionTable
from .rolling import _bound, bound_phrase, run_rolling

__all__ = ["chunk_order", "pack_order", "solve_progressive", "solve_static", "solve_slope",
           "slope_pick", "slope_fractional_value"]


def chunk_order(instance: Instance, kind: str) -> list[tuple[int, int]]:
    """The fixed send order of ``progressive`` or ``static`` (unheld chunks only)."""
    inst = instance
    mean = inst.utility.mean(axis=0)                 # [J, L] time-averaged utility
    eff = mean / inst.cost
    chunks = [(j, l) for j in range(inst.J) for l in range(inst.L) if not inst.held[j, l]]
    if kind == "progressive":
        chunks.sort(key=lambda c: (c[1], -eff[c], c[0]))
    elif kind == "static":
        chunks.sort(key=lambda c: (-eff[c], c[1], c[0]))
    else:
        raise SolveError(f"order {kind!r} is not one of progressive, static")
    if not inst.layered:
        return chunks
    # Pull lower layers in just before a layer that needs them.
    placed = inst.held.copy()
    out: list[tuple[int, int]] = []
    for j, l in chunks:
        for k in range(l + 1):
            if not placed[j, k]:
                placed[j, k] = True
                out.append((j, k))
    return out


def pack_order(instance: Instance, order: list[tuple[int, int]]) -> list[tuple[int, int, int]]:
    """Arrivals ``(j, l, t)`` of sending ``order`` slot by slot (see module doc)."""
    inst = instance
    T = inst.T
    strict = not inst.options.same_slot_layers
    mean = inst.utility.mean(axis=0)
    best = np.where(inst.held, mean, 0.0).max(axis=1, initial=0.0) if not inst.layered else None
    arrived = np.full((inst.J, inst.L), -1, dtype=np.int64)
    held = inst.held.copy()
    out: list[tuple[int, int, int]] = []

    # Signed layer utilities: layers no optimum holds (presolve's rule) would only spend bytes.
    keep = presolve(inst).active | inst.held if inst.layered and (inst.utility < 0).any() else None

    def useful(j: int, l: int) -> bool:
        if inst.layered:
            return keep is None or bool(keep[j, l])
        return mean[j, l] > best[j]

    if inst.options.budget == "cumulative":
        cum = np.cumsum(np.asarray(inst.bandwidth, dtype=np.int64))
        total = 0
        for j, l in order:
            if not useful(j, l):
                continue
            if inst.layered and l > 0 and not held[j, l - 1]:
                continue   # its lower layer never arrived
            c = int(inst.cost[j, l])
            t = int(np.searchsorted(cum, total + c, side="left"))
            if inst.layered and strict and l > 0 and not inst.held[j, l - 1]:
                t = max(t, int(arrived[j, l - 1]) + 1)
            if t >= T:
                continue   # does not arrive within the horizon: the link skips it
            total += c
            held[j, l] = True
            arrived[j, l] = t
            if best is not None:
                best[j] = max(best[j], mean[j, l])
            out.append((j, l, t))
        return out
    pending = list(order)
    for t in range(T):
        budget = int(inst.bandwidth[t])
        changed = True
        while changed and pending and budget > 0:
            changed = False
            rest = []
            for j, l in pending:
                if held[j, l] or not useful(j, l):
                    continue
                ok = True
                if inst.layered and l > 0 and not inst.held[j, l - 1]:
                    ok = held[j, l - 1] and (not strict or arrived[j, l - 1] < t)
                c = int(inst.cost[j, l])
                if ok and c <= budget:
                    budget -= c
                    held[j, l] = True
                    arrived[j, l] = t
                    if best is not None:
                        best[j] = max(best[j], mean[j, l])
                    out.append((j, l, t))
                    changed = True
                else:
                    rest.append((j, l))
            pending = rest
    return out


def _solve_order(instance: Instance, kind: str, *, slot: int | None, with_bound: bool,
                 time_limit_s: float | None) -> Solution:
    if slot is not None:
        raise SolveError(f"method {kind!r} schedules the whole horizon: slot does not apply")
    started = time.perf_counter()
    arrivals = trim_losing_layers(instance, pack_order(instance, chunk_order(instance, kind)))
    schedule_s = time.perf_counter() - started
    bound, bound_s = _bound(instance, with_bound, started, time_limit_s)
    return finish_solution(instance, arrivals, problem=instance.problem, method=kind, status=Status.FEASIBLE,
                           bound=bound, runtime_s=time.perf_counter() - started,
                           message=f"{kind}: fixed-order heuristic; {bound_phrase(bound)}",
                           details={"schedule_s": schedule_s, "bound_s": bound_s})


def solve_progressive(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
                      with_bound: bool = True, **_ignored: Any) -> Solution:
    """Progressive loading (all base layers first, then second layers, ...)."""
    return _solve_order(instance, "progressive", slot=slot, with_bound=with_bound, time_limit_s=time_limit_s)


def solve_static(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
                 with_bound: bool = True, **_ignored: Any) -> Solution:
    """One fixed order by time-averaged utility per byte."""
    return _solve_order(instance, "static", slot=slot, with_bound=with_bound, time_limit_s=time_limit_s)


def slope_pick(table: OptionTable, time_left: float | None = None) -> MckpResult:
    """The paper's per-slot greedy: repeatedly take the option of best incremental slope (value
    per byte above the row's current choice) that fits the bytes left."""
    n = table.n
    choice = np.full(n, -1, dtype=np.int64)
    cur_c = np.zeros(n, dtype=np.int64)
    cur_v = np.zeros(n)
    spare = table.budget
    while n:
        dc = table.cost - cur_c[:, None]
        dv = table.value - cur_v[:, None]
        cand = table.valid & (dc > 0) & (dv > 0) & (dc <= spare)
        if not cand.any():
            break
        slope = np.where(cand, dv / np.where(dc > 0, dc, 1), -np.inf)
        i, k = np.unravel_index(int(np.argmax(slope)), slope.shape)
        spare -= int(dc[i, k])
        cur_c[i], cur_v[i], choice[i] = table.cost[i, k], table.value[i, k], k
    return MckpResult(choice, math.fsum(cur_v.tolist()), math.inf, False, {})


def solve_slope(instance: Instance, *, slot: int | None = None, time_limit_s: float | None = None,
                with_bound: bool = True, **_ignored: Any) -> Solution:
    """The paper's greedy by incremental slope, slot by slot."""
    if slot is not None:
        raise SolveError("method 'slope' schedules the whole horizon: slot does not apply")
    return run_rolling(instance, slope_pick, method="slope", time_limit_s=time_limit_s, with_bound=with_bound)


def slope_fractional_value(instance: Instance) -> float:
    """Objective of the slope greedy with divisible layers (fractions of a layer count pro rata).

    Under static utilities the greedy sends hull increments in one slope order and has
    delivered every byte of the slots so far by the end of each slot, so its value is
    ``sum_t (held_t + H(bytes shown at t))`` where ``H`` is the concave upper-hull fill of all
    objects. That is the LP optimum of Problem I (the paper's "greedy is optimal" for divisible
    layers); the tests check it against an independent LP.

    Raises
    ------
    SolveError
        Separate representation, strict same-slot layers, or utilities that change over time.
    """
    inst = instance
    if not inst.layered:
        raise SolveError("slope_fractional_value: layered instances only")
    if not inst.options.same_slot_layers:
        raise SolveError("slope_fractional_value: needs same-slot layers (the strict variant is another LP)")
    if not np.all(inst.utility == inst.utility[:1]):
        raise SolveError("slope_fractional_value: utilities must be static (the same in every slot)")
    gain, constant = shown_value(inst, inst.utility[:1])
    total_cost = int(inst.cost.sum())
    table = _mckp.build_table(layered=True, cost=inst.cost, gain=gain[0], held=inst.held, budget=total_cost)
    if table.n:
        _, _, dc, dv, slope = _mckp.hull_increments(table)
        order = np.argsort(-slope, kind="stable")
        xs = np.r_[0.0, np.cumsum(dc[order].astype(np.float64))]
        ys = np.r_[0.0, np.cumsum(dv[order])]
    else:
        xs, ys = np.array([0.0]), np.array([0.0])
    cum = np.cumsum(np.asarray(inst.bandwidth, dtype=np.float64))
    if inst.options.availability == "next_slot":
        cum = np.r_[0.0, cum[:-1]]
    return math.fsum((constant + np.interp(cum, xs, ys)).tolist())
