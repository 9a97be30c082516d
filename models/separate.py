"""Problems II and IV: separate versions, the best version held is shown.

The paper's ``max_l`` is linearised with ``w[j,l,t]`` = version l is the one shown at slot t:
``max sum (U[j,l,t] - h[j,t])^+ w[j,l,t] + sum h[j,t]`` where ``h`` is the best held version's
utility, subject to ``sum_l w[j,l,t] <= 1``, ``w[j,l,t] <= y[j,l,t-s]``, byte budgets and
``y[t] = y[t-1] + x[t]``. ``w`` may be continuous: for integral ``y`` the best ``w`` is integral.
Problem IV is the same model for a single object.
"""

from __future__ import annotations

import numpy as np

from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import Reduction

from ._common import add_arrivals, add_budget, add_holding, shift
from .linear import LinearModel, ModelBuilder, index_name

__all__ = ["build_separate"]


def build_separate(instance: Instance, reduction: Reduction, *, presolved: bool) -> LinearModel:
    inst, red = instance, reduction
    b = ModelBuilder(inst.problem)
    b.constant = red.constant
    x = add_arrivals(b, inst, red)
    add_budget(b, inst, x, drop_redundant=presolved)
    y = add_holding(b, inst, red, x)
    s = shift(inst)
    one = inst.J == 1
    shown: dict[tuple[int, int], list[int]] = {}
    for j, l in zip(*np.nonzero(red.active)):
        j, l = int(j), int(l)
        for t in range(inst.T):
            gain = float(red.gain[t, j, l])
            if presolved and gain <= 0:
                continue
            source = y.get((j, l, t - s))
            if source is None and presolved:
                continue
            w = b.var(index_name("w", j, l, t, one_object=one), obj=gain, integer=False, integral_ok=True)
            cols, vals = [w], [1.0]
            if source is not None:
                cols.append(source)
                vals.append(-1.0)
            b.row(f"show{index_name('', j, l, t, one_object=one)}", cols, vals,
                  ub=1.0 if (source is None and inst.held[j, l]) else 0.0)
            shown.setdefault((j, t), []).append(w)
    for (j, t), ws in shown.items():
        if presolved and len(ws) < 2:
            continue
        b.row(f"one[{t}]" if one else f"one[{j},{t}]", ws, [1.0] * len(ws), ub=1.0)
    return b.build(**red.stats)
