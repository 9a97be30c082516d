"""The trace-driven delivery simulator: a client fetches a bundle over a real link, slot by slot,
and what it shows each second is scored against the full teacher scene.

Each slot ``t`` (``slot_s`` seconds, 1 s by default):

1. **Predict.** The client predicts its viewport for the coming slot from the poses before the
   slot starts (``viewport``: ``lr`` -- the paper's linear regression over ``hw_s`` seconds --,
   ``last`` or ``oracle``), ``samples_per_slot`` viewpoints spread over the slot, and the slot's
   bandwidth from the bytes the link delivered in earlier slots (``bandwidth_predictor``:
   ``harmonic`` mean of the last ``bandwidth_window`` slots, optionally ``robust``; ``last``;
   ``oracle``). Slot 0 has no history: the client knows the throughput of its manifest fetch,
   modelled as slot 0's own bytes.
2. **Utility.** Eq. 1 (:mod:`l3gs_opt.utility`) of every splat, averaged over the predicted
   viewpoints (``utility="exact"``), or per (object, layer) from a precomputed viewpoint table
   (``utility="table"``), summed per deliverable unit.
3. **Schedule.** The method's :class:`Scheduler` gets a :class:`SlotView` (predicted utilities
   and bytes, what is held and in flight) and returns an ordered list of units to request.
   The simulator decides nothing itself; it only checks the list (no unit twice, nothing held,
   layers above their lower layers).
4. **Deliver.** The link (:class:`l3gs_opt.link.Link`) moves the slot's bytes of the trace: first
   the chunk cut off at the end of the last slot, then the requests in order. A chunk streams
   its splats in descending utility for the viewpoints predicted when its first byte is sent (as
   in the paper; ``sort`` keeps the bundle's global-significance order), and each splat is usable
   as soon as its bytes have arrived. Idle bytes are lost, or banked with ``budget="cumulative"``.
5. **Render.** At the end of the slot the client renders what it holds from the *true* viewpoint
   (the last pose at or before the slot's end); SSIM and PSNR against the reference scene
   (the full teacher) rendered from the same viewpoint (cached per slot).

Units (what a scheduler requests) follow the method's *view* of the bundle: ``object`` -- one unit
per (object, level), the bundle's chunks (an unsegmented bundle has one object); ``scene`` --
one unit per level, the objects merged (whole-scene layers or versions). Layered bundles
(``layered``, ``sort``, ``distill``) stack layers: every arrived splat is shown. Separate bundles
(``separate``, ``hierarchy``) hold versions: an object shows its highest *complete* version, and a
better version replaces a worse one as a whole. A ``distill`` layer is sent as compact chunk plus
SH upgrade in one stream (each splat usable with its full SH once both parts arrived) and a
``hierarchy`` version as a plain version: their two-step and parent-linked deliveries are methods
still to come (a new :class:`Scheduler` and, where needed, new unit kinds in :class:`Catalog`).

Methods (:data:`SIM_METHODS`, plus every solver method of :func:`l3gs_opt.method_names`):

* ``l3gs`` -- layered and segmented: each slot the single-slot MCKP (Lemma 3) over the predicted
  bytes, given what is held or in flight, solved by ``solver`` (``bb`` by default; ``dp``,
  ``greedy``, ``fptas:EPS``, ``ilp``, ...);
* ``l3gs-noseg`` -- the same on whole-scene layers;
* ``separate`` -- the same on whole-scene versions of a separate bundle (versions replace each
  other);
* ``sort`` -- a ``sort`` bundle's splats in global-significance order, one stream, not
  view-dependent;
* ``preload`` -- the largest model is on the client from the start (the upper reference);
* a single-slot solver name (``bb``, ``dp``, ``greedy``, ``fptas:EPS``) -- ``l3gs`` with that solver;
* a multi-slot method (``rolling:SOLVER``, ``rolling-future:SOLVER``, ``mpc:H``, ``slope``,
  ``progressive``, ``static``, ``ilp``, ``exact``) -- each slot, an instance over the remaining
  horizon (at most ``horizon`` slots) whose utilities and bandwidth hold the slot's prediction
  constant; the slot-0 arrivals are requested first.

``fill`` (default on): the link does not idle while something useful is left -- after the slot's
picks come the plan's later arrivals (multi-slot methods), then every other unit by predicted
utility per byte (layered; lower layers first) or the next larger versions (separate). What does
not arrive in the slot is re-planned next slot, except the chunk cut off, which carries over.
``fill=False`` requests the slot's picks only.

Results: one record per slot (``ssim``, ``psnr``, bytes, requests, per-slot timings of prediction,
utility, scheduling, rendering, reference and metrics) and a summary whose ``ssim_per_s`` has one
value per slot (per second at the default slot length).

``bytes_wasted``: bytes delivered that the last rendered frame does not use: versions replaced
(separate), chunks still incomplete at the end (separate), and the bytes of splats cut in half at
the end (layered).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Protocol, Sequence

import numpy as np

from .errors import L3gsError, SolveError
from .link import BUDGETS, Link

__all__ = ["SimulationError", "SimConfig", "Catalog", "build_catalog", "SlotView", "Scheduler",
           "SlotSolverScheduler", "HorizonScheduler", "FixedOrderScheduler", "PreloadScheduler", "order_requests",
           "MethodSpec", "method_spec", "SIM_METHODS", "SLOT_SOLVERS", "Simulation", "SimulationResult", "simulate",
           "trace_bytes", "TIMING_KEYS"]

#: The simulator's own methods; every solver method name is accepted too.
SIM_METHODS = ("l3gs", "l3gs-noseg", "separate", "sort", "preload")
#: Solver names that solve one slot's MCKP (``--solver`` of l3gs, l3gs-noseg, separate).
SLOT_SOLVERS = ("bb", "dp", "greedy", "fptas:EPS", "ilp", "exact", "brute")
#: Per-slot timings kept in every slot record (seconds).
TIMING_KEYS = ("prediction", "utility", "scheduling", "rendering", "reference", "metrics")
_VIEWPORT = ("lr", "last", "oracle")
_BANDWIDTH = ("harmonic", "last", "oracle")
_UTILITY = ("exact", "table")
#: Multi-slot registry methods that take ``options={"bound": False}`` (skip their LP bound: the
#: simulator uses the schedule only).
_BOUND_OPTION_PREFIXES = ("rolling:", "rolling-future:", "mpc:", "slope", "progressive", "static")


class SimulationError(L3gsError, ValueError):
    """Bad simulator input (method, option, bundle, pose log); names the field, and the index where one is at fault."""

    def __init__(self, field: str, message: str, index: int | None = None):
        self.field = field
        self.index = index
        super().__init__(f"{field}{'' if index is None else f'[{index}]'}: {message}")


# ---------------------------------------------------------------------------------------- config
@dataclass(frozen=True)
class SimConfig:
    """Options of a simulation (see the module docstring).

    Parameters
    ----------
    slot_s : float
        Slot length, seconds.
    budget : {"per_slot", "cumulative"}
        Idle bytes lost, or banked for the next slot.
    width, height : int
        Rendered (and utility) image size in pixels.
    fov_deg : float
        Horizontal field of view, degrees.
    samples_per_slot : int
        Predicted viewpoints per slot whose utilities are averaged.
    viewport : {"lr", "last", "oracle"}
        Viewport predictor; ``hw_s``: its history window, seconds.
    bandwidth_predictor : {"harmonic", "last", "oracle"}
        ``bandwidth_window``: slots in the harmonic mean; ``robust``: RobustMPC's discount.
    utility : {"exact", "table"}
        Eq. 1 per predicted viewpoint, or a lookup in a viewpoint table
        (:meth:`l3gs_opt.utility.UtilityTable.lookup` with its defaults).
    pose_start_s : float
        Pose-log time of slot 0's start, seconds.
    time_limit_s : float or None
        Seconds per scheduling call (passed to the solver).
    horizon : int or None
        Multi-slot methods plan at most this many slots ahead (None: the rest of the run).
    fill : bool
        Keep the link busy after the slot's picks (see the module docstring).
    backend : str
        ILP backend of ``ilp``, ``mpc:H``, ``rolling:ilp``.
    """

    slot_s: float = 1.0
    budget: str = "per_slot"
    width: int = 160
    height: int = 120
    fov_deg: float = 70.0
    samples_per_slot: int = 2
    viewport: str = "lr"
    hw_s: float = 0.5
    bandwidth_predictor: str = "harmonic"
    bandwidth_window: int = 5
    robust: bool = False
    utility: str = "exact"
    pose_start_s: float = 0.0
    time_limit_s: float | None = None
    horizon: int | None = None
    fill: bool = True
    backend: str = "highs"

    def __post_init__(self) -> None:
        def positive(name: str, integer: bool = False) -> None:
            v = getattr(self, name)
            ok = isinstance(v, (int, np.integer)) if integer else isinstance(v, (int, float, np.integer, np.floating))
            if isinstance(v, bool) or not ok or not math.isfinite(v) or v <= 0:
                kind = "a positive integer" if integer else "a positive number"
                raise SimulationError(name, f"{v!r}: must be {kind}")

        for name in ("slot_s", "fov_deg", "hw_s"):
            positive(name)
        for name in ("width", "height", "samples_per_slot", "bandwidth_window"):
            positive(name, integer=True)
        if self.width < 11 or self.height < 11:
            raise SimulationError("width", f"{self.width}x{self.height}: SSIM needs at least 11x11 pixels")
        for name, allowed in (("budget", BUDGETS), ("viewport", _VIEWPORT), ("bandwidth_predictor", _BANDWIDTH),
                              ("utility", _UTILITY)):
            if getattr(self, name) not in allowed:
                raise SimulationError(name, f"{getattr(self, name)!r} is not one of {', '.join(allowed)}")
        if self.time_limit_s is not None:
            positive("time_limit_s")
        if self.horizon is not None:
            positive("horizon", integer=True)
        if not (isinstance(self.pose_start_s, (int, float)) and math.isfinite(self.pose_start_s)
                and self.pose_start_s >= 0):
            raise SimulationError("pose_start_s", f"{self.pose_start_s!r}: must be a number >= 0 (seconds)")


# ---------------------------------------------------------------------------------------- catalog
@dataclass(frozen=True, eq=False)
class Catalog:
    """What a method can request: the bundle's splats grouped into units of one view.

    Unit ``k = j * L + l`` is object ``j`` (of the view) at level ``l``.

    Attributes
    ----------
    view : {"object", "scene"}
    representation : {"layered", "separate"}
    rows : list of int arrays, K of them
        Rows of ``scene`` in each unit, in the bundle's order (``scene`` view: objects of a level
        interleaved in proportion, which keeps a ``sort`` bundle's global-significance order as
        far as the per-object chunks allow).
    unit_of_row : int array [N]
        The unit of each row of ``scene``.
    splats, bytes_per_splat, bytes : int arrays [K]
        Splats, bytes per splat and bytes (= splats x bytes per splat) of each unit; an empty
        unit has 0 of each.
    shape : (J, L)
    """

    view: str
    representation: str
    rows: list
    unit_of_row: np.ndarray
    splats: np.ndarray
    bytes_per_splat: np.ndarray
    bytes: np.ndarray
    shape: tuple[int, int]

    @property
    def units(self) -> int:
        return len(self.rows)

    @property
    def cost(self) -> np.ndarray:
        """``[J, L]`` bytes per unit; an empty unit costs 1 byte (the instance contract wants > 0)."""
        return np.maximum(self.bytes, 1).reshape(self.shape)

    @property
    def empty(self) -> np.ndarray:
        return (self.splats == 0).reshape(self.shape)

    def top_units(self) -> np.ndarray:
        """Units of the largest model: every unit (layered) or the last level's (separate)."""
        J, L = self.shape
        if self.representation == "layered":
            return np.arange(J * L)
        return np.arange(J) * L + (L - 1)


