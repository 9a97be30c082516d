"""Rolling-horizon schedulers for Problems I-IV: ``rolling:SOLVER``, ``rolling-future:SOLVER``, ``mpc:H``.

``rolling:SOLVER`` is the L3GS scheduler: slot by slot, solve the single-slot MCKP given what
is held (the paper's Lemma 3) with SOLVER (``bb``, ``dp``, ``fptas:EPS``, ``greedy``, ``ilp``)
and commit its answer. ``rolling-future:SOLVER`` values a chunk by the utility it adds over
the rest of the horizon (the GAP form's ``dU~``) instead of at the slot alone. ``mpc:H`` solves
Problem I/II exactly over the next H slots with the ILP and commits the first slot.

How the instance's options are respected:

* ``availability="next_slot"``: a chunk that arrives in slot t is valued from slot t+1 (so the
  last slot schedules nothing: nothing it sends is ever shown).
* ``same_slot_layers=False``: one layer per object per slot, on top of the layers held before
  the slot.
* ``budget="cumulative"`` (one sequential link): unspent bytes carry to the next slot. When
  bytes are left after a slot's MCKP, the link starts the most efficient option (value per
  byte, valued as the slot's MCKP values it) that does not fit them but fits the bytes still
  to come; that download is *in flight*: the following slots' bytes go to it and it arrives
  in the first slot whose cumulative bytes cover it, where the leftover bytes feed that slot's
  MCKP. Nothing else arrives while it is in flight.
* Separate representation: an option is one version; it replaces the held one, and its cost
  is the whole version.
* Signed layer utilities: an option is a whole level valued by the cumulative ``dU`` of the
  layers it adds, so a negative layer is sent only with the layers above it that make the
  level worth more; a layer bought for its value at one slot may lose more later, so each
  answer keeps, per object, its delivered prefix of best value
  (:func:`~l3gs_opt.problem.evaluate.trim_losing_layers`).

Every answer carries as ``bound`` the LP relaxation of Problem I/II (:func:`~.bounds.lp_bound`),
so its gap is certified; ``details`` has the scheduling and bound seconds apart.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from l3gs_opt.errors import SolveError
from l3gs_opt.problem.evaluate import trim_losing_layers
from l3gs_opt.problem.instance import Instance
from l3gs_opt.problem.presolve import shown_value
from l3gs_opt.problem.solution import Solution, Status, finish_solution

from . import _mckp
from ._mckp import MckpResult, OptionTable
from .bounds import lp_bound

__all__ = ["SLOT_SOLVERS", "slot_picker", "slot_gains", "RollingForm", "chunk_form", "run_rolling", "solve_rolling", "solve_mpc"]

#: Names a rolling scheduler accepts for its per-slot solver (``fptas:EPS`` too).
SLOT_SOLVERS = ("bb", "dp", "greedy", "ilp")

Picker = Callable[[OptionTable, "float | None"], MckpResult]


def _ilp_pick(backend: str) -> Picker:
    """Per-slot picker that solves the option table as a one-slot ILP (``separate`` view: one
    row per object, one version per option)."""

    def pick(table: OptionTable, time_left: float | None) -> MckpResult:
        from l3gs_opt.models import solve_ilp

        if table.n == 0:
            return MckpResult(np.zeros(0, np.int64), 0.0, 0.0, True, {})
        cost = np.where(table.valid, table.cost, table.budget + 1)
        view = Instance(representation="separate", bandwidth=[table.budget], cost=np.maximum(cost, 1),
                        utility=np.where(table.valid, table.value, 0.0)[None])
        sol = solve_ilp(view, backend=backend, slot=0, time_limit_s=time_left)
        choice = np.full(table.n, -1, dtype=np.int64)
        for i, k, _ in sol.arrivals:
            choice[i] = k
        value = float(table.value[np.arange(table.n)[choice >= 0], choice[choice >= 0]].sum())
        return MckpResult(choice, value, sol.bound if sol.bound is not None else np.inf,
                          sol.status is Status.OPTIMAL, {})

    return pick


def slot_picker(name: str, *, backend: str = "highs") -> Picker:
    """The per-slot solver behind ``rolling:NAME``: ``bb``, ``dp``, ``greedy``, ``ilp`` or
    ``fptas:EPS``. Raises :class:`SolveError` for anything else."""
    if name == "bb":
        return lambda table, left: _mckp.branch_and_bound(table, time_limit_s=left)
    if name == "dp":
        return lambda table, left: _mckp.dynamic_programme(table)
    if name == "greedy":
        return lambda table, left: _mckp.greedy(table)
    if name == "ilp":
        return _ilp_pick(backend)
    if name.startswith("fptas:"):
        eps = parse_eps(name)
        return lambda table, left: _mckp.fptas(table, eps)
    raise SolveError(f"per-slot solver {name!r} is not one of bb, dp, fptas:EPS, greedy, ilp")


def parse_eps(name: str) -> float:
    """EPS of ``fptas:EPS`` as a float in (0, 1)."""
    text = name.split(":", 1)[1]
    try:
        eps = float(text)
    except ValueError:
        raise SolveError(f"method {name!r}: EPS = {text!r} must be a number in (0, 1)") from None
    if not 0 < eps < 1:
        raise SolveError(f"method {name!r}: EPS = {eps!r} must be in (0, 1)")
    return eps


def slot_gains(instance: Instance, slot: int, held: np.ndarray, *, future: bool) -> np.ndarray:
    """``[J, L]`` value of each unheld chunk when it arrives in ``slot``, given ``held``.

    Myopic (``future=False``): its gain at the first slot it is shown in (``slot``, or
    ``slot + 1`` under next-slot availability); ``future=True``: summed from that slot to the
    end of the horizon. Layered: per-layer utility; separate: the version's utility above the
    best held version, clipped at 0, per slot. Held chunks: 0.
    """
    inst = instance
    first = slot + (1 if inst.options.availability == "next_slot" else 0)
    if first >= inst.T:
        return np.zeros((inst.J, inst.L))
    utility = inst.utility[first:] if future else inst.utility[first:first + 1]
    if inst.layered:
        return np.where(held[None], 0.0, utility).sum(axis=0)
    base = np.where(held[None], utility, 0.0).max(axis=2, initial=0.0)
    return np.where(held[None], 0.0, np.clip(utility - base[:, :, None], 0.0, None)).sum(axis=0)


def bound_phrase(bound: float | None) -> str:
    """How a heuristic's message names its bound."""
    return ("bound is the LP relaxation" if bound is not None else
            "no bound (the LP relaxation did not finish within the time limit, or was not asked for)")


