"""Problems II and IV (separate versions) as per-object paths, and their Lagrangian bound.

With at-most-once arrivals and "show the best held version", object j's part of a schedule is a
*path*: the set of its versions that arrive, each with its slot. Its value is
``sum_t max(0, max_{l held at t} g[t,j,l])`` with ``g`` the version's utility above the best held
version (presolve's ``gain``), and it spends ``c[j,l]`` bytes in its arrival slot. The objects
are coupled only by the byte budgets, so Problem II is::

    max  sum_j sum_p v[j,p] lam[j,p]
    s.t. sum_p lam[j,p] <= 1                                   (one path per object; mu[j])
         sum_{j,p} a[j,p,t] lam[j,p] <= R[t]                    (budget row t; pi[t] >= 0)
         lam in {0, 1}

with ``a[j,p,t]`` the bytes path p brings in slot t and ``R[t] = B[t]`` (``per_slot``), or the
bytes it brings by slot t and ``R[t] = sum_{s<=t} B[s]`` (``cumulative``: one sequential link).
Dualising the budget rows with ``pi >= 0`` leaves one longest-path problem per object with the
arrival price ``rho[s] = pi[s]`` (per slot) or ``rho[s] = sum_{t>=s} pi[t]`` (cumulative)::

    L(pi) = constant + sum_t pi[t] R[t] + sum_j max_p (v[j,p] - sum_s rho[s] a[j,p,s])

an upper bound on the optimum for every ``pi >= 0`` (the empty path is always a candidate, so
each object adds at least 0). Paths are priced exactly by a dynamic programme over (slot, set of
versions held) states: ``2^V`` states for the ``V`` versions presolve keeps (a set, not a chain,
because utilities vary over the slots: a version worse than another now may be better later).
Within a slot any set of new versions may arrive together, as long as their bytes fit the slot's
budget (``cumulative``: the budget up to that slot) - a constraint every schedule meets, so the
bound stays valid and gets tighter. The DP is exact in its arithmetic order; the bound is valid
for any ``pi``, whatever the LP that proposed it did.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import presolve

__all__ = ["MAX_VERSIONS", "SeparateData", "separate_data", "PriceResult", "price_paths", "lagrangian_bound",
           "Path", "path_value", "path_bytes", "schedule_feasible"]

#: Most versions per object the path DP takes after presolve: ``2^V`` states and ``3^V`` (state,
#: arrivals) pairs per slot, 6,561 at V = 8 (the paper's scenes have 4).
MAX_VERSIONS = 8

#: A path: per version bit, its arrival slot or -1 (never).
Path = tuple[int, ...]


@dataclass(frozen=True, eq=False)
class SeparateData:
    """A separate instance over the objects and versions presolve keeps.

    Attributes
    ----------
    T, V : int
        Slots, and versions per object after presolve (the largest count; bits beyond an
        object's own count are padding that never arrives).
    objects : int array [K]
        Instance object index of each kept object ``k`` (an object with at least one version worth
        fetching).
    versions : int array [K, V]
        Instance version index of each bit (-1: padding).
    cost : int64 array [K, V]
        Bytes of each version (0 for padding).
    gain : float64 array [T, K, V]
        Utility of the version above the object's best held version at slot t (clipped at 0).
    allowed : int64 array [K, T]
        Bit mask of the versions that may arrive in slot t (presolve: it fits, it adds something).
    show : float64 array [T, K, 2^V]
        Utility shown at slot t above the held base when the object holds the version set S.
    rhs : int64 array [T]
        Budget row right-hand sides in bytes: ``B[t]`` or ``sum_{s<=t} B[s]`` (cumulative).
    cumulative, shift : bool, int
        The budget kind, and 1 under ``next_slot`` availability (a version is shown from the slot
        after it arrives), else 0.
    constant : float
        Utility of the best held versions over the horizon.
    pair_from, pair_add, pair_to : int arrays [P]
        The (state, arrivals) pairs of one slot: from set ``S'``, arriving set ``A`` (disjoint,
        non-empty), to set ``S' | A``; sorted by ``pair_to``. ``pair_starts`` [2^V - 1] indexes the
        first pair of each target 1..2^V - 1.
    pair_cost : int64 array [K, P]
        Bytes of each pair's arrivals per object.
    """

    T: int
    V: int
    objects: np.ndarray
    versions: np.ndarray
    cost: np.ndarray
    gain: np.ndarray
    allowed: np.ndarray
    show: np.ndarray
    rhs: np.ndarray
    budget: np.ndarray
    cumulative: bool
    shift: int
    constant: float
    pair_from: np.ndarray
    pair_add: np.ndarray
    pair_to: np.ndarray
    pair_starts: np.ndarray
    pair_cost: np.ndarray
    stats: dict = field(default_factory=dict)

    @property
    def K(self) -> int:
        return int(self.objects.shape[0])

    @property
    def states(self) -> int:
        return 1 << self.V

    def arrivals(self, paths: dict[int, Path]) -> list[tuple[int, int, int]]:
        """Arrivals ``(j, l, t)`` of one path per object (objects missing: nothing arrives)."""
        out = []
        for k, path in paths.items():
            for b, t in enumerate(path):
                if t >= 0:
                    out.append((int(self.objects[k]), int(self.versions[k, b]), int(t)))
        return out

    def paths_of(self, arrivals) -> dict[int, Path]:
        """One path per object of a schedule; versions presolve dropped are left out (they add
        nothing wherever they could be shown, so leaving them out only frees bytes), and so is an
        arrival after the version's last event slot; under the cumulative budget an arrival in a
        slot presolve leaves out waits for the version's next event slot (the same value, a looser
        budget: :mod:`l3gs_opt.problem.presolve`)."""
        index = {(int(self.objects[k]), int(self.versions[k, b])): (k, b)
                 for k in range(self.K) for b in range(self.V) if self.versions[k, b] >= 0}
        slots = np.full((self.K, self.V), -1, dtype=np.int64)
        for j, l, t in arrivals:
            hit = index.get((int(j), int(l)))
            if hit is not None:
                k, b = hit
                ok = np.nonzero((self.allowed[k, int(t):] >> b) & 1)[0]
                if len(ok) and (ok[0] == 0 or self.cumulative):
                    slots[hit] = int(t) + int(ok[0])
        return {k: tuple(int(s) for s in slots[k]) for k in range(self.K) if (slots[k] >= 0).any()}


def separate_data(instance: Instance) -> SeparateData:
    """The path form of a separate instance (see the module doc).

    Raises
    ------
    SolveError
        A layered instance, or an object with more than :data:`MAX_VERSIONS` versions worth
        fetching after presolve.
    """
    inst = instance
    if inst.layered:
        raise SolveError("separate_data: separate instances only (Problems II and IV)")
    red = presolve(inst)
    T = inst.T
    counts = red.active.sum(axis=1)
    keep = np.nonzero(counts > 0)[0]
    V = int(counts.max(initial=0))
    if V > MAX_VERSIONS:
        j = int(np.argmax(counts))
        raise SolveError(f"method 'exact': object {j} has {V} versions worth fetching after presolve; the path "
                         f"search takes at most {MAX_VERSIONS} per object (2^V states); use method 'ilp'")
    K = len(keep)
    versions = np.full((K, V), -1, dtype=np.int64)
    cost = np.zeros((K, V), dtype=np.int64)
    gain = np.zeros((T, K, V))
    allowed = np.zeros((K, T), dtype=np.int64)
    for k, j in enumerate(keep):
        ls = np.nonzero(red.active[j])[0]
        versions[k, :len(ls)] = ls
        cost[k, :len(ls)] = inst.cost[j, ls]
        gain[:, k, :len(ls)] = red.gain[:, j, ls]
        for b, l in enumerate(ls):
            allowed[k] |= red.arrive[j, l, :].astype(np.int64) << b
    S = 1 << V
    # show[t, k, S] = max over the bits of S of gain (0 for the empty set), built up bit by bit.
    show = np.zeros((T, K, S))
    for s in range(1, S):
        low = (s & -s).bit_length() - 1
        show[:, :, s] = np.maximum(show[:, :, s & (s - 1)], gain[:, :, low])
    # Every (from, arrivals) pair with disjoint, non-empty arrivals; sorted by target set.
    pf, pa = [], []
    for a in range(1, S):
        rest = (S - 1) & ~a
        sub = rest
        while True:      # every subset of the bits not arriving
            pf.append(sub)
            pa.append(a)
            if sub == 0:
                break
            sub = (sub - 1) & rest
    pf, pa = np.asarray(pf, dtype=np.int64), np.asarray(pa, dtype=np.int64)
    pt = pf | pa
    order = np.lexsort((pf, pt))
    pf, pa, pt = pf[order], pa[order], pt[order]
    starts = np.searchsorted(pt, np.arange(1, S)) if S > 1 else np.zeros(0, dtype=np.int64)
    bits = ((pa[:, None] >> np.arange(V)[None, :]) & 1).astype(np.int64)          # [P, V]
    pair_cost = cost @ bits.T if K and V else np.zeros((K, len(pa)), dtype=np.int64)
    budget = inst.bandwidth.astype(np.int64)
    cumulative = inst.options.budget == "cumulative"
    rhs = np.cumsum(budget) if cumulative else budget.copy()
    stats = dict(red.stats)
    stats.update({"objects": K, "versions_per_object": V, "pairs_per_slot": int(len(pa))})
    return SeparateData(T=T, V=V, objects=keep.astype(np.int64), versions=versions, cost=cost, gain=gain,
                        allowed=allowed, show=show, rhs=rhs, budget=budget, cumulative=cumulative,
                        shift=1 if inst.options.availability == "next_slot" else 0, constant=red.constant,
                        pair_from=pf, pair_add=pa, pair_to=pt, pair_starts=starts.astype(np.int64),
                        pair_cost=pair_cost.astype(np.int64), stats=stats)


# -- paths --------------------------------------------------------------------------------------

def _held_sets(data: SeparateData, path: Path) -> np.ndarray:
    """``[T]`` version set shown at each slot along ``path``."""
    held = np.zeros(data.T, dtype=np.int64)
    for b, t in enumerate(path):
        if t >= 0 and t + data.shift < data.T:
            held[t + data.shift:] |= 1 << b
    return held


def path_value(data: SeparateData, k: int, path: Path) -> float:
    """Utility the path adds above the held base, summed over the slots (exactly rounded)."""
    held = _held_sets(data, path)
    return math.fsum(data.show[np.arange(data.T), k, held].tolist())


def path_bytes(data: SeparateData, k: int, path: Path) -> dict[int, int]:
    """Bytes the path brings per slot (Python ints)."""
    out: dict[int, int] = {}
    for b, t in enumerate(path):
        if t >= 0:
            out[t] = out.get(t, 0) + int(data.cost[k, b])
    return out


def schedule_feasible(data: SeparateData, paths: dict[int, Path], *, allowed: np.ndarray | None = None) -> bool:
    """Budgets hold in exact integer bytes and every arrival is allowed (by ``allowed``,
    default presolve's mask)."""
    allowed = data.allowed if allowed is None else allowed
    spent = [0] * data.T
    for k, path in paths.items():
        for b, t in enumerate(path):
            if t < 0:
                continue
            if not (int(allowed[k, t]) >> b) & 1:
                return False
            spent[t] += int(data.cost[k, b])
    used = 0
    for t in range(data.T):
        used = used + spent[t] if data.cumulative else spent[t]
        if used > int(data.rhs[t]):
            return False
    return True


# -- pricing ------------------------------------------------------------------------------------

@dataclass(eq=False)
class PriceResult:
    """Best path per object at arrival prices ``rho`` (``value`` -inf: no path meets the node's
    restrictions)."""

    value: np.ndarray            #: [K] best reduced value (path value minus priced bytes)
    paths: list[Path | None]     #: [K] the best path (None when value is -inf)


def price_paths(data: SeparateData, rho: np.ndarray, *, allowed: np.ndarray | None = None,
                must: np.ndarray | None = None, cap: np.ndarray | None = None,
                objects: np.ndarray | None = None) -> PriceResult:
    """Longest path per object: max over paths of ``value - sum_s rho[s] * bytes(s)``.

    Parameters
    ----------
    rho : float array [T]
        Price of one byte arriving in slot s (utility per byte).
    allowed : int array [K, T], optional
        Bit mask of versions that may arrive in slot t (a node's; default presolve's).
    must : int array [K], optional
        Versions each object's path must contain (a branch "arrives by slot t").
    cap : int array [K, T] or [T], optional
        Bytes the versions arriving together in slot t may take (default the budget row's
        right-hand side, which every schedule meets).
    objects : int array, optional
        Price only these objects (default all); the result's arrays are over them.
    """
    K_all, T, S = data.K, data.T, data.states
    ks = np.arange(K_all) if objects is None else np.asarray(objects, dtype=np.int64)
    K = len(ks)
    allowed = (data.allowed if allowed is None else allowed)[ks]
    cap = data.rhs if cap is None else cap
    cap = np.broadcast_to(cap, (K_all, T))[ks] if np.ndim(cap) == 2 else np.broadcast_to(cap, (K, T))
    pf, pa, pt, starts = data.pair_from, data.pair_add, data.pair_to, data.pair_starts
    pcost = data.pair_cost[ks]
    pcost_f = pcost.astype(np.float64)
    show = data.show[:, ks, :]
    value = np.full((K, S), -np.inf)
    value[:, 0] = 0.0
    history = np.empty((T, K, S))
    oks = np.empty((T, K, len(pa)), dtype=bool)
    for t in range(T):
        if data.shift:
            value = value + show[t]
        history[t] = value
        ok = ((pa[None, :] & ~allowed[:, t][:, None]) == 0) & (pcost <= cap[:, t][:, None])
        oks[t] = ok
        if S > 1 and ok.any():
            cand = np.where(ok, value[:, pf] - rho[t] * pcost_f, -np.inf)
            best = np.maximum.reduceat(cand, starts, axis=1)
            value = value.copy()
            value[:, 1:] = np.maximum(value[:, 1:], best)
        if not data.shift:
            value = value + show[t]
    states = np.arange(S)
    if must is not None:
        need = np.asarray(must, dtype=np.int64)[ks]
        value = np.where((states[None, :] & need[:, None]) == need[:, None], value, -np.inf)
    end = np.argmax(value, axis=1)
    out_value = value[np.arange(K), end]
    paths: list[Path | None] = []
    for i in range(K):
        if out_value[i] == -np.inf:
            paths.append(None)
            continue
        slots = [-1] * data.V
        s = int(end[i])
        for t in range(T - 1, -1, -1):
            if s == 0:
                break
            before = history[t, i]
            lo, hi = (int(starts[s - 1]), int(starts[s]) if s < S - 1 else len(pt))
            # Staying (no arrival) wins ties: no bytes spent for nothing.
            best_v, best_from, best_add = before[s], s, 0
            for p in range(lo, hi):
                if not oks[t, i, p]:
                    continue
                v = before[pf[p]] - rho[t] * pcost_f[i, p]
                if v > best_v:
                    best_v, best_from, best_add = v, int(pf[p]), int(pa[p])
            for b in range(data.V):
                if (best_add >> b) & 1:
                    slots[b] = t
            s = best_from
        paths.append(tuple(slots))
    return PriceResult(value=out_value, paths=paths)


def lagrangian_bound(data: SeparateData, pi: np.ndarray, *, allowed: np.ndarray | None = None,
                     must: np.ndarray | None = None) -> tuple[float, PriceResult]:
    """``L(pi)`` of the module doc (held constant included) and the paths that attain it; ``-inf``
    when some object has no path meeting the restrictions. ``pi`` (utility per byte, one per
    budget row) is clipped at 0: the bound holds for every ``pi >= 0``."""
    pi = np.maximum(np.asarray(pi, dtype=np.float64), 0.0)
    rho = np.flip(np.cumsum(np.flip(pi))) if data.cumulative else pi
    res = price_paths(data, rho, allowed=allowed, must=must)
    if (res.value == -np.inf).any():
        return -math.inf, res
    terms = [data.constant, *(pi * data.rhs.astype(np.float64)).tolist(), *res.value.tolist()]
    return math.fsum(terms), res
