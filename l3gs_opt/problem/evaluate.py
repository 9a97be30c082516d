"""Objective and feasibility of a schedule, computed from the instance alone.

Nothing here trusts a solver: the objective is re-evaluated in float64 with ``math.fsum``
(exactly rounded sums, so utilities spanning 1e-9..1e9 do not lose the small terms to
summation order), and feasibility is checked in exact integer bytes (Python ints).

A schedule is a collection of arrivals ``(j, l, t)``: chunk (j, l) arrives in slot t (0-based).
For the single-slot problem (``slot=t``) every arrival is in slot t and the objective is the
utility shown at slot t, held items included.

Malformed input is refused, never guessed at (:func:`checked_arrivals`): each arrival must be a
triple of integers (Python or numpy; not bool, float or str) within the instance, so ``-1`` is
not the last object and ``2.9`` not item 2. A well-formed schedule that breaks a rule (over
budget, a layer without the one below) is what :func:`feasibility_violations` reports.

Layered utilities may be negative (docs/design.md): every layer shown counts with its sign, so a
schedule can be worth less than the empty one. :func:`trim_losing_layers` cuts each object's
delivered layers back to its best prefix, which heuristics use so as never to keep a negative
layer that no later layer makes worth it.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from l3gs_opt.errors import InstanceError
from l3gs_opt.problem.arguments import check_instance, check_slot
from l3gs_opt.problem.instance import Instance

__all__ = [
    "Arrival",
    "checked_arrivals",
    "normalize_arrivals",
    "arrival_slots",
    "evaluate_objective",
    "feasibility_violations",
    "is_feasible",
    "repair_schedule",
    "trim_losing_layers",
]

Arrival = tuple[int, int, int]
NEVER = -1


def normalize_arrivals(arrivals: Iterable[Sequence[int]]) -> tuple[Arrival, ...]:
    """Sorted tuple of ``(j, l, t)`` int triples (by slot, object, layer)."""
    out = [(int(a[0]), int(a[1]), int(a[2])) for a in arrivals]
    return tuple(sorted(out, key=lambda a: (a[2], a[0], a[1])))


def _shown(value: Any) -> str:
    """An arrival or entry as the user wrote it, briefly (a numpy row as a tuple of numbers)."""
    if isinstance(value, np.ndarray):
        value = tuple(value.tolist())
    elif isinstance(value, np.generic):
        value = value.item()
    elif isinstance(value, (tuple, list)):
        value = type(value)(v.item() if isinstance(v, np.generic) else v for v in value)
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def checked_arrivals(arrivals: Any, axes: Sequence[tuple[str, int | None]]) -> list[Arrival]:
    """``arrivals`` as a list of Python int triples, refusing malformed input.

    ``axes`` names each entry and its size, e.g. ``[("object", J), ("layer", L), ("slot", T)]``
    (size ``None``: any integer, for a label). Each arrival must be a tuple, list or 1-D array of
    ``len(axes)`` integers (numpy integers included; a bool, float or str is refused, not
    truncated or parsed), each in ``0..size-1`` (a negative index is refused, not wrapped).

    Raises
    ------
    InstanceError
        Field ``arrivals``, naming the arrival's index, e.g.
        ``arrivals[3] = (0, 5, 1): layer 5 is out of range 0..1``.
    """
    shape = "(" + ", ".join(name for name, _ in axes) + ")"
    if isinstance(arrivals, (str, bytes, Mapping)):
        raise InstanceError("arrivals", f"must be a list of {shape} arrivals, got {type(arrivals).__name__}")
    try:
        items = list(arrivals)
    except TypeError:   # None, a number, a 0-d array
        raise InstanceError("arrivals", f"must be a list of {shape} arrivals, got {type(arrivals).__name__}") \
            from None
    out: list[Arrival] = []
    for k, a in enumerate(items):
        row = isinstance(a, (tuple, list)) or (isinstance(a, np.ndarray) and a.ndim == 1)
        if not row or len(a) != len(axes):
            raise InstanceError("arrivals", f"= {_shown(a)}: must be a {shape} tuple of {len(axes)} integers", (k,))
        entry = []
        for v, (name, size) in zip(a, axes):
            if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, np.integer)):
                raise InstanceError("arrivals", f"= {_shown(a)}: {name} {_shown(v)} is not an integer", (k,))
            if size is not None and not 0 <= v < size:
                where = f"out of range 0..{size - 1}" if size else f"out of range (there is no {name})"
                raise InstanceError("arrivals", f"= {_shown(a)}: {name} {int(v)} is {where}", (k,))
            entry.append(int(v))
        out.append(tuple(entry))
    return out


def _chunk_axes(instance: Instance) -> list[tuple[str, int]]:
    return [("object", instance.J), ("layer" if instance.layered else "version", instance.L), ("slot", instance.T)]


def arrival_slots(instance: Instance, arrivals: Iterable[Arrival]) -> np.ndarray:
    """``[J, L]`` array: the slot each chunk arrives in, or -1 (never).

    Raises
    ------
    InstanceError
        A malformed arrival (:func:`checked_arrivals`), or a chunk given twice: it has no one
        arrival slot, and taking the first or the last would make the answer depend on the order.
    """
    slots = np.full((instance.J, instance.L), NEVER, dtype=np.int64)
    first: dict[tuple[int, int], int] = {}
    for k, (j, l, t) in enumerate(checked_arrivals(arrivals, _chunk_axes(instance))):
        if (j, l) in first:
            raise InstanceError("arrivals", f"= {(j, l, t)}: chunk {(j, l)} is given twice (also as "
                                            f"arrivals[{first[(j, l)]}]); a chunk arrives at most once", (k,))
        first[(j, l)] = k
        slots[j, l] = t
    return slots


def _available(instance: Instance, slots: np.ndarray, slot: int | None) -> np.ndarray:
    """Boolean ``[T, J, L]`` (or ``[1, J, L]`` for one slot): chunk shown at slot t."""
    if slot is not None:
        return (instance.held | (slots == slot))[None]
    t = np.arange(instance.T)[:, None, None]
    arrived = slots[None] >= 0
    if instance.options.availability == "same_slot":
        ok = arrived & (slots[None] <= t)
    else:
        ok = arrived & (slots[None] < t)
    return ok | instance.held[None]


def evaluate_objective(instance: Instance, arrivals: Iterable[Arrival], *, slot: int | None = None) -> float:
    """Total utility of the schedule, held chunks included.

    Layered: ``sum_t sum_{j,l} dU[t,j,l] * shown[t,j,l]``, each term with its sign (a negative
    layer held lowers the value). Separate: ``sum_t sum_j max(0, max_l U[t,j,l] * shown[t,j,l])``
    (the best version held is shown; ``U >= 0``). With ``slot=t`` only slot t counts and a chunk
    arriving in t is shown at t (one arriving in another slot is not).

    Each chunk counts from its arrival as written: budgets, layer order and chunks already held
    are not checked here (:func:`feasibility_violations` does that; a solver's schedule is
    checked and repaired before it is valued), so an infeasible schedule gets the value of the
    formula above, e.g. a layer counted without the layer below it.

    Raises
    ------
    InstanceError
        A malformed schedule (:func:`checked_arrivals`: wrong type or length, an index out of
        range, a non-integer), or a chunk given twice (see :func:`arrival_slots`).
    SolveError
        ``instance`` is not an :class:`Instance`; ``slot`` is not an integer in ``0..T-1``.
    """
    check_instance(instance, Instance)
    slot = check_slot(slot, instance.T)
    slots = arrival_slots(instance, arrivals)
    shown = _available(instance, slots, slot)
    utility = instance.utility[slot:slot + 1] if slot is not None else instance.utility
    if instance.layered:
        values = utility[shown]
    else:
        values = np.where(shown, utility, 0.0).max(axis=2, initial=0.0).ravel()
    return math.fsum(values.tolist())


def budget_violations(spent: Mapping[int, int], bandwidth: Sequence[int], *, cumulative: bool) -> list[str]:
    """Budget rules broken by ``spent[t]`` bytes arriving in slot t, in exact integers: per slot,
    or (``cumulative``) the bytes by slot t against the bandwidth of slots 0..t (first breach only).
    Shared by both instance forms."""
    bandwidth = [int(b) for b in bandwidth]
    problems: list[str] = []
    if not cumulative:
        for t in sorted(spent):
            if 0 <= t < len(bandwidth) and spent[t] > bandwidth[t]:
                problems.append(f"slot {t}: {spent[t]} bytes arrive, budget is {bandwidth[t]} bytes")
        return problems
    used = budget = 0
    for t, b in enumerate(bandwidth):
        used += spent.get(t, 0)
        budget += b
        if used > budget:
            problems.append(f"slots 0..{t}: {used} bytes arrive, cumulative budget is {budget} bytes")
            break
    return problems


def first_breach(spent: Mapping[int, int], bandwidth: Sequence[int], *, cumulative: bool) -> int:
    """The first slot whose budget ``spent`` breaks (per slot, or cumulative up to it); the last slot
    when none does. The repairs of both instance forms drop a chunk arriving there (or, cumulative,
    by then)."""
    if not cumulative:
        return next((t for t in sorted(spent) if spent[t] > int(bandwidth[t])), len(bandwidth) - 1)
    used = budget = 0
    for t, b in enumerate(bandwidth):
        used += spent.get(t, 0)
        budget += int(b)
        if used > budget:
            return t
    return len(bandwidth) - 1


def feasibility_violations(instance: Instance, arrivals: Iterable[Arrival], *,
                           slot: int | None = None) -> list[str]:
    """Every rule the schedule breaks, as readable strings (empty list: feasible).

    Checked exactly: each chunk at most once and not already held, in slot ``slot`` when given,
    per-slot or cumulative byte budgets in integer bytes, and (layered) layer l only after layer
    l-1 (same slot allowed unless ``options.same_slot_layers`` is false).

    Raises
    ------
    InstanceError
        A malformed schedule, which is not a schedule to report on (:func:`checked_arrivals`:
        wrong type or length, an index out of range, a non-integer).
    SolveError
        ``instance`` is not an :class:`Instance`; ``slot`` is not an integer in ``0..T-1``.
    """
    inst = instance
    check_instance(inst, Instance)
    slot = check_slot(slot, inst.T)
    problems: list[str] = []
    seen: dict[tuple[int, int], int] = {}
    spent: dict[int, int] = defaultdict(int)
    for j, l, t in checked_arrivals(arrivals, _chunk_axes(inst)):
        if slot is not None and t != slot:
            problems.append(f"arrival {(j, l, t)} is not in slot {slot}")
        if (j, l) in seen:
            problems.append(f"chunk {(j, l)} arrives twice (slots {seen[(j, l)]} and {t})")
            continue
        if inst.held[j, l]:
            problems.append(f"chunk {(j, l)} is already held")
        seen[(j, l)] = t
        spent[t] += int(inst.cost[j, l])
    problems += budget_violations(spent, inst.bandwidth, cumulative=inst.options.budget == "cumulative" and slot is None)
    if inst.layered:
        strict = not inst.options.same_slot_layers
        for (j, l), t in seen.items():
            if l == 0 or inst.held[j, l - 1]:
                continue
            below = seen.get((j, l - 1))
            if below is None or below > t or (strict and below == t):
                rule = "a strictly earlier slot" if strict else "the same or an earlier slot"
                problems.append(f"chunk {(j, l)} arrives in slot {t} but layer {l - 1} does not arrive in {rule}")
    return problems


def is_feasible(instance: Instance, arrivals: Iterable[Arrival], *, slot: int | None = None) -> bool:
    """Whether :func:`feasibility_violations` finds nothing; malformed input raises as it does there."""
    return not feasibility_violations(instance, arrivals, slot=slot)


def repair_schedule(instance: Instance, arrivals: Iterable[Arrival], *,
                    slot: int | None = None) -> tuple[tuple[Arrival, ...], int]:
    """Drop chunks until the schedule is feasible; return it and how many chunks were dropped.

    Used when a backend's tolerances let a schedule exceed a budget by a few bytes (byte costs of
    1e5-1e9 against an integrality tolerance of 1e-6). Per over-full slot it drops the chunk of
    least utility per byte (with, for layered objects, every layer above it), so a repaired
    schedule is never worse than necessary by much, but it is no longer proven optimal.
    """
    inst = instance
    current = {(j, l): t for j, l, t in normalize_arrivals(arrivals)
               if 0 <= j < inst.J and 0 <= l < inst.L and 0 <= t < inst.T and not inst.held[j, l]}
    start = len(current)
    value = inst.utility.sum(axis=0)

    def drop(j: int, l: int) -> None:
        top = inst.L if inst.layered else l + 1
        for k in range(l, top):
            current.pop((j, k), None)

    while True:
        schedule = [(j, l, t) for (j, l), t in current.items()]
        if is_feasible(inst, schedule, slot=slot):
            return normalize_arrivals(schedule), start - len(current)
        # Precedence first: a layer without its lower layer is dropped with everything above it.
        if inst.layered:
            orphan = next(((j, l) for (j, l), t in current.items()
                           if l > 0 and not inst.held[j, l - 1]
                           and ((j, l - 1) not in current or current[(j, l - 1)] > t
                                or (not inst.options.same_slot_layers and current[(j, l - 1)] == t))), None)
            if orphan is not None:
                drop(*orphan)
                continue
        spent: dict[int, int] = defaultdict(int)
        for (j, l), t in current.items():
            spent[t] += int(inst.cost[j, l])
        cumulative = inst.options.budget == "cumulative" and slot is None
        bad_t = first_breach(spent, inst.bandwidth, cumulative=cumulative)
        pool = [(j, l) for (j, l), t in current.items() if (t <= bad_t if cumulative else t == bad_t)]
        j, l = min(pool, key=lambda jl: (value[jl] / inst.cost[jl], -jl[1]))
        drop(j, l)


def trim_losing_layers(instance: Instance, arrivals: Iterable[Sequence[int]], *,
                       slot: int | None = None) -> tuple[Arrival, ...]:
    """Layered: each object's delivered layers cut back to the prefix worth the most.

    Object j holding ``h`` layers and receiving layers ``h..m`` keeps ``h..p`` for the ``p`` that
    maximises ``sum_{l=h..p} value(l)`` (``p = h-1``: none), where ``value(l)`` is what layer l
    adds from its first showing to the horizon (``slot=t``: at slot t); ties keep the shorter
    prefix, which costs fewer bytes. Leaving out a top run of layers keeps a feasible schedule
    feasible (bytes only freed, layer order kept) and, by the choice of ``p``, never lowers the
    objective: a negative layer stays only when the layers above it recover its loss.

    Instances without a negative utility (and separate ones) come back unchanged, as do layers
    above a gap in an object's delivered run (the schedule is then infeasible; that is for
    :func:`feasibility_violations` to say).

    Returns
    -------
    tuple of (j, l, t)
        The kept arrivals, normalised (:func:`normalize_arrivals`).
    """
    inst = instance
    schedule = normalize_arrivals(arrivals)
    if not inst.layered or not (inst.utility < 0).any():
        return schedule
    slots = np.full((inst.J, inst.L), NEVER, dtype=np.int64)
    for j, l, t in schedule:
        if 0 <= j < inst.J and 0 <= l < inst.L:
            slots[j, l] = t
    shift = 1 if inst.options.availability == "next_slot" else 0
    drop: set[tuple[int, int]] = set()
    for j in range(inst.J):
        h = int(inst.held[j].sum())
        values: list[float] = []
        best, cut = 0.0, h
        for l in range(h, inst.L):
            a = int(slots[j, l])
            if not 0 <= a < inst.T:
                break
            if slot is not None:
                values.append(float(inst.utility[slot, j, l]))
            else:
                values.append(math.fsum(inst.utility[a + shift:, j, l].tolist()))
            total = math.fsum(values)
            if total > best:
                best, cut = total, l + 1
        drop.update((j, l) for l in range(cut, h + len(values)))
    return tuple(a for a in schedule if (a[0], a[1]) not in drop)
