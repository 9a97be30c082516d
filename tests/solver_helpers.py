"""Seeded instance generators and checks shared by the solver tests (test_mckp*, test_rolling*, test_solvers*,
test_exact*).

Families for the single-slot MCKP: ``random`` (small integers), ``stiff`` (utilities 1e-9..1e9,
costs 1e2..1e9), ``ties`` (few distinct costs and utilities), ``zero`` / ``huge`` budgets and
``held`` (a prefix of layers / some versions already held).
"""

from __future__ import annotations

import itertools

import numpy as np

from l3gs_opt.problem.evaluate import evaluate_objective, is_feasible
from l3gs_opt.problem.instance import Instance, Options

FAMILIES = ("random", "stiff", "ties", "zero", "huge", "held")
OPTIONS = [Options(), Options(same_slot_layers=False), Options(availability="next_slot"),
           Options(budget="cumulative"), Options(availability="next_slot", same_slot_layers=False, budget="cumulative")]


def bench_instance(J: int, seed: int, budget: str = "per_slot") -> Instance:
    """The bench's T=60 instance (L=4, bundled Lumos5G trace; ``benchmarks/results/exact*.md``):
    60 s is not enough for any method to prove J=20 s0 or J=50 s1."""
    from l3gs_opt.bench.suites import paper_spec

    inst = paper_spec(J, seed).build()
    return inst.replace(options=Options.from_dict({**inst.options.to_dict(), "budget": budget}))


def _held(rng: np.random.Generator, representation: str, J: int, L: int) -> np.ndarray:
    if representation == "layered":
        h = rng.integers(0, L + 1, size=J)
        return np.arange(L)[None, :] < h[:, None]
    return rng.random((J, L)) < 0.3


def mckp_instance(seed: int, family: str, *, J: int = 3, L: int = 3, representation: str | None = None,
                  same_slot_layers: bool = True) -> Instance:
    """A one-slot instance of a family (brute force handles J * L <= 16 comfortably)."""
    rng = np.random.default_rng(seed)
    representation = representation or ("layered" if rng.random() < 0.5 else "separate")
    if family == "stiff":
        cost = np.round(10.0 ** rng.uniform(2, 9, size=(J, L))).astype(np.int64)
        utility = 10.0 ** rng.uniform(-9, 9, size=(1, J, L))
    elif family == "ties":
        cost = rng.choice([2, 4, 6], size=(J, L))
        utility = rng.choice([0.0, 1.0, 2.0, 3.0], size=(1, J, L))
    else:
        cost = rng.integers(1, 30, size=(J, L))
        utility = rng.integers(0, 20, size=(1, J, L)).astype(np.float64) + rng.random((1, J, L)).round(3)
    held = _held(rng, representation, J, L) if family == "held" else np.zeros((J, L), bool)
    total = int(cost.sum())
    if family == "zero":
        budget = 0
    elif family == "huge":
        budget = 4 * total
    else:
        budget = int(rng.integers(0, total + 1))
    return Instance(representation=representation, bandwidth=[budget], cost=cost, utility=utility, held=held,
                    options=Options(same_slot_layers=same_slot_layers))


def multi_instance(seed: int, *, J: int = 2, L: int = 2, T: int = 3, representation: str | None = None,
                   options: Options | None = None, held: bool = False) -> Instance:
    """A tiny multi-slot instance (brute force: (T + 1) ** (J * L) schedules)."""
    rng = np.random.default_rng(seed)
    representation = representation or ("layered" if rng.random() < 0.5 else "separate")
    cost = rng.integers(1, 10, size=(J, L))
    utility = rng.integers(0, 10, size=(T, J, L)) + rng.random((T, J, L)).round(2)
    bandwidth = rng.integers(0, int(cost.sum()) // 2 + 2, size=T)
    h = _held(rng, representation, J, L) if held else np.zeros((J, L), bool)
    return Instance(representation=representation, bandwidth=bandwidth, cost=cost, utility=utility, held=h,
                    options=options or Options())


def rel_close(a: float, b: float, rtol: float = 1e-9) -> bool:
    """Objectives agree to ``rtol`` relative (float sums of the same terms in other orders; 1e-9
    is ``GAP_TOL``, the gap that counts as optimal)."""
    return abs(a - b) <= rtol * max(abs(a), abs(b), 1e-300)


def check_answer(inst: Instance, sol) -> None:
    """An exact method's answer: feasible in exact bytes, its objective the instance's own
    evaluation of its schedule, a bound at or above it."""
    assert is_feasible(inst, sol.arrivals)
    assert sol.objective == evaluate_objective(inst, sol.arrivals)
    assert sol.bound is not None and sol.bound >= sol.objective


def kp01_brute(weight: list[int], profit: list[int], capacity: int) -> int:
    """The optimum of a 0-1 knapsack by enumeration (n <= ~16), in exact integers."""
    best = 0
    for pick in itertools.product((0, 1), repeat=len(weight)):
        if sum(w for w, on in zip(weight, pick) if on) <= capacity:
            best = max(best, sum(p for p, on in zip(profit, pick) if on))
    return best
