"""What a simulated scheduler sees (:class:`SlotView`, :class:`ItemSlotView`) and the built-in schedulers.

A scheduler gets a view at the start of each slot (and, with ``SimConfig.substeps > 1``, again
before each later part of the slot) and returns an ordered list of units to request. Units are
``(j, l)`` pairs of a ``[J, L]`` grid, or ``(j, l, f)`` triples of the ``distill`` view's
``[J, L, 2]`` grid (``f = 0`` compact, ``f = 1`` SH upgrade).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np

__all__ = ["SlotView", "ItemSlotView", "Scheduler", "order_requests", "SlotSolverScheduler", "HorizonScheduler",
           "FixedOrderScheduler", "PreloadScheduler"]

#: Multi-slot registry methods that take ``options={"bound": False}`` (skip their LP bound: the
#: simulator uses the schedule only).
_BOUND_OPTION_PREFIXES = ("rolling:", "rolling-future:", "mpc:", "slope", "progressive", "static")


@dataclass(frozen=True, eq=False)
class SlotView:
    """What a scheduler knows at the start of a slot (indices of its :class:`Catalog`: ``[J, L]``).

    Attributes
    ----------
    slot, slots_left : int
        This slot (0-based) and the slots left including it.
    representation : {"layered", "separate"}
    cost : int array [J, L]
        Bytes of each unit (1 for an empty one).
    utility : float array [J, L]
        Predicted utility of each unit for the coming slot: per layer ``dU`` (layered) or per
        version ``U`` (separate).
    predicted_bytes : int
        Predicted bytes of the coming slot (re-planned within a slot: of the rest of the slot).
    bank_bytes : int
        Bytes banked from earlier slots (cumulative budget).
    in_flight_bytes : int
        Bytes still to come of the chunk cut off at the end of the last slot (sent first).
    held, in_flight, empty : bool arrays [J, L]
        Units complete on the client, cut off and continuing, without splats (always complete).
    budget : {"per_slot", "cumulative"}
        The budget option of the instances a scheduler plans on: ``cumulative`` when the link
        banks idle bytes or is kept busy (``fill``: nothing idles while something is left and a
        chunk cut off carries over, so the bytes arriving by slot t are bounded by the bytes up
        to t), else ``per_slot``.
    slot_s : float
    predicted_bytes_later : int or None
        Predicted bytes of each later slot; None: ``predicted_bytes`` (they differ when a slot is
        re-planned part-way, where ``predicted_bytes`` is what is left of this slot).
    prefix : callable ``(unit) -> float array [splats + 1]`` or None
        Predicted value of a unit's first ``n`` splats in the order they stream (given with
        ``SimConfig.last_chunk="prefix"``); ``bytes_per_splat`` (int array [J, L]) with it.
    """

    slot: int
    slots_left: int
    representation: str
    cost: np.ndarray
    utility: np.ndarray
    predicted_bytes: int
    bank_bytes: int
    in_flight_bytes: int
    held: np.ndarray
    in_flight: np.ndarray
    empty: np.ndarray
    budget: str
    slot_s: float = 1.0
    predicted_bytes_later: int | None = None
    prefix: Callable[[tuple[int, ...]], np.ndarray] | None = None
    bytes_per_splat: np.ndarray | None = None

    @property
    def layered(self) -> bool:
        return self.representation == "layered"

    @property
    def available_bytes(self) -> int:
        """Predicted bytes left for new requests in this slot (after the in-flight chunk)."""
        return max(0, self.predicted_bytes + self.bank_bytes - self.in_flight_bytes)

    def taken(self) -> np.ndarray:
        """Units nobody needs to request: held, in flight or empty."""
        return self.held | self.in_flight | self.empty

    def prerequisites(self, unit: tuple[int, ...]) -> list[tuple[int, ...]]:
        """Units that must be there before ``unit`` (lowest first): its lower layers (layered)."""
        j, l = unit[:2]
        return [(j, k) for k in range(l)] if self.layered else []

    def instance_held(self) -> np.ndarray:
        """``held`` of the instance: held or in flight (what will be there); layered: the prefix
        of such units (an empty unit above a missing layer does not count)."""
        got = (self.held | self.in_flight) & ~self.empty if not self.layered else self.taken()
        if self.layered:
            got = np.cumprod(got, axis=1).astype(bool)
        return got

    def _bandwidth(self, slots: int) -> list[int]:
        """Bytes per planned slot: the prediction (later slots: ``predicted_bytes_later``), the
        bank in slot 0, the in-flight chunk's bytes taken from the first slots (it is sent first)."""
        later = self.predicted_bytes if self.predicted_bytes_later is None else self.predicted_bytes_later
        bw = [int(self.predicted_bytes)] + [int(later)] * (int(slots) - 1)
        bw[0] += int(self.bank_bytes)
        owed = int(self.in_flight_bytes)
        for s in range(len(bw)):
            take = min(owed, bw[s])
            bw[s] -= take
            owed -= take
        return bw

    def instance(self, slots: int = 1, *, options=None):
        """The delivery instance from this slot on: ``slots`` slots whose utility and bandwidth
        hold this slot's prediction (see :meth:`_bandwidth`)."""
        from l3gs_opt.problem.instance import Instance, Options

        utility = np.where(self.empty, 0.0, self.utility)
        return Instance(self.representation, bandwidth=self._bandwidth(slots), cost=self.cost,
                        utility=np.repeat(utility[None], int(slots), axis=0), held=self.instance_held(),
                        slot_s=self.slot_s, options=options if options is not None else Options(budget=self.budget))

    def arrival_units(self, solution) -> list[tuple[tuple[int, ...], int]]:
        """``(unit, slot)`` of each arrival of a solution of :meth:`instance`."""
        return [((int(j), int(l)), int(t)) for j, l, t in solution.arrivals]


