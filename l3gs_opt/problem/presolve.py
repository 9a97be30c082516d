"""Presolve: leave out what an instance does not need, without changing its optimum.

Multi-slot problems (I-IV, GAP form) get a :class:`Reduction`: which chunk may arrive in which
slot, and from which slot a chunk can first be held. Rules, each safe for the exact optimum:

* a held chunk gets no variables (its utility is a constant);
* a chunk can arrive in slot t only if its own cost fits: per-slot budget
  ``cost <= bandwidth[t]``, cumulative budget ``cost <= sum_{t'<=t} bandwidth[t']``; so a slot
  with zero bandwidth takes no arrivals under per-slot budgets;
* layered: layer l cannot arrive before the earliest slot layer l-1 can (strictly after it
  when same-slot layers are off), so a layer above one that never fits never fits either;
* separate: a version is dropped when it adds no utility above the best held version in any
  slot it could be shown in;
* layered, with signed layer utilities ``dU`` (docs/design.md): let ``best[l]`` be the most
  layer l can add, over the slots it may arrive in, from its first showing to the horizon (a
  suffix sum of ``dU``; negative when every suffix is). Layer l is dropped, with every layer
  above it, when no run of layers starting at it can add anything: ``sum_{k=l..m} best[k] <= 0``
  for every ``m >= l``. Then any schedule holding layers ``l..m`` loses nothing by leaving them
  out (it only frees bytes), so some optimum never holds layer l. A layer with ``dU < 0`` under
  a layer that recovers more is kept: it is a step to a better level. With ``dU >= 0`` this is
  the plain rule "no layer from l up adds anything";
* per-slot budget: a chunk arrives no later than its last *event slot* (below): after it the chunk
  is worth nothing for the rest of the horizon, and neither is any layer above it (those arrive no
  earlier), so leaving them all out loses nothing and only frees bytes. 5-21 % of the pairs on the
  bench's T=60 instances (an object that leaves the view for good);
* cumulative budget: a chunk arrives only in its *event slots*, those in which having it is worth
  something (``gain != 0`` at the slot it would be shown from: t, or t+1 under next-slot
  availability) and, layered, those the layer above needs it by (its event slots, one earlier with
  strict layers). Under one link an arrival may always wait across slots in which it is worth
  nothing: the value is the same, each budget row in between holds one chunk fewer and the later
  rows hold the same chunks, and the slot it waits for still fits it (the bytes only grow). So every
  schedule has one as good inside these slots, and so does every LP point. About a fifth of the
  (chunk, slot) pairs on the bench's T=60 instances, where an object out of view is worth nothing.
  Not under per-slot budgets: there the later slot may be full. (This replaces an earlier rule that
  moved arrivals of a zero-bandwidth slot one slot *earlier*; the two normalise in opposite
  directions and cannot both hold.)

Single-slot MCKP options are reduced by :func:`mckp_options` (dominated levels removed: a
level that costs at least as much as another and is worth no more). An option is a whole level,
valued by the *cumulative* utility of the layers it adds, so a negative layer is never an option
of its own unless it is worth something with the layers under it, and a level above it that
recovers stays an option. LP-dominated levels (below the upper convex hull) are *not* removed:
they can be in the integer optimum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from l3gs_opt.problem.arguments import check_instance
from l3gs_opt.problem.instance import Instance

__all__ = ["Reduction", "presolve", "shown_value", "event_slots", "up_to_last", "MckpOptions", "mckp_options"]


@dataclass(frozen=True, eq=False)
class Reduction:
    """Which variables a multi-slot model needs.

    Attributes
    ----------
    arrive : bool array [J, L, T]
        Chunk (j, l) may arrive in slot t.
    first : int array [J, L]
        Earliest slot chunk (j, l) can arrive in (T when never, also for held chunks).
    active : bool array [J, L]
        Chunk gets variables.
    gain : float array [T, J, L]
        Objective coefficient of "chunk shown at slot t": dU (layered, any sign; 0 for held
        layers) or the version's utility above the best held version, clipped at 0 (separate).
    constant : float
        Utility of the held chunks (separate: of the best held version), summed over slots.
    stats : dict
        What was dropped, for reports.
    """

    arrive: np.ndarray
    first: np.ndarray
    active: np.ndarray
    gain: np.ndarray
    constant: float
    stats: dict


def shown_value(instance: Instance, utility: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Per-(t, j, l) objective gain of showing a chunk, and the held constant (float64).

    ``utility`` defaults to the instance's; pass a slice ``[T', J, L]`` for a few slots.
    """
    held = instance.held[None]
    utility = instance.utility if utility is None else utility
    if instance.layered:
        gain = np.where(held, 0.0, utility)
        constant = math.fsum(utility[np.broadcast_to(held, utility.shape)].tolist())
    else:
        base = np.where(held, utility, 0.0).max(axis=2, initial=0.0)
        gain = np.where(held, 0.0, np.clip(utility - base[:, :, None], 0.0, None))
        constant = math.fsum(base.ravel().tolist())
    return gain, constant