def _base_scene(bundle):
    """All splats the bundle can deliver, with per-row object ids (manifest ids) and levels."""
    from .bundle import _concat

    L = bundle.num_levels
    segmented = bundle.manifest["segmented"]
    if bundle.manifest["representation"] == "layered":
        scene = bundle.scene(L - 1)
        level = np.zeros(scene.num_splats, np.int64) if scene.layers is None else scene.layers.astype(np.int64)
    else:
        parts = [bundle.level_scene(l) for l in range(L)]
        scene = _concat(parts)
        level = np.concatenate([np.full(p.num_splats, l, np.int64) for l, p in enumerate(parts)])
    obj = scene.object_ids.astype(np.int64) if segmented and scene.object_ids is not None \
        else np.zeros(scene.num_splats, np.int64)
    return scene, obj, level


def _chunk_bytes_per_splat(bundle) -> dict:
    """``(object id, level) -> bytes per splat`` over the SH forms of that chunk (distill: both parts)."""
    sums: dict = {}
    splats: dict = {}
    for c in bundle.manifest["chunks"]:
        key = (c["object"], c["level"])
        sums[key] = sums.get(key, 0) + int(c["bytes"])
        if c["sh_form"] != "sh_upgrade":
            splats[key] = int(c["splats"])
    out = {}
    for key, total in sums.items():
        n = splats.get(key, 0)
        if n <= 0 or total % n:
            raise SimulationError("chunks", f"object {key[0]} level {key[1]}: {total} bytes do not split into "
                                            f"{n} splats")
        out[key] = total // n
    return out


