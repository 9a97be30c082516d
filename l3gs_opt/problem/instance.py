"""The delivery instance: bandwidth per slot, chunk costs, utilities over time, what is held.

An :class:`Instance` is immutable and validated on construction. Every fault raises one
:class:`~l3gs_opt.errors.InstanceError` naming the field and the index, e.g.
``cost[2][3] = -1: must be a positive integer (bytes)``.

Conventions (see docs/design.md): object ``j`` (0-based here), layer or version ``l``, slot ``t``.

* ``layered``: ``cost[j, l]`` is the per-layer cost ``dc[j,l]`` in bytes and
  ``utility[t, j, l]`` the per-layer utility ``dU[j,l,t]``; layer ``l`` is useful only on top
  of layers ``< l``. ``dU`` may be negative (a refinement layer that makes the picture worse at
  that distance): every layer held is shown, so a negative layer is worth fetching only as a step
  to a later layer that recovers more than it loses (docs/design.md, "signed layer utilities").
* ``separate``: ``cost[j, l]`` is the whole cost of version ``l`` and ``utility[t, j, l]``
  its utility ``U[j,l,t]``, ``>= 0``; the best version held is the one shown. A version worse
  than a lower one is a smaller ``U``, never a negative one: the objective shows at least
  nothing (0), so a negative ``U`` would be silently read as 0 and is refused instead.
"""

from __future__ import annotations

import copy
import json
import math
import types
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from l3gs_opt.checks import as_float, brief, is_real
from l3gs_opt.errors import InstanceError
from l3gs_opt.input_files import MAX_JSON_DEPTH, key_name, parse_json

__all__ = [
    "SCHEMA",
    "MAX_BYTES",
    "MAX_UTILITY_TOTAL",
    "REPRESENTATIONS",
    "Options",
    "Instance",
]

SCHEMA = "l3gs-opt/instance@1"
#: Largest byte count accepted (2**53): every byte count and budget is then exact in float64,
#: which the LP/MIP backends use for their rows.
MAX_BYTES = 2**53
#: Largest sum of the magnitudes of all utilities of an instance (signed layer utilities count by
#: their absolute value). Every objective, bound and gap is then a finite float64 with room to
#: spare (1e300 is 2**-27 of the largest float), whatever the slots add up; single utilities down
#: to the smallest subnormal (5e-324) are accepted and solved.
MAX_UTILITY_TOTAL = 1e300
REPRESENTATIONS = ("layered", "separate")
_AVAILABILITY = ("same_slot", "next_slot")
_BUDGET = ("per_slot", "cumulative")


@dataclass(frozen=True)
class Options:
    """The modelling choices docs/design.md makes explicit.

    Parameters
    ----------
    availability : {"same_slot", "next_slot"}
        An item that arrives in slot t counts from slot t (default, as in the paper's proof of
        Lemma 1) or from slot t+1.
    same_slot_layers : bool
        Layers l-1 and l may arrive in the same slot (default True; needed for the single-slot
        problem to be an MCKP). False: layer l must arrive strictly after layer l-1.
    budget : {"per_slot", "cumulative"}
        ``per_slot``: slot t's arrivals cost at most ``bandwidth[t]`` bytes. ``cumulative``: the
        arrivals up to slot t cost at most the bandwidth up to slot t (one sequential link).
    """

    availability: str = "same_slot"
    same_slot_layers: bool = True
    budget: str = "per_slot"

    def __post_init__(self) -> None:
        if self.availability not in _AVAILABILITY:
            raise InstanceError("options.availability",
                                f"{self.availability!r} is not one of {', '.join(_AVAILABILITY)}")
        if not isinstance(self.same_slot_layers, (bool, np.bool_)):
            raise InstanceError("options.same_slot_layers",
                                f"{self.same_slot_layers!r}: must be true or false")
        object.__setattr__(self, "same_slot_layers", bool(self.same_slot_layers))
        if self.budget not in _BUDGET:
            raise InstanceError("options.budget", f"{self.budget!r} is not one of {', '.join(_BUDGET)}")

    @classmethod
    def from_dict(cls, data: Any) -> "Options":
        """Build from a JSON object; an unknown key is an error (a typo must not drop data)."""
        if data is None:
            return cls()
        if not isinstance(data, Mapping):
            raise InstanceError("options", "must be a JSON object")
        known = {"availability", "same_slot_layers", "budget"}
        for key in data:
            if key not in known:
                raise InstanceError(f"options.{key_name(key)}", f"unknown option (known: {', '.join(sorted(known))})")
        return cls(**dict(data))

    def to_dict(self) -> dict[str, Any]:
        return {"availability": self.availability, "same_slot_layers": self.same_slot_layers,
                "budget": self.budget}


