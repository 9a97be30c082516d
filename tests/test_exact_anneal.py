"""The first-fit decoder and the annealing over chunk orders (solvers/exact/anneal.py).

Checked against brute force (every optimum is the decoding of its slot order), against the plain
Python decoder (the compiled one decodes every order alike), and for feasibility in exact bytes.
"""

from __future__ import annotations

import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core_helpers import PER_SLOT_OPTIONS, random_instance
from l3gs_opt import solve
from l3gs_opt.errors import SolveError
from l3gs_opt.problem.evaluate import evaluate_objective, is_feasible
from l3gs_opt.solvers.brute_force import solve_brute_force
from l3gs_opt.solvers.exact import _anneal_kernels as kernels
from l3gs_opt.solvers.exact.anneal import anneal_race, anneal_schedule, first_fit, slot_order
from l3gs_opt.solvers.exact.lagrange import assignment_feasible, assignment_value, gap_data

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _compiled_decode(data, order):
    """The compiled decoder on ``order``: a round of no moves returns the decoding of its start."""
    _, value, assign = kernels.anneal(order, data.cost, data.profit, data.allowed, data.lower, data.upper,
                                      bool(data.strict), data.budget.astype(np.int64), 0, 1.0, 0.5, 3, 0)
    return value, assign


@SETTINGS
@given(seed=st.integers(0, 10_000), opt=st.integers(0, len(PER_SLOT_OPTIONS) - 1), held=st.booleans())
def test_every_optimum_is_the_decoding_of_its_slot_order(seed: int, opt: int, held: bool) -> None:
    """The module doc's claim, against brute force: decoding an optimal schedule's slot order puts
    each of its chunks in its slot or earlier, feasibly, at the optimum's value."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=3, J=3, L=2, options=PER_SLOT_OPTIONS[opt], held_p=0.4 if held else 0.0)
    ref = solve_brute_force(inst)
    data = gap_data(inst)
    best = data.assignment(ref.arrivals)
    out = first_fit(data, slot_order(data, best))
    assert assignment_feasible(data, out)
    on = best >= 0
    assert (out[on] >= 0).all() and (out[on] <= best[on]).all()
    assert assignment_value(data, out) >= ref.objective - 1e-9 * max(1.0, abs(ref.objective))


@SETTINGS
@given(seed=st.integers(0, 10_000), opt=st.integers(0, len(PER_SLOT_OPTIONS) - 1))
def test_compiled_decoder_equals_the_reference(seed: int, opt: int) -> None:
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=5, J=4, L=3, options=PER_SLOT_OPTIONS[opt], tight=0.4, held_p=0.3)
    data = gap_data(inst)
    if data.n == 0:
        return
    for _ in range(5):
        order = rng.permutation(data.n).astype(np.int64)
        ref = first_fit(data, order)
        value, assign = _compiled_decode(data, order)
        assert np.array_equal(assign, ref)
        assert assignment_feasible(data, ref)
        assert value == pytest.approx(assignment_value(data, ref) - data.constant, rel=1e-12, abs=1e-12)


@SETTINGS
@given(seed=st.integers(0, 10_000), opt=st.integers(0, len(PER_SLOT_OPTIONS) - 1), held=st.booleans())
def test_anneal_is_feasible_never_below_its_start_never_above_the_optimum(seed: int, opt: int, held: bool) -> None:
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=3, J=3, L=2, options=PER_SLOT_OPTIONS[opt], held_p=0.4 if held else 0.0)
    data = gap_data(inst)
    ref = solve_brute_force(inst).objective
    start = np.full(data.n, -1, dtype=np.int64)
    out = anneal_schedule(data, start, rounds=1, seed=seed, moves=200)
    assert assignment_feasible(data, out)
    assert is_feasible(inst, data.arrivals(out))
    value = assignment_value(data, out)
    assert value == pytest.approx(evaluate_objective(inst, data.arrivals(out)), rel=1e-12, abs=1e-12)
    assert value >= assignment_value(data, start)
    assert value <= ref + 1e-9 * max(1.0, abs(ref))


@SETTINGS
@given(seed=st.integers(0, 10_000), opt=st.integers(0, len(PER_SLOT_OPTIONS) - 1))
def test_anneal_race_is_the_first_best_of_its_chains(seed: int, opt: int) -> None:
    """Chains raced in threads give what each gives alone (the kernel shares nothing between
    calls), and the race keeps the best, the earliest seed on a tie."""
    rng = np.random.default_rng(seed)
    inst = random_instance(rng, T=4, J=4, L=2, options=PER_SLOT_OPTIONS[opt], tight=0.5)
    data = gap_data(inst)
    seeds = (seed, seed + 1, seed + 2)
    alone = [anneal_schedule(data, None, rounds=2, seed=s, moves=300) for s in seeds]
    values = [assignment_value(data, a) for a in alone]
    first_best = alone[values.index(max(values))]
    out = anneal_race(data, None, seeds=seeds, rounds=2, moves=300)
    assert np.array_equal(out, first_best)
    assert assignment_feasible(data, out) and is_feasible(inst, data.arrivals(out))


def test_anneal_stops_between_rounds_when_asked() -> None:
    """``stop`` is polled before each round: true at once runs none (the start comes back); in a
    race, a chain that fails ends its sibling too, and the failure reaches the caller."""
    inst = random_instance(np.random.default_rng(3), T=4, J=6, L=2, tight=0.5)
    data = gap_data(inst)
    start = np.full(data.n, -1, dtype=np.int64)
    assert np.array_equal(anneal_schedule(data, start, rounds=10**6, moves=200, stop=lambda: True), start)
    assert np.array_equal(anneal_race(data, start, seeds=(0, 1), rounds=10**6, moves=200, stop=lambda: True), start)
    calls = []

    def failing() -> bool:   # raises once, in whichever chain asks fifth: the other must be told
        calls.append(1)
        if len(calls) == 5:
            raise RuntimeError("chain failed")
        return False

    began = time.perf_counter()
    with pytest.raises(RuntimeError, match="chain failed"):
        anneal_race(data, start, seeds=(0, 1), rounds=10**6, moves=200, stop=failing)
    assert time.perf_counter() - began < 30.0   # 10**6 rounds would take minutes


def test_anneal_race_needs_a_seed() -> None:
    data = gap_data(random_instance(np.random.default_rng(0), T=2, J=2, L=2))
    with pytest.raises(SolveError, match="at least one seed"):
        anneal_race(data, None, seeds=(), rounds=1)


def test_anneal_finds_the_optimum_of_small_instances() -> None:
    """Not a proof, a search: on 20 seeded instances (6 objects of 2 layers over 4 slots) a round of
    2,000 moves reaches the ILP's proven optimum on nearly all (a decoder that could not express an
    optimum, or a search that did not move, fails this)."""
    hits = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        inst = random_instance(rng, T=4, J=6, L=2, tight=0.5)
        data = gap_data(inst)
        ref = solve(inst, "ilp").objective
        out = anneal_schedule(data, None, rounds=1, seed=seed, moves=2000)
        hits += assignment_value(data, out) >= ref - 1e-9 * max(1.0, ref)
    assert hits >= 18


def test_anneal_improves_a_heuristic_at_scale() -> None:
    """A J=20, L=4, T=60 instance of the paper's scale: from rolling-future:bb's schedule a few rounds
    beat it and stay feasible in exact bytes."""
    from l3gs_opt.bench.suites import paper_spec

    inst = paper_spec(20, 4).build()
    data = gap_data(inst)
    start = data.assignment(solve(inst, "rolling-future:bb", options={"bound": False}).arrivals)
    out = anneal_schedule(data, start, deadline=time.perf_counter() + 1.0, seed=0)
    assert assignment_feasible(data, out) and is_feasible(inst, data.arrivals(out))
    assert assignment_value(data, out) > assignment_value(data, start) * 1.01


def test_empty_and_start_kept() -> None:
    rng = np.random.default_rng(3)
    inst = random_instance(rng, T=2, J=2, L=2)
    data = gap_data(inst)
    best = data.assignment(solve_brute_force(inst).arrivals)
    out = anneal_schedule(data, best, rounds=1, moves=10)
    assert assignment_value(data, out) >= assignment_value(data, best)


def test_the_anneal_method() -> None:
    """``solve(..., "anneal")``: a feasible schedule labelled ``feasible`` (never optimal), the LP
    bound above it, the same schedule on a second call (fixed rounds and seeds), and the instances
    it does not take refused by name."""
    from l3gs_opt import Options
    from l3gs_opt.errors import SolveError
    from l3gs_opt.problem.solution import Status

    rng = np.random.default_rng(7)
    inst = random_instance(rng, T=4, J=4, L=3, tight=0.5)
    sol = solve(inst, "anneal")
    assert sol.status is Status.FEASIBLE and is_feasible(inst, sol.arrivals)
    assert sol.bound is not None and sol.bound >= sol.objective - 1e-9
    assert sol.objective <= solve(inst, "ilp").objective + 1e-9
    assert solve(inst, "anneal").arrivals == sol.arrivals
    assert solve(inst, "anneal", options={"bound": False}).bound is None
    with pytest.raises(SolveError, match="slot does not apply"):
        solve(inst, "anneal", slot=0)
    with pytest.raises(SolveError, match="budget 'cumulative' is not supported"):
        solve(inst.replace(options=Options(budget="cumulative")), "anneal")
    separate = random_instance(rng, representation="separate", T=3, J=2, L=2)
    with pytest.raises(SolveError, match="separate representation"):
        solve(separate, "anneal")


def test_a_deadline_sizes_the_rounds() -> None:
    """A J=50 round of the default size takes about 2 s here; under a 0.5 s deadline the rounds are cut
    to fit (the first one measures the speed), so the search ends near it (the margin is for a loaded
    machine), and a deadline already passed runs nothing."""
    from l3gs_opt.bench.suites import paper_spec

    data = gap_data(paper_spec(50, 0).build())
    start = np.full(data.n, -1, dtype=np.int64)
    anneal_schedule(data, start, rounds=1, moves=10)   # compiled or loaded from the cache first
    began = time.perf_counter()
    out = anneal_schedule(data, start, deadline=began + 0.5)
    assert time.perf_counter() - began < 0.5 + 1.0
    assert assignment_feasible(data, out) and assignment_value(data, out) > 0
    assert np.array_equal(anneal_schedule(data, start, deadline=time.perf_counter() - 1.0), start)


@pytest.mark.parametrize("seed", range(4))
def test_patience_stops_after_rounds_that_find_nothing(monkeypatch, seed: int) -> None:
    """With ``patience`` p (no deadline: every round has its full size and a fixed seed) the search
    stops after p rounds in a row that found nothing better: its schedule is the one of the same
    number of rounds without patience, and p rounds fewer are worth as much."""
    from l3gs_opt.solvers.exact import anneal

    inst = random_instance(np.random.default_rng(seed), T=8, J=6, L=3, tight=0.3)
    data = gap_data(inst)
    start = np.full(data.n, -1, dtype=np.int64)
    calls = []
    real = anneal._kernels()

    class Counting:
        def anneal(self, *a):
            calls.append(1)
            return real.anneal(*a)

    monkeypatch.setattr(anneal, "_kernels", lambda: Counting())
    out = anneal_schedule(data, start, rounds=60, moves=200, patience=2)
    ran = len(calls)
    assert 2 <= ran < 60
    monkeypatch.setattr(anneal, "_kernels", lambda: real)
    same = anneal_schedule(data, start, rounds=ran, moves=200)
    assert np.array_equal(out, same)
    assert assignment_value(data, anneal_schedule(data, start, rounds=ran - 2, moves=200)) == \
        assignment_value(data, out)
