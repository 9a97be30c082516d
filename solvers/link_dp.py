"""``link-dp``: the exact optimum of Problems I-IV under the ``cumulative`` budget, by dynamic
programming over what has been delivered.

With one sequential link (``budget="cumulative"``: the bytes arriving by slot t are at most the
bandwidth of slots 0..t) a schedule is an order of chunks, and each chunk is best delivered in the
first slot whose cumulative bandwidth covers it and everything before it:

* any feasible schedule, listed by arrival slot (a layer after the layers below it), gives an
  order whose k-th chunk fits by that "greedy" slot ``t_k = min{t : sum_{s<=t} B[s] >= P_k}``
  (``P_k`` = bytes of the first k chunks), which is never later than its slot in the schedule;
* held utility never decreases with an earlier arrival (utilities ``>= 0``), so the greedy
  slots are at least as good, and they are feasible (the bytes by slot t are ``P_k <= sum B``).

So the optimum is the best order. The value of an order depends only on which chunks precede
each one, not on their order: the DP state is the set delivered so far -- per object a prefix
of layers (layered: ``L+1`` states) or a set of versions (separate: ``2^L`` states) -- and the
state fixes its total bytes, hence the slot ``t(s)`` in which its last chunk arrives:

    V(s) = max over the chunk c last in s of  V(s - c) + gain(c | s - c, t(s))

with ``gain`` the utility ``c`` adds from ``t(s)`` (``next_slot`` availability: from
``t(s) + 1``) to the horizon: layered, ``sum_{t' >= t} dU[j,l,t']``; separate, the rise of
``max_{held versions} U[j,.,t']`` over the slots ``t' >= t`` (versions replace each other).
The optimum is ``max_s V(s)`` over the states whose bytes fit the whole horizon. States are
processed in order of chunk count, vectorised over numpy arrays: ``prod_j (states of j)``
states (layered J=5, L=4: 3,125; separate J=5, L=4: 1,048,576).

**Signed layer utilities** (a layer with ``dU < 0`` somewhere): an earlier arrival can be worse,
so the greedy slots are no longer best. A schedule is still an order with nondecreasing slots
``a_k >= t_k`` (and every such order is feasible: the bytes by slot ``a_k`` are ``P_k <= sum B``),
so the DP gains a slot axis: ``W(s, t)``, the best value of delivering ``s`` with every arrival in
a slot ``<= t``, is ``max(W(s, t-1), max_c W(s - c, t) + gain(c, t))`` for ``t >= t(s)``. It has
``T`` times the states (``max_states`` counts them) and is used only when some unheld layer's
utility is negative.

Supported: either representation, availability ``same_slot`` or ``next_slot``, held chunks.
Rejected (:class:`~l3gs_opt.errors.SolveError`): the ``per_slot`` budget (a chunk's slot is not
a function of the bytes before it) and strict layers (``same_slot_layers=False``: the greedy
slot of a layer may equal its lower layer's), and more than ``max_states`` states.
"""

from __future__ import annotations

import time

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.solution import Solution, Status, finish_solution

__all__ = ["solve_link_dp", "link_dp_states", "MAX_STATES"]

#: Largest state space solved (float64 values + back-pointers: ~40 bytes a state).
MAX_STATES = 4_000_000


def _local_states(inst: Instance, j: int, shift: int):
    """Object ``j``'s states: bitmasks of delivered chunks (held ones included), their chunk
    counts and bytes (held excluded), and the transitions ``(a, b, l, gain[T])`` adding chunk l."""
    T, L = inst.T, inst.L
    U = inst.utility[:, j, :]                                  # [T, L]
    held = [bool(h) for h in inst.held[j]]
    cost = [int(c) for c in inst.cost[j]]
    base = sum(1 << l for l in range(L) if held[l])

    def suffix(series: np.ndarray) -> np.ndarray:
        """``g[t] = sum_{t' >= t + shift} series[t']``, t = 0..T-1."""
        s = np.concatenate([np.cumsum(series[::-1])[::-1], [0.0, 0.0]])
        return s[shift:shift + T]

    if inst.layered:
        first = int(np.argmin(held + [False]))                 # held is a prefix: levels first..L
        masks = [(1 << h) - 1 for h in range(first, L + 1)]
    else:
        masks = [m for m in range(1 << L) if m & base == base]
    index = {m: i for i, m in enumerate(masks)}
    count = np.array([bin(m ^ base).count("1") for m in masks], np.int64)
    nbytes = np.array([sum(cost[l] for l in range(L) if (m ^ base) >> l & 1) for m in masks], np.int64)
    shown = {}
    if not inst.layered:
        for m in masks:
            ls = [l for l in range(L) if m >> l & 1]
            shown[m] = U[:, ls].max(axis=1) if ls else np.zeros(T)
    trans = []
    for m in masks:
        for l in range(L):
            if not (m >> l & 1) or (base >> l & 1):
                continue
            a = m & ~(1 << l)
            if a not in index:                                 # layered: only the top layer comes last
                continue
            gain = suffix(U[:, l]) if inst.layered else suffix(shown[m] - shown[a])
            trans.append((index[a], index[m], l, gain))
    return count, nbytes, trans