def _show(value: np.generic) -> str:
    """A numpy scalar as the user wrote it (``-0.5``, not ``np.float64(-0.5)``)."""
    return repr(value.item())


def validated_common(slot_s: Any, options: Any, names: Any, meta: Any, *, count: int,
                     axis: str) -> tuple[float, "Options", tuple[str, ...] | None, types.MappingProxyType]:
    """Check the fields both instance forms share: ``slot_s`` (seconds, > 0), ``options``,
    ``names`` (``count`` strings, one per ``axis`` entry) and ``meta`` (a JSON object, copied by a
    JSON round trip and frozen). Raises :class:`InstanceError` naming the field and index."""
    seconds = as_float(slot_s) if is_real(slot_s) else math.nan
    if not math.isfinite(seconds) or seconds <= 0:
        raise InstanceError("slot_s", f"{brief(slot_s)}: must be a positive number of seconds")
    options = options if options is not None else Options()
    if not isinstance(options, Options):
        options = Options.from_dict(options)
    # Names are labels (reports, the names of converted items), never looked up: they need not be unique.
    if names is not None:
        # A str or bytes is a Sequence too: b"ab" would be read as the names 97 and 98.
        if isinstance(names, (str, bytes, bytearray)) or not isinstance(names, Sequence):
            raise InstanceError("names", f"must be a list of {axis} strings, got {type(names).__name__}")
        if len(names) != count:
            raise InstanceError("names", f"has {len(names)} entries, expected {axis} = {count}")
        for k, name in enumerate(names):
            if not isinstance(name, str):
                raise InstanceError("names", f"{brief(name)}: must be a string", (k,))
        names = tuple(names)
    meta = meta if meta is not None else {}
    if not isinstance(meta, Mapping):
        raise InstanceError("meta", "must be a JSON object")
    try:
        # A JSON round trip both checks and copies; read-only mappings (an instance's own meta,
        # passed back through ``replace``) are written as the objects they stand for.
        text = json.dumps(meta, allow_nan=False, default=_mapping_as_dict)
    except (TypeError, ValueError, RecursionError) as exc:
        raise InstanceError("meta", f"must be JSON-serialisable: {exc}") from None
    # Strictly decoded, one level less deep than a file allows (meta sits inside the instance
    # object): keys 1 and "1" would collide, and a saved instance must read back.
    meta = parse_json(text, lambda _key, message: InstanceError("meta", message), max_depth=MAX_JSON_DEPTH - 1)
    return seconds, options, names, types.MappingProxyType(meta)


def scale_exponent(values: np.ndarray, top: int) -> int:
    """``k`` such that ``np.ldexp(values, k)`` has its largest ``|value|`` in ``[2**(top-1), 2**top)``
    (0 when all are zero). Multiplying by ``2**k`` is exact in float64 for every value that stays
    a normal number (subnormal utilities scaled up included), so an optimum of the scaled values
    is an optimum of the originals times ``2**k``. Used to bring utilities from 5e-324 to 1e300
    into the range solvers' absolute tolerances assume; ``ldexp`` because ``2**k`` itself
    overflows for ``k`` near 1,074."""
    largest = float(np.abs(values).max()) if np.size(values) else 0.0
    return top - math.frexp(largest)[1] if largest > 0 else 0


