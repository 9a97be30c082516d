"""The paper's Lemma 1 (Problem I == GAP form) and Lemma 3 (T=1 Problem I == single-slot MCKP)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from l3gs_opt import Options, Status, solve
from l3gs_opt.pipeline.synth import synth_instance

from core_helpers import ALL_OPTIONS, option_id, random_instance


@pytest.mark.parametrize("options", ALL_OPTIONS, ids=option_id)
def test_lemma1_problem_I_equals_gap_form(options):
    """Beyond brute-force sizes: both forms solved to proven optimality agree."""
    rng = np.random.default_rng(11)
    for _ in range(3):
        inst = random_instance(rng, options=options, T=5, J=4, L=3, held_p=0.2, cost_range=(1, 20))
        a = solve(inst, "ilp", backend="highs")
        b = solve(inst, "ilp", backend="highs", form="gap")
        assert a.status is b.status is Status.OPTIMAL
        assert a.problem in ("I", "III") and b.problem == "A"
        assert math.isclose(a.objective, b.objective, rel_tol=1e-9)


def test_lemma1_on_a_real_trace():
    inst = synth_instance(objects=5, layers=3, slots=12, seed=4, start=200)
    a = solve(inst, "ilp", backend="highs")
    b = solve(inst, "ilp", backend="cpsat", form="gap")
    assert a.status is Status.OPTIMAL and b.status is Status.OPTIMAL
    assert math.isclose(a.objective, b.objective, rel_tol=1e-9)


@pytest.mark.parametrize("representation", ["layered", "separate"])
@pytest.mark.parametrize("held_p", [0.0, 0.4])
def test_lemma3_one_slot_problem_equals_mckp(representation, held_p):
    rng = np.random.default_rng(5)
    for _ in range(10):
        inst = random_instance(rng, representation=representation, T=1, J=6, L=4, held_p=held_p,
                               cost_range=(1, 30))
        full = solve(inst, "ilp", backend="highs")
        mckp = solve(inst, "ilp", backend="highs", slot=0)
        assert mckp.problem == "MCKP"
        assert math.isclose(full.objective, mckp.objective, rel_tol=1e-9)


def test_lemma3_needs_same_slot_layers():
    """With strict layer order only one new layer per object fits in one slot: still equal."""
    rng = np.random.default_rng(8)
    inst = random_instance(rng, T=1, J=5, L=3, options=Options(same_slot_layers=False), cost_range=(1, 9))
    assert math.isclose(solve(inst, "ilp").objective, solve(inst, "ilp", slot=0).objective, rel_tol=1e-9)
    assert all(l == int(inst.held[j].sum()) for j, l, _ in solve(inst, "ilp", slot=0).arrivals)
