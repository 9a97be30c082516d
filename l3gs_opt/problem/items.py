"""The item instance (``l3gs-opt/items@1``): chunks with a precedence DAG and replacement groups.

Length (~640 lines): the item form's validation (labels, edges, groups, held sets closed under
precedence, each fault named) and its builders from the instance form and the bundle variants.

Problems I and II (:class:`~l3gs_opt.problem.instance.Instance`) fix one structure per representation:
a chain of layers per object, or a set of interchangeable versions per object. The bundle
variants ``distill`` (a layer can be sent compact and upgraded later by its SH bytes) and
``hierarchy`` need other structures. An :class:`ItemInstance` states them all in one form:

* **items** ``i = 0..N-1``, each of one ``object``, with a ``cost`` in bytes;
* **precedence** edges ``requires = [[parent, child], ...]`` (a DAG, parent and child of one
  object): the child may be held only with its parent. Same-slot arrival of parent and child
  is allowed unless ``options.same_slot_layers`` is false (the option's name is Problem I's; here
  it applies to every edge);
* **replacement groups** ``group[i]`` (items of one object): at each slot a group shows its best
  held item, ``utility[t, i]`` is the group's utility when item i is the one shown. A group of one
  item is additive, like a layer of Problem I.

Objective, over slots ``t`` and groups ``g``::

    sum_t sum_g max(0, max { utility[t, i] : i in g, i shown at t })

with "shown at t" = held, or arrived in a slot ``<= t`` (``< t`` under next-slot availability).
Budgets, at-most-once and the options are those of Problems I/II.

Problem I is one singleton group per chunk and a chain per object; Problem II one group per
object and no edges (:func:`items_from_instance`). :func:`distill_items` and
:func:`hierarchy_items` give the shapes of the two new bundle variants.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass, field
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from l3gs_opt.checks import brief as _brief
from l3gs_opt.errors import InstanceError
from l3gs_opt.problem.instance import SCHEMA as INSTANCE_SCHEMA
from l3gs_opt.problem.instance import (Instance, Options, _byte_array, _first_index, _show, binary_array,
                                       checked_utility_values, validated_common)

__all__ = [
    "ITEMS_SCHEMA",
    "ItemInstanceError",
    "ItemInstance",
    "items_from_instance",
    "instance_arrivals",
    "item_gain",
    "distill_items",
    "hierarchy_items",
]

ITEMS_SCHEMA = "l3gs-opt/items@1"
#: Largest object or group label: labels are kept as int64 and shown in names and arrivals.
_MAX_LABEL = 2**31 - 1
#: Items of a precedence cycle shown in its error (a cycle may run through every item of a file).
_MAX_CYCLE_SHOWN = 10


class ItemInstanceError(InstanceError):
    """An item instance (or item file) breaks the ``l3gs-opt/items@1`` contract.

    Same attributes as :class:`InstanceError`: ``field`` and ``index`` of the fault.
    """


def _labels(value: Any, name: str, N: int) -> np.ndarray:
    """Canonical int64 array [N] of non-negative labels (object or group ids)."""
    arr = np.asarray(value)
    if arr.ndim != 1:
        raise ItemInstanceError(name, f"must be a list of N integers, got {arr.ndim} dimensions")
    if arr.shape[0] != N:
        raise ItemInstanceError(name, f"has {arr.shape[0]} entries, expected N = {N} (one per item, from cost)")
    if N == 0:
        out = np.zeros(0, dtype=np.int64)
        out.setflags(write=False)
        return out
    if arr.dtype.kind == "O":
        # numpy's answer to an int beyond int64 (or to a mix of numbers and other things): name the entry.
        for idx, v in enumerate(arr):
            if isinstance(v, int) and not isinstance(v, bool) and not 0 <= v <= _MAX_LABEL:
                raise ItemInstanceError(name, f"= {_brief(v)}: must be an integer in 0..{_MAX_LABEL}", (idx,))
    if arr.dtype.kind == "b" or arr.dtype.kind not in "iuf":
        raise ItemInstanceError(name, f"must hold integers, got dtype {arr.dtype}")
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr) | (arr != np.floor(arr))
        if bad.any():
            idx = _first_index(bad)
            raise ItemInstanceError(name, f"= {_show(arr[idx])}: must be an integer", idx)
    bad = (arr < 0) | (arr > _MAX_LABEL)
    if bad.any():
        idx = _first_index(bad)
        raise ItemInstanceError(name, f"= {_show(arr[idx])}: must be an integer in 0..{_MAX_LABEL}", idx)
    out = arr.astype(np.int64)
    out.setflags(write=False)
    return out


def _utility_matrix(value: Any, T: int, N: int) -> np.ndarray:
    arr = np.asarray(value)
    if arr.ndim != 2:
        raise ItemInstanceError("utility", f"must be a 2-dimensional array (T, N), got {arr.ndim} dimensions")
    if arr.shape != (T, N):
        raise ItemInstanceError("utility", f"has shape {arr.shape}, expected (T, N) = {(T, N)} from bandwidth and cost")
    if arr.size and (arr.dtype.kind == "b" or arr.dtype.kind not in "iuf"):
        raise ItemInstanceError("utility", f"must hold numbers, got dtype {arr.dtype}")
    return checked_utility_values(arr, ItemInstanceError)


def _edges(value: Any, N: int, objects: np.ndarray) -> np.ndarray:
    """Canonical int64 [E, 2] edge list (order kept), each edge checked."""
    if value is None:
        value = []
    arr = np.asarray(value)
    if arr.size == 0:
        out = np.zeros((0, 2), dtype=np.int64)
        out.setflags(write=False)
        return out
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ItemInstanceError("requires", f"must be a list of [parent, child] pairs, got shape {arr.shape}")
    if arr.dtype.kind == "b" or arr.dtype.kind not in "iuf":
        raise ItemInstanceError("requires", f"must hold item indices (integers), got dtype {arr.dtype}")
    seen: dict[tuple[int, int], int] = {}
    out = np.zeros(arr.shape, dtype=np.int64)
    for e, (p, c) in enumerate(arr.tolist()):
        pair = f"= [{_brief(p)}, {_brief(c)}]"
        for v in (p, c):
            if not (isinstance(v, int) or (isinstance(v, float) and v.is_integer())) or not 0 <= v < N:
                raise ItemInstanceError("requires", f"{pair}: {_brief(v)} is not an item index in 0..{N - 1}", (e,))
        p, c = int(p), int(c)
        if p == c:
            raise ItemInstanceError("requires", f"{pair}: an item cannot require itself", (e,))
        if objects[p] != objects[c]:
            raise ItemInstanceError("requires", f"{pair}: item {p} is of object {objects[p]}, item {c} of object "
                                                f"{objects[c]}; precedence joins items of one object", (e,))
        if (p, c) in seen:
            raise ItemInstanceError("requires", f"{pair}: repeats requires[{seen[(p, c)]}]", (e,))
        seen[(p, c)] = e
        out[e] = (p, c)
    out.setflags(write=False)
    return out


def _topological(N: int, parents: Sequence[tuple[int, ...]], children: Sequence[tuple[int, ...]]) -> np.ndarray:
    """Items in an order where every parent comes before its children (Kahn); a cycle is an error
    naming the items on one cycle."""
    indeg = np.array([len(p) for p in parents], dtype=np.int64)
    order: list[int] = [i for i in range(N) if indeg[i] == 0]
    k = 0
    while k < len(order):
        for c in children[order[k]]:
            indeg[c] -= 1
            if indeg[c] == 0:
                order.append(c)
        k += 1
    if len(order) < N:
        # Walk parents inside the unresolved set until an item repeats: that closes a cycle.
        left = set(range(N)) - set(order)
        start = min(left)
        path, pos = [start], {start: 0}
        while True:
            nxt = next(p for p in parents[path[-1]] if p in left)
            if nxt in pos:
                cycle = path[pos[nxt]:][::-1]
                cycle.append(cycle[0])
                if len(cycle) > _MAX_CYCLE_SHOWN + 1:
                    steps = " -> ".join(str(i) for i in cycle[:_MAX_CYCLE_SHOWN]) + f" -> ... ({len(cycle) - 1} items)"
                else:
                    steps = " -> ".join(str(i) for i in cycle)
                raise ItemInstanceError("requires", f"cycle through item {nxt}: {steps} (parent -> child)")
            pos[nxt] = len(path)
            path.append(nxt)
    out = np.asarray(order, dtype=np.int64)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class ItemInstance:
    """N items of J objects over T slots: costs, precedence, replacement groups, utilities.

    Parameters
    ----------
    bandwidth : array of int, shape [T]
        Bytes available in each slot (bytes per slot), >= 0.
    object : array of int, shape [N]
        The object each item belongs to (any labels >= 0).
    cost : array of int, shape [N]
        Bytes of each item, > 0.
    utility : array of float, shape [T, N]
        Utility of item i's group at slot t when i is the item it shows (a singleton group: the
        item's additive utility ``dU``); finite, >= 0.
    group : array of int, shape [N], optional
        Replacement group of each item (labels >= 0; all items of a group of one object). Default:
        every item its own group (all additive).
    requires : array of int, shape [E, 2], optional
        Precedence edges ``[parent, child]``: the child may be held only with the parent. Acyclic,
        both ends of one object, no repeats.
    held : array of bool, shape [N], optional
        Items the client already holds; closed under precedence (a held child's parents are held).
    slot_s : float
        Slot length in seconds (default 1.0).
    options : Options, optional
        As for :class:`~l3gs_opt.problem.instance.Instance`; ``same_slot_layers`` applies to every edge
        (False: a child arrives strictly after its parent).
    names : sequence of str, optional
        Item names, N of them (e.g. the bundle chunk ``o3_l1_compact``): labels, not keys, so
        two items may share one.
    meta : mapping, optional
        Free-form provenance (JSON-serialisable).

    Raises
    ------
    ItemInstanceError
        Naming the field and index at fault, e.g. ``requires[3] = [5, 2]: ...``.

    Example
    -------
    >>> inst = ItemInstance(bandwidth=[5], object=[0, 0], cost=[2, 3], utility=[[1.0, 0.5]],
    ...                     requires=[[0, 1]])
    >>> inst.N, inst.J, inst.parents[1]
    (2, 1, (0,))
    """

    bandwidth: np.ndarray
    object: np.ndarray
    cost: np.ndarray
    utility: np.ndarray
    group: np.ndarray | None = None
    requires: np.ndarray | None = None
    held: np.ndarray | None = None
    slot_s: float = 1.0
    options: Options = field(default_factory=Options)
    names: tuple[str, ...] | None = None
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        bandwidth = _ours(_byte_array, self.bandwidth, "bandwidth", 1, positive=False)
        cost = _ours(_byte_array, self.cost, "cost", 1, positive=True)
        if bandwidth.shape[0] < 1:
            raise ItemInstanceError("bandwidth", "must have at least one slot")
        T, N = bandwidth.shape[0], cost.shape[0]
        objects = _labels(self.object, "object", N)
        utility = _utility_matrix(self.utility, T, N)
        groups = np.arange(N, dtype=np.int64) if self.group is None else _labels(self.group, "group", N)
        if self.group is None:
            groups.setflags(write=False)
        owner: dict[int, int] = {}
        for i, g in enumerate(groups.tolist()):
            first = owner.setdefault(g, i)
            if objects[first] != objects[i]:
                raise ItemInstanceError("group", f"= {g}: item {i} is of object {objects[i]} but group {g} holds "
                                                 f"item {first} of object {objects[first]}; a group replaces "
                                                 "versions of one object", (i,))
        edges = _edges(self.requires, N, objects)
        parents: list[list[int]] = [[] for _ in range(N)]
        children: list[list[int]] = [[] for _ in range(N)]
        for p, c in edges.tolist():
            parents[c].append(p)
            children[p].append(c)
        parents_t = tuple(tuple(p) for p in parents)
        children_t = tuple(tuple(c) for c in children)
        order = _topological(N, parents_t, children_t)
        held = self._validated_held(self.held, N, edges)
        slot_s, options, names, meta = _ours(validated_common, self.slot_s, self.options, self.names, self.meta,
                                             count=N, axis="N")
        for name, value in [("bandwidth", bandwidth), ("object", objects), ("cost", cost), ("utility", utility),
                            ("group", groups), ("requires", edges), ("held", held), ("slot_s", slot_s),
                            ("options", options), ("names", names), ("meta", meta)]:
            object.__setattr__(self, name, value)
        # Derived structure (not fields): adjacency, a topological order, dense group indices.
        labels, gindex = np.unique(groups, return_inverse=True)
        gindex = gindex.astype(np.int64).reshape(-1)
        gindex.setflags(write=False)
        # Members of each group in item order, by one stable sort (a scan per group was quadratic:
        # minutes for a file of 10^6 singleton items).
        by_group = np.argsort(gindex, kind="stable")
        bounds = np.searchsorted(gindex[by_group], np.arange(labels.shape[0] + 1)).tolist()
        by_group = by_group.tolist()
        members = tuple(tuple(by_group[bounds[g]:bounds[g + 1]]) for g in range(labels.shape[0]))
        object.__setattr__(self, "_parents", parents_t)
        object.__setattr__(self, "_children", children_t)
        object.__setattr__(self, "_order", order)
        object.__setattr__(self, "_group_index", gindex)
        object.__setattr__(self, "_members", members)

    def _validated_held(self, held: Any, N: int, edges: np.ndarray) -> np.ndarray:
        if held is None:
            out = np.zeros(N, dtype=bool)
        else:
            out = _ours(binary_array, held, "held", (N,), "(N,)")
            for p, c in edges.tolist():
                if out[c] and not out[p]:
                    raise ItemInstanceError("held", f"= 1 but item {p} it requires is not held: the held set must "
                                                    "be closed under precedence", (c,))
        out.setflags(write=False)
        return out

    # -- shape and structure ------------------------------------------------------------------
    @property
    def T(self) -> int:
        """Number of slots."""
        return int(self.bandwidth.shape[0])

    @property
    def N(self) -> int:
        """Number of items."""
        return int(self.cost.shape[0])

    @property
    def objects(self) -> np.ndarray:
        """The distinct object labels, sorted."""
        return np.unique(self.object)

    @property
    def J(self) -> int:
        """Number of distinct objects."""
        return int(self.objects.shape[0])

    @property
    def problem(self) -> str:
        """``"items"`` (the general form; "I"/"II" name the Instance special cases)."""
        return "items"

    @property
    def parents(self) -> tuple[tuple[int, ...], ...]:
        """Per item, the items it requires."""
        return self._parents  # type: ignore[attr-defined]

    @property
    def children(self) -> tuple[tuple[int, ...], ...]:
        """Per item, the items that require it."""
        return self._children  # type: ignore[attr-defined]

    @property
    def order(self) -> np.ndarray:
        """Items in a topological order (parents first), int64 [N]."""
        return self._order  # type: ignore[attr-defined]

    @property
    def group_index(self) -> np.ndarray:
        """Dense group index of each item, ``0..G-1`` in order of the group labels, int64 [N]."""
        return self._group_index  # type: ignore[attr-defined]

    @property
    def members(self) -> tuple[tuple[int, ...], ...]:
        """Per dense group index, its items (ascending)."""
        return self._members  # type: ignore[attr-defined]

    @property
    def G(self) -> int:
        """Number of replacement groups."""
        return len(self.members)

    def replace(self, **changes: Any) -> "ItemInstance":
        """A validated copy with some fields changed."""
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        fields.update(changes)
        return ItemInstance(**fields)

    def slot_instance(self, slot: int) -> "ItemInstance":
        """The single-slot problem at ``slot`` as a one-slot instance: what arrives is shown at once
        (same-slot availability) and the slot's own bandwidth is the budget; strict precedence is kept."""
        opts = dataclasses.replace(self.options, availability="same_slot", budget="per_slot")
        return self.replace(bandwidth=self.bandwidth[slot:slot + 1], utility=self.utility[slot:slot + 1],
                            options=opts)

    def to_dict(self) -> dict[str, Any]:
        """The ``l3gs-opt/items@1`` JSON object."""
        out: dict[str, Any] = {
            "schema": ITEMS_SCHEMA,
            "slot_s": self.slot_s,
            "bandwidth": self.bandwidth.tolist(),
            "object": self.object.tolist(),
            "cost": self.cost.tolist(),
            "utility": self.utility.tolist(),
        }
        if not np.array_equal(self.group, np.arange(self.N)):
            out["group"] = self.group.tolist()
        if self.requires.shape[0]:
            out["requires"] = self.requires.tolist()
        if self.held.any():
            out["held"] = self.held.astype(int).tolist()
        if self.options != Options():
            out["options"] = self.options.to_dict()
        if self.names is not None:
            out["names"] = list(self.names)
        if self.meta:
            out["meta"] = copy.deepcopy(dict(self.meta))
        return out

    def __reduce__(self):
        # meta is a read-only mapping proxy, which pickle cannot copy: rebuild (and re-validate).
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}
        fields["meta"] = copy.deepcopy(dict(self.meta))
        return (_rebuild, (fields,))

    def __repr__(self) -> str:
        singles = sum(len(m) == 1 for m in self.members)
        return (f"ItemInstance(T={self.T}, N={self.N}, J={self.J}, groups={self.G} ({singles} singleton), "
                f"edges={self.requires.shape[0]}, options={self.options})")