@dataclass(frozen=True, eq=False)
class ItemSlotView(SlotView):
    """A :class:`SlotView` whose instances are item instances (``l3gs-opt/items@1``).

    ``variant`` ``distill``: arrays ``[J, L, 2]`` (form 0 compact, 1 SH upgrade), representation
    ``layered``; the instance is :func:`l3gs_opt.problem.items.distill_items` (compact chain per
    object, each upgrade after its compact chunk). ``hierarchy``: arrays ``[J, L]`` of
    versions, representation ``separate``; the instance is :func:`l3gs_opt.problem.items.hierarchy_items`
    (an object's versions one replacement group). Empty units get no item.
    """

    variant: str = "distill"

    def prerequisites(self, unit: tuple[int, ...]) -> list[tuple[int, ...]]:
        """distill: the compact chunks below (and, for an upgrade, of) its layer; hierarchy: none."""
        if self.variant != "distill":
            return []
        j, l, f = unit
        return [(j, k, 0) for k in range(l + 1 if f == 1 else l)]

    def instance_held(self) -> np.ndarray:
        """Held or in flight, non-empty units (closed: a unit gets bytes only after its prerequisites)."""
        return (self.held | self.in_flight) & ~self.empty

    def item_units(self) -> list[tuple[int, ...]]:
        """The unit of each item of :meth:`instance`, in item order."""
        here = ~self.empty
        if self.variant == "distill":
            J, L, _ = here.shape
            return [(j, l, f) for j in range(J) for l in range(L) if here[j, l, 0] for f in (0, 1)]
        return [(int(j), int(l)) for j, l in zip(*np.nonzero(here))]

    def instance(self, slots: int = 1, *, options=None):
        """The item instance from this slot on (see :meth:`SlotView.instance`)."""
        from l3gs_opt.problem.instance import Options
        from l3gs_opt.problem.items import distill_items, hierarchy_items

        opts = options if options is not None else Options(budget=self.budget)
        bw = self._bandwidth(slots)
        utility = np.repeat(np.where(self.empty, 0.0, self.utility)[None], int(slots), axis=0)
        held = self.instance_held()
        if self.variant == "distill":
            here = ~self.empty[..., 0]
            return distill_items(self.cost[..., 0], self.cost[..., 1], utility[..., 0], utility[..., 1], bw,
                                 present=here, held_compact=held[..., 0], held_upgrade=held[..., 1],
                                 slot_s=self.slot_s, options=opts)
        return hierarchy_items(self.cost, utility, bw, present=~self.empty, held=held, slot_s=self.slot_s,
                               options=opts)

    def arrival_units(self, solution) -> list[tuple[tuple[int, ...], int]]:
        units = self.item_units()
        return [(units[int(i)], int(t)) for _, i, t in solution.arrivals]


class Scheduler(Protocol):
    """Each slot, an ordered list of units to request (see :mod:`l3gs_opt.simulator.simulation`).

    Resuming a run (:meth:`Simulation.run` with ``resume``) assumes the requests depend on the
    view only, as for every built-in scheduler.
    """

    name: str

    def requests(self, view: SlotView) -> list[tuple[int, ...]]:
        ...


