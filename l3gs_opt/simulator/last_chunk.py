"""The slot's last chunk counted by the splats of it that arrive (``SimConfig.last_chunk="prefix"``).

The paper's per-slot problem (Lemma 3) counts a chunk only when all of it arrives within the
slot. The simulated link streams a chunk's splats in descending predicted utility and the viewer
shows every splat that has arrived, and the chunk cut off at the slot's end carries over. So
when the slot's bytes run out inside a chunk, the first splats of that chunk already count.
Early in a session, when the most useful chunks are larger than a slot's bytes, the whole-chunk
problem picks the small chunks that fit and leaves the valuable large ones for later
(`benchmarks/results/last_chunk/`).

:func:`plan_last_chunk` solves the per-slot problem with that accounted: choose for each object
how many more layers arrive whole (a precedence-closed set within the slot's bytes, as the
single-slot MCKP does) and at most one more chunk, the object's next layer, that gets the bytes
left and is worth the predicted value of its first ``left // bytes_per_splat`` splats in
streaming order. It is an exact dynamic programme over the bytes in steps of their greatest
common divisor (every chunk is whole splats of one record size, so the step is at least one
record); if that grid would have more than :data:`MAX_GRID` steps, chunk bytes are rounded up
to a coarser step (the plan still fits the bytes, but the partial may then get more bytes than
planned, and the plan may miss the optimum).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from l3gs_opt.checks import ArgumentError, check_count, real_array, shown

__all__ = ["LAST_CHUNKS", "MAX_GRID", "LastChunkPlan", "plan_last_chunk"]

#: ``whole``: the paper's model (only complete chunks count); ``prefix``: :func:`plan_last_chunk`.
LAST_CHUNKS = ("whole", "prefix")
#: Most steps of the byte grid of :func:`plan_last_chunk`. Its work is objects x log2(objects) x
#: layers x steps (see ``_all_but_one``).
MAX_GRID = 100_000
#: A partial plan must beat the best whole-chunk plan by this relative margin to be chosen (a tie
#: keeps the whole chunks: a partial commits the next slot's first bytes to the rest of its chunk).
TIE_TOL = 1e-9

_NEG = -math.inf


@dataclass(frozen=True)
class LastChunkPlan:
    """A slot's plan: ``picks`` arrive whole (per object lowest layer first), then ``partial`` (or
    None) gets the bytes left; ``value`` is what the plan is predicted to be worth in the slot
    (the picks' utilities plus the partial's first splats), ``whole_value`` the best plan of
    whole chunks only, ``partial_bytes`` the bytes the partial is predicted to get."""

    picks: tuple[tuple[int, int], ...]
    partial: tuple[int, int] | None
    value: float
    whole_value: float
    partial_bytes: int


def _start(cap: int, exact: bool) -> np.ndarray:
    """The table of no object: value 0 at ``c`` steps for every ``c`` (at most) or for 0 only (exactly)."""
    f = np.zeros(cap + 1)
    if exact:
        f[1:] = _NEG
    return f


def _table(options: list[list[tuple[int, float]]], cap: int, exact: bool = False) -> np.ndarray:
    """``f[c]``: the best value of one option per object with total steps at most (``exact``:
    exactly) ``c``; ``-inf`` where none fits."""
    f = _start(cap, exact)
    for opts in options:
        f = _add(f, opts, cap)
    return f


def _add(f: np.ndarray, opts: list[tuple[int, float]], cap: int) -> np.ndarray:
    g = np.full(cap + 1, _NEG)
    for w, v in opts:
        if w <= cap:
            np.maximum(g[w:], f[:cap + 1 - w] + v, out=g[w:])
    return g


def _all_but_one(options: list[list[tuple[int, float]]], cap: int, visit: Callable[[int, np.ndarray], None], *,
                 wanted: list[bool]) -> None:
    """``visit(j, table)`` in order of ``j`` for every wanted object, ``table`` being :func:`_table`
    (``exact``) of all objects but ``j``: by halving, each table built from its parent's, so the
    work is ``J log J`` table steps instead of ``J^2``, and at most ``log J`` tables are held."""

    def down(lo: int, hi: int, f: np.ndarray) -> None:   # f: the table of every object outside [lo, hi)
        if not any(wanted[lo:hi]):
            return
        if hi - lo == 1:
            visit(lo, f)
            return
        mid = (lo + hi) // 2
        for a, b, c, d in ((lo, mid, mid, hi), (mid, hi, lo, mid)):
            g = f
            for k in range(c, d):
                g = _add(g, options[k], cap)
            down(a, b, g)

    if options:
        down(0, len(options), _start(cap, True))


def _choose(options: list[list[tuple[int, float]]], cap: int, exact: bool = False) -> list[int]:
    """The option index per object of a best plan of at most (``exact``: exactly) ``cap`` steps
    (backtracking through the tables of :func:`_table`)."""
    tables = [_start(cap, exact)]
    for opts in options:
        tables.append(_add(tables[-1], opts, cap))
    c, out = cap, []
    for i in range(len(options) - 1, -1, -1):
        target = tables[i + 1][c]
        for k, (w, v) in enumerate(options[i]):
            if w <= c and tables[i][c - w] + v >= target - 1e-12 * max(1.0, abs(target)):
                out.append(k)
                c -= w
                break
        else:  # pragma: no cover - the tables hold the values the loop looks for
            raise AssertionError("backtracking found no option")
    return out[::-1]


def _checked(cost, utility, held, empty, capacity, prefix, bytes_per_splat):
    arrays = {"cost": real_array("cost", cost), "utility": real_array("utility", utility),
              "bytes_per_splat": real_array("bytes_per_splat", bytes_per_splat)}
    masks = {"held": np.asarray(held), "empty": np.asarray(empty)}
    shape = arrays["cost"].shape
    for name, a in (*arrays.items(), *masks.items()):
        if a.ndim != 2 or a.shape != shape:
            raise ArgumentError(name, f"has shape {a.shape}, expected [J, L] = {shape} (the shape of cost)")
    for name, a in masks.items():
        if a.dtype != bool:
            raise ArgumentError(name, "must be a bool array")
    if not np.isfinite(arrays["utility"]).all():
        raise ArgumentError("utility", "must be finite")
    solid = ~masks["empty"]
    for name in ("cost", "bytes_per_splat"):
        a = arrays[name]
        if (solid & ((a < 1) | (a != np.round(a)) | ~np.isfinite(a))).any():
            raise ArgumentError(name, "must be whole bytes >= 1 for every layer that is not empty")
    check_count("capacity", capacity, low=0, high=2**62)
    if not callable(prefix):
        raise ArgumentError("prefix", f"{shown(prefix)}: must be a function (j, l) -> values of the first n splats")
    return (np.where(solid, arrays["cost"], 1).astype(np.int64),
            np.where(solid, arrays["bytes_per_splat"], 1).astype(np.int64), arrays["utility"], masks["held"],
            masks["empty"])


def plan_last_chunk(cost: np.ndarray, utility: np.ndarray, held: np.ndarray, empty: np.ndarray,
                    capacity: int, prefix: Callable[[tuple[int, int]], np.ndarray],
                    bytes_per_splat: np.ndarray) -> LastChunkPlan:
    """The best plan of one slot whose bytes may end inside one chunk (see the module docstring).

    Parameters
    ----------
    cost : int array [J, L]
        Bytes of each layer (an empty layer's entry is ignored: it costs nothing).
    utility : float array [J, L]
        Predicted value of each whole layer (any sign).
    held : bool array [J, L]
        Layers already there or on their way (a prefix of each object's layers).
    empty : bool array [J, L]
        Layers without splats (always complete).
    capacity : int
        Bytes of the slot for new requests.
    prefix : callable ``(j, l) -> float array [splats + 1]``
        Predicted value of the layer's first ``n`` splats in streaming order (``prefix[-1]`` is
        its whole value); called for the layers that may be the partial one.
    bytes_per_splat : int array [J, L]
        Bytes of one splat of each layer.

    Raises
    ------
    ArgumentError
        Arrays not all ``[J, L]``, a non-finite utility, a cost or splat size below 1 byte where
        a layer is not empty, a negative or non-integer capacity (naming the argument).
    """
    cost, bytes_per_splat, utility, held, empty = _checked(cost, utility, held, empty, capacity, prefix,
                                                           bytes_per_splat)
    J, L = cost.shape
    levels = np.cumprod(held | empty, axis=1).sum(axis=1)
    free = [(j, l) for j in range(J) for l in range(int(levels[j]), L) if not empty[j, l]]
    capacity = int(capacity)
    if capacity <= 0 or not free:
        return LastChunkPlan((), None, 0.0, 0.0, 0)
    step = 0
    for j, l in free:
        step = math.gcd(step, int(cost[j, l]), int(bytes_per_splat[j, l]))
    step = max(step, -(-capacity // MAX_GRID))
    cap, rest = divmod(capacity, step)
    # Per object: (steps, value) of taking 0, 1, ... more layers whole, and the layers that could
    # be the partial one on top of each such choice.
    options: list[list[tuple[int, float]]] = []
    partials: list[list[tuple[int, int]]] = []
    for j in range(J):
        w, v, opts, parts = 0, 0.0, [(0, 0.0)], []
        for l in range(int(levels[j]), L):
            if not empty[j, l]:
                parts.append((len(opts) - 1, l))
                w += -(-int(cost[j, l]) // step)
                v += float(utility[j, l])
            opts.append((w, v))
        options.append(opts)
        partials.append(parts)
    whole = float(_table(options, cap)[cap])
    best, where = whole, None

    def visit(j: int, others: np.ndarray) -> None:
        nonlocal best, where
        for k, l in partials[j]:
            w, v = options[j][k]
            if w > cap:
                continue
            pre = np.asarray(prefix((j, l)), dtype=np.float64)
            used = np.arange(cap - w + 1)                    # steps the other objects may use
            left = (cap - w - used) * step + rest             # bytes the partial gets
            n = np.minimum(left // int(bytes_per_splat[j, l]), len(pre) - 1)
            total = others[: cap - w + 1] + v + pre[n]
            i = int(np.argmax(total))   # (-inf where the others cannot use exactly that many steps)
            if total[i] > best + TIE_TOL * max(1.0, abs(best)):
                best, where = float(total[i]), (j, k, l, i, int(left[i]))

    # The others use exactly c steps, so the partial gets exactly the bytes left: with signed
    # splat values a longer prefix may be worth less, so "at most c" would misprice it.
    _all_but_one(options, cap, visit, wanted=[bool(p) for p in partials])
    if where is None:
        chosen = _choose(options, cap)
        picks = [(j, l) for j in range(J) for l in range(int(levels[j]), int(levels[j]) + chosen[j])]
        return LastChunkPlan(tuple(p for p in picks if not empty[p]), None, whole, whole, 0)
    j0, k0, l0, used, got = where
    rest_objects = [j for j in range(J) if j != j0]
    chosen = dict(zip(rest_objects, _choose([options[j] for j in rest_objects], used, exact=True)))
    chosen[j0] = k0
    picks = [(j, l) for j in range(J) for l in range(int(levels[j]), int(levels[j]) + chosen[j])]
    return LastChunkPlan(tuple(p for p in picks if not empty[p]), (j0, l0), best, whole, got)
