"""Problem A, the GAP form of Problem I (the paper's appendix): arrival variables only.

``max sum dU~[j,l,t] x[j,l,t]`` with ``dU~[j,l,t] = sum_{t' >= t+s} dU[j,l,t']`` (the utility
the chunk earns from its arrival to the horizon), subject to byte budgets, ``sum_t x[j,l,t] <= 1``
and layer order on arrival counts ``sum_{t'<=t} x[j,l,t'] <= sum_{t'<=t} x[j,l-1,t']``
(``t' <= t-1`` on the right when same-slot layers are off). Its optimum equals Problem I's
(Lemma 1); the tests check that.
"""

from __future__ import annotations

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import Reduction

from ._common import add_arrivals, add_budget, shown_objective
from .linear import LinearModel, ModelBuilder, index_name

__all__ = ["build_gap"]


def build_gap(instance: Instance, reduction: Reduction, *, presolved: bool) -> LinearModel:
    inst, red = instance, reduction
    if not inst.layered:
        raise SolveError("form 'gap' is defined for the layered representation (Problems I/III) only")
    shown = shown_objective(inst, red)                       # [J, L, T]: value of "held at t"
    future = np.flip(np.cumsum(np.flip(shown, axis=2), axis=2), axis=2)  # sum over t' >= t
    b = ModelBuilder("A")
    b.constant = red.constant
    x = add_arrivals(b, inst, red, obj=future)
    add_budget(b, inst, x, drop_redundant=presolved)
    one = inst.J == 1
    slots: dict[tuple[int, int], list[int]] = {}
    for j, l, t in sorted(x):
        slots.setdefault((j, l), []).append(t)
    for (j, l), ts in slots.items():
        if not presolved or len(ts) > 1:
            b.row(f"once{index_name('', j, l, None, one_object=one)}", [x[(j, l, t)] for t in ts],
                  [1.0] * len(ts), ub=1.0)
    strict = not inst.options.same_slot_layers
    for (j, l), ts in slots.items():
        if l == 0 or (presolved and inst.held[j, l - 1]):
            continue
        lower = slots.get((j, l - 1), [])
        rhs = 1.0 if inst.held[j, l - 1] else 0.0
        for t in ts:
            cols = [x[(j, l, u)] for u in ts if u <= t]
            below = [x[(j, l - 1, u)] for u in lower if (u < t if strict else u <= t)]
            b.row(f"order{index_name('', j, l, t, one_object=one)}", cols + below,
                  [1.0] * len(cols) + [-1.0] * len(below), ub=rhs)
    return b.build(**red.stats)