def order_requests(view: SlotView, picks: Sequence[tuple[int, ...]], later: Sequence[Sequence[tuple[int, ...]]] = (),
                   *, fill: bool = True) -> list[tuple[int, ...]]:
    """The request list: ``picks``, then each group of ``later``, then (``fill``) the rest.

    Inside a group, units go by predicted utility per byte (ties: lower level, lower object,
    lower form); a unit's missing prerequisites (:meth:`SlotView.prerequisites`: lower layers,
    a distill upgrade's compact chunk) are put just before it. The rest: every other unit the
    same way (layered), or per object the versions above the best one held or requested,
    smallest first (separate). Held, in-flight and empty units are never listed.
    """
    eff = np.where(view.empty, 0.0, view.utility) / view.cost
    taken = view.taken().copy()
    out: list[tuple[int, ...]] = []

    def key(c):
        return (-eff[c], c[1], c[0], *c[2:])

    def add(group) -> None:
        for unit in sorted((tuple(int(v) for v in u) for u in group), key=key):
            for u in (*view.prerequisites(unit), unit):
                if not taken[u]:
                    taken[u] = True
                    out.append(u)

    add(picks)
    for group in later:
        add(group)
    if fill:
        if view.layered:
            add([tuple(int(v) for v in u) for u in np.argwhere(~taken)])
        else:
            J, L = view.cost.shape[:2]
            rest = []
            for j in range(J):
                mine = np.flatnonzero(taken[j] & ~view.empty[j])
                top = int(mine.max()) if mine.size else -1
                rest += [(j, l) for l in range(top + 1, L) if not taken[j, l]]
            for u in sorted(rest, key=lambda c: (c[1], -eff[c], c[0])):
                taken[u] = True
                out.append(u)
    return out


@dataclass
class SlotSolverScheduler:
    """The L3GS scheduler: each slot, the single-slot MCKP over the predicted bytes left after
    the in-flight chunk, given what is held or in flight, solved by ``solver`` (on an
    :class:`ItemSlotView`: the item MCKP over precedence-closed sets).

    ``last_chunk="prefix"`` (layered units, a view with ``prefix``): the slot's bytes may end
    inside one chunk whose first splats count (:func:`~l3gs_opt.simulator.last_chunk.plan_last_chunk`,
    its own exact programme: ``solver`` is not used); that chunk is requested after the whole ones."""

    solver: str = "bb"
    time_limit_s: float | None = None
    backend: str = "highs"
    fill: bool = True
    name: str = "l3gs"
    last_chunk: str = "whole"

    def requests(self, view: SlotView) -> list[tuple[int, ...]]:
        from l3gs_opt.methods import solve

        if self.last_chunk == "prefix" and view.prefix is not None:
            return self._with_prefix(view)
        picks: list[tuple[int, ...]] = []
        if view.available_bytes > 0:
            inst = view.instance(1)   # its one slot has view.available_bytes
            sol = solve(inst, self.solver, slot=0, time_limit_s=self.time_limit_s, backend=self.backend)
            picks = [u for u, _ in view.arrival_units(sol)]
        return order_requests(view, picks, fill=self.fill)

    def _with_prefix(self, view: SlotView) -> list[tuple[int, ...]]:
        from l3gs_opt.simulator.last_chunk import plan_last_chunk

        plan = plan_last_chunk(view.cost, np.where(view.empty, 0.0, view.utility), view.instance_held(), view.empty,
                               view.available_bytes, view.prefix, view.bytes_per_splat)
        out = order_requests(view, plan.picks, fill=False)

        def then(units: list[tuple[int, ...]]) -> None:   # append what is not requested yet, in order
            seen = set(out)
            out.extend(u for u in units if u not in seen)

        if plan.partial is not None:   # last of the slot's own requests: the slot's bytes end inside it
            then(order_requests(view, [*out, plan.partial], fill=False))
        if self.fill:
            then(order_requests(view, out, fill=True))
        return out


@dataclass
class HorizonScheduler:
    """A multi-slot method on the instance over the rest of the run (at most ``horizon`` slots)
    with the slot's prediction held constant; its slot-0 arrivals first, then (``fill``) its
    later ones in slot order."""

    method: str
    horizon: int | None = None
    time_limit_s: float | None = None
    backend: str = "highs"
    fill: bool = True
    name: str = ""

    def __post_init__(self) -> None:
        self.name = self.name or self.method

    def requests(self, view: SlotView) -> list[tuple[int, ...]]:
        from l3gs_opt.methods import solve

        slots = view.slots_left if self.horizon is None else min(view.slots_left, self.horizon)
        inst = view.instance(slots)
        options = {"bound": False} if self.method.startswith(_BOUND_OPTION_PREFIXES) else None
        sol = solve(inst, self.method, time_limit_s=self.time_limit_s, backend=self.backend, options=options)
        by_slot: dict[int, list[tuple[int, ...]]] = {}
        for unit, t in view.arrival_units(sol):
            by_slot.setdefault(t, []).append(unit)
        later = [by_slot[t] for t in sorted(by_slot) if t > 0] if self.fill else []
        return order_requests(view, by_slot.get(0, []), later, fill=self.fill)


@dataclass
class FixedOrderScheduler:
    """Every unit not yet there, level by level (then object by object): the bundle's order."""

    name: str = "sort"

    def requests(self, view: SlotView) -> list[tuple[int, int]]:
        J, L = view.cost.shape
        taken = view.taken()
        return [(j, l) for l in range(L) for j in range(J) if not taken[j, l]]


@dataclass
class PreloadScheduler:
    """Requests nothing: the largest model is on the client from the start."""

    name: str = "preload"

    def requests(self, view: SlotView) -> list[tuple[int, int]]:
        return []
