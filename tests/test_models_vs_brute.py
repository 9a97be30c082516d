"""Every exact model equals brute force, for both representations and every option."""

from __future__ import annotations

import math
import zlib

import numpy as np
import pytest

from l3gs_opt import Status, is_feasible, solve

from core_helpers import ALL_OPTIONS, option_id, random_instance

REL = 1e-9  # objectives are re-evaluated with fsum; backends solve to zero gap


def close(a: float, b: float) -> bool:
    return math.isclose(a, b, rel_tol=REL, abs_tol=1e-12)


@pytest.mark.parametrize("options", ALL_OPTIONS, ids=option_id)
@pytest.mark.parametrize("representation", ["layered", "separate"])
def test_problem_equals_brute_force(representation, options):
    rng = np.random.default_rng(zlib.crc32(f"{representation}-{option_id(options)}".encode()))
    for trial in range(6):
        inst = random_instance(rng, representation=representation, options=options, T=3, J=2, L=2,
                               held_p=0.3 if trial % 2 else 0.0)
        ref = solve(inst, "brute")
        forms = ["standard", "gap"] if representation == "layered" else ["standard"]
        for form in forms:
            for presolve in (True, False):
                sol = solve(inst, "ilp", backend="highs", form=form, presolve=presolve)
                assert sol.status is Status.OPTIMAL, sol.message
                assert close(sol.objective, ref.objective), (form, presolve, sol.objective, ref.objective, inst.to_dict())
                assert is_feasible(inst, sol.arrivals)


@pytest.mark.parametrize("options", ALL_OPTIONS[:4], ids=option_id)
@pytest.mark.parametrize("representation", ["layered", "separate"])
def test_single_slot_mckp_equals_brute_force(representation, options):
    rng = np.random.default_rng(7)
    for trial in range(8):
        inst = random_instance(rng, representation=representation, options=options, T=2, J=3, L=3, held_p=0.3)
        for slot in range(inst.T):
            ref = solve(inst, "brute", slot=slot)
            for presolve in (True, False):
                sol = solve(inst, "ilp", backend="highs", slot=slot, presolve=presolve)
                assert sol.problem == "MCKP" and sol.slot == slot
                assert sol.status is Status.OPTIMAL
                assert close(sol.objective, ref.objective), (slot, presolve, inst.to_dict())
                assert all(t == slot for _, _, t in sol.arrivals)


def test_presolve_shrinks_and_reports_sizes():
    rng = np.random.default_rng(3)
    inst = random_instance(rng, T=6, J=4, L=3, held_p=0.4, zero_p=0.5)
    sol = solve(inst, "ilp", backend="highs")
    assert sol.size_before.variables >= sol.size_after.variables
    assert sol.size_before.constraints >= sol.size_after.constraints
    naive = solve(inst, "ilp", backend="highs", presolve=False)
    assert naive.size_before == naive.size_after == sol.size_before
    assert close(naive.objective, sol.objective)
