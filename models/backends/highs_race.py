"""One MIP, several HiGHS runs at once (different random seeds, one thread each), sharing schedules.

HiGHS 1.14's branch-and-cut runs on one core, and its run time on one model varies several-fold
with the random seed. On a 2-core machine a second run of the same model with another seed costs
no wall time; whichever closes first ends both. Each improving solution one run finds is handed
to the others through HiGHS's user-solution callback, so every run prunes with the best objective
any of them has. Each run's dual bound is valid for the one model, so the best of them is too.
"""

from __future__ import annotations

import math
import sys
import threading
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import highspy
import numpy as np

from l3gs_opt.executors import usable_cores
from l3gs_opt.models.backends import highs as _highs  # noqa: F401  (forked children get a fresh HiGHS pool)

__all__ = ["RACE_RUNS", "RACE_SWITCH_INTERVAL_S", "RaceOutcome", "mip_seeds", "race_mip"]

#: Runs raced at most (one per core this process may use, up to this many).
RACE_RUNS = 2

#: GIL switch interval (s) while the runs race: their callbacks need the GIL (as in
#: :mod:`l3gs_opt.solvers.exact.sides`).
RACE_SWITCH_INTERVAL_S = 1e-4

_CLOSED = (highspy.HighsModelStatus.kOptimal, highspy.HighsModelStatus.kInfeasible,
           highspy.HighsModelStatus.kObjectiveBound)


@dataclass(frozen=True)
class RaceOutcome:
    """The finished runs and which of them closed the model (``winner``; None: none did).

    ``best`` is the run holding the best solution found (None: no run has one); ``dual`` the best
    dual bound of the runs (HiGHS's sense, minimisation: the largest; ``-inf`` when none has one).
    """

    runs: tuple[highspy.Highs, ...]
    winner: int | None
    best: int | None
    dual: float

    def pick(self, decode: Callable[[np.ndarray], Any], check: Callable[[Any], bool],
             value: Callable[[Any], float], floor: float) -> tuple[Any | None, bool]:
        """The best of the runs' solutions (``decode``d from HiGHS's column values) that passes the
        caller's exact ``check`` and is worth more than ``floor`` (None: none is), and whether
        the winner's own solution passed (when it did not, its "closed" proves nothing: HiGHS's
        tolerances let it accept a point the exact check refuses)."""
        best, best_value, winner_ok = None, floor, True
        for k, h in enumerate(self.runs):
            if h.getInfo().primal_solution_status != 2:
                continue
            cand = decode(np.asarray(h.getSolution().col_value))
            if not check(cand):
                winner_ok = winner_ok and k != self.winner
                continue
            v = value(cand)
            if v > best_value:
                best, best_value = cand, v
        return best, winner_ok


def mip_seeds() -> tuple[int, ...]:
    """Seeds to race: one per core this process may use (in a worker pool: its share,
    :func:`l3gs_opt.executors.usable_cores`), at most :data:`RACE_RUNS`."""
    return tuple(range(max(1, min(RACE_RUNS, usable_cores()))))


def race_mip(build: Callable[[int], highspy.Highs], seeds: Sequence[int], *,
             stop: Callable[[], bool] | None = None) -> RaceOutcome:
    """Run ``build(seed)`` (a HiGHS model set up to solve, minimising) for each seed, each in its own
    thread (one seed: in this one), until one closes it, every run ends, or ``stop()`` is true.

    ``build`` may subscribe its own callbacks (they run in the runs' threads). The runs hand each
    other every improving solution (HiGHS checks a handed-over point before using it).
    """
    if not seeds:
        raise ValueError("race_mip needs at least one seed")
    lock = threading.Lock()
    done = threading.Event()
    shared: dict = {"obj": math.inf, "x": None, "version": 0}
    runs = [build(int(seed)) for seed in seeds]
    for h, seed in zip(runs, seeds):
        h.setOptionValue("random_seed", int(seed))
        _share(h, shared, lock, done, stop)
    if len(runs) == 1:
        runs[0].run()
    else:
        old = sys.getswitchinterval()
        sys.setswitchinterval(min(old, RACE_SWITCH_INTERVAL_S))

        def run(h: highspy.Highs) -> None:
            h.run()
            if h.getModelStatus() in _CLOSED:
                done.set()

        workers = [threading.Thread(target=run, args=(h,), name=f"highs-race-{k}", daemon=True)
                   for k, h in enumerate(runs)]
        try:
            for w in workers:
                w.start()
            for w in workers:
                w.join()
        finally:
            sys.setswitchinterval(old)
    winner = next((k for k, h in enumerate(runs) if h.getModelStatus() in _CLOSED), None)
    objs = [h.getInfo().objective_function_value if h.getInfo().primal_solution_status == 2 else math.inf
            for h in runs]
    best = int(np.argmin(objs)) if min(objs) < math.inf else None
    duals = [float(h.getInfo().mip_dual_bound) for h in runs]
    duals = [d for d in duals if math.isfinite(d)]
    return RaceOutcome(tuple(runs), winner, best, max(duals) if duals else -math.inf)


def _share(h: highspy.Highs, shared: dict, lock: threading.Lock, done: threading.Event,
           stop: Callable[[], bool] | None) -> None:
    seen = [0]

    def improving(event) -> None:
        obj = float(event.data_out.objective_function_value)
        with lock:
            if obj < shared["obj"]:
                shared["obj"], shared["x"] = obj, np.array(event.data_out.mip_solution, dtype=np.float64)
                shared["version"] += 1
                seen[0] = shared["version"]

    def user_solution(event) -> None:
        with lock:
            if shared["version"] == seen[0] or shared["obj"] >= float(event.data_out.mip_primal_bound):
                return
            seen[0] = shared["version"]
            x = shared["x"]
        event.data_in.setSolution(x)

    def interrupt(event) -> None:
        if done.is_set() or (stop is not None and stop()):
            event.interrupt()

    h.cbMipImprovingSolution.subscribe(improving)
    h.cbMipUserSolution.subscribe(user_solution)
    for hook in (h.cbSimplexInterrupt, h.cbMipInterrupt):
        hook.subscribe(interrupt)