def link_dp_states(instance: Instance) -> int:
    """Number of DP states of ``instance`` (product over objects of their local states)."""
    n = 1
    for j in range(instance.J):
        if instance.layered:
            n *= instance.L + 1 - int(np.sum(instance.held[j]))
        else:
            n *= 1 << (instance.L - int(np.sum(instance.held[j])))
    return n


def solve_link_dp(instance: Instance, *, max_states: int = MAX_STATES, time_limit_s: float | None = None,
                  **_ignored) -> Solution:
    """Exact optimum of a ``cumulative``-budget instance (see the module docstring).

    Parameters
    ----------
    instance : Instance
        Layered or separate, ``options.budget == "cumulative"``, same-slot layers allowed.
    max_states : int
        Refuse larger state spaces (:func:`link_dp_states`; times T with signed layer utilities).
    time_limit_s : float, optional
        Not used (the DP is not interruptible); accepted so it plugs in like other methods.

    Returns
    -------
    Solution
        Status ``optimal``; the bound is the optimum itself.

    Raises
    ------
    SolveError
        Per-slot budget, strict layers, or more than ``max_states`` states.
    """
    t0 = time.perf_counter()
    inst = instance
    if inst.options.budget != "cumulative":
        raise SolveError("method 'link-dp': needs options.budget 'cumulative' (one link whose unspent bytes carry "
                         f"over), not {inst.options.budget!r}; use ilp")
    if inst.layered and not inst.options.same_slot_layers:
        raise SolveError("method 'link-dp': strict layers (same_slot_layers false) are not supported; use ilp")
    n_states = link_dp_states(inst)
    if n_states > max_states:
        raise SolveError(f"method 'link-dp': {n_states} states exceed max_states = {max_states}; use ilp")
    shift = 1 if inst.options.availability == "next_slot" else 0
    J, T = inst.J, inst.T
    signed = inst.layered and bool((np.where(inst.held[None], 0.0, inst.utility) < 0).any())
    if signed and n_states * T > max_states:
        raise SolveError(f"method 'link-dp': {n_states} states x {T} slots (signed layer utilities need the slot "
                         f"axis) exceed max_states = {max_states}; use ilp")
    objects = [_local_states(inst, j, shift) for j in range(J)]
    sizes = [len(c) for c, _, _ in objects]
    strides = np.ones(J, np.int64)
    for j in range(J - 2, -1, -1):
        strides[j] = strides[j + 1] * sizes[j + 1]
    g = np.arange(n_states, dtype=np.int64)
    local = [(g // strides[j]) % sizes[j] for j in range(J)]
    count = np.zeros(n_states, np.int64)
    nbytes = np.zeros(n_states, np.int64)
    for j, (c, b, _) in enumerate(objects):
        count += c[local[j]]
        nbytes += b[local[j]]
    cum = np.cumsum(np.asarray([int(b) for b in inst.bandwidth], dtype=np.int64))
    slot = np.searchsorted(cum, nbytes, side="left")          # first slot covering the state's bytes
    fits = slot < T
    if signed:
        arrivals, dp_value = _signed_dp(inst, objects, local, strides, count, slot, fits)
        return _finish(inst, arrivals, n_states, dp_value, t0)
    value = np.full(n_states, -np.inf)
    value[0] = 0.0                                             # every object at its held state
    back_state = np.full(n_states, -1, np.int64)
    back_chunk = np.full((n_states, 2), -1, np.int64)
    for states, moves in _moves_by_count(objects, local, strides, count, fits):
        t_of = slot[states]
        for j, l, gain, sel, gs, prev in moves:
            cand = value[prev] + gain[t_of[sel]]
            better = cand > value[gs]
            if better.any():
                upd = gs[better]
                value[upd] = cand[better]
                back_state[upd] = prev[better]
                back_chunk[upd] = (j, l)
    best = int(np.argmax(np.where(fits, value, -np.inf)))
    arrivals = []
    s = best
    while s > 0:
        j, l = (int(v) for v in back_chunk[s])
        arrivals.append((j, l, int(slot[s])))
        s = int(back_state[s])
    return _finish(inst, arrivals, n_states, float(value[best]), t0)


def _moves_by_count(objects: list, local: list, strides: np.ndarray, count: np.ndarray, fits: np.ndarray):
    """Both DPs' sweep: for k = 1, 2, ... chunks delivered, the states of k chunks whose bytes fit
    the horizon, and per chunk (j, l) that can be their last: ``(j, l, gain, sel, states, before)``
    (``sel`` the mask over the k-chunk states, ``before`` the states of k - 1 chunks they come from)."""
    order = np.argsort(count, kind="stable")
    bounds = np.searchsorted(count[order], np.arange(count.max() + 2))
    for k in range(1, int(count.max()) + 1):
        states = order[bounds[k]:bounds[k + 1]]
        states = states[fits[states]]
        if states.size == 0:
            continue
        moves = []
        for j, (_, _, trans) in enumerate(objects):
            loc = local[j][states]
            for a, b, l, gain in trans:
                sel = loc == b
                if sel.any():
                    gs = states[sel]
                    moves.append((j, l, gain, sel, gs, gs - (b - a) * strides[j]))
        yield states, moves


def _finish(inst: Instance, arrivals: list, n_states: int, dp_value: float, t0: float) -> Solution:
    from l3gs_opt.problem.evaluate import evaluate_objective

    objective = evaluate_objective(inst, arrivals)
    problem = ("I" if inst.J > 1 else "III") if inst.layered else ("II" if inst.J > 1 else "IV")
    # The DP enumerates every delivered set, so its best schedule is optimal: the bound is its value.
    return finish_solution(inst, arrivals, problem=problem, method="link-dp", status=Status.OPTIMAL,
                           bound=objective, runtime_s=time.perf_counter() - t0,
                           details={"states": n_states, "dp_value": dp_value})


def _signed_dp(inst: Instance, objects: list, local: list, strides: np.ndarray, count: np.ndarray,
               slot: np.ndarray, fits: np.ndarray) -> tuple[list[tuple[int, int, int]], float]:
    """The DP with a slot axis (module doc, signed layer utilities): arrivals and the DP's value.

    ``direct[s, t]`` is the best value of ``s`` whose last chunk arrives exactly in slot t (``code``
    says which chunk: ``j * L + l``); ``W = max.accumulate(direct)`` along t.
    """
    T, L = inst.T, inst.L
    n = count.shape[0]
    W = np.full((n, T), -np.inf)
    W[0] = 0.0                                                  # every object at its held state
    direct = np.full((n, T), -np.inf)
    code = np.full((n, T), -1, np.int64)
    before = np.arange(T)[None, :] < slot[:, None]             # slots too early for the state's bytes
    for states, moves in _moves_by_count(objects, local, strides, count, fits):
        for j, l, gain, _, gs, prev in moves:
            cand = W[prev] + gain[None, :]
            cand[before[gs]] = -np.inf
            better = cand > direct[gs]
            if better.any():
                rows, cols = np.nonzero(better)
                direct[gs[rows], cols] = cand[rows, cols]
                code[gs[rows], cols] = j * L + l
        W[states] = np.maximum.accumulate(direct[states], axis=1)
    best = int(np.argmax(np.where(fits, W[:, T - 1], -np.inf)))
    value = float(W[best, T - 1])
    arrivals = []
    s, t = best, T - 1
    while s > 0:
        t = int(np.nonzero(direct[s, :t + 1] == W[s, t])[0].max())   # the last chunk's slot
        j, l = divmod(int(code[s, t]), L)
        arrivals.append((j, l, t))
        s -= int(strides[j])                                   # layered: one layer less of object j
    return arrivals, value