def _bound(instance: Any, with_bound: bool, started: float | None = None,
           time_limit_s: float | None = None) -> tuple[float | None, float]:
    """The answer's LP bound (:func:`~.bounds.lp_bound`) and its seconds, in what is left of
    ``time_limit_s`` from ``started`` (``time.perf_counter()``): None when that ran out first."""
    if not with_bound:
        return None, 0.0
    if time_limit_s is None or started is None:
        return lp_bound(instance)
    return lp_bound(instance, time_limit_s=float(time_limit_s) - (time.perf_counter() - started))


@dataclass(frozen=True)
class RollingForm:
    """What the rolling loop needs to know of an instance form (chunks of Problems I-IV, or items).

    ``units`` index ``held`` (a ``(j, l)`` chunk or an item number); ``table(t, held, fresh,
    budget)`` is the slot's option table, valued at slot ``t`` given ``held``, where ``fresh``
    marks the units that arrived at the start of the slot (under strict layers nothing may go on
    top of them in the same slot), with ``decode(row, option)`` giving the units an option sends.
    """

    held: np.ndarray
    table: Callable[[int, np.ndarray, np.ndarray, int], tuple[OptionTable, Callable[[int, int], list]]]
    arrival: Callable[[Any, int], tuple[int, int, int]]
    finish: Callable[..., Solution]
    held_value: float          # what the held units show over the horizon (added to one-slot bounds)
    bound_label: str
    details: Callable[[], dict[str, Any]] = dict