def build_catalog(bundle, view: str = "object", *, base=None) -> Catalog:
    """The units of ``bundle`` seen by ``view`` (``object`` or ``scene``; see :class:`Catalog`).

    ``base`` (the ``(scene, object ids, levels)`` of :func:`_base_scene`) avoids reading the
    chunks again.
    """
    if view not in ("object", "scene"):
        raise SimulationError("view", f"{view!r} is not one of object, scene")
    m = bundle.manifest
    scene, obj, level = base if base is not None else _base_scene(bundle)
    objects = list(m["objects"]) if m["segmented"] else [0]
    index = {o: j for j, o in enumerate(objects)}
    L = bundle.num_levels
    J = len(objects) if view == "object" else 1
    if view == "object":
        j_of_row = np.array([index[o] for o in obj.tolist()], np.int64)
    else:
        j_of_row = np.zeros(len(obj), np.int64)
    unit = j_of_row * L + level
    bps_chunk = _chunk_bytes_per_splat(bundle)
    K = J * L
    rows, splats, bps = [], np.zeros(K, np.int64), np.zeros(K, np.int64)
    for k in range(K):
        r = np.flatnonzero(unit == k)
        if view == "scene" and r.size:
            # Interleave the objects of the level in proportion (rank within object / object size).
            key = np.zeros(r.size)
            for o in np.unique(obj[r]):
                sel = obj[r] == o
                key[sel] = (np.arange(sel.sum()) + 0.5) / sel.sum()
            r = r[np.argsort(key, kind="stable")]
        rows.append(r)
        splats[k] = r.size
        if r.size:
            members = {bps_chunk.get((int(o), int(level[r[0]])), None) for o in np.unique(obj[r])}
            if None in members or len(members) != 1:
                raise SimulationError("chunks", f"unit {k}: its chunks have different record sizes {sorted(members)}"
                                                " and cannot be merged into one stream")
            bps[k] = members.pop()
    return Catalog(view=view, representation=m["representation"], rows=rows, unit_of_row=unit,
                   splats=splats, bytes_per_splat=bps, bytes=splats * bps, shape=(J, L))


# ---------------------------------------------------------------------------------------- schedulers
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
        Predicted bytes of the coming slot.
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

    def instance_held(self) -> np.ndarray:
        """``held`` of the instance: held or in flight (what will be there); layered: the prefix
        of such units (an empty unit above a missing layer does not count)."""
        got = (self.held | self.in_flight) & ~self.empty if not self.layered else self.taken()
        if self.layered:
            got = np.cumprod(got, axis=1).astype(bool)
        return got

    def instance(self, slots: int = 1, *, options=None):
        """The delivery instance from this slot on: ``slots`` slots whose utility and bandwidth
        hold this slot's prediction; slot 0 gets the bank, and the in-flight chunk's bytes are
        taken from the first slots (it is sent first)."""
        from .instance import Instance, Options

        bw = [int(self.predicted_bytes)] * int(slots)
        bw[0] += int(self.bank_bytes)
        owed = int(self.in_flight_bytes)
        for s in range(len(bw)):
            take = min(owed, bw[s])
            bw[s] -= take
            owed -= take
        utility = np.where(self.empty, 0.0, self.utility)
        return Instance(self.representation, bandwidth=bw, cost=self.cost,
                        utility=np.repeat(utility[None], int(slots), axis=0), held=self.instance_held(),
                        slot_s=self.slot_s, options=options if options is not None else Options(budget=self.budget))


class Scheduler(Protocol):
    """Each slot, an ordered list of units ``(j, l)`` to request (see the module docstring)."""

    name: str

    def requests(self, view: SlotView) -> list[tuple[int, int]]:
        ...