def _ours(fn: Any, *args: Any, **kwargs: Any) -> Any:
    """Run a check shared with :mod:`l3gs_opt.problem.instance`; its InstanceError becomes ours."""
    try:
        return fn(*args, **kwargs)
    except ItemInstanceError:
        raise
    except InstanceError as exc:
        raise ItemInstanceError(exc.field, _tail(exc), exc.index) from None


def _tail(exc: InstanceError) -> str:
    """The message of an InstanceError without its ``field[index]`` prefix."""
    text = str(exc)
    where = exc.field + "".join(f"[{i}]" for i in exc.index or ())
    rest = text[len(where):] if text.startswith(where) else text
    return rest[2:] if rest.startswith(": ") else rest.lstrip()


def _rebuild(fields: dict) -> ItemInstance:
    return ItemInstance(**fields)


# -- valuation shared by the models and solvers ---------------------------------------------------------

def item_gain(instance: ItemInstance, utility: np.ndarray | None = None,
              held: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """What showing an unheld item adds over what its group shows from held items.

    ``max(base, max_shown U) = base + max(0, max_shown (U - base))``, so with ``base[t, g]`` the
    best held utility of group g at slot t, the objective is ``sum base + sum_g max_shown gain``.

    Parameters
    ----------
    utility : float array [T', N], optional
        Defaults to ``instance.utility``; pass a slice for a few slots.
    held : bool array [N], optional
        Defaults to ``instance.held``.

    Returns
    -------
    gain : float array [T', N]
        ``max(0, U[t, i] - base[t, g(i)])`` for unheld items, 0 for held ones.
    base : float array [T', G]
        Best held utility per slot and (dense) group, 0 when the group holds nothing.
    """
    utility = instance.utility if utility is None else np.asarray(utility, dtype=np.float64)
    held = instance.held if held is None else np.asarray(held, dtype=bool)
    gi = instance.group_index
    base = np.zeros((utility.shape[0], instance.G))
    if held.any():
        np.maximum.at(base, (slice(None), gi[held]), utility[:, held])
    gain = np.where(held[None, :], 0.0, np.clip(utility - base[:, gi], 0.0, None))
    return gain, base


# -- Problems I/II as item instances ---------------------------------------------------------------

def items_from_instance(instance: Instance) -> ItemInstance:
    """Problem I/II (or III/IV) as an item instance; item ``i = j * L + l`` is chunk (j, l).

    Layered: one singleton group per chunk, a chain ``(j, l-1) -> (j, l)`` per object. Separate:
    one group per object (its versions replace each other), no edges. Costs, utilities, held
    chunks, bandwidth, options and slot length carry over unchanged, so both forms have the same
    schedules (:func:`instance_arrivals` maps one back) and the same objective.

    Raises
    ------
    ItemInstanceError
        A layered instance with a negative layer utility: a group of the item form shows
        ``max(0, ...)``, so a negative singleton item would be read as 0 (not the layered
        objective, where every held layer counts); the item form keeps utilities ``>= 0``.
    """
    inst = instance
    J, L = inst.J, inst.L
    negative = inst.utility < 0
    if negative.any():
        t, j, l = (int(v) for v in np.argwhere(negative)[0])
        raise ItemInstanceError("utility", f"= {float(inst.utility[t, j, l])!r}: a negative layer utility has no item "
                                           "form (a group shows at least nothing, 0); solve the layered instance "
                                           "itself", (t, j, l))
    items = np.arange(J * L, dtype=np.int64)
    objects = items // L if L else items
    if inst.layered:
        group = items
        requires = [[j * L + l - 1, j * L + l] for j in range(J) for l in range(1, L)]
    else:
        group = objects
        requires = []
    names = None
    if inst.names is not None:
        names = [f"{inst.names[j]}/{'l' if inst.layered else 'v'}{l}" for j in range(J) for l in range(L)]
    meta: dict[str, Any] = {"converted_from": {"schema": INSTANCE_SCHEMA, "representation": inst.representation,
                                               "objects": J, "layers": L}}
    if inst.meta:
        meta["instance_meta"] = dict(inst.meta)
    return ItemInstance(bandwidth=inst.bandwidth, object=objects, cost=inst.cost.reshape(-1),
                        utility=inst.utility.reshape(inst.T, J * L), group=group, requires=requires,
                        held=inst.held.reshape(-1), slot_s=inst.slot_s, options=inst.options, names=names, meta=meta)


def instance_arrivals(arrivals: Iterable[Sequence[int]], layers: int) -> list[tuple[int, int, int]]:
    """Arrivals ``(object, item, t)`` of an item instance made by :func:`items_from_instance` from an
    instance with ``layers`` layers (versions), as that instance's ``(j, l, t)``."""
    return [(int(i) // layers, int(i) % layers, int(t)) for _, i, t in arrivals]


# -- shapes of the new bundle variants -------------------------------------------------------------

def _present(present: Any, shape: tuple[int, int], name: str = "present") -> np.ndarray:
    if present is None:
        return np.ones(shape, dtype=bool)
    return _ours(binary_array, present, name, shape, "(J, L)")


def _grid(value: Any, name: str, shape: tuple[int, ...], here: np.ndarray, *, cost: bool) -> np.ndarray:
    """A [J, L] cost or [T, J, L] utility grid, checked on its present cells only (an absent cell
    may hold anything, e.g. 0 bytes), so that a fault names the grid's own index."""
    arr = np.asarray(value)
    if arr.shape != shape:
        raise ItemInstanceError(name, f"has shape {arr.shape}, expected {shape}")
    mask = np.broadcast_to(here, shape)
    if cost:
        return _ours(_byte_array, np.where(mask, arr, 1), name, len(shape), positive=True)
    if arr.size and (arr.dtype.kind == "b" or arr.dtype.kind not in "iuf"):
        raise ItemInstanceError(name, f"must hold numbers, got dtype {arr.dtype}")
    out = np.where(mask, arr.astype(np.float64), 0.0)
    bad = ~np.isfinite(out) | (out < 0)
    if bad.any():
        idx = _first_index(bad)
        raise ItemInstanceError(name, f"= {_show(out[idx])}: must be finite and >= 0", idx)
    return out


def distill_items(compact_cost: Any, upgrade_cost: Any, compact_utility: Any, upgrade_utility: Any,
                  bandwidth: Any, *, present: Any = None, held_compact: Any = None, held_upgrade: Any = None,
                  slot_s: float = 1.0, options: Options | None = None,
                  meta: Mapping[str, Any] | None = None) -> ItemInstance:
    """The item structure of a ``distill`` bundle: per (object, layer) a compact chunk and its SH upgrade.

    Item order: for each object j, for each present layer l, ``compact(j, l)`` then
    ``upgrade(j, l)``, named after the bundle's chunk files (``o{j}_l{l}_compact``,
    ``o{j}_l{l}_sh_upgrade``; j is the row here, not the bundle's object id). Edges:
    ``compact(j, l') -> compact(j, l)`` for the previous present layer l' (layers stack), and
    ``compact(j, l) -> upgrade(j, l)`` (the upgrade replaces the SH of splats the client has).
    An upgrade needs no other upgrade. Every item is its own group: utilities add up, so
    ``compact_utility`` is the layer's utility with compact SH and ``upgrade_utility`` what full
    SH adds on top of it (>= 0), and sending both costs both.

    Parameters
    ----------
    compact_cost, upgrade_cost : int arrays [J, L]
        Bytes of each compact chunk and each SH upgrade chunk (> 0 where present).
    compact_utility, upgrade_utility : float arrays [T, J, L]
    bandwidth : int array [T]
        Bytes per slot.
    present : bool array [J, L], optional
        (object, layer) cells that have chunks (an object may have no splats in a layer); absent
        cells get no items and the compact chain skips them. Default: all.
    held_compact, held_upgrade : bool arrays [J, L], optional
        Chunks the client holds (must be closed: a held upgrade's compact chunk, and the compact
        chunks below a held one, are held).

    Returns
    -------
    ItemInstance
    """
    shape = np.shape(compact_cost)
    if len(shape) != 2:
        raise ItemInstanceError("compact_cost", f"must be a 2-dimensional array (J, L), got {len(shape)} dimensions")
    J, L = shape
    T = int(np.asarray(bandwidth).reshape(-1).shape[0])
    here = _present(present, (J, L))
    cc = _grid(compact_cost, "compact_cost", (J, L), here, cost=True)
    uc = _grid(upgrade_cost, "upgrade_cost", (J, L), here, cost=True)
    cu = _grid(compact_utility, "compact_utility", (T, J, L), here, cost=False)
    uu = _grid(upgrade_utility, "upgrade_utility", (T, J, L), here, cost=False)
    hc = _present(held_compact, (J, L), "held_compact") & here if held_compact is not None else np.zeros((J, L), bool)
    hu = _present(held_upgrade, (J, L), "held_upgrade") & here if held_upgrade is not None else np.zeros((J, L), bool)
    objects, costs, utilities, held, names, requires = [], [], [], [], [], []
    for j in range(J):
        prev = None
        for l in range(L):
            if not here[j, l]:
                continue
            c = len(objects)
            for form, cost, util, h in (("compact", cc, cu, hc), ("sh_upgrade", uc, uu, hu)):
                objects.append(j)
                costs.append(cost[j, l])
                utilities.append(util[:, j, l])
                held.append(bool(h[j, l]))
                names.append(f"o{j}_l{l}_{form}")
            requires.append([c, c + 1])
            if prev is not None:
                requires.append([prev, c])
            prev = c
    utility = np.stack(utilities, axis=1) if utilities else np.zeros((T, 0))
    return ItemInstance(bandwidth=bandwidth, object=objects, cost=np.asarray(costs), utility=utility,
                        requires=requires, held=held, slot_s=slot_s, options=options or Options(), names=names,
                        meta={"variant": "distill", **dict(meta or {})})


def hierarchy_items(cost: Any, utility: Any, bandwidth: Any, *, present: Any = None, held: Any = None,
                    slot_s: float = 1.0, options: Options | None = None,
                    meta: Mapping[str, Any] | None = None) -> ItemInstance:
    """The item structure of a ``hierarchy`` bundle: each object's versions in one replacement group.

    A version is sent **whole** (its chunk's bytes, the 4-byte ``parent`` field per splat
    included), never as a delta over the version below it: the trainer fine-tunes every version
    on its own (``separate`` training, Prune2TargetSize chained from the next larger version), so
    a version-l splat is not a version-(l-1) splat plus a change, and its ``parent`` is the
    nearest-mean splat of version l-1 of the same object, a link, not an identity. The bundle
    stores each version's records in full and no delta encoding exists to send.

    What the tree adds is for the client, not the scheduler: with parent links a renderer can
    morph from a version to the next (each new splat starts at its parent) or refine an object
    region by region. At the chunk granularity scheduled here (one chunk per object and version)
    the schedule's structure is Problem II's: item ``(j, l)`` named ``o{j}_l{l}_full``, group j,
    no edges; absent (object, version) cells get no item, which an :class:`Instance` cannot say.

    Parameters
    ----------
    cost : int array [J, L]
        Bytes of each version's chunk.
    utility : float array [T, J, L]
        Each version's whole utility ``U`` (the object's utility when that version is shown).
    bandwidth : int array [T]
    present : bool array [J, L], optional
    held : bool array [J, L], optional
    """
    shape = np.shape(cost)
    if len(shape) != 2:
        raise ItemInstanceError("cost", f"must be a 2-dimensional array (J, L), got {len(shape)} dimensions")
    J, L = shape
    T = int(np.asarray(bandwidth).reshape(-1).shape[0])
    here = _present(present, (J, L))
    c = _grid(cost, "cost", (J, L), here, cost=True)
    u = _grid(utility, "utility", (T, J, L), here, cost=False)
    h = _present(held, (J, L), "held") & here if held is not None else np.zeros((J, L), bool)
    jj, ll = np.nonzero(here)
    return ItemInstance(bandwidth=bandwidth, object=jj, cost=c[jj, ll], utility=u[:, jj, ll], group=jj,
                        held=h[jj, ll], slot_s=slot_s, options=options or Options(),
                        names=[f"o{j}_l{l}_full" for j, l in zip(jj.tolist(), ll.tolist())],
                        meta={"variant": "hierarchy", **dict(meta or {})})
