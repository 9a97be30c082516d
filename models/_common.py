"""Pieces every multi-slot formulation shares: arrival variables, byte budgets, holding chains."""

from __future__ import annotations

import numpy as np

from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import Reduction

from .linear import ModelBuilder, index_name

Key = tuple[int, int, int]


def shift(instance: Instance) -> int:
    """Slots between arrival and first showing: 0 (same_slot) or 1 (next_slot)."""
    return 1 if instance.options.availability == "next_slot" else 0


def add_arrivals(b: ModelBuilder, inst: Instance, red: Reduction,
                 obj: np.ndarray | None = None) -> dict[Key, int]:
    """Binary ``x[j,l,t]`` = chunk (j, l) arrives in slot t, where the reduction allows it.

    ``obj`` ([J, L, T]) gives objective coefficients (GAP form); held chunks of a naive model
    get ``ub = 0``.
    """
    one = inst.J == 1
    x: dict[Key, int] = {}
    for j, l, t in zip(*np.nonzero(red.arrive & red.active[:, :, None])):
        j, l, t = int(j), int(l), int(t)
        x[(j, l, t)] = b.var(index_name("x", j, l, t, one_object=one),
                             obj=0.0 if obj is None else float(obj[j, l, t]),
                             ub=0.0 if inst.held[j, l] else 1.0)
        b.decode.append((x[(j, l, t)], ((j, l, t),)))
    return x


def add_budget(b: ModelBuilder, inst: Instance, x: dict[Key, int], *, drop_redundant: bool) -> None:
    """Byte budgets. Per slot: ``sum c x[., ., t] <= B[t]``. Cumulative: prefix rows "arrivals up
    to t cost at most the bytes up to t" over the binary x (exact digits above 2**31 bytes,
    :meth:`ModelBuilder.byte_row`).

    The prefix rows take O(items T) non-zeros. The sparser carry form (a byte carry
    ``r[t] = r[t-1] + B[t] - sum c x[., ., t] >= 0`` per slot, up to ~1.8e8 bytes at J=20, T=60)
    made both HiGHS 1.14 (carry declared integer) and CBC 2.10.3 (carry continuous) claim wrong
    optima: T60-J20-s9 (HiGHS 228,703.84 "optimal", 229,046.60 feasible in that very model), s6 and
    s8 (CBC); on the prefix rows all three close at the right optimum
    (``benchmarks/results/exact_cumulative.md``, ninth session's notes).
    """
    by_slot: dict[int, list[Key]] = {}
    for key in x:
        by_slot.setdefault(key[2], []).append(key)
    bandwidth = [int(v) for v in inst.bandwidth]
    if inst.options.budget == "per_slot":
        for t in range(inst.T):
            keys = by_slot.get(t, [])
            costs = [int(inst.cost[j, l]) for j, l, _ in keys]
            if drop_redundant and sum(costs) <= bandwidth[t]:
                continue
            b.byte_row(f"budget[{t}]", [x[k] for k in keys], costs, bandwidth[t])
        return
    slots = sorted(by_slot) if drop_redundant else list(range(inst.T))
    if drop_redundant and slots and _cumulative_redundant(inst, x, slots, bandwidth):
        return
    keys: list[Key] = []   # arrivals in the slots up to t
    for t in slots:
        keys += by_slot.get(t, [])
        b.byte_row(f"cumulative[{t}]", [x[k] for k in keys], [int(inst.cost[j, l]) for j, l, _ in keys],
                   sum(bandwidth[:t + 1]))


def _cumulative_redundant(inst: Instance, x: dict[Key, int], slots: list[int], bandwidth: list[int]) -> bool:
    """Whether no schedule can break a cumulative budget: for every slot t with arrivals, the
    distinct chunks that can arrive by t cost at most the bytes up to t (each arrives at most
    once). Summing x's keys against the last slot's budget, as before, missed a slot-0 overflow
    of two chunks that fit one by one (regression test in tests/test_items.py)."""
    first: dict[tuple[int, int], int] = {}
    for j, l, t in x:
        first[(j, l)] = min(first.get((j, l), t), t)
    by_first: dict[int, int] = {}
    for (j, l), t in first.items():
        by_first[t] = by_first.get(t, 0) + int(inst.cost[j, l])
    spent = budget = 0
    prev = -1
    for t in slots:
        spent += by_first.get(t, 0)
        budget += sum(bandwidth[prev + 1:t + 1])
        prev = t
        if spent > budget:
            return False
    return True


def add_holding(b: ModelBuilder, inst: Instance, red: Reduction, x: dict[Key, int],
                obj: np.ndarray | None = None) -> dict[Key, int]:
    """Binary ``y[j,l,t]`` = chunk (j, l) has arrived by the end of slot t, for t from its first
    possible arrival: ``y[t] - y[t-1] - x[t] = held`` (held only on the first row of a naive
    model). ``obj`` ([J, L, T]) are the objective coefficients of y. The rows are equalities, not
    ``y <= ...``: with a negative layer utility (signed ``dU``) a model could otherwise fetch a
    layer and leave it "unshown", which the client cannot do.
    """
    one = inst.J == 1
    y: dict[Key, int] = {}
    for j, l in zip(*np.nonzero(red.active)):
        j, l = int(j), int(l)
        held = bool(inst.held[j, l])
        start = int(red.first[j, l])
        for t in range(start, inst.T):
            y[(j, l, t)] = v = b.var(index_name("y", j, l, t, one_object=one),
                                     obj=0.0 if obj is None else float(obj[j, l, t]),
                                     lb=1.0 if held else 0.0)
            cols, vals = [v], [1.0]
            if t > start:
                cols.append(y[(j, l, t - 1)])
                vals.append(-1.0)
            if (j, l, t) in x:
                cols.append(x[(j, l, t)])
                vals.append(-1.0)
            rhs = 1.0 if held and t == start else 0.0
            b.row(f"hold{index_name('', j, l, t, one_object=one)}", cols, vals, lb=rhs, ub=rhs)
    return y


def shown_objective(inst: Instance, red: Reduction) -> np.ndarray:
    """``[J, L, T]`` coefficient of "arrived by slot t": the gain shown at slot t + shift."""
    gain = np.moveaxis(red.gain, 0, -1)  # [J, L, T]
    s = shift(inst)
    if s == 0:
        return gain.copy()
    out = np.zeros_like(gain)
    out[:, :, :-s] = gain[:, :, s:]
    return out