def order_requests(view: SlotView, picks: Sequence[tuple[int, int]], later: Sequence[Sequence[tuple[int, int]]] = (),
                   *, fill: bool = True) -> list[tuple[int, int]]:
    """The request list: ``picks``, then each group of ``later``, then (``fill``) the rest.

    Inside a group, units go by predicted utility per byte (ties: lower level, lower object);
    a layer's missing lower layers are put just before it. The rest: every other unit the same
    way (layered), or per object the versions above the best one held or requested, smallest
    first (separate). Held, in-flight and empty units are never listed.
    """
    eff = np.where(view.empty, 0.0, view.utility) / view.cost
    taken = view.taken().copy()
    out: list[tuple[int, int]] = []

    def add(group) -> None:
        for j, l in sorted(((int(j), int(l)) for j, l in group), key=lambda c: (-eff[c], c[1], c[0])):
            for k in (range(l + 1) if view.layered else (l,)):
                if not taken[j, k]:
                    taken[j, k] = True
                    out.append((j, k))

    add(picks)
    for group in later:
        add(group)
    if fill:
        J, L = view.cost.shape
        if view.layered:
            add([(j, l) for j in range(J) for l in range(L) if not taken[j, l]])
        else:
            rest = []
            for j in range(J):
                mine = np.flatnonzero(taken[j] & ~view.empty[j])
                top = int(mine.max()) if mine.size else -1
                rest += [(j, l) for l in range(top + 1, L) if not taken[j, l]]
            for j, l in sorted(rest, key=lambda c: (c[1], -eff[c], c[0])):
                taken[j, l] = True
                out.append((j, l))
    return out


@dataclass
class SlotSolverScheduler:
    """The L3GS scheduler: each slot, the single-slot MCKP over the predicted bytes left after
    the in-flight chunk, given what is held or in flight, solved by ``solver``."""

    solver: str = "bb"
    time_limit_s: float | None = None
    backend: str = "highs"
    fill: bool = True
    name: str = "l3gs"

    def requests(self, view: SlotView) -> list[tuple[int, int]]:
        from .api import solve

        picks: list[tuple[int, int]] = []
        if view.available_bytes > 0:
            inst = view.instance(1)   # its one slot has view.available_bytes
            sol = solve(inst, self.solver, slot=0, time_limit_s=self.time_limit_s, backend=self.backend)
            picks = [(j, l) for j, l, _ in sol.arrivals]
        return order_requests(view, picks, fill=self.fill)


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

    def requests(self, view: SlotView) -> list[tuple[int, int]]:
        from .api import solve

        slots = view.slots_left if self.horizon is None else min(view.slots_left, self.horizon)
        inst = view.instance(slots)
        options = {"bound": False} if self.method.startswith(_BOUND_OPTION_PREFIXES) else None
        sol = solve(inst, self.method, time_limit_s=self.time_limit_s, backend=self.backend, options=options)
        by_slot: dict[int, list[tuple[int, int]]] = {}
        for j, l, t in sol.arrivals:
            by_slot.setdefault(int(t), []).append((j, l))
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


@dataclass(frozen=True)
class MethodSpec:
    """How a method sees the bundle and who schedules.

    ``view``: ``object`` or ``scene`` units; ``order``: ``utility`` (a chunk's splats in
    descending predicted utility) or ``bundle`` (stored order); ``preload``: start with the
    largest model.
    """

    name: str
    solver: str | None
    view: str
    order: str
    scheduler: Any
    preload: bool = False


def _is_slot_solver(name: str) -> bool:
    return name in ("bb", "dp", "greedy", "ilp", "exact", "brute") or name.startswith("fptas:")


def _check_solver_name(name: str, field: str) -> None:
    from .api import METHODS

    if name == "lp":
        raise SimulationError(field, "'lp' is a bound (a relaxation), not a schedule")
    if name not in METHODS:
        from .solvers.registry import resolve

        try:
            resolve(name)
        except SolveError as exc:
            raise SimulationError(field, str(exc)) from None


def method_spec(name: str, *, solver: str | None = None, representation: str = "layered", variant: str = "layered",
                config: SimConfig = SimConfig()) -> MethodSpec:
    """Resolve a simulator method name for a bundle of ``representation`` and ``variant``.

    Raises
    ------
    SimulationError
        Unknown method or solver; a method that does not apply to the bundle (``l3gs`` on a
        separate bundle, ``separate`` on a layered one, ``sort`` on a bundle not built as ``sort``);
        ``solver`` given to a method that has its own.
    """
    if not isinstance(name, str) or not name:
        raise SimulationError("method", f"{name!r} must be a method name")
    kw = dict(time_limit_s=config.time_limit_s, backend=config.backend, fill=config.fill)
    if name in ("l3gs", "l3gs-noseg", "separate"):
        solver = solver or "bb"
        _check_solver_name(solver, "solver")
        if not _is_slot_solver(solver):
            raise SimulationError("solver", f"{solver!r} does not solve one slot's MCKP; use one of "
                                            f"{', '.join(SLOT_SOLVERS)} (or pass {solver!r} as the method)")
        if name == "separate" and representation != "separate":
            raise SimulationError("method", f"'separate' needs a separate bundle (variant separate or hierarchy), "
                                            f"not {variant!r}")
        if name != "separate" and representation != "layered":
            raise SimulationError("method", f"{name!r} needs a layered bundle (variant layered, sort or distill), "
                                            f"not {variant!r}; use method 'separate'")
        view = "object" if name == "l3gs" else "scene"
        return MethodSpec(name, solver, view, "utility", SlotSolverScheduler(solver, name=name, **kw))
    if solver is not None:
        raise SimulationError("solver", f"applies to l3gs, l3gs-noseg and separate only, not to method {name!r}")
    if name == "sort":
        if variant != "sort":
            raise SimulationError("method", f"'sort' needs a bundle built as variant sort (global-significance "
                                            f"order), not {variant!r}")
        return MethodSpec(name, None, "scene", "bundle", FixedOrderScheduler())
    if name == "preload":
        return MethodSpec(name, None, "scene", "bundle", PreloadScheduler(), preload=True)
    _check_solver_name(name, "method")
    if _is_slot_solver(name) and name not in ("ilp", "exact", "brute"):
        return MethodSpec(name, None, "object", "utility", SlotSolverScheduler(name, name=name, **kw))
    return MethodSpec(name, None, "object", "utility", HorizonScheduler(name, horizon=config.horizon, **kw))