def _first_index(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _uneven_at(value: Any) -> tuple[tuple[int, ...], str] | None:
    """The index and a description of the first list in nested lists (tuples, arrays) whose length
    differs from the first list of its level, or that mixes lists and numbers; None if none does."""
    def is_list(v: Any) -> bool:
        return isinstance(v, (list, tuple)) or (isinstance(v, np.ndarray) and v.ndim > 0)

    level: list[tuple[tuple[int, ...], Any]] = [((), value)]
    while level:
        lists = [(idx, v) for idx, v in level if is_list(v)]
        if not lists:
            return None
        if len(lists) != len(level):
            idx = next(idx for idx, v in level if not is_list(v))
            return idx, "a number where the other entries are lists"
        first, size = lists[0][0], len(lists[0][1])
        for idx, v in lists:
            if len(v) != size:
                where = "".join(f"[{i}]" for i in first)
                return idx, f"expected {size} entries, got {len(v)} ({{name}}{where} has {size})"
        level = [(idx + (i,), item) for idx, v in lists for i, item in enumerate(v)]
    return None


def as_array(value: Any, name: str) -> np.ndarray:
    """``np.asarray(value)``, with nested lists of unequal length (numpy's "inhomogeneous shape"
    ``ValueError``) raised as :class:`InstanceError` naming ``name`` and the list at fault."""
    try:
        return np.asarray(value)
    except ValueError:
        where = _uneven_at(value)
        if where is None:
            raise InstanceError(name, "must be an array of numbers: rows of unequal length") from None
        idx, what = where
        raise InstanceError(name, f"rows of unequal length: {what.format(name=name)}", idx) from None


def binary_array(value: Any, name: str, shape: tuple[int, ...], axes: str) -> np.ndarray:
    """``value`` as a (writable) bool array of ``shape`` (named ``axes`` in messages, e.g. "(J, L)"),
    from 0/1 numbers; raises :class:`InstanceError` naming ``name`` and the first bad index."""
    arr = as_array(value, name)
    if arr.shape != shape:
        raise InstanceError(name, f"has shape {arr.shape}, expected {axes} = {shape}")
    if arr.size and arr.dtype.kind not in "biuf":
        raise InstanceError(name, f"must hold 0/1 values, got dtype {arr.dtype}")
    bad = (arr != 0) & (arr != 1)
    if bad.any():
        idx = _first_index(bad)
        raise InstanceError(name, f"= {_show(arr[idx])}: must be 0 or 1", idx)
    return arr.astype(bool)


def _byte_array(value: Any, name: str, ndim: int, *, positive: bool) -> np.ndarray:
    """Canonical int64 byte array; integral floats are accepted, fractions are not."""
    arr = as_array(value, name)
    if arr.ndim != ndim:
        raise InstanceError(name, f"must be a {ndim}-dimensional array, got {arr.ndim} dimensions")
    what = "a positive integer (bytes)" if positive else "a non-negative integer (bytes)"
    if arr.dtype.kind == "O":
        _object_bytes(arr, name, what)
    if arr.dtype.kind == "b" or arr.dtype.kind not in "iuf":
        raise InstanceError(name, f"must hold integers (bytes), got dtype {arr.dtype}")
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = _first_index(bad)
            raise InstanceError(name, f"= {_show(arr[idx])}: must be {what}", idx)
        frac = arr != np.floor(arr)
        if frac.any():
            idx = _first_index(frac)
            raise InstanceError(name, f"= {_show(arr[idx])}: must be {what}; fractional bytes", idx)
    low = arr <= 0 if positive else arr < 0
    if low.any():
        idx = _first_index(low)
        raise InstanceError(name, f"= {_show(arr[idx])}: must be {what}", idx)
    high = arr > MAX_BYTES
    if high.any():
        idx = _first_index(high)
        raise InstanceError(name, f"= {_show(arr[idx])}: must be at most 2**53 = {MAX_BYTES} bytes", idx)
    out = arr.astype(np.int64)
    out.setflags(write=False)
    return out


def _object_bytes(arr: np.ndarray, name: str, what: str) -> None:
    """Name the first entry of an object array (numpy's answer to an int beyond int64, or to a
    mix of numbers and other things) that is no byte count: out of range, or not a number."""
    for idx in np.ndindex(arr.shape):
        v = arr[idx]
        if not is_real(v):
            raise InstanceError(name, f"= {brief(v)}: must be {what}", idx)
        if isinstance(v, int) and v > MAX_BYTES:
            raise InstanceError(name, f"= {brief(v)}: out of range: must be at most 2**53 = {MAX_BYTES} bytes", idx)
        if isinstance(v, int) and v < 0:
            raise InstanceError(name, f"= {brief(v)}: out of range: must be {what}", idx)


def _utility_array(value: Any, representation: str) -> np.ndarray:
    arr = as_array(value, "utility")
    if arr.ndim != 3:
        raise InstanceError("utility", f"must be a 3-dimensional array (T, J, L), got {arr.ndim} dimensions")
    if arr.dtype.kind == "b" or arr.dtype.kind not in "iuf":
        raise InstanceError("utility", f"must hold numbers, got dtype {arr.dtype}")
    signed = representation == "layered"
    why = "" if signed else " (a separate version's utility U; a version worse than another is a smaller U)"
    return checked_utility_values(arr, InstanceError, signed=signed, why=why)


def checked_utility_values(arr: np.ndarray, error: type[InstanceError], *, signed: bool = False,
                           why: str = "") -> np.ndarray:
    """``arr`` as a read-only float64 array of utilities: each finite (subnormals included), each
    ``>= 0`` unless ``signed`` (the layered form's per-layer ``dU``), and their magnitudes together
    at most :data:`MAX_UTILITY_TOTAL`, so that no schedule's objective, bound or gap can overflow
    float64 (with signs, a sum of positive terms alone must stay finite too). Faults are
    ``error("utility", ...)`` naming the first index at fault; ``why`` is appended to the
    message of a negative value."""
    with np.errstate(over="ignore"):   # a long double beyond float64 becomes inf, named just below
        out = arr.astype(np.float64)
    bad = ~np.isfinite(out)
    if bad.any():
        idx = _first_index(bad)
        raise error("utility", f"= {_show(out[idx])}: must be finite", idx)
    if not signed:
        neg = out < 0
        if neg.any():
            idx = _first_index(neg)
            raise error("utility", f"= {_show(out[idx])}: must be >= 0{why}", idx)
    with np.errstate(over="ignore"):
        total = float(np.abs(out).sum())
    if not total <= MAX_UTILITY_TOTAL:
        what = "all utilities together" if not signed else "all |utilities| together"
        raise error("utility", f"sums to {total:.3g}: {what} must be at most {MAX_UTILITY_TOTAL:g} "
                               "(an objective summed over slots must stay a finite float64); scale them down")
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Instance:
    """One delivery problem over T slots for J objects with L layers (or versions) each.

    Parameters
    ----------
    representation : {"layered", "separate"}
    bandwidth : array of int, shape [T]
        Bytes available in each slot (bytes per slot).
    cost : array of int, shape [J, L]
        Bytes of each chunk: per-layer cost (layered) or whole-version cost (separate). > 0.
    utility : array of float, shape [T, J, L]
        Per-layer utility ``dU`` (layered; finite, any sign: a negative layer is fetched only as a
        step to a better level) or per-version utility ``U`` (separate; finite, >= 0).
    held : array of bool, shape [J, L], optional
        What the client already holds; for layered objects a prefix of the layers.
    slot_s : float
        Slot length in seconds (default 1.0).
    options : Options, optional
    names : sequence of str, optional
        Object names, J of them: labels for people (reports, item names), not keys, so two
        objects may share one.
    meta : mapping, optional
        Free-form provenance (JSON-serialisable), e.g. trace, window and scale factor.

    Raises
    ------
    InstanceError
        Naming the field and index at fault (e.g. ``utility[0][1][2] = -0.5: must be >= 0`` for
        a separate instance, ``utility[...] = nan: must be finite`` for either).
    """

    representation: str
    bandwidth: np.ndarray
    cost: np.ndarray
    utility: np.ndarray
    held: np.ndarray | None = None
    slot_s: float = 1.0
    options: Options = field(default_factory=Options)
    names: tuple[str, ...] | None = None
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # A str first: ``np.array(["layered"]) in REPRESENTATIONS`` compares elementwise and is true.
        if not isinstance(self.representation, str):
            raise InstanceError("representation", f"must be a str, one of {', '.join(REPRESENTATIONS)}; got "
                                                  f"{type(self.representation).__name__}")
        if self.representation not in REPRESENTATIONS:
            raise InstanceError("representation",
                                f"{self.representation!r} is not one of {', '.join(REPRESENTATIONS)}")
        # Stored as a plain str (not np.str_), so that it compares, hashes and writes as one.
        object.__setattr__(self, "representation", str(self.representation))
        bandwidth = _byte_array(self.bandwidth, "bandwidth", 1, positive=False)
        if bandwidth.shape[0] < 1:
            raise InstanceError("bandwidth", "must have at least one slot")
        cost = _byte_array(self.cost, "cost", 2, positive=True)
        utility = _utility_array(self.utility, self.representation)
        T, (J, L) = bandwidth.shape[0], cost.shape
        if J > 0 and L < 1:
            raise InstanceError("cost", "every object needs at least one layer or version")
        if utility.shape != (T, J, L):
            raise InstanceError("utility", f"has shape {utility.shape}, expected (T, J, L) = {(T, J, L)} "
                                           "from bandwidth and cost")
        held = self._validated_held(self.held, J, L)
        slot_s, options, names, meta = validated_common(self.slot_s, self.options, self.names, self.meta,
                                                        count=J, axis="J")
        for name, value in [("bandwidth", bandwidth), ("cost", cost), ("utility", utility), ("held", held),
                            ("slot_s", slot_s), ("options", options), ("names", names), ("meta", meta)]:
            object.__setattr__(self, name, value)

    def _validated_held(self, held: Any, J: int, L: int) -> np.ndarray:
        if held is None:
            out = np.zeros((J, L), dtype=bool)
        else:
            out = binary_array(held, "held", (J, L), "(J, L)")
            if self.representation == "layered" and L > 1:
                gap = out[:, 1:] & ~out[:, :-1]
                if gap.any():
                    j, l = _first_index(gap)
                    raise InstanceError("held", f"= 1 but layer {l} below it is not held: a layered "
                                                "object holds a prefix of its layers", (j, l + 1))
        out.setflags(write=False)
        return out

    # -- shape ---------------------------------------------------------------------------
    @property
    def T(self) -> int:
        """Number of slots."""
        return int(self.bandwidth.shape[0])

    @property
    def J(self) -> int:
        """Number of objects."""
        return int(self.cost.shape[0])

    @property
    def L(self) -> int:
        """Number of layers (layered) or versions (separate) per object."""
        return int(self.cost.shape[1])

    @property
    def layered(self) -> bool:
        return self.representation == "layered"

    @property
    def problem(self) -> str:
        """The paper's problem name: I/II (segmented), III/IV (one object)."""
        one = self.J == 1
        if self.layered:
            return "III" if one else "I"
        return "IV" if one else "II"

    @property
    def held_levels(self) -> np.ndarray:
        """Layered: number of layers held per object, shape [J]. Separate: count held."""
        return self.held.sum(axis=1).astype(np.int64)

    def replace(self, **changes: Any) -> "Instance":
        """A validated copy with some fields changed."""
        fields = {name: getattr(self, name) for name in
                  ("representation", "bandwidth", "cost", "utility", "held", "slot_s", "options", "names",
                   "meta")}
        fields.update(changes)
        return Instance(**fields)

    def to_dict(self) -> dict[str, Any]:
        """The ``l3gs-opt/instance@1`` JSON object."""
        out: dict[str, Any] = {
            "schema": SCHEMA,
            "representation": self.representation,
            "slot_s": self.slot_s,
            "bandwidth": self.bandwidth.tolist(),
            "cost": self.cost.tolist(),
            "utility": self.utility.tolist(),
        }
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
        # meta is a read-only mapping proxy, which pickle cannot copy: rebuild (and re-validate) instead.
        return (_rebuild, (self.representation, self.bandwidth, self.cost, self.utility, self.held, self.slot_s,
                           self.options, self.names, copy.deepcopy(dict(self.meta))))

    def __repr__(self) -> str:
        return (f"Instance(problem={self.problem}, representation={self.representation!r}, T={self.T}, "
                f"J={self.J}, L={self.L}, options={self.options})")


def _mapping_as_dict(value: Any) -> dict[str, Any]:
    if isinstance(value, Mapping):
        return dict(value)
    raise TypeError(f"Object of type {type(value).__name__} is not JSON serializable")


def _rebuild(representation, bandwidth, cost, utility, held, slot_s, options, names, meta) -> Instance:
    return Instance(representation=representation, bandwidth=bandwidth, cost=cost, utility=utility, held=held,
                    slot_s=slot_s, options=options, names=names, meta=meta)