def chunk_form(instance: Instance, *, future: bool) -> RollingForm:
    """The rolling form of a chunk instance (Problems I-IV)."""
    inst = instance
    strict = not inst.options.same_slot_layers

    def table(t: int, held: np.ndarray, fresh: np.ndarray, budget: int):
        gain = slot_gains(inst, t, held, future=future)
        if strict:
            gain[fresh.any(axis=1)] = 0.0   # a layer that arrived this slot takes no layer on top of it now
        tab = _mckp.build_table(layered=inst.layered, cost=inst.cost, gain=gain, held=held, budget=budget,
                                same_slot_layers=not strict)
        levels = held.sum(axis=1)

        def decode(row: int, option: int) -> list[tuple[int, int]]:
            j, top = int(tab.rows[row]), int(tab.level[row, option])
            return [(j, l) for l in range(int(levels[j]), top + 1)] if inst.layered else [(j, top)]

        return tab, decode

    def finish(arrivals, **kw) -> Solution:
        # A layer worth buying at its slot may lose more later (signed dU): keep each object's
        # best delivered prefix (unchanged without negative utilities).
        return finish_solution(inst, trim_losing_layers(inst, arrivals), problem=inst.problem, **kw)

    return RollingForm(held=inst.held.copy(), table=table, arrival=lambda u, t: (u[0], u[1], t), finish=finish,
                       held_value=shown_value(inst)[1], bound_label="LP relaxation of Problem I/II")


def run_rolling(instance: Any, pick: Picker, *, method: str, future: bool = False,
                time_limit_s: float | None = None, with_bound: bool = True,
                form: RollingForm | None = None) -> Solution:
    """Schedule slot by slot with ``pick`` solving each slot's option table (see module doc).

    ``form`` adapts another instance form (the item form passes its own); default: chunks.
    """
    inst = instance
    started = time.perf_counter()
    form = form if form is not None else chunk_form(inst, future=future)
    T = inst.T
    cumulative = inst.options.budget == "cumulative"
    bandwidth = [int(b) for b in inst.bandwidth]
    held = form.held
    arrivals: list[tuple[int, int, int]] = []
    carry = 0
    flight: tuple[list, int] | None = None   # (units, bytes still to come)
    all_optimal = True
    stopped = ""
    in_flight_count = 0
    result: MckpResult | None = None
    for t in range(T):
        left = None if time_limit_s is None else time_limit_s - (time.perf_counter() - started)
        if left is not None and left <= 0:
            stopped = f"time limit reached before slot {t}; later slots send nothing"
            break
        avail = carry + bandwidth[t] if cumulative else bandwidth[t]
        fresh = np.zeros_like(held)
        if flight is not None:
            units, rest = flight
            if avail < rest:
                flight = (units, rest - avail)
                carry = 0
                continue
            avail -= rest
            for u in units:
                arrivals.append(form.arrival(u, t))
                held[u] = fresh[u] = True
            flight = None
        table, decode = form.table(t, held, fresh, avail)
        result = pick(table, left)
        all_optimal &= bool(result.optimal)
        for row in np.nonzero(result.choice >= 0)[0]:
            for u in decode(int(row), int(result.choice[row])):
                held[u] = True
                avail -= int(inst.cost[u])
                arrivals.append(form.arrival(u, t))
        if not cumulative:
            continue
        carry = avail
        to_come = sum(bandwidth[t + 1:])
        if carry <= 0 or to_come <= 0:
            continue
        # Start an in-flight download with the spare bytes: the most efficient option that does
        # not fit them but fits the bytes still to come.
        wide, wide_decode = form.table(t, held, np.zeros_like(held), carry + to_come)
        if wide.n == 0:
            continue
        cand = wide.valid & (wide.cost > carry)
        if not cand.any():
            continue
        eff = np.where(cand, wide.value / np.maximum(wide.cost, 1), -np.inf)
        r, k = np.unravel_index(int(np.argmax(eff)), eff.shape)
        flight = (wide_decode(int(r), int(k)), int(wide.cost[r, k]) - carry)
        carry = 0
        in_flight_count += 1
    schedule_s = time.perf_counter() - started
    bound, bound_s = _bound(inst, with_bound, started, time_limit_s)
    status = Status.TIME_LIMIT if stopped else Status.FEASIBLE
    if T == 1 and result is not None and all_optimal and not stopped and inst.options.availability == "same_slot":
        # One slot: the rolling answer is the exact single-slot optimum, i.e. the whole problem's.
        status = Status.OPTIMAL
        bound = result.bound + form.held_value
    details: dict[str, Any] = {"schedule_s": schedule_s, "bound_s": bound_s,
                               "bound": form.bound_label if bound is not None else None, **form.details()}
    if cumulative:
        details["in_flight_downloads"] = in_flight_count
    message = (f"{stopped}; {bound_phrase(bound)}" if stopped else
               f"{method}: rolling heuristic; {bound_phrase(bound)}" if status is not Status.OPTIMAL else "")
    return form.finish(arrivals, method=method, status=status, bound=bound, runtime_s=time.perf_counter() - started,
                       message=message, details=details)