# ---------------------------------------------------------------------------------------- results
@dataclass
class SimulationResult:
    """One run: a record per slot and the summary (``to_dict``)."""

    method: str
    solver: str | None
    records: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    #: Rows of :attr:`Simulation.scene` shown in the last slot.
    final_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def ssim_per_s(self) -> list[float]:
        return [r["ssim"] for r in self.records]

    @property
    def ssim_mean(self) -> float:
        return float(np.mean(self.ssim_per_s)) if self.records else float("nan")

    def to_dict(self) -> dict:
        return dict(self.summary)


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def trace_bytes(trace: str, *, mbps: float | None = None, start: int = 0, slots: int = 60,
                slot_s: float = 1.0) -> tuple[np.ndarray, dict]:
    """Bytes per slot of a trace window (scaled to a mean of ``mbps`` Mbit/s first) and what was used."""
    from .traces import mbps_to_bytes, read_bandwidth_trace

    raw = read_bandwidth_trace(trace)
    scaled, factor = raw.scaled(mbps) if mbps is not None else (raw, 1.0)
    window = scaled.window(start, slots)
    info = {"trace": raw.name, "trace_mean_mbps_raw": float(raw.mbps.mean()), "scale_factor": factor,
            "target_mean_mbps": mbps, "window": {"start_s": start, "length_s": slots},
            "window_mean_mbps": float(window.mbps.mean())}
    return mbps_to_bytes(window.mbps, slot_s), info


