"""The item form (``l3gs-opt/items@1``): precedence DAG and replacement groups, as one ILP.

Variables, for active items i (see :mod:`l3gs_opt.problem.items_presolve`) and slots t:

* ``x[i,t]`` binary: item i arrives in slot t; ``y[i,t]`` binary: i has arrived by slot t,
  ``y[t] = y[t-1] + x[t]`` (so each item arrives at most once);
* ``w[i,t]`` in [0, 1] for items of groups with two or more (active) items: i is the item its
  group shows at slot t, ``sum_{i in g} w[i,t] <= 1`` and ``w[i,t] <= y[i,t-s]`` (s = 0, or 1
  under next-slot availability); for integral ``y`` the best ``w`` is integral.

``max sum gain[t,i] w[i,t] + sum_{i alone in its group} gain[t+s,i] y[i,t] + held constant``
subject to byte budgets, and per edge ``parent -> child`` the precedence
``y[child,t] <= y[parent,t]`` (``<= y[parent,t-1]`` when ``same_slot_layers`` is false).

Problem I is the special case of singleton groups and chains, Problem II of one group per object
and no edges: on :func:`~l3gs_opt.problem.items.items_from_instance` this model has the optimum of
:mod:`.layered` / :mod:`.separate` (tests/test_items.py). The arrival, holding and budget rows
are those of :mod:`._common`, applied to the items as the "layers" of one object.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.arguments import check_slot
from l3gs_opt.problem.instance import Options
from l3gs_opt.problem.items import ItemInstance
from l3gs_opt.problem.items_presolve import ItemReduction, presolve_items
from l3gs_opt.problem.solution import Solution

from ._common import add_arrivals, add_budget, add_holding
from .backends import Backend
from .ilp import solve_built
from .linear import LinearModel, ModelBuilder

__all__ = ["build_items_model", "solve_items_ilp"]


@dataclass(frozen=True)
class _AsOneObject:
    """The item instance as :mod:`._common` reads an Instance: one object whose layers are the items."""

    T: int
    bandwidth: np.ndarray
    cost: np.ndarray     # [1, N]
    held: np.ndarray     # [1, N]
    options: Options
    J: int = 1


@dataclass(frozen=True)
class _ReductionView:
    arrive: np.ndarray   # [1, N, T]
    first: np.ndarray    # [1, N]
    active: np.ndarray   # [1, N]


def build_items_model(instance: ItemInstance, *, slot: int | None = None,
                      presolve_enabled: bool = True) -> LinearModel:
    """The ILP of an item instance (see the module docstring), or with ``slot`` its single-slot
    problem given ``held`` (:meth:`~l3gs_opt.problem.items.ItemInstance.slot_instance`; arrivals decode to
    that slot, ``problem = "MCKP"``).

    Raises
    ------
    SolveError
        ``slot`` out of range.
    """
    target = instance
    if slot is not None:
        slot = check_slot(slot, instance.T)
        target = instance.slot_instance(slot)
    red = presolve_items(target, enabled=presolve_enabled)
    model = _build(target, red, presolved=presolve_enabled, problem="items" if slot is None else "MCKP")
    if slot is None:
        return model
    decode = [(v, tuple((j, i, slot) for j, i, _ in chunks)) for v, chunks in model.decode]
    return dataclasses.replace(model, decode=decode, slot=slot)


def _build(inst: ItemInstance, red: ItemReduction, *, presolved: bool, problem: str) -> LinearModel:
    N, T = inst.N, inst.T
    s = 1 if inst.options.availability == "next_slot" else 0
    view = _AsOneObject(T=T, bandwidth=inst.bandwidth, cost=inst.cost[None, :], held=inst.held[None, :],
                        options=inst.options)
    rview = _ReductionView(arrive=red.arrive[None], first=red.first[None], active=red.active[None])
    # Which groups need the shown-item variables w: a group with one (active) item shows it
    # whenever it is held, so its gain goes straight onto y.
    alone = np.zeros(N, dtype=bool)
    for items in inst.members:
        kept = [i for i in items if red.active[i]] if presolved else list(items)
        if len(kept) == 1:
            alone[kept[0]] = True
    obj_y = np.zeros((1, N, T))
    if T > s:
        obj_y[0, :, :T - s] = np.where(alone[:, None], red.gain[s:].T, 0.0)
    b = ModelBuilder(problem)
    b.constant = red.constant
    x = add_arrivals(b, view, rview)
    # _common names arrivals (0, i, t): the object is the item's own.
    b.decode = [(v, tuple((int(inst.object[i]), i, t) for _, i, t in chunks)) for v, chunks in b.decode]
    add_budget(b, view, x, drop_redundant=presolved)
    y = add_holding(b, view, rview, x, obj=obj_y)
    for g, items in enumerate(inst.members):
        ws_by_t: dict[int, list[int]] = {}
        for i in items:
            if alone[i] or not red.active[i]:
                continue
            for t in range(T):
                gain = float(red.gain[t, i])
                if presolved and gain <= 0:
                    continue
                source = y.get((0, i, t - s))
                if source is None and presolved:
                    continue
                w = b.var(f"w[{i},{t}]", obj=gain, integer=False, integral_ok=True)
                cols, vals = [w], [1.0]
                if source is not None:
                    cols.append(source)
                    vals.append(-1.0)
                b.row(f"show[{i},{t}]", cols, vals, ub=1.0 if (source is None and inst.held[i]) else 0.0)
                ws_by_t.setdefault(t, []).append(w)
        for t, ws in ws_by_t.items():
            if presolved and len(ws) < 2:
                continue
            b.row(f"one[{g},{t}]", ws, [1.0] * len(ws), ub=1.0)
    strict = 1 if not inst.options.same_slot_layers else 0
    for p, c in inst.requires.tolist():
        if presolved and inst.held[p]:
            continue
        for t in range(T):
            v = y.get((0, c, t))
            if v is None:
                continue
            below = y.get((0, p, t - strict))
            cols, vals, rhs = [v], [1.0], 0.0
            if below is not None:
                cols.append(below)
                vals.append(-1.0)
            elif inst.held[p]:
                rhs = 1.0
            b.row(f"req[{p},{c},{t}]", cols, vals, ub=rhs)
    return b.build(**red.stats)


def solve_items_ilp(instance: ItemInstance, *, backend: "str | Backend" = Backend.HIGHS, form: str = "standard",
                    slot: int | None = None, time_limit_s: float | None = None, presolve: bool = True,
                    relax: bool = False, options: Mapping[str, Any] | None = None) -> Solution:
    """Solve an item instance (or its single-slot problem at ``slot``) exactly with an ILP backend.

    As :func:`l3gs_opt.models.solve_ilp`: the naive model's size is reported next to the one
    solved, ``relax`` gives the LP bound with the empty schedule, and the answer is checked in
    exact bytes and re-evaluated from the instance. Arrivals are ``(object, item, t)``.

    Raises
    ------
    SolveError
        ``form`` other than "standard" (the GAP form is Problem I's), bad slot or backend.
    """
    if form != "standard":
        raise SolveError(f"form {form!r}: an item instance has only the standard form (the GAP form is "
                         "Problem I's; convert with l3gs_opt.Instance for it)")
    return solve_built(instance, lambda enabled: build_items_model(instance, slot=slot, presolve_enabled=enabled),
                       backend=backend, slot=slot, time_limit_s=time_limit_s, presolve=presolve, relax=relax,
                       options=options)
