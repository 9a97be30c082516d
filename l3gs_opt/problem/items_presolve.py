"""Presolve of the item form: leave out what an item instance does not need, without changing its optimum.

The rules of :mod:`l3gs_opt.problem.presolve`, stated on the general form:

* a held item gets no variables (its group's best held utility is a constant, ``base``);
* an item can arrive in slot t only if it fits: per-slot budget ``cost <= bandwidth[t]``,
  cumulative budget ``cost <= sum_{t' <= t} bandwidth[t']``; so under per-slot budgets a slot
  with zero bandwidth takes no arrivals;
* per-slot budget: an item arrives no later than its last event slot (below): after it neither
  it nor any item requiring it (those arrive no earlier) adds anything, so leaving them out loses
  nothing;
* cumulative budget: an item arrives only in its *event slots*: those where it adds something
  over its group's held items (``gain > 0`` at the slot it would be shown from) and those an item
  requiring it needs it by (that item's event slots, one earlier under strict precedence). Under
  one link an arrival may wait across slots where the item adds nothing: the group's max is the
  same there (the held items are at least as good), each budget row in between holds one item
  fewer, and the slot it waits for still fits it (as :mod:`l3gs_opt.problem.presolve` does for
  layers; it replaces the rule that moved zero-bandwidth arrivals one slot earlier);
* an item cannot arrive before the earliest slot each unheld parent can (strictly after it
  under strict precedence): an item below one that never fits drags its descendants with it;
* an item is dropped when it adds nothing over its group's held items (``gain = 0``) in every
  slot it could be shown in and no item kept requires it.

Items dominated inside a replacement group are *not* removed: with precedence and budgets over
time that needs care, and the per-slot solvers drop dominated options anyway.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from l3gs_opt.problem.items import ItemInstance, item_gain
from l3gs_opt.problem.presolve import up_to_last

__all__ = ["ItemReduction", "presolve_items"]


@dataclass(frozen=True, eq=False)
class ItemReduction:
    """Which variables an item model needs.

    Attributes
    ----------
    arrive : bool array [N, T]
        Item i may arrive in slot t.
    first : int array [N]
        Earliest slot item i can arrive in (T when never, also for held or dropped items).
    active : bool array [N]
        Item gets variables.
    gain : float array [T, N]
        What showing item i at slot t adds over its group's held items (see
        :func:`l3gs_opt.problem.items.item_gain`).
    constant : float
        Utility of the held items (per group its best), summed over slots.
    stats : dict
        What was dropped, for reports.
    """

    arrive: np.ndarray
    first: np.ndarray
    active: np.ndarray
    gain: np.ndarray
    constant: float
    stats: dict


def _event_slots(inst: ItemInstance, gain: np.ndarray) -> np.ndarray:
    """[N, T] (bool): under the cumulative budget, the slots item i needs to be able to arrive in
    (module doc); ``gain`` [T, N]."""
    T = inst.T
    shift = 1 if inst.options.availability == "next_slot" else 0
    d = 0 if inst.options.same_slot_layers else 1
    events = np.zeros((inst.N, T), dtype=bool)
    events[:, :T - shift] = gain[shift:, :].T > 0
    for i in inst.order.tolist()[::-1]:   # children first: an item's own set is complete
        for p in inst.parents[i]:
            events[p, :T - d] |= events[i, d:]
    return events


def presolve_items(instance: ItemInstance, *, enabled: bool = True) -> ItemReduction:
    """Reduce an item instance; ``enabled=False`` keeps every item and slot (the naive model)."""
    inst = instance
    T, N = inst.T, inst.N
    gain, base = item_gain(inst)
    constant = math.fsum(base.ravel().tolist())
    if not enabled:
        return ItemReduction(arrive=np.ones((N, T), dtype=bool), first=np.zeros(N, dtype=np.int64),
                             active=np.ones(N, dtype=bool), gain=gain, constant=constant, stats={"presolve": False})
    bandwidth = inst.bandwidth.astype(np.int64)
    strict = not inst.options.same_slot_layers
    if inst.options.budget == "per_slot":
        fits = inst.cost[:, None] <= bandwidth[None, :]
    else:
        fits = inst.cost[:, None] <= np.cumsum(bandwidth)[None, :]
    fits &= ~inst.held[:, None]
    slots = np.arange(T)
    first = np.full(N, T, dtype=np.int64)
    for i in inst.order.tolist():
        lower = max((int(first[p]) + strict for p in inst.parents[i] if not inst.held[p]), default=0)
        if lower > 0:
            fits[i, :min(lower, T)] = False
        if fits[i].any():
            first[i] = int(fits[i].argmax())
    shift = 1 if inst.options.availability == "next_slot" else 0
    value = np.where(slots[:, None] >= (first + shift)[None, :], gain, 0.0).sum(axis=0)
    useful = value > 0
    for i in inst.order.tolist()[::-1]:  # children first: an item some useful item requires is useful
        if not useful[i] and any(useful[c] for c in inst.children[i]):
            useful[i] = True
    never_fit = (first >= T) & ~inst.held
    active = useful & ~never_fit & ~inst.held
    # Event slots last, so that the counts keep their meaning (as in the layered presolve).
    events = _event_slots(inst, gain)
    arrive = fits & active[:, None] & (up_to_last(events) if inst.options.budget == "per_slot" else events)
    first = np.where(arrive.any(axis=1), arrive.argmax(axis=1), T)
    stats = {
        "presolve": True,
        "held": int(inst.held.sum()),
        "never_fit": int(never_fit.sum()),
        "no_utility": int((~useful & ~never_fit & ~inst.held).sum()),
        "active_items": int(active.sum()),
        "slots_without_arrivals": int((~arrive.any(axis=0)).sum()) if N else T,
    }
    return ItemReduction(arrive=arrive, first=np.where(active, first, T), active=active, gain=gain,
                         constant=constant, stats=stats)
