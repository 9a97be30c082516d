"""The cumulative budget's ILP rows: prefix rows over the binary arrivals, no byte carry column.

The carry form made HiGHS and CBC claim wrong optima on two held-out benchmark instances
(models/_common.py: ``add_budget``); here the backends' optimum claims are checked against
``exact``'s (arrived-by form, its own proof) and against each other on those instances.
"""

from __future__ import annotations

import pytest

from l3gs_opt.methods import solve
from l3gs_opt.models.build import build_model
from l3gs_opt.problem.solution import GAP_TOL, Status

from solver_helpers import bench_instance


def _held_out(seed: int):
    return bench_instance(20, seed, "cumulative")


def test_cumulative_rows_are_prefix_rows_over_binaries():
    model = build_model(_held_out(9))
    assert not any(name.startswith(("carry", "r[")) for name in model.row_names + model.var_names)
    assert model.integer.all()   # no continuous column left for a backend's tolerances
    assert any(name.startswith("cumulative[") for name in model.row_names)


@pytest.mark.slow
@pytest.mark.parametrize("seed, backend", [(9, "highs"), (6, "cbc")])
def test_backend_optimum_agrees_with_exact_on_the_instances_the_carry_form_broke(seed, backend):
    inst = _held_out(seed)
    ref = solve(inst, "exact", time_limit_s=120)
    got = solve(inst, "ilp", backend=backend, time_limit_s=120)
    assert ref.status is Status.OPTIMAL and got.status is Status.OPTIMAL
    assert got.objective == pytest.approx(ref.objective, rel=GAP_TOL)