def presolve(instance: Instance, *, enabled: bool = True) -> Reduction:
    """Reduce a multi-slot instance; ``enabled=False`` keeps every chunk and slot (naive model)."""
    check_instance(instance, Instance)
    inst = instance
    T, J, L = inst.T, inst.J, inst.L
    gain, constant = shown_value(inst)
    if not enabled:
        arrive = np.ones((J, L, T), dtype=bool)
        first = np.zeros((J, L), dtype=np.int64)
        return Reduction(arrive=arrive, first=first, active=np.ones((J, L), dtype=bool), gain=gain,
                         constant=constant, stats={"presolve": False})
    bandwidth = inst.bandwidth.astype(np.int64)
    if inst.options.budget == "per_slot":
        fits = inst.cost[:, :, None] <= bandwidth[None, None, :]
    else:
        fits = inst.cost[:, :, None] <= np.cumsum(bandwidth)[None, None, :]
    fits &= ~inst.held[:, :, None]
    slots = np.arange(T)
    first = np.full((J, L), T, dtype=np.int64)
    if inst.layered:
        strict = not inst.options.same_slot_layers
        for l in range(L):
            if l == 0:
                lower = np.zeros(J, dtype=np.int64)
            else:  # held chunks have first = T, so a held lower layer must not constrain
                lower = np.where(inst.held[:, l - 1], 0, first[:, l - 1] + (1 if strict else 0))
            fits[:, l, :] &= slots[None, :] >= lower[:, None]
            any_fit = fits[:, l, :].any(axis=1)
            first[:, l] = np.where(any_fit, fits[:, l, :].argmax(axis=1), T)
    else:
        any_fit = fits.any(axis=2)
        first = np.where(any_fit, fits.argmax(axis=2), T)
    never_fit = (first >= T) & ~inst.held
    if inst.layered:
        useful = _layers_worth_keeping(inst, gain, fits, never_fit)
    else:
        # Value a version can still add from its earliest possible showing on (gains >= 0).
        shift = 1 if inst.options.availability == "next_slot" else 0
        mask = slots[:, None, None] >= (first + shift)[None]
        useful = np.where(mask, gain, 0.0).sum(axis=0) > 0  # [J, L]
    active = useful & ~never_fit & ~inst.held
    # Event slots last, so that the counts above keep their meaning (a chunk worth nothing anywhere
    # is "no utility", not "never fits"); a useful chunk keeps its first slot worth something.
    events = event_slots(inst, gain)
    arrive = fits & active[:, :, None] & (up_to_last(events) if inst.options.budget == "per_slot" else events)
    first = np.where(arrive.any(axis=2), arrive.argmax(axis=2), T)
    stats = {
        "presolve": True,
        "held": int(inst.held.sum()),
        "never_fit": int(never_fit.sum()),
        "no_utility": int((~useful & ~never_fit & ~inst.held).sum()),
        "active_chunks": int(active.sum()),
        "slots_without_arrivals": int((~arrive.any(axis=(0, 1))).sum()) if J * L else T,
    }
    return Reduction(arrive=arrive, first=np.where(active, first, T), active=active, gain=gain,
                     constant=constant, stats=stats)


def event_slots(instance: Instance, gain: np.ndarray) -> np.ndarray:
    """[J, L, T] (bool): a chunk's event slots (module doc; under the cumulative budget its only
    arrival slots, under per-slot budgets the last one ends them): ``gain`` [T, J, L] (of
    :func:`shown_value`) is not 0 at the slot the chunk would be shown from, or, layered, the layer
    above has an event slot there (one slot later with strict layers)."""
    inst = instance
    T = inst.T
    shift = 1 if inst.options.availability == "next_slot" else 0
    events = np.zeros((inst.J, inst.L, T), dtype=bool)
    events[:, :, :T - shift] = np.moveaxis(gain, 0, -1)[:, :, shift:] != 0
    if inst.layered:
        d = 0 if inst.options.same_slot_layers else 1
        for l in range(inst.L - 2, -1, -1):   # from the top: the layer above is complete
            events[:, l, :T - d] |= events[:, l + 1, d:]
    return events


def up_to_last(events: np.ndarray) -> np.ndarray:
    """[..., T] (bool): the slots up to the last event slot (none when there is none)."""
    T = events.shape[-1]
    last = np.where(events.any(axis=-1), T - 1 - np.argmax(events[..., ::-1], axis=-1), -1)
    return np.arange(T) <= last[..., None]


