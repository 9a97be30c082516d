"""Problems I and III: layered chunks, standard form with holding variables.

``max sum_{j,l,t} dU[j,l,t+s] y[j,l,t]`` (s = 0, or 1 for next-slot availability) subject to
per-slot or cumulative byte budgets on ``x``, ``y[t] = y[t-1] + x[t]`` (so each chunk arrives
at most once), and layer order ``y[j,l,t] <= y[j,l-1,t]`` (``<= y[j,l-1,t-1]`` when same-slot
layers are off). Problem III is the same model for a single object. ``dU`` may be negative (signed
layer utilities): every term stays linear, and the holding equalities make a held layer count.
"""

from __future__ import annotations

from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import Reduction

from ._common import add_arrivals, add_budget, add_holding, shown_objective
from .linear import LinearModel, ModelBuilder, index_name

__all__ = ["build_layered"]


def build_layered(instance: Instance, reduction: Reduction, *, presolved: bool) -> LinearModel:
    inst, red = instance, reduction
    b = ModelBuilder(inst.problem)
    b.constant = red.constant
    x = add_arrivals(b, inst, red)
    add_budget(b, inst, x, drop_redundant=presolved)
    y = add_holding(b, inst, red, x, obj=shown_objective(inst, red))
    strict = not inst.options.same_slot_layers
    one = inst.J == 1
    for (j, l, t), v in y.items():
        if l == 0 or (presolved and inst.held[j, l - 1]):
            continue
        below = y.get((j, l - 1, t - 1 if strict else t))
        cols, vals = [v], [1.0]
        rhs = 0.0
        if below is not None:
            cols.append(below)
            vals.append(-1.0)
        elif inst.held[j, l - 1]:
            rhs = 1.0
        b.row(f"order{index_name('', j, l, t, one_object=one)}", cols, vals, ub=rhs)
    return b.build(**red.stats)