def solve_rolling(instance: Instance, solver: str, *, future: bool = False, slot: int | None = None,
                  time_limit_s: float | None = None, backend: str = "highs", with_bound: bool = True,
                  **_ignored: Any) -> Solution:
    """``rolling:SOLVER`` (``future=False``) or ``rolling-future:SOLVER`` (``future=True``)."""
    name = f"{'rolling-future' if future else 'rolling'}:{solver}"
    if slot is not None:
        raise SolveError(f"method {name!r} schedules the whole horizon: slot does not apply "
                         f"(use method {solver!r} for one slot)")
    pick = slot_picker(solver, backend=backend)
    return run_rolling(instance, pick, method=name, future=future, time_limit_s=time_limit_s,
                       with_bound=with_bound)


def solve_mpc(instance: Any, horizon: int, *, slot: int | None = None, time_limit_s: float | None = None,
              backend: str = "highs", with_bound: bool = True, **_ignored: Any) -> Solution:
    """``mpc:H``: each slot, solve the problem exactly over the next ``horizon`` slots (ILP on
    ``backend``) given what is held, commit the first slot's arrivals, roll on. Either instance
    form: Problems I-IV (``Instance``) or the item form (``ItemInstance``, arrivals ``(object,
    item, t)``).

    Under the cumulative budget the bytes not yet spent are added to the window's first slot,
    so the window's cumulative budgets are the real ones. Each window gets an equal share of
    the time left.
    """
    from l3gs_opt.problem.items import ItemInstance
    from l3gs_opt.models import solve_ilp, solve_items_ilp

    name = f"mpc:{horizon}"
    if slot is not None:
        raise SolveError(f"method {name!r} schedules the whole horizon: slot does not apply")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise SolveError(f"method {name!r}: H = {horizon!r} must be a positive integer (slots)")
    inst = instance
    items = isinstance(inst, ItemInstance)
    solve_window = solve_items_ilp if items else solve_ilp

    def unit(j: int, l: int) -> Any:   # what an arrival (j, l or item, t) adds to ``held``
        return l if items else (j, l)

    started = time.perf_counter()
    cumulative = inst.options.budget == "cumulative"
    bandwidth = np.asarray(inst.bandwidth, dtype=np.int64)
    held = inst.held.copy()
    arrivals: list[tuple[int, int, int]] = []
    carry, stopped, window_limits = 0, "", 0
    for t in range(inst.T):
        left = None if time_limit_s is None else time_limit_s - (time.perf_counter() - started)
        if left is not None and left <= 0:
            stopped = f"time limit reached before slot {t}; later slots send nothing"
            break
        end = min(inst.T, t + int(horizon))
        bw = bandwidth[t:end].copy()
        if cumulative:
            bw[0] += carry
        window = inst.replace(bandwidth=bw, utility=inst.utility[t:end], held=held, names=None, meta={})
        sol = solve_window(window, backend=backend, time_limit_s=None if left is None else left / (inst.T - t))
        window_limits += sol.status is Status.TIME_LIMIT
        spent = 0
        for j, l, tt in sol.arrivals:
            if tt == 0:
                arrivals.append((j, l, t))
                held[unit(j, l)] = True
                spent += int(inst.cost[unit(j, l)])
        if cumulative:
            carry = int(bw[0]) - spent
    if not items:
        arrivals = list(trim_losing_layers(inst, arrivals))   # a window cannot see a layer's later losses
    schedule_s = time.perf_counter() - started
    bound, bound_s = _bound(inst, with_bound, started, time_limit_s)
    details = {"schedule_s": schedule_s, "bound_s": bound_s, "windows_at_time_limit": int(window_limits),
               "backend": backend}
    return finish_solution(inst, arrivals, problem=inst.problem, method=name,
                           status=Status.TIME_LIMIT if stopped else Status.FEASIBLE, bound=bound,
                           runtime_s=time.perf_counter() - started,
                           message=f"{stopped or f'{name}: receding horizon'}; {bound_phrase(bound)}",
                           details=details)
