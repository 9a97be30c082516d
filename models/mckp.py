"""The single-slot multiple-choice knapsack (the paper's Lemma 3).

Per object pick at most one option (a level above what is held: layered; an unheld version:
separate) to maximise the extra utility shown at the slot within the slot's byte budget:
``max sum_{j,o} v[j,o] u[j,o] + held  s.t.  sum_o v[j,o] <= 1,  sum c[j,o] v[j,o] <= B[t]``.
"""

from __future__ import annotations

from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import mckp_options

from .linear import LinearModel, ModelBuilder

__all__ = ["build_mckp"]


def build_mckp(instance: Instance, slot: int, *, presolved: bool) -> LinearModel:
    opts = mckp_options(instance, slot, enabled=presolved)
    b = ModelBuilder("MCKP", slot=slot)
    b.constant = opts.constant
    one = instance.J == 1
    total_max = 0
    choices: list[int] = []
    costs: list[int] = []
    for j, cost, value, arrivals in zip(opts.objects, opts.cost, opts.value, opts.arrivals):
        vs = []
        for o, (c, u, chunks) in enumerate(zip(cost, value, arrivals)):
            v = b.var(f"v[{o}]" if one else f"v[{j},{o}]", obj=u)
            b.decode.append((v, tuple((jj, ll, slot) for jj, ll in chunks)))
            vs.append(v)
            choices.append(v)
            costs.append(int(c))
        if len(vs) > 1 or not presolved:
            b.row("choose" if one else f"choose[{j}]", vs, [1.0] * len(vs), ub=1.0)
        total_max += max(cost)
    if not presolved or total_max > opts.budget:
        b.byte_row("budget", choices, costs, int(opts.budget))
    return b.build(**opts.stats)