# ---------------------------------------------------------------------------------------- simulation
class Simulation:
    """A bundle, a viewer and a link, prepared once; :meth:`run` simulates one method.

    Predictions, utilities and reference renders depend on the slot only, so they are computed
    once and shared by every method run on the same simulation (a cached value keeps the time it
    took, so each run's latency breakdown still shows it).

    Parameters
    ----------
    bundle : path or Bundle
    poses : path or PoseTrace
        The viewer's headset pose log (y up; mapped into the scene by ``mapping``).
    bandwidth_bytes : int array [T]
        Bytes the link allows per slot; T is the number of slots.
    config : SimConfig
    reference : SplatScene, path or None
        The full teacher scene the renders are scored against; None: the bundle's largest model.
    mapping : PoseMapping, optional
        Head pose -> camera (default: :data:`l3gs_opt.scene_instance.Z_UP_MAPPING`, z-up scenes).
    utility_tables : mapping view -> UtilityTable, optional
        Tables for ``utility="table"``, labelled like the view's units; a missing one is built
        on a 3 x 3 grid over the viewer's positions (12 yaws x 3 pitches).
    """

    def __init__(self, bundle, poses, bandwidth_bytes: Sequence[int], *, config: SimConfig = SimConfig(),
                 reference=None, mapping=None, utility_tables: Mapping[str, Any] | None = None,
                 info: Mapping[str, Any] | None = None):
        from .bundle import Bundle, read_bundle
        from .camera_paths import intrinsics_from_fov
        from .poses import PoseTrace, read_pose_log
        from .scene_instance import Z_UP_MAPPING
        from .scene_io import SplatScene, read_ply
        from .utility import UtilityScene

        if not isinstance(config, SimConfig):
            raise SimulationError("config", f"{type(config).__name__} is not a SimConfig")
        self.config = config
        self.bundle = bundle if isinstance(bundle, Bundle) else read_bundle(bundle)
        self.poses = poses if isinstance(poses, PoseTrace) else read_pose_log(poses)
        self.link_bytes = [int(b) for b in Link(list(bandwidth_bytes)).bandwidth]   # validated there
        if not self.link_bytes:
            raise SimulationError("bandwidth_bytes", "needs at least one slot")
        self.T = len(self.link_bytes)
        last_start = config.pose_start_s + (self.T - 1) * config.slot_s
        if self.poses.time_s[-1] < last_start:
            raise SimulationError("path", f"the poses end at {self.poses.time_s[-1]:.1f} s, before the last slot "
                                          f"starts ({last_start:.1f} s): fewer slots, or a longer log")
        self.mapping = mapping or Z_UP_MAPPING
        self.intrinsics = intrinsics_from_fov(config.width, config.height, config.fov_deg)
        self.info = dict(info or {})
        self._base = _base_scene(self.bundle)
        self.scene = self._base[0]
        self._prep = UtilityScene.from_scene(self.scene)
        self._catalogs: dict[str, Catalog] = {}
        self._tables = dict(utility_tables or {})
        if isinstance(reference, (str, os.PathLike)):
            self.reference_label = f"teacher:{reference}"
            reference = read_ply(reference)
        elif isinstance(reference, SplatScene):
            self.reference_label = "given"
        elif reference is None:
            self.reference_label = "bundle:largest"
        else:
            raise SimulationError("reference", f"{type(reference).__name__}: must be a SplatScene, a PLY path or None")
        self._reference = reference
        self._pred: dict[int, dict] = {}
        self._ref: dict[int, tuple] = {}

    # -- per-slot inputs shared by all methods -------------------------------------------
    def catalog(self, view: str) -> Catalog:
        if view not in self._catalogs:
            self._catalogs[view] = build_catalog(self.bundle, view, base=self._base)
        return self._catalogs[view]

    def _cameras(self, poses: np.ndarray) -> list:
        from .cameras import Camera
        from .predictors import wrap_deg

        w2c = self.mapping.world_to_camera(poses[:, :3], wrap_deg(poses[:, 3:]))
        return [Camera(**self.intrinsics, world_to_camera=m) for m in w2c]

    def _predicted_bytes(self, t: int) -> int:
        from .predictors import predict_bandwidth

        cfg = self.config
        b = self.link_bytes
        if cfg.bandwidth_predictor == "oracle" or t == 0:
            return int(b[t])   # slot 0: the manifest fetch's throughput
        if cfg.bandwidth_predictor == "last":
            return int(b[t - 1])
        window = min(cfg.bandwidth_window, t)
        history = np.asarray(b[:t] + [0], dtype=np.float64)   # the 0 stands for the unknown slot t
        return int(math.floor(predict_bandwidth(history, window=window, robust=cfg.robust)[t]))

    def prediction(self, t: int) -> dict:
        """Slot ``t``'s predicted cameras, bytes and (exact mode) per-splat utility, cached."""
        if t in self._pred:
            return self._pred[t]
        from .predictors import predict_viewport
        from .scene_instance import _pose_at, _predicted_poses
        from .utility import splat_utility

        cfg = self.config
        t0 = time.perf_counter()
        start = cfg.pose_start_s + t * cfg.slot_s
        times = start + (np.arange(cfg.samples_per_slot) + 0.5) * cfg.slot_s / cfg.samples_per_slot
        if cfg.viewport == "oracle":
            poses = _pose_at(self.poses, times)
        elif cfg.viewport == "lr":
            poses = _predicted_poses(self.poses, start, times, cfg.hw_s)
        else:
            past = self.poses.features[self.poses.time_s < start]
            last = past[-1:] if len(past) else self.poses.features[:1]
            poses = predict_viewport(last, len(times), method="last")
        cams = self._cameras(poses)
        predicted = self._predicted_bytes(t)
        t1 = time.perf_counter()
        u = None
        if cfg.utility == "exact":
            u = np.mean([splat_utility(self._prep, c) for c in cams], axis=0)
        t2 = time.perf_counter()
        self._pred[t] = {"cameras": cams, "predicted_bytes": predicted, "splat_utility": u,
                         "prediction_s": t1 - t0, "utility_s": t2 - t1}
        return self._pred[t]

    def true_camera(self, t: int):
        from .scene_instance import _pose_at

        end = self.config.pose_start_s + (t + 1) * self.config.slot_s
        return self._cameras(_pose_at(self.poses, np.array([end])))[0]

    def _render(self, scene, camera) -> np.ndarray:
        from .renderer.render import render_scene

        if scene is None or scene.num_splats == 0:
            background = np.clip(np.asarray(camera.background, np.float64), 0.0, 1.0)
            return np.broadcast_to(background, (camera.height, camera.width, 3)).copy()
        return np.clip(render_scene(scene, camera).image.numpy().astype(np.float64), 0.0, 1.0)

    def reference_image(self, t: int) -> tuple[np.ndarray, float]:
        """The reference scene seen from slot ``t``'s true viewpoint, and the seconds it took (cached)."""
        if t not in self._ref:
            t0 = time.perf_counter()
            ref = self._reference
            if ref is None:
                cat = self.catalog("scene")
                rows = np.concatenate([cat.rows[k] for k in cat.top_units()])
                ref = self._reference = self.scene.subset(np.sort(rows))
            self._ref[t] = (self._render(ref, self.true_camera(t)), time.perf_counter() - t0)
        return self._ref[t]

    def _table(self, cat: Catalog):
        if cat.view in self._tables:
            return self._tables[cat.view]
        import dataclasses as dc

        from .utility import build_utility_table

        J, L = cat.shape
        j_of = cat.unit_of_row // L
        labelled = dc.replace(self.scene, object_ids=j_of.astype(np.int32),
                              layers=(cat.unit_of_row % L).astype(np.int32))
        centres = np.array([c.center for c in self._cameras(self.poses.features)])
        lo, hi = centres.min(axis=0), centres.max(axis=0)
        up = int(np.argmin(hi - lo))   # the axis the viewer moves least along: its height
        axes = [a for a in range(3) if a != up]
        grid = []
        for a in np.linspace(lo[axes[0]], hi[axes[0]], 3):
            for b in np.linspace(lo[axes[1]], hi[axes[1]], 3):
                p = np.empty(3)
                p[axes[0]], p[axes[1]], p[up] = a, b, centres[:, up].mean()
                grid.append(p)
        table = build_utility_table(labelled, np.array(grid), yaw_steps=12, pitches_deg=(-20.0, 0.0, 20.0),
                                    up_axis=up, width=self.config.width, height=self.config.height,
                                    fov_deg=self.config.fov_deg)
        self._tables[cat.view] = table
        return table

    def _unit_utility(self, cat: Catalog, pred: dict) -> tuple[np.ndarray, float]:
        """``[J, L]`` predicted utility per unit and the seconds spent (table lookups only)."""
        J, L = cat.shape
        if pred["splat_utility"] is not None:
            u = np.bincount(cat.unit_of_row, weights=pred["splat_utility"], minlength=J * L)
            return u.reshape(J, L), 0.0
        table = self._table(cat)
        t0 = time.perf_counter()
        got = np.mean([table.lookup(c) for c in pred["cameras"]], axis=0)
        out = np.zeros((J, L))
        out[:got.shape[0], :got.shape[1]] = got[:J, :L]
        return out, time.perf_counter() - t0

    def _splat_order(self, cat: Catalog, k: int, pred: dict) -> np.ndarray:
        """Rows of unit ``k`` in descending predicted utility (stable: ties keep the bundle's order)."""
        rows = cat.rows[k]
        u = pred["splat_utility"]
        if u is None:   # table mode: Eq. 1 of this chunk's splats only
            from .utility import splat_utility

            sub = self.scene.subset(rows)
            u_rows = np.mean([splat_utility(sub, c) for c in pred["cameras"]], axis=0)
        else:
            u_rows = u[rows]
        return rows[np.argsort(-u_rows, kind="stable")]

    # -- one method ----------------------------------------------------------------------
    def run(self, method: "str | MethodSpec", *, solver: str | None = None, out_dir: str | os.PathLike | None = None,
            progress: bool = False) -> SimulationResult:
        """Simulate ``method`` over every slot (see the module docstring).

        Parameters
        ----------
        method : str or MethodSpec
            One of :data:`SIM_METHODS` or a solver method name; a :class:`MethodSpec` runs any
            :class:`Scheduler` (how new methods plug in).
        solver : str, optional
            The single-slot solver of ``l3gs``, ``l3gs-noseg``, ``separate`` (default ``bb``).
        out_dir : path, optional
            Append one JSON line per slot to ``OUT/slots.jsonl`` as it finishes, and the summary
            to ``OUT/summary.jsonl``; earlier lines of the same method and solver are replaced.
        progress : bool
            A tqdm bar over the slots (stderr).

        Returns
        -------
        SimulationResult
        """
        from tqdm import tqdm

        from .renderer.metrics import psnr, ssim

        m = self.bundle.manifest
        cfg = self.config
        if isinstance(method, MethodSpec):
            if solver is not None:
                raise SimulationError("solver", "give it in the MethodSpec")
            spec = method
        else:
            spec = method_spec(method, solver=solver, representation=m["representation"], variant=m["variant"],
                               config=cfg)
        cat = self.catalog(spec.view)
        J, L = cat.shape
        K = cat.units
        got = np.zeros(K, np.int64)            # bytes delivered per unit
        complete = cat.splats == 0
        order: list = [None] * K
        if spec.preload:
            for k in cat.top_units():
                complete[k] = True
                order[k] = cat.rows[k]
        link = Link(self.link_bytes, budget=cfg.budget)
        writer = _Writer(out_dir, spec.name, spec.solver)
        load_start = list(os.getloadavg())
        started = time.perf_counter()
        result = SimulationResult(spec.name, spec.solver)
        idle_total = 0
        # A kept-busy link never idles while something is left, and a chunk cut off carries over:
        # the bytes arriving by slot t are bounded by the bytes up to t, the cumulative budget.
        plan_budget = "cumulative" if cfg.budget == "cumulative" or cfg.fill else "per_slot"
        for t in tqdm(range(self.T), desc=f"simulate {spec.name}", unit="slot", disable=not progress):
            pred = self.prediction(t)
            unit_u, lookup_s = self._unit_utility(cat, pred)
            flight = np.zeros(K, bool)
            for transfer in link.in_flight:
                flight[transfer.key] = True
            view = SlotView(slot=t, slots_left=self.T - t, representation=cat.representation, cost=cat.cost,
                            utility=unit_u, predicted_bytes=pred["predicted_bytes"], bank_bytes=link.bank,
                            in_flight_bytes=link.in_flight_bytes, held=complete.reshape(J, L).copy(),
                            in_flight=flight.reshape(J, L), empty=cat.empty, budget=plan_budget, slot_s=cfg.slot_s)
            t0 = time.perf_counter()
            wanted = spec.scheduler.requests(view)
            schedule_s = time.perf_counter() - t0
            ids = self._check_requests(wanted, view, spec.name)
            delivery = link.step([(k, int(cat.bytes[k])) for k in ids])
            t1 = time.perf_counter()
            for k in delivery.started:
                order[k] = self._splat_order(cat, k, pred) if spec.order == "utility" else cat.rows[k]
            order_s = time.perf_counter() - t1
            for k, b in delivery.delivered.items():
                got[k] += b
            for k in delivery.completed:
                complete[k] = True
            idle_total += delivery.idle
            # Render what is held from the true viewpoint at the slot's end.
            t2 = time.perf_counter()
            rows, _ = self._shown(cat, got, complete, order, spec.preload)
            camera = self.true_camera(t)
            image = self._render(self.scene.subset(rows) if rows.size else None, camera)
            render_s = time.perf_counter() - t2
            ref, reference_s = self.reference_image(t)
            t3 = time.perf_counter()
            s, p = ssim(image, ref), psnr(image, ref)
            metrics_s = time.perf_counter() - t3
            record = {"method": spec.name, "solver": spec.solver, "slot": t, "time_s": (t + 1) * cfg.slot_s,
                      "ssim": s, "psnr": _finite_or_none(p), "splats_shown": int(rows.size),
                      "bytes_trace": int(self.link_bytes[t]), "bytes_capacity": int(delivery.capacity),
                      "bytes_delivered": int(delivery.bytes), "bytes_idle": int(delivery.idle),
                      "bytes_banked": int(delivery.banked), "predicted_bytes": int(pred["predicted_bytes"]),
                      "requests": [list(divmod(k, L)) for k in ids],
                      "completed": [list(divmod(k, L)) for k in delivery.completed],
                      "in_flight": [[*divmod(k, L), int(r)] for k, r in delivery.in_flight],
                      "timings_s": {"prediction": pred["prediction_s"], "utility": pred["utility_s"] + lookup_s
                                    + order_s, "scheduling": schedule_s, "rendering": render_s,
                                    "reference": reference_s, "metrics": metrics_s}}
            result.records.append(record)
            writer.slot(record)
        rows, shown_units = self._shown(cat, got, complete, order, spec.preload)
        delivered = int(got.sum())
        useful = int(sum(int(min(got[k], (got[k] // cat.bytes_per_splat[k]) * cat.bytes_per_splat[k]))
                         for k in shown_units if cat.bytes_per_splat[k]))
        replaced = int(sum(int(got[k]) for k in range(K) if complete[k] and k not in shown_units))
        run_s = time.perf_counter() - started
        timings = {key: float(np.mean([r["timings_s"][key] for r in result.records])) for key in TIMING_KEYS}
        ssims = result.ssim_per_s
        psnrs = [r["psnr"] for r in result.records]
        result.summary = {
            "method": spec.name, "solver": spec.solver, "slots": self.T, "slot_s": cfg.slot_s,
            "ssim_mean": float(np.mean(ssims)), "ssim_per_s": ssims, "psnr_per_s": psnrs,
            "psnr_mean": float(np.mean([p for p in psnrs if p is not None])) if any(p is not None for p in psnrs)
            else None,
            "bytes_delivered": delivered, "bytes_wasted": delivered - useful, "bytes_replaced": replaced,
            "bytes_unshown": delivered - useful - replaced, "bytes_idle": int(idle_total),
            "bytes_trace": int(sum(self.link_bytes)), "bytes_model": int(cat.bytes[cat.top_units()].sum()),
            "splats_final": int(rows.size), "timings_mean_s": timings, "run_s": run_s,
            "loadavg_start": load_start, "loadavg_end": list(os.getloadavg()),
            "bundle": str(self.bundle.path), "variant": m["variant"], "representation": cat.representation,
            "view": cat.view, "units": [J, L], "reference": self.reference_label,
            "config": dataclasses.asdict(cfg), **self.info,
        }
        result.final_rows = rows
        writer.summary(result.summary)
        return result

    def _check_requests(self, wanted, view: SlotView, method: str) -> list[int]:
        J, L = view.cost.shape
        taken = view.taken()
        listed = np.zeros((J, L), bool)
        ids = []
        for i, req in enumerate(wanted):
            try:
                j, l = (int(v) for v in req)
            except (TypeError, ValueError):
                raise SimulationError("requests", f"{req!r}: scheduler {method!r} must return (object, level) "
                                                  "pairs", i) from None
            if not (0 <= j < J and 0 <= l < L):
                raise SimulationError("requests", f"({j}, {l}) is outside the {J} x {L} units", i)
            if taken[j, l] or listed[j, l]:
                what = "requested twice" if listed[j, l] else ("empty" if view.empty[j, l] else "held or in flight")
                raise SimulationError("requests", f"({j}, {l}) is {what} (scheduler {method!r})", i)
            if view.layered and l > 0 and not (taken[j, l - 1] or listed[j, l - 1]):
                raise SimulationError("requests", f"({j}, {l}) before its layer {l - 1} (scheduler {method!r})", i)
            listed[j, l] = True
            ids.append(j * L + l)
        return ids

    def _shown(self, cat: Catalog, got: np.ndarray, complete: np.ndarray, order: list,
               preload: bool) -> tuple[np.ndarray, set]:
        """Rows the client shows and the units they come from."""
        J, L = cat.shape
        parts, units = [], set()
        if cat.representation == "layered":
            for k in range(cat.units):
                if not cat.splats[k]:
                    continue
                n = cat.splats[k] if complete[k] else int(got[k] // cat.bytes_per_splat[k])
                if n > 0:
                    parts.append((order[k] if order[k] is not None else cat.rows[k])[:n])
                    units.add(k)
        else:
            for j in range(J):
                done = [l for l in range(L) if complete[j * L + l] and cat.splats[j * L + l]]
                if done:
                    k = j * L + max(done)
                    parts.append(cat.rows[k])
                    units.add(k)
        rows = np.sort(np.concatenate(parts)) if parts else np.zeros(0, np.int64)
        return rows, units


class _Writer:
    """Slot records and the summary, appended as they finish (an interrupted run loses nothing)."""

    def __init__(self, out_dir, method: str, solver: str | None):
        self.dir = None if out_dir is None else Path(out_dir)
        if self.dir is None:
            return
        self.dir.mkdir(parents=True, exist_ok=True)
        self.key = (method, solver)
        for name in ("slots.jsonl", "summary.jsonl"):
            path = self.dir / name
            if path.exists():   # a re-run replaces this method's earlier lines, keeps the others
                keep = [line for line in path.read_text().splitlines() if _key(line) not in (self.key, None)]
                path.write_text("".join(line + "\n" for line in keep))

    def _append(self, name: str, obj: dict) -> None:
        if self.dir is None:
            return
        with open(self.dir / name, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(obj, allow_nan=False) + "\n")
            fh.flush()

    def slot(self, record: dict) -> None:
        self._append("slots.jsonl", record)

    def summary(self, summary: dict) -> None:
        self._append("summary.jsonl", summary)


def _key(line: str) -> tuple | None:
    """``(method, solver)`` of a record line; None for a blank or cut-off line (an interrupted write)."""
    try:
        obj = json.loads(line)
    except json.JSONDecodeError:
        return None
    return (obj.get("method"), obj.get("solver")) if isinstance(obj, dict) else None


def simulate(bundle, poses, bandwidth_bytes: Sequence[int], method: str, *, solver: str | None = None,
             config: SimConfig = SimConfig(), reference=None, mapping=None, out_dir=None,
             progress: bool = False) -> SimulationResult:
    """One method over one bundle, viewer and link (:class:`Simulation` + :meth:`Simulation.run`).

    Example
    -------
    >>> from l3gs_opt.simulate import simulate, trace_bytes        # doctest: +SKIP
    >>> bw, _ = trace_bytes("lumos-throughput-mid-11", mbps=2.0, slots=20)   # doctest: +SKIP
    >>> r = simulate("bundle/", "viewer.log", bw, "l3gs")         # doctest: +SKIP
    >>> r.ssim_mean, r.summary["bytes_delivered"]                 # doctest: +SKIP
    """
    sim = Simulation(bundle, poses, bandwidth_bytes, config=config, reference=reference, mapping=mapping)
    return sim.run(method, solver=solver, out_dir=out_dir, progress=progress)
