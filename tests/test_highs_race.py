"""Racing HiGHS runs of one MIP (models/backends/highs_race.py), against brute force."""

from __future__ import annotations

import time

import highspy
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from l3gs_opt.models.backends.highs import new_highs
from l3gs_opt.models.backends.highs_race import RaceOutcome, mip_seeds, race_mip
from solver_helpers import kp01_brute


def _knapsack_builder(value: list[int], weight: list[int], capacity: int, *, time_limit_s: float | None = None):
    """A 0-1 knapsack as a HiGHS MIP (minimise -value), built fresh for each seed."""
    n = len(value)

    def build(seed: int) -> highspy.Highs:
        h = new_highs(time_limit_s=time_limit_s, mip=True)
        h.addCols(n, -np.asarray(value, float), np.zeros(n), np.ones(n), 0, np.zeros(n, np.int32),
                  np.zeros(0, np.int32), np.zeros(0))
        h.changeColsIntegrality(n, np.arange(n, dtype=np.int32), np.full(n, highspy.HighsVarType.kInteger))
        h.addRow(-highspy.kHighsInf, float(capacity), n, np.arange(n, dtype=np.int32), np.asarray(weight, float))
        return h

    return build


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 60), st.integers(1, 40)), min_size=1, max_size=9),
       st.integers(0, 120), st.sampled_from([(0,), (0, 1), (3, 7, 11)]))
def test_race_closes_at_the_brute_force_optimum(items, capacity, seeds):
    value, weight = [v for v, _ in items], [w for _, w in items]
    out = race_mip(_knapsack_builder(value, weight, capacity), seeds)
    assert isinstance(out, RaceOutcome) and len(out.runs) == len(seeds)
    assert out.winner is not None
    opt = kp01_brute(weight, value, capacity)
    winner = out.runs[out.winner]
    assert -winner.getInfo().objective_function_value == pytest.approx(opt, abs=1e-6)
    assert out.best is not None
    assert -out.runs[out.best].getInfo().objective_function_value == pytest.approx(opt, abs=1e-6)
    # The best dual bound is valid and, for a closed model, the optimum.
    assert -out.dual >= opt - 1e-6
    x = np.asarray(out.runs[out.best].getSolution().col_value)
    assert sum(w for w, xi in zip(weight, x) if xi > 0.5) <= capacity


def _hard_builder(n: int = 60, seed: int = 5):
    # Strongly correlated knapsack: HiGHS needs a real tree on it.
    rng = np.random.default_rng(seed)
    weight = rng.integers(10_000, 100_000, n)
    value = weight + 10_000
    return _knapsack_builder(value.tolist(), weight.tolist(), int(weight.sum() // 2))


def test_stop_ends_every_run_at_once():
    t = time.perf_counter()
    out = race_mip(_hard_builder(), (0, 1), stop=lambda: True)
    assert time.perf_counter() - t < 5.0
    assert out.winner is None
    for h in out.runs:
        assert h.getModelStatus() == highspy.HighsModelStatus.kInterrupt


def test_the_first_to_close_ends_the_other():
    # Run 0 gets an easy knapsack, run 1 a market-split system (hard for branch-and-bound, and no
    # time limit): the race must end when run 0 closes, run 1 interrupted.
    n = 30
    easy = _knapsack_builder(list(range(1, n + 1)), list(range(2, n + 2)), 40)
    rng = np.random.default_rng(0)
    a = rng.integers(0, 100, (4, n))

    def build(seed: int) -> highspy.Highs:
        if seed == 0:
            return easy(seed)
        h = new_highs(mip=True)
        h.addCols(n, np.zeros(n), np.zeros(n), np.ones(n), 0, np.zeros(n, np.int32), np.zeros(0, np.int32),
                  np.zeros(0))
        h.changeColsIntegrality(n, np.arange(n, dtype=np.int32), np.full(n, highspy.HighsVarType.kInteger))
        for row in a:
            b = float(row.sum() // 2)
            h.addRow(b, b, n, np.arange(n, dtype=np.int32), row.astype(float))
        return h

    t = time.perf_counter()
    out = race_mip(build, (0, 1))
    assert time.perf_counter() - t < 10.0
    assert out.winner == 0
    assert out.runs[1].getModelStatus() == highspy.HighsModelStatus.kInterrupt


def test_no_seed_is_refused_and_seeds_follow_the_cores(monkeypatch):
    with pytest.raises(ValueError, match="seed"):
        race_mip(_hard_builder(), ())
    import l3gs_opt.models.backends.highs_race as race

    monkeypatch.setattr(race, "RACE_RUNS", 1)
    assert mip_seeds() == (0,)
    monkeypatch.setattr(race, "RACE_RUNS", 64)
    assert mip_seeds() == tuple(range(min(64, race.usable_cores())))


def test_infeasible_model_closes_without_a_solution():
    def build(seed: int) -> highspy.Highs:
        h = new_highs(mip=True)
        h.addCols(1, np.ones(1), np.zeros(1), np.ones(1), 0, np.zeros(1, np.int32), np.zeros(0, np.int32), np.zeros(0))
        h.changeColsIntegrality(1, np.zeros(1, np.int32), np.full(1, highspy.HighsVarType.kInteger))
        h.addRow(0.3, 0.7, 1, np.zeros(1, np.int32), np.ones(1))
        return h

    out = race_mip(build, (0, 1))
    assert out.winner is not None and out.best is None


def test_worker_processes_race_their_share_of_the_cores(monkeypatch):
    import os

    import l3gs_opt.models.backends.highs_race as race
    from l3gs_opt.executors import WORKER_CORES_ENV, run_tasks, usable_cores

    monkeypatch.setattr(race, "RACE_RUNS", 64)
    monkeypatch.delenv(WORKER_CORES_ENV, raising=False)
    cores = usable_cores()
    assert cores == len(os.sched_getaffinity(0))
    assert len(mip_seeds()) == cores
    monkeypatch.setenv(WORKER_CORES_ENV, "1")
    assert mip_seeds() == (0,)
    monkeypatch.setenv(WORKER_CORES_ENV, "not a number")   # ignored
    assert len(mip_seeds()) == cores
    monkeypatch.delenv(WORKER_CORES_ENV)
    seen = {}
    run_tasks([1, 2], lambda task: os.environ.get(WORKER_CORES_ENV), lambda task, got: seen.update({task: got}),
              jobs=2, failed=lambda task, s, why: why)
    assert seen == {1: str(max(1, cores // 2)), 2: str(max(1, cores // 2))}
    assert WORKER_CORES_ENV not in os.environ   # (set in the workers only)


def test_pick_keeps_the_best_checked_solution_and_refuses_an_unchecked_proof():
    # One run (so the winner is run 0, whatever the threads' timing). The exact check below refuses
    # every point with item 0 chosen, the floor what is worth no more than it.
    value, weight = [10, 7, 6], [5, 4, 3]
    out = race_mip(_knapsack_builder(value, weight, 8), (0,))
    assert out.winner == 0
    decode = (lambda col: tuple(int(c > 0.5) for c in col))
    worth = (lambda x: sum(v for v, on in zip(value, x) if on))
    best, ok = out.pick(decode, lambda x: True, worth, 0.0)
    assert worth(best) == kp01_brute(weight, value, 8) == 16 and ok
    assert out.pick(decode, lambda x: True, worth, 16.0) == (None, True)   # nothing above the floor
    best, ok = out.pick(decode, lambda x: x[0] == 0, worth, 0.0)            # (the optimum takes item 0)
    assert best is None and not ok