def _layers_worth_keeping(inst: Instance, gain: np.ndarray, fits: np.ndarray, never_fit: np.ndarray) -> np.ndarray:
    """Layered: ``[J, L]`` layers some optimum may hold (see the module doc's signed rule).

    ``best[j, l]`` is the largest suffix sum of ``gain[:, j, l]`` from the first showing of an
    arrival slot ``fits`` allows (``-inf`` when none does). Layer l is useless when every run
    ``l..m`` adds at most 0; it and every layer above a useless one are dropped. Sums are compared
    with a margin for their float round-off, so a run whose true sum is positive is never dropped
    (a run that sums to 0 within round-off is kept: harmless, it only keeps a variable).
    """
    T, J, L = gain.shape
    shift = 1 if inst.options.availability == "next_slot" else 0
    g = np.moveaxis(gain, 0, -1)                                          # [J, L, T]
    suffix = np.concatenate([np.flip(np.cumsum(np.flip(g, axis=2), axis=2), axis=2),
                             np.zeros((J, L, 1 + shift))], axis=2)        # suffix[t] = sum_{t' >= t}
    shown = suffix[:, :, shift:shift + T]                                 # value of arriving in slot a
    best = np.where(fits, shown, -np.inf).max(axis=2, initial=-np.inf)
    best = np.where(never_fit, -np.inf, best)
    # Magnitude of the terms in the suffixes compared (the earliest arrival's suffix holds them all).
    magnitude = np.concatenate([np.flip(np.cumsum(np.flip(np.abs(g), axis=2), axis=2), axis=2),
                                np.zeros((J, L, 1 + shift))], axis=2)[:, :, shift:shift + T]
    size = np.where(fits, magnitude, 0.0).max(axis=2, initial=0.0)
    # Each suffix has at most T terms and a run adds at most L of them: (T + L + 2) ulps of the
    # magnitudes bound the round-off; 0 when every term that can be shown is 0, so a layer worth
    # exactly nothing is dropped as it was before signed utilities.
    ulp = (T + L + 2) * np.finfo(np.float64).eps
    useless = np.zeros((J, L), dtype=bool)
    for l in range(L):
        run = np.cumsum(best[:, l:], axis=1)
        margin = ulp * np.cumsum(size[:, l:], axis=1)
        useless[:, l] = ~inst.held[:, l] & (run + margin <= 0).all(axis=1)
    return np.logical_and.accumulate(~useless, axis=1)


@dataclass(frozen=True, eq=False)
class MckpOptions:
    """The single-slot multiple-choice knapsack: per object, the levels it may move up to.

    ``objects[i]`` is the object index; ``cost[i]``, ``value[i]`` and ``arrivals[i]`` are lists
    over that object's options: extra bytes, extra utility at the slot, and the chunks
    ``(j, l)`` that arrive. ``constant`` is the utility shown from held chunks.
    """

    objects: tuple[int, ...]
    cost: tuple[tuple[int, ...], ...]
    value: tuple[tuple[float, ...], ...]
    arrivals: tuple[tuple[tuple[tuple[int, int], ...], ...], ...]
    budget: int
    constant: float
    stats: dict


def mckp_options(instance: Instance, slot: int, *, enabled: bool = True) -> MckpOptions:
    """Options of the single-slot MCKP at ``slot`` given ``held`` (docs/design.md, Lemma 3).

    Layered object j holding h layers may move to any level z > h (all of layers h..z-1 arrive;
    only z = h+1 when same-slot layers are off): extra cost ``C[z] - C[h]``, extra value the
    summed ``dU`` of those layers at the slot. Separate: any unheld version, extra value its
    utility above the best held version (clipped at 0), cost the whole version.

    Presolve (``enabled``) drops options over the budget, options worth nothing, and dominated
    options (another option of the same object costs no more and is worth at least as much).
    """
    inst = instance
    budget = int(inst.bandwidth[slot])
    gain, held_value = shown_value(inst, inst.utility[slot:slot + 1])
    gain = gain[0]
    objects, costs, values, arrivals = [], [], [], []
    dropped = {"over_budget": 0, "no_value": 0, "dominated": 0}
    for j in range(inst.J):
        opts: list[tuple[int, float, tuple[tuple[int, int], ...]]] = []
        if inst.layered:
            h = int(inst.held[j].sum())
            top = inst.L if inst.options.same_slot_layers else min(inst.L, h + 1)
            c, v = 0, 0.0
            for z in range(h, top):
                c += int(inst.cost[j, z])
                v += float(gain[j, z])
                opts.append((c, v, tuple((j, k) for k in range(h, z + 1))))
        else:
            for l in range(inst.L):
                if not inst.held[j, l]:
                    opts.append((int(inst.cost[j, l]), float(gain[j, l]), ((j, l),)))
        if enabled:
            kept = []
            for o in opts:
                if o[0] > budget:
                    dropped["over_budget"] += 1
                elif o[1] <= 0:
                    dropped["no_value"] += 1
                else:
                    kept.append(o)
            # Dominance: sort by cost, then value descending; keep strictly increasing values.
            kept.sort(key=lambda o: (o[0], -o[1]))
            pareto = []
            for o in kept:
                if pareto and o[1] <= pareto[-1][1]:
                    dropped["dominated"] += 1
                    continue
                pareto.append(o)
            opts = pareto
        if opts:
            objects.append(j)
            costs.append(tuple(o[0] for o in opts))
            values.append(tuple(o[1] for o in opts))
            arrivals.append(tuple(o[2] for o in opts))
    stats = {"presolve": enabled, **(dropped if enabled else {})}
    return MckpOptions(objects=tuple(objects), cost=tuple(costs), value=tuple(values), arrivals=tuple(arrivals),
                       budget=budget, constant=held_value, stats=stats)
